"""One piece of the fit in a second thread, which the main thread can follow and stop (issue 16).

The fit refines two starts, the SDP solution and the least-squares candidate, and the second does not depend on
the first: on two cores it runs beside the SDP solve and the first refinement.  Their kernels (eigenvalues, matrix
products, FFTs, the L-BFGS update) release the GIL; measured at r = 35, two refinements took 2.0 s side by side
against 3.3 s one after the other, with the same results (each thread runs its own computation; the BLAS pools
stay at one thread, process-wide, held by the caller).

Measured and not kept: the SDP's two normalizations side by side (same bits; the SDP alone at r = 50 took 17.2 s
against 20.1 s, but the whole fit 36.3 s against 35.1 s, since the second start already keeps the other core
busy).  Large LAPACK calls gain little from threads here anyway: SciPy's OpenBLAS serializes concurrent calls (two
threads factoring a 2550-square matrix five times each: 1.40 s against 1.48 s one after the other; NumPy's
OpenBLAS 1.16 s against 1.97 s).

Signals reach the main thread only.  The main thread therefore never leaves a :class:`Background` running: on any
exception it calls :meth:`Background.cancel`, which asks the worker to stop at its next iteration and waits for
it.  The worker looks at the request in :func:`checkpoint`, which the refinement's L-BFGS calls every iteration
and which does nothing outside a :class:`Background`.
"""

from __future__ import annotations

import contextvars
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

from ._progress import Progress

__all__ = ["Background", "Cancelled", "checkpoint"]

T = TypeVar("T")

#: The :class:`Background` whose worker thread is the current one (unset in every other thread).
_CURRENT: contextvars.ContextVar["Background[Any] | None"] = contextvars.ContextVar("fmu_opinf_background",
                                                                                     default=None)

#: Seconds between two looks of the waiting main thread (signals are handled between them).
_POLL = 0.1


class Cancelled(Exception):
    """Raised in the worker thread at its next :func:`checkpoint` after :meth:`Background.cancel`."""


def checkpoint(done: int) -> None:
    """Record ``done`` units of work of the current background call; raise :class:`Cancelled` if it was
    cancelled.  Outside a background thread: nothing."""
    call = _CURRENT.get()
    if call is None:
        return
    call.done = done
    if call._stop.is_set():
        raise Cancelled


class Background(Generic[T]):
    """``function(*args, **kwargs)`` started in a daemon thread at once.

    Parameters
    ----------
    function, args, kwargs
        The call.  It reports progress and honours :meth:`cancel` through :func:`checkpoint`.
    label : str
        What :meth:`result` calls the work on its progress bar.
    total : int
        Units of work that :func:`checkpoint` counts (for the progress bar).
    """

    def __init__(self, function: Callable[..., T], *args: Any, label: str = "background work", total: int = 1,
                 **kwargs: Any) -> None:
        self.label, self.total, self.done = label, int(total), 0
        self._stop = threading.Event()
        self._outcome: tuple[bool, Any] | None = None
        self._thread = threading.Thread(target=self._run, args=(function, args, kwargs), daemon=True,
                                        name=f"fmu-opinf {label}")
        self._thread.start()

    def _run(self, function: Callable[..., T], args: tuple, kwargs: dict) -> None:
        _CURRENT.set(self)
        try:
            self._outcome = (True, function(*args, **kwargs))
        except BaseException as error:  # handed to the main thread by result()
            self._outcome = (False, error)

    def result(self, progress: bool = False) -> T:
        """Wait for the call (with a labelled progress bar on a terminal when ``progress``) and return its
        value, or raise its exception here."""
        with Progress(self.total, self.label, quiet=not progress) as bar:
            while self._thread.is_alive():
                bar.update(self.done)
                self._thread.join(_POLL)
            bar.update(self.done)
        ok, value = self._outcome
        if not ok:
            raise value
        return value

    def cancel(self) -> None:
        """Ask the call to stop at its next :func:`checkpoint` and wait until the thread has ended."""
        self._stop.set()
        while self._thread.is_alive():
            self._thread.join(_POLL)
