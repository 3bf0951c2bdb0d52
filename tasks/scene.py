"""The scene as a planner knows it: shapes placed in the world, and the part the hand holds."""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np
import pinocchio as pin

TABLE_HALF = (1.2, 1.2, 0.05)  # a slab whose top is the table surface (z = 0)


@dataclass
class Obstacle:
    """A shape of the scene the arm must not touch, placed in the world."""

    name: str
    shape: coal.CollisionGeometry
    pose: pin.SE3


@dataclass
class HeldObject:
    """A cylinder attached to the hand (a held gear or peg), pose in the hand joint's frame."""

    radius: float
    height: float
    hand_to_object: pin.SE3


def table_obstacle() -> Obstacle:
    top = pin.SE3(np.eye(3), np.array([0, 0, -TABLE_HALF[2]]))
    return Obstacle("table", coal.Box(*(2 * np.array(TABLE_HALF))), top)
