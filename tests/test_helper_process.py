"""The helper process (:mod:`bsslam.helper_process`): a run whose reader and front end
run in a second process gives the same numbers as a run in one, hands its front end over
for checkpoints, raises the second process's errors here, and never hangs on a dead one."""

from __future__ import annotations

import operator
import pickle
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.errors import BsslamError, InputError
from bsslam.helper_process import HelperProcess, RemoteTraceback, can_prefetch
from bsslam.io import open_dataset
from bsslam.mapper import Mapper
from bsslam.pipeline import run_dataset
from bsslam.sim import SimConfig, get_world, simulate

sys.path.insert(0, str(Path(__file__).parent))
from test_cli import write_carmen_log  # noqa: E402

#: short submaps, so that 150 scans of the room's double loop hold several and a loop closure
CONFIG = SLAMConfig.from_dict({"submaps": {"max_distance_m": 8.0}})


class HandOverAt(HelperProcess):
    """A helper that says it is ready at frame ``frame`` (the pipeline asks once a
    frame): the run's first frames in this process, the rest in the helper, at a frame the
    test picks instead of whenever the interpreter is up."""

    def __init__(self, frame: int, ahead_bytes: int | None = 1 << 20) -> None:
        super().__init__(ahead_bytes=ahead_bytes)
        self.frame, self.asked = frame, 0

    def ready(self) -> bool:
        self.asked += 1
        return self.asked > self.frame


@pytest.fixture(scope="module")
def room():
    return simulate(get_world("rounded-room"), SimConfig(), seed=3, steps=150)


@pytest.fixture(scope="module")
def one_process(room):
    return run_dataset(room, CONFIG, point_stride=3)


def assert_same_run(a, b) -> None:
    for name in ("trajectory", "estimate", "odometry", "frontend"):
        x, y = getattr(a, name), getattr(b, name)
        np.testing.assert_array_equal(x.poses, y.poses, err_msg=name)
        np.testing.assert_array_equal(x.stamps, y.stamps, err_msg=name)
    np.testing.assert_array_equal(a.trajectory.covariances, b.trajectory.covariances)
    assert len(a.map) == len(b.map)
    for s, t in zip(a.map, b.map):
        np.testing.assert_array_equal(s.curve.control_points, t.curve.control_points)
        np.testing.assert_array_equal(s.covariance, t.covariance)
    np.testing.assert_array_equal(a.points, b.points)
    assert a.skipped.counts == b.skipped.counts
    assert {k: v for k, v in b.totals.items() if k != "frontend_in_helper"} == a.totals


@pytest.mark.parametrize("frame", [0, 37])
def test_a_run_handed_over_to_the_helper_gives_the_same_numbers(room, one_process, frame):
    assert can_prefetch(room)
    with HandOverAt(frame) as helper:
        result = run_dataset(room, CONFIG, point_stride=3, prefetch=helper)
        assert helper.asked == frame + 1      # it went on in the helper from that frame
    # the front end matched every later frame there (the first frame has no match)
    assert result.totals["frontend_in_helper"] == 150 - max(frame, 1)
    assert result.totals["loop_closures"] > 0 and result.totals["submaps"] > 2
    assert_same_run(one_process, result)


class EveryScans:
    """A checkpoint due every ``n`` frames, which keeps a pickled copy of the mapper at
    each write (as :class:`~bsslam.io.checkpoint.Checkpointer` would write it)."""

    def __init__(self, n: int) -> None:
        self.n, self.last, self.saved = n, 0, {}

    def due(self, next_frame: int) -> bool:
        return next_frame - self.last >= self.n

    def __call__(self, next_frame: int, mapper: Mapper) -> None:
        if self.due(next_frame):
            self.saved[next_frame] = pickle.dumps(mapper)
            self.last = next_frame


def test_checkpoints_of_a_handed_over_run_hold_the_front_end_and_resume_to_the_same_result(room, one_process):
    """The front end lives in the helper; a checkpoint must wait for its state. Each
    checkpoint resumed in one process gives the run never stopped."""
    checkpoint = EveryScans(40)
    # the system's pipe (64 KiB, ~16 frames ahead): the helper is still matching when asked
    with HandOverAt(50, ahead_bytes=None) as helper:
        run_dataset(room, CONFIG, point_stride=3, prefetch=helper, checkpoint=checkpoint)
    frames = sorted(checkpoint.saved)
    assert len(frames) >= 2 and frames[0] == 40       # before the handover: on time
    # after it, at the first frame the helper matched after being asked
    assert all(b - a >= 40 for a, b in zip(frames, frames[1:])) and frames[-1] <= 150
    for next_frame in frames[1:]:
        mapper = pickle.loads(checkpoint.saved[next_frame])
        alone = Mapper(CONFIG)
        for frame in list(room)[:next_frame]:
            alone.add_frame(frame)
        np.testing.assert_array_equal(mapper.frontend.pose, alone.frontend.pose)
        assert mapper.frontend.stats == alone.frontend.stats
    resumed = run_dataset(room, CONFIG, point_stride=3, mapper=pickle.loads(checkpoint.saved[frames[1]]),
                          start=frames[1])
    assert_same_run(one_process, resumed)


