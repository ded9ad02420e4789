"""Checkpoint and resume (``bsslam run --checkpoint-every``, ``--resume``): a run stopped
midway — by a crash in-process or a SIGKILL — and resumed from its checkpoint writes the
same files, byte for byte, as a run never stopped."""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from bsslam.cli import app
from bsslam.errors import ConfigError, InputError
from bsslam.helper_process import HelperProcess
from bsslam.io.checkpoint import (CHECKPOINT_FILE, CheckpointEvery, Checkpointer, CheckpointHeader, load_checkpoint,
                                  read_header, source_digest)
from bsslam.slam.state import JointState
from bsslam.submaps.pose_graph import PoseGraph

sys.path.insert(0, str(Path(__file__).parent))
from test_cli import write_carmen_log  # noqa: E402

runner = CliRunner()
#: The files whose bytes depend on the run's numbers only (pictures and wall times left out).
SAME_FILES = ("trajectory.tum", "trajectory_online.tum", "map.json", "pose_covariance.csv",
              "pose_covariance_online.csv", "odometry.tum", "frontend.tum", "grid.pgm", "map.geojson",
              "map_metric.svg", "config.yaml")
#: Summary entries that are wall times or about the checkpoints, not results.
NOT_RESULTS = ("wall_time_s", "relocalize_time_s", "loop_sweep_time_s", "ms_per_step", "checkpoints", "checkpoint_mb",
               "checkpoint_write_s", "resumed_at_frame", "frontend_in_helper")


def cli(*args, code=0):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == code, result.output
    return result


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """The rounded room's double loop as a CARMEN log, and a configuration with short
    submaps (8 m): several submaps and loop closures in 265 scans."""
    folder = tmp_path_factory.mktemp("room")
    log = write_carmen_log(folder / "room.clf", "rounded-room", 3, None)
    config = folder / "config.yaml"
    config.write_text("submaps:\n  max_distance_m: 8.0\n")
    return log, config


@pytest.fixture(scope="module")
def uninterrupted(room, tmp_path_factory):
    """The reference runs, one per backend, never stopped (and never checkpointed)."""
    log, config = room
    runs = {}
    for backend, steps in (("submaps", 265), ("ekf", 90)):
        out = tmp_path_factory.mktemp(f"reference-{backend}")
        cli("run", log, "--config", config, "--backend", backend, "--steps", steps, "--out", out, "-q",
            "--checkpoint-every", 0)
        runs[backend] = (out / "latest").resolve()
    return runs


def assert_same_results(reference: Path, resumed: Path) -> None:
    for name in SAME_FILES:
        if (reference / name).exists() or (resumed / name).exists():
            assert (reference / name).read_bytes() == (resumed / name).read_bytes(), name
    # steps.csv: all but the time column
    drop_time = [[c for i, c in enumerate(line.split(",")) if i != 1]
                 for line in (reference / "steps.csv").read_text().splitlines()]
    assert drop_time == [[c for i, c in enumerate(line.split(",")) if i != 1]
                         for line in (resumed / "steps.csv").read_text().splitlines()]
    a, b = (json.loads((run / "summary.json").read_text()) for run in (reference, resumed))
    assert {k: v for k, v in a.items() if k not in NOT_RESULTS} == {k: v for k, v in b.items() if k not in NOT_RESULTS}
    assert b["status"] == "complete"


# -- the parts ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, every", [("500", CheckpointEvery(scans=500)), ("60s", CheckpointEvery(seconds=60.0)),
                                         ("2.5s", CheckpointEvery(seconds=2.5)), (" 7 ", CheckpointEvery(scans=7)),
                                         ("0", CheckpointEvery()), ("0s", CheckpointEvery())])
def test_checkpoint_every_takes_scans_seconds_or_off(text, every):
    parsed = CheckpointEvery.parse(text)
    assert parsed == every and parsed.enabled == (text.strip() not in ("0", "0s"))
    assert CheckpointEvery.parse(str(parsed)) == parsed     # written into a checkpoint, read back


