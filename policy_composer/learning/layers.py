"""Layers the project's models share: image encoders, the mixture density head (Bishop 1994) and the MLP with that
head over a latent state.

The CNN policy, the goal scorers and the dynamics models all predict a mixture of Gaussians from features, so the
head lives below all of them."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn
from torchvision.models import resnet18


class SpatialSoftmax(nn.Module):
    """Feature maps (B, C, H, W) -> the expected image coordinates of each channel (B, 2C), in [-1, 1]: where
    things are, kept precise (Levine et al. 2016, end-to-end visuomotor policies)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C, H, W = x.shape
        attention = F.softmax(x.flatten(2), dim=-1).view(B, C, H, W)
        ys = torch.linspace(-1, 1, H, device=x.device)
        xs = torch.linspace(-1, 1, W, device=x.device)
        return torch.cat([(attention.sum(2) * xs).sum(-1), (attention.sum(3) * ys).sum(-1)], dim=-1)


def image_encoder(backbone: str, out_dim: int, in_channels: int = 3) -> nn.Module:
    """Images (B, in_channels, H, W) in [0, 1] -> features (B, out_dim); `in_channels` > 3 for several cameras'
    images stacked ("small" only).

    "spatial": four convolutions and a spatial softmax (keypoint coordinates), for policies that must place
    things precisely; "small": four strided convolutions pooled to 2x2, for global judgements (the goal score);
    "resnet18": torchvision's, randomly initialised."""
    if backbone == "resnet18":
        net = resnet18(weights=None)  # no download: trained from scratch on our demonstrations
        net.fc = nn.Linear(net.fc.in_features, out_dim)
        return net
    if backbone == "spatial":
        return nn.Sequential(
            nn.Conv2d(3, 32, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(32, 32, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(32, 64, 3, stride=1, padding=1), nn.ReLU(),
            nn.Conv2d(64, 32, 3, stride=1, padding=1),
            SpatialSoftmax(), nn.Linear(64, out_dim), nn.ReLU(),
        )
    if in_channels != 3 and backbone != "small":
        raise ValueError(f"the {backbone} encoder reads 3 channels; stacked cameras need the small one")
    return nn.Sequential(
        nn.Conv2d(in_channels, 32, 5, stride=2, padding=2), nn.ReLU(),
        nn.Conv2d(32, 64, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(64, 64, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(64, 128, 3, stride=2, padding=1), nn.ReLU(),
        nn.AdaptiveAvgPool2d(2), nn.Flatten(), nn.Linear(128 * 4, out_dim), nn.ReLU(),
    )


def encode(encoder: nn.Module, images: torch.Tensor, bfloat16: bool = False) -> torch.Tensor:
    """`encoder(images)`, with its leading convolutions in bfloat16 if asked (autocast: the weights stay float32).
    The convolutions are nearly all of a training step's time, and a CPU with AMX runs them in bfloat16 at about
    twice the speed; what follows them (the spatial softmax's keypoints, whose precision places the gear) runs in
    float32. A backbone that is not a sequence of layers runs wholly under autocast."""
    if not bfloat16:
        return encoder(images)
    bf16 = torch.autocast(images.device.type, dtype=torch.bfloat16)
    if not isinstance(encoder, nn.Sequential):
        with bf16:
            return encoder(images).float()
    x, layers = images, list(encoder)
    with bf16:
        while layers and isinstance(layers[0], (nn.Conv2d, nn.ReLU)):
            x = layers.pop(0)(x)
    x = x.float()
    for layer in layers:
        x = layer(x)
    return x


class MixtureDensityHead(nn.Module):
    """Features -> a mixture of K diagonal Gaussians over a D-dimensional target."""

    def __init__(self, in_dim: int, out_dim: int, num_mixtures: int, min_std: float = 1e-3):
        super().__init__()
        self.D, self.K = out_dim, num_mixtures
        self.min_log_std = math.log(min_std)
        self.logits = nn.Linear(in_dim, num_mixtures)
        self.means = nn.Linear(in_dim, num_mixtures * out_dim)
        self.log_stds = nn.Linear(in_dim, num_mixtures * out_dim)

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        B = h.shape[0]
        log_pi = F.log_softmax(self.logits(h), dim=-1)
        mu = self.means(h).view(B, self.K, self.D)
        log_std = self.log_stds(h).view(B, self.K, self.D).clamp(self.min_log_std, 3.0)
        return log_pi, mu, log_std

    @staticmethod
    def nll(log_pi, mu, log_std, y: torch.Tensor) -> torch.Tensor:
        """Mean negative log-likelihood of targets y (B, D)."""
        z = (y[:, None, :] - mu) / log_std.exp()
        log_prob = -0.5 * (z ** 2).sum(-1) - log_std.sum(-1) - 0.5 * mu.shape[-1] * math.log(2 * math.pi)
        return -torch.logsumexp(log_pi + log_prob, dim=-1).mean()

    @staticmethod
    def sample(log_pi, mu, log_std, generator: torch.Generator | None = None,
               draws: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """One draw per row of log_pi (..., K), mu and log_std (..., K, D): the component by the inverse CDF of a
        uniform, then Gaussian noise. `draws` (uniforms (...,), standard normals (..., D)) are the caller's, so
        that a batch of models samples as each model would alone; by default they come from `generator`."""
        if draws is None:
            draws = (torch.rand(log_pi.shape[:-1], generator=generator),
                     torch.randn(mu.shape[:-2] + mu.shape[-1:], generator=generator))
        u, noise = draws
        k = (log_pi.exp().cumsum(-1) < u[..., None]).sum(-1, keepdim=True).clamp(max=mu.shape[-2] - 1)
        k = k[..., None].expand(*k.shape, mu.shape[-1])
        return mu.gather(-2, k).squeeze(-2) + noise * log_std.gather(-2, k).squeeze(-2).exp()

    @staticmethod
    def mode(log_pi, mu, log_std) -> torch.Tensor:
        """The mean of the most probable component: a deterministic action."""
        return mu[torch.arange(len(mu)), log_pi.argmax(-1)]


class MixtureDensityMLP(nn.Module):
    """A vector (B, in_dim), standardised by the buffers `z_mean` and `z_std`, through two hidden layers to a mixture
    density head: each controller's dynamics model and the latent goal score are this network over the VAE's latent."""

    def __init__(self, in_dim: int, hidden_dim: int, out_dim: int, num_mixtures: int):
        super().__init__()
        self.trunk = nn.Sequential(nn.Linear(in_dim, hidden_dim), nn.ReLU(), nn.Linear(hidden_dim, hidden_dim),
                                   nn.ReLU())
        self.head = MixtureDensityHead(hidden_dim, out_dim, num_mixtures)
        self.register_buffer("z_mean", torch.zeros(in_dim))
        self.register_buffer("z_std", torch.ones(in_dim))

    def forward(self, z: torch.Tensor):
        return self.head(self.trunk((z - self.z_mean) / self.z_std))
