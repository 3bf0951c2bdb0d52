"""The ``policy-composer`` command line: one module per command group, each adding its commands to the parser.

Building the parser imports only light modules (names, configs, recipes; no simulator, torch or LeRobot), so that
`--help` and the flags' checks answer at once: a command imports what it runs when it runs."""

from __future__ import annotations

import argparse
import errno
import os
import sys

from policy_composer.app.cli import compose, dataset, evaluate, experiments, record, train
from policy_composer.app.errors import ClusterError, RunError
from policy_composer.data.atomic import FolderTaken
from policy_composer.data.features import DatasetError
from policy_composer.data.interrupt import flag_interrupts
from policy_composer.data.lock import FolderBusy
from policy_composer.data.recipes import RecipeError
from policy_composer.learning.errors import CheckpointError, TrainingDiverged
from policy_composer.policies.registry import LibraryError

DISK_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)
GROUPS = (experiments, evaluate, train, compose, record, dataset)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="policy-composer", description=(
        "Compose diverse controllers (motion planning, DMPs, a visual CNN, LeRobot policies) with a learned goal "
        "score, in ManiSkill with LeRobot datasets."))
    sub = parser.add_subparsers(dest="command", required=True)
    for group in GROUPS:
        group.add_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not getattr(args, "online", False):  # everything but an upload works offline
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
    try:
        with flag_interrupts():  # a Ctrl-C swallowed by a library is raised again at the next episode or stage
            return args.func(args)
    except (DatasetError, RecipeError, CheckpointError, LibraryError, RunError, FolderBusy, FolderTaken,
            FileNotFoundError, ClusterError, TrainingDiverged) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # the disk, not the program: one line, and the fix
        if e.errno not in DISK_ERRORS:
            raise
        print(f"error: cannot write {e.filename or 'the output'}: {e.strerror or e}; free some space or write "
              "elsewhere (--root, --out); what was saved before is intact", file=sys.stderr)
        return 2
