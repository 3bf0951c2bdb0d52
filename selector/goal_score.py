"""The goal score G (paper: Goal Score Evaluation): a mixture density head estimating task progress, trained on
full-task demonstrations with target frame index / (T - 1).

`GoalScoreModel` reads one camera's image (a CNN): one model per camera, compared by `evaluate_goal_score` on
held-out demonstrations. The selector scores predicted latents by decoding them with the VAE and running the
scorer of the VAE's camera on the decoded images; that scorer also trains on the VAE's reconstructions of its
demonstrations, so it scores blurry decoded images as it scores real ones. `LatentGoalScoreModel` reads the VAE's
latent itself (an MLP): it skips the decoding and the CNN, which are nearly all of a decision's time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from scipy.stats import spearmanr
from torch import nn

from policy_composer.data.frames import episode_bounds, random_shift, to_model_image
from policy_composer.learning.checkpoint import load_checkpoint
from policy_composer.learning.layers import MixtureDensityHead, MixtureDensityMLP, image_encoder
from policy_composer.learning.trainer import Fit, train_model
from policy_composer.selector.configuration import GoalScoreConfig, LatentGoalScoreConfig

TRAIN_HINT = "policy-composer train goal-score"
SCALE = 4.0  # the heads model progress as (progress - 0.5) * SCALE: unit-scale targets train much faster


def progress_nll(params, progress: torch.Tensor) -> torch.Tensor:
    return MixtureDensityHead.nll(*params, (progress[:, None] - 0.5) * SCALE)


def expected_progress(params) -> torch.Tensor:
    """E[progress] of a mixture over scaled progress, clipped to [0, 1]."""
    log_pi, mu, _ = params
    return ((log_pi.exp() * mu[..., 0]).sum(-1) / SCALE + 0.5).clamp(0.0, 1.0)


class GoalScoreModel(nn.Module):
    def __init__(self, config: GoalScoreConfig):
        super().__init__()
        self.config = config
        self.encoder = image_encoder(config.backbone, config.hidden_dim)
        self.trunk = nn.Sequential(nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU())
        self.head = MixtureDensityHead(config.hidden_dim, 1, config.num_mixtures)

    def forward(self, images: torch.Tensor):
        return self.head(self.trunk(self.encoder(images)))

    def loss(self, images: torch.Tensor, progress: torch.Tensor) -> torch.Tensor:
        return progress_nll(self(images), progress)

    @torch.no_grad()
    def expected(self, images: torch.Tensor) -> torch.Tensor:
        """E[progress | image], clipped to [0, 1]: images (B, 3, S, S) in [0, 1] (resized if need be)."""
        return expected_progress(self(to_model_image(images, self.config.image_size)))

    @torch.no_grad()
    def scores(self, images_uint8: torch.Tensor, batch: int = 256) -> torch.Tensor:
        return torch.cat([self.expected(images_uint8[i:i + batch].float() / 255.0)
                          for i in range(0, len(images_uint8), batch)])


class LatentGoalScoreModel(MixtureDensityMLP):
    """G of a latent state (B, L) of the VAE it was trained with. Normalisation statistics live in buffers."""

    def __init__(self, config: LatentGoalScoreConfig):
        super().__init__(config.latent_dim, config.hidden_dim, 1, config.num_mixtures)
        self.config = config

    def loss(self, z: torch.Tensor, progress: torch.Tensor) -> torch.Tensor:
        return progress_nll(self(z), progress)

    @torch.no_grad()
    def expected(self, z: torch.Tensor) -> torch.Tensor:
        """E[progress | latent], clipped to [0, 1]."""
        return expected_progress(self(z))


def train_goal_score(images: torch.Tensor, progress: torch.Tensor, config: GoalScoreConfig,
                     out: str | Path | None = None, progress_bar: bool = True,
                     trained_with: dict[str, str] | None = None) -> tuple[GoalScoreModel, list[float]]:
    """Fit G to uint8 images (N, 3, S, S) and their progress labels in [0, 1]; `trained_with` names the VAE whose
    reconstructions are among the images, if any."""
    _check_progress(progress)

    def build(generator: torch.Generator) -> Fit:
        model = GoalScoreModel(config)
        return Fit(model, len(images),
                   lambda idx: model.loss(random_shift(images[idx].float() / 255.0, config.shift, generator),
                                          progress[idx].float()),
                   log={"frames": len(images)})

    return train_model(config, build, f"training goal score ({config.camera})", out, progress_bar, postfix="nll",
                       trained_with=trained_with)


def train_latent_goal_score(mean: torch.Tensor, logvar: torch.Tensor, progress: torch.Tensor,
                            config: LatentGoalScoreConfig, out: str | Path | None = None, progress_bar: bool = True,
                            trained_with: dict[str, str] | None = None) -> tuple[LatentGoalScoreModel, list[float]]:
    """Fit G to the VAE posteriors (mean, log-variance, (N, L) each) of demonstration frames. Each batch samples its
    latents from the posteriors, as the random shift augments the images: the predicted latents it will score are
    near, not at, the posterior means."""
    _check_progress(progress)
    std = (0.5 * logvar).exp()

    def build(generator: torch.Generator) -> Fit:
        model = LatentGoalScoreModel(config)
        model.z_mean.copy_(mean.mean(0))
        model.z_std.copy_(mean.std(0).clamp_min(1e-3))
        return Fit(model, len(mean),
                   lambda idx: model.loss(mean[idx] + std[idx] * torch.randn(std[idx].shape, generator=generator),
                                          progress[idx].float()),
                   log={"frames": len(mean)})

    return train_model(config, build, "training goal score (latent)", out, progress_bar, postfix="nll",
                       trained_with=trained_with)


def _check_progress(progress: torch.Tensor) -> None:
    if progress.min() < 0:
        raise ValueError("progress labels must be in [0, 1]: train the goal score on successful demonstrations only")


def load_goal_score(path: str | Path) -> GoalScoreModel:
    return load_checkpoint(path, GoalScoreConfig, GoalScoreModel, "goal score", TRAIN_HINT)


def load_latent_goal_score(path: str | Path) -> LatentGoalScoreModel:
    return load_checkpoint(path, LatentGoalScoreConfig, LatentGoalScoreModel, "latent goal score", TRAIN_HINT)


def goal_score_metrics(scores: torch.Tensor, progress: torch.Tensor, episode_index: torch.Tensor) -> dict:
    """Spearman correlation with true progress (mean over episodes) and mean absolute error."""
    rhos = [spearmanr(scores[a:b].numpy(), progress[a:b].numpy()).statistic for a, b in episode_bounds(episode_index)]
    return {"spearman": float(np.mean(rhos)), "mae": float((scores - progress).abs().mean()),
            "episodes": len(rhos), "frames": len(scores)}
