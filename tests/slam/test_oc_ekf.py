"""The observability-constrained EKF (bsslam.slam.oc_ekf): its linearisations keep the
unobservable directions N (global translation and rotation) in their null space — H N = 0
for every range Jacobian and F N_k = N_{k+1} for every prediction — where the paper's EKF
breaks both; its compressed form against the dense textbook form; and its NEES."""

import numpy as np
import pytest
from dense_ekf import DenseEKF, run_in_lockstep
from scipy.stats import chi2

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config, variant_config
from bsslam.se2 import between
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import SplineSLAM
from bsslam.slam.estimator import CompressedEKF
from bsslam.slam.oc_ekf import OCEKF, NullSpaceTracking, pose_null_rows, project_out
from bsslam.trajectory import wrap_angle


class Recording(NullSpaceTracking):
    """Records, for every prediction, (F N_k, N_{k+1}) on the pose rows (F is the identity
    on the map's), and for every linearisation (H, N[cols]) as the filter uses them."""

    def __init__(self, pose, pose_covariance):
        super().__init__(pose, pose_covariance)
        self.transitions, self.jacobians, self.anchored = [], [], 0

    def predict(self, delta, Q):
        before = self.N[:3].copy()
        map_rows = self.N[3:].copy()
        super().predict(delta, Q)
        assert np.array_equal(self.N[3:], map_rows)
        self.transitions.append((self.transition @ before, self.N[:3].copy()))

    def anchor(self, idx_x, idx_y):
        super().anchor(idx_x, idx_y)
        if self.constrained:   # an extended spline's rows sit at its new estimate
            x = self.x
            np.testing.assert_array_equal(self.N[idx_x], np.column_stack([np.ones(len(idx_x)), 0 * idx_x, -x[idx_y]]))
            np.testing.assert_array_equal(self.N[idx_y], np.column_stack([0 * idx_y, np.ones(len(idx_y)), x[idx_x]]))
        self.anchored += 1

    def constrain(self, cols, H, x=None):
        cols, H = super().constrain(cols, H, x)
        self.jacobians.append((H, self.N[cols].copy()))
        return cols, H


class RecordedOC(Recording, CompressedEKF):
    constrained = True


class RecordedEKF(Recording, CompressedEKF):
    """The paper's EKF (its own F and H), with the OC-EKF's N kept beside it."""

    constrained = False


class DenseOC(NullSpaceTracking, DenseEKF):
    """The OC-EKF's bookkeeping over the dense textbook EKF."""


def run_filter(estimator, world: str, seed: int, steps: int, variant: str = "extension"):
    sim = SimConfig()
    frames = list(simulate(get_world(world), sim, seed=seed, steps=steps))
    config = simulation_config(variant_config(variant), sim)
    slam = SplineSLAM(config, initial_pose=frames[0].odometry, estimator=estimator)
    prev, reports = frames[0].odometry, []
    for frame in frames:
        delta = between(prev, frame.odometry)
        prev = frame.odometry
        reports.append(slam.step(delta, frame.scan))
    return slam, reports


def violations(state):
    """(max relative |H N| over the linearisations, max |F N_k − N_{k+1}| over the
    predictions); |H N| relative to |H| |N| (N's rotation column is in metres)."""
    h = max(np.abs(H @ N).max() / (np.abs(H).max() * np.abs(N).max()) for H, N in state.jacobians)
    f = max(np.abs(FN - N1).max() for FN, N1 in state.transitions)
    return h, f


def test_projection_annihilates_the_null_space_and_nothing_else():
    rng = np.random.default_rng(4)
    c = 11
    N = np.vstack([pose_null_rows(rng.normal(size=3) * 5), rng.normal(size=(c - 3, 3)) * 3])
    H = rng.normal(size=(20, c))
    Hs = project_out(H, N)
    np.testing.assert_allclose(Hs @ N, 0.0, atol=1e-12 * np.abs(H).max() * np.abs(N).max())
    np.testing.assert_allclose(project_out(Hs, N), Hs, atol=1e-13)   # a projection
    # the change is in the span of Nᵀ: H − H* = A Nᵀ
    A, *_ = np.linalg.lstsq(N, (H - Hs).T, rcond=None)
    np.testing.assert_allclose(N @ A, (H - Hs).T, atol=1e-12)


