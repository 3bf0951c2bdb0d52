"""GearAssembly-v1 as the library reads it: the left arm's controllers, the gear's subtasks, the scene the left arm
knows, and the simulator's predicates kept apart as the privileged truth."""

from __future__ import annotations

from functools import cache
from operator import methodcaller

import numpy as np

from policy_composer.tasks.base import THRESHOLD, TaskDescription
from policy_composer.tasks.gear_assembly.env import (
    GRASP_OFFSET_MAX,
    PRE_INSERT_RADIUS,
    gear_whereabouts,
)
from policy_composer.tasks.gear_assembly.expert import ExpertConfig, GearAssemblyExpert
from policy_composer.tasks.gear_assembly.geometry import GearSpec
from policy_composer.tasks.gear_assembly.kinematics import HandToPeg
from policy_composer.tasks.gear_assembly.rollout import make_env
from policy_composer.tasks.gear_assembly.scene import GearScene
from policy_composer.tasks.gear_assembly.spec import SPEC
from policy_composer.tasks.gear_assembly.subtasks import INSERTIONS, SUBTASKS, TASK_SEQUENCE

# A gear in the fingers is at most the pick-up's error along them off the hand: held farther than this from the peg's
# axis by kinematics, it is neither at the pre-insertion pose nor on the peg, whatever the images look like.
HELD_GEAR_REACH = PRE_INSERT_RADIUS + GRASP_OFFSET_MAX


@cache
def _hand_to_peg() -> HandToPeg:
    return HandToPeg(GearSpec())


def hand_to_peg(state: np.ndarray, scene: np.ndarray | None = None) -> np.ndarray:
    """Where the left hand is over the peg, by both arms' forward kinematics, for joint states (N, 16) (the scene
    the arms know is the same in every episode)."""
    return _hand_to_peg()(state)


def rule_out(p: dict[str, float], hand: np.ndarray) -> dict[str, float]:
    """A held gear is neither at nor on the peg where the hand is farther than HELD_GEAR_REACH from the peg's axis."""
    if float(np.linalg.norm(hand[:2])) > HELD_GEAR_REACH:
        p["gear_at_peg"] = 0.0
        if p["gear_grasped"] >= THRESHOLD:
            p["gear_on_peg"] = 0.0
    return p


def labels(env, info: dict | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """The privileged labels of the scene now (`info`: its `evaluate()`, where the caller has it): its stage, the
    gear's offset in the hand and the predicates."""
    info = env.evaluate() if info is None else info
    flags = np.array([float(v[0]) for v in env.predicates(info).values()], dtype=np.float32)
    return int(info["stage"][0]), env.gear_offset_in_hand()[0].cpu().numpy().astype(np.float32), flags

TASK = TaskDescription(
    spec=SPEC,
    arm="left_arm",
    progress=("gear_grasped", "gear_lifted", "gear_at_peg", "gear_seated"),
    grasped="gear_grasped",
    subtasks=SUBTASKS,
    sequence=TASK_SEQUENCE,
    insertions=INSERTIONS,
    scene=GearScene,
    make_env=lambda obs_mode, settings, cameras=None, **kwargs: make_env(
        obs_mode, settings.resolution, settings.clearance_mm, cameras or settings.cameras, **kwargs),
    expert=GearAssemblyExpert,
    observe=lambda env: env.unwrapped.observe(),
    truth=methodcaller("predicates"),
    hold_action=methodcaller("hold_action"),
    env_action=lambda env, action: env.flat_to_dict_action(action),
    whereabouts=lambda env, info: gear_whereabouts(info),
    labels=labels,
    stage=lambda env, info: int(info["stage"][0]),
    extra_proprioception=("hand_to_peg_x", "hand_to_peg_y", "hand_to_peg_z"),
    proprioception=hand_to_peg,
    rule_out=rule_out,
    reset_starts={"insert": "pre_insertion", "regrasp": "pre_insertion"},
    expert_starts={"move": "carry"},
    # The open-loop expert carries as if the grasp were centred, as a planner would: the move's trials start with the
    # gear off-centre in the fingers.
    start_expert=lambda env: GearAssemblyExpert(env, ExpertConfig(closed_loop=False)),
    step_unobserved=lambda env, action: env.unwrapped.step_unobserved(env.unwrapped.flat_to_dict_action(action)),
)
