"""A dataset whose scans are corrected for the robot's motion during each sweep."""

from __future__ import annotations

import dataclasses
from typing import Iterator

import numpy as np

from bsslam.dataset import Dataset, Frame
from bsslam.input_limits import InputLimits, increment_problem
from bsslam.scan.deskew import deskew
from bsslam.se2 import between


class DeskewedDataset:
    """Wraps a :class:`~bsslam.dataset.Dataset`: each frame's scan goes through
    :func:`~bsslam.scan.deskew.deskew` (by its own ``sweep_time_s``; scans taken at one
    instant pass unchanged) with the robot's velocity estimated from the odometry since the
    previous frame: its increment over the time between the two, zero for the first frame
    and after a stamp that did not advance.

    Where scans are kept far apart (the shared logs keep one every 0.5–3 s) that is the
    mean velocity over the interval, not the one at the scan; it is the estimate a reader
    of the log has.

    Args:
        dataset: the source; its name, ground truth and skip counter are passed through.
        limits: an odometry step faster than these (:func:`~bsslam.input_limits.increment_problem`)
            gives no velocity: the scan is left as it is (the mapper bridges the step).
    """

    def __init__(self, dataset: Dataset, limits: InputLimits | None = None):
        self._dataset = dataset
        self.limits = limits or InputLimits()
        self.name = getattr(dataset, "name", "dataset")
        self.ground_truth = getattr(dataset, "ground_truth", None)

    @property
    def skipped(self):
        return self._dataset.skipped

    def __iter__(self) -> Iterator[Frame]:
        previous: Frame | None = None
        for frame in self._dataset:
            velocity = (np.zeros(3) if previous is None else
                        odometry_velocity(previous.odometry, previous.stamp, frame.odometry, frame.stamp, self.limits))
            previous = frame
            yield deskewed(frame, velocity)


def odometry_velocity(previous_odometry, previous_stamp: float | None, odometry, stamp: float,
                      limits: InputLimits) -> np.ndarray:
    """(3,) the robot-frame velocity (vx, vy m/s; ω rad/s) that takes the odometry pose
    ``previous_odometry`` at ``previous_stamp`` to ``odometry`` at ``stamp`` (s); zeros
    without a previous pose, when the stamp did not advance or when the step is not
    plausible under ``limits`` (too fast, not finite)."""
    if previous_odometry is None or previous_stamp is None or not stamp > previous_stamp:
        return np.zeros(3)
    step = between(np.asarray(previous_odometry, dtype=float), np.asarray(odometry, dtype=float))
    if increment_problem(step, stamp - previous_stamp, limits) is not None:
        return np.zeros(3)
    return step / (stamp - previous_stamp)


def deskewed(frame: Frame, velocity: np.ndarray) -> Frame:
    """``frame`` with its scan through :func:`~bsslam.scan.deskew.deskew` (the same frame
    when the scan was taken at one instant)."""
    scan = deskew(frame.scan, velocity, frame.laser_offset)
    return frame if scan is frame.scan else dataclasses.replace(frame, scan=scan)
