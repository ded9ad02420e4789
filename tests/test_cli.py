"""The command line through its own entry point: outputs exist, parse and are sane."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from bsslam.cli import app
from bsslam.io.map_file import read_map_json
from bsslam.io.pose_covariance_file import read_pose_covariance_csv
from bsslam.io.trajectory_file import read_trajectory

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


def csv_header(path):
    with open(path) as fh:
        return next(csv.reader(fh))


def check_run_folder(run: Path, scans: int):
    for name in ("trajectory.tum", "pose_covariance.csv", "map.json", "map.png", "map.svg",
                 "grid.pgm", "grid.yaml", "config.yaml", "summary.json"):
        assert (run / name).stat().st_size > 0, name
    traj = read_trajectory(run / "trajectory.tum")
    assert len(traj) == scans
    stamps, covs = read_pose_covariance_csv(run / "pose_covariance.csv")
    np.testing.assert_array_equal(stamps, traj.stamps)
    np.testing.assert_allclose(covs, np.transpose(covs, (0, 2, 1)), atol=1e-15)
    # the first pose defines the map frame (zero covariance); every later one is PD
    assert np.all(np.linalg.eigvalsh(covs[1:]) > 0)
    grid = yaml.safe_load((run / "grid.yaml").read_text())
    assert {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"} <= set(grid)
    assert (run / grid["image"]).exists() and len(grid["origin"]) == 3
    assert (run / "grid.pgm").read_bytes()[:2] == b"P5"
    splines = read_map_json(run / "map.json").splines
    for s in splines:
        n = s.curve.control_points.shape[0]
        assert s.covariance.shape == (2 * n, 2 * n) and s.curve.knots.shape == (n + s.curve.degree + 1,)
    summary = json.loads((run / "summary.json").read_text())
    assert summary["scans"] == scans and summary["splines"] == len(splines)
    return summary


def test_simulate_writes_every_output(tmp_path):
    out = tmp_path / "sim"
    invoke("simulate", "--world", "mixed", "--steps", 30, "--seed", 2, "--out", out)
    run = (out / "latest").resolve()
    assert run.parent == out and run.name != "latest"
    summary = check_run_folder(run, 30)
    for key in ("ate_m", "final_position_error_m", "mean_nees", "splines", "state_size", "ms_per_step"):
        assert key in summary
    assert summary["ate_m"] < 0.05
    gt = read_trajectory(run / "ground_truth.tum")
    assert len(gt) == 30


def test_simulate_list_names_the_worlds():
    out = invoke("simulate", "--list").output
    for name in ("rounded-room", "corridor-loop", "mixed", "curved-wall"):
        assert name in out


def test_unknown_world_is_a_clear_error(tmp_path):
    result = runner.invoke(app, ["simulate", "--world", "atlantis", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "atlantis" in result.output and "rounded-room" in result.output


def test_fit_experiments_write_their_csvs(tmp_path):
    invoke("experiment", "fit-knots", "--runs", 2, "--out", tmp_path / "k")
    invoke("experiment", "fit-order", "--runs", 2, "--out", tmp_path / "o")
    assert csv_header(tmp_path / "k" / "latest" / "fit_knots.csv") == ["knot_spacing_m", "mse_m2"]
    assert csv_header(tmp_path / "o" / "latest" / "fit_order.csv") == ["order", "mse_m2"]
    orders = [int(r[0]) for r in list(csv.reader(open(tmp_path / "o" / "latest" / "fit_order.csv")))[1:]]
    assert orders == [2, 3, 4]


def test_consistency_and_heading_gain_write_their_csvs(tmp_path):
    invoke("experiment", "consistency", "--variant", "no-extension", "--runs", 2, "--steps", 8,
           "--workers", 1, "--out", tmp_path / "c")
    rows = list(csv.reader(open(tmp_path / "c" / "latest" / "nees.csv")))
    assert rows[0] == ["step", "mean_nees", "lower", "upper"] and len(rows) == 1 + 7
    assert (tmp_path / "c" / "latest" / "nees.png").exists()
    invoke("experiment", "heading-gain", "--runs", 2, "--updates", 3, "--workers", 1, "--out", tmp_path / "h")
    rows = list(csv.reader(open(tmp_path / "h" / "latest" / "heading_sigma.csv")))
    assert rows[0] == ["update", "sigma0_rad", "mean_sigma_phi_rad"] and len(rows) == 1 + 3 * 3


@pytest.mark.skipif(not (DATA / "intel" / "intel-rawodom.clf").exists(), reason="shared/data/intel is absent")
def test_run_on_the_first_150_intel_scans(tmp_path):
    out = tmp_path / "run"
    invoke("run", DATA / "intel" / "intel-rawodom.clf", "--steps", 150, "--out", out,
           "--reference", DATA / "intel" / "intel-rawodom.gt.txt")
    run = (out / "latest").resolve()
    summary = check_run_folder(run, 150)
    assert "ate_m" in summary and "frontend_ate_m" in summary and "online_ate_m" in summary
    # the online filter's trajectory beside the relocalised one, with its joint covariances
    online = read_trajectory(run / "trajectory_online.tum")
    stamps, covs = read_pose_covariance_csv(run / "pose_covariance_online.csv")
    np.testing.assert_array_equal(online.stamps, read_trajectory(run / "trajectory.tum").stamps)
    np.testing.assert_array_equal(stamps, online.stamps)
    assert np.all(np.linalg.eigvalsh(covs[1:]) > 0)
    # the front end's own trajectory, one pose per scan at the same stamps
    np.testing.assert_array_equal(read_trajectory(run / "frontend.tum").stamps,
                                  read_trajectory(run / "trajectory.tum").stamps)
    assert summary["filter_steps"] <= 150 and summary["frontend_matched"] + summary.get("frontend_fallbacks", 0) == 149
    # stamps come from the log
    first = read_trajectory((out / "latest" / "trajectory.tum").resolve()).stamps[0]
    log_first = next(float(line.split()[-3]) for line in open(DATA / "intel" / "intel-rawodom.clf")
                     if line.startswith("FLASER"))
    assert first == pytest.approx(log_first)


def test_run_on_a_missing_file_names_it(tmp_path):
    result = runner.invoke(app, ["run", str(tmp_path / "nope.clf"), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "nope.clf" in result.output


def test_an_error_names_a_long_or_bracketed_path_whole(tmp_path):
    """The message is not wrapped at the terminal width (a pytest temp path once pushed
    "nope.clf" across a line break) nor read as rich markup ("[odd]" would vanish)."""
    folder = tmp_path / ("x" * 90) / "[odd]"
    folder.mkdir(parents=True)
    result = runner.invoke(app, ["run", str(folder / "nope.clf"), "--out", str(tmp_path)])
    assert result.exit_code == 2 and str(folder / "nope.clf") in result.output


def test_evaluate_json_on_a_shifted_copy(tmp_path):
    t = np.arange(50.0)
    ref = np.column_stack([t, np.cos(t / 8), np.sin(t / 8), t / 8])
    est = ref.copy()
    est[:, 1] += 0.1  # a constant offset is removed by the rigid alignment
    np.savetxt(tmp_path / "ref.txt", ref)
    np.savetxt(tmp_path / "est.txt", est)
    out = invoke("evaluate", tmp_path / "est.txt", tmp_path / "ref.txt", "--json").output
    metrics = json.loads(out)
    assert metrics["ate_m"] == pytest.approx(0.0, abs=1e-9)


def test_a_machines_first_run_says_it_compiles_first(tmp_path, monkeypatch):
    import bsslam.cli as cli
    import bsslam.compiled as compiled

    monkeypatch.setattr(cli, "_compile_hint_shown", False)
    monkeypatch.setattr(compiled, "needs_compiling", lambda kernel: True)
    first = invoke("simulate", "--world", "mixed", "--steps", 3, "--out", tmp_path / "a").output
    assert "compiling the inner loops" in first
    monkeypatch.setattr(cli, "_compile_hint_shown", False)
    monkeypatch.setattr(compiled, "needs_compiling", lambda kernel: False)
    assert "compiling" not in invoke("simulate", "--world", "mixed", "--steps", 3, "--out", tmp_path / "b").output


def test_the_compile_check_finds_this_machines_cache(monkeypatch, tmp_path):
    """After the filter has run (the tests above compiled it), the cache index is there; an
    empty NUMBA_CACHE_DIR has none."""
    from bsslam.compiled import needs_compiling
    from bsslam.slam.range_kernels import linearize_beams

    invoke("simulate", "--world", "mixed", "--steps", 3, "--out", tmp_path)
    assert not needs_compiling(linearize_beams)
    cache_file = linearize_beams._cache._cache_file
    monkeypatch.setattr(cache_file, "_index_path", str(tmp_path / "missing.nbi"))
    assert needs_compiling(linearize_beams)
