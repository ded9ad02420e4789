"""The runner: results in input order, in this process and on a local Dask cluster, and
the same results wherever the runs go."""

import logging
import os
import sys

import numpy as np
import pytest

from bsslam.errors import ConfigError, MissingDependencyError
from bsslam.experiments.consistency import consistency_experiment
from bsslam.parallel import run_all

pytest.importorskip("distributed")


def square_with_pid(seed):
    """Picklable top-level work function."""
    return seed * seed, os.getpid()


def fail_on_three(seed):
    if seed == 3:
        raise ValueError("seed 3 fails")
    return seed


@pytest.mark.parametrize("workers", [1, 2])
def test_results_come_back_in_input_order_with_progress(workers):
    seeds = [5, 3, 9, 0, 7, 2]
    calls = []
    results = run_all(square_with_pid, seeds, workers=workers, progress=lambda d, t: calls.append((d, t)))
    assert [r[0] for r in results] == [s * s for s in seeds]
    assert calls == [(k, len(seeds)) for k in range(1, len(seeds) + 1)]
    pids = {r[1] for r in results}
    if workers == 1:
        assert pids == {os.getpid()}
    else:  # the local cluster's worker processes
        assert os.getpid() not in pids and len(pids) <= 2


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_run_raises_its_own_error(workers):
    with pytest.raises(ValueError, match="seed 3"):
        run_all(fail_on_three, [1, 2, 3, 4], workers=workers)


def test_invalid_worker_counts_and_both_targets_are_refused():
    with pytest.raises(ConfigError):
        run_all(square_with_pid, [1], workers=0)
    with pytest.raises(ConfigError, match="not both"):
        run_all(square_with_pid, [1, 2], workers=2, scheduler="tcp://127.0.0.1:1")


def test_without_dask_local_runs_fall_back_to_serial_and_a_scheduler_is_an_error(monkeypatch, caplog):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed now fails
    with caplog.at_level(logging.WARNING, logger="bsslam.parallel"):
        results = run_all(square_with_pid, [1, 2, 3], workers=2)
    assert [r[0] for r in results] == [1, 4, 9] and {r[1] for r in results} == {os.getpid()}
    assert len(caplog.records) == 1 and "bsslam[dask]" in caplog.records[0].getMessage()
    with pytest.raises(MissingDependencyError, match=r"bsslam\[dask\]"):
        run_all(square_with_pid, [1, 2], scheduler="tcp://127.0.0.1:1")


def test_a_consistency_experiment_on_two_workers_equals_the_serial_one_exactly():
    serial = consistency_experiment("no-extension", runs=3, steps=6, workers=1)
    cluster = consistency_experiment("no-extension", runs=3, steps=6, workers=2)
    np.testing.assert_array_equal(cluster.nees_runs, serial.nees_runs)
    np.testing.assert_array_equal(cluster.mean_errors, serial.mean_errors)
    np.testing.assert_array_equal(cluster.mean_sigmas, serial.mean_sigmas)
    # three different seeds: the runs differ from each other
    assert not np.array_equal(serial.nees_runs[0], serial.nees_runs[1])
