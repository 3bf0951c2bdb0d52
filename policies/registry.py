"""The registry of controller kinds: each kind registers once, and the library, Table I, the recipes, the main job
and the command line read it.

A kind (MP, DMP, CNN, ...) says which subtasks it serves, how one of its controllers is built, what trained model
it loads (if any) and which cameras that model reads. Its controllers are named `KIND_SUBTASK` (mp_pick,
cnn_insert). The functions are named as "module:attribute" and imported only when used, so reading the registry
(the command line's flags, the main job's keys) does not import the simulator, OMPL or torch.

To add a kind: write its module (a `Controller` subclass and a `build` function) and add one `register_kind` line
below. A kind in another package calls `register_kind` in a module named by a `policy_composer.controller_kinds`
entry point.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any

# The modules of the built-in kinds; importing one registers its kind.
BUILTIN_MODULES = (
    "policy_composer.policies.motion_planning",
    "policy_composer.policies.dmp",
    "policy_composer.policies.cnn.controller",
)
ENTRY_POINT_GROUP = "policy_composer.controller_kinds"


class LibraryError(ValueError):
    """A controller name or kind the library does not have."""


@dataclass(frozen=True)
class ControllerKind:
    name: str  # lower case: the prefix of its controllers' names
    label: str  # its row in Table I
    subtasks: tuple[str, ...]  # the subtasks it has a controller for
    # build(env, subtask, model, max_grasp_offset) -> Controller; `model` is what `load` gave (None without one)
    build: str
    load: str | None = None  # load(path) -> its trained model; None: nothing is trained
    # where `train_command` writes the model by default: a file or folder, or a folder with one per subtask (the
    # subtask's subfolder then identifies the model its controller runs)
    model_path: str | None = None
    train_command: str = ""  # the command that trains the model, for error messages and --help
    cameras: str | None = None  # cameras(model) -> the cameras the loaded model reads; None: none

    @property
    def controller_names(self) -> tuple[str, ...]:
        return tuple(f"{self.name}_{s}" for s in self.subtasks)

    def function(self, role: str) -> Callable[..., Any]:
        """The function named by `build`, `load` or `cameras`."""
        module, _, attribute = getattr(self, role).partition(":")
        target = import_module(module)
        for part in attribute.split("."):
            target = getattr(target, part)
        return target


_KINDS: dict[str, ControllerKind] = {}
_plugins_loaded = False


def register_kind(kind: ControllerKind) -> ControllerKind:
    """Add a kind to the registry (once per name)."""
    if kind.name in _KINDS and _KINDS[kind.name] != kind:
        raise LibraryError(f"controller kind {kind.name!r} is registered twice")
    _KINDS[kind.name] = kind
    return kind


def kinds() -> dict[str, ControllerKind]:
    """Every registered kind, by name, built-in kinds first."""
    global _plugins_loaded
    if not _plugins_loaded:
        _plugins_loaded = True
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            ep.load()
    return dict(_KINDS)


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


_P = "policy_composer.policies"
register_kind(ControllerKind("mp", "MP", ("pick", "move", "insert", "regrasp"), build=f"{_P}.motion_planning:build"))
register_kind(ControllerKind("dmp", "DMP", ("pick", "move", "insert"), build=f"{_P}.dmp:build",
                             load=f"{_P}.dmp:DMPLibrary.load", model_path="results/models/dmp",
                             train_command="policy-composer train dmp"))
register_kind(ControllerKind("cnn", "CNN", ("pick", "move", "insert"), build=f"{_P}.cnn.controller:build",
                             load=f"{_P}.cnn.train:load_cnn_library", cameras=f"{_P}.cnn.controller:policy_cameras",
                             model_path="results/models/cnn", train_command="policy-composer train policy"))
