"""Dynamic movement primitive controllers (paper: DMP), learned from the motion planner's trajectories.

For each subtask, every movement between two of its waypoints
(`policy_composer.policies.subtasks`) gets a joint-space DMP
(`movement_primitives`), fitted to the planner's trajectories for that movement over several episodes (the
forcing-term weights averaged). At run time the DMP is configured with the new episode's start (the arm's
joints) and goal (the waypoint's IK solution) and rolled out: no planner and no collision checks, so a DMP
generalises the planner's shape of motion, not its obstacle avoidance. Gripper changes happen at the same
waypoints as the planner's.

Weights are stored as safetensors with a JSON config beside them.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from movement_primitives.dmp import DMP
from safetensors.numpy import load_file, save_file
from tqdm import tqdm

from policy_composer.data.atomic import check_replaceable, replacing_folder, safetensors_errors
from policy_composer.learning.checkpoint import CheckpointError, check_finite
from policy_composer.policies.arm import Outcome, Segment, run_activation
from policy_composer.policies.dmp.configuration_dmp import DMPConfig
from policy_composer.policies.mp.controller import MotionPlanningController
from policy_composer.policies.mp.planning import VELOCITY_LIMIT, time_parameterize
from policy_composer.policies.subtasks import SubtaskController
from policy_composer.tasks.base import Waypoint
from policy_composer.tasks.registry import task_of

DMP_FILES = ("dmp.safetensors", "dmp.json")
MIN_DEMO_STEPS = 5  # shorter movements (a few mm of alignment) are not worth a DMP: they go straight in joint space


@dataclass
class MovementPrimitive:
    weights: np.ndarray  # (7 * n_weights,)
    duration: float  # mean demonstrated duration (s)


@dataclass
class DMPLibrary:
    config: DMPConfig
    primitives: dict[str, list[MovementPrimitive | None]] = field(default_factory=dict)  # subtask -> per waypoint
    demonstrations: int = 0

    def save(self, directory: str | Path) -> None:
        tensors, layout = {}, {}
        for name, prims in self.primitives.items():
            layout[name] = [None if p is None else p.duration for p in prims]
            for i, p in enumerate(prims):
                if p is not None:
                    tensors[f"{name}.{i}"] = p.weights.astype(np.float64)
        check_replaceable(directory, DMP_FILES, "a DMP library")  # a folder holding anything else is not replaced
        with replacing_folder(directory) as tmp, safetensors_errors(directory):  # the old library or the new, whole
            save_file(tensors, str(tmp / "dmp.safetensors"))
            (tmp / "dmp.json").write_text(json.dumps({"config": asdict(self.config), "durations": layout,
                                                      "demonstrations": self.demonstrations}, indent=1))

    @classmethod
    def load(cls, directory: str | Path) -> DMPLibrary:
        directory = Path(directory)
        if not (directory / "dmp.json").is_file() or not (directory / "dmp.safetensors").is_file():
            raise FileNotFoundError(f"no DMP library in {directory} (expected dmp.json and dmp.safetensors); "
                                    f"fit one with `policy-composer train dmp`")
        try:
            meta = json.loads((directory / "dmp.json").read_text())
            tensors = load_file(str(directory / "dmp.safetensors"))
            lib = cls(DMPConfig(**meta["config"]), demonstrations=meta["demonstrations"])
            for name, durations in meta["durations"].items():
                lib.primitives[name] = [None if d is None else MovementPrimitive(tensors[f"{name}.{i}"], d)
                                        for i, d in enumerate(durations)]
        except Exception as e:  # unreadable JSON or safetensors, or files of another version
            raise CheckpointError(f"the DMP library in {directory} does not read ({type(e).__name__}: "
                                  f"{str(e).splitlines()[0][:200] if str(e) else ''}); fit it again with "
                                  f"`policy-composer train dmp`") from None
        check_finite(directory / "dmp.safetensors", tensors, "fit it again with `policy-composer train dmp`")
        return lib


def _dmp(config: DMPConfig, duration: float):
    return DMP(n_dims=7, execution_time=duration, dt=config.dt, n_weights_per_dim=config.n_weights_per_dim,
               smooth_scaling=config.smooth_scaling)


def fit_primitive(demos: list[np.ndarray], config: DMPConfig) -> MovementPrimitive:
    """One DMP from demonstrations (each (T, 7), starting at the movement's start): weights averaged."""
    weights, durations = [], []
    for y in demos:
        duration = (len(y) - 1) * config.dt
        dmp = _dmp(config, duration)
        dmp.imitate(np.arange(len(y)) * config.dt, y)
        weights.append(dmp.get_weights())
        durations.append(duration)
    return MovementPrimitive(np.mean(weights, axis=0), float(np.mean(durations)))


def rollout(primitive: MovementPrimitive, start: np.ndarray, goal: np.ndarray, config: DMPConfig) -> np.ndarray:
    """Joint targets (T, 7) from start to goal; slowed down where the new movement is longer than the demos'."""
    shortest = float(np.max(np.abs(goal - start) / (config.speed * VELOCITY_LIMIT)))
    dmp = _dmp(config, max(primitive.duration, 2 * shortest, config.dt))
    dmp.set_weights(primitive.weights)
    dmp.configure(start_y=np.asarray(start, dtype=float), goal_y=np.asarray(goal, dtype=float))
    _, y = dmp.open_loop()
    return y


class DMPController(SubtaskController):
    kind = "dmp"
    action_kind = "joint_targets"

    def __init__(self, env, subtask, library: DMPLibrary, **kwargs):
        prims = library.primitives.get(subtask.name)
        if not prims:
            raise ValueError(f"the DMP library has no primitives for subtask {subtask.name!r} "
                             f"(it has {sorted(library.primitives)})")
        super().__init__(env, subtask, **kwargs)
        self.library = library
        self.primitives = prims

    def connect(self, obs, waypoints: list[Waypoint], seed):
        if len(waypoints) != len(self.primitives):
            raise ValueError(f"{self.name}: {len(waypoints)} waypoints but {len(self.primitives)} primitives; "
                             f"the DMP library was fitted to another version of the subtask")
        q, segments = self.q9(obs)[:7], []
        for wp, prim in zip(waypoints, self.primitives):
            if prim is None:  # a gripper change in place, or a movement too short for a primitive
                traj = time_parameterize(np.stack([q, wp.q[:7]]), self.library.config.dt, self.library.config.speed)
            else:
                traj = rollout(prim, q, wp.q[:7], self.library.config)[1:]
            segments.append(Segment(traj, wp.gripper, settle=wp.settle))
            q = wp.q[:7]
        return segments


def fit_dmp_library(env, seeds: list[int], config: DMPConfig | None = None, progress: bool = True) -> DMPLibrary:
    """Run the motion planner through the full task on each seed and fit a DMP to each of its movements."""
    config = config or DMPConfig(dt=1.0 / float(env.unwrapped.control_freq))
    task = task_of(env)
    demos: dict[str, list[list[np.ndarray | None]]] = {n: [] for n in task.sequence}
    for seed in tqdm(seeds, desc="planner demonstrations for the DMPs", unit="episode", disable=not progress):
        obs, _ = env.reset(seed=seed)
        for name in task.sequence:
            mp = MotionPlanningController(env, task.subtasks[name], grasp_offset=0.0)
            if not mp.can_start(obs):
                break
            start = mp.q9(obs)[:7]
            obs = run_activation(env, mp, obs, seed)
            per_wp = []
            for seg, wp in zip(mp.segments, mp.waypoints):
                short = wp.kind == "hold" or len(seg.q) < MIN_DEMO_STEPS
                per_wp.append(None if short else np.vstack([start, seg.q]))
                start = seg.q[-1]
            demos[name].append(per_wp)
            if mp.outcome is not Outcome.DONE:
                break
    library = DMPLibrary(config, demonstrations=len(seeds))
    for name, episodes in demos.items():
        if not episodes:
            continue
        library.primitives[name] = []
        for i in range(len(episodes[0])):
            movement = [ep[i] for ep in episodes if ep[i] is not None]
            library.primitives[name].append(fit_primitive(movement, config)
                                            if len(movement) > len(episodes) // 2 else None)
    return library



def load(path) -> DMPLibrary:
    """The registry's loader: the fitted library (its own configuration inside)."""
    return DMPLibrary.load(path)


def build(env, subtask, library: DMPLibrary, config: DMPConfig, max_grasp_offset: float) -> DMPController:
    """The registry's builder: one subtask's controller from the fitted library, which runs at the configuration it
    was fitted with."""
    return DMPController(env, subtask, library, max_grasp_offset=max_grasp_offset)
