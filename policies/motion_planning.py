"""Motion-planning controllers (paper: MP): pick the gear up, carry it to the peg, insert it open loop.

Free-space motions are planned in joint space with OMPL's RRT-Connect against the scene's collision model
(`policies.planning`) and time-parameterised to the joint velocity limits; approach, lift, descent and
retreat are straight Cartesian lines solved by IK. The plan is made once, when the controller starts, from
the scene as it is then: the controllers are open loop, as the paper's planner was. The pick-up perceives
the gear's position with an error along the fingers, so the gear sits in the hand off-centre by up to
`max_grasp_offset` (about the hole's diameter); carrying and insertion assume a centred grasp, so insertion
fails when the offset exceeds the peg's clearance, as the paper's did.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import sapien

from policies.arm import (CARRY_CLEARANCE, GRIPPER_CLOSED, GRIPPER_OPEN, RELEASE_HEIGHT, ScriptedController, Segment,
                          np0)
from policies.planning import (JOINT_HIGH, JOINT_LOW, HeldObject, PlanningError, SceneCollisionModel, plan_rrt_connect,
                               time_parameterize)
from tasks.gear_kinematics import LeftArmIK, hand_down_quat

PRE_GRASP_HEIGHT = 0.08  # TCP above the grasp point before descending (m)
LIFT_HEIGHT = 0.12  # how far the pick-up lifts the gear (m)
RETREAT_HEIGHT = 0.10


def cartesian_line(ik: LeftArmIK, q_seed: np.ndarray, p_from: np.ndarray, p_to: np.ndarray, quat: np.ndarray,
                   step: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint targets (T, 7) moving the TCP on a straight line at `step` m per control step; and the last q (9)."""
    n = max(1, int(np.ceil(np.linalg.norm(p_to - p_from) / step)))
    q, out = np.asarray(q_seed, dtype=float), []
    for k in range(1, n + 1):
        q, ok = ik.solve(sapien.Pose(p_from + (p_to - p_from) * k / n, quat), q)
        if not ok:
            raise PlanningError(f"no IK solution on the straight line to {np.round(p_to, 3)}")
        out.append(q[:7])
    return np.array(out), q


