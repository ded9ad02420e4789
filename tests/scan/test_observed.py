"""extract_splines: scan → observed splines with their beam → parameter maps (spec §3)."""

from __future__ import annotations

import numpy as np
import pytest
from scan_cases import INTEL_RAWODOM, cast_scan, load_flaser, room_walls

from bsslam.config import SegmentationConfig, SLAMConfig, SplineConfig
from bsslam.scan import LaserScan, beams_to_points, extract_splines
from bsslam.spline import chord_length_parameters


def test_observed_splines_map_beams_to_their_points_and_parameters():
    scan = cast_scan(room_walls())
    ranges = scan.ranges.copy()
    ranges[[10, 100, 101]] = np.nan  # dropouts inside walls: indices must skip them
    scan = LaserScan(0.0, scan.angles, ranges, scan.max_range)
    features = extract_splines(scan, SLAMConfig())
    assert len(features.splines) == 3
    assert features.counts["splines"] == 3 and features.counts["nonfinite"] == 3
    covered = np.concatenate([s.beam_indices for s in features.splines])
    assert np.all(np.diff(covered) > 0) and not np.isin([10, 100, 101], covered).any()
    for obs in features.splines:
        k = obs.beam_indices.shape[0]
        np.testing.assert_array_equal(obs.ranges, scan.ranges[obs.beam_indices])
        np.testing.assert_array_equal(obs.angles, scan.angles[obs.beam_indices])
        np.testing.assert_allclose(obs.points, beams_to_points(obs.angles, obs.ranges))
        np.testing.assert_allclose(obs.params, chord_length_parameters(obs.points))
        assert obs.phi.shape == (obs.curve.n_control, k)
        np.testing.assert_allclose(obs.phi @ obs.points, obs.curve.control_points, atol=1e-12)
        assert obs.curve.degree == 3
        # Straight, noiseless walls are reproduced exactly by the least-squares spline.
        np.testing.assert_allclose(obs.curve.evaluate(obs.params), obs.points, atol=1e-9)


def test_segments_that_cannot_be_fitted_are_counted_not_raised():
    # Three beams on a wall pass a permissive segmenter but a cubic needs four points.
    ranges = np.full(181, np.inf)
    ranges[50:53] = 2.0
    scan = LaserScan(0.0, np.deg2rad(np.arange(-90.0, 91.0)), ranges, 8.0)
    config = SLAMConfig(segmentation=SegmentationConfig(min_points=2, min_length_m=0.0))
    features = extract_splines(scan, config)
    assert features.splines == []
    assert features.counts["segments"] == 1 and features.counts["fit_failed"] == 1
    assert features.counts["splines"] == 0


def test_an_empty_scan_gives_no_splines():
    features = extract_splines(LaserScan(0.0, np.empty(0), np.empty(0), 8.0), SLAMConfig())
    assert features.splines == []
    assert features.counts["beams"] == 0 and features.counts["splines"] == 0


@pytest.mark.parametrize("degree", [1, 3])
def test_fitted_splines_stay_close_to_real_intel_points(degree):
    if not INTEL_RAWODOM.exists():
        pytest.skip(f"Intel log not found at {INTEL_RAWODOM} (shared data folder absent)")
    config = SLAMConfig(spline=SplineConfig(degree=degree, knot_spacing_m=1.0 if degree == 3 else 0.5))
    n_splines = 0
    worst = 0.0
    for scan in load_flaser(INTEL_RAWODOM, 100):
        for obs in extract_splines(scan, config).splines:
            residual = obs.curve.evaluate(obs.params) - obs.points
            worst = max(worst, float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))))
            n_splines += 1
    assert n_splines >= 200  # the corridor walls are found (2–3 per scan), not all dropped
    assert worst <= 0.03
