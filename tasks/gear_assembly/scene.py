"""GearAssembly-v1's scene as the left arm's controllers know it (world frame): their hand from its joints, the peg
module from the right hand that holds it and the hand-over's calibration (`module_in_hand`), the gear and peg from
their drawings (`gear_spec`). The one thing given from the simulator is the gear's position for the pick-up's
planner (`planner_gear`), with `planner_noise` (m, per axis in the table's plane) where the figures ask for it."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import sapien

from policy_composer.tasks.base import np0
from policy_composer.tasks.gear_assembly.env import CARRY_CLEARANCE
from policy_composer.tasks.gear_assembly.kinematics import RIGHT_BASE
from policy_composer.tasks.panda import panda_obstacles, se3
from policy_composer.tasks.scene import Obstacle, table_obstacle


class GearScene:
    def __init__(self, env):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.spec = self.env.gear_spec
        self.grasp_height = self.spec.grasp_height
        self.planner_noise = 0.0
        self.rng = np.random.default_rng()

    def seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    def module_pose(self):
        """The peg module's pose: the right hand's (forward kinematics) times the calibrated grasp on the module."""
        return self.env.right_arm.tcp.pose * self.env.module_in_hand

    def _module_matrix(self) -> np.ndarray:
        return np0(self.module_pose().to_transformation_matrix())

    def finger_dir(self) -> np.ndarray:
        """The peg module's long axis, level: the controllers grasp across it."""
        d = self._module_matrix()[:3, 0].copy()
        d[2] = 0.0
        return d / np.linalg.norm(d)

    def planner_gear(self) -> np.ndarray:
        """The gear's position as the pick-up's planner is given it (the task's privileged planner input)."""
        return self.env.planner_gear_position(self.planner_noise, self.rng)

    def tcp(self) -> np.ndarray:
        return np0(self.env.left_arm.tcp.pose.p)

    def peg_top(self) -> np.ndarray:
        m = self._module_matrix()
        return m[:3, 3] + m[:3, 2] * self.spec.peg_height

    def held_gear_height(self) -> float:
        """How high a gear held at the nominal grasp has its bottom above the peg module's plate (m)."""
        return float(self.tcp()[2] - self.grasp_height - (self.peg_top()[2] - self.spec.peg_height))

    def pre_insertion_tcp(self) -> np.ndarray:
        """TCP position that puts a centred gear's bottom CARRY_CLEARANCE above the peg top."""
        return self.peg_top() + [0, 0, CARRY_CLEARANCE + self.grasp_height]

    def _right_arm(self) -> list[Obstacle]:
        return panda_obstacles(np0(self.env.right_arm.robot.get_qpos()), RIGHT_BASE, "right_")

    def planning_obstacles(self) -> list[Obstacle]:
        """The table, the right arm where its joints say it stands, and the peg module it holds (see
        geometry.build_peg_module)."""
        spec, pose = self.spec, self.module_pose()
        world = se3(sapien.Pose(np0(pose.p), np0(pose.q)))
        hx, hy, hz = spec.plate_half_size
        return [table_obstacle(), *self._right_arm(),
                Obstacle("plate", coal.Box(2 * hx, 2 * hy, 2 * hz),
                         world * pin.SE3(np.eye(3), np.array([-spec.peg_offset - 0.03 + hx, 0.0, -hz]))),
                Obstacle("peg", coal.Cylinder(spec.peg_radius, spec.peg_height),
                         world * pin.SE3(np.eye(3), np.array([0.0, 0.0, spec.peg_height / 2])))]

    def guard_obstacles(self) -> list[Obstacle]:
        """The right arm only: the fingers touch the table when picking, and the gear meets the peg when inserting."""
        return self._right_arm()

    def hand_quat(self, ik, q9: np.ndarray) -> np.ndarray:
        """The hand pointing down, the fingers closing along `finger_dir` (the measured one where IK finds none)."""
        solution = ik.solve_hand_down(self.tcp(), self.finger_dir(), q9)
        return solution[0] if solution is not None else np0(ik.arm.tcp.pose.q)

    def held_part(self, widen: float, lengthen: float) -> tuple[float, float, pin.SE3]:
        """The gear under the TCP, its axis the hand's (the TCP's z points down, into the gear)."""
        spec, length = self.spec, self.spec.height + lengthen
        return (spec.outer_radius + widen, length,
                pin.SE3(np.eye(3), np.array([0.0, 0.0, self.grasp_height + lengthen - length / 2])))
