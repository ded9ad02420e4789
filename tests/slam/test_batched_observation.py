"""The filter's batched searches against the one-curve functions: beam prediction (ranges
and Jacobians) and data association (Fig. 6 of the paper, pair by pair)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from observation_oracle import predict_beams, predict_beams_batch
from bsslam.slam.association import associate, control_point_gaps, relative_sigma
from bsslam.spline import BSplineCurve, fit_curve
from closest_oracle import closest_point
from bsslam.spline.batch import curve_table
from bsslam.spline.knots import clamped_knots_with_spans


def _batch(cs):
    table = curve_table([c.knots for c in cs], [c.degree for c in cs])
    return table.with_control_points(np.vstack([c.control_points for c in cs]))


def _wall(rng, n=300):
    """(n, 2) points along a random wobbly arc (m)."""
    radius, opening, start = rng.uniform(3, 8), rng.uniform(0.5, 2.0), rng.uniform(-np.pi, np.pi)
    phi = start + np.linspace(0.0, opening, n)
    rho = radius * (1.0 + 0.05 * np.sin(5.0 * phi))
    return rng.uniform(-2, 2, 2) + np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), degrees=st.lists(st.integers(1, 4), min_size=1, max_size=4))
def test_predict_beams_batch_matches_each_curve(seed, degrees):
    rng = np.random.default_rng(seed)
    cs = [fit_curve(_wall(rng), d, rng.uniform(0.3, 1.0)).curve for d in degrees]
    batch = _batch(cs)
    pose = np.array([0.2, -0.1, rng.uniform(-np.pi, np.pi)])
    offset = np.array([0.15, 0.05, -0.2])
    which = rng.integers(0, len(cs), 120)
    bearings = rng.uniform(-np.pi, np.pi, 120)
    t0 = np.array([rng.uniform(*cs[c].domain) for c in which])
    got = predict_beams_batch(batch, which, pose, offset, bearings, t0=t0)
    for c, curve in enumerate(cs):
        sel = which == c
        if not sel.any():
            continue
        one = predict_beams(curve, pose, offset, bearings[sel], t0=t0[sel])
        clear = ~(np.abs(one.r) > 20.0)  # grazing beams are dropped by the filter
        np.testing.assert_array_equal(got.hit[sel][clear], one.hit[clear])
        ok = clear & one.hit
        np.testing.assert_allclose(got.z[sel][ok], one.z[ok], atol=1e-9)
        np.testing.assert_allclose(got.H_pose[sel][ok], one.H_pose[ok], rtol=1e-6, atol=1e-8)
        # the same Jacobian, dense over the curve's control points
        n, p = curve.n_control, curve.degree
        for H_b, H_o in ((got.H_cp_x, one.H_cp_x), (got.H_cp_y, one.H_cp_y)):
            dense_b = np.zeros((int(ok.sum()), n))
            dense_o = np.zeros((int(ok.sum()), n))
            rows = np.arange(int(ok.sum()))
            win = got.window[sel][ok] - batch.table.cp_start[c]
            real = got.real[sel][ok]
            np.add.at(dense_b, (np.repeat(rows, real.sum(axis=1)), win[real]), H_b[sel][ok][real])
            dense_o[rows[:, None], one.first_cp[ok][:, None] + np.arange(p + 1)] = H_o[ok]
            np.testing.assert_allclose(dense_b, dense_o, rtol=1e-6, atol=1e-8)


def _reference_associate(observed, mapped, ids, gates, deltas):
    """Fig. 6 pair by pair with the one-curve closest_point (the filter's former code);
    thresholds as numbers or (observed, mapped) matrices."""
    result = [[] for _ in observed]
    gates = np.broadcast_to(gates, (len(observed), len(mapped)))
    deltas = np.broadcast_to(deltas, (len(observed), len(mapped)))
    for j, (fid, m) in enumerate(zip(ids, mapped)):
        lo_m, hi_m = m.domain
        tol = 1e-6 * max(1.0, hi_m - lo_m)
        for i, o in enumerate(observed):
            gate, delta = gates[i, j], deltas[i, j]
            a, b = o.bbox(), m.bbox()
            if b[0] - a[2] > gate or a[0] - b[2] > gate or b[1] - a[3] > gate or a[1] - b[3] > gate:
                continue
            d = o.control_points[:, None, :] - m.control_points[None, :, :]
            if np.sqrt(np.min(np.sum(d * d, axis=2))) > gate:
                continue
            u_ends = np.array(o.domain, dtype=float)
            t_ends = closest_point(m, o.evaluate(u_ends))[0]
            requery = (t_ends <= lo_m + tol) | (t_ends >= hi_m - tol)
            if requery.any():
                u_ends[requery] = closest_point(o, m.evaluate(t_ends[requery]))[0]
            if not (t_ends[1] > t_ends[0] and u_ends[1] > u_ends[0]):
                continue
            gap = o.evaluate(u_ends) - m.evaluate(t_ends)
            if np.max(np.hypot(gap[:, 0], gap[:, 1])) > delta:
                continue
            result[i].append((fid, *u_ends, *t_ends, t_ends[0] <= lo_m + tol, t_ends[1] >= hi_m - tol))
    return [sorted(r, key=lambda m: m[1]) for r in result]


def _association_case(rng):
    mapped, observed = [], []
    for _ in range(3):
        wall = _wall(rng)
        # map splines on stretches of the wall, observed splines on overlapping stretches
        for _ in range(2):
            a = rng.integers(0, 200)
            mapped.append(fit_curve(wall[a:a + rng.integers(40, 100)], 3, 0.3).curve)
        for _ in range(2):
            a = rng.integers(0, 200)
            pts = wall[a:a + rng.integers(30, 100)] + rng.normal(0, 0.002, (1, 2))
            pts = pts[::-1] if rng.random() < 0.2 else pts   # some seen in the opposite direction
            observed.append(fit_curve(pts, 3, 0.3).curve)
    return observed, mapped, np.arange(10, 10 + len(mapped))


def _assert_same_matches(got, expected):
    for g, e in zip(got, expected):
        assert [m.feature_id for m in g] == [r[0] for r in e]
        for m, r in zip(g, e):
            np.testing.assert_allclose([m.u_ini, m.u_fin, m.t_ini, m.t_fin], r[1:5], atol=1e-9)
            assert (m.at_lo, m.at_hi) == (r[5], r[6])


@pytest.mark.parametrize("seed", range(12))
def test_associate_matches_pairwise_reference(seed):
    observed, mapped, ids = _association_case(np.random.default_rng(seed))
    got = associate(_batch(observed), _batch(mapped), ids, np.arange(len(mapped)), 0.5, 0.1)
    expected = _reference_associate(observed, mapped, ids, 0.5, 0.1)
    assert sum(len(e) for e in expected) > 0
    _assert_same_matches(got, expected)


@pytest.mark.parametrize("seed", range(6))
def test_associate_per_pair_thresholds(seed):
    """The filter gates each (observed, map) pair by its own relative uncertainty."""
    rng = np.random.default_rng(100 + seed)
    observed, mapped, ids = _association_case(rng)
    everything = _reference_associate(observed, mapped, ids, 0.5, 0.1)
    # loose thresholds everywhere but on the pairs of one observed spline's first match:
    # tight there, so the pair-wise thresholds must remove exactly that match
    i = next(i for i, e in enumerate(everything) if e)
    j = int(np.flatnonzero(ids == everything[i][0][0])[0])
    gates = np.full((len(observed), len(mapped)), 0.5)
    deltas = np.full((len(observed), len(mapped)), 0.1)
    if seed % 2:
        gates[i, j] = 1e-4      # fails the control-point gate
    else:
        deltas[i, j] = 1e-4     # fails the end-point distance
    got = associate(_batch(observed), _batch(mapped), ids, np.arange(len(mapped)), gates, deltas)
    expected = _reference_associate(observed, mapped, ids, gates, deltas)
    assert sum(len(e) for e in expected) == sum(len(e) for e in everything) - 1
    _assert_same_matches(got, expected)


def _relative_sigma_dense(P, pose, points, cp_rows):
    """relative_sigma with its covariance pieces cut from a dense P (−1 rows: fixed)."""
    fixed = cp_rows[:, 0] < 0
    rows = np.maximum(cp_rows, 0)
    cross = P[:3][:, rows].copy()                                   # (3, F, 2)
    map_var = P[rows[:, 0], rows[:, 0]] + P[rows[:, 1], rows[:, 1]]
    cross[:, fixed] = 0.0
    map_var[fixed] = 0.0
    return relative_sigma(pose, P[:3, :3], points, cross, map_var)


def test_relative_sigma_is_the_offset_covariance():
    """√trace of Cov(p(pose) − c) from the dense Jacobian of the offset over the whole
    state, with the rigid-motion lever checked by finite differences; fixed control points
    contribute nothing."""
    rng = np.random.default_rng(7)
    n = 3 + 2 * 6
    A = rng.normal(size=(n, n))
    P = A @ A.T / n + 0.01 * np.eye(n)
    pose = np.array([1.0, -2.0, 0.4])
    local = rng.uniform(-5, 5, (4, 2))

    def world(p):
        c, s = np.cos(p[2]), np.sin(p[2])
        return local @ np.array([[c, s], [-s, c]]) + p[:2]

    points = world(pose)
    cp_rows = np.array([[3, 4], [9, 10], [-1, -1], [13, 14]])
    got = _relative_sigma_dense(P, pose, points, cp_rows)
    eps = 1e-6
    for i in range(points.shape[0]):
        J_pose = np.column_stack([(world(pose + eps * e)[i] - world(pose - eps * e)[i]) / (2 * eps) for e in np.eye(3)])
        for j, rows in enumerate(cp_rows):
            J = np.zeros((2, n))
            J[:, :3] = J_pose
            if rows[0] >= 0:
                J[[0, 1], rows] = -1.0
            assert got[i, j] == pytest.approx(np.sqrt(np.trace(J @ P @ J.T)), rel=1e-6)


def test_relative_sigma_vanishes_for_a_point_mapped_from_the_same_pose():
    """A wall mapped from the current pose (no noise) moves with the pose: however large the
    pose uncertainty, the wall is exactly where the robot sees it."""
    pose = np.array([3.0, 1.0, 0.7])
    local = np.array([2.0, 1.5])
    c, s = np.cos(pose[2]), np.sin(pose[2])
    point = pose[:2] + np.array([[c, -s], [s, c]]) @ local
    G = np.zeros((5, 3))
    G[:3] = np.eye(3)
    G[3:, :2] = np.eye(2)
    G[3:, 2] = [-(point[1] - pose[1]), point[0] - pose[0]]
    P = G @ np.diag([4.0, 9.0, 0.25]) @ G.T       # control point = g(pose): rank 3
    sigma = _relative_sigma_dense(P, pose, point[None, :], np.array([[3, 4]]))
    assert sigma[0, 0] == pytest.approx(0.0, abs=1e-6)
    assert _relative_sigma_dense(P, pose, point[None, :], np.array([[-1, -1]]))[0, 0] > 1.0


def test_control_point_gaps_brute_force():
    rng = np.random.default_rng(3)
    a = [BSplineCurve(rng.uniform(-3, 3, (k, 2)), clamped_knots_with_spans(1.0, k - 2, 2), 2) for k in (3, 5, 8)]
    b = [BSplineCurve(rng.uniform(-3, 3, (k, 2)), clamped_knots_with_spans(1.0, k - 3, 3), 3) for k in (4, 6)]
    ia, ib = np.array([0, 1, 2, 2, 0]), np.array([0, 1, 0, 1, 1])
    got = control_point_gaps(_batch(a), _batch(b), ia, ib)
    for g, i, j in zip(got, ia, ib):
        d = a[i].control_points[:, None] - b[j].control_points[None]
        assert g == pytest.approx(np.sqrt(np.min(np.sum(d * d, axis=2))), abs=1e-12)
