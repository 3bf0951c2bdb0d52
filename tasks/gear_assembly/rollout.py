"""Running a policy in GearAssembly-v1: one episode at a time, with optional camera frames."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import gymnasium as gym
import numpy as np
import torch

import policy_composer.tasks.gear_assembly.env  # noqa: F401  (registers GearAssembly-v1)
from policy_composer.tasks.base import episode_limit  # noqa: F401  (the episode runs' step limit)
from policy_composer.tasks.gear_assembly.spec import EnvSettings


class Policy(Protocol):
    """Anything that gives the next flat 16-D action of GearAssembly-v1
    (see policy_composer.tasks.gear_assembly.env.ACTION_NAMES)."""

    name: str

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, obs) -> torch.Tensor: ...

    @property
    def done(self) -> bool: ...


def make_env(obs_mode: str, resolution: int = EnvSettings.resolution, clearance_mm: float = EnvSettings.clearance_mm,
             cameras: tuple[str, ...] | None = None, **kwargs):
    """GearAssembly-v1 with square cameras of `resolution` pixels (all three unless `cameras` names some)."""
    if cameras is not None:
        kwargs["cameras"] = tuple(cameras)
    return gym.make("GearAssembly-v1", obs_mode=obs_mode, camera_width=resolution, camera_height=resolution,
                    clearance=clearance_mm / 1000.0, **kwargs)


@dataclass
class EpisodeResult:
    seed: int
    success: bool
    steps: int
    stage: int
    frames: list[np.ndarray] = field(default_factory=list)


def tile_cameras(obs: dict, cameras: tuple[str, ...]) -> np.ndarray:
    """The camera images of env 0 side by side (H x (W * n) x 3, uint8)."""
    return np.concatenate([obs["sensor_data"][c]["rgb"][0].cpu().numpy() for c in cameras], axis=1)


def run_episode(env, policy: Policy, seed: int, max_steps: int | None = None, record_frames: bool = False,
                on_step: Callable[[int, dict], None] | None = None) -> EpisodeResult:
    """Reset with `seed`, run `policy` until it is done or `max_steps`, and report the final evaluation."""
    u = env.unwrapped
    obs, info = env.reset(seed=seed)
    policy.reset(seed)
    max_steps = max_steps or episode_limit(env)
    frames = [tile_cameras(obs, u.camera_names)] if record_frames else []
    steps = 0
    while steps < max_steps and not policy.done:
        obs, _, _, _, info = env.step(u.flat_to_dict_action(policy.act(obs)))
        steps += 1
        if record_frames:
            frames.append(tile_cameras(obs, u.camera_names))
        if on_step is not None:
            on_step(steps, info)
    return EpisodeResult(seed=seed, success=bool(info["success"][0]), steps=steps, stage=int(info["stage"][0]),
                         frames=frames)
