"""The controller library of a task: every controller by name, built from its trained models.

Names are `KIND_SUBTASK` (mp_pick, dmp_move, cnn_insert, ...) for the registered kinds (`registry`), plus one
controller per LeRobot checkpoint the user brings. The selector, Table I and the dataset recipes all build their
controllers here, so a name means the same controller everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from policy_composer.policies.base import Controller
from policy_composer.policies.registry import LibraryError, get_kind, kind_of, kinds
from policy_composer.policies.senses import OracleSenses, Senses
from policy_composer.tasks.base import Subtask, TaskDescription
from policy_composer.tasks.registry import DEFAULT_TASK, get_task

# Where a kind's trained model is unless LibrarySources.models says otherwise: MODELS/KIND (the training commands'
# default output).
MODELS = Path("results/models")

# Bumped when the controllers behave differently, so that stored runs of the old ones are not reused (CHANGELOG.md
# says what each revision changed).
LIBRARY_REVISION = 12

__all__ = ["LIBRARY_REVISION", "LeRobotSource", "LibraryError", "LibrarySources", "all_names", "build_library",
           "cameras_needed", "check_models", "model_ids", "names_of_kind", "subtask_of"]


@dataclass(frozen=True)
class LeRobotSource:
    """A lerobot checkpoint to run as a controller for one subtask."""

    path: str
    subtask: str = "insert"
    name: str | None = None  # default: lerobot_<subtask>

    @property
    def controller_name(self) -> str:
        return self.name or f"lerobot_{self.subtask}"


@dataclass(frozen=True)
class LibrarySources:
    """The task, where the learned controllers' models are, and how the planned ones perceive the scene."""

    models: dict[str, str] = field(default_factory=dict)  # kind name -> model path (default: MODELS/KIND)
    lerobot: tuple[LeRobotSource, ...] = field(default_factory=tuple)
    max_grasp_offset: float = 0.012  # the pick-up's perception error along the fingers (m)
    gear_noise: float = 0.0  # noise on the planner's one privileged input (the part's position), per axis (m)
    insertion: str = ""  # how the planned insertions go: a key of the task's `insertions` ("": its first)
    task: str = DEFAULT_TASK

    def __post_init__(self):
        object.__setattr__(self, "insertion", self.insertion or next(iter(self.description.insertions)))
        if self.insertion not in self.description.insertions:
            raise LibraryError(f"no insertion {self.insertion!r}: choose one of "
                               f"{', '.join(self.description.insertions)}")

    @property
    def description(self) -> TaskDescription:
        return get_task(self.task)

    def subtask(self, name: str) -> Subtask:
        """The subtask `name` as the library's controllers serve it (the insertion as `insertion` says)."""
        return self.description.subtask(name, self.insertion)

    def model_path(self, kind: str) -> str | None:
        """Where the kind's trained model is (None: it has none)."""
        return self.models.get(kind, str(MODELS / kind)) if get_kind(kind).trained else None


def all_names(sources: LibrarySources | None = None) -> tuple[str, ...]:
    """Every controller of the registered kinds for the task's subtasks, then the LeRobot checkpoints'."""
    sources = sources or LibrarySources()
    lerobot = tuple(s.controller_name for s in sources.lerobot)
    return tuple(n for k in kinds().values() for n in names_of_kind(k.name, sources.task)) + lerobot


def names_of_kind(kind: str, task: str = DEFAULT_TASK) -> tuple[str, ...]:
    """The kind's controllers for the subtasks the task has (and, for a kind learned from demonstrations, has
    demonstrations of)."""
    kind, task = get_kind(kind), get_task(task)
    return tuple(f"{kind.name}_{s}" for s in kind.subtasks
                 if s in task.subtasks and (not kind.demonstrated or s in task.spec.demonstrations))


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


def subtask_of(name: str, sources: LibrarySources) -> str:
    """The subtask of a controller of the library, from its name (a kind's: KIND_SUBTASK) or its LeRobot source."""
    lerobot = {s.controller_name: s.subtask for s in sources.lerobot}
    kind = kind_of(name)
    if name not in lerobot and kind is None:
        raise LibraryError(f"no controller {name!r} in the library (it has {', '.join(all_names(sources))})")
    return lerobot.get(name) or name.removeprefix(f"{kind.name}_")


def cameras_needed(names, sources: LibrarySources) -> tuple[str, ...]:
    """The cameras the named controllers read (an env must render them)."""
    from policy_composer.policies.lerobot_policy.controller import lerobot_cameras

    models, cameras = _Models(sources), []
    for kind in dict.fromkeys(k for k in map(kind_of, names) if k is not None and k.trained and k.function("cameras")):
        cameras += kind.function("cameras")(models[kind])
    for source in sources.lerobot:
        if source.controller_name in names:
            cameras += lerobot_cameras(source.path)
    return tuple(dict.fromkeys(cameras))


def model_ids(names, sources: LibrarySources) -> dict[str, str]:
    """The trained model each named controller runs, by `weights_id`, and the insertion of a planned one that does
    not feel for the hole (controllers with neither are left out): recorded with its rollouts, so that a dynamics
    model is never paired with another controller (`check_models` first: a model missing or damaged has no id)."""
    from policy_composer.learning.checkpoint import weights_id

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
    lerobot = {s.controller_name: s for s in sources.lerobot}
    names = tuple(names) if names is not None else all_names(sources)
    models, library = _Models(sources), {}
    for name in names:
        if name in lerobot:
            from policy_composer.policies.lerobot_policy.controller import LeRobotPolicyController

            src = lerobot[name]
            library[name] = LeRobotPolicyController(env, src.path, sources.subtask(src.subtask), name=name)
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
