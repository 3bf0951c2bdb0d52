"""The random-walk MDP benchmark and the selector core: hand-computed choices, analytic expectations, seeding."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from policy_composer.app.mdp import MDPConfig, expected_activations, make_selector, run_mdp
from policy_composer.policies.base import InitiationError
from policy_composer.selector.core import Selector
from policy_composer.tasks.random_walk.controllers import RANDOM_WALK_OPTIONS, random_walk_controllers
from policy_composer.tasks.random_walk.env import RIGHT, RandomWalkEnv
from policy_composer.tasks.random_walk.models import TabularDynamics, model_states


def test_env_and_controllers():
    env = RandomWalkEnv(19, start=19)
    assert env.reset(seed=0)[0] == 19
    state, reward, terminated, _, info = env.step(RIGHT)
    assert (state, reward, terminated, info["success"]) == (20, 1.0, True, True)
    assert RandomWalkEnv(19).start == 10 and RandomWalkEnv(100).start == 50
    with pytest.raises(ValueError, match="non-terminal state in 1..19"):
        RandomWalkEnv(19, start=0)
    c1 = random_walk_controllers(19)[0]
    with pytest.raises(InitiationError, match="c1 cannot start here.*state 20 of 0..20"):
        c1.start(20)
    c1.start(5, seed=0)
    assert c1.act(5) == RIGHT and c1.done(20)


def test_selector_matches_hand_computed_expectation():
    """n = 2, no noise, from state s of 19: E[G] = (s + 1 + (1 - beta) * d) / 20 for a controller going d = +-1."""
    s = 7
    sel = make_selector(MDPConfig(num_states=19, p_dyn=0.0, p_goal=0.0, horizon=2, samples=20000, seed=1))
    d = sel.decide(model_states([s]))
    hand = {"c1": (s + 1.8) / 20, "c2": (s + 1.5) / 20, "c3": (s + 1.1) / 20, "c4": s / 20, "c5": (s - 1.5) / 20}
    for j, name in enumerate(d.names):
        assert float(d.scores[0, j]) == pytest.approx(hand[name], abs=0.004)
    assert d.chosen() == max(hand, key=hand.get) == "c1"
    # Outside an initiation set a controller is never chosen; with no controller applicable there is no choice.
    d = sel.decide(model_states([s, s, s]), torch.tensor([[0, 1, 1, 1, 1], [0, 0, 0, 1, 1], [0, 0, 0, 0, 0]]).bool())
    assert [d.chosen(b) for b in range(3)] == ["c2", "c4", None]
    assert d.log(1)["scores"]["c1"] is None and d.log(1)["choice"] == "c4"


def test_selector_is_generic_over_the_goal():
    """The same selector with a goal at the left end picks the left-going controller."""

    class LeftGoal:
        def score(self, states, generator):
            return 1.0 - states[:, 0].float() / 20

    dynamics = {o.name: TabularDynamics(o, 19) for o in RANDOM_WALK_OPTIONS}
    assert Selector(dynamics, LeftGoal(), horizon=3, samples=64, seed=0).decide(model_states([10])).chosen() == "c5"


def test_never_picks_outside_the_initiation_set():
    gen = torch.Generator().manual_seed(0)
    sel = make_selector(MDPConfig(num_states=19, p_dyn=0.5, p_goal=0.5, samples=4, seed=3))
    states = torch.randint(1, 20, (400,), generator=gen)
    applicable = torch.rand(400, 5, generator=gen) < 0.4
    d = sel.decide(model_states(states), applicable)
    has_any = applicable.any(dim=1)
    assert (d.choice[~has_any] == -1).all()
    assert applicable[has_any.nonzero().flatten(), d.choice[has_any]].all()


def test_noiseless_activations_match_the_analytic_expectation():
    """With exact models the selector runs c1 throughout: E[activations] = 1 + (d - 1) * 0.2."""
    result = run_mdp(MDPConfig(num_states=19, start=1, p_dyn=0.0, p_goal=0.0, samples=64, episodes=2000, seed=5))
    expected = expected_activations(19, 1, 0.2)
    se = np.sqrt(18 * 0.2 * 0.8 / 2000)
    assert result.success.all()
    assert abs(result.mean_activations - expected) < 4 * se, (result.mean_activations, expected)


def test_noise_hurts_and_seeded_runs_repeat():
    cfg = MDPConfig(num_states=19, start=1, p_dyn=0.4, p_goal=0.4, episodes=300, seed=11)
    a, b = run_mdp(cfg, trace=True), run_mdp(cfg, trace=True)
    np.testing.assert_array_equal(a.activations, b.activations)
    assert a.trace == b.trace and a.trace[0]["state"] == 1
    other = run_mdp(MDPConfig(num_states=19, start=1, p_dyn=0.4, p_goal=0.4, episodes=300, seed=12))
    assert not np.array_equal(a.activations, other.activations)
    exact = run_mdp(MDPConfig(num_states=19, start=1, p_dyn=0.0, p_goal=0.0, episodes=300, seed=11))
    assert a.mean_activations > exact.mean_activations + 0.5 and a.success.mean() < 1.0
