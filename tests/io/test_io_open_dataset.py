"""Choosing the reader from the path, and its errors."""

import pytest
from rosbag_builder import standard_bag

from bsslam.errors import ConfigError, InputError
from bsslam.io.carmen import CarmenReader
from bsslam.io.open_dataset import guess_format, open_dataset
from bsslam.io.rosbag import RosbagReader
from bsslam.trajectory import Trajectory

LINE = "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 host 1.0\n"


@pytest.mark.parametrize("name", ["a.clf", "a.log", "a.carmen", "A.CLF"])
def test_carmen_suffixes(tmp_path, name):
    path = tmp_path / name
    path.write_text(LINE)
    assert guess_format(path) == "carmen"
    dataset = open_dataset(path)
    assert isinstance(dataset, CarmenReader)
    assert dataset.ground_truth is None and dataset.skipped.total == 0
    assert [len(f.scan) for f in dataset] == [3]


def test_format_overrides_the_guess_and_ground_truth_is_attached(tmp_path):
    path = tmp_path / "log.txt"
    path.write_text(LINE)
    with pytest.raises(InputError, match="format=") as info:
        open_dataset(path)
    assert info.value.path == str(path)
    reference = Trajectory([1.0], [[0.0, 0.0, 0.0]])
    dataset = open_dataset(path, format="carmen", ground_truth=reference)
    assert dataset.ground_truth is reference and dataset.name == "log"


def test_ros_paths_are_recognised(tmp_path):
    folder = standard_bag("ros2-mcap").write(tmp_path / "r2")
    assert guess_format(folder) == "ros2"
    mcap = next(folder.glob("*.mcap"))
    assert guess_format(mcap) == "ros2"
    bare = tmp_path / "bare"
    bare.mkdir()
    mcap.rename(bare / mcap.name)
    assert guess_format(bare) == "ros2"
    assert len(list(open_dataset(bare))) == 2
    ros1 = standard_bag("ros1").write(tmp_path / "r1.bag")
    assert guess_format(ros1) == "ros1"
    dataset = open_dataset(ros1, scan_topic="/scan", odom_topic="/odom")
    assert isinstance(dataset, RosbagReader) and len(list(dataset)) == 2


def test_errors(tmp_path):
    with pytest.raises(InputError, match="no such file") as info:
        open_dataset(tmp_path / "none.clf")
    assert info.value.path == str(tmp_path / "none.clf")
    with pytest.raises(InputError, match="ROS 2 bag folder"):
        open_dataset(tmp_path)
    path = tmp_path / "a.clf"
    path.write_text(LINE)
    with pytest.raises(ConfigError, match="format"):
        open_dataset(path, format="kitti")
    with pytest.raises(ConfigError, match="ROS"):
        open_dataset(path, scan_topic="/scan")
    with pytest.raises(InputError, match=r"\*\.bag"):
        open_dataset(path, format="ros1")
    not_a_bag = tmp_path / "x.db3"
    not_a_bag.write_text("not sqlite")
    with pytest.raises(InputError, match="cannot read bag") as info:
        open_dataset(not_a_bag)
    assert info.value.path == str(not_a_bag)
