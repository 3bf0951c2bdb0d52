"""Configuration of the CNN + mixture density policy (defaults: the paper's training settings)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from tasks.gear_assembly import CAMERA_NAMES

ARM_DIM = 8  # the left arm's 7 joints and its gripper (width in the state, command in the action)


@dataclass
class CNNPolicyConfig:
    camera: str = "left_forearm"  # which camera the policy sees: head, left_forearm or right_forearm
    image_size: int = 64  # images are resized to this square before the encoder
    backbone: str = "small"  # "small": 4 conv layers; "resnet18": torchvision's, randomly initialised
    state_dim: int = ARM_DIM
    action_dim: int = ARM_DIM  # joint-target deltas of the left arm and its gripper command
    hidden_dim: int = 256
    num_mixtures: int = 24  # paper: 24 Gaussian mixtures
    lr: float = 1e-3
    weight_decay: float = 1e-6  # paper
    batch_size: int = 120  # paper
    epochs: int = 200
    seed: int = 0

    def __post_init__(self):
        if self.camera not in CAMERA_NAMES:
            raise ValueError(f"camera must be one of {CAMERA_NAMES}, not {self.camera!r}")
        if self.backbone not in ("small", "resnet18"):
            raise ValueError(f"backbone must be 'small' or 'resnet18', not {self.backbone!r}")

    def architecture(self) -> dict:
        """The fields a checkpoint must match to be loaded into a model."""
        d = asdict(self)
        return {k: d[k] for k in ("camera", "image_size", "backbone", "state_dim", "action_dim", "hidden_dim", "num_mixtures")}
