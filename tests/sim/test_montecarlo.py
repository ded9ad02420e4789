"""The Monte Carlo runner: results in seed order, in-process and across processes."""

import os

import pytest

from bsslam.errors import ConfigError
from bsslam.sim.montecarlo import run_monte_carlo


def square_with_pid(seed):
    """Picklable top-level work function."""
    return seed * seed, os.getpid()


def fail_on_three(seed):
    if seed == 3:
        raise ValueError("seed 3 fails")
    return seed


@pytest.mark.parametrize("workers", [1, 2])
def test_results_come_back_in_seed_order_with_progress(workers):
    seeds = [5, 3, 9, 0, 7, 2]
    calls = []
    results = run_monte_carlo(square_with_pid, seeds, workers=workers, progress=lambda d, t: calls.append((d, t)))
    assert [r[0] for r in results] == [s * s for s in seeds]
    assert calls == [(k, len(seeds)) for k in range(1, len(seeds) + 1)]
    pids = {r[1] for r in results}
    if workers == 1:
        assert pids == {os.getpid()}
    else:
        assert os.getpid() not in pids


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_run_raises(workers):
    with pytest.raises(ValueError, match="seed 3"):
        run_monte_carlo(fail_on_three, [1, 2, 3, 4], workers=workers)


def test_invalid_worker_count_is_refused():
    with pytest.raises(ConfigError):
        run_monte_carlo(square_with_pid, [1], workers=0)
