"""The command line through its own entry point: outputs exist, parse and are sane."""

import csv
import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

import bsslam
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


def test_simulate_writes_every_output(tmp_path, caplog):
    out = tmp_path / "sim"
    with caplog.at_level(logging.WARNING):
        invoke("simulate", "--world", "mixed", "--steps", 30, "--seed", 2, "--out", out)
    assert not caplog.records, [r.getMessage() for r in caplog.records]  # a clean run warns of nothing
    run = (out / "latest").resolve()
    assert run.parent == out and run.name != "latest"
    summary = check_run_folder(run, 30)
    for key in ("ate_m", "final_position_error_m", "mean_nees", "splines", "state_size", "ms_per_step"):
        assert key in summary
    assert summary["ate_m"] < 0.05
    gt = read_trajectory(run / "ground_truth.tum")
    assert len(gt) == 30


def test_a_run_of_one_scan_completes_without_an_ate(tmp_path):
    """ATE needs two poses to align; a run of one scan (the smallest ``--steps``, or one
    interrupted at its first scan) writes its outputs and leaves ATE out instead of failing."""
    invoke("simulate", "--world", "mixed", "--steps", 1, "--out", tmp_path)
    summary = check_run_folder((tmp_path / "latest").resolve(), 1)
    assert summary["status"] == "complete" and "ate_m" not in summary


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


def test_the_consistency_experiment_starts_from_a_config_file(tmp_path):
    """``--config``: the variant starts from the file's settings (here a shared range error
    and the invariant EKF), the numbers those of the library called with that base; the
    options given on the command line win over the file; a bad file is one line, exit 2."""
    import dataclasses

    from bsslam.config import SLAMConfig
    from bsslam.experiments.consistency import consistency_experiment

    cfg = tmp_path / "shared.yaml"
    cfg.write_text("estimator: invariant\nobservation:\n  sigma_shared_m: 0.01\n")
    args = ("experiment", "consistency", "--variant", "no-extension", "--runs", 2, "--steps", 8, "--workers", 1)
    invoke(*args, "--config", cfg, "--out", tmp_path / "with")
    invoke(*args, "--out", tmp_path / "without")
    invoke(*args, "--config", cfg, "--estimator", "ekf", "--out", tmp_path / "ekf")

    def nees(name):
        return np.array([float(r[1]) for r in list(csv.reader(open(tmp_path / name / "latest" / "nees.csv")))[1:]])

    base = SLAMConfig(estimator="invariant")
    base = base.replace(observation=dataclasses.replace(base.observation, sigma_shared_m=0.01))
    expected = consistency_experiment("no-extension", runs=2, steps=8, workers=1, base=base).mean_nees
    np.testing.assert_allclose(nees("with"), expected, rtol=1e-5)      # the CSV's 6 significant digits
    assert np.abs(nees("with") - nees("without")).max() > 1e-3
    summary = json.loads((tmp_path / "ekf" / "latest" / "summary.json").read_text())
    assert summary["estimator"] == "ekf" and summary["config"] == str(cfg)
    without = json.loads((tmp_path / "without" / "latest" / "summary.json").read_text())
    assert without["estimator"] == "ekf" and without["significant_bends"] is False   # the paper's filter
    bad = tmp_path / "bad.yaml"
    bad.write_text("observation:\n  sigma_shared_m: nope\n")
    result = runner.invoke(app, [str(a) for a in (*args, "--config", bad, "--out", tmp_path / "bad")])
    assert result.exit_code == 2 and str(bad) in result.output and "Traceback" not in result.output


