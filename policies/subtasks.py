"""The gear task's subtasks as waypoints: what a controller must reach, independent of how it moves.

A subtask turns the scene into a list of waypoints (goal configurations by IK, with the gripper command and
whether the way there is free space or a straight TCP line), an initiation set and a success test, both made of the
task's predicates as the controller perceives them (a `Percept`, see policies/senses.py). The
motion-planning controllers connect the waypoints with RRT-Connect and IK lines; the DMP controllers connect
the same waypoints with movement primitives learned from the planner's trajectories.

Besides the task's three (pick, move, insert), `regrasp` puts the gear down on the table, as the paper's PR2 used the
table to re-grasp it: a gear shifted in the hand, which no insertion seats, becomes one lying on the table, which a
pick-up grasps afresh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien

from policy_composer.policies.arm import (
    GRIPPER_CLOSED,
    GRIPPER_OPEN,
    RELEASE_HEIGHT,
    STEP_SPEED_MARGIN,
    LeftArmController,
    SceneGeometry,
    ScriptedController,
    Segment,
    np0,
)
from policy_composer.policies.mp.planning import VELOCITY_LIMIT, PlanningError, SceneCollisionModel
from policy_composer.policies.senses import Percept
from policy_composer.tasks.gear_assembly import CARRY_CLEARANCE
from policy_composer.tasks.gear_kinematics import LeftArmIK

PRE_GRASP_HEIGHT = 0.08  # TCP above the grasp point before descending (m)
LIFT_HEIGHT = 0.12  # how far the pick-up lifts the gear (m)
RETREAT_HEIGHT = 0.10
PLACE_XY = (0.0, -0.30)  # where the re-grasp puts the gear down: the middle of the gear's start area on the table
PLACE_DROP = 0.005  # the gear's bottom above the table when the re-grasp lets go (m)
CLEAR_HEIGHT = 0.05  # the re-grasp first lifts the gear straight up this far, clear of the peg (m)
# A gear let go higher up the peg than this (its bottom above the plate) can stick there, caught on the peg (m).
RELEASE_HEIGHT_MAX = RELEASE_HEIGHT + 0.008
SEARCH_STEP = 0.004  # the insertion's guesses at the gear's offset along the fingers are this far apart (m)
SEARCH_CLEARANCE = 0.008  # between guesses, the gear's bottom goes back up this far above the peg's top (m)
CONFIRM_STEPS = 3  # a learned controller stops once its subtask has been sensed done this many steps in a row
# A probing descent is blocked when, over the last STALL_STEPS control steps, the TCP (joint positions and forward
# kinematics only) went down less than a third of the at least STALL_DESCENT its targets went down.
STALL_STEPS, STALL_DESCENT = 2, 0.004

@dataclass
class Waypoint:
    kind: str  # "free": around obstacles; "line": straight TCP line; "hold": stay (the gripper changes)
    q: np.ndarray  # (9,) goal configuration
    gripper: float
    tcp: np.ndarray | None = None  # goal TCP position (lines)
    quat: np.ndarray | None = None
    step: float = 0.004  # TCP travel per control step on a line (m)
    settle: int = 4  # control steps holding the goal afterwards
    probe: bool = False  # a way down that contact may block (the gear on the peg's top): the controller feels for it


def ik_hand_down(ik: LeftArmIK, scene: SceneGeometry, p: np.ndarray,
                 seed_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(quat, q) putting the TCP at p with the hand down (see LeftArmIK.solve_hand_down)."""
    solution = ik.solve_hand_down(p, scene.finger_dir(), seed_q)
    if solution is None:
        raise PlanningError(f"no IK solution within the joint limits for the TCP at {np.round(p, 3)}")
    return solution


