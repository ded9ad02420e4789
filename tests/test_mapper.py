"""bsslam.Mapper: fed scan by scan it is ``bsslam run``, bit for bit; it ends early on
KeyboardInterrupt with consistent results; it calls its viewer once per scan."""

import dataclasses
import io

import numpy as np
import pytest
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from bsslam import Mapper, PoseEstimate
from bsslam.cli import app
from bsslam.config import SLAMConfig
from bsslam.errors import InputError
from bsslam.io import open_dataset
from bsslam.io.trajectory_file import write_tum
from bsslam.pipeline import run_dataset
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import between, compose
from bsslam.sim import SimConfig, get_world, simulate


@pytest.fixture(scope="module")
def data():
    return simulate(get_world("mixed"), SimConfig(), seed=5, steps=40)


@pytest.fixture(scope="module")
def config():
    """The defaults of ``bsslam run``, with filter steps often enough for a short run."""
    base = SLAMConfig()
    return base.replace(frontend=dataclasses.replace(base.frontend, update_distance_m=0.5))


def by_hand(frames, config, **finish):
    mapper = Mapper(config)
    estimates = [mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset) for f in frames]
    return estimates, mapper.finish(**finish)


def assert_same_run(a, b):
    """Every array of two results equal, bit for bit."""
    for name in ("estimate", "relocalized", "odometry", "frontend"):
        ta, tb = getattr(a, name), getattr(b, name)
        assert (ta is None) == (tb is None), name
        if ta is not None:
            np.testing.assert_array_equal(ta.stamps, tb.stamps)
            np.testing.assert_array_equal(ta.poses, tb.poses)
            if ta.covariances is not None or tb.covariances is not None:
                np.testing.assert_array_equal(ta.covariances, tb.covariances)
    for name in ("state_sizes", "nis", "nis_dof", "points"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.totals == b.totals
    assert len(a.map) == len(b.map)
    for ma, mb in zip(a.map, b.map):
        np.testing.assert_array_equal(ma.curve.control_points, mb.curve.control_points)
        np.testing.assert_array_equal(ma.covariance, mb.covariance)


def test_mapper_fed_by_hand_is_run_dataset_bit_for_bit(data, config):
    estimates, result = by_hand(data, config, name=data.name, ground_truth=data.ground_truth)
    reference = run_dataset(data, config)
    assert_same_run(result, reference)
    assert result.relocalized is not None and not result.interrupted
    assert 3 < result.totals["filter_steps"] < len(data)       # the schedule skipped scans
    # add() returned the online estimate of each scan as it went
    np.testing.assert_array_equal([e.pose for e in estimates], result.estimate.poses)
    np.testing.assert_array_equal([e.covariance for e in estimates], result.estimate.covariances)
    assert sum(e.filter_step for e in estimates) == result.totals["filter_steps"]
    # one (scan, laser offset) per frame, aligned with the trajectory
    assert len(result.scans) == len(result.trajectory) == len(data)
    for (scan, offset), frame in zip(result.scans, data):
        assert scan.stamp == frame.scan.stamp and np.array_equal(scan.ranges, frame.scan.ranges)
        assert np.array_equal(offset, frame.laser_offset)


def _num(values):
    return " ".join(repr(float(v)) for v in values)


@pytest.fixture(scope="module")
def carmen_log(data, tmp_path_factory):
    """A CARMEN log written from the simulated frames (the reader gives them CARMEN's
    180° geometry; what matters is that the CLI and the Mapper read the same file)."""
    lines = []
    for f in data:
        ranges = np.where(np.isfinite(f.scan.ranges) & (f.scan.ranges < f.scan.max_range), f.scan.ranges, 81.83)
        pose = _num(f.odometry)
        lines.append(f"FLASER {ranges.size} {_num(ranges)} {pose} {pose} {f.stamp!r} sim {f.stamp!r}")
    path = tmp_path_factory.mktemp("log") / "tiny.clf"
    path.write_text("\n".join(lines) + "\n")
    return path


def tum_text(trajectory):
    out = io.StringIO()
    write_tum(out, trajectory)
    return out.getvalue()


def test_mapper_is_bsslam_run_on_a_carmen_log(carmen_log, config, tmp_path):
    config_file = tmp_path / "config.yaml"
    config_file.write_text("frontend: {update_distance_m: 0.5}\n")
    cli = CliRunner().invoke(app, ["run", str(carmen_log), "--config", str(config_file), "--out", str(tmp_path / "run")])
    assert cli.exit_code == 0, cli.output
    run = (tmp_path / "run" / "latest").resolve()

    frames = list(open_dataset(carmen_log))
    assert len(frames) == 40
    _, result = by_hand(frames, config)
    assert_same_run(result, run_dataset(open_dataset(carmen_log), config))
    # the files the CLI wrote hold the same numbers (repr round-trips every double)
    assert (run / "trajectory.tum").read_text() == tum_text(result.relocalized)
    assert (run / "trajectory_online.tum").read_text() == tum_text(result.estimate)


def test_odometry_increments_chain_into_the_same_run(data):
    """Without the front end every increment goes to the filter as given; fed as
    increments the odometry poses are chained again, equal up to rounding."""
    config = SLAMConfig().replace(frontend=dataclasses.replace(SLAMConfig().frontend, enabled=False),
                                  relocalize=False)
    frames = list(data)[:15]
    _, as_poses = by_hand(frames, config)
    mapper = Mapper(config, initial_pose=frames[0].odometry)
    prev = None
    for f in frames:
        increment = None if prev is None else between(prev, f.odometry)
        mapper.add(f.scan, stamp=f.stamp, laser_offset=f.laser_offset, odometry_increment=increment)
        prev = f.odometry
    as_increments = mapper.finish()
    np.testing.assert_allclose(as_increments.odometry.poses, as_poses.odometry.poses, atol=1e-12)
    np.testing.assert_allclose(as_increments.estimate.poses, as_poses.estimate.poses, atol=1e-9)
    assert as_increments.totals["filter_steps"] == 15


def test_add_names_bad_odometry(data):
    frame = next(iter(data))
    mapper = Mapper(SLAMConfig())
    with pytest.raises(InputError, match="not both"):
        mapper.add(frame.scan, frame.odometry, odometry_increment=np.zeros(3))
    with pytest.raises(InputError, match="odometry must be 3 finite numbers"):
        mapper.add(frame.scan, [0.0, np.nan, 0.0])
    with pytest.raises(InputError, match="odometry_increment must be 3 finite numbers"):
        mapper.add(frame.scan, odometry_increment=[1.0, 2.0])
    estimate = mapper.add(frame.scan, frame.odometry)
    assert isinstance(estimate, PoseEstimate) and estimate.stamp == frame.scan.stamp and estimate.filter_step
    with pytest.raises(InputError, match="None only on the first scan"):
        mapper.add(frame.scan)
    assert mapper.scans == 1


def test_initial_pose_sets_the_map_frame(data, config):
    frames = list(data)[:12]
    _, default = by_hand(frames, config)
    mapper = Mapper(config, initial_pose=frames[0].odometry)
    for f in frames:
        mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset)
    assert_same_run(mapper.finish(), default)
    shift = np.array([5.0, -2.0, 0.0])     # a shifted map frame: the same run, shifted
    start = frames[0].odometry + shift
    mapper = Mapper(config, initial_pose=start)
    for f in frames:
        mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset)
    shifted = mapper.finish()
    np.testing.assert_allclose(shifted.estimate.poses - shift, default.estimate.poses,
                               atol=1e-9)
    np.testing.assert_array_equal(shifted.odometry.poses, default.odometry.poses)


