"""Parsing single CARMEN log lines into typed messages (no file handling here).

Layouts (fields separated by whitespace; every message ends ``ipc_ts host logger_ts``)::

    ODOM x y theta tv rv accel ...
    PARAM name value ...
    FLASER|RLASER n r_1..r_n x y theta odom_x odom_y odom_theta ...
    RAWLASER1..4 laser_type start_angle fov angular_res max_range accuracy remission_mode
                 n r_1..r_n n_rem rem_1..rem_n_rem ...
    ROBOTLASER1|2 laser_type start_angle fov angular_res max_range accuracy remission_mode
                 n r_1..r_n n_rem rem.. laser_x laser_y laser_theta robot_x robot_y robot_theta
                 tv rv forward_safety side_safety turn_axis ...

Stamps are the ipc timestamp (third field from the end): the time the message was
produced on the robot, which the ``*.gt.txt`` references and the relations files use
(in the shipped logs it equals the logger timestamp).

FLASER/RLASER carry no beam geometry; CARMEN's convention is a 180° scan whose first beam
points at −90° (the laser's right), 1° apart for 180/181 beams and 0.5° for 360/361;
any other count spreads the beams evenly over −90°…+90° (both ends included).

A line that does not fit its layout raises :class:`MalformedLine`; the reader decides
whether that is a counted skip or an :class:`~bsslam.errors.InputError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


class MalformedLine(ValueError):
    """A line that does not fit its message layout; ``reason`` is a short category."""

    def __init__(self, reason: str, detail: str = ""):
        self.reason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}" if detail else reason)


@dataclass(frozen=True)
class LaserMessage:
    """One laser message.

    Attributes:
        kind: the message type ("FLASER", "RAWLASER1", …).
        stamp: ipc timestamp (s).
        angles: (n,) beam bearings in the laser frame (rad).
        ranges: (n,) ranges as logged (m).
        max_range_m: the message's maximum range (m), or None when the layout has none.
        robot_pose: (3,) odometry pose of the robot (x m, y m, φ rad), or None (RAWLASER).
        laser_pose: (3,) odometry pose of the laser, or None (RAWLASER).
    """

    kind: str
    stamp: float
    angles: np.ndarray
    ranges: np.ndarray
    max_range_m: float | None
    robot_pose: np.ndarray | None
    laser_pose: np.ndarray | None


def carmen_beam_angles(n: int) -> np.ndarray:
    """(n,) bearings (rad) of an n-beam FLASER/RLASER scan by the CARMEN convention."""
    if n in (180, 181):
        step = math.radians(1.0)
    elif n in (360, 361):
        step = math.radians(0.5)
    else:
        step = math.pi / (n - 1) if n > 1 else 0.0
    return -0.5 * math.pi + step * np.arange(n)


def _floats(fields: list[str], what: str) -> np.ndarray:
    try:
        return np.array(fields, dtype=float)
    except ValueError:
        raise MalformedLine("non-numeric value", f"in the {what}") from None


def _count(text: str, what: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise MalformedLine("non-numeric value", f"{what} {text!r} is not an integer") from None
    if n < 0:
        raise MalformedLine("negative count", f"{what} = {n}")
    return n


def _check_length(fields: list[str], expected: int) -> None:
    if len(fields) != expected:
        raise MalformedLine("wrong field count", f"{fields[0]} needs {expected} fields, got {len(fields)}")


def _stamp(fields: list[str]) -> float:
    # ipc timestamp; the host name and the logger timestamp follow it
    stamp = float(_floats(fields[-3:-2], "timestamp")[0])
    if not math.isfinite(stamp):
        raise MalformedLine("non-finite timestamp", fields[-3])
    return stamp


def parse_odom(fields: list[str]) -> tuple[float, np.ndarray]:
    """ODOM → (stamp s, pose (3,) x m, y m, θ rad)."""
    _check_length(fields, 10)
    return _stamp(fields), _floats(fields[1:4], "pose")


def parse_param(fields: list[str]) -> tuple[str, str]:
    """PARAM → (name, value text)."""
    if len(fields) < 3:
        raise MalformedLine("wrong field count", f"PARAM needs a name and a value, got {len(fields)} fields")
    return fields[1], fields[2]


def parse_flaser(fields: list[str]) -> LaserMessage:
    """FLASER/RLASER (old format, CARMEN beam geometry)."""
    if len(fields) < 2:
        raise MalformedLine("wrong field count", f"{fields[0]} without a beam count")
    n = _count(fields[1], "beam count")
    _check_length(fields, n + 11)
    ranges = _floats(fields[2:2 + n], "ranges")
    poses = _floats(fields[2 + n:8 + n], "poses")
    return LaserMessage(fields[0], _stamp(fields), carmen_beam_angles(n), ranges, None,
                        robot_pose=poses[3:6], laser_pose=poses[0:3])


def _parse_laser_block(fields: list[str], tail: int) -> tuple[np.ndarray, np.ndarray, float, int]:
    """The part RAWLASER and ROBOTLASER share: (angles, ranges, max_range_m, index after
    the remissions). ``tail`` is the number of fields after the remissions."""
    if len(fields) < 10:
        raise MalformedLine("wrong field count", f"{fields[0]} is too short ({len(fields)} fields)")
    header = _floats(fields[2:6], "laser header")
    start_angle, _fov, angular_res, max_range = header
    n = _count(fields[8], "beam count")
    if len(fields) < 10 + n:
        raise MalformedLine("wrong field count", f"{fields[0]} ends inside its {n} ranges")
    n_rem = _count(fields[9 + n], "remission count")
    end = 10 + n + n_rem
    _check_length(fields, end + tail)
    ranges = _floats(fields[9:9 + n], "ranges")
    angles = start_angle + angular_res * np.arange(n)
    return angles, ranges, float(max_range), end


def parse_rawlaser(fields: list[str]) -> LaserMessage:
    """RAWLASER1–4: beam geometry from the message; no pose (odometry comes from ODOM)."""
    angles, ranges, max_range, _ = _parse_laser_block(fields, tail=3)
    return LaserMessage(fields[0], _stamp(fields), angles, ranges, max_range, None, None)


def parse_robotlaser(fields: list[str]) -> LaserMessage:
    """ROBOTLASER1/2: beam geometry from the message, laser and robot odometry poses."""
    angles, ranges, max_range, end = _parse_laser_block(fields, tail=11 + 3)
    poses = _floats(fields[end:end + 6], "poses")
    return LaserMessage(fields[0], _stamp(fields), angles, ranges, max_range,
                        robot_pose=poses[3:6], laser_pose=poses[0:3])


LASER_PARSERS = {
    "FLASER": parse_flaser, "RLASER": parse_flaser,
    "RAWLASER1": parse_rawlaser, "RAWLASER2": parse_rawlaser,
    "RAWLASER3": parse_rawlaser, "RAWLASER4": parse_rawlaser,
    "ROBOTLASER1": parse_robotlaser, "ROBOTLASER2": parse_robotlaser,
}
