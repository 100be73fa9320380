"""Producers driving a source block by block: in this process, or in a child process with shared memory.

A producer fills the rows a sink provides and yields ``(i0, count)`` per filled block; a failing
step is raised as :class:`~fmu_opinf.sources.StepError` after the valid samples before it were yielded.
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing as mp
import os
import pickle
import signal as _signal
import sys
import warnings
from collections.abc import Iterator
from multiprocessing import shared_memory
import time as _time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._forked import exit_with_parent
from .._interrupts import _SIGNALS, check_interrupt, deferred_interrupts
from .._validate import either
from ..errors import FMUError, FmuOpinfError, Interrupted
from ..sources import Source, StepError, first_report, said_key

if TYPE_CHECKING:
    from ._run import _Sink

__all__ = ["produce_inprocess", "produce_isolated", "source_label", "Interrupted", "deferred_interrupts",
           "check_interrupt", "use_fork_server"]


class _BlockSizes:
    """Rows per block: from a few, growing fourfold while a block takes less than a second, up to the sink's block.

    A fast model reaches full blocks after a few; a stiff one (an FE model whose integrator crawls: 0.4 s per
    sample, twelfth audit) keeps blocks of seconds, so the caller sees its progress instead of silence for
    minutes."""

    FIRST = 16
    SECONDS = 1.0

    def __init__(self, cap: int) -> None:
        self.cap = max(int(cap), 1)
        self.size = min(self.FIRST, self.cap)
        self.started = _time.perf_counter()

    def next(self, left: int) -> int:
        self.started = _time.perf_counter()
        return min(self.size, left)

    def took(self, count: int) -> None:
        if count >= self.size and _time.perf_counter() - self.started < self.SECONDS:
            self.size = min(4 * self.size, self.cap)


def produce_inprocess(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink) -> Iterator[tuple[int, int]]:
    """Fill the sink's rows block by block, yielding ``(i0, count)`` of each filled block.

    A :class:`StepError` is raised after the block holding the valid samples before it is yielded.
    """
    k = len(t)
    source.start(t, U)
    blocks = _BlockSizes(sink.block)
    try:
        i = 0
        while i < k:
            check_interrupt()
            count = blocks.next(k - i)
            try:
                source.advance(sink.rows(i, count), i, count)
            except StepError as exc:
                valid = max(0, exc.step - i) if exc.step >= 0 else 0
                if valid:
                    yield i, valid
                raise
            blocks.took(count)
            yield i, count
            i += count
    finally:
        sink.events = source.events_seen()  # also those before a failure
        sink.report = source.run_report()
        source.close()


_HEADER = 64  # bytes before the row buffer in shared memory: int64 count of valid rows


def _child_main(conn: Any, shm_name: str, cap: int, source: Source | bytes, t: np.ndarray, U: np.ndarray,
                inherited: _Inherited | None = None) -> None:
    """Child process: run the source, fill the shared buffer, report through ``conn``.

    The child ignores SIGINT and SIGTERM: the parent decides (Ctrl-C reaches the whole process group)
    and kills the child when it stops; a child whose parent died leaves at once (audit of 2026-12-05: one inside a
    sample that took minutes outlived its killed command for 7 minutes, and ignored SIGTERM).  A child of the fork
    server gets ``inherited`` (the caller's environment and standard output and error at the start of the run,
    which a spawned child inherits anyway) and the source pickled, unpickled only once that is in place.
    """
    for signum in _SIGNALS:
        _signal.signal(signum, _signal.SIG_IGN)
    exit_with_parent()
    if inherited is not None:
        inherited.take_over()
    warnings.showwarning = functools.partial(_relay_warning, conn)
    if isinstance(source, bytes):
        source = pickle.loads(source)
    shm = shared_memory.SharedMemory(name=shm_name)
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, source.width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    try:
        _child_loop(conn, source, t, U, count, rows)
    except (BrokenPipeError, EOFError, ConnectionResetError):
        pass  # the parent is gone (killed, or stopped the run): nobody to report to
    finally:
        del count, rows
        shm.close()


def _relay_warning(conn: Any, message: Warning | str, category: type[Warning], filename: str, lineno: int,
                   file: Any = None, line: str | None = None) -> None:
    """The child's ``warnings.showwarning``: the warning goes to the parent, which issues it there (formatted as
    the caller's warnings are: one line on the command line, caught by ``warnings.catch_warnings``)."""
    conn.send(("warning", category.__name__, str(message)))


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
    blocks = _BlockSizes(cap)
    try:
        while i < k:
            c = blocks.next(k - i)
            count[0] = 0
            try:
                source.advance(rows, i, c, published=count)
            except StepError as exc:
                conn.send(("fail", str(exc), exc.step, exc.time, source.events_seen(), source.run_report()))
                return
            i += c
            blocks.took(c)
            conn.send(("block", c))
            conn.recv()
        # stepping time without process start-up, and the events the model had
        conn.send(("done", _time.perf_counter() - started, source.events_seen(), source.run_report()))
    finally:
        source.close()


