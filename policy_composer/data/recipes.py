"""Dataset recipes: what each of the project's datasets holds and how it is made (`datasets/recipes/*.toml`)."""

from __future__ import annotations

import re
import tomllib
import types
import typing
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

from policy_composer.data.features import read_info, read_sidecar
from policy_composer.tasks.base import TaskSpec
from policy_composer.tasks.registry import DEFAULT_TASK, TaskError, get_spec

RECIPE_DIR = Path(__file__).resolve().parents[2] / "datasets" / "recipes"
DRIVERS = ("expert", "controllers", "dagger")


class RecipeError(ValueError):
    pass


PLAIN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


def check_plain_name(name: object, what: str) -> None:
    """A recipe's name is a dataset's default folder name: a plain name, so that it cannot lead out of its folder
    (a path goes in --root)."""
    if not isinstance(name, str) or not PLAIN_NAME.match(name) or ".." in name:
        raise RecipeError(f"{what} name {name!r} is not a plain name (letters, digits, '.', '_' or '-', no leading "
                          "dot, no '..'): name it plainly and give a path with --root")


@dataclass(frozen=True)
class Recipe:
    name: str
    description: str
    task: str  # LeRobot's per-frame task string
    episodes: int  # default number of episodes (per controller for the "controllers" driver)
    # "expert": the scripted expert; "controllers": each controller of the library; "dagger": one controller of the
    # library acts from the expert's start states while the expert labels every frame (DAgger, Ross et al. 2011)
    driver: str
    record_phases: tuple[str, ...] = ()  # expert phases to record; empty: the whole episode
    # The flag of GearAssemblyEnv.evaluate() an episode must end with to succeed. The expert's episodes end once it
    # has left the last of `record_phases`, so a recipe of the first subtasks simulates nothing after them.
    goal: str = "success"
    start: str = ""  # "expert" driver: where episodes start (one of the task's start states; "": its first)
    keep: str = "success"  # "success": failed episodes are dropped and another seed is tried; "all"
    train_episodes: int | None = None  # episodes [0, train_episodes) train, the rest are held out
    # "expert" driver: control steps recorded after the expert is done, the part held where it ended, so that the
    # recordings show the goal reached (what a "seated" classifier and a policy's stop learn from)
    hold_steps: int = 0
    # "controllers" driver: which to run (empty: every registered controller); "dagger": the one that acts
    controllers: tuple[str, ...] = ()
    cameras: tuple[str, ...] = ()  # cameras to render and record (empty: every camera of the task)
    task_name: str = DEFAULT_TASK  # the library's task the episodes are recorded in (`--task`)
    expert: object = None  # the [expert] table, as the task's `expert_settings` (None: its defaults)

    @property
    def spec(self) -> TaskSpec:
        return get_spec(self.task_name)

    def reset_options(self) -> dict:
        """The env's reset options for the expert's episodes: where they start, and what the task's expert settings
        say of the scene there."""
        return {"start": self.start, **self.expert.reset_options()}

    def __post_init__(self):
        check_plain_name(self.name, "recipe")
        try:
            spec = self.spec
        except TaskError as e:
            raise RecipeError(f"recipe {self.name}: {e}") from None
        if self.expert is None:
            object.__setattr__(self, "expert", spec.expert_settings())
        object.__setattr__(self, "start", self.start or spec.start_states[0])
        object.__setattr__(self, "cameras", self.cameras or spec.cameras)
        if self.episodes < 1:
            raise RecipeError(f"recipe {self.name}: episodes must be at least 1, not {self.episodes}")
        if self.hold_steps < 0 or (self.hold_steps and self.driver != "expert"):
            raise RecipeError(f"recipe {self.name}: hold_steps must be at least 0, and is for the expert driver only "
                              f"(it is {self.hold_steps}, driver {self.driver!r})")
        if self.train_episodes is not None and self.train_episodes < 0:
            raise RecipeError(f"recipe {self.name}: train_episodes must be at least 0, not {self.train_episodes}")
        if self.driver not in DRIVERS:
            raise RecipeError(f"recipe {self.name}: driver {self.driver!r} is not one of {DRIVERS}")
        if self.driver == "dagger" and len(self.controllers) != 1:
            raise RecipeError(f"recipe {self.name}: the dagger driver runs one controller (controllers = [\"NAME\"]), "
                              f"not {list(self.controllers)}")
        if set(self.cameras) - set(spec.cameras):
            raise RecipeError(f"recipe {self.name}: cameras {list(self.cameras)} must be a subset of "
                              f"{spec.env_id}'s {list(spec.cameras)}")
        if self.start not in spec.start_states:
            raise RecipeError(f"recipe {self.name}: start must be one of {list(spec.start_states)}, not {self.start!r}")
        if set(self.record_phases) - set(spec.expert_phases):
            raise RecipeError(f"recipe {self.name}: record_phases {list(self.record_phases)} must be phases of the "
                              f"expert: {list(spec.expert_phases)}")
        if self.goal not in spec.goal_flags:
            raise RecipeError(f"recipe {self.name}: goal must be one of {list(spec.goal_flags)}, not {self.goal!r}")
        if self.keep not in ("success", "all"):
            raise RecipeError(f"recipe {self.name}: keep must be 'success' or 'all', not {self.keep!r}")

    def splits(self, num_episodes: int) -> dict[str, list[int]]:
        if self.train_episodes is None:
            return {"train": list(range(num_episodes))}
        n = min(self.train_episodes, num_episodes)
        return {"train": list(range(n)), "heldout": list(range(n, num_episodes))}


