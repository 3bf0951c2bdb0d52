"""Config dataclass fields that carry their own help and choices, so the command line reads its flags, defaults
and choices from the config classes (as LeRobot's commands parse theirs) instead of repeating them."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, NoReturn

from policy_composer.tasks.registry import DEFAULT_TASK, TASKS

# The image encoders `learning.layers.image_encoder` builds.
BACKBONES = ("spatial", "small", "resnet18")


def option(default: Any, help: str = "", choices: tuple | None = None, minimum: float | None = None,
           camera: bool = False) -> Any:
    """A config field with a help text and, optionally, the values it may take or its smallest value; `camera`: it
    names a camera of the config's task (the command line offers every task's)."""
    return field(default=default, metadata={"help": help, "choices": choices, "minimum": minimum, "camera": camera})


def check_options(config: Any) -> None:
    """Refuse a field outside its declared choices or below its minimum, naming the field and what it may be."""
    for f in fields(config):
        value, choices, minimum = getattr(config, f.name), f.metadata.get("choices"), f.metadata.get("minimum")
        if choices is not None and value not in choices:
            raise ValueError(f"{type(config).__name__}.{f.name} must be one of {', '.join(map(str, choices))}, "
                             f"not {value!r}")
        if minimum is not None and value is not None and value < minimum:
            raise ValueError(f"{type(config).__name__}.{f.name} must be at least {minimum}, not {value!r}")


# Fields a checkpoint's config may lack, saved before the field existed, and the value every such checkpoint had.
ADDED_FIELDS = {"task": DEFAULT_TASK, "lr_decay": False}


def refuse(message: str) -> NoReturn:
    """A config value that cannot work, in a config LeRobot's commands parse (the plugins'): under `lerobot-train` or
    `lerobot-eval`, whose parser shows any error as a long traceback of its own frames, one line and exit code 2,
    as argparse says it; elsewhere a ValueError."""
    if Path(sys.argv[0]).name.startswith("lerobot-"):
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2)
    raise ValueError(message)


@dataclass
class TrainingConfig:
    """What every trained model's configuration holds: the task it is trained for, Adam's step size and weight decay,
    the minibatch size, the epochs and the seed. A model's config subclasses it, adds its own fields and may change a
    default or a help."""

    task: str = option(DEFAULT_TASK, "the task the model is trained for", tuple(TASKS))
    lr: float = 1e-3
    weight_decay: float = 0.0
    batch_size: int = option(64, "minibatch size", minimum=1)
    epochs: int = option(60, "training epochs", minimum=1)
    seed: int = option(0, "seed of the initialisation and the minibatches")

    def __post_init__(self):
        check_options(self)
