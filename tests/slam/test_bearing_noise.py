"""A beam's bearing noise in the range model (``observation.sigma_bearing_rad``): its
derivative against finite differences, the rescaled rows against the update with each
beam's own variance (the dense oracle), and the noise model against simulated scans whose
bearings err (a χ² test)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from bsslam.config import ObservationConfig
from bsslam.errors import ConfigError
from bsslam.slam.features import SplineFeature
from bsslam.slam.map_curves import MapCurves
from bsslam.slam.measurement import Beams, RangeModel, bearing_derivatives, laser_pose
from bsslam.spline import fit_curve

from dense_ekf import DenseGain

OFFSET = np.array([0.2, -0.05, 0.1])          # a laser ahead of the axle, a little turned


def _map(points: np.ndarray, spacing: float = 0.7) -> tuple[MapCurves, np.ndarray]:
    """A one-spline map (fixed control points) through ``points`` (k, 2), and their
    chord-length parameters."""
    fit = fit_curve(points, 3, spacing)
    feature = SplineFeature(0, 3, fit.curve.knots.copy(), fixed_control_points=fit.curve.control_points.copy())
    return MapCurves([feature]), fit.params


def _wavy_wall() -> np.ndarray:
    s = np.linspace(-6.0, 6.0, 400)
    return np.column_stack([s, 3.0 + 0.3 * np.sin(0.8 * s)])


def _beams(bearings, ranges, t0) -> Beams:
    return Beams(np.zeros(len(bearings), dtype=np.intp), np.asarray(bearings, float), np.asarray(ranges, float),
                 np.asarray(t0, float))


def test_bearing_derivative_matches_central_differences():
    curves, params = _map(_wavy_wall())
    pose = np.array([0.4, -0.3, 0.25])
    bearings = np.linspace(0.5, 2.3, 25) - pose[2] - OFFSET[2]     # world beam angles 0.5–2.3 rad: up the wall
    t0 = np.full(bearings.shape, 0.5 * (params[0] + params[-1]))
    model = RangeModel(ObservationConfig(sigma_bearing_rad=0.0, max_incidence_rad=math.radians(80)))   # raw residuals
    ranges = np.full(bearings.shape, 3.0)                             # any: z − h only shifts the residual
    lin = model.linearize(_beams(bearings, ranges, t0), curves, pose, OFFSET)
    assert lin is not None and lin.beam.shape[0] >= 20
    rows = lin.beam
    predicted = ranges[rows] - lin.residual
    got = bearing_derivatives(lin.H_c, predicted, pose[2] + OFFSET[2] + bearings[rows])
    h = 1e-6

    def predicted_at(b):
        moved = model.linearize(_beams(b, ranges[rows], lin.hit_t), curves, pose, OFFSET)
        assert moved.beam.shape[0] == rows.shape[0]
        return ranges[rows] - moved.residual

    want = (predicted_at(bearings[rows] + h) - predicted_at(bearings[rows] - h)) / (2 * h)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    assert np.ptp(got) > 1.0          # oblique and square-on beams both tested


def test_rescaled_rows_give_the_update_with_each_beams_own_variance():
    curves, params = _map(_wavy_wall())
    pose = np.array([0.1, 0.2, -0.1])
    rng = np.random.default_rng(3)
    bearings = np.sort(rng.uniform(0.6, 2.5, 40)) - pose[2] - OFFSET[2]
    ranges = rng.uniform(2.5, 8.0, 40)
    t0 = np.full(40, 0.5 * (params[0] + params[-1]))
    plain = RangeModel(ObservationConfig(sigma_range_m=0.02, sigma_bearing_rad=0.0, max_incidence_rad=math.radians(75)))
    noisy = RangeModel(ObservationConfig(sigma_range_m=0.02, sigma_bearing_rad=0.01, max_incidence_rad=math.radians(75)))
    a = plain.linearize(_beams(bearings, ranges, t0), curves, pose, OFFSET)
    b = noisy.linearize(_beams(bearings, ranges, t0), curves, pose, OFFSET)
    np.testing.assert_array_equal(a.beam, b.beam)
    assert b.R == a.R == plain.R
    dz = bearing_derivatives(a.H_c, ranges[a.beam] - a.residual, pose[2] + OFFSET[2] + bearings[a.beam])
    own = a.R + noisy.bearing_variance * dz ** 2                      # each beam's variance (m²)
    assert own.max() > 2 * a.R                                        # some beams weigh far less
    P = np.diag([0.04, 0.03, 0.002])
    rows = np.arange(3)
    want = DenseGain(P, rows, a.cols, a.H_c, own)                     # the oracle, diagonal R
    got = DenseGain(P, rows, b.cols, b.H_c, b.R)                      # the rescaled rows, R I
    np.testing.assert_allclose(got.posterior(), want.posterior(), rtol=1e-10, atol=1e-14)
    dx_want, nis_want = want.correction(a.residual)
    dx_got, nis_got = got.correction(b.residual)
    np.testing.assert_allclose(dx_got, dx_want, rtol=1e-9, atol=1e-14)
    assert nis_got == pytest.approx(nis_want, rel=1e-9)
    # a gate on a row compares its residual with its own variance
    np.testing.assert_allclose(b.residual ** 2 / b.R, a.residual ** 2 / own, rtol=1e-12)


def test_bearing_noise_explains_scans_whose_bearings_err():
    """Scans of a straight wall ray-cast with bearings off by N(0, σ_τ²) and ranges by
    N(0, σ_r²), seen from the true pose in the exact map: Σ ν²/R over the rows is χ² with
    as many degrees of freedom when the model holds σ_τ, and far above it when it does not."""
    wall = np.column_stack([np.linspace(-4.0, 30.0, 200), np.full(200, 2.0)])   # y = 2
    curves, _ = _map(wall, spacing=2.0)
    rng = np.random.default_rng(11)
    sigma_r, sigma_b = 0.01, 0.004
    statistic = {0.0: 0.0, sigma_b: 0.0}
    dof = 0
    for _ in range(30):
        pose = np.array([rng.uniform(-1, 1), rng.uniform(-1.0, 0.5), rng.uniform(-0.3, 0.3)])
        laser = laser_pose(pose, OFFSET)
        origin, heading = laser[:2], laser[2]
        bearings = np.linspace(0.15, 1.5, 60) - heading                 # world angles, incidence up to 81°
        true_mu = heading + bearings + sigma_b * rng.standard_normal(60)
        ranges = (2.0 - origin[1]) / np.sin(true_mu) + sigma_r * rng.standard_normal(60)
        hit_x = origin[0] + ranges * np.cos(true_mu)
        t0 = hit_x + 4.0                                               # the wall's parameter: x + 4
        for sb in statistic:
            model = RangeModel(ObservationConfig(sigma_range_m=sigma_r, sigma_model_m=0.0, sigma_bearing_rad=sb,
                                                 max_incidence_rad=math.radians(80)))
            lin = model.linearize(_beams(bearings, ranges, t0), curves, pose, OFFSET)
            statistic[sb] += float(np.sum(lin.residual ** 2) / lin.R)
            if sb:
                dof += lin.residual.shape[0]
    assert dof > 1200
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], dof)                    # a false alarm one run in a thousand
    assert lo < statistic[sigma_b] < hi
    assert statistic[0.0] > 3 * hi                                     # exact bearings: far too sure


@pytest.mark.parametrize("value", [-1e-3, 0.2, math.nan, math.inf])
def test_bearing_sigma_out_of_range_is_refused(value):
    with pytest.raises(ConfigError, match="sigma_bearing_rad"):
        ObservationConfig(sigma_bearing_rad=value)
