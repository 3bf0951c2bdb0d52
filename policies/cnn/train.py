"""Behaviour cloning of the CNN policies on LeRobot datasets (the insertion on `gear-insertion-demos`, the pick-up
and the move on the stages of `gear-transport-demos`), and their checkpoints.

The dataset's frames are decoded once into memory at the policy's image size (a few thousand frames), so each
epoch costs only the network, not video decoding. A checkpoint is a safetensors file of weights and normalisation
statistics with the config as JSON beside it; the library's CNN model is a folder with one per subtask.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import torch

from policy_composer.data.features import DatasetError, image_key, read_sidecar
from policy_composer.data.frames import check_distinct, load_frames, random_shift
from policy_composer.data.recipes import check_recipe
from policy_composer.learning.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_config,
    model_writer,
    save_checkpoint,
)
from policy_composer.learning.trainer import Fit, cosine_decay, train_model
from policy_composer.policies.cnn.configuration_cnn import PROPRIOCEPTION, SUBTASKS, CNNPolicyConfig
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.tasks.panda import PandaForwardKinematics
from policy_composer.tasks.registry import get_spec, get_task


def policy_state(state: torch.Tensor, config: CNNPolicyConfig, scene: torch.Tensor | None = None) -> torch.Tensor:
    """What the policy reads of observation.state (N, S) and, where the task has them, the scenes the robot knows
    (N, len(scene_names)) (see PROPRIOCEPTION)."""
    own = state[..., PROPRIOCEPTION[config.proprioception]]
    if config.proprioception != "scene":
        return own
    return torch.cat([own.float(), get_task(config.task).kinematics(state, scene)], dim=-1)


def previous_commands(state: torch.Tensor, action: torch.Tensor, episode_index: torch.Tensor) -> torch.Tensor:
    """The command before each frame's: the previous frame's action, or at an episode's first frame the
    measured state (where the arm is when the controller takes over)."""
    prev = action.roll(1, dims=0).clone()
    first = torch.ones(len(episode_index), dtype=torch.bool)
    first[1:] = episode_index[1:] != episode_index[:-1]
    prev[first] = state[first]
    return prev


def action_target(state: torch.Tensor, action: torch.Tensor, previous: torch.Tensor, action_space: str,
                  turn: np.ndarray | None = None) -> torch.Tensor:
    """What the policy predicts from a recorded frame, in `action_space` (see ACTION_SPACES), with the gripper
    command last: the change from the previous command, not from the measured joints, since the gap between a
    command and where the arm is depends on the arm's velocity, which one image does not show. In the "hand" space
    the move is in the hand's frame turned by `turn` (N, 3, 3; `TaskDescription.grasp_turns`) where given."""
    gripper = action[..., 7:8]
    if action_space == "joint":
        return torch.cat([action[..., :7] - previous[..., :7], gripper], dim=-1)
    fk = PandaForwardKinematics()
    _, R_now = fk.tcp(state[..., :7].double().numpy())
    p_prev, _ = fk.tcp(previous[..., :7].double().numpy())
    p_target, _ = fk.tcp(action[..., :7].double().numpy())
    if turn is not None:
        R_now = R_now @ turn
    in_hand = np.einsum("nji,nj->ni", R_now, p_target - p_prev)  # R^T (p_target - p_prev)
    return torch.cat([torch.as_tensor(in_hand, dtype=torch.float32), gripper], dim=-1)