class Interrupted:
    """A dataset whose iterator raises KeyboardInterrupt (Ctrl-C) after ``k`` frames."""

    def __init__(self, data, k):
        self.data, self.k = data, k
        self.name, self.ground_truth, self.skipped = data.name, data.ground_truth, data.skipped

    def __iter__(self):
        for i, frame in enumerate(self.data):
            if i == self.k:
                raise KeyboardInterrupt
            yield frame


@pytest.fixture(scope="module")
def full_run(data, config):
    return run_dataset(data, config)


def test_an_interrupted_run_returns_the_frames_so_far(data, config, full_run):
    result = run_dataset(Interrupted(data, 25), config)
    assert result.interrupted and result.relocalized is None and result.trajectory is result.estimate
    assert result.steps == 25 and len(result.scans) == 25
    for name in ("odometry", "frontend"):
        assert len(getattr(result, name)) == 25
    for name in ("state_sizes", "nis", "nis_dof", "step_times_s"):
        assert getattr(result, name).shape == (25,)
    # the online filter is causal: its first 25 poses are those of the whole run
    np.testing.assert_array_equal(result.estimate.poses, full_run.estimate.poses[:25])
    np.testing.assert_array_equal(result.estimate.covariances, full_run.estimate.covariances[:25])
    assert result.totals["filter_steps"] < full_run.totals["filter_steps"]
    assert result.totals["frontend_matched"] + result.totals.get("frontend_fallbacks", 0) == 24
    assert len(result.map) > 0 and len(result.points) > 0       # points at the online poses
    assert result.relocalize_time_s == 0.0


