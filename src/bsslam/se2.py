"""Planar pose algebra on (..., 3) arrays (x m, y m, φ rad), vectorised over leading axes.

The one implementation for every layer (readers, filter, metrics); numpy only."""

from __future__ import annotations

import numpy as np

from bsslam.trajectory import wrap_angle


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ∘ b: pose b, given in the frame of a, expressed in a's parent frame."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: np.ndarray) -> np.ndarray:
    """a⁻¹, so that compose(a, inverse(a)) is the identity."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack([-c * a[..., 0] - s * a[..., 1],
                     s * a[..., 0] - c * a[..., 1],
                     wrap_angle(-a[..., 2])], axis=-1)


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a⁻¹ ∘ b: pose b seen from pose a (the motion from a to b in a's frame)."""
    return compose(inverse(a), b)
