"""The CARMEN reader: round trips of every message kind, bad input, real logs."""

import math
import os
from pathlib import Path

import numpy as np
import pytest

from bsslam.errors import ConfigError, InputError
from bsslam.input_limits import InputLimits
from bsslam.io.carmen import CarmenReader
from bsslam.io.carmen_messages import carmen_beam_angles
from bsslam.io.no_return import detect_no_return_code, mark_no_return
from bsslam.io.reader_config import ReaderConfig
from bsslam.io.trajectory_file import read_trajectory
from bsslam.trajectory import wrap_angle

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def _num(values):
    return " ".join(repr(float(v)) for v in values)


def flaser(ranges, stamp, odom, laser=None, kind="FLASER"):
    laser = odom if laser is None else laser
    return f"{kind} {len(ranges)} {_num(ranges)} {_num(laser)} {_num(odom)} {stamp!r} host {stamp!r}"


def odom(pose, stamp):
    return f"ODOM {_num(pose)} 0 0 0 {stamp!r} host {stamp!r}"


def rawlaser(ranges, stamp, start=-1.5, res=0.01, max_range=30.0, kind="RAWLASER1", rem=(0.5, 0.7)):
    return (f"{kind} 0 {start!r} {res * (len(ranges) - 1)!r} {res!r} {max_range!r} 0.01 0 "
            f"{len(ranges)} {_num(ranges)} {len(rem)} {_num(rem)} {stamp!r} host {stamp!r}")


def robotlaser(ranges, stamp, laser_pose, robot_pose, start=-1.0, res=0.02, max_range=40.0, kind="ROBOTLASER1"):
    return (f"{kind} 0 {start!r} {res * (len(ranges) - 1)!r} {res!r} {max_range!r} 0.01 0 "
            f"{len(ranges)} {_num(ranges)} 0 {_num(laser_pose)} {_num(robot_pose)} 0.1 0.2 1.5 0.3 0.0 "
            f"{stamp!r} host {stamp!r}")


def write_log(tmp_path, lines, name="log.clf", final_newline=True):
    path = tmp_path / name
    path.write_text("\n".join(lines) + ("\n" if final_newline else ""))
    return path


def _frames(path, **kwargs):
    reader = CarmenReader(path, **kwargs)
    return reader, list(reader)


# -- geometry and no-return rule -------------------------------------------------------
@pytest.mark.parametrize("n, first_deg, step_deg", [(180, -90, 1), (181, -90, 1), (360, -90, 0.5), (361, -90, 0.5),
                                                    (5, -90, 45)])
def test_carmen_beam_angles(n, first_deg, step_deg):
    np.testing.assert_allclose(np.degrees(carmen_beam_angles(n)), first_deg + step_deg * np.arange(n), atol=1e-12)


def test_detect_no_return_code():
    config = ReaderConfig()
    assert detect_no_return_code([50.0] * 30 + list(np.linspace(3, 19, 70)), config) == 50.0
    # a far value that is the maximum of only a few scans is a real return
    assert detect_no_return_code([30.16] * 5 + list(np.linspace(3, 19, 95)), config) is None
    # a frequent maximum below code_min_m is a real wall (a robot standing still)
    assert detect_no_return_code([12.5] * 80, config) is None
    assert detect_no_return_code([], config) is None


def test_mark_no_return_keeps_nan_and_sets_inf():
    out = mark_no_return(np.array([1.0, 81.83, np.nan, 79.9, 80.0]), 80.0)
    np.testing.assert_array_equal(out, [1.0, np.inf, np.nan, 79.9, np.inf])


def test_reader_config_validates():
    with pytest.raises(ConfigError):
        ReaderConfig(laser_message="LASER9")
    with pytest.raises(ConfigError):
        ReaderConfig(code_min_share=0)
    for sweep in (-0.001, 2.0, math.nan):
        with pytest.raises(ConfigError, match="carmen_sweep_time_s"):
            ReaderConfig(carmen_sweep_time_s=sweep)


def test_scans_carry_the_configured_sweep_time(tmp_path):
    path = write_log(tmp_path, [odom([0, 0, 0], 10.0), flaser([1.5] * 180, 10.0, [0.0, 0.0, 0.0])])
    (frame,) = list(CarmenReader(path))
    assert frame.scan.sweep_time_s == pytest.approx(1 / 150)     # a SICK LMS's 180°
    (frame,) = list(CarmenReader(path, config=ReaderConfig(carmen_sweep_time_s=0.0)))
    assert frame.scan.sweep_time_s == 0.0
    # half-degree scans are interlaced over two turns of the mirror: no linear sweep
    path = write_log(tmp_path, [odom([0, 0, 0], 10.0), flaser([1.5] * 361, 10.0, [0.0, 0.0, 0.0])])
    (frame,) = list(CarmenReader(path))
    assert frame.scan.sweep_time_s == 0.0


