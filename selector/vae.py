"""The latent state: a convolutional VAE of one camera's images (paper: the world model's encoder and decoder).

The dynamics models predict in its latent space and share its decoder, so any predicted latent decodes to an
image: a user can look at what the model expects a controller to do.
"""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from policy_composer.learning.checkpoint import load_checkpoint
from policy_composer.learning.trainer import Fit, train_model
from policy_composer.selector.configuration import VAEConfig

TRAIN_HINT = "policy-composer train world-model"


class ChannelsLast(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.contiguous(memory_format=torch.channels_last)


class VAE(nn.Module):
    def __init__(self, config: VAEConfig):
        super().__init__()
        if config.image_size % 16:
            raise ValueError(f"the VAE's image_size must be a multiple of 16, not {config.image_size}")
        self.config = config
        s = config.image_size // 16
        self.encoder = nn.Sequential(
            nn.Conv2d(3, 32, 4, 2, 1), nn.ReLU(), nn.Conv2d(32, 64, 4, 2, 1), nn.ReLU(),
            nn.Conv2d(64, 128, 4, 2, 1), nn.ReLU(), nn.Conv2d(128, 256, 4, 2, 1), nn.ReLU(), nn.Flatten(),
        )
        self.to_stats = nn.Linear(256 * s * s, 2 * config.latent_dim)
        self.from_latent = nn.Linear(config.latent_dim, 256 * s * s)
        self.decoder = nn.Sequential(
            nn.Unflatten(1, (256, s, s)), nn.ConvTranspose2d(256, 128, 4, 2, 1), nn.ReLU(),
            nn.ConvTranspose2d(128, 64, 4, 2, 1), nn.ReLU(), nn.ConvTranspose2d(64, 32, 4, 2, 1), nn.ReLU(),
            nn.ConvTranspose2d(32, 3, 4, 2, 1), nn.Sigmoid(),
        )

    def encode(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 3, S, S) in [0, 1] -> mean and log-variance of q(z | image), (B, L) each."""
        mu, logvar = self.to_stats(self.encoder(images)).chunk(2, dim=-1)
        return mu, logvar.clamp(-10, 10)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return self.decoder(self.from_latent(z))

    @torch.no_grad()
    def inference_decoder(self) -> nn.Module:
        """`decode` for many latents at once (the selector's futures), same function: the latent layer and the first
        transposed convolution are both linear, so they fold into one matrix (a third of the work), and the rest
        runs channels-last, the layout the CPU's convolution kernels want. A snapshot: build it after training."""
        first, s = self.decoder[1], self.config.image_size // 16
        linear_part = first(self.from_latent.weight.T.reshape(-1, 256, s, s)) - first.bias[:, None, None]
        folded = nn.Linear(self.config.latent_dim, linear_part[0].numel())
        folded.weight.copy_(linear_part.flatten(1).T)
        folded.bias.copy_(first(self.from_latent.bias.reshape(1, 256, s, s)).flatten())
        rest = copy.deepcopy(self.decoder[2:]).to(memory_format=torch.channels_last)
        return nn.Sequential(folded, nn.Unflatten(1, linear_part.shape[1:]), ChannelsLast(), *rest).eval()

    def loss(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Negative ELBO per image: summed squared reconstruction error + beta * KL; also returns the error."""
        mu, logvar = self.encode(images)
        z = mu + torch.randn_like(mu) * (0.5 * logvar).exp()
        recon = F.mse_loss(self.decode(z), images, reduction="none").flatten(1).sum(1)
        kl = -0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum(1)
        return (recon + self.config.beta * kl).mean(), recon.mean()

    @torch.no_grad()
    def latents(self, images_uint8: torch.Tensor, batch: int = 256) -> torch.Tensor:
        """Posterior means of uint8 images (N, 3, S, S): the deterministic latent state the selector uses."""
        return torch.cat([self.encode(images_uint8[i:i + batch].float() / 255.0)[0]
                          for i in range(0, len(images_uint8), batch)]) if len(images_uint8) else \
            torch.zeros(0, self.config.latent_dim)


def _digest(images: torch.Tensor) -> str:
    """Which images a training is of (a snapshot of a VAE trained on others is not resumed)."""
    return hashlib.sha256(images.contiguous().numpy()).hexdigest()[:16]


def train_vae(images: torch.Tensor, config: VAEConfig, out: str | Path | None = None,
              progress: bool = True) -> tuple[VAE, list[float]]:
    """Fit the VAE to uint8 images (N, 3, S, S); returns it and the per-epoch mean loss."""

    def build(generator: torch.Generator) -> Fit:
        model = VAE(config)
        return Fit(model, len(images), lambda idx: model.loss(images[idx].float() / 255.0)[0],
                   log={"frames": len(images)}, snapshot={"images": _digest(images)})

    return train_model(config, build, f"training VAE ({config.camera})", out, progress, digits=1)


def load_vae(path: str | Path) -> VAE:
    return load_checkpoint(path, VAEConfig, VAE, "VAE", TRAIN_HINT)
