"""Record a recipe's dataset: make the env, drive it with the recipe's driver, keep the episodes it asks for."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from policy_composer.recording import journal
from policy_composer.recording.features import read_sidecar
from policy_composer.recording.recipes import Recipe, RecipeError


@dataclass(frozen=True)
class EnvSettings:
    resolution: int = 128
    clearance_mm: float = 2.0


def make_recording_env(settings: EnvSettings):
    import gymnasium as gym

    import tasks  # noqa: F401  (registers GearAssembly-v1)

    return gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=settings.resolution,
                    camera_height=settings.resolution, clearance=settings.clearance_mm / 1000.0)


def _driver(recipe: Recipe, env):
    if recipe.driver == "controllers":
        raise RecipeError(f"recipe {recipe.name} records the controllers of the library ({', '.join(recipe.controllers)}), "
                          f"and the library has none of them yet; record the expert recipes for now")
    from tasks.gear_expert import ExpertConfig, GearAssemblyExpert

    return GearAssemblyExpert(env, ExpertConfig(grasp_offset=recipe.expert.grasp_offset_mm / 1000.0,
                                                teleop=recipe.expert.teleop))


def record_recipe(recipe: Recipe, root: str | Path, episodes: int | None = None, seed: int = 0, resume: bool = False,
                  settings: EnvSettings | None = None, progress: bool = True) -> dict:
    """Record until the dataset at `root` holds `episodes` episodes; returns its sidecar (seeds, success, ...).

    With `resume`, an existing dataset is continued with its own env settings and the seed after the last
    one it tried; an episode interrupted mid-way is simply recorded again.
    """
    import torch
    from tqdm import tqdm

    from policy_composer.recording.recorder import LeRobotRecorder
    from policy_composer.rollout import episode_limit

    torch.set_num_threads(1)  # the encoder threads need the second core
    root = Path(root)
    target = episodes if episodes is not None else recipe.episodes
    if resume:
        journal.recover(root)  # before reading the sidecar: an interrupted save may have written it already
    previous = read_sidecar(root) if resume else {}
    if previous:
        if previous.get("recipe") != recipe.name:
            raise RecipeError(f"{root} was recorded from recipe {previous.get('recipe')!r}, not {recipe.name!r}")
        settings = EnvSettings(**previous["env"])
        seed = previous["next_seed"]
    settings = settings or EnvSettings()
    env = make_recording_env(settings)
    recorder = LeRobotRecorder(env, root, task=recipe.task, resume=resume,
                               metadata={"recipe": recipe.name, "env": asdict(settings),
                                         "expert": asdict(recipe.expert), "train_episodes": recipe.train_episodes})
    driver = _driver(recipe, recorder)
    limit = episode_limit(env)
    bar = tqdm(total=target, initial=min(recorder.num_episodes, target), desc=recipe.name, unit="episode",
               disable=not progress)
    attempts = 0
    try:
        while recorder.num_episodes < target:
            attempts += 1
            if attempts > 3 * target + 5:
                raise RuntimeError(f"{recipe.name}: too few episodes succeed ({recorder.num_episodes} kept after "
                                   f"{attempts - 1} attempts); check the env settings {settings}")
            obs, _ = recorder.reset(seed=seed)
            driver.reset(seed)
            recorder.controller = driver.name
            info = None
            for _ in range(limit):
                if driver.done:
                    break
                recorder.recording = not recipe.record_phases or driver.phase in recipe.record_phases
                obs, _, _, _, info = recorder.step(driver.act(obs))
            success = info is not None and bool(info["success"][0])
            seed += 1
            if recorder.buffered_frames == 0 or (recipe.keep == "success" and not success):
                recorder.discard_episode()
                continue
            recorder.sidecar["next_seed"] = seed
            recorder.save_episode(success, seed=seed - 1, grasp_offset_mm=round(driver.grasp_offset * 1000, 3))
            bar.update()
            bar.set_postfix(seed=seed - 1, frames=recorder.episodes[-1]["length"])
    finally:
        bar.close()
        env.close()
    return recorder.sidecar