def test_the_consistency_experiment_scales_the_simulated_noise(tmp_path):
    """The noise-scale options give the library's numbers with :func:`scaled_noise`, and
    summary.json records the scales and the results; a negative scale is a one-line error."""
    from bsslam.config import SLAMConfig
    from bsslam.experiments.consistency import consistency_experiment, paper_filter, scaled_noise

    args = ("experiment", "consistency", "--variant", "no-extension", "--runs", 2, "--steps", 8, "--workers", 1)
    invoke(*args, "--translation-noise-scale", 0.3, "--heading-noise-scale", 2, "--out", tmp_path / "s")
    nees = np.array([float(r[1]) for r in list(csv.reader(open(tmp_path / "s" / "latest" / "nees.csv")))[1:]])
    expected = consistency_experiment("no-extension", runs=2, steps=8, workers=1, base=paper_filter(SLAMConfig()),
                                      sim=scaled_noise(translation_scale=0.3, heading_scale=2.0))
    np.testing.assert_allclose(nees, expected.mean_nees, rtol=1e-5)
    summary = json.loads((tmp_path / "s" / "latest" / "summary.json").read_text())
    assert summary["noise_scales"] == {"range": 1.0, "translation": 0.3, "heading": 2.0}
    assert summary["results"]["fraction_inside_band"] == pytest.approx(expected.fraction_inside(), abs=1e-4)
    assert summary["results"]["mean_nees"] == pytest.approx(expected.mean_nees.mean(), abs=1e-4)
    z = np.sqrt(np.mean(expected.mean_error_z() ** 2, axis=0))
    assert summary["results"]["rms_mean_error_z"] == pytest.approx(z, abs=0.01)
    result = runner.invoke(app, [str(a) for a in (*args, "--range-noise-scale", -1, "--out", tmp_path / "bad")])
    assert result.exit_code == 2 and "Traceback" not in result.output


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
    out = invoke("evaluate", tmp_path / "est.txt", tmp_path / "ref.txt", "--json", "-").output
    metrics = json.loads(out)
    assert metrics["ate_m"] == pytest.approx(0.0, abs=1e-9)


def test_evaluate_saves_json_and_plot_and_keeps_printing(tmp_path):
    t = np.arange(60.0)
    ref = np.column_stack([t, np.cos(t / 8), np.sin(t / 8), t / 8])
    est = ref.copy()
    est[:, 2] += 0.002 * t  # a growing error the alignment cannot remove
    np.savetxt(tmp_path / "ref.txt", ref)
    np.savetxt(tmp_path / "est.txt", est)
    out = invoke("evaluate", tmp_path / "est.txt", tmp_path / "ref.txt", "--json", tmp_path / "m.json",
                 "--plot", tmp_path / "e.png").output
    saved = json.loads((tmp_path / "m.json").read_text())
    assert saved["matched"] == 60 and saved["ate_m"] > 0.01
    assert "ate_m" in out and f"{saved['ate_m']:.4g}"[:5] in out  # the table is still printed
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _nees_files(tmp_path, n=60):
    """An estimate with covariances and its reference in another frame, as a run writes them."""
    from bsslam.io.pose_covariance_file import write_pose_covariance_csv
    from bsslam.io.trajectory_file import write_tum
    from bsslam.se2 import compose
    from bsslam.trajectory import Trajectory

    rng = np.random.default_rng(2)
    t = np.arange(float(n))
    truth = np.column_stack([np.cos(t / 8), np.sin(t / 8), t / 8])
    cov = np.tile(np.diag([0.01, 0.04, 0.0004]), (n, 1, 1))
    cov[0] = 0.0
    est = Trajectory(t, truth + rng.normal(size=(n, 3)) * [0.1, 0.2, 0.02], cov)
    write_tum(tmp_path / "est.tum", est)
    write_pose_covariance_csv(tmp_path / "cov.csv", est)
    np.savetxt(tmp_path / "ref.txt", np.column_stack([t, compose(np.array([2.0, -1.0, 1.0]), truth)]))
    return tmp_path / "est.tum", tmp_path / "ref.txt", tmp_path / "cov.csv"


def test_evaluate_nees_with_the_reference_sigma_json_and_plot(tmp_path):
    import math

    from bsslam.eval.evaluate_files import nees_files

    est, ref, cov = _nees_files(tmp_path)
    out = invoke("evaluate", est, ref, "--covariance", cov, "--reference-sigma", "0.03,0.5",
                 "--json", tmp_path / "m.json", "--plot", tmp_path / "e.png").output
    saved = json.loads((tmp_path / "m.json").read_text())
    expected = nees_files(est, ref, cov, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=math.radians(0.5))
    assert saved["nees_mean"] == pytest.approx(expected.mean) and saved["nees_median"] == pytest.approx(expected.median)
    assert saved["nees_fraction_outside_95"] == expected.fraction_outside_95
    assert saved["nees_count"] == 59 and saved["nees_skipped_singular"] == 1
    assert "nees_fraction_outside_95" in out and str(saved["nees_mean"])[:6] in out  # the table
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the reference's σ only ever lowers NEES
    plain = json.loads(invoke("evaluate", est, ref, "--covariance", cov, "--json", "-").output)
    assert plain["nees_mean"] > saved["nees_mean"] and plain["ate_m"] == saved["ate_m"]


