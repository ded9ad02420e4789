"""pose_nees: χ² statistics on samples drawn from the stated covariances, invariance to the
frames of the estimate and the reference, skipped singular poses, and bad input."""

import math

import numpy as np
import pytest
from scipy import stats

from bsslam.errors import InputError
from bsslam.eval.consistency import chi2_band, nees
from bsslam.eval.pose_nees import pose_nees, singular_covariances
from bsslam.eval.trajectory_error import _transform
from bsslam.se2 import compose
from bsslam.trajectory import Trajectory, wrap_angle


def _random_covariances(rng, n):
    """(n, 3, 3) correlated, strongly anisotropic covariances (σ from mm to dm)."""
    a = rng.normal(size=(n, 3, 3)) * np.array([0.2, 0.03, 0.05])[None, :, None]
    return a @ a.transpose(0, 2, 1) + np.diag([1e-4, 1e-6, 1e-5])


def _sampled_case(seed, n, sigma_xy=0.03, sigma_phi=math.radians(0.5)):
    """Truth in the estimate's frame; the estimate off by N(0, P_k), the reference off by
    N(0, P_ref) and given in another frame (rotated by 2 rad and shifted)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.5
    truth = np.column_stack([10 * np.cos(t / 40), 6 * np.sin(t / 25), wrap_angle(t / 7)])
    cov = _random_covariances(rng, n)
    est = truth + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 3)))
    ref = truth + rng.normal(size=(n, 3)) * np.array([sigma_xy, sigma_xy, sigma_phi])
    return Trajectory(t, est), Trajectory(t, compose(np.array([3.0, -7.0, 2.0]), ref)), cov, ref


def test_nees_of_samples_from_the_stated_covariance_is_chi2_3():
    n = 2000
    sigma_xy, sigma_phi = 0.03, math.radians(0.5)
    est, ref, cov, _ = _sampled_case(7, n, sigma_xy, sigma_phi)
    report = pose_nees(est, ref, cov, reference_sigma_xy_m=sigma_xy, reference_sigma_phi_rad=sigma_phi,
                       frame="aligned")
    assert report.matched == n and len(report.nees) == n and report.skipped_singular == 0
    # the mean of n χ²(3) values lies in the 99.9 % band of χ²(3n)/n (the alignment's three
    # fitted parameters shift it by about 3/n, far inside)
    low, high = chi2_band(3, n, 0.999)
    assert low < report.mean < high
    assert report.median == pytest.approx(stats.chi2.median(3), rel=0.1)
    # the count above χ²(3, 0.95) is Binomial(n, 0.05): inside its 99.9 % interval
    k_low, k_high = stats.binom.ppf([0.0005, 0.9995], n, 0.05)
    assert k_low / n <= report.fraction_outside_95 <= k_high / n
    assert report.upper_95 == pytest.approx(7.8147, abs=1e-4)
    assert report.band_95 == pytest.approx((0.2158, 9.3484), abs=1e-4)
    # leaving the reference's σ out makes the same errors look too large
    assert pose_nees(est, ref, cov, frame="aligned").mean > high


def test_nees_does_not_depend_on_the_frames_of_estimate_or_reference():
    est, ref, cov, ref_in_est_frame = _sampled_case(11, 300)
    base = pose_nees(est, ref, cov, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01, frame="aligned")
    # the errors are those in the estimate's frame, up to the alignment's own error
    expected = est.poses - ref_in_est_frame
    np.testing.assert_allclose(base.errors, expected, atol=0.05)
    # the reference in yet another frame: same NEES, covariances untouched
    moved_ref = Trajectory(ref.stamps, compose(np.array([-40.0, 5.0, -2.5]), ref.poses))
    np.testing.assert_allclose(pose_nees(est, moved_ref, cov, reference_sigma_xy_m=0.03,
                                         reference_sigma_phi_rad=0.01, frame="aligned").nees, base.nees, rtol=1e-7)
    # the estimate with its covariances moved rigidly (the frame is arbitrary): same NEES
    angle = 1.3
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = _transform(Trajectory(est.stamps, est.poses, cov), rotation, np.array([12.0, -4.0]))
    again = pose_nees(moved, ref, moved.covariances, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01,
                      frame="aligned")
    np.testing.assert_allclose(again.nees, base.nees, rtol=1e-7)
    np.testing.assert_allclose(again.errors[:, 2], base.errors[:, 2], atol=1e-12)


def test_error_weighed_in_the_wrong_frame_changes_the_nees():
    """The test above can fail: weighing the aligned-frame error with the unrotated
    covariance gives a different NEES for anisotropic covariances."""
    est, ref, cov, _ = _sampled_case(11, 300)
    base = pose_nees(est, ref, cov, frame="aligned")
    angle = 2.0  # the frame rotation built into _sampled_case
    c, s = math.cos(angle), math.sin(angle)
    wrong = base.errors.copy()
    wrong[:, :2] = base.errors[:, :2] @ np.array([[c, -s], [s, c]]).T
    wrong_nees = np.einsum("ni,ni->n", wrong, np.linalg.solve(cov, wrong[:, :, None])[:, :, 0])
    assert np.median(np.abs(wrong_nees / base.nees - 1)) > 0.2


def test_known_errors_with_the_reference_sigma_and_a_wrapped_heading():
    stamps = np.arange(3.0)
    ref = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, math.pi - 0.01], [2.0, 1.0, 0.5]])
    est = ref + np.array([[0.0, 0.0, 0.0], [0.1, -0.2, 0.0], [0.0, 0.05, 0.0]])
    est[1, 2] = -math.pi + 0.05  # 0.06 rad from the reference across ±π
    cov = np.stack([np.zeros((3, 3)), np.diag([0.01, 0.03, 0.0002]), np.diag([0.01, 0.01, 0.01])])
    report = pose_nees(Trajectory(stamps, est), Trajectory(stamps, ref), cov, reference_sigma_xy_m=0.1,
                       reference_sigma_phi_rad=0.01, frame="same")
    assert report.skipped_singular == 1 and report.matched == 3
    np.testing.assert_allclose(report.stamps, [1.0, 2.0])
    np.testing.assert_allclose(report.errors[0], [0.1, -0.2, 0.06], atol=1e-12)
    expected = [0.1 ** 2 / 0.02 + 0.2 ** 2 / 0.04 + 0.06 ** 2 / 0.0003, 0.05 ** 2 / 0.02]
    np.testing.assert_allclose(report.nees, expected)
    assert report.mean == pytest.approx(np.mean(expected)) and report.median == pytest.approx(np.mean(expected))
    assert report.fraction_outside_95 == 0.5  # 14.8 is above 7.81, 0.125 is not


def _drifting_case(rng, n, sigma_xy, sigma_phi, step_sigma=(0.02, 0.01, 0.01)):
    """A SLAM-like estimate: its first pose exact, then an odometry-like random walk whose
    covariance P_k grows from zero; the reference off by N(0, P_ref) at every pose, the
    first included, and given in another frame. Returns (est, ref, P)."""
    steps = np.column_stack([np.full(n - 1, 0.5), np.zeros(n - 1), rng.uniform(-0.3, 0.3, n - 1)])
    truth = np.zeros((n, 3))
    for k in range(1, n):
        truth[k] = compose(truth[k - 1], steps[k - 1])
    q = np.diag(step_sigma) ** 2          # per step (m, m, rad), in the robot frame
    est, cov = truth.copy(), np.zeros((n, 3, 3))
    for k in range(1, n):
        noisy = steps[k - 1] + rng.normal(size=3) * np.sqrt(np.diag(q))
        est[k] = compose(est[k - 1], noisy)
        c, s_ = math.cos(est[k - 1, 2]), math.sin(est[k - 1, 2])
        F = np.array([[1, 0, -s_ * noisy[0] - c * noisy[1]], [0, 1, c * noisy[0] - s_ * noisy[1]], [0, 0, 1]])
        G = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
        cov[k] = F @ cov[k - 1] @ F.T + G @ q @ G.T
    ref = truth + rng.normal(size=(n, 3)) * np.array([sigma_xy, sigma_xy, sigma_phi])
    stamps = np.arange(n, dtype=float)
    return Trajectory(stamps, est), Trajectory(stamps, compose(np.array([5.0, 2.0, -1.0]), ref)), cov


def test_in_the_first_pose_frame_a_drifting_estimate_is_chi2_3():
    """Estimates whose covariance grows from zero at the first pose, as SLAM's do, scored
    in that pose's frame: NEES over many runs is χ²(3) — with the reference's own error at
    the anchor carried to every pose; without it, too large. The ATE's best rigid fit
    scores the same consistent runs as overconfident: it hands the early poses, whose
    covariance is near zero, a share of the drift."""
    rng = np.random.default_rng(4)
    sigma_xy, sigma_phi = 0.03, math.radians(0.5)
    first, aligned = [], []
    for _ in range(100):
        est, ref, cov = _drifting_case(rng, 100, sigma_xy, sigma_phi)
        report = pose_nees(est, ref, cov, reference_sigma_xy_m=sigma_xy, reference_sigma_phi_rad=sigma_phi)
        assert report.skipped_singular == 1 and len(report.nees) == 99     # the anchor
        first.append(report.nees)
        aligned.append(pose_nees(est, ref, cov, reference_sigma_xy_m=sigma_xy, reference_sigma_phi_rad=sigma_phi,
                                 frame="aligned").nees)
    first = np.concatenate(first)
    # the runs are independent (the poses of one run share their anchor's error): the mean
    # of 100 run means lies within ±0.25 of 3 (2.93 here)
    assert abs(first.mean() - 3.0) < 0.25
    assert 0.03 < np.mean(first > stats.chi2.ppf(0.95, 3)) < 0.08
    assert np.mean(np.concatenate(aligned) > stats.chi2.ppf(0.95, 3)) > 0.12


def test_the_reference_error_at_the_anchor_is_carried_to_every_pose():
    """An almost exact estimate against a noisy reference: the error is the reference's,
    at each pose and at the anchor. With the anchor's share NEES is χ²(3); the same errors
    weighed with the reference's own σ alone are far too large."""
    rng = np.random.default_rng(8)
    sigma_xy, sigma_phi = 0.03, math.radians(0.5)
    first, own_only = [], []
    for _ in range(200):
        est, ref, cov = _drifting_case(rng, 30, sigma_xy, sigma_phi, step_sigma=(1e-4, 1e-4, 1e-5))
        report = pose_nees(est, ref, cov, reference_sigma_xy_m=sigma_xy, reference_sigma_phi_rad=sigma_phi)
        first.append(report.nees)
        own_only.append(nees(report.errors, cov[1:] + np.diag([sigma_xy, sigma_xy, sigma_phi]) ** 2))
    assert abs(np.concatenate(first).mean() - 3.0) < 0.25
    assert np.concatenate(own_only).mean() > 4.5


