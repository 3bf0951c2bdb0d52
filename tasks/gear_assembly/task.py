"""GearAssembly-v1 as the library reads it: the left arm's controllers, the gear's subtasks, the scene the left arm
knows, and the simulator's predicates kept apart as the privileged truth."""

from __future__ import annotations

from operator import methodcaller

from policy_composer.tasks.base import TaskDescription
from policy_composer.tasks.gear_assembly.env import gear_whereabouts
from policy_composer.tasks.gear_assembly.scene import GearScene
from policy_composer.tasks.gear_assembly.spec import (
    ACTION_NAMES,
    CAMERA_NAMES,
    ENV_ID,
    INSERTION_WINDOWS,
    PREDICATES,
    STATE_NAMES,
)
from policy_composer.tasks.gear_assembly.subtasks import INSERTIONS, SUBTASKS, TASK_SEQUENCE

TASK = TaskDescription(
    name="gear-assembly",
    env_id=ENV_ID,
    arm="left_arm",
    cameras=CAMERA_NAMES,
    state_names=STATE_NAMES,
    action_names=ACTION_NAMES,
    predicates=PREDICATES,
    progress=("gear_grasped", "gear_lifted", "gear_at_peg", "gear_seated"),
    grasped="gear_grasped",
    subtasks=SUBTASKS,
    sequence=TASK_SEQUENCE,
    insertions=INSERTIONS,
    scene=GearScene,
    truth=methodcaller("predicates"),
    hold_action=methodcaller("hold_action"),
    env_action=lambda env, action: env.flat_to_dict_action(action),
    whereabouts=gear_whereabouts,
    stage=lambda info: int(info["stage"][0]),
    instruction="Insert the gear held by the left gripper onto the peg held by the right arm.",
    insertion_windows=INSERTION_WINDOWS,
)
