"""ManiSkill's PegInsertionSide-v1 through the task adapter: its flags against ManiSkill's own evaluate(), and the
strict success refusing a peg pushed past the box (ManiSkill issue 1391)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import sapien
import torch
from conftest import run_cli
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.act.configuration_act import ACTConfig
from mani_skill.utils.structs.pose import Pose

from policy_composer.app.demo import Makings
from policy_composer.app.profiles import PROFILES
from policy_composer.data.features import read_info, read_sidecar
from policy_composer.learning.checkpoint import CheckpointError
from policy_composer.policies import subtasks
from policy_composer.policies.arm import Outcome, run_activation
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.train import policy_state
from policy_composer.policies.lerobot_policy.controller import LeRobotPolicyController
from policy_composer.policies.library import LibrarySources, build_library
from policy_composer.tasks.base import Percept, PlanningError
from policy_composer.tasks.peg_insertion_side import subtasks as subtasks_of_peg
from policy_composer.tasks.peg_insertion_side.env import CAMERA_NAMES, PREDICATES, make_env, predicates, strict_success
from policy_composer.tasks.peg_insertion_side.kinematics import HAND_IN_HOLE, hand_in_hole, rule_out
from policy_composer.tasks.peg_insertion_side.scene import EMPTY_HAND_GAP, PegScene, grasp_offset, pose0
from policy_composer.tasks.peg_insertion_side.spec import SCENE_NAMES, STATE_NAMES
from policy_composer.tasks.peg_insertion_side.subtasks import INSERT_STEP, SEATED, SUBTASKS
from policy_composer.tasks.peg_insertion_side.task import labels
from policy_composer.tasks.registry import get_task


@pytest.fixture(scope="module")
def env():
    env = make_env(obs_mode="state_dict")
    yield env
    env.close()


def _peg_head_at(env, depth: float):
    """Put the peg on the hole's axis with its head `depth` metres into the hole from its centre plane."""
    u = env.unwrapped
    along = Pose.create_from_pq(p=torch.tensor([[depth, 0.0, 0.0]]))
    u.peg.set_pose(u.box_hole_pose * along * u.peg_head_offsets.inv())


def test_the_adapters_flags_are_maniskills_and_the_strict_success_refuses_an_overshoot(env):
    env.reset(seed=3)
    flags = predicates(env)
    assert set(flags) == set(PREDICATES)
    assert not any(bool(f[0]) for f in flags.values())  # the peg on the table, the hand open
    half_depth = float(env.unwrapped.peg_half_sizes[0, 0])
    for depth, inserted, seated in ((-half_depth - 0.02, False, False),  # in front of the box's near face
                                    (0.0, True, True),  # the head at the hole's centre plane: the goal pose
                                    (half_depth - 0.005, True, True),  # just inside the far face
                                    (half_depth + 0.03, True, False)):  # pushed through, past the far face
        _peg_head_at(env, depth)
        maniskill = bool(env.unwrapped.evaluate()["success"][0])
        flags = predicates(env)
        assert maniskill == inserted and bool(flags["peg_inserted"][0]) == maniskill, depth
        assert bool(strict_success(env)[0]) == seated == bool(flags["peg_seated"][0]), depth
        assert not flags["peg_grasped"][0] and not flags["peg_at_hole"][0]  # nothing holds it


def test_at_the_hole_is_a_held_peg_on_the_holes_axis_in_front_of_the_box_or_part_way_in(env, monkeypatch):
    env.reset(seed=3)
    monkeypatch.setattr(env.unwrapped.agent, "is_grasping", lambda actor: torch.tensor([True]))  # a held peg
    half_depth = float(env.unwrapped.peg_half_sizes[0, 0])
    for depth, at_hole in ((-half_depth - 0.02, True), (-half_depth - 0.08, False), (-half_depth + 0.01, True),
                           (0.0, False)):  # in front, too far, part-way in short of ManiSkill's bound, inserted
        _peg_head_at(env, depth)
        assert bool(predicates(env)["peg_at_hole"][0]) == at_hole, depth


def test_it_is_maniskills_env_with_the_wrist_camera():
    env = make_env(obs_mode="rgb")
    try:
        obs, _ = env.reset(seed=0)
        assert env.unwrapped.robot_uids == "panda_wristcam"
        assert set(obs["sensor_data"]) == set(CAMERA_NAMES)
        assert all(obs["sensor_data"][c]["rgb"].float().std() > 0 for c in CAMERA_NAMES)  # rendered, not blank
    finally:
        env.close()


