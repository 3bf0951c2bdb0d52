"""PegInsertionSide-v1 as the library reads it: the Panda's controllers, the peg's subtasks, the scene the planner may
know, and the simulator's predicates kept apart as the privileged truth."""

from __future__ import annotations

import numpy as np
import torch

from policy_composer.tasks.base import TaskDescription
from policy_composer.tasks.peg_insertion_side.env import ArmState, make_env, predicates
from policy_composer.tasks.peg_insertion_side.expert import PegInsertionSideExpert
from policy_composer.tasks.peg_insertion_side.scene import PegScene, pose0
from policy_composer.tasks.peg_insertion_side.spec import SPEC
from policy_composer.tasks.peg_insertion_side.subtasks import INSERTIONS, SUBTASKS, TASK_SEQUENCE

PROGRESS = ("peg_grasped", "peg_at_hole", "peg_inserted", "peg_seated")
EPISODE_LIMIT = 200  # control steps an episode of the library's may take: twice ManiSkill's default


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
    """0 pick, 1 move, 2 insert, 3 done, from the predicates (`flags`, where the caller has them)."""
    flags = predicates(env) if flags is None else flags
    if bool(flags["peg_seated"][0]):
        return 3
    if bool(flags["peg_at_hole"][0] | flags["peg_inserted"][0]):
        return 2
    return int(bool(flags["peg_grasped"][0]))


def labels(env, info: dict | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """The stage, the peg's centre in the TCP's frame (m) and the predicates."""
    u = env.unwrapped
    flags = predicates(u)
    offset = (pose0(u.agent.tcp.pose).inv() * pose0(u.peg.pose)).p.astype(np.float32)
    return stage(u, flags=flags), offset, np.array([float(v[0]) for v in flags.values()], dtype=np.float32)


def whereabouts(env, info: dict | None = None) -> str:
    flags = predicates(env)
    for name, words in (("peg_seated", "in the hole"), ("peg_inserted", "pushed past the box's far face"),
                        ("peg_at_hole", "in the hand in front of the hole"), ("peg_grasped", "in the hand")):
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
)
