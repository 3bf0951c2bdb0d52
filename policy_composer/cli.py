"""The ``policy-composer`` command line."""

from __future__ import annotations

import argparse
import errno
import os
import sys
import time
from pathlib import Path

from policy_composer.arguments import add_config_options, at_least, between, config_from, subset_of
from policy_composer.data import atomic
from policy_composer.demo import PROFILES
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.configuration_dmp import FIT_EPISODES, FIT_FIRST_SEED
from policy_composer.policies.library import LeRobotSource, LibrarySources
from policy_composer.policies.registry import LibraryError, kinds
from policy_composer.selector.configuration import (
    GOAL_SCORES,
    ComposeConfig,
    DynamicsConfig,
    GoalScoreConfig,
    VAEConfig,
)
from policy_composer.tasks.spec import (
    CAMERA_NAMES,
    CLEARANCE_MM,
    GRASP_OFFSET_MM,
    RESOLUTION,
    SUBTASK_COLUMNS,
    EnvSettings,
)
from policy_composer.workers import usable_cores

DEFAULT_GRASP_OFFSET_MM = LibrarySources.max_grasp_offset * 1000  # the expert's and the pick-up's
MODELS = Path("results/models")
WORLD = str(MODELS / "world")  # the world model and goal scorers' folder
DISK_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)


def _dataset(recipe: str) -> str:
    return str(Path("datasets") / recipe)


def _sources(args: argparse.Namespace):
    """The library's model sources from the per-kind flags (`model_options`) and --lerobot."""
    return LibrarySources(models={k.name: getattr(args, k.name) for k in kinds().values() if k.model_path},
                          lerobot=tuple(_lerobot_source(spec) for spec in getattr(args, "lerobot", ())),
                          max_grasp_offset=getattr(args, "grasp_offset", DEFAULT_GRASP_OFFSET_MM) / 1000.0)


def _lerobot_source(spec: str) -> LeRobotSource:
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
    return LeRobotSource(path, subtask, name)


def _make_env(obs_mode: str, args: argparse.Namespace, cameras: tuple[str, ...] | None = None, **kwargs):
    from policy_composer.tasks.rollout import make_env

    return make_env(obs_mode, args.resolution, args.clearance, cameras, **kwargs)


