"""`dataset`: inspect, label, view and share recorded LeRobot datasets."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from policy_composer.app.arguments import at_least


def cmd_dataset_info(args: argparse.Namespace) -> int:
    from policy_composer.data.catalog import format_summary, summarize

    print(format_summary(summarize(args.path)))
    return 0


def cmd_dataset_drop(args: argparse.Namespace) -> int:
    """Remove a controller's rollouts (then record them again with `record gear-controller-rollouts --resume`)."""
    from policy_composer.data.catalog import drop_controller

    print(f"removed {drop_controller(args.path, args.controller)} episodes of {args.controller} from {args.path}")
    return 0


def cmd_dataset_view(args: argparse.Namespace) -> int:
    """LeRobot's rerun viewer on one episode, with the project's labels: saved to --out, or shown."""
    from policy_composer.data.catalog import view_dataset

    path = view_dataset(args.path, args.episode, args.out)
    if path is not None:
        print(f"wrote {path} (open it with `rerun {path}`)")
    return 0


def cmd_dataset_card(args: argparse.Namespace) -> int:
    """The dataset card `dataset push` uploads, built offline: printed, or written to --out."""
    from policy_composer.data.catalog import dataset_card

    card = str(dataset_card(args.path, args.repo_id))
    if args.out:
        Path(args.out).write_text(card)
        print(f"wrote {args.out}")
    else:
        print(card)
    return 0


def cmd_dataset_push(args: argparse.Namespace) -> int:
    from policy_composer.data.catalog import HubUnreachable, push_dataset

    try:
        url = push_dataset(args.path, args.repo_id, private=args.private, branch=args.branch)
    except (HubUnreachable, ValueError) as e:
        print(f"push failed: {e}", file=sys.stderr)
        return 2
    print(f"pushed {args.path} to {url}")
    return 0



def add_commands(sub) -> None:
    dataset = sub.add_parser("dataset", help="inspect and share recorded LeRobot datasets")
    ds_sub = dataset.add_subparsers(dest="what", required=True)
    info = ds_sub.add_parser("info", help="episodes, frames, features, cameras, fps, success rate")
    info.add_argument("path")
    info.set_defaults(func=cmd_dataset_info)
    drop = ds_sub.add_parser("drop", help="remove one controller's episodes from a controller-rollouts dataset")
    drop.add_argument("path")
    drop.add_argument("--controller", required=True)
    drop.set_defaults(func=cmd_dataset_drop)
    view = ds_sub.add_parser("view", help="LeRobot's rerun viewer on one episode, with the labels (progress, stage, "
                             "controller)")
    view.add_argument("path")
    view.add_argument("--episode", type=at_least(0), default=0)
    view.add_argument("--out", default=None, help="save an .rrd file in this folder instead of opening the viewer")
    view.set_defaults(func=cmd_dataset_view)
    card = ds_sub.add_parser("card", help="the dataset card `push` uploads (recipe, task, cameras, labels, success)")
    card.add_argument("path")
    card.add_argument("--repo-id", default=None, help="USER/NAME the card will link to")
    card.add_argument("--out", default=None, help="write it to this file (default: print it)")
    card.set_defaults(func=cmd_dataset_card)
    push = ds_sub.add_parser("push", help="upload to the Hugging Face Hub with LeRobotDataset.push_to_hub, with "
                             "its dataset card")
    push.add_argument("path")
    push.add_argument("--repo-id", required=True, help="USER/NAME of the Hub dataset repo")
    push.add_argument("--private", action="store_true")
    push.add_argument("--branch", default=None)
    push.set_defaults(func=cmd_dataset_push, online=True)  # the one command that needs the Hub
