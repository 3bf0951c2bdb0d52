"""Not one frame lost: a recording holds every frame in its videos, lined up with its state and action, however slow
the encoder; a video that lost a frame is refused by every reader and by the main job's reuse of a stage."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

import av
import gymnasium as gym
import lerobot.datasets.compute_stats as compute_stats  # the encoder thread imports its helper from here
import numpy as np
import pytest
import torch
from conftest import run_cli, tree_digest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from policy_composer.app.demo import _verify_dataset
from policy_composer.app.pipeline import MARKER, Stage, run_stages
from policy_composer.data import recorder
from policy_composer.data.features import DatasetError, image_key, read_info
from policy_composer.data.frames import load_frames, to_model_image
from policy_composer.data.recorder import FrameBuffer, LeRobotWriter
from policy_composer.data.verify import open_dataset, video_frames
from policy_composer.tasks.gear_assembly.expert import GearAssemblyExpert
from policy_composer.tasks.gear_assembly.spec import CAMERA_NAMES

RES, STEPS, BLOCK = 64, 30, 8  # the frame index is stamped as 8 black or white 8x8 blocks along the top row
BIN = Path(sys.executable).parent


def stamp(image: np.ndarray, index: int) -> None:
    for bit in range(RES // BLOCK):
        image[:BLOCK, bit * BLOCK:(bit + 1) * BLOCK] = 255 if index >> bit & 1 else 0


def read_stamp(image: np.ndarray) -> int:
    """The index stamped on a decoded (H, W, 3) image in [0, 255] (h264 blurs the blocks' edges, not their centres)."""
    c = BLOCK // 2
    return sum(1 << bit for bit in range(RES // BLOCK) if image[c, bit * BLOCK + c].mean() > 127)


class Stamped(gym.Wrapper):
    """Stamps every observation's camera images with the observation's number before anything above it sees them,
    and keeps the state observed with each number: a frame whose image and state come from different steps shows
    it."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.states: list[np.ndarray] = []

    def _stamped(self, obs):
        for sensor in obs["sensor_data"].values():
            image = sensor["rgb"][0].cpu().numpy().copy()
            stamp(image, len(self.states))
            sensor["rgb"][0] = torch.as_tensor(image)
        self.states.append(obs["extra"]["state"][0].cpu().numpy().copy())
        return obs

    def reset(self, **kwargs):
        self.states = []
        obs, info = self.env.reset(**kwargs)
        return self._stamped(obs), info

    def step(self, action):
        obs, *rest = self.env.step(action)
        return self._stamped(obs), *rest


@pytest.fixture(scope="module")
def episode():
    """One expert episode's buffered frames (three cameras), each image stamped with its step's number below the
    buffer, and the state observed with each number."""
    env = Stamped(gym.make("GearAssembly-v1", obs_mode="rgb", camera_width=RES, camera_height=RES))
    buffer = FrameBuffer(env)
    expert = GearAssemblyExpert(buffer)
    obs, _ = buffer.reset(seed=3)
    expert.reset(3)
    buffer.controller = "expert"
    actions = []
    for _ in range(STEPS):
        actions.append(expert.act(obs))
        obs, *_ = buffer.step(actions[-1])
    frames = buffer.take_episode()
    buffer.close()
    return frames, env.states, [a.numpy().astype(np.float32).ravel() for a in actions]


def test_a_buffered_frame_holds_the_image_state_and_action_of_one_step(episode):
    """Frame t: the images and the state observed before step t, and the action of step t."""
    frames, states, actions = episode
    assert len(frames) == STEPS and len(states) == STEPS + 1  # the observation after the last step is no frame
    for t, frame in enumerate(frames):
        assert [read_stamp(frame[image_key(c)]) for c in CAMERA_NAMES] == [t] * len(CAMERA_NAMES), t
        np.testing.assert_array_equal(frame["observation.state"], states[t])
        np.testing.assert_array_equal(frame["action"], actions[t])


def slow_encoder(monkeypatch, seconds: float = 0.15) -> None:
    """lerobot's encoder threads take `seconds` a frame (more than its 0.1 s wait before dropping one), as on a CPU
    shared with other work."""
    real = compute_stats.auto_downsample_height_width
    monkeypatch.setattr(compute_stats, "auto_downsample_height_width",
                        lambda image: (time.sleep(seconds), real(image))[1])


def writer(root: Path, queue_size: int = 1, resume: bool = False) -> LeRobotWriter:
    w = LeRobotWriter(root, "insert the gear", 20, RES, CAMERA_NAMES, resume=resume)
    w.video["encoder_queue_maxsize"] = queue_size  # a full queue at every frame
    return w


def test_a_slow_encoder_loses_no_frame_and_image_i_is_state_i(tmp_path, monkeypatch, episode):
    slow_encoder(monkeypatch)
    root = tmp_path / "slow"
    frames, _, _ = episode
    writer(root).save_episode(frames, success=False, seed=3)

    info = read_info(root)
    for camera in CAMERA_NAMES:
        path = root / info["video_path"].format(video_key=image_key(camera), chunk_index=0, file_index=0)
        assert video_frames(path) == STEPS
    ds = open_dataset(root)
    assert ds.num_frames == STEPS
    for i in range(STEPS):
        item = ds[i]
        np.testing.assert_array_equal(item["observation.state"].numpy(), frames[i]["observation.state"])
        np.testing.assert_array_equal(item["action"].numpy(), frames[i]["action"])
        for camera in CAMERA_NAMES:
            decoded = (item[image_key(camera)].permute(1, 2, 0).numpy() * 255).round()
            assert read_stamp(decoded) == i, f"{camera}: image {i} shows frame {read_stamp(decoded)}"


def test_a_lossy_encoder_is_caught_before_the_episode_is_committed(tmp_path, monkeypatch, episode):
    """lerobot's own real-time encoder under the same load drops frames: the check refuses the episode and the
    dataset stays as it was before it."""
    root = tmp_path / "lossy"
    frames, _, _ = episode
    writer(root, queue_size=30).save_episode(frames, success=False, seed=3)
    before = tree_digest(root)
    slow_encoder(monkeypatch)
    monkeypatch.setattr(recorder, "LosslessDataset", LeRobotDataset)
    with pytest.raises(DatasetError, match=r"episode 1 was not saved.*camera head: .* \d+ frames for 30 steps"):
        writer(root, resume=True).save_episode(frames, success=False, seed=4)
    assert tree_digest(root) == before
    assert open_dataset(root).num_episodes == 1


def drop_last_frame(video: Path) -> None:
    """Re-encode `video` without its last frame, as a recorder that dropped one would have written it."""
    with av.open(str(video)) as src:
        frames = [f.to_ndarray(format="rgb24") for f in src.decode(video=0)]
        rate = src.streams.video[0].average_rate
    tmp = video.with_suffix(".tmp.mp4")
    with av.open(str(tmp), "w") as dst:
        stream = dst.add_stream("h264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = RES, RES, "yuv420p"
        for image in frames[:-1]:
            dst.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        dst.mux(stream.encode())
    tmp.replace(video)


@pytest.fixture
def damaged(insertion_demos, tmp_path) -> tuple[Path, Path]:
    """A copy of the insertion demos whose second episode's head video lost its last frame: (root, that file)."""
    root = tmp_path / "damaged"
    shutil.copytree(insertion_demos, root)
    video = sorted((root / "videos" / image_key("head")).rglob("*.mp4"))[1]
    frames = video_frames(video)
    drop_last_frame(video)
    assert video_frames(video) == frames - 1
    return root, video


def test_every_reader_refuses_a_video_one_frame_short(damaged):
    root, video = damaged
    res = run_cli("dataset", "info", str(root))
    assert res.returncode == 2, res.stderr
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert str(video.relative_to(root)) in res.stderr and "episode 1, camera head" in res.stderr
    assert "record the dataset again" in res.stderr
    with pytest.raises(DatasetError, match="do not hold their episode's frames"):  # training loads through here
        load_frames(root, ("head",), 32, progress=False)


def test_a_reused_stage_with_a_damaged_dataset_is_made_again(damaged, insertion_demos, tmp_path):
    """The main job's check of a finished recording stage: named, made again, and the stage reading it too."""
    root, _ = damaged
    calls, lines = [], []

    def record(out: Path, _):
        calls.append("record")
        shutil.copytree(root if len(calls) == 1 else insertion_demos, out / "dataset")  # damaged, then good
        return {}

    def train(out: Path, inputs):
        calls.append("train")
        return {"episodes": read_info(inputs["demos"] / "dataset")["total_episodes"]}

    stages = [Stage("demos", "record", {}, record, resumable=True, verify=_verify_dataset),
              Stage("model", "train", {}, train, inputs=("demos",))]
    run_stages(stages, tmp_path / "run", log=lines.append)  # a recording whose damage went unseen at the time
    records = run_stages(stages, tmp_path / "run", log=lines.append)
    assert calls == ["record", "train", "record", "train"]
    assert not records["demos"].reused and not records["model"].reused
    assert any("damaged" in line and str(records["demos"].folder) in line and "head" in line for line in lines)
    assert any("made again, as demos was" in line for line in lines)
    assert (records["demos"].folder / MARKER).exists()
    assert all(r.reused for r in run_stages(stages, tmp_path / "run", log=lines.append).values())


def test_a_window_is_cut_at_the_images_own_resolution():
    """The insertion's window keeps the pixels it covers: a 128 px image's 64 px window, at 64, is those pixels
    untouched, not a resampling of the whole image."""
    image = torch.randint(0, 256, (1, 128, 128, 3), dtype=torch.uint8)
    window = (0.1875, 0.28125, 0.5)
    cut = to_model_image(image, 64, window)
    torch.testing.assert_close(cut, image[:, 24:88, 36:100].permute(0, 3, 1, 2).float() / 255.0)