@pytest.mark.parametrize("text", ["-5", "1.5", "60m", "s", "", "nan s", "inf"])
def test_checkpoint_every_refuses_anything_else(text):
    with pytest.raises(ConfigError, match="--checkpoint-every"):
        CheckpointEvery.parse(text)


def test_a_checkpoint_is_due_after_n_scans_or_n_seconds(tmp_path):
    header = CheckpointHeader(log="x.clf", log_sha256="0" * 64, config={})
    by_scans = Checkpointer(tmp_path, CheckpointEvery(scans=5), header, start_frame=10)
    assert [f for f in range(11, 30) if by_scans.due(f)] == list(range(15, 30))   # until one is written
    by_scans.write(15, {"state": 1})
    assert not by_scans.due(19) and by_scans.due(20)
    now = [100.0]
    by_time = Checkpointer(tmp_path, CheckpointEvery(seconds=60), header, clock=lambda: now[0])
    assert not by_time.due(1000)
    now[0] = 160.0
    assert by_time.due(1)
    assert not Checkpointer(tmp_path, CheckpointEvery(), header).due(10 ** 9)


def test_a_failed_write_leaves_the_previous_checkpoint_whole(tmp_path, monkeypatch):
    log = tmp_path / "a.clf"
    log.write_text("not read here\n")
    header = CheckpointHeader(log=os.fspath(log), log_sha256="", config={"backend": "ekf"}, options={"steps": 3})
    writer = Checkpointer(tmp_path, CheckpointEvery(scans=1), header)
    writer(1, {"frames": [1]})
    saved = read_header(tmp_path)
    assert saved.next_frame == 1 and saved.options == {"steps": 3} and len(saved.log_sha256) == 64

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(InputError, match="No space left"):
        writer(2, {"frames": [1, 2]})
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.clf", CHECKPOINT_FILE]   # no temporary
    header, state = load_checkpoint(tmp_path)
    assert header.next_frame == 1 and state == {"frames": [1]}


def test_the_digest_of_a_log_file_or_bag_folder_sees_any_change(tmp_path):
    bag = tmp_path / "bag"
    (bag / "sub").mkdir(parents=True)
    (bag / "metadata.yaml").write_text("a")
    (bag / "sub" / "x.db3").write_bytes(b"\0\1")
    before = source_digest(bag)
    assert before == source_digest(bag) and len(before) == 64
    (bag / "sub" / "x.db3").write_bytes(b"\0\2")
    assert source_digest(bag) != before
    (bag / "sub" / "x.db3").write_bytes(b"\0\1")
    (bag / "sub" / "x.db3").rename(bag / "x.db3")       # same bytes, another name
    assert source_digest(bag) != before
    assert source_digest(bag / "metadata.yaml") == hashlib.sha256(b"a").hexdigest()


def test_the_pose_graph_pickles_as_its_calls_and_goes_on_bit_for_bit():
    rng = np.random.default_rng(0)
    graphs = [PoseGraph(np.zeros(3), robust_kernel_width=2.0)]

    def grow(graph, start):
        for i in range(start, start + 6):
            graph.add_node(np.r_[1.0, 0.1 * rng.standard_normal(2)], np.diag([1e-2, 1e-2, 1e-3]))
            graph.optimize()
            if i >= 3:
                graph.add_loop(i - 3, i + 1, np.r_[rng.standard_normal(2), 0.1], 0.05 * np.eye(3))
                graph.optimize()
            graph.covariance(i + 1)

    grow(graphs[0], 0)
    copy = pickle.loads(pickle.dumps(graphs[0]))
    assert np.array_equal(copy.poses(), graphs[0].poses()) and copy.loops == graphs[0].loops
    rng_state = rng.bit_generator.state
    grow(graphs[0], 6)
    rng.bit_generator.state = rng_state
    grow(copy, 6)
    assert np.array_equal(copy.poses(), graphs[0].poses())
    assert np.array_equal(copy.loop_weights(), graphs[0].loop_weights())
    assert np.array_equal(copy.relative(0, 12)[1], graphs[0].relative(0, 12)[1])


