"""Record a task's rollouts into a LeRobotDataset, the way ManiSkill's `RecordEpisode` records trajectories.

Two halves, so that episodes can run in worker processes and be written by one: `FrameBuffer` wraps the env and,
while `recording` is on, buffers the observation each action was chosen from, the action, the stage and the name
of the controller that produced it; `LeRobotWriter` labels an episode's frames (progress, done) and writes them as
one LeRobot episode: videos per camera (h264 with streaming encoding, about 3x faster than lerobot's default AV1
here), the rest in parquet. `LeRobotRecorder` is the two in one process.

LeRobot's streaming encoder is built for real-time capture: when its encoder falls behind, it drops frames. A
simulation has no deadline, so `LosslessEncoder` waits for it instead, and every saved episode's videos are checked
to hold exactly its frames before the episode is committed. Each save is journalled (see `journal`), so a Ctrl-C,
`kill -9` or failed check at any moment leaves every episode saved before it loadable, and a writer (or recorder)
made with `resume=True` appends to the same dataset.
"""

from __future__ import annotations

import json
import queue
import warnings
from contextlib import contextmanager
from pathlib import Path

import av
import datasets
import gymnasium as gym
import numpy as np
import torch
from lerobot.configs.video import RGBEncoderConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.video_utils import StreamingVideoEncoder

from policy_composer.data import interrupt, journal
from policy_composer.data.features import SIDECAR, DatasetError, dataset_features, image_key, read_info, read_sidecar
from policy_composer.data.verify import check_videos, data_digests
from policy_composer.tasks.registry import DEFAULT_TASK, get_spec, task_of

VCODEC = "h264"  # not "auto": it picks NVENC and fails without a GPU


@contextmanager
def _quiet_lerobot():
    """Keep a recording's terminal to its progress bar: no per-episode encoder stats, map bars or bool warnings."""
    av.logging.set_libav_level(av.logging.ERROR)  # lerobot restores the default callback, which obeys this
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Converting input from bool", RuntimeWarning)
        yield


def _flat(action, env) -> np.ndarray:
    if isinstance(action, dict):  # ManiSkill's per-arm dict, in agent order
        action = torch.cat([torch.as_tensor(action[k]).reshape(-1) for k in env.agent.agents_dict])
    return torch.as_tensor(action, dtype=torch.float32).reshape(-1).cpu().numpy()


class FrameBuffer(gym.Wrapper):
    """Wraps a single env of one of the library's tasks (obs_mode "rgb") and buffers the frames of the episode being
    recorded, with `cameras` (default: every camera the env renders; it may render more, for a controller that reads
    them). Frames are plain arrays and the controller's name, so they can be sent to the process that writes them."""

    def __init__(self, env: gym.Env, cameras: tuple[str, ...] | None = None):
        super().__init__(env)
        u = env.unwrapped
        self.task = task_of(u)
        if u.num_envs != 1:
            raise ValueError(f"the recorder writes one episode at a time; got num_envs={u.num_envs}")
        if "rgb" not in u.obs_mode:
            raise ValueError(f"recording needs camera images: make the env with obs_mode='rgb' (got {u.obs_mode!r})")
        sizes = {name: (s.config.width, s.config.height) for name, s in u.scene.sensors.items()}
        self.cameras = tuple(cameras or sizes)
        missing = [c for c in self.cameras if c not in sizes]
        if missing:
            raise ValueError(f"the recorder records cameras {missing} that the env does not render; make the env "
                             f"with them")
        width, height = sizes[self.cameras[0]]
        if {sizes[c] for c in self.cameras} != {(width, width)}:
            raise ValueError(f"recordings use square camera images of one size; got {[sizes[c] for c in self.cameras]}")
        self.resolution, self.fps = width, int(u.control_freq)
        self.recording = True
        self.controller = "unknown"  # set by the driver: the controller whose action the next step applies
        self._frames: list[dict] = []
        self._obs = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._frames = []
        return self._starting_from(obs), info

    def observe(self):
        """The env's observation now, from which the next frame is recorded: after steps taken around the buffer
        (unrecorded and unrendered, say by the expert bringing the arm to where a subtask starts)."""
        return self._starting_from(self.task.observe(self.env))

    def _starting_from(self, obs):
        """`obs` is the state the next frame records, with the scene's labels there."""
        self._obs, self._labels = obs, self.task.labels(self.env.unwrapped, None)
        return obs

    def step(self, action, label=None):
        """Step with `action`; the frame records `label` as its action if given (DART: the expert's own command,
        where the arm was sent a perturbed one)."""
        interrupt.check()  # a Ctrl-C swallowed mid-episode (say, by a rebuilt scene's __del__) ends it here
        u = self.env.unwrapped
        flat = _flat(action, u)
        obs, reward, terminated, truncated, info = self.env.step(self.task.env_action(u, flat))
        if self.recording:
            prev = self._obs
            self._frames.append({
                **{image_key(c): prev["sensor_data"][c]["rgb"][0].cpu().numpy() for c in self.cameras},
                "observation.state": prev["extra"]["state"][0].cpu().numpy().astype(np.float32),
                **({"observation.environment_state": prev["extra"]["scene"][0].cpu().numpy().astype(np.float32)}
                   if "scene" in prev["extra"] else {}),
                "action": (flat if label is None else _flat(label, u)).astype(np.float32),
                "stage": np.array([self._labels[0]], dtype=np.int64),
                "gear_offset": self._labels[1],
                "predicates": self._labels[2],
                "controller": self.controller,  # its index in the dataset's list, when written
                "next.success": np.array([bool(info["success"][0])]),
            })
        self._obs, self._labels = obs, self.task.labels(u, info)
        return obs, reward, terminated, truncated, info

    @property
    def buffered_frames(self) -> int:
        return len(self._frames)

    def discard_episode(self) -> None:
        self._frames = []

    def take_episode(self) -> list[dict]:
        """The buffered frames, leaving the buffer empty."""
        frames, self._frames = self._frames, []
        return frames


