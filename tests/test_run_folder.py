"""The life of a run folder: ``latest`` moves only to a complete run; a failed or interrupted
run says so in its ``summary.json``; faults of the output path are one-line errors; SIGINT
and SIGTERM end ``bsslam simulate`` with exit 130 and whole files."""

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

import bsslam.io.atomic_file as atomic_file
import bsslam.pipeline as pipeline
from bsslam.cli import app
from bsslam.errors import FilterError, InputError
from bsslam.io.map_file import read_map_json
from bsslam.io.results import create_run_dir, publish_run, run_folder, write_summary
from bsslam.io.trajectory_file import read_trajectory

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"


def simulate(out, *extra):
    return runner.invoke(app, ["simulate", "--world", "mixed", "--steps", "3", "--out", str(out), *map(str, extra)])


def good_run(out) -> Path:
    result = simulate(out)
    assert result.exit_code == 0, result.output
    return (out / "latest").resolve()


def runs(out):
    return sorted(p for p in out.iterdir() if p.is_dir() and not p.is_symlink())


def summary_of(run):
    return json.loads((run / "summary.json").read_text())


def one_line_error(result, code=2):
    assert result.exit_code == code, result.output
    assert isinstance(result.exception, SystemExit)          # no traceback
    assert "Traceback" not in result.output
    # the progress bar may have drawn before the error; the message itself is one line
    lines = [line for line in result.output.splitlines() if line.startswith(("error:", "interrupted"))]
    assert len(lines) == 1 and lines[0] == result.output.rstrip().splitlines()[-1], result.output
    return lines[0]


def assert_whole(run: Path):
    """Every file in the folder is complete: no temporaries, JSON parses, TUM rows have
    eight numbers, the map reads."""
    for path in run.iterdir():
        assert not path.name.startswith("."), path
        if path.suffix == ".json":
            json.loads(path.read_text())
        if path.suffix == ".tum":
            rows = [line.split() for line in path.read_text().splitlines() if not line.startswith("#")]
            assert all(len(r) == 8 for r in rows) and read_trajectory(path) is not None
        if path.name == "map.json":
            read_map_json(path)


# ---------------------------------------------------------------------------- library
def test_latest_moves_only_to_a_complete_run(tmp_path):
    first = create_run_dir(tmp_path)
    assert not (tmp_path / "latest").exists()
    write_summary(first, {}, "complete")
    assert publish_run(first)
    second = create_run_dir(tmp_path)
    write_summary(second, {}, "interrupted", "by SIGINT")
    assert not publish_run(second)
    assert (tmp_path / "latest").resolve() == first
    third = create_run_dir(tmp_path)
    assert not publish_run(third)                 # no summary at all
    assert (tmp_path / "latest").resolve() == first


def test_run_folder_marks_failures_and_interruptions(tmp_path):
    with pytest.raises(FilterError):
        with run_folder(tmp_path) as failed:
            raise FilterError("covariance not positive definite")
    assert summary_of(failed) == {"status": "failed", "reason": "covariance not positive definite"}
    with pytest.raises(KeyboardInterrupt):
        with run_folder(tmp_path) as stopped:
            raise KeyboardInterrupt("SIGTERM")
    assert summary_of(stopped) == {"status": "interrupted", "reason": "interrupted by SIGTERM"}
    assert not (tmp_path / "latest").exists()
    with run_folder(tmp_path) as good:
        write_summary(good, {"scans": 1}, "complete")
    assert (tmp_path / "latest").resolve() == good


def test_a_folder_that_cannot_be_created_is_an_input_error(tmp_path, monkeypatch):
    def refuse(self, *args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))

    monkeypatch.setattr(Path, "mkdir", refuse)
    with pytest.raises(InputError, match="Permission denied") as info:
        create_run_dir(tmp_path / "out")
    assert "out" in str(info.value)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_results_folder_is_a_one_line_error(tmp_path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o500)
    try:
        line = one_line_error(simulate(out))
    finally:
        out.chmod(0o700)
    assert str(out) in line


# ---------------------------------------------------------------------------- CLI faults
def test_out_is_a_file(tmp_path):
    out = tmp_path / "file"
    out.write_text("x")
    line = one_line_error(simulate(out))
    assert str(out) in line and "file" in line


def test_out_under_a_file(tmp_path):
    (tmp_path / "file").write_text("x")
    line = one_line_error(simulate(tmp_path / "file" / "results"))
    assert "file" in line


