"""The paper's visual policy: a CNN encoder and a mixture density head over the next motion, and a logit for each
binary command (the gripper's).

One network for both of its trainers: the project's loop (`policies/cnn/train.py`) and LeRobot's `lerobot-train`
(the `lerobot_policy_cnn_mdn` plugin). Its config gives `backbone`, `hidden_dim`, `state_dim`, `action_dim`,
`binary_actions`, `num_mixtures`, `min_std` and `offset_weight`, and may give `precision` (float32 when it does not).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from policy_composer.learning.layers import MixtureDensityHead, encode, image_encoder


class CNNPolicy(nn.Module):
    """(image, state) -> a mixture over the normalised motion targets, and the odds that each binary command is on.

    The gripper command is binary in the demonstrations, so it gets its own logistic output: inside the
    mixture its two values would draw near-zero variances whose likelihood swamps the motion's, and the
    components would split on the gripper instead of on the motion. A binary entry is on above zero and is acted
    as +1 or -1. Normalisation statistics live in buffers (identity where the caller normalises, as LeRobot's
    processors do)."""

    def __init__(self, config):
        super().__init__()
        self.config = config
        self.binary = tuple(config.binary_actions)
        self.motion = tuple(i for i in range(config.action_dim) if i not in self.binary)
        self.encoder = image_encoder(config.backbone, config.hidden_dim)
        self.bfloat16 = getattr(config, "precision", "float32") == "bfloat16"  # the convolutions, while training
        self.trunk = nn.Sequential(nn.Linear(config.hidden_dim + config.state_dim, config.hidden_dim), nn.ReLU(),
                                   nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU())
        self.head = MixtureDensityHead(config.hidden_dim, len(self.motion), config.num_mixtures, config.min_std)
        self.gripper = nn.Linear(config.hidden_dim, len(self.binary))
        normalised = [("state", config.state_dim), ("action", len(self.motion))]
        if config.offset_weight:  # the auxiliary head (see CNNPolicyConfig.offset_weight), unused when acting
            self.offset = nn.Linear(config.hidden_dim, 3)
            normalised.append(("offset", 3))
        self.normalised = tuple(name for name, _ in normalised)  # what training sets the statistics of
        for name, dim in normalised:
            self.register_buffer(f"{name}_mean", torch.zeros(dim))
            self.register_buffer(f"{name}_std", torch.ones(dim))

    def forward(self, image: torch.Tensor, state: torch.Tensor, features: bool = False):
        """image (B, 3, S, S) in [0, 1]; state (B, state_dim) raw -> (mixture parameters, binary logits (B, n)), and
        the image features if asked."""
        f = encode(self.encoder, image, self.bfloat16 and self.training)
        s = (state - self.state_mean) / self.state_std
        h = self.trunk(torch.cat([f, s], dim=-1))
        return (self.head(h), self.gripper(h)) + ((f,) if features else ())

    def loss(self, image, state, action, offset: torch.Tensor | None = None) -> torch.Tensor:
        """NLL of the motion target plus the binary commands' cross-entropy; action (B, action_dim). With an
        auxiliary head, plus `offset_weight` times the squared error of the gear's offset (B, 3) (normalised)."""
        params, logits, f = self(image, state, features=True)
        loss = self.head.nll(*params, (action[:, self.motion] - self.action_mean) / self.action_std)
        if self.binary:
            loss = loss + F.binary_cross_entropy_with_logits(logits, (action[:, self.binary] > 0).float())
        if self.config.offset_weight:
            target = (offset - self.offset_mean) / self.offset_std
            loss = loss + self.config.offset_weight * F.mse_loss(self.offset(f), target)
        return loss

    @torch.no_grad()
    def act(self, image, state, sample: bool = False, generator: torch.Generator | None = None) -> torch.Tensor:
        """(B, action_dim): the motion target (sampled, or the most probable component's mean) and each binary
        command, +1 (on: the gripper open) or -1."""
        params, logits = self(image, state)
        motion = self.head.sample(*params, generator=generator) if sample else self.head.mode(*params)
        action = torch.empty(len(motion), self.config.action_dim, dtype=motion.dtype, device=motion.device)
        action[:, self.motion] = motion * self.action_std + self.action_mean
        action[:, self.binary] = torch.where(logits > 0, 1.0, -1.0)
        return action