def _expert(env, args: argparse.Namespace):
    from policy_composer.tasks.gear_expert import ExpertConfig, GearAssemblyExpert

    return GearAssemblyExpert(env, ExpertConfig(grasp_offset=args.grasp_offset / 1000.0,
                                                closed_loop=not getattr(args, "open_loop", False)))


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: the whole paper, stage by stage (finished stages are reused), then the report."""
    from policy_composer.demo import run_demo

    try:
        _, report = run_demo(args.profile, args.out, args.workers or usable_cores())
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished stages (and the episodes of an unfinished recording or composed run) are kept "
              f"in {Path(args.out) / 'pipeline'}; run the same command again to resume", file=sys.stderr)
        return 130
    print(f"report: {report} and {report.with_suffix('.html')} (open it in a browser)")
    return 0


def cmd_expert(args: argparse.Namespace) -> int:
    """Run the scripted expert on a few seeds, print each success and write an mp4 of the three cameras."""
    import imageio
    from tqdm import tqdm

    from policy_composer.tasks.rollout import episode_limit, run_episode

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = _make_env("rgb", args)
    expert = _expert(env, args)
    successes = 0
    for seed in range(args.seed, args.seed + args.episodes):
        with tqdm(total=episode_limit(env), desc=f"expert seed {seed}", unit="step", leave=False) as bar:
            result = run_episode(env, expert, seed, record_frames=True, on_step=lambda *_, bar=bar: bar.update())
        video = out / f"expert_seed{seed}.mp4"
        with atomic.replacing(video) as tmp:
            imageio.mimsave(tmp, result.frames, fps=int(env.unwrapped.control_freq), macro_block_size=1)
        successes += result.success
        print(f"seed {seed}: {'success' if result.success else 'FAILED'} in {result.steps} steps "
              f"(grasp offset {expert.grasp_offset * 1000:+.1f} mm, stage {result.stage}) -> {video}")
    print(f"expert success: {successes}/{args.episodes}")
    env.close()
    return 0 if successes == args.episodes else 1


def cmd_evaluate_expert(args: argparse.Namespace) -> int:
    """Full-task success of the scripted expert over many seeds (state observations: no rendering)."""
    from tqdm import tqdm

    from policy_composer.tasks.rollout import run_episode

    env = _make_env("state_dict", args)
    expert = _expert(env, args)
    failures = []
    t0 = time.time()
    for seed in tqdm(range(args.seed, args.seed + args.episodes), desc="expert", unit="episode"):
        if not run_episode(env, expert, seed).success:
            failures.append(seed)
    n = args.episodes
    mode = "open-loop insertion" if args.open_loop else "closed-loop insertion"
    print(f"expert ({mode}) full-task success: {n - len(failures)}/{n} = {100 * (n - len(failures)) / n:.1f}% "
          f"(grasp offset up to {args.grasp_offset:g} mm, clearance {args.clearance:g} mm, {time.time() - t0:.0f} s)")
    if failures:
        print(f"failed seeds: {failures}")
    env.close()
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    """Record a recipe's dataset (see datasets/recipes/) into a LeRobotDataset."""
    from dataclasses import replace

    from policy_composer.data.catalog import format_summary, summarize
    from policy_composer.data.features import read_sidecar
    from policy_composer.data.recipes import RecipeError, load_recipe
    from policy_composer.record import recipe_controllers, record_recipe

    recipe = load_recipe(args.recipe)
    sources = _sources(args)
    if args.controllers:
        chosen = tuple(args.controllers.split(","))
        known = (*recipe_controllers(recipe), *(s.controller_name for s in sources.lerobot))
        if recipe.driver != "controllers" or set(chosen) - set(known):
            raise RecipeError(f"--controllers must name controllers of recipe {recipe.name} or --lerobot ones "
                              f"({', '.join(known) or 'it runs none'}), not {', '.join(chosen)}")
        recipe = replace(recipe, controllers=chosen)
    root = Path(args.root) if args.root else Path("datasets") / recipe.name
    given = {k: v for k, v in (("resolution", args.resolution), ("clearance_mm", args.clearance)) if v is not None}
    previous = read_sidecar(root).get("env") if args.resume else None  # a flag not given keeps the dataset's value
    settings = replace(EnvSettings(**previous), **given) if previous else EnvSettings(**given)
    try:
        record_recipe(recipe, root, episodes=args.episodes, seed=args.seed, resume=args.resume, settings=settings,
                      sources=sources, workers=args.workers or usable_cores())
    except KeyboardInterrupt:
        print(f"\ninterrupted: every finished episode is saved in {root}; continue with --resume", file=sys.stderr)
        return 130
    print(format_summary(summarize(root)))
    return 0


def cmd_dataset_info(args: argparse.Namespace) -> int:
    from policy_composer.data.catalog import format_summary, summarize

    print(format_summary(summarize(args.path)))
    return 0


def cmd_dataset_card(args: argparse.Namespace) -> int:
    """The dataset card `dataset push` uploads, built offline: printed, or written to --out."""
    from policy_composer.data.catalog import dataset_card

    card = str(dataset_card(args.path, args.repo_id))
    if args.out:
        Path(args.out).write_text(card)
        print(f"wrote {args.out}")
    else:
        print(card)
    return 0


def cmd_dataset_view(args: argparse.Namespace) -> int:
    """LeRobot's rerun viewer on one episode, with the project's labels: saved to --out, or shown."""
    from policy_composer.data.catalog import view_dataset

    path = view_dataset(args.path, args.episode, args.out)
    if path is not None:
        print(f"wrote {path} (open it with `rerun {path}`)")
    return 0


def cmd_dataset_push(args: argparse.Namespace) -> int:
    from policy_composer.data.catalog import HubUnreachable, push_dataset

    try:
        url = push_dataset(args.path, args.repo_id, private=args.private, branch=args.branch)
    except (HubUnreachable, ValueError) as e:
        print(f"push failed: {e}", file=sys.stderr)
        return 2
    print(f"pushed {args.path} to {url}")
    return 0


