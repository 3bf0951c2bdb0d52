"""`evaluate`: success rates of the expert and of each controller (Table I), and the goal scores."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from policy_composer.app.arguments import at_least, names, subset_of
from policy_composer.app.cli.options import (
    WORLD,
    dataset_path,
    env_options,
    episode_workers,
    library_sources,
    make_env,
    make_expert,
    model_options,
    workers_option,
)
from policy_composer.policies.registry import kinds
from policy_composer.selector.configuration import SENSES
from policy_composer.tasks.gear_assembly.spec import CAMERA_NAMES, SUBTASK_COLUMNS


def cmd_evaluate_expert(args: argparse.Namespace) -> int:
    """Full-task success of the scripted expert over many seeds (state observations: no rendering)."""
    from tqdm import tqdm

    from policy_composer.tasks.gear_assembly.rollout import run_episode

    env = make_env("state_dict", args)
    expert = make_expert(env, args)
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


def cmd_evaluate_controllers(args: argparse.Namespace) -> int:
    """Paper Table I, rows MP, DMP and CNN, and a row for each --lerobot checkpoint."""
    from policy_composer.app.controller_table import evaluate_table, paper_table, write_table

    rows = evaluate_table([k for k in args.kinds.split(",") if k], library_sources(args), args.trials, args.seed,
                          args.resolution, args.clearance, workers=episode_workers(args),
                          columns=args.subtasks, predicates=args.models if args.senses == "learned" else None)
    for kind, row in rows.items():
        print(f"{kind}: " + ", ".join(f"{c} {cell}" for c, cell in row.items()))
    print(f"table: {write_table(rows, Path(args.out), paper=paper_table(args.task))}")
    return 0


def cmd_evaluate_goal_score(args: argparse.Namespace) -> int:
    """Each camera's goal score on the held-out full-task demos: curves and rank correlation."""
    from policy_composer.selector.evaluate import evaluate_goal_scores

    metrics = evaluate_goal_scores(args.models, args.demos, args.out, args.cameras)
    for camera, m in metrics.items():
        print(f"{camera}: Spearman {m['spearman']:.3f}, mean abs. error {m['mae']:.3f} over {m['episodes']} episodes")
    print(f"figure: {Path(args.out) / 'goal_score.png'}")
    return 0



def add_commands(sub) -> None:
    evaluate = sub.add_parser("evaluate", help="measure success rates")
    ev_sub = evaluate.add_subparsers(dest="what", required=True)
    ev_expert = ev_sub.add_parser("expert", help="full-task success of the scripted expert")
    env_options(ev_expert)
    ev_expert.add_argument("--episodes", type=at_least(1), default=50)
    ev_expert.add_argument("--open-loop", action="store_true",
                           help="carry and insert assuming a centred grasp (shows why insertion needs feedback)")
    ev_expert.set_defaults(func=cmd_evaluate_expert)
    ev_ctrl = ev_sub.add_parser("controllers", help="each controller kind on each subtask (paper Table I)")
    env_options(ev_ctrl, task=True)
    labels = ",".join(k.label for k in kinds().values())
    ev_ctrl.add_argument("--trials", type=at_least(1), default=10)
    ev_ctrl.add_argument("--kinds", default=labels, help=f"comma-separated kinds (default: {labels}; '' for none: "
                                                          f"only the --lerobot checkpoints' rows)")
    ev_ctrl.add_argument("--subtasks", type=subset_of(SUBTASK_COLUMNS), default=SUBTASK_COLUMNS,
                         help=f"comma-separated columns to run (default: all, {','.join(SUBTASK_COLUMNS)})")
    model_options(ev_ctrl)
    ev_ctrl.add_argument("--senses", choices=SENSES, default="oracle",
                         help="where the controllers have the task's predicates from: the simulator's truth (default: "
                              "the oracle), or the classifiers in --models (learned)")
    ev_ctrl.add_argument("--models", default=WORLD, help="the world-model folder whose predicate classifiers the "
                         "controllers sense with (--senses learned)")
    ev_ctrl.add_argument("--out", default="results/controllers")
    workers_option(ev_ctrl)
    ev_ctrl.set_defaults(func=cmd_evaluate_controllers)

    ev_goal = ev_sub.add_parser("goal-score", help="each camera's goal score on held-out full-task demos")
    ev_goal.add_argument("--models", default=WORLD)
    ev_goal.add_argument("--demos", default=dataset_path("gear-full-task-demos"))
    ev_goal.add_argument("--cameras", type=names, default=",".join(CAMERA_NAMES))
    ev_goal.add_argument("--out", default="results/goal_score")
    ev_goal.set_defaults(func=cmd_evaluate_goal_score)
