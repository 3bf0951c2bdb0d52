"""LeRobot datasets of GearAssembly-v1 rollouts: what is written is what loads, labels, recipes, bad input,
LeRobot's trainer."""

from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from importlib.metadata import version
from pathlib import Path

import gymnasium as gym
import numpy as np
import psutil
import pytest
import torch
from conftest import run_cli, tree_digest
from lerobot.datasets.dataset_tools import delete_episodes
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from test_frames import Stamped, read_stamp

import policy_composer.tasks.gear_assembly.env  # noqa: F401  (registers GearAssembly-v1)
from policy_composer.app.record import record_recipe
from policy_composer.data import journal
from policy_composer.data.catalog import HubUnreachable, card_fields, drop_controller, push_dataset, summarize
from policy_composer.data.features import LEROBOT_VERSION, DatasetError
from policy_composer.data.recipes import RecipeError, available_recipes, load_recipe
from policy_composer.data.recorder import LeRobotRecorder
from policy_composer.data.verify import open_dataset
from policy_composer.learning.checkpoint import CheckpointError
from policy_composer.policies.library import LeRobotSource, LibraryError, LibrarySources
from policy_composer.tasks.gear_assembly.expert import ExpertConfig, GearAssemblyExpert
from policy_composer.tasks.gear_assembly.spec import (
    ACTION_NAMES,
    CAMERA_NAMES,
    STATE_NAMES,
    EnvSettings,
    ExpertSettings,
)

RES = 64
BIN = Path(sys.executable).parent


def test_reloaded_dataset_equals_what_was_written(tmp_path):
    env = Stamped(gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=RES, camera_height=RES))
    root = tmp_path / "full"
    recorder = LeRobotRecorder(env, root, task="pick the gear")
    expert = GearAssemblyExpert(recorder, ExpertConfig())
    obs, _ = recorder.reset(seed=4)
    expert.reset(4)
    recorder.controller = "expert"
    written = {"state": [], "action": [], "head": [], "stage": []}
    for _ in range(25):
        action = expert.act(obs)
        written["state"].append(obs["extra"]["state"][0].numpy().copy())
        written["head"].append(obs["sensor_data"]["head"]["rgb"][0].numpy().copy())
        written["stage"].append(int(env.unwrapped.evaluate()["stage"][0]))
        written["action"].append(action.numpy().copy())
        obs, *_ = recorder.step(action)
    recorder.save_episode(success=False, seed=4)
    env.close()

    ds = open_dataset(root, required={"observation.images.head": (RES, RES, 3)}, fps=20)
    assert ds.num_episodes == 1 and ds.num_frames == 25
    assert ds.meta.features["observation.state"]["names"] == list(STATE_NAMES)
    assert ds.meta.features["action"]["names"] == list(ACTION_NAMES)
    frames = [ds[i] for i in range(25)]
    np.testing.assert_array_equal(np.stack([f["observation.state"].numpy() for f in frames]),
                                  np.stack(written["state"]))
    np.testing.assert_array_equal(np.stack([f["action"].numpy() for f in frames]), np.stack(written["action"]))
    assert [int(f["stage"]) for f in frames] == written["stage"]
    assert all(float(f["progress"]) == -1.0 for f in frames)  # failed (unfinished) episode: no progress target
    assert [bool(f["next.done"]) for f in frames] == [False] * 24 + [True]
    assert frames[0]["task"] == "pick the gear"
    # Video is lossy (h264): decoded frames match the rendered ones closely, and each is its own step's image (the
    # number stamped on it below the recorder), not a neighbour's of the same scene.
    decoded = np.stack([(f["observation.images.head"].permute(1, 2, 0).numpy() * 255) for f in frames])
    err = np.abs(decoded - np.stack(written["head"]).astype(np.float32)).mean(axis=(1, 2, 3))
    assert err.max() < 12.0, err  # crf 30, yuv420p at 64x64
    assert [read_stamp(image) for image in decoded] == list(range(25))


