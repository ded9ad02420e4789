"""The EKF prediction on a dense covariance, the form the filter used before its state kept
the pose's rows apart (:func:`bsslam.slam.motion.predict_state`): the oracle the state's
prediction is checked against."""

import numpy as np

from bsslam.se2 import compose, compose_jacobians


def predict(x: np.ndarray, P: np.ndarray, delta: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """EKF prediction in place on a mean (n,) and a dense covariance (n, n); returns F_x (3, 3).

    Only the pose block and the pose rows/columns change:
    ``P_rr ← F_x P_rr F_xᵀ + F_u Q F_uᵀ``, ``P_rm ← F_x P_rm`` — never the full F of (32).
    """
    F_x, F_u = compose_jacobians(x[:3], delta)
    x[:3] = compose(x[:3], delta)
    P_rm = F_x @ P[:3, 3:]
    P_rr = F_x @ P[:3, :3] @ F_x.T + F_u @ Q @ F_u.T
    P[:3, 3:] = P_rm
    P[3:, :3] = P_rm.T
    P[:3, :3] = 0.5 * (P_rr + P_rr.T)
    return F_x
