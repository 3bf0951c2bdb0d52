"""A write-ahead journal that makes saving one episode into a LeRobotDataset all-or-nothing.

lerobot (0.4 to 0.6) writes an episode in several steps (data parquet, episode metadata, videos, info.json,
stats.json) and nothing is loadable until `finalize()`. The recorder saves each episode into new files
(it reopens the dataset per episode, lerobot's own resume path), so the committed state is a set of files
that later episodes never touch, plus a few small files they rewrite. Before saving, `begin` notes which
files exist and copies the rewritten ones; `commit` drops the note. After a crash, `recover` deletes
every file the unfinished save created and restores the copies, leaving exactly the finished episodes.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

MUTABLE = ("meta/info.json", "meta/stats.json", "meta/tasks.parquet", "meta/policy_composer.json")


def journal_dir(root: Path) -> Path:
    # Beside the dataset, not in it: the first save creates the root, which lerobot wants absent.
    return root.parent / f".{root.name}.journal"


def _files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file()) if root.exists() else []


def begin(root: Path) -> None:
    jdir = journal_dir(root)
    if jdir.exists():
        recover(root)
    tmp = jdir.with_name(jdir.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "copies").mkdir(parents=True)
    for rel in MUTABLE:
        if (root / rel).is_file():
            (tmp / "copies" / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(root / rel, tmp / "copies" / rel)
    (tmp / "manifest.json").write_text(json.dumps({"root_existed": root.exists(), "files": _files(root)}))
    tmp.rename(jdir)  # the journal exists only once it is complete


def commit(root: Path) -> None:
    shutil.rmtree(journal_dir(root))


def recover(root: Path) -> bool:
    """Roll back an unfinished episode save, if any; True if there was one."""
    root = Path(root)
    jdir = journal_dir(root)
    shutil.rmtree(jdir.with_name(jdir.name + ".tmp"), ignore_errors=True)
    if not jdir.exists():
        return False
    manifest = json.loads((jdir / "manifest.json").read_text())
    if not manifest["root_existed"]:
        shutil.rmtree(root, ignore_errors=True)
    else:
        keep = set(manifest["files"])
        for rel in _files(root):
            if rel not in keep:
                (root / rel).unlink()
        for path in sorted(root.rglob("*"), reverse=True):  # empty folders left by the unfinished save
            if path.is_dir() and not any(path.iterdir()):
                path.rmdir()
        copies = jdir / "copies"
        for rel in MUTABLE:
            if (copies / rel).is_file():
                shutil.copy2(copies / rel, root / rel)
            elif (root / rel).is_file():
                (root / rel).unlink()
    shutil.rmtree(jdir)
    return True
