"""Inverse kinematics of GearAssembly-v1's left arm (SAPIEN's pinocchio model, about 0.3 ms a solve), the
hand-down grasp orientation that the expert and the controllers share, and where the left hand is over the peg by
both arms' forward kinematics (`HandToPeg`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import sapien
from mani_skill import PACKAGE_ASSET_DIR
from transforms3d.euler import euler2quat
from transforms3d.quaternions import mat2quat, quat2mat

from policy_composer.tasks.gear_geometry import GearSpec

PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
PANDA_URDF, PANDA_SRDF = PANDA_DIR / "panda_v2.urdf", PANDA_DIR / "panda_v2.srdf"

LEFT_BASE = sapien.Pose(p=[0.0, -0.7, 0.0], q=euler2quat(0, 0, np.pi / 2))
RIGHT_BASE = sapien.Pose(p=[0.0, 0.7, 0.0], q=euler2quat(0, 0, -np.pi / 2))
ARM_MASK = np.array([1] * 7 + [0, 0], dtype=np.int32)  # solve for the 7 arm joints, keep the fingers
# Franka Panda arm joint limits (rad), as in the URDF.
JOINT_LOW = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
JOINT_HIGH = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
# Both arms' configuration at reset (arm joints and fingers).
REST_QPOS = np.array([0.0, np.pi / 8, 0.0, -np.pi * 5 / 8, 0.0, np.pi * 3 / 4, np.pi / 4, 0.04, 0.04])


class LeftArmIK:
    def __init__(self, env):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        robot = self.arm.robot._objs[0]
        self._model = robot.create_pinocchio_model()
        self._tcp_index = [link.name.endswith("panda_hand_tcp") for link in robot.get_links()].index(True)

    @property
    def arm(self):
        """The env's left arm now: a reset rebuilds the scene, and with it the arm's objects."""
        return self.env.left_arm

    def base(self) -> sapien.Pose:
        pose = self.arm.robot.pose
        return sapien.Pose(pose.p[0].cpu().numpy().astype(float), pose.q[0].cpu().numpy().astype(float))

    def solve(self, tcp_target: sapien.Pose, q_seed: np.ndarray) -> tuple[np.ndarray, bool]:
        """Joint angles (9: arm + fingers as seeded) putting the TCP at a world pose, and whether IK converged."""
        qpos, ok, _ = self._model.compute_inverse_kinematics(
            self._tcp_index, self.base().inv() * tcp_target, initial_qpos=np.asarray(q_seed, dtype=float),
            active_qmask=ARM_MASK, max_iterations=200)
        return np.asarray(qpos), bool(ok)

    def tcp_positions(self, q7: np.ndarray) -> np.ndarray:
        """World TCP positions (N, 3) of arm configurations q7 (N, 7), fingers open."""
        base = self.base()
        out = np.empty((len(q7), 3))
        for i, q in enumerate(np.asarray(q7, dtype=float)):
            self._model.compute_forward_kinematics(np.concatenate([q[:7], [0.04, 0.04]]))
            out[i] = (base * self._model.get_link_pose(self._tcp_index)).p
        return out

    def solve_hand_down(self, p: np.ndarray, finger_dir: np.ndarray,
                        q_seed: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(quat, q) putting the TCP at p with the hand down. The gripper is symmetric, so of the two finger
        directions (+-finger_dir) take the one whose solution is within the joint limits and nearest q_seed;
        None if neither is. Where the solver finds neither from q_seed (an arm left contorted by a learned
        controller), it starts again from the rest configuration: the goal is the same pose either way."""
        q_seed = np.asarray(q_seed, dtype=float)
        for start in (q_seed, np.concatenate([REST_QPOS[:7], q_seed[7:]])):
            best = None
            for quat in (hand_down_quat(finger_dir), hand_down_quat(-np.asarray(finger_dir))):
                q, ok = self.solve(sapien.Pose(p, quat), start)
                if ok and np.all(q[:7] >= JOINT_LOW) and np.all(q[:7] <= JOINT_HIGH):
                    cost = float(np.abs(q[:7] - q_seed[:7]).sum())
                    if best is None or cost < best[0]:
                        best = (cost, quat, q)
            if best is not None:
                return best[1], best[2]
        return None


class PandaForwardKinematics:
    """TCP poses of a Panda from its arm joints, in its base frame. Needs no simulator, so recorded datasets
    can be turned into Cartesian quantities offline (pinocchio on ManiSkill's URDF)."""

    def __init__(self):
        import pinocchio as pin

        self._pin = pin
        self.model = pin.buildModelFromUrdf(str(PANDA_URDF))
        self.data = self.model.createData()
        self._tcp = self.model.getFrameId("panda_hand_tcp")

    def tcp(self, q7: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q7 (N, 7) -> positions (N, 3) and rotations (N, 3, 3) of the TCP."""
        q7 = np.atleast_2d(np.asarray(q7, dtype=np.float64))
        p, R = np.empty((len(q7), 3)), np.empty((len(q7), 3, 3))
        for i, q in enumerate(q7):
            self._pin.framesForwardKinematics(self.model, self.data, np.concatenate([q, [0.04, 0.04]]))
            pose = self.data.oMf[self._tcp]
            p[i], R[i] = pose.translation, pose.rotation
        return p, R


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
        self.tcp = self.model.getFrameId("panda_hand_tcp")
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

