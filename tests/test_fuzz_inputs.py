"""Seeded fuzzing of the input boundary through the real CLI (issue 18).

A small clean CARMEN log is made here from the simulator; each case corrupts it one way
(and a few ROS 2 bags are written with rosbags) and runs ``bsslam run`` in-process. Every
case must end in one of two ways:

* exit 0 with complete, finite outputs — trajectory.tum finite with one pose per accepted
  scan, every pose covariance symmetric positive semi-definite — and exactly the scans the
  case left valid accepted;
* exit 2 with a one-line ``error: …`` naming the file;

never a traceback, a hang, NaN in a file or an empty result called success. The run
prints a table of outcomes by kind (``pytest -s``).

The runs are in one process (``--no-parallel``), where the map pictures are replaced by a
no-op (matplotlib costs seconds per run and the pictures only draw the trajectory checked
here); one test draws them for real on a bridged log. Each kind runs once more through the
helper process (the default ``--parallel``), handed over at the first frame: its errors
and skips must come out the same.
"""

from __future__ import annotations

import gzip
import importlib.util
import math
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import bsslam.outputs
from bsslam.cli import app
from bsslam.outputs import _save_map_figure
from bsslam.helper_process import HelperProcess
from bsslam.sim import SimConfig, get_world, simulate

N_SCANS = 6
SEEDS_PER_KIND = 8
runner = CliRunner()


# -- the clean log -------------------------------------------------------------------------
def _num(values) -> str:
    return " ".join(f"{float(v):.6f}" for v in values)


@dataclass(frozen=True)
class Clean:
    """The clean log as lines, with the index of each scan's FLASER line."""

    lines: tuple[str, ...]
    scan_lines: tuple[int, ...]


def clean_log() -> Clean:
    data = simulate(get_world("rounded-room"), SimConfig(), seed=0, steps=N_SCANS)
    lines, scans = ["# synthetic CARMEN log", "PARAM robot_frontlaser_offset 0.0 host 0"], []
    for frame in data:
        t = 1000.0 + frame.stamp
        # the simulator's no return (max_range) becomes the logger's 100 m (≥ no_return_m)
        ranges = np.where(frame.scan.ranges >= 8.0, 100.0, frame.scan.ranges)
        pose = _num(frame.odometry)
        lines.append(f"ODOM {pose} 0 0 0 {t:.6f} host {t:.6f}")
        scans.append(len(lines))
        lines.append(f"FLASER {ranges.size} {' '.join(f'{r:.3f}' for r in ranges)} {pose} {pose} "
                     f"{t:.6f} host {t:.6f}")
    return Clean(tuple(lines), tuple(scans))


CLEAN = clean_log()


# -- corruptions: each returns (content bytes, expected): the number of scans exit 0 must
#    accept, None when it must be exit 2, or a set of acceptable numbers (0: exit 2) ------
def _text(lines) -> bytes:
    return ("\n".join(lines) + "\n").encode()


def _fields(line: str) -> list[str]:
    return line.split()


def _set_field(rng, k_from: int, field_of, value) -> tuple[bytes, object]:
    """Set one field (``field_of(fields) → index``) of a random scan ≥ k_from to ``value``."""
    lines = list(CLEAN.lines)
    k = int(rng.integers(k_from, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k]])
    f[field_of(f)] = value
    lines[CLEAN.scan_lines[k]] = " ".join(f)
    return _text(lines), k


def _beam(rng, value):
    content, _ = _set_field(rng, 0, lambda f: 2 + int(rng.integers(0, int(f[1]))), value)
    return content, N_SCANS


def _odometry(rng, which: int, value, first_ok: bool = True):
    """Corrupt the robot pose component ``which`` (0 x, 1 y, 2 θ) of one scan; both pose
    triples of FLASER carry it. A bad pose on the first scan skips that scan."""
    lines = list(CLEAN.lines)
    k = int(rng.integers(0 if not first_ok else 1, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k]])
    n = int(f[1])
    f[2 + n + which] = value
    f[5 + n + which] = value
    lines[CLEAN.scan_lines[k]] = " ".join(f)
    return _text(lines), (N_SCANS - 1 if k == 0 else N_SCANS)


def _jump(rng, dx: float, persist: bool):
    """Add ``dx`` metres to the x of one scan's odometry (and of all later ones)."""
    lines = list(CLEAN.lines)
    k = int(rng.integers(1, N_SCANS))
    for j in range(k, N_SCANS if persist else k + 1):
        f = _fields(lines[CLEAN.scan_lines[j]])
        n = int(f[1])
        for i in (2 + n, 5 + n):
            f[i] = f"{float(f[i]) + dx:.6f}"
        lines[CLEAN.scan_lines[j]] = " ".join(f)
    return _text(lines), N_SCANS


