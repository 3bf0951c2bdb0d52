"""Ctrl-C that a long run cannot lose, and cannot cut an episode's write in half.

Python turns Ctrl-C into a KeyboardInterrupt in whatever code runs at that moment, and some places swallow it: a
`__del__` (e.g. a progress bar closing itself), a weakref callback, a library's catch-all. While
`flag_interrupts()` is active, Ctrl-C also leaves a flag, and the long loops (stages, episodes) call `check()`
between units of work, so a lost KeyboardInterrupt is raised again at the next safe point. `held_back()` delays
Ctrl-C to the end of a block that must finish (writing an episode).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

_requested = threading.Event()
_active = threading.Event()  # outside flag_interrupts() nothing is remembered: no stale flag for later work


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed since `flag_interrupts()` began, even if it was swallowed."""
    if _requested.is_set():
        raise KeyboardInterrupt


def _note() -> None:
    if _active.is_set():
        _requested.set()


@contextmanager
def _sigint_handler(handler: Callable) -> Iterator[None]:
    """`handler` receives SIGINT for the block (only the main thread can install one: elsewhere, nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextmanager
def flag_interrupts() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt as usual and is remembered for `check()`."""
    def handler(signum, frame):
        _note()
        raise KeyboardInterrupt

    _requested.clear()
    _active.set()
    try:
        with _sigint_handler(handler):
            yield
    finally:
        _active.clear()
        _requested.clear()


@contextmanager
def held_back() -> Iterator[None]:
    """Hold back Ctrl-C while the block runs, then raise it."""
    caught = []

    def hold(signum, frame):
        caught.append(True)
        _note()

    with _sigint_handler(hold):
        yield
    if caught:
        raise KeyboardInterrupt
