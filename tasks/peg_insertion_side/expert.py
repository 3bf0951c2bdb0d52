"""Scripted expert for ManiSkill's PegInsertionSide-v1, using privileged state (the true peg and hole poses).

**What it does:** the Panda picks the peg up from above, behind its centre (ManiSkill's grasp point, so the fingers
stay clear of the box while the head goes in), lifts it, carries it along a collision-free joint path to the
pre-insertion pose (the peg's axis on the hole's, its head `pre_insertion` in front of the box's near face), corrects
the residual error there, pushes the peg along the hole's axis until the strict success holds and on to the depth
the library's insertions aim at, and holds still.

**Why the grasp is chosen:** what the hand does at the box is fixed by the grasp, so each episode's grasp is the
first of a short list (hand straight down, then tilted about the closing axis, nearer or farther from the peg's
centre, then turned about) from which IK reaches the peg, the pre-insertion pose and the seated pose without the arm
touching the table or the box (the planner's collision model, plus panda_wristcam's wrist camera, which that model
lacks). A low, far hole meets a hand straight down with the forearm; a peg at the edge of the reach needs a grasp
nearer its centre, and then a camera on the head's side meets the box.

**Why closed loop:** the fingers centre the peg across them, but it may slide along them or pivot about them while
they close, and the arm sags a few mm under it. So every pose the expert commands from the grasp on is one for the
peg, not for the hand: the hand's target is the peg's target times the peg-in-hand transform measured at that step,
corrected by the integral of the peg's measured error off the hole's axis. The hole is 3 mm wider than the peg each
side and the peg is square, so its roll about its axis matters as well as its axis (all six degrees are corrected).

**Why planned:** the carry from the table to the box is planned in joint space (OMPL's RRT-Connect, the library's
`policies.mp.planning`) against the table and the box's four walls, with the held peg attached to the hand as a
cylinder around it, and time-parameterised to the Panda's velocity limits. A straight Cartesian carry swings the
elbow and the peg's tail about and can sweep the peg through the box's edge.

**Why it stops:** ManiSkill's success has no bound on the far side (a peg pushed through the box counts); the
expert pushes on from the step the strict success (`env.strict_success`) holds to a depth (`seat_depth`) far short
of the box's far face, so the head is never past it; so deep, because the predicate classifiers learn "seated" from
these recordings, and the library's insertions leave the peg anywhere between ManiSkill's bound and that depth.

**Action:** ``pd_joint_pos``, 8-D: the 7 arm joint targets (rad, absolute, not normalised) and the gripper in
[-1, 1], which ManiSkill maps linearly onto a target of each (mimicked) finger joint in [-0.01, 0.04] m: +1 opens
the fingers 40 mm each, -1 closes them to -10 mm, past touching, so a held peg is squeezed at the drive's force limit.

Joint targets come from SAPIEN's pinocchio IK (`tasks.panda.ArmIK`); where IK fails the last reachable
configuration is kept. Deterministic given the seed. Works on a single environment (``num_envs == 1``), CPU sim.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import coal
import numpy as np
import pinocchio as pin
import sapien
import torch
from transforms3d.quaternions import axangle2quat, qinverse, qmult, quat2axangle

from policy_composer.policies.mp.planning import SceneCollisionModel, plan_rrt_connect, time_parameterize
from policy_composer.tasks.base import PlanningError, np0
from policy_composer.tasks.panda import GRIPPER_CLOSED, GRIPPER_OPEN, JOINT_HIGH, JOINT_LOW, ArmIK, hand_down_quat, se3
from policy_composer.tasks.peg_insertion_side.flags import HOLE_ENTRY, box_half_depth, strict_success
from policy_composer.tasks.peg_insertion_side.scene import box_obstacles, plan_grasp, pose0, tilt_quat
from policy_composer.tasks.peg_insertion_side.spec import EXPERT_PHASES  # noqa: F401  (its phases, in order)
from policy_composer.tasks.peg_insertion_side.subtasks import SEATED
from policy_composer.tasks.scene import HeldObject, table_obstacle

HELD_MARGIN = 0.004  # around the held peg, the wrist camera and the box's walls in the collision checks (m)
CAMERA_LINK = "camera_link"  # panda_wristcam's wrist camera


@dataclass
class ExpertConfig:
    max_step: float = 0.02  # TCP travel per control step in the free Cartesian motions (approach, lift) (m)
    max_rot_step: float = 0.12  # TCP rotation per control step in those (rad)
    approach_height: float = 0.06  # TCP above the grasp point before the descent (m)
    descend_step: float = 0.01  # TCP travel per control step descending onto the peg (m)
    # Grasp point from the peg's centre toward its tail (m); None: ManiSkill's max(0.05, half-length / 2 + 0.01),
    # far enough back that the fingers stay out of the box with the head at the hole's centre.
    grasp_offset: float | None = None
    # The grasps tried, in order, until one is feasible (see PegInsertionSideExpert._choose_grasp): the hand as it
    # comes (TCP x toward the peg's head, the wrist camera on that side) or turned about; its tilt about the closing
    # axis, the wrist toward the peg's tail (rad); shifts of grasp_offset (m).
    grasp_turns: tuple[bool, ...] = (False, True)
    grasp_pitches: tuple[float, ...] = (0.0, 0.3, -0.3, 0.5, -0.5)
    grasp_offset_shifts: tuple[float, ...] = (0.0, -0.02, 0.02)
    close_steps: int = 6  # control steps the gripper takes to close on the peg
    lift_height: float = 0.08  # TCP rise off the table before the carry (m)
    pre_insertion: float = 0.02  # the peg's head in front of the box's near face at the pre-insertion pose (m)
    move_speed: float = 0.5  # the planned carry runs at this fraction of the joint velocity limits
    plan_checks: int = 20_000  # collision checks the carry's RRT-Connect plan may spend
    settle_tol: float = 0.005  # the carry ends once the measured TCP is this close to the plan's end (m)
    settle_steps: int = 15  # or after holding the plan's end this long
    align_step: float = 0.01  # hand target change per control step while aligning and inserting, at most (m)
    integral_gain: float = 0.4  # fraction of the peg's lateral and angular error added to the hand's bias a step
    align_tol: float = 0.0015  # aligned when the peg's head and tail are this close to the hole's axis line (m)
    align_steps: int = 20  # insert anyway after aligning this long
    insert_step: float = 0.005  # push along the hole's axis per control step (m)
    # The peg's target leads its measured head along the hole's axis by at most this many insert steps (a peg caught
    # on the hole's rim is not rammed harder and harder).
    insert_lead: float = 3.0
    # Once the peg is seated, the push goes on until its head is this far past the hole's centre plane (m), as deep as
    # the library's insertions aim it, or for at most seat_steps control steps more: the recordings then show a seated
    # peg over the depths those insertions leave it at, not only at ManiSkill's bound.
    seat_depth: float = SEATED
    seat_steps: int = 8
    # DART (Laskey et al. 2017): while aligning and inserting, the executed TCP target is off the expert's own by a
    # slowly drifting offset of this standard deviation per axis (m), which the expert does not know of; it corrects
    # the peg that strays with it, and the recorded action is its own command.
    noise: float = 0.0
    noise_steps: float = 10.0  # the offset's correlation time, control steps
    # Step from where the hand is (the measured TCP), and follow the carry's plan from the waypoint nearest the
    # measured joints, not from the expert's own last command: labels for states another policy drives (DAgger), each a
    # move the learner can make, as large as the expert's own steps (see _move_peg and _insert_target). A learner adds
    # its steps to its command, which is the integral action, so the expert keeps none of its own.
    from_arm: bool = False


@dataclass
class EpisodeResult:
    seed: int
    strict_success: bool  # the peg seated, not past the far face, when the episode ended
    success: bool  # ManiSkill's success then
    overshoot: bool  # ManiSkill's success held at some step without the strict success
    steps: int
    phases: list[str] = field(default_factory=list)  # the expert's phase after choosing each step's action


def _rotation_between(q_from: np.ndarray, q_to: np.ndarray) -> tuple[np.ndarray, float]:
    """(axis, angle in [0, pi]) of the world-frame rotation taking orientation q_from to q_to."""
    rel = qmult(q_to, qinverse(q_from))
    if rel[0] < 0:
        rel = -rel
    axis, angle = quat2axangle(rel)
    return np.asarray(axis), float(angle)


def step_pose(current: sapien.Pose, goal: sapien.Pose, max_step: float, max_rot: float,
              gain: float = 1.0) -> sapien.Pose:
    """`current` moved toward `goal` by the fraction `gain` of the way, at most `max_step` (m) and `max_rot` (rad):
    translation and rotation scaled alike, so the two arrive together."""
    dp = (goal.p - current.p) * gain
    axis, angle = _rotation_between(current.q, goal.q)
    angle *= gain
    dist = float(np.linalg.norm(dp))
    scale = min(1.0, max_step / dist if dist > 0 else 1.0, max_rot / angle if angle > 0 else 1.0)
    q = qmult(axangle2quat(axis, angle * scale), current.q) if angle > 0 else current.q
    return sapien.Pose(current.p + dp * scale, q)


def pose_error(a: sapien.Pose, b: sapien.Pose) -> tuple[float, float]:
    """(distance m, angle rad) between two poses."""
    return float(np.linalg.norm(a.p - b.p)), _rotation_between(a.q, b.q)[1]


class PegInsertionSideExpert:
    """Phase machine through EXPERT_PHASES: approach -> descend -> close -> lift -> move -> align -> insert -> done.

    After `reset`: `grasp_turned`, `grasp_pitch`, `grasp_offset` (the grasp chosen), `grasp_feasible` (whether it
    passed the reach and collision checks); after each `act`: `label` (the action returned) and `executed` (the action
    to send: the label moved by the DART noise where it is on); `plan_error` says why the carry's plan failed, if it
    did."""

    name = "expert"

    def __init__(self, env, config: ExpertConfig | None = None):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        if self.env.num_envs != 1:
            raise ValueError(f"the scripted expert drives one environment; got num_envs={self.env.num_envs}")
        if self.env.control_mode != "pd_joint_pos":
            raise ValueError(f"the scripted expert sends pd_joint_pos actions; the env's control mode is "
                             f"{self.env.control_mode!r}")
        self.config = config or ExpertConfig()
        self._ik = ArmIK(self.env, "agent")
        self.phase = "done"

    # ------------------------------------------------------------------ the scene (privileged)
    def _peg(self) -> sapien.Pose:
        return pose0(self.env.peg.pose)

    def _hole(self) -> sapien.Pose:
        return pose0(self.env.box_hole_pose)

    def _tcp(self) -> sapien.Pose:
        return pose0(self.env.agent.tcp.pose)

    def _qpos(self) -> np.ndarray:
        return np0(self.env.agent.robot.get_qpos())

    def peg_goal(self, head_x: float) -> sapien.Pose:
        """The peg's pose on the hole's axis, its frame the hole's, its head at `head_x` along the axis from the
        hole's centre plane (the box's near face is at -box_half_depth)."""
        return self._hole() * sapien.Pose([head_x - self._half_length, 0.0, 0.0])

    def head_in_hole(self) -> np.ndarray:
        """The peg's head in the hole's frame (x along the axis into the box)."""
        return (self._hole().inv() * self._peg() * self._head).p

    # ------------------------------------------------------------------ commands
    def _solve(self, target: sapien.Pose, seed: np.ndarray) -> tuple[np.ndarray, bool]:
        q, ok = self._ik.solve(target, seed)
        return q, ok and bool(np.all(q[:7] >= JOINT_LOW) and np.all(q[:7] <= JOINT_HIGH))

    def _ik_joint_targets(self, target: sapien.Pose) -> np.ndarray:
        q, ok = self._solve(target, self._q_seed)
        if ok:  # otherwise keep the last reachable configuration
            self._q_seed = q
        return self._q_seed[:7]

    def _command_base(self) -> sapien.Pose:
        """Where the next Cartesian step starts: the expert's last command, or the measured hand (from_arm)."""
        return self._tcp() if self.config.from_arm else self._cmd

    def _toward(self, goal: sapien.Pose, step: float) -> tuple[sapien.Pose, float]:
        """The next TCP target on the way to `goal`, and the distance that was left."""
        start = self._command_base()
        self._cmd = step_pose(start, goal, step, self.config.max_rot_step)
        dist, angle = pose_error(start, goal)
        return self._cmd, max(dist, angle * 0.05)  # 1 rad counted as 50 mm

    def _move_peg(self, peg_target: sapien.Pose) -> sapien.Pose:
        """The TCP target putting the peg at `peg_target`: the hand pose that does so as the hand holds the peg now
        (the measured peg-in-hand transform), corrected by the integral of the peg's lateral and angular error off the
        hole's axis (the arm's static sag under the held peg, which a target from the measured state alone leaves),
        reached at most align_step and max_rot_step a control step from the last command. The error along the axis is
        not integrated: there it is the arm's lag while pushing, which insert_lead bounds.

        Labelling a learner (from_arm), the hand is only moved, not turned: the learned insertion keeps its hand's
        orientation (`Scene.hand_quat`), so the label is the move that puts the peg's head where `peg_target` has it."""
        cfg = self.config
        peg, tcp = self._peg(), self._tcp()
        if cfg.from_arm:
            hand = sapien.Pose(tcp.p + (peg_target * self._head).p - (peg * self._head).p, tcp.q)
        else:
            along = (self._hole().inv() * peg).p[0]
            on_axis = self._hole() * sapien.Pose([along, 0.0, 0.0])
            self._bias = step_pose(peg, on_axis, np.inf, np.inf, cfg.integral_gain) * peg.inv() * self._bias
            hand = self._bias * peg_target * peg.inv() * tcp
        self._cmd = step_pose(self._command_base(), hand, cfg.align_step, cfg.max_rot_step)
        return self._cmd

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> None:
        """Read the new episode's scene (call after env.reset). An episode that starts with the peg in the hand (the
        pre-insertion start) starts at the alignment."""
        env, cfg = self.env, self.config
        self._half_length = float(env.peg_half_sizes[0, 0])
        self._head = sapien.Pose([self._half_length, 0.0, 0.0])  # the peg's head in its frame
        self._half_width = float(env.peg_half_sizes[0, 1])
        self._box_half_depth = float(box_half_depth(env)[0])
        episode_seed = seed if seed is not None else int(env._episode_seed[0])
        self._q_seed = self._qpos()
        self._cmd = self._tcp()
        self.phase, self._timer, self._gripper = "approach", 0, GRIPPER_OPEN
        self._seated_at: int | None = None  # the control step the peg was first seated at
        # A Cartesian motion has arrived when its command has (the expert's own), or, stepping from the measured hand,
        # when the hand is within settle_tol: the PD arm sags a few mm under the held peg, short of its target.
        self._arrived = cfg.settle_tol if cfg.from_arm else 1e-3
        self._collision = SceneCollisionModel(self._ik.base())
        self._obstacles = [table_obstacle(), *box_obstacles(self.env, HELD_MARGIN)]  # the walls grown by HELD_MARGIN
        self._walls = self._obstacles[1:]
        self._camera = self._camera_shapes()
        self._plan: np.ndarray | None = None
        self.plan_error: str | None = None  # why the carry's plan failed, if it did (a straight joint line is run)
        self._noise_rng = np.random.default_rng([episode_seed, 1])
        self._offset = np.zeros(3)
        self.label: torch.Tensor | None = None  # the last action the expert commanded
        self.executed: torch.Tensor | None = None  # the last action sent, noise included (see ExpertConfig.noise)
        if bool(self.env.agent.is_grasping(self.env.peg)[0]):  # an episode that starts with the peg in the hand
            self.phase, self._gripper, self._bias = "align", GRIPPER_CLOSED, sapien.Pose()
            self.grasp_turned, self.grasp_pitch, self.grasp_feasible = False, 0.0, True
            self.grasp_offset = float(-(self._tcp().inv() * self._peg()).p[0])
            return
        self._choose_grasp()
        self._above = self._grasp * sapien.Pose([0.0, 0.0, -cfg.approach_height])

    def act(self, obs=None) -> torch.Tensor:
        """The next 8-D pd_joint_pos action (7 arm joint targets, gripper)."""
        cfg = self.config
        self._timer += 1
        target = None
        self._check_seated()
        if self.phase == "approach":
            target, left = self._toward(self._above, cfg.max_step)
            if left < self._arrived:
                self.phase, self._timer = "descend", 0
        elif self.phase == "descend":
            target, left = self._toward(self._grasp, cfg.descend_step)
            # The fingers close once the hand is at the peg (or has tried for long enough), not merely commanded there.
            if left < self._arrived and (np.linalg.norm(self._tcp().p - self._grasp.p) < 0.004 or self._timer > 25):
                self.phase, self._timer = "close", 0
        elif self.phase == "close":
            self._gripper = GRIPPER_CLOSED
            if self._timer >= cfg.close_steps:
                self._lift = sapien.Pose(self._cmd.p + [0.0, 0.0, cfg.lift_height], self._cmd.q)
                self.phase = "lift"
        elif self.phase == "lift":
            target, left = self._toward(self._lift, cfg.max_step)
            if left < self._arrived:
                self._plan_move()
                self.phase, self._timer, target = "move", 0, None
        if self.phase == "move":
            q7 = self._follow_plan()
            self._q_seed = np.concatenate([q7, self._q_seed[7:]])
            if self._plan_index >= len(self._plan):
                # The arm lags its plan; the alignment's integral would take the lag for the arm's sag under the
                # peg, so it starts once the arm is there.
                self._cmd = self._tcp_of(self._q_seed)
                settled = np.linalg.norm(self._tcp().p - self._cmd.p) < cfg.settle_tol
                if settled or self._plan_index >= len(self._plan) + cfg.settle_steps:
                    self.phase, self._timer, self._bias = "align", 0, sapien.Pose()
        elif self.phase == "align":
            goal = self.peg_goal(-self._box_half_depth - cfg.pre_insertion)
            target = self._move_peg(goal)
            if self._axis_error(goal) < cfg.align_tol or self._timer >= cfg.align_steps:
                self._begin_insert()
        elif self.phase == "insert":
            target = self._insert_target()
        action = np.empty(8)
        if target is not None:
            action[:7] = self._ik_joint_targets(target)
        else:
            action[:7] = self._q_seed[:7]
        action[7] = self._gripper
        self.label = torch.as_tensor(action, dtype=torch.float32)
        perturbed = self._perturbed(action, target)
        self.executed = self.label if perturbed is action else torch.as_tensor(perturbed, dtype=torch.float32)
        return self.label

    # ------------------------------------------------------------------ phases
    def _axis_error(self, goal: sapien.Pose) -> float:
        """How far the measured peg's head and tail are from where `goal` puts them (m)."""
        peg = self._peg()
        ends = [sapien.Pose([s * self._half_length, 0.0, 0.0]) for s in (1.0, -1.0)]
        return max(float(np.linalg.norm((peg * e).p - (goal * e).p)) for e in ends)

    def _begin_insert(self) -> None:
        """Phase insert, the push starting from where the head is."""
        self.phase, self._timer, self._push_x = "insert", 0, float(self.head_in_hole()[0])

    def _insert_target(self) -> sapien.Pose:
        """The peg's target on the hole's axis, its head advanced by insert_step a control step, never more than
        insert_lead steps ahead of the measured head (with from_arm: one step ahead of it, the step its own command
        takes); the hand's target follows from the measured grasp, so the head's and the axis's lateral errors are
        corrected as it goes."""
        cfg = self.config
        head_x = float(self.head_in_hole()[0])
        if cfg.from_arm:
            self._push_x = head_x + cfg.insert_step
        else:
            self._push_x = min(self._push_x + cfg.insert_step, head_x + cfg.insert_lead * cfg.insert_step)
        return self._move_peg(self.peg_goal(self._push_x))

    def _tcp_of(self, q9: np.ndarray) -> sapien.Pose:
        model, data = self._collision.model, self._collision.data
        pin.framesForwardKinematics(model, data, q9)
        local = data.oMf[model.getFrameId("panda_hand_tcp")]
        return self._ik.base() * sapien.Pose(local.translation, pin.Quaternion(local.rotation).coeffs()[[3, 0, 1, 2]])

    def _held_peg(self) -> HeldObject:
        """The peg as the planner carries it: a cylinder around its square section, along its axis, placed in the
        hand joint's frame as the measured grasp holds it."""
        model = self._collision.model
        joint7_to_tcp = model.frames[model.getFrameId("panda_hand_tcp")].placement
        tcp_to_peg = se3(self._tcp().inv() * self._peg())
        along_x = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3))  # coal's cylinder axis (z) onto the peg's x
        radius = self._half_width * np.sqrt(2.0) + HELD_MARGIN
        return HeldObject(radius, 2 * (self._half_length + HELD_MARGIN), joint7_to_tcp * tcp_to_peg * along_x)

    def _camera_shapes(self) -> list[tuple[coal.Box, sapien.Pose]]:
        """The wrist camera's collision boxes (grown by HELD_MARGIN) and their poses in the TCP frame: panda_wristcam
        carries it on the hand's side toward the peg's head, and the planner's Panda model has no camera."""
        agent = self.env.agent
        link = agent.robot.links_map[CAMERA_LINK]
        tcp_to_link = pose0(agent.tcp.pose).inv() * pose0(link.pose)
        return [(coal.Box(*(2 * (np.asarray(shape.half_size, dtype=float) + HELD_MARGIN))),
                 tcp_to_link * shape.get_local_pose()) for shape in link._objs[0].get_collision_shapes()]

    def _camera_clear(self, tcp: sapien.Pose) -> bool:
        """Whether the wrist camera clears the box's walls with the TCP at `tcp`."""
        for shape, local in self._camera:
            where = se3(tcp * local)
            for wall in self._walls:
                if coal.collide(shape, where, wall.shape, wall.pose, coal.CollisionRequest(), coal.CollisionResult()):
                    return False
        return True

    def _choose_grasp(self) -> None:
        """The grasp (self._grasp, and self._q_pre, the arm at the pre-insertion pose it leads to): the first of
        ExpertConfig's grasps (hand turns, pitches, offsets) from which the arm reaches the peg without touching the
        table, and reaches the pre-insertion pose and the seated pose without touching the box, as a grasp holding
        the peg where it is aimed would. Where the hole is low and far, a hand straight down meets the box with its
        forearm (link5) before the head is in; a hand tilted back keeps it clear. Where the peg lies at the edge of
        the reach, a grasp nearer the peg's centre reaches it, and the hand turned about, its wrist camera toward
        the tail, keeps the camera off the box. None feasible: the first is taken."""
        cfg = self.config
        self._collision.set_scene(self._obstacles, held=None, fingers=0.04)
        peg = self._peg()
        axis = peg.to_transformation_matrix()[:3, 0]
        default = cfg.grasp_offset if cfg.grasp_offset is not None else max(0.05, self._half_length / 2 + 0.01)
        candidates = []
        for turned in cfg.grasp_turns:
            # Hand down, the fingers closing across the peg, the TCP's x along the peg's axis toward its head (the
            # hand turns the least on its way to the hole, whose axis, like the peg's, points away from the robot),
            # or turned about toward its tail; then tilted about the closing axis (TCP y), the wrist toward the tail
            # for a positive pitch.
            x = -axis if turned else axis
            for pitch in cfg.grasp_pitches:
                quat = qmult(hand_down_quat(x), tilt_quat(-pitch if turned else pitch))
                for shift in cfg.grasp_offset_shifts:
                    offset = float(np.clip(default + shift, 0.04, self._half_length - 0.02))
                    candidates.append(((turned, pitch, offset), sapien.Pose(peg.p - axis * offset, quat)))
        chosen = next(((c, q_pre) for c in candidates if (q_pre := self._feasible(c[1])) is not None), None)
        self.grasp_feasible = chosen is not None  # whether a grasp passed the checks (else the preferred one is tried)
        ((self.grasp_turned, self.grasp_pitch, self.grasp_offset), self._grasp), self._q_pre = \
            chosen or (candidates[0], None)
        plan_grasp(self.env, -self.grasp_pitch if self.grasp_turned else self.grasp_pitch, self.grasp_offset)

    def _feasible(self, grasp: sapien.Pose) -> np.ndarray | None:
        """The arm at the pre-insertion pose after `grasp` (9), or None where IK or the collision model (table, box,
        no held peg; the wrist camera against the box) rules the grasp out. IK is chained the way the phases will seed
        it."""
        cfg = self.config
        q, ok = self._solve(grasp * sapien.Pose([0.0, 0.0, -cfg.approach_height]), self._q_seed)
        if ok:
            q, ok = self._solve(grasp, q)
        if not ok or self._collision.in_collision(q[:7]):
            return None
        q, ok = self._solve(sapien.Pose(grasp.p + [0.0, 0.0, cfg.lift_height], grasp.q), q)
        peg_in_hand = grasp.inv() * self._peg()
        pre_x = -self._box_half_depth - cfg.pre_insertion
        q_pre = None
        seated = HOLE_ENTRY + 2 * cfg.insert_step  # as far in as the push must go to seat the peg, with some lag
        for head_x in np.linspace(pre_x, seated, 5):  # the pre-insertion pose, then the insertion
            if not ok:
                return None
            tcp = self.peg_goal(head_x) * peg_in_hand.inv()
            q, ok = self._solve(tcp, q)
            if not ok or self._collision.in_collision(q[:7]) or not self._camera_clear(tcp):
                return None
            q_pre = q if q_pre is None else q_pre
        return q_pre

    def _plan_move(self) -> None:
        """Plan the carry to the pre-insertion pose from the lifted configuration, with the peg as held now."""
        cfg = self.config
        fingers = float(np.mean(self._qpos()[7:9]))
        self._collision.set_scene(self._obstacles, held=self._held_peg(), fingers=fingers)
        goal_peg = self.peg_goal(-self._box_half_depth - cfg.pre_insertion)
        goal_tcp = goal_peg * self._peg().inv() * self._tcp()
        start = self._q_seed.copy()
        ok = False
        for seed in ([] if self._q_pre is None else [self._q_pre]) + [start]:  # the arm posture the grasp was chosen by
            q_goal, ok = self._solve(goal_tcp, seed)
            if ok:
                break
        dt = 1.0 / self.env.control_freq
        try:
            if not ok:
                raise PlanningError("no IK solution for the pre-insertion pose")
            path = plan_rrt_connect(self._collision, start[:7], q_goal[:7], cfg.plan_checks)
        except PlanningError as e:
            self.plan_error = str(e)
            path = np.stack([start[:7], q_goal[:7] if ok else start[:7]])
        self._plan = time_parameterize(path, dt, cfg.move_speed)
        self._plan_index = 0

    def _follow_plan(self) -> np.ndarray:
        """The carry's next joint target: the plan's next waypoint, or (from_arm) the one after the waypoint nearest
        the measured joints."""
        if self.config.from_arm:
            nearest = int(np.argmin(np.abs(self._plan - self._qpos()[:7]).sum(axis=1)))
            self._plan_index = max(self._plan_index, nearest)
        q7 = self._plan[min(self._plan_index, len(self._plan) - 1)]
        self._plan_index += 1
        return q7

    def _perturbed(self, action: np.ndarray, target: sapien.Pose | None) -> np.ndarray:
        """`action` with the TCP target moved by the drifting offset (ExpertConfig.noise): it drifts while aligning and
        inserting. Steps without a TCP target (the gripper closing, the planned carry, holding) go as commanded."""
        cfg = self.config
        if cfg.noise <= 0.0 or target is None or self.phase not in ("align", "insert"):
            return action
        a = float(np.exp(-1.0 / cfg.noise_steps))
        self._offset = a * self._offset + np.sqrt(1.0 - a * a) * cfg.noise * self._noise_rng.standard_normal(3)
        q, ok = self._solve(sapien.Pose(target.p + self._offset, target.q), self._q_seed)
        return np.concatenate([q[:7], action[7:]]) if ok else action

    def _check_seated(self) -> None:
        """Stop pushing once the head is seated (the strict success, read while aligning and inserting) and at
        seat_depth, or seat_steps control steps after it was first seated: phase done, the arm's target the peg where
        it is, with no push left in it."""
        if self.phase not in ("align", "insert") or not bool(strict_success(self.env)[0]):
            return
        if self.phase == "align":
            self._begin_insert()
        head_x, step = float(self.head_in_hole()[0]), int(self.env.elapsed_steps[0])
        self._seated_at = step if self._seated_at is None else self._seated_at
        if head_x >= self.config.seat_depth or step - self._seated_at >= self.config.seat_steps:
            self.phase = "done"
            self._ik_joint_targets(self._move_peg(self.peg_goal(head_x)))

    @property
    def done(self) -> bool:
        """Whether the peg is seated, as of the last env step (reading it ends the insertion the step it is)."""
        self._check_seated()
        return self.phase == "done"


