"""The library's controllers by name, and where their models are: what the command line's flags, the recipes and the
main job's stage keys read of the library, without the simulator or torch (`library` builds the controllers)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from policy_composer.policies.lerobot_policy.configuration_lerobot_policy import LeRobotSource
from policy_composer.policies.registry import LibraryError, get_kind, kind_of, kinds
from policy_composer.tasks.base import Subtask, TaskDescription
from policy_composer.tasks.registry import DEFAULT_TASK, get_task

# Where a kind's trained model is unless LibrarySources.models says otherwise: MODELS/KIND (the training commands'
# default output).
MODELS = Path("results/models")


@dataclass(frozen=True)
class LibrarySources:
    """The task, where the learned controllers' models are, and how the planned ones perceive the scene."""

    models: dict[str, str] = field(default_factory=dict)  # kind name -> model path (default: MODELS/KIND)
    lerobot: tuple[LeRobotSource, ...] = field(default_factory=tuple)  # the LeRobot checkpoints the user brings
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


def subtask_of(name: str, sources: LibrarySources) -> str:
    """The subtask of a controller of the library, from its name (a kind's: KIND_SUBTASK) or its LeRobot source."""
    lerobot = {s.controller_name: s.subtask for s in sources.lerobot}
    kind = kind_of(name)
    if name not in lerobot and kind is None:
        raise LibraryError(f"no controller {name!r} in the library (it has {', '.join(all_names(sources))})")
    return lerobot.get(name) or name.removeprefix(f"{kind.name}_")
