"""The Franka Panda as the library's controllers drive it, whatever the task: ManiSkill's URDF and SRDF, its joint
position and velocity limits, inverse kinematics of one arm in an env (SAPIEN's pinocchio model, about 0.3 ms a solve)
and forward kinematics without a simulator. A task names which of its robots the controllers drive; the rest of what
they know of the scene is the task's own."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pinocchio as pin
import sapien
from mani_skill import PACKAGE_ASSET_DIR
from transforms3d.quaternions import mat2quat

from policy_composer.tasks.base import PlanningError, Waypoint
from policy_composer.tasks.scene import Obstacle

PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
PANDA_URDF, PANDA_SRDF = PANDA_DIR / "panda_v2.urdf", PANDA_DIR / "panda_v2.srdf"
TCP_LINK = "panda_hand_tcp"
ARM_MASK = np.array([1] * 7 + [0, 0], dtype=np.int32)  # solve for the 7 arm joints, keep the fingers
# Arm joint position (rad) and velocity (rad/s) limits, as in the URDF.
JOINT_LOW = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
JOINT_HIGH = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
VELOCITY_LIMIT = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0  # the gripper's normalised commands
# A configuration the solvers start again from where the measured one leads nowhere (arm joints and fingers).
REST_QPOS = np.array([0.0, np.pi / 8, 0.0, -np.pi * 5 / 8, 0.0, np.pi * 3 / 4, np.pi / 4, 0.04, 0.04])


class ArmIK:
    """Inverse and forward kinematics of the Panda that `env.<arm>` names (an agent with `.robot` and `.tcp`): the
    left arm of a bimanual task, `agent` for ManiSkill's one-robot tasks."""

    def __init__(self, env, arm: str):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.arm_name = arm
        robot = self.arm.robot._objs[0]
        self._model = robot.create_pinocchio_model()
        self._tcp_index = [link.name.endswith(TCP_LINK) for link in robot.get_links()].index(True)

    @property
    def arm(self):
        """The env's arm now: a reset may rebuild the scene, and with it the arm's objects."""
        return getattr(self.env, self.arm_name)

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
        self.model = pin.buildModelFromUrdf(str(PANDA_URDF))
        self.data = self.model.createData()
        self._tcp = self.model.getFrameId(TCP_LINK)

    def tcp(self, q7: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q7 (N, 7) -> positions (N, 3) and rotations (N, 3, 3) of the TCP."""
        q7 = np.atleast_2d(np.asarray(q7, dtype=np.float64))
        p, R = np.empty((len(q7), 3)), np.empty((len(q7), 3, 3))
        for i, q in enumerate(q7):
            pin.framesForwardKinematics(self.model, self.data, np.concatenate([q, [0.04, 0.04]]))
            pose = self.data.oMf[self._tcp]
            p[i], R[i] = pose.translation, pose.rotation
        return p, R


def hand_down_quat(finger_dir: np.ndarray) -> np.ndarray:
    """TCP orientation pointing straight down with its x axis along `finger_dir` (projected on the table)."""
    x = np.array([finger_dir[0], finger_dir[1], 0.0])
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, -1.0])
    return mat2quat(np.stack([x, np.cross(z, x), z], axis=1))


def se3(pose) -> pin.SE3:
    """sapien.Pose -> pin.SE3."""
    return pin.SE3(pin.Quaternion(float(pose.q[0]), *map(float, pose.q[1:])).matrix(), np.asarray(pose.p, dtype=float))


@cache
def panda_geometry() -> tuple[pin.Model, pin.GeometryModel]:
    """The Panda's kinematic model and collision meshes (shared: callers copy what they change)."""
    model = pin.buildModelFromUrdf(str(PANDA_URDF))
    geom = pin.buildGeomFromUrdf(model, str(PANDA_URDF), pin.GeometryType.COLLISION, package_dirs=[str(PANDA_DIR)])
    return model, geom


def panda_obstacles(qpos: np.ndarray, base, prefix: str) -> list[Obstacle]:
    """A Panda where it stands (`qpos`: 9 values, `base`: its base's world pose) as obstacles, its collision meshes
    placed by forward kinematics."""
    model, geom = panda_geometry()
    data, gdata = model.createData(), pin.GeometryData(geom)
    q = pin.neutral(model)
    q[:9] = qpos
    pin.framesForwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geom, gdata)
    world = se3(base)
    return [Obstacle(f"{prefix}{g.name}", g.geometry, world * gdata.oMg[i]) for i, g in enumerate(geom.geometryObjects)]


def ik_hand_down(ik: ArmIK, finger_dir: np.ndarray, p: np.ndarray,
                 seed_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(quat, q) putting the TCP at p with the hand down (see ArmIK.solve_hand_down), or a PlanningError."""
    solution = ik.solve_hand_down(p, finger_dir, seed_q)
    if solution is None:
        raise PlanningError(f"no IK solution within the joint limits for the TCP at {np.round(p, 3)}")
    return solution


def tcp_line(ik: ArmIK, q_from: np.ndarray, p_from: np.ndarray, p_to: np.ndarray, quat: np.ndarray,
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


def line_to(ik: ArmIK, q_from: np.ndarray, p: np.ndarray, quat: np.ndarray, gripper: float, step: float,
            settle: int = 4) -> Waypoint:
    q, ok = ik.solve(sapien.Pose(p, quat), q_from)
    if not ok:
        raise PlanningError(f"no IK solution for the TCP at {np.round(p, 3)}")
    return Waypoint("line", q, gripper, tcp=np.asarray(p, dtype=float), quat=quat, step=step, settle=settle)