# -- round trips -----------------------------------------------------------------------
def test_flaser_round_trip_with_junk_lines_and_param_offset(tmp_path):
    r1 = [1.0, 2.5, 81.83, 3.25] + [4.0] * 176
    r2 = [1.5] * 180
    lines = ["# a comment", "PARAM robot_frontlaser_offset 0.1 host 0",
             "PARAM robot_some_other_param abc host 0", "SYNC tag 1.0 host 1.0",
             odom([0, 0, 0], 10.0), flaser(r1, 10.0, [1.0, 2.0, 0.5]), "",
             "NEFF 15", flaser(r2, 11.0, [1.5, 2.0, -3.0]), "GARBAGE"]
    reader, frames = _frames(write_log(tmp_path, lines))
    assert reader.laser_message == "FLASER" and reader.name == "log"
    assert [f.stamp for f in frames] == [10.0, 11.0]
    np.testing.assert_array_equal(frames[0].odometry, [1.0, 2.0, 0.5])
    np.testing.assert_array_equal(frames[1].odometry, [1.5, 2.0, -3.0])
    np.testing.assert_array_equal(frames[0].scan.ranges, [1.0, 2.5, np.inf, 3.25] + [4.0] * 176)
    np.testing.assert_allclose(frames[0].scan.angles, np.radians(np.arange(-90, 90)), atol=1e-12)
    assert frames[0].scan.max_range == 80.0
    np.testing.assert_array_equal(frames[0].laser_offset, [0.1, 0.0, 0.0])
    # message types the reader does not use (ODOM with FLASER included) are no problems:
    # counted silently under one key, not as skips
    assert reader.skipped.counts == {} and reader.skipped.total == 0
    assert reader.skipped.ignored == {"other_messages": 4}
    assert reader.skipped.examples == []


