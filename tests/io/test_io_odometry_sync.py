"""Pairing scans with interpolated odometry in a stream."""

import numpy as np

from bsslam.io.odometry_sync import AFTER_LAST, BEFORE_FIRST, TOO_OLD, OdometrySync, interpolate_pose


def test_interpolate_pose_is_linear_and_exact_at_the_ends():
    p0, p1 = np.array([0.0, 0.0, 0.1]), np.array([2.0, -4.0, 0.5])
    np.testing.assert_allclose(interpolate_pose(1.25, 1.0, p0, 2.0, p1), [0.5, -1.0, 0.2])
    np.testing.assert_allclose(interpolate_pose(1.0, 1.0, p0, 2.0, p1), p0, atol=1e-15)
    np.testing.assert_allclose(interpolate_pose(2.0, 1.0, p0, 2.0, p1), p1, atol=1e-15)


def test_scans_wait_for_odometry_after_their_stamp():
    sync = OdometrySync()
    sync.add_scan(0.5, "early")
    assert list(sync.ready()) == []  # odometry with an earlier stamp could still come
    sync.add_odometry(1.0, [0, 0, 0])
    assert [(item, reason) for item, _, reason in sync.ready()] == [("early", BEFORE_FIRST)]
    sync.add_scan(1.5, "mid")
    assert list(sync.ready()) == []
    sync.add_odometry(2.0, [1, 0, 0])
    (item, pose, reason), = sync.ready()
    assert item == "mid" and reason is None
    np.testing.assert_allclose(pose, [0.5, 0, 0])
    sync.add_scan(3.0, "late")
    assert list(sync.ready()) == []
    assert [(item, reason) for item, _, reason in sync.ready(final=True)] == [("late", AFTER_LAST)]


def test_scans_older_than_the_kept_window_are_released_unpaired():
    sync = OdometrySync(window=3)
    for t in range(10):
        sync.add_odometry(float(t), [t, 0, 0])
    sync.add_scan(0.5, "old")
    sync.add_scan(8.5, "new")
    out = list(sync.ready())
    assert out[0][0] == "old" and out[0][2] == TOO_OLD
    assert out[1][0] == "new" and out[1][2] is None
    np.testing.assert_allclose(out[1][1], [8.5, 0, 0])
