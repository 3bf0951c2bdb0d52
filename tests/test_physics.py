"""The gear seats on the peg when released aligned, and not when released off by more than the clearance; the grasp
flag is ManiSkill's."""

import gymnasium as gym
import pytest
import torch
from mani_skill.utils.structs.pose import Pose

from policy_composer.tasks.gear_assembly.expert import GearAssemblyExpert
from policy_composer.tasks.gear_assembly.rollout import run_episode


def release_above_peg(env, seed: int, radial_offset: float, steps: int = 40) -> dict:
    env.reset(seed=seed)
    u = env.unwrapped
    u.gear.set_pose(u.peg_module.pose * Pose.create_from_pq(p=[radial_offset, 0.0, u.gear_spec.peg_height + 0.005]))
    hold = u.flat_to_dict_action(u.hold_action())
    for _ in range(steps):
        _, _, _, _, info = env.step(hold)
    return info


@pytest.mark.parametrize("seed", [0, 1])
def test_aligned_gear_slides_down_and_seats(state_env, seed):
    info = release_above_peg(state_env, seed, 0.0)
    assert bool(info["success"][0]) and int(info["stage"][0]) == 3
    assert float(info["height_above_base"][0]) < 0.004


@pytest.mark.parametrize("seed", [0, 1])
def test_gear_offset_beyond_the_clearance_does_not_seat(state_env, seed):
    clearance = state_env.unwrapped.gear_spec.clearance
    info = release_above_peg(state_env, seed, 2.5 * clearance)
    assert not bool(info["success"][0])


@pytest.mark.parametrize("clearance", [0.001, 0.003])
def test_clearance_is_configurable(clearance):
    env = gym.make("GearAssembly-v1", obs_mode="state_dict", clearance=clearance)
    assert env.unwrapped.gear_spec.hole_radius == pytest.approx(env.unwrapped.gear_spec.peg_radius + clearance)
    assert bool(release_above_peg(env, 0, 0.0)["success"][0])
    assert not bool(release_above_peg(env, 0, clearance + 0.002)["success"][0])
    env.close()


def test_the_grasp_flag_is_maniskills_with_the_contacts_read_once_per_physics_step(state_env):
    """At every step of an expert episode (before, during and after the grasp), the task's grasp check and its
    finger forces equal ManiSkill's `is_grasping` and `get_pairwise_contact_forces` bit for bit."""
    u = state_env.unwrapped
    flags = []

    def check(*_):
        ours = u._left_grasping()
        assert torch.equal(ours, u.left_arm.is_grasping(u.gear))
        for link, force in zip((u.left_arm.finger1_link, u.left_arm.finger2_link), u._finger_forces()):
            assert torch.equal(force, u.scene.get_pairwise_contact_forces(link, u.gear))
        flags.append(bool(ours[0]))

    assert run_episode(state_env, GearAssemblyExpert(state_env), 3, on_step=check).success
    assert True in flags and False in flags