def test_dart_records_the_experts_own_commands_where_the_arm_was_sent_perturbed_ones(tmp_path, monkeypatch):
    """DART: the arm strays by the drifting offset, the expert corrects, and the LeRobot dataset holds the expert's
    labels, not what was sent."""
    sent = []
    act = GearAssemblyExpert.act

    def logged(self, obs=None):
        label = act(self, obs)
        sent.append((label.numpy(), self.executed.numpy()))
        return label

    monkeypatch.setattr(GearAssemblyExpert, "act", logged)
    recipe = load_recipe("gear-insertion-demos")
    recipe = replace(recipe, expert=replace(recipe.expert, noise_mm=3.0))
    sidecar = record_recipe(recipe, tmp_path / "dart", episodes=1, settings=EnvSettings(resolution=32),
                            progress=False)
    ds = open_dataset(tmp_path / "dart")
    actions = np.stack(ds.hf_dataset["action"])
    labels, executed = (np.stack(x[-len(actions):]) for x in zip(*sent))  # the kept episode's steps
    np.testing.assert_array_equal(actions, labels)
    strayed = np.abs(executed[:, :7] - labels[:, :7]).max(axis=1)
    assert strayed.max() > 5e-3, strayed  # radians: the arm was sent elsewhere
    np.testing.assert_array_equal(executed[:, 7], labels[:, 7])  # the gripper as the expert commands it
    assert sidecar["expert"]["noise_mm"] == 3.0 and sidecar["episodes"][0]["success"]


def test_insertion_demos_labels_and_variety(insertion_demos):
    ds = open_dataset(insertion_demos, required={f"observation.images.{c}": (RES, RES, 3) for c in CAMERA_NAMES})
    sidecar = json.loads((insertion_demos / "meta" / "policy_composer.json").read_text())
    assert ds.num_episodes == 2 and sidecar["recipe"] == "gear-insertion-demos"
    assert [e["seed"] for e in sidecar["episodes"]] == [0, 1] and all(e["success"] for e in sidecar["episodes"])
    progress = ds.hf_dataset["progress"]
    episode = ds.hf_dataset["episode_index"]
    frame = ds.hf_dataset["frame_index"]
    stages = set(int(s) for s in ds.hf_dataset["stage"])
    for ep in (0, 1):
        idx = [i for i, e in enumerate(episode) if int(e) == ep]
        T = len(idx)
        np.testing.assert_allclose([float(progress[i]) for i in idx], [int(frame[i]) / (T - 1) for i in idx], atol=1e-6)
    assert stages <= {2, 3} and 2 in stages  # recording starts at the pre-insertion pose
    assert {sidecar["controllers"][int(c)] for c in ds.hf_dataset["controller"]} == {"expert"}
    # Two demonstrations are not one path replayed: different starts and different lengths or actions.
    a0 = torch.stack([ds[i]["action"] for i in range(len(ds)) if int(episode[i]) == 0])
    a1 = torch.stack([ds[i]["action"] for i in range(len(ds)) if int(episode[i]) == 1])
    assert a0.shape != a1.shape or not torch.allclose(a0, a1, atol=1e-3)


def test_dataset_info_and_push_without_network(insertion_demos, monkeypatch):
    out = run_cli("dataset", "info", str(insertion_demos)).stdout
    assert ("episodes:    2" in out and "task done:   100% of episodes" in out and "head 64x64x3" in out
            and "fps: 20" in out)
    before = tree_digest(insertion_demos)
    res = run_cli("dataset", "push", str(insertion_demos), "--repo-id", "me/gears")
    assert res.returncode == 2 and "unreachable" in res.stderr and "intact" in res.stderr
    assert tree_digest(insertion_demos) == before
    with pytest.raises(ValueError, match="USER/NAME"):
        push_dataset(insertion_demos, "no-slash")
    # Reachable hub: the command hands the local dataset to LeRobotDataset.push_to_hub under the new repo id.
    calls = []
    monkeypatch.setattr("policy_composer.data.catalog._check_hub_reachable", lambda root: None)
    monkeypatch.setattr(LeRobotDataset, "push_to_hub", lambda self, **kw: calls.append((self.repo_id, self.root, kw)))
    assert push_dataset(insertion_demos, "me/gears", private=True) == "https://huggingface.co/datasets/me/gears"
    assert calls[0][0] == "me/gears" and Path(calls[0][1]) == insertion_demos and calls[0][2]["private"] is True
    assert calls[0][2]["dataset_description"] == card_fields(insertion_demos)["dataset_description"]
    monkeypatch.undo()  # the real reachability check, offline
    monkeypatch.setattr("huggingface_hub.constants.HF_HUB_OFFLINE", True)
    with pytest.raises(HubUnreachable, match="HF_HUB_OFFLINE"):
        push_dataset(insertion_demos, "me/gears")