def test_the_first_pose_frame_does_not_depend_on_the_frames_of_estimate_or_reference():
    est, ref, cov = _drifting_case(np.random.default_rng(2), 40, 0.03, 0.01)
    base = pose_nees(est, ref, cov, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01)
    moved_ref = Trajectory(ref.stamps, compose(np.array([-40.0, 5.0, -2.5]), ref.poses))
    np.testing.assert_allclose(pose_nees(est, moved_ref, cov, reference_sigma_xy_m=0.03,
                                         reference_sigma_phi_rad=0.01).nees, base.nees, rtol=1e-7)
    angle = 1.3
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = _transform(Trajectory(est.stamps, est.poses, cov), rotation, np.array([12.0, -4.0]))
    again = pose_nees(moved, ref, moved.covariances, reference_sigma_xy_m=0.03, reference_sigma_phi_rad=0.01)
    np.testing.assert_allclose(again.nees, base.nees, rtol=1e-7)


def test_an_unknown_frame_is_refused():
    est, ref, cov, _ = _sampled_case(3, 6)
    with pytest.raises(InputError, match="unknown NEES frame 'best'"):
        pose_nees(est, ref, cov, frame="best")


def test_only_matched_poses_are_scored():
    est, ref, cov, _ = _sampled_case(3, 50)
    ref = Trajectory(ref.stamps[::5] + 0.01, ref.poses[::5])
    report = pose_nees(est, ref, cov, max_dt=0.05, frame="aligned")
    assert report.matched == 10 and len(report.nees) == 10
    np.testing.assert_allclose(report.stamps, est.stamps[::5])


