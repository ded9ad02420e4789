"""Knot vectors: building clamped and uniform ones, and reading their domain.

A spline of degree p (order κ = p + 1) with ``n_control`` control points has
``n_control + p + 1`` knots ξ_0 … ξ_{n+κ}; its valid parameter domain is
``[ξ_p, ξ_{n_control}]`` (spec §0). Parameters are arc lengths, so knot values are metres.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from bsslam.errors import SplineError

# Tolerance on length/spacing before taking the ceiling: a length that is an exact multiple
# of the spacing up to rounding must not gain an almost empty extra span.
_SPAN_ROUNDING = 1e-9


def check_degree(degree: object) -> int:
    """Return ``degree`` as an int, or raise SplineError unless it is an integer ≥ 1."""
    if isinstance(degree, bool) or not isinstance(degree, numbers.Integral) or degree < 1:
        raise SplineError(f"degree must be an integer ≥ 1, got {degree!r}")
    return int(degree)


def span_count(length: float, spacing_m: float) -> int:
    """Number of spans that keeps consecutive knots at most about ``spacing_m`` apart.

    ``max(1, ceil(length / spacing_m))``, where a ratio within 1e-9 above an integer
    rounds down (so 3 m at 1 m spacing is 3 spans, not 4).
    """
    if not (math.isfinite(length) and length > 0):
        raise SplineError(f"length must be finite and > 0, got {length!r}")
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise SplineError(f"knot spacing must be finite and > 0, got {spacing_m!r} m")
    return max(1, math.ceil(length / spacing_m - _SPAN_ROUNDING))


def clamped_knots_with_spans(length: float, spans: int, degree: int, start: float = 0.0) -> np.ndarray:
    """Clamped knot vector on ``[start, start + length]`` with exactly ``spans`` equal spans.

    Returns:
        (spans + 2·degree + 1,) knots: ``start`` and ``start + length`` each repeated
        degree + 1 times around ``spans - 1`` uniform interior knots.
    """
    degree = check_degree(degree)
    if not (math.isfinite(length) and length > 0):
        raise SplineError(f"length must be finite and > 0, got {length!r}")
    if not math.isfinite(start):
        raise SplineError(f"start must be finite, got {start!r}")
    if isinstance(spans, bool) or not isinstance(spans, numbers.Integral) or spans < 1:
        raise SplineError(f"spans must be an integer ≥ 1, got {spans!r}")
    end = start + length
    interior = start + length * (np.arange(1, spans) / spans)
    return np.concatenate([np.full(degree + 1, float(start)), interior, np.full(degree + 1, float(end))])


def clamped_knots(length: float, spacing_m: float, degree: int, start: float = 0.0) -> np.ndarray:
    """Clamped knot vector on ``[start, start + length]`` (spec §2).

    Args:
        length: extent of the parameter domain (m, arc length), > 0.
        spacing_m: target knot spacing ρ (m), > 0.
        degree: polynomial degree p (order κ = p + 1), ≥ 1.
        start: first knot value (m).

    Returns:
        (spans + 2·degree + 1,) knots with ``spans = span_count(length, spacing_m)``:
        first and last value repeated degree + 1 times, interior knots uniform.
        The spline has ``spans + degree`` control points.
    """
    return clamped_knots_with_spans(length, span_count(length, spacing_m), degree, start)


def uniform_knots(n_control: int, degree: int, spacing: float = 1.0, start: float = 0.0) -> np.ndarray:
    """Unclamped uniform knot vector ``start + spacing · [0, 1, …, n_control + degree]``.

    Args:
        n_control: number of control points, ≥ degree + 1.
        degree: polynomial degree p, ≥ 1.
        spacing: distance between consecutive knots (m), > 0.
        start: first knot value (m).

    Returns:
        (n_control + degree + 1,) knots; the domain is ``[start + degree·spacing,
        start + n_control·spacing]``.
    """
    degree = check_degree(degree)
    if isinstance(n_control, bool) or not isinstance(n_control, numbers.Integral) or n_control < degree + 1:
        raise SplineError(f"n_control must be an integer ≥ degree + 1 = {degree + 1}, got {n_control!r}")
    if not (math.isfinite(spacing) and spacing > 0):
        raise SplineError(f"spacing must be finite and > 0, got {spacing!r}")
    if not math.isfinite(start):
        raise SplineError(f"start must be finite, got {start!r}")
    return start + spacing * np.arange(n_control + degree + 1, dtype=float)


def n_control_points(knots: np.ndarray, degree: int) -> int:
    """Number of control points that a knot vector of a degree-``degree`` spline carries."""
    return len(knots) - degree - 1


def knot_domain(knots: np.ndarray, degree: int) -> tuple[float, float]:
    """Valid parameter domain ``(knots[degree], knots[-degree-1])`` (m)."""
    return float(knots[degree]), float(knots[-degree - 1])


def check_knots(knots: object, degree: int) -> np.ndarray:
    """Validate a knot vector for a degree-``degree`` spline and return it as float64.

    Raises SplineError with the specific problem: not 1-D, non-finite, decreasing, too
    short for one span, an empty domain, or an interior knot repeated more than
    degree + 1 times.
    """
    degree = check_degree(degree)
    k = np.asarray(knots, dtype=float)
    if k.ndim != 1:
        raise SplineError(f"knots must be a 1-D array, got shape {k.shape}")
    if k.shape[0] < 2 * (degree + 1):
        raise SplineError(
            f"a degree-{degree} spline needs at least {2 * (degree + 1)} knots, got {k.shape[0]}")
    if not np.all(np.isfinite(k)):
        raise SplineError("knots must be finite")
    steps = np.diff(k)
    if np.any(steps < 0):
        raise SplineError(f"knots must be non-decreasing; knot {int(np.argmax(steps < 0)) + 1} decreases")
    lo, hi = knot_domain(k, degree)
    if not lo < hi:
        raise SplineError(f"empty parameter domain [{lo}, {hi}]")
    # A run of equal knots longer than degree + 1 makes a basis function identically zero.
    run_starts = np.flatnonzero(np.concatenate([[True], steps > 0]))
    runs = np.diff(np.concatenate([run_starts, [k.shape[0]]]))
    if np.any(runs > degree + 1):
        worst = int(np.argmax(runs))
        raise SplineError(
            f"knot {k[run_starts[worst]]} is repeated {runs[worst]} times; at most degree + 1 = {degree + 1}")
    return k
