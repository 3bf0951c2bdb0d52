"""`policy-composer demo`: the paper reproduced end to end, as stages of the pipeline runner.

record the demo sets -> fit the DMPs, train the CNN policies (and their DAgger rounds) -> record the controllers'
rollouts -> train the VAE, the dynamics models, the goal scorers and the predicate classifiers -> evaluate the goal
scores and the controllers (Table I) -> compose the library with the selector, on the oracle's predicates and on the
sensed ones -> the report. The gear's job adds the paper's straight-down insertions (their rollouts, dynamics
models, Table I and compositions), the recovery from a knock-out and the random-walk MDP experiments.

A profile (`profiles`) says how big each stage is; `Makings` holds what the stages are made with at its sizes, and
`stages` lists them, each a named run function with its settings bound.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path

import torch

from policy_composer.app import mdp
from policy_composer.app.composition import compose_library
from policy_composer.app.controller_table import SUBTASK_COLUMNS, evaluate_table, paper_table, write_table
from policy_composer.app.pipeline import Stage, StageRecord, run_stages
from policy_composer.app.profiles import PROFILES, Profile
from policy_composer.app.record import record_recipe
from policy_composer.app.report import write_report
from policy_composer.data import interrupt
from policy_composer.data.catalog import summarize
from policy_composer.data.features import FEATURES_REVISION
from policy_composer.data.lock import one_writer
from policy_composer.data.recipes import Recipe, load_recipe
from policy_composer.data.verify import verify_dataset
from policy_composer.learning.checkpoint import finished
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.train import train_cnn_policy
from policy_composer.policies.dmp.configuration_dmp import FIT_FIRST_SEED
from policy_composer.policies.dmp.controller import fit_dmp_library
from policy_composer.policies.library import LIBRARY_REVISION, LibrarySources, all_names
from policy_composer.policies.registry import kinds
from policy_composer.selector.configuration import (
    ComposeConfig,
    DynamicsConfig,
    GoalScoreConfig,
    PredicateConfig,
    VAEConfig,
)
from policy_composer.selector.evaluate import evaluate_goal_scores
from policy_composer.selector.train import train_goal_scores, train_predicate_models, train_world_model
from policy_composer.tasks.base import TaskSpec
from policy_composer.tasks.gear_assembly.env import TASK_REVISION
from policy_composer.tasks.registry import DEFAULT_TASK, get_spec, get_task

# The controllers that `--insertion straight` changes on the gear: the paper's open-loop insertions.
STRAIGHT = ("mp_insert", "dmp_insert")
# The first seed of each CNN policy's DAgger rollouts (round K starts 1000 (K - 1) later): clear of the seeds the
# job's tables and compositions run (and of the replacements Table I draws, seed + 1000 k).
DAGGER_SEEDS = {"insert": 80000, "move": 90000}
BC_STAGE = "bc-cnn"  # the CNN policies behaviour-cloned on their demonstrations, where DAgger rounds follow


def stage_name(recipe: str) -> str:
    """A recording stage's name: its recipe's less the task's prefix (gear-insertion-demos: insertion-demos)."""
    return recipe.split("-", 1)[1]


def env_key(task: str, resolution: int) -> dict:
    """What a stage's results depend on of the env: the gear's settings and revision, or another task's name and
    revision."""
    if task != DEFAULT_TASK:
        return {"resolution": resolution, "task": task, "task_revision": get_spec(task).revision}
    return {"resolution": resolution, "clearance_mm": 2.0, "task_revision": TASK_REVISION}


