"""Episodes across processes: each worker builds its own env and models once, then runs the seeds it is handed.

An episode depends on its seed only (the env and the selector are reseeded at every reset), so a seed gives the same
episode in any worker; the results come back in the order of the seeds given, as from the serial loop. Workers are
spawned, not forked: a forked copy of a process that already holds a renderer or torch's thread pool can hang.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable, Iterable
from typing import Any

Runner = Callable[[Any], Any]  # one episode (or trial) from its seed, in a process that built what it needs once

_runner: Runner | None = None


def usable_cores() -> int:
    """The cores this process may run on (the default number of workers)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def in_process(items: list, workers: int) -> bool:
    """Whether `run_episodes` runs `items` in this process (no pool to start)."""
    return workers <= 1 or len(items) <= 1


def _start(setup: Callable[[], Runner]) -> None:
    global _runner
    import torch

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it keeps what finished and stops the pool
    torch.set_num_threads(1)  # one core per worker: the workers are the parallelism
    _runner = setup()


def _run(item):
    return item, _runner(item)


def run_episodes(setup: Callable[[], Runner], items: Iterable, workers: int = 1,
                 on_result: Callable[[Any, Any], None] | None = None) -> list:
    """`setup()` builds a runner (env, models) and `runner(item)` runs one item; returns the results in the order
    of `items`. With `workers` > 1 each of that many processes calls `setup` (a picklable callable: a module-level
    function or a `functools.partial` of one) and takes items as it finishes the last; `on_result(item, result)`
    sees each result as it arrives (to save it at once), in the order they finish."""
    items = list(items)
    results = {}
    if not items:
        return []
    if in_process(items, workers):
        runner = setup()
        try:
            for item in items:
                results[item] = runner(item)
                if on_result is not None:
                    on_result(item, results[item])
        finally:
            getattr(runner, "close", lambda: None)()
        return [results[i] for i in items]
    context = multiprocessing.get_context("spawn")
    with context.Pool(min(workers, len(items)), initializer=_start, initargs=(setup,)) as pool:
        for item, result in pool.imap_unordered(_run, items):
            results[item] = result
            if on_result is not None:
                on_result(item, result)
    return [results[i] for i in items]
