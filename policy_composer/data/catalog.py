"""Operations on a whole recorded dataset: summarise it (`dataset info`), describe it in a dataset card and share it
(`dataset push`)."""

from __future__ import annotations

import json
import re
import shutil
import urllib.error
import urllib.request
from importlib.metadata import version
from pathlib import Path

import pyarrow.parquet as pq
import rerun as rr
from huggingface_hub import constants
from lerobot.datasets.dataset_tools import delete_episodes
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.utils import DatasetInfo, create_lerobot_dataset_card
from lerobot.scripts.lerobot_dataset_viz import visualize_dataset

from policy_composer.data import journal
from policy_composer.data.features import SIDECAR, DatasetError, read_info, read_sidecar
from policy_composer.data.lock import one_writer
from policy_composer.data.recipes import RecipeError, load_recipe
from policy_composer.data.verify import data_digests, open_dataset, verify_dataset
from policy_composer.tasks.base import TaskSpec
from policy_composer.tasks.registry import DEFAULT_TASK, TASKS, get_spec

REPO_ID = re.compile(r"^[A-Za-z0-9][\w.-]*/[A-Za-z0-9][\w.-]*$")


class HubUnreachable(RuntimeError):
    pass


def _episode_success(root: Path, info: dict) -> list[bool] | None:
    """Per episode, whether its last frame is a success (None if the dataset has no `next.success`)."""
    if "next.success" not in info["features"]:
        return None
    last: dict[int, bool] = {}
    for path in sorted((root / "data").rglob("*.parquet")):
        table = pq.read_table(path, columns=["episode_index", "frame_index", "next.success"]).to_pydict()
        order = sorted(zip(table["episode_index"], table["frame_index"], table["next.success"]))
        for ep, _, ok in order:
            last[ep] = bool(ok)
    return [last[e] for e in sorted(last)]


def provenance(info: dict, sidecar: dict) -> str | None:
    """Why the project's own facts of a dataset (recipe, controller names, per-episode seeds) are missing or do not
    fit it; None when they do. LeRobot's edit tools (lerobot-edit-dataset) write new datasets without them."""
    if not sidecar:
        names = info["features"].get("observation.state", {}).get("names")
        spec = next((get_spec(t) for t in TASKS if list(get_spec(t).state_names) == names), None)
        if spec is not None:
            return (f"meta/policy_composer.json is missing: this {spec.env_id} recording was edited by a tool that "
                    "does not carry it (such as lerobot-edit-dataset), so its recipe and the names of its controllers "
                    "are unknown; copy the file from the dataset it came from to restore them")
        return "not recorded by policy-composer (no meta/policy_composer.json): only LeRobot's metadata is known"
    listed = len(sidecar.get("episodes", []))
    if listed != info["total_episodes"]:
        return (f"meta/policy_composer.json lists {listed} episodes but the dataset holds {info['total_episodes']} "
                "(it was edited by a tool that does not update the file): per-episode facts are not shown")
    return None


def summarize(root: str | Path) -> dict:
    """What `policy-composer dataset info` prints: size, features, cameras, fps, success rate, provenance."""
    root = Path(root)
    info = verify_dataset(root)
    sidecar = read_sidecar(root)
    features = info["features"]
    cameras = {k.removeprefix("observation.images."): tuple(v["shape"]) for k, v in features.items()
               if v["dtype"] in ("video", "image")}
    success = _episode_success(root, info)
    unfit = provenance(info, sidecar)
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
        "outcomes": {} if unfit else _outcomes(sidecar),
        "provenance": unfit,
        "robot_type": info.get("robot_type"),
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
    if summary["provenance"]:
        lines.append(f"  provenance:  {summary['provenance']}")
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
    intact = f"nothing was uploaded; the local dataset at {root} is intact"
    if constants.HF_HUB_OFFLINE:
        raise HubUnreachable(f"the Hugging Face Hub is unreachable: HF_HUB_OFFLINE=1 is set. Unset it on a machine "
                             f"with internet access and log in (`hf auth login`) to push; {intact}")
    try:
        urllib.request.urlopen(urllib.request.Request(constants.ENDPOINT, method="HEAD"), timeout=5)
    except urllib.error.HTTPError:
        pass  # the Hub answered
    except (urllib.error.URLError, OSError) as e:
        raise HubUnreachable(f"the Hugging Face Hub at {constants.ENDPOINT} is unreachable ({type(e).__name__}); "
                             f"{intact}") from None


CARD_TAGS = ["policy-composer", "maniskill"]  # and the task's name
# What the labels beside LeRobot's own features mean (the card says it to people who never read this project).
LABELS = {
    "progress": "frame index / (T - 1) in a successful episode, -1 in a failed one (the goal score's target)",
    "stage": "how far the task is at this frame",
    "controller": "which controller produced the frame's action: an index into `controllers` of "
                  "meta/policy_composer.json",
    "next.success": "the task is done after this frame's action",
    "next.done": "the episode's last frame",
}
PAPER = ("Composing Diverse Policies for Temporally Extended Tasks (Angelov, Hristov, Burke, Ramamoorthy, "
         "RA-L 2020)")
