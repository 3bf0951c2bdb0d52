"""Each episode loop on one process and on several: wall time, speed-up, and whether the results are the same.

Run: python benchmarks/workers_speed.py [--workers 2] [--episodes 12] [--resolution 64] [--models DIR --dmp DIR
     --cnn DIR]

The loops need no trained model except composing: recording (the expert's insertion demonstrations), the
controllers' rollouts and Table I (the motion planner's pick-up and insertion), and, with `--models` (a world-model
folder of the main job, with its `--dmp` and `--cnn` folders), composing. Each runs the same seeds with 1 worker
(the reference, in the same run) and with `--workers`; a speed-up below the number of workers is what the
processes' start-up (each imports torch and ManiSkill and builds its env) and the software renderer's own threads
cost on the same cores.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from policy_composer.app.composition import compose_library
from policy_composer.app.controller_table import evaluate_rows
from policy_composer.app.record import record_recipe
from policy_composer.data.recipes import load_recipe
from policy_composer.policies.library import LibrarySources
from policy_composer.selector.configuration import ComposeConfig
from policy_composer.tasks.gear_assembly.spec import EnvSettings

os.environ.setdefault("HF_HUB_OFFLINE", "1")


def record(recipe: str, root: Path, episodes: int, resolution: int, workers: int, **changes) -> dict:
    sidecar = record_recipe(replace(load_recipe(recipe), **changes), root, episodes=episodes,
                            settings=EnvSettings(resolution=resolution), progress=False, sources=LibrarySources(),
                            workers=workers)
    return {"episodes": sidecar["episodes"], "data": sorted(p.stat().st_size for p in root.rglob("*.parquet"))}


def table(trials: int, resolution: int, workers: int) -> dict:
    rows = evaluate_rows({"MP": ("mp_pick", "mp_insert")}, LibrarySources(), trials, first_seed=7000,
                         resolution=resolution, progress=False, workers=workers)
    return {c: (cell.successes, cell.trials) for c, cell in rows["MP"].items()}


def compose(models: str, dmp: str, cnn: str, episodes: int, resolution: int, workers: int, out: Path) -> list:
    sources = LibrarySources(models={"dmp": dmp, "cnn": cnn})
    runs = compose_library(models, sources, ComposeConfig(), list(range(12000, 12000 + episodes)), out, videos=0,
                           resolution=resolution, progress=False, workers=workers)
    return [json.dumps(e.to_dict(), sort_keys=True) for e in runs]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--episodes", type=int, default=12, help="per loop (per controller for the rollouts)")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--models", default=None, help="a world-model folder: also time composing")
    parser.add_argument("--dmp", default=None)
    parser.add_argument("--cnn", default=None)
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="workers-bench-"))
    n, res = args.episodes, args.resolution
    loops = {
        "recording (insertion demos)": lambda w: record("gear-insertion-demos", tmp / f"demos{w}", n, res, w),
        "controller rollouts (mp_pick, mp_insert)": lambda w: record(
            "gear-controller-rollouts", tmp / f"rollouts{w}", n // 2, res, w, controllers=("mp_pick", "mp_insert")),
        "Table I (MP row)": lambda w: table(max(1, n // 2), res, w),
    }
    if args.models:
        loops["composing"] = lambda w: compose(args.models, args.dmp, args.cnn, n, res, w, tmp / f"compose{w}")
    print(f"{os.cpu_count()} cores; {n} episodes per loop at {res} px")
    try:
        for label, loop in loops.items():
            times, results = {}, {}
            for w in (1, args.workers):
                t0 = time.perf_counter()
                results[w] = loop(w)
                times[w] = time.perf_counter() - t0
            same = "same results" if results[1] == results[args.workers] else "RESULTS DIFFER"
            print(f"{label}: 1 worker {times[1]:.1f} s, {args.workers} workers {times[args.workers]:.1f} s, "
                  f"speed-up {times[1] / times[args.workers]:.2f}x, {same}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
