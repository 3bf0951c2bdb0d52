"""CNN encoder + mixture density network head (Bishop 1994), as the paper's visual policy and goal scorer use."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from policies.cnn.configuration_cnn import CNNPolicyConfig


def image_encoder(backbone: str, out_dim: int) -> nn.Module:
    """Images (B, 3, H, W) in [0, 1] -> features (B, out_dim)."""
    if backbone == "resnet18":
        from torchvision.models import resnet18

        net = resnet18(weights=None)  # no download: trained from scratch on our demonstrations
        net.fc = nn.Linear(net.fc.in_features, out_dim)
        return net
    return nn.Sequential(
        nn.Conv2d(3, 32, 5, stride=2, padding=2), nn.ReLU(),
        nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(64, 64, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(64, 128, 3, stride=2, padding=1), nn.ReLU(),
        nn.AdaptiveAvgPool2d(2), nn.Flatten(), nn.Linear(128 * 4, out_dim), nn.ReLU(),
    )


class MixtureDensityHead(nn.Module):
    """Features -> a mixture of K diagonal Gaussians over a D-dimensional target."""

    def __init__(self, in_dim: int, out_dim: int, num_mixtures: int):
        super().__init__()
        self.D, self.K = out_dim, num_mixtures
        self.logits = nn.Linear(in_dim, num_mixtures)
        self.means = nn.Linear(in_dim, num_mixtures * out_dim)
        self.log_stds = nn.Linear(in_dim, num_mixtures * out_dim)

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        B = h.shape[0]
        log_pi = F.log_softmax(self.logits(h), dim=-1)
        mu = self.means(h).view(B, self.K, self.D)
        log_std = self.log_stds(h).view(B, self.K, self.D).clamp(-7.0, 3.0)
        return log_pi, mu, log_std

    @staticmethod
    def nll(log_pi, mu, log_std, y: torch.Tensor) -> torch.Tensor:
        """Mean negative log-likelihood of targets y (B, D)."""
        z = (y[:, None, :] - mu) / log_std.exp()
        log_prob = -0.5 * (z ** 2).sum(-1) - log_std.sum(-1) - 0.5 * mu.shape[-1] * math.log(2 * math.pi)
        return -torch.logsumexp(log_pi + log_prob, dim=-1).mean()

    @staticmethod
    def sample(log_pi, mu, log_std, generator: torch.Generator | None = None) -> torch.Tensor:
        k = torch.multinomial(log_pi.exp(), 1, generator=generator).squeeze(-1)
        idx = torch.arange(len(k))
        noise = torch.randn(mu[idx, k].shape, generator=generator)
        return mu[idx, k] + noise * log_std[idx, k].exp()

    @staticmethod
    def mode(log_pi, mu, log_std) -> torch.Tensor:
        """The mean of the most probable component: a deterministic action."""
        return mu[torch.arange(len(mu)), log_pi.argmax(-1)]


class CNNPolicy(nn.Module):
    """(image, arm state) -> mixture over normalised action targets. Normalisation statistics live in buffers."""

    def __init__(self, config: CNNPolicyConfig):
        super().__init__()
        self.config = config
        self.encoder = image_encoder(config.backbone, config.hidden_dim)
        self.trunk = nn.Sequential(nn.Linear(config.hidden_dim + config.state_dim, config.hidden_dim), nn.ReLU(),
                                   nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU())
        self.head = MixtureDensityHead(config.hidden_dim, config.action_dim, config.num_mixtures)
        for name, dim in (("state", config.state_dim), ("action", config.action_dim)):
            self.register_buffer(f"{name}_mean", torch.zeros(dim))
            self.register_buffer(f"{name}_std", torch.ones(dim))

    def forward(self, image: torch.Tensor, state: torch.Tensor):
        """image (B, 3, S, S) in [0, 1]; state (B, state_dim) raw."""
        h = self.encoder(image)
        s = (state - self.state_mean) / self.state_std
        return self.head(self.trunk(torch.cat([h, s], dim=-1)))

    def loss(self, image, state, action) -> torch.Tensor:
        return self.head.nll(*self(image, state), (action - self.action_mean) / self.action_std)

    @torch.no_grad()
    def act(self, image, state, sample: bool = False, generator: torch.Generator | None = None) -> torch.Tensor:
        params = self(image, state)
        a = self.head.sample(*params, generator=generator) if sample else self.head.mode(*params)
        return a * self.action_std + self.action_mean
