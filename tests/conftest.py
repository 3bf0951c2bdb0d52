import contextlib
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # the test workers are the parallelism: torch takes one core each

from dataclasses import replace

import gymnasium as gym
import pytest
from filelock import FileLock

import policy_composer.tasks  # noqa: F401  (registers GearAssembly-v1; the simulator loads at the first gym.make)
from policy_composer.app.cli import main
from policy_composer.app.record import record_recipe
from policy_composer.data.recipes import load_recipe
from policy_composer.policies.library import LibrarySources
from policy_composer.tasks.gear_assembly.spec import INSERTION_WINDOWS, EnvSettings


def pytest_collection_modifyitems(items):
    items.sort(key=lambda item: item.get_closest_marker("runs_first") is None)  # stable: the rest keep their order


@pytest.fixture(scope="session")
def state_env():
    """One state-only env for the physics and expert tests (building an env costs seconds)."""
    env = gym.make("GearAssembly-v1", obs_mode="state_dict")
    yield env
    env.close()


def shared(tmp_path_factory, name: str, build: Callable[[Path], object]) -> Path:
    """A folder `build` fills once per test run: the first pytest-xdist worker to ask builds it under a file lock,
    the others wait and reuse it (pytest-xdist's documented pattern for session fixtures). Tests only read it."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        folder = tmp_path_factory.mktemp(name)
        build(folder)
        return folder
    folder = tmp_path_factory.getbasetemp().parent / name
    with FileLock(f"{folder}.lock"):
        done = folder / ".built"
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


def record_dataset(folder: Path, recipe: str, episodes: int, resolution: int, name: str | None = None, sources=None,
                   **changes) -> Path:
    """Record `episodes` of `recipe` (with `changes` to its fields) at `resolution` px into `folder`/`name`."""
    root = folder / (name or recipe)
    record_recipe(replace(load_recipe(recipe), **changes), root, episodes=episodes,
                  settings=EnvSettings(resolution=resolution), progress=False, sources=sources)
    return root


@pytest.fixture(scope="session")
def insertion_demos(tmp_path_factory):
    """Two insertion demonstrations at 64x64, recorded once for every test that needs a real dataset."""
    record = partial(record_dataset, recipe="gear-insertion-demos", episodes=2, resolution=64)
    return shared(tmp_path_factory, "insertion", record) / "gear-insertion-demos"


@pytest.fixture(scope="session")
def transport_demos(tmp_path_factory):
    """Two pick-up and carry demonstrations at 32x32: the CNN pick-up and move policies' data."""
    record = partial(record_dataset, recipe="gear-transport-demos", episodes=2, resolution=32)
    return shared(tmp_path_factory, "transport", record) / "gear-transport-demos"


@pytest.fixture(scope="session")
def full_task_demos(tmp_path_factory):
    """Three full-task demonstrations at 32x32, the first two for training, the third held out."""
    record = partial(record_dataset, recipe="gear-full-task-demos", episodes=3, resolution=32, train_episodes=2)
    return shared(tmp_path_factory, "full-task", record) / "gear-full-task-demos"


@pytest.fixture(scope="session")
def controller_rollouts(tmp_path_factory):
    """One rollout each of mp_pick and mp_insert at 32x32 (head and left forearm cameras): the dynamics models' data."""
    record = partial(record_dataset, recipe="gear-controller-rollouts", episodes=1, resolution=32, name="rollouts",
                     sources=LibrarySources(max_grasp_offset=0.0), controllers=("mp_pick", "mp_insert"))
    return shared(tmp_path_factory, "rollouts", record) / "rollouts"


