"""The ROS bag reader: bags written with rosbags' own writers, read back."""

import math
from pathlib import Path

import numpy as np
import pytest
from rosbag_builder import KINDS, LASER, Bag, bag_path, standard_bag

from bsslam.errors import InputError
from bsslam.io.rosbag import RosbagReader


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip_with_interpolated_odometry(tmp_path, kind):
    path = standard_bag(kind).write(bag_path(tmp_path, kind))
    reader = RosbagReader(path)
    assert (reader.scan_topic, reader.odom_topic, reader.odometry_from_tf) == ("/scan", "/odom", False)
    frames = list(reader)
    assert [f.stamp for f in frames] == pytest.approx([1.5, 2.0], abs=1e-9)
    np.testing.assert_allclose(frames[0].odometry, [0.3, 0.0, 0.3], atol=1e-9)
    np.testing.assert_allclose(frames[1].odometry, [0.8, 0.0, 0.8], atol=1e-9)
    scan = frames[0].scan
    np.testing.assert_array_equal(scan.angles, -1.5 + 0.25 * np.arange(6))
    # 30.0 ≥ range_max → no return (+inf); 0.05 < range_min → invalid (NaN)
    np.testing.assert_array_equal(scan.ranges, [1.0, 2.5, np.inf, np.inf, np.nan, 4.125])
    assert scan.max_range == 30.0
    np.testing.assert_allclose(frames[0].laser_offset, [0.2, 0.05, 0.0], atol=1e-12)
    assert reader.skipped.counts == {"scan before the first odometry": 1, "scan after the last odometry": 1}
    assert reader.expected_frames == 4      # the scan topic's messages: a bound on the frames


@pytest.mark.parametrize("kind", ["ros1", "ros2-sqlite3"])
def test_odometry_from_tf_when_there_is_no_odometry_topic(tmp_path, kind):
    bag = Bag(kind)
    bag.tf(1.0, "odom", "base_footprint", 1.0, 2.0, 3.0)
    bag.tf(1.0, "map", "odom", 5.0, 5.0, 0.0)   # another transform in /tf is ignored
    bag.scan(1.5, frame="base_footprint")
    bag.tf(2.0, "odom", "base_footprint", 2.0, 2.0, -3.0)
    reader = RosbagReader(bag.write(bag_path(tmp_path, kind)))
    assert reader.odometry_from_tf and reader.odom_topic == "/tf"
    (frame,) = list(reader)
    np.testing.assert_allclose(frame.odometry[:2], [1.5, 2.0], atol=1e-9)
    assert abs(abs(frame.odometry[2]) - math.pi) < 1e-9  # half-way from 3 to −3 through ±π
    np.testing.assert_array_equal(frame.laser_offset, np.zeros(3))


def test_negative_increment_is_reversed_into_increasing_bearings(tmp_path):
    bag = Bag("ros2-sqlite3")
    bag.odom(0.0, 0.0, 0.0, 0.0)
    bag.scan(0.5, ranges=[1.0, 2.0, 3.0], increment=-0.5)
    bag.odom(1.0, 0.0, 0.0, 0.0)
    (frame,) = list(RosbagReader(bag.write(tmp_path / "b")))
    np.testing.assert_array_equal(frame.scan.angles, [-2.5, -2.0, -1.5])
    np.testing.assert_array_equal(frame.scan.ranges, [3.0, 2.0, 1.0])


def test_sweep_time_comes_from_time_increment_in_the_order_of_measurement(tmp_path):
    bag = Bag("ros2-sqlite3")
    bag.odom(0.0, 0.0, 0.0, 0.0)
    bag.scan(0.2, ranges=[1.0, 2.0, 3.0], time_increment=0.001)
    bag.scan(0.5, ranges=[1.0, 2.0, 3.0], increment=-0.5, time_increment=0.001)   # measured from the left
    bag.scan(0.7, ranges=[1.0, 2.0, 3.0])                                        # the driver does not say
    bag.odom(1.0, 0.0, 0.0, 0.0)
    sweeps = [frame.scan.sweep_time_s for frame in RosbagReader(bag.write(tmp_path / "b"))]
    np.testing.assert_allclose(sweeps, [0.002, -0.002, 0.0], rtol=1e-6)


