"""The per-controller table (paper Table I, rows MP, DMP, CNN): each controller kind on each subtask from that
subtask's standard start states, and on the full task with its three controllers in the fixed order.

Standard start states: pick from the episode's start; move with the gear grasped (off-centre by up to 12 mm) and
lifted, where the scripted expert in its open-loop mode (which carries as if the grasp were centred, as a planner
would) stops; insert from the task's own pre_insertion start (the hand at the pre-insertion pose above the peg, off
by a rough carry's error, the gear off-centre along the fingers by up to 12 mm). The re-grasp (not a column of the
paper's table) starts where the insertion does.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import torch
from tqdm import tqdm

from policy_composer.app.starts import start_state
from policy_composer.app.stats import rate
from policy_composer.app.workers import run_episodes
from policy_composer.data import atomic
from policy_composer.policies.arm import Outcome, run_activation
from policy_composer.policies.base import InitiationError
from policy_composer.policies.library import build_library, cameras_needed, names_of_kind, subtask_of
from policy_composer.policies.registry import kind_of_source
from policy_composer.policies.senses import OracleSenses
from policy_composer.selector.predicates import LearnedSenses, load_predicates
from policy_composer.tasks.base import PlanningError, TaskDescription
from policy_composer.tasks.registry import DEFAULT_TASK, task_of

SUBTASK_COLUMNS = ("pick", "move", "insert", "full")
PAPER = {  # paper Table I; "*": stopped for safety; "-": not run
    "MP": {"pick": "10/10", "move": "10/10", "insert": "1/10", "full": "1/10"},
    "DMP": {"pick": "10/10", "move": "10/10", "insert": "1/10", "full": "1/10"},
    "CNN": {"pick": "*", "move": "10/10", "insert": "10/10", "full": "-"},
}


@dataclass
class Cell:
    successes: int = 0
    trials: int = 0
    safety_stops: int = 0
    failures: list[str] = field(default_factory=list)
    completed: list[int] = field(default_factory=list)  # per trial: how many of its subtasks were done, in order

    def __str__(self) -> str:
        return rate(self.successes, self.trials) + (f" ({self.safety_stops}*)" if self.safety_stops else "")


def sequences(task: TaskDescription) -> dict[str, tuple[str, ...]]:
    """What each column runs: one subtask, or the full task's in order."""
    return {**{s: (s,) for s in task.subtasks}, "full": task.sequence}


@dataclass(frozen=True)
class Trial:
    ok: bool
    completed: int  # subtasks done, in order (the last one counts only if it seated the gear)
    safety_stop: bool
    failure: str = ""


def run_trial(env, controllers: dict[str, object], column: str, seed: int) -> Trial:
    """One trial of a Table I cell: `controllers` (subtask -> controller) run `column`'s sequence from its start."""
    task = task_of(env)
    sequence = sequences(task)[column]
    truth = OracleSenses(env)
    obs = start_state(env, seed, column)
    outcome, why, done = Outcome.DONE, "", 0
    for s in sequence:
        c = controllers[s]
        try:
            obs = run_activation(env, c, obs, seed)
        except InitiationError as e:
            outcome, why = Outcome.FAILED, str(e)
            break
        except PlanningError as e:
            outcome, why = Outcome.FAILED, f"{c.name}: no plan: {e}"
            break
        outcome, why = c.outcome, c.reason
        truly, not_so = c.subtask.succeeded(truth(obs))
        if outcome is Outcome.DONE and not truly:  # the controller's senses said done; the scorer reads the truth
            outcome, why = Outcome.FAILED, f"it terminated as done, but {not_so}"
        if outcome is not Outcome.DONE:
            break
        done += 1
    ok = outcome is Outcome.DONE and (column != "full" or bool(task.truth(env.unwrapped)[task.progress[-1]][0]))
    return Trial(ok, done if ok or done < len(sequence) else done - 1, outcome is Outcome.SAFETY_STOP,
                 "" if ok else f"seed {seed}: {why or outcome.value}")


class TrialRunner:
    """Table I trials in one process: each row's env (with the cameras its controllers read) and controllers, built
    when its first trial comes. Called with (row, column, seed)."""

    def __init__(self, rows: dict[str, tuple[str, ...]], sources, resolution: int = 128, clearance_mm: float = 2.0,
                 predicates: str | Path | None = None):
        self.rows, self.sources, self.resolution, self.clearance_mm = rows, sources, resolution, clearance_mm
        task = sources.description
        self.senses = LearnedSenses(load_predicates(predicates, task)) if predicates is not None else None
        self.built: dict[str, tuple] = {}

    def __call__(self, item: tuple[str, str, int]) -> Trial:
        row, column, seed = item
        if row not in self.built:
            cameras = tuple(dict.fromkeys((*cameras_needed(self.rows[row], self.sources),
                                           *(self.senses.cameras if self.senses else ()))))
            task = self.sources.description
            env = task.make_env("rgb" if cameras else "state_dict",
                                task.settings(self.resolution, clearance_mm=self.clearance_mm), cameras or None)
            library = build_library(env, self.rows[row], self.sources, self.senses)
            self.built[row] = env, {c.subtask.name: c for c in library.values()}
        return run_trial(*self.built[row], column, seed)

    def close(self) -> None:
        for env, _ in self.built.values():
            env.close()


