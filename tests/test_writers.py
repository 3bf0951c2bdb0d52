"""One writer at a time, and nothing mistyped, damaged or out of space runs: each refused with one line, exit 2,
and what was written before left as it was."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio
import numpy as np
import pytest
import torch
from conftest import run_cli, tree_digest
from safetensors.torch import load_file

from policy_composer.app.composition import RunError, VideoWriter, begin_run, compose_library
from policy_composer.data import lock, recorder
from policy_composer.data.features import read_info
from policy_composer.data.lock import FolderBusy, lock_path, one_writer
from policy_composer.data.recipes import load_recipe
from policy_composer.learning.snapshot import Snapshots
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.policies.cnn.train import load_demonstrations, train_cnn_policy
from policy_composer.selector.configuration import ComposeConfig

BIN = Path(sys.executable).parent
HOLD = "import sys, time; from policy_composer.data.lock import one_writer\nwith one_writer(sys.argv[1]):\n" \
       "    print('held', flush=True); time.sleep(600)"


def one_line_error(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2, res.stdout + res.stderr
    assert "Traceback" not in res.stderr, res.stderr
    lines = res.stderr.strip().splitlines()  # a progress bar may stand above it
    assert [line for line in lines if line.startswith("error:")] == lines[-1:], res.stderr
    return lines[-1]


@contextlib.contextmanager
def holder(folder: Path):
    """Another process holding `folder`'s writer lock."""
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        yield proc
    finally:
        proc.kill()
        proc.wait()


def test_a_second_writer_is_refused_at_once_and_the_first_ones_data_stays(insertion_demos, tmp_path):
    root = tmp_path / "demos"
    shutil.copytree(insertion_demos, root)
    before = tree_digest(root)
    with holder(root) as proc:
        t0 = time.perf_counter()
        line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "4", "--resume", "--root",
                                  str(root)))
        assert f"{root} is being written by another process (pid {proc.pid})" in line
        assert time.perf_counter() - t0 < 60  # at once: no episode was run
        with pytest.raises(FolderBusy, match=f"pid {proc.pid}"):
            compose_library(tmp_path / "no-models", None, ComposeConfig(), [0], root)
        assert run_cli("dataset", "info", str(root)).returncode == 0  # readers are not blocked
    assert tree_digest(root) == before


def test_a_killed_writer_leaves_no_stale_lock(tmp_path):
    folder = tmp_path / "out"
    with holder(folder) as proc:
        with pytest.raises(FolderBusy), one_writer(folder):
            pass
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        with one_writer(folder), one_writer(folder):  # the kernel released it; this process may nest its own
            assert lock_path(folder.resolve()).read_text().strip() == str(os.getpid())


@pytest.mark.parametrize("text, message", [
    ('name = "../../escaped_by_name"\n', "recipe name '../../escaped_by_name' is not a plain name"),
    ('name = ".hidden"\n', "recipe name '.hidden' is not a plain name"),
    ("name = [unclosed\n", "is not a readable TOML file"),
    (b"\x89PNG\r\n\x1a\n\x00\xff", "is not a readable TOML file"),
    ('name = "mine"\nepisodes = "many"\n', 'episodes must be a whole number, not \'many\''),
    ('name = "mine"\nepisodes = 0\n', "recipe mine: episodes must be at least 1, not 0"),
    ('name = "mine"\n[expert]\ngrip = 1\n', "[expert]: unknown keys ['grip']"),
    ('name = "mine"\n[expert]\ngrasp_offset_mm = -1e9\n', "grasp_offset_mm must be between 0 and 19 mm"),
    ("", "missing keys ['name']"),
])
def test_a_bad_recipe_file_is_refused_before_anything_is_written(tmp_path, text, message):
    base = load_recipe("gear-insertion-demos")
    recipe = tmp_path / "a" / "b" / "recipe.toml"
    recipe.parent.mkdir(parents=True)
    if isinstance(text, bytes):
        recipe.write_bytes(text)
    else:  # the rest of a valid recipe, so that only what `text` says is wrong (a table last, as TOML has it)
        given, table, rest = text.partition("\n[")
        recipe.write_text(given + "\n" * bool(given) + "".join(
            f'{k} = {json.dumps(getattr(base, k))}\n' for k in ("description", "task", "episodes", "driver", "start")
            if f"{k} =" not in given) + table.lstrip("\n") + rest)
    line = one_line_error(run_cli("record", str(recipe), "--episodes", "1", cwd=recipe.parent))
    assert message in line and ("TOML" not in message or str(recipe) in line)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b", "recipe.toml"]


