"""Any LeRobot policy checkpoint (ACT, Diffusion Policy, the paper's own `cnn_mdn`, ... trained with `lerobot-train`
on our datasets) as a controller.

The user gives the initiation set and termination by naming the subtask the policy was trained for. The
checkpoint's own processors normalise inputs and outputs, as in `lerobot-eval`. Its input features must be
cameras this env renders (`observation.images.<camera>`) and the task's `observation.state`; of its action (the task's
flat action), the driven arm's part is applied (any other arm holds), like every controller of the library.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
from lerobot.utils.import_utils import register_third_party_plugins

from policy_composer.data.frames import to_model_image
from policy_composer.learning.checkpoint import CheckpointError, check_finite
from policy_composer.policies.lerobot_policy.configuration_lerobot_policy import LeRobotSource
from policy_composer.policies.subtasks import LearnedController, check_camera
from policy_composer.tasks.base import Subtask
from policy_composer.tasks.registry import task_of

POLICY_NAMES = {"act": "ACT", "diffusion": "Diffusion Policy", "pi0": "pi0", "smolvla": "SmolVLA", "vqbet": "VQ-BeT",
                "cnn_mdn": "CNN + MDN"}


@functools.cache
def register_plugins() -> None:
    """Import the installed LeRobot plugins (`lerobot_policy_*` and the like), as LeRobot's scripts do at start-up,
    so that a checkpoint of a plugin's policy type (the paper's `cnn_mdn`) loads."""
    register_third_party_plugins()


def lerobot_cameras(path: str | Path) -> tuple[str, ...]:
    """The cameras a LeRobot checkpoint reads, from its config (without loading the policy)."""
    config = Path(path) / "config.json"
    features = json.loads(config.read_text()).get("input_features", {}) if config.is_file() else {}
    return tuple(k.removeprefix("observation.images.") for k in features if k.startswith("observation.images."))


def lerobot_label(path: str | Path) -> str:
    """A checkpoint's row in Table I, by its policy type: "ACT (LeRobot)", "Diffusion Policy (LeRobot)"."""
    config = Path(path) / "config.json"
    kind = json.loads(config.read_text()).get("type", "policy") if config.is_file() else "policy"
    return f"{POLICY_NAMES.get(kind, kind)} (LeRobot)"


@contextmanager
def damaged_files(path: Path, what: str) -> Iterator[None]:
    """A checkpoint file that LeRobot cannot read (truncated, edited, of another version), said in one line that
    names it: LeRobot's own error is a parser's or safetensors' that names no file."""
    try:
        yield
    except Exception as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[0][:200]
        raise CheckpointError(f"{path} {what} ({first}); train the policy again with lerobot-train, or restore "
                              "the checkpoint from a copy") from None


class LeRobotPolicyController(LearnedController):
    def __init__(self, env, pretrained_path: str | Path, subtask: Subtask | None = None, name: str | None = None,
                 instruction: str | None = None, max_steps: int = 120):
        """`subtask`: the one the policy was trained for (default: the task's last); `instruction`: LeRobot's
        `task` string (default: the task's own)."""
        register_plugins()
        path = Path(pretrained_path)
        if not (path / "config.json").is_file():
            raise FileNotFoundError(f"{path} is not a LeRobot policy checkpoint (no config.json); pass the "
                                    f"`pretrained_model` folder that lerobot-train saves")
        with damaged_files(path / "config.json", "is not a LeRobot policy config"):
            cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device, cfg.pretrained_path = "cpu", str(path)
        task = task_of(env)
        subtask = subtask or task.subtasks[task.sequence[-1]]
        super().__init__(env, subtask, name or f"{cfg.type}_{subtask.name}", max_steps)
        self.images = {}
        for key, feature in cfg.input_features.items():
            if key.startswith("observation.images."):
                camera = key.removeprefix("observation.images.")
                check_camera(self.env, camera, f"the {cfg.type} policy at {path}")
                self.images[key] = (camera, int(feature.shape[-1]))
            elif key == "observation.state" and tuple(feature.shape) != (len(task.spec.state_names),):
                raise CheckpointError(f"the policy at {path} takes a state of shape {tuple(feature.shape)}, "
                                      f"{task.spec.env_id} gives ({len(task.spec.state_names)},)")
            elif key == "observation.environment_state" and tuple(feature.shape) != (len(task.spec.scene_names),):
                raise CheckpointError(f"the policy at {path} takes a scene of shape {tuple(feature.shape)}, "
                                      f"{task.spec.env_id} gives ({len(task.spec.scene_names)},): train it again on "
                                      "recordings made by this version")
        if tuple(cfg.output_features["action"].shape) != (len(task.spec.action_names),):
            raise CheckpointError(f"the policy at {path} outputs actions of shape "
                                  f"{tuple(cfg.output_features['action'].shape)}, "
                                  f"{task.spec.env_id} takes ({len(task.spec.action_names)},)")
        with damaged_files(path / "model.safetensors", "does not hold the weights of this policy"):
            self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg).eval()
        check_finite(path / "model.safetensors", self.policy.state_dict(), "train it again with lerobot-train")
        with damaged_files(path, "does not hold readable processors (policy_preprocessor.json and its files)"):
            self.preprocess, self.postprocess = make_pre_post_processors(
                cfg, pretrained_path=str(path), preprocessor_overrides={"device_processor": {"device": "cpu"}})
        self.instruction = instruction or task.spec.instruction
        self.reads_scene = "observation.environment_state" in cfg.input_features
        self.obs_keys = (tuple(f"sensor_data.{c}.rgb" for c, _ in self.images.values()) + ("extra.state",)
                         + (("extra.scene",) if self.reads_scene else ()))

    def reset(self, obs, seed=None):
        super().reset(obs, seed)
        self.policy.reset()

    @torch.no_grad()
    def predict(self, obs):
        batch = {key: to_model_image(obs["sensor_data"][camera]["rgb"][:1].cpu(), size)
                 for key, (camera, size) in self.images.items()}
        batch["observation.state"] = obs["extra"]["state"][:1].cpu().float()
        if self.reads_scene:
            batch["observation.environment_state"] = obs["extra"]["scene"][:1].cpu().float()
        batch["task"] = [self.instruction]
        action = self.postprocess(self.policy.select_action(self.preprocess(batch)))
        a = action[0].cpu().numpy().astype(np.float64)
        return a[:7], float(np.clip(a[7], -1.0, 1.0))


def build(env, subtask: Subtask, model, config: LeRobotSource, max_grasp_offset: float) -> LeRobotPolicyController:
    """The registry's builder: the checkpoint `config` names, as its controller for `subtask`."""
    return LeRobotPolicyController(env, config.path, subtask, name=config.controller_name)


def cameras(config: LeRobotSource) -> tuple[str, ...]:
    return lerobot_cameras(config.path)


def label(config: LeRobotSource) -> str:
    return lerobot_label(config.path)
