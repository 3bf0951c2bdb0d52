"""Command-line flags read from config dataclasses: each flag's default, type, choices and help come from its field,
so the command line never repeats a model's defaults (LeRobot's commands parse their config classes the same way)."""

from __future__ import annotations

import argparse
from dataclasses import fields
from typing import Any

from policy_composer.learning.config import default_of

_TYPES = {"int": int, "float": float, "str": str}


def add_config_options(parser: argparse.ArgumentParser, config_cls: type, flags: dict[str, str]) -> None:
    """One `--FLAG` per entry of `flags` (field name -> flag name) of `config_cls`."""
    by_name = {f.name: f for f in fields(config_cls)}
    for name, flag in flags.items():
        f = by_name[name]
        default = default_of(config_cls, name)
        help_text = f.metadata.get("help") or name.replace("_", " ")
        parser.add_argument(f"--{flag}", dest=f"{config_cls.__name__}.{name}", default=default,
                            type=_TYPES[str(f.type).split(" |")[0]], choices=f.metadata.get("choices"),
                            help=f"{help_text} (default: {default})")


def config_from(args: argparse.Namespace, config_cls: type, **values: Any):
    """`config_cls` filled with the flags `add_config_options` added for it, and `values`."""
    prefix = f"{config_cls.__name__}."
    flags = {k.removeprefix(prefix): v for k, v in vars(args).items() if k.startswith(prefix)}
    return config_cls(**{**flags, **values})