class MotionPlanningController(ScriptedController):
    action_kind = "joint_waypoints"

    def __init__(self, env, planning_timeout: float = 2.0):
        super().__init__(env)
        self.ik = LeftArmIK(self.env)
        self.collision = SceneCollisionModel()
        self.planning_timeout = planning_timeout

    def _q9(self, obs) -> np.ndarray:
        state = np0(obs["extra"]["state"])
        return np.concatenate([state[:7], [state[7] / 2] * 2])

    def _set_scene(self, obs, held: HeldObject | None = None) -> None:
        finger = float(np0(obs["extra"]["state"])[7] / 2)
        self.collision.set_scene(np0(self.env.right_arm.robot.get_qpos()),
                                 sapien.Pose(np0(self.env.peg_module.pose.p), np0(self.env.peg_module.pose.q)),
                                 held=held, fingers=finger)

    def _plan_to(self, obs, q_goal: np.ndarray, gripper: float, seed: int | None) -> Segment:
        path = plan_rrt_connect(self.collision, self._q9(obs)[:7], q_goal[:7], timeout=self.planning_timeout, seed=seed)
        return Segment(time_parameterize(path, 1.0 / self.rate_hz), gripper, settle=6)

    def _ik_hand_down(self, p: np.ndarray, seed_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(quat, q) putting the TCP at p, hand down: of the two finger directions (the gripper is symmetric),
        the one whose solution is within the joint limits and nearest `seed_q`."""
        best = None
        x = self.scene.finger_dir()
        for quat in (hand_down_quat(x), hand_down_quat(-x)):
            q, ok = self.ik.solve(sapien.Pose(p, quat), seed_q)
            if ok and np.all(q[:7] >= JOINT_LOW) and np.all(q[:7] <= JOINT_HIGH):
                cost = float(np.abs(q[:7] - seed_q[:7]).sum())
                if best is None or cost < best[0]:
                    best = (cost, quat, q)
        if best is None:
            raise PlanningError(f"{self.name}: no IK solution within the joint limits for the TCP at {np.round(p, 3)}")
        return best[1], best[2]

    def nominal_held_gear(self) -> HeldObject:
        """The gear as a cylinder centred under the TCP (the nominal grasp), in the hand joint's frame."""
        model = self.collision.model
        tcp = model.frames[model.getFrameId("panda_hand_tcp")].placement
        spec, h = self.scene.spec, self.scene.grasp_height
        return HeldObject(spec.outer_radius, spec.height, tcp * pin.SE3(np.eye(3), np.array([0, 0, h - spec.height / 2])))


class MPPick(MotionPlanningController):
    name = "mp_pick"
    initiation = "gear lying on the table, not in the gripper"

    def __init__(self, env, max_grasp_offset: float = 0.012, grasp_offset: float | None = None, **kwargs):
        super().__init__(env, **kwargs)
        self.max_grasp_offset = max_grasp_offset
        self.fixed_grasp_offset = grasp_offset  # set: every pick is off by exactly this much (tests, tables)
        self.grasp_offset = 0.0

    def can_start(self, obs) -> bool:
        info = self.scene.info()
        return not info["gear_grasped"] and self.scene.gear()[2] < 0.02 and not info["gear_inserted"]

    def plan(self, obs, seed):
        rng = np.random.default_rng(seed)
        # The perceived gear position is off along the fingers: the gear will sit off-centre in the hand.
        self.grasp_offset = float(rng.uniform(-self.max_grasp_offset, self.max_grasp_offset)
                                  if self.fixed_grasp_offset is None else self.fixed_grasp_offset)
        grasp = self.scene.gear() + self.scene.finger_dir() * self.grasp_offset + [0, 0, self.scene.grasp_height]
        pre = grasp + [0, 0, PRE_GRASP_HEIGHT]
        quat, q_pre = self._ik_hand_down(pre, self._q9(obs))
        self._set_scene(obs)
        to_pre = self._plan_to(obs, q_pre, GRIPPER_OPEN, seed)
        descend, q_grasp = cartesian_line(self.ik, q_pre, pre, grasp, quat, step=0.004)
        lift, _ = cartesian_line(self.ik, q_grasp, grasp, grasp + [0, 0, LIFT_HEIGHT], quat, step=0.006)
        return [to_pre, Segment(descend, GRIPPER_OPEN), Segment(descend[-1:], GRIPPER_CLOSED, settle=8),
                Segment(lift, GRIPPER_CLOSED)]

    def succeeded(self, info):
        return info["gear_lifted"], "the gear is not in the gripper after the lift"


class MPMove(MotionPlanningController):
    name = "mp_move"
    initiation = "gear grasped and lifted off the table"

    def can_start(self, obs) -> bool:
        info = self.scene.info()
        return info["gear_lifted"] and not info["gear_inserted"]

    def plan(self, obs, seed):
        _, q_goal = self._ik_hand_down(self.scene.pre_insertion_tcp().p, self._q9(obs))
        self._set_scene(obs, held=self.nominal_held_gear())
        return [self._plan_to(obs, q_goal, GRIPPER_CLOSED, seed)]

    def succeeded(self, info):
        return info["gear_at_peg"], "the gear is not at the pre-insertion pose above the peg"


class MPInsert(MotionPlanningController):
    name = "mp_insert"
    initiation = "gear grasped, held above the peg at the pre-insertion pose"

    def can_start(self, obs) -> bool:
        return self.scene.info()["gear_at_peg"]

    def plan(self, obs, seed):
        tcp, top = self.scene.tcp(), self.scene.peg_top()
        quat, _ = self._ik_hand_down(tcp, self._q9(obs))
        spec, h = self.scene.spec, self.scene.grasp_height
        # Open loop: the nominal grasp puts the gear's axis on the TCP, so slide the TCP down the peg's axis.
        above = np.array([top[0], top[1], max(tcp[2], top[2] + CARRY_CLEARANCE + h)])
        release = np.array([top[0], top[1], top[2] - spec.peg_height + RELEASE_HEIGHT + h])
        align, q = cartesian_line(self.ik, self._q9(obs), tcp, above, quat, step=0.003)
        descend, q = cartesian_line(self.ik, q, above, release, quat, step=0.003)
        retreat, _ = cartesian_line(self.ik, q, release, release + [0, 0, RETREAT_HEIGHT], quat, step=0.006)
        return [Segment(align, GRIPPER_CLOSED, settle=2), Segment(descend, GRIPPER_CLOSED),
                Segment(descend[-1:], GRIPPER_OPEN, settle=8), Segment(retreat, GRIPPER_OPEN)]

    def succeeded(self, info):
        return info["success"], "the gear is not seated on the peg"


def motion_planning_controllers(env, max_grasp_offset: float = 0.012) -> list[MotionPlanningController]:
    return [MPPick(env, max_grasp_offset), MPMove(env), MPInsert(env)]
