"""Configuration of the CNN + mixture density policy (defaults: the paper's training settings)."""

from __future__ import annotations

from dataclasses import dataclass

from tasks.gear_assembly import CAMERA_NAMES

# What the policy reads of observation.state besides its image, and its size:
# "gripper": the gripper's width only. With the joints as input, a few dozen demonstrations can be fitted from
#            the joints alone (each episode's joint path is unique), and the image gets ignored; measured on
#            the insertion table, see the README.
# "arm": the left arm's 7 joints and the gripper width (the paper's wording).
PROPRIOCEPTION = {"gripper": slice(7, 8), "arm": slice(0, 8)}
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
    backbone: str = "spatial"  # see modeling_cnn.image_encoder: "spatial", "small" or "resnet18"
    proprioception: str = "gripper"  # see PROPRIOCEPTION
    action_space: str = "hand"  # see ACTION_SPACES
    hidden_dim: int = 256
    num_mixtures: int = 24  # paper: 24 Gaussian mixtures
    # Smallest standard deviation of a component, in units of the target's spread. Without a floor the
    # likelihood is won by shrinking variances, and the means (the actions) are left barely fitted: on two
    # demonstrations, a floor of 0.2 cut the fitted descent error from 2.4 mm to 0.5 mm a step.
    min_std: float = 0.2
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
        if self.backbone not in ("spatial", "small", "resnet18"):
            raise ValueError(f"backbone must be 'spatial', 'small' or 'resnet18', not {self.backbone!r}")
        if self.proprioception not in PROPRIOCEPTION:
            raise ValueError(f"proprioception must be one of {tuple(PROPRIOCEPTION)}, not {self.proprioception!r}")
        if self.action_space not in ACTION_SPACES:
            raise ValueError(f"action_space must be one of {tuple(ACTION_SPACES)}, not {self.action_space!r}")

    @property
    def state_dim(self) -> int:
        sl = PROPRIOCEPTION[self.proprioception]
        return sl.stop - sl.start

    @property
    def action_dim(self) -> int:
        return ACTION_SPACES[self.action_space]