def test_flaser_laser_offset_from_the_two_pose_triples(tmp_path):
    robot = [1.0, 2.0, math.pi / 2]
    laser = [1.0, 2.2, math.pi / 2]  # 0.2 m ahead of a robot facing +y
    _, frames = _frames(write_log(tmp_path, [flaser([1.0] * 180, 1.0, robot, laser)]))
    np.testing.assert_allclose(frames[0].laser_offset, [0.2, 0.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(frames[0].odometry, robot)


def test_rlaser_uses_the_rear_offset_turned_by_pi(tmp_path):
    lines = ["PARAM robot_rearlaser_offset -0.3 host 0", flaser([2.0] * 181, 1.0, [0, 0, 0], kind="RLASER")]
    reader, frames = _frames(write_log(tmp_path, lines))
    assert reader.laser_message == "RLASER"
    np.testing.assert_allclose(frames[0].laser_offset, [-0.3, 0.0, math.pi])


def test_robotlaser_uses_its_own_angles_poses_and_max_range(tmp_path):
    ranges = [1.0, 2.0, 45.0, 39.0]
    robot = [3.0, -1.0, math.pi]
    laser = [2.9, -1.0, math.pi]  # 0.1 m ahead of a robot facing −x
    reader, frames = _frames(write_log(tmp_path, [robotlaser(ranges, 5.0, laser, robot)]))
    frame = frames[0]
    np.testing.assert_allclose(frame.scan.angles, [-1.0, -0.98, -0.96, -0.94])
    np.testing.assert_array_equal(frame.scan.ranges, [1.0, 2.0, np.inf, 39.0])
    assert frame.scan.max_range == 40.0
    np.testing.assert_array_equal(frame.odometry, robot)
    np.testing.assert_allclose(frame.laser_offset, [0.1, 0.0, 0.0], atol=1e-12)


def test_rawlaser_odometry_is_interpolated_between_odom_messages(tmp_path):
    lines = ["PARAM robot_frontlaser_offset 0.2 host 0",
             rawlaser([1.0, 2.0, 3.0], 0.5),          # before the first ODOM
             odom([0.0, 0.0, 3.0], 1.0),
             rawlaser([1.0, 31.0, 3.0], 1.5),
             rawlaser([4.0, 5.0, 6.0], 2.0),
             odom([1.0, 2.0, -3.0], 2.0),            # heading crosses ±π
             rawlaser([1.0, 2.0, 3.0], 2.5)]          # after the last ODOM
    reader, frames = _frames(write_log(tmp_path, lines))
    assert [f.stamp for f in frames] == [1.5, 2.0]
    # half-way from 3.0 to −3.0 the short way (through ±π), not through 0
    np.testing.assert_allclose(frames[0].odometry[:2], [0.5, 1.0])
    assert abs(wrap_angle(frames[0].odometry[2] - (3.0 + (2 * math.pi - 6.0) / 2))) < 1e-12
    np.testing.assert_array_equal(frames[1].odometry, [1.0, 2.0, -3.0])
    np.testing.assert_allclose(frames[0].scan.angles, [-1.5, -1.49, -1.48])
    np.testing.assert_array_equal(frames[0].scan.ranges, [1.0, np.inf, 3.0])  # ≥ its max range 30
    np.testing.assert_array_equal(frames[0].laser_offset, [0.2, 0, 0])
    assert reader.skipped.counts == {"scan before the first odometry": 1, "scan after the last odometry": 1}
    assert reader.skipped.examples[0].endswith("log.clf:2: scan before the first odometry")


def test_best_laser_stream_is_chosen_and_the_others_counted(tmp_path):
    lines = [odom([0, 0, 0], 0.5), rawlaser([1.0] * 3, 1.0), flaser([1.0] * 180, 1.0, [0, 0, 0]),
             robotlaser([1.0] * 4, 1.0, [0, 0, 0], [0, 0, 0]), odom([0, 0, 0], 1.5)]
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path)
    assert reader.laser_message == "ROBOTLASER1" and len(frames) == 1
    # the two other laser lines and the two ODOM lines are ignored silently, not skips
    assert reader.skipped.total == 0 and reader.skipped.ignored == {"other_messages": 4}
    reader, frames = _frames(path, config=ReaderConfig(laser_message="RAWLASER1"))
    assert len(frames) == 1 and len(frames[0].scan) == 3


def test_logger_code_is_detected_and_can_be_switched_off(tmp_path):
    rng = np.random.default_rng(0)
    lines = []
    for i in range(40):
        ranges = rng.uniform(1, 20, 180)
        if i % 2 == 0:
            ranges[10:20] = 50.0
        lines.append(flaser(np.round(ranges, 2), float(i), [0, 0, 0]))
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path)
    assert reader.no_return_code_m == 50.0
    assert frames[0].scan.max_range == 50.0 and np.all(np.isinf(frames[0].scan.ranges[10:20]))
    reader, frames = _frames(path, config=ReaderConfig(detect_no_return_code=False))
    assert reader.no_return_code_m is None and np.all(frames[0].scan.ranges[10:20] == 50.0)


def test_iterating_twice_gives_the_same_frames_and_counts(tmp_path):
    path = write_log(tmp_path, [flaser([1.0] * 180, 1.0, [0, 0, 0]), "FLASER 2 1.0", flaser([2.0] * 180, 2.0, [0, 0, 0])])
    reader = CarmenReader(path)
    first, second = list(reader), list(reader)
    assert [f.stamp for f in first] == [f.stamp for f in second] == [1.0, 2.0]
    assert reader.skipped.total == 1


