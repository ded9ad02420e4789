"""Run one function over many seeds in parallel processes (Monte Carlo experiments)."""

from __future__ import annotations

import os
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from typing import Callable, Sequence, TypeVar

from bsslam.errors import ConfigError

T = TypeVar("T")

# The usual BLAS/OpenMP thread-count variables. Each worker is one process per core, so a
# multi-threaded BLAS inside each would oversubscribe the cores.
_THREAD_ENV_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def limit_blas_threads() -> None:
    """Process initializer: one BLAS thread per worker.

    The environment variables take effect for BLAS libraries loaded after this call; a
    library already loaded (inherited through ``fork``) is limited through threadpoolctl
    when it is installed.
    """
    for name in _THREAD_ENV_VARS:
        os.environ[name] = "1"
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: without it only not-yet-loaded libraries are limited
        return
    threadpool_limits(limits=1)


def run_monte_carlo(
    fn: Callable[[int], T],
    seeds: Sequence[int],
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[T]:
    """Call ``fn(seed)`` for every seed, in parallel processes.

    Args:
        fn: a picklable top-level function of one seed; its result must be picklable.
        seeds: the seeds, one run each.
        workers: processes; None = ``os.cpu_count()``; 1 (or a single seed) runs in this
            process (for tests and debugging, no pickling).
        progress: called as ``progress(done, total)`` each time a run finishes.

    Returns:
        The results in the order of ``seeds`` (not of completion).

    Raises:
        Whatever ``fn`` raises, for the first failing run; runs not yet started are cancelled.
    """
    seeds = list(seeds)
    total = len(seeds)
    if workers is None:
        workers = os.cpu_count() or 1
    if workers < 1:
        raise ConfigError(f"workers must be ≥ 1, got {workers}")
    results: list = [None] * total
    if workers == 1 or total <= 1:
        for i, seed in enumerate(seeds):
            results[i] = fn(seed)
            if progress is not None:
                progress(i + 1, total)
        return results

    with ProcessPoolExecutor(max_workers=min(workers, total), initializer=limit_blas_threads) as pool:
        index_of = {pool.submit(fn, seed): i for i, seed in enumerate(seeds)}
        pending = set(index_of)
        done_count = 0
        while pending:
            finished, pending = wait(pending, return_when=FIRST_EXCEPTION)
            for future in finished:
                error = future.exception()
                if error is not None:
                    for other in pending:
                        other.cancel()
                    raise error
                results[index_of[future]] = future.result()
                done_count += 1
                if progress is not None:
                    progress(done_count, total)
    return results