def _heading_jump(rng, dphi: float):
    lines = list(CLEAN.lines)
    k = int(rng.integers(1, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k]])
    n = int(f[1])
    for i in (4 + n, 7 + n):
        f[i] = repr(float(f[i]) + dphi)
    lines[CLEAN.scan_lines[k]] = " ".join(f)
    return _text(lines), N_SCANS


def _stamps(rng, how: str):
    lines = list(CLEAN.lines)
    k = int(rng.integers(1, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k - 1]])
    previous = float(f[-3])
    if how == "gap":        # the logger paused: every later line is 1e5 s later
        for j in range(k, N_SCANS):
            g = _fields(lines[CLEAN.scan_lines[j]])
            g[-3] = g[-1] = f"{float(g[-3]) + 1e5:.6f}"
            lines[CLEAN.scan_lines[j]] = " ".join(g)
        return _text(lines), N_SCANS
    g = _fields(lines[CLEAN.scan_lines[k]])
    g[-3] = f"{previous if how == 'duplicate' else previous - 5.0:.6f}"
    lines[CLEAN.scan_lines[k]] = " ".join(g)
    return _text(lines), N_SCANS - 1


def _beam_count(rng):
    lines = list(CLEAN.lines)
    k = int(rng.integers(0, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k]])
    f[1] = str(int(f[1]) + int(rng.choice([-3, -1, 1, 2, 1000])))
    lines[CLEAN.scan_lines[k]] = " ".join(f)
    return _text(lines), N_SCANS - 1


def _truncate(rng):
    content = _text(CLEAN.lines)
    cut = int(rng.integers(1, len(content)))
    head = content[:cut]
    complete = sum(1 for i in CLEAN.scan_lines if len(_text(CLEAN.lines[:i + 1])) <= cut)
    # a cut inside the last fields (host name, logger stamp) can leave a parseable line
    return head, {complete, complete + 1}


def _insert(rng, line: str | bytes):
    lines = [ln.encode() for ln in CLEAN.lines]
    at = int(rng.integers(0, len(lines) + 1))
    lines.insert(at, line if isinstance(line, bytes) else line.encode())
    return b"\n".join(lines) + b"\n", N_SCANS


def _garbage_bytes(rng) -> bytes:
    # no NUL and no newline: a binary-looking line inside a text log
    values = rng.integers(1, 256, int(rng.integers(5, 200)))
    return bytes(int(v) for v in values if v not in (10, 13))


def _long_line(rng):
    return _insert(rng, "X" * int(rng.integers(700_000, 1_000_000)))


def _huge_scan(rng):
    lines = list(CLEAN.lines)
    k = int(rng.integers(0, N_SCANS))
    f = _fields(lines[CLEAN.scan_lines[k]])
    n = 200_000
    f = [f[0], str(n), *(["1.0"] * n), *f[2 + int(f[1]):]]
    lines[CLEAN.scan_lines[k]] = " ".join(f)
    return _text(lines), N_SCANS - 1


def _robotlaser_junk(rng):
    junk = [f"ROBOTLASER1 0 -1.57 3.14 0.0174 80.0 0.01 0 9 1.0 2.0 {1000.0 + 0.01 * i} host 0" for i in range(20)]
    return _text([*junk, *CLEAN.lines]), N_SCANS


def _param(rng, value):
    name = str(rng.choice(["robot_frontlaser_offset", "robot_frontlaser_side_offset",
                           "robot_frontlaser_angular_offset"]))
    return _insert(rng, f"PARAM {name} {value} host 0")


def _unknown(rng):
    lines = list(CLEAN.lines)
    for _ in range(int(rng.integers(1, 10))):
        at = int(rng.integers(0, len(lines) + 1))
        lines.insert(at, str(rng.choice(["NEFF 15 2 3", "SYNC 1 2", "TRUEPOS 0 0 0 0 0 0 1 h 1", "RLASER 1 2",
                                         "GPS-GGA 1 2 3", "zzz"])))
    return _text(lines), N_SCANS


def _odom_only(rng):
    return _text([ln for ln in CLEAN.lines if ln.startswith("ODOM")]), None


