"""Growing a map spline past one of its ends (spec §8.2, paper (47)–(55)).

First the end is *unclamped* (Piegl & Tiller, *The NURBS Book*, A12.1): its repeated knots
are replaced by new ones beyond the domain and the last degree − 1 control points change by
a linear map T so that the curve on the old domain stays exactly the same. Then new spans
and control points are appended, and only the new control points are fitted to the new
data, the old ones being held: ``x_new = G (D − B_old T x_old)``. The whole result is one
constant linear map Ψ of ``[x_old; D]``, which the filter uses to grow the covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import FitError, SplineError
from bsslam.spline import extend_kernels
from bsslam.spline.curve import BSplineCurve, as_points
from bsslam.spline.fit import chord_length_parameters, least_squares_operator
from bsslam.spline.knots import check_degree, check_knots, span_count

_SIDES = ("left", "right")


def _check_side(side: str) -> None:
    if side not in _SIDES:
        raise SplineError(f"side must be 'left' or 'right', got {side!r}")


def unclamp(
    knots: object, control_points: object, degree: int, side: str, new_knots: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unclamp one end of a clamped spline without changing it on its domain (spec §8.2).

    Args:
        knots: (n_control + degree + 1,) knot vector, clamped (end knot repeated
            degree + 1 times) at ``side``.
        control_points: (n_control, 2) control points (m).
        degree: polynomial degree p.
        side: ``'right'`` or ``'left'``.
        new_knots: (degree,) non-decreasing knots that replace the repeated ones: for
            ``'right'`` the new ``knots[n_control + 1 …]``, all > the domain end; for
            ``'left'`` the new ``knots[0 … degree − 1]``, all < the domain start (m).

    Returns:
        ``(knots', control_points', T)``: knots' (same length), control_points'
        (n_control, 2) and T (n_control, n_control) with ``control_points' = T @
        control_points``. T depends on the knots only; for degree 1 it is the identity.
    """
    p = check_degree(degree)
    _check_side(side)
    u = np.array(check_knots(knots, p), dtype=float)
    cp = as_points(control_points, "control_points")
    n = cp.shape[0] - 1  # index of the last control point, as in the book
    if u.shape[0] != n + p + 2:
        raise SplineError(f"{u.shape[0]} knots do not fit {n + 1} control points of degree {p}")
    new = np.asarray(new_knots, dtype=float)
    if new.shape != (p,) or not np.all(np.isfinite(new)) or np.any(np.diff(new) < 0):
        raise SplineError(f"new_knots must be {p} finite non-decreasing values, got {new_knots!r}")
    right = side == "right"
    if right:
        end = u[n + 1]
        if np.any(u[n + 1 :] != end):
            raise SplineError("the right end is not clamped (last knot not repeated degree + 1 times)")
        if not new[0] > end:
            raise SplineError(f"new right knots must lie beyond the domain end {end}, got {new[0]}")
    else:
        start = u[p]
        if np.any(u[: p + 1] != start):
            raise SplineError("the left end is not clamped (first knot not repeated degree + 1 times)")
        if not new[-1] < start:
            raise SplineError(f"new left knots must lie before the domain start {start}, got {new[-1]}")
    transform = extend_kernels.unclamp_transform(u, p, right, new)
    return u, transform @ cp, transform


@dataclass(frozen=True, eq=False)
class Extension:
    """A spline grown past one end.

    Attributes:
        curve: the extended curve, clamped at its new end.
        psi: (n_control + n_added, n_control + k) Ψ: the new control points are
            ``psi @ [old control points; new data points]`` (x and y alike). Columns: the
            old control points, then the k data points; rows in the order of
            ``curve.control_points`` (right: [old; new], left: [new; old]).
        n_added: number of control points (and spans) added.
        side: ``'right'`` or ``'left'``.
        T: (n_control, n_control) the unclamping map of the old control points.
    """

    curve: BSplineCurve
    psi: np.ndarray
    n_added: int
    side: str
    T: np.ndarray


def continuation_parameters(curve: BSplineCurve, side: str, points: object) -> tuple[np.ndarray, np.ndarray]:
    """Where new data points (k, 2), in order along the wall from the curve's ``side`` end
    outwards for ``'right'`` and towards it for ``'left'`` (a scan's order either way),
    continue the curve: ``(beyond (k,) bool, params (b,))`` — the points past the end along
    the end's outward tangent, and for those the parameter continuing the curve's chord
    length: the end's parameter plus (right) or minus (left) the first one's distance past
    the end along that tangent and then the chord lengths between consecutive points (m).

    The points' own geometry places them, so an error in where a scan was matched to the
    curve (the association's interval ends, taken at the predicted pose) does not shift the
    new data along the curve: shifted, a wall that bends past the end is fitted with its
    bend in the wrong place, and every run that extends there errs alike (simulated double
    loops with extension, 30 runs: rounded-room's shared bias 3.9, 3.5, 3.4 standard errors
    → 1.8, 1.2, 1.5).
    """
    _check_side(side)
    pts = as_points(points)
    right = side == "right"
    lo, hi = curve.domain
    at = np.array([hi if right else lo])
    end = curve.evaluate(at)[0]
    tangent = curve.evaluate(at, der=1)[0]
    tangent = tangent / max(float(np.hypot(tangent[0], tangent[1])), 1e-12) * (1.0 if right else -1.0)
    beyond = (pts - end) @ tangent > 1e-9          # a nanometre: parameters strictly past the end
    out = pts[beyond] if right else pts[beyond][::-1]             # from the end outwards
    if out.shape[0] == 0:
        return beyond, np.empty(0)
    dist = chord_length_parameters(out, float((out[0] - end) @ tangent))
    return beyond, (hi + dist if right else (lo - dist)[::-1])