def test_topic_ambiguity_lists_candidates_and_naming_resolves_it(tmp_path):
    bag = standard_bag("ros2-sqlite3")
    bag.scan(1.7, topic="/rear_scan")
    bag.odom(1.3, 0.0, 0.0, 0.0, topic="/odom_filtered")
    path = bag.write(tmp_path / "b")
    with pytest.raises(InputError, match="/rear_scan, /scan") as info:
        RosbagReader(path)
    assert info.value.path == str(path)
    with pytest.raises(InputError, match="/odom, /odom_filtered"):
        RosbagReader(path, scan_topic="/scan")
    reader = RosbagReader(path, scan_topic="/rear_scan", odom_topic="/odom")
    assert [f.stamp for f in reader] == pytest.approx([1.7]) and reader.expected_frames == 1
    with pytest.raises(InputError, match="not a sensor_msgs"):
        RosbagReader(path, scan_topic="/odom")


def test_bag_without_odometry_is_an_input_error(tmp_path):
    bag = Bag("ros2-sqlite3")
    bag.scan(1.0)
    with pytest.raises(InputError, match="no odometry"):
        RosbagReader(bag.write(tmp_path / "b"))


def test_bad_scans_counted_by_default_and_raised_when_strict(tmp_path):
    bag = Bag("ros1")
    bag.odom(0.0, 0.0, 0.0, 0.0)
    bag.scan(1.0)
    bag.scan(1.2, ranges=[])                     # empty
    bag.scan(1.4)
    bag.messages.append(("/scan", LASER, 1.6, bag.messages[-1][3]))  # same header stamp again
    bag.odom(2.0, 1.0, 0.0, 0.0)
    path = bag.write(tmp_path / "b.bag")
    reader = RosbagReader(path)
    assert [f.stamp for f in reader] == pytest.approx([1.0, 1.4])
    assert reader.skipped.counts == {"empty scan": 1, "duplicate scan timestamp": 1}
    assert reader.skipped.examples[0] == f"{path}:3: empty scan"
    with pytest.raises(InputError, match="empty scan") as info:
        list(RosbagReader(path, strict=True))
    assert (info.value.path, info.value.line) == (str(path), 3)


@pytest.mark.parametrize("name", ["missing.bag", "missing_dir"])
def test_missing_bag_is_an_input_error(tmp_path, name):
    with pytest.raises(InputError, match="cannot read bag") as info:
        RosbagReader(tmp_path / name)
    assert info.value.path == str(tmp_path / name)


def test_corrupt_bag_is_an_input_error(tmp_path):
    path = tmp_path / "junk.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 100)
    with pytest.raises(InputError, match="cannot read bag"):
        RosbagReader(path)


def test_mcap_file_alone_is_readable(tmp_path):
    folder = standard_bag("ros2-mcap").write(tmp_path / "b")
    mcap = next(Path(folder).glob("*.mcap"))
    assert len(list(RosbagReader(mcap))) == 2


# -- input limits (issue 18) -------------------------------------------------------------
@pytest.mark.parametrize("kind", ["ros1", "ros2-sqlite3"])
def test_invalid_scan_headers_and_odometry_are_counted_and_strict_raises(tmp_path, kind):
    bag = Bag(kind)
    bag.odom(0.5, 0.0, 0.0, 0.0)
    bag.scan(1.0)
    bag.scan(1.1, increment=0.0)                          # message 3
    bag.scan(1.2, increment=float("nan"))
    bag.scan(1.3, angle_max=float("nan"))
    bag.scan(1.4, angle_max=3.0)                          # disagrees with the beams
    bag.odom(1.45, float("nan"), 0.0, 0.0)
    bag.scan(1.5, ranges=[1.0, -1.0, 2.0])
    bag.odom(2.0, 0.2, 0.0, 0.0)
    path = bag.write(bag_path(tmp_path, kind))
    reader = RosbagReader(path)
    frames = list(reader)
    assert [f.stamp for f in frames] == pytest.approx([1.0, 1.5])
    assert np.isnan(frames[1].scan.ranges[1])
    assert reader.skipped.counts == {"angle increment 0": 1, "non-finite beam angles in the header": 1,
                                     "non-finite angle_max": 1,
                                     "angle_max disagrees with angle_min + (n−1)·angle_increment": 1,
                                     "non-finite odometry pose in /odom": 1}
    assert reader.skipped.examples[0] == f"{path}:3: angle increment 0"
    with pytest.raises(InputError, match="angle increment 0") as info:
        list(RosbagReader(path, strict=True))
    assert (info.value.path, info.value.line) == (str(path), 3)


def test_bag_without_a_valid_scan_is_an_error(tmp_path):
    bag = Bag("ros2-sqlite3")
    bag.odom(0.5, 0.0, 0.0, 0.0)
    bag.scan(1.0, increment=0.0)
    bag.odom(2.0, 0.0, 0.0, 0.0)
    path = bag.write(tmp_path / "b")
    with pytest.raises(InputError, match="no laser scans") as info:
        list(RosbagReader(path))
    assert info.value.path == str(path)
