"""The paper's visual policy: a CNN encoder and a mixture density head over the next motion, and a gripper logit."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from policy_composer.learning.layers import MixtureDensityHead, image_encoder
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig


class CNNPolicy(nn.Module):
    """(image, state) -> a mixture over the normalised motion targets, and the odds of an open gripper.

    The gripper command is binary in the demonstrations, so it gets its own logistic output: inside the
    mixture its two values would draw near-zero variances whose likelihood swamps the motion's, and the
    components would split on the gripper instead of on the motion. Normalisation statistics live in buffers."""

    def __init__(self, config: CNNPolicyConfig):
        super().__init__()
        self.config = config
        self.encoder = image_encoder(config.backbone, config.hidden_dim)
        self.trunk = nn.Sequential(nn.Linear(config.hidden_dim + config.state_dim, config.hidden_dim), nn.ReLU(),
                                   nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU())
        motion = config.action_dim - 1
        self.head = MixtureDensityHead(config.hidden_dim, motion, config.num_mixtures, config.min_std)
        self.gripper = nn.Linear(config.hidden_dim, 1)
        normalised = [("state", config.state_dim), ("action", motion)]
        if config.offset_weight:  # the auxiliary head (see CNNPolicyConfig.offset_weight), unused when acting
            self.offset = nn.Linear(config.hidden_dim, 3)
            normalised.append(("offset", 3))
        self.normalised = tuple(name for name, _ in normalised)  # what training sets the statistics of
        for name, dim in normalised:
            self.register_buffer(f"{name}_mean", torch.zeros(dim))
            self.register_buffer(f"{name}_std", torch.ones(dim))

    def forward(self, image: torch.Tensor, state: torch.Tensor, features: bool = False):
        """image (B, 3, S, S) in [0, 1]; state (B, state_dim) raw -> (mixture parameters, gripper-open logit), and
        the image features if asked."""
        f = self.encoder(image)
        s = (state - self.state_mean) / self.state_std
        h = self.trunk(torch.cat([f, s], dim=-1))
        return (self.head(h), self.gripper(h)[:, 0]) + ((f,) if features else ())

    def loss(self, image, state, action, offset: torch.Tensor | None = None) -> torch.Tensor:
        """NLL of the motion target plus the gripper's cross-entropy; action (B, action_dim), gripper last. With
        an auxiliary head, plus `offset_weight` times the squared error of the gear's offset (B, 3) (normalised)."""
        params, logit, f = self(image, state, features=True)
        nll = self.head.nll(*params, (action[:, :-1] - self.action_mean) / self.action_std)
        loss = nll + F.binary_cross_entropy_with_logits(logit, (action[:, -1] > 0).float())
        if self.config.offset_weight:
            target = (offset - self.offset_mean) / self.offset_std
            loss = loss + self.config.offset_weight * F.mse_loss(self.offset(f), target)
        return loss

    @torch.no_grad()
    def act(self, image, state, sample: bool = False, generator: torch.Generator | None = None) -> torch.Tensor:
        """(B, action_dim): the motion target (sampled, or the most probable component's mean) and the gripper
        command, +1 (open) or -1."""
        params, logit = self(image, state)
        motion = self.head.sample(*params, generator=generator) if sample else self.head.mode(*params)
        gripper = torch.where(logit > 0, 1.0, -1.0)[:, None]
        return torch.cat([motion * self.action_std + self.action_mean, gripper], dim=-1)
