"""The pure input checks shared by the readers and the public API."""

import math

import numpy as np
import pytest

from bsslam.errors import ConfigError
from bsslam.input_limits import (InputLimits, OdometryGate, angles_problem, beam_geometry_problem,
                                 increment_problem, invalid_ranges, offset_problem, pose_problem)
from bsslam.se2 import between

LIMITS = InputLimits()


@pytest.mark.parametrize("kwargs", [dict(max_beams=0), dict(max_speed_m_s=0.0), dict(min_dt_s=float("nan")),
                                    dict(max_turn_rad_s=-1.0), dict(max_coordinate_m=float("inf"))])
def test_limits_are_validated(kwargs):
    with pytest.raises(ConfigError):
        InputLimits(**kwargs)


def test_pose_and_offset_checks():
    assert pose_problem([1.0, 2.0, 100.0], LIMITS) is None          # headings are wrapped later
    assert pose_problem([np.nan, 0, 0], LIMITS) == "non-finite odometry pose"
    assert pose_problem([0, 2e6, 0], LIMITS) == "odometry pose beyond max_coordinate_m"
    assert pose_problem([0, 0], LIMITS).startswith("odometry pose must have 3 values")
    assert offset_problem([0.2, 0.0, 3.0], LIMITS) is None
    assert offset_problem([20.0, 0.0, 0.0], LIMITS) == "laser offset beyond max_laser_offset_m"
    assert offset_problem([0.0, np.inf, 0.0], LIMITS) == "non-finite laser offset"


@pytest.mark.parametrize("n, start, inc, end, reason", [
    (181, -math.pi / 2, math.pi / 180, math.pi / 2, None),
    (181, -math.pi / 2, math.pi / 180, math.pi / 2 + math.pi / 180, None),     # one beam off: tolerated
    (181, -math.pi / 2, math.pi / 180, None, None),
    (0, 0.0, 0.1, None, "empty scan"),
    (10_001, 0.0, 1e-4, None, "too many beams"),
    (10, 0.0, 0.0, None, "angle increment 0"),
    (10, np.nan, 0.1, None, "non-finite beam angles in the header"),
    (10, 0.0, np.inf, None, "non-finite beam angles in the header"),
    (1000, 0.0, 0.1, None, "beams span more than a full turn"),
    (181, -math.pi / 2, math.pi / 180, 3.0, "angle_max disagrees with angle_min + (n−1)·angle_increment"),
    (181, -math.pi / 2, math.pi / 180, np.nan, "non-finite angle_max"),
])
def test_beam_geometry(n, start, inc, end, reason):
    assert beam_geometry_problem(n, start, inc, LIMITS, end_rad=end) == reason


def test_explicit_angles_and_ranges():
    assert angles_problem(np.linspace(-1, 1, 5), LIMITS) is None
    assert angles_problem(np.zeros(3), LIMITS) == "angle increment 0"
    assert angles_problem(np.array([0.0, 1.0, 0.5]), LIMITS) == "beam angles not strictly increasing"
    assert angles_problem(np.array([0.0, np.nan]), LIMITS) == "non-finite beam angles"
    assert angles_problem(np.zeros(0), LIMITS) == "empty scan"
    r, nonfinite, negative = invalid_ranges([1.0, -2.0, np.nan, np.inf, -np.inf])
    assert (nonfinite, negative) == (3, 2)
    assert r[0] == 1.0 and np.isnan(r[1]) and np.isnan(r[2]) and r[3] == np.inf and np.isnan(r[4])


def test_increment_plausibility_uses_a_minimum_dt():
    assert increment_problem([0.5, 0, 0], 1.0, LIMITS) is None
    assert increment_problem([3.5, 0, 0], 1.0, LIMITS) == "implausible odometry increment (too fast)"
    # stamps 1 ms apart: judged over min_dt_s (0.2 s → 0.6 m, 0.8 rad)
    assert increment_problem([0.5, 0, 0.5], 0.001, LIMITS) is None
    assert increment_problem([0.0, 0.0, math.pi], 0.001, LIMITS) == "implausible odometry increment (turns too fast)"
    assert increment_problem([0.0, 0.0, 2 * math.pi], 0.001, LIMITS) is None     # a full turn is no turn
    assert increment_problem([np.nan, 0, 0], None, LIMITS) == "non-finite odometry increment"
    assert increment_problem([1e3, 0, 0], None, LIMITS) is None                  # no stamps: finiteness only


def test_gate_passes_clean_poses_bit_for_bit_and_bridges_bad_steps():
    gate = OdometryGate(LIMITS)
    raw = [[0.0, 0.0, 0.0], [0.3, 0.0, 0.1], [100.0, 0.0, 0.1], [100.3, 0.1, 0.2], [np.nan, 0, 0],
           [100.9, 0.2, 0.3]]
    out = [gate.accept(float(k), pose) for k, pose in enumerate(raw)]
    assert out[0][1] is None and out[0][0].tolist() == raw[0]
    assert out[1][1] is None and out[1][0].tolist() == raw[1]          # unchanged, bit for bit
    assert out[2][1] == "implausible odometry increment (too fast)"
    # the bridge repeats the previous plausible increment (same duration: 1 s)
    np.testing.assert_allclose(between(out[1][0], out[2][0]), between(raw[0], raw[1]), atol=1e-12)
    assert out[3][1] is None                                          # re-anchored at the jump
    np.testing.assert_allclose(between(out[2][0], out[3][0]), between(raw[2], raw[3]), atol=1e-12)
    assert out[4][1] == "non-finite odometry pose"
    np.testing.assert_allclose(between(out[3][0], out[4][0]), between(raw[2], raw[3]), atol=1e-12)
    # after an invalid pose the next increment is measured from the last valid one
    np.testing.assert_allclose(between(out[3][0], out[5][0]), between(raw[3], raw[5]), atol=1e-12)


def test_gate_bridges_with_zero_motion_before_any_step_and_never_extrapolates_a_gap():
    gate = OdometryGate(LIMITS)
    gate.accept(0.0, [0.0, 0.0, 0.0])
    pose, reason = gate.accept(1.0, [50.0, 0.0, 0.0])
    assert reason is not None and pose.tolist() == [0.0, 0.0, 0.0]   # no velocity yet
    gate.accept(2.0, [50.5, 0.0, 0.0])                                # 0.5 m in 1 s
    pose, reason = gate.accept(1000.0, [np.inf, 0.0, 0.0])            # a long gap: one step at most
    assert reason is not None and pose[0] == pytest.approx(1.0)


def test_gate_without_a_first_valid_pose_returns_none():
    gate = OdometryGate(LIMITS)
    assert gate.accept(0.0, [np.inf, 0, 0]) == (None, "non-finite odometry pose")
    pose, reason = gate.accept(1.0, [0.0, 0.0, 7.0])
    assert reason is None and pose[2] == pytest.approx(7.0 - 2 * math.pi)
