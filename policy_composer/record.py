"""Record a recipe's dataset: make the env, drive it with the recipe's driver, keep the episodes it asks for."""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, replace
from pathlib import Path

from policy_composer.data import interrupt, journal
from policy_composer.data.features import read_sidecar
from policy_composer.data.recipes import Recipe, RecipeError
from policy_composer.policies.library import LibrarySources, all_names, build_library, cameras_needed, model_ids
from policy_composer.tasks.rollout import make_env
from policy_composer.tasks.spec import EXPERT_PHASES, EnvSettings


def recipe_controllers(recipe: Recipe) -> tuple[str, ...]:
    """The controllers a "controllers" recipe runs: the ones it names, or every registered kind's."""
    return (recipe.controllers or all_names()) if recipe.driver == "controllers" else ()


def record_recipe(recipe: Recipe, root: str | Path, episodes: int | None = None, seed: int | None = None,
                  resume: bool = False, settings: EnvSettings | None = None, progress: bool = True,
                  sources: LibrarySources | None = None) -> dict:
    """Record until the dataset at `root` holds `episodes` episodes (per controller, for the "controllers"
    driver); returns its sidecar (seeds, success, ...).

    With `resume`, an existing dataset is continued with its own env settings and models, from the seed after the
    last one it tried; an episode interrupted mid-way is simply recorded again. A `seed`, `settings` or model
    that contradicts the dataset's is refused. `sources` says where the library's trained models are (the
    "controllers" driver).
    """
    import torch
    from tqdm import tqdm

    from policy_composer.data.recorder import LeRobotRecorder

    torch.set_num_threads(1)  # the encoder threads need the second core
    root = Path(root)
    sources = sources or LibrarySources()
    controllers = recipe_controllers(recipe)
    models = model_ids(controllers, sources)
    per_unit = episodes if episodes is not None else recipe.episodes
    if resume:
        journal.recover(root)  # before reading the sidecar: an interrupted save may have written it already
    previous = read_sidecar(root) if resume else {}
    if previous:
        check_resume(root, previous, recipe, seed, settings, models)
        settings, seed = EnvSettings(**previous["env"]), previous["next_seed"]
    settings, seed = settings or EnvSettings(), seed or 0
    needed = cameras_needed(controllers, sources)
    if not previous:  # the recipe's cameras, and any others its controllers read
        settings = replace(settings, cameras=tuple(dict.fromkeys((*recipe.cameras, *needed))))
    # A resumed dataset keeps its cameras; a controller added to it may read more, which are rendered, not recorded.
    rendered = tuple(dict.fromkeys((*settings.cameras, *needed)))
    env = make_env("rgb", settings.resolution, settings.clearance_mm, rendered)
    recorder = LeRobotRecorder(env, root, task=recipe.task, resume=resume, cameras=settings.cameras,
                               metadata={"recipe": recipe.name, "env": asdict(settings), "controller_models": models,
                                         "expert": asdict(recipe.expert), "train_episodes": recipe.train_episodes})
    recorded = Counter(e.get("controller_name") for e in recorder.episodes)  # per controller, when resuming
    if recipe.driver == "controllers":  # a controller with more episodes than asked for counts only what was asked
        total, done = per_unit * len(controllers), sum(min(recorded[n], per_unit) for n in controllers)
    else:
        total, done = per_unit, min(recorder.num_episodes, per_unit)
    bar = tqdm(total=total, initial=done, desc=recipe.name, unit="episode", disable=not progress)
    try:
        if recipe.driver == "controllers":
            library = build_library(recorder, controllers, sources)
            for name in controllers:
                seed = _record_controller(recorder, library[name], recorded[name], per_unit, seed, bar)
        else:
            _record_expert(recipe, recorder, per_unit, seed, bar)
    finally:
        bar.close()
        env.close()
    return recorder.sidecar


