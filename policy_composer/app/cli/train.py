"""`train`: the library's learned controllers (CNN policies, DMPs), the world model and the goal scores."""

from __future__ import annotations

import argparse
import time

from policy_composer.app.arguments import add_config_options, at_least, config_from, names
from policy_composer.app.cli.options import WORLD, dataset_path, env_options, training_threads
from policy_composer.data.atomic import check_replaceable
from policy_composer.data.catalog import dataset_spec
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.dmp.configuration_dmp import FIT_EPISODES, FIT_FIRST_SEED
from policy_composer.policies.sources import MODELS
from policy_composer.selector.configuration import DynamicsConfig, GoalScoreConfig, PredicateConfig, VAEConfig
from policy_composer.tasks.gear_assembly.spec import CAMERA_NAMES
from policy_composer.tasks.registry import DEFAULT_TASK, TASKS, get_spec, get_task


def cmd_train_policy(args: argparse.Namespace) -> int:
    """Behaviour-clone the CNN policy of one subtask on its demonstrations."""
    from policy_composer.policies.cnn.train import train_cnn_policy

    training_threads(args.threads)
    task = args.task or (dataset_spec(args.dataset[0]).name if args.dataset else DEFAULT_TASK)
    config = config_from(args, CNNPolicyConfig, task=task)
    dataset = args.dataset or [dataset_path(get_spec(config.task).demonstrations[config.subtask][0])]
    out = args.out or str(MODELS / "cnn" / config.subtask)
    t0 = time.time()
    _, losses = train_cnn_policy(dataset, config, out=out)
    print(f"trained {out} in {time.time() - t0:.0f} s: nll {losses[0]:.3f} -> {losses[-1]:.3f} "
          f"over {len(losses)} epochs")
    return 0


def cmd_train_dmp(args: argparse.Namespace) -> int:
    """Fit the DMP library to the motion planner's trajectories."""
    from policy_composer.learning.checkpoint import model_writer
    from policy_composer.policies.dmp.controller import DMP_FILES, fit_dmp_library

    with model_writer(args.out):
        check_replaceable(args.out, DMP_FILES, "a DMP library")
        task = get_task(args.task)
        env = task.make_env("state_dict", task.settings(args.resolution, clearance_mm=args.clearance))
        t0 = time.time()
        library = fit_dmp_library(env, seeds=list(range(args.seed, args.seed + args.episodes)))
        library.save(args.out)
        env.close()
    print(f"fitted DMPs to {args.episodes} planner episodes in {time.time() - t0:.0f} s -> {args.out}")
    return 0


def cmd_train_world_model(args: argparse.Namespace) -> int:
    """The VAE and one dynamics model per controller (paper: Controller Dynamics Modelling)."""
    from policy_composer.selector.train import train_world_model

    training_threads(args.threads)
    timings = train_world_model(
        args.rollouts, args.demos, args.out, config_from(args, VAEConfig), config_from(args, DynamicsConfig),
        controllers=list(args.controllers) if args.controllers else None, reuse_vae=args.reuse_vae)
    for what, seconds in timings.items():
        print(f"trained {what} in {seconds:.0f} s")
    return 0


def cmd_train_goal_score(args: argparse.Namespace) -> int:
    """One goal scorer per camera on the training full-task demos (paper: Goal Score Evaluation)."""
    from policy_composer.selector.train import train_goal_scores

    training_threads(args.threads)
    config = config_from(args, GoalScoreConfig)
    for what, seconds in train_goal_scores(args.demos, args.out, args.cameras, config).items():
        print(f"trained {what} in {seconds:.0f} s")
    return 0

def cmd_train_predicates(args: argparse.Namespace) -> int:
    """One classifier per task predicate on the labelled recordings: what the controllers sense."""
    from policy_composer.selector.train import train_predicate_models

    training_threads(args.threads)
    task = args.task or (dataset_spec(args.dataset[0]).name if args.dataset else DEFAULT_TASK)
    config = config_from(args, PredicateConfig, task=task, **({"cameras": args.cameras} if args.cameras else {}))
    spec = get_spec(task)
    labelled = (spec.controller_rollouts, spec.full_task_demos, spec.demonstrations["insert"][0],
                spec.corrections.get("insert"))
    datasets = args.dataset or [dataset_path(name) for name in labelled if name]
    for name, figures in train_predicate_models(datasets, args.out, config).items():
        print(f"trained predicate {name} in {figures['seconds']:.0f} s: held-out accuracy {figures['accuracy']:.3f}, "
              f"false positives {figures['false_positive_rate']:.3f} ({figures['frames']} frames, "
              f"{figures['positives']} positive)")
    return 0


