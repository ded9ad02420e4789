"""The rerun viewer: ``--viewer save`` writes a recording that reads back with rerun's own
reader; without rerun the CLI says so in one line; the ellipses are the 2σ contours."""

import json
import sys
from collections import defaultdict

import numpy as np
import pytest
from typer.testing import CliRunner

from bsslam.cli import app
from bsslam.config import SLAMConfig
from bsslam.io.trajectory_file import read_trajectory
from bsslam.pipeline import run_dataset
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.spline import BSplineCurve
from bsslam.viz.rerun_viewer import ellipse_outline, sample_curve

runner = CliRunner()


def test_ellipse_outline_is_the_nsigma_contour():
    cov = np.array([[0.04, 0.015], [0.015, 0.01]])
    center = np.array([3.0, -1.0])
    outline = ellipse_outline(center, cov, nsigma=2.0, n=64)
    d = outline - center
    mahalanobis2 = np.einsum("ij,jk,ik->i", d, np.linalg.inv(cov), d)
    np.testing.assert_allclose(mahalanobis2, 4.0, rtol=1e-12)
    np.testing.assert_array_equal(outline[0], outline[-1])             # closed
    # a singular covariance (a pose known exactly) is a point, not a NaN
    np.testing.assert_array_equal(ellipse_outline(center, np.zeros((2, 2))), np.tile(center, (49, 1)))


def test_sample_curve_spans_the_curve_at_the_step():
    curve = BSplineCurve(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 1.0]]),
                         np.array([0.0, 0.0, 0.0, 0.0, 4.0, 4.0, 4.0, 4.0]), 3)
    points = sample_curve(curve, 0.1)
    assert len(points) == 41
    np.testing.assert_allclose(points[[0, -1]], curve.evaluate(np.array([0.0, 4.0])), atol=1e-12)


def test_the_viewer_without_rerun_is_one_clear_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)      # `import rerun` now raises ImportError
    result = runner.invoke(app, ["simulate", "--steps", "3", "--out", str(tmp_path), "--viewer", "save"])
    assert result.exit_code == 2, result.output
    assert "rerun-sdk" in result.output and "bsslam[viewer]" in result.output
    assert isinstance(result.exception, SystemExit) and "Traceback" not in result.output   # no ImportError escaped
    assert len([line for line in result.output.splitlines() if "rerun-sdk" in line]) == 1


def test_an_unknown_viewer_mode_is_named(tmp_path):
    result = runner.invoke(app, ["simulate", "--steps", "3", "--out", str(tmp_path), "--viewer", "window"])
    assert result.exit_code == 2 and "'window'" in result.output and "spawn" in result.output


def recording_rows(path):
    """{entity path: [(scan index, {column: value})]} of a .rrd, through rerun's reader."""
    from rerun.chunk import RrdReader

    rows = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        keep = [name for name in batch.schema.names if name == "scan" or ":" in name]   # components, scan index
        for row in batch.select(keep).to_pylist():
            rows[chunk.entity_path].append((row.get("scan"), row))
    for entity in rows:
        rows[entity].sort(key=lambda r: -1 if r[0] is None else r[0])
    return rows


def test_save_writes_a_recording_of_the_run(tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk (the extra bsslam[viewer]) is not installed")
    result = runner.invoke(app, ["simulate", "--world", "mixed", "--steps", "25", "--seed", "1",
                                 "--out", str(tmp_path), "--viewer", "save"])
    assert result.exit_code == 0, result.output
    run = (tmp_path / "latest").resolve()
    summary = json.loads((run / "summary.json").read_text())
    rows = recording_rows(run / "viewer.rrd")

    scans, filter_steps = 25, summary["filter_steps"]
    assert [len(rows[e]) for e in ("/world/scan", "/world/robot", "/world/robot/covariance")] == [scans] * 3
    assert [i for i, _ in rows["/world/scan"]] == list(range(scans))
    assert len(rows["/world/trajectory/online/0"]) == scans
    assert len(rows["/world/ellipses/0"]) == filter_steps
    assert len(rows["/world/map/splines"]) == filter_steps + 1           # and the final map
    assert "/world/trajectory/relocalized" not in rows                 # simulate has no second pass

    # the last trail is the whole online trajectory; the final map has every spline
    trail = np.array(rows["/world/trajectory/online/0"][-1][1]["LineStrips3D:strips"][0])
    online = read_trajectory(run / "trajectory.tum")
    np.testing.assert_allclose(trail[:, :2], online.poses[:, :2], atol=1e-5)     # float32
    assert np.all(trail[:, 2] == 0)
    final_map = rows["/world/map/splines"][-1][1]["LineStrips3D:strips"]
    assert len(final_map) == summary["splines"] > 0
    ellipses = rows["/world/ellipses/0"][-1][1]["LineStrips3D:strips"]
    assert len(ellipses) == filter_steps


def test_watching_changes_nothing(tmp_path):
    pytest.importorskip("rerun", reason="rerun-sdk (the extra bsslam[viewer]) is not installed")
    from bsslam.viz.rerun_viewer import RerunViewer

    data = simulate(get_world("mixed"), SimConfig(), seed=3, steps=20)
    watched = run_dataset(data, SLAMConfig(), viewer=RerunViewer.save(tmp_path / "v.rrd", block=8))
    plain = run_dataset(data, SLAMConfig())
    np.testing.assert_array_equal(watched.trajectory.poses, plain.trajectory.poses)
    np.testing.assert_array_equal(watched.estimate.covariances, plain.estimate.covariances)
    rows = recording_rows(tmp_path / "v.rrd")
    # blocks of 8 scans, each starting where the last ended
    assert [len(rows[f"/world/trajectory/online/{k}"]) for k in range(3)] == [8, 8, 4]
    first = np.array(rows["/world/trajectory/online/1"][-1][1]["LineStrips3D:strips"][0])
    assert len(first) == 9
    np.testing.assert_allclose(first[0, :2], plain.estimate.poses[7, :2], atol=1e-5)
    assert len(rows["/world/trajectory/relocalized"]) == 1
