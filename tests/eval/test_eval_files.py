"""evaluate_files on small files written in tmp_path, and on the shipped Intel reference."""

import math
from pathlib import Path

import numpy as np
import pytest

from bsslam.errors import InputError
from bsslam.eval.evaluate_files import evaluate_files, nees_files
from bsslam.eval.pose_nees import pose_nees
from bsslam.io.carmen import CarmenReader
from bsslam.io.pose_covariance_file import write_pose_covariance_csv
from bsslam.io.trajectory_file import read_trajectory, write_tum
from bsslam.se2 import compose
from bsslam.trajectory import Trajectory, wrap_angle

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


def _nees_case(tmp_path, n=40):
    """A run folder with trajectory and covariances, and a reference in another frame."""
    rng = np.random.default_rng(5)
    stamps = 100.0 + np.arange(n) * 0.5
    truth = np.column_stack([np.cos(stamps / 5), np.sin(stamps / 3), wrap_angle(stamps / 4)])
    covariances = np.tile(np.diag([0.04, 0.01, 0.0025]), (n, 1, 1))
    covariances[0] = 0.0
    est = Trajectory(stamps, truth + rng.normal(size=(n, 3)) * [0.2, 0.1, 0.05], covariances)
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    write_tum(run / "trajectory_online.tum", est)
    write_pose_covariance_csv(run / "pose_covariance_online.csv", est)
    _write_reference(tmp_path / "gt.txt", Trajectory(stamps, compose(np.array([5.0, 1.0, 0.7]), truth)))
    return run / "trajectory_online.tum", tmp_path / "gt.txt", run / "pose_covariance_online.csv", est


def test_nees_from_files_matches_the_library(tmp_path):
    est_path, ref_path, cov_path, est = _nees_case(tmp_path)
    result = evaluate_files(est_path, ref_path, covariance_path=cov_path, reference_sigma_xy_m=0.03,
                            reference_sigma_phi_rad=0.01)
    expected = pose_nees(read_trajectory(est_path), read_trajectory(ref_path), est.covariances,
                         reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01)
    assert result["nees_mean"] == pytest.approx(expected.mean) and result["nees_median"] == expected.median
    assert result["nees_fraction_outside_95"] == expected.fraction_outside_95
    assert result["nees_count"] == 39 and result["nees_skipped_singular"] == 1
    assert 1.0 < result["nees_mean"] < 6.0  # the errors were drawn from the covariances
    report = nees_files(est_path, ref_path, cov_path, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01)
    np.testing.assert_array_equal(report.nees, expected.nees)


def _rewrite_row(path, row, change):
    lines = path.read_text().splitlines()
    fields = lines[row + 1].split(",")
    change(fields)
    lines[row + 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("change, message", [
    (lambda f: f.__setitem__(0, repr(float(f[0]) + 0.01)), "row 3 has stamp"),
    (lambda f: f.__setitem__(5, "nan"), "non-finite covariance in row 3"),
    (lambda f: f.__setitem__(9, "-1.0"), "row 3 is not positive semidefinite"),
    (lambda f: f.__setitem__(2, "0.5"), "row 3 is not symmetric"),
])
def test_bad_covariance_files_are_named(tmp_path, change, message):
    est_path, ref_path, cov_path, _ = _nees_case(tmp_path)
    _rewrite_row(cov_path, 3, change)
    with pytest.raises(InputError, match=f"^{cov_path}: .*{message}"):
        evaluate_files(est_path, ref_path, covariance_path=cov_path)


def test_a_covariance_file_of_another_run_is_refused(tmp_path):
    est_path, ref_path, cov_path, _ = _nees_case(tmp_path)
    lines = cov_path.read_text().splitlines()
    cov_path.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(InputError, match=f"^{cov_path}: 39 covariance rows for an estimate of 40 poses"):
        evaluate_files(est_path, ref_path, covariance_path=cov_path)
