"""Trajectory metrics on hand-made cases with known answers, scipy as an oracle."""

import math

import numpy as np
import pytest
from scipy.spatial.distance import mahalanobis
from scipy.spatial.transform import Rotation

from bsslam.errors import InputError
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import associate
from bsslam.eval.consistency import chi2_band, nees
from bsslam.eval.relations import relations_error
from bsslam.se2 import between, compose, inverse
from bsslam.eval.trajectory_error import ate, rpe
from bsslam.trajectory import Trajectory, wrap_angle


def _random_poses(n, seed):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.normal(0, 5, n), rng.normal(0, 5, n), rng.uniform(-math.pi, math.pi, n)])


def _rigid(poses, angle, shift):
    c, s = math.cos(angle), math.sin(angle)
    xy = poses[:, :2] @ np.array([[c, -s], [s, c]]).T + shift
    return np.column_stack([xy, wrap_angle(poses[:, 2] + angle)])


# -- SE(2) ------------------------------------------------------------------------------
def test_se2_inverse_and_between():
    a, b = _random_poses(20, 1), _random_poses(20, 2)
    np.testing.assert_allclose(compose(a, inverse(a)), np.zeros((20, 3)), atol=1e-12)
    np.testing.assert_allclose(compose(a, between(a, b)), b, atol=1e-12)
    # a hand case: from (1, 1) facing +y, the point (1, 3) is 2 m straight ahead
    np.testing.assert_allclose(between([1, 1, math.pi / 2], [1, 3, math.pi / 2]), [2, 0, 0], atol=1e-15)


# -- association ------------------------------------------------------------------------
def test_associate_nearest_one_to_one_with_offset():
    ref = Trajectory([0.0, 1.0, 2.0, 3.0], np.zeros((4, 3)))
    est = Trajectory([-0.5 + 0.004, 0.5, 0.505, 1.503, 9.0], np.zeros((5, 3)))
    est_idx, ref_idx = associate(est, ref, max_dt=0.01, offset=0.5)
    # est 1 (t+offset = 1.0) and est 2 (1.005) both want ref 1: the closer wins
    assert est_idx.tolist() == [0, 1, 3] and ref_idx.tolist() == [0, 1, 2]
    est_idx, _ = associate(est, ref, max_dt=0.001, offset=0.5)
    assert est_idx.tolist() == [1]


# -- alignment --------------------------------------------------------------------------
def test_alignment_recovers_a_rigid_motion_and_agrees_with_scipy():
    rng = np.random.default_rng(4)
    est = rng.normal(size=(30, 2))
    ref = _rigid(np.column_stack([est, np.zeros(30)]), 2.5, np.array([3.0, -1.0]))[:, :2]
    ref_noisy = ref + rng.normal(0, 0.05, ref.shape)
    rotation, translation = align_rigid_2d(est, ref)
    np.testing.assert_allclose(rotation, [[math.cos(2.5), -math.sin(2.5)], [math.sin(2.5), math.cos(2.5)]], atol=1e-12)
    np.testing.assert_allclose(translation, [3.0, -1.0], atol=1e-12)
    # oracle: scipy's Kabsch on the centred points, embedded in 3-D with z = 0
    rotation, _ = align_rigid_2d(est, ref_noisy)
    centred = [np.column_stack([p - p.mean(axis=0), np.zeros(len(p))]) for p in (ref_noisy, est)]
    oracle, _ = Rotation.align_vectors(*centred)
    np.testing.assert_allclose(rotation, oracle.as_matrix()[:2, :2], atol=1e-10)


def test_alignment_needs_two_points():
    with pytest.raises(InputError):
        align_rigid_2d(np.zeros((1, 2)), np.zeros((1, 2)))


# -- ATE / RPE --------------------------------------------------------------------------
def test_ate_of_a_rigidly_moved_copy_is_zero():
    ref = Trajectory(np.arange(40.0), _random_poses(40, 5))
    est = Trajectory(ref.stamps, _rigid(ref.poses, -1.1, np.array([10.0, 4.0])))
    rmse, matched, aligned = ate(est, ref)
    assert rmse == pytest.approx(0.0, abs=1e-12) and matched == 40
    np.testing.assert_allclose(aligned.poses, ref.poses, atol=1e-12)


def test_ate_constant_offset_along_a_line_is_removed_by_alignment():
    # every estimate is 0.1 m ahead in x: the best rigid alignment is that translation, ATE = 0
    ref = Trajectory(np.arange(10.0), np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)]))
    est = Trajectory(ref.stamps, ref.poses + [0.1, 0.0, 0.0])
    rmse, matched, _ = ate(est, ref)
    assert rmse == pytest.approx(0.0, abs=1e-14) and matched == 10


def test_ate_of_a_scaled_square_is_the_scale_error():
    # corners of a 2 m square and the same square 10 % larger: by symmetry the alignment is
    # the identity, every corner is off by 0.1·√2 m
    square = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)
    ref = Trajectory(np.arange(4.0), np.column_stack([square, np.zeros(4)]))
    est = Trajectory(ref.stamps, np.column_stack([1.1 * square + [5.0, 2.0], np.zeros(4)]))
    rmse, _, aligned = ate(est, ref)
    assert rmse == pytest.approx(0.1 * math.sqrt(2), abs=1e-12)
    np.testing.assert_allclose(aligned.poses[:, :2], 1.1 * square, atol=1e-12)


