"""One BLAS thread for the small dense kernels of the fit and of the ROM simulation (issue 16, *Threads*).

The matrices of a reduced model are small (a few hundred rows at most): a second BLAS thread gains little on an
idle machine and collapses under oversubscription (measured: a 400-step ROM simulation at r = 36 took 1.4 ms
with one thread and 8-20 ms with two on a shared 2-core machine; inside the demo, where a C compiler and a second
model run beside it, 170 ms).  With one thread the results also do not depend on the machine's thread count.

threadpoolctl's limits are process-wide: two threads of one process entering and leaving them at once can leave
the pools at one thread (slower afterwards, never wrong).  The command line and the demo enter them from one
thread only; a library user running ROM simulations in a thread pool can hold one limit around the whole pool.
"""

from __future__ import annotations

import contextlib
import functools
import os
from typing import Any, Callable, TypeVar

__all__ = ["single_threaded", "run_single_threaded", "threads_for", "usable_cores", "SMALL_ENTRIES"]

T = TypeVar("T")


def single_threaded() -> Any:
    """Context manager limiting the BLAS/OpenMP thread pools to one thread (threadpoolctl)."""
    controller = _controller()
    return contextlib.nullcontext() if controller is None else controller.limit(limits=1)


@functools.lru_cache(maxsize=1)
def _controller() -> Any:
    """One threadpoolctl controller for the process, made after NumPy and SciPy have loaded their BLAS
    libraries: ``threadpool_limits`` scans the loaded libraries on every call (0.7 ms, 2.4 ms under load: a small
    projection took 2.5 ms instead of 13 us), the controller once (its limit then costs 0.02 ms)."""
    import numpy  # noqa: F401 - their BLAS libraries are loaded before the scan
    import scipy.linalg  # noqa: F401
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency; stay usable without it
        return None
    return ThreadpoolController()


#: Dense kernels on matrices up to this many entries (32 MB) run with one thread (:func:`threads_for`): a
#: 600 x 201 POD matrix took 0.2 s per SVD with two threads on the loaded machine and 5 ms with one.
SMALL_ENTRIES = 4_000_000


def threads_for(entries: int) -> Any:
    """:func:`single_threaded` for a kernel on a matrix of at most :data:`SMALL_ENTRIES` entries, else no limit
    (large factorizations keep the machine's threads)."""
    return single_threaded() if entries <= SMALL_ENTRIES else contextlib.nullcontext()


def run_single_threaded(function: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``function(*args, **kwargs)`` with one BLAS thread (picklable through ``functools.partial``)."""
    with single_threaded():
        return function(*args, **kwargs)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the platform says, else the CPU count)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
