"""The registry of controller kinds: each kind registers once, on its configuration class, and the library, Table I,
the recipes, the main job and the command line read it.

A kind (MP, DMP, CNN, ...) lives in its own folder, the way LeRobot keeps a policy: `configuration_KIND.py` (light:
no simulator, OMPL or torch) holds the config class that `register_kind` decorates, and `controller.py` beside it
holds `build(env, subtask, model, config, max_grasp_offset)`, plus `load(path)` for a kind with a trained model and
`cameras(model)` for one whose model reads cameras. Its controllers are named `KIND_SUBTASK` (mp_pick, cnn_insert).
Reading the registry imports only the configuration modules, so the command line's flags do not load the simulator.

A checkpoint kind (LeRobot's policies) has no controller per subtask: its controllers are the checkpoints the user
brings (`LibrarySources.lerobot`), each an instance of its config that names the checkpoint and its subtask. Its
`build` gets that instance as `config` (and no model), `cameras(config)` reads the checkpoint's cameras and
`label(config)` its row in Table I, one row per checkpoint. It is left out of `kinds()`, which the flags, the
library's names and Table I's rows of kinds read.

To add a kind: write its folder and add its name to `BUILTIN_KINDS`. A kind in another package names its
configuration module in a `policy_composer.controller_kinds` entry point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any

# The built-in kinds, in Table I's order; `policies/KIND/configuration_KIND.py` registers each.
BUILTIN_KINDS = ("mp", "dmp", "cnn", "lerobot_policy")
ENTRY_POINT_GROUP = "policy_composer.controller_kinds"


class LibraryError(ValueError):
    """A controller name or kind the library does not have."""


@dataclass(frozen=True)
class ControllerKind:
    name: str  # lower case: the prefix of its controllers' names
    label: str  # its row in Table I
    subtasks: tuple[str, ...]  # the subtasks it has a controller for
    config: type  # its configuration class; `build` gets an instance with the defaults
    trained: bool = False  # its controllers run a trained model, which `load(path)` reads
    planned: bool = False  # its insertion goes down the peg as LibrarySources.insertion says (MP, DMP)
    module: str = ""  # where build, load and cameras are; default: `controller` beside the configuration
    demonstrated: bool = False  # it serves only the subtasks its task has demonstrations of (TaskSpec.demonstrations)
    checkpoints: bool = False  # its controllers are checkpoints the user brings, each an instance of `config`

    @property
    def controller_names(self) -> tuple[str, ...]:
        return tuple(f"{self.name}_{s}" for s in self.subtasks)

    def function(self, role: str) -> Callable[..., Any] | None:
        """The controller module's `build`, `load`, `cameras` or `label` (None where the kind has no such
        function)."""
        module = self.module or self.config.__module__.rpartition(".")[0] + ".controller"
        return getattr(import_module(module), role, None)


_KINDS: dict[str, ControllerKind] = {}
_loaded = False


def register_kind(name: str, label: str, subtasks: tuple[str, ...], trained: bool = False, planned: bool = False,
                  module: str = "", demonstrated: bool = False, checkpoints: bool = False):
    """Decorate a kind's configuration class to add the kind to the registry (once per name)."""

    def register(config: type) -> type:
        kind = ControllerKind(name, label, tuple(subtasks), config, trained, planned, module, demonstrated,
                              checkpoints)
        if name in _KINDS and _KINDS[name] != kind:
            raise LibraryError(f"controller kind {name!r} is registered twice")
        _KINDS[name] = kind
        return config

    return register


def _registered() -> dict[str, ControllerKind]:
    """Every registered kind, by name: the built-in kinds first, in Table I's order."""
    global _loaded
    if not _loaded:
        _loaded = True
        for name in BUILTIN_KINDS:
            import_module(f"policy_composer.policies.{name}.configuration_{name}")
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            ep.load()
    order = [n for n in BUILTIN_KINDS if n in _KINDS] + [n for n in _KINDS if n not in BUILTIN_KINDS]
    return {n: _KINDS[n] for n in order}


def kinds() -> dict[str, ControllerKind]:
    """Every registered kind with a controller per subtask, by name: the built-in kinds first, in Table I's order."""
    return {n: k for n, k in _registered().items() if not k.checkpoints}


def kind_of_source(config) -> ControllerKind:
    """The checkpoint kind whose config `config` is (a LeRobotSource: the LeRobot policy kind)."""
    for kind in _registered().values():
        if kind.checkpoints and isinstance(config, kind.config):
            return kind
    raise LibraryError(f"no controller kind runs a {type(config).__name__}")


def get_kind(name: str) -> ControllerKind:
    """A kind by its name or Table I label, in any case."""
    for kind in kinds().values():
        if name.lower() in (kind.name, kind.label.lower()):
            return kind
    raise LibraryError(f"unknown controller kind {name!r}; the library has "
                       f"{', '.join(k.label for k in kinds().values())}")


def kind_of(controller: str) -> ControllerKind | None:
    """The kind a controller name belongs to (None: not a registered kind's controller)."""
    return next((k for k in kinds().values() if controller in k.controller_names), None)
