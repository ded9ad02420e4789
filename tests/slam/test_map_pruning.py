"""Map splines that no later scan confirms leave the state (mapping.prune_after_scans)."""

import dataclasses

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.scan import LaserScan
from bsslam.slam import SplineSLAM

ANGLES = np.radians(np.arange(-90.0, 90.5, 0.5))


def wall_scan(rng, wall_x=3.0, sigma=0.005):
    """A robot at the origin facing a straight wall x = wall_x; beams beyond ±45° see nothing."""
    ranges = np.full(ANGLES.shape, 100.0)
    sees = np.abs(ANGLES) < np.radians(45.0)
    ranges[sees] = wall_x / np.cos(ANGLES[sees]) + rng.normal(0.0, sigma, sees.sum())
    return LaserScan(0.0, ANGLES, ranges, max_range=80.0)


def empty_scan():
    return LaserScan(0.0, ANGLES, np.full(ANGLES.shape, 100.0), max_range=80.0)


def config(prune_after):
    base = SLAMConfig()
    return base.replace(mapping=dataclasses.replace(base.mapping, prune_after_scans=prune_after))


def test_unconfirmed_spline_is_pruned_and_state_shrinks_to_the_pose():
    rng = np.random.default_rng(0)
    slam = SplineSLAM(config(2))
    slam.step(None, wall_scan(rng))
    assert len(slam.features) == 1 and slam.state_size > 3
    pruned = [slam.step(None, empty_scan()).pruned_splines for _ in range(3)]
    assert pruned == [0, 1, 0]
    assert slam.state_size == 3 and not slam.features


def test_confirmed_spline_stays_and_keeps_its_covariance():
    rng = np.random.default_rng(1)
    slam = SplineSLAM(config(2))
    slam.step(None, wall_scan(rng))
    slam.step(None, wall_scan(rng))          # the wall seen again: used in an update
    (fid, feature), = slam.features.items()
    assert feature.observations >= 1
    idx = feature.state_indices
    before = slam.state.P[np.ix_(idx, idx)].copy()
    for _ in range(4):
        assert slam.step(None, empty_scan()).pruned_splines == 0
    assert fid in slam.features
    np.testing.assert_array_equal(slam.state.P[np.ix_(idx, idx)], before)


def test_pruning_off_by_default_keeps_everything():
    rng = np.random.default_rng(2)
    slam = SplineSLAM(config(0))
    slam.step(None, wall_scan(rng))
    for _ in range(5):
        slam.step(None, empty_scan())
    assert len(slam.features) == 1


def test_no_unconfirmed_spline_outlives_its_window_on_a_simulated_run():
    """The filter only looks at the splines added since it last looked (not the whole map):
    after every step, each spline no update has used is younger than the window, as a pass
    over the whole map would leave it; one removed by the caller meanwhile is simply gone."""
    from bsslam.experiments.consistency import simulation_config
    from bsslam.se2 import between
    from bsslam.sim import SimConfig, get_world, simulate

    sim = SimConfig()
    frames = list(simulate(get_world("corridor-loop"), sim, seed=3, steps=80))
    slam = SplineSLAM(simulation_config(config(2), sim), initial_pose=frames[0].odometry)
    prev, pruned, removed = frames[0].odometry, 0, None
    for k, fr in enumerate(frames):
        pruned += slam.step(between(prev, fr.odometry), fr.scan).pruned_splines
        prev = fr.odometry
        assert all(f.observations > 0 or slam.steps - 1 - f.created < 2 for f in slam.features.values())
        young = [f.id for f in slam.features.values() if f.observations == 0]
        if removed is None and young and k > 10:
            removed = young[0]
            slam.remove_feature(removed)
    assert pruned > 0 and removed is not None and removed not in slam.features
