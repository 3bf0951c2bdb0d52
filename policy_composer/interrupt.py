"""Ctrl-C that a long run cannot lose.

Python turns Ctrl-C into a KeyboardInterrupt in whatever code runs at that moment, and some places swallow it: a
`__del__` (e.g. a progress bar closing itself), a weakref callback, a library's catch-all. While
`flag_interrupts()` is active, Ctrl-C also leaves a flag, and the long loops (stages, episodes) call `check()`
between units of work, so a lost KeyboardInterrupt is raised again at the next safe point.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

_requested = threading.Event()
_active = threading.Event()  # outside flag_interrupts() nothing is remembered: no stale flag for later work


def request() -> None:
    """Note a Ctrl-C (for handlers that hold it back, like the recorder's while it writes an episode)."""
    if _active.is_set():
        _requested.set()


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed since `flag_interrupts()` began, even if it was swallowed."""
    if _requested.is_set():
        raise KeyboardInterrupt


@contextmanager
def flag_interrupts() -> Iterator[None]:
    """Ctrl-C raises KeyboardInterrupt as usual and is remembered for `check()` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        _requested.set()
        raise KeyboardInterrupt

    _requested.clear()
    _active.set()
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _active.clear()
        _requested.clear()