@dataclass(frozen=True)
class Makings:
    """What the main job's stages are made with, for a task at a profile's sizes: the recipes they record, the
    configurations they train and compose with, and what of the env and of the library their keys name."""

    spec: TaskSpec
    demos: tuple[tuple[Recipe, int, str], ...]  # the CNN policies' demonstrations: recipe, episodes, what they show
    full_task: Recipe  # the full-task demonstrations (the goal scorers')
    rollouts: Recipe  # each controller's rollouts (the dynamics models')
    straight_rollouts: Recipe  # the straight-down insertions' rollouts (the gear's)
    cnn: dict[str, CNNPolicyConfig]  # subtask -> its CNN policy's training
    dagger: dict[str, tuple[Recipe, CNNPolicyConfig]]  # subtask -> its corrections' recipe, its DAgger trainings
    vae: VAEConfig
    dynamics: DynamicsConfig
    goal: GoalScoreConfig
    predicates: PredicateConfig
    compose: ComposeConfig  # on the oracle's predicates
    sensed: ComposeConfig  # on the predicate classifiers
    insertion: str  # the planned insertions' default ("feel" on the gear)
    table_kinds: tuple[str, ...]  # Table I's rows
    env: dict  # in the key of each stage that runs the env (`env_key`)
    # In the keys of the models that read the task's kinematics (the CNN policies, the predicate classifiers).
    kinematics: tuple[str, ...]
    # In the keys of the stages that run the controllers (the DMPs' too: they learn the planner's trajectories): a
    # changed or added controller re-runs them.
    library: dict

    @classmethod
    def of(cls, p: Profile, task: str) -> Makings:
        spec, description = get_spec(task), get_task(task)
        insertion = spec.demonstrations["insert"][0]  # its recipe comes first
        demos = tuple((load_recipe(name), p.insertion_demos, "the insertion demonstrations") if name == insertion
                      else (load_recipe(name), p.transport_demos, "the pick-up and carry demonstrations")
                      for name in dict.fromkeys((insertion, *(r for r, _ in spec.demonstrations.values()))))
        rollouts = load_recipe(spec.controller_rollouts)
        max_steps = min(p.cnn_max_steps, spec.policy_steps or p.cnn_max_steps)
        cnn = {s: CNNPolicyConfig(subtask=s, task=task, epochs=(s == "insert" and p.insert_epochs) or p.cnn_epochs,
                                  num_mixtures=p.mixtures, image_size=p.image_size, max_steps=max_steps,
                                  precision="bfloat16" if s in p.bfloat16_subtasks else "float32")
               for s in ("pick", "move", "insert") if s in spec.demonstrations}
        compose = ComposeConfig(horizon=p.horizon, samples=p.samples,
                                max_steps=min(p.compose_max_steps, spec.episode_steps or p.compose_max_steps))
        return cls(
            spec=spec, demos=demos,
            full_task=replace(load_recipe(spec.full_task_demos), train_episodes=p.train_demos),
            rollouts=rollouts, straight_rollouts=replace(rollouts, controllers=STRAIGHT),
            cnn=cnn, dagger={s: (load_recipe(spec.corrections[s]), replace(cnn[s], epochs=p.dagger_epochs))
                             for s in p.dagger_subtasks if s in spec.corrections},
            vae=VAEConfig(task=task, epochs=p.vae_epochs, image_size=p.image_size),
            dynamics=DynamicsConfig(task=task, epochs=p.dynamics_epochs),
            goal=GoalScoreConfig(task=task, epochs=p.goal_epochs, num_mixtures=p.mixtures, image_size=p.image_size),
            predicates=PredicateConfig(task=task, epochs=p.predicate_epochs * spec.predicate_epoch_factor,
                                       image_size=min(PredicateConfig.image_size, p.image_size)),
            compose=compose, sensed=replace(compose, senses="learned"),
            insertion=next(iter(description.insertions)), table_kinds=tuple(k.label for k in kinds().values()),
            env=env_key(task, p.resolution), kinematics=description.extra_proprioception,
            library={"library_revision": LIBRARY_REVISION, "controllers": all_names(LibrarySources(task=task))})

    def demonstrations(self, subtasks) -> dict:
        """In the key of a stage that trains the CNN policies of `subtasks`: the recipe and the stages of it each
        learns from (the task's spec picks them; the recording's key does not say which)."""
        return {s: self.spec.demonstrations[s] for s in subtasks}

    def recording(self, recipe: Recipe, episodes: int) -> dict:
        """The key of a stage that records `episodes` of `recipe`."""
        return {"recipe": asdict(recipe), "episodes": episodes, "features_revision": FEATURES_REVISION, **self.env}


