"""The main job's report: `results/report.md` and `results/report.html` (the same text, figures and video inline),
each figure beside the paper's, from the outputs the pipeline's stages left in their folders."""

from __future__ import annotations

import contextlib
import os
import platform
import shutil
import time
from importlib import metadata
from pathlib import Path

import markdown

from policy_composer.app.composition import (
    PAPER_COMPOSED,
    back_offs,
    failure_table,
    load_episodes,
    progressive,
    sequence_counts,
    served_table,
)
from policy_composer.app.controller_table import Cell, paper_table, table_row
from policy_composer.app.pipeline import StageRecord
from policy_composer.app.stats import rate
from policy_composer.data import atomic
from policy_composer.selector.compose import ComposedEpisode
from policy_composer.tasks.base import TaskSpec
from policy_composer.tasks.registry import DEFAULT_TASK, get_spec

ASSETS = "report"  # folder beside report.md with the figures and videos it shows
PAPER_CAMERAS = ("the head camera does not see the fine details of the movement which the forearm cameras do, "
                 "leading to a closer to goal score")


def write_report(out: Path, profile, records: dict[str, StageRecord], wall_seconds: float,
                 spec: TaskSpec | None = None) -> Path:
    """Write report.md and report.html in `out` for the main job of the task of `spec` (default: the gear's); returns
    report.md's path. The gear's job has the paper's straight-down insertions, the knock-out and the MDP besides."""
    spec = spec or get_spec(DEFAULT_TASK)
    assets = out / ASSETS
    if assets.exists():
        shutil.rmtree(assets)
    assets.mkdir(parents=True)

    def asset(stage: str, name: str, as_name: str | None = None) -> str | None:
        src = records[stage].folder / name
        if not src.exists():
            return None
        shutil.copy(src, assets / (as_name or name))
        return f"{ASSETS}/{as_name or name}"

    def link(stage: str, name: str) -> str:
        return os.path.relpath(records[stage].folder / name, out)

    def episodes(stage: str) -> list[ComposedEpisode]:
        return load_episodes(records[stage].folder) if stage in records else []

    composed, knocked, straight = episodes("compose"), episodes("knock-out"), episodes("straight-compose")
    sensed, sensed_straight = episodes("sensed-compose"), episodes("sensed-straight-compose")
    sections = [
        _header(profile, records, wall_seconds, out, spec),
        _senses(records["world-model"].facts.get("predicates", {})),
        *([_papers_table(records, straight, sensed_straight, link,
                         *(asset("straight-compose", f"composed_seed{straight[0].seed}{name}", f"straight{name}")
                           if straight else None for name in (".mp4", "_goal_score.png")))]
          if "straight-table" in records else []),
        _table_one(records, composed, sensed, knocked, link, "straight-table" in records, paper_table(spec.name)),
        _composition(composed, asset("compose", f"composed_seed{composed[0].seed}.mp4", "composed.mp4")
                     if composed else None,
                     asset("knock-out", f"composed_seed{knocked[0].seed}.mp4", "knock_out.mp4") if knocked else None),
        _goal_score(records["goal-score"], asset("goal-score", "goal_score.png"), spec),
        *([_mdp(records["mdp"], [asset("mdp", f) for f in ("mdp19_solution.png", "mdp100_heatmap_lookahead.png",
                                                             "mdp100_heatmap_step.png")])] if "mdp" in records else []),
        _timings(records, wall_seconds),
        _machine(),
    ]
    md = "\n\n".join(sections) + "\n"
    path = out / "report.md"
    atomic.write_text(path, md)
    atomic.write_text(out / "report.html", to_html(md, f"policy-composer report ({profile.name})"))
    return path