def test_no_scored_pose_gives_nan_not_an_error():
    est, ref, _, _ = _sampled_case(3, 5)
    report = pose_nees(est, ref, np.zeros((5, 3, 3)))
    assert report.skipped_singular == 5 and len(report.nees) == 0 and math.isnan(report.mean)


@pytest.mark.parametrize("bad, message", [
    (lambda c: c.__setitem__((2, 1, 1), np.nan), "non-finite covariance in row 2"),
    (lambda c: c.__setitem__((3, 0, 1), 1.0), "row 3 is not symmetric"),
    (lambda c: c.__setitem__((4, 2, 2), -1e-3), "row 4 is not positive semidefinite"),
])
def test_bad_covariances_are_named(bad, message):
    est, ref, cov, _ = _sampled_case(3, 6)
    bad(cov)
    with pytest.raises(InputError, match=message):
        pose_nees(est, ref, cov)
    with pytest.raises(InputError, match=f"^cov.csv: .*{message}"):
        singular_covariances(cov, "cov.csv")


def test_other_bad_input():
    est, ref, cov, _ = _sampled_case(3, 6)
    with pytest.raises(InputError, match=r"need \(6, 3, 3\) covariances"):
        pose_nees(est, ref, cov[:5])
    with pytest.raises(InputError, match="σ must be ≥ 0"):
        pose_nees(est, ref, cov, reference_sigma_xy_m=-0.1)
    with pytest.raises(InputError, match="σ must be ≥ 0"):
        pose_nees(est, ref, cov, reference_sigma_phi_rad=math.nan)
    with pytest.raises(InputError, match="only 0 poses matched"):
        pose_nees(est, Trajectory(ref.stamps + 100, ref.poses), cov)


def test_semidefinite_with_rounding_is_singular_not_an_error():
    v = np.array([1.0, 2.0, 0.5])
    rank_one = np.outer(v, v)[None] * (1 + 1e-16)
    assert singular_covariances(rank_one).tolist() == [True]
    assert singular_covariances(np.eye(3)[None] * 1e-12).tolist() == [False]  # tiny but definite
