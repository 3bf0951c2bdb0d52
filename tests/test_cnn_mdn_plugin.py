"""The paper's visual policy as a LeRobot policy type (`cnn_mdn`, the `lerobot_policy_cnn_mdn` plugin): LeRobot finds
it by its distribution's name, `lerobot-train` fits it on a dataset the project did not record and on the project's,
`lerobot-eval` runs it on GearAssembly, and it is the project's own network."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import lerobot, lerobot_train, trained
from lerobot.configs import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot_policy_cnn_mdn import CNNMDNConfig
from lerobot_policy_cnn_mdn.modeling_cnn_mdn import CNNMDNPolicy

from policy_composer.policies.cnn.modeling_cnn import CNNPolicy


def test_lerobot_finds_the_policy_by_its_distributions_name():
    """Nothing imports the plugin but LeRobot's discovery of installed `lerobot_policy_*` distributions; then the
    type resolves to its policy class and processors by LeRobot's naming convention."""
    code = """
import json
from lerobot.configs.policies import PreTrainedConfig
before = "cnn_mdn" in PreTrainedConfig.get_known_choices()
from lerobot.utils.import_utils import register_third_party_plugins
register_third_party_plugins()
from lerobot.policies.factory import _make_processors_from_policy_config, get_policy_class
config = PreTrainedConfig.get_choice_class("cnn_mdn")()
pre, post = _make_processors_from_policy_config(config)
print(json.dumps([before, get_policy_class("cnn_mdn").__name__, pre.name, post.name]))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "HF_HUB_OFFLINE": "1"})
    assert res.returncode == 0, res.stderr[-2000:]
    found = json.loads(res.stdout.splitlines()[-1])
    assert found == [False, "CNNMDNPolicy", "policy_preprocessor", "policy_postprocessor"]


def foreign_dataset(root: Path) -> Path:
    """A LeRobot dataset the project did not record: one 48-px wrist camera stored as images, a 6-D state, and a
    6-D action whose last entry is a gripper commanded to 0 or 0.08."""
    names = [f"joint{i}" for i in range(5)] + ["gripper"]
    features = {"observation.images.wrist": {"dtype": "image", "shape": (48, 48, 3),
                                             "names": ["height", "width", "channels"]},
                "observation.state": {"dtype": "float32", "shape": (6,), "names": names},
                "action": {"dtype": "float32", "shape": (6,), "names": names}}
    ds = LeRobotDataset.create("local/foreign", fps=10, features=features, root=root / "foreign", use_videos=False)
    rng = np.random.default_rng(0)
    for _ in range(2):
        for t in range(8):
            action = rng.normal(size=6).astype(np.float32)
            action[5] = 0.08 if t < 4 else 0.0
            ds.add_frame({"observation.images.wrist": rng.integers(0, 256, (48, 48, 3), dtype=np.uint8),
                          "observation.state": rng.normal(size=6).astype(np.float32), "action": action,
                          "task": "pick the cube"})
        ds.save_episode()
    ds.finalize()
    return root / "foreign"


def test_lerobot_train_fits_it_on_a_dataset_the_project_did_not_record(tmp_path):
    lerobot_train(foreign_dataset(tmp_path), tmp_path, "cnn_mdn", ("--policy.hidden_dim=32", "--policy.num_mixtures=2"))
    checkpoint, res = trained(tmp_path)
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    config = json.loads((checkpoint / "config.json").read_text())
    # Its camera is the dataset's only one; the gripper is found two-valued in the dataset's statistics.
    assert config["camera"] == "wrist" and config["binary_actions"] == [5]

    policy = CNNMDNPolicy.from_pretrained(checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    batch = {"observation.images.wrist": torch.rand(3, 48, 48), "observation.state": torch.zeros(6), "task": ""}
    action = post(policy.select_action(pre(batch)))[0]
    assert action.shape == (6,) and torch.isfinite(action).all()
    assert min(abs(action[5].item() - 0.08), abs(action[5].item())) < 1e-5  # one of the gripper's two commands


def test_lerobot_train_fits_it_on_the_projects_dataset_with_the_projects_network(cnn_mdn_checkpoint):
    """Trained as the project trains its insertion; the weights are those of policies/cnn/modeling_cnn.py's network,
    and the camera it does not read is not among its inputs."""
    checkpoint, res = cnn_mdn_checkpoint
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    assert "step:2" in res.stdout + res.stderr
    policy = CNNMDNPolicy.from_pretrained(checkpoint)
    assert type(policy.model) is CNNPolicy and policy.config.binary_actions == [7]  # the left gripper
    assert set(policy.config.input_features) == {"observation.images.left_forearm", "observation.state"}
    offset_std = policy.model.offset_std
    assert (offset_std != 1).all()  # the auxiliary target's statistics, from the dataset's


def test_lerobot_eval_runs_it_on_gear_assembly(cnn_mdn_checkpoint, tmp_path):
    checkpoint, _ = cnn_mdn_checkpoint
    res = lerobot("lerobot-eval", f"--policy.path={checkpoint}", "--policy.device=cpu", "--env.type=gear_assembly",
                  "--env.task=insert", "--env.resolution=64", "--env.cameras=[left_forearm]",
                  "--env.episode_length=5", "--eval.n_episodes=1", "--eval.batch_size=1",
                  "--eval.use_async_envs=false", f"--output_dir={tmp_path}", "--seed=500")
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    info = json.loads((tmp_path / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and len(list(tmp_path.rglob("*.mp4"))) == 1


def test_a_dataset_without_a_camera_is_refused_with_the_reason():
    config = CNNMDNConfig(input_features={"observation.state": PolicyFeature(FeatureType.STATE, (6,))},
                          output_features={"action": PolicyFeature(FeatureType.ACTION, (6,))})
    with pytest.raises(ValueError, match="at least one camera .* and a state"):
        config.validate_features()
    with pytest.raises(ValueError, match="--policy.backbone='vit' is not one of"):
        CNNMDNConfig(backbone="vit")


def test_lerobot_train_names_a_bad_policy_setting_in_one_line(insertion_demos, tmp_path):
    res = lerobot("lerobot-train", f"--dataset.repo_id=local/{insertion_demos.name}",
                  f"--dataset.root={insertion_demos}", "--policy.type=cnn_mdn", "--policy.push_to_hub=false",
                  "--policy.device=cpu", "--policy.state_indices=[99]", "--steps=1", "--batch_size=2",
                  "--num_workers=0", f"--output_dir={tmp_path / 'run'}", "--wandb.enable=false", timeout=300)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stderr.strip().splitlines()[-1] == "error: --policy.state_indices=[99] must be entries of the state, " \
                                                   "0 to 15"
