"""The controller library of GearAssembly-v1: every controller by name, built from its trained models.

Names are `KIND_SUBTASK` (mp_pick, dmp_move, cnn_insert, ...). The selector, the per-controller table and the
dataset recipes all build their controllers here, so a name means the same controller everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from policies.base import Controller

# Which subtasks each kind has a controller for.
KINDS: dict[str, tuple[str, ...]] = {"mp": ("pick", "move", "insert"), "dmp": ("pick", "move", "insert"),
                                     "cnn": ("insert",)}
ALL_NAMES = tuple(f"{kind}_{s}" for kind, subtasks in KINDS.items() for s in subtasks)
# Bumped when the controllers behave differently, so that stored runs of the old ones are not reused.
# 2: an insertion that would let the gear go on top of the peg backs off with it to the pre-insertion pose.
LIBRARY_REVISION = 2


class LibraryError(ValueError):
    """A controller name or kind the library does not have."""


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
    """Where the learned controllers' models are, and how the planned ones perceive the gear."""

    dmp: str = "results/models/dmp"
    cnn: str = "results/models/cnn_insert"
    lerobot: tuple[LeRobotSource, ...] = field(default_factory=tuple)
    max_grasp_offset: float = 0.012  # the pick-up's perception error along the fingers (m)


def names_of_kind(kind: str) -> tuple[str, ...]:
    if kind.lower() not in KINDS:
        raise LibraryError(f"unknown controller kind {kind!r}; the library has {', '.join(k.upper() for k in KINDS)}")
    return tuple(f"{kind.lower()}_{s}" for s in KINDS[kind.lower()])


def cameras_needed(names, sources: LibrarySources) -> tuple[str, ...]:
    """The cameras the named controllers read (an env must render them)."""
    import json
    from pathlib import Path

    cameras = []
    if any(n.startswith("cnn_") for n in names):
        from policies.cnn.train import load_cnn_policy

        cameras.append(load_cnn_policy(sources.cnn).config.camera)
    for source in sources.lerobot:
        config = Path(source.path) / "config.json"
        if source.controller_name in names and config.is_file():
            features = json.loads(config.read_text()).get("input_features", {})
            cameras += [k.removeprefix("observation.images.") for k in features if k.startswith("observation.images.")]
    return tuple(dict.fromkeys(cameras))


def build_library(env, names=None, sources: LibrarySources | None = None) -> dict[str, Controller]:
    """The named controllers (default: every one of ALL_NAMES plus the lerobot sources), ready to start in `env`."""
    from policies.subtasks import SUBTASKS

    sources = sources or LibrarySources()
    lerobot = {s.controller_name: s for s in sources.lerobot}
    names = tuple(names) if names is not None else ALL_NAMES + tuple(lerobot)
    library: dict[str, Controller] = {}
    loaded: dict[str, object] = {}
    for name in names:
        if name in lerobot:
            from policies.lerobot_policy import LeRobotPolicyController

            src = lerobot[name]
            library[name] = LeRobotPolicyController(env, src.path, SUBTASKS[src.subtask], name=name)
            continue
        if name not in ALL_NAMES:
            raise LibraryError(f"no controller named {name!r}; the library has {', '.join(ALL_NAMES + tuple(lerobot))}")
        kind, subtask = name.split("_", 1)
        if kind == "mp":
            from policies.motion_planning import MotionPlanningController

            library[name] = MotionPlanningController(env, SUBTASKS[subtask], max_grasp_offset=sources.max_grasp_offset)
        elif kind == "dmp":
            from policies.dmp import DMPController, DMPLibrary

            if "dmp" not in loaded:
                loaded["dmp"] = DMPLibrary.load(Path(sources.dmp))
            library[name] = DMPController(env, SUBTASKS[subtask], loaded["dmp"], max_grasp_offset=sources.max_grasp_offset)
        else:
            from policies.cnn.controller import CNNController
            from policies.cnn.train import load_cnn_policy

            if "cnn" not in loaded:
                loaded["cnn"] = load_cnn_policy(sources.cnn)
            library[name] = CNNController(env, loaded["cnn"], SUBTASKS[subtask])
    return library
