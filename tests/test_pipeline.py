"""The main job: stages kept under their configuration's key, reused, resumed; `policy-composer demo` end to end,
and its report rendered with its figures and videos in a real headless browser."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from html import unescape
from pathlib import Path

import pytest
from conftest import run_cli

from policy_composer.app import demo
from policy_composer.app.demo import _train_cnn
from policy_composer.app.pipeline import MARKER, Stage, StageRecord, run_stages, stage_key
from policy_composer.app.profiles import PROFILES
from policy_composer.app.report import _header
from policy_composer.data.interrupt import flag_interrupts
from policy_composer.learning.checkpoint import weights_id
from policy_composer.policies.cnn import train
from policy_composer.policies.cnn.configuration_cnn import CNNPolicyConfig
from policy_composer.tasks.registry import DEFAULT_TASK, get_spec

ROOT = Path(__file__).resolve().parents[1]


def _stages(calls: list[str], record_config: dict, fail_train: bool = False) -> list[Stage]:
    def record(out: Path, _):
        calls.append("record")
        done = len(list(out.glob("episode_*")))  # a recording keeps its finished episodes
        for i in range(done, 3):
            (out / f"episode_{i}").write_text(str(i))
        return {"episodes": 3, "recorded_now": 3 - done}

    def train(out: Path, inputs):
        calls.append("train")
        assert not any(out.iterdir()), "an unfinished non-resumable stage must start from an empty folder"
        (out / "partial").write_text("half an epoch")
        if fail_train:
            raise KeyboardInterrupt
        (out / "model").write_text(str(len(list(inputs["record"].glob("episode_*")))))
        return {"trained_on": int((out / "model").read_text())}

    return [Stage("record", "record", record_config, record, resumable=True),
            Stage("train", "train", {"epochs": 2}, train, inputs=("record",))]


def test_stages_are_reused_resumed_and_rerun_when_their_configuration_changes(tmp_path):
    calls: list[str] = []
    with pytest.raises(KeyboardInterrupt):  # interrupted in the second stage
        run_stages(_stages(calls, {"episodes": 3}, fail_train=True), tmp_path, log=lambda _: None)
    assert calls == ["record", "train"]
    record_dir = next(tmp_path.glob("record-*"))
    assert (record_dir / MARKER).exists() and not any(tmp_path.glob(f"train-*/{MARKER}"))

    records = run_stages(_stages(calls, {"episodes": 3}), tmp_path, log=lambda _: None)  # resumes at "train"
    assert calls == ["record", "train", "train"]
    assert records["record"].reused and not records["train"].reused
    assert records["train"].facts == {"trained_on": 3}
    assert json.loads((records["train"].folder / MARKER).read_text())["inputs"] == {"record": records["record"].key}

    again = run_stages(_stages(calls, {"episodes": 3}), tmp_path, log=lambda _: None)  # everything reused
    assert calls == ["record", "train", "train"] and all(r.reused for r in again.values())
    assert again["train"].facts == {"trained_on": 3}

    changed = run_stages(_stages(calls, {"episodes": 3, "resolution": 64}), tmp_path, log=lambda _: None)
    assert calls[3:] == ["record", "train"]  # a new recording key re-runs everything downstream of it
    assert changed["train"].key != records["train"].key
    assert records["train"].folder.exists() and changed["train"].folder.exists()  # old outputs kept


def test_an_interrupted_recording_stage_keeps_its_episodes(tmp_path):
    calls: list[str] = []
    stage = _stages(calls, {"episodes": 3})[0]
    folder = tmp_path / "partial"
    run = stage.run

    def interrupted(out: Path, inputs):
        (out / "episode_0").write_text("0")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_stages([Stage(stage.name, stage.title, stage.config, interrupted, resumable=True)], folder,
                   log=lambda _: None)
    records = run_stages([Stage(stage.name, stage.title, stage.config, run, resumable=True)], folder,
                         log=lambda _: None)
    assert records["record"].facts == {"episodes": 3, "recorded_now": 2}


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_ctrl_c_that_a_stage_swallows_still_stops_the_run_after_that_stage(tmp_path):
    """A KeyboardInterrupt raised inside a `__del__` is printed and dropped by Python; the run must stop anyway."""
    calls: list[str] = []

    class ClosesOnCollect:  # like a progress bar that writes when it is collected
        def __del__(self):
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C lands here: its KeyboardInterrupt is ignored
            time.sleep(0.05)

    stages = _stages(calls, {"episodes": 3})
    recording = stages[0].run

    def record(out: Path, inputs):
        ClosesOnCollect()
        return recording(out, inputs)

    stages[0] = Stage("record", "record", {"episodes": 3}, record, resumable=True)
    with flag_interrupts(), pytest.raises(KeyboardInterrupt):
        run_stages(stages, tmp_path, log=lambda _: None)
    assert calls == ["record"]  # the recording finished (and is kept), training never started
    assert (next(tmp_path.glob("record-*")) / MARKER).exists()
    run_stages(stages, tmp_path, log=lambda _: None)  # outside flag_interrupts nothing stale is left
    assert calls == ["record", "train"]


def test_a_stage_reading_a_missing_stage_is_refused(tmp_path):
    with pytest.raises(ValueError, match="reads \\['record'\\]"):
        run_stages([Stage("train", "train", {}, lambda out, i: {}, inputs=("record",))], tmp_path)


@pytest.mark.parametrize("task", [DEFAULT_TASK, "peg-insertion-side"])
def test_the_cnn_policies_are_trained_again_when_their_task_picks_other_frames_of_the_same_recording(task,
                                                                                                     monkeypatch):
    """Which stages of its demonstrations a CNN policy learns from is the task spec's, not the recording's: a change
    there keys the training stages (and the DAgger rounds') anew, the recordings not."""
    def keys() -> dict[str, str]:
        made = demo.stages(PROFILES["quick"], task=task)
        recorded: dict[str, str] = {}
        for stage in made:  # the stages in order, as run_stages keys them
            recorded[stage.name] = stage_key(stage, {n: recorded[n] for n in stage.inputs})
        return recorded

    before, spec = keys(), get_spec(task)
    recipe, _ = spec.demonstrations["insert"]
    changed = replace(spec, demonstrations={**spec.demonstrations, "insert": (recipe, (1, 2))})
    monkeypatch.setattr(demo, "get_spec", lambda name: changed if name == task else get_spec(name))
    after = keys()
    trained = {n for n in before if n in ("cnn", demo.BC_STAGE) or n.startswith("dagger-cnn")}
    assert trained and all(after[n] != before[n] for n in trained)
    assert all(after[n] == before[n] for n in before if n.endswith("-demos"))


def test_an_interrupted_cnn_training_stage_keeps_the_policies_it_finished(insertion_demos, transport_demos,
                                                                         tmp_path, monkeypatch):
    inputs = {}
    for stage, dataset in (("insertion-demos", insertion_demos), ("transport-demos", transport_demos)):
        (tmp_path / stage).mkdir()
        (tmp_path / stage / "dataset").symlink_to(dataset)
        inputs[stage] = tmp_path / stage
    configs = {s: CNNPolicyConfig(subtask=s, epochs=1, num_mixtures=2, image_size=32, batch_size=32)
               for s in ("move", "insert")}
    real, trained = train.train_cnn_policy, []

    def interrupted_at_the_insertion(root, config, **kwargs):
        if config.subtask == "insert":
            raise KeyboardInterrupt
        trained.append(config.subtask)
        return real(root, config, **kwargs)

    out = tmp_path / "bc-cnn"
    monkeypatch.setattr(demo, "train_cnn_policy", interrupted_at_the_insertion)
    with pytest.raises(KeyboardInterrupt):
        _train_cnn(out, inputs, configs, get_spec("gear-assembly"))
    move = weights_id(out / "cnn" / "move")
    assert trained == ["move"] and not (out / "cnn" / "insert").exists()

    def counted(root, config, **kwargs):
        trained.append(config.subtask)
        return real(root, config, **kwargs)

    monkeypatch.setattr(demo, "train_cnn_policy", counted)
    facts = _train_cnn(out, inputs, configs, get_spec("gear-assembly"))
    assert trained == ["move", "insert"], "the move policy, finished before the interruption, was trained again"
    assert weights_id(out / "cnn" / "move") == move and (out / "cnn" / "insert" / "model.safetensors").exists()
    assert set(facts["timings"]) == {"CNN move policy", "CNN insert policy"} and set(facts["nll"]) == set(configs)

    configs["move"] = CNNPolicyConfig(subtask="move", epochs=2, num_mixtures=2, image_size=32, batch_size=32)
    _train_cnn(out, inputs, configs, get_spec("gear-assembly"))  # a policy at another config is trained again
    assert trained == ["move", "insert", "move"]


def _browser_check(html: Path) -> dict:
    """Open `html` in headless Chromium; return each image's natural width and each video's ready state."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "Chromium is not installed: run scripts/setup.sh"
    probe = html.with_name("_probe.html")
    probe.write_text(html.read_text().replace("</body>", """<script>
window.addEventListener('load', () => setTimeout(() => {
  const images = [...document.images].map(i => [i.getAttribute('src'), i.naturalWidth]);
  const videos = [...document.querySelectorAll('video')].map(v => [v.getAttribute('src'), v.readyState, v.videoWidth]);
  document.body.setAttribute('data-probe', JSON.stringify({images, videos}));
}, 1000));
</script></body>"""))
    out = subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=10000",
                          "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120)
    probe.unlink()
    found = re.search(r'data-probe="([^"]*)"', out.stdout)
    assert found, f"the page did not load in Chromium: {out.stderr[-2000:]}"
    return json.loads(unescape(found.group(1)))


def _interrupt_once_a_full_task_demo_is_saved(cmd: list[str], env: dict, out: Path) -> subprocess.CompletedProcess:
    """Start the main job, Ctrl-C it once its full-task recording has saved an episode; its exit code and output."""
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as in a terminal
    streams = {"stdout": [], "stderr": []}
    readers = [threading.Thread(target=acc.extend, args=(getattr(proc, name),), daemon=True)
               for name, acc in streams.items()]  # drained as it runs: a full pipe would stall the job
    for reader in readers:
        reader.start()
    t0 = time.time()
    while time.time() - t0 < 600:
        sidecars = list(out.glob("pipeline/full-task-demos-*/dataset/meta/policy_composer.json"))
        try:
            if sidecars and json.loads(sidecars[0].read_text())["episodes"]:
                break
        except json.JSONDecodeError:
            pass
        assert proc.poll() is None, "".join(streams["stderr"])[-3000:]
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=300)
    for reader in readers:
        reader.join(timeout=10)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(streams["stdout"]), "".join(streams["stderr"]))


def _messages(stderr: str) -> str:
    """A run's stderr without its progress bars (what to show when a check fails)."""
    return "\n".join(line for line in stderr.replace("\r", "\n").splitlines() if line.strip() and "it/s]" not in line
                     and not re.search(r"\d+%\|", line))


def _table_cells(stage: Path) -> dict[str, list[str]]:
    """A Table I stage's rows that ran: the kind's cell, then its pick, move, insert and full-task cells."""
    return {line.split(" | ")[0]: line.split(" | ")[1:] for line in (stage / "controllers.md").read_text().splitlines()
            if line.startswith("| ") and " (95% CI " in line}


@pytest.mark.runs_first
@pytest.mark.timeout(3600)
def test_the_main_job_runs_every_stage_reuses_them_and_writes_a_report_a_browser_renders(tmp_path):
    exe = Path(sys.executable).parent / "policy-composer"
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    cmd = [str(exe), "demo", "--profile", "smoke", "--out", str(tmp_path)]
    interrupted = _interrupt_once_a_full_task_demo_is_saved(cmd, env, tmp_path)
    assert interrupted.returncode == 130 and "run the same command again to resume" in interrupted.stderr, \
        _messages(interrupted.stderr)[-4000:]
    first = run_cli(*cmd[1:], cwd=ROOT)  # resumed in-process: only the interrupt needs a process of its own
    assert first.returncode == 0, first.stdout[-3000:] + _messages(first.stderr)[-4000:]
    resumed = [line for line in first.stdout.splitlines() if line.startswith("[")]
    assert ": reused " in resumed[0] and ": reused " in resumed[1]  # the demos finished before the interrupt
    assert resumed[2].startswith("[3/21] record the full-task") and resumed[2].endswith("(resuming)"), resumed[2]
    second = run_cli(*cmd[1:], cwd=ROOT)
    assert second.returncode == 0, _messages(second.stderr)[-4000:]
    stage_lines = [line for line in second.stdout.splitlines() if line.startswith("[")]
    assert len(stage_lines) == 21 and all(": reused " in line for line in stage_lines), second.stdout

    report = (tmp_path / "report.md").read_text()
    for row in ("| MP |", "| DMP |", "| CNN |", "| composed (selector), oracle predicates |", "| head |",
                "| left_forearm |", "| right_forearm |", "planning steps to the goal", "| step | chosen |",
                "## Machine", "(95% CI ", "| composed (selector), sensed predicates | picked ", " frames/s",
                " episodes/s", " trials/s", "| gear_seated | "):
        assert row in report, f"{row!r} missing from the report"
    assert "0 of 21 stages ran" in report
    # The paper's experiment comes first: its Table I with the straight-down insertions, and which controller
    # served each subtask in its composed episodes.
    assert report.index("## Table I, the paper's experiment") < report.index("## Table I beyond the paper")
    assert report.index("| subtask | finished by | tried, not finished |") < report.index("## Table I beyond")

    # Table I's stage: every kind's row, each cell one trial with its interval beside the paper's, the insertion's
    # two (the profile's insert_trials).
    table = next((tmp_path / "pipeline").glob("table-*"))
    rows = _table_cells(table)
    assert set(rows) == {"| MP", "| DMP", "| CNN"}, rows
    assert all(["/1 (95% CI " in c for c in r] == [True, True, False, True] and "/2 (95% CI " in r[2]
               for r in rows.values()), rows
    assert "paper 10/10" in rows["| MP"][0] and (table / "controllers.csv").read_text().count("\n") == 1 + 3 * 4
    # The straight-down table runs the planned kinds' insert and full task only (pick and move do not change).
    straight = next((tmp_path / "pipeline").glob("straight-table-*"))
    rows = _table_cells(straight)
    assert set(rows) == {"| MP", "| DMP"}, rows
    assert all(r[0].startswith("-") and "/2 (95% CI " in r[2] and "/1 (95% CI " in r[3] for r in rows.values()), rows
    # The MDP stage: both experiments' tables, figures, trace and report.
    mdp = next((tmp_path / "pipeline").glob("mdp-*"))
    for name in ("mdp19_solution.png", "mdp19_episodes.csv", "mdp19_trace.json", "mdp100_heatmap_lookahead.png",
                 "mdp100_heatmap_step.csv", "mdp_report.md"):
        assert (mdp / name).stat().st_size > 0, name
    with open(mdp / "mdp100_heatmap_lookahead.csv") as f:
        assert {(float(r["p_dyn"]), float(r["p_goal"])) for r in csv.DictReader(f)} == {
            (a, b) for a in (0.0, 0.4, 0.8) for b in (0.0, 0.4, 0.8)}
    trace = json.loads((mdp / "mdp19_trace.json").read_text())
    assert trace[-1]["reached"] in (0, 20) and set(trace[0]["predicted_mean"]) == {"c1", "c2", "c3", "c4", "c5"}
    assert "| 19 states from state 1, p = 0.2" in (mdp / "mdp_report.md").read_text()

    probe = _browser_check(tmp_path / "report.html")
    images = dict(probe["images"])
    assert {"report/goal_score.png", "report/mdp19_solution.png", "report/mdp100_heatmap_lookahead.png",
            "report/straight_goal_score.png"} <= set(images)
    assert all(width > 0 for width in images.values()), f"figures that did not render: {images}"
    assert probe["videos"] and all(state >= 1 and width > 0 for _, state, width in probe["videos"]), probe["videos"]


def test_the_report_states_only_its_own_runs_figures(tmp_path):
    """Figures other runs measured are not written into a report as its own: they are named, dated and linked."""
    out = tmp_path / "results"
    records = {"compose": StageRecord("compose", "compose", "k", out / "pipeline" / "compose-k", 60.0, False)}
    header = _header(PROFILES["quick"], records, 60.0, out, get_spec("gear-assembly"))
    assert "99/100" not in header and "20 of 20" not in header
    # Its sizes are the ones the stages train with: the insertion's own epochs and bfloat16 included.
    assert f"CNN 80 epochs, the insertion {PROFILES['quick'].insert_epochs}, in bfloat16 for the pick" in header
    line = next(line for line in header.splitlines() if line.startswith("**Measured elsewhere, not by this run:**"))
    assert "(measured 2026-12-05)" in line
    target = re.search(r"\]\(([^)#]+)#the-main-job\)", line).group(1)
    assert (out / target).resolve() == ROOT / "README.md"
    assert "## The main job" in (ROOT / "README.md").read_text()


def test_another_tasks_report_claims_none_of_the_gears_figures(tmp_path):
    """The profiles' words on what holds at their size are the gear's figures (keyed by it): a second task's report
    points to its own docs instead."""
    out = tmp_path / "results"
    records = {"compose": StageRecord("compose", "compose", "k", out / "pipeline" / "compose-k", 60.0, False)}
    header = _header(PROFILES["quick"], records, 60.0, out, get_spec("peg-insertion-side"))
    assert PROFILES["quick"].holds[DEFAULT_TASK] not in header and "Measured elsewhere" not in header
    assert "PegInsertionSide-v1's held-out figures are in the task's docs" in header