CITATION = """@article{angelov2020composing,
  title={Composing Diverse Policies for Temporally Extended Tasks},
  author={Angelov, Daniel and Hristov, Yordan and Burke, Michael and Ramamoorthy, Subramanian},
  journal={IEEE Robotics and Automation Letters},
  volume={5}, number={2}, pages={2658--2665}, year={2020}
}"""


def card_fields(root: str | Path) -> dict[str, str]:
    """The dataset card's description, paper and citation (LeRobot's card template fills them in): what the dataset
    holds (its recipe, task, cameras), what its labels mean, its success rate and the project version. A dataset
    this project did not record (or whose metadata an edit dropped) is described from LeRobot's metadata alone."""
    summary, sidecar = summarize(root), read_sidecar(root)
    if not sidecar:
        return {"dataset_description": _foreign_description(summary)}
    try:
        recipe = load_recipe(summary["recipe"]) if summary["recipe"] else None
    except RecipeError:  # a recipe of the user's own, not shipped with this version
        recipe = None
    env = sidecar.get("env", {})
    spec = dataset_spec(root)
    rate = summary["success_rate"]
    kept = [e["success"] for e in sidecar.get("episodes", [])] if not summary["provenance"] else []
    goal = (f" Each episode's goal, `{recipe.goal}`, was reached in {100 * sum(kept) / len(kept):.0f}% of them."
            if recipe is not None and recipe.goal != "success" and kept else "")
    lines = [f"Recorded with policy-composer {version('policy-composer')} in the ManiSkill task {spec.env_id} "
             f"({spec.card['scene']}), for a reproduction of *{PAPER}*.", ""]
    if summary["provenance"]:
        lines += [f"**Edited.** {summary['provenance']}.", ""]
    if recipe is not None:
        lines += [f"**Recipe `{recipe.name}`.** {recipe.description}", "", f"**Task.** {recipe.task}", ""]
    lines += [f"**Size.** {summary['episodes']} episodes, {summary['frames']} frames at {summary['fps']} fps; the "
              "task done in " + ("an unknown share of" if rate is None else f"{100 * rate:.0f}% of the") + " episodes."
              + goal + (f" Splits: {summary['splits']}." if "splits" in summary else ""), "",
              "**Cameras.** " + ", ".join(f"`observation.images.{c}` ({'x'.join(map(str, s))})"
                                         for c, s in summary["cameras"].items())
              + (f"; clearance between peg and hole {env['clearance_mm']} mm." if "clearance_mm" in env else "."), "",
              f"**State and action.** {spec.card['state_action']}.", "",
              "**Labels.**", *[f"- `{k}`: {v}{_for_task(k, spec)}" for k, v in LABELS.items()
                               if k in summary["features"]]]
    if summary["controllers"]:
        lines += ["", f"**Controllers.** {', '.join(summary['controllers'])}."]
    return {"dataset_description": "\n".join(lines), "paper": PAPER, "citation_bibtex": CITATION,
            "url": "policy-composer (see its README)"}


def _foreign_description(summary: dict) -> str:
    """What a dataset without the project's metadata holds, from LeRobot's own: no claim about how it was made."""
    rate = summary["success_rate"]
    lines = [f"A LeRobot dataset ({summary['format']}" + (f", robot type `{summary['robot_type']}`"
                                                         if summary["robot_type"] else "") + ").", "",
             f"**Provenance.** {summary['provenance']}.", "",
             f"**Size.** {summary['episodes']} episodes, {summary['frames']} frames at {summary['fps']} fps"
             + ("." if rate is None else f"; `next.success` at the end of {100 * rate:.0f}% of the episodes."), "",
             "**Cameras.** " + (", ".join(f"`observation.images.{c}` ({'x'.join(map(str, s))})"
                                          for c, s in summary["cameras"].items()) or "none") + ".", "",
             "**Features.**", *[f"- `{k}`: {dtype} {list(shape)}" for k, (dtype, shape) in summary["features"].items()]]
    return "\n".join(lines)


def dataset_card(root: str | Path, repo_id: str | None = None):
    """The card `dataset push` uploads, built offline (a huggingface_hub DatasetCard)."""
    return create_lerobot_dataset_card(tags=card_tags(root), dataset_info=DatasetInfo.from_dict(read_info(root)),
                                       license="apache-2.0", repo_id=repo_id, **card_fields(root))


def card_tags(root: str | Path) -> list[str]:
    """The project's tags on a card of its own recordings only (LeRobot adds its own tag to every card)."""
    return [*CARD_TAGS, dataset_spec(root).name] if read_sidecar(root) else []


def dataset_spec(root: str | Path) -> TaskSpec:
    """The task a recording of the project's was made in (its metadata says; before it did, the default task)."""
    return get_spec(read_sidecar(root).get("task_name", DEFAULT_TASK))


def _for_task(label: str, spec: TaskSpec) -> str:
    """What a label's values mean in the task, where it says (the stages, the success)."""
    words = {"stage": spec.card.get("stage"), "next.success": spec.card.get("success")}.get(label)
    return f" ({words})" if words else ""


