"""Producers driving a source block by block: in this process, or in a child process with shared memory.

A producer fills the rows a sink provides and yields ``(i0, count)`` per filled block; a failing
step is raised as :class:`~fmu_opinf.sources.StepError` after the valid samples before it were yielded.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal as _signal
import sys
from collections.abc import Iterator
from multiprocessing import shared_memory
import time as _time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._interrupts import _SIGNALS, check_interrupt, deferred_interrupts
from ..errors import FMUError, FmuOpinfError, Interrupted
from ..sources import Source, StepError

if TYPE_CHECKING:
    from ._record import _Sink

__all__ = ["produce_inprocess", "produce_isolated", "source_label", "Interrupted", "deferred_interrupts",
           "check_interrupt"]


def produce_inprocess(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink) -> Iterator[tuple[int, int]]:
    """Fill the sink's rows block by block, yielding ``(i0, count)`` of each filled block.

    A :class:`StepError` is raised after the block holding the valid samples before it is yielded.
    """
    k = len(t)
    source.start(t, U)
    try:
        i = 0
        while i < k:
            check_interrupt()
            count = min(sink.block, k - i)
            try:
                source.advance(sink.rows(i, count), i, count)
            except StepError as exc:
                valid = max(0, exc.step - i) if exc.step >= 0 else 0
                if valid:
                    yield i, valid
                raise
            yield i, count
            i += count
    finally:
        source.close()


_HEADER = 64  # bytes before the row buffer in shared memory: int64 count of valid rows


def _child_main(conn: Any, shm_name: str, cap: int, source: Source, t: np.ndarray, U: np.ndarray,
                where: tuple[str, dict[str, str]] | None = None) -> None:
    """Child process: run the source, fill the shared buffer, report through ``conn``.

    The child ignores SIGINT and SIGTERM: the parent decides (Ctrl-C reaches the whole process group)
    and kills the child when it stops.  ``where``: the parent's working directory and environment at the
    start of the run (a child of the fork server inherits the server's, which may be older).
    """
    for signum in _SIGNALS:
        _signal.signal(signum, _signal.SIG_IGN)
    if where is not None:
        _take_over(*where)
    shm = shared_memory.SharedMemory(name=shm_name)
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, source.width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    try:
        _child_loop(conn, source, t, U, count, rows)
    finally:
        del count, rows
        shm.close()


def _child_loop(conn: Any, source: Source, t: np.ndarray, U: np.ndarray, count: np.ndarray, rows: np.ndarray) -> None:
    """Fill the shared buffer block by block, publishing the number of finished rows after every sample."""
    k, cap = len(t), len(rows)
    try:
        source.start(t, U)
    except StepError as exc:
        conn.send(("fail", str(exc), exc.step, exc.time))
        return
    except FmuOpinfError as exc:  # nothing recorded yet: the parent raises the same kind of error
        conn.send(("error", type(exc).__name__, str(exc)))
        return
    i = 0
    started = _time.perf_counter()
    try:
        while i < k:
            c = min(cap, k - i)
            count[0] = 0
            try:
                source.advance(rows, i, c, published=count)
            except StepError as exc:
                conn.send(("fail", str(exc), exc.step, exc.time))
                return
            i += c
            conn.send(("block", c))
            conn.recv()
        conn.send(("done", _time.perf_counter() - started))  # stepping time without process start-up
    finally:
        source.close()


def produce_isolated(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink,
                     timeout: float | None = None) -> Iterator[tuple[int, int]]:
    """Like :func:`produce_inprocess`, with the source in a spawned child process.

    The child writes samples into shared memory and publishes after each sample how many rows are
    complete, so when it dies (a crashing binary) every sample it finished is still taken over.
    With ``timeout`` (seconds for the whole run) a hanging binary is killed and reported as
    :class:`~fmu_opinf.errors.FMUError`.
    """
    deadline = None if timeout is None else _time.monotonic() + timeout
    k, width = len(t), source.width
    cap = sink.block
    shm = shared_memory.SharedMemory(create=True, size=_HEADER + 8 * cap * max(width, 1))
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    count[0] = 0
    ctx = _process_context()
    where = (os.getcwd(), dict(os.environ)) if ctx.get_start_method() == "forkserver" else None
    here, there = ctx.Pipe()
    proc = ctx.Process(target=_child_main, args=(there, shm.name, cap, source, t, U, where), daemon=True)
    i0 = 0
    try:
        with _signals_blocked(), _main_not_rerun(source):  # the child starts with SIGINT/SIGTERM blocked
            proc.start()
        there.close()
        while True:
            message = _receive(here, proc, deadline)
            if message == ("timeout",):
                i = i0 + int(count[0])
                raise FMUError(f"{source_label(source)} did not finish within the timeout of {timeout:g} s "
                               f"(step {i} of {k}, t={t[min(i, k - 1)]:g}); it was stopped, increase --timeout "
                               "or check the FMU")
            valid = _valid_rows(message, int(count[0]))
            if valid:
                sink.rows(i0, valid)[:] = rows[:valid]
                yield i0, valid
            if message is None:  # the child died without a word
                check_interrupt()  # killed with us by the same signal: an interrupt, not a crash
                proc.join(5)  # reap it, so that its exit code (the signal) is known
                i = i0 + valid
                raise StepError(_crash_text(source, proc.exitcode, i, t), i, float(t[min(i, k - 1)]))
            if message[0] == "fail":
                raise StepError(message[1], message[2], message[3])
            if message[0] == "error":
                raise _error_class(message[1])(message[2])
            if message[0] == "done":
                sink.seconds = message[1] if len(message) > 1 else None
                return
            i0 += valid
            here.send("ack")
    finally:
        if proc.is_alive():
            proc.kill()
        if proc.pid is not None:
            proc.join(5)
        here.close()
        del count, rows
        shm.close()
        shm.unlink()


#: Modules the fork server imports once, so that a run's child process starts without importing them (about
#: 0.4 s per run with a fresh interpreter, 0.03 s forked from the server).
_PRELOAD = ["fmu_opinf.snapshots._isolation", "fmu_opinf.sources", "scipy.integrate", "fmpy.fmi2", "fmpy.fmi3"]

#: The process whose fork server the runs use (None: none started by fmu-opinf yet).
_server_owner: int | None = None


def _process_context() -> Any:
    """Where a run's child process comes from: multiprocessing's fork server, else a fresh interpreter (spawn).

    Every run gets a process of its own either way (a crashing binary loses only its run, and no state of an
    FMU's library survives into the next run), but the fork server has imported fmu-opinf, numpy, scipy and
    fmpy once, so a child starts in about 30 ms instead of 0.4 s (a recording runs 4-10 of them).  The server
    is used only in the process that started it, inside :func:`_signals_blocked`, so that it and its children
    keep SIGINT and SIGTERM blocked from the start; a server started by other code, a forked process (whose
    parent owns the server) and platforms without fork servers (Windows) spawn as before.
    """
    global _server_owner
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    from multiprocessing import forkserver

    running = getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", "unknown")
    if _server_owner == os.getpid():
        return mp.get_context("forkserver")
    if running is None:  # no server in this process yet: the first run starts fmu-opinf's
        context = mp.get_context("forkserver")
        context.set_forkserver_preload(_PRELOAD)
        _server_owner = os.getpid()
        return context
    return mp.get_context("spawn")


def _take_over(cwd: str, environment: dict[str, str]) -> None:
    """Adopt the parent's working directory and environment (a relative FMU path, a licence variable)."""
    with contextlib.suppress(OSError):
        os.chdir(cwd)
    if dict(os.environ) != environment:
        os.environ.clear()
        os.environ.update(environment)


@contextlib.contextmanager
def _main_not_rerun(source: Source) -> Iterator[None]:
    """Start a spawned child without running the caller's main script again.

    A spawned child normally re-imports the parent's ``__main__`` (by path or module name); a user's script
    without an ``if __name__ == "__main__":`` guard then runs again in the child, which tries to spawn in turn
    and dies (``record(isolate=True)`` reported a crash at step 0; ``compare`` hung, even for SIGTERM: third
    audit, 2026-11-26).  The child needs nothing from ``__main__`` unless the source's class is defined
    there, so the main module's path and spec are hidden while the child starts."""
    main = sys.modules.get("__main__")
    if main is None or type(source).__module__ == "__main__":
        yield
        return
    hidden = {name: main.__dict__.pop(name) for name in ("__file__",) if name in main.__dict__}
    spec = getattr(main, "__spec__", None)
    main.__spec__ = None
    try:
        yield
    finally:
        main.__dict__.update(hidden)
        main.__spec__ = spec


@contextlib.contextmanager
def _signals_blocked() -> Iterator[None]:
    """Block SIGINT and SIGTERM while a child process is started (the mask is inherited), so that a
    Ctrl-C during the child's start-up cannot kill it with a traceback before it ignores them."""
    if not hasattr(_signal, "pthread_sigmask"):
        yield
        return
    old = _signal.pthread_sigmask(_signal.SIG_BLOCK, _SIGNALS)
    try:
        yield
    finally:
        _signal.pthread_sigmask(_signal.SIG_SETMASK, old)


def _error_class(name: str) -> type:
    """The fmu-opinf error class called ``name`` (FMUError if unknown)."""
    from .. import errors, sources

    cls = getattr(errors, name, None) or getattr(sources, name, None)
    return cls if isinstance(cls, type) and issubclass(cls, FmuOpinfError) else errors.FMUError


def _valid_rows(message: tuple | None, published: int) -> int:
    """Rows of the shared buffer to take over: a full block, or what was published before a failure."""
    if message is None or message[0] == "fail":
        return published
    return message[1] if message[0] == "block" else 0


def _receive(conn: Any, proc: Any, deadline: float | None = None) -> tuple | None:
    """Next message from the child, None once it has exited without one, ``("timeout",)`` after ``deadline``."""
    while True:
        check_interrupt()
        if deadline is not None and _time.monotonic() > deadline:
            return ("timeout",)
        if conn.poll(0.05):
            try:
                return conn.recv()
            except (EOFError, OSError):
                return None
        if not proc.is_alive():
            if conn.poll(0):
                continue
            return None


def _crash_text(source: Source, exitcode: int | None, i: int, t: np.ndarray) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            how = f"signal {_signal.Signals(-exitcode).name}"
        except ValueError:
            how = f"signal {-exitcode}"
    else:
        how = f"exit code {exitcode}"
    when = f"t={t[i - 1]:g} -> {t[i]:g}" if 0 < i < len(t) else f"t={t[min(i, len(t) - 1)]:g}"
    return f"{source_label(source)} crashed the simulation process ({how}) at step {i} ({when})"


def source_label(source: Source) -> str:
    path = getattr(source, "path", None)
    return Path(path).name if path else type(source).__name__
