"""Tasks of policy-composer: ``GearAssembly-v1`` (ManiSkill, bimanual gear assembly), its scripted expert, and the
random-walk MDP. ``policy_composer.tasks.spec`` names its cameras, state and action without importing the simulator.

Importing this package registers ``GearAssembly-v1`` with gymnasium, as ``import mani_skill.envs`` registers
ManiSkill's tasks; the simulator itself is imported when the first env is made, not here (it costs seconds).
"""

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from policy_composer.tasks.spec import ENV_ID, MAX_EPISODE_STEPS

if ENV_ID not in gym.registry:  # the arguments ManiSkill's register_env gives gym.register, its entry points by name
    gym.register(ENV_ID, entry_point="policy_composer.tasks.gear_assembly:make_env",
                 vector_entry_point="policy_composer.tasks.gear_assembly:make_vec_env",
                 max_episode_steps=MAX_EPISODE_STEPS, disable_env_checker=True,
                 additional_wrappers=(WrapperSpec("MSTimeLimit", "mani_skill.utils.registration:TimeLimitWrapper",
                                                  {"max_episode_steps": MAX_EPISODE_STEPS}),))
