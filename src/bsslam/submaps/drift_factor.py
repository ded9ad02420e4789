"""The odometry-like factor between two submap bases with a heading drift rate the
seams share.

A seam (the base of submap i+1 seen from submap i's) comes from the local filter, whose
heading drifts over a submap by more than its covariance says. Part of that drift is the
seam's own (``submaps.seam_drift_rad_per_m``, added to its covariance), but part of it has
a direction that holds over a whole run — the front end and the filter turning the same
way wherever the robot leaves a narrow passage (docs/real_logs.md). Independent noise per
seam cannot describe that: over n seams it grows as √n, the shared part as n, and a loop
closure that corrects a few seams leaves the others where they were. So the pose graph
holds one more unknown, the rate δ (rad/m) at which the seams turn, with a zero-mean
Gaussian prior; every seam's measurement is read as

    z'(δ) = A z A,   A = Pose2(0, 0, −δ d / 2),

d the distance (m) the robot travelled in the submap: the heading turned back by δ d and
the translation by half of it (a constant turn rate along a straight chord). The loop
closures then estimate δ, and it corrects every seam, also those no loop closure reaches
— the way a graph calibrates a gyro's bias or an odometry's scale.

The factor's error is GTSAM's between-factor error with z'(δ) for z:
``Log(z'(δ)⁻¹ · xᵢ⁻¹ xⱼ)``, its Jacobians GTSAM's (right perturbations of xᵢ, xⱼ; δ a
1-vector).
"""

from __future__ import annotations

import gtsam
import numpy as np

#: GTSAM key of the drift rate δ: the pose nodes use the integers 0, 1, 2, …
DRIFT_KEY = gtsam.symbol("d", 0)


def drift_corrected(z: gtsam.Pose2, rate: float, distance_m: float) -> gtsam.Pose2:
    """z'(δ) = A z A with A = Pose2(0, 0, −δ d / 2): the seam ``z`` with a drift of
    ``rate`` (rad/m) over ``distance_m`` (m) taken out."""
    a = gtsam.Pose2(0.0, 0.0, -0.5 * rate * distance_m)
    return a.compose(z).compose(a)


def drift_error(z: gtsam.Pose2, distance_m: float, xi: gtsam.Pose2, xj: gtsam.Pose2, rate: float,
                jacobians: list | None = None) -> np.ndarray:
    """(3,) ``Log(z'(δ)⁻¹ · xᵢ⁻¹ xⱼ)``, the whitening left to the noise model; with
    ``jacobians`` (a list of three) it sets them to the (3, 3), (3, 3) and (3, 1)
    derivatives in xᵢ, xⱼ (right perturbations) and δ."""
    f = 0.5 * distance_m
    half_back = gtsam.Pose2(0.0, 0.0, 0.5 * rate * distance_m)      # A⁻¹ = Exp((0, 0, δd/2))
    Ja1, Jz = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    w = half_back.compose(z.inverse(), Ja1, Jz)                     # A⁻¹ z⁻¹
    Jw, Ja2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    zinv = w.compose(half_back, Jw, Ja2)                            # z'⁻¹ = A⁻¹ z⁻¹ A⁻¹
    Hi, Hj = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    b = xi.between(xj, Hi, Hj)
    Hz, Hb = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
    c = zinv.compose(b, Hz, Hb)
    Hlog = np.zeros((3, 3), order="F")
    error = gtsam.Pose2.Logmap(c, Hlog)
    if jacobians is not None:
        # A⁻¹(δ + ε) = A⁻¹ · Exp((0, 0, d ε / 2)): both occurrences move alike
        dzinv = (Jw @ Ja1 + Ja2) @ np.array([[0.0], [0.0], [f]])
        jacobians[0] = Hlog @ Hb @ Hi
        jacobians[1] = Hlog @ Hb @ Hj
        jacobians[2] = Hlog @ Hz @ dzinv
    return error


def drift_factor(i: int, j: int, z: gtsam.Pose2, distance_m: float,
                 noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """The factor on nodes ``i``, ``j`` and :data:`DRIFT_KEY` whose error is
    :func:`drift_error` (``noise`` in GTSAM's tangent convention, as a
    ``BetweenFactorPose2``'s)."""
    d = float(distance_m)

    def error(factor: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        keys = factor.keys()
        rate = float(values.atVector(keys[2])[0])
        return drift_error(z, d, values.atPose2(keys[0]), values.atPose2(keys[1]), rate, H)

    return gtsam.CustomFactor(noise, [i, j, DRIFT_KEY], error)