@pytest.mark.parametrize("world, seed", [("rounded-room", 2), ("corridor-loop", 2)])
def test_oc_ekf_keeps_the_null_space_where_the_ekf_breaks_it(world, seed):
    """Random scans (two worlds, seeded) with extension and pruning: every Jacobian of the
    OC-EKF annihilates N and every prediction maps N_k onto N_{k+1}, to rounding; the paper's
    EKF with the same N misses both by the size of its updates' corrections."""
    oc, oc_reports = run_filter(RecordedOC, world, seed, 60)
    ekf, _ = run_filter(RecordedEKF, world, seed, 60)
    assert sum(r.new_splines for r in oc_reports) > 2
    assert oc.state.anchored == sum(r.extended_splines for r in oc_reports) > 0
    assert len(oc.state.jacobians) > 60 and len(oc.state.transitions) == 60
    h_oc, f_oc = violations(oc.state)
    h_ekf, f_ekf = violations(ekf.state)
    assert h_oc < 1e-13 and f_oc < 1e-12
    assert h_ekf > 1e-3 and f_ekf > 1e-3     # its updates move the pose by centimetres


def test_the_filter_on_the_dense_oc_ekf_gives_the_same_run():
    """Forty steps with map building (new splines, extensions, pruning) on the compressed and
    on the dense OC-EKF: the same poses, covariances, map and N to rounding."""
    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=3, steps=40))
    config = simulation_config(SLAMConfig(estimator="oc-ekf"), sim)
    runs, reports = run_in_lockstep(config, frames, (None, DenseOC), 1e-9, 1e-12, 1e-7, nis_rtol=1e-7)
    assert isinstance(runs[0].state, OCEKF)   # chosen by the configuration
    extended = sum(r.extended_splines for r in reports)
    assert runs[0].state_size > 100 and extended
    np.testing.assert_allclose(runs[0].state.x, runs[1].state.x, atol=1e-9)
    np.testing.assert_allclose(runs[0].state.P, runs[1].state.P, atol=1e-12)
    np.testing.assert_allclose(runs[0].state.N, runs[1].state.N, atol=1e-9)


def test_localization_uses_the_ekf():
    """With the map fixed the pose is observable: the OC-EKF's projection would discard every
    measurement, so localisation ignores the setting."""
    slam = SplineSLAM(SLAMConfig(estimator="oc-ekf", mode="localization"))
    assert type(slam.state) is CompressedEKF
    assert isinstance(SplineSLAM(SLAMConfig(estimator="oc-ekf")).state, OCEKF)
    assert type(SplineSLAM(SLAMConfig(estimator="ekf")).state) is CompressedEKF   # the paper's filter
    assert type(SplineSLAM(SLAMConfig(mode="localization")).state) is CompressedEKF   # whatever the default


def heading_nees(estimator: str, seed: int, sigma0: float, updates: int) -> np.ndarray:
    """(updates,) heading NEES e_φ²/σ_φ² of a stationary robot facing the curved wall (the
    paper's Fig. 11 setting), its initial heading drawn from its prior N(truth, σ₀²)."""
    sim = SimConfig()
    data = simulate(get_world("curved-wall"), sim, seed=seed, steps=updates + 1)
    truth = data.ground_truth.poses[0]
    start = truth + np.array([0.0, 0.0, np.random.default_rng([seed, 7]).normal(0.0, sigma0)])
    config = simulation_config(SLAMConfig(estimator=estimator), sim)
    slam = SplineSLAM(config, initial_pose=start, initial_covariance=np.diag([0.0, 0.0, sigma0 ** 2]))
    out = []
    for k, frame in enumerate(data):
        report = slam.step(None, frame.scan)
        if k:
            assert report.beams_used > 50
            out.append(wrap_angle(slam.pose[2] - truth[2]) ** 2 / slam.pose_covariance[2, 2])
    return np.array(out)


def test_monte_carlo_heading_nees_stays_in_the_band_with_oc_ekf_only():
    """Ten seeded runs, ten updates each. For a consistent filter the mean over R runs of the
    (1-dof) heading NEES at each update is χ²(R)/R; the two-sided band at each of the K
    updates holds with probability 1 − α/K, so the OC-EKF falls outside it anywhere with
    probability at most α = 1% (Bonferroni: whatever the correlation between updates). The
    paper's EKF, which believes the map told it its heading, leaves it by orders of magnitude."""
    runs, updates, sigma0, alpha = 10, 10, 0.05, 0.01
    lower, upper = chi2.ppf([alpha / (2 * updates), 1 - alpha / (2 * updates)], runs) / runs
    oc = np.mean([heading_nees("oc-ekf", s, sigma0, updates) for s in range(runs)], axis=0)
    ekf = np.mean([heading_nees("ekf", s, sigma0, updates) for s in range(runs)], axis=0)
    assert np.all((oc >= lower) & (oc <= upper)), (oc, lower, upper)
    assert np.all(ekf[2:] > 10 * upper), ekf
