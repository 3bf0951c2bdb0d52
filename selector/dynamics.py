"""Controller dynamics models (paper: Controller Dynamics Modelling): one mixture density network per
controller, predicting the latent state `frame_skip` control steps ahead while that controller runs.

Each model trains only on its own controller's rollouts. It shares the VAE's decoder: besides the likelihood
of the next latent, its expected prediction must decode to the real next image, which keeps the predicted
latents where the decoder (and so the goal score) understands them.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from policy_composer.data.frames import episode_bounds
from policy_composer.learning.checkpoint import CheckpointError, load_checkpoint
from policy_composer.learning.layers import MixtureDensityHead, MixtureDensityMLP
from policy_composer.learning.trainer import Fit, train_model
from policy_composer.selector.configuration import DynamicsConfig
from policy_composer.selector.vae import VAE

TRAIN_HINT = "policy-composer train world-model"


class LatentDynamics(MixtureDensityMLP):
    """z_t -> a mixture over z_{t+k} - z_t. Normalisation statistics live in buffers."""

    def __init__(self, config: DynamicsConfig):
        L = config.latent_dim
        super().__init__(L, config.hidden_dim, L, config.num_mixtures)
        self.config = config
        self.register_buffer("delta_mean", torch.zeros(L))
        self.register_buffer("delta_std", torch.ones(L))

    def expected(self, z: torch.Tensor, params=None) -> torch.Tensor:
        """The mixture's mean next latent (differentiable: the decoder loss trains through it)."""
        log_pi, mu, _ = params if params is not None else self(z)
        delta = (log_pi.exp()[..., None] * mu).sum(1)
        return z + delta * self.delta_std + self.delta_mean

    def loss(self, z: torch.Tensor, z_next: torch.Tensor, vae: VAE | None = None,
             next_images: torch.Tensor | None = None) -> torch.Tensor:
        params = self(z)
        nll = self.head.nll(*params, (z_next - z - self.delta_mean) / self.delta_std)
        if vae is None or self.config.decoder_weight == 0:
            return nll
        decoded = vae.decode(self.expected(z, params))
        recon = F.mse_loss(decoded, next_images, reduction="none").flatten(1).sum(1).mean()
        return nll + self.config.decoder_weight * recon

    @torch.no_grad()
    def step(self, states: torch.Tensor, generator: torch.Generator | None = None,
             draws: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """One sampled dynamics step, (M, L) -> (M, L): the selector's D_w (`draws`: see MixtureDensityHead.sample)."""
        delta = self.head.sample(*self(states), generator=generator, draws=draws)
        return states + delta * self.delta_std + self.delta_mean


class StackedDynamics(nn.Module):
    """The dynamics models of several controllers as one module: a step of all of them is a few batched matrix
    products instead of a Python loop over controllers and layers. Same arithmetic as each `LatentDynamics.step`."""

    def __init__(self, models: list[LatentDynamics]):
        super().__init__()
        if not self.stackable(models):
            raise ValueError("stacked dynamics models must share one shape (latent, hidden, mixtures)")
        self.L, self.K = models[0].config.latent_dim, models[0].config.num_mixtures
        # Each layer as (W, in, out) weights and (W, 1, out) biases. The head's three layers read the same features,
        # so one matrix product makes all three outputs.
        layers = {"fc1": [[m.trunk[0]] for m in models], "fc2": [[m.trunk[2]] for m in models],
                  "head": [[m.head.logits, m.head.means, m.head.log_stds] for m in models]}
        for name, per_model in layers.items():
            self.register_buffer(f"{name}_w", torch.stack([torch.cat([lin.weight for lin in ls]).T
                                                           for ls in per_model]).detach())
            self.register_buffer(f"{name}_b", torch.stack([torch.cat([lin.bias for lin in ls])[None]
                                                           for ls in per_model]).detach())
        stats = {name: torch.stack([getattr(m, name)[None] for m in models]) for name in  # (W, 1, L)
                 ("z_mean", "z_std", "delta_mean", "delta_std")}
        # The input's normalisation is linear too: it folds into the first layer.
        self.fc1_b = self.fc1_b - (stats["z_mean"] / stats["z_std"]) @ self.fc1_w
        self.fc1_w = self.fc1_w / stats["z_std"].transpose(1, 2)
        self.register_buffer("delta_mean", stats["delta_mean"])
        self.register_buffer("delta_std", stats["delta_std"])
        self.min_log_std = models[0].head.min_log_std

    def select(self, index: torch.Tensor) -> StackedDynamics:
        """The stack of models `index` only (a copy of their parameters): a decision steps only what may start."""
        sub = copy.copy(self)
        sub._buffers = {name: buffer[index] for name, buffer in self._buffers.items()}
        return sub

    @staticmethod
    def stackable(models: list[LatentDynamics]) -> bool:
        return len({(m.config.latent_dim, m.config.hidden_dim, m.config.num_mixtures) for m in models}) == 1

    @torch.no_grad()
    def step(self, z: torch.Tensor, draws: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """(W, M, L) latents, model w stepping row w -> (W, M, L); draws (W, M) and (W, M, L)."""
        W, M, _ = z.shape
        h = torch.relu(torch.baddbmm(self.fc1_b, z, self.fc1_w))
        h = torch.relu(torch.baddbmm(self.fc2_b, h, self.fc2_w))
        logits, mu, log_std = torch.baddbmm(self.head_b, h, self.head_w).split(
            [self.K, self.K * self.L, self.K * self.L], dim=-1)
        log_pi = torch.log_softmax(logits, dim=-1)
        mu, log_std = mu.reshape(W, M, self.K, self.L), log_std.reshape(W, M, self.K, self.L)
        delta = MixtureDensityHead.sample(log_pi, mu, log_std.clamp(self.min_log_std, 3.0), draws=draws)
        return z + delta * self.delta_std + self.delta_mean


def transition_pairs(episode_index: torch.Tensor, frame_skip: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Row indices (t, t+k) within each episode; past an episode's end the controller has stopped, so the
    target is its last frame (the model learns that a finished controller changes nothing)."""
    src, dst = [], []
    for start, end in episode_bounds(episode_index):
        t = torch.arange(start, end)
        src.append(t)
        dst.append((t + frame_skip).clamp(max=end - 1))
    return torch.cat(src), torch.cat(dst)


@torch.no_grad()
def prediction_error(model: LatentDynamics, latents: torch.Tensor, episode_index: torch.Tensor) -> dict[str, float]:
    """The model's mean squared error over recorded transitions `frame_skip` steps apart (latents (N, L) of one
    controller's frames), beside that of predicting no change: a model that learnt nothing scores as "unchanged"."""
    src, dst = transition_pairs(episode_index, model.config.frame_skip)
    target = latents[dst]
    return {"model": float(((model.expected(latents[src]) - target) ** 2).mean()),
            "unchanged": float(((latents[src] - target) ** 2).mean())}


def train_dynamics(latents: torch.Tensor, images: torch.Tensor, episode_index: torch.Tensor, config: DynamicsConfig,
                   vae: VAE, out: str | Path | None = None, progress: bool = True,
                   trained_with: dict[str, str] | None = None) -> tuple[LatentDynamics, list[float]]:
    """Fit D_w on one controller's frames: latents (N, L) from the VAE, their uint8 images and episodes.
    `trained_with` names the VAE and the controller's model (see `weights_id`) in the checkpoint."""
    if len(latents) < 2:
        raise ValueError(f"controller {config.controller!r} has {len(latents)} recorded frames; record its rollouts "
                         f"first (policy-composer record gear-controller-rollouts)")
    src, dst = transition_pairs(episode_index, config.frame_skip)

    def build(generator: torch.Generator) -> Fit:
        model = LatentDynamics(config)
        delta = latents[dst] - latents[src]
        model.z_mean.copy_(latents.mean(0))
        model.z_std.copy_(latents.std(0).clamp_min(1e-3))
        model.delta_mean.copy_(delta.mean(0))
        model.delta_std.copy_(delta.std(0).clamp_min(1e-3))
        for p in vae.parameters():  # shared, not trained here
            p.requires_grad_(False)
        return Fit(model, len(src),
                   lambda idx: model.loss(latents[src[idx]], latents[dst[idx]], vae, images[dst[idx]].float() / 255.0),
                   log={"pairs": len(src)})

    return train_model(config, build, f"training dynamics ({config.controller})", out, progress, digits=2,
                       trained_with=trained_with)


def load_dynamics(path: str | Path, latent_dim: int | None = None) -> LatentDynamics:
    model = load_checkpoint(path, DynamicsConfig, LatentDynamics, "dynamics model", TRAIN_HINT)
    if latent_dim is not None and model.config.latent_dim != latent_dim:
        raise CheckpointError(f"dynamics model {path} predicts {model.config.latent_dim}-D latents, but the VAE's are "
                              f"{latent_dim}-D; train the world model again as one (`{TRAIN_HINT}`)")
    return model
