"""The perturbed dataset of ``bench --perturb``: seeded, only returns moved, the noise's
spread as asked (a χ² bound), float32 rounding exact."""

import numpy as np
import pytest
from scipy import stats

from bsslam.dataset import Frame, SkipCounter
from bsslam.perturbed_dataset import PerturbedDataset
from bsslam.scan import LaserScan


class _Frames:
    name = "frames"
    ground_truth = None

    def __init__(self, frames):
        self.frames = frames
        self.skipped = SkipCounter()

    def __iter__(self):
        return iter(self.frames)


def _dataset(n_frames=20, n_beams=181, seed=1):
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_frames):
        ranges = rng.uniform(0.5, 20.0, n_beams)
        ranges[::17] = np.inf        # no return
        ranges[5::23] = 30.0         # at max_range: no return
        ranges[7::29] = np.nan       # invalid
        scan = LaserScan(float(k), np.linspace(-np.pi / 2, np.pi / 2, n_beams), ranges, 30.0)
        frames.append(Frame(float(k), np.zeros(3), scan))
    return _Frames(frames)


def _ranges(dataset):
    return [f.scan.ranges for f in dataset]


def test_same_seed_same_ranges_other_seed_other_ranges():
    data = _dataset()
    a, b, c = (_ranges(PerturbedDataset(data, 0.001, seed=s)) for s in (3, 3, 4))
    assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, c))


def test_only_returns_move_and_their_noise_has_the_asked_spread():
    data = _dataset()
    sigma = 0.001
    diffs = []
    for orig, pert in zip(_ranges(data), _ranges(PerturbedDataset(data, sigma, seed=0))):
        hit = np.isfinite(orig) & (orig < 30.0)
        assert np.array_equal(orig[~hit], pert[~hit], equal_nan=True)
        diffs.append(pert[hit] - orig[hit])
    d = np.concatenate(diffs)
    # Σ(d/σ)² is χ²(k): outside its two-sided 99.9% interval fails one run in a thousand
    chi2 = float(np.sum((d / sigma) ** 2))
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], d.size)
    assert lo < chi2 < hi
    assert abs(d.mean()) < 4 * sigma / np.sqrt(d.size)


def test_float32_rounds_the_returns_exactly():
    data = _dataset()
    for orig, pert in zip(_ranges(data), _ranges(PerturbedDataset(data, float32=True))):
        hit = np.isfinite(orig) & (orig < 30.0)
        assert np.array_equal(pert[hit], orig[hit].astype(np.float32).astype(float))
        assert np.array_equal(orig[~hit], pert[~hit], equal_nan=True)


def test_passes_name_reference_and_skips_through_and_rejects_bad_sigma():
    data = _dataset(2)
    p = PerturbedDataset(data, 0.001)
    assert p.name == data.name and p.ground_truth is None and p.skipped is data.skipped
    with pytest.raises(ValueError):
        PerturbedDataset(data, float("nan"))
