"""evaluate_files on small files written in tmp_path, and on the shipped Intel reference."""

import math
from pathlib import Path

import numpy as np
import pytest

from bsslam.eval.evaluate_files import evaluate_files
from bsslam.io.carmen import CarmenReader
from bsslam.io.pose_covariance_file import write_pose_covariance_csv
from bsslam.io.trajectory_file import write_tum
from bsslam.trajectory import Trajectory

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def _write_reference(path, traj):
    rows = np.column_stack([traj.stamps, traj.poses])
    np.savetxt(path, rows, header="timestamp x y theta")


def _case(tmp_path):
    n = 20
    stamps = np.arange(n) * 0.5
    truth = np.column_stack([np.cos(stamps), np.sin(stamps), stamps + math.pi / 2])
    # the estimate is off by a known error with a known covariance: NEES of each pose = 3
    sigma = np.array([0.1, 0.2, 0.05])
    signs = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    covariances = np.tile(np.diag(sigma ** 2), (n, 1, 1))
    covariances[0] = 0.0  # like a real run: the first pose defines the frame
    est = Trajectory(stamps, truth + signs[:, None] * sigma, covariances)
    run = tmp_path / "run"
    run.mkdir()
    write_tum(run / "trajectory.tum", est)
    write_pose_covariance_csv(run / "pose_covariance.csv", est)
    _write_reference(tmp_path / "gt.txt", Trajectory(stamps, truth))
    return run / "trajectory.tum", tmp_path / "gt.txt"


def test_metrics_and_nees_with_an_exact_reference(tmp_path):
    est_path, ref_path = _case(tmp_path)
    result = evaluate_files(est_path, ref_path, exact_reference=True)
    assert result["matched"] == 20
    assert result["nees_mean"] == pytest.approx(3.0) and result["nees_count"] == 19
    assert result["ate_m"] < math.hypot(0.1, 0.2)  # alignment can only reduce the error
    for key in ("rpe_trans_m", "rpe_rot_deg", "rpe_trans_mean_m", "rpe_rot_mean_deg"):
        assert result[key] > 0
    # an approximate reference gives no NEES, and without relations no relation keys
    plain = evaluate_files(est_path, ref_path)
    assert "nees_mean" not in plain and not any(k.startswith("relations") for k in plain)
    assert plain["ate_m"] == result["ate_m"]


def test_time_offset_and_relations(tmp_path):
    est_path, ref_path = _case(tmp_path)
    assert evaluate_files(est_path, ref_path, ref_offset=0.5)["matched"] == 19
    relations = tmp_path / "r.relations"
    relations.write_text("100.0 100.5 0 0 0 0 0 0\n")
    result = evaluate_files(est_path, None, relations, offset=100.0)
    assert result["relations_used"] == 1 and result["relations_total"] == 1
    assert "ate_m" not in result


def test_odometry_of_the_intel_log_scores_like_the_data_readme(tmp_path):
    log = DATA / "intel" / "intel-rawodom.clf"
    if not log.exists():
        pytest.skip(f"shared CARMEN data not found at {DATA}")
    frames = list(CarmenReader(log))
    odometry = Trajectory([f.stamp for f in frames], [f.odometry for f in frames])
    reference = DATA / "intel" / "intel-rawodom.gt.txt"
    est_path = tmp_path / "odometry.tum"
    write_tum(est_path, odometry)
    result = evaluate_files(est_path, reference)
    assert result["matched"] == 174
    assert 20.0 < result["ate_m"] < 28.0  # "drifts by ~24 m ATE"
