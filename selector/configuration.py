"""Configurations of the selector's learned models (paper: Goal Score Evaluation, Controller Dynamics Modelling).

Defaults are the sizes the project trains at on a 2-core CPU; `policy-composer demo --profile paper` and the
CLI flags change them. Each config is saved beside its checkpoint, and a checkpoint only loads into the
configuration it was trained with.
"""

from __future__ import annotations

from dataclasses import dataclass

from tasks.gear_assembly import CAMERA_NAMES


def _check_camera(camera: str) -> None:
    if camera not in CAMERA_NAMES:
        raise ValueError(f"camera must be one of {CAMERA_NAMES}, not {camera!r}")


@dataclass
class VAEConfig:
    """The latent state s_t: a variational autoencoder of one camera's images (the paper uses the head camera)."""

    camera: str = "head"
    image_size: int = 64
    latent_dim: int = 32
    beta: float = 1.0  # weight of the KL term against the per-image reconstruction error (summed over pixels)
    lr: float = 1e-3
    batch_size: int = 64
    epochs: int = 30
    seed: int = 0

    def __post_init__(self):
        _check_camera(self.camera)


@dataclass
class DynamicsConfig:
    """D_w: a mixture density network over the next latent under controller w."""

    controller: str = ""
    latent_dim: int = 32  # the VAE's
    frame_skip: int = 5  # control steps per dynamics step (one selector look-ahead step)
    hidden_dim: int = 256
    num_mixtures: int = 5
    decoder_weight: float = 1.0  # the shared decoder: the predicted latent must decode to the real next image
    lr: float = 1e-3
    batch_size: int = 64
    epochs: int = 60
    seed: int = 0


@dataclass
class GoalScoreConfig:
    """G: a CNN with a mixture density head over task progress, trained on full-task demonstrations."""

    camera: str = "head"
    image_size: int = 64
    backbone: str = "small"
    hidden_dim: int = 256
    num_mixtures: int = 24  # paper: 24 Gaussian mixtures
    shift: int = 4  # random-shift augmentation (pixels)
    lr: float = 1e-3
    weight_decay: float = 1e-6
    batch_size: int = 120
    epochs: int = 60
    seed: int = 0

    def __post_init__(self):
        _check_camera(self.camera)
