"""A dataset's files checked before anything reads them, and the dataset opened.

Every consumer (the CNN policy, the VAE, the dynamics models, the goal scorers) opens its dataset through
`open_dataset`, so a wrong path, a missing camera or a feature of the wrong shape fails at once with an
error that names the dataset, what is missing and what was expected, not deep inside a training loop; damaged
files, values that are not finite and videos that do not hold their episodes' frames fail the same way.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import av
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from policy_composer.data.features import REPAIR, DatasetError, check_features, read_info, read_sidecar
from policy_composer.data.journal import recover


def check_files(root: Path, info: dict) -> None:
    """Raise DatasetError naming the first parquet file whose rows do not read or differ from what was recorded, the
    first value that is not finite, the video files that are missing, or the videos that do not hold their episodes'
    frames."""
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
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return stream.frames or sum(1 for packet in container.demux(stream) if packet.size)


def video_mismatches(root: Path, info: dict, episodes: list[int] | None = None) -> list[str]:
    """For each episode and camera, a line naming the file if the episode's video segment (its timestamps) or the
    file's frame count (the sum of the segments in it) differs from the episode's length."""
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
    root = Path(root)
    recover(root)
    info = read_info(root)
    check_files(root, info)
    return info


def open_dataset(root: str | Path, required: dict[str, tuple[int, ...] | None] | None = None,
                 fps: int | None = None, episodes: list[int] | None = None, **kwargs):
    """Check a local dataset, then load it with plain `LeRobotDataset(repo_id, root=...)` (offline)."""
    root = Path(root)
    info = verify_dataset(root)
    check_features(root, info, required or {}, fps)
    repo_id = read_sidecar(root).get("repo_id", f"local/{root.name}")
    return LeRobotDataset(repo_id, root=root, episodes=episodes, **kwargs)
