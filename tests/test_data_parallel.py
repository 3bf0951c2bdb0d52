"""Training under Accelerate: the command that trains in one process trains data-parallel under `accelerate launch`
(here 2 CPU processes) with the same steps, so it gives the same model up to float rounding."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import run_cli
from safetensors.torch import load_file

BIN = Path(sys.executable).parent


@pytest.mark.timeout(600)
def test_two_processes_train_the_one_process_model(insertion_demos, tmp_path):
    # No random image shift: each process draws its own, so only then are the two runs' steps the same.
    train = ["train", "policy", "--subtask", "insert", "--dataset", str(insertion_demos), "--epochs", "3",
             "--image-size", "32", "--mixtures", "4", "--shift", "0", "--batch-size", "32", "--threads", "2"]
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    one = run_cli(*train, "--out", str(tmp_path / "one"))  # one process: this one
    assert one.returncode == 0, one.stderr[-3000:]
    launch = [str(BIN / "accelerate"), "launch", "--multi_gpu", "--num_processes", "2", "--num_machines", "1",
              "--mixed_precision", "no", "--dynamo_backend", "no"]
    res = subprocess.run([*launch, str(BIN / "policy-composer"), *train, "--out", str(tmp_path / "two")], env=env,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-3000:]
    logs = {r: json.loads((tmp_path / r / "train_log.json").read_text()) for r in ("one", "two")}
    assert (logs["one"]["processes"], logs["two"]["processes"]) == (1, 2)
    one, two = logs["one"]["losses"], logs["two"]["losses"]
    assert len(one) == len(two) == 3 and one[-1] < one[0]
    assert two == pytest.approx(one, rel=1e-3, abs=1e-3)  # the per-epoch loss over all frames, every process's
    a, b = (load_file(str(tmp_path / r / "model.safetensors")) for r in ("one", "two"))
    assert a.keys() == b.keys()
    assert all((a[k] - b[k]).abs().max() <= 1e-3 * (1 + a[k].abs().max()) for k in a)
    # Only the first process wrote: one checkpoint, no leftovers of a second writer.
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".lock") == ["one", "two"]  # no partial folder
