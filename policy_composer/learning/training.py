"""The minibatch loop every model of the project trains with: shuffled batches, one Adam-style step each,
the frame-weighted mean loss per epoch on a progress bar."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn


def fit_epochs(model: nn.Module, optimizer: torch.optim.Optimizer, n: int, batch_size: int, epochs: int,
               loss_fn: Callable[[torch.Tensor], torch.Tensor], generator: torch.Generator, desc: str,
               progress: bool = True, schedule=None, postfix: str = "loss", digits: int = 3) -> list[float]:
    """Train `model` for `epochs` over `n` rows; `loss_fn(rows)` gives a batch's mean loss. Returns the
    per-epoch mean loss and leaves the model in eval mode."""
    from tqdm import tqdm

    losses = []
    bar = tqdm(range(epochs), desc=desc, unit="epoch", disable=not progress)
    for _ in bar:
        model.train()
        total = 0.0
        for idx in torch.randperm(n, generator=generator).split(batch_size):
            loss = loss_fn(idx)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(idx)
        if schedule is not None:
            schedule.step()
        losses.append(total / n)
        bar.set_postfix({postfix: f"{losses[-1]:.{digits}f}"})
    model.eval()
    return losses