# -- bad input -------------------------------------------------------------------------
GOOD = flaser([1.0] * 180, 1.0, [0, 0, 0])
BAD_CASES = {
    "wrong field count": ([GOOD, "FLASER 180 1.0 2.0 0 0 0 0 0 0 2.0 host 2.0"], 2,
                          "malformed FLASER line (wrong field count)"),
    "non-numeric range": ([GOOD, flaser([1.0] * 180, 2.0, [0, 0, 0]).replace(" 1.0 ", " x1 ", 1)], 2,
                          "malformed FLASER line (non-numeric value)"),
    "non-numeric count": ([GOOD, "FLASER abc 1 2 3"], 2, "malformed FLASER line (non-numeric value)"),
    "bad ODOM for RAWLASER": ([odom([0, 0, 0], 0.0), "ODOM 1 2 3", rawlaser([1.0], 0.0)], 2,
                              "malformed ODOM line (wrong field count)"),
    "bad PARAM offset": (["PARAM robot_frontlaser_offset abc host 0", GOOD], 1,
                         "malformed PARAM line (non-numeric value)"),
    "empty scan": ([GOOD, flaser([], 2.0, [0, 0, 0])], 2, "empty scan"),
    "duplicate timestamp": ([GOOD, flaser([2.0] * 180, 1.0, [0, 0, 0])], 2, "duplicate scan timestamp"),
    "backwards timestamp": ([GOOD, flaser([2.0] * 180, 0.5, [0, 0, 0])], 2, "backwards scan timestamp"),
    "truncated last line": ([GOOD, flaser([2.0] * 180, 2.0, [0, 0, 0])[:300]], 2, "truncated last line"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_is_a_counted_skip_by_default(tmp_path, case):
    lines, line_number, reason = BAD_CASES[case]
    path = write_log(tmp_path, lines, final_newline=case != "truncated last line")
    reader, frames = _frames(path)
    assert len(frames) == 1
    assert reader.skipped.counts.get(reason) == 1, reader.skipped.counts
    assert f"{path}:{line_number}: {reason}" in reader.skipped.examples


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_raises_with_file_and_line_when_strict(tmp_path, case):
    lines, line_number, reason = BAD_CASES[case]
    path = write_log(tmp_path, lines, final_newline=case != "truncated last line")
    with pytest.raises(InputError) as info:
        list(CarmenReader(path, strict=True))
    assert (info.value.path, info.value.line) == (str(path), line_number)
    assert str(info.value).startswith(f"{path}:{line_number}: {reason}")


def test_nan_and_inf_ranges_are_kept_and_counted(tmp_path):
    ranges = [1.0, float("nan"), float("inf"), 2.0] + [1.0] * 176
    path = write_log(tmp_path, [flaser(ranges, 1.0, [0, 0, 0])])
    reader, frames = _frames(path)
    r = frames[0].scan.ranges
    assert np.isnan(r[1]) and r[2] == np.inf and r[3] == 2.0
    assert reader.skipped.examples == [f"{path}:1: NaN/inf ranges (kept as invalid beams)"]
    with pytest.raises(InputError, match="NaN/inf"):
        list(CarmenReader(path, strict=True))


def test_complete_last_line_without_newline_is_accepted(tmp_path):
    path = write_log(tmp_path, [GOOD, flaser([2.0] * 180, 2.0, [0, 0, 0])], final_newline=False)
    reader, frames = _frames(path, strict=True)
    assert len(frames) == 2


@pytest.mark.parametrize("make", [lambda p: p / "missing.clf", lambda p: p])
def test_missing_or_unreadable_file_is_an_input_error(tmp_path, make):
    with pytest.raises(InputError) as info:
        CarmenReader(make(tmp_path))
    assert info.value.path == str(make(tmp_path))


# -- real data -------------------------------------------------------------------------
def test_first_scans_of_the_intel_log_match_the_reference_stamps():
    log = DATA / "intel" / "intel-rawodom.clf"
    if not log.exists():
        pytest.skip(f"shared CARMEN data not found at {DATA}")
    frames = []
    for frame in CarmenReader(log, strict=True):
        frames.append(frame)
        if len(frames) == 50:
            break
    assert all(len(f.scan) == 180 for f in frames)
    stamps = np.array([f.stamp for f in frames])
    assert np.all(np.diff(stamps) > 0)
    reference = read_trajectory(DATA / "intel" / "intel-rawodom.gt.txt")
    overlap = reference.stamps[(reference.stamps >= stamps[0]) & (reference.stamps <= stamps[-1])]
    assert len(overlap) >= 1
    assert np.min(np.abs(stamps[:, None] - overlap[None, :]), axis=0).max() < 1e-9
    # no-return beams (81.83 in this log) are +inf, everything else below 80 m
    ranges = np.concatenate([f.scan.ranges for f in frames])
    assert np.all((ranges < 80.0) | np.isinf(ranges))


# -- input limits (issue 18) -------------------------------------------------------------
def _walk(n, step_m=0.1, dt=0.5, start=10.0):
    """n FLASER lines of a robot driving along x at step_m per dt (plausible)."""
    return [flaser([1.0 + 0.01 * i] * 180, start + dt * i, [step_m * i, 0.0, 0.0]) for i in range(n)]


@pytest.mark.parametrize("bad_pose, reason", [
    ([1e308, 0.0, 0.0], "odometry pose beyond max_coordinate_m (bridged)"),
    ([float("nan"), 0.0, 0.0], "non-finite odometry pose (bridged)"),
    ([0.3, float("-inf"), 0.0], "non-finite odometry pose (bridged)"),
    ([100.0, 0.0, 0.0], "implausible odometry increment (too fast) (bridged)"),
    ([0.3, 0.0, math.pi], "implausible odometry increment (turns too fast) (bridged)"),
])
def test_bad_odometry_is_bridged_counted_and_strict_raises(tmp_path, bad_pose, reason):
    lines = _walk(6)
    lines[3] = flaser([1.0] * 180, 11.5, bad_pose)
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path)
    assert len(frames) == 6                       # every scan is kept
    poses = np.array([f.odometry for f in frames])
    assert np.all(np.isfinite(poses))
    # the bad step repeats the previous velocity (0.1 m per 0.5 s); a spike re-anchors, so
    # the way back is bridged too; the robot's steady motion comes out unchanged
    np.testing.assert_allclose(np.diff(poses[:, 0]), 0.1, atol=1e-9)
    np.testing.assert_allclose(poses[:, 1:], 0.0, atol=1e-9)
    assert np.all(np.abs(poses[:, 2]) <= math.pi)
    assert reader.skipped.counts[reason] >= 1
    assert f"{path}:4: {reason}" in reader.skipped.examples
    with pytest.raises(InputError) as info:
        list(CarmenReader(path, strict=True))
    assert (info.value.path, info.value.line) == (str(path), 4)


def test_clean_odometry_passes_bit_for_bit_and_headings_are_wrapped(tmp_path):
    lines = [flaser([1.0] * 180, 1.0 + i, [0.3 * i, -0.2 * i, 3.0 + 0.5 * i]) for i in range(5)]
    reader, frames = _frames(write_log(tmp_path, lines))
    assert reader.skipped.total == 0
    for i, f in enumerate(frames):
        assert f.odometry[:2].tolist() == [0.3 * i, -0.2 * i]
        assert f.odometry[2] == pytest.approx(float(wrap_angle(3.0 + 0.5 * i)), abs=1e-12)


def test_bad_first_odometry_skips_its_scan(tmp_path):
    lines = _walk(3)
    lines[0] = flaser([1.0] * 180, 10.0, [float("nan"), 0.0, 0.0])
    reader, frames = _frames(write_log(tmp_path, lines))
    assert len(frames) == 2 and reader.skipped.counts == {"non-finite odometry pose (scan skipped)": 1}


def test_bad_param_offset_and_laser_pose_are_counted_not_fatal(tmp_path):
    lines = ["PARAM robot_frontlaser_offset nan host 0", "PARAM robot_frontlaser_side_offset 1e300 host 0",
             "PARAM robot_frontlaser_angular_offset 1000.0 host 0",
             "PARAM robot_frontlaser_angular_offset 4.0 host 0", *_walk(3)]
    lines[5] = flaser([1.0] * 180, 10.5, [0.1, 0, 0], laser=[float("nan"), 0, 0])
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path)
    assert len(frames) == 3
    assert reader.skipped.counts == {"invalid laser offset in PARAM (ignored)": 3,
                                     "non-finite laser pose (PARAM offset used)": 1}
    for f in frames:   # the valid angular offset is wrapped, the invalid ones left at 0
        np.testing.assert_allclose(f.laser_offset, [0.0, 0.0, float(wrap_angle(4.0))])
    assert f"{path}:1: invalid laser offset in PARAM (ignored)" in reader.skipped.examples
    with pytest.raises(InputError, match="PARAM") as info:
        list(CarmenReader(path, strict=True))
    assert info.value.line == 1


