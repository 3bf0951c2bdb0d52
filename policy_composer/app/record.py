"""Record a recipe's dataset: episodes run in one or more processes, each with its own env and the recipe's driver,
and this process writes the ones the recipe keeps into one LeRobot dataset, in the order of their seeds.

An episode depends on its seed only, and the seeds are handed out in rounds of as many as are still wanted, so any
number of workers writes the dataset the serial loop writes, episode for episode; each episode is saved as soon
as it and those of lower seeds are in, so an interrupted recording keeps them all and `--resume` goes on from there.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path

import torch
from tqdm import tqdm

from policy_composer.app.starts import expert_until, start_state
from policy_composer.app.workers import Workers
from policy_composer.data import interrupt, journal
from policy_composer.data.features import read_sidecar
from policy_composer.data.lock import one_writer
from policy_composer.data.recipes import Recipe, RecipeError
from policy_composer.data.recorder import FrameBuffer, LeRobotWriter
from policy_composer.policies.arm import run_activation
from policy_composer.policies.library import (
    LibrarySources,
    all_names,
    build_library,
    cameras_needed,
    check_models,
    model_ids,
)
from policy_composer.tasks.base import episode_limit
from policy_composer.tasks.registry import get_task


@dataclass
class RecordedEpisode:
    """What a worker sends back: the frames to write, and the episode's entry in the dataset's sidecar."""

    seed: int
    frames: list[dict]
    success: bool
    info: dict


def recipe_controllers(recipe: Recipe) -> tuple[str, ...]:
    """The controllers a recipe runs: the ones it names, or for the "controllers" driver every registered kind's."""
    every = all_names(LibrarySources(task=recipe.task_name))
    return (recipe.controllers or every) if recipe.driver == "controllers" else recipe.controllers


def record_recipe(recipe: Recipe, root: str | Path, episodes: int | None = None, seed: int | None = None,
                  resume: bool = False, settings=None, progress: bool = True,
                  sources: LibrarySources | None = None, workers: int = 1) -> dict:
    """Record until the dataset at `root` holds `episodes` episodes (per controller, for the "controllers"
    driver); returns its sidecar (seeds, success, ...).

    With `resume`, an existing dataset is continued with its own env settings and models, from the seed after the
    last one it tried; an episode interrupted mid-way is simply recorded again. A `seed`, `settings` or model
    that contradicts the dataset's is refused. `sources` says where the library's trained models are (the
    "controllers" driver). The episodes run on `workers` processes; the dataset is the same for any number.
    """
    torch.set_num_threads(1)  # the encoder threads need the second core
    root = Path(root)
    with one_writer(root):  # a second recording into it stops at once
        sources = sources or LibrarySources(task=recipe.task_name)
        if sources.task != recipe.task_name:
            raise RecipeError(f"recipe {recipe.name} records {recipe.task_name}, but its controllers' models are "
                              f"given for {sources.task}: give the models of {recipe.task_name}'s library")
        controllers = recipe_controllers(recipe)
        check_models(controllers, sources)
        models = model_ids(controllers, sources)
        per_unit = episodes if episodes is not None else recipe.episodes
        if resume:
            journal.recover(root)  # before reading the sidecar: an interrupted save may have written it already
        previous = read_sidecar(root) if resume else {}
        if previous:
            check_resume(root, previous, recipe, seed, settings, models)
            settings, seed = recipe.spec.env_settings(**previous["env"]), previous["next_seed"]
        settings, seed = settings or recipe.spec.env_settings(), seed or 0
        first_seed = first_seed_of(previous) if previous else None
        first_seed = seed if first_seed is None else first_seed
        needed = cameras_needed(controllers, sources)
        if not previous:  # the recipe's cameras, and any others its controllers read
            settings = replace(settings, cameras=tuple(dict.fromkeys((*recipe.cameras, *needed))))
        writer = LeRobotWriter(root, recipe.task, recipe.spec.control_freq, settings.resolution, settings.cameras,
                               resume=resume, task_name=recipe.task_name,
                               metadata={"recipe": recipe.name, "task_name": recipe.task_name, "env": asdict(settings),
                                         "first_seed": first_seed, "controller_models": models,
                                         "expert": asdict(recipe.expert), "train_episodes": recipe.train_episodes})
        recorded = Counter(e.get("controller_name") for e in writer.episodes)  # per controller, when resuming
        units = controllers if recipe.driver == "controllers" else (None,)
        done = {u: min(recorded[u] if u else writer.num_episodes, per_unit) for u in units}
        setup = partial(EpisodeRecorder, recipe, settings, sources, controllers)
        total, initial = per_unit * len(units), sum(done.values())
        with tqdm(total=total, initial=initial, desc=recipe.name, unit="episode", disable=not progress) as bar, \
                Workers(setup, min(workers, max(total - initial, 1))) as pool:
            for unit in units:
                # The expert's episodes that fail are dropped (the recipe keeps successes): give up when most do.
                attempts = None if unit else 3 * per_unit + 5
                seed = _record_unit(pool, writer, unit, done[unit], per_unit, seed, attempts, partial(_saved, bar))
        return writer.sidecar


