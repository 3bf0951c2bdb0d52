"""The CNN policy trains and reloads, refuses mismatched checkpoints, and runs as a controller; a lerobot-train
checkpoint runs as a controller; the per-controller table command."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch
from conftest import run_cli
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
from transforms3d.quaternions import quat2mat

from policy_composer.app.record import record_recipe
from policy_composer.app.starts import start_state
from policy_composer.data.features import read_sidecar
from policy_composer.data.frames import load_frames, to_model_image
from policy_composer.data.recipes import RecipeError, load_recipe
from policy_composer.data.recorder import FrameBuffer
from policy_composer.data.verify import open_dataset
from policy_composer.learning.training import fit_epochs
from policy_composer.policies.arm import Outcome, run_activation
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.controller import MAX_LEAD, CNNController, hand_step
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.policies.cnn.train import (
    CheckpointError,
    action_target,
    load_cnn_library,
    load_cnn_policy,
    load_demonstrations,
    policy_state,
    previous_commands,
    train_cnn_policy,
)
from policy_composer.policies.lerobot_policy.controller import LeRobotPolicyController, lerobot_label
from policy_composer.policies.library import LibrarySources
from policy_composer.tasks.base import np0
from policy_composer.tasks.gear_assembly.expert import ExpertConfig, GearAssemblyExpert
from policy_composer.tasks.gear_assembly.kinematics import LeftArmIK
from policy_composer.tasks.gear_assembly.spec import EnvSettings
from policy_composer.tasks.gear_assembly.subtasks import SUBTASKS
from policy_composer.tasks.panda import PandaForwardKinematics

TINY = dict(image_size=32, hidden_dim=64, num_mixtures=4, batch_size=16, epochs=30)


@pytest.fixture(scope="module")
def rgb_env():
    env = gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=64, camera_height=64)
    yield env
    env.close()


def test_hand_frame_targets_map_back_to_the_recorded_joint_targets(state_env):
    """The "hand" action space loses nothing: a recorded (state, joint target) pair, turned into a displacement in
    the hand's frame and back through IK from the measured joints, gives the recorded joint target."""
    obs, _ = state_env.reset(seed=2)
    ik = LeftArmIK(state_env)
    state = obs["extra"]["state"][0].double()
    quat = np0(ik.arm.tcp.pose.q)
    move = np.array([0.004, -0.003, -0.005])  # world frame
    target, ok = ik.solve(sapien.Pose(np0(ik.arm.tcp.pose.p) + move, quat), np0(ik.arm.robot.get_qpos()))
    assert ok
    action = state.clone()
    action[:7] = torch.as_tensor(target[:7])
    # The controller's first step: the previous command is the measured state.
    in_hand = action_target(state[None].float(), action[None].float(), state[None].float(), "hand")[0, :3].numpy()
    np.testing.assert_allclose(np.linalg.norm(in_hand), np.linalg.norm(move), atol=2e-4)
    assert abs(in_hand[2] - np.dot(quat2mat(quat)[:, 2], move)) < 2e-4  # the hand's z axis points down
    command, q = hand_step(ik, np0(ik.arm.tcp.pose.p), in_hand, quat)
    np.testing.assert_allclose(command, np0(ik.arm.tcp.pose.p) + move, atol=2e-4)
    np.testing.assert_allclose(q, target[:7], atol=2e-3)


def test_targets_are_changes_of_the_command():
    state = torch.tensor([[0.0] * 16, [1.0] * 16, [2.0] * 16])
    action = torch.tensor([[0.5] * 16, [1.5] * 16, [9.0] * 16])
    prev = previous_commands(state, action, torch.tensor([0, 0, 1]))
    assert prev[:, 0].tolist() == [0.0, 0.5, 2.0]  # episode starts continue from the measured joints
    assert action_target(state, action, prev, "joint")[:, 0].tolist() == [0.5, 1.0, 7.0]


