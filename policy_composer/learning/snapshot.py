"""A long training's state between epochs, so that an interrupted training goes on where it was.

A snapshot holds everything the next epoch depends on: the weights, the optimiser's moments, the schedule, the
shuffling generator and torch's global generator (dropout, a VAE's sampling). A training resumed from one therefore
ends with the weights an uninterrupted one would have. Tensors are safetensors, the rest JSON; the folder is
replaced as a whole (`data.atomic`), so a run killed while writing leaves the previous snapshot.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from policy_composer.data.atomic import replacing_folder, safetensors_errors


@dataclass
class Snapshots:
    """Where a training keeps its snapshot (`folder`, removed by `done` once the trained model is saved), what it
    is a training of (`of`: its config and data; a snapshot of anything else is not resumed), and how often it is
    written (after the first epoch that ends `every_s` seconds after the last snapshot)."""

    folder: Path
    of: str
    every_s: float = 120.0
    _last: float = field(default_factory=time.monotonic, repr=False)

    @classmethod
    def beside(cls, out: str | Path, **of) -> Snapshots:
        """The snapshots of the training whose model goes to `out`, in `out`.snapshot; `of` names the training."""
        out = Path(out)
        return cls(out.with_name(f"{out.name}.snapshot"), json.dumps(of))

    def due(self) -> bool:
        return time.monotonic() - self._last >= self.every_s

    def save(self, epoch: int, losses: list[float], model: nn.Module, optimizer: torch.optim.Optimizer, schedule,
             generator: torch.Generator) -> None:
        """The state after `epoch` epochs (`losses` theirs)."""
        opt = optimizer.state_dict()
        moments = {f"{i}.{k}": v.contiguous() for i, state in opt["state"].items() for k, v in state.items()}
        with replacing_folder(self.folder) as tmp, safetensors_errors(self.folder):
            save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(tmp / "model.safetensors"))
            save_file(moments, str(tmp / "optimizer.safetensors"))
            save_file({"generator": generator.get_state(), "torch": torch.get_rng_state()},
                      str(tmp / "generators.safetensors"))
            (tmp / "state.json").write_text(json.dumps({
                "of": self.of, "epoch": epoch, "losses": losses, "param_groups": opt["param_groups"],
                "schedule": schedule.state_dict() if schedule is not None else None}))
        self._last = time.monotonic()

    def restore(self, model: nn.Module, optimizer: torch.optim.Optimizer, schedule,
                generator: torch.Generator) -> tuple[int, list[float]]:
        """Load the snapshot of this training into the objects; returns its epoch and losses ((0, []) if there is
        none, or it is of another training)."""
        try:
            state = json.loads((self.folder / "state.json").read_text())
        except (OSError, ValueError):
            return 0, []
        if state.get("of") != self.of:
            return 0, []
        model.load_state_dict(load_file(str(self.folder / "model.safetensors")))
        moments: dict[int, dict[str, torch.Tensor]] = {}
        for key, value in load_file(str(self.folder / "optimizer.safetensors")).items():
            index, name = key.split(".", 1)
            moments.setdefault(int(index), {})[name] = value
        optimizer.load_state_dict({"state": moments, "param_groups": state["param_groups"]})
        if schedule is not None:
            schedule.load_state_dict(state["schedule"])
        generators = load_file(str(self.folder / "generators.safetensors"))
        generator.set_state(generators["generator"])
        torch.set_rng_state(generators["torch"])
        self._last = time.monotonic()
        return state["epoch"], state["losses"]

    def done(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
