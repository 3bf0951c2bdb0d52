"""PegInsertionSide-v1 as the library reads it: the Panda's controllers, the peg's subtasks, the scene the planner may
know, and the simulator's predicates kept apart as the privileged truth."""

from __future__ import annotations

import numpy as np
import sapien
import torch

from policy_composer.tasks.base import TaskDescription
from policy_composer.tasks.peg_insertion_side.env import ArmState, make_env, step_unobserved
from policy_composer.tasks.peg_insertion_side.expert import PegInsertionSideExpert
from policy_composer.tasks.peg_insertion_side.flags import predicates, stage_of
from policy_composer.tasks.peg_insertion_side.kinematics import HAND_IN_HOLE, grasp_turn, hand_in_hole, rule_out
from policy_composer.tasks.peg_insertion_side.scene import PegScene, pose0
from policy_composer.tasks.peg_insertion_side.spec import EPISODE_LIMIT, SPEC
from policy_composer.tasks.peg_insertion_side.subtasks import INSERTIONS, SUBTASKS, TASK_SEQUENCE

PROGRESS = ("peg_grasped", "peg_at_hole", "peg_inserted", "peg_seated")


def make_library_env(obs_mode: str, settings, cameras: tuple[str, ...] | None = None, **kwargs):
    """The env at the settings' resolution; ManiSkill renders both cameras whichever are asked for. An episode may run
    to EPISODE_LIMIT control steps (ManiSkill's default is MAX_EPISODE_STEPS)."""
    kwargs.setdefault("max_episode_steps", EPISODE_LIMIT)
    return make_env(obs_mode=obs_mode, sensor_configs={"width": settings.resolution, "height": settings.resolution},
                    **kwargs)


def observe(env) -> dict:
    """The observation of the scene now, as the made env gives it (with `extra.state`)."""
    while not isinstance(env, ArmState):
        env = env.env
    return env.observation(env.unwrapped.get_obs())


def hold_action(env) -> torch.Tensor:
    """(1, 8): the arm and the gripper at their current targets."""
    controllers = env.agent.controller.controllers
    gripper = controllers["gripper"]
    low, high = gripper.config.lower, gripper.config.upper
    return torch.cat([controllers["arm"]._target_qpos, 2 * (gripper._target_qpos[..., :1] - low) / (high - low) - 1],
                     dim=-1)


def env_action(env, action: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(action, dtype=torch.float32).reshape(1, -1)


def stage(env, info: dict | None = None, flags: dict | None = None) -> int:
    """0 pick, 1 move, 2 insert, 3 done (the info's, or from the predicates `flags` where the caller has them)."""
    if info is not None and "stage" in info:
        return int(info["stage"][0])
    return int(stage_of(predicates(env) if flags is None else flags)[0])


def labels(env, info: dict | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """The stage, the peg's head in the hole's frame (m; what the insertion corrects, x along the axis into the box) and
    the predicates."""
    u = env.unwrapped
    flags = predicates(u)
    offset = (pose0(u.box_hole_pose).inv() * pose0(u.peg.pose) * sapien.Pose([float(u.peg_half_sizes[0, 0]), 0, 0])
              ).p.astype(np.float32)
    return stage(u, flags=flags), offset, np.array([float(v[0]) for v in flags.values()], dtype=np.float32)


def whereabouts(env, info: dict | None = None) -> str:
    flags = predicates(env)
    for name, words in (("peg_seated", "in the hole"), ("peg_inserted", "pushed past the box's far face"),
                        ("peg_at_hole", "in the hand at the hole"), ("peg_grasped", "in the hand")):
        if bool(flags[name][0]):
            return words
    return "out of the hand"


TASK = TaskDescription(
    spec=SPEC,
    arm="agent",
    progress=PROGRESS,
    grasped="peg_grasped",
    subtasks=SUBTASKS,
    sequence=TASK_SEQUENCE,
    insertions=INSERTIONS,
    scene=PegScene,
    make_env=make_library_env,
    expert=PegInsertionSideExpert,
    observe=observe,
    truth=predicates,
    hold_action=hold_action,
    env_action=env_action,
    whereabouts=whereabouts,
    labels=labels,
    stage=stage,
    extra_proprioception=HAND_IN_HOLE,
    proprioception=hand_in_hole,
    rule_out=rule_out,
    reset_starts={"insert": "pre_insertion"},
    expert_starts={"move": "move"},
    start_expert=PegInsertionSideExpert,
    step_unobserved=step_unobserved,
    grasp_turn=grasp_turn,
)
