"""The `cnn_mdn` policy: policy-composer's CNN policy network (`policies/cnn/modeling_cnn.py`, the same module the
project's own loop trains) behind LeRobot's policy interface."""

from __future__ import annotations

import numpy as np
import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_policy_cnn_mdn.configuration_cnn_mdn import CNNMDNConfig
from policy_composer.data.frames import random_shift, to_model_image
from policy_composer.learning.config import refuse
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy


def two_valued(stats: dict) -> list[int]:
    """The entries whose statistics show two values only: their variance reaches the Bhatia-Davis bound
    (max - mean)(mean - min), which holds with equality for two-valued data alone (a constant entry is not one)."""
    lo, hi, mean, std = (np.asarray(stats[k], dtype=np.float64).reshape(-1) for k in ("min", "max", "mean", "std"))
    span = hi - lo
    bound = (hi - mean) * (mean - lo)
    return [int(i) for i in np.flatnonzero((span > 0) & (np.abs(std ** 2 - bound) <= 1e-3 * span ** 2))]


class CNNMDNPolicy(PreTrainedPolicy):
    config_class = CNNMDNConfig
    name = "cnn_mdn"

    def __init__(self, config: CNNMDNConfig, dataset_stats: dict | None = None, **kwargs):
        super().__init__(config)
        config.validate_features()
        if config.binary_actions is None:
            if dataset_stats is None or ACTION not in dataset_stats:
                refuse("cnn_mdn finds its binary action entries in the dataset's statistics, and has none "
                                 "here: set them with --policy.binary_actions='[7]' (or '[]')")
            config.binary_actions = two_valued(dataset_stats[ACTION])
        if config.auxiliary_feature and dataset_stats is not None and config.auxiliary_feature not in dataset_stats:
            refuse(f"--policy.auxiliary_feature={config.auxiliary_feature} is not a feature of the "
                                 f"dataset (it has {', '.join(dataset_stats)})")
        self.model = CNNPolicy(config)
        if config.auxiliary_feature and dataset_stats is not None:  # the auxiliary target is not LeRobot-normalised
            stats = dataset_stats[config.auxiliary_feature]
            if np.asarray(stats["mean"]).size != 3:
                refuse(f"--policy.auxiliary_feature={config.auxiliary_feature} has "
                                 f"{np.asarray(stats['mean']).size} values; the auxiliary head regresses 3 (an "
                                 "offset such as gear_offset)")
            self.model.offset_mean.copy_(torch.as_tensor(np.asarray(stats["mean"]), dtype=torch.float32))
            self.model.offset_std.copy_(torch.as_tensor(np.asarray(stats["std"]), dtype=torch.float32).clamp_min(1e-5))

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self):
        """Nothing carries over between steps: one observation in, one action out."""

    def _image(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return to_model_image(batch[self.config.image_key], self.config.image_size,
                              tuple(self.config.window) if self.config.window else None)

    def _state(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        state = batch[OBS_STATE]
        return state[:, self.config.state_indices] if self.config.state_indices is not None else state

    def forward(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict]:
        image = random_shift(self._image(batch), self.config.shift, None)
        offset = None
        if self.config.auxiliary_feature:
            if self.config.auxiliary_feature not in batch:
                refuse(f"the batch has no {self.config.auxiliary_feature} (--policy.auxiliary_feature): "
                                 "only the preprocessor of make_cnn_mdn_pre_post_processors passes it through, not "
                                 "one loaded from a checkpoint (--resume); train afresh, or without it "
                                 "(--policy.auxiliary_feature=null)")
            offset = batch[self.config.auxiliary_feature].float()
        loss = self.model.loss(image, self._state(batch), batch[ACTION], offset)
        return loss, {"nll": loss.item()}

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, torch.Tensor], **kwargs) -> torch.Tensor:
        """(B, 1, action_dim): the most probable component's mean, each binary entry at -1 or +1 (normalised)."""
        return self.model.act(self._image(batch), self._state(batch))[:, None]

    @torch.no_grad()
    def select_action(self, batch: dict[str, torch.Tensor], **kwargs) -> torch.Tensor:
        return self.predict_action_chunk(batch)[:, 0]
