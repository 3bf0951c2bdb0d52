"""What several command groups share: the env flags, the library's model flags, default paths."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from safetensors import safe_open

from policy_composer.app.arguments import at_least, between
from policy_composer.policies.registry import LibraryError, kinds
from policy_composer.policies.sources import MODELS, LeRobotSource, LibrarySources
from policy_composer.tasks.gear_assembly.spec import CLEARANCE_MM, GRASP_OFFSET_MM, RESOLUTION, EnvSettings
from policy_composer.tasks.registry import DEFAULT_TASK, TASKS

DEFAULT_GRASP_OFFSET_MM = LibrarySources.max_grasp_offset * 1000  # the expert's and the pick-up's
WORLD = str(MODELS / "world")  # the world model and goal scorers' folder
# The command that trains each built-in kind's model, for the flags' help.
TRAIN_COMMANDS = {"dmp": "policy-composer train dmp", "cnn": "policy-composer train policy"}


def dataset_path(recipe: str) -> str:
    return str(Path("datasets") / recipe)


def library_sources(args: argparse.Namespace, task: str | None = None) -> LibrarySources:
    """The library of `task` (default: --task, or the default task), its model sources from the per-kind flags
    (`model_options`) and --lerobot."""
    lerobot = tuple(lerobot_source(spec) for spec in getattr(args, "lerobot", ()))
    named = [s.controller_name for s in lerobot]
    if len(set(named)) < len(named):
        raise LibraryError(f"--lerobot names controllers {', '.join(named)}: each needs a name of its own "
                           "(PATH:SUBTASK:NAME)")
    return LibrarySources(models={k.name: getattr(args, k.name) for k in kinds().values() if k.trained},
                          lerobot=lerobot,
                          max_grasp_offset=getattr(args, "grasp_offset", DEFAULT_GRASP_OFFSET_MM) / 1000.0,
                          gear_noise=getattr(args, "gear_noise", 0.0) / 1000.0,
                          insertion=getattr(args, "insertion", LibrarySources.insertion),
                          task=task or getattr(args, "task", None) or DEFAULT_TASK)


def lerobot_source(spec: str) -> LeRobotSource:
    """--lerobot PATH:SUBTASK[:NAME], checked before any work starts."""
    path, _, subtask = spec.rpartition(":")
    subtasks = tuple(dict.fromkeys(s for k in kinds().values() for s in k.subtasks))
    name = None
    if subtask not in subtasks and path.rpartition(":")[2] in subtasks:  # PATH:SUBTASK:NAME
        (path, _, subtask), name = path.rpartition(":"), subtask
    if not path or subtask not in subtasks:
        raise LibraryError(f"--lerobot {spec!r}: give PATH:SUBTASK or PATH:SUBTASK:NAME, SUBTASK one of "
                           f"{', '.join(subtasks)}")
    if name is not None and not name.isidentifier():
        raise LibraryError(f"--lerobot {spec!r}: the controller's name must be letters, digits and _, not {name!r}")
    if not (Path(path) / "config.json").is_file():
        raise LibraryError(f"--lerobot {spec!r}: no LeRobot policy checkpoint at {path} (expected the "
                           f"`pretrained_model` folder that lerobot-train saves, with its config.json)")
    check_readable(Path(path))
    return LeRobotSource(path, subtask, name)


def check_readable(path: Path) -> None:
    """A LeRobot checkpoint's config and weights files read (a damaged one is named before any work starts; loading
    the policy, later and in each worker, says more)."""
    fix = "train the policy again with lerobot-train, or restore the checkpoint from a copy"
    try:
        config = json.loads((path / "config.json").read_text())
        if not isinstance(config, dict) or "type" not in config:
            raise ValueError("no policy type in it")
    except (ValueError, UnicodeDecodeError) as e:
        raise LibraryError(f"{path / 'config.json'} is not a LeRobot policy config ({e}); {fix}") from None
    weights = path / "model.safetensors"
    try:
        with safe_open(str(weights), "pt") as f:
            f.keys()
    except Exception as e:  # safetensors' own error: a truncated or foreign file
        raise LibraryError(f"{weights} is not a readable safetensors file ({str(e)[:200]}); {fix}") from None


def insertion(value: str) -> str:
    """--insertion, checked by LibrarySources when given (not at every command's start: the check loads the
    controllers' module, and with it the simulator)."""
    try:
        LibrarySources(insertion=value)
    except LibraryError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return value


def make_env(obs_mode: str, args: argparse.Namespace, cameras: tuple[str, ...] | None = None, **kwargs):
    from policy_composer.tasks.gear_assembly.rollout import make_env

    return make_env(obs_mode, args.resolution, args.clearance, cameras, **kwargs)


def make_expert(env, args: argparse.Namespace):
    from policy_composer.tasks.gear_assembly.expert import ExpertConfig, GearAssemblyExpert

    return GearAssemblyExpert(env, ExpertConfig(grasp_offset=args.grasp_offset / 1000.0,
                                                closed_loop=not getattr(args, "open_loop", False)))


def training_threads(threads: int) -> None:
    """--threads, shared among the processes when `accelerate launch` runs the training data-parallel."""
    import torch

    from policy_composer.learning.training import threads_per_process

    torch.set_num_threads(threads_per_process(threads))



def env_options(p: argparse.ArgumentParser, grasp: bool = True, task: bool = False) -> None:
    """The env's settings and the first seed; with `task`, --task (a command that runs any task's library)."""
    p.add_argument("--resolution", type=between(*RESOLUTION, " pixels", int), default=EnvSettings.resolution,
                   help="camera width and height in pixels")
    p.add_argument("--clearance", type=between(*CLEARANCE_MM, " mm"), default=EnvSettings.clearance_mm,
                   help="radial clearance between peg and hole, mm")
    if grasp:
        p.add_argument("--grasp-offset", type=between(*GRASP_OFFSET_MM, " mm"), default=DEFAULT_GRASP_OFFSET_MM,
                       help="max grasp offset of the gear in the gripper, mm")
        p.add_argument("--gear-noise", type=between(0.0, 50.0, " mm"), default=0.0,
                       help="noise (standard deviation per axis in the table's plane, mm) on the gear position the "
                            "pick-up's planner is given, its one input from the simulator")
    p.add_argument("--seed", type=at_least(0), default=0, help="first seed")
    if task:
        p.add_argument("--task", default=DEFAULT_TASK, choices=tuple(TASKS),
                       help=f"the task whose library runs (default {DEFAULT_TASK}); settings it lacks are ignored")


def workers_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=at_least(1), default=None,
                   help="processes running episodes side by side, each with its own env (default: the usable "
                        "cores, or the Ray cluster's); the results are the same for any number")
    p.add_argument("--ray", metavar="ADDRESS", default=None, type=ray_address,
                   help="run the episodes on the Ray cluster at ADDRESS ('auto': the one this machine belongs to; "
                        "'local': a new one here); every node needs the project installed at the same path. The "
                        "results are the same as on this machine")


