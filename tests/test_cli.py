"""The command line as a user runs it: the scripted expert with its videos, and bad values refused up front."""

import json
import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest
from conftest import tree_digest

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


def run_cli(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "policy-composer"
    return subprocess.run([str(exe), *args], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "HF_HUB_OFFLINE": "1"})


@pytest.mark.parametrize("args, message", [
    (("compose", "--episodes", "0"), "argument --episodes: must be at least 1, not 0"),
    (("evaluate", "expert", "--episodes", "-1"), "argument --episodes: must be at least 1, not -1"),
    (("evaluate", "controllers", "--trials", "0"), "argument --trials: must be at least 1, not 0"),
    (("compose", "--clearance", "0.002"), "argument --clearance: must be between 0.5 and 6 mm, not 0.002"),
    (("record", "gear-insertion-demos", "--resolution", "8"), "argument --resolution: must be between 16 and 512"),
    (("compose", "--horizon", "0"), "argument --horizon: must be at least 1, not 0"),
    (("compose", "--samples", "many"), "argument --samples: must be a whole number, not 'many'"),
    (("train", "policy", "--epochs", "0"), "argument --epochs: must be at least 1, not 0"),
    (("train", "policy", "--image-size", "4"), "argument --image-size: must be at least 16, not 4"),
    (("train", "world-model", "--camera", "wrist"), "argument --camera: invalid choice: 'wrist'"),
    (("compose", "--lerobot", "nowhere:insert"), "no LeRobot policy checkpoint at nowhere"),
    (("compose", "--lerobot", "nowhere"), "give PATH:SUBTASK, SUBTASK one of pick, move, insert"),
    (("record", "gear-insertion-demos", "--lerobot", "ckpt:fly"), "give PATH:SUBTASK"),
])
def test_a_bad_value_is_refused_before_any_work(tmp_path, args, message):
    """Values out of range, of the wrong type, or naming what does not exist: exit 2, one line that names the flag
    and what it may be, and nothing written."""
    result = run_cli(*args, cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr
    assert message in result.stderr.strip().splitlines()[-1]
    assert "Traceback" not in result.stderr and not any(tmp_path.iterdir())


def test_compose_does_not_overwrite_a_finished_run(tmp_path):
    """A composed run in --out is kept: a new run there is refused (with the way to continue it), not truncated."""
    out = tmp_path / "compose"
    out.mkdir()
    (out / "episodes.jsonl").write_text(json.dumps(
        {"seed": 0, "success": True, "steps": 10, "knocked_out": False, "activations": [], "decisions": []}) + "\n")
    (out / "summary.md").write_text("composed: 1/1\n")
    before = tree_digest(out)
    result = run_cli("compose", "--episodes", "1", "--out", str(out), "--models", str(tmp_path / "no-models"))
    assert result.returncode == 2 and "holds a composed run (1 episodes); continue it with --resume" in result.stderr
    assert tree_digest(out) == before


@pytest.mark.parametrize("command, wrong, message", [
    (("train", "policy", "--dataset"), "full_task_demos",
     "holds gear-full-task-demos episodes, but training the CNN policy needs gear-insertion-demos"),
    (("train", "world-model", "--rollouts"), "insertion_demos",
     "holds gear-insertion-demos episodes, but training the dynamics models needs gear-controller-rollouts"),
    (("train", "goal-score", "--demos"), "insertion_demos",
     "holds gear-insertion-demos episodes, but training the goal score needs gear-full-task-demos"),
])
def test_training_on_the_wrong_recipe_is_refused(request, tmp_path, command, wrong, message):
    """A dataset's own metadata names its recipe: a model is not trained on another kind of episode."""
    dataset = request.getfixturevalue(wrong)
    before = tree_digest(dataset)
    result = run_cli(*command, str(dataset), "--out", str(tmp_path / "model"), cwd=tmp_path)
    assert result.returncode == 2 and message in result.stderr, result.stderr[-2000:]
    assert not (tmp_path / "model").exists() and tree_digest(dataset) == before
