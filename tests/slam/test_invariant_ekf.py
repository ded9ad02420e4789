"""The invariant EKF (bsslam.slam.invariant_ekf): in its error coordinates the unobservable
directions are one constant N_s, every range Jacobian it updates with annihilates it and its
prediction is the identity there, where the paper's EKF breaks that; its compressed form
against the dense textbook EKF with the same change of coordinates; its NEES."""

import dataclasses

import numpy as np
import pytest
from constraint_oracle import project_out
from dense_ekf import DenseEKF, run_in_lockstep
from scipy.stats import chi2
from test_oc_ekf import RecordedEKF, heading_nees, run_filter, violations

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.se2 import between
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import SplineSLAM
from bsslam.slam.invariant_ekf import InvariantEKF


class RecordedInvariant(InvariantEKF):
    """Records every range linearisation (H', N(x̂)[cols]) as the filter updates with it."""

    def __init__(self, pose, pose_covariance):
        super().__init__(pose, pose_covariance)
        self.jacobians = []

    def constrain(self, cols, H, x=None):
        cols, H = super().constrain(cols, H, x)
        if np.any(cols < 2):    # a range's rows (the pose's columns), not a bend's
            self.jacobians.append((H, self.null_space(self.x, cols)))
        return cols, H


@pytest.mark.parametrize("world, seed", [("rounded-room", 2), ("corridor-loop", 2)])
def test_every_update_annihilates_the_constant_null_space(world, seed):
    """Random scans (two worlds, seeded) with extension and pruning: every Jacobian the
    invariant EKF updates with annihilates N at its mean, the directions its covariance is
    carried along, to rounding; the paper's EKF misses N by the size of its corrections."""
    inv, reports = run_filter(RecordedInvariant, world, seed, 60)
    ekf, _ = run_filter(RecordedEKF, world, seed, 60)
    assert sum(r.extended_splines for r in reports) > 0 and len(inv.state.jacobians) > 60
    h_inv = max(np.abs(H @ N).max() / (np.abs(H).max() * np.abs(N).max()) for H, N in inv.state.jacobians)
    h_ekf, _ = violations(ekf.state)
    assert h_inv < 1e-12
    assert h_ekf > 1e-3


class DenseInvariant(DenseEKF):
    """The invariant EKF written out on the dense textbook EKF: the Jacobian at x_l is H
    (projected off N(x_l)) times A(x₀ → x_l) = I + J(x_l − x₀) e_φᵀ, and after each update
    the covariance is carried to the new mean, P ← A P Aᵀ with A = I + J(x⁺ − x₀) e_φᵀ, as
    dense products."""

    def __init__(self, pose, pose_covariance):
        super().__init__(pose, pose_covariance)
        self.mate, self.sign = np.array([1, 0, 0]), np.array([-1.0, 1.0, 0.0])

    def turn(self, v):
        return self.sign * v[self.mate]

    def null_space(self, x, cols):
        N = np.zeros((len(cols), 3))
        N[self.sign[cols] < 0, 0] = 1.0
        N[self.sign[cols] > 0, 1] = 1.0
        N[:, 2] = np.where(cols == 2, 1.0, self.turn(x)[cols])
        return N

    def constrain(self, cols, H, x=None):
        if x is None:
            return cols, H
        if np.any(cols == 2):
            H = project_out(H, self.null_space(x, cols))
        else:
            cols, H = np.append(cols, 2), np.column_stack([H, np.zeros(len(H))])
        H = H.copy()
        H[:, list(cols).index(2)] += H @ self.turn(x - self.x)[cols]
        return cols, H

    def update(self, cols, H, residual, R, gain=None):
        before = self.x.copy()
        innovation = super().update(cols, H, residual, R, gain)
        dx = self.x - before
        A = np.eye(self.size)
        A[:, 2] += self.turn(dx)
        self.P = A @ self.P @ A.T
        return innovation

    def append(self, mean, cols, J, noise):
        idx = super().append(mean, cols, J, noise)
        q = len(idx) // 2
        self.mate = np.concatenate([self.mate, idx[q:], idx[:q]])
        self.sign = np.concatenate([self.sign, -np.ones(q), np.ones(q)])
        return idx

    def remove(self, indices):
        mapping = super().remove(indices)
        keep = mapping >= 0
        self.mate, self.sign = mapping[self.mate[keep]], self.sign[keep]
        return mapping


@pytest.mark.parametrize("bends", [False, True])
def test_the_filter_on_the_dense_form_gives_the_same_run(bends):
    """Thirty steps with map building (new splines, extensions) on the compressed invariant
    EKF (its carried covariance deferred) and on the dense textbook form, with the paper's
    update and with significant bends and wall angles only (whose variances are read through
    the same Jacobians): the same poses, covariances and map to rounding."""
    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=3, steps=30))
    config = simulation_config(SLAMConfig(estimator="invariant"), sim)
    config = config.replace(observation=dataclasses.replace(config.observation, significant_bends_only=bends,
                                                            significant_wall_angles=bends))
    runs, _ = run_in_lockstep(config, frames, (None, DenseInvariant), 1e-8, 1e-11, 1e-6)
    assert isinstance(runs[0].state, InvariantEKF)   # chosen by the configuration
    assert runs[0].state_size > 80
    np.testing.assert_allclose(runs[0].state.P, runs[1].state.P, atol=1e-10)


def test_monte_carlo_heading_nees_stays_in_the_band():
    """As test_oc_ekf's Monte Carlo test (ten seeded runs, Bonferroni band at α = 1 %): the
    stationary robot's heading NEES stays in the χ² band with the invariant EKF."""
    runs, updates, sigma0, alpha = 10, 10, 0.05, 0.01
    lower, upper = chi2.ppf([alpha / (2 * updates), 1 - alpha / (2 * updates)], runs) / runs
    inv = np.mean([heading_nees("invariant", s, sigma0, updates) for s in range(runs)], axis=0)
    assert np.all((inv >= lower) & (inv <= upper)), (inv, lower, upper)


def test_a_pickled_filter_continues_bit_for_bit():
    """A run's checkpoint pickles the filter: the invariant EKF's pairing of coordinates and
    its deferred covariance come back, and the restored filter continues exactly like the
    original."""
    import pickle

    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=4, steps=24))
    config = simulation_config(SLAMConfig(estimator="invariant"), sim)
    slam = SplineSLAM(config, initial_pose=frames[0].odometry)
    prev = frames[0].odometry
    deltas = []
    for frame in frames:
        deltas.append(between(prev, frame.odometry))
        prev = frame.odometry
    for delta, frame in zip(deltas[:12], frames[:12]):
        slam.step(delta, frame.scan)
    copy = pickle.loads(pickle.dumps(slam))
    for delta, frame in zip(deltas[12:], frames[12:]):
        slam.step(delta, frame.scan)
        copy.step(delta, frame.scan)
    assert isinstance(copy.state, InvariantEKF)
    np.testing.assert_array_equal(copy.state.x, slam.state.x)
    np.testing.assert_array_equal(copy.state.P, slam.state.P)
