"""ManiSkill's own PegInsertionSide-v1, as mani-skill ships it, seen through this project's eyes: the subtask predicates
its recordings are labelled with, a strict success beside ManiSkill's, and the observation entry the library reads.

**Task Description:** the Panda (``panda_wristcam``: ManiSkill's ``hand_camera`` on the hand, and the env's
``base_camera``) picks up a peg lying on the table and pushes its head sideways into the hole of a box.

**Randomizations:** ManiSkill's: the peg's length (85-125 mm half-length) and radius (15-25 mm, the hole 3 mm
wider), the hole's place in the box, the peg's and the box's positions and yaws on the table.

**Success Conditions:** ManiSkill's ``success`` holds once the peg's head is at most 15 mm short of the hole's centre
plane and within the hole's radius; it has no bound the other way, so a peg pushed through and past the box counts
(ManiSkill issue 1391). ``strict_success`` asks, as well, that the head be no farther in than the box's far face.

The env is made by mani-skill itself (``gym.make``), not copied: this module reads its state, and one wrapper adds
what the library reads of a task: ``extra.state`` (the arm's joints and the gripper's width, its
`observation.state`), ``extra.scene`` (the hole's pose, the peg's size and the grasp planned, as the planner knows
them), the strict
success as ``info["success"]`` (ManiSkill's own beside it as ``info["success_maniskill"]``), the stage, and a second
start state (``reset(options={"start": "pre_insertion"})``: the peg in the hand in front of the hole, where the
insertion begins).
"""

from __future__ import annotations

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PegInsertionSide-v1)
import torch

from policy_composer.tasks.peg_insertion_side.expert import PegInsertionSideExpert
from policy_composer.tasks.peg_insertion_side.flags import (  # noqa: F401  (the adapter's readings, re-exported)
    HOLE_ENTRY,
    PRE_INSERTION_DISTANCE,
    box_half_depth,
    predicates,
    stage_of,
    strict_success,
)
from policy_composer.tasks.peg_insertion_side.scene import plan_grasp, planned_grasp
from policy_composer.tasks.peg_insertion_side.spec import (  # noqa: F401  (CAMERA_NAMES and PREDICATES: the task's names)
    CAMERA_NAMES,
    CONTROL_MODE,
    ENV_ID,
    PREDICATES,
    ROBOT,
)

PRE_INSERTION_STEPS = 200  # control steps the scripted expert may take to bring the peg to the pre-insertion pose


class ArmState(gym.Wrapper):
    """PegInsertionSide-v1 as the library reads a task.

    - `extra.state`, (B, 8): the arm's 7 joint angles and the gripper's width (both fingers' positions summed), as the
      library's controllers and recordings read a task's joint state;
    - `extra.scene`, (B, 11): the hole's pose in the arm's base frame (position, quaternion wxyz), the peg's
      half-length and half-width, and the grasp planned this episode (its tilt and offset, `scene.plan_grasp`; the
      library's pick-up's until one is), what the planner knows of the scene (`observation.environment_state`);
    - `info["success"]`: the strict success (ManiSkill's is `info["success_maniskill"]`), and `info["stage"]`;
    - `reset(options={"start": "pre_insertion"})`: the scripted expert picks the peg up and carries it to the
      pre-insertion pose, unobserved (no camera renders), and the episode starts there, at step 0, with the carry's
      residual error uncorrected. Where the expert does not get there (its carry found no plan) the episode starts
      where it stopped, and the subtask's initiation set says whether it may run from there.
    """

    def reset(self, *, seed=None, options=None):
        options = dict(options or {})
        start = options.pop("start", "table")
        obs, info = self.env.reset(seed=seed, options=options)
        plan_grasp(self.env)
        if start == "pre_insertion":
            self._carry_to_the_hole(seed)
            info = self.env.unwrapped.get_info()
            obs = self.env.unwrapped.get_obs(info)
        elif start != "table":
            raise ValueError(f"PegInsertionSide-v1 starts at 'table' or 'pre_insertion', not {start!r}")
        return self.observation(obs), self._info(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self.observation(obs), reward, terminated, truncated, self._info(info)

    def observation(self, obs):
        if not isinstance(obs, dict) or "agent" not in obs:
            raise ValueError("the library reads PegInsertionSide-v1 with obs_mode 'state_dict' or 'rgb', not "
                             f"{self.env.unwrapped.obs_mode!r}")
        qpos = obs["agent"]["qpos"]
        extra = obs.setdefault("extra", {})
        extra["state"] = torch.cat([qpos[:, :7], qpos[:, 7:8] + qpos[:, 8:9]], dim=-1)
        u = self.env.unwrapped
        extra["scene"] = torch.cat([(u.agent.robot.pose.inv() * u.box_hole_pose).raw_pose, u.peg_half_sizes[:, :2],
                                    planned_grasp(u)], dim=-1)
        return obs

    def _info(self, info: dict) -> dict:
        flags = predicates(self.env)
        info["success_maniskill"], info["success"] = info["success"], flags["peg_seated"]
        info["stage"] = stage_of(flags)
        return info

    def _carry_to_the_hole(self, seed) -> None:
        u = self.env.unwrapped
        expert = PegInsertionSideExpert(u)
        expert.reset(seed)
        for _ in range(PRE_INSERTION_STEPS):
            if expert.phase in ("align", "insert", "done"):
                break
            step_unobserved(u, expert.act())
        u._elapsed_steps[:] = 0  # the episode starts here


def step_unobserved(env, action) -> None:
    """A control step without an observation: physics only, no camera renders (ManiSkill's `step` less its
    observation); for driving the scene where no one looks."""
    u = env.unwrapped
    u._step_action(action)
    u._elapsed_steps += 1


def make_env(**kwargs) -> gym.Env:
    """PegInsertionSide-v1 with the wrist camera robot, in joint-position control unless `control_mode` says otherwise;
    `kwargs` go to `gym.make` (obs_mode, max_episode_steps, sensor_configs, ...)."""
    kwargs.setdefault("control_mode", CONTROL_MODE)
    return ArmState(gym.make(ENV_ID, robot_uids=ROBOT, **kwargs))

