"""The scripted expert completes the full task, whatever its grasp offset."""

import pytest

from policy_composer.tasks.gear_expert import PHASES, ExpertConfig, GearAssemblyExpert
from policy_composer.tasks.rollout import run_episode


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


def test_a_dart_demonstrator_is_sent_off_its_course_and_corrects_it(state_env):
    """With a perturbation, the arm is sent commands off the demonstrator's own while it inserts (and only then);
    the demonstrator closes the loop on the gear and still seats it, so its recorded commands are corrections."""
    import numpy as np

    u = state_env.unwrapped
    obs, _ = state_env.reset(seed=9, options={"start": "pre_insertion"})
    expert = GearAssemblyExpert(state_env, ExpertConfig(teleop=True, perturbation=0.002))
    expert.reset(9)
    gaps = []
    for _ in range(150):
        if expert.done:
            break
        action = expert.act(obs)
        if expert.phase == "insert":
            gaps.append(float(np.abs(expert.executed - action).max()))
        else:
            assert expert.executed is None
        obs, _, _, _, info = state_env.step(u.flat_to_dict_action(action if expert.executed is None
                                                                   else expert.executed))
    assert bool(info["success"][0]) and len(gaps) > 10 and max(gaps) > 1e-3 and min(gaps) < max(gaps)
