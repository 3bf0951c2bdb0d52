"""Joint-space motion planning for a Panda: OMPL RRT-Connect with collision checks by pinocchio + coal.

The collision model is the Panda's own (ManiSkill's URDF collision meshes, self-collision pairs filtered by
its SRDF) plus the scene as the task says the planner sees it at planning time (`Obstacle`s: the table, another arm
at its current configuration, what the task's scene holds) and, while carrying, the object attached to the hand. A
check takes tens of microseconds, so RRT-Connect with path simplification plans in well under a second. Paths are
then time-parameterised to the Panda's joint velocity limits.

A plan is a function of its problem alone: OMPL's random streams restart from one seed for every plan, and the
planner's budget is a number of collision checks, not seconds, so neither earlier plans nor a busy CPU change it.
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from policy_composer.policies.mp.configuration_mp import MPConfig
from policy_composer.tasks.base import PlanningError
from policy_composer.tasks.panda import JOINT_HIGH, JOINT_LOW, PANDA_SRDF, VELOCITY_LIMIT, panda_geometry, se3
from policy_composer.tasks.scene import HeldObject, Obstacle

OMPL_SEED = 1  # OMPL rejects 0


class SceneCollisionModel:
    """The planned Panda and its scene, in the arm's base frame (`base`: its world pose)."""

    def __init__(self, base):
        self.model, self._robot_geom = panda_geometry()
        self._robot_geom = self._robot_geom.copy()
        self._robot_geom.addAllCollisionPairs()
        pin.removeCollisionPairsFromXML(self.model, self._robot_geom, PANDA_SRDF.read_text())
        self.to_base = se3(base).inverse()
        self.hand_joint = self.model.getJointId("panda_joint7")
        self.geom = self._robot_geom
        self.data = self.model.createData()
        self.gdata = pin.GeometryData(self.geom)
        self.fingers = np.array([0.04, 0.04])
        self.checks = 0

    def _robot_link_geoms(self) -> list[int]:
        return [i for i, g in enumerate(self._robot_geom.geometryObjects) if "link0" not in g.name]

    def set_scene(self, obstacles: list[Obstacle], held: HeldObject | None = None, fingers: float = 0.04) -> None:
        """Place the obstacles for the next plans, and the object the hand holds (none where `held` is None)."""
        geom = self._robot_geom.copy()
        placed = [geom.addGeometryObject(pin.GeometryObject(o.name, 0, self.to_base * o.pose, o.shape))
                  for o in obstacles]
        robot = self._robot_link_geoms()
        for o in placed:
            for r in robot:
                geom.addCollisionPair(pin.CollisionPair(r, o))
        if held is not None:
            gid = geom.addGeometryObject(pin.GeometryObject("held", self.hand_joint, held.hand_to_object,
                                                            coal.Cylinder(held.radius, held.height)))
            for o in placed:
                geom.addCollisionPair(pin.CollisionPair(gid, o))
            for r in robot:  # the held object may touch the hand and fingers, not the rest of the arm
                name = self._robot_geom.geometryObjects[r].name
                if not any(k in name for k in ("hand", "finger", "link7", "link6")):
                    geom.addCollisionPair(pin.CollisionPair(r, gid))
        self.geom, self.gdata = geom, pin.GeometryData(geom)
        self.fingers = np.array([fingers, fingers])

    def in_collision(self, q7: np.ndarray) -> bool:
        self.checks += 1
        q = np.concatenate([q7, self.fingers])
        return bool(pin.computeCollisions(self.model, self.data, self.geom, self.gdata, q, True))

    def colliding_pairs(self, q7: np.ndarray) -> list[tuple[str, str]]:
        """Which geometry pairs collide at q7 (for error messages)."""
        q = np.concatenate([q7, self.fingers])
        pin.computeCollisions(self.model, self.data, self.geom, self.gdata, q, False)
        names = [g.name for g in self.geom.geometryObjects]
        return [(names[p.first], names[p.second]) for k, p in enumerate(self.geom.collisionPairs)
                if self.gdata.collisionResults[k].isCollision()]