def extend_curve(curve: BSplineCurve, side: str, points: object, params: object, spacing_m: float, *,
                 max_noise_gain: float | None = None) -> Extension:
    """Append control points fitted to new data beyond one end (spec §8.2).

    Args:
        curve: the map spline, clamped at ``side``.
        side: ``'right'`` (past the domain end) or ``'left'`` (before the start).
        points: (k, 2) new data points (m).
        params: (k,) their parameters, continuing the curve's arc length: all > the
            domain end for ``'right'``, all < the domain start for ``'left'`` (m).
        spacing_m: knot spacing ρ (m) for the new spans.
        max_noise_gain: as in :func:`fit_curve`, for the least-squares map of the new points.

    Returns:
        Extension. The new domain end is the outermost parameter; the number of new
        spans is ``ceil(extent / spacing_m)`` (≥ 1), reduced while Schoenberg–Whitney fails
        for the new basis functions. The curve on the old domain is unchanged.

    Raises:
        FitError: no number of new spans gives a well-posed fit.
        SplineError: malformed input (shapes, side, parameters not beyond the end).
    """
    _check_side(side)
    p = curve.degree
    pts = as_points(points)
    t = np.asarray(params, dtype=float)
    k = pts.shape[0]
    if t.shape != (k,) or not np.all(np.isfinite(t)):
        raise SplineError(f"params must be {k} finite values, got shape {t.shape}")
    if k == 0:
        raise FitError("no data points to extend the curve with")
    lo, hi = curve.domain
    right = side == "right"
    distinct = np.unique(t)
    if right and not distinct[0] > hi:
        raise SplineError(f"right extension parameters must all be > the domain end {hi}")
    if not right and not distinct[-1] < lo:
        raise SplineError(f"left extension parameters must all be < the domain start {lo}")
    end = float(distinct[-1] if right else distinct[0])
    extent = end - hi if right else lo - end
    n_old = curve.n_control
    most = min(span_count(extent, spacing_m), distinct.shape[0])
    below = most
    while True:
        status, spans, knots, transform, colloc_new, colloc_old = extend_kernels.extension_setup(
            curve.knots, p, right, end, t, distinct, below)
        if status == extend_kernels.BAD_UNCLAMP:   # unclamp names what is wrong
            new_knots = knots[n_old + 1 : n_old + p + 1] if right else knots[spans : spans + p]
            unclamp(curve.knots, curve.control_points, p, side, new_knots)
        if status != extend_kernels.READY:
            raise FitError(
                f"no extension with 1..{max(most, 1)} new spans fits these {k} points "
                "(Schoenberg–Whitney fails for the new control points)")
        g = least_squares_operator(colloc_new, max_noise_gain)
        if g is not None:
            break
        below = spans - 1
    new_rows = slice(n_old, n_old + spans) if right else slice(0, spans)
    old_rows = slice(0, n_old) if right else slice(spans, spans + n_old)
    psi = np.zeros((n_old + spans, n_old + k))
    psi[old_rows, :n_old] = transform
    psi[new_rows, :n_old] = -g @ colloc_old @ transform
    psi[new_rows, n_old:] = g
    control = psi @ np.concatenate([curve.control_points, pts])
    return Extension(BSplineCurve.unchecked(control, knots, p), psi, spans, side, transform)


def runs_outward(old: BSplineCurve, new: BSplineCurve, side: str, samples: int = 16) -> bool:
    """Whether the extended curve ``new`` runs outward all along the stretch it adds to
    ``old`` on ``side``: its tangent keeps a positive component along that stretch's chord.

    A fit that overshoots the new data's end and folds back passes the distance check (the
    fold lies along the wall) but leaves an end pointing back into the wall. The next
    scan's points beyond it then find their closest map point at the fold, a metre from
    the end they continue, the match fails, and the wall is mapped a second time over
    itself (the simulated long corridor, seed 0: an extension at scan 34 overshot to
    54.75 m and came back to 54.59; from scan 37 a new spline lay 4 m over it). The
    filter refuses such an extension (:meth:`bsslam.slam.filter.SplineSLAM._extend_feature`)."""
    _check_side(side)
    lo, hi = old.domain
    new_lo, new_hi = new.domain
    a, b = (hi, new_hi) if side == "right" else (new_lo, lo)
    ends = new.evaluate(np.array([a, b]))
    chord = ends[1] - ends[0]
    tangents = new.evaluate(np.linspace(a, b, samples), der=1)
    return bool(np.all(tangents @ chord > 0.0))
