"""The CNN insertion policy trained two ways on one dataset: the project's loop and lerobot-train (`cnn_mdn`).

Run: python benchmarks/cnn_trainers.py --dataset DEMOS [--epochs 200] [--num-workers 2] [--one-camera] --out DIR

Both train the same network (policies/cnn/modeling_cnn.py) with the same batch size (120), number of gradient steps
(the loop's epochs times its batches an epoch), optimiser and cosine decay; the loop first (the reference, in the
same run). The loop decodes its camera's frames into memory once; lerobot-train decodes every sample's videos as it
goes, all the dataset's cameras unless `--one-camera` first writes a copy holding only the left forearm camera with
`lerobot-edit-dataset --operation.type=remove_feature` (its time printed apart). It prints both wall times, each with
its start-up, and their ratio, and keeps both policies in DIR for the held-out evaluation:

    policy-composer evaluate controllers --kinds CNN --subtasks insert --cnn DIR/loop ...
    policy-composer evaluate controllers --kinds '' --lerobot DIR/lerobot/checkpoints/last/pretrained_model:insert ...
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

from policy_composer.tasks.gear_assembly.spec import INSERTION_WINDOWS

BIN = Path(sys.executable).parent
OTHER_CAMERAS = '["observation.images.head","observation.images.right_forearm"]'


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", required=True, type=Path, help="insertion demonstrations (a LeRobot dataset)")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--num-workers", type=int, default=2, help="lerobot-train's data-loading processes")
    parser.add_argument("--one-camera", action="store_true", help="train lerobot-train on a one-camera copy")
    args = parser.parse_args()
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    frames = json.loads((args.dataset / "meta" / "info.json").read_text())["total_frames"]
    batch = 120
    steps = args.epochs * math.ceil(frames / batch)
    loop = timed([str(BIN / "policy-composer"), "train", "policy", "--subtask", "insert", "--dataset",
                  str(args.dataset), "--epochs", str(args.epochs), "--batch-size", str(batch), "--out",
                  str(args.out / "loop" / "insert")])
    dataset = args.dataset
    if args.one_camera:
        dataset = args.out / f"{args.dataset.name}-left-forearm"
        edit = timed([str(BIN / "lerobot-edit-dataset"), f"--repo_id=local/{args.dataset.name}",
                      f"--root={args.dataset}", f"--new_repo_id=local/{dataset.name}", f"--new_root={dataset}",
                      "--operation.type=remove_feature", f"--operation.feature_names={OTHER_CAMERAS}"])
        print(f"lerobot-edit-dataset, the one-camera copy: {edit:.0f} s")
    window = ",".join(map(str, INSERTION_WINDOWS["left_forearm"]))
    lerobot = timed([str(BIN / "lerobot-train"), f"--dataset.repo_id=local/{dataset.name}", f"--dataset.root={dataset}",
                     "--policy.type=cnn_mdn", "--policy.camera=left_forearm", f"--policy.window=[{window}]",
                     "--policy.state_indices=[7]", "--policy.binary_actions=[7]",
                     "--policy.auxiliary_feature=gear_offset", "--policy.push_to_hub=false", "--policy.device=cpu",
                     f"--batch_size={batch}", f"--steps={steps}", f"--save_freq={steps}", "--log_freq=200",
                     f"--num_workers={args.num_workers}", "--seed=0", "--wandb.enable=false",
                     f"--output_dir={args.out / 'lerobot'}"])
    print(f"{frames} frames, {args.epochs} epochs, {steps} steps of {batch}")
    print(f"project loop (policy-composer train policy): {loop:.0f} s")
    print(f"lerobot-train --policy.type=cnn_mdn: {lerobot:.0f} s ({lerobot / loop:.2f}x the loop)")


if __name__ == "__main__":
    main()
