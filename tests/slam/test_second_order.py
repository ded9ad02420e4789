"""The ranges' second-order error under the prior (``observation.second_order``): its
covariance ½ tr(∇²h_i P ∇²h_j P) against a Monte Carlo of the range model itself, the
whitened rows against the dense update with that block noise, and its rows carried through
the gates' selection."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bsslam.config import ObservationConfig
from bsslam.errors import ConfigError
from bsslam.slam.features import SplineFeature
from bsslam.slam.invariant_ekf import InvariantEKF
from bsslam.slam.map_curves import MapCurves
from bsslam.slam.measurement import Beams, RangeModel
from bsslam.spline import fit_curve

from dense_ekf import DenseGain
from second_order_oracle import second_order_block

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
    want = model.with_second_order(beams, curves, x, OFFSET, P, work).second_order   # (b, b), m²
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


@pytest.mark.parametrize("invariant", [False, True])
def test_the_beams_own_variables_give_the_block_of_the_principal_axes(invariant):
    """One step per class of variables on each beam's own (the pose, its piece's control
    points) gives the block of every beam's Hessian in the prior's principal axes, one step
    per axis (the oracle), with the invariant error's curvature or without, and a bearing
    σ: under a prior of millimetres, where both central differences are the Hessian."""
    rng = np.random.default_rng(5)
    curves, x, P, beams = _scene(rng)
    P = 1e-2 * P
    work = np.arange(x.shape[0])
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.01, max_incidence_rad=math.radians(80)))
    est = _invariant(x) if invariant else None
    want = second_order_block(model, beams, curves, x, OFFSET, P, work, est)
    got = model.with_second_order(beams, curves, x, OFFSET, P, work,
                                  est.error_curvature if invariant else None).second_order
    assert np.abs(want).max() > 1e-10                                  # (tens of micrometres)²
    assert np.linalg.norm(got - want) < 1e-3 * np.linalg.norm(want)


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
    block = lin.R * np.eye(lin.beam.shape[0]) + beams.second_order[np.ix_(lin.beam, lin.beam)]
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
    was, now = lin.beam[keep], kept_lin.beam
    np.testing.assert_array_equal(kept.second_order[np.ix_(now, now)], beams.second_order[np.ix_(was, was)])
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
    want = exact.with_second_order(beams, curves, x, OFFSET, P, work).second_order[np.ix_(lin_e.beam, lin_e.beam)]
    want *= np.outer(factor, factor)
    got = noisy.with_second_order(beams, curves, x, OFFSET, P, work).second_order[np.ix_(lin_n.beam, lin_n.beam)]
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


def _invariant(x: np.ndarray) -> InvariantEKF:
    """An invariant EKF whose mean is ``x`` (the pose, then the control points' x and y
    coordinates); its covariance is not read here (the priors are the tests' own)."""
    est = InvariantEKF(x[:3], np.eye(3))
    k = x.shape[0] - 3
    est.append(x[3:], np.arange(3), np.zeros((k, 3)), np.eye(k))
    return est


def _exp(x: np.ndarray, xi: np.ndarray, mate: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """exp(ξ) x̂ of the invariant error: every position p ← R(ξ_φ) p + V(ξ_φ) ξ_p, the
    heading + ξ_φ (written out here from the group's exponential, not from the filter)."""
    th = xi[2]
    c, s = math.cos(th), math.sin(th)
    a, b = (s / th, (1.0 - c) / th) if th else (1.0, 0.0)
    out = x.copy()
    px = sign < 0                                   # the x coordinates; their mates are the y
    X, Y = x[px], x[mate[px]]
    ex, ey = xi[px], xi[mate[px]]
    out[px] = c * X - s * Y + a * ex - b * ey
    out[mate[px]] = s * X + c * Y + b * ex + a * ey
    out[2] = x[2] + th
    return out


def test_a_rigid_motion_of_everything_has_no_curvature_along_the_invariant_error():
    """A prior on the global motion alone (translation and rotation of the robot and the
    wall together): no range changes along it, so in the invariant EKF's error coordinates
    the second-order rows vanish; along x − x̂ the same prior stretches every distance (a
    straight step along a rotation) and gives millimetres."""
    rng = np.random.default_rng(11)
    curves, x, _, beams = _scene(rng)
    est = _invariant(x)
    work = np.arange(x.shape[0])
    N = est.null_space(x, work)
    P = N @ np.diag([0.05, 0.05, 0.05]) ** 2 @ N.T
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80)))
    linear = model.with_second_order(beams, curves, x, OFFSET, P, work).second_order
    invariant = model.with_second_order(beams, curves, x, OFFSET, P, work, est.error_curvature).second_order
    assert np.sqrt(np.abs(linear).max()) > 5e-3                    # millimetres along x − x̂
    assert np.abs(invariant).max() < 1e-4 * np.abs(linear).max()