@contextlib.contextmanager
def small_disk(path: Path, size: str, read_only: bool = False, *, fallback: str):
    """A tmpfs of `size` at `path`. Where mounting is refused (no root, or a container without CAP_SYS_ADMIN) the
    test skips, naming the test that takes the same path with the OS error raised where the disk would raise it."""
    path.mkdir(parents=True)
    options = f"size={size}" + (",ro" if read_only else "")
    mount = shutil.which("mount")
    if not mount or subprocess.run([mount, "-t", "tmpfs", "-o", options, "tmpfs", str(path)],
                                   capture_output=True).returncode:
        pytest.skip(f"mounting a {size} tmpfs is refused here; {fallback} takes the same path on any machine")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)


def disk_error(code: int, path: Path):
    """What a write on a full or read-only disk raises."""
    def raising(*args, **kwargs):
        raise OSError(code, os.strerror(code), str(path))
    return raising


def test_a_full_disk_mid_episode_leaves_the_dataset_as_it_was(tmp_path):
    with small_disk(tmp_path / "disk", "64m", fallback="test_a_save_failing_mid_episode_rolls_back") as disk:
        root = disk / "demos"
        res = run_cli("record", "gear-insertion-demos", "--episodes", "1", "--resolution", "32", "--root", str(root))
        assert res.returncode == 0, res.stderr[-2000:]
        before = tree_digest(root)
        # The disk fills up, but for room to begin the next episode's save.
        with open(disk / "filler", "wb", buffering=0) as f:
            with contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * 4096)
                    f.flush()
            f.truncate(f.tell() - 64 * 1024)
        line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "2", "--resume", "--root",
                                  str(root)))
        assert "No space left on device" in line, line
        assert tree_digest(root) == before and read_info(root)["total_episodes"] == 1
        (disk / "filler").unlink()
        assert run_cli("dataset", "info", str(root)).returncode == 0


def test_a_save_failing_mid_episode_rolls_back(insertion_demos, tmp_path, monkeypatch):
    """The full disk's path without a small disk: the episode's files written, then the save fails with ENOSPC."""
    root = Path(shutil.copytree(insertion_demos, tmp_path / "demos"))
    before = tree_digest(root)
    monkeypatch.setattr(recorder, "data_digests", disk_error(errno.ENOSPC, root / "data"))
    line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "3", "--resume", "--root",
                                  str(root)))
    assert "episode 2 was not saved" in line and "No space left on device" in line, line
    assert tree_digest(root) == before and read_info(root)["total_episodes"] == 2


def test_a_read_only_disk_is_one_line(tmp_path):
    with small_disk(tmp_path / "ro", "1m", read_only=True, fallback="test_a_read_only_folder_is_one_line") as disk:
        line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "1", "--root",
                                  str(disk / "demos")))
        assert "Read-only file system" in line and str(disk) in line


def test_a_read_only_folder_is_one_line(tmp_path, monkeypatch):
    """The read-only disk's path without one: the first write (the writer's lock) fails with EROFS."""
    monkeypatch.setattr(lock.os, "open", disk_error(errno.EROFS, tmp_path / ".demos.lock"))
    line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "1", "--root",
                                  str(tmp_path / "demos")))
    assert "Read-only file system" in line and str(tmp_path) in line