def cmd_mdp(args: argparse.Namespace) -> int:
    """The paper's random-walk experiments: 19 states (planning steps, solution figure), 100 states (noise heatmap)."""
    from policy_composer import mdp

    t0 = time.time()
    units = ("lookahead", "step") if args.noise_unit == "both" else (args.noise_unit,)
    s19, heatmaps = mdp.run_experiments(Path(args.out), args.episodes_19, args.episodes_100, units, args.seed)
    print(f"19 states, p = 0.2: {s19['mean_planning_steps']:.2f} planning steps on average "
          f"(paper: {mdp.PAPER['planning_steps_19']}), {100 * s19['success_rate']:.1f}% reach the goal")
    for unit, h in heatmaps.items():
        c = h["claims"]
        print(f"100-state heatmap ({unit}): {c['range'][0]:.1f} to {c['range'][1]:.1f} "
              f"activations (paper: {mdp.PAPER['heatmap_min']} to {mdp.PAPER['heatmap_max']})")
    print(f"report: {Path(args.out) / 'mdp_report.md'} ({time.time() - t0:.0f} s)")
    return 0


def _training_threads(threads: int) -> None:
    """--threads, shared among the processes when `accelerate launch` runs the training data-parallel."""
    import torch

    from policy_composer.learning.training import threads_per_process

    torch.set_num_threads(threads_per_process(threads))


def cmd_train_policy(args: argparse.Namespace) -> int:
    """Behaviour-clone the CNN policy of one subtask on its demonstrations."""
    from policy_composer.policies.cnn.configuration_cnn import DEMONSTRATIONS
    from policy_composer.policies.cnn.train import train_cnn_policy

    _training_threads(args.threads)
    config = config_from(args, CNNPolicyConfig)
    dataset = args.dataset or _dataset(DEMONSTRATIONS[config.subtask][0])
    out = args.out or str(Path(kinds()["cnn"].model_path) / config.subtask)
    t0 = time.time()
    _, losses = train_cnn_policy(dataset, config, out=out)
    print(f"trained {out} in {time.time() - t0:.0f} s: nll {losses[0]:.3f} -> {losses[-1]:.3f} "
          f"over {len(losses)} epochs")
    return 0


def cmd_train_dmp(args: argparse.Namespace) -> int:
    """Fit the DMP library to the motion planner's trajectories."""
    from policy_composer.policies.dmp import fit_dmp_library

    env = _make_env("state_dict", args)
    t0 = time.time()
    library = fit_dmp_library(env, seeds=list(range(args.seed, args.seed + args.episodes)))
    library.save(args.out)
    env.close()
    print(f"fitted DMPs to {args.episodes} planner episodes in {time.time() - t0:.0f} s -> {args.out}")
    return 0


def cmd_evaluate_controllers(args: argparse.Namespace) -> int:
    """Paper Table I, rows MP, DMP and CNN, and a row for each --lerobot checkpoint."""
    from policy_composer.controller_table import evaluate_table, write_table

    rows = evaluate_table([k for k in args.kinds.split(",") if k], _sources(args), args.trials, args.seed,
                          args.resolution, args.clearance, workers=args.workers or usable_cores(),
                          columns=args.subtasks)
    for kind, row in rows.items():
        print(f"{kind}: " + ", ".join(f"{c} {cell}" for c, cell in row.items()))
    print(f"table: {write_table(rows, Path(args.out))}")
    return 0


def cmd_train_world_model(args: argparse.Namespace) -> int:
    """The VAE and one dynamics model per controller (paper: Controller Dynamics Modelling)."""
    from policy_composer.selector.train import train_world_model

    _training_threads(args.threads)
    timings = train_world_model(
        args.rollouts, args.demos, args.out, config_from(args, VAEConfig), config_from(args, DynamicsConfig),
        controllers=args.controllers.split(",") if args.controllers else None, reuse_vae=args.reuse_vae)
    for what, seconds in timings.items():
        print(f"trained {what} in {seconds:.0f} s")
    return 0


def cmd_train_goal_score(args: argparse.Namespace) -> int:
    """One goal scorer per camera on the training full-task demos (paper: Goal Score Evaluation)."""
    from policy_composer.selector.train import train_goal_scores

    _training_threads(args.threads)
    config = config_from(args, GoalScoreConfig)
    for what, seconds in train_goal_scores(args.demos, args.out, tuple(args.cameras.split(",")), config).items():
        print(f"trained {what} in {seconds:.0f} s")
    return 0


