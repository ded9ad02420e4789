"""The filter on seeded simulated runs with exact ground truth."""

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.eval import ate, chi2_band, pose_errors
from bsslam.experiments.consistency import simulation_config, variant_config
from bsslam.pipeline import run_dataset
from bsslam.parallel import run_all
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam.ekf import StackedGain

LOOP_WORLDS = ["rounded-room", "corridor-loop", "mixed"]


@pytest.mark.parametrize("world", LOOP_WORLDS)
def test_hundred_steps_inside_three_sigma_and_accurate(world):
    sim = SimConfig()
    data = simulate(get_world(world), sim, seed=11, steps=100)
    result = run_dataset(data, simulation_config(SLAMConfig(), sim), point_stride=0)
    err = pose_errors(result.estimate, data.ground_truth)
    pos_err = np.hypot(err.errors[:, 0], err.errors[:, 1])
    # 3σ of the position along the error direction, from the 2×2 position covariance
    cov = result.estimate.covariances[:, :2, :2]
    dirs = err.errors[:, :2] / np.maximum(pos_err, 1e-12)[:, None]
    sigma_along = np.sqrt(np.einsum("ni,nij,nj->n", dirs, cov, dirs))
    inside = (pos_err <= 3 * sigma_along + 1e-9)[1:]
    assert inside.mean() >= 0.95, f"position inside 3σ on {inside.mean():.0%} of steps"
    heading_inside = (np.abs(err.errors[1:, 2]) <= 3 * err.sigmas[1:, 2]).mean()
    assert heading_inside >= 0.95
    rmse, _, _ = ate(result.estimate, data.ground_truth)
    assert rmse < 0.05, f"ATE {rmse:.3f} m"
    # the map was built and used
    assert len(result.map) > 0 and result.totals["beams_used"] > 50 * 100
    # the covariance stayed symmetric positive definite
    assert np.all(np.linalg.eigvalsh(result.estimate.covariances[1:]) > 0)


def _nees_run(seed):
    sim = SimConfig()
    data = simulate(get_world("rounded-room"), sim, seed=seed, steps=60)
    config = simulation_config(variant_config("no-extension"), sim)
    result = run_dataset(data, config, point_stride=0)
    return pose_errors(result.estimate, data.ground_truth).nees


# At the defaults (map splines no later scan confirms are pruned after 2 scans) the mean
# NEES is inside the band on 56 of 59 steps here; 51/59 in mixed, 48/59 in corridor-loop.
# Without pruning it was 53/59 here (40/59, 51/59 in the other two worlds).
def test_monte_carlo_nees_inside_chi2_band_without_extension():
    runs = 20
    nees = np.array(run_all(_nees_run, list(range(100, 100 + runs)), workers=2))
    mean = nees[:, 1:].mean(axis=0)  # step 0 defines the map frame: P = 0
    lower, upper = chi2_band(3, runs)
    inside = (mean >= lower) & (mean <= upper)
    assert inside.mean() >= 0.9, f"mean NEES inside the band on {inside.mean():.0%} of steps: {np.round(mean, 2)}"


def test_iterations_stop_close_to_the_update_iterated_further():
    """The iterated update stops once a Gauss–Newton step is below 0.1 σ of the pose. From the
    same prior, and with the same beams through the gates, its estimate stays within 0.15 σ of
    the update iterated five times (the steps shrink by about half or faster here, so what a
    stop leaves is about the last step)."""
    import copy
    import dataclasses

    from bsslam.se2 import between
    from bsslam.slam import SplineSLAM

    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=5, steps=40))
    config = simulation_config(SLAMConfig(), sim)
    further = config.replace(observation=dataclasses.replace(config.observation, iterations=5,
                                                             iteration_tolerance=0.0))
    slam = SplineSLAM(config, initial_pose=frames[0].odometry)
    worst, stopped_early = 0.0, 0
    for prev, frame in zip(frames, frames[1:]):
        delta = between(prev.odometry, frame.odometry)
        reference = copy.deepcopy(slam)
        reference.config = further
        gains = []
        original = StackedGain.__init__

        def counting(self, *args, _original=original, **kwargs):
            gains.append(1)
            _original(self, *args, **kwargs)

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(StackedGain, "__init__", counting)
            report = slam.step(delta, frame.scan)
        if reference.step(delta, frame.scan).beams_used != report.beams_used:
            # a beam at its gate's edge went the other way at the other estimate (6 of the 39
            # steps; seed 5's step 38: 122 against 121 beams, 0.21 σ apart): another update
            continue
        stopped_early += 0 < len(gains) < 4   # fewer than the gating gain + 3 iterations
        sigma = np.sqrt(np.diag(reference.pose_covariance))
        worst = max(worst, float(np.max(np.abs(slam.pose - reference.pose) / sigma)))
    assert stopped_early >= 20   # the stop is exercised
    assert worst < 0.15, f"{worst:.3f} σ from the update iterated five times"


def test_reading_the_map_leaves_the_run_bit_for_bit():
    """``SplineSLAM.map`` (the submap backend reads it while a submap grows, a viewer may
    read it every scan) is a pure read: a run that reads it after every step ends with the
    same state, to the last bit, as one that never does. A fold of the pending update or a
    row cached by the read would change the later arithmetic by rounding, and through the
    gates' knife edges the map."""
    from bsslam.se2 import between
    from bsslam.slam import SplineSLAM

    sim = SimConfig()
    frames = list(simulate(get_world("mixed"), sim, seed=3, steps=60))
    config = simulation_config(SLAMConfig(), sim)
    quiet, reader = (SplineSLAM(config, initial_pose=frames[0].odometry) for _ in range(2))
    reads = 0
    for prev, frame in zip(frames, frames[1:]):
        delta = between(prev.odometry, frame.odometry)
        quiet.step(delta, frame.scan)
        reader.step(delta, frame.scan)
        reads += len(reader.map)
    assert reads > 100
    assert np.array_equal(quiet.state.x, reader.state.x)
    assert np.array_equal(quiet.state.P, reader.state.P)
