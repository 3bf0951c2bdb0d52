"""The paper's CNN + mixture density policy as a LeRobot policy type: `lerobot-train --policy.type=cnn_mdn`.

LeRobot imports this package at start-up (it imports installed distributions named `lerobot_policy_*`), which
registers `CNNMDNConfig`; LeRobot finds `CNNMDNPolicy` and `make_cnn_mdn_pre_post_processors` in the sibling
`modeling_cnn_mdn` and `processor_cnn_mdn` modules by its naming convention.
"""

from lerobot_policy_cnn_mdn.configuration_cnn_mdn import CNNMDNConfig

__all__ = ["CNNMDNConfig"]
