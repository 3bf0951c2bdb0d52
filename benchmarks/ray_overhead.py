"""What running the episodes on a Ray cluster costs against the local process pool, on the same machine.

Run: python benchmarks/ray_overhead.py --models WORLD --dmp DMP --cnn CNN [--episodes 20] [--workers 2]
     [--resolution 64] [--seed 7000]

The main job's models (its world-model, DMP and CNN folders) compose `--episodes` seeds twice: on `--workers` local
processes (the reference, in the same run), then on a Ray head this script starts on 127.0.0.1 with as many CPUs
(at niceness 0, as the local workers run) and stops. It prints both wall times, each including its workers'
start-up, and whether the two runs' episodes are the same.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from policy_composer.app.workers import ray_head

BIN = Path(sys.executable).parent


def compose(args: argparse.Namespace, out: Path, *extra: str) -> float:
    t0 = time.perf_counter()
    subprocess.run([str(BIN / "policy-composer"), "compose", "--models", args.models, "--dmp", args.dmp, "--cnn",
                    args.cnn, "--resolution", str(args.resolution), "--videos", "0", "--seed", str(args.seed),
                    "--episodes", str(args.episodes), "--workers", str(args.workers), "--out", str(out), *extra],
                   check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for flag in ("--models", "--dmp", "--cnn"):
        parser.add_argument(flag, required=True)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--seed", type=int, default=7000)
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        local = compose(args, tmp / "local")
        with ray_head(args.workers, tmp / "ray-head") as address:  # the head's start is not counted
            time.sleep(5)  # the raylet registers a few seconds after the port opens
            ray = compose(args, tmp / "ray", "--ray", address)
        same = (tmp / "ray" / "episodes.jsonl").read_text() == (tmp / "local" / "episodes.jsonl").read_text()
        print(json.dumps({"episodes": args.episodes, "workers": args.workers, "local_pool_s": round(local, 1),
                          "ray_s": round(ray, 1), "overhead": f"{ray / local - 1:+.1%}", "same_episodes": same}))


if __name__ == "__main__":
    main()
