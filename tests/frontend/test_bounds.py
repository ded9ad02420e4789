"""The front end's work is bounded by its configuration whatever the input: grids sized by
the extent of the points are refused past MAX_FIELD_CELLS, far keyframes are dropped, and
non-finite poses never reach the numba kernels."""

from __future__ import annotations

import numpy as np
import pytest

from bsslam.dataset import Frame
from bsslam.errors import InputError
from bsslam.frontend import FrontendConfig, LaserOdometry
from bsslam.frontend.scan_matcher import MAX_FIELD_CELLS, LikelihoodField, ReferenceMap
from bsslam.sim import SimConfig, get_world, simulate


def _wall(x0: float, y0: float, n: int = 60) -> np.ndarray:
    return np.column_stack((x0 + 0.05 * np.arange(n), np.full(n, y0)))


def test_a_reference_too_wide_for_its_grids_is_unusable_not_allocated():
    cfg = FrontendConfig()
    points = np.vstack((_wall(0.0, 0.0), _wall(10_000.0, 5.0)))       # two walls 10 km apart
    assert LikelihoodField.cells_needed(points, cfg.fine_step_m, cfg.fine_sigma_m, 1.0) > MAX_FIELD_CELLS
    ref = ReferenceMap(points, cfg)
    assert not ref.usable and ref.unusable_reason == "reference_too_large"
    result = ref.match(_wall(0.0, 0.0), np.zeros(3))
    assert not result.ok and result.reason == "reference_too_large"
    with pytest.raises(InputError, match="MAX_FIELD_CELLS"):
        LikelihoodField.build(points, cfg.fine_step_m, cfg.fine_sigma_m, 1.0)
    # a compact reference is usable
    assert ReferenceMap(np.vstack((_wall(0.0, 0.0), _wall(0.0, 3.0), _wall(1.0, -2.0))), cfg).usable


@pytest.mark.parametrize("bad", [[0.0, -np.inf, 0.0], [np.nan, 0.0, 0.0], [1e308, 0.0, 0.0]])
def test_non_finite_or_huge_odometry_is_an_input_error_before_any_kernel(bad):
    frames = list(simulate(get_world("mixed"), SimConfig(), seed=0, steps=2))
    lo = LaserOdometry()
    lo.step(frames[0])
    with pytest.raises(InputError, match="odometry pose"):
        lo.step(Frame(frames[1].stamp, np.array(bad), frames[1].scan))


def test_a_long_jump_drops_the_far_keyframes_and_keeps_the_grids_small():
    frames = list(simulate(get_world("mixed"), SimConfig(), seed=0, steps=6))
    lo = LaserOdometry()
    for f in frames[:4]:
        lo.step(f)
    far = Frame(frames[4].stamp, frames[4].odometry + np.array([10_000.0, 0.0, 0.0]), frames[4].scan)
    step = lo.step(far)                       # 10 km away: no match possible, no huge grid
    assert step.fallback and step.keyframe
    assert len(lo._keyframes) == 1            # the old keyframes cannot overlap any more
    step = lo.step(Frame(frames[5].stamp, far.odometry, frames[5].scan))
    assert np.all(np.isfinite(step.pose))