class LosslessEncoder(StreamingVideoEncoder):
    """lerobot's per-camera encoder threads, with a writer that waits for them however long they take:
    `feed_frame` blocks while the queue is full (lerobot's drops the frame after 0.1 s), and `finish_episode`
    waits for every thread to finish (lerobot's gives up after 120 s and keeps a truncated file)."""

    def _put(self, video_key: str, item) -> bool:
        """Put `item` on the camera's queue, waiting as long as its encoder runs; False if it has stopped."""
        while self._episode_active and self._threads[video_key].is_alive():
            try:
                self._frame_queues[video_key].put(item, timeout=1.0)
                return True
            except queue.Full:
                continue
        return False

    def feed_frame(self, video_key: str, image: np.ndarray) -> None:
        if not self._put(video_key, image.copy()):
            super().feed_frame(video_key, image)  # no episode, or a crashed encoder: lerobot raises its error

    def finish_episode(self):
        for video_key in self._threads:
            if self._put(video_key, None):  # lerobot's end-of-episode sentinel
                self._threads[video_key].join()
        return super().finish_episode()  # its sentinels and joins find the threads done; it collects results


class LosslessDataset(LeRobotDataset):
    """LeRobotDataset whose streaming encoder never drops a frame."""

    @staticmethod
    def _build_streaming_encoder(fps, rgb_encoder, depth_encoder, encoder_queue_maxsize, encoder_threads):
        return LosslessEncoder(fps=fps, rgb_encoder=rgb_encoder, depth_encoder=depth_encoder,
                               queue_maxsize=encoder_queue_maxsize, encoder_threads=encoder_threads)