def maniskill_success(info: dict) -> bool:
    """ManiSkill's own success in a step's info (the library's adapter moves it to `success_maniskill`)."""
    return bool(info.get("success_maniskill", info["success"])[0])


def run_episode(env, expert: PegInsertionSideExpert, seed: int, max_steps: int | None = None,
                on_step: Callable[[int, dict], None] | None = None) -> EpisodeResult:
    """Reset with `seed` and run the expert until it is done or `max_steps` (the env's limit unless given), sending
    its executed action (the label, unless DART noise is on). ManiSkill's termination on success is not obeyed: the
    expert's own `done` ends the episode, so a push past the far face would show."""
    obs, info = env.reset(seed=seed)
    expert.reset(seed)
    max_steps = max_steps or getattr(env.spec, "max_episode_steps", None) or 100
    phases, steps, overshoot = [], 0, False
    while steps < max_steps and not expert.done:
        expert.act(obs)
        phases.append(expert.phase)
        obs, _, _, _, info = env.step(expert.executed)
        steps += 1
        strict = bool(strict_success(env)[0])
        overshoot |= bool(maniskill_success(info)) and not strict
        if on_step is not None:
            on_step(steps, info)
    return EpisodeResult(seed=seed, strict_success=bool(strict_success(env)[0]), success=maniskill_success(info),
                         overshoot=overshoot, steps=steps, phases=phases)
