"""ManiSkill's own PegInsertionSide-v1, as mani-skill ships it, seen through this project's eyes: the subtask predicates
its recordings are labelled with, a strict success beside ManiSkill's, and the observation entry the library reads.

**Task Description:** the Panda (``panda_wristcam``: ManiSkill's ``hand_camera`` on the hand, and the env's
``base_camera``) picks up a peg lying on the table and pushes its head sideways into the hole of a box.

**Randomizations:** ManiSkill's: the peg's length (85-125 mm half-length) and radius (15-25 mm, the hole 3 mm
wider), the hole's place in the box, the peg's and the box's positions and yaws on the table.

**Success Conditions:** ManiSkill's ``success`` holds once the peg's head is at most 15 mm short of the hole's centre
plane and within the hole's radius; it has no bound the other way, so a peg pushed through and past the box counts
(ManiSkill issue 1391). ``strict_success`` asks, as well, that the head be no farther in than the box's far face.

The env is made by mani-skill itself (``gym.make``), not copied: this module reads its state, and one observation
wrapper adds ``extra.state`` (the arm's joints and the gripper's width, the library's `observation.state`).
"""

from __future__ import annotations

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PegInsertionSide-v1)
import torch

from policy_composer.tasks.peg_insertion_side.spec import (  # noqa: F401  (CAMERA_NAMES and PREDICATES: the task's names)
    CAMERA_NAMES,
    CONTROL_MODE,
    ENV_ID,
    PREDICATES,
    ROBOT,
)

HOLE_ENTRY = -0.015  # ManiSkill's bound: the peg's head this far short of the hole's centre plane, along its axis (m)
PRE_INSERTION_DISTANCE = 0.05  # the peg's head at most this far in front of the box's near face (m)
ALIGN_TOL_DEG = 10.0  # the peg's axis within this of the hole's at the pre-insertion pose


class ArmState(gym.ObservationWrapper):
    """Adds `extra.state`, (B, 8): the arm's 7 joint angles and the gripper's width (both fingers' positions summed),
    as the library's controllers and recordings read a task's joint state."""

    def observation(self, obs):
        if not isinstance(obs, dict) or "agent" not in obs:
            raise ValueError("the library reads PegInsertionSide-v1 with obs_mode 'state_dict' or 'rgb', not "
                             f"{self.env.unwrapped.obs_mode!r}")
        qpos = obs["agent"]["qpos"]
        obs.setdefault("extra", {})["state"] = torch.cat([qpos[:, :7], qpos[:, 7:8] + qpos[:, 8:9]], dim=-1)
        return obs


def make_env(**kwargs) -> gym.Env:
    """PegInsertionSide-v1 with the wrist camera robot, in joint-position control unless `control_mode` says otherwise;
    `kwargs` go to `gym.make` (obs_mode, max_episode_steps, sensor_configs, ...)."""
    kwargs.setdefault("control_mode", CONTROL_MODE)
    return ArmState(gym.make(ENV_ID, robot_uids=ROBOT, **kwargs))


def box_half_depth(env) -> torch.Tensor:
    """(B,) half the box's depth along the hole's axis: ManiSkill builds the box as deep as the peg is long."""
    return env.unwrapped.peg_half_sizes[:, 0]


def _not_past(env, inserted: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
    """ManiSkill's `has_peg_inserted()` (inserted, the peg's head in the hole's frame, x into the box), with the head
    no farther in than the box's far face."""
    return inserted & (head[:, 0] <= box_half_depth(env))


def strict_success(env) -> torch.Tensor:
    """(B,) bool: ManiSkill's success, with the peg's head no farther in than the box's far face."""
    return _not_past(env, *env.unwrapped.has_peg_inserted())


def predicates(env) -> dict[str, torch.Tensor]:
    """Each of PREDICATES from the simulator's truth, (B,) bool: privileged, for labels and the oracle."""
    u = env.unwrapped
    inserted, head = u.has_peg_inserted()
    radius = u.box_hole_radii
    peg_axis = u.peg.pose.to_transformation_matrix()[:, :3, 0]
    hole_axis = u.box_hole_pose.to_transformation_matrix()[:, :3, 0]
    aligned = (peg_axis * hole_axis).sum(-1) > torch.cos(torch.deg2rad(torch.tensor(ALIGN_TOL_DEG)))
    on_axis = torch.linalg.norm(head[:, 1:], dim=-1) < radius
    near_face = -box_half_depth(u)
    in_front = (head[:, 0] < near_face) & (head[:, 0] > near_face - PRE_INSERTION_DISTANCE)
    grasped = u.agent.is_grasping(u.peg)
    return {"peg_grasped": grasped, "peg_at_hole": grasped & aligned & on_axis & in_front,
            "peg_inserted": inserted, "peg_seated": _not_past(u, inserted, head)}