def test_the_dataset_card_says_what_the_dataset_holds(insertion_demos, tmp_path):
    """The card `dataset push` uploads, built and checked offline: LeRobot's card with the recipe, the task, the
    cameras, what the labels mean, the success rate and the project version."""
    out = tmp_path / "README.md"
    res = run_cli("dataset", "card", str(insertion_demos), "--repo-id", "me/gears", "--out", str(out))
    assert res.returncode == 0, res.stderr
    card = out.read_text()
    for expected in ("This dataset was created using [LeRobot]", "- LeRobot", "- gear-assembly",
                     "**Recipe `gear-insertion-demos`.** Insertion from the pre-insertion pose",
                     "**Task.** Insert the gear held by the left gripper onto the peg held by the right arm.",
                     "2 episodes", "the task done in 100% of the episodes",
                     "`observation.images.left_forearm` (64x64x3)",
                     "- `stage`: how far the task is at this frame (0 pick, 1 move, 2 insert, 3 done)",
                     f"policy-composer {version('policy-composer')}", '"codebase_version": "v3.0"',
                     "visualize_dataset?path=me/gears"):
        assert expected in card, expected


def test_dataset_info_refuses_a_dataset_with_a_video_missing(insertion_demos, tmp_path):
    """A dataset whose episodes point to a video file that is gone is not reported as whole: exit 2, the file named."""
    broken = tmp_path / "broken"
    shutil.copytree(insertion_demos, broken)
    video = sorted((broken / "videos" / "observation.images.head").rglob("*.mp4"))[0]
    video.unlink()
    res = run_cli("dataset", "info", str(broken))
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"missing 1 video file(s) its episodes point to ({video.relative_to(broken)})" in res.stderr
    assert "Traceback" not in res.stderr


def test_bad_input_is_named(insertion_demos, tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        open_dataset(tmp_path / "nothing")
    (tmp_path / "plain").mkdir()
    with pytest.raises(DatasetError, match="not a LeRobot dataset"):
        open_dataset(tmp_path / "plain")
    with pytest.raises(DatasetError, match=r"lacks the camera\(s\) \['observation.images.wrist'\]"):
        open_dataset(insertion_demos, required={"observation.images.wrist": None})
    with pytest.raises(DatasetError, match=r"'observation.state' has shape \(16,\), expected \(14,\)"):
        open_dataset(insertion_demos, required={"observation.state": (14,)})
    with pytest.raises(DatasetError, match="recorded at 20 fps, expected 30"):
        open_dataset(insertion_demos, fps=30)
    old = tmp_path / "old"
    (old / "meta").mkdir(parents=True)
    (old / "meta" / "info.json").write_text(json.dumps({"codebase_version": "v2.1"}))
    with pytest.raises(DatasetError, match=f"reads v3.0 \\(lerobot {LEROBOT_VERSION}\\); convert it"):
        open_dataset(old)
    assert importlib.metadata.version("lerobot") == LEROBOT_VERSION  # the checks name the release installed
    env = gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=32, camera_height=32)
    with pytest.raises(DatasetError, match="--resume"):
        LeRobotRecorder(env, insertion_demos, task="x")
    with pytest.raises(DatasetError, match="cannot resume"):
        LeRobotRecorder(env, insertion_demos, task="x", resume=True)
    env.close()
    with pytest.raises(RecipeError, match="known recipes"):
        load_recipe("gear-nothing")
    assert available_recipes() == ["gear-controller-rollouts", "gear-full-task-demos", "gear-insertion-dagger",
                                   "gear-insertion-demos", "gear-move-dagger", "gear-transport-demos",
                                   "peg-controller-rollouts", "peg-full-task-demos", "peg-insertion-dagger",
                                   "peg-insertion-demos"]
    assert load_recipe("gear-full-task-demos").splits(8) == {"train": [0, 1, 2, 3, 4], "heldout": [5, 6, 7]}
    rollouts = load_recipe("gear-controller-rollouts")
    assert rollouts.cameras == ("head", "left_forearm")
    with pytest.raises(LibraryError, match="no controller named 'mp_fly'"):
        record_recipe(replace(rollouts, controllers=("mp_fly",)), tmp_path / "ro1", settings=EnvSettings(resolution=32))
    missing = LibrarySources(models={"dmp": str(tmp_path / "none"),
                                     "cnn": str(tmp_path / "none")})  # not results/models
    with pytest.raises(CheckpointError, match="no CNN policy in .* train them with `policy-composer train policy"):
        record_recipe(replace(rollouts, controllers=("cnn_insert",)), tmp_path / "ro2",
                      settings=EnvSettings(resolution=32), sources=missing)
    with pytest.raises(FileNotFoundError, match="no DMP library in .* train dmp"):  # the library's first missing
        record_recipe(rollouts, tmp_path / "ro3", settings=EnvSettings(resolution=32), sources=missing)
    with pytest.raises(RecipeError, match="must be a subset of GearAssembly-v1's"):
        replace(rollouts, cameras=("wrist",))
    with pytest.raises(RecipeError, match="goal must be one of"):
        replace(rollouts, goal="gear_seated")
    with pytest.raises(RecipeError, match="must be phases of the expert"):
        replace(rollouts, record_phases=("insert", "wave"))
    with pytest.raises(RecipeError, match="the dagger driver runs one controller"):
        replace(load_recipe("gear-insertion-dagger"), controllers=("cnn_insert", "mp_insert"))
    with pytest.raises(ValueError, match="labels must be one of"):
        ExpertSettings(labels="hand")
    with pytest.raises(RecipeError, match="no task 'stack-gears'"):
        replace(rollouts, task_name="stack-gears")