def test_evaluate_nees_bad_input(tmp_path):
    est, ref, cov = _nees_files(tmp_path)
    lines = cov.read_text().splitlines()
    lines[5] = lines[5].rsplit(",", 1)[0] + ",inf"
    cov.write_text("\n".join(lines) + "\n")
    result = runner.invoke(app, ["evaluate", str(est), str(ref), "--covariance", str(cov)])
    assert result.exit_code == 2 and str(cov) in result.output and "non-finite" in result.output
    for bad in ("0.03", "0.03,-1", "a,b", "0.03,nan"):
        result = runner.invoke(app, ["evaluate", str(est), str(ref), "--covariance", str(cov),
                                     "--reference-sigma", bad])
        assert result.exit_code == 2 and "SIGMA_XY_M,SIGMA_HEADING_DEG" in result.output, bad
    result = runner.invoke(app, ["evaluate", str(est), str(ref), "--reference-sigma", "0.03,0.5"])
    assert result.exit_code == 2 and "give --covariance" in result.output


def test_version_and_verbosity_flags_before_or_after_the_verb():
    assert invoke("--version").output.strip() == f"bsslam {bsslam.__version__}"
    for args in (["-q", "config"], ["config", "-q"], ["config", "--verbose"], ["-v", "config"]):
        assert "spline:" in invoke(*args).output
    result = runner.invoke(app, ["config", "-v", "-q"])
    assert result.exit_code != 0 and "not both" in result.output


def test_config_prints_the_defaults_as_yaml_that_loads_back_equal(tmp_path):
    from bsslam.config import SLAMConfig
    from bsslam.io.config_file import load_config

    (tmp_path / "c.yaml").write_text(invoke("config").stdout)
    assert load_config(tmp_path / "c.yaml") == SLAMConfig()


@pytest.mark.parametrize("middle", ["mid.tum", "mid.txt"])
def test_convert_round_trips_both_formats(tmp_path, middle):
    t = np.linspace(10.0, 20.0, 11)
    poses = np.column_stack([t, np.sin(t), np.cos(t), np.linspace(-3.1, 3.1, 11)])
    np.savetxt(tmp_path / "in.txt", poses, fmt="%.17g")
    invoke("convert", tmp_path / "in.txt", tmp_path / middle, "--to", "tum")
    assert len((tmp_path / middle).read_text().splitlines()[1].split()) == 8
    invoke("convert", tmp_path / middle, tmp_path / "back.txt")
    back = read_trajectory(tmp_path / "back.txt")
    assert len((tmp_path / "back.txt").read_text().splitlines()[1].split()) == 4
    np.testing.assert_array_equal(back.stamps, t)
    np.testing.assert_array_equal(back.poses[:, :2], poses[:, 1:3])
    np.testing.assert_allclose(back.poses[:, 2], poses[:, 3], atol=1e-15)


def test_convert_of_a_bad_file_names_its_line(tmp_path):
    (tmp_path / "bad.txt").write_text("1 2 3 4\n1 2 x 4\n")
    result = runner.invoke(app, ["convert", str(tmp_path / "bad.txt"), str(tmp_path / "o.tum")])
    assert result.exit_code == 2 and "bad.txt:2" in result.output


def write_carmen_log(path, world, seed, steps):
    """A CARMEN log (FLASER lines) and its ``.gt.txt`` reference from a simulated run: the
    simulator's 181 beams over 180° are CARMEN's beam layout; no return → 81.9 m."""
    from bsslam.io.carmen_messages import carmen_beam_angles
    from bsslam.sim import SimConfig, get_world, simulate

    data = simulate(get_world(world), SimConfig(), seed=seed, steps=steps)
    with open(path, "w") as fh:
        for frame in data:
            np.testing.assert_array_equal(frame.scan.angles, carmen_beam_angles(181))
            ranges = np.where(frame.scan.ranges < frame.scan.max_range, frame.scan.ranges, 81.9)
            pose = " ".join(map(repr, frame.odometry.tolist()))
            fh.write(f"FLASER 181 {' '.join(map(repr, ranges.tolist()))} {pose} {pose} {frame.stamp!r} sim {frame.stamp!r}\n")
    gt = data.ground_truth
    np.savetxt(path.with_suffix(".gt.txt"), np.column_stack([gt.stamps, gt.poses]), fmt="%.17g")
    return path


