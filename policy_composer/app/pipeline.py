"""The main job's runner: stages whose outputs are kept under a key of their configuration.

A stage's key hashes its own configuration and the keys of the stages it reads, so a second run reuses every
finished stage, a changed setting re-runs that stage and everything downstream of it (the old outputs stay, under
their own keys), and an interrupted run resumes at the stage it stopped in. A stage is finished when its
`stage.json` exists (it is written last, atomically) and its output passes the stage's `verify`: a damaged output
is named, cleared and made again, and so is everything made from it. Recording stages keep a partial folder and
continue it episode by episode, training stages model by model; any other unfinished folder is cleared and its stage
run again.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from policy_composer.data import interrupt

MARKER = "stage.json"


@dataclass
class Stage:
    name: str
    title: str  # what the progress line says
    config: dict  # every setting the output depends on, besides its inputs
    run: Callable[[Path, dict[str, Path]], dict]  # (its folder, its inputs' folders) -> facts for the report
    inputs: tuple[str, ...] = ()  # the stages whose outputs it reads
    resumable: bool = False  # keeps an unfinished folder (recordings go on episode by episode, trainings by model)
    verify: Callable[[Path], None] | None = None  # raises ValueError naming what is damaged in a (partial) output


@dataclass
class StageRecord:
    name: str
    title: str
    key: str
    folder: Path
    seconds: float  # of the run that produced it
    reused: bool
    facts: dict = field(default_factory=dict)


def stage_key(stage: Stage, input_keys: dict[str, str]) -> str:
    blob = json.dumps({"stage": stage.name, "config": stage.config, "inputs": input_keys}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def run_stages(stages: list[Stage], root: Path, log: Callable[[str], None] = print) -> dict[str, StageRecord]:
    """Run (or reuse) each stage in order; returns each stage's record."""
    records: dict[str, StageRecord] = {}
    remade: set[str] = set()  # stages run again because an output they read was damaged
    for i, stage in enumerate(stages, 1):
        missing = [n for n in stage.inputs if n not in records]
        if missing:
            raise ValueError(f"stage {stage.name!r} reads {missing}, which no earlier stage produces")
        key = stage_key(stage, {n: records[n].key for n in stage.inputs})
        folder = root / f"{stage.name}-{key}"
        marker = folder / MARKER
        head = f"[{i}/{len(stages)}] {stage.title}"
        stale = remade.intersection(stage.inputs)
        damage = None if stale or not folder.exists() else _damage(stage, folder)
        if stale or damage:
            remade.add(stage.name)
            if folder.exists():
                log(f"{head}: " + (f"its output in {folder} is damaged ({damage}); making it again" if damage else
                                   f"made again, as {', '.join(sorted(stale))} was"))
                shutil.rmtree(folder)
        if marker.exists():
            done = json.loads(marker.read_text())
            records[stage.name] = StageRecord(stage.name, stage.title, key, folder, done["seconds"], True,
                                              done["facts"])
            log(f"{head}: reused {folder} ({done['seconds']:.0f} s when it ran)")
            continue
        if folder.exists() and not stage.resumable:
            shutil.rmtree(folder)
        log(f"{head} -> {folder}" + (" (resuming)" if folder.exists() else ""))
        folder.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        facts = stage.run(folder, {n: records[n].folder for n in stage.inputs}) or {}
        seconds = time.perf_counter() - t0
        tmp = folder / (MARKER + ".tmp")
        tmp.write_text(json.dumps({"stage": stage.name, "key": key, "config": stage.config,
                                   "inputs": {n: records[n].key for n in stage.inputs}, "seconds": seconds,
                                   "finished": time.strftime("%Y-%m-%d %H:%M:%S"), "facts": facts}, indent=1))
        os.replace(tmp, marker)
        records[stage.name] = StageRecord(stage.name, stage.title, key, folder, seconds, False, facts)
        log(f"{head}: done in {seconds:.0f} s")
        interrupt.check()
    return records


def _damage(stage: Stage, folder: Path) -> str | None:
    """Why the stage's output (finished, or partial and about to be resumed) cannot be trusted; None if it can."""
    if stage.verify is None:
        return None
    try:
        stage.verify(folder)
    except ValueError as e:
        return str(e)
    return None