def test_cnn_loss_falls_and_checkpoint_reloads(insertion_demos, tmp_path):
    config = CNNPolicyConfig(**TINY)
    data = load_demonstrations(insertion_demos, config, progress=False)
    assert data["image"].shape[1:] == (3, 32, 32) and data["image"].dtype == torch.uint8
    # The insertion's defaults: the window on the gear and the peg, and the gear's offset as an auxiliary target.
    assert config.view == "insertion" and config.offset_weight == 1.0
    assert data["offset"].shape == (len(data["image"]), 3)
    model, losses = train_cnn_policy(insertion_demos, config, out=tmp_path / "cnn", data=data, progress=False)
    assert losses[-1] < losses[0] - 1.0, losses
    again = load_cnn_policy(tmp_path / "cnn", camera="left_forearm", state_dim=1)
    torch.testing.assert_close(again.offset_mean, data["offset"].mean(0))
    image, state = data["image"][:5].float() / 255, data["state"][:5]
    torch.testing.assert_close(again.act(image, state), model.act(image, state))
    with pytest.raises(CheckpointError, match="trained on camera 'left_forearm', but this controller reads 'head'"):
        load_cnn_policy(tmp_path / "cnn", camera="head")
    with pytest.raises(CheckpointError, match="state of size 1, this controller gives 16"):
        load_cnn_policy(tmp_path / "cnn", state_dim=16)
    with pytest.raises(CheckpointError, match="no CNN policy checkpoint"):
        load_cnn_policy(tmp_path)
    config_file = tmp_path / "cnn" / "config.json"
    config_file.write_text(config_file.read_text().replace('"action_space"', '"action_dim": 8, "action_space"'))
    with pytest.raises(CheckpointError, match="another configuration of the CNN policy"):
        load_cnn_policy(tmp_path / "cnn")


def test_training_flushes_denormal_numbers_to_zero_and_then_stops():
    """A fitted model's gradients fall below float32's normal range, which the CPU computes with slowly (a converged
    CNN policy's backward pass took 13x as long): the training loop flushes them to zero. The simulator computes under
    the same flag, so the loop leaves it as it found it."""
    denormal = torch.tensor([1e-39])
    assert (denormal * 2).item() != 0
    model = torch.nn.Linear(2, 1)
    opt = torch.optim.SGD(model.parameters(), lr=0.1)
    x, seen = torch.randn(8, 2), []

    def loss(idx):
        seen.append((denormal * 2).item())
        return model(x[idx]).pow(2).mean()

    fit_epochs(model, opt, 8, 4, 1, loss, torch.Generator(), "fit", progress=False)
    assert seen == [0.0, 0.0]
    assert (denormal * 2).item() != 0


def test_a_bfloat16_training_runs_only_the_convolutions_in_bfloat16_and_acts_in_float32():
    """`precision = bfloat16` runs the encoder's convolutions in bfloat16 while the policy trains (on a CPU with AMX,
    about twice as fast); the keypoints, the heads, the weights and their gradients stay float32, and the trained
    policy acts in float32, exactly as the same weights configured for float32."""
    torch.manual_seed(0)
    model = CNNPolicy(CNNPolicyConfig(**TINY, precision="bfloat16"))
    reference = CNNPolicy(CNNPolicyConfig(**TINY))
    reference.load_state_dict(model.state_dict())
    images, state = torch.rand(6, 3, 32, 32), torch.rand(6, 1)
    action, offset = torch.cat([torch.randn(6, 3), torch.ones(6, 1)], dim=-1), torch.randn(6, 3)
    dtypes = []
    for layer in model.encoder:
        layer.register_forward_hook(lambda layer, inputs, out: dtypes.append((type(layer).__name__, out.dtype)))
    model.train()
    model.loss(images, state, action, offset).backward()
    convolutions = [d for name, d in dtypes if name == "Conv2d"]
    assert convolutions and set(convolutions) == {torch.bfloat16}, dtypes
    assert dict(dtypes)["SpatialSoftmax"] == torch.float32
    assert {p.grad.dtype for p in model.parameters()} == {torch.float32}
    reference.train()
    assert torch.allclose(model(images, state)[0][1], reference(images, state)[0][1], atol=0.05)  # only rounded
    model.eval()
    reference.eval()
    assert torch.equal(model.act(images, state), reference.act(images, state))


