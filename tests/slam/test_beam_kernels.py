"""The filter's compiled beam bookkeeping (:meth:`RangeModel.beams`,
:meth:`RangeModel.select`, :mod:`bsslam.slam.beam_kernels`) against the numpy form it
replaced (``beam_groups_oracle``), bit for bit, on seeded random scans."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bsslam.config import ObservationConfig
from bsslam.slam.association import Match
from bsslam.slam import beam_kernels
from bsslam.slam.measurement import RangeModel

from beam_groups_oracle import beam_groups as oracle_beam_groups
from beam_groups_oracle import select_rows as oracle_select_rows
from second_order_oracle import half_pair_traces


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Same shape, dtype and bits."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _observed(rng, n):
    """A stand-in observed spline of n beams: increasing chord parameters from 0 (some
    repeated), bearings and ranges (only these attributes are read)."""
    steps = rng.uniform(0.0, 0.1, n)
    steps[rng.random(n) < 0.1] = 0.0
    params = np.cumsum(steps) - steps[0]
    return SimpleNamespace(params=params, angles=rng.uniform(-np.pi, np.pi, n), ranges=rng.uniform(0.1, 8.0, n))


def _matches(rng, obs, feature_ids):
    """0–4 matches sorted by u_ini: overlapping or disjoint intervals, some with ends on a
    beam's parameter exactly, some past the spline's end or between two beams."""
    top = obs.params[-1]
    out = []
    for _ in range(rng.integers(0, 5)):
        if rng.random() < 0.4:   # ends on beams
            a, b = np.sort(rng.choice(obs.params, 2))
            if a == b:
                b = a + 0.01
        else:
            a = rng.uniform(-0.2, top + 0.1)
            b = a + rng.uniform(1e-4, top + 0.2)
        t_ini = rng.uniform(-1.0, 5.0)
        out.append(Match(int(rng.choice(feature_ids)), float(a), float(b), t_ini, t_ini + rng.uniform(-3.0, 3.0),
                         bool(rng.random() < 0.5), bool(rng.random() < 0.5)))
    return sorted(out, key=lambda m: m.u_ini)


class _Model:
    """The range model over a stand-in map table (``beams`` reads only its id → curve map)."""

    def __init__(self, index, stride):
        self.model = RangeModel(ObservationConfig(beam_stride=stride))
        self.curves = SimpleNamespace(index=index)

    def beams(self, observed, matches):
        return self.model.beams(observed, matches, self.curves)


def _filter(index, stride):
    return _Model(index, stride)


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_beam_groups_matches_the_numpy_form(stride):
    rng = np.random.default_rng(100 + stride)
    feature_ids = [3, 7, 11, 20, 42]
    index = {fid: c for c, fid in enumerate(rng.permutation(feature_ids).tolist())}
    slam = _filter(index, stride)
    assigned = empty = 0
    for _ in range(300):
        observed = [_observed(rng, int(rng.integers(1, 40))) for _ in range(rng.integers(0, 6))]
        matches = [_matches(rng, o, feature_ids) for o in observed]
        want = oracle_beam_groups(observed, matches, index, stride)
        got = slam.beams(observed, matches)
        if want is None:
            assert got is None
            empty += 1
            continue
        assigned += 1
        assert all(_same(w, g) for w, g in zip(want, (got.curve, got.bearings, got.ranges, got.t0)))
    assert assigned > 100 and empty > 10   # both outcomes exercised


def test_first_match_by_u_ini_wins():
    obs = SimpleNamespace(params=np.array([0.0, 0.1, 0.2, 0.3]), angles=np.arange(4.0), ranges=np.arange(4.0) + 1)
    first = Match(1, 0.0, 0.2, 0.0, 1.0, False, False)
    second = Match(2, 0.1, 0.3, 5.0, 6.0, False, False)
    got = _filter({1: 0, 2: 1}, 1).beams([obs], [[first, second]])
    assert got.curve.tolist() == [0, 0, 0, 1]
    assert got.bearings.tolist() == [0.0, 1.0, 2.0, 3.0]
    got = _filter({1: 0, 2: 1}, 2).beams([obs], [[first, second]])
    assert got.curve.tolist() == [0, 0] and got.bearings.tolist() == [0.0, 2.0]


def test_no_beam_in_any_interval_gives_none():
    obs = SimpleNamespace(params=np.array([0.0, 0.5]), angles=np.zeros(2), ranges=np.ones(2))
    slam = _filter({1: 0}, 1)
    assert slam.beams([obs], [[Match(1, 0.1, 0.4, 0.0, 1.0, False, False)]]) is None
    assert slam.beams([obs], [[]]) is None
    assert slam.beams([], []) is None


def test_select_matches_the_numpy_form():
    rng = np.random.default_rng(7)
    for _ in range(200):
        b, m, c = int(rng.integers(1, 30)), int(rng.integers(0, 30)), int(rng.integers(3, 12))
        beams = SimpleNamespace(curve=rng.integers(0, 5, b).astype(np.intp), bearings=rng.normal(size=b),
                                ranges=rng.normal(size=b))
        lin = SimpleNamespace(cols=np.arange(c), R=1e-4, beam=np.sort(rng.integers(0, b, m)).astype(np.intp),
                              H_c=rng.normal(size=(m, c)), residual=rng.normal(size=m), hit_t=rng.normal(size=m))
        keep = rng.random(m) < rng.choice([0.0, 0.5, 1.0])
        sub_beams, sub = RangeModel(ObservationConfig()).select(beams, lin, keep)
        want = oracle_select_rows(keep, lin.beam, beams.curve, beams.bearings, beams.ranges, lin.H_c, lin.residual,
                                  lin.hit_t)
        got = (sub_beams.curve, sub_beams.bearings, sub_beams.ranges, sub_beams.t0, sub.H_c, sub.residual, sub.beam,
               sub.hit_t)
        assert all(_same(w, g) for w, g in zip(want, got))
        assert sub.cols is lin.cols
        assert sub_beams.t0 is not sub.hit_t


def test_no_map_and_no_matches_gives_none():
    obs = SimpleNamespace(params=np.array([0.0, 0.5]), angles=np.zeros(2), ranges=np.ones(2))
    assert RangeModel(ObservationConfig()).beams([obs], [[]], None) is None   # the first scan: no map yet


def _dense_whitening(group, ratio):
    """The numpy oracle of :func:`beam_kernels.whiten_shared`: (I + ratio Σ_g 1_g 1_gᵀ)^(-1/2)
    by an eigendecomposition of the dense (m, m) matrix."""
    same = (group[:, None] == group[None, :]).astype(float)
    vals, vecs = np.linalg.eigh(np.eye(group.size) + ratio * same)
    return (vecs / np.sqrt(vals)) @ vecs.T


@pytest.mark.parametrize("seed", range(4))
def test_rows_are_whitened_against_the_shared_error_as_the_dense_inverse_root(seed):
    """W H and W ν of the compiled kernel equal R^(-1/2) H and R^(-1/2) ν of the dense block
    noise, so (W H)ᵀ (W H) is the information Hᵀ R⁻¹ H of the block noise."""
    from bsslam.slam.beam_kernels import whiten_shared

    rng = np.random.default_rng(seed)
    m, c = int(rng.integers(1, 60)), int(rng.integers(1, 12))
    group = rng.integers(0, 6, m) * 3           # sparse labels, some unused, groups interleaved
    ratio = float(rng.uniform(0.0, 5.0))
    H, nu = rng.normal(size=(m, c)), rng.normal(size=m)
    got_H, got_nu = whiten_shared(group, ratio, H, nu)
    W = _dense_whitening(group, ratio)
    np.testing.assert_allclose(got_H, W @ H, atol=1e-12)
    np.testing.assert_allclose(got_nu, W @ nu, atol=1e-12)
    R = np.eye(m) + ratio * (group[:, None] == group[None, :])
    np.testing.assert_allclose(got_H.T @ got_H, H.T @ np.linalg.solve(R, H), atol=1e-10)


def test_without_a_shared_error_the_rows_are_not_whitened():
    lin = SimpleNamespace()
    assert RangeModel(ObservationConfig()).whitened(None, lin) is lin
    model = RangeModel(ObservationConfig(sigma_range_m=0.03, sigma_model_m=0.0, sigma_shared_m=0.01))
    assert model.row_variance == pytest.approx(0.03 ** 2 + 0.01 ** 2)


def test_half_pair_traces_match_the_numpy_form_and_the_dense_trace():
    """The compiled pairs' traces equal the numpy form (the oracle), and both ½ tr(H_i P H_j P)
    written densely on the whole state; the result is exactly symmetric."""
    rng = np.random.default_rng(2)
    m, L, w = 17, 5, 12
    local = np.stack([rng.choice(w, L, replace=False) for _ in range(m)])
    H = rng.standard_normal((m, L, L))
    H = H + H.transpose(0, 2, 1)
    A = rng.standard_normal((w, w))
    P = A @ A.T
    Y = H @ P[local]
    got = beam_kernels.half_pair_traces(Y, local)
    np.testing.assert_allclose(got, half_pair_traces(Y, local), rtol=1e-12, atol=1e-12)
    dense = np.zeros((m, w, w))
    for i in range(m):
        dense[i][np.ix_(local[i], local[i])] = H[i]
    want = 0.5 * np.einsum("iab,bc,jcd,da->ij", dense, P, dense, P)
    np.testing.assert_allclose(got, want, rtol=1e-10)
    np.testing.assert_array_equal(got, got.T)
