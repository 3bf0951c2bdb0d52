import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import gymnasium as gym
import pytest

import tasks  # noqa: F401  (registers GearAssembly-v1)


@pytest.fixture(scope="session")
def state_env():
    """One state-only env for the physics and expert tests (building an env costs seconds)."""
    env = gym.make("GearAssembly-v1", obs_mode="state_dict")
    yield env
    env.close()
