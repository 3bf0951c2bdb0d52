"""Train the selector's models from the recorded datasets into one world-model folder (see world_model.py).

- the VAE on the VAE camera's frames of the controller rollouts and the training full-task demos;
- one dynamics model per controller, on that controller's rollout frames only;
- one goal scorer per camera on the training full-task demos (the VAE camera's also on their reconstructions),
  and one on the VAE's latents of those demos;
- one classifier per task predicate on the labelled recordings (the controllers' senses), held-out episodes apart.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import torch

from policy_composer.data.features import DatasetError, image_key, read_sidecar
from policy_composer.data.frames import check_distinct, load_frames, to_model_image
from policy_composer.data.recipes import check_recipe
from policy_composer.learning.checkpoint import check_out, finished, model_writer, weights_id
from policy_composer.selector.configuration import (
    DynamicsConfig,
    GoalScoreConfig,
    LatentGoalScoreConfig,
    PredicateConfig,
    VAEConfig,
)
from policy_composer.selector.dynamics import train_dynamics
from policy_composer.selector.goal_score import train_goal_score, train_latent_goal_score
from policy_composer.selector.predicates import held_out, train_predicates
from policy_composer.selector.vae import VAE, load_vae, train_vae
from policy_composer.tasks.registry import DEFAULT_TASK, get_spec


def demo_split(root: str | Path, split: str) -> list[int]:
    """Episode indices of a full-task demo set's "train" or "heldout" split (its recipe's train_episodes)."""
    sidecar = read_sidecar(root)
    n = len(sidecar.get("episodes", []))
    if not n or not all(e["success"] for e in sidecar["episodes"]):
        recipe = get_spec(sidecar.get("task_name") or DEFAULT_TASK).full_task_demos
        raise DatasetError(f"{root} is not a set of successful full-task demonstrations (record {recipe})")
    k = sidecar.get("train_episodes") or n
    episodes = list(range(min(k, n))) if split == "train" else list(range(k, n))
    if not episodes:
        raise DatasetError(f"{root} has no {split!r} episodes ({n} episodes, the first {k} train)")
    return episodes


def train_world_model(rollouts: str | Path, demos: str | Path, out: str | Path, vae_config: VAEConfig | None = None,
                      dynamics_config: DynamicsConfig | None = None, controllers: list[str] | None = None,
                      reuse_vae: bool = False, progress: bool = True, resume: bool = False) -> dict[str, float]:
    """VAE, then every controller's dynamics model; returns the training time of each (s). With `reuse_vae`,
    the VAE already in `out` is kept (to add or retrain some controllers' dynamics models). With `resume`, every
    model already in `out` at its configuration (and with its VAE) is kept: a training cut short goes on where it
    stopped."""
    with model_writer(out):
        return _train_world_model(Path(out), rollouts, demos, vae_config, dynamics_config, controllers, reuse_vae,
                                  progress, resume)


def _train_world_model(out: Path, rollouts, demos, vae_config, dynamics_config, controllers, reuse_vae: bool,
                       progress: bool, resume: bool) -> dict[str, float]:
    kept = resume and vae_config is not None and finished(out / "vae", vae_config)
    vae = load_vae(out / "vae") if reuse_vae or kept else None
    vae_config = vae.config if vae is not None else vae_config or VAEConfig()  # a kept VAE keeps its camera
    dynamics_config = dynamics_config or DynamicsConfig()
    camera, size = vae_config.camera, vae_config.image_size
    spec = get_spec(vae_config.task)
    check_recipe(rollouts, spec.controller_rollouts, "the dynamics models")
    check_recipe(demos, spec.full_task_demos, "the VAE")
    recorded = read_sidecar(rollouts).get("controllers", [])
    unknown = [c for c in controllers or () if c not in recorded]
    if unknown:  # before any training: nothing would be trained for them
        raise DatasetError(f"{rollouts} holds no rollouts of {', '.join(unknown)}: --controllers takes the "
                           f"controllers it recorded, {', '.join(recorded) or 'none'}")
    if vae is None:
        check_out(out / "vae", VAEConfig)
    for name in controllers or recorded:
        check_out(out / "dynamics" / name, DynamicsConfig)
    ro = load_frames(rollouts, (camera,), size, required={"controller": (1,)}, progress=progress)
    timings = {}
    if vae is None:
        demo = load_frames(demos, (camera,), size, demo_split(demos, "train"), progress=progress)
        t0 = time.perf_counter()
        vae, _ = train_vae(torch.cat([ro[image_key(camera)], demo[image_key(camera)]]), vae_config, out / "vae",
                           progress)
        timings["vae"] = time.perf_counter() - t0
    elif kept:
        timings["vae"] = kept["seconds"]
    sidecar = read_sidecar(rollouts)
    names, models = sidecar["controllers"], sidecar.get("controller_models", {})
    vae_id = weights_id(out / "vae")
    latents = vae.latents(ro[image_key(camera)])
    for index, name in enumerate(names):
        if controllers is not None and name not in controllers:
            continue
        rows = (ro["controller"] == index).nonzero().flatten()
        config = replace(dynamics_config, controller=name, latent_dim=vae_config.latent_dim)
        parts = {"vae": vae_id, **({"controller": models[name]} if name in models else {})}
        if resume and (log := finished(out / "dynamics" / name, config, parts)):
            timings[f"dynamics {name}"] = log["seconds"]
            continue
        t0 = time.perf_counter()
        train_dynamics(latents[rows], ro[image_key(camera)][rows], ro["episode_index"][rows], config, vae,
                       out / "dynamics" / name, progress, parts)
        timings[f"dynamics {name}"] = time.perf_counter() - t0
    return timings


def train_goal_scores(demos: str | Path, out: str | Path, cameras: tuple[str, ...],
                      config: GoalScoreConfig | None = None, progress: bool = True,
                      resume: bool = False) -> dict[str, float]:
    """One goal scorer per camera on the training demos; returns the training time of each (s). The VAE in
    `out/vae`, if there is one, adds its reconstructions to its own camera's training images, and a goal scorer of
    its latents is trained too (`goal_score/latent`). With `resume`, a goal scorer already in `out` at its
    configuration is kept."""
    with model_writer(out):
        return _train_goal_scores(Path(out), demos, cameras, config or GoalScoreConfig(), progress, resume)


def _train_goal_scores(out: Path, demos, cameras: tuple[str, ...], config: GoalScoreConfig, progress: bool,
                       resume: bool) -> dict[str, float]:
    for camera in cameras:
        check_out(out / "goal_score" / camera, GoalScoreConfig)
    check_recipe(demos, get_spec(config.task).full_task_demos, "the goal score")
    frames = load_frames(demos, cameras, config.image_size, demo_split(demos, "train"),
                         required={"progress": (1,)}, progress=progress)
    vae = load_vae(out / "vae") if (out / "vae" / "config.json").is_file() else None
    vae_id = weights_id(out / "vae") if vae is not None else None
    timings = {}
    for camera in cameras:
        images, target = frames[image_key(camera)], frames["progress"]
        with_vae = vae is not None and vae.config.camera == camera
        parts = {"vae": vae_id} if with_vae else {}
        path, camera_config = out / "goal_score" / camera, replace(config, camera=camera)
        if resume and (log := finished(path, camera_config, parts)):
            timings[f"goal score {camera}"] = log["seconds"]
            continue
        if with_vae:
            images, target = torch.cat([images, reconstructions(vae, images)]), torch.cat([target, target])
        t0 = time.perf_counter()
        train_goal_score(images, target, camera_config, path, progress, parts)
        timings[f"goal score {camera}"] = time.perf_counter() - t0
    if vae is None:
        return timings
    path, parts = out / "goal_score" / "latent", {"vae": vae_id}
    latent_config = LatentGoalScoreConfig(latent_dim=vae.config.latent_dim, seed=config.seed)
    if resume and (log := finished(path, latent_config, parts)):
        timings["goal score latent"] = log["seconds"]
        return timings
    camera = vae.config.camera
    images = frames[image_key(camera)] if camera in cameras else \
        load_frames(demos, (camera,), vae.config.image_size, demo_split(demos, "train"), progress=progress)[
            image_key(camera)]
    t0 = time.perf_counter()
    train_latent_goal_score(*posteriors(vae, images), frames["progress"], latent_config, path, progress, parts)
    timings["goal score latent"] = time.perf_counter() - t0
    return timings


def train_predicate_models(datasets: list[str | Path], out: str | Path, config: PredicateConfig | None = None,
                           progress: bool = True, resume: bool = False) -> dict[str, dict]:
    """One classifier per predicate on the labelled recordings `datasets` (every fifth episode of each held out);
    returns each one's held-out figures and training time (s)."""
    config = config or PredicateConfig()
    check_distinct(datasets)
    with model_writer(out):
        spec = get_spec(config.task)
        scene = ("observation.environment_state",) if spec.scene_names else ()
        frames = [load_frames(d, config.cameras, config.image_size,
                              required={"predicates": (len(spec.predicates),), "observation.state": None,
                                        **{k: (len(spec.scene_names),) for k in scene}},
                              progress=progress) for d in datasets]
        keys = (*(image_key(c) for c in config.cameras), "observation.state", *scene, "predicates")
        joined = {k: torch.cat([f[k] for f in frames]) for k in keys}
        joined["held_out"] = torch.cat([held_out(f["episode_index"]) for f in frames])
        return train_predicates(joined, out, config, progress=progress, resume=resume)


@torch.no_grad()
def posteriors(vae: VAE, images_uint8: torch.Tensor, batch: int = 256) -> tuple[torch.Tensor, torch.Tensor]:
    """The VAE's q(z | image) of uint8 images at any size: means and log-variances, (N, L) each."""
    parts = [vae.encode(to_model_image(images_uint8[i:i + batch].float() / 255.0, vae.config.image_size))
             for i in range(0, len(images_uint8), batch)]
    return torch.cat([m for m, _ in parts]), torch.cat([v for _, v in parts])


@torch.no_grad()
def reconstructions(vae: VAE, images_uint8: torch.Tensor, batch: int = 256) -> torch.Tensor:
    """The VAE's decoding of each image's posterior mean, uint8 at the images' size."""
    mean, _ = posteriors(vae, images_uint8, batch)
    return torch.cat([(to_model_image(vae.decode(mean[i:i + batch]), images_uint8.shape[-1]) * 255).round().to(
        torch.uint8) for i in range(0, len(mean), batch)])
