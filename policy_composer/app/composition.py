"""`policy-composer compose`: composed episodes over many seeds, with their decision logs, a summary beside the
paper's composed row of Table I, and videos with the running controller and the goal score drawn on the frames."""

from __future__ import annotations

import errno
import json
from collections import Counter
from dataclasses import asdict
from functools import partial
from pathlib import Path

import imageio
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import torch
from PIL import Image, ImageDraw
from tqdm import tqdm

from policy_composer.app.errors import RunError
from policy_composer.app.stats import rate
from policy_composer.app.workers import in_process, run_episodes
from policy_composer.data import atomic, interrupt
from policy_composer.data.lock import one_writer
from policy_composer.data.verify import video_frames
from policy_composer.policies.library import build_library, cameras_needed, check_models, model_ids
from policy_composer.selector.compose import ComposedEpisode, compose_episode
from policy_composer.selector.configuration import ComposeConfig
from policy_composer.selector.world_model import WorldModel
from policy_composer.tasks.registry import DEFAULT_TASK

PAPER_COMPOSED = "10/10"  # paper Table I: MP + CNN composed by the selector, full task
MILESTONES = ("picked", "at the pre-insertion pose", "seated")  # the full task's subtasks done, in order


class VideoWriter:
    """Collects the world model's camera frames with the running controller and goal score written on them."""

    def __init__(self, camera: str, scale: int = 2):
        self.camera, self.scale, self.frames = camera, scale, []
        self.trace: list[tuple[str, float]] = []  # per step: the running controller and the goal score

    def __call__(self, obs, controller: str, score: float) -> None:
        self.trace.append((controller, score))
        rgb = obs["sensor_data"][self.camera]["rgb"][0].cpu().numpy()
        img = Image.fromarray(rgb).resize((rgb.shape[1] * self.scale, rgb.shape[0] * self.scale), Image.NEAREST)
        draw = ImageDraw.Draw(img)
        w = img.width
        draw.rectangle([0, 0, w, 22], fill=(0, 0, 0))
        draw.text((4, 5), f"{controller}   G = {score:.2f}", fill=(255, 255, 255))
        draw.rectangle([0, img.height - 6, int(w * score), img.height], fill=(60, 200, 90))
        self.frames.append(np.asarray(img))

    def save(self, path: Path, fps: int) -> Path:
        with atomic.replacing(path) as tmp:
            imageio.mimsave(tmp, self.frames, fps=fps, macro_block_size=1)
            try:  # the encoder can fail without a word (ffmpeg on a full disk): only a whole video goes in place
                written = video_frames(tmp)
            except Exception:  # noqa: BLE001  (any decoder error means the same: not a whole video)
                written = 0
            if written != len(self.frames):
                raise OSError(errno.EIO, f"the video holds {written} of its {len(self.frames)} frames (is the disk "
                              "full?); nothing was put in its place", str(path))
        return path


