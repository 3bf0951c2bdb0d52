"""The CNN policy as a controller of the library (`cnn_insert`): camera pixels and arm joints in, joint targets out."""

from __future__ import annotations

import numpy as np

from policies.arm import np0
from policies.cnn.modeling_cnn import CNNPolicy
from policies.cnn.train import arm_state, to_model_image
from policies.subtasks import SUBTASKS, LearnedController, Subtask


def check_camera(env, camera: str, who: str) -> None:
    if camera not in env.camera_names:
        raise ValueError(f"{who} reads camera {camera!r}, which this env does not render (it has "
                         f"{list(env.camera_names)}); make the env with that camera")
    if "rgb" not in env.obs_mode:
        raise ValueError(f"{who} needs camera images: make the env with obs_mode='rgb', not {env.obs_mode!r}")


class CNNController(LearnedController):
    def __init__(self, env, policy: CNNPolicy, subtask: Subtask = SUBTASKS["insert"], max_steps: int = 120):
        super().__init__(env, subtask, f"cnn_{subtask.name}", max_steps)
        check_camera(self.env, policy.config.camera, "the CNN policy")
        self.policy = policy
        self.obs_keys = (f"sensor_data.{policy.config.camera}.rgb", "extra.state[:8]")

    def predict(self, obs):
        camera, size = self.policy.config.camera, self.policy.config.image_size
        image = to_model_image(obs["sensor_data"][camera]["rgb"][:1].cpu(), size)
        a = self.policy.act(image, arm_state(obs["extra"]["state"][:1].cpu().float()))[0].numpy().astype(np.float64)
        return np0(obs["extra"]["state"])[:7] + a[:7], float(np.clip(a[7], -1.0, 1.0))