@pytest.fixture(scope="module")
def peg_library():
    env = make_env(obs_mode="state_dict", max_episode_steps=1000)
    sources = LibrarySources(task="peg-insertion-side", max_grasp_offset=0.0)
    yield env, build_library(env, ["mp_pick", "mp_move", "mp_insert"], sources)
    env.close()


@pytest.mark.parametrize("seed", [0, 2])
def test_the_librarys_controller_kinds_run_the_peg_task_from_its_description(peg_library, seed):
    """The gear's motion-planning kind on a task it was not written for, through the same code: the library builds
    PegInsertionSide-v1's controllers from the task's description, each starts only inside its initiation set,
    the planned pick-up and carry reach their terminations, and the open-loop insertion's verdict (sensed, from the
    oracle here) is the strict success's."""
    env, library = peg_library
    obs, _ = env.reset(seed=seed)
    assert not library["mp_move"].can_start(obs) and not library["mp_insert"].can_start(obs)
    for name in ("mp_pick", "mp_move"):
        obs = run_activation(env, library[name], obs, seed)
        assert library[name].outcome is Outcome.DONE, (name, library[name].reason)
    assert not library["mp_pick"].can_start(obs) and library["mp_insert"].can_start(obs)
    run_activation(env, library["mp_insert"], obs, seed)
    assert (library["mp_insert"].outcome is Outcome.DONE) == bool(strict_success(env)[0])


def test_the_planned_insertion_lines_the_peg_up_from_its_grasp_and_trims_the_arms_sag(peg_library, monkeypatch):
    """From the pre-insertion start, where the carry left the peg's head more than the 3 mm clearance off the hole's
    axis, the planned insertion lines the peg up as its grasp model says, measures from the arm's joints how far the
    held peg's weight sags the hand below its target, corrects it, and seats the peg, stopping a margin after it senses
    it seated (its plan aims 20 mm past the hole's centre plane, deeper than any demonstration held it); a correction it
    finds no plan for fails the activation with the reason instead of raising."""
    env, library = peg_library
    insert = library["mp_insert"]
    obs, _ = env.reset(seed=3000, options={"start": "pre_insertion"})
    head = labels(env)[1]
    assert max(abs(head[1]), abs(head[2])) > 0.003  # off the axis by more than the clearance
    run_activation(env, insert, obs, 3000)
    assert insert.outcome is Outcome.DONE and bool(strict_success(env)[0]), insert.reason
    # Sensed seated at ManiSkill's bound (15 mm short of the centre plane), it confirmed it and pushed its margin on
    # (3 + 3 steps of 3 mm): about the centre plane, short of where its plan aims.
    assert -INSERT_STEP / 2 < labels(env)[1][0] < SEATED
    assert 0.0005 < np.linalg.norm(insert.trimmed) < 0.005 and "trimmed the hand's steady error" in insert.reason

    def no_plan(*args, **kwargs):
        raise PlanningError("no IK solution for the TCP")

    obs, _ = env.reset(seed=3000, options={"start": "pre_insertion"})
    monkeypatch.setattr(subtasks, "line_to", no_plan)  # the trim's re-plan
    run_activation(env, insert, obs, 3000)
    assert insert.outcome is Outcome.FAILED and "no way on from where the hand was" in insert.reason


def _peg_in_hand(env) -> np.ndarray:
    """Where the peg sits in the hand: its position in the TCP's frame (m)."""
    u = env.unwrapped
    return (u.agent.tcp.pose.inv() * u.peg.pose).p[0].cpu().numpy()


def test_an_insertion_held_back_by_the_boxs_face_stops_before_the_peg_slides_in_the_fingers(peg_library,
                                                                                             monkeypatch):
    """A push aimed 12 mm above the hole meets the box's face: the insertion stops, held back (from its commands and
    the measured joints), with the peg where the grasp put it; pushed on, the same miss slides the peg along the
    fingers, and no controller that assumes the grasp could seat it after that."""
    env, library = peg_library
    insert = library["mp_insert"]
    monkeypatch.setattr(subtasks_of_peg, "DROOP", 0.012)  # the plan lifts the peg 12 mm, not 1.5
    slid = {}
    for guarded in (True, False):
        monkeypatch.setattr(insert.subtask, "stops_when_held_back", guarded)
        obs, _ = env.reset(seed=3000, options={"start": "pre_insertion"})
        before = _peg_in_hand(env)
        run_activation(env, insert, obs, 3000)
        assert insert.outcome is Outcome.FAILED and not strict_success(env)[0]
        assert ("held back" in insert.reason) == guarded, insert.reason
        slid[guarded] = float(np.linalg.norm(_peg_in_hand(env) - before))
    assert slid[True] < 0.002 < 0.01 < slid[False], slid