def check_recipe(root: str | Path, expected: str | tuple[str, ...], purpose: str) -> None:
    """Refuse a dataset whose metadata names another of the project's recipes than the one (or ones) `purpose`
    needs. A dataset of a recipe of the user's own (a name the project does not have) is taken as it is."""
    read_info(root)  # first, that it is a dataset at all
    recipe = read_sidecar(root).get("recipe")
    expected = (expected,) if isinstance(expected, str) else expected
    if recipe not in expected and recipe in available_recipes():
        raise RecipeError(f"{root} holds {recipe} episodes, but training {purpose} needs {' or '.join(expected)}: "
                          f"pass a {expected[0]} dataset (record one with `policy-composer record {expected[0]}`)")


def available_recipes() -> list[str]:
    return sorted(p.stem for p in RECIPE_DIR.glob("*.toml"))


def load_recipe(name_or_path: str | Path) -> Recipe:
    """A recipe by name (one of `available_recipes()`) or from a TOML file."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = RECIPE_DIR / f"{name_or_path}.toml"
    if not path.is_file():
        raise RecipeError(f"no recipe {str(name_or_path)!r}; known recipes: {', '.join(available_recipes())} "
                          f"(or give the path of a .toml recipe)")
    try:
        raw = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise RecipeError(f"recipe {path} is not a readable TOML file ({e}); see datasets/recipes/ for the "
                          "format") from None
    expert = raw.pop("expert", {})
    if not isinstance(expert, dict):
        raise RecipeError(f"recipe {path}: expert must be a table ([expert]), not {expert!r}")
    raw = typed_fields(Recipe, raw, f"recipe {path}", skip=("expert",))
    try:
        settings = get_spec(raw.get("task_name", DEFAULT_TASK)).expert_settings
    except TaskError as e:
        raise RecipeError(f"recipe {path}: {e}") from None
    try:
        raw["expert"] = settings(**typed_fields(settings, expert, f"recipe {path}, [expert]"))
    except ValueError as e:
        raise RecipeError(str(e) if str(e).startswith("recipe ") else f"recipe {path}, {e}") from None
    return Recipe(**raw)


def typed_fields(cls: type, raw: dict, where: str, skip: tuple[str, ...] = ()) -> dict:
    """`raw`'s keys checked against `cls`'s fields, their names, types and required ones, in one RecipeError that
    names the key and what it must be (a dataclass would say TypeError, or take a string for a number); lists as
    tuples."""
    hints = typing.get_type_hints(cls)
    own = [f for f in fields(cls) if f.name not in skip]
    unknown = sorted(set(raw) - {f.name for f in own})
    if unknown:
        raise RecipeError(f"{where}: unknown keys {unknown}; it takes {sorted(f.name for f in own)}")
    missing = [f.name for f in own if f.name not in raw and f.default is MISSING and f.default_factory is MISSING]
    if missing:
        raise RecipeError(f"{where}: missing keys {missing}; see datasets/recipes/ for the format")
    for name, value in raw.items():
        if not _fits(value, hints[name]):
            raise RecipeError(f"{where}: {name} must be {_describe(hints[name])}, not {value!r}")
    return {k: tuple(v) if isinstance(v, list) else v for k, v in raw.items()}


def _fits(value: object, hint) -> bool:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args)
    if origin is tuple:
        return isinstance(value, list | tuple) and all(_fits(v, args[0]) for v in value)
    if hint is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return hint is type(None) and value is None or isinstance(hint, type) and isinstance(value, hint)


def _describe(hint) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in args if a is not type(None))
    if origin is tuple:
        return f"a list, each item {_describe(args[0])}"
    return {int: "a whole number", float: "a number", str: "a string", bool: "true or false"}.get(hint, str(hint))
