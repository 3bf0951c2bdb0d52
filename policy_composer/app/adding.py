"""A LeRobot checkpoint joins the library in one step: its rollouts, its dynamics model, its Table I cell.

Like every controller of the library, a checkpoint the user brings is chosen by the selector only through its own
dynamics model, learned from its own rollouts; its Table I cell says how it does alone. The rollouts go into the
library's rollouts dataset (continued with its own settings), and the dynamics model is trained with the world
model's VAE and the configuration of the dynamics models already there, so that the selector looks as far ahead
with it as with the others.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import torch

from policy_composer.app.controller_table import evaluate_controllers
from policy_composer.app.record import record_recipe
from policy_composer.data.features import read_sidecar
from policy_composer.data.recipes import load_recipe
from policy_composer.policies.library import LeRobotSource, LibraryError, LibrarySources, all_names
from policy_composer.selector.dynamics import load_dynamics
from policy_composer.selector.train import train_world_model
from policy_composer.tasks.gear_assembly.spec import EnvSettings


def add_lerobot_controller(source: LeRobotSource, rollouts: str | Path, demos: str | Path, models: str | Path,
                           episodes: int, trials: int, seed: int, progress: bool = True) -> dict:
    """Record `episodes` rollouts of the checkpoint's controller into `rollouts`, train its dynamics model into
    `models`, and run it `trials` times on its subtask from seed `seed`. Returns the timings (s) and the cell."""
    rollouts, models, name = Path(rollouts), Path(models), source.controller_name
    if name in all_names():
        raise LibraryError(f"{name!r} is already a controller of the library; name the checkpoint's controller "
                           f"otherwise (PATH:{source.subtask}:NAME)")
    if not (rollouts / "meta" / "policy_composer.json").is_file():
        raise LibraryError(f"{rollouts} holds no controller rollouts; record the library's first "
                           f"(`policy-composer record gear-controller-rollouts --root {rollouts}`)")
    others = sorted(p.parent for p in (models / "dynamics").glob("*/config.json") if p.parent.name != name)
    if not (models / "vae" / "config.json").is_file() or not others:
        raise LibraryError(f"{models} holds no world model to add to; train it first (`policy-composer train "
                           f"world-model --rollouts {rollouts} --out {models}`)")
    sources, settings = LibrarySources(lerobot=(source,)), EnvSettings(**read_sidecar(rollouts)["env"])
    timings = {}
    t0 = time.perf_counter()
    record_recipe(replace(load_recipe("gear-controller-rollouts"), controllers=(name,)), rollouts, episodes=episodes,
                  resume=True, settings=settings, sources=sources, progress=progress)
    timings["rollouts"] = time.perf_counter() - t0
    dynamics = replace(load_dynamics(others[0]).config, controller=name)
    torch.set_num_threads(2)
    timings.update(train_world_model(rollouts, demos, models, dynamics_config=dynamics, controllers=[name],
                                     reuse_vae=True, progress=progress))
    t0 = time.perf_counter()
    row = evaluate_controllers([name], sources, trials, seed, settings.resolution, settings.clearance_mm, progress,
                               f"{name} on {source.subtask}")
    timings["evaluation"] = time.perf_counter() - t0
    return {"controller": name, "subtask": source.subtask, "cell": row[source.subtask], "timings": timings}