def test_every_way_through_the_insertion_has_the_movements_its_dmp_has(peg_library):
    """The insertion's DMP has one primitive per movement of the planned insertion, so a peg at the hole and one pushed
    through (back along the axis) are both reached in the same number of movements: a DMP refuses any other."""
    env, library = peg_library
    insert, probe = library["mp_insert"], library["mp_insert"].subtask
    obs, _ = env.reset(seed=3000, options={"start": "pre_insertion"})
    q = insert.q9(obs)
    at_hole = {"peg_grasped": 1.0, "peg_at_hole": 1.0, "peg_inserted": 0.0, "peg_seated": 0.0}
    through = {**at_hole, "peg_at_hole": 0.0, "peg_inserted": 1.0}
    ways = [probe.waypoints(insert.ik, insert.scene, q, 0.0, Percept(p, "oracle")) for p in (at_hole, through)]
    assert [len(w) for w in ways] == [2, 2] and all(w.kind == "line" for way in ways for w in way)
    assert probe.can_start(Percept(through, "oracle"))


@pytest.mark.parametrize("grasped", [0.0, 1.0])
@pytest.mark.parametrize("at_hole", [0.0, 1.0])
def test_a_peg_sensed_in_the_hole_is_in_no_initiation_set(grasped, at_hole):
    """A composed episode ends when no controller can start: with the peg sensed seated, none may, whatever the
    classifiers say of the hand and the hole beside it (an insertion that started again on a seated peg, sensed at the
    hole too, was done at once, and the next one with it, until one pulled the peg out)."""
    sensed = {"peg_grasped": grasped, "peg_at_hole": at_hole, "peg_inserted": 1.0, "peg_seated": 1.0}
    percept = Percept(sensed, "learned")
    assert not [s.name for s in SUBTASKS.values() if s.can_start(percept)]