def produce_isolated(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink,
                     timeout: float | None = None) -> Iterator[tuple[int, int]]:
    """Like :func:`produce_inprocess`, with the source in a child process of its own (:func:`_process_context`).

    The child writes samples into shared memory and publishes after each sample how many rows are
    complete, so when it dies (a crashing binary) every sample it finished is still taken over.
    With ``timeout`` (seconds for the whole run) a hanging binary is killed and reported as
    :class:`~fmu_opinf.errors.FMUError`.
    """
    deadline = None if timeout is None else _time.monotonic() + timeout
    k, width = len(t), source.width
    cap = sink.block
    ctx = _process_context()
    forked = ctx.get_start_method() == "forkserver"
    payload = pickle.dumps(source) if forked else source   # (before the block: a source that fails to pickle,
    inherited = _Inherited(dict(os.environ)) if forked else None   # an FMU that does not unpack, left it behind)
    shm = shared_memory.SharedMemory(create=True, size=_HEADER + 8 * cap * max(width, 1))
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    count[0] = 0
    here, there = ctx.Pipe()
    proc = ctx.Process(target=_child_main, args=(there, shm.name, cap, payload, t, U, inherited), daemon=True)
    i0 = 0
    try:
        with _signals_blocked(), _main_not_rerun(source):  # the child starts with SIGINT/SIGTERM blocked
            try:
                proc.start()
            except (OSError, EOFError):  # the fork server died as the run was handed to it
                if not (forked and _server_dead(_SERVER_EXIT_WAIT)):
                    raise
                raise FMUError(f"the fork server of fmu-opinf's simulation processes stopped as the run of "
                               f"{source_label(source)} started; the run was stopped, run the command again") from None
        there.close()
        while True:
            message = _receive(here, proc, deadline)
            if message == ("timeout",):
                i = i0 + int(count[0])
                raise FMUError(f"{source_label(source)} did not finish within the timeout of {timeout:g} s "
                               f"(step {i} of {k}, t={t[min(i, k - 1)]:g}); it was stopped, increase "
                               f"{either('--timeout')} "
                               "or check the FMU")
            if message is not None and message[0] == "warning":  # no rows, no acknowledgement
                # each child opens the FMU afresh and says what it finds; the user hears it once
                if first_report(said_key(message[1], message[2])):
                    warnings.warn(message[2], _warning_class(message[1]), stacklevel=2)
                continue
            valid = _valid_rows(message, int(count[0]))
            if valid:
                sink.rows(i0, valid)[:] = rows[:valid]
                yield i0, valid
            if message is None:  # the child died without a word
                check_interrupt()  # killed with us by the same signal: an interrupt, not a crash
                proc.join(5)  # reap it, so that its exit code (the signal) is known
                i = i0 + valid
                if forked and _server_lost(proc):
                    raise FMUError(f"the fork server of fmu-opinf's simulation processes stopped during the run of "
                                   f"{source_label(source)} (step {i} of {k}); the run was stopped, run the command "
                                   "again")
                raise StepError(_crash_text(source, proc.exitcode, i, t), i, float(t[min(i, k - 1)]))
            if message[0] == "fail":
                sink.events = message[4] if len(message) > 4 else None  # the events before the failure
                sink.report = message[5] if len(message) > 5 else {}
                raise StepError(message[1], message[2], message[3])
            if message[0] == "error":
                raise _error_class(message[1])(message[2])
            if message[0] == "done":
                sink.seconds = message[1]
                sink.events, sink.report = message[2], message[3]
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
#: 0.4 s per run with a fresh interpreter, 0.025 s forked from the server).
_PRELOAD = ["fmu_opinf.snapshots._isolation", "fmu_opinf.sources", "scipy.integrate", "fmpy.fmi2", "fmpy.fmi3"]

