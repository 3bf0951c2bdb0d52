"""Checkpoints of the project's models: weights as safetensors, the config dataclass as JSON beside them.

No pickle anywhere: a checkpoint folder holds `model.safetensors`, `config.json` and, optionally, the
training log. Loading checks the config against the dataclass, so a checkpoint from another configuration
or another kind of model fails with an error that says so.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, fields
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:  # torch is imported where a model is saved or built, so that the command line starts fast
    from torch import nn

C = TypeVar("C")


class CheckpointError(ValueError):
    """A checkpoint that is missing, of another kind of model, or from another configuration."""


def save_checkpoint(model: nn.Module, config, out: str | Path, log: dict | None = None) -> Path:
    from safetensors.torch import save_file

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(out / "model.safetensors"))
    (out / "config.json").write_text(json.dumps({"kind": type(config).__name__, **asdict(config)}, indent=1))
    if log is not None:
        (out / "train_log.json").write_text(json.dumps(log, indent=1))
    return out


def load_config(path: str | Path, config_cls: type[C], what: str, train_hint: str) -> C:
    """The config of the checkpoint at `path`, or a CheckpointError naming what is wrong and how to fix it."""
    path = Path(path)
    if not (path / "config.json").is_file() or not (path / "model.safetensors").is_file():
        raise CheckpointError(f"no {what} checkpoint in {path} (expected config.json and model.safetensors); "
                              f"train one with `{train_hint}`")
    raw = json.loads((path / "config.json").read_text())
    kind = raw.pop("kind", config_cls.__name__)
    if kind != config_cls.__name__:
        raise CheckpointError(f"{path} holds a {kind} checkpoint, not a {what} ({config_cls.__name__})")
    known = {f.name for f in fields(config_cls)}
    if set(raw) != known:
        raise CheckpointError(f"checkpoint {path} comes from another configuration of the {what} (fields "
                              f"{sorted(set(raw) ^ known)} differ); retrain it with `{train_hint}`")
    return config_cls(**raw)


def load_checkpoint(path: str | Path, config_cls: type[C], build: Callable[[C], nn.Module], what: str,
                    train_hint: str) -> nn.Module:
    """Build the model from the checkpoint's config and load its weights, in eval mode."""
    from safetensors.torch import load_file

    config = load_config(path, config_cls, what, train_hint)
    model = build(config)
    model.load_state_dict(load_file(str(Path(path) / "model.safetensors")))
    return model.eval()
