"""PegInsertionSide-v1's first figures, on seeds no model was trained or tuned on: the scripted expert (strict
success, ManiSkill's success, overshoots, steps needed beside ManiSkill's default of 100), and the library's
motion-planning controllers through the full task (each subtask from where the one before left the scene), all with
Wilson 95% intervals.

Run: python benchmarks/peg_insertion_side.py [--seed 1000] [--episodes 100]
(The expert was tuned on seeds 0-299.)
"""

from __future__ import annotations

import argparse
import statistics
import time

from tqdm import tqdm

from policy_composer.app.stats import rate
from policy_composer.policies.arm import Outcome, run_activation
from policy_composer.policies.library import LibrarySources, build_library
from policy_composer.tasks.base import PlanningError
from policy_composer.tasks.peg_insertion_side.env import make_env, strict_success
from policy_composer.tasks.peg_insertion_side.expert import PegInsertionSideExpert, run_episode
from policy_composer.tasks.peg_insertion_side.spec import MAX_EPISODE_STEPS

LIMIT = 400  # control steps an episode may take here (ManiSkill's default is MAX_EPISODE_STEPS)


def expert_figures(seeds: range) -> None:
    env = make_env(obs_mode="state_dict", max_episode_steps=LIMIT)
    expert = PegInsertionSideExpert(env)
    results = [run_episode(env, expert, seed, LIMIT) for seed in tqdm(seeds, desc="expert", unit="episode")]
    n, steps = len(results), [r.steps for r in results if r.strict_success]
    within = sum(r.strict_success and r.steps <= MAX_EPISODE_STEPS for r in results)
    print(f"expert, strict success: {rate(sum(r.strict_success for r in results), n)}; ManiSkill's success: "
          f"{rate(sum(r.success for r in results), n)}; overshoots: {sum(r.overshoot for r in results)}")
    print(f"expert, strict success within ManiSkill's {MAX_EPISODE_STEPS} steps: {rate(within, n)}; steps of the "
          f"successes: median {statistics.median(steps)}, max {max(steps)}")
    env.close()


def planned_figures(seeds: range) -> None:
    env = make_env(obs_mode="state_dict", max_episode_steps=LIMIT)
    names = ("mp_pick", "mp_move", "mp_insert")
    library = build_library(env, names, LibrarySources(task="peg-insertion-side", max_grasp_offset=0.0))
    done = dict.fromkeys(names, 0)
    tried = dict.fromkeys(names, 0)
    full = 0
    for seed in tqdm(seeds, desc="MP, full task", unit="episode"):
        obs, _ = env.reset(seed=seed)
        for name in names:
            controller = library[name]
            if not controller.can_start(obs):
                break
            tried[name] += 1
            try:
                obs = run_activation(env, controller, obs, seed)
            except PlanningError:
                break
            if controller.outcome is not Outcome.DONE:
                break
            done[name] += 1
        full += bool(strict_success(env)[0])
    for name in names:
        print(f"{name}, from where the one before left the scene: {rate(done[name], tried[name])}")
    print(f"MP, full task (strict success): {rate(full, len(seeds))}")
    env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    seeds = range(args.seed, args.seed + args.episodes)
    t0 = time.perf_counter()
    expert_figures(seeds)
    planned_figures(seeds)
    print(f"seeds {seeds.start}-{seeds.stop - 1}, {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
