"""Configurations of the selector's learned models (paper: Goal Score Evaluation, Controller Dynamics Modelling).

Defaults are the sizes the project trains at on a 2-core CPU; `policy-composer demo --profile paper` and the
CLI flags change them. Each config is saved beside its checkpoint, and a checkpoint only loads into the
configuration it was trained with.
"""

from __future__ import annotations

from dataclasses import dataclass

from policy_composer.learning.config import BACKBONES, TrainingConfig, check_options, option
from policy_composer.tasks.registry import get_spec

GOAL_SCORES = ("image", "latent")  # what the selector's goal score reads: each prediction decoded, or the latent
# Where the library's controllers have the task's predicates from: classifiers of the cameras and joints, or the
# simulator's truth (privileged: the oracle's side of the figures).
SENSES = ("learned", "oracle")


def check_cameras(config, cameras: tuple[str, ...]) -> None:
    """Refuse cameras the config's task does not have, naming those it has."""
    spec = get_spec(config.task)
    unknown = [c for c in cameras if c not in spec.cameras]
    if unknown or not cameras:
        raise ValueError(f"{type(config).__name__}: {spec.env_id} has the cameras {list(spec.cameras)}, not "
                         f"{list(cameras)}")


@dataclass
class VAEConfig(TrainingConfig):
    """The latent state s_t: a variational autoencoder of one camera's images. The paper uses the head camera; on
    the gear the arm hides the insertion from it (its goal score is the same for a gear held above the peg and one
    seated on it), so the selector sees through the left forearm camera, which watches the gear in the hand (each
    task's `latent_camera`)."""

    camera: str = option("", "the camera whose images make the latent state (default: the task's)", camera=True)
    image_size: int = option(64, "images are resized to this square", minimum=16)
    latent_dim: int = option(32, "size of the latent state", minimum=1)
    beta: float = 1.0  # weight of the KL term against the per-image reconstruction error (summed over pixels)
    epochs: int = option(30, "VAE training epochs", minimum=1)

    def __post_init__(self):
        super().__post_init__()
        self.camera = self.camera or get_spec(self.task).latent_camera
        check_cameras(self, (self.camera,))


@dataclass
class DynamicsConfig(TrainingConfig):
    """D_w: a mixture density network over the next latent under controller w."""

    controller: str = ""
    latent_dim: int = 32  # the VAE's
    # n = 10 steps of 15 look 150 control steps ahead: as long as an insertion that feels for the hole takes, so the
    # selector sees where an insertion ends (seated, or backed off), not only how fast it starts down.
    frame_skip: int = option(15, "control steps per dynamics step (one selector look-ahead step)", minimum=1)
    hidden_dim: int = 256
    num_mixtures: int = option(5, "mixture components of each dynamics model", minimum=1)
    decoder_weight: float = 1.0  # the shared decoder: the predicted latent must decode to the real next image
    epochs: int = option(60, "dynamics-model training epochs", minimum=1)


@dataclass
class GoalScoreConfig(TrainingConfig):
    """G: a CNN with a mixture density head over task progress, trained on full-task demonstrations."""

    camera: str = option("", "the camera the goal score sees (default: the task's)", camera=True)
    image_size: int = option(64, "images are resized to this square", minimum=16)
    backbone: str = option("small", "image encoder", BACKBONES)
    hidden_dim: int = 256
    num_mixtures: int = option(24, "Gaussian mixture components (paper: 24)", minimum=1)
    shift: int = 4  # random-shift augmentation (pixels)
    weight_decay: float = 1e-6
    batch_size: int = option(120, "minibatch size", minimum=1)
    epochs: int = option(60, "goal-score training epochs", minimum=1)

    def __post_init__(self):
        super().__post_init__()
        self.camera = self.camera or get_spec(self.task).goal_camera
        check_cameras(self, (self.camera,))


@dataclass
class LatentGoalScoreConfig(TrainingConfig):
    """G on the VAE's latent state (the paper's experiments: the goal score "operates on the latent space"): an MLP
    with a mixture density head, so the selector scores its predicted latents without decoding them to images."""

    latent_dim: int = 32  # the VAE's
    hidden_dim: int = 256
    num_mixtures: int = option(24, "Gaussian mixture components (paper: 24)", minimum=1)
    weight_decay: float = 1e-6
    batch_size: int = option(120, "minibatch size", minimum=1)
    epochs: int = option(300, "latent goal-score training epochs (an epoch is a few batches)", minimum=1)


@dataclass
class PredicateConfig(TrainingConfig):
    """One of the task's predicates as a robot has it: a binary classifier of the cameras' images, stacked, and the
    joint state, trained on the recordings' labels."""

    predicate: str = option("", "the predicate (one of the task's)")
    cameras: tuple[str, ...] = ()  # the cameras of every recording they train on (default: the task's)
    image_size: int = option(64, "images are resized to this square", minimum=16)
    hidden_dim: int = 128
    shift: int = 4  # random-shift augmentation (pixels)
    weight_decay: float = 1e-6
    batch_size: int = option(128, "minibatch size", minimum=1)
    epochs: int = option(6, "predicate training epochs", minimum=1)
    lr_decay: bool = True  # the step size decays to zero over the epochs (`cosine_decay`)

    def __post_init__(self):
        super().__post_init__()
        spec = get_spec(self.task)
        self.cameras = tuple(self.cameras) or spec.predicate_cameras  # a list when read back from JSON
        check_cameras(self, self.cameras)
        if self.predicate and self.predicate not in spec.predicates:
            raise ValueError(f"PredicateConfig.predicate must be one of {spec.env_id}'s {', '.join(spec.predicates)}, "
                             f"not {self.predicate!r}")


@dataclass
class ComposeConfig:
    horizon: int = option(10, "n: dynamics steps looked ahead (paper: 10)", minimum=1)
    samples: int = option(16, "K: sampled rollouts per controller", minimum=1)
    reselect_every: int | None = option(None, "also decide every this many control steps (default: only when the "
                                        "running controller terminates)", minimum=1)
    max_steps: int = 900  # control steps per episode
    max_failures: int = option(1, "a controller that failed this often since the last success is not chosen again",
                               minimum=1)
    episode_failures: int = option(2, "a controller that failed this often in the episode is not chosen again",
                                   minimum=1)
    senses: str = option("oracle", "where the controllers have the task's predicates from: the simulator's truth "
                         "(the oracle), or the world model's classifiers (learned)", SENSES)

    def __post_init__(self):
        check_options(self)
