"""`policy-composer library add`: a LeRobot checkpoint gets its rollouts, its dynamics model and its Table I cell, and
the selector can then choose it."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from conftest import run_cli

from policy_composer.app.adding import add_lerobot_controller
from policy_composer.policies.library import LeRobotSource, LibraryError
from policy_composer.selector.configuration import DynamicsConfig, GoalScoreConfig, VAEConfig
from policy_composer.selector.train import train_goal_scores, train_world_model
from policy_composer.selector.world_model import WorldModel


@pytest.mark.parametrize("policy", ["act", "cnn_mdn"])
def test_a_lerobot_checkpoint_joins_the_library(policy, controller_rollouts, full_task_demos, tmp_path, request):
    """ACT's checkpoint, and the paper's policy trained by lerobot-train through its plugin."""
    checkpoint, res = request.getfixturevalue(f"{policy}_checkpoint")
    name = f"{policy}_insert"
    assert res.returncode == 0, (res.stdout + res.stderr)[-2000:]
    rollouts, models = tmp_path / "rollouts", tmp_path / "world"
    shutil.copytree(controller_rollouts, rollouts)
    train_world_model(rollouts, full_task_demos, models, VAEConfig(image_size=32, latent_dim=8, epochs=2),
                      DynamicsConfig(hidden_dim=32, num_mixtures=2, frame_skip=3, epochs=2), progress=False)
    train_goal_scores(full_task_demos, models, ("left_forearm",),
                      GoalScoreConfig(image_size=32, hidden_dim=32, num_mixtures=2, epochs=2), progress=False)
    source = LeRobotSource(str(checkpoint), "insert", name)

    with pytest.raises(LibraryError, match="'mp_insert' is already a controller of the library"):
        add_lerobot_controller(LeRobotSource(str(checkpoint), "insert", "mp_insert"), rollouts, full_task_demos,
                               models, 1, 1, 200, progress=False)
    with pytest.raises(LibraryError, match="holds no world model to add to; train it first"):
        add_lerobot_controller(source, rollouts, full_task_demos, tmp_path / "none", 1, 1, 200, progress=False)

    added = add_lerobot_controller(source, rollouts, full_task_demos, models, episodes=1, trials=1, seed=200,
                                   progress=False)
    assert added["controller"] == name and added["cell"].trials == 1
    sidecar = json.loads((rollouts / "meta" / "policy_composer.json").read_text())
    assert sidecar["controllers"] == ["mp_pick", "mp_insert", name]  # the library's rollouts are kept
    assert [e["controller_name"] for e in sidecar["episodes"]].count(name) == 1
    world = WorldModel.load(models)
    assert set(world.dynamics) == {"mp_pick", "mp_insert", name}
    assert world.dynamics[name].config.frame_skip == 3  # one look-ahead for every controller
    decision = world.selector(horizon=2, samples=2, seed=0).decide(torch.zeros(1, 8))
    assert torch.isfinite(decision.scores).all() and name in decision.names


def test_a_lerobot_checkpoint_gets_its_own_row_in_table_one(act_checkpoint, tmp_path):
    """`evaluate controllers --lerobot` adds a row named after the checkpoint's policy type, beside MP, DMP, CNN."""
    checkpoint, _ = act_checkpoint
    res = run_cli("evaluate", "controllers", "--kinds", "", "--lerobot", f"{checkpoint}:insert", "--trials", "1",
                  "--resolution", "32", "--workers", "1", "--senses", "oracle", "--out", str(tmp_path))
    assert res.returncode == 0, res.stderr[-2000:]
    table = (tmp_path / "controllers.md").read_text()
    row = next(line for line in table.splitlines() if line.startswith("| ACT (LeRobot) |"))
    assert row.count("/1 (95% CI") == 1 and row.count("; paper -") == 4  # the insert column only
