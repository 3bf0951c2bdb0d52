"""The controllers that serve a task's subtask (`policy_composer.tasks.base.Subtask`): planned ones, which connect its
waypoints (`SubtaskController`; the MP and DMP kinds), and learned closed-loop ones, which act every step until its
termination is sensed (`LearnedController`; the CNN and LeRobot kinds)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from policy_composer.policies.arm import STEP_SPEED_MARGIN, ArmController, ScriptedController, Segment
from policy_composer.policies.mp.planning import VELOCITY_LIMIT, SceneCollisionModel
from policy_composer.tasks.base import Percept, PlanningError, Subtask, Waypoint, np0
from policy_composer.tasks.panda import line_to

CONFIRM_STEPS = 3  # a learned controller (or a planned one whose subtask says so) stops once its subtask has been
# sensed done this many steps in a row
# A probing descent is blocked when, over the last STALL_STEPS control steps, the TCP (joint positions and forward
# kinematics only) went down less than a third of the at least STALL_DESCENT its targets went down.
STALL_STEPS, STALL_DESCENT = 2, 0.004


class SubtaskController(ScriptedController):
    """A controller for one subtask: the subtask gives waypoints, the subclass says how to connect them."""

    kind = ""  # "mp", "dmp"

    def __init__(self, env, subtask: Subtask, max_grasp_offset: float = 0.012, grasp_offset: float | None = None):
        super().__init__(env)
        self.subtask = subtask
        self.name = f"{self.kind}_{subtask.name}"
        self.initiation = subtask.initiation
        self.max_grasp_offset = max_grasp_offset
        self.fixed_grasp_offset = grasp_offset  # set: every pick is off by exactly this much (tests, tables)
        self.grasp_offset = 0.0
        self.tries = 0  # how many offsets the last activation tried (Subtask.search)
        self.trimmed = None  # the hand's steady error the last activation corrected (Waypoint.trim; m, world)
        self.replan_failed = ""  # why a re-plan on the way (a retry, a trim) found no way on

    def can_start(self, obs) -> bool:
        return self.subtask.can_start(self.senses(obs))

    def succeeded(self, percept: Percept) -> tuple[bool, str]:
        if self.replan_failed:
            return False, f"no way on from where the hand was: {self.replan_failed}"
        return self.subtask.succeeded(percept)

    def q9(self, obs) -> np.ndarray:
        state = np0(obs["extra"]["state"])
        return np.concatenate([state[:7], [state[7] / 2] * 2])

    def plan(self, obs, seed):
        self.guesses = list(self.subtask.search)
        if self.guesses:
            self.grasp_offset = self.guesses.pop(0)
        else:  # the pick-up perceives the part's position with an error along the fingers: it will sit off-centre
            rng = np.random.default_rng(seed)
            offset = rng.uniform(-self.max_grasp_offset, self.max_grasp_offset)
            self.grasp_offset = float(offset if self.fixed_grasp_offset is None else self.fixed_grasp_offset)
        self.tries, self.trimmed, self.replan_failed, self._confirmed = 1, None, "", 0
        return self._connect(obs, self.subtask.waypoints(self.ik, self.scene, self.q9(obs), self.grasp_offset,
                                                         self.senses(obs)), seed)

    def _connect(self, obs, waypoints: list[Waypoint], seed: int | None) -> list[Segment]:
        """connect(), noting the commanded TCP heights of the probing segments (for `blocked`)."""
        self.waypoints, self._heights = waypoints, []
        segments = self.connect(obs, waypoints, seed)
        self._probe_z = {k: self.ik.tcp_positions(s.q)[:, 2]
                         for k, (s, wp) in enumerate(zip(segments, waypoints)) if wp.probe}
        self._trims = {id(s): i for i, (s, wp) in enumerate(zip(segments, waypoints)) if wp.trim}
        return segments

    def _trim_due(self) -> int | None:
        """The index of the trimmed waypoint whose segment has just settled (None: none has)."""
        if self._k >= len(self.segments):
            return None
        seg = self.segments[self._k]
        return self._trims.get(id(seg)) if self._t == len(seg.q) + seg.settle else None

    def _trim(self, obs, i: int) -> None:
        """Measure where the hand settled at waypoint `i` (its joints, forward kinematics) and re-plan from there: the
        line-up again and every line after it, shifted by the hand's steady error (Waypoint.trim)."""
        wp = self.waypoints[i]
        self.trimmed = wp.tcp - self.scene.tcp()
        q, again = self.q9(obs), []
        for w in (replace(wp, trim=False), *self.waypoints[i + 1:]):
            if w.kind == "line":
                w = line_to(self.ik, q, w.tcp + self.trimmed, w.quat, w.gripper, w.step, w.settle)
            again.append(w)
            q = w.q
        self.segments = self._connect(obs, again, None)
        self._k, self._t = 0, 0

    def next_command(self, obs):
        if self.subtask.stops_when_sensed:
            self._confirmed = self._confirmed + 1 if self.subtask.succeeded(self.senses(obs))[0] else 0
            if self._confirmed >= CONFIRM_STEPS + self.subtask.sensed_margin:
                return None
        try:
            if self.guesses and self.blocked(obs):  # back up and line up for the next guess
                self.grasp_offset, self.tries = self.guesses.pop(0), self.tries + 1
                self.segments = self._connect(obs, self.subtask.retry(self.ik, self.scene, self.q9(obs),
                                                                      self.grasp_offset, self.senses(obs)), None)
                self._k, self._t = 0, 0
            elif (i := self._trim_due()) is not None:
                self._trim(obs, i)
        except PlanningError as e:
            self.replan_failed = str(e)
            return None
        return super().next_command(obs)

    def remark(self):
        remarks = []
        if self.trimmed is not None:
            remarks.append(f"trimmed the hand's steady error, {1000 * np.linalg.norm(self.trimmed):.1f} mm")
        if self.tries >= 2:
            remarks.append(f"felt for the hole: {self.tries} guesses, the last {1000 * self.grasp_offset:+.0f} mm "
                           "along the fingers")
        return "; ".join(remarks)

    def blocked(self, obs) -> bool:
        """Whether, on a probing segment, the TCP went down less than a third of what it was commanded to over the
        last STALL_STEPS steps (and at least STALL_DESCENT): something holds it up."""
        k, t = self._k, self._t
        if k not in self._probe_z or not 0 < t < len(self.segments[k].q):
            self._heights = []
            return False
        self._heights.append(float(self.scene.tcp()[2]))
        if len(self._heights) <= STALL_STEPS:
            return False
        commanded = self._probe_z[k][t - 1 - STALL_STEPS] - self._probe_z[k][t - 1]
        measured = self._heights[-1 - STALL_STEPS] - self._heights[-1]
        return commanded >= STALL_DESCENT and measured < commanded / 3

    def connect(self, obs, waypoints: list[Waypoint], seed: int | None) -> list[Segment]:
        raise NotImplementedError


