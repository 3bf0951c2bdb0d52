"""`record`: a dataset recipe (datasets/recipes/) into a LeRobotDataset."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields, replace
from pathlib import Path

from policy_composer.app.arguments import at_least, names
from policy_composer.app.cli.options import env_options, episode_workers, library_sources, model_options, workers_option
from policy_composer.data.features import read_sidecar
from policy_composer.data.recipes import RecipeError, available_recipes, load_recipe


def cmd_record(args: argparse.Namespace) -> int:
    """Record a recipe's dataset (see datasets/recipes/) into a LeRobotDataset."""
    from policy_composer.app.record import recipe_controllers, record_recipe
    from policy_composer.data.catalog import format_summary, summarize

    recipe = load_recipe(args.recipe)
    sources = library_sources(args, recipe.task_name)
    if args.controllers:
        chosen = args.controllers
        known = (*recipe_controllers(recipe), *(s.controller_name for s in sources.lerobot))
        if recipe.driver == "expert" or set(chosen) - set(known) or (recipe.driver == "dagger" and len(chosen) > 1):
            raise RecipeError(f"--controllers must name controllers of recipe {recipe.name} or --lerobot ones "
                              f"({', '.join(known) or 'it runs none'}), not {', '.join(chosen)}")
        recipe = replace(recipe, controllers=chosen)
    root = Path(args.root) if args.root else Path("datasets") / recipe.name
    given = {k: v for k, v in (("resolution", args.resolution), ("clearance_mm", args.clearance)) if v is not None}
    env_settings = recipe.spec.env_settings
    unknown = [k for k in given if k not in {f.name for f in fields(env_settings)}]
    if unknown:
        raise RecipeError(f"{recipe.spec.env_id} has no setting {unknown[0].removesuffix('_mm')}: leave the flag out "
                          f"for recipe {recipe.name}")
    previous = read_sidecar(root).get("env") if args.resume else None  # a flag not given keeps the dataset's value
    settings = replace(env_settings(**previous), **given) if previous else env_settings(**given)
    try:
        record_recipe(recipe, root, episodes=args.episodes, seed=args.seed, resume=args.resume, settings=settings,
                      sources=sources, workers=episode_workers(args))
    except KeyboardInterrupt:
        print(f"\ninterrupted: every finished episode is saved in {root}; continue with --resume", file=sys.stderr)
        return 130
    print(format_summary(summarize(root)))
    return 0



def add_commands(sub) -> None:
    record = sub.add_parser("record", help="record a dataset recipe (datasets/recipes/) into a LeRobotDataset")
    record.add_argument("recipe", help=f"recipe name ({', '.join(available_recipes())}) or path of a .toml recipe")
    record.add_argument("--episodes", type=at_least(1), default=None,
                        help="episodes the dataset should hold (default: the recipe's)")
    record.add_argument("--root", default=None, help="dataset folder (default: datasets/RECIPE)")
    record.add_argument("--resume", action="store_true", help="continue an interrupted or shorter recording")
    env_options(record, grasp=False)
    record.set_defaults(resolution=None, clearance=None, seed=None)  # not given: the defaults, or the resumed dataset's
    record.add_argument("--controllers", type=names, default=None,
                        help="comma-separated subset of the recipe's controllers to record (recipes that run "
                             "the controllers), or the one a dagger recipe runs")
    model_options(record)
    workers_option(record)
    record.set_defaults(func=cmd_record)