def ray_address(text: str) -> str:
    """--ray's value, its form checked before any work (whether a cluster answers there, when it is used)."""
    from policy_composer.app.workers import RAY_FORMS, ClusterError, ray_endpoint

    try:
        ray_endpoint(text)
    except ClusterError:
        raise argparse.ArgumentTypeError(f"must be {RAY_FORMS}, not {text!r}") from None
    return text


def episode_workers(args: argparse.Namespace) -> int:
    """The number of episode workers that `workers_option`'s flags ask for; with --ray, the episodes run on that
    cluster from now on."""
    from policy_composer.app.workers import usable_cores, use_ray

    cores = usable_cores() if args.ray is None else use_ray(args.ray)
    return args.workers or cores


def model_options(p: argparse.ArgumentParser) -> None:
    """--KIND for every registered kind that loads a trained model, and --lerobot checkpoints."""
    for kind in kinds().values():
        if kind.trained:
            trained_by = TRAIN_COMMANDS.get(kind.name, "its own training")
            p.add_argument(f"--{kind.name}", default=str(MODELS / kind.name), help=f"{kind.label} model ({trained_by})")
    p.add_argument("--insertion", type=insertion, default=LibrarySources.insertion,
                   help="how the MP and DMP insertions go down the peg: feel for the hole, trying offsets 4 mm apart "
                        "(ours), or straight down once, assuming a centred grasp (the paper's)")
    p.add_argument("--lerobot", action="append", default=[], metavar="PATH:SUBTASK[:NAME]",
                   help="a lerobot checkpoint as controller NAME (default lerobot_SUBTASK) for SUBTASK (it "
                        "needs its own dynamics model to be composed: `policy-composer library add`)")
