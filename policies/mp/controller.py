"""Motion-planning controllers (paper: MP): a subtask's waypoints connected by plans, executed open loop.

Free-space motions are planned in joint space with OMPL's RRT-Connect against the scene's collision model
(`mp/planning.py`, the obstacles the task's scene gives) and time-parameterised to the joint velocity limits;
approach, lift, descent and retreat are straight TCP lines solved by IK. The plan is made once, when the controller
starts, from the scene as it is then: the controllers are open loop, as the paper's planner was. The pick-up
perceives the part's position with an error along the fingers, so the part sits in the hand off-centre by up to
`max_grasp_offset`; the carry assumes a centred grasp, and an insertion that cannot see the offset may feel for the
hole (`Subtask.search`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import sapien

from policy_composer.policies.arm import Segment
from policy_composer.policies.mp.configuration_mp import MPConfig
from policy_composer.policies.mp.planning import SceneCollisionModel, plan_rrt_connect, time_parameterize
from policy_composer.policies.subtasks import SubtaskController
from policy_composer.tasks.base import PlanningError, Waypoint, np0
from policy_composer.tasks.panda import TCP_LINK, tcp_line
from policy_composer.tasks.scene import HeldObject

HELD_MARGIN = 0.003  # around the held part, for the arm lagging its planned path (m)


class MotionPlanningController(SubtaskController):
    kind = "mp"
    action_kind = "joint_waypoints"

    def __init__(self, env, subtask, config: MPConfig | None = None, **kwargs):
        super().__init__(env, subtask, **kwargs)
        self.config = config or MPConfig()
        self.collision = SceneCollisionModel(self.ik.base())

    def connect(self, obs, waypoints: list[Waypoint], seed):
        finger = float(np0(obs["extra"]["state"])[7] / 2)
        self.collision.set_scene(self.scene.planning_obstacles(),
                                 held=self.nominal_held_part() if self.subtask.holds_part else None, fingers=finger)
        q, segments = self.q9(obs), []
        for wp in waypoints:
            if wp.kind == "free":
                path = plan_rrt_connect(self.collision, q[:7], wp.q[:7], self.config.plan_checks)
                traj = time_parameterize(path, 1.0 / self.rate_hz, self.config.speed)
            elif wp.kind == "line":
                traj, _ = self.cartesian_line(q, wp)
            else:
                traj = wp.q[None, :7]
            segments.append(Segment(traj, wp.gripper, settle=wp.settle))
            q = wp.q
        return segments

    def cartesian_line(self, q_from: np.ndarray, wp: Waypoint) -> tuple[np.ndarray, np.ndarray]:
        """Joint targets (T, 7) moving the TCP on a straight line to the waypoint at `wp.step` m per step."""
        try:
            return tcp_line(self.ik, q_from, self._tcp_of(q_from), wp.tcp, wp.quat, wp.step)
        except PlanningError as e:
            raise PlanningError(f"{self.name}: {e}") from None

    def _tcp_of(self, q9: np.ndarray) -> np.ndarray:
        """World TCP position at configuration q9 (forward kinematics in the planner's model)."""
        model, data = self.collision.model, self.collision.data
        pin.framesForwardKinematics(model, data, q9)
        local = data.oMf[model.getFrameId(TCP_LINK)].translation
        return (self.ik.base() * sapien.Pose(local)).p

    def nominal_held_part(self) -> HeldObject:
        """The held part at the nominal grasp, in the hand joint's frame, widened by how far off-centre the pick-up
        may have left it and by the arm's lag behind its path: the real part, not the nominal one, must pass clear of
        the scene (a gear caught on the peg's top tips out of the hand)."""
        model = self.collision.model
        tcp = model.frames[model.getFrameId(TCP_LINK)].placement
        radius, length, pose = self.scene.held_part(self.max_grasp_offset + HELD_MARGIN, HELD_MARGIN)
        return HeldObject(radius, length, tcp * pose)


def build(env, subtask, model, config: MPConfig, max_grasp_offset: float) -> MotionPlanningController:
    """The registry's builder (nothing trained: `model` is None)."""
    return MotionPlanningController(env, subtask, config, max_grasp_offset=max_grasp_offset)
