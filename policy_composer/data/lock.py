"""One writer at a time for a folder (a dataset root, a composed run's output): an OS file lock held for the run.

The lock is `flock` on a hidden file beside the folder (the folder itself may not exist yet: LeRobot creates a
dataset's root on its first save). The kernel releases it when the process ends, however it ends, so a `kill -9`
never leaves a stale lock; the file only keeps the holder's process id for the message a second writer gets.
Readers take no lock. A process may take the same folder's lock again (nested writers of one run).
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

_held: dict[Path, int] = {}  # folder -> how many nested holders in this process


class FolderBusy(RuntimeError):
    """Another process is writing the folder."""


def lock_path(folder: Path) -> Path:
    return folder.parent / f".{folder.name}.lock"


@contextmanager
def one_writer(folder: str | Path) -> Iterator[None]:
    """Hold `folder`'s writer lock for the block, or raise FolderBusy at once naming the process that holds it."""
    folder = Path(folder).resolve()
    if folder in _held:
        _held[folder] += 1
        try:
            yield
        finally:
            _held[folder] -= 1
        return
    path = lock_path(folder)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        os.close(fd)
        raise FolderBusy(f"{folder} is being written by another process (pid {holder}); wait until it ends, or "
                         "write to another folder") from None
    os.pwrite(fd, f"{os.getpid():<20}".encode(), 0)  # fixed width, in place: no new block on a full disk
    _held[folder] = 1
    try:
        yield
    finally:
        del _held[folder]
        os.close(fd)  # releases the lock
