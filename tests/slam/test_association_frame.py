"""The filter's compiled inputs to association (candidates, nearest and farthest control
points, pose Jacobians, coefficients, grown thresholds) against the numpy forms they
replaced (association_oracle.py), bit for bit: the matches may not depend on how they are
computed."""

from __future__ import annotations

import numpy as np
import pytest

import association_oracle as oracle
from bsslam.slam import kernels
from bsslam.slam.association import association_thresholds, relative_sigma
from bsslam.spline import BSplineCurve, fit_curve
from bsslam.spline.batch import curve_table
from bsslam.spline.knots import clamped_knots_with_spans


def _curves(rng, n):
    """n fitted splines of mixed degrees scattered over a 20 m square."""
    out = []
    for _ in range(n):
        phi = rng.uniform(-np.pi, np.pi) + np.linspace(0.0, rng.uniform(0.3, 1.5), rng.integers(20, 80))
        radius = rng.uniform(1, 4)
        pts = rng.uniform(-10, 10, 2) + radius * np.column_stack([np.cos(phi), np.sin(phi)])
        out.append(fit_curve(pts, int(rng.integers(1, 4)), 0.3).curve)
    return out


def _table(cs):
    return curve_table([c.knots for c in cs], [c.degree for c in cs]), np.vstack([c.control_points for c in cs])


