"""The paper's random-walk experiments: the selector composing five options with noisy tabular models.

Episodes run in lock-step so that each round's decisions for all live episodes are one batched call of the
selector; the options themselves run in the Gymnasium env, as controllers of the library.
"""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
from tqdm import tqdm

from policy_composer.data import atomic
from policy_composer.selector.core import Selector
from policy_composer.tasks.random_walk.controllers import RANDOM_WALK_OPTIONS, random_walk_controllers
from policy_composer.tasks.random_walk.env import RandomWalkEnv
from policy_composer.tasks.random_walk.models import TabularDynamics, TabularGoalScore, model_states

PAPER = {"planning_steps_19": 4, "heatmap_min": 8, "heatmap_max": 72, "optimal_100": 12, "low_noise_below": 20}


@dataclass(frozen=True)
class MDPConfig:
    num_states: int = 19
    start: int | None = None  # None: the middle state (see policy_composer.tasks.random_walk.env)
    p_dyn: float = 0.2  # probability that a dynamics prediction is a wrong state
    p_goal: float = 0.2  # probability that the goal score reports a wrong state's value
    # "step": p_dyn is per application of a dynamics model, so an n-step look-ahead errs with 1-(1-p)^n;
    # "lookahead": p_dyn is the probability that an n-step look-ahead contains a wrong prediction.
    dyn_noise_unit: str = "lookahead"
    horizon: int = 10  # n
    samples: int = 16  # K
    episodes: int = 1000
    seed: int = 0
    max_activations: int = 1000  # an episode still running after this many is counted as not converged


@dataclass
class MDPResult:
    config: MDPConfig
    activations: np.ndarray  # (E,) controller activations per episode
    success: np.ndarray  # (E,) reached N+1 (not 0, not the cap)
    trace: list[dict] = field(default_factory=list)  # episode 0, one record per planning step, if asked

    @property
    def mean_activations(self) -> float:
        """Mean activations over the episodes that reached the goal (the paper's "controllers used")."""
        return float(self.activations[self.success].mean()) if self.success.any() else float("nan")


def expected_activations(num_states: int, start: int, beta: float) -> float:
    """Activations of one rightward option with termination beta from `start` to N+1: 1 + (d-1) * beta."""
    return 1.0 + (num_states + 1 - start - 1) * beta


def per_step_noise(cfg: MDPConfig) -> float:
    if cfg.dyn_noise_unit == "step":
        return cfg.p_dyn
    if cfg.dyn_noise_unit == "lookahead":
        return 1.0 - (1.0 - cfg.p_dyn) ** (1.0 / cfg.horizon)
    raise ValueError(f"dyn_noise_unit must be 'step' or 'lookahead', not {cfg.dyn_noise_unit!r}")


def make_selector(cfg: MDPConfig, keep_predictions: bool = False) -> Selector:
    q = per_step_noise(cfg)
    dynamics = {o.name: TabularDynamics(o, cfg.num_states, q) for o in RANDOM_WALK_OPTIONS}
    return Selector(dynamics, TabularGoalScore(cfg.num_states, cfg.p_goal), horizon=cfg.horizon,
                    samples=cfg.samples, seed=cfg.seed, keep_predictions=keep_predictions)


def run_mdp(cfg: MDPConfig, trace: bool = False) -> MDPResult:
    """Run `cfg.episodes` episodes: choose a controller, run it until it terminates, choose again."""
    E = cfg.episodes
    envs = [RandomWalkEnv(cfg.num_states, cfg.start) for _ in range(E)]
    seeds = np.random.SeedSequence(cfg.seed).generate_state(E)
    libraries = [random_walk_controllers(cfg.num_states) for _ in range(E)]
    for lib, s in zip(libraries, seeds):
        for j, c in enumerate(lib):
            c.reset(None, seed=int(s) * 8 + j)
    states = np.array([env.reset(seed=int(s))[0] for env, s in zip(envs, seeds)])
    selector = make_selector(cfg, keep_predictions=trace)
    activations = np.zeros(E, dtype=np.int64)
    success = np.zeros(E, dtype=bool)
    alive = np.ones(E, dtype=bool)
    records = []
    while alive.any():
        idx = np.flatnonzero(alive)
        applicable = torch.tensor([[c.can_start(states[i]) for c in libraries[i]] for i in idx])
        decision = selector.decide(model_states(states[idx]), applicable)
        before = states[0]
        for j, i in enumerate(idx):
            controller = libraries[i][int(decision.choice[j])]
            controller.start(states[i])
            env, s = envs[i], states[i]
            while True:
                s, _, terminated, _, _ = env.step(controller.act(s))
                if terminated or controller.done(s):
                    break
            states[i] = s
            activations[i] += 1
            if terminated:
                alive[i] = False
                success[i] = s == env.goal
            elif activations[i] >= cfg.max_activations:
                alive[i] = False
        if trace and idx[0] == 0:
            predicted = decision.predicted[0, :, :, 0].float()  # (W, K) end positions
            records.append({"step": int(activations[0]), "state": int(before), "reached": int(states[0]),
                            **decision.log(0),
                            "predicted_mean": {n: float(p.mean()) for n, p in zip(decision.names, predicted)},
                            "predicted": {n: p.long().tolist() for n, p in zip(decision.names, predicted)}})
    return MDPResult(cfg, activations, success, records)


