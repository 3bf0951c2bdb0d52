"""GearAssembly-v1's two Pandas: where they stand, the left arm's kinematics (the arm its controllers drive), and
where the left hand is over the peg by both arms' forward kinematics (`HandToPeg`)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import sapien
from transforms3d.euler import euler2quat
from transforms3d.quaternions import quat2mat

from policy_composer.tasks.gear_assembly.geometry import GearSpec
from policy_composer.tasks.panda import PANDA_URDF, TCP_LINK, ArmIK

LEFT_BASE = sapien.Pose(p=[0.0, -0.7, 0.0], q=euler2quat(0, 0, np.pi / 2))
RIGHT_BASE = sapien.Pose(p=[0.0, 0.7, 0.0], q=euler2quat(0, 0, -np.pi / 2))


class LeftArmIK(ArmIK):
    """The left arm's kinematics: the arm the gear task's controllers drive."""

    def __init__(self, env):
        super().__init__(env, "left_arm")


def plate_direction(env) -> np.ndarray:
    """The peg module's long axis in the world: the expert and the controllers grasp across it."""
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    return env.peg_module.pose.to_transformation_matrix()[0, :3, 0].cpu().numpy().astype(float)


def module_in_hand(spec: GearSpec) -> tuple[np.ndarray, np.ndarray]:
    """The peg module's pose in the right TCP frame, (p, wxyz quaternion): flipped (the TCP's z points down) and
    shifted so that the hand grips the plate's end while the peg stands `peg_offset` beside the fingers."""
    return np.array([spec.peg_offset, 0.0, -spec.plate_half_size[2]]), np.array([0.0, 1.0, 0.0, 0.0])


def _se3(p, q) -> pin.SE3:
    return pin.SE3(quat2mat(q), np.asarray(p, dtype=float))


class HandToPeg:
    """The left TCP's position relative to the peg's top, in the peg module's frame (x, y across the peg's axis, z
    along it, m), from both arms' joint angles (`observation.state`) by forward kinematics on the Panda's URDF and the
    peg module's place in the right hand: where the robot knows its hand is over the peg without a camera."""

    def __init__(self, spec: GearSpec):
        self.model = pin.buildModelFromUrdf(str(PANDA_URDF))
        self.data = self.model.createData()
        self.tcp = self.model.getFrameId(TCP_LINK)
        self.left, self.right = (_se3(b.p, b.q) for b in (LEFT_BASE, RIGHT_BASE))
        self.top_in_hand = _se3(*module_in_hand(spec)) * pin.SE3(np.eye(3), np.array([0.0, 0.0, spec.peg_height]))

    def _tcp(self, base: pin.SE3, arm: np.ndarray) -> pin.SE3:
        q = np.concatenate([arm[:7], [arm[7] / 2] * 2]).astype(float)
        pin.framesForwardKinematics(self.model, self.data, q)
        return base * self.data.oMf[self.tcp]

    def __call__(self, state: np.ndarray) -> np.ndarray:
        """(N, 3) for states (N, 16): [left 7 joints, left gripper width, right 7 joints, right gripper width]."""
        state = np.asarray(state, dtype=float).reshape(-1, 16)
        out = np.empty((len(state), 3))
        for i, s in enumerate(state):
            top = self._tcp(self.right, s[8:]) * self.top_in_hand
            out[i] = top.actInv(self._tcp(self.left, s[:8]).translation)
        return out

