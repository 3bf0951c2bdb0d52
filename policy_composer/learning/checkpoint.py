"""Checkpoints of the project's models: weights as safetensors, the config dataclass as JSON beside them.

No pickle anywhere: a checkpoint folder holds `model.safetensors`, `config.json` and, optionally, the
training log. Loading checks the config against the dataclass, so a checkpoint from another configuration
or another kind of model fails with an error that says so; the weights file keeps its own copy of the config, so a
`config.json` edited after the training is refused too. The folder is written aside and renamed into place, so it
is always one training's whole output, and only over a folder that holds nothing but a checkpoint of the same kind.
`config.json` also names the models it was trained with (by `weights_id`), so parts that must belong together can
be checked.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, fields
from pathlib import Path
from typing import TypeVar

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import nn

from policy_composer.data.atomic import FolderTaken, check_replaceable, replacing_folder, safetensors_errors
from policy_composer.data.lock import one_writer
from policy_composer.learning.config import ADDED_FIELDS
from policy_composer.learning.errors import CheckpointError
from policy_composer.learning.training import is_main_process, processes, wait_for_everyone

C = TypeVar("C")


CHECKPOINT_FILES = ("model.safetensors", "config.json", "train_log.json")


def check_out(out: str | Path, config_cls: type) -> None:
    """Refuse an output folder that holds anything but a checkpoint of `config_cls`'s kind: it would be replaced."""
    out = Path(out)
    what = f"a {config_cls.__name__} checkpoint"
    check_replaceable(out, CHECKPOINT_FILES, what)
    try:
        kind = json.loads((out / "config.json").read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        return  # none, or a damaged one of ours: replaced
    if kind not in (None, config_cls.__name__):
        raise FolderTaken(f"{out} holds a {kind} checkpoint, not {what}: give --out another folder")


@contextmanager
def model_writer(out: str | Path, config_cls: type | None = None) -> Iterator[None]:
    """Hold the writer lock of `out` for a training whose models go there, after checking that the folder may be
    replaced by a `config_cls` checkpoint (if given): a second training into it, or one over what is not its kind's
    checkpoint, stops before any work."""
    if config_cls is not None:
        check_out(out, config_cls)
    if not is_main_process():  # data-parallel: the first process writes
        yield
        return
    with one_writer(out):
        yield


def save_checkpoint(model: nn.Module, config, out: str | Path, log: dict | None = None,
                    trained_with: dict[str, str] | None = None) -> Path:
    """Write the model to `out` as a whole; `trained_with` names (by `weights_id`) the models it was trained with.
    Trained data-parallel, the first process writes it and the others wait until it is there."""
    out = Path(out)
    if is_main_process():
        check_out(out, type(config))
        with replacing_folder(out) as tmp:
            with safetensors_errors(out):
                save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(tmp / "model.safetensors"),
                          metadata={"config": json.dumps(asdict(config))})
            meta = {"kind": type(config).__name__, "trained_with": trained_with or {}}
            (tmp / "config.json").write_text(json.dumps({**meta, **asdict(config)}, indent=1))
            if log is not None:
                (tmp / "train_log.json").write_text(json.dumps({**log, "processes": processes()}, indent=1))
    wait_for_everyone()
    return out


def weights_id(folder: str | Path) -> str:
    """A short digest of the model in `folder`, its weights (the .safetensors files) and its configuration
    (config.json): equal ids, the same trained model run the same way."""
    digest = hashlib.sha256()
    folder = Path(folder)
    for path in [*sorted(folder.glob("*.safetensors")), *[p for p in [folder / "config.json"] if p.is_file()]]:
        with open(path, "rb") as f:
            digest.update(hashlib.file_digest(f, "sha256").digest())
    return digest.hexdigest()[:16]


def _read_config(path: Path, what: str, train_hint: str) -> dict:
    if not (path / "config.json").is_file() or not (path / "model.safetensors").is_file():
        raise CheckpointError(f"no {what} checkpoint in {path} (expected config.json and model.safetensors); "
                              f"train one with `{train_hint}`")
    try:
        raw = json.loads((path / "config.json").read_text())
        if not isinstance(raw, dict):
            raise ValueError("not a JSON object")
    except (ValueError, UnicodeDecodeError) as e:
        raise CheckpointError(f"{path / 'config.json'} is not a readable config ({e}); train the {what} again with "
                              f"`{train_hint}`") from None
    return raw


