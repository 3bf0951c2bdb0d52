"""The skeleton every trainer of the project shares: seed, build the model, Adam, fit, save.

A trainer gives what is its own (its data, its model built from it, its batch loss, its log's fields) and
`train_model` does the rest in one order, so that a seed gives the same weights from every trainer, and a training
that keeps snapshots resumes to the weights an uninterrupted one would have.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from policy_composer.learning.checkpoint import save_checkpoint
from policy_composer.learning.snapshot import Snapshots
from policy_composer.learning.training import adam, fit_epochs


@dataclass
class Fit:
    """A trainer's model, ready to train: how many rows its data has, a batch's mean loss from the rows' indices,
    its log's own fields (the data's size), and what names its data in a snapshot (None: it keeps none)."""

    model: nn.Module
    rows: int
    loss: Callable[[torch.Tensor], torch.Tensor]
    log: dict[str, Any] = field(default_factory=dict)
    snapshot: dict[str, Any] | None = None


def cosine_decay(epochs: int) -> Callable[[torch.optim.Optimizer], Any]:
    """A `schedule` for `train_model`: the step size decays to zero over the epochs, so that the last epoch's
    weights, the ones kept, come from small steps rather than wherever one last large step left them."""
    return lambda optimizer: torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs)


def train_model(config, build: Callable[[torch.Generator], Fit], desc: str, out: str | Path | None = None,
                progress: bool = True, schedule: Callable[[torch.optim.Optimizer], Any] | None = None,
                postfix: str = "loss", digits: int = 3,
                trained_with: dict[str, str] | None = None) -> tuple[nn.Module, list[float]]:
    """Train the model that `build(generator)` makes once torch's global RNG is seeded (its initial weights, then
    dropout and sampling), with Adam (and `schedule(optimizer)`, if given) for the config's epochs; `generator`, of
    the same seed, orders the batches and drives the trainer's own augmentations. With `out`, the model is saved
    there, its log holding the losses and the seconds the whole training took. Returns the model and the per-epoch
    losses."""
    t0 = time.perf_counter()
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    fit = build(generator)
    optimizer = adam(fit.model, config)
    scheduler = schedule(optimizer) if schedule is not None else None
    snapshots = None
    if out is not None and fit.snapshot is not None:
        snapshots = Snapshots.beside(out, config=asdict(config), **fit.snapshot)
    losses = fit_epochs(fit.model, optimizer, fit.rows, config.batch_size, config.epochs, fit.loss, generator, desc,
                        progress, schedule=scheduler, postfix=postfix, digits=digits, snapshots=snapshots)
    if out is not None:
        log = {**fit.log, "losses": losses, "seconds": round(time.perf_counter() - t0, 1)}
        save_checkpoint(fit.model, config, out, log, trained_with)
        if snapshots is not None:
            snapshots.done()
    return fit.model, losses