def view_dataset(root: str | Path, episode: int, out: str | Path | None = None) -> Path | None:
    """LeRobot's viewer (rerun) on one episode of a recorded dataset: every camera, the state and the action as
    `lerobot-dataset-viz` shows them, and this project's labels (`progress`, `stage`, `controller`) beside them on
    the same timeline. Saved as an .rrd file in `out` (returned), or shown in a rerun viewer."""
    root = Path(root)
    journal.recover(root)
    info = read_info(root)
    if not 0 <= episode < info["total_episodes"]:
        raise DatasetError(f"{root} has episodes 0 to {info['total_episodes'] - 1}, not {episode}")
    dataset = LeRobotDataset(read_sidecar(root).get("repo_id", f"local/{root.name}"), root=root, episodes=[episode])
    path = visualize_dataset(dataset, episode, num_workers=0, save=out is not None,
                             output_dir=Path(out) if out is not None else None)
    labels = [k for k in ("progress", "stage", "controller") if k in info["features"]]
    frames = dataset.hf_dataset.select_columns(["frame_index", "timestamp", *labels])
    for row in frames:  # lerobot's viewer puts each frame at its frame_index and timestamp: the same timeline
        rr.set_time("frame_index", sequence=int(row["frame_index"]))
        rr.set_time("timestamp", timestamp=float(row["timestamp"]))
        for k in labels:
            rr.log(k, rr.Scalars(float(row[k])))
    rr.disconnect()  # flushes what was logged after lerobot saved the file
    return path


def push_dataset(root: str | Path, repo_id: str, private: bool = False, branch: str | None = None) -> str:
    """Upload a local dataset with LeRobotDataset.push_to_hub, with its card; returns the dataset's Hub URL."""
    root = Path(root)
    if not REPO_ID.match(repo_id):
        raise ValueError(f"--repo-id must look like USER/NAME (a Hugging Face dataset repo), not {repo_id!r}")
    journal.recover(root)
    read_info(root)  # a clear error if this is no dataset
    _check_hub_reachable(root)
    dataset = LeRobotDataset(repo_id, root=root)
    dataset.push_to_hub(branch=branch, private=private, tags=card_tags(root), **card_fields(root))
    return f"https://huggingface.co/datasets/{repo_id}"


def episode_controllers(root: Path, info: dict, sidecar: dict) -> list[str | None]:
    """Per episode, the controller it records: the one its rollout ran, or the one that produced all its frames
    (a demonstration's expert); None for an episode several controllers drove."""
    episodes, names = sidecar.get("episodes", []), sidecar.get("controllers", [])
    if all("controller_name" in e for e in episodes):
        return [e["controller_name"] for e in episodes]
    used: dict[int, set[int]] = {}
    if "controller" in info["features"]:
        for path in sorted((root / "data").rglob("*.parquet")):
            table = pq.read_table(path, columns=["episode_index", "controller"]).to_pydict()
            for ep, c in zip(table["episode_index"], table["controller"]):
                used.setdefault(ep, set()).add(c)
    return [e.get("controller_name") or (names[next(iter(used[i]))] if len(used.get(i, ())) == 1 else None)
            for i, e in enumerate(episodes)]


def drop_controller(root: str | Path, controller: str) -> int:
    """Remove one controller's episodes from a controller-rollouts dataset (to record them again after
    retraining it, with `record --resume`); returns how many were removed. LeRobot's `delete_episodes` writes
    the new dataset beside the old one, which is swapped in only once complete."""
    root = Path(root)
    with one_writer(root):
        return _drop_controller(root, controller)


def _drop_controller(root: Path, controller: str) -> int:
    journal.recover(root)
    info, sidecar = read_info(root), read_sidecar(root)
    unfit = provenance(info, sidecar)
    if unfit:
        raise DatasetError(f"cannot tell {root}'s episodes by controller: {unfit}")
    owners = episode_controllers(root, info, sidecar)
    drop = [i for i, owner in enumerate(owners) if owner == controller]
    if not drop:
        raise DatasetError(f"{root} has no episodes of controller {controller!r} (its episodes are "
                           f"{', '.join(sorted(set(owners) - {None})) or 'of several controllers each'}'s)")
    if len(drop) == len(owners):
        raise DatasetError(f"every episode of {root} is {controller}'s: dropping them would leave no dataset "
                           "(delete the folder instead)")
    new_root = root.with_name(root.name + ".dropping")
    shutil.rmtree(new_root, ignore_errors=True)
    delete_episodes(open_dataset(root), drop, output_dir=new_root, repo_id=sidecar.get("repo_id"))
    sidecar["episodes"] = [e for i, e in enumerate(sidecar["episodes"]) if i not in set(drop)]
    sidecar["data_digests"] = data_digests(new_root)
    (new_root / SIDECAR).write_text(json.dumps(sidecar, indent=1))
    old_root = root.with_name(root.name + ".dropped")
    root.rename(old_root)
    new_root.rename(root)
    shutil.rmtree(old_root)
    return len(drop)
