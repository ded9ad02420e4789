"""Physical limits of the input (laser scans and odometry) and the pure checks against them.

One set of checks for every way data enters bsslam: the log readers (:mod:`bsslam.io`)
call them once per message, and the public API (``SplineSLAM.step``, a streaming mapper)
can call the same functions on what a user hands in. Nothing here reads files, prints or
raises on bad data: each check returns ``None`` for good input or a short reason string,
and the caller decides between a counted skip and an :class:`~bsslam.errors.InputError`.
That keeps the numba kernels downstream from ever seeing non-finite or huge values.

Odometry plausibility (:class:`OdometryGate`): an increment between two consecutive
odometry poses is implausible when it moves faster than ``max_speed_m_s`` or turns faster
than ``max_turn_rad_s`` over ``max(dt, min_dt_s)`` (the floor keeps two stamps a few
milliseconds apart from making every real motion "too fast"). An implausible increment
(or an invalid pose) is *bridged*: the step repeats the previous plausible velocity over
its own duration, at most one previous step long (so nothing is extrapolated over a gap;
zero motion before any plausible step), and the stream is re-anchored at the new raw pose,
so the following increments are measured from it. The front end's scan matcher then
corrects the bridged guess within its search window. On the first 80 scans of
intel-noisy.clf (steps up to 1.2 m at ~1 Hz) repeating the velocity keeps the run within
~0.3 m of the clean one where zero motion left it ~1 m off. A single spike (one pose far
off, then back) costs two bridged steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bsslam.errors import ConfigError
from bsslam.se2 import between, compose, inverse

# Bearings of one scan may cover at most a full turn; this slack allows a 360-beam scan
# whose first and last beam coincide and float round-off in the header.
_TURN_SLACK_RAD = 1e-3


@dataclass(frozen=True)
class InputLimits:
    """Physical limits of the input data (defaults for ground robots).

    Attributes:
        max_beams: most beams one scan may have; a longer scan is refused (a corrupt
            count would otherwise make one scan cost minutes).
        max_speed_m_s: fastest plausible translation of the robot (m/s).
        max_turn_rad_s: fastest plausible rotation (rad/s).
        min_dt_s: the time (s) an increment is at least allowed, however close the stamps.
        max_coordinate_m: largest plausible |x|, |y| of an odometry pose (m).
        max_laser_offset_m: largest plausible distance (m) of the laser from the robot's
            origin (PARAM offsets, the laser pose of a message).
    """

    max_beams: int = 10_000
    max_speed_m_s: float = 3.0
    max_turn_rad_s: float = 4.0
    min_dt_s: float = 0.2
    max_coordinate_m: float = 1e6
    max_laser_offset_m: float = 10.0

    def __post_init__(self) -> None:
        if not (isinstance(self.max_beams, int) and self.max_beams >= 1):
            raise ConfigError(f"max_beams must be an integer ≥ 1, got {self.max_beams!r}")
        for name in ("max_speed_m_s", "max_turn_rad_s", "min_dt_s", "max_coordinate_m", "max_laser_offset_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")


def wrap(angle: float) -> float:
    """``angle`` (rad, finite) wrapped to (−π, π]; unchanged (bit for bit) when inside."""
    if -math.pi < angle <= math.pi:
        return angle
    return math.pi - (math.pi - angle) % (2.0 * math.pi)


def pose_problem(pose, limits: InputLimits, what: str = "odometry pose") -> str | None:
    """None when ``pose`` is a (3,) finite pose within ``max_coordinate_m``; else the reason."""
    p = np.asarray(pose, dtype=float)
    if p.shape != (3,):
        return f"{what} must have 3 values, got shape {p.shape}"
    if not np.all(np.isfinite(p)):
        return f"non-finite {what}"
    if max(abs(p[0]), abs(p[1])) > limits.max_coordinate_m:
        return f"{what} beyond max_coordinate_m"
    return None


def offset_problem(offset, limits: InputLimits) -> str | None:
    """None when the laser offset (3,) (x m, y m, φ rad) is finite and within
    ``max_laser_offset_m``; else the reason."""
    o = np.asarray(offset, dtype=float)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        return "non-finite laser offset"
    if math.hypot(o[0], o[1]) > limits.max_laser_offset_m:
        return "laser offset beyond max_laser_offset_m"
    return None


def beam_geometry_problem(n: int, start_rad: float, increment_rad: float, limits: InputLimits,
                          end_rad: float | None = None) -> str | None:
    """None when ``n`` beams at ``start + i·increment`` make a sane scan; else the reason.

    Checks: 1 ≤ n ≤ ``max_beams``; start and increment finite; increment non-zero; the beams
    span at most a full turn; and, when the header states the last bearing ``end_rad``
    (ROS ``angle_max``), that it agrees with ``start + (n−1)·increment`` within two
    increments (drivers differ by one beam in how they count).
    """
    if n < 1:
        return "empty scan"
    if n > limits.max_beams:
        return "too many beams"
    if not (math.isfinite(start_rad) and math.isfinite(increment_rad)):
        return "non-finite beam angles in the header"
    if increment_rad == 0.0 and n > 1:
        return "angle increment 0"
    if (n - 1) * abs(increment_rad) > 2.0 * math.pi + _TURN_SLACK_RAD:
        return "beams span more than a full turn"
    if end_rad is not None:
        if not math.isfinite(end_rad):
            return "non-finite angle_max"
        last = start_rad + (n - 1) * increment_rad
        if abs(last - end_rad) > 2.0 * abs(increment_rad) + 1e-6:
            return "angle_max disagrees with angle_min + (n−1)·angle_increment"
    return None


def angles_problem(angles, limits: InputLimits) -> str | None:
    """None when bearings (n,) are finite, strictly increasing, at most ``max_beams`` and
    within one turn; else the reason (for scans made from explicit bearings)."""
    a = np.asarray(angles, dtype=float)
    if a.ndim != 1 or a.size == 0:
        return "empty scan"
    if a.size > limits.max_beams:
        return "too many beams"
    if not np.all(np.isfinite(a)):
        return "non-finite beam angles"
    if a.size > 1:
        step = np.diff(a)
        if np.any(step == 0):
            return "angle increment 0"
        if not np.all(step > 0):
            return "beam angles not strictly increasing"
    if a[-1] - a[0] > 2.0 * math.pi + _TURN_SLACK_RAD:
        return "beams span more than a full turn"
    return None


def invalid_ranges(ranges) -> tuple[np.ndarray, int, int]:
    """(ranges with negative and −inf values set to NaN, #non-finite, #negative).

    +inf stays +inf ("no return"); NaN is a failed measurement. Ranges above the maximum
    are the no-return rule's business (:func:`bsslam.io.no_return.mark_no_return`)."""
    r = np.array(ranges, dtype=float)
    with np.errstate(invalid="ignore"):
        negative = r < 0
    nonfinite = int(np.count_nonzero(~np.isfinite(r)))
    n_negative = int(np.count_nonzero(negative))
    if n_negative:
        r[negative] = np.nan
    return r, nonfinite, n_negative


def increment_problem(delta, dt_s: float | None, limits: InputLimits) -> str | None:
    """None when the robot-frame increment ``delta`` (3,) is finite and, with ``dt_s`` (s)
    given, within the plausible speed and turn rate; else the reason. Without ``dt_s`` (the
    filter's ``step`` sees no stamps) only finiteness and ``max_coordinate_m`` are checked."""
    d = np.asarray(delta, dtype=float)
    if d.shape != (3,) or not np.all(np.isfinite(d)):
        return "non-finite odometry increment"
    distance = math.hypot(d[0], d[1])
    if distance > limits.max_coordinate_m:
        return "odometry increment beyond max_coordinate_m"
    if dt_s is None:
        return None
    dt = max(float(dt_s), limits.min_dt_s)
    turn = abs(wrap(float(d[2])))
    if distance > limits.max_speed_m_s * dt:
        return "implausible odometry increment (too fast)"
    if turn > limits.max_turn_rad_s * dt:
        return "implausible odometry increment (turns too fast)"
    return None



class OdometryGate:
    """Checks a stream of odometry poses and bridges the implausible steps.

    Feed poses in stamp order with :meth:`accept`; it returns the pose to use (heading
    wrapped) and the reason when the raw pose was not used as is. See the module text for
    the bridging rule.

    Args:
        limits: the plausible speed, turn rate and coordinate range.
    """

    def __init__(self, limits: InputLimits) -> None:
        self.limits = limits
        self._raw: tuple[float, float, float] | None = None       # last usable raw pose
        self._raw_stamp: float | None = None
        self._out: tuple[float, float, float] | None = None       # last pose returned
        self._out_stamp: float | None = None
        # returned pose = correction ∘ raw pose; None (identity) until the first bridge,
        # so a clean stream comes out bit for bit as it went in
        self._correction: tuple[float, float, float] | None = None
        # the last plausible increment and its duration (s): what a bridge repeats
        self._last_increment: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self._last_dt = limits.min_dt_s

    def accept(self, stamp: float, pose) -> tuple[np.ndarray | None, str | None]:
        """(pose (3,) to use, None) for a plausible pose; (bridged pose, reason) for a bad
        one after the first; (None, reason) for a bad first pose (nothing to bridge from)."""
        reason = pose_problem(pose, self.limits)
        raw = None
        if reason is None:
            x, y, phi = (float(v) for v in np.asarray(pose, dtype=float))
            raw = (x, y, wrap(phi))
            previous, previous_stamp = self._raw, self._raw_stamp
            self._raw, self._raw_stamp = raw, stamp   # re-anchored here even when implausible
            if previous is not None:
                delta = between(previous, raw)
                reason = increment_problem(delta, stamp - previous_stamp, self.limits)
            if reason is None:
                if previous is not None:
                    self._last_increment, self._last_dt = tuple(delta), max(stamp - previous_stamp, self.limits.min_dt_s)
                self._out = raw if self._correction is None else tuple(compose(self._correction, raw))
                self._out_stamp = stamp
                return np.array(self._out), None
        if self._out is None:
            return None, reason
        # bridge: the previous plausible velocity for this step's time, at most one
        # previous step long (no extrapolation over a gap)
        dt = max(stamp - self._out_stamp, self.limits.min_dt_s)
        scale = min(1.0, dt / self._last_dt)
        self._out = tuple(compose(self._out, scale * np.asarray(self._last_increment)))
        self._out_stamp = stamp
        if raw is not None:
            # later increments are measured from this raw pose
            self._correction = tuple(compose(self._out, inverse(raw)))
        return np.array(self._out), reason