def stages(p: Profile, workers: int = 1, task: str = DEFAULT_TASK) -> list[Stage]:
    """The main job's stages for `task` at the sizes of profile `p`; the episode loops run on `workers` processes
    (not in a stage's key: the results are the same for any number). The gear's job adds the paper's straight-down
    insertions, the knock-out and the random-walk MDP."""
    m = Makings.of(p, task)
    gear = task == DEFAULT_TASK
    runs = {"resolution": p.resolution, "workers": workers}  # the env's resolution, the episode loops' processes
    ran = {**m.env, **m.library}  # in the key of each stage that runs the library's controllers
    demos = tuple(stage_name(recipe.name) for recipe, _, _ in m.demos)
    dagger = _dagger_rounds(p, m, workers)
    # What the predicate classifiers learn from: every recording of the library's and the expert's episodes that
    # reaches the part's counterpart (the gear's pick-up and carry demonstrations add nothing there).
    labelled = ("controller-rollouts", "full-task-demos", stage_name(m.spec.demonstrations["insert"][0]),
                *(s.name for s in dagger if s.verify is _verify_dataset))
    trials = f"{p.table_trials} per cell" + (f", {p.insert_trials} per insertion" if p.insert_trials else "")
    compose = partial(_composition, p=p, task=task, workers=workers, key=ran)
    return [
        # The recordings the library learns from; its DMPs and CNN policies.
        *(_recording(stage_name(recipe.name), f"record {what} ({episodes})", m.recording(recipe, episodes),
                     partial(_record_stage, recipe=recipe, episodes=episodes, **runs))
          for recipe, episodes, what in m.demos),
        _recording("full-task-demos", f"record the full-task demonstrations ({p.full_task_demos}, of which "
                   f"{p.train_demos} train the goal scorers)", m.recording(m.full_task, p.full_task_demos),
                   partial(_record_stage, recipe=m.full_task, episodes=p.full_task_demos, **runs)),
        Stage("dmp", f"fit the DMPs to the motion planner's episodes ({p.dmp_episodes})",
              {"episodes": p.dmp_episodes, "library_revision": LIBRARY_REVISION, **m.env},
              partial(_fit_dmp, episodes=p.dmp_episodes, task=task, resolution=p.resolution)),
        Stage(BC_STAGE if dagger else "cnn",
              f"train the CNN policies on the demonstrations: {', '.join(m.cnn)} ({p.cnn_training(tuple(m.cnn))})",
              {**{s: asdict(c) for s, c in m.cnn.items()}, "kinematics": m.kinematics,
               "demonstrations": m.demonstrations(m.cnn)},
              partial(_train_cnn, configs=m.cnn, spec=m.spec), inputs=demos, resumable=True),
        *dagger,  # the CNN policies' DAgger rounds, the last of which trains stage "cnn"
        # The world model: learned from the controllers' rollouts and the demonstrations.
        _recording("controller-rollouts", f"record rollouts of each controller ({p.rollouts} each)",
                   {**m.recording(m.rollouts, p.rollouts), **m.library},
                   partial(_record_stage, recipe=m.rollouts, episodes=p.rollouts, task=task, **runs),
                   inputs=("dmp", "cnn")),
        Stage("world-model", "train the VAE, the dynamics models, the goal scorers and the predicate classifiers",
              {"vae": asdict(m.vae), "dynamics": asdict(m.dynamics), "goal": asdict(m.goal),
               "cameras": m.spec.cameras, "predicates": asdict(m.predicates), "kinematics": m.kinematics},
              partial(_train_world, vae=m.vae, dynamics=m.dynamics, goal=m.goal, predicates=m.predicates,
                      labelled=labelled, cameras=m.spec.cameras),
              inputs=tuple(dict.fromkeys(("controller-rollouts", "full-task-demos", *labelled))), resumable=True),
        Stage("goal-score", "evaluate the goal score of each camera on the held-out demonstrations",
              {"cameras": m.spec.cameras},
              partial(_evaluate_goal, cameras=m.spec.cameras), inputs=("world-model", "full-task-demos")),
        # Table I and the compositions.
        Stage("table", f"Table I: each controller kind on each subtask ({trials})",
              {"trials": p.table_trials, "insert_trials": p.insert_trials, "kinds": m.table_kinds, **ran},
              partial(_table, p=p, kinds=m.table_kinds, workers=workers, task=task), inputs=("dmp", "cnn")),
        # The gear's only: the paper's Table I as the paper got it, the MP and DMP insertions going straight down
        # once (`--insertion straight`), with their rollouts and dynamics models recorded and trained again for it.
        *([
            _recording("straight-rollouts", f"record rollouts of the straight-down insertions ({p.rollouts} each)",
                       {**m.recording(m.straight_rollouts, p.rollouts), **m.library},
                       partial(_record_stage, recipe=m.straight_rollouts, episodes=p.rollouts, task=task,
                               insertion="straight", **runs),
                       inputs=("dmp", "cnn")),
            Stage("straight-world-model", "train the straight-down insertions' dynamics models",
                  {"dynamics": asdict(m.dynamics), "controllers": STRAIGHT},
                  partial(_train_straight, dynamics=m.dynamics),
                  inputs=("world-model", "straight-rollouts", "full-task-demos")),
            Stage("straight-table", f"Table I with the straight-down insertions: MP and DMP ({trials})",
                  {"trials": p.table_trials, "insert_trials": p.insert_trials, **ran},
                  partial(_table, p=p, kinds=("MP", "DMP"), workers=workers, task=task, insertion="straight",
                          columns=("insert", "full")),
                  inputs=("dmp", "cnn")),
            compose("straight-compose", "compose the library with the straight-down insertions", m.compose,
                    "straight", "straight-world-model"),
            compose("sensed-straight-compose", "compose it again on the predicate classifiers", m.sensed,
                    "straight", "straight-world-model"),
        ] if gear else []),
        compose("compose", "compose the library with the selector", m.compose, m.insertion, "world-model"),
        compose("sensed-compose", "compose it again on the predicate classifiers", m.sensed, m.insertion,
                "world-model"),
        # The gear's only: recovery from a knock-out, and the random-walk MDP.
        *([
            Stage("knock-out", f"recovery from the gear knocked out of the gripper (episodes: {p.knockout_episodes})",
                  {"compose": asdict(m.compose), "episodes": p.knockout_episodes, "knock_out_step": 100, **ran},
                  partial(_compose, config=m.compose, seeds=list(range(100, 100 + p.knockout_episodes)),
                          knock_out_step=100, task=task, insertion=m.insertion, world="world-model", **runs),
                  inputs=("dmp", "cnn", "world-model"), resumable=True),
            Stage("mdp", "the random-walk MDP experiments (19 and 100 states)",
                  {"episodes_19": p.mdp_episodes_19, "episodes_100": p.mdp_episodes_100, "levels": p.mdp_levels},
                  partial(_mdp, p=p)),
        ] if gear else []),
    ]


