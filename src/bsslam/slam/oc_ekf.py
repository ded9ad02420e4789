"""The observability-constrained EKF (OC-EKF; Huang, Mourikis and Roumeliotis 2008–2010).

SLAM without absolute measurements cannot observe where the whole scene is: moving the
robot and every control point by one rigid motion of the plane changes no range. Those
three directions (global x, y translation and rotation) span the null space of the true
system. The EKF linearises each prediction at the latest updated pose and each range at the
latest estimate, and the Jacobians at different estimates no longer share that null space:
the filter gains spurious information along it, the heading above all (the paper's
Fig. 11: σ_φ of a stationary robot falls from 0.2 to 0.004 rad), and its NEES leaves the
χ² band.

The OC-EKF keeps N (n, 3), the unobservable directions at the filter's linearisation
points, and makes every linearisation respect it:

* pose rows ``[[1, 0, −ŷ], [0, 1, x̂], [0, 0, 1]]`` at the pose's *propagated* estimate
  p̂_{k|k−1}; a control point's rows ``[1, 0, −c_y]`` (its x entry) and ``[0, 1, c_x]`` (its
  y entry);
* prediction: the pose Jacobian's heading column uses the displacement between the
  propagated poses, p̂_{k+1|k} − p̂_{k|k−1}, instead of the one from the updated estimate,
  so that F N_k = N_{k+1}; then N's pose rows move to p̂_{k+1|k};
* update: the range Jacobian on its touched columns is projected onto the complement of
  N_c: H* = H − H N_c (N_cᵀ N_c)⁻¹ N_cᵀ, so H* N = 0 (:meth:`constrain`; the filter applies
  it to every linearisation it gates, iterates and updates with). It touches only the
  columns H touches, so the compressed update keeps its structure;
* new entries v = J x[cols] + w get the rows J N[cols]: the augmentation then maps N onto
  N exactly. For a new spline (built from the pose and ranges) these are the first-estimate
  rows at c + (p̂_N − p̂): the point as placed from the pose N holds (the propagated one)
  rather than the updated one, a few centimetres apart on the simulated runs;
* an extension rewrites the old control points (x[idx] ← T x[idx], T the unclamping) and
  appends new ones from them, the pose and the ranges; J N[cols] and T N[idx] would keep
  the augmentation exact, but they carry the old points' first-estimate drift through T
  and the extension's least-squares map, which amplify it (rotation rows up to 2.7 m away
  from the points' estimates on the simulated rounded room after 60 scans), and the
  projection then distorts H by as much: one run in eight diverged (NEES above 1000). So
  :meth:`anchor` sets the whole refitted spline's rows at its new estimate instead — what
  a spline first seen now would get; the augmentation then maps N onto N' up to that
  re-anchoring, the only place where the OC-EKF can gain a little spurious information;
* removal drops rows.

Measured (``SLAMConfig(estimator=...)`` through the experiments' ``base``): σ_φ after 30
updates / σ₀ of the stationary robot (heading-gain, 50 runs) is 1.0 for σ₀ = 0.01, 0.05,
0.2 (EKF: 0.41, 0.09, 0.022): the map built from the robot tells it nothing about its
heading. Over the double loops the NEES barely changes (20 runs, fraction of steps in the
95% band, EKF → OC-EKF): rounded-room 0.58 → 0.60 without extension, 0.39 → 0.37 with
(50 runs: 0.48 → 0.48, 0.33 → 0.35; both first leave it at step 59, 40);
corridor-loop 0.18 → 0.17 and 0.08 → 0.10; mixed 0.95 → 0.95 and 0.34 → 0.55. What keeps
those filters out of the band is not information along the unobservable directions. The
projection is least squares in the state's own units; where the ranges leave a direction
nearly unobserved (along a corridor) the change H* − H, a combination of N's columns, can
lend the pose a little sensitivity along it.

:class:`NullSpaceTracking` is that bookkeeping over any estimator with
``move_pose``: :class:`OCEKF` on the compressed EKF; with ``constrained = False`` it keeps
the same N beside the paper's Jacobians, which is how the tests show the paper's filter
violating it.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError
from bsslam.se2 import compose, compose_jacobians
from bsslam.slam.constraint_kernels import project_off
from bsslam.slam.estimator import CompressedEKF


def pose_null_rows(pose: np.ndarray) -> np.ndarray:
    """(3, 3) the unobservable directions' rows of a pose (x, y m, φ rad): the columns are
    global x and y translation and the rotation about the origin."""
    return np.array([[1.0, 0.0, -pose[1]], [0.0, 1.0, pose[0]], [0.0, 0.0, 1.0]])


def project_out(H_c: np.ndarray, N_c: np.ndarray) -> np.ndarray:
    """(m, c) H − H N (Nᵀ N)⁻¹ Nᵀ: the rows of H (m, c) projected onto the orthogonal
    complement of the columns of N (c, 3), which must be independent (a new array);
    compiled: :func:`~bsslam.slam.constraint_kernels.project_off`."""
    H = np.array(H_c, dtype=float, order="C")
    if not project_off(H, np.ascontiguousarray(N_c, dtype=float)):
        raise FilterError("unobservable directions not independent on the touched columns")
    return H


class NullSpaceTracking:
    """A mixin over an :class:`~bsslam.slam.estimator.Estimator` with ``move_pose(pose, F,
    Q_pose)``: keeps N and, when ``constrained``, the OC-EKF's Jacobians (see the module
    docstring).

    Attributes:
        N: (n, 3) the unobservable directions at the linearisation points.
        transition: (3, 3) the last prediction's pose Jacobian F (for tests).
    """

    constrained = True

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray):
        super().__init__(pose, pose_covariance)
        self.N = pose_null_rows(np.asarray(pose, dtype=float))
        self.transition = np.eye(3)

    def predict(self, delta: np.ndarray, Q: np.ndarray) -> None:
        pose = self.pose
        F_x, F_u = compose_jacobians(pose, delta)
        new = compose(pose, delta)
        if self.constrained:
            # the heading column from the propagated poses: F N_k = N_{k+1}
            x_prev, y_prev = self.N[1, 2], -self.N[0, 2]
            F_x[0, 2] = -(new[1] - y_prev)
            F_x[1, 2] = new[0] - x_prev
        self.transition = F_x
        self.move_pose(new, F_x, F_u @ Q @ F_u.T)
        self.N[:3] = pose_null_rows(new)

    def constrain(self, cols: np.ndarray, H_c: np.ndarray, x: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(cols, H_c (m, c) projected so that H* N[cols] = 0; H_c itself when not
        constrained)."""
        if not self.constrained:
            return cols, H_c
        return cols, project_out(H_c, self.N[cols])

    def anchor(self, idx_x: np.ndarray, idx_y: np.ndarray) -> None:
        """The rows of control points (x entries ``idx_x``, y entries ``idx_y``, paired) at
        their current estimate."""
        x = self.x
        self.N[idx_x] = np.column_stack([np.ones(len(idx_x)), np.zeros(len(idx_x)), -x[idx_y]])
        self.N[idx_y] = np.column_stack([np.zeros(len(idx_y)), np.ones(len(idx_y)), x[idx_x]])

    def append(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray, noise: np.ndarray) -> np.ndarray:
        idx = super().append(mean, cols, J, noise)
        self.N = np.concatenate([self.N, J @ self.N[np.asarray(cols, dtype=np.intp)]])
        return idx

    def transform(self, idx: np.ndarray, T: np.ndarray) -> None:
        super().transform(idx, T)
        self.N[idx] = T @ self.N[idx]    # exact for A N; the filter re-anchors a refitted spline

    def remove(self, indices: np.ndarray) -> np.ndarray:
        mapping = super().remove(indices)
        self.N = self.N[mapping >= 0]
        return mapping


class OCEKF(NullSpaceTracking, CompressedEKF):
    """The observability-constrained EKF on the compressed state. Implements
    :class:`~bsslam.slam.estimator.Estimator`."""
