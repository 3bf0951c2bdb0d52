"""Episodes across processes: the same results as the serial loop, in the order of the seeds."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace

import numpy as np
import psutil
import pytest
import torch

from policy_composer.app.controller_table import evaluate_rows
from policy_composer.app.record import record_recipe
from policy_composer.app.workers import ClusterError, ray_head, run_episodes, stop_ray, use_ray
from policy_composer.data.recipes import load_recipe
from policy_composer.data.verify import open_dataset
from policy_composer.policies.library import LibrarySources
from policy_composer.tasks.gear_assembly.spec import EnvSettings


def _square(x: int) -> int:
    return x * x


def _squarer():
    return _square


def _broken():
    raise ValueError("no model at /nowhere: train it first")


def test_a_worker_that_cannot_start_raises_its_error_instead_of_hanging():
    with pytest.raises(ValueError, match="no model at /nowhere"):
        run_episodes(_broken, [1, 2], workers=2)


def test_results_come_back_in_the_order_of_the_items():
    seen = []
    assert run_episodes(_squarer, [3, 1, 2], workers=2, on_result=lambda i, r: seen.append((i, r))) == [9, 1, 4]
    assert sorted(seen) == [(1, 1), (2, 4), (3, 9)]  # each result is handed over as it arrives
    assert run_episodes(_squarer, [], workers=2) == []


@pytest.mark.timeout(600)
def test_table_one_on_two_workers_gives_the_serial_cells():
    rows = {"MP": ("mp_pick", "mp_insert")}
    serial, parallel = (evaluate_rows(rows, LibrarySources(), trials=1, first_seed=40, resolution=32, progress=False,
                                      workers=w) for w in (1, 2))
    assert parallel == serial
    assert [serial["MP"][c].trials for c in ("pick", "move", "insert", "full")] == [1, 0, 1, 0]


@pytest.mark.timeout(600)
def test_rollouts_recorded_on_two_workers_are_the_serial_dataset(controller_rollouts, tmp_path):
    """The same recipe and seeds on 2 workers: one LeRobot dataset, equal to the serial one episode for episode."""
    root = tmp_path / "rollouts"
    recipe = replace(load_recipe("gear-controller-rollouts"), controllers=("mp_pick", "mp_insert"))
    record_recipe(recipe, root, episodes=1, settings=EnvSettings(resolution=32), progress=False,
                  sources=LibrarySources(max_grasp_offset=0.0), workers=2)
    assert_same_dataset(root, controller_rollouts)


def assert_same_dataset(root, serial) -> None:
    """The dataset at `root` is the serial recording `serial`, episode for episode and frame for frame."""
    ours, theirs = (json.loads((r / "meta" / "policy_composer.json").read_text()) for r in (root, serial))
    assert ours == theirs  # seeds, controllers, outcomes, lengths, next seed, digests
    ours, theirs = open_dataset(root), open_dataset(serial)
    assert ours.num_frames == theirs.num_frames
    for column in ("observation.state", "action", "controller", "progress", "episode_index"):
        assert torch.equal(torch.as_tensor(np.stack(ours.hf_dataset[column])),
                           torch.as_tensor(np.stack(theirs.hf_dataset[column]))), column
    for i in (0, ours.num_frames - 1):  # the videos decode to the same images
        for key in ours.meta.video_keys:
            assert torch.equal(ours[i][key], theirs[i][key]), (i, key)


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A Ray head on 127.0.0.1 with 2 CPUs, this module's alone; this process runs its episode loops there."""
    ray = pytest.importorskip("ray", reason="Ray is the distributed extra (scripts/setup.sh installs it)")
    with ray_head(2, tmp_path_factory.mktemp("ray")) as address:
        try:
            for _ in range(120):  # the raylet registers a few seconds after the port opens (more on a busy machine)
                try:
                    assert use_ray(address) == 2
                    break
                except ClusterError:
                    time.sleep(1)
            else:
                pytest.fail(f"the Ray head at {address} did not start")
            yield address
        finally:
            stop_ray()
    assert not ray.is_initialized()


def test_episodes_on_a_ray_cluster_are_the_serial_ones_and_a_killed_worker_runs_its_episode_again(
        ray_cluster, transport_demos, tmp_path):
    """Two workers as Ray actors: the results in the order of the items; a worker killed while the episodes run is
    restarted and its episode (if it had one) run again, and this process writes each episode once: the serial
    dataset."""
    killed = []

    def kill_one_worker():
        """The first worker seen, running an episode or waiting for one: the pool's actors live as long as the
        recording, so one is always found (waiting for one mid-episode would race a fast machine's episodes)."""
        while not killed:
            for p in psutil.process_iter(["cmdline"]):
                if (p.info["cmdline"] or [""])[0].startswith("ray::PoolActor"):
                    p.kill()
                    killed.append(p.pid)
                    return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_worker, daemon=True)
    killer.start()
    root = tmp_path / "gear-transport-demos"
    record_recipe(load_recipe("gear-transport-demos"), root, episodes=2, settings=EnvSettings(resolution=32),
                  progress=False, workers=2)
    assert killed, "the recording ended before the killer saw a worker"
    assert_same_dataset(root, transport_demos)
