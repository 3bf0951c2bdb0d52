"""The minibatch loop every model of the project trains with: shuffled batches, one Adam-style step each,
the frame-weighted mean loss per epoch on a progress bar.

Started by `accelerate launch --multi_gpu --num_processes N` (torchrun under Accelerate; on a CPU-only machine
it starts N CPU processes), the same loop trains data-parallel, as `lerobot-train` does: every process holds the
whole model and dataset, takes its share of each batch, and the processes sum their share-weighted gradients
before the step, so each step is the one-process step on the whole batch and the models stay identical. Only the
first process writes files.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable

import torch
from accelerate import PartialState
from torch import nn
from tqdm import tqdm

from policy_composer.learning.errors import TrainingDiverged
from policy_composer.learning.snapshot import Snapshots


def data_parallel():
    """Accelerate's state of the training processes a launcher started, or None when training runs as one."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return None
    return PartialState(cpu=True)  # the models train on the CPU: gloo


def processes() -> int:
    """How many processes train together (1 without a launcher)."""
    return max(1, int(os.environ.get("WORLD_SIZE", "1")))


def threads_per_process(threads: int) -> int:
    """Torch threads for each training process: `threads` shared among the data-parallel processes."""
    return max(1, threads // processes())


def is_main_process() -> bool:
    state = data_parallel()
    return state is None or state.is_main_process


def wait_for_everyone() -> None:
    state = data_parallel()
    if state is not None:
        state.wait_for_everyone()


def _sum_gradients(params: list[nn.Parameter]) -> None:
    """Sum the processes' gradients (each already weighted by its share of the batch) in one all-reduce."""
    grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
    flat = torch.cat([g.reshape(-1) for g in grads])
    torch.distributed.all_reduce(flat)
    for p, g in zip(params, flat.split([g.numel() for g in grads])):
        p.grad = g.view_as(p).clone()


def adam(model: nn.Module, config) -> torch.optim.Adam:
    """Adam at a `TrainingConfig`'s step size and weight decay."""
    return torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)


def _flushing_denormals(fit):
    """Run `fit` with denormal numbers flushed to zero. Once a model fits, some gradients fall below float32's normal
    range, which the CPU computes in microcode: a converged CNN policy's backward pass took 13x as long. The flag is
    the process's, and the simulator computes under it too, so it is put back as it was: an episode's physics must
    not depend on whether a training ran before it in the same process."""

    @functools.wraps(fit)
    def flushing(*args, **kwargs):
        flushed = (torch.tensor([1e-39]) * 2).item() == 0  # torch sets the flag but has no getter for it
        torch.set_flush_denormal(True)
        try:
            return fit(*args, **kwargs)
        finally:
            torch.set_flush_denormal(flushed)

    return flushing


@_flushing_denormals
def fit_epochs(model: nn.Module, optimizer: torch.optim.Optimizer, n: int, batch_size: int, epochs: int,
               loss_fn: Callable[[torch.Tensor], torch.Tensor], generator: torch.Generator, desc: str,
               progress: bool = True, schedule=None, postfix: str = "loss", digits: int = 3,
               snapshots: Snapshots | None = None) -> list[float]:
    """Train `model` for `epochs` over `n` rows; `loss_fn(rows)` gives a batch's mean loss. Returns the
    per-epoch mean loss and leaves the model in eval mode. With `snapshots` (one process only), the training
    starts from its last snapshot, if any, and writes one now and then."""
    state = data_parallel()
    rank, world = (state.process_index, state.num_processes) if state is not None else (0, 1)
    params = [p for p in model.parameters() if p.requires_grad]
    if world > 1:
        snapshots = None
    start, losses = snapshots.restore(model, optimizer, schedule, generator) if snapshots else (0, [])
    bar = tqdm(range(start, epochs), desc=desc, unit="epoch", initial=start, total=epochs,
               disable=not progress or rank != 0)
    for epoch in bar:
        model.train()
        total = 0.0
        order = torch.randperm(n, generator=generator)
        if world > 1:  # the first process's order: the others' generators part ways in their own augmentations
            torch.distributed.broadcast(order, 0)
        for batch, idx in enumerate(order.split(batch_size)):
            mine = idx[rank::world]
            optimizer.zero_grad()
            if len(mine):
                loss = loss_fn(mine)
                value = loss.item()
                if not math.isfinite(value):
                    raise TrainingDiverged(
                        f"{desc}: the loss is {value} at epoch {epoch + 1}, batch {batch + 1} (rows "
                        f"{mine[:3].tolist()}...); nothing was saved. The datasets' numbers are finite (every reader "
                        "checks them), so the training diverged: train again with another --seed")
                (loss * (len(mine) / len(idx))).backward()
                total += value * len(mine)
            if world > 1:
                _sum_gradients(params)
            optimizer.step()
        if schedule is not None:
            schedule.step()
        if world > 1:
            summed = torch.tensor([total], dtype=torch.float64)
            torch.distributed.all_reduce(summed)
            total = summed.item()
        losses.append(total / n)
        bar.set_postfix({postfix: f"{losses[-1]:.{digits}f}"})
        if snapshots and epoch + 1 < epochs and snapshots.due():
            snapshots.save(epoch + 1, losses, model, optimizer, schedule, generator)
    model.eval()
    return losses
