"""What a task's LeRobot dataset holds, and the checks a consumer runs before it trusts one.

Every consumer (the CNN policy, the VAE, the dynamics models, the goal scorers) opens its dataset through
`open_dataset`, so a wrong path, a missing camera or a feature of the wrong shape fails at once with an
error that names the dataset, what is missing and what was expected, not deep inside a training loop.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pyarrow is imported where a dataset is read
    import pyarrow as pa

    from policy_composer.tasks.base import TaskSpec

LEROBOT_VERSION = "0.6.1"  # the release pyproject.toml pins; its datasets are of FORMAT_VERSION
FORMAT_VERSION = "v3.0"
SIDECAR = "meta/policy_composer.json"  # recipe, seeds, success and controller names per episode


def image_key(camera: str) -> str:
    return f"observation.images.{camera}"


# Bump when dataset_features changes: the main job's recording stages key on it, so no recording without a column
# the models need is reused.
FEATURES_REVISION = 3


def dataset_features(spec: TaskSpec, cameras: tuple[str, ...] | None = None, resolution: int = 128) -> dict[str, dict]:
    """LeRobot feature spec of a recording of the task: camera videos (default: all of the task's), joint state,
    action and the per-frame labels."""
    cameras = spec.cameras if cameras is None else cameras
    unknown = set(cameras) - set(spec.cameras)
    if unknown:
        raise ValueError(f"unknown camera(s) {sorted(unknown)}; {spec.env_id} has {list(spec.cameras)}")
    features = {
        image_key(c): {"dtype": "video", "shape": (resolution, resolution, 3), "names": ["height", "width", "channels"]}
        for c in cameras
    }
    features.update({
        "observation.state": {"dtype": "float32", "shape": (len(spec.state_names),), "names": list(spec.state_names)},
        "action": {"dtype": "float32", "shape": (len(spec.action_names),), "names": list(spec.action_names)},
        # frame_index / (T - 1) in a successful episode, -1 in a failed one: the goal score's target.
        "progress": {"dtype": "float32", "shape": (1,), "names": None},
        # The task's labels of the observed state (TaskDescription.labels), privileged, never a policy's input: the
        # stage reached (on the gear: 0 pick, 1 move, 2 insert, 3 done), the held part's offset in the hand (m; the
        # column keeps the gear's name), and each predicate, 0 or 1 (the predicate classifiers' labels).
        "stage": {"dtype": "int64", "shape": (1,), "names": None},
        "gear_offset": {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
        "predicates": {"dtype": "float32", "shape": (len(spec.predicates),), "names": list(spec.predicates)},
        # Index into the sidecar's "controllers" list: which controller produced this frame's action.
        "controller": {"dtype": "int64", "shape": (1,), "names": None},
        "next.success": {"dtype": "bool", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    })
    return features


REPAIR = "record the dataset again (or restore the file from a copy)"


class DatasetError(ValueError):
    """A dataset that is missing, not a LeRobot dataset, or lacks what its consumer needs."""


def read_info(root: str | Path) -> dict:
    """meta/info.json of a LeRobot dataset, or a DatasetError that says why `root` is not one."""
    root = Path(root)
    if not root.exists():
        raise DatasetError(f"no dataset at {root}: the path does not exist "
                           "(record one with `policy-composer record RECIPE`)")
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise DatasetError(f"{root} is not a LeRobot dataset: it has no meta/info.json "
                           f"(expected a LeRobotDataset {FORMAT_VERSION} folder, as `policy-composer record` writes)")
    info = read_json(info_path, REPAIR)
    if info.get("codebase_version") != FORMAT_VERSION:
        raise DatasetError(f"{root} is a LeRobot dataset of format {info.get('codebase_version')}; this project reads "
                           f"{FORMAT_VERSION} (lerobot {LEROBOT_VERSION}); convert it with lerobot's v30 conversion "
                           "script")
    return info


def read_sidecar(root: str | Path) -> dict:
    """The project's metadata of a dataset it recorded ({} if there is none)."""
    path = Path(root) / SIDECAR
    return read_json(path, REPAIR) if path.is_file() else {}


def read_json(path: Path, fix: str) -> dict:
    """A JSON object from `path`, or a DatasetError that names the file and `fix`."""
    try:
        value = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path} is not readable JSON ({e}); {fix}") from None
    if not isinstance(value, dict):
        raise DatasetError(f"{path} holds a JSON {type(value).__name__}, not an object; {fix}")
    return value


