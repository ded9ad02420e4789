"""Hypothesis strategies and small builders shared by the spline tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from bsslam.spline import BSplineCurve, fit_curve
from bsslam.spline.batch import CurveBatch, curve_table

_GAP = st.floats(0.05, 3.0)


@st.composite
def knot_vectors(draw, clamped: bool | None = None, min_degree: int = 1, max_degree: int = 4):
    """(degree, knots): random valid knot vectors of degree 1…4.

    Distinct break points are at least 0.05 m apart, interior knots are repeated 1…degree
    times, and unclamped ends get degree extra knots (possibly repeated) outside the domain.
    """
    degree = draw(st.integers(min_degree, max_degree))
    n_spans = draw(st.integers(1, 6))
    start = draw(st.floats(-10.0, 10.0))
    breaks = start + np.concatenate([[0.0], np.cumsum(draw(st.lists(_GAP, min_size=n_spans, max_size=n_spans)))])
    mults = draw(st.lists(st.integers(1, degree), min_size=n_spans - 1, max_size=n_spans - 1))
    interior = np.repeat(breaks[1:-1], mults)
    if clamped is None:
        clamped = draw(st.booleans())
    if clamped:
        left = np.full(degree, breaks[0])
        right = np.full(degree, breaks[-1])
    else:
        outer = st.lists(st.one_of(st.just(0.0), _GAP), min_size=degree, max_size=degree)
        left = breaks[0] - np.cumsum(draw(outer))[::-1]
        right = breaks[-1] + np.cumsum(draw(outer))
    knots = np.concatenate([left, [breaks[0]], interior, [breaks[-1]], right])
    return degree, knots


@st.composite
def curves(draw, clamped: bool | None = None, min_degree: int = 1, max_degree: int = 4):
    """Random BSplineCurve with control points in a 10 m box."""
    degree, knots = draw(knot_vectors(clamped=clamped, min_degree=min_degree, max_degree=max_degree))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    control = rng.uniform(-5.0, 5.0, size=(len(knots) - degree - 1, 2))
    return BSplineCurve(control, knots, degree)


def domain_samples(knots: np.ndarray, degree: int, rng: np.random.Generator, m: int = 40) -> np.ndarray:
    """Random parameters in the domain plus its ends and every knot inside it."""
    lo, hi = knots[degree], knots[-degree - 1]
    inside = knots[(knots >= lo) & (knots <= hi)]
    return np.concatenate([rng.uniform(lo, hi, m), [lo, hi], inside])


def wavy_wall(n: int, rng: np.random.Generator, noise_m: float = 0.0) -> np.ndarray:
    """(n, 2) ordered points along a gently curved 8 m wall, optional Gaussian noise."""
    x = np.linspace(0.0, 8.0, n)
    pts = np.column_stack([x, 1.0 + 0.4 * np.sin(0.9 * x)])
    return pts + rng.normal(0.0, noise_m, pts.shape) if noise_m else pts


@st.composite
def wall_curves(draw, min_degree: int = 1, max_degree: int = 4):
    """Curves like the filter's map features: a fitted, wobbly circular arc.

    Radius 2…8 m, opening 0.5…5 rad (so U shapes that a ray can cross twice occur),
    knot spacing 0.5…2 m, degree 1…4.
    """
    degree = draw(st.integers(min_degree, max_degree))
    radius = draw(st.floats(2.0, 8.0))
    opening = draw(st.floats(0.5, 5.0))
    wobble = draw(st.floats(0.0, 0.1))
    spacing = draw(st.floats(0.5, 2.0))
    start = draw(st.floats(-np.pi, np.pi))
    phi = start + np.linspace(0.0, opening, 400)
    rho = radius * (1.0 + wobble * np.sin(5.0 * phi))
    center = np.array(draw(st.tuples(st.floats(-3, 3), st.floats(-3, 3))))
    return fit_curve(center + np.column_stack([rho * np.cos(phi), rho * np.sin(phi)]), degree, spacing).curve


def dense_samples(curve: BSplineCurve, n: int = 200_001) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force reference: (n,) parameters and (n, 2) points evenly spaced in the domain."""
    t = np.linspace(*curve.domain, n)
    return t, curve.evaluate(t)


def corners(curve: BSplineCurve) -> np.ndarray:
    """Interior knots repeated degree times or more: where the curve is only C0 and its
    tangent may jump (every interior knot of a polyline)."""
    lo, hi = curve.domain
    knots, counts = np.unique(curve.knots[(curve.knots > lo) & (curve.knots < hi)], return_counts=True)
    return knots[counts >= curve.degree]


def corner_between(curve: BSplineCurve, a: np.ndarray, b: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    """Whether a corner lies within ``tol`` of the parameter interval between a and b (m,),
    elementwise (NaN ends count as no interval). Newton from a start on one side of a
    corner may stop on either side, at a different local solution or a different best
    iterate, so searches from a start and from a global sampling can disagree there."""
    c = corners(curve)
    lo, hi = np.fmin(a, b)[:, None], np.fmax(a, b)[:, None]
    return ((c[None, :] >= lo - tol) & (c[None, :] <= hi + tol)).any(axis=1)


def batch_of(cs: list[BSplineCurve]) -> CurveBatch:
    """The curves as one :class:`CurveBatch` (curve c of the batch is ``cs[c]``)."""
    table = curve_table([c.knots for c in cs], [c.degree for c in cs])
    return table.with_control_points(np.vstack([c.control_points for c in cs]))


def params_in(cs: list[BSplineCurve], which: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniformly drawn parameter in the domain of curve ``which[j]``, for every j."""
    return np.array([rng.uniform(*cs[c].domain) for c in which])