def test_an_interrupt_from_the_progress_callback_keeps_the_frame_it_followed(data, config, full_run):
    def progress(done, total):
        if done == 7:
            raise KeyboardInterrupt

    result = run_dataset(data, config, progress=progress)
    assert result.interrupted and result.steps == 7
    np.testing.assert_array_equal(result.estimate.poses, full_run.estimate.poses[:7])


def test_an_interrupt_in_the_second_pass_skips_it(data, config, full_run):
    def progress(done, total):
        if done == 10:
            raise KeyboardInterrupt

    result = run_dataset(data, config, relocalize_progress=progress)
    assert result.interrupted and result.relocalized is None
    np.testing.assert_array_equal(result.estimate.poses, full_run.estimate.poses)
    assert result.steps == len(data) and result.relocalize_time_s == 0.0


class RecordingViewer:
    def __init__(self):
        self.updates, self.results, self.map_sizes = [], [], []

    def update(self, estimate, points, mapper):
        self.updates.append((estimate, points))
        self.map_sizes.append(len(mapper.curves))

    def finish(self, result):
        self.results.append(result)


def test_the_viewer_sees_every_scan_and_the_result(data, config, full_run):
    viewer = RecordingViewer()
    result = run_dataset(data, config, viewer=viewer)
    assert len(viewer.updates) == len(data) and viewer.results == [result]
    assert [e.stamp for e, _ in viewer.updates] == [f.stamp for f in data]
    # each scan's valid beams, in the world at its pose: on the true walls within a few cm
    for (estimate, points), frame in zip(viewer.updates, data):
        valid = np.isfinite(frame.scan.ranges) & (frame.scan.ranges < frame.scan.max_range)
        assert points.shape == (valid.sum(), 2)
    walls = cKDTree(np.vstack(data.world.polylines(0.01)))
    distance, _ = walls.query(viewer.updates[-1][1])
    assert np.median(distance) < 0.02 and distance.max() < 0.1
    np.testing.assert_array_equal([e.pose for e, _ in viewer.updates], result.estimate.poses)
    assert viewer.map_sizes[-1] == len(result.map) > 0
    assert_same_run(result, full_run)        # watching changes nothing


def test_add_checks_its_input_at_the_boundary(data, config):
    """The public API applies the readers' limits: an odometry jump beyond the plausible
    speed is bridged and counted (an InputError when strict), the run stays within the
    scans' own motion of the clean one; bad bearings and backward stamps are InputErrors."""
    frames = list(data)[:12]
    jump = np.array([100.0, 0.0, 0.0])     # 100 m in one step: no ground robot does that
    jumped = [f.odometry + (jump if i == 6 else 0.0) for i, f in enumerate(frames)]

    mapper = Mapper(config)
    for f, odo in zip(frames, jumped):
        mapper.add(f.scan, odo, f.stamp, f.laser_offset)
    result = mapper.finish()
    assert sum(result.skipped.counts.values()) >= 1
    assert all("implausible" in k for k in result.skipped.counts)
    clean = run_dataset(frames_dataset(frames), config)
    # the bridged step repeats the previous velocity; the scans then correct it
    assert np.max(np.hypot(*(result.estimate.poses - clean.estimate.poses)[:, :2].T)) < 1.0

    strict = Mapper(config, strict=True)
    with pytest.raises(InputError, match="implausible"):
        for f, odo in zip(frames, jumped):
            strict.add(f.scan, odo, f.stamp, f.laser_offset)

    bad = Mapper(config)
    f0 = frames[0]
    with pytest.raises(InputError, match="angle"):
        bad.add(dataclasses.replace(f0.scan, angles=np.zeros_like(f0.scan.angles)), f0.odometry, f0.stamp)
    bad.add(f0.scan, f0.odometry, f0.stamp)
    with pytest.raises(InputError, match="not after"):
        bad.add(frames[1].scan, frames[1].odometry, f0.stamp - 1.0)


class frames_dataset:
    """A Dataset over a list of frames."""

    name = "frames"
    ground_truth = None

    def __init__(self, frames):
        from bsslam.dataset import SkipCounter
        self.frames, self.skipped = frames, SkipCounter()

    def __iter__(self):
        return iter(self.frames)


