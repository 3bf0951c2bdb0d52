"""Nothing a user owns is overwritten, nothing non-finite trains, and a model is what its files say: each refusal
one line, exit 2, before any work, and every file that was there before byte-identical after."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import safetensors.torch
import torch
from conftest import run_cli, tree_digest
from test_writers import holder, one_line_error, small_disk

from policy_composer.app.record import first_seed_of
from policy_composer.data.features import read_sidecar
from policy_composer.learning import checkpoint
from policy_composer.learning.checkpoint import CheckpointError, save_checkpoint, weights_id
from policy_composer.learning.training import TrainingDiverged
from policy_composer.policies.cnn import train
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.policies.cnn.modeling_cnn import CNNPolicy
from policy_composer.policies.cnn.train import load_cnn_policy, train_cnn_policy
from policy_composer.selector.configuration import VAEConfig
from policy_composer.selector.vae import VAE

TINY = ("--epochs", "1", "--mixtures", "2", "--image-size", "32", "--batch-size", "32")


def _copy(dataset: Path, to: Path) -> Path:
    return Path(shutil.copytree(dataset, to))


def _train(dataset: Path, out: Path, *more: str):
    return run_cli("train", "policy", "--dataset", str(dataset), *more, *TINY, "--out", str(out))


def _cnn_checkpoint(folder: Path, **changes) -> Path:
    """A real (untrained) CNN policy checkpoint at 32 px."""
    config = CNNPolicyConfig(image_size=32, num_mixtures=2, **changes)
    save_checkpoint(CNNPolicy(config), config, folder)
    return folder


@pytest.mark.parametrize("what", ["dataset", "notes", "vae"])
def test_train_policy_does_not_replace_a_folder_it_did_not_write(insertion_demos, tmp_path, what):
    """--out on a LeRobot dataset, on a folder of the user's notes, or on another kind of model: refused before the
    training, the folder as it was. A checkpoint of its own kind is replaced (retraining into one place)."""
    out = tmp_path / "out"
    if what == "dataset":
        _copy(insertion_demos, out)
        message = "holds data, meta, videos, which a CNNPolicyConfig checkpoint does not consist of"
    elif what == "notes":
        out.mkdir()
        (out / "notes.txt").write_text("my notes")
        message = "holds notes.txt, which a CNNPolicyConfig checkpoint does not consist of"
    else:
        config = VAEConfig(image_size=32, latent_dim=8)
        save_checkpoint(VAE(config), config, out)
        message = f"{out} holds a VAEConfig checkpoint, not a CNNPolicyConfig checkpoint"
    before = tree_digest(out)
    line = one_line_error(_train(insertion_demos, out))
    assert message in line and "give --out" in line, line
    assert tree_digest(out) == before

    own = _cnn_checkpoint(tmp_path / "own")
    assert _train(insertion_demos, own).returncode == 0
    assert json.loads((own / "train_log.json").read_text())["frames"] > 0


def test_a_second_training_into_one_folder_is_refused_at_once(insertion_demos, tmp_path):
    out = _cnn_checkpoint(tmp_path / "cnn")
    before = tree_digest(out)
    with holder(out):
        line = one_line_error(_train(insertion_demos, out))
    assert f"{out.resolve()} is being written by another process" in line
    assert tree_digest(out) == before


def _with_value(dataset: Path, column: str, value: float) -> Path:
    """The dataset with one value of a numeric column replaced, its digest updated as a recording that wrote the
    value would have it."""
    path = sorted((dataset / "data").rglob("*.parquet"))[0]
    table = pq.read_table(path)
    rows = table.column(column).to_pylist()
    rows[5] = [value, *rows[5][1:]] if isinstance(rows[5], list) else value
    table = table.set_column(table.column_names.index(column), column, pa.array(rows, table.schema.field(column).type))
    pq.write_table(table, path)
    sidecar = dataset / "meta" / "policy_composer.json"
    meta = json.loads(sidecar.read_text())
    meta["data_digests"][str(path.relative_to(dataset))] = hashlib.sha256(path.read_bytes()).hexdigest()
    sidecar.write_text(json.dumps(meta))
    return dataset


@pytest.mark.parametrize("column, value", [("observation.state", float("nan")), ("action", float("inf"))])
def test_a_non_finite_value_is_refused_where_it_enters(insertion_demos, tmp_path, column, value):
    bad = _with_value(_copy(insertion_demos, tmp_path / "bad"), column, value)
    line = one_line_error(run_cli("dataset", "info", str(bad)))
    assert f"{bad} holds a value that is not finite (NaN or Inf): data/chunk-000/file-000.parquet, column " \
           f"'{column}', episode_index 0, frame_index 5" in line, line
    out = _cnn_checkpoint(tmp_path / "cnn")
    before = tree_digest(out), tree_digest(bad)
    line = one_line_error(run_cli("train", "policy", "--dataset", str(insertion_demos), str(bad), *TINY,
                                  "--out", str(out)))  # beside a good dataset too
    assert "holds a value that is not finite" in line and column in line
    assert (tree_digest(out), tree_digest(bad)) == before


def test_a_training_that_diverges_stops_and_saves_nothing(insertion_demos, tmp_path, monkeypatch):
    loss = CNNPolicy.loss
    monkeypatch.setattr(CNNPolicy, "loss", lambda self, *a: loss(self, *a) * torch.tensor(float("nan")))
    config = CNNPolicyConfig(epochs=2, num_mixtures=2, image_size=32, batch_size=32)
    with pytest.raises(TrainingDiverged, match=r"training cnn policy: the loss is nan at epoch 1, batch 1 .* "
                                               r"nothing was saved"):
        train_cnn_policy(insertion_demos, config, out=tmp_path / "cnn", progress=False)
    assert not (tmp_path / "cnn").exists() and not (tmp_path / "cnn.snapshot").exists()


def test_a_dataset_given_twice_is_refused(insertion_demos, tmp_path):
    again = f"{insertion_demos}/../{insertion_demos.name}"
    line = one_line_error(run_cli("train", "policy", "--dataset", str(insertion_demos), again, *TINY,
                                  "--out", str(tmp_path / "cnn")))
    assert f"--dataset lists {again} twice (as {insertion_demos})" in line
    assert not (tmp_path / "cnn").exists()


def test_dagger_refuses_a_policy_of_another_subtask_in_the_insertions_place(tmp_path):
    cnn = tmp_path / "cnn"
    _cnn_checkpoint(cnn / "insert", subtask="pick")
    before = tree_digest(cnn)
    line = one_line_error(run_cli("record", "gear-insertion-dagger", "--cnn", str(cnn), "--episodes", "1",
                                  "--resolution", "32", "--root", str(tmp_path / "dagger")))
    assert f"checkpoint {cnn / 'insert'} is a CNN policy of the pick subtask (its config.json says so), in the " \
           "insert policy's place" in line
    assert tree_digest(cnn) == before and not (tmp_path / "dagger").exists()


def test_a_model_is_what_its_files_say(tmp_path):
    """config.json edited after the training (another image size) is refused where the model loads, and the model's
    id covers its configuration as well as its weights."""
    folder = _cnn_checkpoint(tmp_path / "cnn")
    trained = weights_id(folder)
    config = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps({**config, "image_size": 128}))
    assert weights_id(folder) != trained
    with pytest.raises(CheckpointError, match=r"config.json says image_size 128 \(trained with 32\): it no longer "
                                              r"describes the weights beside it"):
        load_cnn_policy(folder)
    line = one_line_error(run_cli("evaluate", "controllers", "--kinds", "CNN", "--subtasks", "insert", "--trials",
                                  "1", "--resolution", "32", "--cnn", str(folder), "--workers", "1",
                                  "--senses", "oracle"))
    assert "says image_size 128 (trained with 32)" in line


def test_resume_takes_the_command_that_began_the_dataset(insertion_demos, tmp_path):
    """`--resume` with the dataset's own first seed (the habit LeRobot's recorder teaches) continues it; another
    seed is refused, naming both."""
    root = _copy(insertion_demos, tmp_path / "demos")
    first = first_seed_of(read_sidecar(root))
    before = tree_digest(root)
    done = run_cli("record", "gear-insertion-demos", "--root", str(root), "--seed", str(first), "--resume",
                   "--episodes", "2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert tree_digest(root) == before  # it held its 2 episodes already
    line = one_line_error(run_cli("record", "gear-insertion-demos", "--root", str(root), "--seed", "9999",
                                  "--resume", "--episodes", "3"))
    assert f"first seed 9999 (it began at seed {first} and continues from seed" in line


def test_a_read_only_out_is_refused_before_the_training(insertion_demos, tmp_path, monkeypatch):
    monkeypatch.setattr(train, "load_demonstrations", lambda *a, **k: pytest.fail("the training began"))
    with small_disk(tmp_path / "ro", "1m", read_only=True, fallback="test_a_read_only_folder_is_one_line") as disk:
        line = one_line_error(_train(insertion_demos, disk / "cnn"))
    assert "Read-only file system" in line


def _train_onto_a_full_disk(insertion_demos: Path, out: Path) -> None:
    before = tree_digest(out)
    line = one_line_error(_train(insertion_demos, out))
    assert "No space left on device" in line and str(out) in line
    assert tree_digest(out) == before  # the model trained before it


def test_a_full_disk_at_the_save_is_one_line_and_the_old_model_stays(insertion_demos, tmp_path):
    with small_disk(tmp_path / "disk", "2m", fallback="test_a_save_that_runs_out_of_room_is_one_line") as disk:
        out = _cnn_checkpoint(disk / "cnn")
        with open(disk / "filler", "wb") as f:
            f.write(b"\0" * (2 * 2**20 - 3 * (out / "model.safetensors").stat().st_size // 2))
        _train_onto_a_full_disk(insertion_demos, out)


def test_a_save_that_runs_out_of_room_is_one_line(insertion_demos, tmp_path, monkeypatch):
    """The full disk's path without a small disk: safetensors fails as it does on one (its own error, the OS's code
    in its text)."""
    def full(*args, **kwargs):
        raise safetensors.SafetensorError("Error while serializing: I/O error: No space left on device (os error 28)")

    out = _cnn_checkpoint(tmp_path / "cnn")
    monkeypatch.setattr(checkpoint, "save_file", full)
    _train_onto_a_full_disk(insertion_demos, out)


def test_a_damaged_lerobot_checkpoint_is_named(cnn_mdn_checkpoint, tmp_path):
    checkpoint, _ = cnn_mdn_checkpoint
    ckpt = _copy(checkpoint, tmp_path / "ckpt")
    weights = ckpt / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[:100])
    line = one_line_error(run_cli("library", "add", "--lerobot", f"{ckpt}:insert:mine", cwd=tmp_path))
    assert f"{weights} is not a readable safetensors file" in line
    (ckpt / "config.json").write_text("[1, 2]")
    line = one_line_error(run_cli("compose", "--lerobot", f"{ckpt}:insert", cwd=tmp_path))
    assert f"{ckpt / 'config.json'} is not a LeRobot policy config" in line


def test_one_checkpoint_given_twice_is_refused(cnn_mdn_checkpoint, tmp_path):
    checkpoint, _ = cnn_mdn_checkpoint
    line = one_line_error(run_cli("compose", "--lerobot", f"{checkpoint}:insert", "--lerobot",
                                  f"{checkpoint}:insert", "--out", str(tmp_path / "run"), cwd=tmp_path))
    assert "--lerobot names controllers lerobot_insert, lerobot_insert: each needs a name of its own" in line
    assert not (tmp_path / "run").exists()