def test_pick_and_move_policies_learn_their_stages_of_the_transport_demos(transport_demos, tmp_path):
    """A transport demonstration ends at the pre-insertion pose (nothing after it is simulated); the pick-up policy
    learns its frames before the lift, the move policy the carry; the library's CNN model is a folder of them."""
    sidecar = read_sidecar(transport_demos)
    assert all(e["success"] for e in sidecar["episodes"]), sidecar["episodes"]
    frames = load_frames(transport_demos, ("left_forearm",), 32, progress=False)
    last = torch.cat([frames["episode_index"][1:] != frames["episode_index"][:-1], torch.tensor([True])])
    assert frames["stage"][last].tolist() == [2, 2]  # every episode ends at the pre-insertion pose, not further
    counts = torch.bincount(frames["stage"], minlength=4).tolist()
    assert counts[0] > 20 and counts[1] > 20 and counts[3] == 0, counts
    sizes = {}
    for subtask in ("pick", "move"):
        config = CNNPolicyConfig(**{**TINY, "subtask": subtask, "epochs": 2})
        sizes[subtask] = len(load_demonstrations(transport_demos, config, progress=False)["image"])
        train_cnn_policy(transport_demos, config, out=tmp_path / "cnn" / subtask, progress=False)
    assert sizes == {"pick": counts[0], "move": counts[1] + counts[2]}
    library = load_cnn_library(tmp_path / "cnn")
    assert sorted(library) == ["move", "pick"] and library["pick"].config.subtask == "pick"
    assert list(load_cnn_library(tmp_path / "cnn" / "move")) == ["move"]
    with pytest.raises(RecipeError, match="holds gear-transport-demos episodes, but training the CNN insert policy "
                                          "needs gear-insertion-demos"):
        load_demonstrations(transport_demos, CNNPolicyConfig(**TINY), progress=False)
    with pytest.raises(CheckpointError, match="train them with `policy-composer train policy --subtask SUBTASK`"):
        load_cnn_library(tmp_path)


def test_a_dagger_round_records_the_experts_labels_along_the_policys_own_path(insertion_demos, tmp_path,
                                                                              monkeypatch):
    """DAgger: the CNN policy drives the arm, the scripted expert labels each frame, the LeRobot dataset holds the
    labels (failures included), and the policy trains on it beside its demonstrations."""
    config = CNNPolicyConfig(**{**TINY, "max_steps": 12})
    train_cnn_policy(insertion_demos, config, out=tmp_path / "cnn" / "insert", progress=False)
    labels, sent, stepped = [], [], []
    expert_act, policy_act, step = GearAssemblyExpert.act, CNNController.act, FrameBuffer.step
    monkeypatch.setattr(GearAssemblyExpert, "act",
                        lambda self, obs=None: labels.append(expert_act(self, obs)) or labels[-1])
    monkeypatch.setattr(CNNController, "act", lambda self, obs: sent.append(policy_act(self, obs)) or sent[-1])

    def logged(self, action, label=None):
        # Each step sends the policy's latest command and records the expert's latest label.
        stepped.append((action is sent[-1] and label is labels[-1], action.numpy(), label.numpy()))
        return step(self, action, label)

    monkeypatch.setattr(FrameBuffer, "step", logged)
    sources = LibrarySources(models={"cnn": str(tmp_path / "cnn")})
    root = tmp_path / "dagger"
    sidecar = record_recipe(load_recipe("gear-insertion-dagger"), root, episodes=2, seed=3,
                            settings=EnvSettings(resolution=32), sources=sources, progress=False)
    assert len(sidecar["episodes"]) == 2 and sidecar["controllers"] == ["cnn_insert"]
    assert all(e["outcome"] in ("done", "failed") for e in sidecar["episodes"])  # kept whatever the outcome
    ds = open_dataset(root)
    assert [e["length"] for e in sidecar["episodes"]] == np.bincount(ds.hf_dataset["episode_index"]).tolist()
    matched, executed, recorded = zip(*stepped)
    assert all(matched) and len(stepped) == len(ds)
    np.testing.assert_array_equal(np.stack(ds.hf_dataset["action"]), np.stack(recorded))
    assert np.abs(np.stack(executed)[:, :7] - np.stack(recorded)[:, :7]).max() > 1e-3  # the arm followed the policy
    data = load_demonstrations([insertion_demos, root], config, progress=False)
    assert len(data["image"]) == len(load_demonstrations(insertion_demos, config, progress=False)["image"]) + len(ds)
    # A policy that reaches the goal, as the expert judges it, before it terminates is an episode done, a success.
    monkeypatch.setattr(GearAssemblyExpert, "done", property(lambda self: len(labels) % 3 == 0))
    labels.clear()
    done = record_recipe(load_recipe("gear-insertion-dagger"), tmp_path / "done", episodes=1, seed=3,
                         settings=EnvSettings(resolution=32), sources=sources, progress=False)["episodes"]
    assert [(e["outcome"], e["success"], e["length"]) for e in done] == [("done", True, 3)]


