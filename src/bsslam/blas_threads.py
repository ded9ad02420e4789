"""BLAS on one thread, for the per-scan work of the filter and the front end."""

from __future__ import annotations

import functools

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread"]


@functools.cache
def _blas_controller() -> ThreadpoolController:
    return ThreadpoolController()     # scanning the loaded libraries takes ~10 ms: once per process


def one_blas_thread():
    """A context in which BLAS runs on one thread. The per-scan matrices are small
    (hundreds of rows): BLAS threads only add overhead, under load they make a 170×170
    Cholesky 100× slower, and the thread count must not change the numbers between two
    runs of the same data."""
    return _blas_controller().limit(limits=1, user_api="blas")