def _all_nan_odometry(rng):
    lines = list(CLEAN.lines)
    for i in CLEAN.scan_lines:
        f = _fields(lines[i])
        n = int(f[1])
        f[2 + n] = f[5 + n] = "nan"
        lines[i] = " ".join(f)
    return _text(lines), None


KINDS = {
    "nan range": lambda rng: _beam(rng, "nan"),
    "inf range": lambda rng: _beam(rng, "inf"),
    "huge range": lambda rng: _beam(rng, "1e300"),
    "negative range": lambda rng: _beam(rng, "-2.5"),
    "nan odometry x": lambda rng: _odometry(rng, 0, "nan", first_ok=False),
    "-inf odometry y": lambda rng: _odometry(rng, 1, "-inf"),
    "huge odometry x": lambda rng: _odometry(rng, 0, "1e308"),
    "nan heading": lambda rng: _odometry(rng, 2, "nan"),
    "huge heading": lambda rng: _odometry(rng, 2, "1e300"),
    "heading jump pi": lambda rng: _heading_jump(rng, math.pi),
    "heading jump 1000 rad": lambda rng: _heading_jump(rng, 1000.0),
    "odometry spike 100 m": lambda rng: _jump(rng, 100.0, persist=False),
    "odometry step 10 km": lambda rng: _jump(rng, 10_000.0, persist=True),
    "nan PARAM offset": lambda rng: _param(rng, "nan"),
    "huge PARAM offset": lambda rng: _param(rng, "1e300"),
    "wrong beam count": _beam_count,
    "garbage text line": lambda rng: _insert(rng, "FLASER the quick brown fox 1 2 3"),
    "binary line": lambda rng: _insert(rng, _garbage_bytes(rng)),
    "duplicate stamp": lambda rng: _stamps(rng, "duplicate"),
    "backward stamp": lambda rng: _stamps(rng, "backward"),
    "huge stamp gap": lambda rng: _stamps(rng, "gap"),
    "truncation": _truncate,
    "very long line": _long_line,
    "200000-beam scan": _huge_scan,
    "unknown messages": _unknown,
    "malformed ROBOTLASER1 head": _robotlaser_junk,
    "BOM": lambda rng: (b"\xef\xbb\xbf" + _text(CLEAN.lines), N_SCANS),
    "CRLF": lambda rng: (_text(CLEAN.lines).replace(b"\n", b"\r\n"), N_SCANS),
    "empty file": lambda rng: (b"", None),
    "ODOM only": _odom_only,
    "all odometry NaN": _all_nan_odometry,
    "gzip": lambda rng: (gzip.compress(_text(CLEAN.lines)), None),
    "UTF-16": lambda rng: (_text(CLEAN.lines).decode().encode("utf-16"), None),
    "PNG": lambda rng: (b"\x89PNG\r\n\x1a\n" + bytes(rng.integers(0, 256, 64).astype(np.uint8)), None),
}
# kinds whose content does not depend on the seed: one case each
_FIXED = {"BOM", "CRLF", "empty file", "ODOM only", "all odometry NaN", "gzip", "UTF-16",
          "malformed ROBOTLASER1 head"}


def _cases():
    for kind, make in KINDS.items():
        for seed in range(1 if kind in _FIXED else SEEDS_PER_KIND):
            yield kind, seed


# -- running and checking --------------------------------------------------------------------
TABLE: dict[str, Counter] = {}


@pytest.fixture(autouse=True)
def _no_pictures(monkeypatch):
    monkeypatch.setattr(bsslam.outputs, "_save_map_figure", lambda *args, **kwargs: None)


@pytest.fixture
def _helper_from_the_first_frame(monkeypatch):
    """Runs wait for their helper process and hand it every frame (by default a run goes on
    in this process until the helper's interpreter is up: after these short logs). The
    helper draws the map pictures (not replaced there: its process is not patched)."""
    monkeypatch.setattr(HelperProcess, "ready", lambda self: self.wait_ready(120))
    monkeypatch.setattr(bsslam.outputs, "_save_map_figure", _save_map_figure)


@pytest.fixture(scope="module")
def config_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "config.yaml"
    path.write_text("relocalize: false\n")
    return path


def run_cli(log: Path, out: Path, config: Path, *extra: str, parallel: bool = False):
    return runner.invoke(app, ["run", str(log), "--out", str(out), "--config", str(config),
                               "--steps", "1000", "--parallel" if parallel else "--no-parallel", *extra])