def test_a_damaged_data_file_is_named_by_dataset_info(insertion_demos, tmp_path):
    """Damage in the middle of a parquet file, its footer intact: its values still read (parquet keeps no
    checksums), but not the digest saved with it, and info says which file."""
    root = tmp_path / "demos"
    shutil.copytree(insertion_demos, root)
    data = sorted((root / "data").rglob("*.parquet"))[0]
    raw = bytearray(data.read_bytes())
    raw[len(raw) // 3:len(raw) // 3 + 64] = b"\xff" * 64
    data.write_bytes(bytes(raw))
    line = one_line_error(run_cli("dataset", "info", str(root)))
    assert f"{data} does not hold what was recorded (its SHA-256 differs" in line


def test_world_model_controllers_are_those_recorded(controller_rollouts, full_task_demos, tmp_path):
    line = one_line_error(run_cli("train", "world-model", "--rollouts", str(controller_rollouts), "--demos",
                              str(full_task_demos), "--controllers", "mp_pick,nosuch", "--out", str(tmp_path / "w")))
    assert "holds no rollouts of nosuch: --controllers takes the controllers it recorded, mp_pick, mp_insert" in line
    assert not (tmp_path / "w").exists()


def test_run_files_that_do_not_read_or_no_longer_fit(tmp_path):
    out = tmp_path / "compose"
    out.mkdir()
    (out / "run.json").write_text("{not json")
    with pytest.raises(RunError, match="run.json is not readable JSON .* compose into another --out"):
        begin_run(out, resume=True, settings={"resolution": 64})
    (out / "run.json").write_text("[1, 2]")
    with pytest.raises(RunError, match=r"run.json is not readable JSON \(a JSON list, not an object\)"):
        begin_run(out, resume=True, settings={"resolution": 64})
    # A run killed right after writing its settings: the next new run there is labelled with its own.
    (out / "run.json").write_text(json.dumps({"config": {"horizon": 3}}))
    begin_run(out, resume=False, settings={"config": {"horizon": 10}})
    assert json.loads((out / "run.json").read_text()) == {"config": {"horizon": 10}}
    with pytest.raises(RunError, match="differs in config"):
        begin_run(out, resume=True, settings={"config": {"horizon": 5}})


def test_recording_over_a_dataset_without_resume_is_one_line(insertion_demos, tmp_path):
    root = tmp_path / "demos"
    shutil.copytree(insertion_demos, root)
    line = one_line_error(run_cli("record", "gear-insertion-demos", "--episodes", "1", "--root", str(root)))
    assert f"{root} already exists (2 episodes); pass --resume to append to it" in line


def test_a_video_the_encoder_did_not_finish_is_not_put_in_place(tmp_path, monkeypatch):
    """As ffmpeg on a full disk: the writer returns, the file is truncated. Nothing replaces the target."""
    video = VideoWriter("head")
    video.frames = [np.zeros((32, 32, 3), np.uint8)] * 10
    monkeypatch.setattr(imageio, "mimsave", lambda path, frames, **kw: Path(path).write_bytes(b"\x00\x00\x00\x18ftyp"))
    with pytest.raises(OSError, match="holds 0 of its 10 frames") as caught:
        video.save(tmp_path / "composed.mp4", fps=20)
    assert caught.value.errno == errno.EIO and not any(tmp_path.iterdir())


def test_an_interrupted_training_goes_on_from_its_snapshot_to_the_uninterrupted_weights(insertion_demos, tmp_path,
                                                                                        monkeypatch):
    config = CNNPolicyConfig(subtask="insert", epochs=4, num_mixtures=2, image_size=32, batch_size=32)
    data = load_demonstrations(insertion_demos, config, progress=False)
    _, whole = train_cnn_policy(insertion_demos, config, out=tmp_path / "whole", progress=False, data=data)

    monkeypatch.setattr(Snapshots, "due", lambda self: True)  # a snapshot after every epoch
    save, saved = Snapshots.save, []

    def killed_after_the_second(self, epoch, *args):
        save(self, epoch, *args)
        saved.append(epoch)
        if epoch == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(Snapshots, "save", killed_after_the_second)
    with pytest.raises(KeyboardInterrupt):
        train_cnn_policy(insertion_demos, config, out=tmp_path / "cut", progress=False, data=data)
    snapshot = tmp_path / "cut.snapshot"
    assert saved == [1, 2] and (snapshot / "state.json").exists() and not (tmp_path / "cut").exists()
    model = CNNPolicy(config)
    opt = torch.optim.Adam(model.parameters())
    assert Snapshots(snapshot, of="another training").restore(model, opt, None, torch.Generator()) == (0, [])

    _, resumed = train_cnn_policy(insertion_demos, config, out=tmp_path / "cut", progress=False, data=data)
    assert saved == [1, 2, 3], "the resumed training started again from the first epoch"
    assert resumed == whole
    a, b = (load_file(str(tmp_path / name / "model.safetensors")) for name in ("whole", "cut"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert not snapshot.exists(), "the snapshot outlived the saved model"