def test_a_move_dagger_round_starts_after_the_pick_and_labels_steps_from_the_hand(transport_demos, tmp_path):
    """The move's corrections: the expert picks the gear up unrecorded, the policy carries it, and each label is the
    expert's step from where the policy left the hand, so a policy that strays for long gets no wound-up labels."""
    config = CNNPolicyConfig(**{**TINY, "subtask": "move", "max_steps": 25})
    train_cnn_policy(transport_demos, config, out=tmp_path / "cnn" / "move", progress=False)
    root = tmp_path / "dagger"
    sources = LibrarySources(models={"cnn": str(tmp_path / "cnn")})
    sidecar = record_recipe(load_recipe("gear-move-dagger"), root, episodes=2, seed=3,
                            settings=EnvSettings(resolution=32), sources=sources, progress=False)
    assert sidecar["controllers"] == ["cnn_move"] and sidecar["expert"]["labels"] == "arm"
    frames = open_dataset(root).hf_dataset
    first = np.flatnonzero(np.diff(np.asarray(frames["episode_index"]), prepend=-1))
    assert len(first) == 2 and all(frames[int(i)]["stage"] == 1 for i in first)  # lifted: the pick is not recorded
    fk = PandaForwardKinematics()
    hand, _ = fk.tcp(np.stack(frames["observation.state"])[:, :7].astype(np.float64))
    label, _ = fk.tcp(np.stack(frames["action"])[:, :7].astype(np.float64))
    steps = np.linalg.norm(label - hand, axis=1)
    assert steps.max() <= ExpertConfig().max_step + 1e-3 and steps.min() > 0  # a step from the hand, never wound up
    moving = np.isin(np.asarray(frames["stage"]).ravel(), (1, 2))  # the move's frames (a dropped gear's are not)
    data = load_demonstrations([transport_demos, root], config, progress=False)
    demos = load_demonstrations(transport_demos, config, progress=False)
    assert len(data["action"]) == len(demos["action"]) + moving.sum()
    np.testing.assert_allclose(np.linalg.norm(data["action"][len(demos["action"]):, :3], axis=1), steps[moving],
                               atol=1e-5)


def test_a_policy_pushing_against_the_table_keeps_its_command_near_the_hand(rgb_env):
    """A pick-up trained on 20 demonstrations pressed down beside the gear and wound its command up, 5 mm a step,
    until joint 2 passed its limit (a safety stop): the command now stays within MAX_LEAD of the measured TCP, so
    the same policy runs out of steps instead, within the joints' limits."""
    class PressesDown:  # the policy's interface: config and act(image, state) -> (1, 4)
        config = CNNPolicyConfig(subtask="pick", image_size=32, max_steps=100)  # its controller's step limit

        def act(self, image, state):
            return torch.tensor([[0.0, 0.0, 0.01, 1.0]])  # 10 mm a step along the hand's z axis (down), open

    obs = start_state(rgb_env, 3, "pick")
    controller = CNNController(rgb_env, PressesDown(), SUBTASKS["pick"])
    run_activation(rgb_env, controller, obs, seed=3)
    assert controller.outcome is Outcome.FAILED and controller._steps == 100, controller.reason
    assert np.linalg.norm(controller._command - np0(controller.ik.arm.tcp.pose.p)) <= MAX_LEAD + 1e-9
    assert controller.scene.tcp()[2] < 0.03  # it did press down to the table


def follow_demonstration(env, model, seed: int) -> dict[str, np.ndarray]:
    """The expert replays a recorded insertion demonstration in a live env; at each recorded step, the policy's
    prediction from the live camera image and state, beside the target the training code makes of the expert's
    command there (the change from its previous command, in the hand's frame, and the gripper), and the gear's
    offset from the peg."""
    u = env.unwrapped
    recipe = load_recipe("gear-insertion-demos")
    obs, _ = env.reset(seed=seed, options=recipe.reset_options())  # the demonstration's first recorded frame
    expert = GearAssemblyExpert(env, recipe.expert.config())  # the recipe's demonstrator, DART included
    expert.reset(seed)
    config, rows = model.config, {"predicted": [], "target": [], "gear_offset": []}
    prev = obs["extra"]["state"][:1].float()  # an episode's first previous command: the measured joints
    while not expert.done and expert.phase in ("insert", "release", "retreat"):
        action = expert.act(obs)
        state = obs["extra"]["state"][:1].float()
        image = to_model_image(obs["sensor_data"][config.camera]["rgb"][:1].cpu(), config.image_size, config.window)
        rows["gear_offset"].append(u.gear_offset_in_hand()[0].numpy())
        rows["predicted"].append(model.act(image, policy_state(state, config))[0].numpy())
        rows["target"].append(action_target(state, action[None].float(), prev, config.action_space)[0].numpy())
        prev = action[None].float()
        obs, *_ = env.step(u.flat_to_dict_action(expert.executed))  # what the arm was sent
    return {k: np.stack(v) for k, v in rows.items()}


