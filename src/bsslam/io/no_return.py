"""Recognising "no return" beams (see :class:`bsslam.io.reader_config.ReaderConfig`)."""

from __future__ import annotations

from collections import Counter
from typing import Iterable

import numpy as np

from bsslam.io.reader_config import ReaderConfig


def detect_no_return_code(scan_maxima: Iterable[float], config: ReaderConfig) -> float | None:
    """The logger's no-return code, or None.

    Args:
        scan_maxima: the largest finite range of each examined scan (m).
        config: ``code_min_m`` and ``code_min_share`` decide (see ReaderConfig).

    Returns:
        the value most often a scan's maximum when it is ≥ ``code_min_m`` and the maximum
        of at least ``code_min_share`` of the scans (and of two or more); else None.
    """
    counts = Counter(float(m) for m in scan_maxima)
    if not counts:
        return None
    value, times = counts.most_common(1)[0]
    needed = max(2.0, config.code_min_share * sum(counts.values()))
    if value >= config.code_min_m and times >= needed:
        return value
    return None


def no_return_threshold(config: ReaderConfig, message_max_range_m: float | None = None,
                        code_m: float | None = None) -> float:
    """Ranges at or above the returned value (m) are no return: the smallest of
    ``config.no_return_m``, a positive finite message maximum range and a detected code."""
    threshold = config.no_return_m
    for value in (message_max_range_m, code_m):
        if value is not None and np.isfinite(value) and value > 0:
            threshold = min(threshold, value)
    return float(threshold)


def mark_no_return(ranges: np.ndarray, threshold_m: float) -> np.ndarray:
    """A copy of (n,) ``ranges`` with every range ≥ ``threshold_m`` set to +inf (NaN stays
    NaN), so "no return" is distinct from a measurement error downstream."""
    ranges = np.asarray(ranges, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(ranges >= threshold_m, np.inf, ranges)
