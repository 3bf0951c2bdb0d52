"""DMP controllers: a primitive reproduces its demonstration and reaches new goals; the library round-trips;
learned from the planner, the DMPs complete the subtasks."""

from __future__ import annotations

import numpy as np
import pytest

from policy_composer.policies.arm import Outcome, run_activation
from policy_composer.policies.dmp.controller import (
    DMPConfig,
    DMPController,
    DMPLibrary,
    fit_dmp_library,
    fit_primitive,
    rollout,
)
from policy_composer.policies.mp.planning import time_parameterize
from policy_composer.tasks.gear_assembly.subtasks import SUBTASKS


def test_primitive_reproduces_its_demonstration_and_reaches_a_new_goal():
    config = DMPConfig()
    start, via, goal = (np.zeros(7), np.array([0.4, -0.3, 0.2, -0.5, 0.1, 0.6, -0.2]),
                        np.array([0.8, 0.1, 0.3, -1.0, 0.2, 0.9, 0.1]))
    demo = np.vstack([time_parameterize(np.stack([start, via, goal]), config.dt)])
    demo = np.vstack([start, demo])
    prim = fit_primitive([demo], config)
    again = rollout(prim, start, goal, config)  # may run slower than the demo (never over the speed limit)
    phase = np.linspace(0, 1, 50)
    def resample(y):
        return np.stack([np.interp(phase, np.linspace(0, 1, len(y)), y[:, j]) for j in range(7)], axis=1)
    assert np.abs(resample(again) - resample(demo)).max() < 0.08  # the demonstrated shape, in its own time
    straight = start + phase[:, None] * (goal - start)
    assert np.abs(resample(demo) - straight).max() > 0.15  # (which is not a straight line)
    assert np.abs(again[-1] - goal).max() < 0.01
    new_goal = goal + [0.2, -0.1, 0.1, 0.2, 0.0, -0.2, 0.3]
    moved = rollout(prim, start + 0.05, new_goal, config)
    assert np.abs(moved[0] - (start + 0.05)).max() < 1e-6 and np.abs(moved[-1] - new_goal).max() < 0.01


def test_dmps_learned_from_the_planner_complete_the_task(state_env, tmp_path):
    library = fit_dmp_library(state_env, seeds=[100, 101], progress=False)
    library.save(tmp_path)
    loaded = DMPLibrary.load(tmp_path)
    for name, prims in library.primitives.items():
        for a, b in zip(prims, loaded.primitives[name]):
            assert (a is None) == (b is None) and (a is None or np.array_equal(a.weights, b.weights))
    obs, _ = state_env.reset(seed=1)
    u = state_env.unwrapped
    for name in ("pick", "move", "insert"):
        controller = DMPController(state_env, SUBTASKS[name], loaded, grasp_offset=0.0)
        obs = run_activation(state_env, controller, obs, seed=1, max_steps=300)
        assert controller.outcome is Outcome.DONE, (name, controller.reason)
    assert bool(u.evaluate()["success"][0])


def test_library_errors_are_clear(state_env, tmp_path):
    with pytest.raises(FileNotFoundError, match="no DMP library.*policy-composer train dmp"):
        DMPLibrary.load(tmp_path)
    with pytest.raises(ValueError, match="no primitives for subtask 'pick'"):
        DMPController(state_env, SUBTASKS["pick"], DMPLibrary(DMPConfig()))
