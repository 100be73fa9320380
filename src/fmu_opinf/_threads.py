"""One BLAS thread for the small dense kernels of the fit and of the ROM simulation (issue 16, *Threads*).

The matrices of a reduced model are small (a few hundred rows at most): a second BLAS thread gains little on an
idle machine and collapses under oversubscription (measured: a 400-step ROM simulation at r = 36 took 1.4 ms
with one thread and 8-20 ms with two on a shared 2-core machine; inside the demo, where a C compiler and a second
model run beside it, 170 ms).  With one thread the results also do not depend on the machine's thread count.
"""

from __future__ import annotations

import contextlib
from typing import Any, Callable, TypeVar

__all__ = ["single_threaded", "run_single_threaded"]

T = TypeVar("T")


def single_threaded() -> Any:
    """Context manager limiting the BLAS/OpenMP thread pools to one thread (threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency; stay usable without it
        return contextlib.nullcontext()
    return threadpool_limits(limits=1)


def run_single_threaded(function: Callable[..., T], *args: Any, **kwargs: Any) -> T:
    """``function(*args, **kwargs)`` with one BLAS thread (picklable through ``functools.partial``)."""
    with single_threaded():
        return function(*args, **kwargs)
