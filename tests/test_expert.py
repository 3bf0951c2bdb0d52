"""The scripted expert completes the full task, whatever its grasp offset."""

import pytest

from policy_composer.tasks.gear_assembly.expert import ExpertConfig, GearAssemblyExpert
from policy_composer.tasks.gear_assembly.rollout import run_episode
from policy_composer.tasks.gear_assembly.spec import EXPERT_PHASES as PHASES


@pytest.mark.parametrize("seed", [0, 3, 7])
def test_expert_succeeds_on_fixed_seeds(state_env, seed):
    expert = GearAssemblyExpert(state_env)
    stages = []
    result = run_episode(state_env, expert, seed, on_step=lambda _, info: stages.append(int(info["stage"][0])))
    assert result.success, f"seed {seed}: expert failed in phase {expert.phase}"
    # The task passes through pick (0), move (1), insert (2) and done (3), in that order.
    assert sorted(set(stages)) == [0, 1, 2, 3]
    assert stages == sorted(stages)


def test_grasp_offset_varies_within_its_bound(state_env):
    expert = GearAssemblyExpert(state_env, ExpertConfig(grasp_offset=0.01))
    offsets = []
    for seed in range(8):
        state_env.reset(seed=seed)
        expert.reset(seed)
        offsets.append(expert.grasp_offset)
    assert max(abs(o) for o in offsets) <= 0.01
    assert max(offsets) - min(offsets) > 0.005


def test_phase_names_are_ordered():
    assert PHASES[0] == "approach" and PHASES[-1] == "done"


def test_open_loop_insertion_fails_when_the_grasp_offset_exceeds_the_clearance(state_env):
    """Seed 3 draws a ~10 mm grasp offset (clearance 2 mm): closed loop seats the gear, open loop does not."""
    open_loop = GearAssemblyExpert(state_env, ExpertConfig(closed_loop=False))
    result = run_episode(state_env, open_loop, 3)
    assert abs(open_loop.grasp_offset) > 4 * state_env.unwrapped.gear_spec.clearance
    assert not result.success
    assert run_episode(state_env, GearAssemblyExpert(state_env), 3).success