def test_the_helpers_read_errors_and_skips_are_the_ones_of_one_process(tmp_path):
    """A malformed line past the handover: counted the same in lenient mode, raised with
    the same file:line message under strict."""
    log = write_carmen_log(tmp_path / "room.clf", "rounded-room", 3, 60)
    lines = log.read_text().splitlines(keepends=True)
    lines.insert(40, "FLASER 181 1.0 2.0 nonsense\n")
    log.write_text("".join(lines))
    alone = run_dataset(open_dataset(log), CONFIG, point_stride=0)
    with HandOverAt(5) as helper:
        helped = run_dataset(open_dataset(log), CONFIG, point_stride=0, prefetch=helper)
    assert alone.skipped.total == 1 and alone.skipped.counts == helped.skipped.counts
    assert alone.skipped.examples == helped.skipped.examples
    np.testing.assert_array_equal(alone.trajectory.poses, helped.trajectory.poses)

    with pytest.raises(InputError) as here:
        run_dataset(open_dataset(log, strict=True), CONFIG)
    with HandOverAt(5) as helper, pytest.raises(InputError) as there:
        run_dataset(open_dataset(log, strict=True), CONFIG, prefetch=helper)
    assert str(there.value) == str(here.value) and f"{log}:41" in str(there.value)
    assert isinstance(there.value.__cause__, RemoteTraceback)    # where it was raised, for a bug report


def test_a_helper_that_dies_is_an_error_here_not_a_hang(room):
    with HelperProcess() as helper:
        frames = helper.prefetch(room, Mapper(CONFIG).frontend)
        first = next(frames)
        assert first.index == 0 and first.step is not None
        helper._process.kill()
        with pytest.raises(BsslamError, match="helper process ended unexpectedly"):
            for _ in frames:
                pass
        # a broken helper runs calls here
        assert helper.call(operator.add, 2, 3)() == 5


def test_a_call_runs_in_the_helper_and_raises_its_error_here():
    with HelperProcess() as helper:
        assert helper.call(operator.mul, 6, 7)() == 42
        waiting = helper.call(int, "not a number")
        with pytest.raises(ValueError, match="not a number") as error:
            waiting()
        assert isinstance(error.value.__cause__, RemoteTraceback) and "Traceback" in str(error.value.__cause__)
        assert helper.call(operator.add, "a", "b")() == "ab"      # it goes on after an error
        here = []
        assert helper.call(lambda: here.append(1) or len(here))() == 1   # a lambda does not pickle: run here
        assert helper.call(operator.mul, 6, 7)() == 42                   # and the helper still takes calls
        failing = helper.call(lambda: int("run here"))    # run here, and it fails: its own error, later
        with pytest.raises(ValueError, match="run here"):
            failing()


class _Unpicklable:
    """A dataset holding something that does not pickle (a lock, an open stream)."""

    def __init__(self, data) -> None:
        self.data, self.name, self.ground_truth = data, "unpicklable", data.ground_truth
        self.lock = threading.Lock()

    @property
    def skipped(self):
        return self.data.skipped

    def __iter__(self):
        return iter(self.data)


def test_a_dataset_that_does_not_pickle_is_read_here(room, one_process):
    """It cannot reach a second process: the run reads it here, with the same numbers, and
    the helper passed in is left for its calls."""
    data = _Unpicklable(room)
    assert not can_prefetch(data) and not can_prefetch(iter(room))
    with HandOverAt(0) as helper:
        result = run_dataset(data, CONFIG, point_stride=3, prefetch=helper)
        assert helper.asked == 0 and helper.call(operator.mul, 6, 7)() == 42
    assert "frontend_in_helper" not in result.totals
    assert_same_run(one_process, result)


def test_the_pipeline_imports_no_plotting():
    """The helper draws the map picture, so the filter's process must not pay for
    matplotlib's import (most of a second) by importing the pipeline."""
    code = "import sys, bsslam.pipeline, bsslam.outputs; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_wait_ready_waits_for_the_interpreter_and_says_no_for_a_dead_one():
    with HelperProcess() as helper:
        assert helper.wait_ready(120) and helper.ready()
    helper = HelperProcess()
    helper._process.kill()      # before it could say it was ready
    helper._process.join()
    assert not helper.wait_ready(120) and not helper.ready()
    helper.close()
