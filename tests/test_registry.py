"""The registry of controller kinds: one registration puts a new kind in the library, the recipes, Table I and the
command line (docs/adding-a-controller.md's wiggle kind, registered on its config)."""

from __future__ import annotations

import importlib
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from policy_composer.app.cli import build_parser
from policy_composer.app.record import recipe_controllers
from policy_composer.data.recipes import load_recipe
from policy_composer.policies import registry
from policy_composer.policies.library import LibrarySources, all_names, build_library, cameras_needed, names_of_kind
from policy_composer.policies.registry import LibraryError, get_kind, register_kind
from policy_composer.policies.subtasks import LearnedController


class WiggleInsert(LearnedController):
    def predict(self, obs):
        q = self.arm_qpos(obs)
        q[6] += self.amplitude * (-1) ** self._steps
        return q, -1.0


@dataclass
class WiggleConfig:
    amplitude: float = 0.02


def build(env, subtask, model, config, max_grasp_offset):
    controller = WiggleInsert(env, subtask, name=f"wiggle_{subtask.name}", max_steps=80)
    controller.amplitude = config.amplitude
    return controller


def load(path):
    return {"camera": "right_forearm", "path": path}


def cameras(model):
    return (model["camera"],)


@pytest.fixture
def wiggle():
    saved = dict(registry._KINDS)
    register_kind("wiggle", "Wiggle", ("insert",), trained=True, module=__name__)(WiggleConfig)
    yield registry.get_kind("wiggle")
    registry._KINDS.clear()
    registry._KINDS.update(saved)


def test_the_built_in_kinds():
    assert [(k.name, k.label, k.subtasks) for k in registry.kinds().values()] == [
        ("mp", "MP", ("pick", "move", "insert", "regrasp")), ("dmp", "DMP", ("pick", "move", "insert")),
        ("cnn", "CNN", ("pick", "move", "insert"))]
    assert all_names() == ("mp_pick", "mp_move", "mp_insert", "mp_regrasp", "dmp_pick", "dmp_move", "dmp_insert",
                           "cnn_pick", "cnn_move", "cnn_insert")
    assert names_of_kind("dmp") == names_of_kind("DMP") == ("dmp_pick", "dmp_move", "dmp_insert")
    with pytest.raises(LibraryError, match="unknown controller kind 'RL'; the library has MP, DMP, CNN"):
        get_kind("RL")


def test_one_registration_reaches_every_reader(wiggle, state_env, tmp_path):
    assert "wiggle_insert" in all_names() and names_of_kind("Wiggle") == ("wiggle_insert",)
    assert recipe_controllers(load_recipe("gear-controller-rollouts"))[-1] == "wiggle_insert"
    sources = LibrarySources(models={"wiggle": str(tmp_path)})
    assert cameras_needed(["mp_pick", "wiggle_insert"], sources) == ("right_forearm",)
    controller = build_library(state_env, ["wiggle_insert"], sources)["wiggle_insert"]
    assert isinstance(controller, WiggleInsert) and controller.subtask.name == "insert" and controller.max_steps == 80
    assert controller.amplitude == WiggleConfig.amplitude  # built with its kind's configuration
    args = build_parser().parse_args(["compose", "--wiggle", "elsewhere"])
    assert args.wiggle == "elsewhere" and args.cnn == "results/models/cnn"
    assert build_parser().parse_args(["evaluate", "controllers"]).kinds == "MP,DMP,CNN,Wiggle"
    with pytest.raises(LibraryError, match="registered twice"):
        register_kind("wiggle", "Wiggle", ("pick",), module=__name__)(WiggleConfig)


def test_the_documented_kind_runs_as_written(state_env, tmp_path, monkeypatch):
    """docs/adding-a-controller.md's wiggle kind, its two files copied out of the page: registered on its config, its
    controller module found beside it by convention, built with the config's defaults."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "adding-a-controller.md").read_text()
    package = tmp_path / "wiggle_kind"
    package.mkdir()
    (package / "__init__.py").write_text("")
    for name in ("configuration_wiggle", "controller"):
        code = re.search(rf"```python\n# policies/wiggle/{name}\.py\n(.*?)```", page, re.S).group(1)
        (package / f"{name}.py").write_text(code)
    monkeypatch.syspath_prepend(str(tmp_path))
    saved = dict(registry._KINDS)
    try:
        config = importlib.import_module("wiggle_kind.configuration_wiggle").WiggleConfig
        kind = get_kind("wiggle")
        assert kind.config is config and not kind.trained and kind.controller_names == ("wiggle_insert",)
        controller = build_library(state_env, ["wiggle_insert"], LibrarySources())["wiggle_insert"]
        assert type(controller).__module__ == "wiggle_kind.controller" and controller.amplitude == config.amplitude
    finally:
        registry._KINDS.clear()
        registry._KINDS.update(saved)
