"""Configuration of the CNN + mixture density policy (defaults: the paper's training settings)."""

from __future__ import annotations

from dataclasses import dataclass

from tasks.gear_assembly import CAMERA_NAMES

ARM_DIM = 8  # the left arm's 7 joints and its gripper (width in the state, command in the action)
# What the mixture density head predicts, and its size (the gripper command is the last entry of both):
# "hand": the next TCP target as a displacement in the hand's own frame (the forearm camera's frame too, so
#         what the image shows maps to the action without the arm's Jacobian); the controller turns it into
#         joint targets by inverse kinematics, keeping the hand's orientation.
# "joint": the next joint targets as deltas from the measured joints (the paper's wording).
ACTION_SPACES = {"hand": 4, "joint": 8}


@dataclass
class CNNPolicyConfig:
    camera: str = "left_forearm"  # which camera the policy sees: head, left_forearm or right_forearm
    image_size: int = 64  # images are resized to this square before the encoder
    backbone: str = "small"  # "small": 4 conv layers; "resnet18": torchvision's, randomly initialised
    state_dim: int = ARM_DIM
    action_space: str = "hand"  # see ACTION_SPACES
    hidden_dim: int = 256
    num_mixtures: int = 24  # paper: 24 Gaussian mixtures
    lr: float = 1e-3
    weight_decay: float = 1e-6  # paper
    batch_size: int = 120  # paper
    epochs: int = 200
    shift: int = 4  # random-shift augmentation (pixels at image_size): behaviour cloning's usual guard against
    # memorising a few demonstrations
    seed: int = 0

    def __post_init__(self):
        if self.camera not in CAMERA_NAMES:
            raise ValueError(f"camera must be one of {CAMERA_NAMES}, not {self.camera!r}")
        if self.backbone not in ("small", "resnet18"):
            raise ValueError(f"backbone must be 'small' or 'resnet18', not {self.backbone!r}")
        if self.action_space not in ACTION_SPACES:
            raise ValueError(f"action_space must be one of {tuple(ACTION_SPACES)}, not {self.action_space!r}")

    @property
    def action_dim(self) -> int:
        return ACTION_SPACES[self.action_space]