def test_second_order_along_the_invariant_error_matches_a_monte_carlo_of_it():
    """With ξ ~ N(0, A⁻¹ P A⁻ᵀ) and x = exp(ξ) x̂ (a prior with a global rotation of
    0.03 rad besides the scene's), h(x) − h(x̂) − H A ξ has the block of the rows with the
    invariant error's curvature; the rows along x − x̂ miss it."""
    rng = np.random.default_rng(12)
    curves, x, P, beams = _scene(rng)
    est = _invariant(x)
    work = np.arange(x.shape[0])
    N = est.null_space(x, work)
    P = P + 0.03 ** 2 * np.outer(N[:, 2], N[:, 2])
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80)))
    want = model.with_second_order(beams, curves, x, OFFSET, P, work, est.error_curvature).second_order
    linear = model.with_second_order(beams, curves, x, OFFSET, P, work).second_order
    h0, lin = _predicted(model, beams, curves, x)
    H = np.zeros((lin.beam.shape[0], x.shape[0]))
    H[:, lin.cols] = lin.H_c
    A = np.eye(x.shape[0])
    A[:, 2] += est.turn(x)                          # A = I + J x̂ e_φᵀ
    L = np.linalg.cholesky(np.linalg.solve(A, np.linalg.solve(A, P).T))   # Σ_ξ = A⁻¹ P A⁻ᵀ
    samples = 6000
    e = np.empty((samples, h0.shape[0]))
    for i in range(samples):
        xi = L @ rng.standard_normal(x.shape[0])
        e[i] = _predicted(model, beams, curves, _exp(x, xi, est._mate, est._sign))[0] - h0 - H @ (A @ xi)
    got = np.cov(e.T)
    assert np.linalg.norm(got - want) < 0.15 * np.linalg.norm(want)
    assert np.linalg.norm(got - linear) > 0.5 * np.linalg.norm(want)
    np.testing.assert_allclose(np.sqrt(np.diag(got)), np.sqrt(np.diag(want)), rtol=0.1)


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_second_order_must_be_a_boolean(value):
    with pytest.raises(ConfigError, match="second_order"):
        ObservationConfig(second_order=value)


def test_a_gains_posterior_block_is_the_dense_posterior_on_its_rows():
    """What the second-order block is taken under (the first gain's posterior on the
    working rows) is the textbook P − K H P there, for a window of part of the state."""
    from bsslam.slam.ekf import CovarianceColumns

    rng = np.random.default_rng(9)
    n, m = 14, 14                                   # m ≥ 2c: the compressed gain with a scalar R
    A = rng.standard_normal((n, n))
    P = A @ A.T + np.eye(n)
    rows = np.array([0, 1, 2, 4, 5, 8, 9, 11])
    cols = np.array([0, 1, 2, 5, 8, 9])
    H_c = rng.standard_normal((m, cols.shape[0]))
    for R in (0.3, 0.3 * np.eye(m) + 0.1):
        got = CovarianceColumns(P, rows).gain(cols, H_c, R).posterior_block()
        want = DenseGain(P, rows, cols, H_c, R).posterior_block()
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("estimator", ["ekf", "invariant"])
def test_the_filter_weighs_the_second_order_block_of_each_scan(monkeypatch, estimator):
    """With the option on, each scan's update takes a block that is a covariance (symmetric,
    PSD, not zero) under a PSD prior (the first gain's posterior); the run stays finite
    and its pose covariance positive definite."""
    from bsslam.config import SLAMConfig
    from bsslam.experiments.consistency import simulation_config
    from bsslam.se2 import between
    from bsslam.sim import SimConfig, get_world, simulate
    from bsslam.slam import SplineSLAM

    seen = []
    original = RangeModel.with_second_order

    def spy(self, beams, curves, x, laser_offset, prior, work, curvature=None):
        out = original(self, beams, curves, x, laser_offset, prior, work, curvature)
        seen.append((out.second_order, prior))
        return out

    monkeypatch.setattr(RangeModel, "with_second_order", spy)
    sim = SimConfig()
    base = SLAMConfig(estimator=estimator)
    config = simulation_config(base, sim)
    config = config.replace(observation=dataclasses.replace(config.observation, second_order=True))
    frames = list(simulate(get_world("rounded-room"), sim, seed=3, steps=30))
    slam = SplineSLAM(config, initial_pose=frames[0].odometry)
    prev = frames[0].odometry
    for frame in frames:
        slam.step(between(prev, frame.odometry), frame.scan)
        prev = frame.odometry
    assert len(seen) > 20
    for block, prior in seen:
        np.testing.assert_array_equal(block, block.T)
        assert np.linalg.eigvalsh(block).min() > -1e-12 * max(np.abs(block).max(), 1e-30)
        assert np.linalg.eigvalsh(prior).min() > -1e-12
    assert max(np.abs(block).max() for block, _ in seen) > 0.0
    assert np.all(np.isfinite(slam.state.x))
    assert np.linalg.eigvalsh(slam.state.pose_covariance).min() > 0.0
