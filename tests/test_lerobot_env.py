"""GearAssembly as a LeRobot env: LeRobot's conventions in the env, and `lerobot-eval` running a checkpoint trained
on our dataset through the `lerobot_env_gear_assembly` plugin."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest
from conftest import lerobot, run_cli
from lerobot.envs.utils import preprocess_observation
from lerobot_env_gear_assembly import GearAssemblyEnv
from rerun.experimental import RrdReader

from policy_composer.tasks.gear_assembly.expert import GearAssemblyExpert
from policy_composer.tasks.gear_assembly.lerobot_env import TASKS, GearAssemblyLeRobotEnv
from policy_composer.tasks.gear_assembly.spec import CAMERA_NAMES


@pytest.fixture(scope="module")
def insert_env():
    env = GearAssemblyLeRobotEnv("insert", resolution=32)
    yield env
    env.close()


def test_observations_and_success_in_lerobots_conventions(insert_env):
    """LeRobot's preprocessing turns the env's observation into our datasets' feature names, and `is_success` turns
    true when the demonstrator seats the gear."""
    obs, info = insert_env.reset(seed=3)
    assert insert_env.observation_space.contains(obs) and info == {"is_success": False}
    batch = preprocess_observation({"pixels": {c: im[None] for c, im in obs["pixels"].items()},
                                    "agent_pos": obs["agent_pos"][None]})
    assert sorted(batch) == sorted([f"observation.images.{c}" for c in CAMERA_NAMES] + ["observation.state"])
    assert batch["observation.images.head"].shape == (1, 3, 32, 32) and batch["observation.state"].shape == (1, 16)
    assert insert_env.render().shape == (32, 32 * 3, 3) and insert_env.metadata["render_fps"] == 20
    expert = GearAssemblyExpert(insert_env.env)  # the insertion demos' demonstrator, on the same start
    expert.reset(3)
    for _ in range(TASKS["insert"][1]):
        obs, reward, terminated, truncated, info = insert_env.step(expert.act(None).numpy())
        if terminated or truncated:
            break
    assert terminated and not truncated and info == {"is_success": True}, (insert_env._steps, info)


def test_the_full_task_starts_from_the_table_and_is_cut_off_unfinished():
    """`--env.task=full`: the gear on the table, not in the hand; an episode that does not seat it ends truncated at
    its step limit, not a success."""
    env = GearAssemblyLeRobotEnv("full", resolution=32, cameras=("head",), max_episode_steps=5)
    try:
        obs, info = env.reset(seed=3)
        flags = env.env.unwrapped.evaluate()
        assert int(flags["stage"][0]) == 0 and not bool(flags["gear_grasped"][0]) and info == {"is_success": False}
        assert env.task_description == TASKS["full"][2] and sorted(obs["pixels"]) == ["head"]
        ends = [env.step(obs["agent_pos"])[2:] for _ in range(5)]  # the joints held where they are
        assert [(terminated, truncated) for terminated, truncated, _ in ends] == [(False, False)] * 4 + [(False, True)]
        assert ends[-1][2] == {"is_success": False}
    finally:
        env.close()


def test_bad_task_or_camera_is_named():
    with pytest.raises(ValueError, match="no task 'stack': choose one of insert, full"):
        GearAssemblyLeRobotEnv("stack")
    with pytest.raises(ValueError, match="cameras are head, left_forearm, right_forearm, not \\['wrist'\\]"):
        GearAssemblyLeRobotEnv("insert", cameras=("wrist",))
    with pytest.raises(ValueError, match="at least one step, not 0 \\(--env.episode_length\\)"):
        GearAssemblyLeRobotEnv("insert", max_episode_steps=0)


def test_lerobot_eval_runs_a_checkpoint_trained_on_our_dataset(act_checkpoint, tmp_path):
    """`lerobot-eval --env.type=gear_assembly` finds the env through LeRobot's plugin discovery, runs two episodes
    side by side (--eval.batch_size=2), cut off at --env.episode_length, and writes its results and videos."""
    checkpoint, trained = act_checkpoint
    assert trained.returncode == 0, (trained.stdout + trained.stderr)[-2000:]
    out = tmp_path / "eval"
    res = lerobot("lerobot-eval", f"--policy.path={checkpoint}", "--policy.device=cpu", "--env.type=gear_assembly",
                  "--env.task=insert", "--env.resolution=64", "--env.episode_length=25", "--eval.n_episodes=2",
                  "--eval.batch_size=2", "--eval.use_async_envs=false", f"--output_dir={out}", "--seed=500")
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    info = json.loads((out / "eval_info.json").read_text())
    (task,) = info["per_task"]
    metrics = task["metrics"]
    assert task["task_group"] == "gear_assembly" and info["overall"]["n_episodes"] == 2, info["overall"]
    assert len(metrics["successes"]) == 2 and all(isinstance(s, bool) for s in metrics["successes"]), metrics
    videos = sorted(out.rglob("*.mp4"))
    assert np.isfinite(metrics["sum_rewards"]).all() and len(videos) == 2
    assert all(av.open(str(v)).streams.video[0].frames <= 26 for v in videos)  # cut off at 25 steps (and the start)


def test_lerobot_eval_says_when_the_policy_was_trained_on_other_images(act_checkpoint, monkeypatch, caplog):
    """A checkpoint trained on 64-px images, evaluated on 128-px ones: the plugin says so, with the fix, before the
    run (it reads lerobot-eval's --policy.path the way lerobot does)."""
    checkpoint, _ = act_checkpoint
    assert GearAssemblyEnv(resolution=64).policy_mismatches(checkpoint) == []
    assert GearAssemblyEnv(resolution=64, cameras=["head"]).policy_mismatches(checkpoint) == [
        f"it reads the {c} camera, which --env.cameras leaves out" for c in ("left_forearm", "right_forearm")]
    monkeypatch.setattr(sys, "argv", ["lerobot-eval", f"--policy.path={checkpoint}", "--env.type=gear_assembly"])
    with caplog.at_level("WARNING"):
        envs = GearAssemblyEnv(resolution=128).create_envs(n_envs=1)
    envs["gear_assembly"][0].close()
    warned = [r.getMessage() for r in caplog.records if "will not see what it was trained on" in r.getMessage()]
    assert len(warned) == 3 and all("64x64" in w and "--env.resolution=64" in w for w in warned), warned


def recorded_entities(rrd: Path) -> set[str]:
    return {str(c.entity_path) for c in RrdReader(rrd).store().schema().component_columns()}


def test_lerobots_viewer_opens_our_dataset(insertion_demos, tmp_path):
    """`lerobot-dataset-viz` reads a recorded dataset offline and saves a rerun recording with every camera, the
    state, the action and the success labels; `dataset view` adds the project's own labels on the same timeline."""
    cmd = [str(Path(sys.executable).parent / "lerobot-dataset-viz"), f"--repo-id=local/{insertion_demos.name}",
           f"--root={insertion_demos}", "--episode-index=1", "--save=1", f"--output-dir={tmp_path / 'lerobot'}",
           "--num-workers=0"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    cameras = {f"/observation.images.{c}" for c in CAMERA_NAMES}
    lerobots = recorded_entities(tmp_path / "lerobot" / "local_gear-insertion-demos_episode_1.rrd")
    assert cameras | {"/state", "/action", "/next.success", "/next.done"} <= lerobots, sorted(lerobots)
    res = run_cli("dataset", "view", str(insertion_demos), "--episode", "1", "--out", str(tmp_path / "ours"))
    assert res.returncode == 0, res.stderr[-3000:]
    ours = recorded_entities(tmp_path / "ours" / "local_gear-insertion-demos_episode_1.rrd")
    assert lerobots | {"/progress", "/stage", "/controller"} <= ours, sorted(ours)
    res = run_cli("dataset", "view", str(insertion_demos), "--episode", "5")
    assert res.returncode == 2 and "has episodes 0 to 1, not 5" in res.stderr, res.stderr[-2000:]


@pytest.mark.parametrize("flag, message", [
    ("--env.resolution=0", "--env.resolution must be between 16 and 512 pixels, not 0"),
    ("--env.cameras=[wrist]",
     "GearAssembly's cameras are head, left_forearm, right_forearm, not ['wrist'] (--env.cameras)"),
    ("--env.task=stack", "GearAssembly has no task 'stack': choose one of insert, full (--env.task)"),
])
def test_lerobot_eval_names_a_bad_env_setting_in_one_line(tmp_path, flag, message):
    """Under LeRobot's own command the plugin's refusal is one line and exit 2, before the policy loads (there is
    none here), not the parser's traceback."""
    res = lerobot("lerobot-eval", f"--policy.path={tmp_path}", "--env.type=gear_assembly", flag, timeout=300)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stderr.strip().splitlines()[-1] == f"error: {message}"
