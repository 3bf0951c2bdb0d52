"""GearAssembly-v1: put a compound gear on a peg module held by the other arm (the paper's PR2 task).

Two Panda arms face each other across a table. The left arm (``agent.agents[0]``) picks the gear up
from the table, carries it to the peg and inserts it. The right arm (``agent.agents[1]``) holds the peg
module (base plate + vertical peg) rigidly in its hand, at a pose that varies per episode, as the PR2
held the peg module in its other hand. Cameras: ``head`` (fixed, over the whole workspace) and
``left_forearm`` / ``right_forearm`` (on each hand, seeing its gripper and what it holds).

**Task Description:** the left arm picks the gear up, carries it to the peg and slides it down the peg.

**Randomizations:** per seed, the gear's x, y and yaw on the table, the right arm's configuration (so the
peg's position and yaw), and small noise on the left arm's start configuration.

**Success Conditions:** the gear seated on the peg (axes aligned within ``ALIGN_TOL_DEG``, the gear down at the base
plate). ``evaluate`` also gives the subtask flags and an integer ``stage`` (0 pick, 1 move, 2 insert,
3 done) used as labels by the datasets and by evaluation.

**Sensed and privileged:** a robot senses its joints and gripper (``observation.state``), its hands' poses from them,
the peg module from the right hand that holds it (``module_in_hand``, the hand-over's calibration) and the cameras.
The gear's pose, ``evaluate``, ``predicates`` and the peg module's actor are the simulator's truth: for the scripted
expert, the recordings' labels and the scorer. The planner's pick-up is given one of them, the gear's position on
the table (``planner_gear_position``), with noise if asked.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

import numpy as np
import torch
from mani_skill.agents.multi_agent import MultiAgent
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.envs.utils.randomization.pose import random_quaternions
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common, sapien_utils
from mani_skill.utils.registration import make, make_vec, register
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose
from transforms3d.euler import euler2quat

from policy_composer.tasks import panda_light  # noqa: F401  (registers the "panda_light" agent)
from policy_composer.tasks.gear_assembly.geometry import GearSpec, build_gear, build_peg_module
from policy_composer.tasks.gear_assembly.kinematics import (
    LEFT_BASE,
    RIGHT_BASE,
    LeftArmIK,
    module_in_hand,
    plate_direction,
)
from policy_composer.tasks.gear_assembly.spec import (  # noqa: F401
    ACTION_NAMES,
    ARM_JOINTS,
    CAMERA_NAMES,
    ENV_ID,
    MAX_EPISODE_STEPS,
    PREDICATES,
    START_STATES,
    STATE_NAMES,
)
from policy_composer.tasks.panda import REST_QPOS

SUPPORTED_ROBOTS = (("panda_light", "panda_light"), ("panda", "panda"))
SUPPORTED_CONTROL_MODES = ("pd_joint_pos", "pd_joint_delta_pos")  # the first is the default

# The left arm starts retracted above its own side of the table, hand down, clear of the peg.
LEFT_START_QPOS = np.array([0.0, -0.25, 0.0, -2.55, 0.0, 2.30, np.pi / 4, 0.04, 0.04])
HEAD_EYE, HEAD_TARGET = [0.35, -0.10, 0.70], [0.0, -0.10, 0.05]
# Forearm cameras ride beside each hand (hand frame, z towards the fingers), looking at what it holds. The left
# one looks obliquely from behind the fingers' plane, so that at the pre-insertion pose it sees the held gear over
# the peg and its offset along the fingers. The right one looks obliquely at the peg from beside the plate, so it
# sees the gear come down onto the peg (the paper's right forearm camera judges the insertion; from behind the
# fingers, where it first was, the hand hid the peg and its goal score could not learn).
FOREARM_VIEWS = {"left": ([-0.08, 0.06, 0.08], [0.0, 0.0, 0.15]), "right": ([0.16, -0.15, 0.03], [0.10, 0.0, 0.07])}
# Bump when a change alters what the task simulates or renders: the main job's recording stages key on it, so
# recordings made before the change are not reused after it (CHANGELOG.md says what each revision changed).
TASK_REVISION = 6
GEAR_XY_CENTER = (0.0, -0.30)
GEAR_XY_RANGE = (0.10, 0.06)  # half-ranges of the gear's uniform position on the table
PLATE_GRIP = 0.024  # right finger position holding the plate
ALIGN_TOL_DEG = 8.0
INSERT_TILT_DEG = 15.0  # a gear at or on the peg tilted further is caught on it, not going down it
SEATED_TOL = 0.004  # gear bottom at most this far above the plate
LIFT_HEIGHT = 0.03
ON_TABLE_HEIGHT = 0.02  # a gear lying flat on the table has its origin (its bottom) below this (m)
GRASP_DISTANCE = 0.05  # gear origin to the left TCP while grasped (m)
PRE_INSERT_RADIUS = 0.015
PRE_INSERT_HEIGHT = 0.06
# reset(options={"start": "pre_insertion"}): the episode starts with the gear already in the left gripper above the
# peg, where the insertion begins (Table I's insert column; the insertion demonstrations), instead of on the table.
GRASP_OFFSET_MAX = 0.012  # gear centre off the fingers' centre, along the fingers, up to this (m)
ARRIVAL_ERROR_MAX = (0.004, 0.010)  # a rough carry leaves the hand off the pre-insertion pose by up to (xy, +z) (m)
CARRY_CLEARANCE = 0.03  # gear bottom above the peg top at the pre-insertion pose (m)
# A gear in the hand and off the peg is off course when it tipped past INSERT_TILT_DEG or was led this far off the
# peg's axis (m): past the pre-insertion tolerance and the farthest wrong guess of an insertion feeling for the hole
# (12 mm the other way of a gear 12 mm off-centre), which lands it on the peg's top; below the top, nearer: a gear
# pushed down beside the peg tips in the fingers and falls.
OFF_COURSE_RADIUS = 0.03
BESIDE_PEG_RADIUS = PRE_INSERT_RADIUS + 0.005
CLOSE_STEPS = 6  # control steps the gripper takes to close on the gear (held still meanwhile)
SETTLE_STEPS = 4  # then the grasp alone holds it


class GearAssemblyEnv(BaseEnv):
    """Bimanual gear assembly: the left Panda puts the gear on the peg the right Panda holds."""

    SUPPORTED_ROBOTS = list(SUPPORTED_ROBOTS)
    agent: MultiAgent

    def __init__(
        self,
        *args,
        robot_uids: tuple[str, str] = ("panda_light", "panda_light"),
        control_mode: str | None = SUPPORTED_CONTROL_MODES[0],
        cameras: Sequence[str] = CAMERA_NAMES,
        camera_width: int = 128,
        camera_height: int = 128,
        clearance: float = 0.002,
        robot_init_qpos_noise: float = 0.02,
        knock_out_step: int | None = None,
        **kwargs,
    ):
        robot_uids = tuple(robot_uids) if not isinstance(robot_uids, str) else robot_uids
        if robot_uids not in SUPPORTED_ROBOTS:
            raise ValueError(f"GearAssembly-v1 does not support robot_uids={robot_uids!r}; "
                             f"choose one of {list(SUPPORTED_ROBOTS)}")
        control_mode = control_mode or SUPPORTED_CONTROL_MODES[0]  # None: the default, as in ManiSkill's scripts
        if control_mode not in SUPPORTED_CONTROL_MODES:
            raise ValueError(f"GearAssembly-v1 does not support control_mode={control_mode!r}; "
                             f"choose one of {list(SUPPORTED_CONTROL_MODES)}")
        unknown = [c for c in cameras if c not in CAMERA_NAMES]
        if unknown or len(set(cameras)) != len(cameras):
            raise ValueError(f"unknown or repeated camera names {unknown or list(cameras)}; "
                             f"valid cameras are {list(CAMERA_NAMES)}")
        for name, value in (("camera_width", camera_width), ("camera_height", camera_height)):
            if not isinstance(value, (int, np.integer)) or value <= 0:
                raise ValueError(f"{name}={value!r}: the camera resolution must be a positive integer (default 128)")
        self.camera_names = tuple(cameras)
        self.camera_size = (int(camera_width), int(camera_height))
        self.gear_spec = GearSpec(clearance=clearance)
        self.robot_init_qpos_noise = robot_init_qpos_noise
        # Perturbation: from this control step on, the first time the gear is in the left gripper it is knocked
        # out onto the table (to test that a composition recovers). None: never.
        self.knock_out_step = knock_out_step
        self.knocked_out = False
        self.start = "table"
        self.grasp_offset = 0.0  # at a pre-insertion start: where the gear sits along the fingers (m)
        self._physics_steps, self._finger_forces_at = 0, None
        # Without CUDA, render on the CPU (lavapipe) directly instead of warning and falling back.
        kwargs.setdefault("render_backend", "gpu" if torch.cuda.is_available() else "cpu")
        # Rebuild the scene at every reset (about 0.4 s on the CPU): PhysX keeps contact state across set_pose, so
        # without it an episode depends on the one before (the gear's pose drifts by 1e-6 from the first step).
        kwargs.setdefault("reconfiguration_freq", 1)
        super().__init__(*args, robot_uids=robot_uids, control_mode=control_mode, **kwargs)

    # ---------------------------------------------------------------- configuration
    def _camera_config(self, name: str) -> CameraConfig:
        w, h = self.camera_size
        if name == "head":
            return CameraConfig("head", sapien_utils.look_at(eye=HEAD_EYE, target=HEAD_TARGET), w, h, np.deg2rad(60),
                                0.01, 100)
        side = name.removesuffix("_forearm")
        arm = self.agent.agents[0 if side == "left" else 1]
        return CameraConfig(name, sapien_utils.look_at(*FOREARM_VIEWS[side], up=[0, 0, -1]), w, h, np.deg2rad(80),
                            0.01, 100, mount=arm.robot.links_map["panda_hand"])

    @property
    def _default_sensor_configs(self):
        return [self._camera_config(name) for name in self.camera_names]

    @property
    def _default_human_render_camera_configs(self):
        pose = sapien_utils.look_at(eye=[0.9, -0.5, 0.6], target=[0.0, -0.05, 0.1])
        return CameraConfig("render_camera", pose, 512, 512, 1, 0.01, 10)

    # ---------------------------------------------------------------- loading
    def _load_agent(self, options: dict):
        super()._load_agent(options, [LEFT_BASE, RIGHT_BASE])

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(env=self, robot_init_qpos_noise=0)
        self.table_scene.build()
        self.gear = build_gear(self.scene, self.gear_spec)
        self.peg_module = build_peg_module(self.scene, self.gear_spec)
        self.module_in_hand = Pose.create_from_pq(*module_in_hand(self.gear_spec), device=self.device)

    # ---------------------------------------------------------------- episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = len(env_idx)
            self.table_scene.initialize(env_idx)
            left, right = self.agent.agents
            left.robot.set_pose(LEFT_BASE)
            right.robot.set_pose(RIGHT_BASE)

            qpos = torch.as_tensor(LEFT_START_QPOS, dtype=torch.float32).repeat(b, 1)
            qpos[:, :7] += torch.randn((b, 7)) * self.robot_init_qpos_noise
            left.reset(qpos)

            # Right arm: hand pointing straight down (q6 = q2 - q4), so the peg stands vertical.
            rq = torch.as_tensor(REST_QPOS, dtype=torch.float32).repeat(b, 1)
            rq[:, 0] = (torch.rand(b) * 2 - 1) * 0.20
            rq[:, 1] = 0.25 + torch.rand(b) * 0.25
            rq[:, 3] = -2.05 + (torch.rand(b) * 2 - 1) * 0.15
            rq[:, 5] = rq[:, 1] - rq[:, 3]
            rq[:, 6] = np.pi / 4 + (torch.rand(b) * 2 - 1) * 0.35
            rq[:, 7:] = PLATE_GRIP
            right.reset(rq)

            xyz = torch.zeros((b, 3))
            xyz[:, 0] = GEAR_XY_CENTER[0] + (torch.rand(b) * 2 - 1) * GEAR_XY_RANGE[0]
            xyz[:, 1] = GEAR_XY_CENTER[1] + (torch.rand(b) * 2 - 1) * GEAR_XY_RANGE[1]
            self.gear.set_pose(Pose.create_from_pq(p=xyz, q=random_quaternions(b, lock_x=True, lock_y=True)))
            self._refresh_kinematics()
            self._attach_peg_module()
            self._control_steps, self.knocked_out = 0, False

    def reset(self, seed=None, options: dict | None = None):
        """ManiSkill's reset; with options={"start": "pre_insertion"} the gear starts in the left gripper above the
        peg, off-centre along the fingers by up to GRASP_OFFSET_MAX (or options["grasp_offset_max"]). With
        options["gear_arrival_max"] (m), the gear is off the peg's axis by a uniform draw within that radius,
        whatever the grasp (a carry that watched the gear); by default the hand is off by a rough carry's error and
        the gear by its grasp offset besides."""
        options = dict(options or {})
        start = options.pop("start", "table")
        offset_max = float(options.pop("grasp_offset_max", GRASP_OFFSET_MAX))
        gear_arrival_max = options.pop("gear_arrival_max", None)
        if start not in START_STATES:
            raise ValueError(f"unknown start state {start!r}: choose one of {list(START_STATES)}")
        if self.num_envs != 1 and start != "table":
            raise ValueError(f"start={start!r} places one env's gear; got num_envs={self.num_envs}")
        obs, info = super().reset(seed=seed, options=options)
        self.start, self.grasp_offset = start, 0.0
        if start == "pre_insertion":
            obs, info = self._start_at_pre_insertion(offset_max, gear_arrival_max)
        return obs, info

    def _start_at_pre_insertion(self, offset_max: float, gear_arrival_max: float | None = None):
        """Put the hand at the pre-insertion pose (off by a rough carry's error) with the gear between its open
        fingers, held still while they close on it, then let physics hold it: what the pick-up and carry leave,
        without simulating them."""
        rng = self._episode_rng
        self.grasp_offset = float(rng.uniform(-offset_max, offset_max))
        xy_error, z_error = ARRIVAL_ERROR_MAX
        arrival = np.append(rng.uniform(-xy_error, xy_error, 2), rng.uniform(0.0, z_error))
        yaw = float(rng.uniform(0, 2 * np.pi))
        grasp_height = self.gear_spec.grasp_height
        x = plate_direction(self)
        x[2] = 0.0
        x /= np.linalg.norm(x)
        if gear_arrival_max is not None:
            radius, angle = gear_arrival_max * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
            arrival[:2] = x[:2] * self.grasp_offset + radius * np.array([np.cos(angle), np.sin(angle)])
        tcp = self.peg_top.p[0].cpu().numpy() + [0.0, 0.0, CARRY_CLEARANCE + grasp_height] + arrival
        solution = LeftArmIK(self).solve_hand_down(tcp, x, LEFT_START_QPOS)
        if solution is None:
            raise RuntimeError("the pre-insertion pose is out of the left arm's reach for this seed")
        q = np.concatenate([solution[1][:7], [0.04, 0.04]])  # fingers open
        left = self.left_arm
        left.robot.set_qpos(torch.as_tensor(q, dtype=torch.float32)[None])
        left.robot.set_qvel(torch.zeros((1, 9)))
        gear_p = tcp - [0.0, 0.0, grasp_height] - x * self.grasp_offset
        self.gear.set_pose(Pose.create_from_pq(p=torch.as_tensor(gear_p, dtype=torch.float32)[None],
                                               q=torch.as_tensor(euler2quat(0, 0, yaw), dtype=torch.float32)[None]))
        body = self.gear._bodies[0]
        body.kinematic = True
        for controller in self.agent.controller.values():  # drive targets from the new joint angles
            controller.reset()
        action = self.hold_action()[0]
        action[:7] = torch.as_tensor(q[:7])
        action[7] = -1.0  # close
        action = self.flat_to_dict_action(action[None])
        for i in range(CLOSE_STEPS + SETTLE_STEPS):  # physics only: nothing renders until the episode begins
            body.kinematic = i < CLOSE_STEPS
            self._step_action(action)
        self._control_steps = 0
        info = self.get_info()
        obs = self.get_obs(info)
        self._last_obs = obs
        return obs, info

    def step_unobserved(self, action) -> None:
        """A control step without an observation: physics only, no camera renders. For driving the scene where no
        one looks (the scripted expert's pick-up before a controller's start state); `observe` ends it."""
        self._step_action(action)
        self._elapsed_steps += 1

    def observe(self) -> dict:
        """The observation of the scene as it is now (after `step_unobserved`)."""
        self._last_obs = self.get_obs(self.get_info())
        return self._last_obs

    def knock_gear_out(self) -> None:
        """Knock the gear out of the gripper: it lands flat somewhere else on the table, at rest."""
        with torch.device(self.device):
            b = self.num_envs
            xyz = torch.zeros((b, 3))
            u = torch.as_tensor(self._episode_rng.uniform(-1, 1, (b, 2)), dtype=torch.float32)
            xyz[:, 0] = GEAR_XY_CENTER[0] + u[:, 0] * GEAR_XY_RANGE[0]
            xyz[:, 1] = GEAR_XY_CENTER[1] + u[:, 1] * GEAR_XY_RANGE[1]
            self.gear.set_pose(Pose.create_from_pq(p=xyz, q=random_quaternions(b, lock_x=True, lock_y=True)))
            self.gear.set_linear_velocity(torch.zeros((b, 3)))
            self.gear.set_angular_velocity(torch.zeros((b, 3)))
        self.knocked_out = True

    def _refresh_kinematics(self):
        if self.gpu_sim_enabled:  # link poses follow qpos only after a GPU kinematics update
            self.scene._gpu_apply_all()
            self.scene.px.gpu_update_articulation_kinematics()
            self.scene._gpu_fetch_all()

    def _attach_peg_module(self):
        self.peg_module.set_pose(self.agent.agents[1].tcp.pose * self.module_in_hand)

    def _after_simulation_step(self):
        self._physics_steps += 1  # the contacts PhysX reports change only here

    def _after_control_step(self):
        # The peg module is rigidly attached to the right hand: follow it if the right arm moves.
        self._attach_peg_module()
        self._control_steps += 1
        if (self.knock_out_step is not None and not self.knocked_out and self._control_steps >= self.knock_out_step
                and bool(self.evaluate()["gear_lifted"].any())):
            self.knock_gear_out()

    # ---------------------------------------------------------------- state
    @property
    def left_arm(self):
        return self.agent.agents[0]

    @property
    def right_arm(self):
        return self.agent.agents[1]

    @property
    def peg_top(self) -> Pose:
        """The peg's top centre (z along the peg)."""
        return self.peg_module.pose * Pose.create_from_pq(p=[0, 0, self.gear_spec.peg_height], device=self.device)

    def gear_in_peg_frame(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Gear origin in the peg-module frame (x, y radial; z above the plate) and the cosine between axes."""
        rel = self.peg_module.pose.inv() * self.gear.pose
        axis_cos = rel.to_transformation_matrix()[..., 2, 2]
        return rel.p, axis_cos

    def gear_offset_in_hand(self) -> torch.Tensor:
        """(B, 3) the gear's origin from the peg's top, in the left hand's frame (m): what a camera on that hand must
        judge to insert. The expert's recordings keep it as a label (the policies' auxiliary target); no controller
        reads it."""
        hand = self.left_arm.tcp.pose.to_transformation_matrix()[..., :3, :3]
        return (hand.transpose(-1, -2) @ (self.gear.pose.p - self.peg_top.p)[..., None])[..., 0]

    def _left_grasping(self) -> torch.Tensor:
        """ManiSkill's `Panda.is_grasping(gear)` (0.5 N, 85 degrees), with the fingers' contact forces read once per
        physics step on the CPU: `evaluate` runs at every control step and again for each controller's checks, and
        each of ManiSkill's force queries walks all the scene's contacts in Python (a third of an episode's time)."""
        arm = self.left_arm
        if self.gpu_sim_enabled:
            return arm.is_grasping(self.gear)
        l_force, r_force = self._finger_forces()
        l_open = arm.finger1_link.pose.to_transformation_matrix()[..., :3, 1]  # the direction that opens each finger
        r_open = -arm.finger2_link.pose.to_transformation_matrix()[..., :3, 1]
        return _pushes(l_force, l_open) & _pushes(r_force, r_open)

    def _finger_forces(self) -> tuple[torch.Tensor, torch.Tensor]:
        """ManiSkill's `scene.get_pairwise_contact_forces(finger, gear)` for both left fingers, from one pass over the
        last physics step's contacts, kept until the next step."""
        cached = self._finger_forces_at
        if cached is None or cached[0] is not self.scene or cached[1] != self._physics_steps:
            arm = self.left_arm
            fingers = [link._bodies[0].entity for link in (arm.finger1_link, arm.finger2_link)]
            by_finger = sapien_utils.get_multiple_pairwise_contacts(self.scene.px.get_contacts(),
                                                                    self.gear._bodies[0].entity, fingers)
            forces = tuple(common.to_tensor(sapien_utils.compute_total_impulse(  # signed as seen by the finger
                [(contact, not gear_first) for contact, gear_first in by_finger[f]]))[None, :] / self.scene.px.timestep
                for f in fingers)
            cached = self._finger_forces_at = (self.scene, self._physics_steps, forces)
        return cached[2]

    def joint_state(self) -> torch.Tensor:
        """observation.state: [left 7 joints, left gripper width, right 7 joints, right gripper width]."""
        parts = []
        for arm in self.agent.agents:
            q = arm.robot.get_qpos()
            parts += [q[:, :7], q[:, 7:9].sum(-1, keepdim=True)]
        return torch.cat(parts, dim=-1)

    def flat_to_dict_action(self, action: torch.Tensor | np.ndarray) -> dict:
        """Split a flat 16-D action (see ACTION_NAMES) into the per-arm dict ManiSkill expects."""
        action = torch.as_tensor(action, dtype=torch.float32, device=self.device)
        if action.shape[-1] != len(ACTION_NAMES):
            raise ValueError(f"flat action has {action.shape[-1]} values; "
                             f"GearAssembly-v1 expects {len(ACTION_NAMES)} ({', '.join(ACTION_NAMES)})")
        uids = list(self.agent.agents_dict.keys())
        return {uids[0]: action[..., :8], uids[1]: action[..., 8:]}

    def hold_action(self) -> torch.Tensor:
        """A flat action that keeps both arms at their current joint targets."""
        parts = []
        for arm in self.agent.agents:
            arm_target = arm.controller.controllers["arm"]._target_qpos
            gripper = arm.controller.controllers["gripper"]
            low, high = gripper.config.lower, gripper.config.upper
            parts += [arm_target, 2 * (gripper._target_qpos[..., :1] - low) / (high - low) - 1]
        return torch.cat(parts, dim=-1)

    # ---------------------------------------------------------------- evaluation
    def evaluate(self) -> dict[str, Any]:
        rel_p, axis_cos = self.gear_in_peg_frame()
        radial = torch.linalg.norm(rel_p[:, :2], dim=-1)
        height = rel_p[:, 2]
        peg_h = self.gear_spec.peg_height
        # Contact forces are those of the last physics step (stale right after a reset): also ask for the
        # gear to be at the fingers.
        near = torch.linalg.norm(self.gear.pose.p - self.left_arm.tcp.pose.p, dim=-1) < GRASP_DISTANCE
        grasped = self._left_grasping() & near
        lifted = grasped & (self.gear.pose.p[:, 2] > LIFT_HEIGHT)
        aligned = axis_cos > np.cos(np.deg2rad(ALIGN_TOL_DEG))
        at_peg = (grasped & (radial < PRE_INSERT_RADIUS) & (height >= peg_h - 0.003)
                  & (height <= peg_h + PRE_INSERT_HEIGHT) & (axis_cos > np.cos(np.deg2rad(INSERT_TILT_DEG))))
        inserted = ((radial < self.gear_spec.hole_radius + 0.0015) & (height < peg_h - 0.003) & (height > -0.005)
                    & (axis_cos > np.cos(np.deg2rad(INSERT_TILT_DEG))))
        success = inserted & aligned & (height < SEATED_TOL)
        upright = self.gear.pose.to_transformation_matrix()[:, 2, 2] > np.cos(np.deg2rad(ALIGN_TOL_DEG))
        on_table = ~grasped & ~inserted & (self.gear.pose.p[:, 2] < ON_TABLE_HEIGHT) & upright
        stage = torch.where(success, 3, torch.where(at_peg | inserted, 2, torch.where(lifted, 1, 0)))
        return dict(success=success, gear_grasped=grasped, gear_lifted=lifted, gear_at_peg=at_peg,
                    gear_inserted=inserted, gear_on_table=on_table, stage=stage, radial_offset=radial,
                    height_above_base=height)

    def predicates(self, info: dict | None = None) -> dict[str, torch.Tensor]:
        """Each of PREDICATES from the simulator's truth, (B,) bool: the recordings' labels and the oracle's
        perception (privileged: no controller of the library reads it). `info`: `evaluate()` of the scene now, where
        the caller has it."""
        info = self.evaluate() if info is None else info
        grasped, lifted, inserted = info["gear_grasped"], info["gear_lifted"], info["gear_inserted"]
        radial, height = info["radial_offset"], info["height_above_base"]
        axis = self.gear.pose.to_transformation_matrix()[:, :3, 2]
        level = axis[:, 2] > np.cos(np.deg2rad(INSERT_TILT_DEG))
        centred = torch.linalg.norm((self.gear.pose.p - self.left_arm.tcp.pose.p)[:, :2], dim=-1) < PRE_INSERT_RADIUS
        below_top = height < self.gear_spec.peg_height - 0.003
        led_away = (radial > OFF_COURSE_RADIUS) | (below_top & (radial > BESIDE_PEG_RADIUS))
        flags = dict(gear_on_table=(self.gear.pose.p[:, 2] < ON_TABLE_HEIGHT) & ~inserted, gear_grasped=grasped,
                     gear_lifted=lifted, gear_held_level=lifted & level & centred, gear_at_peg=info["gear_at_peg"],
                     gear_on_peg=inserted, gear_seated=info["success"], gear_lying_flat=info["gear_on_table"],
                     gear_off_course=grasped & ~inserted & (~level | led_away))
        return {name: flags[name] for name in PREDICATES}

    def planner_gear_position(self, noise_m: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
        """The gear's position (world, m) as the pick-up's planner is given it: the task's one privileged input to a
        controller (the paper's planner was given the object poses), with Gaussian noise of `noise_m` per axis in
        the table's plane."""
        p = self.gear.pose.p[0].cpu().numpy().astype(np.float64)
        if noise_m:
            p[:2] += (rng or np.random.default_rng()).normal(0.0, noise_m, 2)
        return p

    def _get_obs_extra(self, info: dict):
        obs = dict(state=self.joint_state(), tcp_pose=self.left_arm.tcp.pose.raw_pose)
        if "state" in self.obs_mode:
            obs.update(gear_pose=self.gear.pose.raw_pose, peg_top_pose=self.peg_top.raw_pose)
        return obs

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        tcp_to_gear = torch.linalg.norm(self.gear.pose.p - self.left_arm.tcp.pose.p, dim=-1)
        reward = 1 - torch.tanh(5 * tcp_to_gear)
        gear_to_peg = torch.linalg.norm(self.gear.pose.p - self.peg_top.p, dim=-1)
        reward += info["gear_grasped"] * (1 + (1 - torch.tanh(5 * gear_to_peg)))
        reward += info["gear_at_peg"] + 2 * info["gear_inserted"]
        reward[info["success"]] = 6.0
        return reward

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs, action, info) / 6.0


def gear_whereabouts(info: dict) -> str:
    """Where the gear is, in the words of the task's flags."""
    if bool(info["success"][0]):
        return "seated on the peg"
    if bool(info["gear_inserted"][0]):
        return "on the peg, not seated"
    if bool(info["gear_at_peg"][0]):
        return "in the hand above the peg"
    if bool(info["gear_grasped"][0]):
        return "in the hand"
    return "out of the hand"


def _pushes(force: torch.Tensor, opening: torch.Tensor, min_force: float = 0.5, max_angle: float = 85) -> torch.Tensor:
    """A finger presses on the gear: at least `min_force` N, within `max_angle` degrees of its opening direction."""
    angle = torch.rad2deg(common.compute_angle_between(opening, force))
    return (torch.linalg.norm(force, axis=1) >= min_force) & (angle <= max_angle)


# ManiSkill's registry (its `make` reads it); gymnasium's entry, which points here, is made by `policy_composer.tasks`.
register(ENV_ID, GearAssemblyEnv, max_episode_steps=MAX_EPISODE_STEPS)
make_env = partial(make, env_id=ENV_ID)
make_vec_env = partial(make_vec, env_id=ENV_ID)