def evaluate_rows(rows: dict[str, tuple[str, ...]], sources, trials: int, first_seed: int = 0,
                  resolution: int = 128, clearance_mm: float = 2.0, progress: bool = True,
                  workers: int = 1, columns: tuple[str, ...] = SUBTASK_COLUMNS,
                  column_trials: dict[str, int] | None = None,
                  predicates: str | Path | None = None) -> dict[str, dict[str, Cell]]:
    """Rows of Table I: each row's named controllers (one per subtask) on each of `columns` they cover, `trials`
    seeds from `first_seed` each (or the column's own number in `column_trials`), the trials spread over `workers`
    processes. The controllers sense the predicates with the classifiers of the world model in `predicates`, or
    (None) with the simulator's truth; the trials are judged on the truth either way."""
    torch.set_num_threads(1)
    runs = sequences(sources.description)
    needed = {s for column in columns for s in runs[column]}  # only these controllers are built and loaded
    rows = {row: tuple(n for n in names if subtask_of(n, sources) in needed) for row, names in rows.items()}
    items = []
    for row, names in rows.items():
        subtasks = {subtask_of(n, sources) for n in names}
        items += [(row, column, seed) for column in columns if set(runs[column]) <= subtasks
                  for seed in range(first_seed, first_seed + (column_trials or {}).get(column, trials))]
    setup = partial(TrialRunner, rows, sources, resolution, clearance_mm, predicates)
    with tqdm(total=len(items), desc=" and ".join(rows), unit="trial", disable=not progress) as bar:
        results = run_episodes(setup, items, workers, lambda *_: bar.update())
    table = {row: {c: Cell() for c in SUBTASK_COLUMNS} for row in rows}
    for (row, column, _), trial in zip(items, results):
        cell = table[row][column]
        cell.trials += 1
        cell.successes += trial.ok
        cell.safety_stops += trial.safety_stop
        cell.completed.append(trial.completed)
        if trial.failure:
            cell.failures.append(trial.failure)
    return table


def evaluate_controllers(names, sources, trials: int, first_seed: int = 0, resolution: int = 128,
                         clearance_mm: float = 2.0, progress: bool = True, label: str = "controllers",
                         workers: int = 1) -> dict[str, Cell]:
    """One row of Table I: the named controllers (one per subtask)."""
    return evaluate_rows({label: tuple(names)}, sources, trials, first_seed, resolution, clearance_mm, progress,
                         workers)[label]


def evaluate_table(kinds: list[str], sources, trials: int, first_seed: int = 0, resolution: int = 128,
                   clearance_mm: float = 2.0, progress: bool = True, workers: int = 1,
                   columns: tuple[str, ...] = SUBTASK_COLUMNS, column_trials: dict[str, int] | None = None,
                   predicates: str | Path | None = None) -> dict[str, dict[str, Cell]]:
    """Rows of Table I: one for each of `kinds` (MP, DMP, CNN), then one for each LeRobot checkpoint in `sources`."""
    rows = {kind: names_of_kind(kind, sources.task) for kind in kinds}
    rows.update({kind_of_source(s).function("label")(s): (s.controller_name,) for s in sources.lerobot})
    return evaluate_rows(rows, sources, trials, first_seed, resolution, clearance_mm, progress, workers, columns,
                         column_trials, predicates)


def paper_table(task: str) -> dict[str, dict[str, str]]:
    """The paper's Table I where it measured the task (the gear assembly), else nothing."""
    return PAPER if task == DEFAULT_TASK else {}


def table_row(kind: str, row: dict[str, Cell], paper: dict[str, dict[str, str]] = PAPER) -> str:
    """One kind's markdown row of Table I: each cell with its interval, then the paper's (where `paper` has the
    task)."""
    if not paper:
        return f"| {kind} | " + " | ".join(str(row[c]) for c in SUBTASK_COLUMNS) + " |"
    theirs = paper.get(kind, {})
    return f"| {kind} | " + " | ".join(f"{row[c]}; paper {theirs.get(c, '-')}" for c in SUBTASK_COLUMNS) + " |"


def write_table(rows: dict[str, dict[str, Cell]], out: Path, notes: dict[str, str] | None = None,
                paper: dict[str, dict[str, str]] = PAPER) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    with atomic.replacing(out / "controllers.csv") as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["kind", "subtask", "successes", "trials", "safety_stops", "paper"])
        for kind, row in rows.items():
            for column, cell in row.items():
                w.writerow([kind, column, cell.successes, cell.trials, cell.safety_stops,
                            paper.get(kind, {}).get(column, "")])
    lines = ["# Controllers on each subtask (paper Table I, first rows)", "",
             "Each cell: ours, with the Wilson 95% interval" + ("; then the paper's" if paper else "")
             + ". `*`: stopped for safety. `-`: not run.",
             "",
             "| controller | pick | move | insert | full task |", "|---|---|---|---|---|"]
    lines += [table_row(kind, row, paper) for kind, row in rows.items()]
    lines += ["", "## Failures", ""]
    for kind, row in rows.items():
        for column, cell in row.items():
            for failure in cell.failures:
                lines.append(f"- {kind} {column}, {failure}")
    for kind, note in (notes or {}).items():
        lines += ["", f"**{kind}**: {note}"]
    path = out / "controllers.md"
    atomic.write_text(path, "\n".join(lines) + "\n")
    return path