class LeRobotWriter:
    """Writes episodes of buffered frames into the LeRobotDataset at `root`, each one whole or not at all."""

    def __init__(self, root: str | Path, task: str, fps: int, resolution: int, cameras: tuple[str, ...],
                 repo_id: str | None = None, resume: bool = False, metadata: dict | None = None,
                 vcodec: str = VCODEC, streaming_encoding: bool = True, task_name: str = DEFAULT_TASK):
        self.video = {"rgb_encoder": RGBEncoderConfig(vcodec=vcodec), "streaming_encoding": streaming_encoding}
        self.root, self.task, self.fps, self.cameras = Path(root), task, fps, tuple(cameras)
        self.features = dataset_features(get_spec(task_name), self.cameras, resolution)
        if resume:
            journal.recover(self.root)
        if self.root.exists():
            if not resume:
                raise DatasetError(f"{self.root} already exists ({self._describe()}); pass --resume to append "
                                   f"to it, or choose another --root")
            self._check_compatible(read_info(self.root))
            self.sidecar = read_sidecar(self.root)
        else:
            self.sidecar = {"repo_id": repo_id or f"local/{self.root.name}", "controllers": [], "episodes": []}
        self.sidecar.update(metadata or {})
        self.repo_id = self.sidecar["repo_id"]

    @property
    def num_episodes(self) -> int:
        return len(self.sidecar["episodes"])

    @property
    def episodes(self) -> list[dict]:
        """Per saved episode: seed, success, length, and anything the driver added."""
        return self.sidecar["episodes"]

    def _describe(self) -> str:
        try:
            return f"{read_info(self.root)['total_episodes']} episodes"
        except DatasetError as e:
            return str(e)

    def _check_compatible(self, info: dict) -> None:
        theirs = {k: (v["dtype"], tuple(v["shape"])) for k, v in info["features"].items() if k in self.features}
        ours = {k: (v["dtype"], tuple(v["shape"])) for k, v in self.features.items()}
        if theirs != ours or info["fps"] != self.fps:
            raise DatasetError(f"cannot resume {self.root}: it holds {theirs} at {info['fps']} fps, this env records "
                               f"{ours} at {self.fps} fps (same cameras and resolution needed)")

    def _controller_index(self, name: str) -> int:
        names = self.sidecar["controllers"]
        if name not in names:
            names.append(name)
        return names.index(name)

    def save_episode(self, frames: list[dict], success: bool, **episode_info) -> None:
        """Label `frames` (from a `FrameBuffer`) and write them as one episode; all or nothing, even on kill -9.
        An episode that cannot be written whole (a full disk, videos short of its frames) is rolled back, and a
        DatasetError says so."""
        if not frames:
            raise ValueError("no frames to save: step the env with recording on first")
        T = len(frames)
        frames = [{**frame, "controller": np.array([self._controller_index(frame["controller"])], dtype=np.int64),
                   "progress": np.array([t / max(T - 1, 1) if success else -1.0], dtype=np.float32),
                   "next.done": np.array([t == T - 1]), "task": self.task} for t, frame in enumerate(frames)]
        with interrupt.held_back(), _quiet_lerobot():  # an episode is written whole
            journal.begin(self.root)
            saved = self.num_episodes
            try:
                self._write(frames)
                self.sidecar["data_digests"] = data_digests(self.root)
                self.sidecar["episodes"].append({"success": bool(success), "length": T, **episode_info})
                (self.root / SIDECAR).write_text(json.dumps(self.sidecar, indent=1))
            except (OSError, RuntimeError, DatasetError) as e:  # a full disk, an encoder's error, a short video
                del self.sidecar["episodes"][saved:]
                journal.recover(self.root)
                raise DatasetError(f"episode {saved} was not saved, and the recording stopped ({e}); "
                                   f"{self.root} holds the episodes saved before it") from None
            journal.commit(self.root)

    def _write(self, frames: list[dict]) -> None:
        """Add the labelled frames as one LeRobot episode and check that its videos hold every one of them."""
        if self.root.exists():  # lerobot's resume path: this episode goes into new files
            dataset = LosslessDataset.resume(self.repo_id, root=self.root, **self.video)
        else:
            dataset = LosslessDataset.create(self.repo_id, fps=self.fps, features=self.features, root=self.root,
                                             robot_type="panda_pair", use_videos=True, **self.video)
        datasets.disable_progress_bars()  # after opening: lerobot's loader turns them back on
        for frame in frames:
            dataset.add_frame(frame)
        dataset.save_episode()
        dataset.finalize()
        info = read_info(self.root)
        check_videos(self.root, info, episodes=[info["total_episodes"] - 1])


class LeRobotRecorder(FrameBuffer):
    """A `FrameBuffer` whose `save_episode` writes what it buffered through its own `LeRobotWriter`: recording in
    one process."""

    def __init__(self, env: gym.Env, root: str | Path, task: str, repo_id: str | None = None, resume: bool = False,
                 metadata: dict | None = None, vcodec: str = VCODEC, streaming_encoding: bool = True,
                 cameras: tuple[str, ...] | None = None):
        super().__init__(env, cameras)
        self.writer = LeRobotWriter(root, task, self.fps, self.resolution, self.cameras, repo_id, resume, metadata,
                                    vcodec, streaming_encoding)

    @property
    def sidecar(self) -> dict:
        return self.writer.sidecar

    @property
    def episodes(self) -> list[dict]:
        return self.writer.episodes

    @property
    def num_episodes(self) -> int:
        return self.writer.num_episodes

    def save_episode(self, success: bool, **episode_info) -> None:
        self.writer.save_episode(self.take_episode(), success, **episode_info)
