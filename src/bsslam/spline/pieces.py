"""A spline curve as one polynomial per knot span, for fast repeated evaluation.

The de Boor triangle costs O(degree²) array operations per evaluation; once a curve is
fixed, converting it to per-span power-basis coefficients makes every later evaluation a
Horner loop of ``degree`` fused multiply-adds. Closest-point and ray-intersection searches
evaluate the same curve many times, so they work on this form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bsslam.spline.basis import as_parameters, basis_functions


@dataclass(frozen=True, eq=False)
class PolynomialPieces:
    """A 2-D spline curve as a polynomial per non-empty knot span.

    Attributes:
        breaks: (S+1,) the distinct knot values in the domain, ``lo = b_0 < … < b_S = hi`` (m).
        coeffs: (S, degree+1, 2) Taylor coefficients at the start of each piece:
            ``coeffs[s, k] = s⁽ᵏ⁾(b_s) / k!``, so on piece s the curve is
            ``Σ_k coeffs[s, k] · (t − b_s)ᵏ`` (m / mᵏ).
        spans: (S,) knot span index of each piece; its control points are
            ``spans[s] − degree … spans[s]``.
        degree: polynomial degree p.
    """

    breaks: np.ndarray
    coeffs: np.ndarray
    spans: np.ndarray
    degree: int

    @property
    def widths(self) -> np.ndarray:
        """(S,) parameter length of each piece (m)."""
        return np.diff(self.breaks)

    def subdivide(self, counts: object) -> np.ndarray:
        """Parameters cutting every piece into equal parts, ends included.

        Args:
            counts: parts per piece, an int or (S,) ints ≥ 1.

        Returns:
            (Σ counts + 1,) increasing parameters (m); every break is among them.
        """
        widths = self.widths
        counts = np.broadcast_to(np.asarray(counts, dtype=np.intp), widths.shape)
        piece = np.repeat(np.arange(widths.shape[0]), counts)
        part = np.arange(piece.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)
        t = self.breaks[piece] + widths[piece] * (part / counts[piece])
        return np.append(t, self.breaks[-1])

    def locate(self, t: object) -> tuple[np.ndarray, np.ndarray]:
        """Piece index (m,) and local parameter ``u = t − b_piece`` (m,) of parameters ``t``.

        ``t`` is clamped into the domain first; the domain end belongs to the last piece.
        """
        t = np.clip(as_parameters(t), self.breaks[0], self.breaks[-1])
        piece = np.searchsorted(self.breaks, t, side="right") - 1
        np.clip(piece, 0, self.breaks.shape[0] - 2, out=piece)
        return piece, t - self.breaks[piece]

    def evaluate_local(self, piece: np.ndarray, u: np.ndarray, nder: int = 0) -> np.ndarray:
        """Curve and derivatives 0 … nder on given pieces at local parameters.

        Args:
            piece: (m,) piece indices.
            u: (m,) local parameters (m); not clamped, so a piece can be extrapolated.
            nder: highest derivative order.

        Returns:
            (nder+1, m, 2) array (m / mᵏ).
        """
        return horner_with_derivatives(self.coeffs[piece], u, nder)

    def evaluate(self, t: object, nder: int = 0) -> np.ndarray:
        """Curve and derivatives 0 … nder at parameters ``t`` (clamped), (nder+1, m, 2)."""
        piece, u = self.locate(t)
        return self.evaluate_local(piece, u, nder)


def horner_with_derivatives(coeffs: np.ndarray, u: np.ndarray, nder: int) -> np.ndarray:
    """Evaluate polynomials and their derivatives by Horner's scheme.

    Args:
        coeffs: (m, degree+1, ...) ascending power coefficients, one polynomial per row
            (trailing axes, e.g. x/y, are carried along).
        u: (m,) evaluation points.
        nder: highest derivative order.

    Returns:
        (nder+1, m, ...) values; entry k is the k-th derivative.
    """
    degree = coeffs.shape[1] - 1
    uu = u.reshape(u.shape + (1,) * (coeffs.ndim - 2))
    if nder == 0:
        # values only (the common call): the same operations without the zeroed buffer
        v = coeffs[:, degree].copy() if degree == 0 else coeffs[:, degree]
        for i in range(degree - 1, -1, -1):
            v = v * uu
            v += coeffs[:, i]
        return v[None]
    out = np.zeros((nder + 1,) + coeffs.shape[:1] + coeffs.shape[2:])
    out[0] = coeffs[:, degree]
    # Horner on the value and, interleaved, on the derivatives (Knuth's scheme): after the
    # loop out[k] holds the k-th derivative divided by k!.
    for i in range(degree - 1, -1, -1):
        for k in range(min(nder, degree - i), 0, -1):
            out[k] = out[k] * uu + out[k - 1]
        out[0] = out[0] * uu + coeffs[:, i]
    for k in range(2, nder + 1):
        out[k] *= math.factorial(k)
    return out


def horner_rows(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Polynomials c (degree+1, B, ...) in ascending powers at x (B, ...) -> (B, ...), one
    coefficient row per power: each Horner step works on whole contiguous rows."""
    if c.shape[0] == 1:
        return np.broadcast_to(c[0], np.broadcast_shapes(c.shape[1:], x.shape)).copy()
    v = c[-1] * x
    v += c[-2]
    for i in range(c.shape[0] - 3, -1, -1):
        v *= x
        v += c[i]
    return v


def polynomial_pieces(control_points: np.ndarray, knots: np.ndarray, degree: int) -> PolynomialPieces:
    """Convert a B-spline curve to :class:`PolynomialPieces` (exact up to rounding).

    Args:
        control_points: (n_control, 2) control points (m).
        knots: (n_control + degree + 1,) valid knot vector.
        degree: polynomial degree p.
    """
    n_control = control_points.shape[0]
    breaks = np.unique(knots[degree : n_control + 1])
    starts = breaks[:-1]
    # At each piece's first break, find_span picks the non-empty span that starts there.
    span, values = basis_functions(knots, degree, starts, degree)
    local = control_points[span[:, None] - degree + np.arange(degree + 1)]  # (S, p+1, 2)
    derivs = np.einsum("kmr,mrd->mkd", values, local)  # (S, p+1, 2)
    factorials = np.array([math.factorial(k) for k in range(degree + 1)], dtype=float)
    coeffs = derivs / factorials[None, :, None]
    return PolynomialPieces(breaks=breaks, coeffs=coeffs, spans=span, degree=degree)
