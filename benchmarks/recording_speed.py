"""Recording and decoding speed of GearAssembly-v1 LeRobot datasets (three 128x128 cameras).

Prints one line per figure. Recording is timed end to end (render + buffer + encode + write) for the
project's setting (h264, streaming encoding) and for lerobot's default (AV1 through PNG files), in the
same process, against rendering alone as the reference. Decoding is timed through a torch DataLoader,
as training reads it, for lerobot's torchcodec and pyav backends.

    python benchmarks/recording_speed.py [--episodes 2] [--steps 150]
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import gymnasium as gym  # noqa: E402
import torch  # noqa: E402

import policy_composer.tasks.gear_assembly.env  # noqa: E402,F401  (registers GearAssembly-v1)
from policy_composer.data.recorder import LeRobotRecorder  # noqa: E402
from policy_composer.data.verify import open_dataset  # noqa: E402
from policy_composer.tasks.gear_assembly.expert import GearAssemblyExpert  # noqa: E402


def run(env, episodes: int, steps: int, recorder: LeRobotRecorder | None) -> tuple[int, float]:
    """Frames rendered and the wall time of `episodes` expert episodes of `steps` steps."""
    target = recorder or env
    expert = GearAssemblyExpert(env)
    frames, t0 = 0, time.perf_counter()
    for seed in range(episodes):
        obs, _ = target.reset(seed=seed)
        expert.reset(seed)
        for _ in range(steps):
            action = expert.act(obs)
            obs, *_ = target.step(action if recorder else env.unwrapped.flat_to_dict_action(action))
            frames += 1
        if recorder:
            recorder.save_episode(success=False, seed=seed)
    return frames, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--resolution", type=int, default=128)
    args = parser.parse_args()
    torch.set_num_threads(1)
    tmp = Path(tempfile.mkdtemp(prefix="recording-bench-"))
    env = gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=args.resolution, camera_height=args.resolution)
    configs = (("h264, streaming (project default)", {}),
               ("libsvtav1 via PNG (lerobot default)", {"vcodec": "libsvtav1", "streaming_encoding": False}))
    run(env, 1, 5, None)  # warm up the renderer, and lerobot's imports and encoders (seconds, once)
    for i, (_, kwargs) in enumerate(configs):
        run(env, 1, 5, LeRobotRecorder(env, tmp / f"warmup{i}", task="bench", **kwargs))

    n, t = run(env, args.episodes, args.steps, None)
    ref = n / t
    print(f"render only (reference):            {ref:6.1f} frames/s")
    for label, kwargs in configs:
        root = tmp / label.split()[0].strip(",")
        n, t = run(env, args.episodes, args.steps, LeRobotRecorder(env, root, task="bench", **kwargs))
        overhead = 1000 * (t / n - 1 / ref)
        print(f"record {label:36s} {n / t:6.1f} frames/s  ({n / t / ref:.2f}x render only; "
              f"recording adds {overhead:.1f} ms/frame)")
    env.close()

    root = tmp / "h264"
    for backend in ("torchcodec", "pyav"):
        ds = open_dataset(root, video_backend=backend)
        loader = torch.utils.data.DataLoader(ds, batch_size=32, shuffle=True, num_workers=0)
        t0 = time.perf_counter()
        count = sum(len(batch["index"]) for batch in loader)
        t = time.perf_counter() - t0
        print(f"decode via DataLoader ({backend:10s})   {count / t:6.1f} frames/s  "
              "(3 cameras per frame, batch 32, shuffled)")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
