"""Behaviour cloning of the CNN policy on a LeRobot dataset (`gear-insertion-demos`), and its checkpoints.

The dataset's frames are decoded once into memory at the policy's image size (the insertion demos are a
few thousand frames), so each epoch costs only the network, not video decoding. Checkpoints are a
safetensors file of weights and normalisation statistics with the config as JSON beside it.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import torch
import torch.nn.functional as F

from policies.cnn.configuration_cnn import ARM_DIM, CNNPolicyConfig
from policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.recording.features import image_key, open_dataset


class CheckpointError(ValueError):
    pass


def to_model_image(rgb: torch.Tensor, size: int) -> torch.Tensor:
    """(B, H, W, 3) uint8 or (B, 3, H, W) float in [0, 1] -> (B, 3, size, size) float in [0, 1]."""
    if rgb.dtype == torch.uint8:
        rgb = rgb.permute(0, 3, 1, 2).float() / 255.0
    if rgb.shape[-1] != size:
        rgb = F.interpolate(rgb, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return rgb.clamp(0, 1)


def arm_state(state16: torch.Tensor) -> torch.Tensor:
    """The left arm's 7 joints and gripper width from observation.state."""
    return state16[..., :ARM_DIM]


def action_target(state16: torch.Tensor, action16: torch.Tensor) -> torch.Tensor:
    """What the policy predicts: the left arm's joint-target deltas and its gripper command."""
    return torch.cat([action16[..., :7] - state16[..., :7], action16[..., 7:8]], dim=-1)


def load_demonstrations(root: str | Path, config: CNNPolicyConfig, episodes: list[int] | None = None,
                        progress: bool = True) -> dict[str, torch.Tensor]:
    """Decode a dataset into memory: images (N, 3, S, S) uint8, arm state (N, 8), action target (N, 8), episode (N,)."""
    from tqdm import tqdm

    key = image_key(config.camera)
    ds = open_dataset(root, required={key: None, "observation.state": (16,), "action": (16,)}, episodes=episodes)
    loader = torch.utils.data.DataLoader(ds, batch_size=64, shuffle=False, num_workers=0)
    parts: dict[str, list] = {"image": [], "state": [], "action": [], "episode": [], "progress": []}
    for batch in tqdm(loader, desc=f"decoding {Path(root).name} ({config.camera})", unit="batch", disable=not progress):
        img = to_model_image(batch[key], config.image_size)
        parts["image"].append((img * 255).round().to(torch.uint8))
        parts["state"].append(arm_state(batch["observation.state"]))
        parts["action"].append(action_target(batch["observation.state"], batch["action"]))
        parts["episode"].append(batch["episode_index"])
        parts["progress"].append(batch["progress"] if "progress" in batch else torch.zeros(len(img)))
    return {k: torch.cat(v) for k, v in parts.items()}


def train_cnn_policy(root: str | Path, config: CNNPolicyConfig, out: str | Path | None = None,
                     progress: bool = True, data: dict[str, torch.Tensor] | None = None) -> tuple[CNNPolicy, list[float]]:
    """Fit the policy by maximum likelihood of the demonstrated actions; returns it and the loss per epoch."""
    from tqdm import tqdm

    torch.manual_seed(config.seed)
    data = data if data is not None else load_demonstrations(root, config, progress=progress)
    model = CNNPolicy(config)
    for name in ("state", "action"):
        x = data[name].float()
        getattr(model, f"{name}_mean").copy_(x.mean(0))
        getattr(model, f"{name}_std").copy_(x.std(0).clamp_min(1e-3))
    opt = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    n, losses = len(data["image"]), []
    gen = torch.Generator().manual_seed(config.seed)
    bar = tqdm(range(config.epochs), desc="training cnn policy", unit="epoch", disable=not progress)
    for _ in bar:
        model.train()
        total = 0.0
        for idx in torch.randperm(n, generator=gen).split(config.batch_size):
            loss = model.loss(data["image"][idx].float() / 255.0, data["state"][idx], data["action"][idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        losses.append(total / n)
        bar.set_postfix(nll=f"{losses[-1]:.3f}")
    model.eval()
    if out is not None:
        save_cnn_policy(model, out, {"dataset": str(root), "frames": n, "losses": losses})
    return model, losses


def save_cnn_policy(model: CNNPolicy, out: str | Path, log: dict | None = None) -> None:
    from safetensors.torch import save_file

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(out / "model.safetensors"))
    (out / "config.json").write_text(json.dumps(asdict(model.config), indent=1))
    if log is not None:
        (out / "train_log.json").write_text(json.dumps(log, indent=1))


def load_cnn_policy(path: str | Path, camera: str | None = None, state_dim: int | None = None) -> CNNPolicy:
    """Load a checkpoint; refuse one trained for another camera or state size, saying which."""
    from safetensors.torch import load_file

    path = Path(path)
    if not (path / "config.json").is_file() or not (path / "model.safetensors").is_file():
        raise CheckpointError(f"no CNN policy checkpoint in {path} (expected config.json and model.safetensors); "
                              f"train one with `policy-composer train policy`")
    config = CNNPolicyConfig(**json.loads((path / "config.json").read_text()))
    if camera is not None and config.camera != camera:
        raise CheckpointError(f"checkpoint {path} was trained on camera {config.camera!r}, but this controller reads "
                              f"{camera!r}; train one for {camera!r} or configure the controller with {config.camera!r}")
    if state_dim is not None and config.state_dim != state_dim:
        raise CheckpointError(f"checkpoint {path} takes a state of size {config.state_dim}, this controller gives "
                              f"{state_dim}")
    model = CNNPolicy(config)
    model.load_state_dict(load_file(str(path / "model.safetensors")))
    return model.eval()
