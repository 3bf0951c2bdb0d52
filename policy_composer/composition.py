"""`policy-composer compose`: composed episodes over many seeds, with their decision logs, a summary beside the
paper's composed row of Table I, and videos with the running controller and the goal score drawn on the frames."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np

from policy_composer.data import interrupt
from policy_composer.selector.compose import ComposedEpisode, compose_episode
from policy_composer.selector.configuration import ComposeConfig
from policy_composer.selector.world_model import GearWorldModel

PAPER_COMPOSED = "10/10"  # paper Table I: MP + CNN composed by the selector, full task


class VideoWriter:
    """Collects the world model's camera frames with the running controller and goal score written on them."""

    def __init__(self, camera: str, scale: int = 2):
        self.camera, self.scale, self.frames = camera, scale, []

    def __call__(self, obs, controller: str, score: float) -> None:
        from PIL import Image, ImageDraw

        rgb = obs["sensor_data"][self.camera]["rgb"][0].cpu().numpy()
        img = Image.fromarray(rgb).resize((rgb.shape[1] * self.scale, rgb.shape[0] * self.scale), Image.NEAREST)
        draw = ImageDraw.Draw(img)
        w = img.width
        draw.rectangle([0, 0, w, 22], fill=(0, 0, 0))
        draw.text((4, 5), f"{controller}   G = {score:.2f}", fill=(255, 255, 255))
        draw.rectangle([0, img.height - 6, int(w * score), img.height], fill=(60, 200, 90))
        self.frames.append(np.asarray(img))

    def save(self, path: Path, fps: int) -> Path:
        import imageio

        imageio.mimsave(path, self.frames, fps=fps, macro_block_size=1)
        return path


def compose_library(models: str | Path, sources, config: ComposeConfig, seeds: list[int], out: Path, videos: int = 1,
                    resolution: int = 128, clearance_mm: float = 2.0, knock_out_step: int | None = None,
                    resume: bool = False, progress: bool = True) -> list[ComposedEpisode]:
    """Load the world model in `models`, build every controller it has a dynamics model of from `sources`
    (a `LibrarySources`), and compose on each seed in an env with the cameras they all need."""
    import torch

    from policy_composer.policies.library import build_library, cameras_needed
    from policy_composer.tasks.rollout import make_env

    check_out(Path(out), resume)  # before any work: a finished run in `out` is never overwritten
    torch.set_num_threads(1)
    world = GearWorldModel.load(models)
    names = list(world.dynamics)
    cameras = tuple(dict.fromkeys((world.camera, *cameras_needed(names, sources))))
    env = make_env("rgb", resolution, clearance_mm, cameras, knock_out_step=knock_out_step)
    try:
        return run_composition(env, build_library(env, names, sources), world, config, seeds, out, videos, resume,
                               progress)
    finally:
        env.close()


def run_composition(env, library: dict, world: GearWorldModel, config: ComposeConfig, seeds: list[int], out: Path,
                    videos: int = 1, resume: bool = False, progress: bool = True) -> list[ComposedEpisode]:
    """Compose on each seed; write episodes.jsonl (decision logs), summary.md and the first `videos` videos.
    With `resume`, the episodes already in episodes.jsonl are kept and their seeds not run again."""
    from tqdm import tqdm

    check_out(out, resume)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "episodes.jsonl"
    done = {e.seed: e for e in load_episodes(out)} if resume else {}
    episodes = [done[s] for s in seeds if s in done]
    with open(path, "a" if resume else "w") as log:
        for i, seed in enumerate(tqdm(seeds, desc="composed episodes", unit="episode", disable=not progress)):
            if seed in done:
                continue
            video = VideoWriter(world.camera) if i < videos else None
            result = compose_episode(env, library, world, config, seed, on_frame=video)
            episodes.append(result)
            log.write(json.dumps(result.to_dict()) + "\n")
            log.flush()  # an interrupted run keeps every finished episode
            if video is not None:
                video.save(out / f"composed_seed{seed}.mp4", int(env.unwrapped.control_freq))
            interrupt.check()
    episodes.sort(key=lambda e: seeds.index(e.seed))
    (out / "summary.md").write_text(summary(episodes, config))
    return episodes


def check_out(out: Path, resume: bool) -> None:
    """Refuse to start a new run over the episodes of an earlier one (it would truncate them)."""
    earlier = [] if resume else load_episodes(out)
    if earlier:
        raise FileExistsError(f"{out} holds a composed run ({len(earlier)} episodes); continue it with "
                              f"--resume, or give another --out")


def load_episodes(out: Path) -> list[ComposedEpisode]:
    """The episodes a composed run wrote to `out`/episodes.jsonl (none if it has not written any)."""
    path = out / "episodes.jsonl"
    if not path.exists():
        return []
    return [ComposedEpisode.from_dict(json.loads(line)) for line in path.read_text().splitlines()]


def sequence_counts(episodes: list[ComposedEpisode]) -> list[tuple[str, int]]:
    """Each order in which the selector ran controllers, with how many episodes followed it, commonest first."""
    return Counter(" -> ".join(e.sequence) for e in episodes).most_common()


def back_offs(episodes: list[ComposedEpisode]) -> str:
    """How often a controller backed off with the gear, and how often the task was done anyway ("" if never)."""
    backed = [e for e in episodes if any(a.reason.startswith("backed off") for a in e.activations)]
    if not backed:
        return ""
    return (f"A controller backed off with the gear (instead of letting it go where its subtask fails) in "
            f"{len(backed)} episode{'s' * (len(backed) != 1)}; another controller then finished the task in "
            f"{sum(e.success for e in backed)}/{len(backed)}.")


def summary(episodes: list[ComposedEpisode], config: ComposeConfig) -> str:
    n, ok = len(episodes), sum(e.success for e in episodes)
    lines = ["# Composed controllers (the selector over the whole library)", "",
             f"Horizon n = {config.horizon}, K = {config.samples} samples per controller, decisions at termination"
             + (f" and every {config.reselect_every} steps" if config.reselect_every else "") + ".", "",
             "| | full task | paper |", "|---|---|---|", f"| composed | {ok}/{n} | {PAPER_COMPOSED} |", ""]
    knocked = [e for e in episodes if e.knocked_out]
    if knocked:
        lines += [f"Gear knocked out of the gripper in {len(knocked)} episodes; recovered (task still done) in "
                  f"{sum(e.success for e in knocked)}/{len(knocked)}.", ""]
    backed = back_offs(episodes)
    if backed:
        lines += [backed, ""]
    lines += ["## Controller sequences", "", "| sequence | episodes |", "|---|---|"]
    lines += [f"| {s} | {c} |" for s, c in sequence_counts(episodes)]
    failed = [e for e in episodes if not e.success]
    if failed:
        lines += ["", "## Failures", ""]
        for e in failed:
            last = e.activations[-1] if e.activations else None
            why = f"{last.controller}: {last.outcome} {last.reason}".strip() if last else "no controller could start"
            lines.append(f"- seed {e.seed}: {why} (sequence {' -> '.join(e.sequence) or '-'})")
    return "\n".join(lines) + "\n"
