"""The filter's update schedule: compounding increments exactly, covariance to first order."""

import numpy as np

from bsslam.frontend import UpdateSchedule
from bsslam.se2 import compose, compose_with_covariance


def test_compounded_increment_equals_composition_and_resets():
    sched = UpdateSchedule(distance_m=1.0, angle_rad=1.0)
    steps = [np.array([0.2, 0.05, 0.1]), np.array([0.3, -0.02, -0.05]), np.array([0.25, 0.0, 0.2])]
    expected = np.zeros(3)
    for d in steps:
        assert not sched.add(d, np.eye(3) * 1e-4)
        expected = compose(expected, d)
    np.testing.assert_allclose(sched.increment, expected, atol=1e-12)
    inc, _ = sched.take()
    np.testing.assert_allclose(inc, expected, atol=1e-12)
    np.testing.assert_array_equal(sched.increment, np.zeros(3))


def test_update_is_due_by_distance_or_by_angle():
    by_distance = UpdateSchedule(distance_m=0.5, angle_rad=1.0)
    assert not by_distance.add(np.array([0.3, 0.0, 0.0]), np.zeros((3, 3)))
    assert by_distance.add(np.array([0.3, 0.0, 0.0]), np.zeros((3, 3)))
    by_angle = UpdateSchedule(distance_m=10.0, angle_rad=0.2)
    assert by_angle.add(np.array([0.0, 0.0, 0.25]), np.zeros((3, 3)))
    every_scan = UpdateSchedule(0.0, 0.0)
    assert every_scan.add(np.zeros(3), np.zeros((3, 3)))


def test_compounded_covariance_matches_monte_carlo():
    """First-order propagation against sampled increments (small noise: linearisation exact
    to within the sampling error)."""
    rng = np.random.default_rng(4)
    steps = [np.array([0.4, 0.1, 0.3]), np.array([0.5, -0.1, -0.2]), np.array([0.3, 0.0, 0.4])]
    covs = [np.diag([1e-4, 4e-4, 1e-4]), np.diag([2e-4, 1e-4, 3e-4]), np.diag([1e-4, 1e-4, 2e-4])]
    sched = UpdateSchedule(10.0, 10.0)
    for d, c in zip(steps, covs):
        sched.add(d, c)
    n = 40000
    acc = np.zeros((n, 3))
    for d, c in zip(steps, covs):
        acc = compose(acc, d + rng.multivariate_normal(np.zeros(3), c, n))
    sample_cov = np.cov(acc.T)
    np.testing.assert_allclose(sched.covariance, sample_cov, rtol=0.05, atol=2e-6)


def test_pose_between_updates_composes_the_filter_pose():
    sched = UpdateSchedule(10.0, 10.0)
    sched.add(np.array([0.2, 0.0, 0.1]), np.diag([1e-4, 1e-4, 1e-5]))
    pose, P = np.array([1.0, 2.0, 0.5]), np.diag([1e-3, 2e-3, 1e-4])
    got_pose, got_cov = sched.pose_between_updates(pose, P)
    want_pose, want_cov = compose_with_covariance(pose, P, sched.increment, sched.covariance)
    np.testing.assert_allclose(got_pose, want_pose)
    np.testing.assert_allclose(got_cov, want_cov)
    assert np.all(np.linalg.eigvalsh(got_cov) > 0)


def test_the_filter_predicts_with_a_matchs_translation_scaled_and_a_fallback_as_is():
    """``frontend.filter_translation_scale``: a trusted match reaches the filter with its
    translation variances × s (σ × √s, correlations kept) and its heading variance as
    stated; a fallback (raw odometry) is not scaled."""
    from bsslam.config import FrontendConfig
    from bsslam.frontend.laser_odometry import FrontendStep
    from bsslam.mapper import _FrontendMotion

    s = 0.25
    motion = _FrontendMotion(FrontendConfig(update_distance_m=0.0, update_angle_rad=0.0, filter_translation_scale=s))
    a = np.random.default_rng(7).normal(size=(3, 3))
    q = a @ a.T * 1e-3 + np.eye(3) * 1e-4
    pose, inc = np.zeros(3), np.array([0.3, 0.02, 0.1])
    assert motion.next(None, FrontendStep(None, None, pose, None, None, False, True))[1] is None
    run, delta, cov, key = motion.next(None, FrontendStep(inc, q, pose, inc, None, False, True))
    assert run and key == "frontend_matched"
    np.testing.assert_allclose(delta, inc)
    np.testing.assert_allclose(np.diag(cov), np.diag(q) * [s, s, 1.0], rtol=1e-12)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.testing.assert_allclose(corr, q / np.sqrt(np.outer(np.diag(q), np.diag(q))), rtol=1e-12)
    run, delta, cov, key = motion.next(None, FrontendStep(inc, q, pose, inc, None, True, False))
    assert run and key == "frontend_fallbacks"
    np.testing.assert_allclose(cov, q, rtol=1e-12)