def test_the_recorder_records_the_peg_tasks_expert_from_both_cameras(tmp_path):
    """The same recording path as the gear's: a recipe of the peg task, its expert, its two cameras, its 8-D state and
    action and its predicates, into a LeRobot dataset that LeRobot loads; `--clearance`, a setting the task does not
    have, is refused in one line, and so is training the insertion's policy on it (the task read from the dataset);
    the task's predicate classifiers train on it with the task's cameras."""
    root = tmp_path / "peg"
    result = run_cli("record", "peg-full-task-demos", "--episodes", "2", "--resolution", "32", "--root", str(root),
                     cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    info = read_info(root)
    assert {f"observation.images.{c}" for c in CAMERA_NAMES} <= set(info["features"])
    assert info["features"]["observation.state"]["names"] == list(STATE_NAMES)
    assert info["features"]["predicates"]["names"] == list(PREDICATES)
    assert info["features"]["observation.environment_state"]["names"] == list(SCENE_NAMES)
    sidecar = read_sidecar(root)
    assert sidecar["task_name"] == "peg-insertion-side" and sidecar["episodes"][0]["success"]
    frames = LeRobotDataset("local/peg", root=root)
    assert frames.num_episodes == 2 and frames[0]["observation.images.hand_camera"].shape == (3, 32, 32)
    # The recipe's hold_steps: the episode ends with the peg seated for that many frames and more, so the recordings
    # show the goal reached.
    seated = list(PREDICATES).index("peg_seated")
    last = [bool(frames[len(frames) - 1 - k]["predicates"][seated]) for k in range(5)]
    assert all(last) and not frames[0]["predicates"][seated]
    # The scene the robot knows is the box's, which stays put: the same hole pose in every frame of an episode, a
    # unit quaternion.
    columns = frames.hf_dataset  # the frames' non-image columns, no video decoded
    first = np.asarray(columns["episode_index"]) == 0
    scene = torch.as_tensor(np.stack(columns["observation.environment_state"])[first])
    assert torch.allclose(scene, scene[:1].expand_as(scene)) and abs(float(scene[0, 3:7].norm()) - 1) < 1e-5
    refused = run_cli("record", "peg-full-task-demos", "--clearance", "2", "--root", str(tmp_path / "no"),
                      cwd=tmp_path)
    assert refused.returncode == 2 and "PegInsertionSide-v1 has no setting clearance" in refused.stderr
    # Training reads the task from the dataset: these are the peg's full-task demonstrations, not its insertion's.
    refused = run_cli("train", "policy", "--dataset", str(root), "--out", str(tmp_path / "cnn"), cwd=tmp_path)
    assert refused.returncode == 2 and "needs peg-insertion-demos" in refused.stderr, refused.stderr[-2000:]
    world = tmp_path / "world"
    trained = run_cli("train", "predicates", "--dataset", str(root), "--epochs", "1", "--image-size", "32", "--out",
                      str(world), cwd=tmp_path)
    assert trained.returncode == 0, trained.stderr[-2000:]
    config = json.loads((world / "predicates" / "peg_at_hole" / "config.json").read_text())
    assert config["task"] == "peg-insertion-side" and config["cameras"] == list(CAMERA_NAMES)


def _planned_head_error(obs, u) -> np.ndarray:
    """Where the hand's kinematics put the peg's head, less where it is, in the hole's frame (m)."""
    known = hand_in_hole(obs["extra"]["state"].numpy(), obs["extra"]["scene"].numpy())[0]
    return known[6:9] - ((u.box_hole_pose.inv() * u.peg.pose).p[0].numpy() + [float(u.peg_half_sizes[0, 0]), 0, 0])


def test_the_pre_insertion_start_holds_the_peg_in_front_of_the_hole_at_step_zero(env):
    """The insertion's start state: the reset option carries the peg to the hole unobserved, and the episode starts
    there (step 0) with the peg grasped in front of the box, its carry's residual error left for the insertion; the
    info's success is the strict one, ManiSkill's beside it."""
    obs, info = env.reset(seed=5, options={"start": "pre_insertion"})
    flags = predicates(env)
    assert bool(flags["peg_grasped"][0]) and bool(flags["peg_at_hole"][0]) and not bool(flags["peg_inserted"][0])
    assert int(env.unwrapped.elapsed_steps[0]) == 0 and int(info["stage"][0]) == 2
    assert not bool(info["success"][0]) and not bool(info["success_maniskill"][0])
    assert obs["extra"]["state"].shape == (1, 8) and obs["extra"]["scene"].shape == (1, len(SCENE_NAMES))
    # Where the robot knows its hand is against the hole, by its joints' kinematics and the hole the planner knows, is
    # where the simulator has it: a TCP behind the box's near face on the hole's axis, the hand's fingers across it.
    known = hand_in_hole(obs["extra"]["state"].numpy(), obs["extra"]["scene"].numpy())[0]
    u = env.unwrapped
    tcp = u.box_hole_pose.inv() * u.agent.tcp.pose
    assert np.allclose(known[:3], tcp.p[0].numpy(), atol=1e-4), (known, tcp.p)
    assert np.allclose(known[3:6], tcp.to_transformation_matrix()[0, 0, :3].numpy(), atol=1e-4)
    assert known[0] < -float(u.peg_half_sizes[0, 0]) and np.linalg.norm(known[1:3]) < 0.01
    # The head where the planned grasp holds the peg: in front of the box's near face, within the hole's radius of its
    # axis and a few mm of the true head (the carry's residual error and how the peg sits in the fingers).
    assert np.linalg.norm(_planned_head_error(obs, u)) < 0.02, _planned_head_error(obs, u)
    assert -float(u.peg_half_sizes[0, 0]) - 0.05 < known[6] < -float(u.peg_half_sizes[0, 0])
    assert known[9] == pytest.approx(known[6] + float(u.peg_half_sizes[0, 0])) and -0.002 > known[10] > -0.005
    with pytest.raises(ValueError, match="starts at 'table' or 'pre_insertion'"):
        env.reset(seed=5, options={"start": "in_the_hole"})


def test_the_main_job_composes_the_peg_task_through_the_generic_stages(tmp_path):
    """`demo --task peg-insertion-side` at the smoke profile: every stage of the generic job (demonstrations,
    DMPs, the CNN insertion, rollouts, the world model with a goal scorer per camera, Table I, the compositions) runs
    on ManiSkill's task, without the DAgger rounds its spec leaves out, and the report has its rows, without the
    paper's gear figures."""
    out = tmp_path / "peg"
    result = run_cli("demo", "--profile", "smoke", "--task", "peg-insertion-side", "--out", str(out), cwd=tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    stages = [line for line in result.stdout.splitlines() if line.startswith("[") and " -> " in line]
    assert len(stages) == 10 and stages[0].startswith("[1/10] record the insertion demonstrations"), stages
    assert not any("DAgger" in line for line in stages)
    report = (out / "report.md").read_text()
    assert "(PegInsertionSide-v1)" in report and "## The random-walk MDP" not in report
    for row in ("| MP | ", "| DMP | ", "| CNN | - | - | ", "| base_camera |", "| hand_camera |",
                "| composed (selector), sensed predicates |", "| peg_seated | "):
        assert row in report, f"{row!r} missing from the report"
    cnn = next(line for line in report.splitlines() if line.startswith("| CNN | "))
    assert "/2 (95% CI " in cnn and "paper" not in report.split("## Table I")[1].split("##")[0]


def test_the_task_bounds_its_learned_controllers_steps_within_the_profiles():
    """The peg's CNN insertion gets the task's 50 steps at the quick profile (120), the smoke profile's 30 stay
    fewer, and the gear, which sets none, keeps the profile's."""
    quick, smoke = PROFILES["quick"], PROFILES["smoke"]
    assert Makings.of(quick, "peg-insertion-side").cnn["insert"].max_steps == 50 < quick.cnn_max_steps
    assert Makings.of(smoke, "peg-insertion-side").cnn["insert"].max_steps == smoke.cnn_max_steps < 50
    assert Makings.of(quick, "gear-assembly").cnn["insert"].max_steps == quick.cnn_max_steps


def test_the_peg_cnn_policy_reads_where_its_hand_is_against_the_hole(env):
    """On a task whose scene differs between episodes, the CNN policy reads by default, besides its image, the
    gripper's width and where its hand is against the scene the robot knows (the hand camera cannot see the hole in
    the box's side); on the gear, whose scene is the same in every episode, the gripper's width only."""
    config = CNNPolicyConfig(task="peg-insertion-side")
    assert config.proprioception == "scene" and config.state_dim == 1 + 11
    assert CNNPolicyConfig().proprioception == "gripper" and CNNPolicyConfig().state_dim == 1
    obs, _ = env.reset(seed=7, options={"start": "pre_insertion"})
    state, scene = obs["extra"]["state"].float(), obs["extra"]["scene"]
    read = policy_state(state, config, scene)
    assert read.shape == (1, 12) and float(read[0, 0]) == pytest.approx(float(state[0, 7]))
    assert np.allclose(read[0, 1:].numpy(), hand_in_hole(state.numpy(), scene.numpy())[0], atol=1e-6)
    with pytest.raises(ValueError, match="observation.environment_state"):
        policy_state(state, config)


def test_a_learned_insertion_holds_the_peg_along_the_holes_axis_as_planned(env):
    """A learned insertion steps in the hand's frame at the orientation its scene gives. Holding the peg, that is the
    hand turned so that the peg, held as planned, lies along the hole's axis (as the planned insertions hold it), not
    the turn the carry left (1-2 degrees off the axis at this start), so its pushes go along the axis. Empty, the hand
    keeps the orientation it has."""
    u = env.unwrapped
    env.reset(seed=3011)  # the hand empty, open over the table
    scene = PegScene(u)
    assert np.allclose(scene.hand_quat(None, u.agent.robot.get_qpos()[0].numpy()), u.agent.tcp.pose.q[0])
    env.reset(seed=3011, options={"start": "pre_insertion"})
    hole = scene.hole().to_transformation_matrix()[:3, :3]
    carried = (u.box_hole_pose.inv() * u.agent.tcp.pose).to_transformation_matrix()[0, :3, 0].numpy()
    assert np.degrees(np.arccos(abs(carried[0]))) > 1.0  # the carry's leftover turn
    kept = sapien.Pose(scene.tcp(), scene.hand_quat(None, u.agent.robot.get_qpos()[0].numpy()))
    assert abs(float(kept.to_transformation_matrix()[:3, 0] @ hole[:, 0])) > 1 - 1e-9  # the hand's x along the axis
    peg = (kept * scene.peg_in_hand()).to_transformation_matrix()[:3, :3]
    assert np.allclose(peg, hole, atol=1e-6)  # the planned peg lies as the hole does, head first


def test_the_robot_knows_the_grasp_it_planned(env):
    """Where a hand straight down would meet the box with its forearm, the expert grasps tilted back 0.3 rad (seed
    3010); where the library's grasp would not reach, 17 mm farther back along the peg (seed 5). The scene the robot
    knows says so, and the planned grasp is then where the peg truly lies in the hand (the library's own grasp had it
    17 degrees off, and the head 15 mm off): the hand's kinematics put the head where it is, the hand is kept at the
    turn that lies the peg along the hole's axis, and a learned insertion's moves "in the hand's frame" go along the
    peg, as in a grasp straight down. A reset from the table forgets the last episode's grasp."""
    u = env.unwrapped
    tilt, offset = SCENE_NAMES.index("grasp_tilt"), SCENE_NAMES.index("grasp_offset")
    obs, _ = env.reset(seed=3010, options={"start": "pre_insertion"})
    assert float(obs["extra"]["scene"][0, tilt]) == pytest.approx(0.3)
    scene, true = PegScene(u), pose0(u.peg.pose).to_transformation_matrix()[:3, :3]
    planned = (pose0(u.agent.tcp.pose) * scene.peg_in_hand()).to_transformation_matrix()[:3, :3]
    assert np.degrees(np.arccos(planned[:, 0] @ true[:, 0])) < 2.0
    assert np.linalg.norm(_planned_head_error(obs, u)) < 0.01
    kept = sapien.Pose(scene.tcp(), scene.hand_quat(None, u.agent.robot.get_qpos()[0].numpy()))
    hole = scene.hole().to_transformation_matrix()[:3, :3]
    assert np.allclose((kept * scene.peg_in_hand()).to_transformation_matrix()[:3, :3], hole, atol=1e-6)
    turn = get_task("peg-insertion-side").grasp_turns(obs["extra"]["scene"], 1)[0]
    hand = pose0(u.agent.tcp.pose).to_transformation_matrix()[:3, :3]
    assert (hand @ turn)[:, 0] @ true[:, 0] > np.cos(np.radians(2.0)) > hand[:, 0] @ true[:, 0] + 0.03
    obs, _ = env.reset(seed=5, options={"start": "pre_insertion"})
    own = grasp_offset(float(u.peg_half_sizes[0, 0]))  # the library's pick-up's grasp
    assert float(obs["extra"]["scene"][0, offset]) > own + 0.015 and float(obs["extra"]["scene"][0, tilt]) == 0.0
    assert np.linalg.norm(_planned_head_error(obs, u)) < 0.005
    obs, _ = env.reset(seed=5)
    assert float(obs["extra"]["scene"][0, tilt]) == 0.0
    assert float(obs["extra"]["scene"][0, offset]) == pytest.approx(own)


def test_a_lerobot_checkpoint_of_another_scene_is_refused_by_name(env, tmp_path):
    """A LeRobot policy trained on recordings whose scene was laid out otherwise (9 values, before the grasp planned
    joined it) is refused with what to do, not run into a shape error inside the model."""
    config = ACTConfig(input_features={"observation.state": PolicyFeature(FeatureType.STATE, (len(STATE_NAMES),)),
                                       "observation.environment_state": PolicyFeature(FeatureType.ENV, (9,))},
                       output_features={"action": PolicyFeature(FeatureType.ACTION, (8,))},
                       pretrained_backbone_weights=None)
    config.save_pretrained(tmp_path)
    with pytest.raises(CheckpointError, match=rf"takes a scene of shape \(9,\), PegInsertionSide-v1 gives "
                                              rf"\({len(SCENE_NAMES)},\): train it again"):
        LeRobotPolicyController(env, tmp_path)


def test_fingers_wider_than_the_peg_hold_nothing():
    """The kinematic rule beside the classifiers: with the fingers wider than the peg the hand holds nothing, so the
    peg is neither grasped, at the pre-insertion pose nor in the hole, whatever the classifiers say (they said
    "seated" at the reset of four held-out seeds, where the hand, open, was where the planned grasp would seat it);
    with the fingers squeezing it, their word stands."""
    said = {"peg_grasped": 0.9, "peg_at_hole": 0.8, "peg_inserted": 0.97, "peg_seated": 0.97}
    gap = list(HAND_IN_HOLE).index("fingers_wider_than_peg")
    kinematics = np.zeros(len(HAND_IN_HOLE))
    kinematics[gap] = EMPTY_HAND_GAP + 0.001
    assert rule_out(dict(said), kinematics) == dict.fromkeys(said, 0.0)
    kinematics[gap] = -0.002
    assert rule_out(dict(said), kinematics) == said