def check_resume(root: Path, previous: dict, recipe: Recipe, seed: int | None, settings,
                 models: dict[str, str]) -> None:
    """Refuse to continue a dataset with another recipe, seed, env setting or controller model than its own."""
    if previous.get("recipe") != recipe.name:
        raise RecipeError(f"{root} was recorded from recipe {previous.get('recipe')!r}, not {recipe.name!r}")
    ours = asdict(settings) if settings is not None else {}
    ours.pop("cameras", None)  # the recipe's and its controllers' cameras, not a setting of the run
    clash = [f"{k} {ours[k]} (it has {v})" for k, v in previous["env"].items() if k in ours and ours[k] != v]
    if seed is not None and seed not in (first_seed_of(previous), previous["next_seed"]):  # the command that began it
        clash.append(f"first seed {seed} (it began at seed {first_seed_of(previous)} and continues from seed "
                     f"{previous['next_seed']})")
    clash += [f"another {name} model ({model}, it has {previous.get('controller_models', {}).get(name)})"
              for name, model in models.items() if previous.get("controller_models", {}).get(name, model) != model]
    if clash:
        raise RecipeError(f"--resume continues {root} with its own settings, but this run asks for "
                          f"{'; '.join(clash)}: give the dataset's own (or leave them out), or record into a new "
                          f"--root")


def first_seed_of(sidecar: dict) -> int | None:
    """The seed a recording began at (its first episode's, for datasets recorded before it was kept)."""
    if "first_seed" in sidecar:
        return sidecar["first_seed"]
    return min((e["seed"] for e in sidecar.get("episodes", []) if "seed" in e), default=None)


def _record_unit(pool, writer, unit: str | None, done: int, target: int, seed: int, attempts: int | None,
                 saved: Callable) -> int:
    """Episodes of one controller (or of the expert, `unit` None) from consecutive seeds until `target` are kept,
    each saved once the seeds before it are in; returns the next seed."""
    tried = 0
    while done < target:
        items = [(unit, s) for s in range(seed, seed + target - done)]
        for (_, s), episode in pool.imap(items):
            tried, seed = tried + 1, s + 1
            if episode is not None:
                writer.sidecar["next_seed"] = seed
                writer.save_episode(episode.frames, episode.success, seed=s, **episode.info)
                done += 1
                saved(writer, s)
            if attempts is not None and tried >= attempts and done < target:
                raise RuntimeError(f"{writer.sidecar['recipe']}: too few episodes succeed ({writer.num_episodes} kept "
                                   f"after {tried} attempts); check the env settings")
    return seed


def _saved(bar, writer, seed: int) -> None:
    bar.update()
    bar.set_postfix(seed=seed, frames=writer.episodes[-1]["length"])
    interrupt.check()


