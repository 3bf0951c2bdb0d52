"""`policy-composer evaluate goal-score`: each camera's goal scorer on held-out full-task demonstrations
(the paper's figure comparing head and forearm cameras), and the goal scorer of the VAE's latents if the world
model has one, as curves with the subtask boundaries marked and as a table of rank correlation with true progress
and mean absolute error."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import torch

from policy_composer.data import atomic
from policy_composer.data.features import image_key
from policy_composer.data.frames import episode_bounds, load_frames
from policy_composer.learning.checkpoint import trained_with
from policy_composer.selector.goal_score import TRAIN_HINT, goal_score_metrics, load_goal_score, load_latent_goal_score
from policy_composer.selector.train import demo_split, posteriors
from policy_composer.selector.vae import load_vae
from policy_composer.selector.world_model import check_trained_together

STAGES = ("pick", "move", "insert", "done")


def evaluate_goal_scores(models: str | Path, demos: str | Path, out: str | Path, cameras: tuple[str, ...],
                         progress: bool = True) -> dict[str, dict]:
    """Score the held-out demos with each camera's model (and the latent one: row "latent"); write
    goal_score.{png,csv,md} to `out`."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scorers = {c: load_goal_score(Path(models) / "goal_score" / c) for c in cameras}
    size = max(m.config.image_size for m in scorers.values())
    frames = load_frames(demos, cameras, size, demo_split(demos, "heldout"), progress=progress)
    curves, metrics = {}, {}
    for camera, model in scorers.items():
        curves[camera] = model.scores(frames[image_key(camera)])
        metrics[camera] = goal_score_metrics(curves[camera], frames["progress"], frames["episode_index"])
    latent = Path(models) / "goal_score" / "latent"
    if (latent / "config.json").is_file():
        check_trained_together(Path(models) / "vae", {latent: trained_with(latent, "latent goal score", TRAIN_HINT)})
        vae = load_vae(Path(models) / "vae")
        if vae.config.camera in cameras:  # the latents of the VAE's camera's frames
            curves["latent"] = load_latent_goal_score(latent).expected(
                posteriors(vae, frames[image_key(vae.config.camera)])[0])
            metrics["latent"] = goal_score_metrics(curves["latent"], frames["progress"], frames["episode_index"])
    _plot(curves, frames, out / "goal_score.png")
    with atomic.replacing(out / "goal_score.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["camera", "spearman", "mae", "episodes", "frames"])
        for camera, m in metrics.items():
            w.writerow([camera, f"{m['spearman']:.4f}", f"{m['mae']:.4f}", m["episodes"], m["frames"]])
    lines = ["# Goal score per camera (held-out full-task demonstrations)", "",
             "| camera | Spearman with true progress | mean abs. error |", "|---|---|---|"]
    lines += [f"| {c} | {m['spearman']:.3f} | {m['mae']:.3f} |" for c, m in metrics.items()]
    lines += ["", f"{next(iter(metrics.values()))['episodes']} held-out episodes; the figure is goal_score.png."]
    atomic.write_text(out / "goal_score.md", "\n".join(lines) + "\n")
    return metrics


def _plot(curves: dict[str, torch.Tensor], frames: dict[str, torch.Tensor], path: Path) -> None:
    matplotlib.use("Agg")
    bounds = episode_bounds(frames["episode_index"])
    fig, axes = plt.subplots(1, len(curves), figsize=(4.5 * len(curves), 3.4), sharey=True, squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (camera, scores) in zip(axes[0], curves.items()):
        for i, (a, b) in enumerate(bounds):
            t = torch.arange(b - a)
            color = colors[i % len(colors)]
            ax.plot(t, scores[a:b], color=color, lw=1.5, label=f"episode {int(frames['episode_index'][a])}")
            ax.plot(t, frames["progress"][a:b], color=color, lw=0.8, ls="--")
            stage = frames["stage"][a:b]
            for j in (stage[1:] != stage[:-1]).nonzero().flatten().tolist():
                ax.axvline(j + 1, color=color, lw=0.6, alpha=0.5)
                ax.text(j + 1, 1.02, STAGES[int(stage[j + 1])], rotation=90, fontsize=6, va="bottom", color=color)
        ax.set_title(camera if camera != "latent" else "latent (the VAE's camera)", pad=22)
        ax.set_xlabel("control step")
        ax.set_ylim(-0.05, 1.05)
    axes[0][0].set_ylabel("goal score (solid), true progress (dashed)")
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    with atomic.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