def add_commands(sub) -> None:
    train = sub.add_parser("train", help="train the library's learned controllers")
    tr_sub = train.add_subparsers(dest="what", required=True)
    tr_policy = tr_sub.add_parser("policy", help="behaviour-clone a CNN + MDN policy (cnn_pick, cnn_move, cnn_insert)")
    tr_policy.add_argument("--dataset", nargs="+", help="its demonstrations (default: datasets/gear-insertion-demos "
                           "for the insertion, datasets/gear-transport-demos for the pick-up and the move), and any "
                           "corrections of its own rollouts (for the insertion: gear-insertion-dagger)")
    add_config_options(tr_policy, CNNPolicyConfig, {
        "subtask": "subtask", "camera": "camera", "view": "view", "backbone": "backbone", "epochs": "epochs",
        "image_size": "image-size", "num_mixtures": "mixtures", "action_space": "action-space",
        "proprioception": "proprioception", "shift": "shift", "batch_size": "batch-size", "seed": "seed",
        "max_steps": "max-steps", "offset_weight": "offset-weight", "precision": "precision"})
    tr_policy.add_argument("--task", choices=tuple(TASKS), help="the task the policy is for (default: the one its "
                           f"first dataset was recorded in, else {DEFAULT_TASK})")
    tr_policy.add_argument("--threads", type=at_least(1), default=2)
    tr_policy.add_argument("--out", help=f"checkpoint folder (default: {MODELS / 'cnn'}/SUBTASK, where the "
                           "library's CNN model looks)")
    tr_policy.set_defaults(func=cmd_train_policy)
    tr_dmp = tr_sub.add_parser("dmp", help="fit the DMPs to the motion planner's trajectories")
    env_options(tr_dmp, grasp=False, task=True)
    tr_dmp.add_argument("--episodes", type=at_least(1), default=FIT_EPISODES, help="planner episodes to fit to")
    tr_dmp.set_defaults(seed=FIT_FIRST_SEED)
    tr_dmp.add_argument("--out", default=str(MODELS / "dmp"))
    tr_dmp.set_defaults(func=cmd_train_dmp)

    tr_world = tr_sub.add_parser("world-model", help="the VAE and one latent dynamics model per controller")
    tr_world.add_argument("--rollouts", default=dataset_path("gear-controller-rollouts"))
    tr_world.add_argument("--demos", default=dataset_path("gear-full-task-demos"))
    add_config_options(tr_world, VAEConfig, {"camera": "camera", "image_size": "image-size", "latent_dim": "latent-dim",
                                             "epochs": "vae-epochs"})
    add_config_options(tr_world, DynamicsConfig, {"epochs": "dynamics-epochs", "frame_skip": "frame-skip",
                                                  "num_mixtures": "mixtures"})
    tr_world.add_argument("--controllers", type=names, default=None,
                          help="comma-separated (default: every controller recorded)")
    tr_world.add_argument("--reuse-vae", action="store_true", help="keep the VAE in --out; train only dynamics models")
    tr_world.add_argument("--threads", type=at_least(1), default=2)
    tr_world.add_argument("--out", default=WORLD)
    tr_world.set_defaults(func=cmd_train_world_model)
    tr_goal = tr_sub.add_parser("goal-score", help="one goal scorer per camera on the full-task demos")
    tr_goal.add_argument("--demos", default=dataset_path("gear-full-task-demos"))
    tr_goal.add_argument("--cameras", type=names, default=",".join(CAMERA_NAMES))
    add_config_options(tr_goal, GoalScoreConfig, {"epochs": "epochs", "image_size": "image-size",
                                                  "num_mixtures": "mixtures"})
    tr_goal.add_argument("--threads", type=at_least(1), default=2)
    tr_goal.add_argument("--out", default=WORLD, help="the world-model folder (its VAE, if any, is used)")
    tr_goal.set_defaults(func=cmd_train_goal_score)
    tr_pred = tr_sub.add_parser("predicates", help="one classifier per task predicate (gear grasped, on the peg, "
                                "seated, ...): what the controllers sense")
    tr_pred.add_argument("--dataset", nargs="+",
                         help="labelled recordings with the cameras the classifiers read (default: the task's "
                              "controller rollouts, full-task and insertion demos and the insertion's DAgger rollouts)")
    tr_pred.add_argument("--task", choices=tuple(TASKS), help="the task whose predicates they are (default: the one "
                         f"the first dataset was recorded in, else {DEFAULT_TASK})")
    tr_pred.add_argument("--cameras", type=names, help="comma-separated (default: the task's predicate cameras)")
    add_config_options(tr_pred, PredicateConfig, {"epochs": "epochs", "image_size": "image-size", "seed": "seed"})
    tr_pred.add_argument("--threads", type=at_least(1), default=2)
    tr_pred.add_argument("--out", default=WORLD, help="the world-model folder")
    tr_pred.set_defaults(func=cmd_train_predicates)
