"""Train the selector's models from the recorded datasets into one world-model folder (see world_model.py).

- the VAE on the VAE camera's frames of the controller rollouts and the training full-task demos;
- one dynamics model per controller, on that controller's rollout frames only;
- one goal scorer per camera on the training full-task demos (the VAE camera's also on their reconstructions).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import torch

from policy_composer.data.features import DatasetError, image_key, read_sidecar
from policy_composer.data.frames import load_frames
from policy_composer.data.recipes import check_recipe
from policy_composer.learning.checkpoint import weights_id
from policy_composer.selector.configuration import DynamicsConfig, GoalScoreConfig, VAEConfig
from policy_composer.selector.dynamics import train_dynamics
from policy_composer.selector.goal_score import train_goal_score
from policy_composer.selector.vae import VAE, load_vae, train_vae


def demo_split(root: str | Path, split: str) -> list[int]:
    """Episode indices of a full-task demo set's "train" or "heldout" split (its recipe's train_episodes)."""
    sidecar = read_sidecar(root)
    n = len(sidecar.get("episodes", []))
    if not n or not all(e["success"] for e in sidecar["episodes"]):
        raise DatasetError(f"{root} is not a set of successful full-task demonstrations (record gear-full-task-demos)")
    k = sidecar.get("train_episodes") or n
    episodes = list(range(min(k, n))) if split == "train" else list(range(k, n))
    if not episodes:
        raise DatasetError(f"{root} has no {split!r} episodes ({n} episodes, the first {k} train)")
    return episodes


def train_world_model(rollouts: str | Path, demos: str | Path, out: str | Path, vae_config: VAEConfig | None = None,
                      dynamics_config: DynamicsConfig | None = None, controllers: list[str] | None = None,
                      reuse_vae: bool = False, progress: bool = True) -> dict[str, float]:
    """VAE, then every controller's dynamics model; returns the training time of each (s). With `reuse_vae`,
    the VAE already in `out` is kept (to add or retrain some controllers' dynamics models)."""
    out = Path(out)
    vae = load_vae(out / "vae") if reuse_vae else None
    vae_config = vae.config if vae is not None else vae_config or VAEConfig()  # a kept VAE keeps its camera
    dynamics_config = dynamics_config or DynamicsConfig()
    camera, size = vae_config.camera, vae_config.image_size
    check_recipe(rollouts, "gear-controller-rollouts", "the dynamics models")
    check_recipe(demos, "gear-full-task-demos", "the VAE")
    ro = load_frames(rollouts, (camera,), size, required={"controller": (1,)}, progress=progress)
    timings = {}
    if vae is None:
        demo = load_frames(demos, (camera,), size, demo_split(demos, "train"), progress=progress)
        t0 = time.perf_counter()
        vae, _ = train_vae(torch.cat([ro[image_key(camera)], demo[image_key(camera)]]), vae_config, out / "vae",
                           progress)
        timings["vae"] = time.perf_counter() - t0
    sidecar = read_sidecar(rollouts)
    names, models = sidecar["controllers"], sidecar.get("controller_models", {})
    vae_id = weights_id(out / "vae")
    latents = vae.latents(ro[image_key(camera)])
    for index, name in enumerate(names):
        if controllers is not None and name not in controllers:
            continue
        rows = (ro["controller"] == index).nonzero().flatten()
        config = replace(dynamics_config, controller=name, latent_dim=vae_config.latent_dim)
        t0 = time.perf_counter()
        parts = {"vae": vae_id, **({"controller": models[name]} if name in models else {})}
        train_dynamics(latents[rows], ro[image_key(camera)][rows], ro["episode_index"][rows], config, vae,
                       out / "dynamics" / name, progress, parts)
        timings[f"dynamics {name}"] = time.perf_counter() - t0
    return timings


def train_goal_scores(demos: str | Path, out: str | Path, cameras: tuple[str, ...],
                      config: GoalScoreConfig | None = None, progress: bool = True) -> dict[str, float]:
    """One goal scorer per camera on the training demos; returns the training time of each (s). The VAE in
    `out/vae`, if there is one, adds its reconstructions to its own camera's training images."""
    out = Path(out)
    config = config or GoalScoreConfig()
    check_recipe(demos, "gear-full-task-demos", "the goal score")
    frames = load_frames(demos, cameras, config.image_size, demo_split(demos, "train"),
                         required={"progress": (1,)}, progress=progress)
    vae = load_vae(out / "vae") if (out / "vae" / "config.json").is_file() else None
    timings = {}
    for camera in cameras:
        images, target, parts = frames[image_key(camera)], frames["progress"], {}
        if vae is not None and vae.config.camera == camera:
            images, target = torch.cat([images, reconstructions(vae, images)]), torch.cat([target, target])
            parts = {"vae": weights_id(out / "vae")}
        t0 = time.perf_counter()
        train_goal_score(images, target, replace(config, camera=camera), out / "goal_score" / camera, progress,
                         parts)
        timings[f"goal score {camera}"] = time.perf_counter() - t0
    return timings


@torch.no_grad()
def reconstructions(vae: VAE, images_uint8: torch.Tensor, batch: int = 256) -> torch.Tensor:
    """The VAE's decoding of each image's posterior mean, uint8 at the images' size."""
    from policy_composer.data.frames import to_model_image

    parts = []
    for i in range(0, len(images_uint8), batch):
        z = vae.encode(to_model_image(images_uint8[i:i + batch].float() / 255.0, vae.config.image_size))[0]
        parts.append((to_model_image(vae.decode(z), images_uint8.shape[-1]) * 255).round().to(torch.uint8))
    return torch.cat(parts)
