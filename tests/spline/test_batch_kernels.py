"""The fast paths of the batched kernels against their plain forms: each pair must agree
to the bit (the filter's results may not depend on which path a call takes)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from ray_oracle import intersect_rays_batch
from spline_cases import batch_of, curves, params_in, wall_curves

from bsslam.spline import intersect as one_curve
from bsslam.spline import kernels
from bsslam.spline.batch import closest_points_batch
from bsslam.spline.pieces import horner_rows

SETTINGS = settings(max_examples=30, deadline=None)


def _assert_same(a, b):
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b), strict=True)


@SETTINGS
@given(cs=st.lists(curves(), min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_table_keys_and_locate_against_each_curves_breaks(cs, seed):
    rng = np.random.default_rng(seed)
    table = batch_of(cs).table
    # the documented break keys: every curve's piece starts, then its end
    breaks = np.insert(table.piece_lo, table.piece_start[1:], table.piece_lo[table.last_piece]
                       + table.width[table.last_piece])
    _assert_same(table.keys, np.repeat(np.arange(len(cs)), np.diff(table.piece_start) + 1) + 1j * breaks)
    _assert_same(table.piece_keys, table.piece_curve + 1j * table.piece_lo)
    which = rng.integers(0, len(cs), 50)
    t = params_in(cs, which, rng)
    t[:5] = [cs[c].domain[1] for c in which[:5]]           # the domain end: last piece
    t[5:10] = [cs[c].domain[0] - 1.0 for c in which[5:10]]  # clamped
    t[10:13] = np.inf
    t[13:15] = np.nan                                        # NaN: its curve's last piece
    piece, u, t_clamped = table.locate(which, t)
    for j, c in enumerate(which):
        lo, hi = cs[c].domain
        first, end = table.piece_start[c], table.piece_start[c + 1]
        if np.isnan(t[j]):
            assert piece[j] == end - 1 and np.isnan(u[j]) and np.isnan(t_clamped[j])
            continue
        tc = min(max(t[j], lo), hi)
        local = np.searchsorted(table.piece_lo[first:end], tc, side="right") - 1
        assert t_clamped[j] == tc
        assert piece[j] == first + local
        assert u[j] == tc - table.piece_lo[first + local]


@SETTINGS
@given(cs=st.lists(curves(), min_size=2, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_evaluate_subset_batches_and_derivative_path(cs, seed):
    rng = np.random.default_rng(seed)
    full = batch_of(cs)
    table = full.table
    # the compiled coefficients are the numpy sum over r, in order r = 0, 1, …, bit for bit
    window_points = full.control_points[table.window]
    _assert_same(full.coeffs, (table.power_basis[:, :, :, None] * window_points[:, None, :, :]).sum(axis=2))
    chosen = rng.choice(len(cs), size=rng.integers(1, len(cs) + 1), replace=False)
    part = table.with_control_points(full.control_points, np.concatenate([chosen, chosen[:1]]))
    mine = np.isin(table.piece_curve, chosen)
    _assert_same(part.coeffs[mine], full.coeffs[mine])
    assert np.all(np.isnan(part.coeffs[~mine]))
    _assert_same(part.coeffs_t, np.ascontiguousarray(part.coeffs.transpose(1, 2, 0)))
    which = rng.choice(chosen, 40)
    t = params_in(cs, which, rng)
    t[:3] = -np.inf
    t[3:5] = np.nan
    points = part.evaluate(which, t)
    assert points.shape == (1, 40, 2) and points.flags.c_contiguous
    # nder = 0 takes its own path; horner_with_derivatives gives the same first row
    _assert_same(points[0], part.evaluate(which, t, 2)[0])
    assert np.all(np.isnan(points[0, 3:5]))


@SETTINGS
@given(cs=st.lists(wall_curves(), min_size=1, max_size=4), seed=st.integers(0, 2**32 - 1))
def test_ray_paths_agree(cs, seed):
    """The ray oracle's paths (shared or per-ray origins, every beam guessed or not)."""
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    origin = rng.uniform(-4.0, 4.0, 2)
    which = rng.integers(0, len(cs), 60)
    angles = rng.uniform(-np.pi, np.pi, 60)
    guess = params_in(cs, which, rng)
    shared = intersect_rays_batch(batch, which, origin, angles, t0=guess)
    per_ray = intersect_rays_batch(batch, which, np.tile(origin, (60, 1)), angles, t0=guess)
    for field in ("t", "range", "r", "hit"):
        _assert_same(getattr(shared, field), getattr(per_ray, field))
    # a ray without a guess sends the call down the other branch; the others are unchanged
    partial = guess.copy()
    partial[0] = np.nan
    mixed = intersect_rays_batch(batch, which, origin, angles, t0=partial)
    searched = intersect_rays_batch(batch, which, origin, angles)
    for field in ("t", "range", "r", "hit"):
        _assert_same(getattr(mixed, field)[1:], getattr(shared, field)[1:])
        _assert_same(getattr(mixed, field)[:1], getattr(searched, field)[:1])


