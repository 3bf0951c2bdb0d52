"""The controller library of a task: every controller by name, built from its trained models.

Names are `KIND_SUBTASK` (mp_pick, dmp_move, cnn_insert, ...) for the registered kinds (`registry`), plus one
controller per LeRobot checkpoint the user brings. The selector, Table I and the dataset recipes all build their
controllers here, so a name means the same controller everywhere. The names and the models' sources are in
`sources`, which the command line reads without building anything.
"""

from __future__ import annotations

from pathlib import Path

from policy_composer.learning.checkpoint import weights_id
from policy_composer.policies.base import Controller
from policy_composer.policies.registry import LibraryError, kind_of, kind_of_source
from policy_composer.policies.senses import OracleSenses, Senses
from policy_composer.policies.sources import (
    MODELS,
    LeRobotSource,
    LibrarySources,
    all_names,
    names_of_kind,
    subtask_of,
)

# Bumped when the controllers behave differently, so that stored runs of the old ones are not reused (CHANGELOG.md
# says what each revision changed).
LIBRARY_REVISION = 18

__all__ = ["LIBRARY_REVISION", "MODELS", "LeRobotSource", "LibraryError", "LibrarySources", "all_names",
           "build_library", "cameras_needed", "check_models", "model_ids", "names_of_kind", "subtask_of"]


class _Models:
    """Each kind's trained model, loaded once however many of its controllers are built."""

    def __init__(self, sources: LibrarySources):
        self.sources, self.loaded = sources, {}

    def __getitem__(self, kind) -> object:
        if not kind.trained:
            return None
        if kind.name not in self.loaded:
            self.loaded[kind.name] = kind.function("load")(self.sources.model_path(kind.name))
        return self.loaded[kind.name]


def cameras_needed(names, sources: LibrarySources) -> tuple[str, ...]:
    """The cameras the named controllers read (an env must render them)."""
    models, cameras = _Models(sources), []
    for kind in dict.fromkeys(k for k in map(kind_of, names) if k is not None and k.trained and k.function("cameras")):
        cameras += kind.function("cameras")(models[kind])
    for source in sources.lerobot:
        if source.controller_name in names:
            cameras += kind_of_source(source).function("cameras")(source)
    return tuple(dict.fromkeys(cameras))


def model_ids(names, sources: LibrarySources) -> dict[str, str]:
    """The trained model each named controller runs, by `weights_id`, and the insertion of a planned one that does
    not feel for the hole (controllers with neither are left out): recorded with its rollouts, so that a dynamics
    model is never paired with another controller (`check_models` first: a model missing or damaged has no id)."""
    lerobot = {s.controller_name: s.path for s in sources.lerobot}
    ids = {}
    for name in names:
        kind = kind_of(name)
        path = lerobot.get(name) or (sources.model_path(kind.name) if kind is not None else None)
        if path is not None and kind is not None:  # a folder with one model per subtask: the subtask's own
            own = Path(path) / name.removeprefix(f"{kind.name}_")
            path = own if own.is_dir() else path
        if path is not None and Path(path).is_dir():
            ids[name] = weights_id(path)
        planned_insert = kind is not None and kind.planned and name == f"{kind.name}_insert"
        if planned_insert and sources.insertion != next(iter(sources.description.insertions)):  # not the default
            ids[name] = f"{ids.get(name, kind.name)}, {sources.insertion} insertion"
    return ids


def check_models(names, sources: LibrarySources) -> None:
    """Load the trained model of each named controller's kind: one that is missing, damaged or of another subtask is
    refused here, in its loader's words, before its id is compared with anything."""
    models = _Models(sources)
    for kind in dict.fromkeys(filter(None, map(kind_of, names))):
        models[kind]  # noqa: B018


def build_library(env, names=None, sources: LibrarySources | None = None,
                  senses: Senses | None = None) -> dict[str, Controller]:
    """The named controllers (default: every one of `all_names(sources)`), ready to start in `env`, all perceiving
    the task's predicates through `senses` (default: the simulator's truth, as for recording)."""
    sources = sources or LibrarySources()
    senses = senses or OracleSenses(env)
    checkpoints = {s.controller_name: s for s in sources.lerobot}
    names = tuple(names) if names is not None else all_names(sources)
    models, library = _Models(sources), {}
    for name in names:
        if name in checkpoints:
            source = checkpoints[name]
            library[name] = kind_of_source(source).function("build")(env, sources.subtask(source.subtask), None,
                                                                      source, sources.max_grasp_offset)
            continue
        kind = kind_of(name)
        if kind is None:
            raise LibraryError(f"no controller named {name!r}; the library has {', '.join(all_names(sources))}")
        subtask = sources.subtask(name.removeprefix(f"{kind.name}_"))
        library[name] = kind.function("build")(env, subtask, models[kind], kind.config(), sources.max_grasp_offset)
    for controller in library.values():
        controller.senses = senses
        controller.scene.planner_noise = sources.gear_noise
    return library