def _recording(name: str, title: str, key: dict, run: Callable[[Path, dict[str, Path]], dict],
               inputs: tuple[str, ...] = ()) -> Stage:
    """A stage that records a dataset: it resumes episode by episode, and what it recorded is verified first."""
    return Stage(name, title, key, run, inputs=inputs, resumable=True, verify=_verify_dataset)


def _composition(name: str, what: str, config: ComposeConfig, insertion: str, world: str, p: Profile, task: str,
                 workers: int, key: dict) -> Stage:
    """A stage that composes the library with the selector (`config`) on the world model of stage `world`, the
    planned controllers inserting as `insertion` says, over seeds 0 to p.compose_episodes - 1. `key`: the env's and
    the library's."""
    return Stage(name, f"{what} (episodes: {p.compose_episodes})",
                 {"compose": asdict(config), "episodes": p.compose_episodes, **key},
                 partial(_compose, config=config, seeds=list(range(p.compose_episodes)), resolution=p.resolution,
                         knock_out_step=None, workers=workers, task=task, insertion=insertion, world=world),
                 inputs=("dmp", "cnn", world), resumable=True)


def run_demo(profile: str = "quick", out: str | Path = "results", workers: int = 1,
             task: str = DEFAULT_TASK) -> tuple[dict[str, StageRecord], Path]:
    """Run (or reuse) every stage of `task`'s job under `out`/pipeline, then write `out`/report.md and report.html."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}: choose one of {', '.join(PROFILES)}")
    spec = get_spec(task)
    p = PROFILES[profile]
    if spec.dagger_rounds is not None:
        p = replace(p, dagger_rounds=min(p.dagger_rounds, spec.dagger_rounds))
    out = Path(out)
    t0 = time.perf_counter()
    with one_writer(out):  # a second main job into the same folder stops at once
        records = run_stages(stages(p, workers, task), out / "pipeline")
        report = write_report(out, p, records, time.perf_counter() - t0, spec)
    return records, report


def _dagger_rounds(p: Profile, m: Makings, workers: int) -> list[Stage]:
    """DAgger for the CNN policies of `m.dagger` (subtask -> its corrections recipe and training config),
    `p.dagger_rounds` times: record each last policy's rollouts labelled by the expert (`insertion-dagger-K`,
    `move-dagger-K`), then train each anew on its demonstrations and every round's rollouts. The last round's model
    is stage `cnn`, the library's (with no rounds, the demonstrations' is)."""
    stages, policy, rollouts = [], BC_STAGE, {s: () for s in m.dagger}
    for k in range(1, p.dagger_rounds + 1):
        for s, (recipe, _) in m.dagger.items():
            seed, name = DAGGER_SEEDS[s] + 1000 * (k - 1), f"{stage_name(recipe.name)}-{k}"
            rollouts[s] += (name,)
            stages.append(_recording(name, f"record the CNN {s} policy's rollouts labelled by the expert (DAgger "
                                     f"round {k}, {p.dagger_episodes})",
                                     {**m.recording(recipe, p.dagger_episodes), "seed": seed},
                                     partial(_record_stage, recipe=recipe, episodes=p.dagger_episodes,
                                             resolution=p.resolution, workers=workers, task=m.spec.name, cnn=policy,
                                             seed=seed),
                                     inputs=(policy,)))
        trained = "cnn" if k == p.dagger_rounds else f"dagger-cnn-{k}"
        configs = {s: config for s, (_, config) in m.dagger.items()}
        datasets = {s: (stage_name(m.spec.demonstrations[s][0]), *rollouts[s]) for s in m.dagger}
        stages.append(Stage(trained, f"train the CNN {', '.join(m.dagger)} policies on their demonstrations and {k} "
                            f"round(s) of the expert's corrections ({p.dagger_epochs} epochs)",
                            {**{s: asdict(c) for s, c in configs.items()},
                             "demonstrations": m.demonstrations(configs)},
                            partial(_train_dagger, configs=configs, policy=policy, datasets=datasets),
                            inputs=(policy, *dict.fromkeys(n for d in datasets.values() for n in d)),
                            resumable=True))
        policy = trained
    return stages


def _record_stage(out: Path, inputs: dict[str, Path], recipe: Recipe, episodes: int, resolution: int, workers: int,
                  task: str | None = None, insertion: str = "", cnn: str = "cnn", seed: int = 0) -> dict:
    """A recording stage's run: `episodes` of `recipe` into out/dataset; with a `task`, the recipe's controllers are
    that task's library with the models of the stages it reads (`_sources`)."""
    sources = _sources(inputs, task, insertion, cnn) if task else None
    return _record(recipe, out, episodes, resolution, workers, sources, seed)


