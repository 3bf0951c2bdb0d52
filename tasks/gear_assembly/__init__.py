"""GearAssembly-v1, the paper's task as this project builds it in ManiSkill: the env (`env`), what it shows and takes
without the simulator (`spec`), the parts' drawings (`geometry`), the two arms' kinematics (`kinematics`), the
scripted expert (`expert`), its LeRobot env (`lerobot_env`) and episode runs (`rollout`).

Importing it registers ``GearAssembly-v1`` with gymnasium by its entry points' names: the simulator is imported when
the first env is made.
"""

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from policy_composer.tasks.gear_assembly.spec import ENV_ID, MAX_EPISODE_STEPS

if ENV_ID not in gym.registry:  # the arguments ManiSkill's register_env gives gym.register, its entry points by name
    gym.register(ENV_ID, entry_point="policy_composer.tasks.gear_assembly.env:make_env",
                 vector_entry_point="policy_composer.tasks.gear_assembly.env:make_vec_env",
                 max_episode_steps=MAX_EPISODE_STEPS, disable_env_checker=True,
                 additional_wrappers=(WrapperSpec("MSTimeLimit", "mani_skill.utils.registration:TimeLimitWrapper",
                                                  {"max_episode_steps": MAX_EPISODE_STEPS}),))