def check_camera(env, camera: str, who: str) -> None:
    if camera not in env.scene.sensors:
        raise ValueError(f"{who} reads camera {camera!r}, which this env does not render (it has "
                         f"{list(env.scene.sensors)}); make the env with that camera")
    if "rgb" not in env.obs_mode:
        raise ValueError(f"{who} needs camera images: make the env with obs_mode='rgb', not {env.obs_mode!r}")


class LearnedController(ArmController):
    """A closed-loop learned policy run for one subtask: it acts every step until the subtask has been sensed achieved
    (and, for one that releases the part, the hand has let go) for `CONFIRM_STEPS` steps in a row, or its step budget
    is spent. Subclasses give `predict(obs) -> (7 joint targets, gripper)`.

    The confirmation is a robot's: a part let go is still moving, and one frame's percept may flicker.

    A command that would put the arm into what its scene guards (another arm, or itself) stops the controller before
    it is sent: a policy that wandered there leaves an arm from which no plan starts (its start "in collision")."""

    action_kind = "joint_targets"

    def __init__(self, env, subtask: Subtask, name: str, max_steps: int = 120):
        super().__init__(env)
        self.subtask, self.name, self.initiation, self.max_steps = subtask, name, subtask.initiation, max_steps
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
        self.guard.set_scene(self.scene.guard_obstacles())

    def next_command(self, obs):
        percept = self.senses(obs)
        achieved = self.subtask.succeeded(percept)[0]
        let_go = self._gripper > 0 and not percept[self.task.grasped]
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
