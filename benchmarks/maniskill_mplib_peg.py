"""ManiSkill's own motion-planning solution for PegInsertionSide-v1, as a baseline row beside this project's figures:
the mplib-based `solve(env, seed, debug, vis)` shipped in mani-skill 3.0.1
(mani_skill/examples/motionplanning/panda/solutions/peg_insertion_side.py), imported and called as it is, on an env
made exactly as that solution's main() makes it (ManiSkill's default panda, pd_joint_pos), over a range of seeds.

Per seed: ManiSkill's success at the end, the strict success (ManiSkill's, with the peg's head no farther in than the
box's far face: ManiSkill issue 1391 notes its success counts a peg pushed past the hole), whether solve returned -1
(a planning failure) or raised, and the control steps it took. ManiSkill issue 993 reports that this solution fails
about a quarter of seeds: this script checks that figure, with Wilson 95% intervals. Whether a success held within
ManiSkill's default of 100 control steps is not recoverable after the fact, so the steps are reported instead.

Run: python benchmarks/maniskill_mplib_peg.py --seed 2000 --episodes 100
Needs mplib 0.1.1, mani-skill 3.0.1's own pin (the solution calls its API; mplib 0.2 changed set_base_pose and
plan_screw), and numpy<2 at run time: both mplib wheels' compiled module crashes (segfault) under numpy 2. The project
uses numpy 2.2, so lay numpy 1 (and a scipy that accepts it) over the environment for this script only:
  pip install --target /tmp/np1 --no-deps numpy==1.26.4 scipy==1.14.1
  PYTHONPATH=/tmp/np1 python benchmarks/maniskill_mplib_peg.py --seed 2000 --episodes 100
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import subprocess
import sys
import time

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (registers PegInsertionSide-v1)
from tqdm import tqdm

from policy_composer.app.stats import wilson
from policy_composer.tasks.peg_insertion_side.flags import strict_success

OVERLAY = "pip install --target /tmp/np1 --no-deps numpy==1.26.4 scipy==1.14.1, then run with PYTHONPATH=/tmp/np1"
# mplib's compiled module crashes the process under numpy 2, so a planner is built in a child process first
PROBE = ("import mplib; from mani_skill.agents.robots.panda import Panda as P; "
         "mplib.Planner(urdf=P.urdf_path, srdf=P.urdf_path.replace('.urdf', '.srdf'), move_group='panda_hand_tcp')")
DEFAULT_STEPS = 100  # ManiSkill's max_episode_steps for PegInsertionSide-v1


def give_up(line: str) -> None:
    print(line, file=sys.stderr)
    sys.exit(2)


def check_mplib() -> str:
    """mplib's version; or one line on stderr saying what to install, and exit code 2."""
    try:
        import mplib  # noqa: PLC0415  (optional, and needs numpy 1 laid over the environment)
    except ImportError:
        give_up("mplib is not installed: pip install --no-deps mplib==0.1.1 toppra (mani-skill 3.0.1's pin), and run "
                f"under numpy<2: {OVERLAY}")
    if "use_point_cloud" not in inspect.signature(mplib.Planner.plan_screw).parameters:
        give_up(f"mplib {mplib.__version__} is not the API ManiSkill 3.0.1's solution calls (mplib 0.2 changed "
                "set_base_pose and plan_screw): pip install --no-deps mplib==0.1.1")
    probe = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    if probe.returncode < 0:
        give_up(f"mplib crashed building a planner (its wheel is built against numpy 1): {OVERLAY}")
    if probe.returncode:
        give_up(f"mplib cannot build a planner here: {(probe.stderr.strip() or '?').splitlines()[-1]}")
    return mplib.__version__


def run_seed(solve, env, seed: int) -> dict:
    """One call of ManiSkill's solve on `seed`, and what the scene shows at its end."""
    error = ""
    try:
        res = solve(env, seed=seed, debug=False, vis=False)
    except Exception as e:  # mplib raises on some seeds
        res, error = -1, f"{type(e).__name__}: {(str(e).splitlines() or [''])[0][:60]}"
    u = env.unwrapped
    return {"seed": seed, "success": bool(u.evaluate()["success"][0]), "strict": bool(strict_success(env)[0]),
            "plan_failed": not error and isinstance(res, int) and res == -1, "error": error,
            "steps": int(u.elapsed_steps[0])}


def row(name: str, k: int, n: int) -> str:
    lo, hi = wilson(k, n)
    return f"| {name} | {k}/{n} | {100 * k / n:.0f}% | {100 * lo:.0f}-{100 * hi:.0f}% |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=2000)
    parser.add_argument("--episodes", type=int, default=100)
    args = parser.parse_args()
    seeds = range(args.seed, args.seed + args.episodes)
    version = check_mplib()
    # imports mplib: after check_mplib has said what is missing
    from mani_skill.examples.motionplanning.panda.solutions.peg_insertion_side import solve  # noqa: PLC0415

    # exactly as the solution's own main() makes it
    env = gym.make("PegInsertionSide-v1", obs_mode="none", control_mode="pd_joint_pos", render_mode="rgb_array",
                   reward_mode="dense")
    t0 = time.perf_counter()
    results = [run_seed(solve, env, seed) for seed in tqdm(seeds, desc="ManiSkill mplib solve", unit="episode")]
    wall = time.perf_counter() - t0
    env.close()

    n, strict = len(results), [r for r in results if r["strict"]]
    print(f"\n| ManiSkill's solution (mplib {version}), PegInsertionSide-v1 | k/n | rate | Wilson 95% CI |")
    print("|---|---|---|---|")
    print(row("ManiSkill's success", sum(r["success"] for r in results), n))
    print(row("strict success", len(strict), n))
    print(row("overshoot (ManiSkill's success, peg past the far face)",
              sum(r["success"] and not r["strict"] for r in results), n))
    print(row("solve returned -1 (planning failure)", sum(r["plan_failed"] for r in results), n))
    print(row("solve raised", sum(bool(r["error"]) for r in results), n))
    print(row(f"strict success in <= {DEFAULT_STEPS} steps", sum(r["steps"] <= DEFAULT_STEPS for r in strict), n))
    if strict:
        steps = [r["steps"] for r in strict]
        print(f"\nsteps of the strict successes: median {statistics.median(steps)}, max {max(steps)}; "
              f"{sum(s <= DEFAULT_STEPS for s in steps)}/{len(steps)} within ManiSkill's default {DEFAULT_STEPS}")
    failures = [r for r in results if not r["strict"]]
    if failures:
        print("\nfailures (not strict success):")
    for r in failures:
        why = r["error"] or ("solve returned -1" if r["plan_failed"] else
                             "peg past the far face" if r["success"] else "not inserted")
        print(f"  seed {r['seed']}: {why} (after {r['steps']} steps)")
    print(f"\nseeds {seeds.start}-{seeds.stop - 1}, {wall:.0f} s ({wall / n:.1f} s/episode)")


if __name__ == "__main__":
    main()
