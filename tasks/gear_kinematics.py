"""Inverse kinematics of GearAssembly-v1's left arm (SAPIEN's pinocchio model, about 0.3 ms a solve), and the
hand-down grasp orientation that the expert and the controllers share."""

from __future__ import annotations

import numpy as np
import sapien
from transforms3d.quaternions import mat2quat

ARM_MASK = np.array([1] * 7 + [0, 0], dtype=np.int32)  # solve for the 7 arm joints, keep the fingers
# Franka Panda arm joint limits (rad), as in the URDF.
JOINT_LOW = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
JOINT_HIGH = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])


class LeftArmIK:
    def __init__(self, env):
        env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.arm = env.left_arm
        robot = self.arm.robot._objs[0]
        self._model = robot.create_pinocchio_model()
        self._tcp_index = [link.name.endswith("panda_hand_tcp") for link in robot.get_links()].index(True)

    def base(self) -> sapien.Pose:
        pose = self.arm.robot.pose
        return sapien.Pose(pose.p[0].cpu().numpy().astype(float), pose.q[0].cpu().numpy().astype(float))

    def solve(self, tcp_target: sapien.Pose, q_seed: np.ndarray) -> tuple[np.ndarray, bool]:
        """Joint angles (9: arm + fingers as seeded) putting the TCP at a world pose, and whether IK converged."""
        qpos, ok, _ = self._model.compute_inverse_kinematics(
            self._tcp_index, self.base().inv() * tcp_target, initial_qpos=np.asarray(q_seed, dtype=float),
            active_qmask=ARM_MASK, max_iterations=200)
        return np.asarray(qpos), bool(ok)

    def solve_hand_down(self, p: np.ndarray, finger_dir: np.ndarray, q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(quat, q) putting the TCP at p with the hand down. The gripper is symmetric, so of the two finger
        directions (+-finger_dir) take the one whose solution is within the joint limits and nearest q_seed;
        None if neither is."""
        best = None
        for quat in (hand_down_quat(finger_dir), hand_down_quat(-np.asarray(finger_dir))):
            q, ok = self.solve(sapien.Pose(p, quat), q_seed)
            if ok and np.all(q[:7] >= JOINT_LOW) and np.all(q[:7] <= JOINT_HIGH):
                cost = float(np.abs(q[:7] - np.asarray(q_seed)[:7]).sum())
                if best is None or cost < best[0]:
                    best = (cost, quat, q)
        return None if best is None else (best[1], best[2])


def hand_down_quat(finger_dir: np.ndarray) -> np.ndarray:
    """TCP orientation pointing straight down with its x axis along `finger_dir` (projected on the table)."""
    x = np.array([finger_dir[0], finger_dir[1], 0.0])
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, -1.0])
    return mat2quat(np.stack([x, np.cross(z, x), z], axis=1))


def plate_direction(env) -> np.ndarray:
    """The peg module's long axis in the world: the expert and the controllers grasp across it."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    return env.peg_module.pose.to_transformation_matrix()[0, :3, 0].cpu().numpy().astype(float)
