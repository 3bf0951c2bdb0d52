"""The paper's runs end to end: the main job, the scripted expert, the random-walk MDP."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from policy_composer.app.arguments import at_least
from policy_composer.app.cli.options import env_options, episode_workers, make_env, make_expert, workers_option
from policy_composer.app.profiles import PROFILES
from policy_composer.data import atomic
from policy_composer.tasks.registry import DEFAULT_TASK, TASKS


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job: the whole paper, stage by stage (finished stages are reused), then the report."""
    from policy_composer.app.demo import run_demo

    out = args.out or ("results" if args.task == DEFAULT_TASK else f"results-{args.task}")
    try:
        _, report = run_demo(args.profile, out, episode_workers(args), args.task)
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished stages (and the episodes of an unfinished recording or composed run) are kept "
              f"in {Path(out) / 'pipeline'}; run the same command again to resume", file=sys.stderr)
        return 130
    print(f"report: {report} and {report.with_suffix('.html')} (open it in a browser)")
    return 0


def cmd_expert(args: argparse.Namespace) -> int:
    """Run the scripted expert on a few seeds, print each success and write an mp4 of the three cameras."""
    import imageio
    from tqdm import tqdm

    from policy_composer.tasks.gear_assembly.rollout import episode_limit, run_episode

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = make_env("rgb", args)
    expert = make_expert(env, args)
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


def cmd_mdp(args: argparse.Namespace) -> int:
    """The paper's random-walk experiments: 19 states (planning steps, solution figure), 100 states (noise heatmap)."""
    from policy_composer.app import mdp

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



def add_commands(sub) -> None:
    demo = sub.add_parser("demo", help="the main job: record, train, evaluate, compose, the MDP, the report")
    demo.add_argument("--profile", default="quick", choices=tuple(PROFILES),
                      help="quick: 30 min on 2 CPU cores; paper: the paper's sizes; smoke: every stage, tiny (tests)")
    demo.add_argument("--out", help="report.md, report.html and the stages' outputs (pipeline/); default: results, "
                      "or results-TASK for a task other than the default")
    demo.add_argument("--task", default=DEFAULT_TASK, choices=tuple(TASKS),
                      help=f"the task the paper's method composes (default {DEFAULT_TASK})")
    workers_option(demo)
    demo.set_defaults(func=cmd_demo)
    expert = sub.add_parser("expert", help="the scripted expert on a few seeds, with videos of the three cameras")
    env_options(expert)
    expert.add_argument("--episodes", type=at_least(1), default=3)
    expert.add_argument("--out", default="results/expert", help="folder for the videos")
    expert.set_defaults(func=cmd_expert)

    mdp = sub.add_parser("mdp", help="the paper's random-walk MDP experiments (19 and 100 states)")
    mdp.add_argument("--out", default="results/mdp")
    mdp.add_argument("--episodes-19", type=at_least(1), default=1000, help="episodes of the 19-state experiment")
    mdp.add_argument("--episodes-100", type=at_least(1), default=100, help="episodes per heatmap cell")
    mdp.add_argument("--noise-unit", choices=("lookahead", "step", "both"), default="both",
                     help="dynamics noise per n-step look-ahead, per model step, or both heatmaps")
    mdp.add_argument("--seed", type=at_least(0), default=0)
    mdp.set_defaults(func=cmd_mdp)