def test_a_fallback_the_walls_contradict_is_predicted_with_the_wide_covariance(data, config):
    """With ``frontend.fallback_learned`` (the default), an increment holding a fallback carries the
    wheels' learned σ (here 1 cm, 0.5°), and a trial step on a copy of the filter with the
    wide covariance decides it: the increment turned 10° off the truth → the walls put the
    pose beyond the learned prediction's 99 % region → the wide covariance; the true
    increment → the learned one. The trial leaves the filter as it was, and without a
    fallback nothing is tried."""
    cfg = config.replace(frontend=dataclasses.replace(config.frontend, update_distance_m=0.0, update_angle_rad=0.0))
    frames = list(data)
    mapper = Mapper(cfg)
    k = 30
    for f in frames[:k]:
        mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset)
    slam, frame = mapper._slam, frames[k]
    truth = data.ground_truth.poses
    learned = np.diag([0.01, 0.01, np.radians(0.5)]) ** 2
    wide = np.diag([0.25, 0.25, np.radians(10.0)]) ** 2
    true_delta = between(truth[k - 1], truth[k])
    wrong_delta = true_delta + np.array([0.0, 0.0, np.radians(10.0)])
    before = (slam.pose.copy(), slam.pose_covariance.copy(), slam.state_size)

    mapper._motion.wide_covariance = None
    cov, widened, _ = mapper._checked_by_walls(slam, frame, wrong_delta, learned)
    assert cov is learned and not widened
    mapper._motion.wide_covariance = wide
    cov, widened, _ = mapper._checked_by_walls(slam, frame, true_delta, learned)
    assert cov is learned and not widened
    cov, widened, _ = mapper._checked_by_walls(slam, frame, wrong_delta, learned)
    assert cov is wide and widened

    np.testing.assert_array_equal(slam.pose, before[0])
    np.testing.assert_array_equal(slam.pose_covariance, before[1])
    assert slam.state_size == before[2]


def test_the_wide_covariance_is_compounded_only_over_an_increment_holding_a_fallback(data, config):
    """The second schedule: a filter step whose increment holds a fallback (an empty scan,
    after the 20 matches that teach the wheels' σ) gets a wide covariance whose heading
    variance exceeds the learned one's; the steps without a fallback get none."""
    frames = list(data)
    k = 28
    empty = LaserScan(frames[k].scan.stamp, frames[k].scan.angles, np.full(frames[k].scan.angles.shape, np.inf),
                      frames[k].scan.max_range)
    frames[k] = dataclasses.replace(frames[k], scan=empty)
    mapper = Mapper(config)
    held = []
    for i, f in enumerate(frames):
        mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset)
        held.append(mapper._motion.wide_covariance)
    assert mapper._motion.odometry.stats.fallbacks == 1
    steps = [i for i, w in enumerate(held) if w is not None]
    assert len(steps) == 1 and steps[0] >= k      # the filter step that took the fallback's increment
    wide = held[steps[0]]
    assert np.all(np.linalg.eigvalsh(wide) > 0)
    # headings add up: the compounded heading variance holds the fallback's model variance
    model = mapper._motion.odometry.odometry_covariance(between(frames[k - 1].odometry, frames[k].odometry))
    assert wide[2, 2] >= model[2, 2]


def test_a_fallback_the_walls_took_back_is_not_taken_back_twice(data, config):
    """Through a whole run: the wheels turn 10° too far on an increment the front end cannot
    match (its scan thinned to every sixth beam), so the fallback hands the filter a heading
    10° off with the wheels' learned σ. The walls contradict it: the step predicts with the
    wide covariance and the filter turns back. The front end's next match, against
    keyframes from before the fallback, takes the 10° back in its increment; that increment
    carries the fallback's error in its covariance, as wide as the step that took the
    fallback predicted it, so the filter does not turn 10° the other way (it did, and stayed
    there). The run counts one widened step, and every filter step's heading ends within 1°
    of the truth."""
    frames = list(data)
    k = 28
    ranges = frames[k].scan.ranges.copy()
    ranges[np.arange(ranges.size) % 6 != 0] = np.inf
    frames[k] = dataclasses.replace(frames[k], scan=LaserScan(frames[k].scan.stamp, frames[k].scan.angles, ranges,
                                                               frames[k].scan.max_range))
    turn = np.array([0.0, 0.0, np.radians(10.0)])
    anchor = frames[k - 1].odometry
    for i in range(k, len(frames)):   # the wheels' increment k-1 → k turned 10° more; the rest as they were
        frames[i] = dataclasses.replace(frames[i], odometry=compose(anchor, compose(turn, between(anchor, frames[i].odometry))))
    mapper = Mapper(config)
    for f in frames:
        mapper.add(f.scan, f.odometry, f.stamp, f.laser_offset)
    result = mapper.finish()
    assert mapper.frontend.stats.fallbacks == 1
    assert result.totals.get("fallbacks_widened", 0) == 1
    steps = [i for i, r in enumerate(mapper._records) if "filter_steps" in r.counts]
    truth = data.ground_truth.poses[steps, 2]
    error = np.angle(np.exp(1j * (result.estimate.poses[steps, 2] - truth)))
    assert np.degrees(np.abs(error)).max() < 1.0
