"""Data association's compiled steps against the whole-array numpy form they replaced: the
matches, their parameters and their order must agree to the bit (the filter's results may
not depend on how association is computed)."""

from __future__ import annotations

import numpy as np
import pytest

from bsslam.slam.association import associate
from bsslam.spline import fit_curve
from bsslam.spline.batch import closest_points_batch, curve_table
from bsslam.spline.pieces import horner_with_derivatives


def _evaluate(batch, curve, t):
    """(m, 2) points, numpy only (the Horner of CurveBatch.evaluate)."""
    piece, u, _ = batch.table.locate(curve, t)
    return horner_with_derivatives(batch.coeffs.take(piece, axis=0), u, 0)[0]


def _numpy_associate(observed, mapped, feature_ids, candidates, gate_m, match_distance_m):
    """The former whole-array form of associate: tuples (id, u_ini, u_fin, t_ini, t_fin,
    at_lo, at_hi) per observed spline."""
    k = observed.table.n_curves
    result = [[] for _ in range(k)]
    candidates = np.asarray(candidates, dtype=np.intp)

    def per_pair(value):
        a = np.asarray(value, dtype=float)
        return np.broadcast_to(a[:, None] if a.ndim == 1 else a, (k, candidates.size))

    def boxes(batch):
        starts = batch.table.cp_start[:-1]
        return np.hstack([np.minimum.reduceat(batch.control_points, starts, axis=0),
                          np.maximum.reduceat(batch.control_points, starts, axis=0)])

    gates, deltas = per_pair(gate_m), per_pair(match_distance_m)
    ob, mb = boxes(observed)[:, None, :], boxes(mapped)[candidates][None, :, :]
    near = ~((mb[..., 0] - ob[..., 2] > gates) | (ob[..., 0] - mb[..., 2] > gates) |
             (mb[..., 1] - ob[..., 3] > gates) | (ob[..., 1] - mb[..., 3] > gates))
    io, jf = np.nonzero(near)
    im = candidates[jf]
    ta, tb = observed.table, mapped.table
    na, nb = ta.cp_start[io + 1] - ta.cp_start[io], tb.cp_start[im + 1] - tb.cp_start[im]
    counts = na * nb
    pair = np.repeat(np.arange(counts.shape[0]), counts)
    local = np.arange(pair.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)
    d = observed.control_points[ta.cp_start[io][pair] + local // nb[pair]] - \
        mapped.control_points[tb.cp_start[im][pair] + local % nb[pair]]
    if io.size:
        gaps = np.sqrt(np.minimum.reduceat(np.einsum("ij,ij->i", d, d), np.cumsum(counts) - counts))
        close = gaps <= gates[io, jf]
        io, jf, im = io[close], jf[close], im[close]
    if io.size == 0:
        return result
    u_ends = np.column_stack([ta.lo[io], ta.hi[io]])
    obs2, map2 = np.repeat(io, 2), np.repeat(im, 2)
    t_ends = closest_points_batch(mapped, map2, _evaluate(observed, obs2, u_ends.ravel()))[0].reshape(-1, 2)
    lo_m, hi_m = tb.lo[im][:, None], tb.hi[im][:, None]
    tol = 1e-6 * np.maximum(1.0, hi_m - lo_m)
    at_lo, at_hi = t_ends <= lo_m + tol, t_ends >= hi_m - tol
    requery = at_lo | at_hi
    if requery.any():
        map_end = _evaluate(mapped, map2[requery.ravel()], t_ends[requery])
        u_ends[requery] = closest_points_batch(observed, obs2[requery.ravel()], map_end)[0]
    ordered = (t_ends[:, 1] > t_ends[:, 0]) & (u_ends[:, 1] > u_ends[:, 0])
    gap = _evaluate(observed, obs2, u_ends.ravel()) - _evaluate(mapped, map2, t_ends.ravel())
    gap = np.hypot(gap[:, 0], gap[:, 1]).reshape(-1, 2).max(axis=1)
    for p in np.flatnonzero(ordered & (gap <= deltas[io, jf])):
        result[io[p]].append((int(feature_ids[im[p]]), float(u_ends[p, 0]), float(u_ends[p, 1]),
                              float(t_ends[p, 0]), float(t_ends[p, 1]), bool(at_lo[p, 0]), bool(at_hi[p, 1])))
    for matches in result:
        matches.sort(key=lambda m: m[1])
    return result


def _wall(rng, n=300):
    radius, opening, start = rng.uniform(3, 8), rng.uniform(0.5, 2.0), rng.uniform(-np.pi, np.pi)
    phi = start + np.linspace(0.0, opening, n)
    rho = radius * (1.0 + 0.05 * np.sin(5.0 * phi))
    return rng.uniform(-2, 2, 2) + np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])