def lerobot(script: str, *args: str, timeout: int = 900) -> subprocess.CompletedProcess:
    """One of LeRobot's commands (`lerobot-train`, `lerobot-eval`) from this environment, offline, one thread."""
    return subprocess.run([str(Path(sys.executable).parent / script), *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"})


def lerobot_train(dataset: Path, out: Path, policy: str, args: tuple[str, ...] = ()):
    """lerobot-train's `policy`, two steps on `dataset` into `out`/run; its log kept in `out`/train.json."""
    res = lerobot("lerobot-train", f"--dataset.repo_id=local/{dataset.name}", f"--dataset.root={dataset}",
                  f"--policy.type={policy}", "--policy.push_to_hub=false", "--policy.device=cpu", "--steps=2",
                  "--batch_size=2", "--num_workers=0", f"--output_dir={out / 'run'}", "--wandb.enable=false",
                  "--log_freq=1", "--save_freq=2", *args, timeout=600)
    (out / "train.json").write_text(json.dumps({"returncode": res.returncode, "stdout": res.stdout,
                                                "stderr": res.stderr}))


def trained(out: Path) -> tuple[Path, subprocess.CompletedProcess]:
    """What `lerobot_train` left in `out`: (the pretrained_model folder, the trainer's exit code and log)."""
    log = json.loads((out / "train.json").read_text())
    return (out / "run" / "checkpoints" / "last" / "pretrained_model",
            subprocess.CompletedProcess(["lerobot-train"], log["returncode"], log["stdout"], log["stderr"]))


@pytest.fixture(scope="session")
def act_checkpoint(insertion_demos, tmp_path_factory):
    train = partial(lerobot_train, insertion_demos, policy="act", args=("--policy.pretrained_backbone_weights=null",))
    return trained(shared(tmp_path_factory, "act", train))


@pytest.fixture(scope="session")
def diffusion_checkpoint(insertion_demos, tmp_path_factory):
    """Diffusion Policy at docs/lerobot-policies.md's settings, shrunk: two observation steps in, chunks of 8 actions
    out."""
    train = partial(lerobot_train, insertion_demos, policy="diffusion", args=(
        "--policy.pretrained_backbone_weights=null", "--policy.use_group_norm=true",
        "--policy.use_separate_rgb_encoder_per_camera=false", "--policy.crop_shape=[56,56]", "--policy.n_obs_steps=2",
        "--policy.horizon=16", "--policy.n_action_steps=8",
        "--policy.drop_n_last_frames=7", "--policy.down_dims=[16,32]", "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=2"))
    return trained(shared(tmp_path_factory, "diffusion", train))


@pytest.fixture(scope="session")
def cnn_mdn_checkpoint(insertion_demos, tmp_path_factory):
    """The paper's policy through lerobot-train (the `lerobot_policy_cnn_mdn` plugin), as the project trains its
    insertion: the left forearm camera's insertion window, the gripper's width, the gear-offset auxiliary loss. Its
    binary action is named: in two episodes, the right arm's joints (still in each) take two values too."""
    window = ",".join(map(str, INSERTION_WINDOWS["left_forearm"]))
    train = partial(lerobot_train, insertion_demos, policy="cnn_mdn", args=(
        "--policy.camera=left_forearm", f"--policy.window=[{window}]", "--policy.state_indices=[7]",
        "--policy.binary_actions=[7]", "--policy.auxiliary_feature=gear_offset", "--policy.num_mixtures=2",
        "--policy.hidden_dim=32"))
    return trained(shared(tmp_path_factory, "cnn_mdn", train))


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`policy-composer ARGS` in this process, as a user sees it: its exit code, stdout and stderr. In-process, a
    command costs what it does, not a fresh interpreter importing torch and the simulator; a raised exception (what
    a user would see as a traceback) fails the test."""
    stdout, stderr, before = io.StringIO(), io.StringIO(), os.getcwd()
    os.chdir(cwd or Path.cwd())
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                code = main(list(args))
            except SystemExit as e:  # argparse's refusals
                code = e.code
    finally:
        os.chdir(before)
    return subprocess.CompletedProcess(["policy-composer", *args], code, stdout.getvalue(), stderr.getvalue())


def tree_digest(root: Path) -> dict[str, str]:
    """Every file under `root` by its SHA-256: equal before and after means nothing was touched."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*"))
            if p.is_file()}
