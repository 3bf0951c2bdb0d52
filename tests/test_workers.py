"""Episodes across processes: the same results as the serial loop, in the order of the seeds."""

from __future__ import annotations

import pytest

from policy_composer.controller_table import evaluate_rows
from policy_composer.policies.library import LibrarySources
from policy_composer.workers import run_episodes


def _square(x: int) -> int:
    return x * x


def _squarer():
    return _square


def test_results_come_back_in_the_order_of_the_items():
    seen = []
    assert run_episodes(_squarer, [3, 1, 2], workers=2, on_result=lambda i, r: seen.append((i, r))) == [9, 1, 4]
    assert sorted(seen) == [(1, 1), (2, 4), (3, 9)]  # each result is handed over as it arrives
    assert run_episodes(_squarer, [], workers=2) == []


@pytest.mark.timeout(600)
def test_table_one_on_two_workers_gives_the_serial_cells():
    rows = {"MP": ("mp_pick", "mp_insert")}
    serial, parallel = (evaluate_rows(rows, LibrarySources(), trials=2, first_seed=40, resolution=32, progress=False,
                                      workers=w) for w in (1, 2))
    assert parallel == serial
    assert [serial["MP"][c].trials for c in ("pick", "move", "insert", "full")] == [2, 0, 2, 0]
