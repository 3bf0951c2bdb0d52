"""PegInsertionSide-v1's subtasks as waypoints: pick the peg up from above, carry it to the pre-insertion pose (its
axis on the hole's, its head in front of the box), push it along the hole's axis.

The planned controllers know the peg's pose on the table (the task's privileged planner input) and the hole's, and
assume the grasp they planned: a peg that slid or pivoted in the fingers arrives off the hole's axis, and a pick-up
that perceived the peg off along its axis leaves it that far off along the hand (the open-loop failures the paper's
Table I shows on the gear)."""

from __future__ import annotations

import numpy as np
import sapien

from policy_composer.tasks.base import PlanningError, Subtask, Waypoint, np0
from policy_composer.tasks.panda import GRIPPER_CLOSED, GRIPPER_OPEN, ik_hand_down, line_to
from policy_composer.tasks.peg_insertion_side.flags import HOLE_ENTRY, PRE_INSERTION_DISTANCE
from policy_composer.tasks.peg_insertion_side.scene import grasp_offset

APPROACH_HEIGHT = 0.06  # TCP above the grasp point before descending (m)
LIFT_HEIGHT = 0.08
PRE_INSERTION = 0.02  # the head in front of the box's near face at the pre-insertion pose (m)
LINE_UP_GAP = 0.01  # the head at least this far in front of the box's near face when the insertion lines up (m)
ALIGN_STEP, ALIGN_SETTLE = 0.002, 8  # a slow line-up, held still before the push: a moving arm sags under the peg
# How much lower the held peg's head hangs than the planned grasp puts it (m): the fingers give under its weight, the
# head's side the heavier. Measured on the insertion's tuning seeds (3000-3079), as a fitter learns a tool's sag.
DROOP = 0.0015
INSERT_STEP = 0.003  # TCP travel per control step along the hole's axis (m)
SEATED = 0.02  # the insertion pushes the head this far past the hole's centre plane (m; the far face is 85 mm on)
assert PRE_INSERTION < PRE_INSERTION_DISTANCE and SEATED > HOLE_ENTRY


class Pick(Subtask):
    name = "pick"
    initiation = "peg out of the hand, not in the hole"

    def can_start(self, percept):
        return not percept["peg_grasped"] and not percept["peg_inserted"]

    def waypoints(self, ik, scene, q_now, grasp_error, percept):
        peg = scene.planner_peg()
        axis = peg.to_transformation_matrix()[:3, 0]
        grasp = peg.p - axis * (grasp_offset(scene.half_length) + grasp_error)
        quat, q_pre = ik_hand_down(ik, scene.finger_dir(), grasp + [0, 0, APPROACH_HEIGHT], q_now)
        down = line_to(ik, q_pre, grasp, quat, GRIPPER_OPEN, step=0.006)
        up = line_to(ik, down.q, grasp + [0, 0, LIFT_HEIGHT], quat, GRIPPER_CLOSED, step=0.01)
        return [Waypoint("free", q_pre, GRIPPER_OPEN, settle=4), down,
                Waypoint("hold", down.q, GRIPPER_CLOSED, settle=8), up]

    def succeeded(self, percept):
        return percept["peg_grasped"], f"the peg is not in the gripper after the lift ({percept.why('peg_grasped')})"


def peg_target_tcp(scene, head_x: float, lift: float = 0.0) -> sapien.Pose:
    """The TCP pose that puts the peg, held as planned, on the hole's axis (`lift` above it) with its head `head_x`
    along it from the hole's centre plane."""
    peg = scene.hole() * sapien.Pose([head_x - scene.half_length, 0.0, lift])
    return peg * scene.peg_in_hand().inv()


class Move(Subtask):
    name = "move"
    initiation = "peg in the hand, not yet at the hole nor in it"
    holds_part = True

    def can_start(self, percept):
        return percept["peg_grasped"] and not percept["peg_at_hole"] and not percept["peg_inserted"]

    def waypoints(self, ik, scene, q_now, grasp_error, percept):
        pre = peg_target_tcp(scene, -scene.box_half_depth - PRE_INSERTION)
        q, ok = ik.solve(pre, q_now)
        if not ok:
            raise PlanningError(f"no IK solution for the pre-insertion pose, the TCP at {np.round(pre.p, 3)}")
        return [Waypoint("free", q, GRIPPER_CLOSED, settle=6)]

    def succeeded(self, percept):
        return percept["peg_at_hole"], (f"the peg is not at the pre-insertion pose in front of the hole "
                                        f"({percept.why('peg_at_hole')})")


class Insert(Subtask):
    """Line the peg up on the hole's axis, as the planned grasp says the hand holds it, trim the hand's sag measured
    from the joints there (`Waypoint.trim`), then push the peg along the axis to the depth that grasp puts the head at.
    Where the peg sits in the fingers is the plan's, not seen: a peg that slid or pivoted there meets the box's face."""

    name = "insert"
    initiation = "peg in the hand at the hole (in front of it or part-way in) or pushed past the box, not seated"
    holds_part = True
    # The push aims past where the head seats whatever the grasp's error; the demonstrations stop where it seats, so
    # the classifiers never saw a peg pushed deeper.
    stops_when_sensed = True
    # The seated classifier says so up to 9 mm before the head reaches ManiSkill's bound (docs/task.md): three more
    # steps of the push (9 mm) seat it, still far short of the box's far face.
    sensed_margin = 3
    # A push whose head meets the box's face beside the hole (a learned policy's miss, a primitive's drift) slid the
    # peg along the fingers by up to 130 mm when it went on (docs/task.md); stopped there, it leaves the grasp as
    # planned for the planned insertion to line up again.
    stops_when_held_back = True

    def can_start(self, percept):
        # Not seated, whatever else is sensed: a peg sensed seated and at the hole would start one insertion after
        # another, each done at once, until one pulled the peg out.
        return not percept["peg_seated"] and (percept["peg_at_hole"]
                                              or (percept["peg_grasped"] and percept["peg_inserted"]))

    def waypoints(self, ik, scene, q_now, grasp_error, percept):
        goal = peg_target_tcp(scene, SEATED, DROOP)
        if percept["peg_inserted"]:  # pushed through: back along the axis from where the hand is, the hole holds it
            tcp = scene.tcp()
            axis = scene.hole().to_transformation_matrix()[:3, 0]
            end = tcp + axis * float(axis @ (goal.p - tcp))
            quat = np0(ik.arm.tcp.pose.q)
            # In two movements, as the line-up and the push: the DMPs have a primitive for each.
            half = line_to(ik, q_now, (tcp + end) / 2, quat, GRIPPER_CLOSED, step=INSERT_STEP, settle=0)
            return [half, line_to(ik, half.q, end, quat, GRIPPER_CLOSED, step=INSERT_STEP, settle=6)]
        line_up = peg_target_tcp(scene, min(scene.held_head_x(), -scene.box_half_depth - LINE_UP_GAP), DROOP)
        align = line_to(ik, q_now, line_up.p, line_up.q, GRIPPER_CLOSED, step=ALIGN_STEP, settle=ALIGN_SETTLE)
        align.trim = True
        push = line_to(ik, align.q, goal.p, goal.q, GRIPPER_CLOSED, step=INSERT_STEP, settle=6)
        return [align, push]

    def succeeded(self, percept):
        return percept["peg_seated"], f"the peg is not in the hole ({percept.why('peg_seated')})"


SUBTASKS = {s.name: s for s in (Pick(), Move(), Insert())}
INSERTIONS = {"straight": SUBTASKS["insert"]}
TASK_SEQUENCE = ("pick", "move", "insert")
