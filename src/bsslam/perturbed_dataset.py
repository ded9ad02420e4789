"""A dataset whose ranges are perturbed: seeded noise or float32 rounding.

A benchmark's single run is one sample of the filter's accuracy; the same log with every
range moved by a millimetre of seeded noise (or rounded to float32, as every ROS bag
stores it) shows how much of a figure is the data and how much is rounding
(``bsslam bench --perturb N``).
"""

from __future__ import annotations

import dataclasses
from typing import Iterator

import numpy as np

from bsslam.dataset import Dataset, Frame
from bsslam.scan.laser_scan import LaserScan


class PerturbedDataset:
    """Wraps a :class:`~bsslam.dataset.Dataset`: each frame's returns (finite ranges
    below the scan's ``max_range``) get independent Gaussian noise of ``sigma_m``, drawn
    from a generator seeded with ``seed`` (the same seed gives the same ranges), and/or
    are rounded to float32. No-return and invalid beams are left as they are; a noisy range
    is clipped to stay positive.

    Args:
        dataset: the source; its name, ground truth and skip counter are passed through.
        sigma_m: noise standard deviation (m); 0 for none.
        seed: seed of the noise generator.
        float32: round the (perturbed) ranges to float32.
    """

    def __init__(self, dataset: Dataset, sigma_m: float = 0.0, seed: int = 0, float32: bool = False):
        if not (np.isfinite(sigma_m) and sigma_m >= 0):
            raise ValueError(f"sigma_m must be a finite number ≥ 0, got {sigma_m}")
        self._dataset = dataset
        self.sigma_m = float(sigma_m)
        self.seed = int(seed)
        self.float32 = bool(float32)
        self.name = dataset.name
        self.ground_truth = dataset.ground_truth

    @property
    def skipped(self):
        return self._dataset.skipped

    def __iter__(self) -> Iterator[Frame]:
        rng = np.random.default_rng(self.seed)
        for frame in self._dataset:
            yield dataclasses.replace(frame, scan=perturb_scan(frame.scan, rng, self.sigma_m, self.float32))


def perturb_scan(scan: LaserScan, rng: np.random.Generator, sigma_m: float, float32: bool = False) -> LaserScan:
    """``scan`` with its returns (finite ranges below ``max_range``) moved by Gaussian noise
    of ``sigma_m`` (m; 0 for none) drawn from ``rng`` (one draw per beam, returns or not)
    and/or rounded to float32; no-return and invalid beams as they are."""
    ranges = scan.ranges.copy()
    hit = np.isfinite(ranges) & (ranges > 0) & (ranges < scan.max_range)
    if sigma_m > 0:
        noise = rng.standard_normal(ranges.shape[0])[hit] * sigma_m
        # a return stays a return: never at or below zero, never at max_range
        ranges[hit] = np.clip(ranges[hit] + noise, 1e-3, np.nextafter(scan.max_range, 0))
    if float32:
        ranges[hit] = ranges[hit].astype(np.float32).astype(float)
    return dataclasses.replace(scan, ranges=ranges)