def to_html(md: str, title: str) -> str:
    body = markdown.markdown(md, extensions=["tables"])
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font-family: system-ui, sans-serif; max-width: 60rem; margin: 2rem auto; padding: 0 1rem; line-height: 1.45; }}
table {{ border-collapse: collapse; margin: 1rem 0; }} th, td {{ border: 1px solid #bbb; padding: .25rem .6rem; }}
th {{ background: #f2f2f2; }} img, video {{ max-width: 100%; }} code {{ background: #f4f4f4; padding: 0 .2rem; }}
</style></head>
<body>
{body}
</body></html>
"""


def _header(profile, records: dict[str, StageRecord], wall_seconds: float, out: Path, spec: TaskSpec) -> str:
    cnn = tuple(s for s in ("pick", "move", "insert") if s in spec.demonstrations)
    ran = [r for r in records.values() if not r.reused]
    readme = Path(__file__).resolve().parents[2] / "README.md"
    where = f"[the README's main-job section]({os.path.relpath(readme, out)}#the-main-job)" if readme.exists() else \
        "the main-job section of policy-composer's README"
    supported = profile.holds.get(spec.name) or (
        f"This run's figures are on its own seeds (0-{profile.compose_episodes - 1} for the compositions); "
        f"{spec.env_id}'s held-out figures are in the task's docs (docs/task.md).")
    holds = [f"**What holds at this size.** {supported}", ""]
    if elsewhere := profile.elsewhere.get(spec.name):
        holds += [f"**Measured elsewhere, not by this run:** {elsewhere}, in {where}.", ""]
    return "\n".join([
        f"# Composing diverse policies: the paper reproduced on this machine ({spec.env_id})", "",
        f"Profile `{profile.name}`, written {time.strftime('%Y-%m-%d %H:%M')}. This run took "
        f"{wall_seconds / 60:.1f} min: {len(ran)} of {len(records)} stages ran"
        + (", the others were reused from an earlier run with the same settings; all stages together took "
           f"{sum(r.seconds for r in records.values()) / 60:.1f} min when they ran."
           if len(ran) < len(records) else "."),
        "",
        *holds,
        f"Sizes: {profile.insertion_demos} insertion demonstrations"
        + (f" and {profile.transport_demos} pick-up and carry demonstrations" if "transport-demos" in records else "")
        + ", "
        f"{profile.train_demos} full-task demonstrations "
        f"for the goal scorers ({profile.full_task_demos - profile.train_demos} held out), {profile.rollouts} rollouts "
        f"per controller, CNN {profile.cnn_training(cnn)}{_dagger(profile, cnn)}, {profile.mixtures} mixtures, "
        f"selector n = {profile.horizon}, "
        f"K = {profile.samples}, cameras at {profile.resolution} px (models see {profile.image_size} px)."])


def _senses(figures: dict[str, dict]) -> str:
    """Which channel each figure reads, and the predicate classifiers' held-out figures."""
    lines = ["## What the controllers sense", "",
             "In Table I's cells the controllers' initiation sets, terminations and guards read the task's predicates "
             "from the simulator's truth (`--senses oracle`); each activation is judged on the truth. The composed "
             "rows run the same seeds twice: on those oracle predicates, and on the predicate classifiers of the "
             "cameras and joints, what a robot senses (`--senses learned`). In both, the pick-up's planner is given "
             "the part's position on the table, the task's one privileged input."]
    if figures:
        some = next(iter(figures.values()))
        lines += ["", f"The classifiers on {some['frames']} frames of held-out episodes (every fifth of each "
                      "recording):", "",
                  "| predicate | accuracy | false positives | false negatives |", "|---|---|---|---|"]
        lines += [f"| {name} | {f['accuracy']:.3f} | {f['false_positive_rate']:.3f} | {f['false_negative_rate']:.3f} |"
                  for name, f in figures.items()]
    return "\n".join(lines)


def _dagger(profile, cnn: tuple[str, ...]) -> str:
    trained = [s for s in profile.dagger_subtasks if s in cnn]
    if not profile.dagger_rounds or not trained:
        return ""
    return (f" (then {profile.dagger_rounds} DAgger round(s) for the {' and '.join(trained)}: "
            f"{profile.dagger_episodes} of each policy's rollouts labelled by the expert, and "
            f"{profile.dagger_epochs} epochs on them and its demonstrations)")


def _rows(record: StageRecord) -> dict[str, dict[str, Cell]]:
    """A Table I stage's rows: kind -> column -> cell."""
    return {kind: {c: Cell(*counts) for c, counts in row.items()}  # counts: successes, trials, safety stops
            for kind, row in record.facts["rows"].items()}


def _composed_rows(oracle: list[ComposedEpisode], sensed: list[ComposedEpisode], paper: bool = True) -> list[str]:
    """Table I's composed rows, on the oracle's predicates and on the sensed ones (the first 10 seeds, as the paper
    ran), and the rates over all seeds if more ran."""
    lines, more = [], []
    for channel, composed in (("oracle", oracle), ("sensed", sensed)):
        first = composed[:10]
        lines += [f"| composed (selector), {channel} predicates | - | - | - | "
                  f"{rate(sum(e.success for e in first), len(first))}"
                  + (f"; paper {PAPER_COMPOSED} |" if paper else " |")]
        if len(composed) > len(first):
            more += [f"Composed over {len(composed)} seeds on {channel} predicates: "
                     f"{rate(sum(e.success for e in composed), len(composed))} full-task successes "
                     "(the paper runs 10)."]
    return lines + (["", *more] if more else [])


def _papers_table(records, composed: list[ComposedEpisode], sensed: list[ComposedEpisode], link, video: str | None,
                  figure: str | None) -> str:
    """Table I as the paper got it: the MP and DMP insertions go straight down once, assuming a centred grasp."""
    feel, straight = _rows(records["table"]), _rows(records["straight-table"])
    rows = {kind: {**feel[kind], **{c: cell for c, cell in straight[kind].items() if cell.trials}}
            for kind in straight}
    rows.update({kind: row for kind, row in feel.items() if kind not in rows})
    lines = ["## Table I, the paper's experiment: planned insertions that go straight down", "",
             "The MP and DMP insertions line up for a centred grasp and go straight down once, as the paper's did "
             "(`--insertion straight`); their dynamics models are trained on their own rollouts. Each cell: ours, "
             "with the Wilson 95% interval; then the paper's. `*`: stopped for safety. Pick and move are the next "
             f"table's (the insertion does not change them); failures: [controllers.md]"
             f"({link('straight-table', 'controllers.md')}).", "",
             "| controller | pick | move | insert | full task |", "|---|---|---|---|---|"]
    lines += [table_row(kind, row) for kind, row in rows.items()]
    lines += _composed_rows(composed, sensed)
    served = served_table(composed)
    if served:
        lines += ["", "Which controller served each subtask in the composed episodes (activations):", "", *served]
    if figure:
        lines += ["", f"![The goal score over composed trial {composed[0].seed}]({figure})", "",
                  "The goal score over a composed trial (the paper's figure of a trial), coloured by the controller "
                  "the selector ran."]
    if video:
        lines += _video(video, f"Composed rollout with the straight-down insertions, seed {composed[0].seed}", ".")
    return "\n".join(lines)


def _video(src: str, title: str, after: str) -> list[str]:
    """A video the report plays inline, with a link to it (for readers of the markdown) and `after` its title."""
    return ["", f'<video src="{src}" controls muted preload="metadata" width="512"></video>', "",
            f"[{title}]({src}){after}"]


def _table_one(records, composed: list[ComposedEpisode], sensed: list[ComposedEpisode],
               knocked: list[ComposedEpisode], link, beyond: bool, paper: dict) -> str:
    intro = ["## Table I beyond the paper: planned insertions that feel for the hole", "",
             "The MP and DMP insertions try offsets around the hole until the gear goes down (the project's default). "
             ] if beyond else ["## Table I", "", "The planned insertions push along the hole's axis once, open loop. "]
    lines = [*intro[:-1], intro[-1] +
             "Each cell: ours, with the Wilson 95% interval" + ("; then the paper's" if paper else "")
             + ". `*`: stopped for safety. `-`: not run. "
             f"Start states, failures: [controllers.md]({link('table', 'controllers.md')}).", "",
             "| controller | pick | move | insert | full task |", "|---|---|---|---|---|"]
    lines += [table_row(kind, row, paper) for kind, row in _rows(records["table"]).items()]
    lines += _composed_rows(composed, sensed, bool(paper))
    completed = records["table"].facts.get("completed", {})
    lines += ["", "Progressive completion of the full task: how many trials got at least this far.", "",
              "| controller | progressive completion |", "|---|---|"]
    lines += [f"| {kind} | {progressive(c)} |" for kind, c in completed.items()]
    lines += [f"| composed (selector), {channel} predicates | {progressive([e.reached for e in episodes])} |"
              for channel, episodes in (("oracle", composed), ("sensed", sensed))]
    hit = [e for e in knocked if e.knocked_out]
    if hit:
        lines += ["", f"Beyond the paper, recovery: the gear was knocked out of the gripper in {len(hit)} of "
                      f"{len(knocked)} episodes, and the selector still finished the task in "
                      f"{rate(sum(e.success for e in hit), len(hit))} "
                      f"([summary]({link('knock-out', 'summary.md')}))."]
    return "\n".join(lines)


def _composition(composed: list[ComposedEpisode], video: str | None, knock_video: str | None) -> str:
    lines = ["## The selector composing the library"]
    if video:
        lines += _video(video, f"Composed rollout, seed {composed[0].seed}", ": the selector's camera (the world "
                        "model's), the running controller and the goal score of the current image.")
    if knock_video:
        lines += _video(knock_video, "The gear knocked out at step 100", ": the selector picks a pick-up again.")
    backed = back_offs(composed)
    if backed:
        lines += ["", backed]
    served = served_table(composed)
    if served:
        lines += ["", "Which controller served each subtask (activations over all composed episodes):", "", *served]
    causes = failure_table(composed)
    if causes:
        lines += ["", "Failed composed episodes by cause:", "", *causes]
    lines += ["", "| controllers chosen, in order | episodes |", "|---|---|"]
    lines += [f"| {s or '(none could start)'} | {c} |" for s, c in sequence_counts(composed)]
    if composed:
        e = composed[0]
        names = sorted(e.decisions[0]["scores"]) if e.decisions else []
        lines += ["", f"Decision log of seed {e.seed} ({'success' if e.success else 'failure'}): the predicted "
                      "goal score of each controller after n dynamics steps; `-` outside its initiation set.", "",
                  "| step | chosen | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
        for d in e.decisions:
            scores = [("-" if d["scores"][n] is None else f"{d['scores'][n]:.3f}") for n in names]
            lines.append(f"| {d['step']} | {d['choice']} | " + " | ".join(scores) + " |")
    return "\n".join(lines)


def _goal_score(record: StageRecord, figure: str | None, spec: TaskSpec) -> str:
    metrics = record.facts["metrics"]
    ranked = sorted((c for c in metrics if c != "latent"), key=lambda c: -metrics[c]["spearman"])
    on_arm_best = ranked[0] not in spec.fixed_cameras
    fixed = " and ".join(spec.fixed_cameras) or "fixed"
    lines = ["## Goal score per camera", ""]
    if figure:
        lines += [f"![goal score per camera]({figure})", ""]
    lines += ["| camera | Spearman with true progress | mean abs. error |", "|---|---|---|"]
    lines += [f"| {c} | {m['spearman']:.3f} | {m['mae']:.3f} |" for c, m in metrics.items()]
    some = next(iter(metrics.values()))
    lines += ["", f"On {some['episodes']} held-out demonstrations the {ranked[0]} camera tracks progress best. "
              f"The paper: \"{PAPER_CAMERAS}\". Ours " + (f"agrees: a camera on the arm ranks above the {fixed} camera."
                                                         if on_arm_best else
                                                         f"disagrees: the {fixed} camera ranks first here.")]
    if "latent" in metrics:
        lines += ["", "Row `latent` is the goal score of the VAE's latents of its camera's frames, which scores the "
                      "selector's predictions without decoding them (`compose --goal-score latent`)."]
    return "\n".join(lines)


def _mdp(record: StageRecord, figures: list[str | None]) -> str:
    text = (record.folder / "mdp_report.md").read_text().splitlines()
    body = [("#" + line if line.startswith("#") else line) for line in text[1:]]  # under this report's heading
    lines = ["## The random-walk MDP", *body, ""]
    lines += [f"![{Path(f).stem}]({f})" for f in figures if f]
    return "\n".join(lines)


def _throughput(r: StageRecord) -> str:
    """What an episode loop got through per second, from its stage's facts ("" for the other stages)."""
    f, seconds = r.facts, max(r.seconds, 1e-9)
    if "frames" in f:
        done = f"{f['episodes'] / seconds:.2f} episodes/s, {f['frames'] / seconds:.1f} frames/s"
    elif "successes" in f:
        done = f"{len(f['successes']) / seconds:.3f} episodes/s"
    elif "rows" in f:
        done = f"{sum(cell[1] for row in f['rows'].values() for cell in row.values()) / seconds:.2f} trials/s"
    else:
        return ""
    return done + (f" ({f['workers']} workers)" if f.get("workers", 1) > 1 else "")


def _timings(records: dict[str, StageRecord], wall_seconds: float) -> str:
    lines = ["## Timings", "", "| stage | seconds | throughput | this run |", "|---|---|---|---|"]
    lines += [f"| {r.title} | {r.seconds:.0f} | {_throughput(r)} | {'reused' if r.reused else 'ran'} |"
              for r in records.values()]
    lines += [f"| **main job, this run** | {wall_seconds:.0f} | | |"]
    models = {what: s for r in records.values() for what, s in r.facts.get("timings", {}).items()}
    if models:
        lines += ["", "| model | training seconds |", "|---|---|"] + [f"| {m} | {s:.0f} |" for m, s in models.items()]
    return "\n".join(lines)


def machine_facts() -> dict[str, str]:
    """The machine and the package versions the figures were measured with."""
    cpu = platform.processor() or "unknown CPU"
    with contextlib.suppress(OSError, StopIteration), open("/proc/cpuinfo") as f:
        cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    facts = {"CPU": f"{cpu}, {os.cpu_count()} cores", "OS": platform.platform(), "Python": platform.python_version()}
    with contextlib.suppress(ValueError, OSError):
        facts["memory"] = f"{os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES') / 2**30:.0f} GiB"
    for package in ("torch", "mani-skill", "sapien", "lerobot", "ompl"):
        try:
            facts[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            facts[package] = "not installed"
    return facts


def _machine() -> str:
    return "\n".join(["## Machine", "", "| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in machine_facts().items()])
