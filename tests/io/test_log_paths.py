"""Which logs a command line names: files, folders, ROS 2 bag folders and patterns."""

import pytest

from bsslam.errors import InputError
from bsslam.io.log_paths import find_logs


@pytest.fixture
def tree(tmp_path):
    for name in ("a/one.clf", "a/deep/two.carmen", "a/three.bag", "a/notes.log", "a/readme.txt", "b/four.clf"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("")
    bag = tmp_path / "a" / "ros2bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("")
    (bag / "ros2bag_0.db3").write_text("")
    return tmp_path


def test_a_folder_gives_its_logs_sorted_and_a_ros2_bag_whole(tree):
    assert find_logs([tree / "a"]) == [tree / "a" / n for n in ("deep/two.carmen", "one.clf", "ros2bag", "three.bag")]


def test_files_and_bags_are_taken_as_named_and_patterns_expanded_each_once(tree):
    named = [tree / "a" / "notes.log", tree / "a" / "ros2bag", str(tree / "*" / "*.clf"), tree / "a" / "one.clf"]
    assert find_logs(named) == [tree / "a" / "notes.log", tree / "a" / "ros2bag", tree / "a" / "one.clf",
                                tree / "b" / "four.clf"]


def test_nothing_found_names_the_argument(tree):
    with pytest.raises(InputError, match="nope"):
        find_logs([tree / "nope*.clf"])
    (tree / "empty").mkdir()
    with pytest.raises(InputError, match="empty: no logs"):
        find_logs([tree / "empty"])