def check_features(root: str | Path, info: dict, required: dict[str, tuple[int, ...] | None],
                   fps: int | None = None) -> None:
    """Raise DatasetError unless every `required` feature exists (with that shape, unless None) and fps matches."""
    features = info.get("features", {})
    missing = [k for k in required if k not in features]
    if missing:
        cameras = [k for k in missing if k.startswith("observation.images.")]
        what = "camera(s)" if len(cameras) == len(missing) else "feature(s)"
        fix = ("Record it with those cameras, or configure the consumer for the ones it has." if cameras else
               "Record it again with this version of policy-composer, which records them, or configure the consumer "
               "not to need them.")
        raise DatasetError(f"dataset {root} lacks the {what} {missing}; it has {sorted(features)}. {fix}")
    for key, shape in required.items():
        if shape is not None and tuple(features[key]["shape"]) != tuple(shape):
            raise DatasetError(f"dataset {root}: feature {key!r} has shape {tuple(features[key]['shape'])}, "
                               f"expected {tuple(shape)}")
    if fps is not None and info.get("fps") != fps:
        raise DatasetError(f"dataset {root} was recorded at {info.get('fps')} fps, expected {fps} "
                           f"(the env's control frequency)")


def check_files(root: Path, info: dict) -> None:
    """Raise DatasetError naming the first parquet file whose rows do not read or differ from what was recorded, the
    first value that is not finite, the video files that are missing, or the videos that do not hold their episodes'
    frames."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    data = {}
    for path in sorted((root / "data").rglob("*.parquet")) + sorted((root / "meta").rglob("*.parquet")):
        try:
            table = pq.read_table(path)  # every row: a file damaged in the middle keeps a readable footer
        except (OSError, ValueError, pa.ArrowException) as e:
            raise DatasetError(f"{path} is not a readable parquet file ({e}); {REPAIR}") from None
        if path.is_relative_to(root / "data"):
            data[path.relative_to(root)] = table
    recorded = read_sidecar(root).get("data_digests", {})  # parquet has no checksums: damaged values still read
    changed = [rel for rel, digest in data_digests(root).items() if rel in recorded and recorded[rel] != digest]
    if changed:
        raise DatasetError(f"{root / changed[0]} does not hold what was recorded (its SHA-256 differs from the one "
                           f"saved with it); {REPAIR}")
    bad = first_nonfinite(data)
    if bad:
        raise DatasetError(f"{root} holds a value that is not finite (NaN or Inf): {bad}; a model trained on it "
                           "would compute with it; record the dataset again, or remove that episode with "
                           "`lerobot-edit-dataset --operation.type=delete_episodes`")
    missing = missing_videos(root, info)
    if missing:
        shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
        raise DatasetError(f"{root} is missing {len(missing)} video file(s) its episodes point to ({shown}); "
                           f"{REPAIR}")
    check_videos(root, info)


def first_nonfinite(tables: dict[Path, pa.Table]) -> str | None:
    """Where the first NaN or Inf of the data tables' float columns is (file, column, episode and frame), or None."""
    import numpy as np
    import pyarrow as pa

    for path, table in tables.items():
        for name in table.column_names:
            column = table.column(name).combine_chunks()
            while pa.types.is_list(column.type) or pa.types.is_fixed_size_list(column.type):
                column = column.flatten()
            if not pa.types.is_floating(column.type):
                continue
            values = column.to_numpy(zero_copy_only=False)
            bad = np.flatnonzero(~np.isfinite(values))
            if len(bad):
                row = int(bad[0]) * table.num_rows // len(values)  # list columns: equal lengths per row
                where = ", ".join(f"{k} {table.column(k)[row].as_py()}" for k in ("episode_index", "frame_index")
                                  if k in table.column_names)
                return f"{path}, column {name!r}, {where} ({values[bad[0]]})"
    return None


def data_digests(root: Path) -> dict[str, str]:
    """Each data file's SHA-256, by its path in the dataset (kept in the sidecar when an episode is saved)."""
    import hashlib

    digests = {}
    for path in sorted((root / "data").rglob("*.parquet")):
        with open(path, "rb") as f:
            digests[str(path.relative_to(root))] = hashlib.file_digest(f, "sha256").hexdigest()
    return digests


