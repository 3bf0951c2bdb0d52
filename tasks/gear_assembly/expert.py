"""Scripted expert for GearAssembly-v1, using privileged state (the true gear and peg poses).

It picks the gear up with a grasp offset drawn per episode (the paper's "grasp variability": the gear
sits in the gripper up to about the hole's diameter off-centre), carries it above the peg, inserts it,
releases it and retreats. Carrying and insertion close the loop on the *measured* gear pose every
step, so the expert succeeds whatever the grasp offset; an open-loop insertion that assumes a centred
grasp does not (that is the motion-planning controller's failure in the paper's Table I).

Joint targets come from SAPIEN's pinocchio IK on the left arm (about 0.3 ms a solve). The right arm
holds its pose. Works on a single environment (``num_envs == 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
import torch

from policy_composer.tasks.gear_assembly.env import GearAssemblyEnv
from policy_composer.tasks.gear_assembly.kinematics import LeftArmIK, plate_direction
from policy_composer.tasks.panda import hand_down_quat

GRIPPER_OPEN = 1.0  # normalised gripper commands (see ACTION_NAMES)
GRIPPER_CLOSED = -1.0


@dataclass
class ExpertConfig:
    grasp_offset: float = 0.012  # max |offset| of the gear centre from the fingers' centre, along the fingers (m)
    carry_clearance: float = 0.03  # gear bottom above the peg top while carrying (m)
    max_step: float = 0.012  # TCP travel per control step (m)
    insert_step: float = 0.004  # descent per control step while inserting (m)
    release_height: float = 0.012  # gear bottom above the plate when the gripper opens (m)
    # TCP travel per control step backing off after the release: the library's insertions back off at this
    # speed, and so many frames of a seated gear teach the goal score what a finished insertion looks like.
    retreat_step: float = 0.006
    seed: int | None = None  # grasp-offset RNG; None: drawn from the env's episode seed
    closed_loop: bool = True  # False: carry and insert assume a centred grasp (what an open-loop planner knows)
    # Teleoperator style (for demonstrations): carry roughly (as if the grasp were centred, off by up to a further
    # `arrival_error`), so the gear arrives above the peg off by its grasp offset as after a planner's carry,
    # then correct it with a per-episode gain and speed. (Pauses and hand wobble were tried and dropped: the
    # commands they add are unpredictable from what a camera sees, and they drowned the corrections a
    # behaviour-cloned policy must learn.)
    teleop: bool = False
    arrival_error: float = 0.004
    # DART (Laskey et al. 2017): while carrying and inserting, the executed TCP target is off the expert's own by a
    # slowly drifting offset of this standard deviation per axis (m), which the expert does not know of. The arm,
    # and the gear with it, strays; the expert, closing the loop on the gear, corrects; and the recorded action is
    # the expert's own command. So the demonstrations show corrections from states off the expert's path.
    noise: float = 0.0
    noise_steps: float = 10.0  # the offset's correlation time, control steps
    # Carry and insert from where the hand is (the measured TCP) each step, not from the expert's own last command.
    # A labeller of states a policy drives (DAgger) needs it: its own command would wind up, step after step, while
    # the policy goes elsewhere, until no IK reaches it. Each label is then the expert's step from the measured hand.
    from_arm: bool = False


class GearAssemblyExpert:
    """Phase machine through spec.EXPERT_PHASES: approach -> descend -> close -> lift -> carry -> insert -> release ->
    retreat -> done."""

    name = "expert"

    def __init__(self, env: GearAssemblyEnv, config: ExpertConfig | None = None):
        self.env = env.unwrapped if hasattr(env, "unwrapped") else env
        if self.env.num_envs != 1:
            raise ValueError(f"the scripted expert drives one environment; got num_envs={self.env.num_envs}")
        self.config = config or ExpertConfig()
        self._ik = LeftArmIK(self.env)

    # ------------------------------------------------------------------ helpers
    def _np(self, x: torch.Tensor) -> np.ndarray:
        return x[0].detach().cpu().numpy().astype(np.float64)

    def _ik_joint_targets(self, target: sapien.Pose) -> np.ndarray:
        qpos, ok = self._ik.solve(target, self._q_seed)
        if ok:  # otherwise keep the last reachable configuration
            self._q_seed = qpos
        return self._q_seed[:7]

    def _toward(self, goal_p: np.ndarray, step: float) -> tuple[sapien.Pose, float]:
        """The next TCP waypoint on the straight line to goal_p (orientation fixed), and the distance left."""
        delta = goal_p - self._cmd_p
        dist = float(np.linalg.norm(delta))
        self._cmd_p = goal_p.copy() if dist <= step else self._cmd_p + delta / dist * step
        return sapien.Pose(self._cmd_p, self._cmd_q), dist

    def _gear_world_p(self) -> np.ndarray:
        """Where the expert takes the gear to be: its true position (privileged) closed loop; where a centred grasp
        would put it open loop, and in the teleoperator's carry (rough, like a planner's: the operator looks
        closely only while inserting)."""
        nominal = not self.config.closed_loop or (self.config.teleop and self.phase == "carry")
        if not nominal or self.phase in ("approach", "descend"):
            return self._np(self.env.gear.pose.p)
        return self._np(self.env.left_arm.tcp.pose.p) - [0.0, 0.0, self._grasp_height]

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> None:
        env, cfg = self.env, self.config
        episode_seed = cfg.seed if cfg.seed is not None else seed if seed is not None else int(env._episode_seed[0])
        rng = np.random.default_rng(episode_seed)
        self.grasp_offset = float(rng.uniform(-cfg.grasp_offset, cfg.grasp_offset))
        self._q_seed = self._np(env.left_arm.robot.get_qpos())
        self.phase, self._timer = "approach", 0
        self._gripper = GRIPPER_OPEN
        # Hand down; the fingers close across the plate's direction, so the hand's thin side faces the
        # right hand while inserting.
        x = plate_direction(env)
        x[2] = 0.0
        x /= np.linalg.norm(x)
        self._cmd_p = self._np(env.left_arm.tcp.pose.p)
        spec = env.gear_spec
        gear = self._gear_world_p()
        self._grasp_height = spec.grasp_height
        self._grasp_p = gear + x * self.grasp_offset + np.array([0, 0, self._grasp_height])
        # Of the two symmetric grasps, the one reachable within the joint limits nearest the start (as the
        # controllers choose).
        solution = self._ik.solve_hand_down(self._grasp_p + [0, 0, 0.08], x, self._q_seed)
        self._cmd_q = solution[0] if solution is not None else hand_down_quat(x)
        if env.start == "pre_insertion":  # the env put the gear in the hand: the insertion begins here
            self.grasp_offset, self.phase, self._gripper = env.grasp_offset, "insert", GRIPPER_CLOSED
            self._cmd_q = self._np(env.left_arm.tcp.pose.q)
        self._hold = self._np(env.hold_action())
        self._noise_rng = np.random.default_rng([episode_seed, 1])  # its own stream: the other draws stay the same
        self._offset = np.zeros(3)
        self.executed = None  # the last action sent to the arm, noise included (see ExpertConfig.noise)
        if cfg.teleop:
            self._arrival = np.append(rng.uniform(-cfg.arrival_error, cfg.arrival_error, 2), rng.uniform(0.0, 0.01))
            self._gain, self._speed = rng.uniform(0.25, 0.6), rng.uniform(0.6, 1.2)
        else:
            self._arrival, self._gain, self._speed = np.zeros(3), 0.5, 1.0

    def act(self, obs=None) -> torch.Tensor:
        """The next flat 16-D action (left arm moves, right arm holds)."""
        env, cfg, spec = self.env, self.config, self.env.gear_spec
        target = None
        self._timer += 1
        if cfg.from_arm and self.phase in ("carry", "insert"):
            self._cmd_p = self._np(env.left_arm.tcp.pose.p)
        if self.phase == "approach":
            target, dist = self._toward(self._grasp_p + [0, 0, 0.08], cfg.max_step)
            if dist < 1e-3:
                self.phase = "descend"
        elif self.phase == "descend":
            target, dist = self._toward(self._grasp_p, cfg.max_step / 2)
            if dist < 1e-3:
                self.phase, self._timer = "close", 0
        elif self.phase == "close":
            self._gripper = GRIPPER_CLOSED
            if self._timer >= 6:
                self.phase = "lift"
        elif self.phase == "lift":
            peg_top_z = self._np(env.peg_top.p)[2]
            self._carry_z = max(peg_top_z + cfg.carry_clearance + spec.height, 0.10)
            goal = self._cmd_p.copy()
            goal[2] = self._carry_z + (self._cmd_p[2] - self._gear_world_p()[2])
            target, dist = self._toward(goal, cfg.max_step)
            if dist < 1e-3:
                self.phase = "carry"
        elif self.phase == "carry":
            # Closed loop: move the *measured* gear above the peg axis.
            peg_top = self._np(env.peg_top.p)
            error = peg_top + [0, 0, cfg.carry_clearance] + self._arrival - self._gear_world_p()
            target, _ = self._toward(self._cmd_p + 0.5 * error, cfg.max_step)
            if np.linalg.norm(error) < 2e-3:
                self.phase, self._timer = "insert", 0
        elif self.phase == "insert":
            peg = self._np(env.peg_module.pose.to_transformation_matrix())
            peg_rot = peg[:3, :3]
            rel = peg_rot.T @ (self._gear_world_p() - peg[:3, 3])
            # Correct the radial error (peg frame -> world) and go down; release low on the peg.
            lateral = -self._gain * peg_rot @ np.append(rel[:2], 0.0)
            down = (np.array([0, 0, -cfg.insert_step * self._speed]) if np.linalg.norm(rel[:2]) < spec.clearance
                    else np.zeros(3))
            target, _ = self._toward(self._cmd_p + lateral + down, cfg.max_step)
            if rel[2] < cfg.release_height:
                self.phase, self._timer = "release", 0
        elif self.phase == "release":
            self._gripper = GRIPPER_OPEN
            if self._timer >= 6:
                self._retreat_p = self._cmd_p + [0, 0, 0.10]
                self.phase = "retreat"
        elif self.phase == "retreat":
            target, dist = self._toward(self._retreat_p, cfg.retreat_step)
            if dist < 1e-3:
                self.phase = "done"
        action = self._hold.copy()
        if target is not None:
            action[:7] = self._ik_joint_targets(target)
        else:
            action[:7] = self._q_seed[:7]
        action[7] = self._gripper
        label = torch.as_tensor(action, dtype=torch.float32)
        perturbed = self._perturbed(action, target)
        self.executed = label if perturbed is action else torch.as_tensor(perturbed, dtype=torch.float32)
        return label

    def _perturbed(self, action: np.ndarray, target: sapien.Pose | None) -> np.ndarray:
        """`action` with the TCP target moved by the drifting offset (ExpertConfig.noise): it drifts while carrying
        and inserting and is held after. A step without a TCP target (closing or opening the gripper) is sent as
        the expert commands it."""
        cfg = self.config
        if cfg.noise <= 0.0:
            return action
        if self.phase in ("carry", "insert"):
            a = float(np.exp(-1.0 / cfg.noise_steps))
            self._offset = a * self._offset + np.sqrt(1.0 - a * a) * cfg.noise * self._noise_rng.standard_normal(3)
        if target is None or not self._offset.any():
            return action
        q, ok = self._ik.solve(sapien.Pose(target.p + self._offset, target.q), self._q_seed)
        return np.concatenate([q[:7], action[7:]]) if ok else action

    @property
    def done(self) -> bool:
        return self.phase == "done"
