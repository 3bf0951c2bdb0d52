"""The CNN policy as a controller of the library (`cnn_insert`): camera pixels and arm joints in, joint targets out."""

from __future__ import annotations

import numpy as np
import torch

from policies.arm import LeftArmController, np0
from policies.cnn.modeling_cnn import CNNPolicy
from policies.cnn.train import arm_state, to_model_image
from policies.subtasks import SUBTASKS, Subtask


class CNNController(LeftArmController):
    action_kind = "joint_targets"

    def __init__(self, env, policy: CNNPolicy, subtask: Subtask = SUBTASKS["insert"], max_steps: int = 120):
        super().__init__(env)
        camera = policy.config.camera
        if camera not in self.env.camera_names:
            raise ValueError(f"the CNN policy reads camera {camera!r}, which this env does not render "
                             f"(it has {list(self.env.camera_names)}); make the env with that camera")
        if "rgb" not in self.env.obs_mode:
            raise ValueError(f"the CNN policy needs camera images: make the env with obs_mode='rgb', not {self.env.obs_mode!r}")
        self.policy = policy
        self.subtask = subtask
        self.name = f"cnn_{subtask.name}"
        self.initiation = subtask.initiation
        self.obs_keys = (f"sensor_data.{camera}.rgb", "extra.state[:8]")
        self.max_steps = max_steps

    def can_start(self, obs) -> bool:
        return self.subtask.can_start(self.scene)

    def succeeded(self, info):
        return self.subtask.succeeded(info)

    def reset(self, obs, seed=None):
        super().reset(obs, seed)
        self._steps = 0

    def next_command(self, obs):
        # Termination: the subtask is achieved and the hand has let go, or the step budget is spent.
        info = self.scene.info()
        if self._steps >= self.max_steps or (info["success"] and self._gripper > 0 and not info["gear_grasped"]):
            return None
        self._steps += 1
        image = to_model_image(obs["sensor_data"][self.policy.config.camera]["rgb"][:1].cpu(), self.policy.config.image_size)
        state = arm_state(obs["extra"]["state"][:1].cpu().float())
        a = self.policy.act(image, state)[0].numpy().astype(np.float64)
        q = np0(obs["extra"]["state"])[:7] + a[:7]
        return q, float(np.clip(a[7], -1.0, 1.0))