# --------------------------------------------------------------------------- experiments
def experiment_19(out: Path, episodes: int = 1000, seed: int = 0) -> dict:
    """19 states from state 1 at p = 0.2: planning steps to the goal, and the paper's "MDP solution" figure."""
    cfg = MDPConfig(num_states=19, start=1, p_dyn=0.2, p_goal=0.2, episodes=episodes, seed=seed)
    result = run_mdp(cfg, trace=True)
    per_step = run_mdp(replace(cfg, dyn_noise_unit="step"))
    exact = run_mdp(replace(cfg, p_dyn=0.0, p_goal=0.0))
    summary = {
        "config": asdict(cfg),
        "mean_planning_steps": result.mean_activations,
        "median_planning_steps": float(np.median(result.activations[result.success])),
        "success_rate": float(result.success.mean()),
        "mean_planning_steps_per_step_noise": per_step.mean_activations,
        "success_rate_per_step_noise": float(per_step.success.mean()),
        "mean_planning_steps_no_noise": exact.mean_activations,
        "analytic_best_controller": expected_activations(19, 1, RANDOM_WALK_OPTIONS[0].beta),
        "paper_planning_steps": PAPER["planning_steps_19"],
    }
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_text(out / "mdp19_trace.json", json.dumps(result.trace, indent=1))
    with atomic.replacing(out / "mdp19_episodes.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "activations", "success"])
        w.writerows(zip(range(len(result.activations)), result.activations.tolist(),
                        result.success.astype(int).tolist()))
    plot_solution(result.trace, 19, out / "mdp19_solution.png")
    atomic.write_text(out / "mdp19_summary.json", json.dumps(summary, indent=1))
    return summary


LEVELS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)