def test_the_joint_state_pickles_its_live_part_only():
    rng = np.random.default_rng(1)
    state = JointState(np.zeros(3), 0.01 * np.eye(3), capacity=512)
    A = rng.standard_normal((40, 43))
    state.append(rng.standard_normal(40), 0.1 * A[:, :3], A @ A.T + np.eye(40))
    state.subtract_column_update(np.array([0, 1, 5, 9]), 0.05 * rng.standard_normal((4, 2)))   # pending
    blob = pickle.dumps(state)
    assert len(blob) < state.nbytes / 20     # the 512-wide buffers' slack stays out
    copy = pickle.loads(blob)
    assert copy.capacity == state.capacity
    for s in (state, copy):
        s.subtract_column_update(np.array([2, 7, 30]), np.full((3, 1), 0.03))
        s.transform_pose(np.eye(3) + 0.01, 1e-4 * np.eye(3))
    assert np.array_equal(copy.x, state.x) and np.array_equal(copy.P, state.P)


# -- resume through the command line -------------------------------------------------------

class _Crash(BaseException):
    """A crash the run does not catch (as a kill, but in-process)."""


@pytest.mark.parametrize("backend, checkpoint_at, crash_at", [("submaps", 140, 150), ("ekf", 40, 47)])
def test_a_crashed_run_resumed_writes_the_same_files(backend, checkpoint_at, crash_at, room, uninterrupted,
                                                     tmp_path, monkeypatch):
    log, config = room
    steps = {"submaps": 265, "ekf": 90}[backend]
    write = Checkpointer.__call__

    def crash_later(self, next_frame, mapper):
        write(self, next_frame, mapper)
        if next_frame == crash_at:
            raise _Crash

    monkeypatch.setattr(Checkpointer, "__call__", crash_later)
    # in one process: with a helper, a checkpoint waits for the front end's state, which
    # comes a few frames later or many, as the two processes' speeds have it
    # (tests/test_helper_process.py checkpoints through a helper at set frames)
    with pytest.raises(_Crash):
        runner.invoke(app, [str(a) for a in ("run", log, "--config", config, "--backend", backend, "--steps", steps,
                                             "--out", tmp_path, "-q", "--checkpoint-every", checkpoint_at,
                                             "--no-parallel")])
    monkeypatch.undo()
    (run,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert read_header(run).next_frame == checkpoint_at and not (tmp_path / "latest").exists()
    if backend == "submaps":     # the checkpoint holds frozen submaps with loop closures
        assert load_checkpoint(run)[1].slam.graph.loop_count > 0

    cli("run", "--resume", run, "-q")
    assert_same_results(uninterrupted[backend], run)
    assert not (run / CHECKPOINT_FILE).exists()            # removed once the run completed
    assert (tmp_path / "latest").resolve() == run


def test_an_interrupted_run_keeps_its_checkpoint_and_says_how_to_resume(room, uninterrupted, tmp_path, monkeypatch):
    """Ctrl-C (or SIGTERM, which the command turns into one): the scans so far are written
    and marked interrupted, exit 130; the checkpoint stays for --resume."""
    log, config = room
    write = Checkpointer.__call__

    def interrupt_later(self, next_frame, mapper):
        write(self, next_frame, mapper)
        if next_frame == 33:
            raise KeyboardInterrupt("SIGTERM")

    monkeypatch.setattr(Checkpointer, "__call__", interrupt_later)
    result = cli("run", log, "--config", config, "--backend", "ekf", "--steps", 90, "--out", tmp_path, "-q",
                 "--checkpoint-every", 30, "--no-parallel", code=130)   # in one process: as above
    monkeypatch.undo()
    (run,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert f"bsslam run --resume {run}" in result.output
    summary = json.loads((run / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["scans"] == 33 and read_header(run).next_frame == 30
    cli("run", "--resume", run, "-q")
    assert_same_results(uninterrupted["ekf"], run)


def test_a_run_in_one_process_writes_the_same_files_as_one_with_a_helper(room, uninterrupted, tmp_path,
                                                                          monkeypatch):
    """``--no-parallel``: no helper process for the reader, the front end and the map
    picture; ``--parallel`` (the default) with the helper taking every frame (the run
    waits for it to start): the same files."""
    log, config = room
    args = ("run", log, "--config", config, "--backend", "submaps", "--steps", 265, "-q", "--checkpoint-every", 0)
    cli(*args, "--out", tmp_path / "one", "--no-parallel")
    monkeypatch.setattr(HelperProcess, "ready", lambda self: self.wait_ready(120))
    result = cli(*args, "--out", tmp_path / "two", "--parallel")
    two = (tmp_path / "two" / "latest").resolve()
    assert json.loads((two / "summary.json").read_text())["frontend_in_helper"] == 264, result.output
    for run in (tmp_path / "one", tmp_path / "two"):
        assert_same_results(uninterrupted["submaps"], (run / "latest").resolve())


def test_resume_refuses_a_changed_log_a_missing_checkpoint_and_options_of_its_own(room, uninterrupted, tmp_path):
    log, config = room
    copy = tmp_path / "room.clf"
    copy.write_bytes(log.read_bytes())
    header = CheckpointHeader(log=os.fspath(copy), log_sha256="", config={})
    (tmp_path / "run").mkdir()
    Checkpointer(tmp_path / "run", CheckpointEvery(scans=1), header).write(3, {"not": "a mapper"})
    with open(copy, "a") as f:
        f.write("# one more line\n")
    for run, message in ((tmp_path / "run", "the log changed since the checkpoint"),
                         (uninterrupted["ekf"], "has no checkpoint"),
                         (tmp_path / "nowhere", "no such run folder")):
        result = cli("run", "--resume", run, code=2)
        assert message in result.output and len(result.output.strip().splitlines()) == 1, result.output
    result = cli("run", log, "--resume", tmp_path / "run", "--backend", "ekf", code=2)
    assert "drop LOG, --backend" in result.output
    assert "--checkpoint-every" in cli("run", log, "--checkpoint-every", "10m", code=2).output


def test_a_run_killed_by_sigkill_resumes_to_the_same_files(room, uninterrupted, tmp_path):
    """The real thing: ``python -m bsslam run`` in a subprocess, SIGKILLed once its
    checkpoint is past frame 100, then ``--resume``d."""
    log, config = room
    env = {**os.environ, "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}   # this checkout's bsslam
    process = subprocess.Popen([sys.executable, "-m", "bsslam", "run", log, "--config", config, "--backend",
                                "submaps", "--out", tmp_path, "-q", "--checkpoint-every", "5",
                                "--no-parallel"],     # a helper could be done with the short log at once
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while True:
            runs = [p for p in tmp_path.iterdir() if (p / CHECKPOINT_FILE).exists()]
            if runs and read_header(runs[0]).next_frame >= 100:
                break
            assert process.poll() is None, f"the run ended before its checkpoint: {process.stderr.read()}"
            assert time.monotonic() < deadline, "no checkpoint past frame 100 in 120 s"
            time.sleep(0.02)
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
        process.stderr.close()
    run = runs[0]
    assert process.returncode == -signal.SIGKILL and not (run / "summary.json").exists()
    assert read_header(run).next_frame < 265

    cli("run", "--resume", run, "-q")
    assert_same_results(uninterrupted["submaps"], run)
    assert [p.name for p in run.iterdir() if p.name.startswith(".")] == []   # no temporary left
    assert (tmp_path / "latest").resolve() == run

