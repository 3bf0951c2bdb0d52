"""Where the robot knows its hand is against the hole, without a camera: the hand's pose by forward kinematics of its
joints (`observation.state`), the hole's pose and the peg's size from what the planner knows of the scene
(`observation.environment_state`), and where the peg's head is if the hand holds the peg as its grasp was planned
(where along the peg, straight down or tilted about the fingers' closing axis, as the scene says). The
predicate classifiers read it beside the cameras, as the gear's read where the hand is over its peg; where the peg
really sits in the fingers is the cameras' to see."""

from __future__ import annotations

from functools import cache

import numpy as np
from transforms3d.quaternions import quat2mat

from policy_composer.tasks.panda import PandaForwardKinematics
from policy_composer.tasks.peg_insertion_side.scene import holds_nothing, tilt_quat

HAND_IN_HOLE = ("hand_in_hole_x", "hand_in_hole_y", "hand_in_hole_z",
                "hole_axis_in_hand_x", "hole_axis_in_hand_y", "hole_axis_in_hand_z",
                "planned_head_in_hole_x", "planned_head_in_hole_y", "planned_head_in_hole_z",
                "planned_head_past_near_face", "fingers_wider_than_peg")


@cache
def _forward_kinematics() -> PandaForwardKinematics:
    return PandaForwardKinematics()


def grasp_turn(scene: np.ndarray) -> np.ndarray:
    """(N, 3, 3) for scenes (N, 11: SCENE_NAMES): the turn, in the hand's frame, that takes back the planned grasp's
    tilt: the hand's orientation times it is the frame in which the peg lies as in a grasp straight down (its axis
    along x)."""
    return np.stack([quat2mat(tilt_quat(-tilt)) for tilt in np.atleast_2d(scene)[:, 9]])


def hand_in_hole(state: np.ndarray, scene: np.ndarray) -> np.ndarray:
    """(N, 11) for joint states (N, 8) and scenes (N, 11: SCENE_NAMES): the TCP's position in the hole's frame (x along
    the hole's axis into the box, m), the hole's axis in the grasp's frame (the hand's, turned by `grasp_turn`), the
    peg's head in the hole's frame as the planned grasp holds it (its axis along the grasp frame's x, the grasp's
    offset back from its centre, its head the end toward the hole) and how far that head is past the box's near face
    (the box is as deep as the peg is long), and how much wider the fingers are than the peg."""
    state, scene = np.atleast_2d(state), np.atleast_2d(scene)
    p, R = _forward_kinematics().tcp(state[:, :7])
    out = np.empty((len(state), len(HAND_IN_HOLE)))
    for i, (known, tcp, hand) in enumerate(zip(scene, p, R @ grasp_turn(scene))):
        hole_R, half_length = quat2mat(known[3:7] / np.linalg.norm(known[3:7])), known[7]
        out[i, :3] = hole_R.T @ (tcp - known[:3])
        out[i, 3:6] = hand.T @ hole_R[:, 0]
        toward_hole = 1.0 if out[i, 3] >= 0 else -1.0
        head = tcp + toward_hole * (known[10] + half_length) * hand[:, 0]
        out[i, 6:9] = hole_R.T @ (head - known[:3])
        out[i, 9] = out[i, 6] + half_length
    out[:, 10] = state[:, 7] - 2 * scene[:, 8]
    return out


def rule_out(p: dict[str, float], kinematics: np.ndarray) -> dict[str, float]:
    """Fingers wider than the peg by more than EMPTY_HAND_GAP hold nothing: the peg is neither grasped nor at the
    hole, whatever the images look like; nor in the hole, which it reaches only in the hand (nothing in
    the task lets go of it), and where the head the planned grasp would hold is no sign of it."""
    if holds_nothing(float(kinematics[HAND_IN_HOLE.index("fingers_wider_than_peg")])):
        p.update(dict.fromkeys(("peg_grasped", "peg_at_hole", "peg_inserted", "peg_seated"), 0.0))
    return p
