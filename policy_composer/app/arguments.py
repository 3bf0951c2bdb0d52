"""Command-line flags read from config dataclasses: each flag's default, type, choices and help come from its field,
so the command line never repeats a model's defaults (LeRobot's commands parse their config classes the same way)."""

from __future__ import annotations

import argparse
from dataclasses import MISSING, fields

from policy_composer.app.errors import RunError
from policy_composer.tasks.registry import known_cameras

_TYPES = {"int": int, "float": float, "str": str}


def at_least(low: float, kind: type = int):
    """An argparse type: a number of `kind` no smaller than `low` (a count of episodes, a step)."""
    def parse(text: str):
        value = _number(text, kind)
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, not {text}")
        return value

    return parse


def between(low: float, high: float, unit: str = "", kind: type = float):
    """An argparse type: a number of `kind` in [low, high], in the flag's own unit."""
    def parse(text: str):
        value = _number(text, kind)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be between {low:g} and {high:g}{unit}, not {text}")
        return value

    return parse


def subset_of(choices: tuple[str, ...]):
    """An argparse type: a comma-separated, non-empty selection from `choices`, in the order of `choices`."""
    def parse(text: str) -> tuple[str, ...]:
        picked = {t.strip() for t in text.split(",") if t.strip()}
        if not picked or picked - set(choices):
            raise argparse.ArgumentTypeError(f"must be one or more of {','.join(choices)}, comma-separated, "
                                             f"not {text!r}")
        return tuple(c for c in choices if c in picked)

    return parse


def names(text: str) -> tuple[str, ...]:
    """An argparse type: comma-separated names, at least one, none given twice (a repeat would be trained or run
    twice, or silently once)."""
    picked = tuple(t.strip() for t in text.split(",") if t.strip())
    repeated = sorted({t for t in picked if picked.count(t) > 1})
    if not picked or repeated:
        raise argparse.ArgumentTypeError(f"must name each once, comma-separated, not {text!r}")
    return picked


def _number(text: str, kind: type):
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {'a whole number' if kind is int else 'a number'}, "
                                         f"not {text!r}") from None


def add_config_options(parser: argparse.ArgumentParser, config_cls: type, flags: dict[str, str]) -> None:
    """One `--FLAG` per entry of `flags` (field name -> flag name) of `config_cls`."""
    by_name = {f.name: f for f in fields(config_cls)}
    for name, flag in flags.items():
        f = by_name[name]
        default = f.default_factory() if f.default is MISSING else f.default
        help_text = f.metadata.get("help") or name.replace("_", " ")
        kind, minimum = _TYPES[str(f.type).split(" |")[0]], f.metadata.get("minimum")
        choices = f.metadata.get("choices") or (known_cameras() if f.metadata.get("camera") else None)
        parser.add_argument(f"--{flag}", dest=f"{config_cls.__name__}.{name}", default=default,
                            type=kind if minimum is None else at_least(minimum, kind),
                            choices=choices, help=f"{help_text} (default: {default!r})")


def config_from(args: argparse.Namespace, config_cls: type, **given):
    """`config_cls` filled with the flags `add_config_options` added for it and the fields `given`; a combination
    the config refuses is the user's to fix (one line, not a traceback)."""
    prefix = f"{config_cls.__name__}."
    try:
        return config_cls(**{k.removeprefix(prefix): v for k, v in vars(args).items() if k.startswith(prefix)},
                          **given)
    except ValueError as e:
        raise RunError(f"{e} (see --help)") from e
