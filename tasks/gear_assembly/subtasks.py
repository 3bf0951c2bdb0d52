"""GearAssembly-v1's subtasks as waypoints: what a controller must reach, independent of how it moves.

Each subtask turns the scene into waypoints (goal configurations by IK, with the gripper command and whether the way
there is free space or a straight TCP line), an initiation set and a success test, both made of the task's
predicates as the controller perceives them. The motion-planning controllers connect the waypoints with RRT-Connect
and IK lines; the DMP controllers connect the same waypoints with movement primitives learned from the planner's
trajectories.

Besides the task's three (pick, move, insert), `regrasp` puts the gear down on the table, as the paper's PR2 used the
table to re-grasp it: a gear shifted in the hand, which no insertion seats, becomes one lying on the table, which a
pick-up grasps afresh.
"""

from __future__ import annotations

import numpy as np

from policy_composer.tasks.base import PlanningError, Subtask, Waypoint, np0
from policy_composer.tasks.gear_assembly.env import CARRY_CLEARANCE
from policy_composer.tasks.panda import GRIPPER_CLOSED, GRIPPER_OPEN, ik_hand_down, line_to, tcp_line

PRE_GRASP_HEIGHT = 0.08  # TCP above the grasp point before descending (m)
LIFT_HEIGHT = 0.12  # how far the pick-up lifts the gear (m)
RETREAT_HEIGHT = 0.10
PLACE_XY = (0.0, -0.30)  # where the re-grasp puts the gear down: the middle of the gear's start area on the table
PLACE_DROP = 0.005  # the gear's bottom above the table when the re-grasp lets go (m)
CLEAR_HEIGHT = 0.05  # the re-grasp first lifts the gear straight up this far, clear of the peg (m)
RELEASE_HEIGHT = 0.012  # gear bottom above the plate when the gripper opens (m)
# A gear let go higher up the peg than this (its bottom above the plate) can stick there, caught on the peg (m).
RELEASE_HEIGHT_MAX = RELEASE_HEIGHT + 0.008
SEARCH_STEP = 0.004  # the insertion's guesses at the gear's offset along the fingers are this far apart (m)
SEARCH_CLEARANCE = 0.008  # between guesses, the gear's bottom goes back up this far above the peg's top (m)


