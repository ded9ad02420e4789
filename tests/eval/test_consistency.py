

def test_pose_errors_nees_matches_the_definition_and_skips_the_exact_first_pose():
    import numpy as np

    from bsslam.eval import pose_errors
    from bsslam.trajectory import Trajectory

    rng = np.random.default_rng(3)
    truth = Trajectory(np.arange(4.0), rng.normal(size=(4, 3)))
    cov = np.stack([np.zeros((3, 3))] + [np.diag([0.01, 0.04, 0.0025])] * 3)
    est_poses = truth.poses.copy()
    est_poses[1:] += np.array([0.1, -0.2, 0.05])
    err = pose_errors(Trajectory(truth.stamps, est_poses, cov), truth)
    assert np.isnan(err.nees[0])
    expected = 0.1 ** 2 / 0.01 + 0.2 ** 2 / 0.04 + 0.05 ** 2 / 0.0025
    np.testing.assert_allclose(err.nees[1:], expected)
    np.testing.assert_allclose(err.sigmas[1], [0.1, 0.2, 0.05])
