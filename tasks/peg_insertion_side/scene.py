"""PegInsertionSide-v1's scene as the arm's controllers know it (world frame): their hand from its joints, and what the
task lets the planner know: where the peg lies (given from the simulator, with `planner_noise` in the table's plane
where the figures ask for it) and where the box and its hole are. Where the peg sits in the hand once grasped, the
planner does not know: it assumes the grasp that was planned (`plan_grasp`): where along the peg, and the hand
straight down or tilted back about the fingers' closing axis."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import sapien
import torch
from transforms3d.quaternions import axangle2quat

from policy_composer.tasks.base import np0
from policy_composer.tasks.panda import se3
from policy_composer.tasks.peg_insertion_side.flags import box_half_depth
from policy_composer.tasks.scene import Obstacle, table_obstacle

MARGIN = 0.004  # around the box's walls in the collision checks (m)
# The fingers squeeze a held peg: in the recordings the gripper was 0.7-3.8 mm narrower than the peg whenever it held
# it. Wider than the peg by more than this, the hand holds nothing (m).
EMPTY_HAND_GAP = 0.002


def holds_nothing(fingers_wider_than_peg: float) -> bool:
    """Whether fingers this much wider than the peg (m, from the gripper's joints) hold nothing."""
    return fingers_wider_than_peg > EMPTY_HAND_GAP


def tilt_quat(tilt: float) -> np.ndarray:
    """The turn (wxyz) of a hand tilted by `tilt` about the TCP's y from straight down."""
    return axangle2quat([0.0, 1.0, 0.0], tilt)


def pose0(pose) -> sapien.Pose:
    """Env 0 of a ManiSkill batched pose."""
    return sapien.Pose(np0(pose.p), np0(pose.q))


def box_obstacles(env, margin: float = MARGIN) -> list[Obstacle]:
    """The box's four walls around the hole, each grown by `margin`, as ManiSkill builds them."""
    box = env.unwrapped.box
    walls = box._objs[0].find_component_by_type(sapien.physx.PhysxRigidBaseComponent)
    world = pose0(box.pose)
    return [Obstacle(f"box_wall{i}", coal.Box(*(2 * (np.asarray(shape.half_size, dtype=float) + margin))),
                     se3(world * shape.get_local_pose())) for i, shape in enumerate(walls.get_collision_shapes())]


def grasp_offset(half_length):
    """Where the library's pick-up grasps the peg, back from its centre toward its tail (m; a float or a tensor of
    them): ManiSkill's choice, far enough back that the fingers stay out of the box with the head in the hole."""
    if isinstance(half_length, torch.Tensor):
        return (half_length / 2 + 0.01).clamp_min(0.05)
    return max(0.05, half_length / 2 + 0.01)


def plan_grasp(env, tilt: float = 0.0, offset: float | None = None) -> None:
    """Let the robot know the grasp planned this episode: the hand's tilt (rad) about the TCP's y, the fingers'
    closing axis, from straight down, and how far back from the peg's centre toward its tail it grasps (m; None: the
    library's own grasp, `grasp_offset`). Until a grasp is planned, the library's pick-up's: straight down."""
    u = env.unwrapped
    known = torch.empty(u.num_envs, 2, dtype=torch.float32, device=u.device)
    known[:, 0] = tilt
    known[:, 1] = grasp_offset(u.peg_half_sizes[:, 0]) if offset is None else offset
    u.planned_grasp = known


def planned_grasp(env) -> torch.Tensor:
    """(B, 2) the grasp planned this episode: its tilt and its offset (see `plan_grasp`)."""
    u = env.unwrapped
    if getattr(u, "planned_grasp", None) is None:
        plan_grasp(u)
    return u.planned_grasp


class PegScene:
    def __init__(self, env):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        self.planner_noise = 0.0
        self.rng = np.random.default_rng()

    def seed(self, seed: int | None) -> None:
        self.rng = np.random.default_rng(seed)

    @property
    def half_length(self) -> float:
        return float(self.env.peg_half_sizes[0, 0])

    @property
    def half_width(self) -> float:
        return float(self.env.peg_half_sizes[0, 1])

    @property
    def box_half_depth(self) -> float:
        return float(box_half_depth(self.env)[0])

    def planner_peg(self) -> sapien.Pose:
        """The peg's pose as the pick-up's planner is given it (the task's privileged planner input)."""
        peg = pose0(self.env.peg.pose)
        if self.planner_noise > 0:
            peg = sapien.Pose(peg.p + np.append(self.rng.normal(0.0, self.planner_noise, 2), 0.0), peg.q)
        return peg

    def hole(self) -> sapien.Pose:
        """The hole's pose, x along its axis into the box (the box is part of the scene the planner knows)."""
        return pose0(self.env.box_hole_pose)

    def tcp(self) -> np.ndarray:
        return np0(self.env.agent.tcp.pose.p)

    def finger_dir(self) -> np.ndarray:
        """The peg's axis, level: the hand grasps across it."""
        d = self.planner_peg().to_transformation_matrix()[:3, 0].copy()
        d[2] = 0.0
        return d / np.linalg.norm(d)

    def hand_quat(self, ik, q9: np.ndarray) -> np.ndarray:
        """Holding the peg (see `holds_nothing`), the hand turned so that the peg, held as planned, lies along the
        hole's axis, as the planned insertions hold it: a learned insertion's steps in the hand's frame then push along
        the axis instead of drifting across it with the carry's leftover turn. Empty, the hand as it is."""
        tcp, hole = pose0(self.env.agent.tcp.pose), self.hole()
        if holds_nothing(float(q9[7] + q9[8]) - 2 * self.half_width):
            return tcp.q
        toward_hole = tcp.to_transformation_matrix()[:3, 0] @ hole.to_transformation_matrix()[:3, 0]
        return (sapien.Pose(q=hole.q) * self.peg_in_hand(1.0 if toward_hole >= 0 else -1.0).inv()).q

    def planning_obstacles(self) -> list[Obstacle]:
        return [table_obstacle(), *box_obstacles(self.env)]

    def guard_obstacles(self) -> list[Obstacle]:
        """Nothing besides the arm itself: the fingers touch the table and the peg meets the box."""
        return []

    def head_along_tcp_x(self) -> float:
        """+1 where the TCP's x points toward the peg's head, -1 where toward its tail (the hand grasps across the peg
        either way round, tilted at most 0.5 rad)."""
        tcp_x = pose0(self.env.agent.tcp.pose).to_transformation_matrix()[:3, 0]
        return 1.0 if float(tcp_x @ self.planner_peg().to_transformation_matrix()[:3, 0]) >= 0 else -1.0

    def peg_in_hand(self, sign: float | None = None) -> sapien.Pose:
        """Where the planned grasp holds the peg, in the TCP frame: across the fingers' centre, the grasp's offset back
        from its centre, its axis along the TCP's x untilted by the grasp's tilt (toward its head, sign +1, or its
        tail, -1; by default as the hand took it)."""
        sign = sign or self.head_along_tcp_x()
        # The TCP's z points down into the hand, the lying peg's z up: half a turn about the TCP's x (the peg's head
        # along it) or its y (the head the other way).
        turn = [0.0, 1.0, 0.0, 0.0] if sign > 0 else [0.0, 0.0, 1.0, 0.0]
        tilt, offset = map(float, planned_grasp(self.env)[0])
        return sapien.Pose(q=tilt_quat(-tilt)) * sapien.Pose([sign * offset, 0.0, 0.0], turn)

    def held_head_x(self) -> float:
        """The peg's head along the hole's axis from its centre plane (m), where the planned grasp puts it."""
        peg = pose0(self.env.agent.tcp.pose) * self.peg_in_hand()
        return float((self.hole().inv() * peg * sapien.Pose([self.half_length, 0.0, 0.0])).p[0])

    def held_part(self, widen: float, lengthen: float) -> tuple[float, float, pin.SE3]:
        """The peg, as the planned grasp holds it, as a cylinder around its square section along its axis."""
        along_x = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3))  # the cylinder's axis (z) onto the peg's x
        return (self.half_width * np.sqrt(2.0) + widen, 2 * self.half_length + lengthen,
                se3(self.peg_in_hand()) * along_x)