def check_outcome(result, log: Path, out: Path, expected) -> str:
    """Assert the invariants; returns "clean" (exit 0) or "clear error" (exit 2)."""
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"traceback: {result.exception!r}\n{result.output}")
    assert "Traceback" not in result.output
    if result.exit_code == 2:
        assert expected is None or (isinstance(expected, set) and 0 in expected), result.output
        errors = [ln for ln in result.output.splitlines() if ln.startswith("error:")]
        assert len(errors) == 1 and str(log) in errors[0], result.output
        return "clear error"
    assert result.exit_code == 0, result.output
    assert expected is not None, f"expected an error, got success\n{result.output}"
    run = out / "latest"
    traj = np.loadtxt(run / "trajectory.tum", comments="#", ndmin=2)
    covs = np.loadtxt(run / "pose_covariance.csv", delimiter=",", skiprows=1, ndmin=2)
    accepted = traj.shape[0]
    assert accepted >= 1 and accepted in (expected if isinstance(expected, set) else {expected}), (accepted, expected, result.output)
    assert traj.shape[1] == 8 and np.all(np.isfinite(traj))
    assert covs.shape[0] == accepted and np.all(np.isfinite(covs))
    mats = covs[:, 1:10].reshape(-1, 3, 3)
    np.testing.assert_allclose(mats, np.transpose(mats, (0, 2, 1)), atol=1e-12)
    assert np.all(np.linalg.eigvalsh(mats) >= -1e-12)
    for name in ("odometry.tum", "frontend.tum"):
        assert np.all(np.isfinite(np.loadtxt(run / name, comments="#", ndmin=2)))
    # no implausible jump reaches the filter: the odometry it used moves at most at the
    # default limits (3 m/s over at least 0.2 s), the estimate at most a search window more
    odo = np.loadtxt(run / "odometry.tum", comments="#", ndmin=2)
    allowed = 3.0 * np.maximum(np.diff(odo[:, 0]), 0.2)
    assert np.all(np.hypot(*np.diff(odo[:, 1:3], axis=0).T) <= allowed + 1e-6)
    assert np.all(np.hypot(*np.diff(traj[:, 1:3], axis=0).T) <= allowed + 1.0)
    return "clean"


@pytest.mark.parametrize("kind, seed", list(_cases()))
def test_corrupted_carmen_log(tmp_path, config_file, kind, seed):
    rng = np.random.default_rng([seed, sum(map(ord, kind))])
    content, expected = KINDS[kind](rng)
    log = tmp_path / "log.clf"
    log.write_bytes(content)
    result = run_cli(log, tmp_path / "out", config_file)
    outcome = "failure"
    try:
        outcome = check_outcome(result, log, tmp_path / "out", expected)
    finally:
        TABLE.setdefault(kind, Counter())[outcome] += 1


@pytest.mark.parametrize("kind", list(KINDS))
def test_corrupted_carmen_log_read_by_the_helper_process(tmp_path, config_file, kind, _helper_from_the_first_frame):
    rng = np.random.default_rng([0, sum(map(ord, kind))])
    content, expected = KINDS[kind](rng)
    log = tmp_path / "log.clf"
    log.write_bytes(content)
    result = run_cli(log, tmp_path / "out", config_file, parallel=True)
    check_outcome(result, log, tmp_path / "out", expected)


@pytest.mark.parametrize("parallel", [False, True])
@pytest.mark.parametrize("kind", ["nan odometry x", "huge odometry x", "wrong beam count"])
def test_strict_mode_stops_with_file_and_line(tmp_path, config_file, kind, parallel, _helper_from_the_first_frame):
    content, _ = KINDS[kind](np.random.default_rng(1))
    log = tmp_path / "log.clf"
    log.write_bytes(content)
    result = run_cli(log, tmp_path / "out", config_file, "--strict", parallel=parallel)
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and re.search(re.escape(str(log)) + r":\d+: ", errors[0]), result.output
    TABLE.setdefault(f"strict: {kind}", Counter())["clear error"] += 1


def test_clean_log_is_clean_in_both_modes_and_reports_no_skips(tmp_path, config_file):
    log = tmp_path / "log.clf"
    log.write_bytes(_text(CLEAN.lines))
    for extra in ((), ("--strict",)):
        result = run_cli(log, tmp_path / "out", config_file, *extra)
        assert check_outcome(result, log, tmp_path / "out", N_SCANS) == "clean"
        assert "input item(s)" not in result.output    # ODOM lines unused with FLASER are no skips


