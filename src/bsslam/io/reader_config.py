"""Settings of the log readers (how to recognise "no return", which stream to read).

These describe the *input data*, not the filter, so they live apart from
:class:`bsslam.config.SLAMConfig`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bsslam.errors import ConfigError
from bsslam.input_limits import InputLimits

# CARMEN laser messages a reader can turn into frames, best first: ROBOTLASER1 carries its
# own beam angles and both the laser and the robot pose; FLASER the odometry pose; RAWLASER1
# needs ODOM messages interpolated to its stamp. The rear/extra lasers come last.
CARMEN_LASER_MESSAGES = ("ROBOTLASER1", "FLASER", "RAWLASER1",
                         "ROBOTLASER2", "RLASER", "RAWLASER2", "RAWLASER3", "RAWLASER4")


@dataclass(frozen=True)
class ReaderConfig:
    """How readers interpret ranges and choose streams.

    No-return rule: a beam is "no return" (set to +inf, and the scan's ``max_range`` set to
    the threshold) when its range is ≥ the smallest of

    * ``no_return_m`` (default 80 m: CARMEN loggers write 81.83 or 81.91 for SICK lasers),
    * the message's own maximum range (RAWLASER/ROBOTLASER ``max_range``, ROS ``range_max``),
    * the logger's no-return code detected from the data (CARMEN only, see below).

    Code detection (``detect_no_return_code``): some loggers write other codes (50.0, 51.1,
    32.77 …). Among the first ``code_detection_scans`` scans of the chosen stream, take
    the value that is most often a scan's maximum; it is the code when it is
    ≥ ``code_min_m`` and is the maximum of at least ``code_min_share`` of those scans
    (and of at least two). Real returns that far away vary from scan to scan, so they do
    not repeat exactly as a maximum; a robot standing still facing a far wall for much of
    the first scans could fool it: disable detection or lower ``no_return_m`` then.

    Attributes:
        no_return_m: ranges at or above this are no return (m).
        detect_no_return_code: look for a logger-specific no-return code (CARMEN).
        code_min_m: smallest value that can be a no-return code (m).
        code_min_share: fraction (0..1] of the examined scans whose maximum the code must be.
        code_detection_scans: how many scans from the start of the log to examine.
        laser_message: CARMEN laser message type to read (e.g. "FLASER", "RLASER",
            "RAWLASER1"); None picks the best present at the start of the log in the order
            ROBOTLASER1, FLASER, RAWLASER1, ROBOTLASER2, RLASER, RAWLASER2…4. Other laser
            streams are skipped (one physical laser is often logged twice).
        tf_odom_frame: ROS: parent frame of the odometry transform in ``/tf``.
        tf_base_frame: ROS: child (robot) frame of that transform; None takes the first
            child of ``tf_odom_frame`` seen.
        limits: physical limits every scan and odometry pose is checked against (beams
            per scan, plausible speed and turn rate, coordinate range; see
            :class:`~bsslam.input_limits.InputLimits`).
        carmen_sweep_time_s: CARMEN: the time a laser takes from its first beam to its
            last (s), which the log does not record; ROS bags give it in each message
            (``time_increment``). Default 1/150 s, the 180° of a SICK LMS 2xx, whose mirror
            turns at 75 Hz (the laser of the classic CARMEN logs); 0 takes every scan as
            instantaneous. Scans finer than one beam per degree are taken as instantaneous
            whatever this says: the LMS interlaces them over several turns of its mirror.
            See :func:`bsslam.scan.deskew`.
    """

    no_return_m: float = 80.0
    detect_no_return_code: bool = True
    code_min_m: float = 20.0
    code_min_share: float = 0.1
    code_detection_scans: int = 200
    laser_message: str | None = None
    tf_odom_frame: str = "odom"
    tf_base_frame: str | None = None
    limits: InputLimits = InputLimits()
    carmen_sweep_time_s: float = 1.0 / 150.0

    def __post_init__(self) -> None:
        if not self.no_return_m > 0:
            raise ConfigError(f"no_return_m must be > 0, got {self.no_return_m}")
        if not self.code_min_m > 0:
            raise ConfigError(f"code_min_m must be > 0, got {self.code_min_m}")
        if not 0 < self.code_min_share <= 1:
            raise ConfigError(f"code_min_share must be in (0, 1], got {self.code_min_share}")
        if self.code_detection_scans < 1:
            raise ConfigError(f"code_detection_scans must be ≥ 1, got {self.code_detection_scans}")
        if not (math.isfinite(self.carmen_sweep_time_s) and 0.0 <= self.carmen_sweep_time_s <= 1.0):
            raise ConfigError(f"carmen_sweep_time_s must be in [0, 1] s, got {self.carmen_sweep_time_s}")
        if not isinstance(self.limits, InputLimits):
            raise ConfigError(f"limits must be an InputLimits, got {type(self.limits).__name__}")
        if self.laser_message is not None and self.laser_message not in CARMEN_LASER_MESSAGES:
            raise ConfigError(f"laser_message must be one of {CARMEN_LASER_MESSAGES}, got {self.laser_message!r}")
