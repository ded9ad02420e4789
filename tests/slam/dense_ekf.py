"""The textbook EKF on a dense mean and covariance: the oracle :class:`~bsslam.slam.estimator.CompressedEKF`
is checked against. It implements the same :class:`~bsslam.slam.estimator.Estimator`
protocol with the plain formulas (K = P Hᵀ S⁻¹ on the whole state, P ← (I − K H) P, the
augmented covariance written out), so the filter runs the same scenario on either.
"""

import numpy as np

from bsslam.se2 import between
from bsslam.slam import SplineSLAM
from bsslam.slam.estimator import Innovation
from bsslam.trajectory import wrap_angle
from motion_oracle import predict


def noise_matrix(R, m: int) -> np.ndarray:
    """(m, m) R from a scalar r (r I), an (m,) diagonal or an (m, m) matrix."""
    R = np.asarray(R, dtype=float)
    if R.ndim == 0:
        return float(R) * np.eye(m)
    return np.diag(R) if R.ndim == 1 else R


def _jacobian(n: int, cols: np.ndarray, H_c: np.ndarray) -> np.ndarray:
    H = np.zeros((H_c.shape[0], n))
    H[:, cols] = H_c
    return H


class DenseGain:
    """K = P Hᵀ S⁻¹ of one linearisation, its rows ``rows`` of the state."""

    def __init__(self, P, rows, cols, H_c, R):
        H = _jacobian(P.shape[0], cols, H_c)
        self.P, self.rows, self.H = P, rows, H
        self.S = H @ P @ H.T + noise_matrix(R, H.shape[0])
        self.K = P @ H.T @ np.linalg.inv(self.S)
        self.S_diag = np.diag(self.S).copy()

    def correction(self, innovation):
        return (self.K @ innovation)[self.rows], float(innovation @ np.linalg.solve(self.S, innovation))

    def posterior(self):
        return self.P - self.K @ self.H @ self.P

    def posterior_block(self):
        return self.posterior()[np.ix_(self.rows, self.rows)]

    def posterior_variances(self, cols, H_c, R):
        H2 = _jacobian(self.P.shape[0], cols, H_c)
        return np.diag(H2 @ self.posterior() @ H2.T) + np.diag(noise_matrix(R, H2.shape[0]))

    def pose_variances(self, prior):
        drop = np.diag(self.P - self.posterior())[:3]
        return np.maximum(prior - drop, 0.0)


class DenseWindow:
    def __init__(self, P, rows):
        self.P = P
        self.rows = np.arange(P.shape[0]) if rows is None else np.asarray(rows)

    def innovation_variances(self, cols, H_c, R):
        H = _jacobian(self.P.shape[0], cols, H_c)
        return np.diag(H @ self.P @ H.T) + np.diag(noise_matrix(R, H.shape[0]))

    def gain(self, cols, H_c, R):
        return DenseGain(self.P, self.rows, cols, H_c, R)


class DenseEKF:
    """Mean (n,) and dense covariance (n, n); the :class:`Estimator` protocol, textbook."""

    def __init__(self, pose, pose_covariance):
        self.x = np.array(pose, dtype=float)
        C = np.asarray(pose_covariance, dtype=float)
        self.P = 0.5 * (C + C.T)

    @property
    def size(self):
        return self.x.shape[0]

    @property
    def pose(self):
        return self.x[:3]

    @property
    def pose_covariance(self):
        return self.P[:3, :3].copy()

    @property
    def nbytes(self):
        return self.x.nbytes + self.P.nbytes

    def limit_memory(self, max_bytes):
        self.max_bytes = max_bytes   # the oracle's tests stay far below any budget

    def predict(self, delta, Q):
        predict(self.x, self.P, delta, Q)

    def move_pose(self, pose, F, Q_pose):
        """x[:3] ← pose, P ← A P Aᵀ + Q_pose on the pose block (A: F on the pose)."""
        A = np.eye(self.size)
        A[:3, :3] = F
        self.x[:3] = pose
        P = A @ self.P @ A.T
        P[:3, :3] += Q_pose
        self.P = 0.5 * (P + P.T)

    def constrain(self, cols, H_c, x=None):
        return cols, H_c

    def anchor(self, idx_x, idx_y):
        pass

    def block(self, rows, cols):
        return self.P[np.ix_(rows, cols)].copy()

    def diagonal(self, rows):
        return self.P[rows, rows].copy()

    def marginal(self, idx):
        return self.P[np.ix_(idx, idx)].copy()

    def window(self, rows=None):
        return DenseWindow(self.P.copy(), rows)

    def update(self, cols, H_c, residual, R, gain=None):
        gain = DenseGain(self.P, None, cols, H_c, R)
        self.x = self.x + gain.K @ residual
        self.x[2] = wrap_angle(self.x[2])
        P = gain.posterior()
        self.P = 0.5 * (P + P.T)
        return Innovation(float(residual @ np.linalg.solve(gain.S, residual)), gain.S_diag)

    def append(self, mean, cols, J, noise):
        n, k = self.size, len(mean)
        cross = J @ self.P[cols, :]
        P = np.zeros((n + k, n + k))
        P[:n, :n] = self.P
        P[n:, :n] = cross
        P[:n, n:] = cross.T
        own = cross[:, cols] @ J.T + noise
        P[n:, n:] = 0.5 * (own + own.T)
        self.x, self.P = np.concatenate([self.x, mean]), P
        return np.arange(n, n + k)

    def transform(self, idx, T):
        A = np.eye(self.size)
        A[np.ix_(idx, idx)] = T
        self.x = A @ self.x
        P = A @ self.P @ A.T
        self.P = 0.5 * (P + P.T)

    def remove(self, indices):
        keep = np.ones(self.size, dtype=bool)
        keep[indices] = False
        mapping = np.full(self.size, -1)
        mapping[keep] = np.arange(keep.sum())
        self.x, self.P = self.x[keep], self.P[np.ix_(keep, keep)]
        return mapping


def run_in_lockstep(config, frames, estimators, pose_atol, covariance_atol, covariance_rtol, nis_rtol=None):
    """The filter with ``config`` on each of ``estimators`` (Estimator classes; None: the
    configured one) through the same simulated ``frames``, one step at a time, asserting at
    every step the same beams and state size, the poses within ``pose_atol``, the pose
    covariances within ``covariance_atol`` / ``covariance_rtol`` and, when ``nis_rtol`` is
    given, the NIS. Returns (the filters, the first filter's reports)."""
    runs = [SplineSLAM(config, initial_pose=frames[0].odometry, estimator=e) for e in estimators]
    prev, first = frames[0].odometry, []
    for frame in frames:
        delta = between(prev, frame.odometry)
        prev = frame.odometry
        reports = [slam.step(delta, frame.scan) for slam in runs]
        first.append(reports[0])
        for other, report in zip(runs[1:], reports[1:]):
            assert reports[0].beams_used == report.beams_used
            assert reports[0].state_size == report.state_size
            np.testing.assert_allclose(runs[0].pose, other.pose, atol=pose_atol)
            np.testing.assert_allclose(runs[0].pose_covariance, other.pose_covariance, atol=covariance_atol,
                                       rtol=covariance_rtol)
            if nis_rtol is not None:
                np.testing.assert_allclose(reports[0].nis, report.nis, rtol=nis_rtol)
    return runs, first