def heatmap_100(out: Path, levels: tuple[float, ...] = LEVELS, episodes: int = 100, seed: int = 0,
                dyn_noise_unit: str = "lookahead", progress: bool = True) -> dict:
    """100 states from the middle: mean activations to the goal over a grid of p_dyn x p_goal."""
    L = len(levels)
    mean = np.zeros((L, L))
    rate = np.zeros((L, L))
    rows = []
    bar = tqdm(total=L * L, desc=f"100-state noise grid ({dyn_noise_unit})", unit="cell", disable=not progress)
    for a, p_dyn in enumerate(levels):
        for b, p_goal in enumerate(levels):
            cfg = MDPConfig(num_states=100, p_dyn=p_dyn, p_goal=p_goal, episodes=episodes, seed=seed + 1000 * a + b,
                            dyn_noise_unit=dyn_noise_unit)
            r = run_mdp(cfg)
            mean[a, b], rate[a, b] = r.mean_activations, r.success.mean()
            rows.append({"p_dyn": p_dyn, "p_goal": p_goal, "mean_activations": mean[a, b],
                         "std_activations": float(r.activations[r.success].std()) if r.success.any() else float("nan"),
                         "success_rate": rate[a, b], "episodes": episodes})
            bar.update()
    bar.close()
    out.mkdir(parents=True, exist_ok=True)
    with atomic.replacing(out / f"mdp100_heatmap_{dyn_noise_unit}.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot_heatmap(mean, levels, out / f"mdp100_heatmap_{dyn_noise_unit}.png", dyn_noise_unit)
    claims = check_claims(mean, rate, levels)
    summary = {"dyn_noise_unit": dyn_noise_unit, "levels": list(levels), "episodes_per_cell": episodes,
               "mean_activations": mean.tolist(), "success_rate": rate.tolist(),
               "analytic_best_controller": expected_activations(100, 50, RANDOM_WALK_OPTIONS[0].beta),
               "claims": claims}
    atomic.write_text(out / f"mdp100_summary_{dyn_noise_unit}.json", json.dumps(summary, indent=1))
    return summary


def check_claims(mean: np.ndarray, rate: np.ndarray, levels: tuple[float, ...]) -> dict:
    """The paper's three statements about its heatmap, tested on ours (rows: p_dyn, columns: p_goal)."""
    lv = np.asarray(levels)
    # The largest noise level p such that every cell with p_dyn, p_goal <= p needs under 20 activations.
    stable = [p for p in lv if np.nanmax(mean[np.ix_(lv <= p, lv <= p)]) < 20]
    low_limit = float(max(stable)) if stable and stable[0] == lv[0] else None
    # Sensitivity: the rise in activations along each axis from the noiseless corner, averaged over levels.
    goal_rise = float(np.nanmean(mean[0, 1:] - mean[0, 0]))
    dyn_rise = float(np.nanmean(mean[1:, 0] - mean[0, 0]))
    return {
        "low_noise_under_20": {"holds": low_limit is not None and low_limit > 0, "up_to_p": low_limit},
        "more_sensitive_to_goal_noise": {"holds": goal_rise > dyn_rise, "mean_rise_goal_axis": goal_rise,
                                         "mean_rise_dynamics_axis": dyn_rise},
        "converges": {"holds": bool(rate.min() == 1.0), "min_success_rate": float(rate.min()),
                      "cell_of_min": [float(lv[i]) for i in np.unravel_index(rate.argmin(), rate.shape)]},
        "range": [float(np.nanmin(mean)), float(np.nanmax(mean))],
    }


# --------------------------------------------------------------------------- figures
def plot_solution(trace: list[dict], num_states: int, path: Path) -> None:
    """Paper Fig. "MDP solution": per planning step, each controller's predicted end state and the state reached."""
    matplotlib.use("Agg")
    names = [o.name for o in RANDOM_WALK_OPTIONS]
    colors = dict(zip(names, plt.get_cmap("tab10").colors))
    fig, ax = plt.subplots(figsize=(8, 0.9 + 0.7 * len(trace)))
    for k, rec in enumerate(trace):
        y = k + 1
        for j, n in enumerate(names):
            dy = (j - 2) * 0.1
            ax.vlines(rec["predicted_mean"][n], y - 0.3 + dy + 0.25, y + 0.05 + dy, color=colors[n], lw=3,
                      label=n if k == 0 else None)
        ax.plot([rec["state"], rec["reached"]], [y, y], color="red", lw=2, marker="o", ms=4,
                label="state reached (chosen controller run)" if k == 0 else None)
        ax.annotate(rec["choice"], (rec["reached"], y), textcoords="offset points", xytext=(6, 4), color="red",
                    fontsize=8)
    ax.set_xlim(-0.5, num_states + 1.5)
    ax.set_xticks(range(0, num_states + 2))
    ax.set_ylim(len(trace) + 0.8, 0.2)
    ax.set_xlabel(f"state (0 and {num_states + 1} terminal, +1 at {num_states + 1})")
    ax.set_ylabel("planning step")
    ax.set_title(f"{num_states}-state MDP: predicted end state of each controller (bars, mean of K rollouts) "
                 "and the state reached", fontsize=9)
    ax.legend(fontsize=7, loc="lower left", ncol=3)
    fig.tight_layout()
    with atomic.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


def plot_heatmap(mean: np.ndarray, levels: tuple[float, ...], path: Path, dyn_noise_unit: str) -> None:
    """Paper Fig. "Sensitivity to noise": mean activations to the goal, p_dyn x p_goal."""
    matplotlib.use("Agg")
    fig, ax = plt.subplots(figsize=(6, 5))
    im = ax.imshow(mean, cmap="magma", origin="upper")
    ax.set_xticks(range(len(levels)), [f"{p:.1f}" for p in levels])
    ax.set_yticks(range(len(levels)), [f"{p:.1f}" for p in levels])
    ax.set_xlabel("goal score noise p_goal")
    ax.set_ylabel(f"dynamics noise p_dyn (per {'look-ahead' if dyn_noise_unit == 'lookahead' else 'model step'})")
    for i in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            ax.text(j, i, f"{mean[i, j]:.0f}", ha="center", va="center", fontsize=7,
                    color="white" if mean[i, j] < np.nanmean(mean) else "black")
    fig.colorbar(im, ax=ax, label="mean controller activations to reach the goal")
    ax.set_title("100-state MDP: sensitivity to noise", fontsize=10)
    fig.tight_layout()
    with atomic.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------- report
def run_experiments(out: Path, episodes_19: int = 1000, episodes_100: int = 100,
                    noise_units: tuple[str, ...] = ("lookahead", "step"), seed: int = 0,
                    levels: tuple[float, ...] = LEVELS) -> tuple[dict, dict[str, dict]]:
    """Both experiments and their report (mdp_report.md); returns the 19-state summary and each heatmap's."""
    s19 = experiment_19(out, episodes=episodes_19, seed=seed)
    heatmaps = {unit: heatmap_100(out, levels, episodes_100, seed, dyn_noise_unit=unit) for unit in noise_units}
    write_report(out, s19, heatmaps)
    return s19, heatmaps


def write_report(out: Path, s19: dict, heatmaps: dict[str, dict]) -> Path:
    """mdp_report.md: our figures beside the paper's, and a verdict on each of its claims."""
    def yes(b: bool) -> str:
        return "agrees" if b else "**disagrees**"

    lines = ["# Random-walk MDP: ours beside the paper's", "",
             f"Selector: n = {s19['config']['horizon']}, K = {s19['config']['samples']}; controllers c1-c3 right "
             "(beta 0.2, 0.5, 0.9), c4 random (beta 0.5), c5 left (beta 0.5). A wrong prediction is a position drawn "
             "uniformly from the other states; `lookahead`: p_dyn is the chance that an n-step look-ahead contains "
             "one, `step`: the chance per model step.", "",
             "| figure | paper | ours |", "|---|---|---|",
             "| 19 states from state 1, p = 0.2: planning steps to the goal | "
             f"{PAPER['planning_steps_19']} (one run) | "
             f"mean {s19['mean_planning_steps']:.2f}, median {s19['median_planning_steps']:.0f} over "
             f"{s19['config']['episodes']} episodes; {100 * s19['success_rate']:.1f}% reach the goal "
             f"(the rest fall off at state 0) |",
             f"| the same, noise per model step | - | mean {s19['mean_planning_steps_per_step_noise']:.2f}; "
             f"{100 * s19['success_rate_per_step_noise']:.1f}% reach the goal |",
             f"| 19 states, no noise | - | {s19['mean_planning_steps_no_noise']:.2f} (analytic for c1: "
             f"{s19['analytic_best_controller']:.2f}) |"]
    for unit, h in heatmaps.items():
        mean = np.asarray(h["mean_activations"])
        c = h["claims"]
        lines += [
            f"| 100 states from state 50, no noise ({unit}) | {PAPER['optimal_100']} (\"optimal, policy 1\") | "
            f"{mean[0, 0]:.2f} (analytic for c1: {h['analytic_best_controller']:.2f}) |",
            f"| 100-state heatmap range ({unit}) | {PAPER['heatmap_min']} to {PAPER['heatmap_max']} | "
            f"{c['range'][0]:.1f} to {c['range'][1]:.1f} (cell means of {h['episodes_per_cell']} episodes) |"]
    lines += ["", "## The paper's claims, checked", ""]
    for unit, h in heatmaps.items():
        c = h["claims"]
        low = c["low_noise_under_20"]["up_to_p"]
        low_cells = ("even the noiseless cell needs 20 or more" if low is None else
                     "only the noiseless cell is under 20" if low == 0 else
                     f"every cell with p_dyn, p_goal <= {low} is under 20")
        lines += [f"With dynamics noise per {unit} (`mdp100_heatmap_{unit}.png`):", "",
                  f"- Low noise stays near optimal (under 20 activations): {yes(c['low_noise_under_20']['holds'])}"
                  f" ({low_cells}).",
                  "- More sensitive to goal-score noise than to dynamics noise: "
                  f"{yes(c['more_sensitive_to_goal_noise']['holds'])}"
                  f" (mean rise along the goal axis {c['more_sensitive_to_goal_noise']['mean_rise_goal_axis']:.1f}, "
                  f"along the dynamics axis {c['more_sensitive_to_goal_noise']['mean_rise_dynamics_axis']:.1f}).",
                  f"- Converges despite the noise: {yes(c['converges']['holds'])} ("
                  + ("every episode of every cell reaches the goal)." if c["converges"]["holds"] else
                     f"lowest share of episodes reaching the goal: {100 * c['converges']['min_success_rate']:.0f}% at "
                     f"p_dyn, p_goal = {c['converges']['cell_of_min']}).") , ""]
    path = out / "mdp_report.md"
    atomic.write_text(path, "\n".join(lines) + "\n")
    return path
