"""The command line as a user runs it: the scripted expert with its videos, and bad values refused up front."""

import json
import shutil
from pathlib import Path

import imageio.v3 as iio
import pytest
from conftest import run_cli, tree_digest

from policy_composer.learning.checkpoint import save_checkpoint
from policy_composer.selector.configuration import VAEConfig
from policy_composer.selector.vae import VAE

ROOT = Path(__file__).resolve().parents[1]


def test_expert_prints_success_and_writes_a_three_camera_video(tmp_path):
    out = run_cli("expert", "--episodes", "1", "--seed", "2", "--resolution", "32", "--out", str(tmp_path))
    assert out.returncode == 0, out.stdout + out.stderr
    assert "seed 2: success" in out.stdout and "expert success: 1/1" in out.stdout
    frames = iio.imread(tmp_path / "expert_seed2.mp4")
    assert frames.shape[1:] == (32, 3 * 32, 3) and len(frames) > 50


@pytest.mark.parametrize("args, message", [
    (("compose", "--episodes", "0"), "argument --episodes: must be at least 1, not 0"),
    (("evaluate", "expert", "--episodes", "-1"), "argument --episodes: must be at least 1, not -1"),
    (("evaluate", "controllers", "--trials", "0"), "argument --trials: must be at least 1, not 0"),
    (("evaluate", "controllers", "--subtasks", "pick,fly"),
     "argument --subtasks: must be one or more of pick,move,insert,full, comma-separated, not 'pick,fly'"),
    (("compose", "--workers", "0"), "argument --workers: must be at least 1, not 0"),
    (("compose", "--clearance", "0.002"), "argument --clearance: must be between 0.5 and 6 mm, not 0.002"),
    (("expert", "--grasp-offset", "1e9"), "argument --grasp-offset: must be between 0 and 19 mm, not 1e9"),
    (("record", "gear-insertion-demos", "--resolution", "8"), "argument --resolution: must be between 16 and 512"),
    (("compose", "--horizon", "0"), "argument --horizon: must be at least 1, not 0"),
    (("compose", "--samples", "many"), "argument --samples: must be a whole number, not 'many'"),
    (("train", "policy", "--epochs", "0"), "argument --epochs: must be at least 1, not 0"),
    (("train", "policy", "--image-size", "4"), "argument --image-size: must be at least 16, not 4"),
    (("train", "world-model", "--camera", "wrist"), "argument --camera: invalid choice: 'wrist'"),
    (("train", "policy", "--camera", "hand_camera"),
     "CNNPolicyConfig.camera must be one of GearAssembly-v1's head, left_forearm, right_forearm, not 'hand_camera'"),
    (("train", "policy", "--task", "peg-insertion-side", "--camera", "head"),
     "CNNPolicyConfig.camera must be one of PegInsertionSide-v1's base_camera, hand_camera, not 'head'"),
    (("compose", "--lerobot", "nowhere:insert"), "no LeRobot policy checkpoint at nowhere"),
    (("compose", "--lerobot", "nowhere"), "give PATH:SUBTASK or PATH:SUBTASK:NAME, SUBTASK one of pick, move, insert"),
    (("record", "gear-insertion-demos", "--lerobot", "ckpt:fly"), "give PATH:SUBTASK"),
    (("record", "gear-insertion-demos", "--ray", "127.0.0.1:1"), "no Ray cluster answers at 127.0.0.1:1"),
    (("record", "gear-insertion-demos", "--ray", "ray://127.0.0.1:1"), "no Ray cluster answers at ray://127.0.0.1:1"),
    (("record", "gear-insertion-demos", "--ray", "not-an-address"),
     "argument --ray: must be auto, local, HOST:PORT or ray://HOST:PORT, not 'not-an-address'"),
    (("compose", "--ray", ""), "argument --ray: must be auto, local, HOST:PORT or ray://HOST:PORT, not ''"),
    (("train", "world-model", "--controllers", "mp_pick,mp_pick"),
     "argument --controllers: must name each once, comma-separated, not 'mp_pick,mp_pick'"),
    (("train", "goal-score", "--cameras", "head,head"), "argument --cameras: must name each once"),
    (("library", "add", "--lerobot", "ckpt:insert:act-1"), "the controller's name must be letters, digits and _"),
    (("library", "add", "--lerobot", "nowhere:insert:act_insert"), "no LeRobot policy checkpoint at nowhere"),
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
    result = run_cli("compose", "--episodes", "1", "--out", str(out), "--models", str(tmp_path / "no-models"),
                     cwd=tmp_path)
    assert result.returncode == 2 and "holds a composed run (1 episodes); continue it with --resume" in result.stderr
    assert tree_digest(out) == before


@pytest.mark.parametrize("command, wrong, message", [
    (("train", "policy", "--dataset"), "full_task_demos",
     "holds gear-full-task-demos episodes, but training the CNN insert policy needs gear-insertion-demos"),
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


def _copy(dataset: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(dataset, tmp_path / "input" / dataset.name))


def _vae(root: Path, truncate: bool = False) -> Path:
    """A real (untrained) VAE checkpoint in a world-model folder, its weights cut in half if `truncate`."""
    config = VAEConfig(image_size=32, latent_dim=8)
    save_checkpoint(VAE(config), config, root / "vae")
    if truncate:
        weights = root / "vae" / "model.safetensors"
        weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    return root


def _unreadable_config(root: Path) -> Path:
    (root / "vae").mkdir(parents=True)
    (root / "vae" / "config.json").write_text("{")
    (root / "vae" / "model.safetensors").write_bytes(b"x")
    return root


def _unreadable_parquet(ds: Path) -> list[str]:
    (ds / "data" / "chunk-000" / "file-000.parquet").write_bytes(b"not a parquet file")
    return ["train", "policy", "--dataset", str(ds)]


def _video_missing(ds: Path) -> list[str]:
    (ds / "videos" / "observation.images.head" / "chunk-000" / "file-001.mp4").unlink()
    return ["train", "policy", "--dataset", str(ds)]


def _broken_info(ds: Path) -> list[str]:
    (ds / "meta" / "info.json").write_text('{"codebase_version": "v3.0", ')
    return ["train", "policy", "--dataset", str(ds)]


@pytest.mark.parametrize("make_args, message", [
    (_unreadable_parquet, "file-000.parquet is not a readable parquet file"),
    (_video_missing, "is missing 1 video file(s) its episodes point to (videos/observation.images.head/"),
    (_broken_info, "info.json is not readable JSON"),
    (lambda ds: ["train", "goal-score", "--demos", str(ds.parent / "gear-ful-task-demos")], "no dataset at"),
    (lambda ds: ["record", "gear-insertion-demos", "--root", str(ds), "--resume", "--resolution", "32"],
     "but this run asks for resolution 32 (it has 64)"),
    (lambda ds: ["record", "gear-insertion-demos", "--root", str(ds), "--resume", "--seed", "7"],
     "first seed 7 (it began at seed 0 and continues from seed"),
    (lambda ds: ["record", "gear-full-task-demos", "--root", str(ds), "--resume"],
     "was recorded from recipe 'gear-insertion-demos', not 'gear-full-task-demos'"),
])
def test_a_bad_dataset_is_named_with_the_fix_and_left_as_it_was(insertion_demos, tmp_path, make_args, message):
    """Unreadable, incomplete or mistyped datasets, and a --resume that contradicts the dataset: exit 2 with one line
    that names the file or setting and what to do, before any work, and the dataset stays as it was."""
    ds = _copy(insertion_demos, tmp_path)
    args = make_args(ds)
    before = tree_digest(ds)
    result = run_cli(*args, *(["--out", str(tmp_path / "model")] if args[0] == "train" else []), cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr[-2000:]
    assert message in result.stderr.strip().splitlines()[-1] and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert tree_digest(ds) == before and not (tmp_path / "model").exists()


@pytest.mark.parametrize("make_models, message", [
    (_unreadable_config, "config.json is not a readable config"),
    (lambda root: _vae(root, truncate=True), "model.safetensors does not hold the weights of this VAE"),
    (lambda root: _vae(root), "has no dynamics model for any controller"),
])
def test_a_bad_model_folder_is_named_with_the_fix_and_left_as_it_was(tmp_path, make_models, message):
    """Unreadable or incomplete model folders given to `compose`: one line naming the file and the fix, nothing
    written, the folder untouched."""
    models = make_models(tmp_path / "models")
    before = tree_digest(models)
    result = run_cli("compose", "--models", str(models), "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert result.returncode == 2, result.stdout + result.stderr[-2000:]
    assert message in result.stderr.strip().splitlines()[-1] and "Traceback" not in result.stderr
    assert tree_digest(models) == before and not (tmp_path / "run").exists()