def test_cnn_follows_a_demonstration_it_was_trained_on(insertion_demos, rgb_env):
    """Data, action targets, training and camera agree end to end: a policy fitted closely to two demonstrations,
    shown the live env's images along the first one (replayed by its demonstrator), predicts the demonstration's
    commands: its error is a small part of the motion, and the gripper command matches. A frame/action mix-up,
    a wrong frame for the hand displacements, or images that differ between recording and control break it.
    (With the hand-frame targets mapping back to joint targets, above, this covers the controller's chain; a
    closed-loop run from the same start would also turn on the last bits of floating point.)"""
    config = CNNPolicyConfig(image_size=32, hidden_dim=128, num_mixtures=2, batch_size=16, epochs=250, shift=0,
                             proprioception="arm")
    model, _ = train_cnn_policy(insertion_demos, config, progress=False)
    rows = follow_demonstration(rgb_env, model, read_sidecar(insertion_demos)["episodes"][0]["seed"])
    predicted, target = rows["predicted"], rows["target"]
    # Medians: where the demonstrator pauses or opens the gripper, a step's timing may differ in the replay.
    error = np.median(np.linalg.norm(predicted[:, :3] - target[:, :3], axis=1))
    motion = np.median(np.linalg.norm(target[:, :3], axis=1))
    gripper = (np.sign(predicted[:, 3]) == np.sign(target[:, 3])).mean()
    # Measured here: 0.37 mm against 4.6 mm, the gripper 35 of 36 steps.
    assert error < 0.3 * motion and gripper >= 0.9, (error, motion, gripper)
    # The recording's privileged label is the live env's, frame by frame.
    recorded = load_frames(insertion_demos, ("left_forearm",), 16, episodes=[0], progress=False)["gear_offset"]
    np.testing.assert_allclose(recorded.numpy(), rows["gear_offset"], atol=1e-5)


def test_cnn_controller_acts_from_pixels_within_limits(insertion_demos, rgb_env, tmp_path):
    config = CNNPolicyConfig(**{**TINY, "epochs": 2})
    model, _ = train_cnn_policy(insertion_demos, config, out=tmp_path / "cnn", progress=False)
    controller = CNNController(rgb_env, model, max_steps=5)
    obs = start_state(rgb_env, 3, "insert")
    assert controller.can_start(obs)
    hold = rgb_env.unwrapped.hold_action()
    controller.start(obs)
    for _ in range(40):  # 5 policy steps, and a back-off if the untrained policy opens the gripper above the peg
        if controller.done(obs):
            break
        action = controller.act(obs)
        assert torch.isfinite(action).all()
        torch.testing.assert_close(action[8:], hold[0, 8:].cpu())  # the right arm holds
        obs, *_ = rgb_env.step(rgb_env.unwrapped.flat_to_dict_action(action))
    assert controller.done(obs) and controller.outcome.value in ("failed", "stopped for safety", "done")
    assert controller.reason.startswith("backed off") or controller._steps == 5, controller.reason
    no_camera = gym.make("GearAssembly-v1", obs_mode="rgb", cameras=("head",), camera_width=32, camera_height=32)
    with pytest.raises(ValueError, match="reads camera 'left_forearm', which this env does not render"):
        CNNController(no_camera, model)
    no_camera.close()


