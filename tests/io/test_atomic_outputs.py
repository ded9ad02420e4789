"""Every result writer replaces its file atomically: a failed write (a full disk, a failing
rename, an exception in the writer) leaves the old file or none under the final name, never
a cut one, and no temporary behind."""

import errno
import io
import json
import os

import numpy as np
import pytest

import bsslam.io.atomic_file as atomic_file
from bsslam.config import SLAMConfig
from bsslam.errors import InputError
from bsslam.io.atomic_file import atomic_write
from bsslam.io.config_file import load_config, write_config
from bsslam.io.grid import write_grid
from bsslam.io.map_file import read_map_json, write_map_json
from bsslam.io.pose_covariance_file import read_pose_covariance_csv, write_pose_covariance_csv
from bsslam.io.results import write_summary
from bsslam.io.trajectory_file import read_trajectory, write_tum
from bsslam.trajectory import Trajectory
from bsslam.viz.figures import new_figure, save_figure


def _trajectory(n=200):
    rng = np.random.default_rng(1)
    a = rng.normal(size=(n, 3, 3))
    return Trajectory(np.arange(n) * 0.1, rng.normal(size=(n, 3)) % 3.0, a @ a.transpose(0, 2, 1))


def _figure():
    fig = new_figure(2, 2)
    fig.add_subplot().plot([0, 1], [1, 0])
    return fig


class _Spline:   # the attributes write_map_json reads
    def __init__(self, i):
        self.id = i
        self.curve = type("C", (), {"degree": 3, "knots": np.r_[0, 0, 0, 0, 1, 2, 2, 2, 2.0],
                                    "control_points": np.arange(10.0).reshape(5, 2)})()
        self.covariance = np.eye(10)


# each writer of a run folder, writing its own kind of file
WRITERS = {
    "trajectory.tum": lambda p: write_tum(p, _trajectory()),
    "pose_covariance.csv": lambda p: write_pose_covariance_csv(p, _trajectory()),
    "map.json": lambda p: write_map_json(p, [_Spline(i) for i in range(40)]),
    "config.yaml": lambda p: write_config(p, SLAMConfig()),
    "grid.pgm": lambda p: write_grid(p, p.with_suffix(".yaml"), np.full((300, 200), 205, np.uint8), (0.0, 0.0), 0.05),
    "map.png": lambda p: save_figure(_figure(), [p]),
    "map.svg": lambda p: save_figure(_figure(), [p]),
    "summary.json": lambda p: write_summary(p.parent, {"scans": 3, "skipped_input_by_reason": {f"reason {i}": i for i in range(30)}}, "complete"),
}


def _leftovers(folder):
    return sorted(n for n in os.listdir(folder) if n.startswith("."))


class _FullDisk:
    """A file whose device fills up after ``room`` bytes: writes past it raise ENOSPC."""

    def __init__(self, handle, room):
        self._handle, self._room = handle, room

    def write(self, data):
        size = len(data)
        if size > self._room:
            self._handle.write(data[:self._room])
            self._room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= size
        return self._handle.write(data)

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._handle.close()


def _fill_disk_after(monkeypatch, room):
    real_fdopen = os.fdopen
    monkeypatch.setattr(atomic_file.os, "fdopen", lambda *a, **k: _FullDisk(real_fdopen(*a, **k), room))


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_each_writer_leaves_a_complete_file_and_no_temporary(tmp_path, name):
    WRITERS[name](tmp_path / name)
    assert (tmp_path / name).stat().st_size > 0
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_a_full_disk_keeps_the_old_file_whole(tmp_path, monkeypatch, name):
    """The old file stays, byte for byte; the error is an InputError naming the file."""
    path = tmp_path / name
    WRITERS[name](path)
    before = path.read_bytes()
    _fill_disk_after(monkeypatch, 100)
    with pytest.raises(InputError, match="No space left") as info:
        WRITERS[name](path)
    assert str(path) in str(info.value)
    assert path.read_bytes() == before
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_a_full_disk_on_a_first_write_leaves_no_file(tmp_path, monkeypatch, name):
    _fill_disk_after(monkeypatch, 100)
    with pytest.raises(InputError, match="No space left"):
        WRITERS[name](tmp_path / name)
    assert not (tmp_path / name).exists()
    assert _leftovers(tmp_path) == []


def test_a_failing_rename_keeps_the_old_file_and_removes_the_temporary(tmp_path, monkeypatch):
    path = tmp_path / "trajectory.tum"
    write_tum(path, _trajectory(5))
    before = path.read_bytes()

    def refuse(src, dst):
        raise OSError(errno.EXDEV, os.strerror(errno.EXDEV))

    monkeypatch.setattr(atomic_file.os, "replace", refuse)
    with pytest.raises(InputError, match="cannot write file") as info:
        write_tum(path, _trajectory(50))
    assert str(path) in str(info.value)
    assert path.read_bytes() == before
    assert _leftovers(tmp_path) == []


def test_the_data_is_synced_before_the_rename(tmp_path, monkeypatch):
    calls = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(atomic_file.os, "fsync", lambda fd: (calls.append("fsync"), real_fsync(fd))[1])
    monkeypatch.setattr(atomic_file.os, "replace", lambda a, b: (calls.append("replace"), real_replace(a, b))[1])
    write_map_json(tmp_path / "map.json", [_Spline(1)])
    assert calls == ["fsync", "replace"]
    assert len(read_map_json(tmp_path / "map.json").splines) == 1


def test_an_exception_in_the_writer_leaves_nothing(tmp_path):
    path = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_write(path) as f:
            f.write("half")
            raise RuntimeError("the writer broke")
    assert not path.exists() and _leftovers(tmp_path) == []


def test_a_folder_in_the_way_is_an_input_error(tmp_path):
    (tmp_path / "map.json").mkdir()
    with pytest.raises(InputError, match="map.json"):
        write_map_json(tmp_path / "map.json", [])
    assert _leftovers(tmp_path) == []


def test_a_missing_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="nowhere"):
        write_tum(tmp_path / "nowhere" / "t.tum", _trajectory(3))


def test_written_files_get_the_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_tum(tmp_path / "t.tum", _trajectory(3))
    finally:
        os.umask(old)
    assert (tmp_path / "t.tum").stat().st_mode & 0o777 == 0o644


def test_round_trips_still_hold_through_the_atomic_writers(tmp_path):
    traj = _trajectory(20)
    write_tum(tmp_path / "t.tum", traj)
    write_pose_covariance_csv(tmp_path / "c.csv", traj)
    write_config(tmp_path / "c.yaml", SLAMConfig())
    np.testing.assert_array_equal(read_trajectory(tmp_path / "t.tum").stamps, traj.stamps)
    np.testing.assert_array_equal(read_pose_covariance_csv(tmp_path / "c.csv")[1], traj.covariances)
    assert load_config(tmp_path / "c.yaml") == SLAMConfig()
    summary = write_summary(tmp_path, {"scans": 3, "status": "ignored"}, "interrupted", "by SIGTERM")
    assert json.loads((tmp_path / "summary.json").read_text()) == summary == {
        "status": "interrupted", "reason": "by SIGTERM", "scans": 3}


def test_an_open_stream_is_written_in_place():
    out = io.StringIO()
    write_tum(out, _trajectory(3))
    assert out.getvalue().count("\n") == 4