def test_bench_takes_logs_folders_and_patterns_and_runs_them_on_two_workers(tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    (tmp_path / "a").mkdir()
    write_carmen_log(tmp_path / "a" / "one.clf", "mixed", 1, 12)
    write_carmen_log(tmp_path / "two.clf", "rounded-room", 2, 12)
    (tmp_path / "a" / "notes.log").write_text("not a laser log: .log is not searched in folders\n")
    monkeypatch.delenv("BSSLAM_DATA", raising=False)
    out = invoke("bench", tmp_path / "a", str(tmp_path / "t*.clf"), "--workers", 2, "-q").output
    rows = {line.split("│")[1].strip(): line for line in out.splitlines() if ".clf" in line}
    assert set(rows) == {"one.clf", "two.clf"}
    assert all(line.split("│")[3].strip() == "12" for line in rows.values())  # scans
    # without LOGS the folder comes from --data or BSSLAM_DATA, never from a default
    result = runner.invoke(app, ["bench"])
    assert result.exit_code == 2 and "BSSLAM_DATA" in result.output
    monkeypatch.setenv("BSSLAM_DATA", str(tmp_path / "a"))
    out = invoke("bench", "--workers", 1, "--steps", 5).output
    assert "one.clf" in out and "two.clf" not in out


def test_bench_perturb_runs_seeded_noise_and_float32_and_reports_the_spread(tmp_path):
    from bsslam.bench import BenchRow, Perturbation, bench_log, stability

    log = write_carmen_log(tmp_path / "one.clf", "mixed", 1, 10)
    out = invoke("bench", log, "--workers", 1, "--perturb", 2, "--steps", 8, "-q").output
    def inputs(output):
        return [line.split("│")[2].strip() for line in output.splitlines()
                if "one.clf" in line and ("noise" in line or "float32" in line)]
    assert inputs(out)[:3] == ["noise seed 0", "noise seed 1", "float32"]
    assert "ATE over 2 runs (seeds 0…1) with 1 mm range noise" in out
    later = invoke("bench", log, "--workers", 1, "--perturb", 2, "--first-seed", 10, "--steps", 8, "-q").output
    assert inputs(later)[:3] == ["noise seed 10", "noise seed 11", "float32"]
    assert "(seeds 10…11)" in later
    result = runner.invoke(app, ["bench", str(log), "--first-seed", "10"])
    assert result.exit_code == 2 and "--perturb" in result.output
    # the same seed gives the same run; the noise does move the result
    from bsslam.config import SLAMConfig
    a, b = (bench_log(log, SLAMConfig(), steps=8, perturbation=Perturbation(0.001, 0)) for _ in range(2))
    clean = bench_log(log, SLAMConfig(), steps=8)
    assert a.ate_m == b.ate_m and a.ate_m != clean.ate_m
    rows = [BenchRow("x", 1, 0, 0, 0, 0, ate, 0, 0, 0, "-", 0, variant, nees_outside_95=out, nees_median=nees)
            for ate, variant, out, nees in [(0.1, "noise seed 0", 0.0, 1.0), (0.3, "noise seed 1", 0.1, 2.0),
                                            (0.2, "noise seed 2", 0.3, 9.0), (0.5, "float32", 0.5, 4.0),
                                            (0.9, "as logged", 0.9, 90.0)]]
    (st,) = stability(rows)
    assert (st.median_m, st.min_m, st.max_m, st.float32_m) == (0.2, 0.1, 0.3, 0.5)
    assert st.spread == pytest.approx(1.0) and st.worst_ratio == pytest.approx(2.5)
    # the covariance's calibration over the noise and float32 runs (not the as-logged one)
    assert (st.nees_median, st.outside_95) == (3.0, 0.2)
    assert "online NEES" in out and "outside 95 %" in out


def test_run_on_a_folder_runs_each_log_in_it(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    write_carmen_log(logs / "one.clf", "mixed", 1, 6)
    write_carmen_log(logs / "two.clf", "mixed", 2, 6)
    invoke("run", logs, "--out", tmp_path / "out", "-q")
    for name in ("one", "two"):
        assert len(read_trajectory((tmp_path / "out" / name / "latest" / "trajectory.tum").resolve())) == 6


def test_a_bag_without_the_ros_extra_names_it(tmp_path, monkeypatch):
    import sys

    for name in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")] or ["rosbags"]:
        monkeypatch.setitem(sys.modules, name, None)  # as if not installed
    monkeypatch.delitem(sys.modules, "bsslam.io.rosbag", raising=False)
    (tmp_path / "x.bag").write_bytes(b"")
    result = runner.invoke(app, ["run", str(tmp_path / "x.bag"), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "bsslam[ros]" in result.output


def test_consistency_on_a_local_cluster_writes_the_serial_numbers(tmp_path):
    pytest.importorskip("distributed")
    for workers in (1, 2):
        invoke("experiment", "consistency", "--variant", "no-extension", "--runs", 3, "--steps", 6,
               "--workers", workers, "--out", tmp_path / str(workers))
    assert ((tmp_path / "1" / "latest" / "nees.csv").read_text()
            == (tmp_path / "2" / "latest" / "nees.csv").read_text())


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


def test_the_input_limits_come_from_the_configuration(tmp_path):
    """``input.max_speed_m_s`` reaches the reader: a robot limited to 1 cm/s has every step
    of the simulated log bridged and counted; the defaults accept them all."""
    import json

    log = write_carmen_log(tmp_path / "one.clf", "mixed", 1, 6)
    (tmp_path / "slow.yaml").write_text("input: {max_speed_m_s: 0.01}\nrelocalize: false\n")
    (tmp_path / "plain.yaml").write_text("relocalize: false\n")
    skipped = {}
    for name in ("slow", "plain"):
        invoke("run", log, "--config", tmp_path / f"{name}.yaml", "--out", tmp_path / name, "-q")
        summary = json.loads((tmp_path / name / "latest" / "summary.json").read_text())
        skipped[name] = summary["skipped_input_by_reason"]
    assert skipped["plain"] == {}
    assert sum(v for k, v in skipped["slow"].items() if "implausible" in k) >= 4


def test_a_signal_whose_interrupt_was_swallowed_is_delivered_by_the_next_progress_step():
    """A KeyboardInterrupt raised from the signal handler while numba compiles (inside a
    ctypes callback) is printed and dropped by the interpreter; the run must still stop,
    once, at its next progress step."""
    import os
    import signal

    from bsslam.cli import progress_bar, signals_interrupt

    with signals_interrupt(), progress_bar("run", 10, "scans") as update:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):   # the handler runs at the next bytecode boundary
                pass
        except KeyboardInterrupt:
            pass                     # what a ctypes callback does with it
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            update(1)
        update(2)                    # delivered once


@pytest.mark.parametrize("argv, status, stream, text", [
    (["--help"], 0, "stdout", "Usage"),
    (["run", "/no/such/log.clf"], 2, "stderr", "no such file"),
])
def test_the_command_exits_with_its_status_its_output_and_the_atexit_handlers(argv, status, stream, text):
    # the command line's app() skips the interpreter's teardown: what it prints, the exit
    # status and the atexit handlers (logging, rerun, temporary folders) must survive that
    import subprocess
    import sys

    code = ("import atexit, sys\n"
            "atexit.register(lambda: print('atexit ran', file=sys.stderr))\n"
            "from bsslam.cli import app\n"
            f"sys.argv = ['bsslam'] + {argv!r}\n"
            "app()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == status, done.stderr
    assert text.lower() in getattr(done, stream).lower()
    assert done.stderr.rstrip().endswith("atexit ran")


def test_bench_json_holds_every_run_and_the_spread_as_valid_json(tmp_path):
    log = write_carmen_log(tmp_path / "one.clf", "mixed", 1, 10)
    target = tmp_path / "bench.json"
    out = invoke("bench", log, "--workers", 1, "--perturb", 2, "--steps", 8, "--json", target, "-q").output
    report = json.loads(target.read_text(), parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))
    assert [r["variant"] for r in report["runs"]] == ["noise seed 0", "noise seed 1", "float32"]
    assert all(r["log"] == "one.clf" and r["scans"] == 8 for r in report["runs"])
    # the same figures as the table, and the spread computed from them
    table = {line.split("│")[2].strip(): float(line.split("│")[11]) for line in out.splitlines()
             if "one.clf" in line and ("noise" in line or "float32" in line)}
    assert {r["variant"]: round(r["ate_m"], 3) for r in report["runs"]} == table
    (st,) = report["stability"]
    ates = sorted(r["ate_m"] for r in report["runs"] if r["variant"].startswith("noise"))
    assert (st["min_m"], st["max_m"], st["runs"]) == (ates[0], ates[1], 2)
    assert st["spread"] == pytest.approx((ates[1] - ates[0]) / st["median_m"])
    assert report["perturb_sigma_m"] == 0.001 and report["failures"] == []
    # '-' prints only the JSON; a log without a reference has null, not NaN, figures
    log.with_suffix(".gt.txt").unlink()
    printed = invoke("bench", log, "--workers", 1, "--steps", 5, "--json", "-", "-q").output
    (run,) = json.loads(printed, parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))["runs"]
    assert run["ate_m"] is None and run["scans"] == 5 and "stability" not in json.loads(printed)
    # a path that cannot be written is refused before any run
    result = runner.invoke(app, ["bench", str(log), "--json", str(tmp_path / "no" / "such.json")])
    assert result.exit_code == 2 and "--json" in result.output
