"""The invariant EKF: the paper's EKF with its covariance carried along each correction of
the mean as the invariant error prescribes (after Barrau and Bonnabel, "An EKF-SLAM
algorithm with consistency properties", 2015/16).

Moving the robot and every control point by one rigid motion of the plane changes no range.
At an estimate x̂ those three directions are N(x̂): global x and y translation, and the
rotation (heading 1, every position p moved by J p̂, J the quarter turn (x, y) → (−y, x)).
Each of the paper's updates annihilates N at the estimate it linearises at, but the next
update linearises elsewhere: together they inform the filter along directions nothing
observes (the heading of a robot in the map it built; the walls of a corridor turning with
it), and its NEES leaves the χ² band.

The rigid motions act on SLAM states as a group, and its right-invariant error has the same
unobservable directions at every estimate. To first order that error is
``ξ = A(x̂)⁻¹ (x − x̂)``, ``A(x̂) = I + J x̂ e_φᵀ`` (the heading's share in every position):
its covariance at x̂ is the ordinary one, and when the mean moves from x̂ to x̂⁺ the same
ξ-covariance describes ``A(x̂⁺) A(x̂)⁻¹ = I + w e_φᵀ``, ``w = J (x̂⁺ − x̂)``, times it. So the
invariant EKF is the paper's filter with three changes:

* **after each update** the covariance is carried to the new mean: ``P ← A P Aᵀ`` with
  ``w = J Δx̂`` (a rank-two term over the whole state, ``w aᵀ + a wᵀ + P_φφ w wᵀ``,
  ``a = P[:, φ]``, deferred into the compressed covariance like the update itself:
  :meth:`~bsslam.slam.state.JointState.shear`);
* **within an update**, a range linearised at x_l (the iterated update's iterates) has the
  Jacobian ``H A(x̂ → x_l)``: the heading's column gains ``H J (x_l − x̂)``;
* the Jacobian is first projected off N(x_l) (a no-op to rounding for the exact range
  model; :mod:`bsslam.slam.bends` can break it), so ``H N(x_l) = 0`` for every update.

Prediction and map growth are the paper's: its motion Jacobian is exactly
``A(x̂_{k+1}) A(x̂_k)⁻¹``, and the maps from pose and control points to new control points
commute with rigid motions (Φ's and Ψ's rows sum to one), so they carry N onto N already.
Then the information the filter holds never grows along N(x̂) at the current estimate.

Cost over the paper's filter: one more column of the deferred covariance term per scan
(it is folded into P a little more often) and O(n) for w.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError
from bsslam.slam.constraint_kernels import HEADING, invariant_jacobian, invariant_null_space
from bsslam.slam.ekf import StackedGain
from bsslam.slam.estimator import CompressedEKF, Innovation, Noise


class InvariantEKF(CompressedEKF):
    """The invariant EKF on the compressed state (see the module docstring). Implements
    :class:`~bsslam.slam.estimator.Estimator`; appended entries are control points, their x
    coordinates first, then their y coordinates in the same order."""

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray):
        super().__init__(pose, pose_covariance)
        # the other coordinate of each position entry and the sign of J there:
        # (J v)_x = −v_y, (J v)_y = v_x; the heading has neither
        self._mate = np.array([1, 0, 0], dtype=np.intp)
        self._sign = np.array([-1.0, 1.0, 0.0])

    def turn(self, v: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """J v on ``rows`` (all when None) of a state-sized vector v (m): (−v_y, v_x) on each
        position entry, 0 on the heading."""
        if rows is None:
            return self._sign * v[self._mate]
        rows = np.asarray(rows, dtype=np.intp)
        return self._sign[rows] * v[self._mate[rows]]

    def null_space(self, x: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(c, 3) N(x) on ``cols``: global x, y translation and the rotation about the
        origin (heading 1, positions J x, m per rad); compiled:
        :func:`~bsslam.slam.constraint_kernels.invariant_null_space`."""
        return invariant_null_space(np.asarray(cols, dtype=np.intp), np.asarray(x, dtype=float), self._sign, self._mate)

    def constrain(self, cols: np.ndarray, H: np.ndarray, x: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(cols', H') for the model's H (m, c) on ``cols`` linearised at ``x`` (the mean
        when None): H projected off N(x) when it has the pose's columns (a range's rows;
        rows on the map alone, a spline's bend, are invariant), then H A(x̂ → x), whose
        heading column (added when missing) gains H J (x − x̂); compiled:
        :func:`~bsslam.slam.constraint_kernels.invariant_jacobian`."""
        x = self.x if x is None else np.asarray(x, dtype=float)
        cols, H, ok = invariant_jacobian(np.asarray(cols, dtype=np.intp), np.ascontiguousarray(H, dtype=float),
                                         x, self.x, self._sign, self._mate)
        if not ok:
            raise FilterError("unobservable directions not independent on the touched columns")
        return cols, H

    def error_curvature(self, index: np.ndarray, G: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """(m, L, L) the invariant error's second-order terms in the Hessians (on x − x̂, the
        covariance this filter carries, ``P = A Σ_ξ Aᵀ``) of m functions, each of its own
        variables ``index`` (m, L) (state indices, −1 for none; each holds the heading, and
        a position's x and y together), with gradients G (m, L) there at ``x`` (the mean
        when None).

        The error ξ acts by the group's exponential: every position p (the robot's and each
        control point) becomes ``R(ξ_φ) p̂ + V(ξ_φ) ξ_p``, ``V(θ) ≈ I + θ J / 2``, so beyond
        first order (``A ξ``) it moves by ``−ξ_φ² p̂ / 2 + ξ_φ J ξ_p / 2``: its second
        derivatives are −p̂ (along ξ_φ twice) and J / 2 (ξ_φ with ξ_p). In these
        coordinates a rigid motion of everything is exact, and a range, which no rigid
        motion changes, has no curvature along one; along x − x̂ it has (a straight step
        along a rotation stretches every distance by √(1 + θ²)), and that spurious part is
        what this removes. In ξ the terms are C: ``c = −Σ_p g_p · p̂`` on (φ, φ) and
        ``Jᵀ g_p / 2`` between φ and p; on x − x̂ they are ``A⁻ᵀ C A⁻¹``, with
        ``A⁻¹ = I − J x̂ e_φᵀ``: local too, on the same variables."""
        x = self.x if x is None else x
        index = np.asarray(index, dtype=np.intp)
        m, L = index.shape
        present = index >= 0
        safe = np.where(present, index, 0)
        is_heading = safe == HEADING
        if np.any(is_heading.sum(axis=1) != 1):
            raise FilterError("error curvature: each function's variables must hold the heading once")
        at = np.argmax(is_heading, axis=1)                     # (m,) the heading's slot
        sign = np.where(present, self._sign[safe], 0.0)
        # the slot of each position's mate (its other coordinate) among the same variables
        mate_of = np.where(present, self._mate[safe], -2)
        same = (index[:, None, :] == mate_of[:, :, None]) & (sign[:, :, None] != 0)
        if np.any(same.sum(axis=2) != (sign != 0)):
            raise FilterError("error curvature: a position's x and y must both be among the variables")
        mate_slot = np.argmax(same, axis=2)
        G = np.where(present, G, 0.0)
        p_hat = x[safe]
        c = -np.einsum("ml,ml->m", np.where(sign != 0, G, 0.0), p_hat)
        half_jt_g = -0.5 * sign * np.take_along_axis(G, mate_slot, axis=1)     # Jᵀ g / 2 = −J g / 2
        rows = np.arange(m)
        C = np.zeros((m, L, L))
        C[rows, at, :] += half_jt_g
        C[rows, :, at] += half_jt_g
        C[rows, at, at] += c
        # A⁻ᵀ C A⁻¹: the heading's column less C (J x̂), then its row less (J x̂)ᵀ of that
        turned = sign * np.take_along_axis(p_hat, mate_slot, axis=1)           # J x̂ on the positions, 0 elsewhere
        C[rows, :, at] -= np.einsum("mab,mb->ma", C, turned)
        C[rows, at, :] -= np.einsum("ma,mab->mb", turned, C)
        return C

    def update(self, cols: np.ndarray, H: np.ndarray, residual: np.ndarray, R: Noise,
               gain: StackedGain | None = None) -> Innovation:
        before = self.x.copy()
        innovation = super().update(cols, H, residual, R, gain)
        w = self.turn(self.x - before)
        if np.any(w):
            self.joint.shear(w, HEADING)   # P ← A P Aᵀ, A = I + w e_φᵀ
        return innovation

    def move_pose(self, pose: np.ndarray, F: np.ndarray, Q_pose: np.ndarray) -> None:
        raise FilterError("the invariant EKF predicts from odometry (predict) only")

    def append(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray, noise: np.ndarray) -> np.ndarray:
        k = np.asarray(mean).shape[0]
        if k % 2:
            raise FilterError(f"new control points come as x, then y coordinates: got {k} entries")
        idx = super().append(mean, cols, J, noise)
        q = idx.shape[0] // 2
        self._mate = np.concatenate([self._mate, idx[q:], idx[:q]])
        self._sign = np.concatenate([self._sign, -np.ones(q), np.ones(q)])
        return idx

    def remove(self, indices: np.ndarray) -> np.ndarray:
        mapping = super().remove(indices)
        keep = mapping >= 0
        mate = mapping[self._mate[keep]]
        self._sign = self._sign[keep]
        if np.any(mate[self._sign != 0] < 0):
            raise FilterError("a control point's x and y coordinates must be removed together")
        self._mate = mate
        return mapping
