"""The compiled constraints of the estimators' Jacobians (bsslam.slam.constraint_kernels)
against their numpy forms (constraint_oracle.py): the projection off the unobservable
directions, the invariant EKF's N(x) and its whole constraint of a linearisation, with and
without the heading's column; dependent directions are refused, not divided by zero."""

import numpy as np
import pytest
from constraint_oracle import invariant_constrain, null_space, project_out as project_out_numpy

from bsslam.errors import FilterError
from bsslam.slam.constraint_kernels import invariant_jacobian, invariant_null_space, project_off
from bsslam.slam.invariant_ekf import InvariantEKF
from bsslam.slam.oc_ekf import pose_null_rows, project_out


def invariant_filter(rng, points=12):
    """An invariant EKF with ``points`` control points appended (x entries, then y)."""
    est = InvariantEKF(rng.normal(size=3) * [4.0, 4.0, 1.0], np.eye(3) * 0.01)
    for _ in range(points // 2):
        est.append(rng.normal(size=4) * 6.0, np.arange(3), rng.normal(size=(4, 3)) * 0.1, np.eye(4) * 0.01)
    return est


@pytest.mark.parametrize("seed", range(5))
def test_projection_equals_the_numpy_form(seed):
    rng = np.random.default_rng(seed)
    c = int(rng.integers(4, 30))
    N = np.vstack([pose_null_rows(rng.normal(size=3) * 5), rng.normal(size=(c - 3, 3)) * 3])
    H = rng.normal(size=(int(rng.integers(1, 100)), c))
    expected = project_out_numpy(H, N)
    got = H.copy()
    assert project_off(got, N)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(project_out(H, N), expected, rtol=0, atol=1e-12 * np.abs(H).max())


def test_dependent_directions_are_refused():
    """Two pose rows alone cannot hold three independent directions: False, H untouched,
    and project_out raises FilterError (the numpy form's posv fails too)."""
    N = pose_null_rows(np.array([1.0, 2.0, 0.3]))[:2]
    H = np.arange(6.0).reshape(3, 2)
    got = H.copy()
    assert not project_off(got, N)
    np.testing.assert_array_equal(got, H)
    assert project_out_numpy(H, N) is None
    with pytest.raises(FilterError):
        project_out(H, N)


@pytest.mark.parametrize("seed", range(5))
def test_invariant_constraint_equals_the_numpy_form(seed):
    """A range's rows (the pose's columns among them) and a bend's (map columns only), at
    an x away from the mean: the same columns and Jacobian as the numpy form, whose N the
    compiled N equals exactly."""
    rng = np.random.default_rng(seed)
    est = invariant_filter(rng)
    n = est.x.shape[0]
    x = est.x + rng.normal(size=n) * 0.05
    sign, mate = est._sign, est._mate
    spline = 3 + rng.choice(n - 3, 8, replace=False)
    cols = np.concatenate([[0, 1, 2], np.sort(spline)])
    np.testing.assert_array_equal(invariant_null_space(cols, x, sign, mate), null_space(x, cols, sign, mate))
    for c in (cols, np.sort(spline)):
        H = rng.normal(size=(int(rng.integers(1, 90)), c.shape[0]))
        want_cols, want = invariant_constrain(c, H, x, est.x, sign, mate)
        got_cols, got, ok = invariant_jacobian(c, H, x, est.x, sign, mate)
        assert ok
        np.testing.assert_array_equal(got_cols, want_cols)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(H).max())
        est_cols, est_H = est.constrain(c, H, x)
        np.testing.assert_array_equal(est_cols, want_cols)
        np.testing.assert_array_equal(est_H, got)
    assert got_cols.shape[0] == spline.shape[0] + 1   # the bend's rows gained the heading's column