def load_demonstrations(root: str | Path | Sequence[str | Path], config: CNNPolicyConfig,
                        episodes: list[int] | None = None, progress: bool = True) -> dict[str, torch.Tensor]:
    """A dataset (or several, one after the other) in memory as the policy trains on it: the frames of the policy's
    subtask (see the task spec's `demonstrations`), as images (N, 3, S, S) uint8, arm state (N, state_dim) and
    action target (N, action_dim)."""
    if not isinstance(root, (str, Path)):
        check_distinct(root)
        parts = [load_demonstrations(r, config, episodes, progress) for r in root]
        return {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    spec = get_spec(config.task)
    if config.subtask not in spec.demonstrations:
        raise ValueError(f"{spec.env_id} has no demonstrations of a {config.subtask} for a CNN policy (it has "
                         f"{', '.join(spec.demonstrations)})")
    recipe, stages = spec.demonstrations[config.subtask]
    accepted = tuple(filter(None, (recipe, spec.corrections.get(config.subtask))))
    check_recipe(root, accepted, f"the CNN {config.subtask} policy")
    required = {"observation.state": (len(spec.state_names),), "action": (len(spec.action_names),), "stage": (1,)}
    scene = "observation.environment_state" if spec.scene_names else None
    if scene:
        required[scene] = (len(spec.scene_names),)
    if config.offset_weight:
        required["gear_offset"] = (3,)
    frames = load_frames(root, (config.camera,), config.image_size, episodes, required=required, progress=progress,
                         window=config.window)
    state, action = frames["observation.state"], frames["action"]
    if read_sidecar(root).get("expert", {}).get("labels") == "arm":  # each label is a step from the measured hand
        prev = state
    else:
        prev = previous_commands(state, action, frames["episode_index"])  # over whole episodes, before the stage cut
    keep = torch.isin(frames["stage"], torch.tensor(stages)) if stages else torch.ones(len(state), dtype=torch.bool)
    if not keep.any():
        raise DatasetError(f"{root} has no frames of the {config.subtask} subtask (stages {list(stages)}); record "
                           f"{recipe} for it")
    known = frames[scene][keep] if scene else None
    data = {"image": frames[image_key(config.camera)][keep],
            "state": policy_state(state[keep], config, known),
            "action": action_target(state[keep], action[keep], prev[keep], config.action_space,
                                    get_task(config.task).grasp_turns(known, int(keep.sum())))}
    if config.offset_weight:
        data["offset"] = frames["gear_offset"][keep]
    return data


def train_cnn_policy(root: str | Path | Sequence[str | Path], config: CNNPolicyConfig, out: str | Path | None = None,
                     progress: bool = True,
                     data: dict[str, torch.Tensor] | None = None) -> tuple[CNNPolicy, list[float]]:
    """Fit the policy by maximum likelihood of the demonstrated actions; returns it and the loss per epoch. Its
    checkpoint folder `out` is checked and locked before the data is read."""
    with model_writer(out, CNNPolicyConfig) if out is not None else nullcontext():
        return _train(root, config, out, progress, data)


def _train(root, config: CNNPolicyConfig, out, progress: bool, data) -> tuple[CNNPolicy, list[float]]:
    roots = [str(root)] if isinstance(root, (str, Path)) else [str(r) for r in root]

    def build(generator: torch.Generator) -> Fit:
        # read here, once torch is seeded: the loader draws from torch's generator
        frames = data if data is not None else load_demonstrations(root, config, progress=progress)
        model = CNNPolicy(config)
        quantities = {"state": frames["state"], "action": frames["action"][:, :-1], "offset": frames.get("offset")}
        for name in model.normalised:
            x = quantities[name].float()
            getattr(model, f"{name}_mean").copy_(x.mean(0))
            getattr(model, f"{name}_std").copy_(x.std(0).clamp_min(1e-5))

        def batch_loss(idx: torch.Tensor) -> torch.Tensor:
            images = random_shift(frames["image"][idx].float() / 255.0, config.shift, generator)
            offset = frames["offset"][idx] if config.offset_weight else None
            return model.loss(images, frames["state"][idx], frames["action"][idx], offset)

        n = len(frames["image"])
        return Fit(model, n, batch_loss, log={"dataset": roots[0] if len(roots) == 1 else roots, "frames": n},
                   snapshot={"datasets": roots, "frames": n})

    # A mixture density network's loss spikes now and then: end on small steps.
    return train_model(config, build, "training cnn policy", out, progress, schedule=cosine_decay(config.epochs),
                       postfix="nll")


def save_cnn_policy(model: CNNPolicy, out: str | Path, log: dict | None = None) -> None:
    save_checkpoint(model, model.config, out, log)


def load_cnn_library(path: str | Path) -> dict[str, CNNPolicy]:
    """The library's CNN model: a folder with one checkpoint per subtask (`pick`, `move`, `insert`), by subtask. A
    single checkpoint's folder is taken as the policy of the subtask it was trained for."""
    path = Path(path)
    if (path / "config.json").is_file():
        policy = load_cnn_policy(path)
        return {policy.config.subtask: policy}
    policies = {s: load_cnn_policy(path / s, subtask=s) for s in SUBTASKS if (path / s / "config.json").is_file()}
    if not policies:
        raise CheckpointError(f"no CNN policy in {path} (expected a checkpoint, or one in a subfolder per subtask: "
                              f"{', '.join(SUBTASKS)}); train them with `policy-composer train policy --subtask "
                              "SUBTASK`")
    return policies


def load_cnn_policy(path: str | Path, camera: str | None = None, state_dim: int | None = None,
                    subtask: str | None = None) -> CNNPolicy:
    """Load a checkpoint; refuse one trained for another subtask, camera or state size, saying which."""
    config = load_config(path, CNNPolicyConfig, "CNN policy", "policy-composer train policy")
    if subtask is not None and config.subtask != subtask:
        raise CheckpointError(f"checkpoint {path} is a CNN policy of the {config.subtask} subtask (its config.json "
                              f"says so), in the {subtask} policy's place; train the {subtask} policy into it with "
                              f"`policy-composer train policy --subtask {subtask} --out {path}`")
    if camera is not None and config.camera != camera:
        raise CheckpointError(f"checkpoint {path} was trained on camera {config.camera!r}, but this controller reads "
                              f"{camera!r}; train one for {camera!r} or configure the controller with "
                              f"{config.camera!r}")
    if state_dim is not None and config.state_dim != state_dim:
        raise CheckpointError(f"checkpoint {path} takes a state of size {config.state_dim}, this controller gives "
                              f"{state_dim}")
    return load_checkpoint(path, CNNPolicyConfig, CNNPolicy, "CNN policy", "policy-composer train policy")
