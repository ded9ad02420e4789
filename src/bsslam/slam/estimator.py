"""The estimator: the joint Gaussian over the robot pose and the map's control points.

The filter (:class:`~bsslam.slam.filter.SplineSLAM`) talks to it through :class:`Estimator`
only: predict with an odometry increment, read marginal blocks, update with a stacked
linearisation ``(cols, H, residual, R)``, append new control points with their
cross-covariance, transform and remove entries. :class:`CompressedEKF` is the library's
implementation (the deferred, compressed update of :class:`~bsslam.slam.state.JointState`);
the tests drive the same scenarios through a dense textbook EKF
(``tests/slam/dense_ekf.py``) that implements the same protocol.

The iterated update reads the prior covariance on a working set of rows several times (a
gain, gates, another gain): :meth:`Estimator.window` serves those reads, and its gains are
what :meth:`Estimator.update` finally applies, so the last iteration's gain is not formed
twice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bsslam.slam.ekf import CovarianceColumns, StackedGain
from bsslam.slam.motion import predict_state
from bsslam.slam.state import JointState
from bsslam.trajectory import wrap_angle

#: Measurement noise: a scalar r (R = r I), the (m,) diagonal of R, or the (m, m) R.
Noise = float | np.ndarray


@dataclass(frozen=True)
class Innovation:
    """What an update did: ``nis`` = ν S⁻¹ ν (χ² with m dof) and ``variances`` (m,), the
    diagonal of S = H P Hᵀ + R (m²)."""

    nis: float
    variances: np.ndarray


class Gain(Protocol):
    """S = H P Hᵀ + R factorised once for one linearisation on a window's rows."""

    S_diag: np.ndarray

    def correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(P Hᵀ S⁻¹ ν on the window's rows (w,), ν S⁻¹ ν)."""

    def posterior_variances(self, cols: np.ndarray, H: np.ndarray, R: Noise) -> np.ndarray:
        """(m,) H P⁺ Hᵀ + R of other rows H (m, c) on ``cols`` under this gain's posterior."""

    def pose_variances(self, prior: np.ndarray) -> np.ndarray:
        """(3,) posterior pose variances under this gain, from the prior ones (3,)."""

    def posterior_block(self) -> np.ndarray:
        """(w, w) the posterior covariance under this gain on the window's rows."""


class CovarianceWindow(Protocol):
    """The prior covariance on working rows (the pose first), read for repeated gains."""

    rows: np.ndarray

    def innovation_variances(self, cols: np.ndarray, H: np.ndarray, R: Noise) -> np.ndarray:
        """(m,) the diagonal of H P Hᵀ + R for H (m, c) on ``cols``."""

    def gain(self, cols: np.ndarray, H: np.ndarray, R: Noise) -> Gain:
        """The gain of H (m, c) on ``cols`` (within ``rows``) with noise R."""


class Estimator(Protocol):
    """The joint Gaussian N(x, P) over the pose x[0:3] (x m, y m, φ rad) and the map's
    control-point coordinates x[3:] (m).

    Attributes:
        x: (n,) the mean (a live view: never keep it across :meth:`append`).
        P: (n, n) the whole covariance (may be costly: for tests and final maps).
        size: n.
        pose: (3,) the pose mean (a view); pose_covariance: (3, 3) a new array.
    """

    x: np.ndarray
    P: np.ndarray
    size: int
    pose: np.ndarray
    pose_covariance: np.ndarray
    nbytes: int     # bytes of its live arrays

    def limit_memory(self, max_bytes: int | None) -> None:
        """Growth of the state past ``max_bytes`` of live arrays raises
        :class:`~bsslam.errors.MemoryBudgetError` before allocating (None: no limit)."""

    def predict(self, delta: np.ndarray, Q: np.ndarray) -> None:
        """The pose moves by the robot-frame increment ``delta`` (3,) with covariance Q (3, 3)."""

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(r, c) the marginal block P[rows][:, cols]."""

    def diagonal(self, rows: np.ndarray) -> np.ndarray:
        """(r,) P[rows, rows]."""

    def marginal(self, idx: np.ndarray) -> np.ndarray:
        """(k, k) P[idx][:, idx] as a pure read: the estimator's later arithmetic stays bit
        for bit what it would have been (a map read in the middle of a run)."""

    def window(self, rows: np.ndarray | None = None) -> CovarianceWindow:
        """The prior on working ``rows`` (sorted, the pose first; all when None)."""

    def constrain(self, cols: np.ndarray, H: np.ndarray, x: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """``(cols', H')``: the Jacobian this estimator linearises with, from the model's H
        (m, c) on ``cols`` linearised at ``x`` (the mean when None): H itself for the EKF,
        its projection for the observability-constrained EKF (:mod:`bsslam.slam.oc_ekf`),
        H in the invariant error at the mean for the invariant EKF
        (:mod:`bsslam.slam.invariant_ekf`, which may add the heading's column). The filter
        gates, iterates and updates with it, and reads the variance of other functions of
        the state (a spline's bend) through it."""

    def error_curvature(self, index: np.ndarray, G: np.ndarray, x: np.ndarray | None = None) -> np.ndarray | None:
        """(m, L, L) what this estimator's error coordinates add to the Hessians of m
        functions of the state, each of its own variables ``index`` (m, L) (state indices,
        −1 for none), given their gradients G (m, L) there at ``x`` (the mean when None): the state's own
        second derivatives along the error coordinates, weighted by G, written on x − x̂.
        None for the EKF and the OC-EKF, whose error x − x̂ is linear; the invariant EKF's
        error rotates every position (:meth:`InvariantEKF.error_curvature`)."""

    def anchor(self, idx_x: np.ndarray, idx_y: np.ndarray) -> None:
        """A spline was refitted (extended): the entries ``idx_x``, ``idx_y`` (paired x and y
        of its control points) are linearised at their current estimate from now on (the
        OC-EKF's unobservable directions; nothing for the EKF)."""

    def update(self, cols: np.ndarray, H: np.ndarray, residual: np.ndarray, R: Noise,
               gain: Gain | None = None) -> Innovation:
        """x ← x + K ν, P ← P − K H P for H (m, c) on ``cols`` and ν = ``residual`` (m,);
        ``gain``: the window gain of this (cols, H, R), formed already. The heading is wrapped."""

    def append(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """New entries v = J x[cols] + w (k,), w ~ N(0, noise) independent of the state;
        ``mean`` (k,) their values: k/2 control points, their x coordinates first, then
        their y coordinates in the same order. Returns their (k,) state indices."""

    def transform(self, idx: np.ndarray, T: np.ndarray) -> None:
        """x[idx] ← T x[idx], P ← A P Aᵀ (A the identity with T on the map block ``idx``)."""

    def remove(self, indices: np.ndarray) -> np.ndarray:
        """Delete map entries; returns the (n_old,) map old index → new (−1 removed)."""


class CompressedEKF:
    """The EKF on a :class:`JointState`: prediction on the pose rows only, the update
    deferred and compressed, new control points appended as eager entries (see
    :mod:`bsslam.slam.state`). Implements :class:`Estimator`.

    Args:
        pose: (3,) initial pose; pose_covariance: (3, 3) its covariance.
    """

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray):
        self.joint = JointState(pose, pose_covariance)

    @property
    def x(self) -> np.ndarray:
        return self.joint.x

    @property
    def P(self) -> np.ndarray:
        """(n, n) the whole covariance, every pending update folded in (O(n²·a))."""
        return self.joint.P

    @property
    def size(self) -> int:
        return self.joint.size

    @property
    def nbytes(self) -> int:
        return self.joint.nbytes

    def limit_memory(self, max_bytes: int | None) -> None:
        self.joint.max_bytes = max_bytes

    @property
    def pose(self) -> np.ndarray:
        return self.joint.pose

    @property
    def pose_covariance(self) -> np.ndarray:
        return self.joint.pose_covariance

    def predict(self, delta: np.ndarray, Q: np.ndarray) -> None:
        predict_state(self.joint, delta, Q)

    def move_pose(self, pose: np.ndarray, F: np.ndarray, Q_pose: np.ndarray) -> None:
        """A prediction with given Jacobians: the pose mean becomes ``pose`` (3,) and
        P ← A P Aᵀ + Q_pose on the pose block, A the identity with F (3, 3) on the pose."""
        self.joint.x[:3] = pose
        self.joint.transform_pose(F, Q_pose)

    def constrain(self, cols: np.ndarray, H: np.ndarray, x: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        return cols, H

    def error_curvature(self, index: np.ndarray, G: np.ndarray, x: np.ndarray | None = None) -> np.ndarray | None:
        return None

    def anchor(self, idx_x: np.ndarray, idx_y: np.ndarray) -> None:
        pass

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return self.joint.block(rows, cols)

    def diagonal(self, rows: np.ndarray) -> np.ndarray:
        return self.joint.diagonal(rows)

    def marginal(self, idx: np.ndarray) -> np.ndarray:
        return self.joint.block(idx, idx, keep=False)

    def window(self, rows: np.ndarray | None = None) -> CovarianceColumns:
        # P[rows, cols] read without folding the pending update
        return CovarianceColumns(self.joint, rows)

    def update(self, cols: np.ndarray, H: np.ndarray, residual: np.ndarray, R: Noise,
               gain: StackedGain | None = None) -> Innovation:
        if gain is None:
            gain = StackedGain(self.window(), cols, H, R)
        dx, nis = gain.state_correction(residual)
        x = self.joint.x
        x[:] = x + dx
        gain.update_covariance(self.joint)
        x[2] = wrap_angle(x[2])
        return Innovation(nis, gain.S_diag)

    def append(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray, noise: np.ndarray) -> np.ndarray:
        return self.joint.append_dependent(mean, cols, J, noise)

    def transform(self, idx: np.ndarray, T: np.ndarray) -> None:
        self.joint.transform(idx, T)

    def remove(self, indices: np.ndarray) -> np.ndarray:
        return self.joint.remove(indices)