def plot_goal_score(trace: list[tuple[str, float]], seed: int, path: Path) -> Path:
    """The paper's figure of a composed trial: the goal score of each step's image, coloured by the running
    controller."""
    matplotlib.use("Agg")
    names = list(dict.fromkeys(name for name, _ in trace))
    colors = dict(zip(names, plt.get_cmap("tab10").colors))
    fig, ax = plt.subplots(figsize=(8, 3))
    start = 0
    for end in [k for k in range(1, len(trace)) if trace[k][0] != trace[k - 1][0]] + [len(trace)]:
        name = trace[start][0]
        ax.plot(range(start, end + (end < len(trace))), [g for _, g in trace[start:end + 1]], color=colors[name],
                lw=2, label=name if name not in ax.get_legend_handles_labels()[1] else None)
        start = end
    ax.set_ylim(0, 1)
    ax.set_xlabel("control step")
    ax.set_ylabel("goal score")
    ax.set_title(f"Composed trial, seed {seed}: the goal score and the controller the selector ran", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    with atomic.replacing(path) as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return path


class Composer:
    """Composed episodes in one process: the world model, the env with the cameras they all need and the library,
    built once. Called with a seed, runs its episode (and writes its video if it is one of `video_seeds`)."""

    def __init__(self, models: str | Path, sources, config: ComposeConfig, resolution: int = 128,
                 clearance_mm: float = 2.0, knock_out_step: int | None = None, out: Path | None = None,
                 video_seeds: tuple[int, ...] = (), world=None, goal_score: str = "image"):
        # given: loaded in this process
        self.world = world if world is not None else WorldModel.load(models, goal_score=goal_score,
                                                                     predicates=config.senses == "learned")
        names = list(self.world.dynamics)
        cameras = tuple(dict.fromkeys((*self.world.cameras(config.senses), *cameras_needed(names, sources))))
        task = sources.description
        knock_out = {"knock_out_step": knock_out_step} if knock_out_step is not None else {}
        self.env = task.make_env("rgb", task.settings(resolution, clearance_mm=clearance_mm), cameras, **knock_out)
        self.library = build_library(self.env, names, sources, self.world.senses(self.env, config.senses))
        self.config, self.out, self.video_seeds = config, out, video_seeds

    def __call__(self, seed: int) -> ComposedEpisode:
        video = VideoWriter(self.world.camera) if seed in self.video_seeds else None
        result = compose_episode(self.env, self.library, self.world, self.config, seed, on_frame=video)
        if video is not None:
            video.save(self.out / f"composed_seed{seed}.mp4", int(self.env.unwrapped.control_freq))
            if video.trace:
                plot_goal_score(video.trace, seed, self.out / f"composed_seed{seed}_goal_score.png")
        return result

    def close(self) -> None:
        self.env.close()


def compose_library(models: str | Path, sources, config: ComposeConfig, seeds: list[int], out: Path, videos: int = 1,
                    resolution: int = 128, clearance_mm: float = 2.0, knock_out_step: int | None = None,
                    resume: bool = False, progress: bool = True, workers: int = 1,
                    goal_score: str = "image") -> list[ComposedEpisode]:
    """Load the world model in `models` with its `goal_score` ("image" or "latent", see WorldModel.load), build
    every controller it has a dynamics model of from `sources`
    (a `LibrarySources`), and compose on each seed (spread over `workers` processes); writes episodes.jsonl
    (decision logs), summary.md and the videos of the first `videos` seeds. With `resume`, the episodes already
    in episodes.jsonl are kept and their seeds not run again."""
    out = Path(out)
    with one_writer(out):  # a second run into it stops at once
        check_out(out, resume)  # first: a finished run in `out` is refused before anything loads
        torch.set_num_threads(1)
        world = WorldModel.load(models, goal_score=goal_score, predicates=config.senses == "learned")
        if world.vae.config.task != sources.task:
            raise RunError(f"the world model in {models} was trained for {world.vae.config.task}, not "
                           f"{sources.task}: compose it with --task {world.vae.config.task}")
        check_models(list(world.dynamics), sources)
        ids = model_ids(list(world.dynamics), sources)
        world.check_controllers(ids)
        settings = {"models": str(Path(models).resolve()), "controller_models": ids, "config": asdict(config),
                    "resolution": resolution, "clearance_mm": clearance_mm, "knock_out_step": knock_out_step,
                    # the image goal score is the default that earlier runs' settings leave out
                    **({"goal_score": goal_score} if goal_score != "image" else {})}
        begin_run(out, resume, settings)
        path = out / "episodes.jsonl"
        kept = {e.seed: e for e in load_episodes(out)} if resume else {}
        if kept:  # rewritten whole, without an episode cut off mid-line
            atomic.write_text(path, "".join(json.dumps(e.to_dict()) + "\n" for e in kept.values()))
        todo = [s for s in seeds if s not in kept]
        setup = partial(Composer, models, sources, config, resolution, clearance_mm, knock_out_step, out,
                        tuple(seeds[:videos]), world=world if in_process(todo, workers) else None,
                        goal_score=goal_score)
        with open(path, "a" if resume else "w") as log, \
                tqdm(total=len(todo), desc="composed episodes", unit="episode", disable=not progress) as bar:
            def save(_seed: int, episode: ComposedEpisode) -> None:
                log.write(json.dumps(episode.to_dict()) + "\n")
                log.flush()  # an interrupted run keeps every finished episode
                bar.update()
                interrupt.check()

            ran = dict(zip(todo, run_episodes(setup, todo, workers, save)))
        episodes = [kept[s] if s in kept else ran[s] for s in seeds]
        others = [e for s, e in kept.items() if s not in seeds]  # the earlier run's seeds that this one did not ask
        # In seed order, as a serial run writes it (workers finish in any order).
        atomic.write_text(path, "".join(json.dumps(e.to_dict()) + "\n" for e in [*episodes, *others]))
        atomic.write_text(out / "summary.md", summary(episodes, config, paper=sources.task == DEFAULT_TASK))
        return episodes


def check_out(out: Path, resume: bool, settings: dict | None = None) -> None:
    """Refuse to start a new run over the episodes of an earlier one (it would truncate them), and to continue
    one with other settings than its own (its episodes would not be of one experiment)."""
    earlier = [] if resume else load_episodes(out)
    if earlier:
        raise RunError(f"{out} holds a composed run ({len(earlier)} episodes); continue it with --resume, or give "
                       f"another --out")
    stored = out / "run.json"
    if resume and settings is not None and stored.is_file():
        try:
            own = json.loads(stored.read_text())
            if not isinstance(own, dict):
                raise ValueError(f"a JSON {type(own).__name__}, not an object")
        except (ValueError, UnicodeDecodeError) as e:
            raise RunError(f"{stored} is not readable JSON ({e}): it holds the settings --resume continues with; "
                           "restore it, or compose into another --out") from None
        clash = [key for key in settings if json.loads(json.dumps(settings[key])) != own.get(key)]
        if clash:
            raise RunError(f"--resume continues {out} with its own settings, but this run differs in "
                           f"{', '.join(clash)} (see {stored}): give the same options, or another --out")


def begin_run(out: Path, resume: bool, settings: dict) -> None:
    """A resumed run continues with its own settings (others are refused); a new run writes its own, over those of
    an earlier run that was stopped before its first episode."""
    check_out(out, resume, settings)
    out.mkdir(parents=True, exist_ok=True)
    if not resume or not (out / "run.json").is_file():
        atomic.write_text(out / "run.json", json.dumps(settings, indent=1))


def load_episodes(out: Path) -> list[ComposedEpisode]:
    """The episodes a composed run wrote to `out`/episodes.jsonl (none if it has not written any)."""
    path = out / "episodes.jsonl"
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.splitlines()
    episodes = []
    for number, line in enumerate(lines, 1):
        try:
            episodes.append(ComposedEpisode.from_dict(json.loads(line)))
        except (ValueError, KeyError, TypeError) as e:
            if number == len(lines) and not text.endswith("\n"):
                break  # the run was killed while writing its last episode: that seed runs again
            raise RunError(f"{path}, line {number}, is not a composed episode ({e}); compose into another --out, "
                           f"or remove the line to run that seed again") from None
    return episodes


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


def progressive(completed: list[int]) -> str:
    """Progressive completion: how many trials got at least as far as each milestone (`completed`: per trial, the
    number of milestones reached)."""
    n = len(completed)
    return " · ".join(f"{m} {sum(c > i for c in completed)}/{n}" for i, m in enumerate(MILESTONES))


def failure_causes(episodes: list[ComposedEpisode]) -> list[tuple[tuple[str, str, str], list[int]]]:
    """The failed episodes grouped by cause: (the last activation and why it ended, how the episode ended, where the
    part was), with their seeds, commonest first."""
    causes: dict[tuple[str, str, str], list[int]] = {}
    for e in episodes:
        if e.success:
            continue
        last = e.activations[-1] if e.activations else None
        why = last.reason.split(":")[0].split(" (")[0].strip() if last else ""
        what = f"{last.controller} {last.outcome}" + (f": {why}" if why else "") if last else "no controller started"
        causes.setdefault((what, e.ended or "-", e.part or "-"), []).append(e.seed)
    return sorted(causes.items(), key=lambda c: -len(c[1]))


def failure_table(episodes: list[ComposedEpisode]) -> list[str]:
    """`failure_causes` as the lines of a markdown table (none if every episode succeeded)."""
    causes = failure_causes(episodes)
    if not causes:
        return []
    return ["| last activation | episode ended | part at the end | episodes | seeds |", "|---|---|---|---|---|"] + [
        f"| {what} | {ended} | {gear} | {len(seeds)} | {', '.join(map(str, seeds))} |"
        for (what, ended, gear), seeds in causes]


def served_table(episodes: list[ComposedEpisode]) -> list[str]:
    """Which controller served each subtask, as the lines of a markdown table: per subtask (in the order they came),
    the controllers whose activations finished it and those whose activations ended otherwise, with counts."""
    served: dict[str, tuple[Counter, Counter]] = {}
    for a in (a for e in episodes for a in e.activations if a.subtask):
        done, other = served.setdefault(a.subtask, (Counter(), Counter()))
        (done if a.outcome == "done" else other)[a.controller] += 1
    if not served:
        return []

    def listed(counts: Counter) -> str:
        return ", ".join(f"{name} {n}" for name, n in counts.most_common()) or "-"

    return ["| subtask | finished by | tried, not finished |", "|---|---|---|"] + [
        f"| {subtask} | {listed(done)} | {listed(other)} |" for subtask, (done, other) in served.items()]


SENSED = {"learned": "The controllers' initiation sets, terminations and guards read the predicate classifiers "
                     "(cameras and joints): what a robot senses.",
          "oracle": "The controllers' initiation sets, terminations and guards read the simulator's truth (the "
                    "oracle): privileged, for comparison."}


def summary(episodes: list[ComposedEpisode], config: ComposeConfig, paper: bool = True) -> str:
    """The run's summary; `paper`: with the paper's composed figure beside it (the gear's task)."""
    n, ok = len(episodes), sum(e.success for e in episodes)
    steps = sorted(e.steps for e in episodes if e.success)
    lines = ["# Composed controllers (the selector over the whole library)", "",
             f"Horizon n = {config.horizon}, K = {config.samples} samples per controller, decisions at termination"
             + (f" and every {config.reselect_every} steps" if config.reselect_every else "") + ". "
             + SENSED[config.senses], "",
             "| | full task | progressive completion |" + (" paper |" if paper else ""),
             "|---|---|---|" + ("---|" if paper else ""),
             f"| composed | {rate(ok, n)} | {progressive([e.reached for e in episodes])} |"
             + (f" {PAPER_COMPOSED} |" if paper else ""), ""]
    if steps:
        lines += [f"Control steps of the successful episodes (at most {config.max_steps}): median "
                  f"{steps[len(steps) // 2]}, {steps[0]}-{steps[-1]}.", ""]
    knocked = [e for e in episodes if e.knocked_out]
    if knocked:
        lines += [f"Gear knocked out of the gripper in {len(knocked)} episodes; recovered (task still done) in "
                  f"{rate(sum(e.success for e in knocked), len(knocked))}.", ""]
    backed = back_offs(episodes)
    if backed:
        lines += [backed, ""]
    broken = Counter(n for e in episodes for d in e.decisions for n in d.get("not_finite", ()))
    if broken:
        lines += ["Left out because its predicted goal score was not finite (NaN or Inf: check its dynamics model "
                  "and the goal scorer): " + ", ".join(f"{n} in {c} decisions" for n, c in broken.items()) + ".", ""]
    served = served_table(episodes)
    if served:
        lines += ["## Which controller served each subtask", "", *served, ""]
    lines += ["## Controller sequences", "", "| sequence | episodes |", "|---|---|"]
    lines += [f"| {s} | {c} |" for s, c in sequence_counts(episodes)]
    failed = [e for e in episodes if not e.success]
    if failed:
        lines += ["", "## Failures by cause", "", *failure_table(episodes), "", "## Failures", ""]
        for e in failed:
            last = e.activations[-1] if e.activations else None
            why = f"{last.controller}: {last.outcome} {last.reason}".strip() if last else "no controller could start"
            lines.append(f"- seed {e.seed}: {why} (sequence {' -> '.join(e.sequence) or '-'})")
    return "\n".join(lines) + "\n"
