"""Run one function over many independent inputs: in this process, or on a Dask cluster.

The Monte Carlo experiments and ``bsslam bench`` go through :func:`run_all`. Every input
is one independent run (a seed, a log), so the results do not depend on where a run
executes: the cluster gives the same results as the serial loop, run for run.

Where the runs go:

- ``workers=1``: one after the other in this process (no pickling; for debugging);
- ``scheduler="tcp://host:8786"``: the workers of a running Dask cluster (they need
  bsslam installed, and the files a run reads);
- otherwise: a :class:`distributed.LocalCluster` of ``workers`` processes (default: one
  per core) started for the call and closed after it.

Dask is the optional extra ``bsslam[dask]``. Without it, the local case falls back to the
serial loop with a one-line warning in the log; asking for a scheduler is an error.
"""

from __future__ import annotations

import asyncio
import logging
import os
from typing import Callable, Sequence, TypeVar

from bsslam.errors import ConfigError, MissingDependencyError

T = TypeVar("T")
Progress = Callable[[int, int], None]

logger = logging.getLogger(__name__)

DASK_EXTRA_HINT = "pip install 'bsslam[dask]'"
#: How long a local worker may take to close before it is killed (s).
WORKER_CLOSE_TIMEOUT_S = 30.0


def run_all(
    fn: Callable[[object], T],
    items: Sequence[object],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> list[T]:
    """Call ``fn(item)`` for every item, in this process or on a Dask cluster.

    Args:
        fn: a top-level function (or a ``functools.partial`` of one) of one item; it and
            its result must pickle, as must the items, unless the runs are serial.
        items: the inputs, one run each.
        workers: 1 = serially in this process; N > 1 = a local cluster of N processes;
            None = a local cluster with one process per core. Not with ``scheduler``.
        scheduler: address of a running Dask scheduler, e.g. ``tcp://10.0.0.5:8786``.
        progress: called as ``progress(done, total)`` each time a run finishes.

    Returns:
        The results in the order of ``items`` (not of completion).

    Raises:
        ConfigError: ``workers`` < 1, or both ``workers`` and ``scheduler`` given.
        MissingDependencyError: ``scheduler`` given but Dask is not installed.
        Whatever ``fn`` raises, for the first failing run to finish; the other runs are
        cancelled.
    """
    items = list(items)
    if workers is not None and workers < 1:
        raise ConfigError(f"workers must be ≥ 1, got {workers}")
    if workers is not None and scheduler is not None:
        raise ConfigError("give workers or a scheduler address, not both: a cluster has its own workers")
    if scheduler is None and (workers == 1 or len(items) <= 1):
        return _run_serially(fn, items, progress)
    try:
        import distributed
    except ImportError:
        if scheduler is not None:
            raise MissingDependencyError(f"a Dask scheduler needs dask[distributed]: {DASK_EXTRA_HINT}") from None
        logger.warning("Dask is not installed (%s): running the %d runs one after the other",
                       DASK_EXTRA_HINT, len(items))
        return _run_serially(fn, items, progress)
    if scheduler is not None:
        with distributed.Client(scheduler) as client:
            return _run_on(client, fn, items, progress)
    n_workers = min(workers or os.cpu_count() or 1, len(items))
    # Processes, one thread each: the filter's step is Python holding the GIL, so threads
    # would not run in parallel. The scheduler's HTTP server on any free port: the default
    # 8787 is taken by a second cluster on the machine, with a warning.
    with distributed.LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, distributed.Client(cluster) as client:
        results = _run_on(client, fn, items, progress)
        # A worker holding numba's compiled code takes seconds to exit, more on a busy
        # machine: longer than the 4 s the cluster's own close waits before it kills the
        # process with a warning. Closed here first, with time to spare.
        cluster.sync(_close_workers, cluster, WORKER_CLOSE_TIMEOUT_S)
        return results


async def _close_workers(cluster, timeout_s: float) -> None:
    await asyncio.gather(*(worker.close(timeout=timeout_s) for worker in cluster.workers.values()))


def _run_serially(fn: Callable[[object], T], items: list, progress: Progress | None) -> list[T]:
    results = []
    for item in items:
        results.append(fn(item))
        if progress is not None:
            progress(len(results), len(items))
    return results


def _run_on(client, fn: Callable[[object], T], items: list, progress: Progress | None) -> list[T]:
    from distributed import as_completed

    # pure=False: every item is its own run even if two are equal, and hashing the function's
    # arguments (a whole configuration) for task keys is wasted work.
    futures = client.map(fn, items, pure=False)
    index_of = {future.key: i for i, future in enumerate(futures)}
    results: list = [None] * len(items)
    try:
        for done, future in enumerate(as_completed(futures), start=1):
            results[index_of[future.key]] = future.result()  # re-raises a failed run's error
            if progress is not None:
                progress(done, len(items))
    except BaseException:
        client.cancel(futures)
        raise
    # Forget the results on the scheduler before the workers that hold them close: else
    # each closing worker "loses" them and the scheduler warns that it must recompute them.
    client.cancel(futures)
    return results