def cmd_evaluate_goal_score(args: argparse.Namespace) -> int:
    """Each camera's goal score on the held-out full-task demos: curves and rank correlation."""
    from policy_composer.selector.evaluate import evaluate_goal_scores

    metrics = evaluate_goal_scores(args.models, args.demos, args.out, tuple(args.cameras.split(",")))
    for camera, m in metrics.items():
        print(f"{camera}: Spearman {m['spearman']:.3f}, mean abs. error {m['mae']:.3f} over {m['episodes']} episodes")
    print(f"figure: {Path(args.out) / 'goal_score.png'}")
    return 0


def cmd_compose(args: argparse.Namespace) -> int:
    """The selector composes the whole library in GearAssembly-v1 rollouts (paper Table I, composed row)."""
    from policy_composer.composition import compose_library

    episodes = compose_library(args.models, _sources(args), config_from(args, ComposeConfig),
                               list(range(args.seed, args.seed + args.episodes)),
                               Path(args.out), videos=args.videos, resolution=args.resolution,
                               clearance_mm=args.clearance, knock_out_step=args.knock_out_step, resume=args.resume,
                               workers=args.workers or usable_cores(), goal_score=args.goal_score)
    ok = sum(e.success for e in episodes)
    print(f"composed: {ok}/{len(episodes)} full-task successes -> {Path(args.out) / 'summary.md'}")
    return 0


def cmd_library_add(args: argparse.Namespace) -> int:
    """A LeRobot checkpoint joins the library: its rollouts, its dynamics model, its Table I cell."""
    from policy_composer.adding import add_lerobot_controller

    source = _lerobot_source(args.lerobot)
    added = add_lerobot_controller(source, args.rollouts, args.demos, args.models, args.episodes, args.trials,
                                   args.seed)
    for what, seconds in added["timings"].items():
        print(f"{what}: {seconds:.0f} s")
    print(f"{added['controller']} alone on {added['subtask']}: {added['cell']}")
    print(f"compose with it: policy-composer compose --models {args.models} --lerobot {args.lerobot}")
    return 0


