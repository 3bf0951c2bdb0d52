"""GearAssembly-v1 builds, renders its three cameras, is deterministic per seed, and rejects bad input."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch
from mani_skill.utils.structs.pose import Pose
from transforms3d.euler import euler2quat

from policy_composer.app.starts import start_state
from policy_composer.tasks.gear_assembly.expert import GearAssemblyExpert
from policy_composer.tasks.gear_assembly.kinematics import HandToPeg
from policy_composer.tasks.gear_assembly.spec import CAMERA_NAMES, CONTROL_FREQ, STATE_NAMES


@pytest.fixture(scope="module")
def rgb_env():
    env = gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=96, camera_height=64)
    yield env
    env.close()


def test_cameras_give_images_of_the_configured_shape_that_are_not_blank(rgb_env):
    obs, info = rgb_env.reset(seed=0)
    assert set(obs["sensor_data"]) == set(CAMERA_NAMES)
    for name in CAMERA_NAMES:
        rgb = obs["sensor_data"][name]["rgb"]
        assert rgb.shape == (1, 64, 96, 3) and rgb.dtype == torch.uint8
        assert rgb.float().std() > 10, f"{name} looks blank"
    u = rgb_env.unwrapped
    obs, *_ = rgb_env.step(u.flat_to_dict_action(u.hold_action()))
    assert obs["extra"]["state"].shape == (1, len(STATE_NAMES))
    # Gripper widths are part of the state: the left gripper starts open (two fingers at 0.04 m).
    assert obs["extra"]["state"][0, 7] == pytest.approx(0.08, abs=0.01)


def test_forearm_cameras_move_with_their_hands(rgb_env):
    u = rgb_env.unwrapped
    obs0, _ = rgb_env.reset(seed=0)
    action = u.hold_action().clone()
    action[0, 0] += 0.3  # swing the left arm's base joint
    for _ in range(10):
        obs, *_ = rgb_env.step(u.flat_to_dict_action(action))

    def changed(c):
        return (obs["sensor_data"][c]["rgb"].float() - obs0["sensor_data"][c]["rgb"].float()).abs().mean()

    assert changed("left_forearm") > 5 * changed("right_forearm")


def test_same_seed_same_state_different_seeds_differ(state_env):
    def initial(seed):
        state_env.reset(seed=seed)
        u = state_env.unwrapped
        return torch.cat([u.gear.pose.raw_pose, u.peg_module.pose.raw_pose, u.joint_state()], -1)

    a, b, c = initial(3), initial(3), initial(4)
    assert torch.equal(a, b)
    assert not torch.allclose(a, c)


def test_an_episode_does_not_depend_on_the_episodes_before_it(state_env):
    """The same seed and actions give the same states whatever ran before the reset (ManiSkill's determinism
    check, across episodes): nothing of the physics survives a reset."""
    def states(seed, steps=40):
        obs, _ = state_env.reset(seed=seed)
        u, expert = state_env.unwrapped, GearAssemblyExpert(state_env)
        expert.reset(seed)
        out = []
        for _ in range(steps):
            obs, *_ = state_env.step(u.flat_to_dict_action(expert.act(obs)))
            out.append(torch.cat([u.gear.pose.raw_pose, u.joint_state()], -1))
        return torch.cat(out)

    first = states(1)
    states(0, steps=150)  # an episode that ends elsewhere, with the gear in hand
    assert torch.equal(states(1), first)


def test_evaluate_reports_the_subtask_flags_and_stage(state_env):
    _, info = state_env.reset(seed=0)
    for key in ("success", "gear_grasped", "gear_lifted", "gear_at_peg", "gear_inserted", "stage"):
        assert key in info
    assert int(info["stage"][0]) == 0 and not bool(info["success"][0])
    assert state_env.unwrapped.control_freq == CONTROL_FREQ  # the fps a recording's writer is made with


@pytest.mark.parametrize("tilt_deg, inserted", [(0, True), (10, True), (40, False), (80, False)])
def test_a_gear_turned_on_its_edge_on_the_peg_is_not_inserted(state_env, tilt_deg, inserted):
    """Half-way down the peg, a gear counts as inserted only with its axis along the peg's: one caught on the peg
    turned on its edge has not gone down it (and a release guard must not let it go there)."""
    state_env.reset(seed=0)
    u = state_env.unwrapped
    in_peg = Pose.create_from_pq(p=[0.002, 0.0, u.gear_spec.peg_height / 2],
                                 q=euler2quat(np.deg2rad(tilt_deg), 0, 0))
    u.gear.set_pose(u.peg_module.pose * in_peg)
    info = u.evaluate()
    assert bool(info["gear_inserted"][0]) is inserted and int(info["stage"][0]) == (2 if inserted else 0)
    assert not bool(info["success"][0])


def test_the_pre_insertion_start_holds_the_gear_above_the_peg_off_centre(state_env):
    """reset(options={"start": "pre_insertion"}) gives the insertion's start state without the pick-up: the gear
    held (not resting on anything), its centre off the fingers' centre by the drawn grasp offset, the hand above the
    peg; the same seed gives the same state, and the expert inserts from there."""
    u = state_env.unwrapped
    offsets, at_peg = [], 0
    for seed in range(4, 8):
        _, info = state_env.reset(seed=seed, options={"start": "pre_insertion"})
        first = torch.cat([u.gear.pose.raw_pose, u.joint_state()], -1)
        assert bool(info["gear_grasped"][0]) and bool(info["gear_lifted"][0]) and int(u.elapsed_steps[0]) == 0
        at_peg += bool(info["gear_at_peg"][0])
        rel = (u.left_arm.tcp.pose.inv() * u.gear.pose).p[0]  # gear in the hand's frame (x along the fingers)
        assert abs(u.grasp_offset) <= 0.012 and abs(abs(float(rel[0])) - abs(u.grasp_offset)) < 0.003
        offsets.append(u.grasp_offset)
        state_env.reset(seed=seed, options={"start": "pre_insertion"})
        assert torch.equal(torch.cat([u.gear.pose.raw_pose, u.joint_state()], -1), first)
    assert at_peg >= 3 and np.ptp(offsets) > 0.01  # offsets differ per seed
    obs, _ = state_env.reset(seed=5, options={"start": "pre_insertion"})
    expert = GearAssemblyExpert(state_env)
    expert.reset(5)
    assert expert.phase == "insert"
    for _ in range(100):
        obs, _, _, _, info = state_env.step(u.flat_to_dict_action(expert.act(obs)))
        if expert.done:
            break
    assert bool(info["success"][0])
    with pytest.raises(ValueError, match="choose one of"):
        state_env.reset(seed=0, options={"start": "above_peg"})
    state_env.reset(seed=0)
    assert u.start == "table" and int(u.evaluate()["stage"][0]) == 0


def test_a_gear_centred_pre_insertion_start_unties_the_gears_offset_from_its_grasp(state_env):
    """With gear_arrival_max the gear, not the hand, is put over the peg (off by at most that), so where it sits in
    the fingers no longer says which way the peg is: at 0 every grasp offset leaves the gear on the peg's axis."""
    u = state_env.unwrapped

    def radial() -> float:  # the gear's distance from the peg's axis (m)
        return float(torch.linalg.norm((u.peg_module.pose.inv() * u.gear.pose).p[0, :2]))

    grasps, off_axis = [], []
    for seed in range(4, 8):
        state_env.reset(seed=seed, options={"start": "pre_insertion"})
        off_axis.append(radial())
        state_env.reset(seed=seed, options={"start": "pre_insertion", "gear_arrival_max": 0.0})
        grasps.append(u.grasp_offset)
        assert radial() < 0.0015
    assert np.ptp(grasps) > 0.01 and max(off_axis) > 0.004  # the grasps differ, and by default the gear is off