def test_stream_is_chosen_by_valid_scans_not_first_lines(tmp_path):
    bad = [robotlaser([1.0] * 4, 1.0 + 0.01 * i, [0, 0, 0], [0, 0, 0]).replace(" 4 ", " 9 ", 1) for i in range(20)]
    lines = bad + _walk(30)
    reader, frames = _frames(write_log(tmp_path, lines))
    assert reader.laser_message == "FLASER" and len(frames) == 30
    # the malformed ROBOTLASER1 lines are not the chosen stream: ignored, not skips
    assert reader.skipped.total == 0 and reader.skipped.ignored == {"other_messages": 20}


@pytest.mark.parametrize("lines", [[], ["# only a comment"], [odom([0, 0, 0], 1.0), odom([1, 0, 0], 2.0)],
                                   ["FLASER 2 1.0", "garbage line"]])
@pytest.mark.parametrize("strict", [False, True])
def test_no_valid_scan_is_an_error_in_both_modes(tmp_path, lines, strict):
    path = write_log(tmp_path, lines)
    with pytest.raises(InputError, match="no laser scans|malformed") as info:
        list(CarmenReader(path, strict=strict))
    assert info.value.path == str(path)


@pytest.mark.parametrize("head, what", [(b"\x1f\x8b\x08\x00", "gzip"), (b"\x89PNG\r\n\x1a\n\x00\x00", "PNG"),
                                        ("FLASER 1 1.0".encode("utf-16"), "UTF-16"),
                                        (b"FLASER\x00\x00\x01", "binary")])
