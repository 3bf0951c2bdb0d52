"""The tasks the library knows, by the command line's name. A task's package holds, by convention, `spec.SPEC` (its
names, importable without the simulator) and `task.TASK` (its description, with the simulator), each imported at
its first lookup, as LeRobot's factory finds a policy's classes by its type."""

from __future__ import annotations

from functools import cache
from importlib import import_module

from policy_composer.tasks.base import TaskDescription, TaskSpec

TASKS = {"gear-assembly": "policy_composer.tasks.gear_assembly",  # name -> package
         "peg-insertion-side": "policy_composer.tasks.peg_insertion_side"}
DEFAULT_TASK = "gear-assembly"


class TaskError(ValueError):
    """A task the library does not know."""


def _package(name: str) -> str:
    if name not in TASKS:
        raise TaskError(f"no task {name!r}: choose one of {', '.join(TASKS)}")
    return TASKS[name]


@cache
def get_spec(name: str) -> TaskSpec:
    return import_module(f"{_package(name)}.spec").SPEC


@cache
def get_task(name: str) -> TaskDescription:
    return import_module(f"{_package(name)}.task").TASK


def known_cameras() -> tuple[str, ...]:
    """Every camera of every task, in the tasks' order."""
    return tuple(dict.fromkeys(c for name in TASKS for c in get_spec(name).cameras))


def spec_of_env(env_id: str) -> TaskSpec:
    """The spec of the task whose env is registered as `env_id`."""
    found = next((get_spec(n) for n in TASKS if get_spec(n).env_id == env_id), None)
    if found is None:
        raise TaskError(f"the env {env_id!r} is no task of the library (it knows {', '.join(TASKS)}): add one as "
                        f"docs/adding-a-task.md shows")
    return found


def task_of(env) -> TaskDescription:
    """The description of the task `env` runs (by its registered id)."""
    u = env.unwrapped if hasattr(env, "unwrapped") else env
    return get_task(spec_of_env(getattr(u.spec, "id", None)).name)
