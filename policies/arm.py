"""Controllers of a task's arm: the shared outcome, safety and guard logic.

A controller here commands the 7 joint targets and the gripper of the arm its task names (`TaskDescription.arm`)
and leaves every other joint at its targets (`TaskDescription.hold_action`). Every command passes a safety check
against the Panda's joint position and velocity limits; a command that would break them stops the controller "for
safety" (the paper's `*`) and holds the arm.

A controller serving a subtask also has the subtask guard its gripper: a release the subtask would not survive
(a gear let go on top of the peg instead of on it) is not sent; the controller backs off to where the subtask
began, still holding the part, and fails, so the selector can give the subtask to another controller. It does the
same when the subtask says it is off course. Where the subtask pushes a held part, the controller also stops where it
is, and fails, when the hand is held back (the part met something: pushing on would slide it in the fingers or turn
it there).

Initiation sets, terminations and guards read the task's predicates through the controller's `senses` (see
policies/senses.py: classifiers of the cameras and joints, or the simulator's truth for recording and the oracle's
figures) and the scene as the robot knows it (the task's `Scene`: its own kinematics); the controllers' inputs stay
their own (joint angles for planning and DMPs, camera pixels for the CNN).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch

from policy_composer.policies.base import Controller
from policy_composer.policies.senses import OracleSenses, Percept, Senses
from policy_composer.tasks.base import np0
from policy_composer.tasks.panda import GRIPPER_CLOSED, GRIPPER_OPEN, JOINT_HIGH, JOINT_LOW, VELOCITY_LIMIT, ArmIK
from policy_composer.tasks.registry import task_of

# Steps a controller did not plan (a learned policy's, the way into a back-off) are limited to this fraction of the
# joint velocity limits.
STEP_SPEED_MARGIN = 0.9
# A controller whose subtask says so (`Subtask.stops_when_held_back`) stops when the hand (joint positions, forward
# kinematics) is at least HELD_BACK_LAG short of where its commands put the TCP and went less than HELD_BACK_MOTION
# towards it over the last HELD_BACK_STEPS control steps. On the peg's tuning seeds, pushes that went on lagged their
# commands by up to 14 mm while the hand moved; a push held back for longer slid the peg along the fingers.
HELD_BACK_LAG, HELD_BACK_MOTION, HELD_BACK_STEPS = 0.012, 0.003, 3


class Outcome(str, Enum):
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    SAFETY_STOP = "stopped for safety"


@dataclass
class Segment:
    """Joint targets to follow one per control step, then `settle` steps holding the last, gripper fixed."""

    q: np.ndarray  # (T, 7)
    gripper: float
    settle: int = 4


class ArmController(Controller):
    """Base of the controllers of a task's arm: outcome bookkeeping, the safety check, the task's flat action."""

    obs_keys = ("extra.state",)
    action_kind = "joint_targets"
    subtask = None  # the task's Subtask it serves: guards the release, says how to back off

    def __init__(self, env):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.task = task_of(self.env)
        self.rate_hz = float(self.env.control_freq)
        self.ik = ArmIK(self.env, self.task.arm)
        self.scene = self.task.scene(self.env)
        self.senses: Senses = OracleSenses(self.env)  # build_library gives its controllers one to share
        self.outcome = Outcome.DONE
        self.reason = ""
        self._gripper = GRIPPER_OPEN

    # ------------------------------------------------------------ subclass hooks
    def next_command(self, obs) -> tuple[np.ndarray, float] | None:
        """The next (7 joint targets, gripper command), or None when the controller has finished."""
        raise NotImplementedError

    def succeeded(self, percept: Percept) -> tuple[bool, str]:
        """Judge the finished activation from what is sensed at its end: (success, reason if not)."""
        return True, ""

    def remark(self) -> str:
        """What the finished activation did that its outcome does not say (for the decision log; "" if nothing)."""
        return ""

    # ------------------------------------------------------------ the interface
    def reset(self, obs, seed: int | None = None) -> None:
        self.outcome, self.reason = Outcome.RUNNING, ""
        self.scene.seed(seed)
        self._hold = np0(self.task.hold_action(self.env))
        self._last = self.arm_qpos(obs)
        self._gripper = float(self._hold[7])
        self._back_off: list[np.ndarray] | None = None  # joint targets still to go, once backing off
        self._back_off_reason = ""
        self._hand: deque[np.ndarray] = deque(maxlen=HELD_BACK_STEPS + 1)  # the measured TCP, for `held_back`

    def act(self, obs) -> torch.Tensor:
        action = self._hold.copy()
        if self.outcome is Outcome.RUNNING:
            cmd = self._guarded_command(obs)
            if cmd is None:
                backed_off = self._back_off is not None
                ok, why = (False, self._back_off_reason) if backed_off else self.succeeded(self.senses(obs))
                self.outcome = Outcome.DONE if ok else Outcome.FAILED
                self.reason = "; ".join(r for r in ("" if ok else why, self.remark()) if r)
            else:
                q, gripper = cmd
                violation = self.safety_violation(q)
                if violation:
                    self.outcome, self.reason = Outcome.SAFETY_STOP, violation
                else:
                    self._last, self._gripper = q, gripper
        action[:7], action[7] = self._last, self._gripper
        return torch.as_tensor(action, dtype=torch.float32)

    def done(self, obs=None) -> bool:
        return self.outcome is not Outcome.RUNNING

    @property
    def backing_off(self) -> str:
        """Why the subtask's guard has taken over, the commands being its back-off's ("" while they are the
        controller's own)."""
        return self._back_off_reason if self._back_off is not None else ""

    def _guarded_command(self, obs) -> tuple[np.ndarray, float] | None:
        """The next command, unless the subtask says to stop here (a release it would not survive, or the part led
        off its course): then the back-off's next one."""
        if self._back_off is None:
            held = self.held_back(obs) if self.subtask is not None and self.subtask.stops_when_held_back else ""
            if held:
                self._back_off, self._back_off_reason = [], f"held back: {held}"
                return None
            cmd = self.next_command(obs)
            if self.subtask is None:
                return cmd
            opening = cmd is not None and cmd[1] > 0
            percept = self.senses(obs)
            why = ((self.subtask.release_blocked(percept, self.scene) if opening else "")
                   or self.subtask.off_course(percept, cmd is None))
            if not why:
                return cmd
            path = self.subtask.back_off(self.ik, self.scene, np0(self.ik.arm.robot.get_qpos()))
            # The path starts at the measured joints, which lag the last command where the arm pushed against
            # something: the targets first go back to them at a safe speed instead of jumping.
            self._back_off = [*ramp(self._last, path[0], self.rate_hz)[:-1], *path] if len(path) else []
            self._back_off_reason = f"{'backed off' if self._back_off else 'kept the part (no way back)'}: {why}"
        return (self._back_off.pop(0), GRIPPER_CLOSED) if self._back_off else None

    def held_back(self, obs) -> str:
        """Why the hand is held back from where its commands have gone ("" if it is not): from the commands and the
        measured joints, as the arm's own controller knows them."""
        commanded, measured = self.ik.tcp_positions(np.stack([self._last, self.arm_qpos(obs)]))
        self._hand.append(measured)
        lag = commanded - measured
        short = float(np.linalg.norm(lag))
        if len(self._hand) <= HELD_BACK_STEPS or short < HELD_BACK_LAG:
            return ""
        went = float((measured - self._hand[0]) @ lag) / short
        if went >= HELD_BACK_MOTION:
            return ""
        return (f"the hand is {1000 * short:.0f} mm short of its command and went {1000 * went:.0f} mm towards it "
                f"over the last {HELD_BACK_STEPS} steps: the part met something")

    def safety_violation(self, q: np.ndarray) -> str:
        """Why joint targets `q` would break the Panda's limits ("" if they would not)."""
        q = np.asarray(q, dtype=np.float64)
        if not np.all(np.isfinite(q)):
            return f"{self.name}: non-finite joint target {q}"
        outside = np.flatnonzero((q < JOINT_LOW) | (q > JOINT_HIGH))
        if len(outside):
            j = outside[0]
            return (f"{self.name}: joint {j + 1} target {q[j]:.3f} rad is outside the Panda's limits "
                    f"[{JOINT_LOW[j]:.3f}, {JOINT_HIGH[j]:.3f}]")
        speed = np.abs(q - self._last) * self.rate_hz
        fast = np.flatnonzero(speed > VELOCITY_LIMIT)
        if len(fast):
            j = fast[0]
            return (f"{self.name}: joint {j + 1} would move at {speed[j]:.2f} rad/s, over the Panda's limit "
                    f"{VELOCITY_LIMIT[j]:.2f} rad/s")
        return ""

    # ------------------------------------------------------------ helpers
    @staticmethod
    def arm_qpos(obs) -> np.ndarray:
        """The driven arm's 7 joint angles (the first entries of observation.state)."""
        return np0(obs["extra"]["state"])[:7]

    def describe(self, obs) -> str:
        return self.senses(obs).why(*self.task.progress)


def ramp(q_from: np.ndarray, q_to: np.ndarray, rate_hz: float) -> np.ndarray:
    """Joint targets (T, 7) from `q_from` (left out) to `q_to` (the last), evenly spaced so that no joint moves faster
    than `STEP_SPEED_MARGIN` of the Panda's velocity limit; T >= 1."""
    step = np.asarray(q_to, dtype=np.float64) - q_from
    n = max(1, int(np.ceil(np.max(np.abs(step) * rate_hz / (STEP_SPEED_MARGIN * VELOCITY_LIMIT)))))
    return q_from + step * (np.arange(1, n + 1) / n)[:, None]


def run_activation(env, controller: Controller, obs, seed: int | None = None, max_steps: int = 400):
    """Start `controller` from obs and step the env until it terminates (or max_steps); returns the last observation.
    The controller's `outcome` and `reason` say how the activation ended."""
    u = env.unwrapped
    task = task_of(u)
    controller.start(obs, seed=seed)
    for _ in range(max_steps):
        if controller.done(obs):
            break
        obs, *_ = env.step(task.env_action(u, controller.act(obs)))
    return obs


class ScriptedController(ArmController):
    """A controller that plans its whole activation at the start as segments of joint targets (MP, DMP)."""

    def plan(self, obs, seed: int | None) -> list[Segment]:
        raise NotImplementedError

    def reset(self, obs, seed: int | None = None) -> None:
        super().reset(obs, seed)
        self.segments = self.plan(obs, seed)
        # A plan may start away from the measured joints (an arm that was pushing against something lags its last
        # commands, and the plan's first target is solved for where the part should be): ramp there at a safe speed.
        first = next((s for s in self.segments if len(s.q)), None)
        if first is not None:
            lead = ramp(self._last, first.q[0], self.rate_hz)[:-1]
            if len(lead):
                self.segments.insert(0, Segment(lead, first.gripper, settle=0))
        self._k, self._t = 0, 0

    def next_command(self, obs):
        while self._k < len(self.segments):
            seg = self.segments[self._k]
            T = len(seg.q)
            if self._t < T + seg.settle:
                q = seg.q[min(self._t, T - 1)]
                self._t += 1
                return q, seg.gripper
            self._k, self._t = self._k + 1, 0
        return None

    @property
    def trajectory(self) -> np.ndarray:
        """The planned joint targets of the activation, (T, 7)."""
        return np.concatenate([s.q for s in self.segments]) if self.segments else np.zeros((0, 7))
