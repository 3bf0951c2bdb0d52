"""`compose` and `library add`: the selector composes the library; a LeRobot checkpoint joins it."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from policy_composer.app.arguments import add_config_options, at_least, config_from
from policy_composer.app.cli.options import (
    WORLD,
    dataset_path,
    env_options,
    episode_workers,
    lerobot_source,
    library_sources,
    model_options,
    workers_option,
)
from policy_composer.selector.configuration import GOAL_SCORES, ComposeConfig
from policy_composer.tasks.registry import get_spec


def cmd_compose(args: argparse.Namespace) -> int:
    """The selector composes the whole library in GearAssembly-v1 rollouts (paper Table I, composed row)."""
    from policy_composer.app.composition import compose_library

    config = config_from(args, ComposeConfig)
    config = replace(config, max_steps=args.max_steps or get_spec(args.task).episode_steps or config.max_steps)
    episodes = compose_library(args.models, library_sources(args), config,
                               list(range(args.seed, args.seed + args.episodes)),
                               Path(args.out), videos=args.videos, resolution=args.resolution,
                               clearance_mm=args.clearance, knock_out_step=args.knock_out_step, resume=args.resume,
                               workers=episode_workers(args), goal_score=args.goal_score)
    ok = sum(e.success for e in episodes)
    print(f"composed: {ok}/{len(episodes)} full-task successes -> {Path(args.out) / 'summary.md'}")
    return 0


def cmd_library_add(args: argparse.Namespace) -> int:
    """A LeRobot checkpoint joins the library: its rollouts, its dynamics model, its Table I cell."""
    from policy_composer.app.adding import add_lerobot_controller

    source = lerobot_source(args.lerobot)
    added = add_lerobot_controller(source, args.rollouts, args.demos, args.models, args.episodes, args.trials,
                                   args.seed)
    for what, seconds in added["timings"].items():
        print(f"{what}: {seconds:.0f} s")
    print(f"{added['controller']} alone on {added['subtask']}: {added['cell']}")
    print(f"compose with it: policy-composer compose --models {args.models} --lerobot {args.lerobot}")
    return 0



def add_commands(sub) -> None:
    compose = sub.add_parser("compose", help="the selector composes the library in GearAssembly-v1 rollouts")
    env_options(compose, task=True)
    compose.add_argument("--episodes", type=at_least(1), default=10)
    compose.add_argument("--models", default=WORLD, help="world-model folder (train world-model, goal-score)")
    model_options(compose)
    add_config_options(compose, ComposeConfig, {"horizon": "horizon", "samples": "samples",
                                                "reselect_every": "reselect-every", "max_failures": "max-failures",
                                                "episode_failures": "episode-failures", "senses": "senses"})
    compose.add_argument("--max-steps", type=at_least(1), default=None,
                         help="control steps an episode may take (default: the task's episode limit, "
                              f"{ComposeConfig.max_steps} where it has none)")
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
    add.add_argument("--rollouts", default=dataset_path("gear-controller-rollouts"),
                     help="the library's rollouts dataset; its own settings are kept")
    add.add_argument("--demos", default=dataset_path("gear-full-task-demos"))
    add.add_argument("--models", default=WORLD, help="the world-model folder its dynamics model joins")
    add.add_argument("--episodes", type=at_least(1), default=20, help="its rollouts (for its dynamics model)")
    add.add_argument("--trials", type=at_least(1), default=20, help="its Table I trials on its subtask")
    add.add_argument("--seed", type=at_least(0), default=200, help="first seed of its Table I trials")
    add.set_defaults(func=cmd_library_add)
