"""Writes that a later command sees whole or not at all: write beside the target, then rename over it.

A run killed mid-write leaves the old file (or folder) in place and a hidden `.NAME.partial` beside it, which the
next write of the same target clears. A rename within one file system is atomic, so a reader sees the old
version or the new one, never a mix. A model folder is replaced as a whole, so its rename also marks it
complete: a folder under its own name always holds every file it was written with.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from pathlib import Path


class FolderTaken(ValueError):
    """An output folder holding files that the command writing there did not write: replacing it would lose them."""


def check_replaceable(folder: str | Path, own: Collection[str], what: str) -> None:
    """Refuse to replace `folder` unless it is missing, empty, or holds nothing but the files `what` consists of
    (`own`): a model written over a dataset or a user's notes would delete them."""
    folder = Path(folder)
    if not folder.exists():
        return
    if not folder.is_dir():
        raise FolderTaken(f"{folder} is a file, not a folder for {what}: give --out a new or empty folder")
    foreign = sorted(p.name for p in folder.iterdir() if p.name not in own)
    if foreign:
        shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
        raise FolderTaken(f"{folder} holds {shown}, which {what} does not consist of: writing {what} there would "
                          "replace the folder and lose them; give --out a new or empty folder, or move them away")


def _partial(path: Path) -> Path:
    """The hidden name a write of `path` goes to first (same suffix, so writers that infer a format from it work)."""
    return path.with_name(f".{path.stem}.partial{path.suffix}")


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """Yield a temporary file path beside `path`; when the block ends without error it replaces `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _partial(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | Path, text: str) -> Path:
    with replacing(path) as tmp:
        tmp.write_text(text)
    return Path(path)


@contextmanager
def replacing_folder(folder: str | Path) -> Iterator[Path]:
    """Yield an empty folder beside `folder` to fill; when the block ends without error it replaces `folder`."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp, old = _partial(folder), folder.with_name(f".{folder.name}.old")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
        shutil.rmtree(old, ignore_errors=True)
        if folder.exists():
            os.replace(folder, old)
        os.replace(tmp, folder)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def safetensors_errors(path: str | Path) -> Iterator[None]:
    """safetensors' write failures (a full or read-only disk) raised as the OSError they are, naming `path`: its
    own error carries the OS's code only in its text."""
    try:
        yield
    except Exception as e:
        code = re.search(r"os error (\d+)", str(e))
        if type(e).__name__ != "SafetensorError" or code is None:
            raise
        raise OSError(int(code[1]), os.strerror(int(code[1])), str(path)) from None
