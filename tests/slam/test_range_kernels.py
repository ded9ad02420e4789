"""The filter's compiled linearisation (:meth:`bsslam.slam.map_curves.MapCurves.linearize`)
against the numpy path it replaced — :func:`predict_beams_batch`, the hit and grazing masks,
:func:`stack_jacobian` — bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from observation_oracle import predict_beams_batch
from ray_oracle import intersect_rays_batch
from bsslam.slam import range_kernels
from bsslam.slam.features import SplineFeature
from bsslam.slam.kernels import stack_jacobian
from bsslam.slam.map_curves import MapCurves
from bsslam.slam.measurement import laser_pose
from bsslam.spline import fit_curve
from bsslam.spline.intersect import _MAX_REFINE, _STEP_TOLERANCE, _unit_grid


def _reference(mc, x, offset, curve, bearings, ranges, t0, max_tan):
    """The filter's former ``_linearize``: the numpy observation model, then the masks and
    the stacked Jacobian of the kept beams."""
    maps = mc.table.with_control_points(mc.control_points(x), np.unique(curve))
    pred = predict_beams_batch(maps, curve, x[:3], offset, bearings, t0=t0)
    ok = pred.hit & np.isfinite(pred.z)
    grazing = ok & (np.abs(pred.r) > max_tan)
    missed = int((~ok).sum())
    ok &= ~grazing
    rows = np.flatnonzero(ok)
    cols, H_c = stack_jacobian(rows, pred.window, pred.real, mc.state_rows, pred.H_cp_x, pred.H_cp_y,
                               pred.H_pose, x.shape[0])
    return cols, H_c, ranges[rows] - pred.z[rows], rows, pred.t[rows], missed, int(grazing.sum())


def _wall(rng, n=200):
    """(n, 2) points along a random wobbly arc around the origin (m)."""
    radius, opening, start = rng.uniform(3, 8), rng.uniform(0.5, 2.0), rng.uniform(-np.pi, np.pi)
    phi = start + np.linspace(0.0, opening, n)
    rho = radius * (1.0 + 0.05 * np.sin(5.0 * phi))
    return rng.uniform(-1, 1, 2) + np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])


def _map(rng, degrees, fixed):
    """A map of splines of ``degrees`` (the ``fixed`` ones outside the state, as in
    localisation mode), their control points at scattered state indices of x."""
    curves = [fit_curve(_wall(rng), d, rng.uniform(0.3, 1.0)).curve for d in degrees]
    n_state = 3 + sum(2 * c.n_control for c, f in zip(curves, fixed) if not f) + 5
    x = rng.normal(size=n_state)
    x[:3] = [rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-np.pi, np.pi)]
    free = 3 + rng.permutation(n_state - 3)
    features, used = [], 0
    for i, (c, f) in enumerate(zip(curves, fixed)):
        if f:
            features.append(SplineFeature(i, c.degree, c.knots, fixed_control_points=c.control_points.copy()))
            continue
        n = c.n_control
        idx = free[used:used + 2 * n]
        used += 2 * n
        x[idx[:n]], x[idx[n:]] = c.control_points[:, 0], c.control_points[:, 1]
        features.append(SplineFeature(i, c.degree, c.knots, idx_x=idx[:n], idx_y=idx[n:]))
    return MapCurves(features), curves, x


def _beams(rng, curves, x, offset, m, bad):
    """m beams aimed at points of random curves with Newton starts near them; a fraction
    ``bad`` of them aimed anywhere or started from nowhere (NaN), for the global search."""
    lp = laser_pose(x[:3], offset)
    curve = rng.integers(0, len(curves), m)
    t0 = np.empty(m)
    bearings = np.empty(m)
    for j, c in enumerate(curve):
        lo, hi = curves[c].domain
        t = rng.uniform(lo, hi)
        point = curves[c].evaluate(np.array([t]))[0]
        bearings[j] = np.arctan2(point[1] - lp[1], point[0] - lp[0]) - lp[2]
        t0[j] = t + rng.normal(0, 0.05)
    wild = rng.random(m) < bad
    bearings[wild] = rng.uniform(-np.pi, np.pi, int(wild.sum()))
    t0[wild & (rng.random(m) < 0.3)] = np.nan
    ranges = rng.uniform(1.0, 10.0, m)
    return curve, bearings, ranges, t0


def _assert_bitwise(got, expected):
    for g, e in zip(got[:5], expected[:5]):
        g, e = np.asarray(g), np.asarray(e)
        assert g.dtype == e.dtype and g.shape == e.shape
        assert g.tobytes() == e.tobytes()
    assert got[5:] == expected[5:]


CASES = [  # degrees, fixed (localisation), fraction of beams for the global search, max tan
    ((3, 3, 3), (False, False, False), 0.0, 3.0),
    ((3, 3, 3), (False, False, False), 0.0, 0.05),       # many grazing
    ((3, 3, 3), (False, False, False), 0.3, 3.0),        # misses and global searches
    ((2, 3, 1, 3), (False, False, False, False), 0.2, 1.0),   # mixed degrees: padded windows
    ((3, 2), (True, True), 0.2, 2.0),                    # localisation: no control point in the state
    ((3, 2, 3), (False, True, False), 0.2, 2.0),         # fixed splines among state ones
    ((1,), (False,), 0.5, 5.0),
]


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("case", range(len(CASES)))
def test_linearize_beams_equals_the_numpy_path(case, seed):
    degrees, fixed, bad, max_tan = CASES[case]
    rng = np.random.default_rng(1000 * case + seed)
    mc, curves, x = _map(rng, degrees, fixed)
    offset = np.array([0.15, -0.05, rng.uniform(-0.3, 0.3)]) if seed % 2 else np.zeros(3)
    beams = _beams(rng, curves, x, offset, 60, bad)
    got = mc.linearize(x, offset, *beams, max_tan)
    _assert_bitwise(got, _reference(mc, x, offset, *beams, max_tan))
    if bad == 0.0 and max_tan == 0.05:
        assert got[6] > 0          # some grazing beams are dropped
    if bad == 0.3:
        assert got[5] > 0          # and some beams miss


def test_global_search_equals_the_numpy_search():
    """Beams whose Newton fails (bad or no start) take the compiled global search: the
    numbers of intersect_rays_batch's (tests/spline/ray_oracle.py), ray by ray."""
    rng = np.random.default_rng(5)
    mc, curves, x = _map(rng, (3, 2, 3), (False, True, False))
    curve, bearings, ranges, t0 = _beams(rng, curves, x, np.zeros(3), 80, 1.0)
    batch = mc.table.with_control_points(mc.control_points(x))
    lp = laser_pose(x[:3], np.zeros(3))
    mu = lp[2] + bearings
    expected = intersect_rays_batch(batch, curve, lp[:2], mu)
    hits = np.full((4, 80), np.nan)
    rays = np.arange(80)
    table = mc.table
    range_kernels.global_search(hits, rays, x, mc.state_rows, mc.fixed_control_points, batch.coeffs_t, table.window,
                                table.piece_lo, table.width, table.piece_start, curve, lp[0], lp[1], np.cos(mu),
                                np.sin(mu), _unit_grid(8), np.inf, _MAX_REFINE, _STEP_TOLERANCE)
    assert 10 < np.isfinite(hits[1]).sum() < 80
    for got, want in zip((hits[0], hits[1], hits[2] / hits[3]), (expected.t, expected.range, expected.r)):
        assert got.tobytes() == want.tobytes()


def test_used_curves_is_unique():
    rng = np.random.default_rng(2)
    for curve in (rng.integers(0, 40, 70), np.array([5, 5, 5]), np.array([3]), np.empty(0, dtype=np.intp)):
        got = range_kernels.used_curves(curve.astype(np.intp))
        expected = np.unique(curve.astype(np.intp))
        assert got.dtype == expected.dtype and got.tolist() == expected.tolist()