def check_resume(root: Path, previous: dict, recipe: Recipe, seed: int | None, settings: EnvSettings | None,
                 models: dict[str, str]) -> None:
    """Refuse to continue a dataset with another recipe, seed, env setting or controller model than its own."""
    if previous.get("recipe") != recipe.name:
        raise RecipeError(f"{root} was recorded from recipe {previous.get('recipe')!r}, not {recipe.name!r}")
    ours = asdict(settings) if settings is not None else {}
    ours.pop("cameras", None)  # the recipe's and its controllers' cameras, not a setting of the run
    clash = [f"{k} {ours[k]} (it has {v})" for k, v in previous["env"].items() if k in ours and ours[k] != v]
    if seed is not None and seed != previous["next_seed"]:
        clash.append(f"first seed {seed} (it continues from seed {previous['next_seed']})")
    clash += [f"another {name} model ({model}, it has {previous.get('controller_models', {}).get(name)})"
              for name, model in models.items() if previous.get("controller_models", {}).get(name, model) != model]
    if clash:
        raise RecipeError(f"--resume continues {root} with its own settings, but this run asks for "
                          f"{'; '.join(clash)}: give the dataset's own (or leave them out), or record into a new "
                          f"--root")


def _save(recorder, bar, success: bool, seed: int, **info) -> None:
    recorder.sidecar["next_seed"] = seed + 1
    recorder.save_episode(success, seed=seed, **info)
    bar.update()
    bar.set_postfix(seed=seed, frames=recorder.episodes[-1]["length"])
    interrupt.check()


def _record_expert(recipe: Recipe, recorder, target: int, seed: int, bar) -> None:
    """The scripted expert from each seed's reset, recording the recipe's phases."""
    from policy_composer.tasks.gear_expert import ExpertConfig, GearAssemblyExpert
    from policy_composer.tasks.rollout import episode_limit

    expert = GearAssemblyExpert(recorder, ExpertConfig(grasp_offset=recipe.expert.grasp_offset_mm / 1000.0,
                                                       teleop=recipe.expert.teleop,
                                                       arrival_error=recipe.expert.arrival_error_mm / 1000.0))
    limit, attempts = episode_limit(recorder), 0
    # The episode ends once the expert has left the last phase the recipe records.
    last = max(map(EXPERT_PHASES.index, recipe.record_phases), default=len(EXPERT_PHASES) - 1)
    while recorder.num_episodes < target:
        attempts += 1
        if attempts > 3 * target + 5:
            raise RuntimeError(f"{recipe.name}: too few episodes succeed ({recorder.num_episodes} kept after "
                               f"{attempts - 1} attempts); check the env settings")
        obs, _ = recorder.reset(seed=seed, options={"start": recipe.start,
                                                    "grasp_offset_max": recipe.expert.grasp_offset_mm / 1000.0})
        expert.reset(seed)
        recorder.controller = expert.name
        info = None
        for _ in range(limit):
            if expert.done or EXPERT_PHASES.index(expert.phase) > last:
                break
            recorder.recording = not recipe.record_phases or expert.phase in recipe.record_phases
            obs, _, _, _, info = recorder.step(expert.act(obs))
        success = info is not None and bool(info[recipe.goal][0])
        if recorder.buffered_frames == 0 or (recipe.keep == "success" and not success):
            recorder.discard_episode()
        else:
            _save(recorder, bar, success, seed, grasp_offset_mm=round(expert.grasp_offset * 1000, 3))
        seed += 1


def _record_controller(recorder, controller, done: int, target: int, seed: int, bar) -> int:
    """Activations of one controller until it has `target` (`done` are recorded already), each from a start state
    inside its initiation set (the open-loop expert run, unrecorded, up to where the controller's subtask begins);
    failures are kept. Returns the next seed."""
    from policy_composer.controller_table import start_state
    from policy_composer.policies.arm import run_activation

    while done < target:
        recorder.recording = False
        obs = start_state(recorder, seed, controller.subtask.name)
        recorder.recording = True
        recorder.controller = controller.name
        run_activation(recorder, controller, obs, seed)
        if recorder.buffered_frames == 0:
            recorder.discard_episode()
        else:
            _save(recorder, bar, controller.outcome.value == "done", seed, controller_name=controller.name,
                  outcome=controller.outcome.value)
            done += 1
        seed += 1
    return seed
