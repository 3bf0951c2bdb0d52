"""The goal score G (paper: Goal Score Evaluation): a CNN with a mixture density head estimating task progress
from one camera's image, trained on full-task demonstrations with target frame index / (T - 1).

One model per camera; `evaluate_goal_score` compares them on held-out demonstrations. The selector scores
predicted latents by decoding them with the VAE and running the scorer of the VAE's camera on the decoded
images; that scorer also trains on the VAE's reconstructions of its demonstrations, so it scores blurry
decoded images as it scores real ones.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from policy_composer.data.frames import episode_bounds, random_shift, to_model_image
from policy_composer.learning.checkpoint import load_checkpoint, save_checkpoint
from policy_composer.learning.layers import MixtureDensityHead, image_encoder
from policy_composer.learning.training import fit_epochs
from policy_composer.selector.configuration import GoalScoreConfig

TRAIN_HINT = "policy-composer train goal-score"


class GoalScoreModel(nn.Module):
    SCALE = 4.0  # the head models progress as (progress - 0.5) * SCALE: unit-scale targets train much faster

    def __init__(self, config: GoalScoreConfig):
        super().__init__()
        self.config = config
        self.encoder = image_encoder(config.backbone, config.hidden_dim)
        self.trunk = nn.Sequential(nn.Linear(config.hidden_dim, config.hidden_dim), nn.ReLU())
        self.head = MixtureDensityHead(config.hidden_dim, 1, config.num_mixtures)

    def forward(self, images: torch.Tensor):
        return self.head(self.trunk(self.encoder(images)))

    def loss(self, images: torch.Tensor, progress: torch.Tensor) -> torch.Tensor:
        return self.head.nll(*self(images), (progress[:, None] - 0.5) * self.SCALE)

    @torch.no_grad()
    def expected(self, images: torch.Tensor) -> torch.Tensor:
        """E[progress | image], clipped to [0, 1]: images (B, 3, S, S) in [0, 1] (resized if need be)."""
        images = to_model_image(images, self.config.image_size)
        log_pi, mu, _ = self(images)
        return ((log_pi.exp() * mu[..., 0]).sum(-1) / self.SCALE + 0.5).clamp(0.0, 1.0)

    @torch.no_grad()
    def scores(self, images_uint8: torch.Tensor, batch: int = 256) -> torch.Tensor:
        return torch.cat([self.expected(images_uint8[i:i + batch].float() / 255.0)
                          for i in range(0, len(images_uint8), batch)])


def train_goal_score(images: torch.Tensor, progress: torch.Tensor, config: GoalScoreConfig,
                     out: str | Path | None = None, progress_bar: bool = True,
                     trained_with: dict[str, str] | None = None) -> tuple[GoalScoreModel, list[float]]:
    """Fit G to uint8 images (N, 3, S, S) and their progress labels in [0, 1]; `trained_with` names the VAE whose
    reconstructions are among the images, if any."""
    t0 = time.perf_counter()
    if progress.min() < 0:
        raise ValueError("progress labels must be in [0, 1]: train the goal score on successful demonstrations only")
    torch.manual_seed(config.seed)
    model = GoalScoreModel(config)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    gen = torch.Generator().manual_seed(config.seed)
    losses = fit_epochs(model, opt, len(images), config.batch_size, config.epochs,
                        lambda idx: model.loss(random_shift(images[idx].float() / 255.0, config.shift, gen),
                                               progress[idx].float()),
                        gen, f"training goal score ({config.camera})", progress_bar, postfix="nll")
    if out is not None:
        log = {"frames": len(images), "losses": losses, "seconds": round(time.perf_counter() - t0, 1)}
        save_checkpoint(model, config, out, log, trained_with)
    return model, losses


def load_goal_score(path: str | Path) -> GoalScoreModel:
    return load_checkpoint(path, GoalScoreConfig, GoalScoreModel, "goal score", TRAIN_HINT)


def goal_score_metrics(scores: torch.Tensor, progress: torch.Tensor, episode_index: torch.Tensor) -> dict:
    """Spearman correlation with true progress (mean over episodes) and mean absolute error."""
    from scipy.stats import spearmanr

    rhos = [spearmanr(scores[a:b].numpy(), progress[a:b].numpy()).statistic for a, b in episode_bounds(episode_index)]
    return {"spearman": float(np.mean(rhos)), "mae": float((scores - progress).abs().mean()),
            "episodes": len(rhos), "frames": len(scores)}