def check_videos(root: Path, info: dict, episodes: list[int] | None = None) -> None:
    """Raise DatasetError unless every camera's video holds exactly its episodes' frames (of `episodes`, default
    all): a short video would shift every later image against its state and action."""
    wrong = video_mismatches(root, info, episodes)
    if wrong:
        shown = "; ".join(wrong[:3]) + (f"; and {len(wrong) - 3} more" if len(wrong) > 3 else "")
        raise DatasetError(f"{root}: {len(wrong)} video segment(s) do not hold their episode's frames ({shown}); "
                           f"the images no longer line up with the states and actions: {REPAIR}")


def video_frames(path: Path) -> int:
    """Frames in a video file, from its container's header (milliseconds; counts packets if the header lacks it)."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return stream.frames or sum(1 for packet in container.demux(stream) if packet.size)


def video_mismatches(root: Path, info: dict, episodes: list[int] | None = None) -> list[str]:
    """For each episode and camera, a line naming the file if the episode's video segment (its timestamps) or the
    file's frame count (the sum of the segments in it) differs from the episode's length."""
    import pyarrow.parquet as pq

    keys = [k for k, v in info["features"].items() if v["dtype"] == "video"]
    fps = info["fps"]
    rows: list[dict] = []
    for path in sorted((root / "meta" / "episodes").rglob("*.parquet")):
        rows += pq.read_table(path, columns=["episode_index", "length", *[
            f"videos/{k}/{c}" for k in keys for c in ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
        ]]).to_pylist()
    wrong = []
    for key in keys:
        files: dict[str, list[dict]] = {}
        for row in rows:
            rel = info["video_path"].format(video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
                                            file_index=row[f"videos/{key}/file_index"])
            files.setdefault(rel, []).append(row)
        camera = key.removeprefix("observation.images.")
        for rel, segments in files.items():
            if episodes is not None and not any(r["episode_index"] in episodes for r in segments):
                continue
            for r in segments:
                span = round((r[f"videos/{key}/to_timestamp"] - r[f"videos/{key}/from_timestamp"]) * fps)
                if span != r["length"]:
                    wrong.append(f"episode {r['episode_index']}, camera {camera}: its segment of {rel} spans {span} "
                                 f"frames for {r['length']} steps")
            held, wanted = video_frames(root / rel), sum(r["length"] for r in segments)
            if held != wanted:
                which = ", ".join(str(r["episode_index"]) for r in segments)
                wrong.append(f"episode{'s' if len(segments) > 1 else ''} {which}, camera {camera}: {rel} holds "
                             f"{held} frames for {wanted} steps")
    return wrong


def missing_videos(root: Path, info: dict) -> list[str]:
    """The video files the episodes' metadata points to that are not on disk."""
    import pyarrow.parquet as pq

    keys = [k for k, v in info["features"].items() if v["dtype"] == "video"]
    columns = [f"videos/{key}/{index}" for key in keys for index in ("chunk_index", "file_index")]
    wanted = set()
    for path in sorted((root / "meta" / "episodes").rglob("*.parquet")):
        table = pq.read_table(path, columns=columns).to_pydict()
        for key in keys:
            for chunk, file in zip(table[f"videos/{key}/chunk_index"], table[f"videos/{key}/file_index"]):
                wanted.add(info["video_path"].format(video_key=key, chunk_index=chunk, file_index=file))
    return sorted(p for p in wanted if not (root / p).is_file())


def verify_dataset(root: str | Path) -> dict:
    """Every check a reader runs on a dataset (after rolling back an interrupted save); returns its info."""
    from policy_composer.data.journal import recover

    root = Path(root)
    recover(root)
    info = read_info(root)
    check_files(root, info)
    return info


def open_dataset(root: str | Path, required: dict[str, tuple[int, ...] | None] | None = None,
                 fps: int | None = None, episodes: list[int] | None = None, **kwargs):
    """Check a local dataset, then load it with plain `LeRobotDataset(repo_id, root=...)` (offline)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = Path(root)
    info = verify_dataset(root)
    check_features(root, info, required or {}, fps)
    repo_id = read_sidecar(root).get("repo_id", f"local/{root.name}")
    return LeRobotDataset(repo_id, root=root, episodes=episodes, **kwargs)
