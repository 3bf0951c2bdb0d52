"""GearAssembly-v1 in LeRobot's env conventions, so that `lerobot-eval` runs a LeRobot policy on it unchanged.

Observations are what LeRobot's `preprocess_observation` reads: `pixels` (one HxWx3 uint8 image per camera) and
`agent_pos` (the 16 joint values), which become `observation.images.<camera>` and `observation.state`, the names of
this project's datasets; actions are the datasets' 16-D `action`. `is_success` is the task's `success`. The
`lerobot_env_gear_assembly` plugin (`plugins/`) registers this env with LeRobot as `--env.type=gear_assembly`.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from policy_composer.tasks.gear_assembly.rollout import make_env, tile_cameras
from policy_composer.tasks.gear_assembly.spec import ACTION_NAMES, CAMERA_NAMES, CLEARANCE_MM, RESOLUTION, STATE_NAMES

# Each task: where an episode starts (GearAssembly-v1's start states), its step limit and LeRobot's task string.
# The insertion starts at the pre-insertion pose with a random grasp offset, as Table I's insert column does; its
# demonstrations take about 40 steps. The full task has the env's own limit.
TASKS = {
    "insert": ("pre_insertion", 200, "Insert the gear held by the left gripper onto the peg held by the right arm."),
    "full": ("table", 400, "Pick up the gear and put it onto the peg held by the right arm."),
}


def check_settings(task: str, resolution: int, cameras, clearance_mm: float, max_episode_steps: int | None) -> None:
    """A ValueError naming the first setting (by its lerobot-eval flag) that GearAssembly cannot run with."""
    if task not in TASKS:
        raise ValueError(f"GearAssembly has no task {task!r}: choose one of {', '.join(TASKS)} (--env.task)")
    unknown = set(cameras) - set(CAMERA_NAMES)
    if unknown or not cameras:
        raise ValueError(f"GearAssembly's cameras are {', '.join(CAMERA_NAMES)}, not {sorted(unknown) or '[]'} "
                         "(--env.cameras)")
    if not RESOLUTION[0] <= resolution <= RESOLUTION[1]:
        raise ValueError(f"--env.resolution must be between {RESOLUTION[0]} and {RESOLUTION[1]} pixels, not "
                         f"{resolution}")
    if not CLEARANCE_MM[0] <= clearance_mm <= CLEARANCE_MM[1]:
        raise ValueError(f"--env.clearance_mm must be between {CLEARANCE_MM[0]:g} and {CLEARANCE_MM[1]:g} mm, not "
                         f"{clearance_mm}")
    if max_episode_steps is not None and max_episode_steps < 1:
        raise ValueError(f"an episode needs at least one step, not {max_episode_steps} (--env.episode_length)")


class GearAssemblyLeRobotEnv(gym.Env):
    """One GearAssembly-v1 env (CPU simulation) with LeRobot's observation, action and info conventions."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, task: str = "insert", resolution: int = 128, cameras: tuple[str, ...] = CAMERA_NAMES,
                 clearance_mm: float = 2.0, render_mode: str = "rgb_array", max_episode_steps: int | None = None):
        check_settings(task, resolution, cameras, clearance_mm, max_episode_steps)
        self.task, self.cameras, self.render_mode = task, tuple(cameras), render_mode
        self._start, self._max_episode_steps, self.task_description = TASKS[task]
        if max_episode_steps is not None:
            self._max_episode_steps = max_episode_steps
        self.env = make_env("rgb", resolution, clearance_mm, self.cameras)
        self.metadata = {**self.metadata, "render_fps": int(self.env.unwrapped.control_freq)}
        image = spaces.Box(0, 255, (resolution, resolution, 3), np.uint8)
        self.observation_space = spaces.Dict({
            "pixels": spaces.Dict({c: image for c in self.cameras}),
            "agent_pos": spaces.Box(-np.inf, np.inf, (len(STATE_NAMES),), np.float32),
        })
        gripper = np.array(["gripper" in n for n in ACTION_NAMES])
        self.action_space = spaces.Box(np.where(gripper, -1.0, -np.inf).astype(np.float32),
                                       np.where(gripper, 1.0, np.inf).astype(np.float32), dtype=np.float32)
        self._obs = None

    def reset(self, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._obs, _ = self.env.reset(seed=seed, options={"start": self._start})
        self._steps = 0
        return self._observation(), {"is_success": False}

    def step(self, action):
        u = self.env.unwrapped
        action = torch.as_tensor(np.asarray(action, dtype=np.float32).reshape(len(ACTION_NAMES)))
        self._obs, reward, _, _, info = self.env.step(u.flat_to_dict_action(action))
        self._steps += 1
        success = bool(info["success"][0])
        truncated = not success and self._steps >= self._max_episode_steps
        return self._observation(), float(reward[0]), success, truncated, {"is_success": success}

    def render(self) -> np.ndarray:
        """The cameras side by side (the rollout videos lerobot-eval writes)."""
        return tile_cameras(self._obs, self.cameras)

    def close(self):
        self.env.close()

    def _observation(self) -> dict:
        sensors = self._obs["sensor_data"]
        return {"pixels": {c: sensors[c]["rgb"][0].cpu().numpy() for c in self.cameras},
                "agent_pos": self._obs["extra"]["state"][0].cpu().numpy().astype(np.float32)}
