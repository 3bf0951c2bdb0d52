"""Every benchmark of the project, one after the other, and the main job's wall time: one line per figure.

Run: python benchmarks/run_all.py [--main-job-profile smoke|quick|paper] [--skip-main-job]

Each benchmark prints its figures beside a reference measured in the same run (env steps/s against ManiSkill's
PickCube-v1, recording against rendering alone, selector latency against one VAE encoding, each episode loop on 2
workers against 1); this script runs them in turn (never side by side: the machine has 2 cores) and then times
`policy-composer demo` from scratch in a temporary folder (default profile `smoke`, every stage at its smallest;
`quick` is the 30-minute main job). The per-stage times of that run follow its wall time.
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

HERE = Path(__file__).resolve().parent
BENCHMARKS = [("env steps/s", ["env_speed.py"]),
              ("recording and decoding frames/s", ["recording_speed.py"]),
              ("selector latency and training times", ["selector_speed.py"]),
              ("episode loops on 1 and 2 workers", ["workers_speed.py"])]


def run(label: str, cmd: list[str], echo: bool = True) -> float:
    """Run one benchmark, echoing its figure lines under `label`; returns its wall time."""
    print(f"== {label}: {' '.join(Path(c).name if c.endswith('.py') else c for c in cmd)}", flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=HERE.parent, capture_output=True, text=True,
                          env={**os.environ, "HF_HUB_OFFLINE": "1"})
    for line in proc.stdout.splitlines() if echo else ():
        print(f"   {line}", flush=True)
    if proc.returncode != 0:
        print(f"   FAILED (exit {proc.returncode}): {proc.stderr.strip().splitlines()[-1:]}", flush=True)
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--main-job-profile", default="smoke", choices=("smoke", "quick", "paper"))
    parser.add_argument("--skip-main-job", action="store_true")
    args = parser.parse_args()
    for label, script in BENCHMARKS:
        run(label, [sys.executable, str(HERE / script[0]), *script[1:]])
    if args.skip_main_job:
        return 0
    exe = Path(sys.executable).parent / "policy-composer"
    with tempfile.TemporaryDirectory() as out:
        wall = run(f"main job, profile {args.main_job_profile}, from scratch",
                   [str(exe), "demo", "--profile", args.main_job_profile, "--out", out], echo=False)
        print(f"   main job wall time ({args.main_job_profile}): {wall:.0f} s", flush=True)
        for marker in sorted(Path(out, "pipeline").glob("*/stage.json"), key=os.path.getmtime):
            stage = json.loads(marker.read_text())
            print(f"   stage {stage['stage']}: {stage['seconds']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