@pytest.mark.parametrize("kwargs, message", [
    (dict(cameras=("head", "wrist")), "valid cameras are"),
    (dict(camera_width=0), "positive integer"),
    (dict(camera_height=-5), "positive integer"),
    (dict(robot_uids=("xarm6", "xarm6")), "choose one of"),
    (dict(control_mode="pd_ee_pose"), "choose one of"),
    (dict(clearance=0.02), "radial clearance between"),
])
def test_bad_configuration_names_the_problem_and_the_choices(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("GearAssembly-v1", obs_mode="state_dict", **kwargs)


def test_the_package_import_registers_the_env_and_none_is_the_default_control_mode():
    """As with ManiSkill's own tasks: `import policy_composer.tasks` is enough for gym.make (the simulator loads only
    then), and control_mode=None, which ManiSkill's example scripts pass, means the task's default."""
    code = ("import sys, gymnasium as gym, policy_composer.tasks\n"
            "assert 'mani_skill' not in sys.modules\n"
            "env = gym.make('GearAssembly-v1', obs_mode='state_dict', control_mode=None)\n"
            "print(sorted(set(env.unwrapped.control_mode.values())), env._max_episode_steps)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[-2] == "['pd_joint_pos'] 400"  # and ManiSkill's time limit


def test_flat_action_of_the_wrong_size_is_refused(state_env):
    state_env.reset(seed=0)
    with pytest.raises(ValueError, match="expects 16"):
        state_env.unwrapped.flat_to_dict_action(np.zeros(7))


def test_the_right_forearm_camera_sees_the_gear_come_down_onto_the_peg(rgb_env):
    """Its goal score can only learn the insertion if the gear enters its view (the hand hid it at first)."""
    u = rgb_env.unwrapped
    obs, _ = rgb_env.reset(seed=0)
    expert = GearAssemblyExpert(rgb_env)
    expert.reset(0)
    first = obs["sensor_data"]["right_forearm"]["rgb"].float()
    for _ in range(400):
        if expert.phase == "insert":
            break
        obs, *_ = rgb_env.step(u.flat_to_dict_action(expert.act(obs)))
    assert expert.phase == "insert"
    above_peg = obs["sensor_data"]["right_forearm"]["rgb"].float()
    assert (above_peg - first).abs().mean() > 3.0  # 7.7 here; 0.05 with the first mount, which saw nothing


def test_the_expert_s_unrecorded_pick_up_renders_nothing_but_the_start_state(rgb_env, monkeypatch):
    """A controller's start state after the expert's pick-up (Table I's move column, the move's rollouts) is stepped
    without observations: one render, at the end; the physics is that of env.step's (the same state)."""
    u = rgb_env.unwrapped
    renders = []
    get_obs = u.get_obs
    monkeypatch.setattr(u, "get_obs", lambda *a, **k: renders.append(1) or get_obs(*a, **k))
    obs = start_state(rgb_env, 2, "move")
    assert len(renders) == 2  # the reset's and the start state's
    assert bool(u.evaluate()["gear_lifted"][0]) and obs["sensor_data"]["head"]["rgb"].shape[1:3] == (64, 96)
    unobserved = torch.cat([u.gear.pose.raw_pose, u.joint_state()], -1)
    steps = int(u.elapsed_steps[0])
    monkeypatch.setattr(u, "step_unobserved", lambda action: rgb_env.step(action))
    start_state(rgb_env, 2, "move")
    assert int(u.elapsed_steps[0]) == steps
    torch.testing.assert_close(torch.cat([u.gear.pose.raw_pose, u.joint_state()], -1), unobserved)


def test_the_robot_knows_its_hand_over_the_peg_from_its_joints(state_env):
    """What the predicate classifiers get besides the cameras: the left hand relative to the peg's top from both arms'
    joint angles (forward kinematics and the peg module's place in the right hand) is where the simulator has it, at
    the start, on the way down and off to the side."""
    u = state_env.unwrapped
    hand_to_peg = HandToPeg(u.gear_spec)
    for seed, start in ((0, None), (1, "pre_insertion")):
        obs, _ = state_env.reset(seed=seed, options={"start": start} if start else None)
        for _ in range(2):
            truth = (u.peg_top.inv() * u.left_arm.tcp.pose).p[0].numpy()
            np.testing.assert_allclose(hand_to_peg(obs["extra"]["state"].numpy())[0], truth, atol=1e-5)
            action = u.hold_action()[0].clone()
            action[:7] += torch.tensor([0.3, -0.2, 0.1, 0.2, 0.0, -0.2, 0.3])  # somewhere else
            for _ in range(20):
                obs, *_ = state_env.step(u.flat_to_dict_action(action))