def test_latest_is_a_real_folder(tmp_path):
    (tmp_path / "latest").mkdir()
    (tmp_path / "latest" / "keep.txt").write_text("mine")
    line = one_line_error(simulate(tmp_path))
    assert str(tmp_path / "latest") in line
    assert (tmp_path / "latest" / "keep.txt").read_text() == "mine"
    assert runs(tmp_path) == [tmp_path / "latest"]      # no run folder was made


def test_a_full_disk_mid_run_is_a_one_line_error_and_leaves_no_cut_file(tmp_path, monkeypatch):
    previous = good_run(tmp_path)
    real_fdopen = os.fdopen

    class FullAfterMapStarts:
        def __init__(self, handle):
            self._handle = handle

        def write(self, data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __getattr__(self, name):
            return getattr(self._handle, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self._handle.close()

    def fdopen(fd, mode, **kwargs):
        handle = real_fdopen(fd, mode, **kwargs)
        name = os.readlink(f"/proc/self/fd/{fd}") if os.path.exists("/proc/self/fd") else ""
        return FullAfterMapStarts(handle) if ".map.json." in name else handle

    monkeypatch.setattr(atomic_file.os, "fdopen", fdopen)
    line = one_line_error(simulate(tmp_path))
    assert "No space left" in line and "map.json" in line
    failed = [r for r in runs(tmp_path) if r != previous]
    assert len(failed) == 1
    assert not (failed[0] / "map.json").exists()
    assert summary_of(failed[0])["status"] == "failed" and "No space left" in summary_of(failed[0])["reason"]
    assert_whole(failed[0])
    assert (tmp_path / "latest").resolve() == previous


def test_a_filter_error_marks_the_run_failed(tmp_path, monkeypatch):
    previous = good_run(tmp_path)

    def broken(*args, **kwargs):
        raise FilterError("the covariance is not positive definite")

    monkeypatch.setattr(pipeline, "run_dataset", broken)
    line = one_line_error(simulate(tmp_path))
    assert "positive definite" in line
    failed = [r for r in runs(tmp_path) if r != previous][0]
    assert summary_of(failed) == {"status": "failed", "reason": "the covariance is not positive definite"}
    assert (tmp_path / "latest").resolve() == previous


def test_an_interruption_without_a_result_marks_the_folder(tmp_path, monkeypatch):
    previous = good_run(tmp_path)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "run_dataset", interrupted)
    line = one_line_error(simulate(tmp_path), code=130)
    assert "interrupted" in line
    stopped = [r for r in runs(tmp_path) if r != previous][0]
    assert summary_of(stopped) == {"status": "interrupted", "reason": "interrupted by SIGINT"}
    assert (tmp_path / "latest").resolve() == previous


def test_a_partial_result_is_written_whole_and_marked_interrupted(tmp_path, monkeypatch):
    """The pipeline's contract: a KeyboardInterrupt inside its loop returns the scans so far
    with ``interrupted = True``; the CLI writes them, says interrupted, exits 130."""
    previous = good_run(tmp_path)
    real = pipeline.run_dataset

    def partial(*args, **kwargs):
        result = real(*args, **kwargs)
        result.interrupted = True
        return result

    monkeypatch.setattr(pipeline, "run_dataset", partial)
    result = simulate(tmp_path)
    assert result.exit_code == 130, result.output
    stopped = [r for r in runs(tmp_path) if r != previous][0]
    summary = summary_of(stopped)
    assert summary["status"] == "interrupted" and summary["scans"] == 3
    assert len(read_trajectory(stopped / "trajectory.tum")) == 3
    assert_whole(stopped)
    assert (tmp_path / "latest").resolve() == previous


# ---------------------------------------------------------------------------- real signals
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_mid_run_ends_simulate_cleanly(tmp_path, sig):
    previous = good_run(tmp_path)
    env = {**os.environ, "PYTHONPATH": str(SRC), "MPLBACKEND": "Agg"}
    # 2000 scans: about 5 s to simulate, tens of seconds to run, so the signal lands mid-run
    proc = subprocess.Popen([sys.executable, "-m", "bsslam.cli", "simulate", "--world", "mixed",
                             "--steps", "2000", "--out", str(tmp_path)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 600     # bounded: the first run may compile the kernels
        while len(runs(tmp_path)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(runs(tmp_path)) == 2, "the run folder never appeared"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    stopped = [r for r in runs(tmp_path) if r != previous][0]
    assert summary_of(stopped)["status"] == "interrupted"
    assert_whole(stopped)
    assert (tmp_path / "latest").resolve() == previous


def _run_python(script: str, timeout: float) -> subprocess.CompletedProcess:
    """``script`` run by a fresh interpreter with this checkout's ``src`` first on its path
    (a signal sent there must not reach pytest); asserts it exits 0. Ctrl-C is Python's
    KeyboardInterrupt there whatever the suite inherited: a shell that starts the suite as
    a background job hands its children SIGINT ignored, and Python then keeps it ignored."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    script = "import signal\nsignal.signal(signal.SIGINT, signal.default_int_handler)\n" + script
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr
    return done


def test_a_signal_just_after_the_folder_is_made_still_marks_it(tmp_path):
    """A signal arriving between making the run folder and the guard that marks it (the
    CLI's mid-run signal test hit that window) is held until the guard is in place: the
    run is interrupted and its folder says so. (In a subprocess: the signal must not reach
    pytest.)"""
    script = f"""
import json, os, signal
import bsslam.io.results as results

real = results.create_run_dir

def create_then_signalled(out):
    run = real(out)
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(1000):      # the handler would run at a bytecode boundary in here
        pass
    return run

results.create_run_dir = create_then_signalled
try:
    with results.run_folder({str(tmp_path)!r}) as run:
        print("body reached")
except KeyboardInterrupt:
    (run,) = [p for p in os.scandir({str(tmp_path)!r}) if p.is_dir()]
    print(json.load(open(os.path.join(run.path, "summary.json")))["status"])
"""
    done = _run_python(script, timeout=120)
    assert done.stdout.split() == ["interrupted"], done.stdout + done.stderr


def test_a_signal_swallowed_in_a_ctypes_callback_is_silent_and_delivered_again():
    """numba calls back into Python while it compiles; a signal landing there raises in the
    callback, where the interpreter drops the exception (and prints it as a traceback). It
    is delivered again, and nothing is printed. (In a subprocess: pytest catches dropped
    exceptions itself.)"""
    script = """
import ctypes, os, signal
from bsslam.cli import _deliver_swallowed_signal, signals_interrupt

@ctypes.CFUNCTYPE(None)
def callback():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(1000):      # the handler runs at a bytecode boundary in here
        pass

with signals_interrupt():
    callback()
    try:
        _deliver_swallowed_signal()
    except KeyboardInterrupt as exc:
        print("delivered", exc)
"""
    done = _run_python(script, timeout=120)
    assert done.stdout.strip() == "delivered SIGINT"
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr


#: A compiled kernel that sends itself a signal (libc's kill through ctypes) and returns
#: arrays: the signal is pending exactly when numba boxes them, in its Python code.
_SIGNALLING_KERNEL = """
import ctypes, os
import numpy as np
from numba import njit

kill = ctypes.CDLL(None).kill
kill.argtypes = [ctypes.c_int, ctypes.c_int]
kill.restype = ctypes.c_int

@njit
def signalled_then_arrays(pid, sig):
    if sig:
        kill(pid, sig)
    return 1, np.zeros(3), np.zeros((0, 2))

"""


def test_a_signal_in_a_kernels_callback_into_numba_is_held_and_delivered_by_progress():
    """A compiled kernel returning arrays calls back into numba's Python code to box them;
    a signal pending then raised its KeyboardInterrupt in there, and the kernel returned a
    SystemError that no interruption handler knew (CI: a SIGTERM mid-simulate exited 1,
    not 130). The kernel here sends the signal itself (libc's kill through ctypes), so it
    is pending exactly when the boxing runs: the call returns whole and the next progress
    callback raises the signal. (In a subprocess: the signal must not reach pytest.)"""
    script = _SIGNALLING_KERNEL + """
from bsslam.cli import _deliver_swallowed_signal, signals_interrupt

signalled_then_arrays(os.getpid(), 0)        # compiled before the signal
with signals_interrupt():
    status, a, b = signalled_then_arrays(os.getpid(), 15)
    print("returned", status, a.shape, b.shape)
    try:
        _deliver_swallowed_signal()
    except KeyboardInterrupt as exc:
        print("delivered", exc)
"""
    done = _run_python(script, timeout=300)
    assert done.stdout.split("\n")[:2] == ["returned 1 (3,) (0, 2)", "delivered SIGTERM"], \
        done.stdout + done.stderr


def test_a_ctrl_c_in_a_kernels_callback_into_numba_is_a_keyboard_interrupt_to_the_library():
    """Without the command line's handler (a library user's Ctrl-C) the KeyboardInterrupt
    raised in a kernel's callback into numba comes out as a SystemError; inside
    :func:`bsslam.compiled.kernel_interrupts` (the run's loops and its end-of-run passes)
    it is the KeyboardInterrupt again, so the run ends early with its results; another
    SystemError passes unchanged. (In a subprocess: the signal must not reach pytest.)"""
    script = _SIGNALLING_KERNEL + """
import signal
from bsslam.compiled import kernel_interrupts

signalled_then_arrays(os.getpid(), 0)
try:
    signalled_then_arrays(os.getpid(), int(signal.SIGINT))
except SystemError as exc:
    print("bare", type(exc).__name__)
try:
    with kernel_interrupts():
        signalled_then_arrays(os.getpid(), int(signal.SIGINT))
except KeyboardInterrupt:
    print("inside KeyboardInterrupt")
try:
    with kernel_interrupts():
        raise SystemError("other")
except SystemError as exc:
    print("other", exc)
"""
    done = _run_python(script, timeout=300)
    assert done.stdout.split("\n")[:3] == ["bare SystemError", "inside KeyboardInterrupt", "other other"], \
        done.stdout + done.stderr


def test_a_signal_while_numba_loads_its_implementations_is_raised_after_the_load():
    """numba loads its implementations at the first kernel call by importing modules that
    register themselves; a KeyboardInterrupt in the middle leaves them half-registered and
    every later kernel call fails ("duplicate registration"). The command line loads them
    on entering its signal handling, with the signals held: a signal during the load is
    raised once it is done, and numba still compiles. (In a subprocess: the signal must not
    reach pytest.)"""
    script = """
import os, signal
import bsslam.compiled as compiled
from bsslam.cli import signals_interrupt

loaded = []
real_load = compiled.load_compiler_registries

def load():
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(1000):      # the handler runs at a bytecode boundary in here
        pass
    real_load()
    loaded.append(True)

compiled.load_compiler_registries = load
try:
    with signals_interrupt():
        print("not interrupted")
except KeyboardInterrupt as exc:
    print("interrupted", exc, loaded)

from numba import njit

@njit
def twice(x):
    return 2.0 * x
print(twice(1.5))
"""
    done = _run_python(script, timeout=300)
    assert done.stdout.split("\n")[:2] == ["interrupted SIGTERM [True]", "3.0"], done.stdout


def test_a_signal_while_numba_compiles_is_raised_once_the_kernel_is_whole():
    """LLVM calls back into Python while numba generates a kernel's code; a
    KeyboardInterrupt raised there leaves LLVM's object cache inconsistent and the process
    aborts (SIGABRT) at the next code generation — a cold-cache run killed mid-compile did.
    The command line holds signals while numba's compiler lock is held (the lock covers
    compiling and loading from the cache) and raises them when it is released; the kernel
    compiled meanwhile works. (In a subprocess: the signal must not reach pytest.)"""
    script = """
import os, signal
from numba import njit
from numba.core.compiler_lock import global_compiler_lock
from bsslam.cli import signals_interrupt

@njit
def twice(x):
    return 2.0 * x

reached = []
try:
    with signals_interrupt():
        with global_compiler_lock:          # as numba holds it while compiling
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):           # the handler runs at a bytecode boundary in here
                pass
            reached.append(twice(1.5))      # a compilation nested in the held lock
        print("not interrupted")
except KeyboardInterrupt as exc:
    print("interrupted", exc, reached)
print(twice(2.5))
"""
    done = _run_python(script, timeout=300)
    assert done.stdout.split("\n")[:2] == ["interrupted SIGTERM [3.0]", "5.0"], done.stdout


def test_a_signal_that_ended_the_run_is_not_raised_again_while_the_results_are_written():
    """A signal's KeyboardInterrupt that reached the run (which then writes its results so
    far) is not raised a second time when a kernel is first called while they are written
    (the end of its compilation raises only a signal held during it), so they are written
    whole. (In a subprocess: the signal must not reach pytest.)"""
    script = """
import os, signal
from numba import njit
from bsslam.cli import signals_interrupt

@njit
def twice(x):
    return 2.0 * x

with signals_interrupt():
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):           # the handler runs at a bytecode boundary in here
            pass
        print("not interrupted")
    except KeyboardInterrupt as exc:
        print("interrupted", exc)       # as run_dataset does; then it writes the results
    try:
        print(twice(1.5))               # a kernel first called while writing them
        print("written")
    except KeyboardInterrupt:
        print("interrupted again")
"""
    done = _run_python(script, timeout=300)
    assert done.stdout.split("\n")[:3] == ["interrupted SIGTERM", "3.0", "written"], done.stdout
