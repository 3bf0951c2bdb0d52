"""`policy-composer expert`, the scripted expert with its videos, as a user runs it."""

import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio

ROOT = Path(__file__).resolve().parents[1]


def test_expert_prints_success_and_writes_a_three_camera_video(tmp_path):
    exe = Path(sys.executable).parent / "policy-composer"  # the venv's console script, whether or not it is on PATH
    assert exe.exists(), "the console command is not installed: run scripts/setup.sh"
    out = subprocess.run([str(exe), "expert", "--episodes", "1", "--seed", "2", "--resolution", "64",
                          "--out", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"},
                         timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "seed 2: success" in out.stdout and "expert success: 1/1" in out.stdout
    frames = iio.imread(tmp_path / "expert_seed2.mp4")
    assert frames.shape[1:] == (64, 3 * 64, 3) and len(frames) > 50
