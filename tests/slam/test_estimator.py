"""The compressed EKF against the dense textbook EKF through the Estimator protocol: the
same operations, and the filter run on either, give the same numbers to rounding."""

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam.estimator import CompressedEKF
from dense_ekf import DenseEKF, run_in_lockstep


def random_spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def both(rng, n):
    """A compressed and a dense estimator holding the same (n,) mean and covariance."""
    P = random_spd(rng, n)
    pose = rng.normal(size=3)
    out = []
    for cls in (CompressedEKF, DenseEKF):
        est = cls(pose, P[:3, :3])
        # the map entries as dependent ones: v = J x[pose] + w reproduces P's blocks
        J = P[3:, :3] @ np.linalg.inv(P[:3, :3])
        noise = P[3:, 3:] - J @ P[:3, 3:]
        est.append(np.linspace(-1, 1, n - 3), np.arange(3), J, 0.5 * (noise + noise.T))
        out.append(est)
    return out


COLS = np.array([0, 1, 2, 5, 6, 7, 20, 21])


def noises(rng, m):
    A = rng.normal(size=(m, m)) * 0.01
    return [1e-4, np.full(m, 1e-4) + rng.uniform(0, 1e-4, m), A @ A.T + 1e-4 * np.eye(m)]


@pytest.mark.parametrize("m", [4, 40])   # measurement space, and compressed for a scalar R
@pytest.mark.parametrize("kind", [0, 1, 2])   # R = r I, diagonal, full
def test_operations_agree_with_the_dense_ekf(m, kind):
    rng = np.random.default_rng(10 + m + kind)
    compressed, dense = both(rng, 30)
    np.testing.assert_allclose(compressed.P, dense.P, atol=1e-10)
    H = rng.normal(size=(m, COLS.size))
    nu = rng.normal(size=m) * 0.01
    R = noises(rng, m)[kind]
    delta, Q = np.array([0.3, -0.1, 0.2]), np.diag([1e-3, 2e-3, 1e-4])
    for est in (compressed, dense):
        est.predict(delta, Q)
    work = np.array([0, 1, 2, 4, 5, 6, 7, 20, 21, 25])
    w_c, w_d = compressed.window(work), dense.window(work)
    np.testing.assert_allclose(w_c.innovation_variances(COLS, H, R), w_d.innovation_variances(COLS, H, R), rtol=1e-10)
    g_c, g_d = w_c.gain(COLS, H, R), w_d.gain(COLS, H, R)
    for a, b in zip(g_c.correction(nu), g_d.correction(nu)):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-11)
    cols2, H2 = np.array([0, 1, 2, 6, 25]), rng.normal(size=(3, 5))
    np.testing.assert_allclose(g_c.posterior_variances(cols2, H2, 1e-4), g_d.posterior_variances(cols2, H2, 1e-4),
                               rtol=1e-9)
    prior = np.diag(compressed.pose_covariance)
    np.testing.assert_allclose(g_c.pose_variances(prior), g_d.pose_variances(prior), atol=1e-10 * prior.max())
    i_c, i_d = compressed.update(COLS, H, nu, R, g_c), dense.update(COLS, H, nu, R)
    np.testing.assert_allclose(i_c.nis, i_d.nis, rtol=1e-9)
    np.testing.assert_allclose(i_c.variances, i_d.variances, rtol=1e-10)
    np.testing.assert_allclose(compressed.x, dense.x, atol=1e-12)
    np.testing.assert_allclose(compressed.P, dense.P, atol=1e-10)
    # append, transform, remove
    J, noise = rng.normal(size=(4, 3)) * 0.1, 1e-3 * np.eye(4)
    cols = np.array([0, 1, 8])
    assert np.array_equal(compressed.append(np.ones(4), cols, J, noise), dense.append(np.ones(4), cols, J, noise))
    T = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    for est in (compressed, dense):
        est.transform(np.array([10, 11, 12]), T)
    np.testing.assert_allclose(compressed.P, dense.P, atol=1e-10)
    gone = np.array([4, 5, 31])
    assert np.array_equal(compressed.remove(gone), dense.remove(gone))
    np.testing.assert_allclose(compressed.x, dense.x, atol=1e-12)
    np.testing.assert_allclose(compressed.P, dense.P, atol=1e-10)
    np.testing.assert_allclose(compressed.block(COLS, work), dense.block(COLS, work), atol=1e-10)
    np.testing.assert_allclose(compressed.diagonal(work), dense.diagonal(work), atol=1e-10)


def test_whitened_rows_update_as_the_block_noise_of_a_shared_error():
    """Rows whitened against an error shared per map spline (:meth:`RangeModel.whitened`)
    with the scalar r update the compressed EKF exactly as the dense EKF updates with the
    unwhitened rows and the block noise R = r I + s Σ_g 1_g 1_gᵀ: mean, covariance, NIS."""
    from bsslam.slam.beam_kernels import whiten_shared

    rng = np.random.default_rng(5)
    compressed, dense = both(rng, 30)
    m, r, s = 40, 1e-4, 3e-4
    group = rng.integers(0, 4, m)
    H, nu = rng.normal(size=(m, COLS.size)), rng.normal(size=m) * 0.01
    R = r * np.eye(m) + s * (group[:, None] == group[None, :])
    WH, Wnu = whiten_shared(group, s / r, H, nu)
    i_c, i_d = compressed.update(COLS, WH, Wnu, r), dense.update(COLS, H, nu, R)
    np.testing.assert_allclose(i_c.nis, i_d.nis, rtol=1e-9)
    np.testing.assert_allclose(compressed.x, dense.x, atol=1e-12)
    np.testing.assert_allclose(compressed.P, dense.P, atol=1e-10)
    # and the shared error costs information: the pose is less certain than with r I alone
    alone = both(np.random.default_rng(5), 30)[1]
    alone.update(COLS, H, nu, r)
    assert np.all(np.linalg.eigvalsh(dense.pose_covariance - alone.pose_covariance) > 0)


def test_the_filter_on_either_estimator_gives_the_same_run():
    """Forty steps of a simulated run with map building through both estimators: the same
    poses, covariances and map to rounding (the same beams, gates and splines)."""
    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=3, steps=40))
    config = simulation_config(SLAMConfig(), sim)
    runs, _ = run_in_lockstep(config, frames, (CompressedEKF, DenseEKF), 1e-9, 1e-12, 1e-7, nis_rtol=1e-7)
    assert runs[0].state_size > 100   # the map grew
    np.testing.assert_allclose(runs[0].state.x, runs[1].state.x, atol=1e-9)
    np.testing.assert_allclose(runs[0].state.P, runs[1].state.P, atol=1e-12)