def test_ate_rotates_covariances_with_the_alignment():
    ref = Trajectory(np.arange(3.0), [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    est = Trajectory(ref.stamps, [[0, 0, 0], [0, 1, 0], [0, 2, 0]], np.tile(np.diag([4.0, 1.0, 0.1]), (3, 1, 1)))
    _, _, aligned = ate(est, ref)
    np.testing.assert_allclose(aligned.covariances[0], np.diag([1.0, 4.0, 0.1]), atol=1e-12)


def test_rpe_known_step_errors():
    n = 11
    ref = Trajectory(np.arange(float(n)), np.column_stack([np.arange(float(n)), np.zeros(n), np.zeros(n)]))
    longer = Trajectory(ref.stamps, np.column_stack([1.1 * np.arange(float(n)), np.zeros(n), np.zeros(n)]))
    result = rpe(longer, ref)
    assert result.pairs == 10
    assert result.trans_rmse_m == pytest.approx(0.1) and result.trans_mean_m == pytest.approx(0.1)
    assert result.rot_rmse_deg == pytest.approx(0.0, abs=1e-12)
    assert rpe(longer, ref, delta=2).trans_mean_m == pytest.approx(0.2)
    # turning 1° more per step than the reference: 1° rotation error, no translation error
    turning = Trajectory(ref.stamps, np.column_stack([np.arange(float(n)), np.zeros(n), np.radians(np.arange(n))]))
    result = rpe(turning, Trajectory(ref.stamps, np.column_stack([turning.poses[:, :2], np.zeros(n)])))
    assert result.rot_mean_deg == pytest.approx(1.0) and result.rot_rmse_deg == pytest.approx(1.0)
    # a rigidly moved copy has no relative error
    moved = Trajectory(ref.stamps, _rigid(turning.poses, 0.7, np.array([1.0, 2.0])))
    assert rpe(moved, turning).trans_rmse_m == pytest.approx(0.0, abs=1e-12)


# -- relations --------------------------------------------------------------------------
def test_relations_known_error_and_matching(tmp_path):
    est = Trajectory([10.0, 11.0, 12.0], [[0, 0, 0], [1.0, 0, math.pi / 2], [1.0, 1.0, math.pi / 2]])
    offset = 1000.0
    # relation 1: true motion 1 m forward turning 88°: estimate 1 m forward turning 90° → 2° error
    # relation 2: true motion 1.2 m forward: estimate 1 m forward → 0.2 m error
    # relation 3: refers to a stamp with no pose
    relations = np.array([[1010.0, 1011.0, 1.0, 0.0, 0, 0, 0, math.radians(88)],
                          [1011.0, 1012.0, 1.2, 0.0, 0, 0, 0, 0.0],
                          [1011.0, 1013.0, 1.0, 0.0, 0, 0, 0, 0.0]])
    result = relations_error(est, relations, offset=offset)
    assert (result.used, result.total) == (2, 3)
    assert result.trans_mean_m == pytest.approx(0.1) and result.trans_std_m == pytest.approx(0.1)
    assert result.rot_mean_deg == pytest.approx(1.0) and result.rot_std_deg == pytest.approx(1.0)
    path = tmp_path / "r.relations"
    np.savetxt(path, relations)
    assert relations_error(est, path, offset=offset) == result
    empty = relations_error(est, path)  # without the offset nothing matches
    assert empty.used == 0 and math.isnan(empty.trans_mean_m)


def test_relations_translation_error_is_measured_in_the_relation_frame():
    # from a pose facing +y, a relation of 1 m ahead vs an estimate 1 m ahead and 0.3 m left
    est = Trajectory([0.0, 1.0], [[0, 0, math.pi / 2], [-0.3, 1.0, math.pi / 2]])
    result = relations_error(est, np.array([[0.0, 1.0, 1.0, 0.0, 0.0]]))
    assert result.trans_mean_m == pytest.approx(0.3)


# -- NEES -------------------------------------------------------------------------------
def test_nees_hand_case_wrapping_and_scipy_oracle():
    cov = np.diag([1.0, 4.0, 0.01])
    assert nees([[1.0, 2.0, 0.1]], [cov])[0] == pytest.approx(3.0)
    assert nees([[1.0, 2.0, 0.1 + 2 * math.pi]], [cov])[0] == pytest.approx(3.0)
    rng = np.random.default_rng(6)
    a = rng.normal(size=(8, 3, 3))
    covs = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(3)
    errors = rng.normal(size=(8, 3)) * [1, 1, 0.3]
    expected = [mahalanobis(e, np.zeros(3), np.linalg.inv(c)) ** 2 for e, c in zip(errors, covs)]
    np.testing.assert_allclose(nees(errors, covs), expected, rtol=1e-10)


def test_nees_refuses_singular_or_mismatched_covariances():
    with pytest.raises(InputError, match="singular"):
        nees([[1.0, 0.0, 0.0]], [np.zeros((3, 3))])
    with pytest.raises(InputError):
        nees(np.zeros((2, 3)), np.zeros((3, 3, 3)))


def test_chi2_band_for_50_runs_of_3_dof():
    lower, upper = chi2_band(3, 50)
    assert (round(lower, 2), round(upper, 2)) == (2.36, 3.72)
    lower1, upper1 = chi2_band(3, 1, probability=0.95)
    assert lower1 == pytest.approx(0.2158, abs=1e-4) and upper1 == pytest.approx(9.3484, abs=1e-4)
