"""Episodes across processes: each worker builds its own env and models once, then runs the seeds it is handed.

An episode depends on its seed only (the env and the selector are reseeded at every reset), so a seed gives the same
episode in any worker; the results come back in the order of the seeds given, as from the serial loop. Workers are
spawned, not forked: a forked copy of a process that already holds a renderer or torch's thread pool can hang.

Past one machine, the same loops run on a Ray cluster (`use_ray`, the `--ray` flag): its workers are Ray actors
(`ray.util.multiprocessing.Pool`, the same interface), and this process still gathers the results and writes every
recording. An actor lost mid-episode (a node gone, a process killed) is restarted and its episode run again.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import torch

from policy_composer.app.errors import ClusterError

Runner = Callable[[Any], Any]  # one episode (or trial) from its seed, in a process that built what it needs once

_runner: Runner | None = None
_ray_address: str | None = None  # the Ray cluster the episode loops run on (see use_ray); None: this machine
# What a Ray worker needs of this process's environment (a node's own environment may lack it).
RAY_ENV = ("HF_HUB_OFFLINE", "HF_LEROBOT_HOME", "POLICY_COMPOSER_CACHE")


def _ray():
    """Ray, with its multiprocessing pool: imported where the episodes go to a cluster, since it is an optional
    extra."""
    try:
        import ray.util.multiprocessing  # noqa: PLC0415  (optional: the `distributed` extra)
    except ImportError:
        raise ClusterError("--ray needs Ray, the project's `distributed` extra: pip install -e '.[distributed]' (or "
                           "run scripts/setup.sh, which installs it)") from None
    return ray


def use_ray(address: str) -> int:
    """Run this process's episode loops on the Ray cluster at `address` (an address, "auto" for the cluster this
    machine belongs to, or "local" for a new one on this machine); returns the cluster's CPUs. Every node needs the
    project installed as here (scripts/setup.sh), at the same path."""
    global _ray_address
    ray = _ray()
    if not ray.is_initialized():
        check_reachable(address)
        if address == "local":  # Ray's workers run at niceness 15; on a machine shared with other jobs they starve
            os.environ.setdefault("RAY_worker_niceness", "0")
        env = {k: os.environ[k] for k in RAY_ENV if k in os.environ}
        try:
            ray.init(address=None if address == "local" else address, runtime_env={"env_vars": env},
                     log_to_driver=False, configure_logging=False)
        except ConnectionError as e:
            raise ClusterError(f"no Ray cluster at {address!r} ({e}): start one with `ray start --head` and pass "
                               "its address (or 'local' for one on this machine alone)") from None
    _ray_address = address
    return int(ray.cluster_resources().get("CPU", 1))


RAY_FORMS = "auto, local, HOST:PORT or ray://HOST:PORT"
RAY_ADDRESS = re.compile(r"^(ray://)?(?P<host>[A-Za-z0-9][A-Za-z0-9.-]*|\[[0-9A-Fa-f:]+\]):(?P<port>\d{1,5})$")


def ray_endpoint(address: str) -> tuple[str, int] | None:
    """The host and port of a Ray address (HOST:PORT, a head's; ray://HOST:PORT, a client server's), None for
    "auto" and "local"; anything else is a ClusterError naming the forms."""
    if address in ("auto", "local"):
        return None
    match = RAY_ADDRESS.match(address)
    if match is None or not 0 < int(match["port"]) < 65536:
        raise ClusterError(f"--ray takes {RAY_FORMS}, not {address!r}")
    return match["host"].strip("[]"), int(match["port"])


def check_reachable(address: str, timeout: float = 10.0) -> None:
    """A HOST:PORT or ray://HOST:PORT address answers (Ray would wait minutes for one that does not, and say
    nothing)."""
    endpoint = ray_endpoint(address)
    if endpoint is None:
        return  # "auto" or "local": Ray itself finds the cluster or says why not
    try:
        socket.create_connection(endpoint, timeout=timeout).close()
    except OSError as e:
        raise ClusterError(f"no Ray cluster answers at {address} ({e.strerror or e}): start its head with `ray start "
                           "--head` and pass the address it prints") from None


@contextmanager
def ray_head(cpus: int, temp_dir: str | Path, timeout: float = 120.0) -> Iterator[str]:
    """A Ray head on 127.0.0.1 with `cpus` CPUs around the block, for tests and benchmarks; yields its address once
    it accepts connections (its raylet registers a few seconds later: `use_ray` says when). Its workers run at
    niceness 0, as local workers do."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    head = subprocess.Popen([str(Path(sys.executable).parent / "ray"), "start", "--head", "--block",
                             "--node-ip-address=127.0.0.1", f"--port={port}", f"--num-cpus={cpus}",
                             "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp_dir}"],
                            env={**os.environ, "RAY_worker_niceness": "0"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    address, deadline = f"127.0.0.1:{port}", time.monotonic() + timeout
    try:
        while True:
            if head.poll() is not None:
                raise ClusterError(f"the Ray head exited with {head.returncode} before it answered at {address}")
            try:
                check_reachable(address, timeout=1)
                break
            except ClusterError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(1)
        yield address
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        head.wait(60)


def stop_ray() -> None:
    """Episode loops run on this machine again, and this process leaves the Ray cluster."""
    global _ray_address
    if _ray_address is not None:
        _ray().shutdown()
        _ray_address = None


def usable_cores() -> int:
    """The cores this process may run on (the default number of workers)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def in_process(items: list, workers: int) -> bool:
    """Whether `run_episodes` runs `items` in this process (no pool to start)."""
    return workers <= 1 or len(items) <= 1


def _die_with_parent(parent: int) -> None:
    """Linux: this worker is killed when the parent dies, even by `kill -9` (a pool's workers would otherwise wait
    for work forever)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request was made
        os._exit(1)


def _start(setup: Callable[[], Runner], parent: int | None) -> None:
    """A worker's start: `parent` is the pid of the process it works for (None: a Ray actor, which Ray stops)."""
    global _runner
    if parent is not None:
        _die_with_parent(parent)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it keeps what finished, stops the pool
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
        if self.pool is not None:  # an interrupted batch leaves nothing running
            if _ray_address is None:
                self.pool.terminate()
            else:  # Pool.terminate asks each actor to exit first: a task their restart policy retries, with a warning
                for actor, _ in self.pool._actor_pool:
                    _ray().kill(actor, no_restart=True)
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
                self.pool = self._ray_pool() if _ray_address is not None else multiprocessing.get_context(
                    "spawn").Pool(self.workers, initializer=_start, initargs=(self.setup, os.getpid()))
            yield from (self.pool.imap if ordered else self.pool.imap_unordered)(_run, items)


    def _ray_pool(self):
        """Ray actors, a core each, restarted when lost, with the episode they were running tried again."""
        actors = _ray().util.multiprocessing.Pool
        try:
            return actors(self.workers, initializer=_start, initargs=(self.setup, None),
                          ray_remote_args={"num_cpus": 1, "max_restarts": -1, "max_task_retries": -1})
        except ValueError as e:  # more workers than the cluster has CPUs
            raise ClusterError(f"{e}: pass --workers at most the cluster's CPUs") from None


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
