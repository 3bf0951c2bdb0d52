"""The tasks the library knows, by the command line's name and by their env's id. Each task's description is in
`<its module>.TASK`, imported at the first lookup (the simulator comes with it), as LeRobot's factory finds a
policy's class by its type."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from importlib import import_module

from policy_composer.tasks.base import TaskDescription


@dataclass(frozen=True)
class TaskEntry:
    env_id: str
    module: str  # holds TASK, the task's description


TASKS = {
    "gear-assembly": TaskEntry("GearAssembly-v1", "policy_composer.tasks.gear_assembly.task"),
}
DEFAULT_TASK = "gear-assembly"


class TaskError(ValueError):
    """A task the library does not know."""


@cache
def get_task(name: str) -> TaskDescription:
    if name not in TASKS:
        raise TaskError(f"no task {name!r}: choose one of {', '.join(TASKS)}")
    return import_module(TASKS[name].module).TASK


def task_of(env) -> TaskDescription:
    """The description of the task `env` runs (by its registered id)."""
    env_id = getattr((env.unwrapped if hasattr(env, "unwrapped") else env).spec, "id", None)
    name = next((n for n, t in TASKS.items() if t.env_id == env_id), None)
    if name is None:
        raise TaskError(f"the env {env_id!r} is no task of the library (it knows {', '.join(TASKS)}): add one as "
                        f"docs/adding-a-task.md shows")
    return get_task(name)
