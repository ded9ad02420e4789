"""B-spline basis functions and their derivatives by the local Cox–de Boor triangle.

Only the degree + 1 basis functions that are non-zero on a knot span are ever computed
(spec §1, paper (5)), for many parameter values at once (Piegl & Tiller, *The NURBS Book*,
A2.2 for the values, vectorised over the parameters; A2.3 for the derivatives, a compiled
loop over the parameters in :mod:`bsslam.spline.kernels`).

Convention: ``degree`` is the polynomial degree p (order κ = p + 1). Parameters and knots
are in metres of arc length; the k-th derivative is per metreᵏ.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from bsslam.errors import SplineError
from bsslam.spline import kernels


def as_parameters(t: object) -> np.ndarray:
    """Parameters as a float64 (m,) array; a scalar becomes (1,)."""
    arr = np.asarray(t, dtype=float)
    if arr.ndim == 0:
        return arr.reshape(1)
    if arr.ndim != 1:
        raise SplineError(f"parameters must be a scalar or a 1-D array, got shape {arr.shape}")
    return arr


def find_span(knots: np.ndarray, degree: int, t: object) -> np.ndarray:
    """Knot span index of each parameter.

    Args:
        knots: (n_control + degree + 1,) non-decreasing knot vector.
        degree: polynomial degree p.
        t: scalar or (m,) parameters (m).

    Returns:
        (m,) int array ``i`` with ``knots[i] <= t < knots[i+1]`` and
        ``degree <= i <= n_control - 1``. ``t`` at the domain end gets the last non-empty
        span; ``t`` outside the domain (and NaN) gets the span of the nearest domain end.
    """
    knots = np.asarray(knots, dtype=float)
    t = as_parameters(t)
    n_control = knots.shape[0] - degree - 1
    lo, hi = knots[degree], knots[n_control]
    # The first span that starts at the domain start, and the last one that ends at its end:
    # repeated knots make empty spans that must never be chosen.
    first = np.searchsorted(knots, lo, side="right") - 1
    last = np.searchsorted(knots, hi, side="left") - 1
    return np.clip(np.searchsorted(knots, t, side="right") - 1, first, last)


def _basis_values(knots: np.ndarray, degree: int, t: np.ndarray, span: np.ndarray) -> np.ndarray:
    """The degree + 1 non-zero basis functions on each parameter's span, shape (degree+1, m):
    column ``degree`` of Piegl & Tiller's triangle (A2.3), bit for bit, with fewer numpy calls.

    Piegl & Tiller A2.2 with its inner loop over r vectorised: at degree j every new value
    is ``right[r+1]·temp[r] + left[j-r]·temp[r-1]`` with ``temp[r] = N[r] / (right[r+1] +
    left[j-r])`` — the same operations on the same operands as the triangle, so the same
    floating-point results, in about 7 calls per degree instead of 5 per (degree, r).
    """
    p = degree
    m = t.shape[0]
    # knots[span + o] for o = 1-p … p, one gather: left[j-1] = t - knots[span+1-j],
    # right[j-1] = knots[span+j] - t (j = 1 … p)
    near = knots[span[None, :] + np.arange(1 - p, p + 1)[:, None]]     # (2p, m)
    left = t - near[p - 1::-1]                                          # (p, m): left[j-1]
    right = near[p:] - t                                                # (p, m): right[j-1]
    n = np.empty((p + 1, m))
    n[0] = 1.0
    for j in range(1, p + 1):
        # r = 0 … j-1: denominators right[r+1] + left[j-r]
        reversed_left = left[j - 1::-1]             # left[j-r] for r = 0 … j-1
        temp = n[:j] / (right[:j] + reversed_left)
        up = right[:j] * temp                       # right[r+1]·temp[r]
        down = reversed_left * temp                 # left[j-r]·temp[r]: the next r's "saved"
        n[j] = down[j - 1]
        n[1:j] = down[: j - 1] + up[1:]
        n[0] = up[0]
    return n


def basis_functions(
    knots: np.ndarray,
    degree: int,
    t: object,
    nder: int = 0,
    *,
    span: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The degree + 1 non-zero basis functions (and derivatives) at each parameter.

    Args:
        knots: (n_control + degree + 1,) non-decreasing knot vector.
        degree: polynomial degree p (order κ = p + 1).
        t: scalar or (m,) parameters (m). Without ``span`` they are clamped into the
            domain ``[knots[degree], knots[-degree-1]]`` (no extrapolation).
        nder: highest derivative order wanted (≥ 0); orders above ``degree`` are zero.
        span: optional (m,) non-empty knot spans to use instead of :func:`find_span`;
            then ``t`` is not clamped and the polynomial piece of that span is evaluated
            (e.g. the left limit at a knot).

    Returns:
        ``(span, values)``: span (m,) int, values (nder+1, m, degree+1) where
        ``values[k, j, r]`` is the k-th derivative (per mᵏ) of basis function
        ``span[j] - degree + r`` at ``t[j]``.
    """
    if nder < 0:
        raise SplineError(f"nder must be ≥ 0, got {nder}")
    knots = np.asarray(knots, dtype=float)
    t = as_parameters(t)
    if span is None:
        span = find_span(knots, degree, t)
        t = np.clip(t, knots[degree], knots[-degree - 1])
    else:
        span = np.asarray(span, dtype=np.intp).reshape(t.shape)
    if nder == 0:  # the values only (what fits evaluate): no triangle kept
        return span, np.ascontiguousarray(_basis_values(knots, degree, t, span).T)[None]
    return span, kernels.basis_derivatives(knots, degree, t, span, nder)


def collocation_matrix(
    knots: np.ndarray,
    degree: int,
    t: object,
    nder: int = 0,
    sparse: bool = False,
) -> np.ndarray | scipy.sparse.csr_matrix:
    """Collocation matrix ``B[j, i] = β_i⁽ⁿᵈᵉʳ⁾(t_j)`` (paper (8)).

    Args:
        knots: (n_control + degree + 1,) knot vector.
        degree: polynomial degree p.
        t: scalar or (m,) parameters (m), clamped into the domain.
        nder: derivative order of the basis functions in the matrix (0 = values).
        sparse: return a scipy.sparse CSR matrix (degree + 1 stored entries a row).

    Returns:
        (m, n_control) dense float64 array, or CSR matrix of that shape.
    """
    knots = np.asarray(knots, dtype=float)
    n_control = knots.shape[0] - degree - 1
    span, values = basis_functions(knots, degree, t, nder)
    m = span.shape[0]
    cols = span[:, None] - degree + np.arange(degree + 1)
    vals = values[nder]
    if sparse:
        indptr = np.arange(0, m * (degree + 1) + 1, degree + 1)
        return scipy.sparse.csr_matrix((vals.ravel(), cols.ravel(), indptr), shape=(m, n_control))
    out = np.zeros((m, n_control))
    np.put_along_axis(out, cols, vals, axis=1)
    return out
