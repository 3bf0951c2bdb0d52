"""Operations on a whole recorded dataset: summarise it (`dataset info`) and share it (`dataset push`)."""

from __future__ import annotations

import re
from pathlib import Path

from policy_composer.data import journal
from policy_composer.data.features import DatasetError, check_files, read_info, read_sidecar

REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*$")


class HubUnreachable(RuntimeError):
    pass


def _episode_success(root: Path, info: dict) -> list[bool] | None:
    """Per episode, whether its last frame is a success (None if the dataset has no `next.success`)."""
    if "next.success" not in info["features"]:
        return None
    import pyarrow.parquet as pq

    last: dict[int, bool] = {}
    for path in sorted((root / "data").rglob("*.parquet")):
        table = pq.read_table(path, columns=["episode_index", "frame_index", "next.success"]).to_pydict()
        order = sorted(zip(table["episode_index"], table["frame_index"], table["next.success"]))
        for ep, _, ok in order:
            last[ep] = bool(ok)
    return [last[e] for e in sorted(last)]


def summarize(root: str | Path) -> dict:
    """What `policy-composer dataset info` prints: size, features, cameras, fps, success rate, provenance."""
    root = Path(root)
    journal.recover(root)
    info = read_info(root)
    check_files(root, info)
    sidecar = read_sidecar(root)
    features = info["features"]
    cameras = {k.removeprefix("observation.images."): tuple(v["shape"]) for k, v in features.items()
               if v["dtype"] in ("video", "image")}
    success = _episode_success(root, info)
    summary = {
        "path": str(root),
        "repo_id": sidecar.get("repo_id", f"local/{root.name}"),
        "format": info["codebase_version"],
        "episodes": info["total_episodes"],
        "frames": info["total_frames"],
        "fps": info["fps"],
        "cameras": cameras,
        "features": {k: (v["dtype"], tuple(v["shape"])) for k, v in features.items()},
        "success_rate": None if not success else sum(success) / len(success),
        "recipe": sidecar.get("recipe"),
        "controllers": sidecar.get("controllers"),
        "outcomes": _outcomes(sidecar),
    }
    if sidecar.get("train_episodes") is not None:
        n = min(sidecar["train_episodes"], info["total_episodes"])
        summary["splits"] = {"train": f"0:{n}", "heldout": f"{n}:{info['total_episodes']}"}
    return summary


def _outcomes(sidecar: dict) -> dict[str, dict[str, int]]:
    """Per controller, how its recorded activations ended (datasets recorded with the controllers driver)."""
    outcomes: dict[str, dict[str, int]] = {}
    for e in sidecar.get("episodes", []):
        if "controller_name" in e:
            counts = outcomes.setdefault(e["controller_name"], {})
            counts[e["outcome"]] = counts.get(e["outcome"], 0) + 1
    return outcomes


def format_summary(summary: dict) -> str:
    lines = [f"{summary['path']}  (LeRobotDataset {summary['format']}, repo_id {summary['repo_id']})"]
    if summary["recipe"]:
        lines.append(f"  recipe:      {summary['recipe']}")
    lines.append(f"  episodes:    {summary['episodes']}   frames: {summary['frames']}   fps: {summary['fps']}")
    rate = summary["success_rate"]
    lines.append(f"  task done:   {'unknown (no next.success)' if rate is None else f'{100 * rate:.0f}%'} of episodes")
    for name, counts in summary.get("outcomes", {}).items():
        lines.append(f"  {name + ':':12s} " + ", ".join(f"{n} {outcome}" for outcome, n in counts.items()))
    if "splits" in summary:
        lines.append("  splits:      " + ", ".join(f"{k} {v}" for k, v in summary["splits"].items()))
    lines.append("  cameras:     " + ", ".join(f"{c} {'x'.join(map(str, s))}" for c, s in summary["cameras"].items()))
    if summary["controllers"]:
        lines.append(f"  controllers: {', '.join(summary['controllers'])}")
    lines.append("  features:")
    lines += [f"    {k:34s} {dtype:8s} {shape}" for k, (dtype, shape) in summary["features"].items()]
    return "\n".join(lines)


def _check_hub_reachable(root: Path) -> None:
    from huggingface_hub import constants

    intact = f"nothing was uploaded; the local dataset at {root} is intact"
    if constants.HF_HUB_OFFLINE:
        raise HubUnreachable(f"the Hugging Face Hub is unreachable: HF_HUB_OFFLINE=1 is set. Unset it on a machine "
                             f"with internet access and log in (`hf auth login`) to push; {intact}")
    import urllib.error
    import urllib.request

    try:
        urllib.request.urlopen(urllib.request.Request(constants.ENDPOINT, method="HEAD"), timeout=5)
    except urllib.error.HTTPError:
        pass  # the Hub answered
    except (urllib.error.URLError, OSError) as e:
        raise HubUnreachable(f"the Hugging Face Hub at {constants.ENDPOINT} is unreachable ({type(e).__name__}); "
                             f"{intact}") from None


def push_dataset(root: str | Path, repo_id: str, private: bool = False, branch: str | None = None) -> str:
    """Upload a local dataset with LeRobotDataset.push_to_hub; returns the dataset's Hub URL."""
    root = Path(root)
    if not REPO_ID.match(repo_id):
        raise ValueError(f"--repo-id must look like USER/NAME (a Hugging Face dataset repo), not {repo_id!r}")
    journal.recover(root)
    read_info(root)  # a clear error if this is no dataset
    _check_hub_reachable(root)
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(repo_id, root=root)
    dataset.push_to_hub(branch=branch, private=private, tags=["policy-composer", "maniskill", "gear-assembly"])
    return f"https://huggingface.co/datasets/{repo_id}"


def drop_controller(root: str | Path, controller: str) -> int:
    """Remove one controller's episodes from a controller-rollouts dataset (to record them again after
    retraining it, with `record --resume`); returns how many were removed. LeRobot's `delete_episodes` writes
    the new dataset beside the old one, which is swapped in only once complete."""
    import json
    import shutil

    from lerobot.datasets.dataset_tools import delete_episodes

    from policy_composer.data.features import SIDECAR, open_dataset

    root = Path(root)
    sidecar = read_sidecar(root)
    drop = [i for i, e in enumerate(sidecar.get("episodes", [])) if e.get("controller_name") == controller]
    if not drop:
        raise DatasetError(f"{root} has no episodes of controller {controller!r} (it has "
                           f"{sorted({e.get('controller_name') for e in sidecar.get('episodes', [])} - {None})})")
    new_root = root.with_name(root.name + ".dropping")
    shutil.rmtree(new_root, ignore_errors=True)
    delete_episodes(open_dataset(root), drop, output_dir=new_root, repo_id=sidecar.get("repo_id"))
    sidecar["episodes"] = [e for i, e in enumerate(sidecar["episodes"]) if i not in set(drop)]
    (new_root / SIDECAR).write_text(json.dumps(sidecar, indent=1))
    old_root = root.with_name(root.name + ".dropped")
    root.rename(old_root)
    new_root.rename(root)
    shutil.rmtree(old_root)
    return len(drop)