def _restart_ompl_random_streams() -> None:
    """Reseed OMPL's seed generator, so the random streams of the next plan's sampler and simplifier are those of
    every plan. (After the first draw OMPL restarts from its first seed and logs an error; silence it.)"""
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    ou.RNG.setSeed(OMPL_SEED)
    ou.setLogLevel(ou.LogLevel.LOG_ERROR)


def plan_rrt_connect(collision: SceneCollisionModel, q_start: np.ndarray, q_goal: np.ndarray,
                     max_checks: int = MPConfig.plan_checks) -> np.ndarray:
    """A simplified collision-free joint path (K, 7) from q_start to q_goal, by OMPL's RRT-Connect, or a
    PlanningError if none is found within `max_checks` collision checks."""
    for label, q in (("start", q_start), ("goal", q_goal)):
        if np.any(q < JOINT_LOW - 1e-6) or np.any(q > JOINT_HIGH + 1e-6):
            raise PlanningError(f"the {label} configuration {np.round(q, 3)} is outside the Panda's joint limits")
        if collision.in_collision(q):
            raise PlanningError(f"the {label} configuration is in collision: {collision.colliding_pairs(q)[:4]}")
    _restart_ompl_random_streams()
    space = ob.RealVectorStateSpace(7)
    bounds = ob.RealVectorBounds(7)
    for i in range(7):
        bounds.setLow(i, float(JOINT_LOW[i]))
        bounds.setHigh(i, float(JOINT_HIGH[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(lambda s: not collision.in_collision(np.array([s[i] for i in range(7)])))
    ss.getSpaceInformation().setStateValidityCheckingResolution(0.005)
    start, goal = space.allocState(), space.allocState()
    for i in range(7):
        start[i], goal[i] = float(q_start[i]), float(q_goal[i])
    ss.setStartAndGoalStates(start, goal)
    ss.setPlanner(og.RRTConnect(ss.getSpaceInformation()))
    budget = collision.checks + max_checks
    if not ss.solve(ob.PlannerTerminationCondition(lambda: collision.checks >= budget)) \
            or not ss.haveExactSolutionPath():
        raise PlanningError(f"RRT-Connect found no path within {max_checks} collision checks")
    path = ss.getSolutionPath()
    ss.getPathSimplifier().simplifyMax(path)
    return np.array([[path.getState(k)[i] for i in range(7)] for k in range(path.getStateCount())])


def time_parameterize(path: np.ndarray, dt: float, speed: float = MPConfig.speed, accel_steps: int = 8) -> np.ndarray:
    """Joint targets every `dt` along a piecewise-linear path: at most `speed` x the velocity limits, with
    linear ramps up and down over `accel_steps` control steps. Returns (T, 7), ending exactly at path[-1]."""
    seg = np.diff(path, axis=0)
    # Time to traverse each segment at full speed: the slowest joint decides.
    seg_t = np.max(np.abs(seg) / (speed * VELOCITY_LIMIT), axis=1) if len(seg) else np.zeros(0)
    total = float(seg_t.sum())
    if total <= 0:
        return path[-1:].copy()
    ramp = accel_steps * dt
    cruise = max(total - ramp / 2, 0.0)  # a linear velocity ramp of ramp/2 at each end costs ramp/2 of path time
    duration = cruise + ramp
    ts = np.arange(dt, duration + dt, dt)

    def progress(t):  # path time travelled by wall time t (trapezoid, normalised to reach `total`)
        up = np.clip(t, 0, ramp / 2)
        flat = np.clip(t - ramp / 2, 0, cruise)
        down = np.clip(t - ramp / 2 - cruise, 0, ramp / 2)
        v_scale = total / (cruise + ramp / 2)
        return v_scale * (up ** 2 / ramp + flat + (down - down ** 2 / ramp))

    knots = np.concatenate([[0.0], np.cumsum(seg_t)])
    s = np.clip(progress(ts), 0, total)
    out = np.stack([np.interp(s, knots, path[:, j]) for j in range(7)], axis=1)
    out[-1] = path[-1]
    return out