class Pick(Subtask):
    name = "pick"
    initiation = "gear on the table, let go or still between the fingers (a lift that did not take it up)"

    def can_start(self, percept):
        # A pick-up that closed on the gear but stalled before the lift leaves it grasped on the table: the pick-up's
        # first waypoint opens the hand on its way up, and grasps afresh.
        return percept["gear_on_table"] and not percept["gear_on_peg"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        grasp = scene.planner_gear() + scene.finger_dir() * grasp_offset + [0, 0, scene.grasp_height]
        quat, q_pre = ik_hand_down(ik, scene.finger_dir(), grasp + [0, 0, PRE_GRASP_HEIGHT], q_now)
        down = line_to(ik, q_pre, grasp, quat, GRIPPER_OPEN, step=0.004)
        up = line_to(ik, down.q, grasp + [0, 0, LIFT_HEIGHT], quat, GRIPPER_CLOSED, step=0.006)
        return [Waypoint("free", q_pre, GRIPPER_OPEN, settle=6), down,
                Waypoint("hold", down.q, GRIPPER_CLOSED, settle=8), up]

    def succeeded(self, percept):
        return percept["gear_lifted"], f"the gear is not in the gripper after the lift ({percept.why('gear_lifted')})"


class Move(Subtask):
    name = "move"
    initiation = ("gear grasped and lifted off the table, level and within the pre-insertion tolerance of the "
                  "fingers' centre, not yet held above the peg")
    holds_part = True

    def can_start(self, percept):
        # A gear tipped in the fingers, or pushed along them, past what the pre-insertion pose allows stays so
        # wherever the hand takes it: the moves after an insertion that had done it failed one after another,
        # until the re-grasp.
        return percept["gear_held_level"] and not percept["gear_at_peg"] and not percept["gear_on_peg"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        _, q = ik_hand_down(ik, scene.finger_dir(), scene.pre_insertion_tcp(), q_now)
        return [Waypoint("free", q, GRIPPER_CLOSED, settle=6)]

    def succeeded(self, percept):
        return percept["gear_at_peg"], (f"the gear is not at the pre-insertion pose above the peg "
                                        f"({percept.why('gear_at_peg')})")


class Insert(Subtask):
    """Slide the gear down the peg's axis, feeling for the hole.

    Where the gear sits along the fingers is unknown without a camera, and a gear more than the clearance off the
    peg's axis rests on its top. So the insertion assumes an offset, lines up for it and goes down; when the TCP
    stops descending (the gear is on the peg's top), it goes back up and tries the next offset, as a fitter's hand
    feels for a hole. Seven guesses 4 mm apart cover the pick-up's +-12 mm."""

    name = "insert"
    initiation = ("gear grasped, held above the peg at the pre-insertion pose, or already part-way down the peg "
                  "and not seated")
    releases = True
    search = (0.0, *(sign * k * SEARCH_STEP for k in (1, 2, 3) for sign in (1, -1)))

    def can_start(self, percept):
        # Part-way down: where a closed-loop insertion stalled with the gear in the hand.
        return percept["gear_at_peg"] or (percept["gear_grasped"] and percept["gear_on_peg"]
                                          and not percept["gear_seated"])

    def waypoints(self, ik, scene, q_now, grasp_offset, percept, clearance=CARRY_CLEARANCE):
        # The TCP over the peg's axis, shifted along the fingers so that a gear `grasp_offset` off-centre is on it;
        # a gear already down the peg goes on straight down from where the hand holds it.
        tcp, h = scene.tcp(), scene.grasp_height
        on_peg = percept["gear_on_peg"]
        top = (np.array([tcp[0], tcp[1], scene.peg_top()[2]]) if on_peg
               else scene.peg_top() + scene.finger_dir() * grasp_offset)
        quat, _ = ik_hand_down(ik, scene.finger_dir(), tcp, q_now)
        above = tcp if on_peg else np.array([top[0], top[1], max(tcp[2], top[2] + clearance + h)])
        release = np.array([top[0], top[1], top[2] - scene.spec.peg_height + RELEASE_HEIGHT + h])
        align = line_to(ik, q_now, above, quat, GRIPPER_CLOSED, step=0.003, settle=2)
        down = line_to(ik, align.q, release, quat, GRIPPER_CLOSED, step=0.003)
        down.probe = True
        back = line_to(ik, down.q, release + [0, 0, RETREAT_HEIGHT], quat, GRIPPER_OPEN, step=0.006)
        return [align, down, Waypoint("hold", down.q, GRIPPER_OPEN, settle=8), back]

    def retry(self, ik, scene, q_now, grasp_offset, percept):
        return self.waypoints(ik, scene, q_now, grasp_offset, percept, clearance=SEARCH_CLEARANCE)

    def succeeded(self, percept):
        return percept["gear_seated"], f"the gear is not seated on the peg ({percept.why('gear_seated')})"

    def release_blocked(self, percept, scene):
        if percept["gear_grasped"] and not percept["gear_on_peg"]:
            return (f"the gear did not go down the peg; it would have been let go on top of it "
                    f"({percept.why('gear_grasped', 'gear_on_peg')})")
        height = scene.held_gear_height()
        if percept["gear_grasped"] and height > RELEASE_HEIGHT_MAX:
            return (f"the gear is only part-way down the peg ({1000 * height:.0f} mm above the plate by the hand's "
                    f"height; it would have been let go where it sticks)")
        return ""

    def off_course(self, percept, finished):
        """A controller that leads the gear away from the peg or tips it in the fingers, or stops with it in the hand
        and off the peg, would leave it where no controller may start: the insertion's termination condition."""
        if not percept["gear_grasped"] or percept["gear_on_peg"]:
            return ""
        if percept["gear_off_course"]:
            return f"the gear was tipped or led away from the peg ({percept.why('gear_off_course')})"
        return "it stopped with the gear in the hand, off the peg" if finished else ""

    def back_off(self, ik, scene, q_now):
        """Straight up to the pre-insertion height, then across to the pre-insertion pose (none if IK finds no way)."""
        tcp, quat, pre = scene.tcp(), np0(ik.arm.tcp.pose.q), scene.pre_insertion_tcp()
        above = np.array([tcp[0], tcp[1], max(tcp[2], pre[2])])
        try:
            up, q = tcp_line(ik, q_now, tcp, above, quat, step=0.004)
            across, _ = tcp_line(ik, q, above, pre, quat, step=0.004)
        except PlanningError:
            return np.zeros((0, 7))
        return np.concatenate([up, across, across[-1:].repeat(4, axis=0)])  # and settle there


class Regrasp(Subtask):
    """Up, clear of the peg; over to the table; down; let go; up. The gear then lies flat where a pick-up finds it."""

    name = "regrasp"
    initiation = "gear grasped and lifted off the table, not seated on the peg"
    releases = True
    holds_part = True

    def can_start(self, percept):
        # Part-way down the peg too: its first waypoint lifts the gear straight up, clear of the peg.
        return percept["gear_lifted"] and not percept["gear_seated"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        tcp, quat = scene.tcp(), np0(ik.arm.tcp.pose.q)
        clear = line_to(ik, q_now, tcp + [0, 0, CLEAR_HEIGHT], quat, GRIPPER_CLOSED, step=0.006, settle=0)
        place = np.array([*PLACE_XY, scene.grasp_height + PLACE_DROP])
        quat, q_above = ik_hand_down(ik, scene.finger_dir(), place + [0, 0, PRE_GRASP_HEIGHT], clear.q)
        down = line_to(ik, q_above, place, quat, GRIPPER_CLOSED, step=0.004)
        up = line_to(ik, down.q, place + [0, 0, RETREAT_HEIGHT], quat, GRIPPER_OPEN, step=0.006)
        return [clear, Waypoint("free", q_above, GRIPPER_CLOSED, settle=6), down,
                Waypoint("hold", down.q, GRIPPER_OPEN, settle=8), up]

    def succeeded(self, percept):
        return percept["gear_lying_flat"], f"the gear is not lying flat on the table ({percept.why('gear_lying_flat')})"


class InsertStraightDown(Insert):
    """The paper's insertion: lined up for a centred grasp and straight down, once. A gear held more than the
    clearance off-centre rests on the peg's top and the insertion fails (paper, Table I: MP and DMP 1/10)."""

    search = (0.0,)


SUBTASKS = {s.name: s for s in (Pick(), Move(), Insert(), Regrasp())}
# How the planned insertions (MP, DMP) go down the peg: feeling for the hole (ours), or straight down (the paper's).
# The learned controllers close the loop on their cameras and do not search either way.
INSERTIONS = {"feel": SUBTASKS["insert"], "straight": InsertStraightDown()}
TASK_SEQUENCE = ("pick", "move", "insert")  # the full task, when nothing goes wrong