def _record(recipe, out: Path, episodes: int, resolution: int, workers: int, sources=None, seed: int = 0) -> dict:
    root = out / "dataset"
    resume = (root / "meta" / "info.json").exists()
    if root.exists() and not resume:  # interrupted before its first episode was saved
        shutil.rmtree(root)
    record_recipe(recipe, root, episodes=episodes, seed=None if resume else seed, resume=resume,
                  settings=recipe.spec.env_settings(resolution=resolution), sources=sources, workers=workers)
    s = summarize(root)
    return {"episodes": s["episodes"], "frames": s["frames"], "outcomes": s["outcomes"], "workers": workers}


def _verify_dataset(out: Path) -> None:
    """A recording stage's dataset, as far as it got, passes every reader's checks (frame counts included)."""
    if (out / "dataset").exists():
        verify_dataset(out / "dataset")


def _sources(inputs: dict[str, Path], task: str, insertion: str = "", cnn: str = "cnn"):
    """The task's library, its models from the stages' outputs: the DMPs, and the CNN policies of stage `cnn`."""
    models = {"cnn": str(inputs[cnn] / "cnn")}
    if "dmp" in inputs:
        models["dmp"] = str(inputs["dmp"] / "dmp")
    return LibrarySources(models=models, insertion=insertion, task=task)