@pytest.mark.parametrize("steps", ["0", "-5"])
def test_steps_below_one_is_an_error(tmp_path, steps):
    log = tmp_path / "log.clf"
    log.write_bytes(_text(CLEAN.lines))
    result = runner.invoke(app, ["run", str(log), "--out", str(tmp_path / "out"), "--steps", steps])
    assert result.exit_code == 2 and "--steps" in result.output and "greater than or equal to 1" in result.output
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("target", ["/dev/null", "fifo"])
def test_devices_and_fifos_are_refused(tmp_path, config_file, target):
    import os

    if target == "fifo":
        target = tmp_path / "pipe.clf"
        os.mkfifo(target)
    result = runner.invoke(app, ["run", str(target), "--format", "carmen", "--out", str(tmp_path / "out"),
                                 "--config", str(config_file)])
    assert result.exit_code == 2 and "not a regular file" in result.output, result.output


def test_pictures_are_drawn_for_a_bridged_log(tmp_path, config_file, monkeypatch):
    monkeypatch.undo()   # the real save_map_figure
    content, expected = _odometry(np.random.default_rng(3), 2, "nan")
    log = tmp_path / "log.clf"
    log.write_bytes(content)
    result = run_cli(log, tmp_path / "out", config_file)
    assert check_outcome(result, log, tmp_path / "out", expected) == "clean"
    assert (tmp_path / "out" / "latest" / "map.png").stat().st_size > 0


# -- ROS 2 bags ---------------------------------------------------------------------------------
def _bag_module():
    spec = importlib.util.spec_from_file_location("rosbag_builder", Path(__file__).parent / "io" / "rosbag_builder.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BAG_KINDS = {
    # kind: (scan header overrides per scan index, odometry override, expected scans)
    "bag clean": ({}, None, N_SCANS),
    "bag angle_increment 0 (one scan)": ({2: dict(increment=0.0)}, None, N_SCANS - 1),
    "bag angle_increment 0 (all scans)": ({k: dict(increment=0.0) for k in range(N_SCANS)}, None, None),
    "bag NaN angle_increment": ({3: dict(increment=float("nan"))}, None, N_SCANS - 1),
    "bag NaN angle_max": ({1: dict(angle_max=float("nan"))}, None, N_SCANS - 1),
    "bag NaN odometry": ({}, (2, "nan"), N_SCANS),
    "bag 10 km odometry step": ({}, (3, "jump"), N_SCANS),
}


@pytest.mark.parametrize("kind", list(BAG_KINDS))
def test_corrupted_ros2_bag(tmp_path, config_file, kind):
    builder = _bag_module()
    overrides, odom_bad, expected = BAG_KINDS[kind]
    data = simulate(get_world("rounded-room"), SimConfig(), seed=0, steps=N_SCANS)
    bag = builder.Bag("ros2-sqlite3")
    frames = list(data)
    for k, frame in enumerate(frames):
        t = 100.0 + frame.stamp
        x, y, yaw = frame.odometry
        if odom_bad == (k, "nan"):
            x = float("nan")
        elif odom_bad is not None and odom_bad[1] == "jump" and k >= odom_bad[0]:
            x += 10_000.0
        bag.odom(t - 0.01, float(x), float(y), float(yaw))
        bag.odom(t + 0.01, float(x), float(y), float(yaw))
        angles = frame.scan.angles
        increment = overrides.get(k, {}).get("increment", float(angles[1] - angles[0]))
        msg_kwargs = {key: v for key, v in overrides.get(k, {}).items() if key != "increment"}
        ranges = np.where(frame.scan.ranges >= 8.0, np.inf, frame.scan.ranges)
        bag.scan(t, ranges=ranges, increment=increment, **msg_kwargs)
    path = bag.write(tmp_path / "bag")
    result = run_cli(path, tmp_path / "out", config_file)
    outcome = "failure"
    try:
        outcome = check_outcome(result, path, tmp_path / "out", expected)
    finally:
        TABLE.setdefault(kind, Counter())[outcome] += 1


def test_print_fuzz_table():
    """The outcomes by kind (run with -s to see them); runs last in this file."""
    if not TABLE:
        pytest.skip("no fuzz case ran")
    width = max(map(len, TABLE))
    print(f"\n{'kind':{width}s}  clean  clear error  failure")
    for kind, c in TABLE.items():
        print(f"{kind:{width}s}  {c['clean']:5d}  {c['clear error']:11d}  {c['failure']:7d}")
    total = sum(TABLE.values(), Counter())
    print(f"{'total':{width}s}  {total['clean']:5d}  {total['clear error']:11d}  {total['failure']:7d}")
    assert total["failure"] == 0