def test_binary_content_is_a_clear_error(tmp_path, head, what):
    path = tmp_path / "log.clf"
    path.write_bytes(head + b"\x00" * 100)
    with pytest.raises(InputError, match=what) as info:
        CarmenReader(path)
    assert info.value.path == str(path)


def test_fifo_and_devices_are_refused_before_opening(tmp_path):
    fifo = tmp_path / "pipe.clf"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        CarmenReader(fifo)           # would block forever if it were opened
    with pytest.raises(InputError, match="not a regular file"):
        CarmenReader("/dev/null")


def test_bom_and_crlf_are_accepted(tmp_path):
    path = tmp_path / "log.clf"
    path.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(_walk(3)).encode() + b"\r\n")
    reader, frames = _frames(path)
    assert len(frames) == 3 and reader.skipped.total == 0


def test_too_many_beams_and_overlong_lines_are_skipped(tmp_path):
    config = ReaderConfig(limits=InputLimits(max_beams=200))
    lines = _walk(3)
    lines.insert(1, flaser([1.0] * 300, 10.2, [0, 0, 0]))             # too many beams
    lines.insert(2, flaser([1.0] * 5000, 10.3, [0, 0, 0]))            # longer than a line may be
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path, config=config)
    assert len(frames) == 3
    assert reader.skipped.counts == {"too many beams": 1, "line too long": 1}
    assert f"{path}:3: line too long" in reader.skipped.examples


def test_angle_increment_zero_and_negative_ranges(tmp_path):
    lines = [odom([0, 0, 0], 0.5), rawlaser([1.0] * 5, 1.0, res=0.0), rawlaser([1.0, -2.0, 3.0], 2.0),
             odom([0, 0, 0], 3.0)]
    path = write_log(tmp_path, lines)
    reader, frames = _frames(path)
    assert len(frames) == 1 and np.isnan(frames[0].scan.ranges[1])
    assert reader.skipped.counts == {"angle increment 0": 1, "negative ranges (kept as invalid beams)": 1}
    with pytest.raises(InputError, match="angle increment 0") as info:
        list(CarmenReader(path, strict=True))
    assert info.value.line == 2


@pytest.mark.parametrize("newline, bom", [("\n", ""), ("\r\n", "\ufeff")])
def test_expected_frames_counts_the_streams_lines_across_reads(tmp_path, newline, bom):
    """The count the progress bar shows: every line of the chosen stream, the one whose
    start straddles two of the counter's 1 MiB reads included; other streams and messages
    are not counted; a pass yields as many frames."""
    lines = []
    for i in range(600):
        lines += [odom([0.01 * i, 0, 0], i + 0.5), flaser([2.0 + 1e-3 * i] * 361, i + 1.0, [0.01 * i, 0, 0])]
        if i % 7 == 0:
            lines.append(rawlaser([1.0] * 3, i + 1.0))
    lines.append(odom([6.0, 0, 0], 601.0))
    text = (bom + newline.join(lines) + newline).encode()
    # pad a message the reader ignores so that the read boundary falls inside "\nFLASER "
    before = text.rindex(b"\nFLASER ", 0, 1 << 20)
    pad = (1 << 20) - 3 - before - len(b"PAD " + newline.encode())
    at = text.rindex(b"\n", 0, before) + 1
    text = text[:at] + b"PAD " + b"x" * pad + newline.encode() + text[at:]
    assert text[(1 << 20) - 3:(1 << 20) + 5] == b"\nFLASER "     # split after "\nFL"
    path = tmp_path / "log.clf"
    path.write_bytes(text)
    reader, frames = _frames(path)
    assert reader.laser_message == "FLASER"
    assert reader.expected_frames == len(frames) == 600
    assert CarmenReader(path, config=ReaderConfig(laser_message="RAWLASER1")).expected_frames == 86
