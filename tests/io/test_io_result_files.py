"""Round trips and bad input for the trajectory, covariance and configuration files."""

import io
import math

import numpy as np
import pytest
import yaml

from bsslam.config import SLAMConfig, SplineConfig
from bsslam.errors import ConfigError, InputError
from bsslam.io.config_file import load_config, write_config
from bsslam.io.pose_covariance_file import read_pose_covariance_csv, write_pose_covariance_csv
from bsslam.io.trajectory_file import read_trajectory, write_tum
from bsslam.trajectory import Trajectory


def _trajectory(n=7, seed=0, with_cov=False):
    rng = np.random.default_rng(seed)
    stamps = 1.1e9 + np.cumsum(rng.uniform(0.05, 0.2, n))
    poses = np.column_stack([rng.normal(0, 10, n), rng.normal(0, 10, n), rng.uniform(-math.pi + 1e-3, math.pi, n)])
    cov = None
    if with_cov:
        a = rng.normal(size=(n, 3, 3))
        cov = a @ a.transpose(0, 2, 1)
    return Trajectory(stamps, poses, cov)


def test_tum_round_trip_is_exact_in_stamps_and_positions(tmp_path):
    traj = _trajectory()
    path = tmp_path / "est.tum"
    write_tum(path, traj)
    back = read_trajectory(path)
    np.testing.assert_array_equal(back.stamps, traj.stamps)
    np.testing.assert_array_equal(back.poses[:, :2], traj.poses[:, :2])
    np.testing.assert_allclose(back.poses[:, 2], traj.poses[:, 2], atol=1e-12)


def test_tum_lines_have_z_zero_and_a_unit_quaternion_about_z():
    traj = Trajectory([1.0], [[2.0, 3.0, math.pi / 2]])
    out = io.StringIO()
    write_tum(out, traj)
    data = [line for line in out.getvalue().splitlines() if not line.startswith("#")]
    values = [float(v) for v in data[0].split()]
    assert values[:4] == [1.0, 2.0, 3.0, 0.0]
    np.testing.assert_allclose(values[4:], [0, 0, math.sqrt(0.5), math.sqrt(0.5)])


def test_reads_four_column_files_with_comments_and_wraps_heading():
    text = "# timestamp x y theta\n\n1.5 1 2 0.5\n2.5 3 4 " + repr(2 * math.pi + 0.25) + "\n"
    traj = read_trajectory(io.StringIO(text))
    np.testing.assert_array_equal(traj.stamps, [1.5, 2.5])
    np.testing.assert_allclose(traj.poses, [[1, 2, 0.5], [3, 4, 0.25]])


@pytest.mark.parametrize("text, line, words", [
    ("1 2 3\n", 1, "columns"),
    ("1 2 3 4\n2 3 4 5 6 7 8 9\n", 2, "columns"),
    ("# c\n1 2 3 4\n2 x 4 5\n", 3, "non-numeric"),
])
def test_bad_trajectory_line_names_file_and_line(tmp_path, text, line, words):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as info:
        read_trajectory(path)
    assert info.value.path == str(path) and info.value.line == line
    assert f"{path}:{line}" in str(info.value)


def test_missing_trajectory_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError) as info:
        read_trajectory(tmp_path / "nope.tum")
    assert info.value.path.endswith("nope.tum")


def test_covariance_csv_round_trip_and_header(tmp_path):
    traj = _trajectory(with_cov=True)
    path = tmp_path / "pose_covariance.csv"
    write_pose_covariance_csv(path, traj)
    assert path.read_text().splitlines()[0] == "stamp,c_xx,c_xy,c_xphi,c_yx,c_yy,c_yphi,c_phix,c_phiy,c_phiphi"
    stamps, cov = read_pose_covariance_csv(path)
    np.testing.assert_array_equal(stamps, traj.stamps)
    np.testing.assert_array_equal(cov, traj.covariances)


def test_covariance_csv_is_row_major():
    cov = np.arange(9.0).reshape(1, 3, 3)
    out = io.StringIO()
    write_pose_covariance_csv(out, Trajectory([0.0], [[0, 0, 0]], cov))
    assert out.getvalue().splitlines()[1] == "0.0,0.0,1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0"


def test_covariance_csv_errors():
    with pytest.raises(InputError, match="no covariances"):
        write_pose_covariance_csv(io.StringIO(), Trajectory([0.0], [[0, 0, 0]]))
    with pytest.raises(InputError, match="header"):
        read_pose_covariance_csv(io.StringIO("stamp,a\n"))
    header = "stamp,c_xx,c_xy,c_xphi,c_yx,c_yy,c_yphi,c_phix,c_phiy,c_phiphi\n"
    with pytest.raises(InputError, match="10") as info:
        read_pose_covariance_csv(io.StringIO(header + "1,2,3\n"))
    assert info.value.line == 2


def test_config_round_trip(tmp_path):
    config = SLAMConfig(spline=SplineConfig(degree=2, knot_spacing_m=0.7), mode="localization",
                        initial_pose_sigma=(0.1, 0.2, 0.03))
    path = tmp_path / "config.yaml"
    write_config(path, config)
    assert load_config(path) == config
    assert yaml.safe_load(path.read_text())["spline"]["knot_spacing_m"] == 0.7


def test_partial_and_empty_config_files_keep_defaults(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("")
    assert load_config(path) == SLAMConfig()
    path.write_text("spline:\n  degree: 2\n")
    assert load_config(path) == SLAMConfig(spline=SplineConfig(degree=2))


@pytest.mark.parametrize("text, words", [
    ("spline: [1, 2\n", "invalid YAML"),
    ("- 1\n- 2\n", "mapping"),
    ("splines:\n  degree: 3\n", "unknown configuration key"),
    ("spline:\n  degree: 9\n", "degree"),
    ("spline:\n  knot_spacing_m: abc\n", "spline"),
])
def test_bad_config_files_are_config_errors_naming_the_file(tmp_path, text, words):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=words) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_missing_config_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="missing.yaml"):
        load_config(tmp_path / "missing.yaml")
