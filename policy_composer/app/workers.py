"""Episodes across processes: each worker builds its own env and models once, then runs the seeds it is handed.

An episode depends on its seed only (the env and the selector are reseeded at every reset), so a seed gives the same
episode in any worker; the results come back in the order of the seeds given, as from the serial loop. Workers are
spawned, not forked: a forked copy of a process that already holds a renderer or torch's thread pool can hang.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from typing import Any

Runner = Callable[[Any], Any]  # one episode (or trial) from its seed, in a process that built what it needs once

_runner: Runner | None = None


def usable_cores() -> int:
    """The cores this process may run on (the default number of workers)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def in_process(items: list, workers: int) -> bool:
    """Whether `run_episodes` runs `items` in this process (no pool to start)."""
    return workers <= 1 or len(items) <= 1


def _die_with_parent(parent: int) -> None:
    """Linux: this worker is killed when the parent dies, even by `kill -9` (a pool's workers would otherwise wait
    for work forever)."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request was made
        os._exit(1)


def _start(setup: Callable[[], Runner], parent: int) -> None:
    global _runner
    import torch

    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it keeps what finished and stops the pool
    torch.set_num_threads(1)  # one core per worker: the workers are the parallelism
    try:
        _runner = setup()
    except Exception as e:  # raised again with the first item: a pool whose initializer fails restarts it forever
        _runner = partial(_raise, e)


def _raise(error: Exception, _item):
    raise error


def _run(item):
    return item, _runner(item)


class Workers:
    """`workers` processes (or, for one, this process) that each call `setup()` once, then run the items they are
    handed; a context manager, so several batches of items reuse the same envs and models. `setup` is picklable:
    a module-level function or a `functools.partial` of one."""

    def __init__(self, setup: Callable[[], Runner], workers: int = 1):
        self.setup, self.workers = setup, max(1, workers)
        self.pool = self.runner = None

    def __enter__(self) -> Workers:
        return self  # started by the first batch: nothing is built for none

    def __exit__(self, *exc) -> None:
        if self.pool is not None:
            self.pool.terminate()  # an interrupted batch leaves nothing running
        if self.runner is not None:
            getattr(self.runner, "close", lambda: None)()

    def imap(self, items: Iterable, ordered: bool = True) -> Iterator[tuple[Any, Any]]:
        """(item, result) for each item: in the order of `items`, each as soon as it and the ones before it are
        done, or (`ordered` False) in the order they finish."""
        if self.workers == 1:
            if self.runner is None:
                self.runner = self.setup()
            yield from ((item, self.runner(item)) for item in items)
        else:
            if self.pool is None:
                context = multiprocessing.get_context("spawn")
                self.pool = context.Pool(self.workers, initializer=_start,
                                         initargs=(self.setup, os.getpid()))
            yield from (self.pool.imap if ordered else self.pool.imap_unordered)(_run, items)


def run_episodes(setup: Callable[[], Runner], items: Iterable, workers: int = 1,
                 on_result: Callable[[Any, Any], None] | None = None) -> list:
    """`setup()` builds a runner (env, models) and `runner(item)` runs one item; returns the results in the order
    of `items`, run on up to `workers` processes (see `Workers`). `on_result(item, result)` sees each result as it
    arrives (to save it at once), in the order they finish."""
    items = list(items)
    if not items:
        return []
    results = {}
    with Workers(setup, 1 if in_process(items, workers) else min(workers, len(items))) as pool:
        for item, result in pool.imap(items, ordered=False):
            results[item] = result
            if on_result is not None:
                on_result(item, result)
    return [results[i] for i in items]
