"""Config dataclass fields that carry their own help and choices, so the command line reads its flags, defaults
and choices from the config classes (as LeRobot's commands parse theirs) instead of repeating them."""

from __future__ import annotations

from dataclasses import MISSING, field, fields
from typing import Any

# The image encoders `learning.layers.image_encoder` builds.
BACKBONES = ("spatial", "small", "resnet18")


def option(default: Any, help: str = "", choices: tuple | None = None) -> Any:
    """A config field with a help text and, optionally, the values it may take."""
    return field(default=default, metadata={"help": help, "choices": choices})


def check_choices(config: Any) -> None:
    """Refuse a field outside its declared choices, naming the field and the choices."""
    for f in fields(config):
        choices = f.metadata.get("choices")
        if choices is not None and getattr(config, f.name) not in choices:
            raise ValueError(f"{type(config).__name__}.{f.name} must be one of {', '.join(map(str, choices))}, "
                             f"not {getattr(config, f.name)!r}")


def default_of(config_cls: type, name: str) -> Any:
    """The default of one field of a config class."""
    f = next(f for f in fields(config_cls) if f.name == name)
    return f.default_factory() if f.default is MISSING else f.default