class EpisodeRecorder:
    """A recipe's episodes in one process: the env (with the recipe's cameras and any its controllers read) and the
    driver, built once. Called with (controller name or None for the expert, seed), runs that episode and returns
    what the recipe keeps of it, or None."""

    def __init__(self, recipe: Recipe, settings, sources: LibrarySources, controllers: tuple[str, ...]):
        task = get_task(recipe.task_name)
        # A resumed dataset keeps its cameras; a controller added to it may read more: rendered, not recorded.
        rendered = tuple(dict.fromkeys((*settings.cameras, *cameras_needed(controllers, sources))))
        self.buffer = FrameBuffer(task.make_env("rgb", settings, rendered), settings.cameras)
        self.recipe = recipe
        if recipe.driver != "expert":
            self.library = build_library(self.buffer, controllers, sources)
        if recipe.driver != "controllers":
            self.expert = task.expert(self.buffer, recipe.expert.config())

    def __call__(self, item: tuple[str | None, int]) -> RecordedEpisode | None:
        name, seed = item
        if name:
            return self._controller(self.library[name], seed)
        return self._dagger(seed) if self.recipe.driver == "dagger" else self._expert(seed)

    def close(self) -> None:
        self.buffer.close()

    def _expert(self, seed: int) -> RecordedEpisode | None:
        """The scripted expert from the seed's reset, recording the recipe's phases."""
        recipe, buffer, expert = self.recipe, self.buffer, self.expert
        phases = recipe.spec.expert_phases
        obs, _ = buffer.reset(seed=seed, options=recipe.reset_options())
        expert.reset(seed)
        buffer.controller = expert.name
        info = None
        # The episode ends once the expert has left the last phase the recipe records, or is done and has held
        # still for the recipe's hold_steps.
        last = max(map(phases.index, recipe.record_phases), default=len(phases) - 1)
        held = 0
        for _ in range(episode_limit(buffer)):
            if phases.index(expert.phase) > last:
                break
            if expert.done:
                if held >= recipe.hold_steps:
                    break
                held += 1
            buffer.recording = not recipe.record_phases or expert.phase in recipe.record_phases
            label = expert.act(obs)
            obs, _, _, _, info = buffer.step(expert.executed, label=label)
        success = info is not None and bool(info[recipe.goal][0])
        if buffer.buffered_frames == 0 or (recipe.keep == "success" and not success):
            buffer.discard_episode()
            return None
        return RecordedEpisode(seed, buffer.take_episode(), success,
                               {"grasp_offset_mm": round(expert.grasp_offset * 1000, 3)})

    def _dagger(self, seed: int) -> RecordedEpisode | None:
        """The recipe's controller acting from its subtask's start state, each frame labelled with the command the
        scripted expert gives in that state. The episode ends where the activation does, with the frame it ended in
        (where the policy's command collided, say); a back-off is left out after its first step, since the
        controller does not choose it (its guard does)."""
        recipe, buffer, expert = self.recipe, self.buffer, self.expert
        controller = self.library[recipe.controllers[0]]
        obs, _ = buffer.reset(seed=seed, options=recipe.reset_options())
        expert.reset(seed)
        phase = buffer.task.expert_starts.get(controller.subtask.name)
        if phase is not None:  # the expert takes the arm, unrecorded, to where the controller's subtask starts
            if not expert_until(buffer, expert, phase, episode_limit(buffer)):
                return None
            obs = buffer.observe()
        if not controller.can_start(obs):  # a start outside its initiation set, which no selector would run it from
            return None
        controller.start(obs, seed=seed)
        buffer.controller = controller.name
        for _ in range(episode_limit(buffer)):
            label = expert.act(obs)
            obs, *_ = buffer.step(controller.act(obs), label=label)
            if controller.done(obs) or controller.backing_off or expert.done:
                break
        # The expert done: the policy reached the subtask's goal, as the expert judges it, before it terminated.
        outcome = "failed" if controller.backing_off else "done" if expert.done else controller.outcome.value
        if buffer.buffered_frames == 0 or (recipe.keep == "success" and outcome != "done"):
            buffer.discard_episode()
            return None
        return RecordedEpisode(seed, buffer.take_episode(), outcome == "done",
                               {"outcome": outcome, "reason": controller.backing_off or controller.reason,
                                "grasp_offset_mm": round(expert.grasp_offset * 1000, 3)})

    def _controller(self, controller, seed: int) -> RecordedEpisode | None:
        """One activation of `controller` from a start state inside its initiation set (the open-loop expert run,
        unrecorded, up to where the controller's subtask begins); failures are kept."""
        buffer = self.buffer
        buffer.recording = False
        obs = start_state(buffer, seed, controller.subtask.name)
        buffer.recording = True
        buffer.controller = controller.name
        run_activation(buffer, controller, obs, seed)
        if buffer.buffered_frames == 0:
            buffer.discard_episode()
            return None
        return RecordedEpisode(seed, buffer.take_episode(), controller.outcome.value == "done",
                               {"controller_name": controller.name, "outcome": controller.outcome.value})