def tcp_line(ik: LeftArmIK, q_from: np.ndarray, p_from: np.ndarray, p_to: np.ndarray, quat: np.ndarray,
             step: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint targets (T, 7) moving the TCP on a straight line from p_from to p_to at `step` m per control step,
    and the last solution (9)."""
    n = max(1, int(np.ceil(np.linalg.norm(p_to - p_from) / step)))
    q, out = np.asarray(q_from, dtype=float), []
    for k in range(1, n + 1):
        q, ok = ik.solve(sapien.Pose(p_from + (p_to - p_from) * k / n, quat), q)
        if not ok:
            raise PlanningError(f"no IK solution on the line to {np.round(p_to, 3)}")
        out.append(q[:7])
    return np.array(out), q


def line_to(ik: LeftArmIK, q_from: np.ndarray, p: np.ndarray, quat: np.ndarray, gripper: float, step: float,
            settle: int = 4) -> Waypoint:
    q, ok = ik.solve(sapien.Pose(p, quat), q_from)
    if not ok:
        raise PlanningError(f"no IK solution for the TCP at {np.round(p, 3)}")
    return Waypoint("line", q, gripper, tcp=np.asarray(p, dtype=float), quat=quat, step=step, settle=settle)


class Subtask:
    name = ""
    initiation = ""
    releases = False  # whether it ends with the gear let go (else: held, as the next subtask needs it)
    # Offsets (m) to assume in turn, each time a probing waypoint is blocked; () draws the pick-up's perception error.
    search: tuple[float, ...] = ()

    def can_start(self, percept: Percept) -> bool:
        raise NotImplementedError

    def waypoints(self, ik: LeftArmIK, scene: SceneGeometry, q_now: np.ndarray, grasp_offset: float,
                  percept: Percept) -> list[Waypoint]:
        """The way through the subtask for a gear (to be) held `grasp_offset` along the fingers."""
        raise NotImplementedError

    def retry(self, ik: LeftArmIK, scene: SceneGeometry, q_now: np.ndarray, grasp_offset: float,
              percept: Percept) -> list[Waypoint]:
        """The way from a blocked probe for the next guess (the same waypoints as the first)."""
        return self.waypoints(ik, scene, q_now, grasp_offset, percept)

    def succeeded(self, percept: Percept) -> tuple[bool, str]:
        raise NotImplementedError

    def release_blocked(self, percept: Percept, scene: SceneGeometry) -> str:
        """Why the gripper must not open now ("" if it may)."""
        return ""

    def off_course(self, percept: Percept, finished: bool) -> str:
        """Why a controller of this subtask must stop now and back off with the gear, though it would go on
        (`finished`: it has nothing more to do) ("" if it need not)."""
        return ""

    def back_off(self, ik: LeftArmIK, scene: SceneGeometry, q_now: np.ndarray) -> np.ndarray:
        """Joint targets (T, 7), gripper closed, from a blocked release back to where the subtask starts."""
        return np.zeros((0, 7))

    holds_gear = False  # whether the gear is in the hand on the way (the planner attaches it)


class Pick(Subtask):
    name = "pick"
    initiation = "gear on the table, let go or still between the fingers (a lift that did not take it up)"

    def can_start(self, percept):
        # A pick-up that closed on the gear but stalled before the lift leaves it grasped on the table: the pick-up's
        # first waypoint opens the hand on its way up, and grasps afresh.
        return percept["gear_on_table"] and not percept["gear_on_peg"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        grasp = scene.planner_gear() + scene.finger_dir() * grasp_offset + [0, 0, scene.grasp_height]
        quat, q_pre = ik_hand_down(ik, scene, grasp + [0, 0, PRE_GRASP_HEIGHT], q_now)
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
    holds_gear = True

    def can_start(self, percept):
        # A gear tipped in the fingers, or pushed along them, past what the pre-insertion pose allows stays so
        # wherever the hand takes it: the moves after an insertion that had done it failed one after another,
        # until the re-grasp.
        return percept["gear_held_level"] and not percept["gear_at_peg"] and not percept["gear_on_peg"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        _, q = ik_hand_down(ik, scene, scene.pre_insertion_tcp(), q_now)
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
        quat, _ = ik_hand_down(ik, scene, tcp, q_now)
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
    holds_gear = True

    def can_start(self, percept):
        # Part-way down the peg too: its first waypoint lifts the gear straight up, clear of the peg.
        return percept["gear_lifted"] and not percept["gear_seated"]

    def waypoints(self, ik, scene, q_now, grasp_offset, percept):
        tcp, quat = scene.tcp(), np0(ik.arm.tcp.pose.q)
        clear = line_to(ik, q_now, tcp + [0, 0, CLEAR_HEIGHT], quat, GRIPPER_CLOSED, step=0.006, settle=0)
        place = np.array([*PLACE_XY, scene.grasp_height + PLACE_DROP])
        quat, q_above = ik_hand_down(ik, scene, place + [0, 0, PRE_GRASP_HEIGHT], clear.q)
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


class SubtaskController(ScriptedController):
    """A controller for one subtask: the subtask gives waypoints, the subclass says how to connect them."""

    kind = ""  # "mp", "dmp"

    def __init__(self, env, subtask: Subtask, max_grasp_offset: float = 0.012, grasp_offset: float | None = None):
        super().__init__(env)
        self.subtask = subtask
        self.name = f"{self.kind}_{subtask.name}"
        self.initiation = subtask.initiation
        self.ik = LeftArmIK(self.env)
        self.max_grasp_offset = max_grasp_offset
        self.fixed_grasp_offset = grasp_offset  # set: every pick is off by exactly this much (tests, tables)
        self.grasp_offset = 0.0
        self.tries = 0  # how many offsets the last activation tried (Subtask.search)

    def can_start(self, obs) -> bool:
        return self.subtask.can_start(self.senses(obs))

    def succeeded(self, percept: Percept) -> tuple[bool, str]:
        return self.subtask.succeeded(percept)

    def q9(self, obs) -> np.ndarray:
        state = np0(obs["extra"]["state"])
        return np.concatenate([state[:7], [state[7] / 2] * 2])

    def plan(self, obs, seed):
        self.guesses = list(self.subtask.search)
        if self.guesses:
            self.grasp_offset = self.guesses.pop(0)
        else:  # the pick-up perceives the gear's position with an error along the fingers: it will sit off-centre
            rng = np.random.default_rng(seed)
            offset = rng.uniform(-self.max_grasp_offset, self.max_grasp_offset)
            self.grasp_offset = float(offset if self.fixed_grasp_offset is None else self.fixed_grasp_offset)
        self.tries = 1
        return self._connect(obs, self.subtask.waypoints(self.ik, self.scene, self.q9(obs), self.grasp_offset,
                                                         self.senses(obs)), seed)

    def _connect(self, obs, waypoints: list[Waypoint], seed: int | None) -> list[Segment]:
        """connect(), noting the commanded TCP heights of the probing segments (for `blocked`)."""
        self.waypoints, self._heights = waypoints, []
        segments = self.connect(obs, waypoints, seed)
        self._probe_z = {k: self.ik.tcp_positions(s.q)[:, 2]
                         for k, (s, wp) in enumerate(zip(segments, waypoints)) if wp.probe}
        return segments

    def next_command(self, obs):
        if self.guesses and self.blocked(obs):  # back up and line up for the next guess
            self.grasp_offset, self.tries = self.guesses.pop(0), self.tries + 1
            self.segments = self._connect(obs, self.subtask.retry(self.ik, self.scene, self.q9(obs),
                                                                  self.grasp_offset, self.senses(obs)), None)
            self._k, self._t = 0, 0
        return super().next_command(obs)

    def remark(self):
        if self.tries < 2:
            return ""
        return f"felt for the hole: {self.tries} guesses, the last {1000 * self.grasp_offset:+.0f} mm along the fingers"

    def blocked(self, obs) -> bool:
        """Whether, on a probing segment, the TCP went down less than a third of what it was commanded to over the
        last STALL_STEPS steps (and at least STALL_DESCENT): something holds it up."""
        k, t = self._k, self._t
        if k not in self._probe_z or not 0 < t < len(self.segments[k].q):
            self._heights = []
            return False
        self._heights.append(float(obs["extra"]["tcp_pose"][0, 2]))
        if len(self._heights) <= STALL_STEPS:
            return False
        commanded = self._probe_z[k][t - 1 - STALL_STEPS] - self._probe_z[k][t - 1]
        measured = self._heights[-1 - STALL_STEPS] - self._heights[-1]
        return commanded >= STALL_DESCENT and measured < commanded / 3

    def connect(self, obs, waypoints: list[Waypoint], seed: int | None) -> list[Segment]:
        raise NotImplementedError


def check_camera(env, camera: str, who: str) -> None:
    if camera not in env.camera_names:
        raise ValueError(f"{who} reads camera {camera!r}, which this env does not render (it has "
                         f"{list(env.camera_names)}); make the env with that camera")
    if "rgb" not in env.obs_mode:
        raise ValueError(f"{who} needs camera images: make the env with obs_mode='rgb', not {env.obs_mode!r}")


class LearnedController(LeftArmController):
    """A closed-loop learned policy run for one subtask: it acts every step until the subtask has been sensed achieved
    (and, for one that releases the gear, the hand has let go) for `CONFIRM_STEPS` steps in a row, or its step budget
    is spent. Subclasses give `predict(obs) -> (7 joint targets, gripper)`.

    The confirmation is a robot's: a gear let go is still moving, and one frame's percept may flicker.

    A command that would put the left arm into the right one (or into itself) stops the controller before it is
    sent: a policy that wandered there leaves an arm from which no plan starts (its start "in collision")."""

    action_kind = "joint_targets"

    def __init__(self, env, subtask: Subtask, name: str, max_steps: int = 120):
        super().__init__(env)
        self.subtask, self.name, self.initiation, self.max_steps = subtask, name, subtask.initiation, max_steps
        self.ik = LeftArmIK(self.env)
        self.guard = SceneCollisionModel(self.ik.base())

    def can_start(self, obs) -> bool:
        return self.subtask.can_start(self.senses(obs))

    def succeeded(self, percept):
        if self._stopped:
            return False, self._stopped
        ok, why = self.subtask.succeeded(percept)
        spent = self._steps >= self.max_steps
        return ok, why if ok or not spent else f"its step budget ({self.max_steps} steps) ran out: {why}"

    def reset(self, obs, seed=None):
        super().reset(obs, seed)
        self._steps, self._stopped, self._confirmed = 0, "", 0
        # The right arm where its joints say it stands; nothing else (the gear meets the peg when inserting).
        self.guard.set_scene(self.scene.obstacles(table=False, module=False))

    def next_command(self, obs):
        percept = self.senses(obs)
        achieved = self.subtask.succeeded(percept)[0]
        let_go = self._gripper > 0 and not percept["gear_grasped"]
        self._confirmed = self._confirmed + 1 if achieved and (let_go or not self.subtask.releases) else 0
        if self._steps >= self.max_steps or self._confirmed >= CONFIRM_STEPS:
            return None
        self._steps += 1
        q, gripper = self.predict(obs)
        q = self.limit_step(q)
        if self.guard.in_collision(q):
            self._stopped = f"stopped before a command that collides: {self.guard.colliding_pairs(q)[:2]}"
            return None
        return q, gripper

    def limit_step(self, q: np.ndarray) -> np.ndarray:
        """Joint targets `q`, with the step from the last command scaled down (its direction kept) so that no joint
        moves faster than `STEP_SPEED_MARGIN` of the Panda's velocity limit. A learned policy's step can overshoot
        where its training data were sparse; the safety check then stops only what limiting cannot mend (joint
        limits, non-finite targets)."""
        step = np.asarray(q, dtype=np.float64) - self._last
        ratio = float(np.max(np.abs(step) * self.rate_hz / (STEP_SPEED_MARGIN * VELOCITY_LIMIT)))
        return self._last + step / ratio if ratio > 1.0 else q

    def predict(self, obs) -> tuple[np.ndarray, float]:
        raise NotImplementedError
