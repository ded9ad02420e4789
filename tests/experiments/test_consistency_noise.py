"""The consistency experiment's noise scales and its bias statistic."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bsslam.errors import ConfigError
from bsslam.experiments.consistency import ConsistencyResult, consistency_experiment, scaled_noise
from bsslam.sim import SimConfig, get_world, simulate


def test_the_scales_multiply_each_noise_and_nothing_else():
    base = SimConfig()
    sim = scaled_noise(base, range_scale=0.5, translation_scale=0.3, heading_scale=2.0)
    assert sim.sigma_range_m == pytest.approx(0.5 * base.sigma_range_m)
    assert (sim.motion.a_xy_m, sim.motion.b_xy) == pytest.approx((0.3 * base.motion.a_xy_m, 0.3 * base.motion.b_xy))
    assert (sim.motion.a_phi_rad, sim.motion.b_phi, sim.motion.b_phi_per_m_rad) == pytest.approx(
        (2 * base.motion.a_phi_rad, 2 * base.motion.b_phi, 2 * base.motion.b_phi_per_m_rad))
    assert (sim.fov_rad, sim.resolution_rad, sim.step_m, sim.max_range_m) == (
        base.fov_rad, base.resolution_rad, base.step_m, base.max_range_m)
    assert scaled_noise(base) == base
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ConfigError, match="noise scale"):
            scaled_noise(base, translation_scale=bad)


def test_zero_odometry_noise_gives_dead_reckoning_on_the_true_path():
    # the scaled simulator draws what it says: no translation or heading noise, exact odometry
    sim = scaled_noise(translation_scale=0.0, heading_scale=0.0)
    data = simulate(get_world("rounded-room"), sim, seed=3, steps=20)
    np.testing.assert_allclose(data.odometry_poses, data.ground_truth.poses, atol=1e-12)


def test_the_filter_is_told_the_scaled_noise():
    # with every noise at a tenth the pose σ the runs report shrinks (not tenfold: the filter's
    # 2.5 mm of map-representation error, observation.sigma_model_m, is not the simulator's)
    full = consistency_experiment("no-extension", runs=2, steps=10, workers=1)
    small = consistency_experiment("no-extension", runs=2, steps=10, workers=1,
                                   sim=scaled_noise(range_scale=0.1, translation_scale=0.1, heading_scale=0.1))
    assert np.all(small.mean_sigmas[-1] < 0.5 * full.mean_sigmas[-1])


def test_the_bias_statistic_is_the_mean_error_in_standard_errors():
    rng = np.random.default_rng(5)
    runs, steps = 16, 6
    errors = rng.normal(size=(steps, 3))
    sigmas = rng.uniform(0.5, 2.0, size=(steps, 3))
    result = ConsistencyResult("no-extension", "w", mean_nees=np.ones(steps), lower=1.0, upper=5.0,
                               mean_errors=errors, mean_sigmas=sigmas, nees_runs=np.ones((runs, steps)))
    np.testing.assert_allclose(result.mean_error_z(), errors / sigmas * 4.0)


def test_unbiased_runs_give_a_bias_statistic_of_unit_rms():
    # 50 runs of zero-mean errors as large as their σ: Σ z² over 200 steps × 3 axes is χ²(600);
    # the test fails with probability 0.2 % (two-sided 99.8 % region)
    from scipy.stats import chi2

    rng = np.random.default_rng(17)
    runs, steps = 50, 200
    sigmas = rng.uniform(0.01, 0.2, size=(steps, 3))
    errors = rng.normal(size=(runs, steps, 3)) * sigmas
    result = ConsistencyResult("no-extension", "w", mean_nees=np.ones(steps), lower=1.0, upper=5.0,
                               mean_errors=errors.mean(axis=0), mean_sigmas=sigmas,
                               nees_runs=np.ones((runs, steps)))
    total = float(np.sum(result.mean_error_z() ** 2))
    assert chi2.ppf(0.001, 600) <= total <= chi2.ppf(0.999, 600)
    # and a bias of half a σ shared by every run is unmistakable: z = 0.5 √50 ≈ 3.5
    biased = dataclasses.replace(result, mean_errors=result.mean_errors + 0.5 * sigmas)
    assert np.sqrt(np.mean(biased.mean_error_z() ** 2)) > 3.0
