"""What a task's LeRobot dataset holds: its features, its metadata, and the checks of them a consumer runs before
it trusts one (`verify` checks the files and opens the dataset). Light: the recipes and the command line read it."""

from __future__ import annotations

import json
from pathlib import Path

from policy_composer.tasks.base import TaskSpec

LEROBOT_VERSION = "0.6.1"  # the release pyproject.toml pins; its datasets are of FORMAT_VERSION
FORMAT_VERSION = "v3.0"
SIDECAR = "meta/policy_composer.json"  # recipe, seeds, success and controller names per episode


def image_key(camera: str) -> str:
    return f"observation.images.{camera}"


# Bump when dataset_features changes: the main job's recording stages key on it, so no recording without a column
# the models need is reused.
FEATURES_REVISION = 5


def dataset_features(spec: TaskSpec, cameras: tuple[str, ...] | None = None, resolution: int = 128) -> dict[str, dict]:
    """LeRobot feature spec of a recording of the task: camera videos (default: all of the task's), joint state,
    action, what the robot knows of the episode's scene (where the task has it) and the per-frame labels."""
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
        **({"observation.environment_state": {"dtype": "float32", "shape": (len(spec.scene_names),),
                                              "names": list(spec.scene_names)}} if spec.scene_names else {}),
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