def _fit_dmp(out: Path, inputs: dict[str, Path], episodes: int, task: str, resolution: int) -> dict:
    description = get_task(task)
    env = description.make_env("state_dict", description.spec.env_settings(resolution=resolution))
    try:
        fit_dmp_library(env, seeds=list(range(FIT_FIRST_SEED, FIT_FIRST_SEED + episodes))).save(out / "dmp")
    finally:
        env.close()
    return {"episodes": episodes}


def _train_cnn(out: Path, inputs: dict[str, Path], configs: dict, spec: TaskSpec) -> dict:
    """One CNN policy per subtask, in the library's CNN model folder (out/cnn/SUBTASK)."""
    demos = {s: [inputs[stage_name(spec.demonstrations[s][0])] / "dataset"] for s in configs}
    return _train_policies(out, configs, demos, {s: f"CNN {s} policy" for s in configs})


def _train_dagger(out: Path, inputs: dict[str, Path], configs: dict[str, CNNPolicyConfig], policy: str,
                  datasets: dict[str, tuple[str, ...]]) -> dict:
    """A CNN model: the policies of stage `policy`, with those of `configs` trained anew on the datasets of their
    stages `datasets` (the demonstrations and the labelled rollouts)."""
    shutil.copytree(inputs[policy] / "cnn", out / "cnn", ignore=shutil.ignore_patterns(*configs), dirs_exist_ok=True)
    return _train_policies(out, configs, {s: [inputs[n] / "dataset" for n in datasets[s]] for s in configs},
                           {s: f"CNN {s} policy, DAgger round {len(datasets[s]) - 1}" for s in configs})


def _train_policies(out: Path, configs: dict[str, CNNPolicyConfig], datasets: dict[str, list[Path]],
                    names: dict[str, str]) -> dict:
    """Train the CNN policy of each subtask of `configs` on its `datasets` into out/cnn/SUBTASK. A policy already
    there at its config was trained by this stage before an interruption (the folder's key fixes the data), and is
    kept."""
    torch.set_num_threads(2)
    timings, nll = {}, {}
    for subtask, config in configs.items():
        if log := finished(out / "cnn" / subtask, config):
            timings[names[subtask]], losses = log["seconds"], log["losses"]
        else:
            t0 = time.perf_counter()
            _, losses = train_cnn_policy(datasets[subtask], config, out=out / "cnn" / subtask)
            timings[names[subtask]] = time.perf_counter() - t0
        nll[subtask] = [losses[0], losses[-1]]
        interrupt.check()
    return {"timings": timings, "nll": nll}