def _batch(cs):
    table = curve_table([c.knots for c in cs], [c.degree for c in cs])
    return table.with_control_points(np.vstack([c.control_points for c in cs]))


def _case(rng):
    """Observed and map splines of mixed degrees on shared walls: overlapping stretches,
    some seen backwards, several observed splines per map spline (equal u_ini ties)."""
    mapped, observed = [], []
    for _ in range(4):
        wall = _wall(rng)
        for _ in range(3):
            a = rng.integers(0, 220)
            mapped.append(fit_curve(wall[a:a + rng.integers(30, 80)], int(rng.integers(1, 4)), 0.3).curve)
        for _ in range(3):
            a = rng.integers(0, 200)
            pts = wall[a:a + rng.integers(20, 100)] + rng.normal(0, 0.003, (1, 2))
            pts = pts[::-1] if rng.random() < 0.2 else pts
            observed.append(fit_curve(pts, 3, 0.3).curve)
    return _batch(observed), _batch(mapped), 7 + 3 * np.arange(len(mapped))


def _thresholds(rng, k, f, typical):
    """One value, (k,) or (k, f) thresholds, spread around ``typical`` so decisions vary."""
    kind = rng.integers(3)
    shape = [(), (k,), (k, f)][kind]
    return typical * rng.uniform(0.2, 3.0, shape)


@pytest.mark.parametrize("seed", range(40))
def test_associate_matches_numpy_form_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    observed, mapped, ids = _case(rng)
    k, C = observed.table.n_curves, mapped.table.n_curves
    candidates = np.sort(rng.choice(C, size=rng.integers(1, C + 1), replace=False))
    if seed % 4 == 0:        # a batch with coefficients only for the candidates (the filter's)
        mapped = mapped.table.with_control_points(mapped.control_points, candidates)
    gate = _thresholds(rng, k, candidates.size, 0.4)
    delta = _thresholds(rng, k, candidates.size, 0.05)
    got = associate(observed, mapped, ids, candidates, gate, delta)
    expected = _numpy_associate(observed, mapped, ids, candidates, gate, delta)
    got = [[(m.feature_id, m.u_ini, m.u_fin, m.t_ini, m.t_fin, m.at_lo, m.at_hi) for m in ms] for ms in got]
    assert got == expected
    for ms in got:            # exact types, as the Match fields are documented
        for m in ms:
            assert [type(v) for v in m] == [int, float, float, float, float, bool, bool]


def test_associate_nan_map_spline_is_never_matched():
    """A diverged map spline (NaN control point) fails the control-point gate, as before."""
    rng = np.random.default_rng(5)
    observed, mapped, ids = _case(rng)
    cp = mapped.control_points.copy()
    first = mapped.table.cp_start[0]
    cp[first + 1] = np.nan
    mapped = mapped.table.with_control_points(cp)
    candidates = np.arange(mapped.table.n_curves)
    got = associate(observed, mapped, ids, candidates, 0.5, 0.1)
    expected = _numpy_associate(observed, mapped, ids, candidates, 0.5, 0.1)
    assert [[(m.feature_id, m.u_ini, m.u_fin, m.t_ini, m.t_fin, m.at_lo, m.at_hi) for m in ms]
            for ms in got] == expected
    assert all(m.feature_id != ids[0] for ms in got for m in ms)
