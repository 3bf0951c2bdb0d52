"""The `cnn_mdn` policy's processors: LeRobot's default ones (normalise the state, the action to [-1, 1], batch,
device; unnormalise the action), with the auxiliary feature passed through to training."""

from __future__ import annotations

from collections.abc import Callable

import torch
from lerobot.lerobot_types import TransitionKey
from lerobot.processor import make_default_pre_post_processors
from lerobot.processor.converters import batch_to_transition

from lerobot_policy_cnn_mdn.configuration_cnn_mdn import CNNMDNConfig


def keeping(feature: str) -> Callable:
    """LeRobot's batch_to_transition, keeping `feature` too: it keeps only observations, the action and a fixed set
    of metadata, and the auxiliary target (a dataset label such as `gear_offset`) is none of them."""

    def to_transition(batch: dict) -> dict:
        transition = batch_to_transition(batch)
        if feature in batch:
            extra = transition.get(TransitionKey.COMPLEMENTARY_DATA) or {}
            transition[TransitionKey.COMPLEMENTARY_DATA] = {**extra, feature: batch[feature]}
        return transition

    return to_transition


def make_cnn_mdn_pre_post_processors(config: CNNMDNConfig,
                                     dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None):
    preprocessor, postprocessor = make_default_pre_post_processors(config, dataset_stats,
                                                                   normalizer_device=config.device)
    if config.auxiliary_feature:
        preprocessor.to_transition = keeping(config.auxiliary_feature)
    return preprocessor, postprocessor
