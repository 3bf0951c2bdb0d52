"""GearAssembly-v1 as a LeRobot env type: `lerobot-eval --env.type=gear_assembly --env.task=insert|full`.

LeRobot imports this package at start-up (it imports installed distributions named `lerobot_env_*`), which
registers the config below; the env is `policy_composer.tasks.gear_assembly.lerobot_env.GearAssemblyLeRobotEnv`.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import gymnasium as gym
from gymnasium.vector import AutoresetMode
from lerobot.configs import FeatureType, PolicyFeature, parser
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from policy_composer.learning.config import refuse
from policy_composer.tasks.gear_assembly.lerobot_env import GearAssemblyLeRobotEnv, check_settings
from policy_composer.tasks.gear_assembly.spec import ACTION_NAMES, CAMERA_NAMES, STATE_NAMES


@EnvConfig.register_subclass("gear_assembly")
@dataclass
class GearAssemblyEnv(EnvConfig):
    task: str | None = "insert"  # "insert": from the pre-insertion pose; "full": from the table
    fps: int = 20  # the env's control frequency
    resolution: int = 128  # camera images, pixels square (the datasets' default)
    cameras: list[str] = field(default_factory=lambda: list(CAMERA_NAMES))
    clearance_mm: float = 2.0
    episode_length: int | None = None  # control steps before an episode is cut off (None: the task's, 200 or 400)

    def __post_init__(self):
        try:  # here, before lerobot-eval loads the policy, rather than when it builds the env
            check_settings(self.task, self.resolution, self.cameras, self.clearance_mm, self.episode_length)
        except ValueError as e:
            refuse(str(e))
        self.features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(len(ACTION_NAMES),)),
                         "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(len(STATE_NAMES),))}
        self.features_map = {ACTION: ACTION, "agent_pos": OBS_STATE}
        for camera in self.cameras:
            self.features[f"pixels/{camera}"] = PolicyFeature(type=FeatureType.VISUAL,
                                                              shape=(self.resolution, self.resolution, 3))
            self.features_map[f"pixels/{camera}"] = f"{OBS_IMAGES}.{camera}"

    @property
    def gym_kwargs(self) -> dict:
        return {"task": self.task, "resolution": self.resolution, "cameras": tuple(self.cameras),
                "clearance_mm": self.clearance_mm, "max_episode_steps": self.episode_length}

    def policy_mismatches(self, policy_path: str | Path) -> list[str]:
        """What a checkpoint's config expects of the cameras that this env does not give: lerobot-eval hands the
        policy the env's images as they are, so a policy trained on other image sizes runs, sees what it never saw,
        and fails without a hint."""
        config = Path(policy_path) / "config.json"
        features = json.loads(config.read_text()).get("input_features", {}) if config.is_file() else {}
        found = []
        for key, feature in features.items():
            camera = key.removeprefix(f"{OBS_IMAGES}.")
            if camera == key:
                continue
            size = tuple(feature["shape"][-2:])  # (3, H, W)
            if camera not in self.cameras:
                found.append(f"it reads the {camera} camera, which --env.cameras leaves out")
            elif size != (self.resolution, self.resolution):
                found.append(f"it was trained on {size[1]}x{size[0]} {camera} images and this env renders "
                             f"{self.resolution}x{self.resolution}: pass --env.resolution={size[1]}")
        return found

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        """{"gear_assembly": {0: a vector of n_envs envs}}, built directly (no gym registry entry to look up)."""
        policy = parser.get_path_arg("policy")  # lerobot-eval's --policy.path, read the way lerobot reads it
        for problem in self.policy_mismatches(policy) if policy else []:
            logging.warning(f"gear_assembly: the policy at {policy} will not see what it was trained on: {problem}")
        make = partial(GearAssemblyLeRobotEnv, **self.gym_kwargs)
        if use_async_envs and n_envs > 1:
            vec = gym.vector.AsyncVectorEnv([make] * n_envs, autoreset_mode=AutoresetMode.SAME_STEP,
                                            context="forkserver")
        else:
            vec = gym.vector.SyncVectorEnv([make] * n_envs, autoreset_mode=AutoresetMode.SAME_STEP)
        return {self.type: {0: vec}}