def _train_world(out: Path, inputs: dict[str, Path], vae, dynamics, goal, predicates, labelled,
                 cameras: tuple[str, ...]) -> dict:
    torch.set_num_threads(2)
    rollouts, demos = inputs["controller-rollouts"] / "dataset", inputs["full-task-demos"] / "dataset"
    timings = train_world_model(rollouts, demos, out / "world", vae, dynamics, resume=True)
    timings.update(train_goal_scores(demos, out / "world", cameras, goal, resume=True))
    figures = train_predicate_models([inputs[n] / "dataset" for n in labelled], out / "world", predicates,
                                     resume=True)
    timings.update({f"predicate {name}": f.pop("seconds") for name, f in figures.items()})
    return {"timings": timings, "predicates": figures}


def _train_straight(out: Path, inputs: dict[str, Path], dynamics) -> dict:
    """The world model with the straight-down insertions' dynamics models in place of the feeling ones': the same
    VAE, goal scorers and other controllers' models (copied), the two insertions' trained on their own rollouts."""
    torch.set_num_threads(2)
    world = out / "world"
    if world.exists():
        shutil.rmtree(world)
    shutil.copytree(inputs["world-model"] / "world", world)
    timings = train_world_model(inputs["straight-rollouts"] / "dataset", inputs["full-task-demos"] / "dataset", world,
                                dynamics_config=dynamics, controllers=list(STRAIGHT), reuse_vae=True)
    return {"timings": timings}


def _evaluate_goal(out: Path, inputs: dict[str, Path], cameras: tuple[str, ...]) -> dict:
    metrics = evaluate_goal_scores(inputs["world-model"] / "world", inputs["full-task-demos"] / "dataset", out, cameras)
    return {"metrics": metrics}


def _table(out: Path, inputs: dict[str, Path], p: Profile, kinds: tuple[str, ...], workers: int, task: str,
           insertion: str = "", columns: tuple[str, ...] | None = None) -> dict:
    """Table I's `columns` (default: all of them) for the rows of `kinds`, into out/controllers.md."""
    rows = evaluate_table(list(kinds), _sources(inputs, task, insertion), p.table_trials, 0, p.resolution,
                          workers=workers, columns=columns or SUBTASK_COLUMNS,
                          column_trials={"insert": p.insert_trials or p.table_trials})
    write_table(rows, out, paper=paper_table(task))
    return {"workers": workers,
            "rows": {kind: {c: [cell.successes, cell.trials, cell.safety_stops] for c, cell in row.items()}
                     for kind, row in rows.items()},
            "completed": {kind: row["full"].completed for kind, row in rows.items() if row["full"].trials}}


def _compose(out: Path, inputs: dict[str, Path], config, seeds: list[int], resolution: int,
             knock_out_step: int | None, workers: int, task: str, insertion: str, world: str) -> dict:
    episodes = compose_library(inputs[world] / "world", _sources(inputs, task, insertion), config, seeds, out,
                               videos=1,
                               resolution=resolution, knock_out_step=knock_out_step, resume=True,
                               workers=workers)
    return {"successes": [e.success for e in episodes], "knocked_out": [e.knocked_out for e in episodes],
            "workers": workers}


def _mdp(out: Path, inputs: dict[str, Path], p: Profile) -> dict:
    levels = {"levels": p.mdp_levels} if p.mdp_levels else {}
    s19, heatmaps = mdp.run_experiments(out, p.mdp_episodes_19, p.mdp_episodes_100, **levels)
    return {"mean_planning_steps_19": s19["mean_planning_steps"],
            "heatmap_range": {unit: h["claims"]["range"] for unit, h in heatmaps.items()}}