@pytest.mark.parametrize("policy", ["act", "diffusion", "cnn_mdn"])
def test_lerobot_policy_runs_as_a_controller(policy, rgb_env, request):
    """ACT, Diffusion Policy and the paper's policy through its LeRobot plugin run as controllers: Diffusion
    Policy's observation queue (two steps in) and action chunks (8 out) carry over from step to step, and start
    afresh at the next activation."""
    checkpoint, res = request.getfixturevalue(f"{policy}_checkpoint")
    assert res.returncode == 0, (res.stdout + res.stderr)[-2000:]
    controller = LeRobotPolicyController(rgb_env, checkpoint, max_steps=3)
    assert controller.name == f"{policy}_insert" and "sensor_data.left_forearm.rgb" in controller.obs_keys
    # cnn_mdn reads the one camera it was trained on; the others read every camera of the dataset
    assert ("sensor_data.head.rgb" in controller.obs_keys) == (policy != "cnn_mdn")
    assert lerobot_label(checkpoint) == {"act": "ACT (LeRobot)", "diffusion": "Diffusion Policy (LeRobot)",
                                         "cnn_mdn": "CNN + MDN (LeRobot)"}[policy]
    obs = start_state(rgb_env, 3, "insert")
    controller.start(obs)
    action = controller.act(obs)
    assert action.shape == (16,) and torch.isfinite(action).all()
    if policy == "diffusion":
        queued = len(controller.policy._queues["action"])
        assert queued == 7  # a chunk of 8 planned, one taken
        controller.act(obs)
        assert len(controller.policy._queues["action"]) == queued - 1
        controller.start(obs)
        assert len(controller.policy._queues["action"]) == 0
    with pytest.raises(FileNotFoundError, match="not a LeRobot policy checkpoint"):
        LeRobotPolicyController(rgb_env, checkpoint.parent)


@pytest.mark.parametrize("policy", ["act", "diffusion", "cnn_mdn"])
def test_a_lerobot_controller_commands_what_the_policy_selects(policy, rgb_env, request):
    """The controller's command is LeRobot's own pipeline on the same observation, loaded afresh: the checkpoint's
    preprocessor, `select_action`, its postprocessor, and the left arm's entries of the 16-D action (0-6, gripper 7).
    A dropped postprocessor or another slice of the action would differ: the test checks that they do."""
    checkpoint, _ = request.getfixturevalue(f"{policy}_checkpoint")
    controller = LeRobotPolicyController(rgb_env, checkpoint, max_steps=3)
    obs = start_state(rgb_env, 3, "insert")
    controller.start(obs)
    torch.manual_seed(0)
    joints, gripper = controller.predict(obs)

    config = PreTrainedConfig.from_pretrained(checkpoint)
    config.device = "cpu"
    reference = get_policy_class(config.type).from_pretrained(checkpoint, config=config).eval()
    pre, post = make_pre_post_processors(config, pretrained_path=str(checkpoint),
                                         preprocessor_overrides={"device_processor": {"device": "cpu"}})
    batch = {"observation.state": obs["extra"]["state"][:1].float(), "task": [controller.task]}
    for key in config.image_features:  # the env renders at the size the policy was trained on: no resizing
        camera = key.removeprefix("observation.images.")
        batch[key] = obs["sensor_data"][camera]["rgb"][:1].permute(0, 3, 1, 2).float() / 255.0
    torch.manual_seed(0)
    with torch.no_grad():
        raw = reference.select_action(pre(batch))
    action = post(raw)[0].double().numpy()
    np.testing.assert_allclose(joints, action[:7], rtol=1e-5, atol=1e-6)
    assert gripper == pytest.approx(float(np.clip(action[7], -1.0, 1.0)), abs=1e-6)
    assert not np.allclose(action[:7], raw[0, :7].double().numpy(), atol=1e-3), "the postprocessor changes nothing"
    assert not np.allclose(action[:7], action[8:15], atol=1e-3), "the arms' entries cannot be told apart"


def test_the_controller_table_runs_only_the_columns_asked_for(insertion_demos, tmp_path):
    """Every column of every kind runs in the main job's test; here one column asked for is one column run, and only
    its controllers are built: a CNN model with an insertion policy alone serves the insert column."""
    train_cnn_policy(insertion_demos, CNNPolicyConfig(**{**TINY, "epochs": 1, "max_steps": 5}),
                     out=tmp_path / "cnn" / "insert", progress=False)
    result = run_cli("evaluate", "controllers", "--kinds", "MP,CNN", "--trials", "1", "--seed", "1", "--subtasks",
                     "insert", "--cnn", str(tmp_path / "cnn"), "--resolution", "32", "--senses", "oracle",
                     "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr[-2000:]
    one = "1/1 (95% CI 21-100%)"  # a single trial says little, and the interval says so
    assert f"MP: pick -, move -, insert {one}, full -" in result.stdout
    assert "CNN: pick -, move -, insert " in result.stdout
    assert f"| MP | -; paper 10/10 | -; paper 10/10 | {one}; paper 1/10 | -; paper 1/10 |" in \
        (tmp_path / "controllers.md").read_text()
