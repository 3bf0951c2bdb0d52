"""Configuration of the `cnn_mdn` policy type (defaults: the paper's, as the project's own CNN policy has them)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PreTrainedConfig
from lerobot.optim.optimizers import AdamConfig
from lerobot.optim.schedulers import CosineAnnealingWithWarmupSchedulerConfig
from lerobot.utils.constants import OBS_IMAGES

from policy_composer.learning.config import BACKBONES, refuse


@PreTrainedConfig.register_subclass("cnn_mdn")
@dataclass
class CNNMDNConfig(PreTrainedConfig):
    """One camera image and the state in, the next action out: a mixture density over the action's continuous
    entries and a logistic output for each binary one (a gripper commanded open or closed).

    The action is the dataset's own `action`, normalised to [-1, 1] by its minimum and maximum, so that a binary
    entry is exactly -1 or +1 and the policy's +1/-1 maps back onto the dataset's two values.
    """

    n_obs_steps: int = 1
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=lambda: {
        "VISUAL": NormalizationMode.IDENTITY, "STATE": NormalizationMode.MEAN_STD,
        "ACTION": NormalizationMode.MIN_MAX})

    # What the policy sees: one camera (`observation.images.<camera>`; None: the first the dataset has), of the
    # square `window` (top, left, side, as fractions of the image; None: all of it), resized to image_size.
    camera: str | None = None
    window: list[float] | None = None
    image_size: int = 64
    # The entries of observation.state the policy reads (None: all). The project's insertion reads the gripper's
    # width alone ([7]): with the joints as input, a few dozen demonstrations are fitted from the joints and the
    # image gets ignored (docs/controllers.md).
    state_indices: list[int] | None = None
    backbone: str = "spatial"
    hidden_dim: int = 256
    num_mixtures: int = 24  # paper
    min_std: float = 0.2  # the smallest component's deviation, in normalised units (see CNNPolicyConfig)
    # The action entries predicted as binary; None: those the dataset's statistics show to take two values only
    # (name them in a dataset of few episodes, where an entry held still in each may take two values too).
    binary_actions: list[int] | None = None
    shift: int = 4  # random-shift augmentation in pixels at image_size
    # A dataset feature of 3 values the image features learn to regress beside the actions (never an input; the
    # project's insertion datasets have `gear_offset`), and its weight.
    auxiliary_feature: str | None = None
    auxiliary_weight: float = 1.0

    optimizer_lr: float = 1e-3
    optimizer_weight_decay: float = 1e-6  # paper

    def __post_init__(self):
        super().__post_init__()
        if self.backbone not in BACKBONES:
            refuse(f"--policy.backbone={self.backbone!r} is not one of {', '.join(BACKBONES)}")
        if self.n_obs_steps != 1:
            refuse(f"cnn_mdn sees one observation step, not {self.n_obs_steps}: use --policy.n_obs_steps=1")
        if self.window is not None and (len(self.window) != 3 or not all(0 <= w <= 1 for w in self.window)):
            refuse(f"--policy.window={self.window} must be [top, left, side], fractions of the image")
        if self.image_size < 16:
            refuse(f"--policy.image_size={self.image_size} is too small for the encoder: use 16 or more")

    def get_optimizer_preset(self) -> AdamConfig:
        """Adam without gradient clipping, as the project's loop trains it."""
        return AdamConfig(lr=self.optimizer_lr, weight_decay=self.optimizer_weight_decay, grad_clip_norm=0.0)

    def get_scheduler_preset(self) -> CosineAnnealingWithWarmupSchedulerConfig:
        """Cosine decay to zero over the run: a mixture density network's loss spikes now and then, and the last
        step's weights are the ones kept, so end on small steps."""
        return CosineAnnealingWithWarmupSchedulerConfig(num_warmup_steps=0)

    def validate_features(self) -> None:
        cameras = [k.removeprefix(f"{OBS_IMAGES}.") for k in self.image_features]
        if not cameras or self.robot_state_feature is None:
            refuse("cnn_mdn needs a dataset with at least one camera (observation.images.*) and a state "
                             f"(observation.state); this one has cameras {cameras} and "
                             f"{'a' if self.robot_state_feature else 'no'} state")
        size = self.robot_state_feature.shape[0]
        if self.state_indices is not None and not all(0 <= i < size for i in self.state_indices):
            refuse(f"--policy.state_indices={self.state_indices} must be entries of the state, 0 to "
                             f"{size - 1}")
        if self.camera is None:
            self.camera = cameras[0]
        elif self.camera not in cameras:
            refuse(f"--policy.camera={self.camera} is not a camera of the dataset: choose one of "
                             f"{', '.join(cameras)}")
        # The cameras it does not read are not its inputs: a controller or an env need not render them.
        self.input_features = {k: v for k, v in self.input_features.items()
                               if v.type is not FeatureType.VISUAL or k == self.image_key}

    @property
    def image_key(self) -> str:
        return f"{OBS_IMAGES}.{self.camera}"

    @property
    def state_dim(self) -> int:
        return len(self.state_indices) if self.state_indices is not None else self.robot_state_feature.shape[0]

    @property
    def action_dim(self) -> int:
        return self.action_feature.shape[0]

    @property
    def offset_weight(self) -> float:
        return self.auxiliary_weight if self.auxiliary_feature else 0.0

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None
