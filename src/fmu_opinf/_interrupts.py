"""Ctrl-C and SIGTERM as exceptions at safe points, never lost.

Python raises ``KeyboardInterrupt`` at an arbitrary bytecode.  When that bytecode belongs to a finalizer (a
``ZipFile.__del__`` while an FMU's description is read, an h5py weakref callback), Python prints "Exception
ignored" and goes on: the run continued to its end although the user pressed Ctrl-C.  Two mechanisms:

* :func:`remembered_interrupts` (the command line, around a whole verb): SIGINT and SIGTERM raise at once, and
  are also remembered; :func:`check_interrupt` raises it again at the next safe point, so a swallowed one is not
  lost;
* :func:`deferred_interrupts` (around a recording or simulation loop): SIGINT and SIGTERM only set the flag, and
  the loop stops at its next block.

Safe points call :func:`check_interrupt`: every block of a recording, every atomic write before its rename
(:func:`fmu_opinf._hdf5.atomic_path`, the FMU archives of :mod:`fmu_opinf.fmus`, the run files of
:mod:`fmu_opinf.runs`) and the end of the command, so an interrupted run never replaces the previous file and
never exits 0.
"""

from __future__ import annotations

import contextlib
import signal as _signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

from .errors import Interrupted

__all__ = ["check_interrupt", "deferred_interrupts", "remembered_interrupts", "interrupt_once_on_sigterm"]

_SIGNALS = (_signal.SIGINT, _signal.SIGTERM)
_pending: list[int] = []  # signals received and not yet acted on by check_interrupt


def check_interrupt() -> None:
    """Raise :class:`~fmu_opinf.errors.Interrupted` if a signal arrived and was not acted on."""
    if _pending:
        raise Interrupted(_pending[0])


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def remembered_interrupts() -> Iterator[None]:
    """SIGINT, and SIGTERM where it has its default action, raise :class:`~fmu_opinf.errors.Interrupted` at once
    and stay pending for :func:`check_interrupt` until the block ends (a raise that Python swallows in a finalizer
    is raised again at the next safe point, and not printed as "Exception ignored"); an error that leaves the block
    while it is pending is reported as the interrupt.  (SIGTERM's default action killed a fit, a comparison or an
    export on the spot, outside the atomic writes: temporary folders and compilers were left behind, audit 55.)

    Only in the main thread and for a signal the process does not ignore; otherwise nothing changes.
    """
    caught = [signum for signum in _SIGNALS if _signal.getsignal(signum) is not _signal.SIG_IGN
              and (signum == _signal.SIGINT or _signal.getsignal(signum) is _signal.SIG_DFL)]
    if not _in_main_thread() or not caught:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        if signum not in _pending:
            _pending.append(signum)
        raise Interrupted(signum)

    previous_hook = sys.unraisablehook
    quiet_hook = _quiet_about_remembered(previous_hook)
    previous = {signum: _signal.getsignal(signum) for signum in caught}
    try:  # installed inside: a Ctrl-C between the two still restores both
        for signum in caught:
            _signal.signal(signum, handler)
        sys.unraisablehook = quiet_hook
        yield
        check_interrupt()  # swallowed in a finalizer after the last safe point: the run still ends interrupted
    except Exception as exc:
        if _pending:  # its echo: a class whose creation the raise interrupted gives a RuntimeError, for instance
            raise Interrupted(_pending[0]) from exc
        raise
    finally:
        for signum, old in previous.items():
            _signal.signal(signum, old)
        sys.unraisablehook = previous_hook
        _pending.clear()


def interrupt_once_on_sigterm() -> None:
    """For a worker process that its caller stops by SIGTERM: the first SIGTERM raises
    :class:`~fmu_opinf.errors.Interrupted` and stays pending for :func:`check_interrupt` (a raise that Python
    swallows in a finalizer is raised again at the next safe point, without "Exception ignored"), later ones do
    nothing (audit 56: ``timeout`` signals the process group and the caller signals the worker again; the second
    raise, inside the handling of the first, ended the worker in a traceback)."""

    def handler(signum: int, frame: Any) -> None:
        if signum in _pending:
            return
        _pending.append(signum)
        raise Interrupted(signum)

    _signal.signal(_signal.SIGTERM, handler)
    sys.unraisablehook = _quiet_about_remembered(sys.unraisablehook)


def _quiet_about_remembered(previous_hook: Any) -> Any:
    """An unraisable hook that drops :class:`~fmu_opinf.errors.Interrupted`: Python swallows a raise inside a
    finalizer and would print its traceback, but the signal is pending and raised again at the next safe point."""

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, Interrupted) and _pending:
            return
        previous_hook(unraisable)

    return hook


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Turn SIGINT and SIGTERM into a flag that :func:`check_interrupt` raises at safe points.

    A KeyboardInterrupt raised at an arbitrary bytecode can land in an h5py weakref callback, where
    Python swallows it, and SIGTERM's default action leaves temporary files behind.  Inside this
    block the signal only sets a flag; the recording loop stops at the next block, the atomic writer
    removes its temporary file and the caller sees :class:`~fmu_opinf.errors.Interrupted`.  A second signal of
    the same kind acts at once.  Outside the main thread, or for a signal the process ignores, nothing changes.
    """
    if not _in_main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        if signum in _pending:  # pressed twice: stop now
            raise Interrupted(signum)
        _pending.append(signum)

    previous = {}
    for signum in _SIGNALS:
        if _signal.getsignal(signum) is not _signal.SIG_IGN:
            previous[signum] = _signal.signal(signum, handler)
    try:
        yield
        check_interrupt()
    finally:
        for signum, old in previous.items():
            _signal.signal(signum, old)
        _pending.clear()