def trained_with(path: str | Path, what: str, train_hint: str) -> dict[str, str]:
    """The models (by `weights_id`) the checkpoint at `path` was trained with: {} if it names none."""
    return _read_config(Path(path), what, train_hint).get("trained_with") or {}


def load_config(path: str | Path, config_cls: type[C], what: str, train_hint: str) -> C:
    """The config of the checkpoint at `path`, or a CheckpointError naming what is wrong and how to fix it."""
    path = Path(path)
    raw = _read_config(path, what, train_hint)
    raw.pop("trained_with", None)
    kind = raw.pop("kind", config_cls.__name__)
    if kind != config_cls.__name__:
        raise CheckpointError(f"{path} holds a {kind} checkpoint, not a {what} ({config_cls.__name__})")
    known = {f.name for f in fields(config_cls)}
    raw = {**{k: v for k, v in ADDED_FIELDS.items() if k in known}, **raw}
    if set(raw) != known:
        raise CheckpointError(f"checkpoint {path} comes from another configuration of the {what} (fields "
                              f"{sorted(set(raw) ^ known)} differ); retrain it with `{train_hint}`")
    return config_cls(**raw)


def finished(path: str | Path, config, made_with: dict[str, str] | None = None) -> dict | None:
    """The training log of the checkpoint at `path` if it was trained with exactly `config` and the models
    `made_with`, else None: a training that was cut short keeps these parts instead of training them again."""
    path = Path(path)
    try:
        same = load_config(path, type(config), "checkpoint", "") == config and \
            trained_with(path, "checkpoint", "") == (made_with or {})
        return json.loads((path / "train_log.json").read_text()) if same else None
    except (CheckpointError, OSError, ValueError):
        return None


def load_checkpoint(path: str | Path, config_cls: type[C], build: Callable[[C], nn.Module], what: str,
                    train_hint: str) -> nn.Module:
    """Build the model from the checkpoint's config and load its weights, in eval mode."""
    config = load_config(path, config_cls, what, train_hint)
    model = build(config)
    weights = Path(path) / "model.safetensors"
    try:
        with safe_open(str(weights), "pt") as f:
            tensors = {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118  (a safetensors handle)
            stored = (f.metadata() or {}).get("config")  # the config it was saved with; none in older files
        trained_as = json.loads(stored) if stored is not None else None
        model.load_state_dict(tensors)
    except Exception as e:  # a truncated or foreign file: safetensors, or torch on missing and unexpected keys
        raise CheckpointError(f"{weights} does not hold the weights of this {what} "
                              f"({str(e).splitlines()[0][:200]}); train it again with `{train_hint}`") from None
    said = json.loads(json.dumps(asdict(config)))
    differ = [k for k in said if trained_as is not None and k in trained_as and trained_as[k] != said[k]]
    if differ:
        shown = ", ".join(f"{k} {said[k]!r} (trained with {trained_as[k]!r})" for k in differ)
        raise CheckpointError(f"{Path(path) / 'config.json'} says {shown}: it no longer describes the weights beside "
                              f"it; restore it, or train the {what} again with `{train_hint}`")
    check_finite(weights, tensors, f"train it again with `{train_hint}`")
    return model.eval()


def check_finite(path: Path, tensors: dict, fix: str) -> None:
    """Refuse weights holding NaN or Inf (a damaged file, or a training that diverged): a model computing with them
    runs, but every decision made from it is noise."""
    as_tensors = {name: torch.as_tensor(t) for name, t in tensors.items()}
    bad = [name for name, t in as_tensors.items() if t.is_floating_point() and not torch.isfinite(t).all()]
    if bad:
        raise CheckpointError(f"{path} holds values that are not finite (NaN or Inf) in {len(bad)} tensor(s) "
                              f"({', '.join(bad[:3])}); {fix}")