#: Whether runs may start from multiprocessing's fork server (:func:`use_fork_server`; off for the Python API).
_FORK_SERVER = {"enabled": False}

#: The process whose fork server the runs use (None: none started by fmu-opinf yet).
_server_owner: int | None = None


def use_fork_server(enabled: bool = True) -> None:
    """Let isolated runs of this process start from multiprocessing's fork server (Linux; the command line does).

    The fork server is one per process and shared with every other user of multiprocessing's ``"forkserver"``
    start method in it: fmu-opinf starts it with SIGINT and SIGTERM blocked and its own preload list, which the
    processes of a ``Pool`` or ``Process(...)`` that the caller's own code starts later from it would inherit
    (``terminate()`` would no longer stop them).  So the Python API keeps spawning a fresh interpreter per run
    unless the caller opts in; the ``fmu-opinf`` command, where no other code shares the process, opts in.
    A script that does not use the ``"forkserver"`` start method itself can opt in as well.  The children take
    over the caller's environment and standard streams at each run, but what a process reads only when it starts
    (``LD_LIBRARY_PATH`` for an FMU's dependent libraries, BLAS thread counts, the umask) is the server's, from
    the first run: set those before it.
    """
    _FORK_SERVER["enabled"] = bool(enabled)


def _process_context() -> Any:
    """Where a run's child process comes from: multiprocessing's fork server, else a fresh interpreter (spawn).

    Every run gets a process of its own either way (a crashing binary loses only its run, and no state of an
    FMU's library survives into the next run), but the fork server has imported fmu-opinf, numpy, scipy and
    fmpy once, so a child starts in about 25 ms instead of 0.4 s (a recording runs 4-10 of them).  Used where
    enabled (:func:`use_fork_server`) on Linux (on macOS, forking after numpy and scipy are loaded is not safe
    with Apple's libraries), only in the process that started the server, which it does inside
    :func:`_signals_blocked` so that the server and its children keep SIGINT and SIGTERM blocked from the start.
    A server started by other code and a forked process (whose parent owns the server) spawn, and so does every
    run where the server's socket would not fit its path (:func:`_server_socket_fits`).
    """
    global _server_owner
    if not (_FORK_SERVER["enabled"] and sys.platform.startswith("linux")
            and "forkserver" in mp.get_all_start_methods()):
        return mp.get_context("spawn")
    if _server_owner != os.getpid() and not _server_socket_fits():
        return mp.get_context("spawn")
    if _server_owner == os.getpid():
        return mp.get_context("forkserver")
    from multiprocessing import forkserver

    if getattr(getattr(forkserver, "_forkserver", None), "_forkserver_pid", "unknown") is None:
        # no server in this process yet: the first run starts fmu-opinf's
        context = mp.get_context("forkserver")
        context.set_forkserver_preload(_PRELOAD)
        _server_owner = os.getpid()
        return context
    return mp.get_context("spawn")


#: Bytes of a Unix socket's path on Linux (``sockaddr_un.sun_path``), its terminating NUL included.
_SUN_PATH = 108


