"""The one way bsslam compiles its inner loops: ``@jit`` (numba).

The hot paths ask many small questions per scan (tens of beams against a few curves, a few
hundred points against a grid). As whole-array numpy each step of such a question is a
dozen calls of a few microseconds, whatever its size; compiled loops cost less than one of
those calls. The options are chosen so that a compiled loop gives numpy's numbers:

* strict IEEE arithmetic (numba's default: no fast-math, no fused multiply-add), so a loop
  doing numpy's operations in numpy's order is bit-identical to it;
* ``error_model="numpy"``: x/0 gives ±inf or NaN as in numpy (the searches rely on it: a
  ray parallel to its curve has a zero slope), where Python semantics would raise;
* ``cache=True``: compiled once per machine into the package's ``__pycache__``, not at every
  start (about a second per kernel, on the first run only);
* ``nogil=True``: callers may run them from threads.
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator

from numba import njit

jit = njit(cache=True, nogil=True, error_model="numpy")


def needs_compiling(kernel) -> bool:
    """Whether this machine has yet to compile ``kernel`` (a ``@jit`` function): it has no
    cache index (nothing was compiled here, or ``NUMBA_CACHE_DIR`` points somewhere new),
    so its first call will wait for the compiler. A hint for the command line: False when
    it cannot tell (the index's path is numba's internal)."""
    try:
        return not os.path.exists(kernel._cache._cache_file._index_path)
    except AttributeError:
        return False


def load_compiler_registries() -> None:
    """Load numba's own implementations now (about half a second, paid anyway at the first
    kernel call). numba loads them lazily at that call, importing some thirty of its modules
    that register themselves in global tables; an exception raised in the middle (a Ctrl-C,
    or a SIGTERM the command line turns into one) leaves a module half-registered, and the
    next kernel call, e.g. while the results so far are written, fails with numba's
    "duplicate registration". A caller that raises on signals calls this first, with the
    signals held."""
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()


@contextlib.contextmanager
def kernel_interrupts() -> Iterator[None]:
    """Inside, a KeyboardInterrupt (Ctrl-C) is a KeyboardInterrupt even when it lands in a
    running kernel's callback into numba's Python code (boxing the arrays it returns): the
    kernel hands it on as a SystemError caused by it, which is raised again as the
    KeyboardInterrupt, so a caller's early end on an interruption still sees it. Any
    other SystemError passes unchanged."""
    try:
        yield
    except SystemError as exc:
        cause = exc.__cause__
        while cause is not None and not isinstance(cause, KeyboardInterrupt):
            cause = cause.__cause__
        if cause is None:
            raise
        raise cause from exc
