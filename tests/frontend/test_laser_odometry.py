"""LaserOdometry: increments on simulated runs, fallbacks, and (when the logs are present)
a short real log."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from bsslam.config import MotionNoiseConfig
from bsslam.dataset import Frame
from bsslam.eval import ate
from bsslam.frontend import FrontendConfig, LaserOdometry
from bsslam.frontend.scan_matcher import MatchResult
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import between, compose
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.trajectory import Trajectory

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def _run(frames, config=FrontendConfig()):
    lo = LaserOdometry(config)
    return lo, [lo.step(f) for f in frames]


def test_first_frame_starts_at_odometry_and_reports_no_increment():
    data = simulate(get_world("mixed"), SimConfig(), seed=0, steps=3)
    frames = list(data)
    lo, out = _run(frames)
    assert out[0].increment is None and out[0].covariance is None and out[0].keyframe
    np.testing.assert_array_equal(out[0].pose, frames[0].odometry)
    for k in (1, 2):
        assert out[k].increment.shape == (3,) and out[k].covariance.shape == (3, 3)
        np.testing.assert_allclose(out[k].pose, compose(out[k - 1].pose, out[k].increment), atol=1e-12)
        np.testing.assert_allclose(out[k].odometry_increment, between(frames[k - 1].odometry, frames[k].odometry))
        assert np.all(np.linalg.eigvalsh(out[k].covariance) > 0)
    assert lo.stats.frames == 3 and lo.stats.matched == 2 and lo.stats.fallbacks == 0


@pytest.mark.parametrize("world", ["mixed", "rounded-room"])
def test_drift_far_below_odometry_on_a_simulated_run(world):
    # Odometry three times noisier than the simulator's default, so it drifts visibly.
    motion = MotionNoiseConfig()
    motion = replace(motion, a_xy_m=3 * motion.a_xy_m, b_xy=3 * motion.b_xy, a_phi_rad=3 * motion.a_phi_rad,
                     b_phi=3 * motion.b_phi)
    data = simulate(get_world(world), SimConfig(sigma_range_m=0.01, motion=motion), seed=4, steps=120)
    frames, truth = list(data), data.ground_truth
    lo, out = _run(frames)
    stamps = np.array([f.stamp for f in frames])
    est = Trajectory(stamps, np.array([o.pose for o in out]))
    odo = Trajectory(stamps, np.array([f.odometry for f in frames]))
    ate_fe, ate_odo = ate(est, truth)[0], ate(odo, truth)[0]
    assert lo.stats.fallbacks == 0
    assert ate_fe < 0.2 * ate_odo, (ate_fe, ate_odo)
    assert ate_fe < 0.1
    # Increments: each error within 4σ of its covariance (the covariance is not overconfident).
    true_inc = between(truth.poses[:-1], truth.poses[1:])
    for o, t in zip(out[1:], true_inc):
        e = between(t, o.increment)
        assert e @ np.linalg.solve(o.covariance, e) < 16.0 * 3
    print(f"{world}: ATE front end {ate_fe:.3f} m, odometry {ate_odo:.3f} m")


def test_empty_scans_fall_back_to_odometry_and_are_counted():
    data = simulate(get_world("mixed"), SimConfig(), seed=2, steps=8)
    frames = list(data)
    empty = LaserScan(0.0, frames[0].scan.angles, np.full(frames[0].scan.angles.shape, np.inf), 8.0)
    frames[4] = Frame(frames[4].stamp, frames[4].odometry, empty, frames[4].laser_offset)
    frames[5] = Frame(frames[5].stamp, frames[5].odometry, empty, frames[5].laser_offset)
    config = FrontendConfig()
    lo, out = _run(frames, config)
    for k in (4, 5):
        assert out[k].fallback
        np.testing.assert_allclose(out[k].increment, out[k].odometry_increment)
        np.testing.assert_allclose(out[k].covariance, lo.odometry_covariance(out[k].odometry_increment))
    assert lo.stats.fallbacks == 2
    assert lo.stats.reasons == {"too_few_scan_points": 2}
    # The scan after the gap is matched again.
    assert not out[6].fallback and not out[7].fallback


def test_all_empty_scans_never_match():
    data = simulate(get_world("mixed"), SimConfig(), seed=2, steps=4)
    frames = [Frame(f.stamp, f.odometry, LaserScan(0.0, np.zeros(0), np.zeros(0), 8.0)) for f in data]
    lo, out = _run(frames)
    assert all(o.fallback for o in out[1:])
    assert lo.stats.fallbacks == 3 and lo.stats.matched == 0
    np.testing.assert_allclose(out[-1].pose, frames[-1].odometry, atol=1e-9)


def test_laser_offset_does_not_bias_the_increments():
    data = simulate(get_world("mixed"), SimConfig(), seed=5, steps=15)
    frames, truth = list(data), data.ground_truth
    # Re-cast the scans from a laser mounted 0.3 m ahead, turned 0.2 rad.
    from bsslam.sim import ray_cast
    offset = np.array([0.3, 0.05, 0.2])
    world = get_world("mixed")
    moved = []
    for f, pose in zip(frames, truth.poses):
        lp = compose(pose, offset)
        ranges = ray_cast(world.walls, lp[:2], lp[2] + f.scan.angles, f.scan.max_range)
        ranges = np.where(np.isfinite(ranges), ranges, f.scan.max_range)
        moved.append(Frame(f.stamp, f.odometry, LaserScan(f.stamp, f.scan.angles, ranges, f.scan.max_range), offset))
    lo, out = _run(moved)
    true_inc = between(truth.poses[:-1], truth.poses[1:])
    err = np.array([between(t, o.increment) for o, t in zip(out[1:], true_inc)])
    assert lo.stats.fallbacks == 0
    assert np.max(np.hypot(err[:, 0], err[:, 1])) < 0.01 and np.max(np.abs(err[:, 2])) < math.radians(0.3)


@pytest.mark.skipif(not (DATA / "intel" / "intel-noisy.clf").exists(), reason="shared/data logs not present")
def test_short_real_log_beats_odometry():
    from bsslam.io.open_dataset import open_dataset
    from bsslam.io.trajectory_file import read_trajectory

    frames = []
    for i, f in enumerate(open_dataset(DATA / "intel" / "intel-noisy.clf")):
        if i >= 150:
            break
        frames.append(f)
    ref = read_trajectory(DATA / "intel" / "intel-noisy.gt.txt")
    lo, out = _run(frames)
    stamps = np.array([f.stamp for f in frames])
    est = Trajectory(stamps, np.array([o.pose for o in out]))
    odo = Trajectory(stamps, np.array([f.odometry for f in frames]))
    assert ate(est, ref)[0] < 0.5 * ate(odo, ref)[0]
    assert lo.stats.fallbacks <= 5


def test_scalar_pose_helpers_equal_se2_bit_for_bit():
    """The front end's float-triple compose/between do se2's arithmetic exactly."""
    from bsslam.frontend.laser_odometry import _between, _compose
    from bsslam.se2 import between, compose

    rng = np.random.default_rng(3)
    a = rng.uniform(-50.0, 50.0, size=(2000, 3))
    b = rng.uniform(-50.0, 50.0, size=(2000, 3))
    a[:, 2] = rng.uniform(-7.0, 7.0, 2000)
    b[:, 2] = rng.uniform(-7.0, 7.0, 2000)
    a[:5, 2] = [0.0, np.pi, -np.pi, 2 * np.pi, -0.0]
    for i in range(a.shape[0]):
        pa, pb = tuple(a[i].tolist()), tuple(b[i].tolist())
        assert np.array_equal(np.array(_compose(pa, pb)), compose(a[i], b[i]))
        assert np.array_equal(np.array(_between(pa, pb)), between(a[i], b[i]))


def test_the_odometry_gate_is_the_chi2_region_of_both_covariances():
    """The decision is d (S_match + S_odo)⁻¹ dᵀ ≤ χ²₃ quantile (scipy as the oracle), with
    the heading difference wrapped; a gate of 1 takes every match."""

    rng = np.random.default_rng(5)
    lo = LaserOdometry(FrontendConfig())
    threshold = chi2.ppf(0.99, 3)
    decided = []
    for _ in range(300):
        odo = rng.normal(0, [0.5, 0.5, 0.5])
        A, B = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
        S_match, S_odo = 0.01 * (A @ A.T + 0.1 * np.eye(3)), 0.01 * (B @ B.T + 0.1 * np.eye(3))
        inc = odo + rng.normal(0, 0.4, 3)
        d = inc - odo
        expected = d @ np.linalg.solve(S_match + S_odo, d) <= threshold
        assert lo._agrees_with_odometry(inc, S_match, odo, S_odo) == expected
        turned = inc + np.array([0.0, 0.0, 2 * np.pi])       # the same heading
        assert lo._agrees_with_odometry(turned, S_match, odo, S_odo) == expected
        decided.append(expected)
    assert 0 < sum(decided) < len(decided)        # both outcomes occurred
    lo = LaserOdometry(FrontendConfig(odometry_gate=1.0))
    assert lo._agrees_with_odometry(np.array([5.0, 5.0, 3.0]), 1e-6 * np.eye(3), np.zeros(3), 1e-6 * np.eye(3))


def test_a_match_far_from_the_odometry_falls_back_to_it(monkeypatch):
    """A confident match 40° away from an odometry that says the robot went straight (what
    a corner seen again from a sparse log's 1 m step gives) is not taken: the step is the
    odometry's, counted as a fallback for that reason. With the gate off it is taken."""
    from bsslam.frontend.scan_matcher import ReferenceMap

    data = simulate(get_world("mixed"), SimConfig(), seed=0, steps=6)
    frames = list(data)
    real_match = ReferenceMap.match

    def turned(self, points, guess, prior_covariance=None, weak_prior_covariance=None):
        result = real_match(self, points, guess, prior_covariance, weak_prior_covariance)
        return replace(result, pose=result.pose + np.array([0.0, 0.0, math.radians(40.0)]))

    monkeypatch.setattr(ReferenceMap, "match", turned)
    for gate, taken in ((0.99, False), (1.0, True)):
        lo, out = _run(frames[:2], FrontendConfig(odometry_gate=gate))
        step = out[1]
        assert step.fallback != taken
        if taken:
            assert abs(math.remainder(step.increment[2] - step.odometry_increment[2], 2 * math.pi)) > math.radians(39)
        else:
            np.testing.assert_array_equal(step.increment, step.odometry_increment)
            assert lo.stats.reasons == {"inconsistent_with_odometry": 1}


def _skewed(frames, k: int, turn_rad: float):
    """``frames`` with frame k's odometry heading turned by ``turn_rad``: increment k then
    claims that much more turn and increment k + 1 that much less — the motion booked to
    the wrong one of two neighbouring increments, their composition unchanged (an odometry
    skewed in time)."""
    out = list(frames)
    odo = out[k].odometry + np.array([0.0, 0.0, turn_rad])
    out[k] = Frame(out[k].stamp, odo, out[k].scan, out[k].laser_offset)
    return out


def test_a_match_is_gated_over_two_steps_where_the_odometry_is_skewed_in_time():
    """The rounded room's robot turns 14.3° a step from step 81 on. Frame 83's odometry
    turned by 14.3° more books the turn of step 84 to step 83 (28.6° and 0°, their
    composition right), as CSAIL's odometry does. Under an odometry model whose heading σ
    grows with the turn, step 83's match is within its wide region; step 84's right match
    is 14° from an odometry that claims no turn with a σ of about 2°. Gated alone it falls
    back to that odometry; gated over two steps (the default) it is taken."""
    data = simulate(get_world("rounded-room"), SimConfig(), seed=0, steps=86)
    frames = _skewed(list(data), 83, math.radians(14.3))
    truth = data.ground_truth.poses
    model = dict(odom_sigma_rad=0.04, odom_sigma_rad_per_rad=0.4, odom_sigma_rad_per_m=0.0)
    true_inc = between(truth[83], truth[84])
    for steps in (1, 2):
        lo, out = _run(frames[:85], FrontendConfig(odometry_gate_steps=steps, **model))
        assert not out[83].fallback
        error = abs(math.remainder(out[84].increment[2] - true_inc[2], 2 * math.pi))
        if steps == 2:
            assert not out[84].fallback and lo.stats.gated_over_steps >= 1
            assert error < math.radians(1.0)
        else:
            assert out[84].fallback and lo.stats.gated_over_steps == 0
            assert error > math.radians(10.0)


def test_a_match_wrong_on_its_own_step_is_not_let_in_by_the_window(monkeypatch):
    """A match 40° off at step 2 after a right match at step 1: composed over both steps it
    is still 40° off the odometry, so the two-step gate rejects it as the one-step gate does."""
    from bsslam.frontend.scan_matcher import ReferenceMap

    data = simulate(get_world("mixed"), SimConfig(), seed=0, steps=4)
    frames = list(data)
    real_match = ReferenceMap.match
    count = []

    def turned_second(self, points, guess, prior_covariance=None, weak_prior_covariance=None):
        count.append(1)
        result = real_match(self, points, guess, prior_covariance, weak_prior_covariance)
        if len(count) == 2:
            result = replace(result, pose=result.pose + np.array([0.0, 0.0, math.radians(40.0)]))
        return result

    monkeypatch.setattr(ReferenceMap, "match", turned_second)
    lo, out = _run(frames[:3], FrontendConfig(odometry_gate_steps=3))
    assert not out[1].fallback and out[2].fallback
    assert lo.stats.reasons == {"inconsistent_with_odometry": 1} and lo.stats.gated_over_steps == 0


def test_the_gate_over_steps_is_the_chi2_test_of_the_composed_increments():
    """_agrees_over_steps against an oracle written out here: the increments composed by
    se2.compose, the matches' covariances and the last odometry increment's (only: the
    window adds no freedom of the earlier odometry steps) propagated by finite-difference
    Jacobians of that composition, the χ²₃ median from scipy (the window has to explain
    the disagreement, not merely pass the gate's 99 % region)."""

    rng = np.random.default_rng(11)
    lo = LaserOdometry(FrontendConfig(odometry_gate_steps=2))
    threshold = chi2.ppf(0.5, 3)

    def fd_cov(a, Pa, b, Pb):
        J = np.zeros((3, 6))
        x0 = np.r_[a, b]
        for i in range(6):
            h = np.zeros(6); h[i] = 1e-6
            d = compose((x0 + h)[:3], (x0 + h)[3:]) - compose((x0 - h)[:3], (x0 - h)[3:])
            d[2] = math.remainder(d[2], 2 * math.pi)
            J[:, i] = d / 2e-6
        P = np.zeros((6, 6)); P[:3, :3], P[3:, 3:] = Pa, Pb
        return J @ P @ J.T

    decided = []
    for _ in range(200):
        def cov():
            A = rng.normal(size=(3, 3))
            return 0.003 * (A @ A.T + 0.1 * np.eye(3))
        prev_match, prev_odo = rng.normal(0, [0.5, 0.2, 0.4]), rng.normal(0, [0.5, 0.2, 0.4])
        match, odo = rng.normal(0, [0.5, 0.2, 0.4]), rng.normal(0, [0.5, 0.2, 0.4])
        Pm0, _, Pm, Po = cov(), cov(), cov(), cov()      # (the second: the earlier odometry's, not used)
        lo._recent.clear()
        lo._recent.append((prev_match, Pm0, prev_odo))
        d = compose(prev_match, match) - compose(prev_odo, odo)
        d[2] = math.remainder(d[2], 2 * math.pi)
        S = fd_cov(prev_match, Pm0, match, Pm) + fd_cov(prev_odo, np.zeros((3, 3)), odo, Po)
        expected = d @ np.linalg.solve(S, d) <= threshold
        assert lo._agrees_over_steps(match, Pm, odo, Po) == expected
        decided.append(expected)
    assert 0 < sum(decided) < len(decided)
    lo._recent.clear()
    assert not lo._agrees_over_steps(np.zeros(3), np.eye(3), np.zeros(3), np.eye(3))   # no window: no second chance


@pytest.mark.parametrize("noise", [1.0, 3.0])
def test_the_odometry_sigma_learned_from_the_matches_is_the_simulated_one(noise):
    """The simulator draws each odometry component with σ = a + b·|Δ| of its own motion
    (forward: 1 mm + 10 % of the step, × ``noise``; sideways a millimetre or so); the front
    end's model says 5 cm + 20 % of the whole step for both. The factor it learns on the
    model's forward σ is the simulator's σ over the model's (the oracle, from the true
    increments) within 20 %; the sideways one, far below the model's, sits at its floor."""
    motion = MotionNoiseConfig()
    motion = replace(motion, a_xy_m=noise * motion.a_xy_m, b_xy=noise * motion.b_xy)
    data = simulate(get_world("mixed"), SimConfig(sigma_range_m=0.01, motion=motion), seed=4, steps=150)
    cfg = FrontendConfig()
    lo, _ = _run(list(data), cfg)
    true = between(data.ground_truth.poses[:-1], data.ground_truth.poses[1:])
    model = cfg.odom_sigma_xy_m + cfg.odom_sigma_xy_per_m * np.hypot(true[:, 0], true[:, 1])
    oracle = float(np.median((motion.a_xy_m + motion.b_xy * np.abs(true[:, 0])) / model))
    scale = lo.odometry_scale()
    assert scale is not None and scale[2] == 1.0
    assert abs(scale[0] / oracle - 1.0) < 0.2, (scale, oracle)
    assert scale[1] == pytest.approx(0.1)
    # not learning: the model's σ throughout
    off, _ = _run(list(data), replace(cfg, odometry_learned_window=0))
    assert off.odometry_scale() is None


@pytest.mark.parametrize("noise", [1.0, 3.0])
def test_a_fallback_is_as_wide_as_the_wheels_err(noise):
    """The simulator draws the odometry's heading with σ = a + b·|Δφ| (× ``noise``); the
    front end's model says 3° + 0.2·|Δφ| + 5°/m. With ``fallback_learned``, once 20 matches
    are in, a fallback (an empty scan) gets the model's covariance with each σ scaled by the RMS disagreement the
    matches measured: in heading, the RMS of the simulator's σ over the model's (the
    oracle, from the true increments), 0.78–0.97 of it over seeds 0–5 (a match started
    from the odometry's guess keeps a little of its error, so the disagreement comes out
    short), here within [0.7, 1.1]. Not learning, or before 20 matches: the model's."""
    motion = MotionNoiseConfig()
    motion = replace(motion, a_phi_rad=noise * motion.a_phi_rad, b_phi=noise * motion.b_phi)
    data = simulate(get_world("mixed"), SimConfig(sigma_range_m=0.01, motion=motion), seed=4, steps=150)
    frames = list(data)
    k = 140
    empty = LaserScan(0.0, frames[k].scan.angles, np.full(frames[k].scan.angles.shape, np.inf), 8.0)
    frames[k] = Frame(frames[k].stamp, frames[k].odometry, empty, frames[k].laser_offset)
    cfg = FrontendConfig()
    assert cfg.fallback_learned
    lo, out = _run(frames[:k], cfg)
    model = lo.odometry_covariance(between(frames[k - 1].odometry, frames[k].odometry))
    expected = lo.fallback_covariance(model)
    step = lo.step(frames[k])
    assert step.fallback
    np.testing.assert_allclose(step.covariance, expected)
    true = between(data.ground_truth.poses[:k - 1], data.ground_truth.poses[1:k])
    d = np.hypot(true[:, 0], true[:, 1])
    sim_phi = motion.a_phi_rad + motion.b_phi * np.abs(true[:, 2]) + motion.b_phi_per_m_rad * d
    model_phi = cfg.odom_sigma_rad + cfg.odom_sigma_rad_per_rad * np.abs(true[:, 2]) + cfg.odom_sigma_rad_per_m * d
    oracle = float(np.sqrt(np.mean((sim_phi / model_phi) ** 2)))
    learned = math.sqrt(expected[2, 2] / model[2, 2])
    assert 0.7 < learned / oracle < 1.1, (learned, oracle)
    assert np.all(np.diag(expected) < np.diag(model))
    # not learning: the model's covariance
    off, _ = _run(frames[:k], FrontendConfig(fallback_learned=False))
    np.testing.assert_array_equal(off.fallback_covariance(model), model)
    early, _ = _run(frames[:15], cfg)
    np.testing.assert_array_equal(early.fallback_covariance(model), model)


def test_the_match_after_fallbacks_carries_their_error():
    """Two fallbacks in a row (empty scans), then a trusted match against the keyframes from
    before them: the match's increment starts from the fallbacks' pose, so it holds their
    error with the opposite sign. Its ``carried`` covariance is J₁Σ₁J₁ᵀ + J₂Σ₂J₂ᵀ, the
    Jacobians of the increment in each fallback's robot-frame error by central
    differences (the oracle) and Σ the odometry model's covariance of each fallback (wider
    than the learned one each was given). Trusted matches otherwise carry nothing."""
    k = 30
    frames, _ = _wheels_wrong_on_fallbacks(np.zeros(3), k, fallbacks=2)
    lo, out = _run(frames[:k + 3])
    first, second, match = out[k], out[k + 1], out[k + 2]
    assert first.fallback and second.fallback and not match.fallback
    assert first.carried is None and second.carried is None
    assert all(s.carried is None for s in out[1:k])
    models = [lo.odometry_covariance(s.odometry_increment) for s in (first, second)]
    np.testing.assert_allclose(match.carried, _carried_oracle(out, k, 2, match.match.pose, models),
                               rtol=1e-6, atol=1e-12)
    assert models[0][2, 2] > first.covariance[2, 2]      # learned from 29 matches: narrower
    fallbacks_pose = compose(compose(out[k - 1].pose, first.increment), second.increment)
    np.testing.assert_allclose(match.increment, between(fallbacks_pose, match.match.pose), atol=1e-12)
    assert lo.step(frames[k + 3]).carried is None


def _wheels_wrong_on_fallbacks(wrong: np.ndarray, k: int = 30, fallbacks: int = 1):
    """A simulated run whose scans k … k + ``fallbacks`` − 1 are empty (fallbacks) and whose
    wheels' increment of step k is off by ``wrong`` (3,: robot-frame x, y m, heading rad;
    the later increments are right). Returns the frames and the true poses in the front
    end's frame."""
    data = simulate(get_world("mixed"), SimConfig(), seed=4, steps=40)
    frames = list(data)
    odometry = [np.asarray(f.odometry, dtype=float) for f in frames]
    turned = compose(odometry[k - 1], between(odometry[k - 1], odometry[k]) + np.asarray(wrong, dtype=float))
    for j in range(k, len(frames)):
        frames[j] = Frame(frames[j].stamp, compose(turned, between(odometry[k], odometry[j])), frames[j].scan,
                          frames[j].laser_offset)
    for j in range(k, k + fallbacks):
        empty = LaserScan(0.0, frames[j].scan.angles, np.full(frames[j].scan.angles.shape, np.inf), 8.0)
        frames[j] = Frame(frames[j].stamp, frames[j].odometry, empty, frames[j].laser_offset)
    truth = [compose(odometry[0], between(data.ground_truth.poses[0], p)) for p in data.ground_truth.poses]
    return frames, truth


def _carried_oracle(out, k: int, fallbacks: int, match_pose: np.ndarray, covariances=None) -> np.ndarray:
    """(3, 3) the covariance of the increment from the last fallback's pose to
    ``match_pose`` that the errors of the fallbacks ``out[k:k + fallbacks]`` make, each
    under its covariance in ``covariances`` (default: the one it was given): ΣJᵢΣᵢJᵢᵀ, Jᵢ
    by central differences in fallback i's robot-frame increment."""
    steps = out[k:k + fallbacks]
    covariances = [s.covariance for s in steps] if covariances is None else covariances
    start = out[k - 1].pose

    def increment(i, error):
        pose = start
        for j, s in enumerate(steps):
            pose = compose(pose, s.increment + (error if j == i else 0.0))
        return between(pose, match_pose)

    total = np.zeros((3, 3))
    for i, cov in enumerate(covariances):
        J = np.zeros((3, 3))
        for c in range(3):
            h = np.zeros(3)
            h[c] = 1e-6
            J[:, c] = (increment(i, h) - increment(i, -h)) / 2e-6
        total += J @ cov @ J.T
    return total


def _in_increment_frame(covariance: np.ndarray, heading: float) -> np.ndarray:
    """(3, 3) a front-end-frame pose ``covariance`` turned into the robot frame of a pose
    with ``heading`` (rad), the frame of an increment from it."""
    c, s = math.cos(heading), math.sin(heading)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot.T @ covariance @ rot


def test_the_gate_carries_the_fallbacks_error_as_each_was_given(monkeypatch):
    """Two fallbacks in a row, the wheels 0.1 m, −0.2 m and 8° off on the first: the
    covariance the odometry gate judges the next match's increment with is the match's own
    (in the increment's frame) plus the fallbacks' error under the covariance each was
    given, carried into the increment (the central-difference oracle). The match after it
    is gated with its own covariance alone: the carry went with the trusted match."""
    k = 30
    frames, _ = _wheels_wrong_on_fallbacks(np.array([0.1, -0.2, math.radians(8.0)]), k, fallbacks=2)
    lo, out = _run(frames[:k + 2])
    assert out[k].fallback and out[k + 1].fallback
    gated = []
    judge = LaserOdometry._agrees_with_odometry

    def spy(self, increment, covariance, *args, **kwargs):
        gated.append(np.array(covariance))
        return judge(self, increment, covariance, *args, **kwargs)

    monkeypatch.setattr(LaserOdometry, "_agrees_with_odometry", spy)
    prev = out[k + 1].pose
    step = lo.step(frames[k + 2])
    assert not step.fallback and len(gated) == 1
    own = _in_increment_frame(step.match.covariance, prev[2])
    carry = _carried_oracle(out, k, 2, step.match.pose)
    assert carry[2, 2] > 0.1 * own[2, 2]           # the carry is not lost in the rounding
    np.testing.assert_allclose(gated[0] - own, carry, rtol=1e-6, atol=1e-12)
    after = lo.step(frames[k + 3])
    assert not after.fallback and len(gated) == 2
    np.testing.assert_allclose(gated[1], _in_increment_frame(after.match.covariance, step.pose[2]),
                               rtol=1e-9, atol=1e-15)


def test_the_match_after_a_fallback_is_gated_with_the_fallbacks_error():
    """The match after a fallback (against the keyframes from before it) undoes the
    fallback's error, which its own step's odometry does not hold. The gate is the χ²₃
    99 % region (scipy) of the match's increment against that step's odometry with the
    match's, the step's model and the carried covariance (the oracle above) added. Over
    wheel errors of 10–26° on the fallback (with and without 0.15 m sideways) the front end
    trusts the match exactly where the oracle's distance is inside; some of those lie
    outside without the carried term (before, they were refused); once trusted, the
    heading is back within 0.5° of the truth. An error well beyond what the wheels are
    measured to err by (here 20° and more) stays refused: the gate cannot tell the match
    from the wheels there."""
    k = 30
    threshold = chi2.ppf(0.99, 3)
    outcomes, carried_mattered = [], False
    for sideways in (0.0, 0.15):
        for degrees in (10.0, 14.0, 17.0, 18.0, 19.0, 20.0, 22.0, 26.0):
            frames, truth = _wheels_wrong_on_fallbacks(np.array([0.0, sideways, math.radians(degrees)]), k)
            lo, out = _run(frames[:k + 2])
            fallback, step = out[k], out[k + 1]
            assert fallback.fallback and step.match is not None
            assert step.match.reason in ("ok", "inconsistent_with_odometry")
            match_cov = _in_increment_frame(step.match.covariance, fallback.pose[2])  # from the prior pose
            odo_cov = lo.odometry_covariance(step.odometry_increment)
            e = between(fallback.pose, step.match.pose) - step.odometry_increment
            e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
            carry = _carried_oracle(out, k, 1, step.match.pose)
            with_carry = e @ np.linalg.solve(match_cov + odo_cov + carry, e)
            alone = e @ np.linalg.solve(match_cov + odo_cov, e)
            trusted = not step.fallback
            assert trusted == (with_carry <= threshold), (sideways, degrees, with_carry)
            outcomes.append(trusted)
            if trusted:
                carried_mattered |= alone > threshold
                error = between(step.pose, truth[k + 1])
                assert math.degrees(abs(error[2])) < 0.5
    assert any(outcomes) and not all(outcomes)
    assert carried_mattered


def test_the_learned_sigma_waits_for_enough_matches():
    data = simulate(get_world("mixed"), SimConfig(), seed=0, steps=15)
    lo, _ = _run(list(data))
    assert lo.stats.matched == 14 and lo.odometry_scale() is None


def test_the_matches_learned_from_do_not_depend_on_a_weak_prior_being_offered():
    """A match in the weak prior's taper (weakness between ``degenerate_ratio`` and twice
    it) is not learned from, whether the prior was offered (share > 0) or not yet (share
    0, before the first 20 matches): the set of matches that measure the odometry is the
    scan's choice, not the learner's state's. One at or above twice the ratio is."""
    lo = LaserOdometry()
    limit = lo.config.degenerate_ratio
    def result(weakness, share):
        return MatchResult(np.zeros(3), np.eye(3), 1.0, True, "ok", weakness < limit, weak_prior_weight=share,
                           weakness=weakness)
    for share in (0.0, 0.3):
        assert not lo._learns_from(result(1.5 * limit, share))
    assert not lo._learns_from(result(0.5 * limit, 1.0))
    assert lo._learns_from(result(2.0 * limit, 0.0)) and lo._learns_from(result(0.3, 0.0))


def _open_ground_frames(steps: int = 12):
    """A robot driving 1 m a step across open ground whose only walls are buildings 30–60 m
    away (an 80 m laser, 1 cm noise), its wheels turning it 1° a step more than it turned."""
    from bsslam.sim import Segment, WallSet

    from .cases import cast_scan

    def block(cx, cy, w, h):
        c = [(cx - w, cy - h), (cx + w, cy - h), (cx + w, cy + h), (cx - w, cy + h)]
        return [Segment(c[i], c[(i + 1) % 4]) for i in range(4)]

    walls = WallSet(tuple(block(20.0, 40.0, 8.0, 5.0) + block(45.0, -35.0, 6.0, 9.0) + block(-10.0, -45.0, 12.0, 4.0)
                          + block(60.0, 10.0, 4.0, 15.0)))
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    rng = np.random.default_rng(3)
    truth = [np.array([float(k), 0.1 * k, 0.0]) for k in range(steps)]
    odometry = [np.array([float(k), 0.1 * k, math.radians(1.0) * k]) for k in range(steps)]
    frames = [Frame(float(k), odometry[k], cast_scan(walls, truth[k], rng, 0.01, 80.0, angles)) for k in range(steps)]
    return frames, truth


def test_open_ground_is_matched_on_its_far_walls():
    """No return within max_range_m (30 m): the front end matches on the far buildings
    (``full_range_when_sparse``) and ends within centimetres and a tenth of a degree of the
    truth; without them every step falls back to the wheels, 11° off at the end."""
    frames, truth = _open_ground_frames()
    lo, out = _run(frames)
    assert lo.stats.fallbacks == 0
    end = between(truth[0], truth[-1])
    error = between(end, between(out[0].pose, out[-1].pose))
    assert math.hypot(error[0], error[1]) < 0.05 and abs(error[2]) < math.radians(0.1)
    lo, out = _run(frames, replace(FrontendConfig(), full_range_when_sparse=False))
    assert lo.stats.fallbacks == len(frames) - 1 and lo.stats.matched == 0
    error = between(end, between(out[0].pose, out[-1].pose))
    assert abs(error[2]) > math.radians(10.0)