def _server_socket_fits() -> bool:
    """Whether the fork server's socket, which multiprocessing makes in its temporary folder
    (``$TMPDIR/pymp-XXXXXXXX/listener-XXXXXXXX``), has a path short enough to be bound.

    With a deep ``$TMPDIR`` (75 characters or so) the server could not start, and every isolated run of the command
    line failed with "the fork server ... stopped as the run ... started; run the command again", which a second
    attempt does not mend (a run table's rows, under pytest -n 2 with pytest's long temporary folders).
    """
    import tempfile

    # the folder multiprocessing would make (pymp- and 8 characters), not made here: asking multiprocessing for it
    # creates it in the current temporary folder, which a command's clean-up does not know of
    listener = os.path.join(tempfile.gettempdir(), "pymp-" + "x" * 8, "listener-" + "x" * 8)
    return len(os.fsencode(listener)) < _SUN_PATH


#: Seconds a fork server that broke its pipes is given to exit: a killed process closes them before it is a zombie.
_SERVER_EXIT_WAIT = 2.0


def _server_lost(proc: Any) -> bool:
    """Whether the fork server died (its children then report exit code 255); its orphaned child is killed."""
    if proc.exitcode != 255 or not _server_dead(_SERVER_EXIT_WAIT):
        return False
    with contextlib.suppress(ProcessLookupError, PermissionError):  # it may still be running
        os.kill(proc.pid, _signal.SIGKILL)
    return True


def _server_dead(wait: float = 0.0) -> bool:
    """Whether multiprocessing's fork server died (waiting up to ``wait`` seconds for it to exit); then it is
    forgotten, and the next run starts a new one."""
    from multiprocessing import forkserver

    server = getattr(forkserver, "_forkserver", None)
    if server is None:
        return False
    deadline = _time.monotonic() + wait
    while True:
        with server._lock:  # the lock multiprocessing takes to start the server: no run restarts it meanwhile
            pid = server._forkserver_pid
            if pid is None:
                return True  # another thread found it dead and reset it
            try:
                dead = os.waitpid(pid, os.WNOHANG)[0] != 0
            except ChildProcessError:
                dead = True
            if dead:
                with contextlib.suppress(OSError, TypeError):
                    os.close(server._forkserver_alive_fd)
                server._forkserver_pid = server._forkserver_alive_fd = server._forkserver_address = None
                return True
        if _time.monotonic() >= deadline:
            return False
        _time.sleep(0.005)


class _Inherited:
    """What a child of the fork server takes over from the caller at the start of its run: the environment, and
    the caller's standard output and error (passed as file descriptors; the server's may be older)."""

    def __init__(self, environment: dict[str, str]) -> None:
        self.environment = environment
        self.streams: list[Any] = []

    def __reduce__(self) -> tuple[Any, ...]:
        from multiprocessing import reduction

        streams = []
        for fd in (1, 2):
            # an inheritable descriptor only: with stdout closed, fd 1 may be the run's shared memory (opened
            # close-on-exec), and a child writing to it would overwrite the recorded samples
            with contextlib.suppress(OSError, ValueError):
                if os.get_inheritable(fd):
                    streams.append((fd, reduction.DupFd(fd)))  # sent with the process start (fork server protocol)
        return (_rebuild_inherited, (self.environment, streams))

    def take_over(self) -> None:
        if dict(os.environ) != self.environment:
            os.environ.clear()
            os.environ.update(self.environment)
        passed = {target for target, _ in self.streams}
        for target, duplicate in self.streams:
            with contextlib.suppress(OSError):
                fd = duplicate.detach() if hasattr(duplicate, "detach") else int(duplicate)
                os.dup2(fd, target)
                os.close(fd)
        for target in {1, 2} - passed:  # closed in the caller: nowhere, rather than the server's old stream
            with contextlib.suppress(OSError):
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, target)
                os.close(null)


def _rebuild_inherited(environment: dict[str, str], streams: list[Any]) -> _Inherited:
    inherited = _Inherited(environment)
    inherited.streams = streams
    return inherited


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


def _warning_class(name: str) -> type[Warning]:
    """The warning class called ``name``: fmu-opinf's own, a built-in one, else :class:`UserWarning`."""
    import builtins

    from .. import errors

    cls = getattr(errors, name, None) or getattr(builtins, name, None)
    return cls if isinstance(cls, type) and issubclass(cls, Warning) else UserWarning


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