def test_controller_rollouts_name_their_controller(controller_rollouts):
    """The dynamics models' data: each controller from its own initiation set, every frame labelled with it."""
    root = controller_rollouts
    sidecar = json.loads((root / "meta" / "policy_composer.json").read_text())
    assert [e["controller_name"] for e in sidecar["episodes"]] == ["mp_pick", "mp_insert"]
    # The pick has no perception error, and the insertion's start (seed 1) holds the gear 0.3 mm off: both succeed.
    assert ([(e["seed"], e["outcome"], e["success"]) for e in sidecar["episodes"]]
            == [(0, "done", True), (1, "done", True)])
    ds = open_dataset(root, required={"observation.images.head": (32, 32, 3), "observation.images.left_forearm": None})
    assert "observation.images.right_forearm" not in ds.meta.features
    names = sidecar["controllers"]
    for ep, name in enumerate(("mp_pick", "mp_insert")):
        frames = ds.hf_dataset.filter(lambda r, ep=ep: r["episode_index"] == ep)
        assert {names[int(c)] for c in frames["controller"]} == {name}
        assert len(frames) == sidecar["episodes"][ep]["length"]
    assert summarize(root)["outcomes"] == {"mp_pick": {"done": 1}, "mp_insert": {"done": 1}}
    stages = np.array(ds.hf_dataset["stage"]).ravel()
    assert stages[0] == 0 and stages[-1] == 3  # the pick starts on the table; the insertion ends seated


def test_a_lerobot_policys_rollouts_record_with_the_cameras_it_reads(act_checkpoint, tmp_path):
    """A LeRobot policy gets its dynamics model's data like the library's own controllers."""
    checkpoint, _ = act_checkpoint
    recipe = replace(load_recipe("gear-controller-rollouts"), controllers=("lerobot_insert",))
    root = tmp_path / "rollouts"
    record_recipe(recipe, root, episodes=1, seed=1, settings=EnvSettings(resolution=32), progress=False,
                  sources=LibrarySources(lerobot=(LeRobotSource(str(checkpoint), "insert"),)))
    sidecar = json.loads((root / "meta" / "policy_composer.json").read_text())
    assert sidecar["controllers"] == ["lerobot_insert"] and len(sidecar["episodes"]) == 1
    assert sidecar["episodes"][0]["outcome"] in ("done", "failed", "stopped for safety")
    act_cameras = [k for k in json.loads((checkpoint / "config.json").read_text())["input_features"]
                   if k.startswith("observation.images.")]
    assert set(act_cameras) <= set(open_dataset(root).meta.camera_keys)  # right_forearm too, beyond the recipe's