def test_the_odometry_decides_when_the_filter_runs_not_the_match():
    """Which scans the filter sees must not move with the ranges' noise: the compounded
    odometry decides, while the matched increments are what is compounded for the filter."""
    sched = UpdateSchedule(distance_m=1.0, angle_rad=0.5)
    matched, odometry = np.array([0.6, 0.0, 0.0]), np.array([0.4, 0.0, 0.0])
    assert not sched.add(matched, np.eye(3) * 1e-4, odometry)    # matches say 1.2 m, wheels 0.8
    assert not sched.add(matched, np.eye(3) * 1e-4, odometry)
    assert sched.add(matched, np.eye(3) * 1e-4, odometry)        # wheels 1.2 m
    inc, _ = sched.take()
    np.testing.assert_allclose(inc, [1.8, 0.0, 0.0], atol=1e-12)
    turning = UpdateSchedule(distance_m=10.0, angle_rad=0.5)
    assert turning.add(np.array([0.0, 0.0, 0.1]), np.zeros((3, 3)), np.array([0.0, 0.0, 0.6]))
    turning.take()
    assert not turning.add(np.array([0.0, 0.0, 0.6]), np.zeros((3, 3)), np.array([0.0, 0.0, 0.1]))


def test_the_match_after_fallbacks_carries_their_error_where_a_step_predicted_them_wide():
    """``_FrontendMotion`` adds a match's ``carried`` covariance to its increment exactly when
    a filter step before it took some of the fallbacks with the model's covariance: widened
    by the walls' check (the mapper reports it), or with nothing learned yet; not where
    every such step kept the learned σ, nor where all the fallbacks share the match's
    increment (their errors cancel in it). An episode that spans a filter step (F1 in one,
    F2 and the match in the next) carries it when F1's step was wide."""
    from bsslam.config import FrontendConfig
    from bsslam.frontend.laser_odometry import FrontendStep
    from bsslam.mapper import _FrontendMotion

    inc, pose = np.array([0.6, 0.0, 0.0]), np.zeros(3)
    carried = np.diag([0.01, 0.02, 0.03])

    def step(fallback, carry=None):
        return FrontendStep(inc, np.eye(3) * 1e-4, pose, inc, None, fallback, False, carry)

    def episode(widened, every_step=True, learned=True):
        """M, then F1 (its own filter step when ``every_step``), F2, then the match (the step
        after F1's); the covariance the match's filter step gets, with and without carry."""
        out = []
        for carry in (carried, None):
            config = FrontendConfig(update_distance_m=0.0 if every_step else 5.0, fallback_learned=learned)
            motion = _FrontendMotion(config)
            motion.next(None, FrontendStep(None, None, pose, None, None, False, True))
            motion.next(None, step(False))
            run = motion.next(None, step(True))[0]
            if run and widened is not None and motion.wide_covariance is not None:
                motion.checked(widened)           # as the mapper's walls' check decides
            if every_step:                        # F2 and the match share the next step
                motion.schedule.distance_m = 1.0
            motion.next(None, step(True))
            motion.schedule.distance_m = 0.0
            out.append(motion.next(None, step(False, carry))[2])
        return out

    with_carry, without = episode(widened=True)
    np.testing.assert_allclose(with_carry - without, carried, atol=1e-15)
    with_carry, without = episode(widened=False)          # the walls kept the learned σ
    np.testing.assert_array_equal(with_carry, without)
    with_carry, without = episode(widened=None, every_step=False)   # all in the match's increment
    np.testing.assert_array_equal(with_carry, without)
    with_carry, without = episode(widened=None, learned=False)      # the model's covariance, nothing to check
    np.testing.assert_allclose(with_carry - without, carried, atol=1e-15)

    # The next episode starts afresh: F1 and the match share a widened step, then F2 takes a
    # step the walls keep at the learned σ; the match after F2 carries nothing.
    out = []
    for carry in (carried, None):
        motion = _FrontendMotion(FrontendConfig(update_distance_m=0.0))
        motion.next(None, FrontendStep(None, None, pose, None, None, False, True))
        motion.next(None, step(False))
        motion.schedule.distance_m = 1.0
        motion.next(None, step(True))
        motion.schedule.distance_m = 0.0
        motion.next(None, step(False, carried))           # F1 and its match: one step
        motion.checked(True)
        motion.next(None, step(True))                     # F2: its own step
        motion.checked(False)
        out.append(motion.next(None, step(False, carry))[2])
    np.testing.assert_array_equal(*out)
