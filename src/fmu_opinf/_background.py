"""One piece of the fit beside the main thread, in a forked process or a second thread, which the main thread can
follow and stop (issue 16).

The fit refines two starts, the SDP solution and the least-squares candidate, and the second does not depend on
the first: on two cores it runs beside the SDP solve and the first refinement.  Their kernels (eigenvalues, matrix
products, FFTs, the L-BFGS update) release the GIL; measured at r = 35, two refinements took 2.0 s side by side
against 3.3 s one after the other, with the same results (each thread runs its own computation; the BLAS pools
stay at one thread, process-wide, held by the caller).

The SDP's two normalizations are independent problems too.  Side by side in *threads* they were measured and not
kept (same bits; the SDP alone at r = 50 took 17.2 s against 20.1 s, but the whole fit 36.3 s against 35.1 s,
since the second start already kept the other core busy): large LAPACK calls gain little from threads here, as
SciPy's OpenBLAS serializes concurrent calls (two threads factoring a 2550-square matrix five times each: 1.40 s
against 1.48 s one after the other; NumPy's OpenBLAS 1.16 s against 1.97 s).  In a forked *process*, with the
second start begun only once both are solved, they are kept from r = 20 on
(:data:`fmu_opinf.inference.SDP_SIDE_BY_SIDE_FROM`; figures there and in the inference module docstring).

Where it can, the call runs in a forked process instead (:class:`Background` ``mode="auto"``): two refinements in
two threads still wait for each other on the GIL between their many small NumPy calls (r = 35: 2.05 s for two
side by side in threads, 1.41 s in two processes, 1.34 s for one alone; r = 20: 1.27 / 0.77 / 0.72 s).  A process
is forked only where that is safe and can run: on Linux, from a process that is not a daemon and runs no other
thread (a lock held by another thread at the fork would stay held in the child; the demo's model workers and
Dask's worker processes therefore keep the thread).  The child computes the same bits (the same code, BLAS
limited to one thread, which the fork inherits); its progress reaches the caller's bar through a shared counter,
and :meth:`Background.cancel` kills it at once.

Signals reach the main thread only.  The main thread therefore never leaves a :class:`Background` running: on any
exception it calls :meth:`Background.cancel`, which asks the worker to stop at its next iteration and waits for
it.  The worker looks at the request in :func:`checkpoint`, which the refinement's L-BFGS calls every iteration
and which does nothing outside a :class:`Background`.
"""

from __future__ import annotations

import contextvars
import multiprocessing as mp
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

from ._progress import Progress

__all__ = ["Background", "Cancelled", "can_fork_here", "checkpoint"]

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
    """``function(*args, **kwargs)`` started at once beside the caller: in a forked process where
    :func:`can_fork_here`, else in a daemon thread (module docstring).

    Parameters
    ----------
    function, args, kwargs
        The call.  It reports progress and, in a thread, honours :meth:`cancel` through :func:`checkpoint`; in a
        process its value (and any exception) must be picklable.
    label : str
        What :meth:`result` calls the work on its progress bar.
    total : int
        Units of work that :func:`checkpoint` counts (for the progress bar).
    mode : {"auto", "process", "thread"}, default="auto"
        ``"auto"``: a process where :func:`can_fork_here`, else a thread.  ``"process"`` is refused where no
        process can be forked.
    """

    def __init__(self, function: Callable[..., T], *args: Any, label: str = "background work", total: int = 1,
                 mode: str = "auto", **kwargs: Any) -> None:
        if mode not in ("auto", "process", "thread"):
            raise ValueError(f"mode={mode!r} is not known; use 'auto', 'process' or 'thread'")
        if mode == "process" and not can_fork_here():
            raise RuntimeError("no process can be forked here (not Linux, a daemon process, or other threads)")
        self.label, self.total, self._done = label, int(total), 0
        self._stop = threading.Event()
        self._outcome: tuple[bool, Any] | None = None
        self.mode = "process" if mode == "process" or (mode == "auto" and can_fork_here()) else "thread"
        if self.mode == "process":
            self._start_process(function, args, kwargs)
            return
        self._thread = threading.Thread(target=self._run, args=(function, args, kwargs), daemon=True,
                                        name=f"fmu-opinf {label}")
        self._thread.start()

    @property
    def done(self) -> int:
        """Units of work done so far (what the call last passed to :func:`checkpoint`)."""
        return int(self._counter.value) if self.mode == "process" else self._done

    @done.setter
    def done(self, value: int) -> None:
        self._done = value

    def _start_process(self, function: Callable[..., T], args: tuple, kwargs: dict) -> None:
        from ._forked import Worker

        self._counter = mp.get_context("fork").Value("l", 0, lock=False)
        self._worker = Worker(f"[{self.label}] ", _counted_call, self._counter, function, args, kwargs,
                              lock=threading.Lock())

    def _run(self, function: Callable[..., T], args: tuple, kwargs: dict) -> None:
        _CURRENT.set(self)
        try:
            self._outcome = (True, function(*args, **kwargs))
        except BaseException as error:  # handed to the main thread by result()
            self._outcome = (False, error)

    def _alive(self) -> bool:
        return self._worker.running() if self.mode == "process" else self._thread.is_alive()

    def _wait(self, seconds: float) -> None:
        if self.mode == "process":
            self._worker.wait(seconds)
        else:
            self._thread.join(seconds)

    def result(self, progress: bool = False) -> T:
        """Wait for the call (with a labelled progress bar on a terminal when ``progress``) and return its
        value, or raise its exception here."""
        with Progress(self.total, self.label, quiet=not progress) as bar:
            while self._alive():
                bar.update(self.done)
                self._wait(_POLL)
            bar.update(self.done)
        if self.mode == "process":
            if self._stop.is_set():
                raise Cancelled
            try:
                return self._worker.result()
            finally:
                self._worker.stop()
        ok, value = self._outcome
        if not ok:
            raise value
        return value

    def cancel(self) -> None:
        """Stop the call: kill the process at once, or ask the thread to stop at its next :func:`checkpoint`
        and wait until it has ended."""
        self._stop.set()
        if self.mode == "process":
            self._worker.stop()
            return
        while self._thread.is_alive():
            self._thread.join(_POLL)


def can_fork_here() -> bool:
    """Whether :class:`Background` can run its call in a forked process: on Linux, in a process that may have
    children (not a daemon) and runs no other thread (module docstring)."""
    from ._forked import can_fork

    return can_fork() and threading.active_count() == 1 and not mp.current_process().daemon


class _ChildProgress:
    """What :func:`checkpoint` sees in the forked process: ``done`` goes to the shared counter, never stopped
    (the parent kills the process instead)."""

    def __init__(self, counter: Any) -> None:
        self._counter = counter
        self._stop = threading.Event()

    @property
    def done(self) -> int:
        return int(self._counter.value)

    @done.setter
    def done(self, value: int) -> None:
        self._counter.value = int(value)


def _counted_call(counter: Any, function: Callable[..., T], args: tuple, kwargs: dict) -> T:
    """In the forked process: ``function(*args, **kwargs)`` with its :func:`checkpoint` counts in ``counter``."""
    _CURRENT.set(_ChildProgress(counter))  # type: ignore[arg-type]
    return function(*args, **kwargs)