@SETTINGS
@given(cs=st.lists(curves(), min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_closest_paths_agree(cs, seed):
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    which = rng.integers(0, len(cs), 30)
    queries = rng.uniform(-8.0, 8.0, (30, 2))
    plain = closest_points_batch(batch, which, queries)
    unguessed = closest_points_batch(batch, which, queries, t0=np.full(30, np.nan))
    for a, b in zip(plain, unguessed):
        _assert_same(a, b)
    _assert_same(plain[1], batch.evaluate(which, plain[0])[0])


@settings(max_examples=60, deadline=None)
@given(degree=st.integers(0, 5), seed=st.integers(0, 2**32 - 1))
def test_horner_rows_and_bracket_refinement_against_numpy(degree, seed):
    """The global search's polynomial rows and root refinement (shared by the one-curve and
    the batched search) against numpy's polynomial evaluation."""
    rng = np.random.default_rng(seed)
    coeffs = rng.normal(size=(50, degree + 1))
    u = np.linspace(0.0, 2.0, 9)
    y = horner_rows(coeffs.T[:, :, None], np.broadcast_to(u, (50, 9)))
    oracle = np.polynomial.polynomial.polyval(u, coeffs.T)                  # (50, 9)
    np.testing.assert_allclose(y, oracle, rtol=1e-12, atol=1e-12)
    pair, j = np.nonzero((y[:, :-1] > 0) != (y[:, 1:] > 0))
    if pair.size == 0:
        return
    a, b = u[j], u[j + 1]
    root = one_curve._refine_brackets(np.ascontiguousarray(coeffs[pair].T), a, b)
    assert np.all((root >= a) & (root <= b))
    scale = np.sum(np.abs(coeffs[pair]) * 2.0 ** np.arange(degree + 1), axis=1)
    residual = np.abs(np.polynomial.polynomial.polyval(root, coeffs[pair].T, tensor=False))
    assert np.all(residual <= 1e-12 * scale), residual.max()


@SETTINGS
@given(cs=st.lists(curves(), min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_bboxes_against_reduceat(cs, seed):
    """The compiled boxes are numpy's min / max per curve, NaN and ±inf included."""
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    cp = batch.control_points.copy()
    bad = rng.integers(0, cp.shape[0], 3)
    cp[bad[0], rng.integers(2)] = np.nan
    cp[bad[1], rng.integers(2)] = np.inf
    cp[bad[2], rng.integers(2)] = -np.inf
    for points in (batch.control_points, cp):
        starts = batch.table.cp_start[:-1]
        expected = np.hstack([np.minimum.reduceat(points, starts, axis=0), np.maximum.reduceat(points, starts, axis=0)])
        _assert_same(batch.table.bboxes(points), expected)


def test_first_per_group_is_the_stable_lexsort_pick():
    """The compiled pick of each group's smallest key equals the lexsort one, with ties,
    NaN keys and an absent group."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        k = int(rng.integers(1, 40))
        key = rng.integers(0, 4, k).astype(float)          # many ties
        key[rng.random(k) < 0.2] = np.nan
        group = rng.integers(0, 6, k)
        np.testing.assert_array_equal(kernels.first_per_group(key, group, 7), one_curve.first_per_group(key, group))
