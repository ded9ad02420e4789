"""The ranges' second-order error under the prior (``observation.second_order``): its
covariance ½ tr(∇²h_i P ∇²h_j P) against a Monte Carlo of the range model itself, the
whitened rows against the dense update with that block noise, and its rows carried through
the gates' selection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bsslam.config import ObservationConfig
from bsslam.errors import ConfigError
from bsslam.slam.features import SplineFeature
from bsslam.slam.map_curves import MapCurves
from bsslam.slam.measurement import Beams, RangeModel
from bsslam.spline import fit_curve

from dense_ekf import DenseGain

OFFSET = np.array([0.2, -0.05, 0.1])


def _scene(rng: np.random.Generator):
    """A wavy wall whose control points are state entries 3 … n − 1 behind the pose, the
    state mean, a prior P over the whole state (a needle along the wall for the pose, its
    heading, and the wall's control points correlated with each other and with the pose),
    and beams up the wall."""
    s = np.linspace(-6.0, 6.0, 400)
    fit = fit_curve(np.column_stack([s, 3.0 + 0.3 * np.sin(0.8 * s)]), 3, 1.0)
    q = fit.curve.control_points.shape[0]
    feature = SplineFeature(0, 3, fit.curve.knots.copy(), idx_x=3 + np.arange(q), idx_y=3 + q + np.arange(q))
    curves = MapCurves([feature])
    pose = np.array([0.4, -0.3, 0.25])
    x = np.concatenate([pose, fit.curve.control_points[:, 0], fit.curve.control_points[:, 1]])
    n = x.shape[0]
    A = 0.01 * rng.standard_normal((n, n)) / math.sqrt(n)
    A[:3, :3] += np.diag([0.08, 0.01, 0.01])            # the pose: 8 cm along the wall, 1 cm, 0.01 rad
    A[3:, :] += 0.01 * rng.standard_normal((n - 3, n)) / math.sqrt(n)
    P = A @ A.T
    bearings = np.linspace(0.8, 2.2, 30) - pose[2] - OFFSET[2]
    t0 = np.full(bearings.shape, 0.5 * (fit.params[0] + fit.params[-1]))
    beams = Beams(np.zeros(bearings.shape, dtype=np.intp), bearings, np.full(bearings.shape, 3.0), t0)
    return curves, x, P, beams


def _predicted(model, beams, curves, x):
    lin = model.linearize(beams, curves, x, OFFSET)
    assert lin is not None and lin.beam.shape[0] == beams.ranges.shape[0]   # every beam hits
    return beams.ranges - lin.residual, lin


def test_second_order_covariance_matches_a_monte_carlo_of_the_ranges():
    """h(x + δ) − h(x) − H δ over δ ~ N(0, P): its covariance is the block the model adds
    (within the Monte Carlo's scatter), and it is far from zero, so the first-order update
    alone misses it."""
    rng = np.random.default_rng(7)
    curves, x, P, beams = _scene(rng)
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80)))
    work = np.arange(x.shape[0])
    with_rows = model.with_second_order(beams, curves, x, OFFSET, P, work)
    F = with_rows.second_order
    want = 0.5 * F @ F.T                                          # (b, b), m²
    h0, lin = _predicted(model, beams, curves, x)
    H = np.zeros((lin.beam.shape[0], x.shape[0]))
    H[:, lin.cols] = lin.H_c
    L = np.linalg.cholesky(P)
    samples = 6000
    e = np.empty((samples, h0.shape[0]))
    for i in range(samples):
        delta = L @ rng.standard_normal(x.shape[0])
        e[i] = _predicted(model, beams, curves, x + delta)[0] - h0 - H @ delta
    got = np.cov(e.T)
    sd = np.sqrt(np.diag(want))
    assert sd.max() > 1e-3                                        # millimetres: not a rounding effect
    np.testing.assert_allclose(np.sqrt(np.diag(got)), sd, rtol=0.1)
    # the beams share it: the whole block, correlations included
    assert np.linalg.norm(got - want) < 0.15 * np.linalg.norm(want)
    off = want - np.diag(np.diag(want))
    assert np.linalg.norm(off) > 0.9 * np.linalg.norm(want)       # mostly shared between the beams


def test_second_order_rows_whiten_to_the_update_with_the_full_block_noise():
    """Rows whitened against r I + ½ F Fᵀ with the scalar r give the dense update with that
    block noise: mean correction, NIS and posterior."""
    rng = np.random.default_rng(3)
    curves, x, P, beams = _scene(rng)
    model = RangeModel(ObservationConfig(sigma_range_m=0.01, sigma_model_m=0.0, sigma_bearing_rad=0.0,
                                         max_incidence_rad=math.radians(80), second_order=True))
    beams = model.with_second_order(beams, curves, x, OFFSET, P, np.arange(x.shape[0]))
    beams = Beams(beams.curve, beams.bearings, beams.ranges + 0.01 * rng.standard_normal(beams.ranges.shape),
                  beams.t0, beams.second_order)
    lin = model.linearize(beams, curves, x, OFFSET)
    white = model.whitened(beams, lin)
    F = beams.second_order[lin.beam]
    block = lin.R * np.eye(lin.beam.shape[0]) + 0.5 * F @ F.T
    rows = np.arange(x.shape[0])
    want = DenseGain(P, rows, lin.cols, lin.H_c, block)
    got = DenseGain(P, rows, white.cols, white.H_c, white.R)
    np.testing.assert_allclose(got.posterior(), want.posterior(), rtol=1e-8, atol=1e-14)
    dx_want, nis_want = want.correction(lin.residual)
    dx_got, nis_got = got.correction(white.residual)
    np.testing.assert_allclose(dx_got, dx_want, rtol=1e-8, atol=1e-12)
    assert nis_got == pytest.approx(nis_want, rel=1e-8)
    # and it costs information: the pose is less certain than with r I alone
    alone = DenseGain(P, rows, lin.cols, lin.H_c, lin.R)
    assert np.all(np.linalg.eigvalsh(want.posterior()[:3, :3] - alone.posterior()[:3, :3]) > 0)


def test_the_gates_selection_keeps_each_beams_second_order_rows():
    rng = np.random.default_rng(4)
    curves, x, P, beams = _scene(rng)
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80), second_order=True))
    beams = model.with_second_order(beams, curves, x, OFFSET, P, np.arange(x.shape[0]))
    lin = model.linearize(beams, curves, x, OFFSET)
    keep = rng.random(lin.beam.shape[0]) < 0.6
    kept, kept_lin = model.select(beams, lin, keep)
    np.testing.assert_array_equal(kept.second_order[kept_lin.beam], beams.second_order[lin.beam[keep]])
    np.testing.assert_array_equal(kept.bearings[kept_lin.beam], beams.bearings[lin.beam[keep]])


def test_a_beams_second_order_rows_scale_with_its_row_for_the_bearings_sigma():
    """With a bearing σ each row is scaled by √(R / (R + σ_τ² (∂z/∂τ)²)) (:meth:`linearize`),
    and its second-order error with it: the rows are those of exact bearings times that factor."""
    rng = np.random.default_rng(6)
    curves, x, P, beams = _scene(rng)
    work = np.arange(x.shape[0])
    exact = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80), second_order=True))
    noisy = RangeModel(ObservationConfig(sigma_bearing_rad=0.01, max_incidence_rad=math.radians(80), second_order=True))
    lin_e, lin_n = exact.linearize(beams, curves, x, OFFSET), noisy.linearize(beams, curves, x, OFFSET)
    factor = lin_n.H_c[:, 0] / lin_e.H_c[:, 0]
    assert factor.min() < 0.9                                     # some rows weigh clearly less
    want = exact.with_second_order(beams, curves, x, OFFSET, P, work).second_order[lin_e.beam] * factor[:, None]
    got = noisy.with_second_order(beams, curves, x, OFFSET, P, work).second_order[lin_n.beam]
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-15)


def test_with_second_order_off_the_update_is_the_first_order_one():
    """The option off (the default), rows the beams carry are neither whitened against nor
    kept by the gates' selection."""
    assert ObservationConfig().second_order is False
    rng = np.random.default_rng(8)
    curves, x, P, beams = _scene(rng)
    on = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80), second_order=True))
    off = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80)))
    beams = on.with_second_order(beams, curves, x, OFFSET, P, np.arange(x.shape[0]))
    lin = off.linearize(beams, curves, x, OFFSET)
    assert off.whitened(beams, lin) is lin
    assert on.whitened(beams, lin) is not lin
    kept, _ = off.select(beams, lin, np.ones(lin.beam.shape[0], dtype=bool))
    assert kept.second_order is None


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_second_order_must_be_a_boolean(value):
    with pytest.raises(ConfigError, match="second_order"):
        ObservationConfig(second_order=value)