def cmd_dataset_drop(args: argparse.Namespace) -> int:
    """Remove a controller's rollouts (then record them again with `record gear-controller-rollouts --resume`)."""
    from policy_composer.data.catalog import drop_controller

    print(f"removed {drop_controller(args.path, args.controller)} episodes of {args.controller} from {args.path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="policy-composer", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    cameras = ",".join(CAMERA_NAMES)

    def env_options(p: argparse.ArgumentParser, grasp: bool = True) -> None:
        p.add_argument("--resolution", type=between(*RESOLUTION, " pixels", int), default=EnvSettings.resolution,
                       help="camera width and height in pixels")
        p.add_argument("--clearance", type=between(*CLEARANCE_MM, " mm"), default=EnvSettings.clearance_mm,
                       help="radial clearance between peg and hole, mm")
        if grasp:
            p.add_argument("--grasp-offset", type=between(*GRASP_OFFSET_MM, " mm"), default=DEFAULT_GRASP_OFFSET_MM,
                           help="max grasp offset of the gear in the gripper, mm")
        p.add_argument("--seed", type=at_least(0), default=0, help="first seed")

    def workers_option(p: argparse.ArgumentParser) -> None:
        p.add_argument("--workers", type=at_least(1), default=None,
                       help="processes running episodes side by side, each with its own env (default: the usable "
                            "cores); the results are the same for any number")

    def model_options(p: argparse.ArgumentParser) -> None:
        """--KIND for every registered kind that loads a trained model, and --lerobot checkpoints."""
        for kind in kinds().values():
            if kind.model_path:
                p.add_argument(f"--{kind.name}", default=kind.model_path,
                               help=f"{kind.label} model ({kind.train_command})")
        p.add_argument("--lerobot", action="append", default=[], metavar="PATH:SUBTASK[:NAME]",
                       help="a lerobot checkpoint as controller NAME (default lerobot_SUBTASK) for SUBTASK (it "
                            "needs its own dynamics model to be composed: `policy-composer library add`)")

    demo = sub.add_parser("demo", help="the main job: record, train, evaluate, compose, the MDP, the report")
    demo.add_argument("--profile", default="quick", choices=tuple(PROFILES),
                      help="quick: 30 min on 2 CPU cores; paper: the paper's sizes; smoke: every stage, tiny (tests)")
    demo.add_argument("--out", default="results", help="report.md, report.html and the stages' outputs (pipeline/)")
    workers_option(demo)
    demo.set_defaults(func=cmd_demo)
    expert = sub.add_parser("expert", help="the scripted expert on a few seeds, with videos of the three cameras")
    env_options(expert)
    expert.add_argument("--episodes", type=at_least(1), default=3)
    expert.add_argument("--out", default="results/expert", help="folder for the videos")
    expert.set_defaults(func=cmd_expert)

    evaluate = sub.add_parser("evaluate", help="measure success rates")
    ev_sub = evaluate.add_subparsers(dest="what", required=True)
    ev_expert = ev_sub.add_parser("expert", help="full-task success of the scripted expert")
    env_options(ev_expert)
    ev_expert.add_argument("--episodes", type=at_least(1), default=50)
    ev_expert.add_argument("--open-loop", action="store_true",
                           help="carry and insert assuming a centred grasp (shows why insertion needs feedback)")
    ev_expert.set_defaults(func=cmd_evaluate_expert)
    ev_ctrl = ev_sub.add_parser("controllers", help="each controller kind on each subtask (paper Table I)")
    env_options(ev_ctrl)
    labels = ",".join(k.label for k in kinds().values())
    ev_ctrl.add_argument("--trials", type=at_least(1), default=10)
    ev_ctrl.add_argument("--kinds", default=labels, help=f"comma-separated kinds (default: {labels}; '' for none: "
                                                          f"only the --lerobot checkpoints' rows)")
    ev_ctrl.add_argument("--subtasks", type=subset_of(SUBTASK_COLUMNS), default=SUBTASK_COLUMNS,
                         help=f"comma-separated columns to run (default: all, {','.join(SUBTASK_COLUMNS)})")
    model_options(ev_ctrl)
    ev_ctrl.add_argument("--out", default="results/controllers")
    workers_option(ev_ctrl)
    ev_ctrl.set_defaults(func=cmd_evaluate_controllers)

    train = sub.add_parser("train", help="train the library's learned controllers")
    tr_sub = train.add_subparsers(dest="what", required=True)
    tr_policy = tr_sub.add_parser("policy", help="behaviour-clone a CNN + MDN policy (cnn_pick, cnn_move, cnn_insert)")
    tr_policy.add_argument("--dataset", help="its demonstrations (default: datasets/gear-insertion-demos for the "
                           "insertion, datasets/gear-transport-demos for the pick-up and the move)")
    add_config_options(tr_policy, CNNPolicyConfig, {
        "subtask": "subtask", "camera": "camera", "backbone": "backbone", "epochs": "epochs",
        "image_size": "image-size", "num_mixtures": "mixtures", "action_space": "action-space",
        "proprioception": "proprioception", "shift": "shift", "batch_size": "batch-size", "seed": "seed"})
    tr_policy.add_argument("--threads", type=at_least(1), default=2)
    tr_policy.add_argument("--out", help=f"checkpoint folder (default: {kinds()['cnn'].model_path}/SUBTASK, where the "
                           "library's CNN model looks)")
    tr_policy.set_defaults(func=cmd_train_policy)
    tr_dmp = tr_sub.add_parser("dmp", help="fit the DMPs to the motion planner's trajectories")
    env_options(tr_dmp, grasp=False)
    tr_dmp.add_argument("--episodes", type=at_least(1), default=FIT_EPISODES, help="planner episodes to fit to")
    tr_dmp.set_defaults(seed=FIT_FIRST_SEED)
    tr_dmp.add_argument("--out", default=kinds()["dmp"].model_path)
    tr_dmp.set_defaults(func=cmd_train_dmp)

    tr_world = tr_sub.add_parser("world-model", help="the VAE and one latent dynamics model per controller")
    tr_world.add_argument("--rollouts", default=_dataset("gear-controller-rollouts"))
    tr_world.add_argument("--demos", default=_dataset("gear-full-task-demos"))
    add_config_options(tr_world, VAEConfig, {"camera": "camera", "image_size": "image-size", "latent_dim": "latent-dim",
                                             "epochs": "vae-epochs"})
    add_config_options(tr_world, DynamicsConfig, {"epochs": "dynamics-epochs", "frame_skip": "frame-skip",
                                                  "num_mixtures": "mixtures"})
    tr_world.add_argument("--controllers", default=None, help="comma-separated (default: every controller recorded)")
    tr_world.add_argument("--reuse-vae", action="store_true", help="keep the VAE in --out; train only dynamics models")
    tr_world.add_argument("--threads", type=at_least(1), default=2)
    tr_world.add_argument("--out", default=WORLD)
    tr_world.set_defaults(func=cmd_train_world_model)
    tr_goal = tr_sub.add_parser("goal-score", help="one goal scorer per camera on the full-task demos")
    tr_goal.add_argument("--demos", default=_dataset("gear-full-task-demos"))
    tr_goal.add_argument("--cameras", default=cameras)
    add_config_options(tr_goal, GoalScoreConfig, {"epochs": "epochs", "image_size": "image-size",
                                                  "num_mixtures": "mixtures"})
    tr_goal.add_argument("--threads", type=at_least(1), default=2)
    tr_goal.add_argument("--out", default=WORLD, help="the world-model folder (its VAE, if any, is used)")
    tr_goal.set_defaults(func=cmd_train_goal_score)

    ev_goal = ev_sub.add_parser("goal-score", help="each camera's goal score on held-out full-task demos")
    ev_goal.add_argument("--models", default=WORLD)
    ev_goal.add_argument("--demos", default=_dataset("gear-full-task-demos"))
    ev_goal.add_argument("--cameras", default=cameras)
    ev_goal.add_argument("--out", default="results/goal_score")
    ev_goal.set_defaults(func=cmd_evaluate_goal_score)

    compose = sub.add_parser("compose", help="the selector composes the library in GearAssembly-v1 rollouts")
    env_options(compose)
    compose.add_argument("--episodes", type=at_least(1), default=10)
    compose.add_argument("--models", default=WORLD, help="world-model folder (train world-model, goal-score)")
    model_options(compose)
    add_config_options(compose, ComposeConfig, {"horizon": "horizon", "samples": "samples",
                                                "reselect_every": "reselect-every", "max_failures": "max-failures",
                                                "episode_failures": "episode-failures"})
    compose.add_argument("--knock-out-step", type=at_least(0), default=None,
                         help="perturbation: knock the gear out of the gripper at this control step "
                              "(or when next lifted)")
    compose.add_argument("--goal-score", choices=GOAL_SCORES, default="image",
                         help="what the selector's goal score reads: each predicted latent decoded to an image "
                              "(default), or the latent itself (about 10x faster decisions)")
    compose.add_argument("--videos", type=at_least(0), default=1, help="episodes to write a video of")
    compose.add_argument("--resume", action="store_true",
                         help="keep the episodes already in --out; run the other seeds")
    compose.add_argument("--out", default="results/compose")
    workers_option(compose)
    compose.set_defaults(func=cmd_compose)

    library = sub.add_parser("library", help="grow the library of controllers")
    lib_sub = library.add_subparsers(dest="library_command", required=True)
    add = lib_sub.add_parser("add", help="a LeRobot checkpoint joins the library: its rollouts, its dynamics model "
                                         "and its Table I cell, after which `compose --lerobot` chooses it")
    add.add_argument("--lerobot", required=True, metavar="PATH:SUBTASK[:NAME]",
                     help="the `pretrained_model` folder lerobot-train saved, the subtask it does, and the "
                          "controller's name (default lerobot_SUBTASK)")
    add.add_argument("--rollouts", default=_dataset("gear-controller-rollouts"),
                     help="the library's rollouts dataset; its own settings are kept")
    add.add_argument("--demos", default=_dataset("gear-full-task-demos"))
    add.add_argument("--models", default=WORLD, help="the world-model folder its dynamics model joins")
    add.add_argument("--episodes", type=at_least(1), default=20, help="its rollouts (for its dynamics model)")
    add.add_argument("--trials", type=at_least(1), default=20, help="its Table I trials on its subtask")
    add.add_argument("--seed", type=at_least(0), default=200, help="first seed of its Table I trials")
    add.set_defaults(func=cmd_library_add)

    record = sub.add_parser("record", help="record a dataset recipe (datasets/recipes/) into a LeRobotDataset")
    record.add_argument("recipe", help="recipe name (gear-insertion-demos, gear-full-task-demos, "
                                       "gear-controller-rollouts) or path of a .toml recipe")
    record.add_argument("--episodes", type=at_least(1), default=None,
                        help="episodes the dataset should hold (default: the recipe's)")
    record.add_argument("--root", default=None, help="dataset folder (default: datasets/RECIPE)")
    record.add_argument("--resume", action="store_true", help="continue an interrupted or shorter recording")
    env_options(record, grasp=False)
    record.set_defaults(resolution=None, clearance=None, seed=None)  # not given: the defaults, or the resumed dataset's
    record.add_argument("--controllers", default=None,
                        help="comma-separated subset of the recipe's controllers to record "
                             "(recipes that run the controllers)")
    model_options(record)
    workers_option(record)
    record.set_defaults(func=cmd_record)

    mdp = sub.add_parser("mdp", help="the paper's random-walk MDP experiments (19 and 100 states)")
    mdp.add_argument("--out", default="results/mdp")
    mdp.add_argument("--episodes-19", type=at_least(1), default=1000, help="episodes of the 19-state experiment")
    mdp.add_argument("--episodes-100", type=at_least(1), default=100, help="episodes per heatmap cell")
    mdp.add_argument("--noise-unit", choices=("lookahead", "step", "both"), default="both",
                     help="dynamics noise per n-step look-ahead, per model step, or both heatmaps")
    mdp.add_argument("--seed", type=at_least(0), default=0)
    mdp.set_defaults(func=cmd_mdp)

    dataset = sub.add_parser("dataset", help="inspect and share recorded LeRobot datasets")
    ds_sub = dataset.add_subparsers(dest="what", required=True)
    info = ds_sub.add_parser("info", help="episodes, frames, features, cameras, fps, success rate")
    info.add_argument("path")
    info.set_defaults(func=cmd_dataset_info)
    drop = ds_sub.add_parser("drop", help="remove one controller's episodes from a controller-rollouts dataset")
    drop.add_argument("path")
    drop.add_argument("--controller", required=True)
    drop.set_defaults(func=cmd_dataset_drop)
    view = ds_sub.add_parser("view", help="LeRobot's rerun viewer on one episode, with the labels (progress, stage, "
                             "controller)")
    view.add_argument("path")
    view.add_argument("--episode", type=at_least(0), default=0)
    view.add_argument("--out", default=None, help="save an .rrd file in this folder instead of opening the viewer")
    view.set_defaults(func=cmd_dataset_view)
    card = ds_sub.add_parser("card", help="the dataset card `push` uploads (recipe, task, cameras, labels, success)")
    card.add_argument("path")
    card.add_argument("--repo-id", default=None, help="USER/NAME the card will link to")
    card.add_argument("--out", default=None, help="write it to this file (default: print it)")
    card.set_defaults(func=cmd_dataset_card)
    push = ds_sub.add_parser("push", help="upload to the Hugging Face Hub with LeRobotDataset.push_to_hub, with "
                             "its dataset card")
    push.add_argument("path")
    push.add_argument("--repo-id", required=True, help="USER/NAME of the Hub dataset repo")
    push.add_argument("--private", action="store_true")
    push.add_argument("--branch", default=None)
    push.set_defaults(func=cmd_dataset_push)
    return parser


def main(argv: list[str] | None = None) -> int:
    from policy_composer.composition import RunError
    from policy_composer.data.features import DatasetError
    from policy_composer.data.interrupt import flag_interrupts
    from policy_composer.data.lock import FolderBusy
    from policy_composer.data.recipes import RecipeError
    from policy_composer.learning.checkpoint import CheckpointError

    args = build_parser().parse_args(argv)
    if args.func is not cmd_dataset_push:  # everything but an upload works offline
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
    try:
        with flag_interrupts():  # a Ctrl-C swallowed by a library is raised again at the next episode or stage
            return args.func(args)
    except (DatasetError, RecipeError, CheckpointError, LibraryError, RunError, FolderBusy, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # the disk, not the program: one line, and the fix
        if e.errno not in DISK_ERRORS:
            raise
        print(f"error: cannot write {e.filename or 'the output'}: {e.strerror or e}; free some space or write "
              "elsewhere (--root, --out); what was saved before is intact", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