def _frame_case(rng, ties: bool, nan: bool):
    mt, map_cp = _table(_curves(rng, int(rng.integers(3, 15))))
    ot, obs_cp = _table(_curves(rng, int(rng.integers(1, 6))))
    lp = np.append(rng.uniform(-10, 10, 2), rng.uniform(-np.pi, np.pi))
    if ties:    # control points equally far from the laser: the earlier row must win
        for cp in (map_cp, obs_cp):
            rows = rng.choice(cp.shape[0], size=cp.shape[0] // 2, replace=False)
            cp[rows] = 2 * lp[:2] - cp[rows[::-1]] if rng.random() < 0.5 else cp[rows[::-1]]
            cp[rows[: rows.size // 2]] = lp[:2] + 0.5
    if nan:
        map_cp[rng.integers(map_cp.shape[0])] = np.nan
        obs_cp[rng.integers(obs_cp.shape[0])] = np.nan
    N = map_cp.shape[0]
    state_rows = (3 + rng.permutation(2 * N)).reshape(N, 2).astype(np.intp)
    state_rows[rng.random(N) < 0.2] = -1
    return mt, map_cp, ot, obs_cp, lp, state_rows


@pytest.mark.parametrize("seed", range(30))
def test_association_frame_matches_numpy_form_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    mt, map_cp, ot, obs_cp, lp, state_rows = _frame_case(rng, ties=seed % 3 == 1, nan=seed % 5 == 4)
    pose = lp + rng.normal(0, 0.1, 3)
    radius = rng.uniform(1.0, 15.0)
    cand, near, J, map_coeffs_t, obs_coeffs_t = kernels.association_frame(
        map_cp, mt.cp_start, mt.power_basis, mt.window, mt.piece_start, state_rows, obs_cp, ot.cp_start,
        ot.power_basis, ot.window, ot.piece_start, lp, radius ** 2, pose)

    want = oracle.candidates(mt.bboxes(map_cp), lp, radius)
    np.testing.assert_array_equal(cand, want)
    assert cand.dtype == np.intp
    np.testing.assert_array_equal(near, state_rows[oracle.extreme_control_points(mt.cp_start, map_cp, want, lp[:2])])
    far = obs_cp[oracle.extreme_control_points(ot.cp_start, obs_cp, np.arange(ot.n_curves), lp[:2], farthest=True)]
    lever = far - pose[:2]
    J_want = np.zeros((far.shape[0], 2, 3))
    J_want[:, 0, 0] = J_want[:, 1, 1] = 1.0
    J_want[:, 0, 2], J_want[:, 1, 2] = -lever[:, 1], lever[:, 0]
    assert J.tobytes() == J_want.tobytes()
    assert obs_coeffs_t.tobytes() == ot.with_control_points(obs_cp).coeffs_t.tobytes()
    assert map_coeffs_t.tobytes() == mt.with_control_points(map_cp, want).coeffs_t.tobytes()


def test_extreme_control_points_nearest_and_farthest_differ():
    """The oracle comparison above can fail: nearest and farthest rows are not the same."""
    rng = np.random.default_rng(1)
    mt, map_cp, *_ = _frame_case(rng, ties=False, nan=False)
    c = mt.n_curves - 1
    args = (map_cp, mt.cp_start[c], mt.cp_start[c + 1], 0.3, -0.2)
    assert kernels.extreme_row(*args, False) != kernels.extreme_row(*args, True)
    assert kernels.extreme_row(*args, False) == oracle.extreme_control_points(mt.cp_start, map_cp, [c],
                                                                              np.array([0.3, -0.2]))[0]


def _covariances(rng, k, F, n_fixed, nan):
    A = rng.normal(size=(3 + 2 * F, 3 + 2 * F))
    P = A @ A.T / A.shape[0]
    near = (3 + np.arange(2 * F)).reshape(F, 2).astype(np.intp)
    near[rng.choice(F, size=n_fixed, replace=False)] = -1
    cross = P[:3, 3:].reshape(3, F, 2).copy()
    diagonal = np.diag(P)[3:].copy()
    if nan:
        diagonal[rng.integers(2 * F)] = np.nan
        cross[rng.integers(3), rng.integers(F), rng.integers(2)] = np.nan
    cross[:, near[:, 0] < 0] = 0.0      # as the filter gives it
    pose = rng.uniform(-5, 5, 3)
    far = pose[:2] + rng.uniform(-8, 8, (k, 2))
    return P[:3, :3].copy(), pose, far, cross, diagonal, near


@pytest.mark.parametrize("seed", range(30))
def test_association_thresholds_match_numpy_form_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    k, F = int(rng.integers(1, 7)), int(rng.integers(1, 12))
    Ppp, pose, far, cross, diagonal, near = _covariances(rng, k, F, int(rng.integers(0, F + 1)), nan=seed % 4 == 3)
    if seed % 7 == 0:       # negative variance sums (rounding): clamped to σ = 0
        Ppp = -Ppp
    sigmas, match_m, max_match_m, gate_m = rng.uniform(1, 4), rng.uniform(0.05, 0.3), rng.uniform(0.2, 1.0), 0.6
    J = kernels.point_jacobians(pose, far)
    gates, deltas = association_thresholds(J, Ppp, cross, diagonal, near, sigmas, match_m, max_match_m, gate_m)
    want_gates, want_deltas = oracle.thresholds(pose, Ppp, far, cross, diagonal, near, sigmas, match_m,
                                                max_match_m, gate_m)
    assert gates.tobytes() == want_gates.tobytes()
    assert deltas.tobytes() == want_deltas.tobytes()
    assert gates.flags.c_contiguous and deltas.flags.c_contiguous


@pytest.mark.parametrize("seed", range(20))
def test_relative_sigma_matches_numpy_form_bit_for_bit(seed):
    rng = np.random.default_rng(100 + seed)
    k, F = int(rng.integers(1, 7)), int(rng.integers(1, 12))
    Ppp, pose, far, cross, diagonal, near = _covariances(rng, k, F, 0, nan=seed % 4 == 3)
    map_var = diagonal.reshape(-1, 2).sum(axis=1)
    got = relative_sigma(pose, Ppp, far, cross, map_var)
    assert got.tobytes() == oracle.relative_sigma(pose, Ppp, far, cross, map_var).tobytes()


def test_extreme_row_brute_force():
    """Nearest and farthest control point of curves of mixed degrees, against argmin/argmax."""
    rng = np.random.default_rng(11)
    cs = [BSplineCurve(rng.uniform(-4, 4, (k, 2)), clamped_knots_with_spans(1.0, k - d, d), d)
          for k, d in ((3, 2), (6, 3), (5, 4), (8, 1))]
    table, cp = _table(cs)
    point = np.array([0.5, -0.3])
    for farthest in (False, True):
        for c in (3, 0, 2):
            r = kernels.extreme_row(cp, table.cp_start[c], table.cp_start[c + 1], point[0], point[1], farthest)
            d = np.linalg.norm(cs[c].control_points - point, axis=1)
            assert r == table.cp_start[c] + (np.argmax(d) if farthest else np.argmin(d))
