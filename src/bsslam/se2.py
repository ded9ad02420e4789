"""Planar pose algebra on (..., 3) arrays (x m, y m, φ rad), vectorised over leading axes.

The one implementation for every layer (readers, filter, metrics); numpy only."""

from __future__ import annotations

import math

import numpy as np

from bsslam.trajectory import wrap_angle


def compose(a: np.ndarray, b: np.ndarray, wrap: bool = True) -> np.ndarray:
    """a ∘ b: pose b, given in the frame of a, expressed in a's parent frame. The heading
    is wrapped to (−π, π] unless ``wrap`` is False (then it is the plain sum a_φ + b_φ,
    e.g. a sensor's heading that beam angles are added to)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    heading = a[..., 2] + b[..., 2]
    return np.stack([a[..., 0] + c * b[..., 0] - s * b[..., 1],
                     a[..., 1] + s * b[..., 0] + c * b[..., 1],
                     wrap_angle(heading) if wrap else heading], axis=-1)


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


def squared_mahalanobis(a: np.ndarray, b: np.ndarray, covariance: np.ndarray) -> float:
    """dᵀ Σ⁻¹ d of d = a − b, two (3,) poses or increments, its heading wrapped to
    [−π, π]: how far apart they are for a difference with ``covariance`` (3, 3), to
    compare with a χ²₃ quantile. Raises ``np.linalg.LinAlgError`` for a singular one."""
    d = np.asarray(a, dtype=float) - b
    d[2] = math.remainder(d[2], 2 * math.pi)
    return float(d @ np.linalg.solve(covariance, d))


def compose_jacobians(pose: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (3×3 each) of ``compose(pose, delta)`` w.r.t. ``pose`` (F_x) and w.r.t.
    ``delta`` (F_u), for one pose and one increment."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    F_x = np.array([[1.0, 0.0, -delta[0] * s - delta[1] * c],
                    [0.0, 1.0, delta[0] * c - delta[1] * s],
                    [0.0, 0.0, 1.0]])
    F_u = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return F_x, F_u


def inverse_with_covariance(a: np.ndarray, cov_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """a⁻¹ and its first-order covariance ``J Σ_a Jᵀ`` for a (3,) with covariance (3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[2]), np.sin(a[2])
    J = np.array([[-c, -s, s * a[0] - c * a[1]],
                  [s, -c, c * a[0] + s * a[1]],
                  [0.0, 0.0, -1.0]])
    cov = J @ cov_a @ J.T
    return inverse(a), 0.5 * (cov + cov.T)


def compose_with_covariance(a: np.ndarray, cov_a: np.ndarray, b: np.ndarray, cov_b: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """a ∘ b and its first-order covariance for independent a (3,) and b (3,) with
    covariances (3, 3) each: ``F_x Σ_a F_xᵀ + F_u Σ_b F_uᵀ``."""
    F_x, F_u = compose_jacobians(a, b)
    cov = F_x @ cov_a @ F_x.T + F_u @ cov_b @ F_u.T
    return compose(a, b), 0.5 * (cov + cov.T)