def test_dropping_a_controllers_rollouts_keeps_the_others(controller_rollouts, tmp_path):
    root = tmp_path / "rollouts"
    shutil.copytree(controller_rollouts, root)
    before = open_dataset(root)
    pick_rows = before.hf_dataset.filter(lambda r: r["episode_index"] == 0)
    assert drop_controller(root, "mp_insert") == 1
    after = open_dataset(root)
    assert after.num_episodes == 1 and after.num_frames == len(pick_rows)
    np.testing.assert_array_equal(np.stack(after.hf_dataset["observation.state"]),
                                  np.stack(pick_rows["observation.state"]))
    assert [e["controller_name"]
            for e in json.loads((root / "meta" / "policy_composer.json").read_text())["episodes"]] == ["mp_pick"]
    with pytest.raises(DatasetError, match="no episodes of controller 'mp_insert'"):
        drop_controller(root, "mp_insert")


def test_journal_rolls_back_an_unfinished_save(insertion_demos, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(insertion_demos, root)
    before = tree_digest(root)
    journal.begin(root)
    # What a save killed half-way leaves: new files, rewritten metadata.
    (root / "data" / "chunk-000" / "file-009.parquet").write_bytes(b"PAR1 truncated")
    (root / "videos" / "observation.images.head" / "chunk-000" / "file-009.mp4").write_bytes(b"\x00")
    (root / "tmpabc").mkdir()
    (root / "tmpabc" / "x_streaming.mp4").write_bytes(b"\x00")
    info = json.loads((root / "meta" / "info.json").read_text())
    info["total_episodes"] += 1
    (root / "meta" / "info.json").write_text(json.dumps(info))
    assert journal.recover(root)
    assert tree_digest(root) == before and not journal.journal_dir(root).exists()
    assert open_dataset(root).num_episodes == 2


def _record_cmd(root: Path, episodes: int, *extra: str) -> list[str]:
    return [str(BIN / "policy-composer"), "record", "gear-insertion-demos", "--episodes", str(episodes),
            "--root", str(root), "--resolution", str(RES), *extra]


def _wait_for_episodes(proc: subprocess.Popen, root: Path, n: int, timeout: float = 300) -> None:
    sidecar = root / "meta" / "policy_composer.json"
    t0 = time.time()
    while time.time() - t0 < timeout:
        if sidecar.is_file():
            try:
                if len(json.loads(sidecar.read_text())["episodes"]) >= n:
                    return
            except json.JSONDecodeError:
                pass
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else "recorder exited early"
        time.sleep(0.2)
    raise TimeoutError(f"no {n} episodes recorded in {timeout} s")


@pytest.mark.parametrize("sig, workers", [("SIGKILL", 2), ("SIGINT", 1)])
def test_interrupted_recording_keeps_finished_episodes_and_resumes(insertion_demos, tmp_path, sig, workers):
    """Killed or stopped after its first episode, a recording (on one process or several) keeps that episode, and
    resumed, it records what an uninterrupted serial recording of the same settings (the insertion_demos fixture)
    does, frame for frame."""
    root = tmp_path / "demos"
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    # The recorder as a foreground process would run: a child inherits an ignored SIGINT (as background jobs
    # have it), in which case Python never turns Ctrl-C into KeyboardInterrupt.
    proc = subprocess.Popen(_record_cmd(root, 2, "--workers", str(workers)), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    _wait_for_episodes(proc, root, 1)
    children = psutil.Process(proc.pid).children(recursive=True)
    proc.send_signal(getattr(signal, sig))
    rc = proc.wait(timeout=120)
    assert rc == (-9 if sig == "SIGKILL" else 130), proc.stderr.read()
    _, alive = psutil.wait_procs(children, timeout=30)
    assert not alive, f"workers left running after the recorder stopped: {alive}"
    # Every finished episode loads with plain LeRobotDataset (after rolling back a save cut short, if any).
    ds = open_dataset(root)
    kept = ds.num_episodes
    # One worker stops after the first episode; with two, the second may have finished meanwhile and been saved.
    assert kept == 1 or (workers > 1 and kept == 2)
    assert ds.num_frames == sum(json.loads((root / "meta/policy_composer.json").read_text())[
        "episodes"][i]["length"] for i in range(kept))
    resumed = run_cli(*_record_cmd(root, 2, "--resume", "--workers", str(workers))[1:])
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    ds = open_dataset(root)
    sidecar = json.loads((root / "meta" / "policy_composer.json").read_text())
    seeds = [e["seed"] for e in sidecar["episodes"]]
    assert ds.num_episodes == 2 and len(set(seeds)) == 2 and seeds == sorted(seeds)
    assert sorted(set(int(e) for e in ds.hf_dataset["episode_index"])) == [0, 1]
    assert ds[len(ds) - 1]["observation.images.head"].shape == (3, RES, RES)
    uninterrupted = open_dataset(insertion_demos)
    assert seeds == [e["seed"] for e in json.loads((insertion_demos / "meta" / "policy_composer.json").read_text())[
        "episodes"]]
    for column in ("observation.state", "action", "episode_index", "frame_index"):
        assert torch.equal(torch.as_tensor(np.stack(ds.hf_dataset[column])),
                           torch.as_tensor(np.stack(uninterrupted.hf_dataset[column]))), column
    last = len(ds) - 1
    assert torch.equal(ds[last]["observation.images.head"], uninterrupted[last]["observation.images.head"])


def test_lerobot_trainer_runs_on_our_dataset(act_checkpoint):
    """lerobot's own trainer (ACT, 2 steps) reads the format: a check of the files, not of our reader."""
    checkpoint, res = act_checkpoint
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-3000:]
    assert "step:2" in log and "End of training" in log
    assert (checkpoint / "model.safetensors").is_file()


def test_a_demonstration_dataset_is_told_by_its_controller(insertion_demos):
    """Demonstrations name no rollout controller per episode: their frames' controller (the expert) tells them."""
    with pytest.raises(DatasetError, match="every episode of .* is expert's: dropping them would leave no dataset"):
        drop_controller(insertion_demos, "expert")
    with pytest.raises(DatasetError, match="no episodes of controller 'mp_pick' \\(its episodes are expert's\\)"):
        drop_controller(insertion_demos, "mp_pick")


def test_a_dataset_edited_by_lerobot_says_what_it_lost(insertion_demos, tmp_path):
    """lerobot-edit-dataset writes a new dataset without the project's metadata: it loads, and `dataset info`, the
    card and `dataset drop` say what is unknown instead of dropping lines or claiming what they cannot know."""
    edited = tmp_path / "edited"
    delete_episodes(open_dataset(insertion_demos), [0], output_dir=edited)
    assert open_dataset(edited).num_episodes == 1
    res = run_cli("dataset", "info", str(edited))
    assert res.returncode == 0, res.stderr
    assert "provenance:  meta/policy_composer.json is missing: this GearAssembly-v1 recording was edited" in res.stdout
    description = card_fields(edited)["dataset_description"]
    assert "edited by a tool that does not carry it" in description and "Recorded with" not in description
    with pytest.raises(DatasetError, match="cannot tell .* episodes by controller: meta/policy_composer.json is"):
        drop_controller(edited, "expert")


def test_the_card_of_a_dataset_recorded_elsewhere_describes_only_what_it_holds(tmp_path):
    """A 7-D, one-camera LeRobot dataset this project did not record: the card claims no task, arms or labels."""
    root = tmp_path / "so100"
    features = {"observation.images.front": {"dtype": "video", "shape": (32, 32, 3),
                                             "names": ["height", "width", "channels"]},
                "observation.state": {"dtype": "float32", "shape": (7,), "names": [f"j{i}" for i in range(7)]},
                "action": {"dtype": "float32", "shape": (7,), "names": [f"j{i}" for i in range(7)]}}
    ds = LeRobotDataset.create("me/so100", fps=30, features=features, root=root, robot_type="so100",
                               use_videos=True)
    rng = np.random.default_rng(0)
    for _ in range(2):
        for _ in range(5):
            ds.add_frame({"observation.images.front": rng.integers(0, 255, (32, 32, 3), dtype=np.uint8),
                          "observation.state": rng.random(7, dtype=np.float32),
                          "action": rng.random(7, dtype=np.float32), "task": "fold"})
        ds.save_episode()
    ds.finalize()
    assert "not recorded by policy-composer" in summarize(root)["provenance"]
    out = tmp_path / "README.md"
    res = run_cli("dataset", "card", str(root), "--out", str(out))
    assert res.returncode == 0, res.stderr
    card = out.read_text()
    for absent in ("GearAssembly", "both arms", "policy-composer 0", "gear-assembly", "`stage`"):
        assert absent not in card, absent
    for present in ("robot type `so100`", "2 episodes, 10 frames at 30 fps", "`observation.images.front` (32x32x3)",
                    "- `observation.state`: float32 [7]"):
        assert present in card, present
