"""One call in a forked worker process, its printed lines labelled and relayed, its errors re-raised here.

The demo runs its benchmark cases side by side with this (one per core).  What the worker prints to
``sys.stdout`` or ``sys.stderr`` reaches this process's streams whole line by whole line, each line
labelled (e.g. ``[triple-chain] ``), so that the lines of several cases stay readable; progress bars are
off inside (they redraw one terminal line, which several processes cannot share).  An exception in the
worker is raised again by :meth:`Worker.result` with its type, message and attributes, the worker's
traceback attached as its ``__cause__``: an :class:`~fmu_opinf.errors.FmuOpinfError` still ends as the
command line's one-line error.  The worker ignores SIGINT (the caller decides), stops as after an interrupt
on the SIGTERM of :meth:`Worker.stop` (its temporary files removed) and exits when the calling process dies.
"""

from __future__ import annotations

import contextlib
import io
import multiprocessing as mp
import multiprocessing.connection
import os
import pickle
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["Worker", "can_fork", "labelled_output"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: Seconds a worker has to clean up after :meth:`Worker.stop` asked it to stop, before it is killed.
STOP_GRACE = 3.0


def can_fork() -> bool:
    """True where workers are forked (Linux; macOS and Windows would need a fresh interpreter per worker)."""
    return sys.platform.startswith("linux") and "fork" in mp.get_all_start_methods()


class LabelledLines(io.TextIOBase):
    """A text stream that hands whole lines, each starting with ``label``, to ``emit``.

    Lines that already start with the label's bracketed name (e.g. ``[anchored-msd] snapshot window``) are
    passed on unchanged.  ``isatty()`` is False, so progress bars stay off.  Threads may write at once (a
    demo case's export thread warning while its main thread prints): each write is whole before the next.
    """

    def __init__(self, label: str, emit: Callable[[str], None]) -> None:
        super().__init__()
        self.label = label
        self._name = label.strip()
        self._emit = emit
        self._pending = ""
        self._lock = threading.RLock()  # reentrant: emit may write here again (a warning printed while emitting)

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return False

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return "utf-8"

    def write(self, text: str) -> int:
        with self._lock:
            *lines, self._pending = (self._pending + text).split("\n")
            if lines:
                self._emit("".join(line + "\n" if line.startswith(self._name) else self.label + line + "\n"
                                   for line in lines))
        return len(text)

    def finish(self) -> None:
        """Pass on an unfinished last line."""
        with self._lock:
            if self._pending:
                self.write("\n")


def _locked_writer(stream: Any, lock: threading.Lock) -> Callable[[str], None]:
    def emit(text: str) -> None:
        with lock:
            stream.write(text)
            stream.flush()

    return emit


@contextlib.contextmanager
def labelled_output(label: str, lock: threading.Lock) -> Iterator[None]:
    """Inside the block this process's ``sys.stdout`` and ``sys.stderr`` write labelled whole lines.

    ``lock`` serialises them with the lines that :class:`Worker` relays to the same streams.
    """
    saved = sys.stdout, sys.stderr
    streams = [LabelledLines(label, _locked_writer(stream, lock)) for stream in saved]
    sys.stdout, sys.stderr = streams
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved
        for stream in streams:
            stream.finish()


class RemoteTraceback(Exception):
    """The traceback of an exception raised in a worker process (attached as ``__cause__``)."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return "\n\nin the worker process:\n" + self.text


def _encode_exception(exc: BaseException) -> tuple[str, bytes | None, str]:
    """``(how, data, traceback text)`` of an exception, for :func:`_decode_exception` in another process.

    Pickled as is where that gives back the same type and message; else its class, ``args`` and attributes
    (classes whose ``__init__`` does not take their ``args``, e.g. ``StepError``); else the text alone.
    """
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    with contextlib.suppress(Exception):
        data = pickle.dumps(exc)
        clone = pickle.loads(data)
        if type(clone) is type(exc) and str(clone) == str(exc):
            return "pickle", data, text
    with contextlib.suppress(Exception):
        return "state", pickle.dumps((type(exc), exc.args, dict(vars(exc)))), text
    return "text", None, text


def _decode_exception(how: str, data: bytes | None, text: str) -> BaseException:
    """The exception :func:`_encode_exception` described, its ``__cause__`` the worker's traceback."""
    exc: BaseException | None = None
    with contextlib.suppress(Exception):
        if how == "pickle":
            exc = pickle.loads(data)
        elif how == "state":
            cls, args, attrs = pickle.loads(data)
            exc = cls.__new__(cls, *args)
            exc.args = args
            exc.__dict__.update(attrs)
    if exc is None:
        exc = RuntimeError("a worker process failed (its traceback follows as the cause)")
    exc.__cause__ = RemoteTraceback(text)
    return exc


def exit_with_parent() -> None:
    """Leave at once when the parent process dies (e.g. killed by SIGKILL or SIGTERM): a child that ignores those
    signals (the parent decides when it stops) would otherwise compute on, unseen, until it next reports."""
    parent = mp.parent_process()
    if parent is None:
        return

    def watch() -> None:
        mp.connection.wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _worker_main(conn: Any, label: str, function: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    """Forked process: ignore SIGINT (a Ctrl-C reaches the parent, which decides), take SIGTERM (the parent's
    :meth:`Worker.stop`) as an interrupt that cleans up, send labelled lines, then ``("done", value)`` or
    ``("error", ...)``."""
    from ._interrupts import interrupt_once_on_sigterm

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    interrupt_once_on_sigterm()
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _SIGNALS)
    exit_with_parent()
    lock = threading.Lock()  # a thread of the call (e.g. a warning) may print while the main thread sends

    def send(message: tuple) -> None:
        with lock:
            conn.send(message)

    streams = [LabelledLines(label, lambda text, kind=kind: send((kind, text))) for kind in ("out", "err")]
    sys.stdout, sys.stderr = streams
    try:
        message: tuple = ("done", function(*args, **kwargs))
    except BaseException as exc:  # noqa: BLE001 - every failure goes to the caller
        message = ("error", _encode_exception(exc))
    for stream in streams:
        stream.finish()
    try:
        send(message)
    except Exception as exc:  # noqa: BLE001 - e.g. a result that cannot be pickled
        send(("error", _encode_exception(exc)))


class Worker:
    """``function(*args, **kwargs)`` in a forked process (see the module's description).

    Parameters
    ----------
    label : str
        Prefix of the worker's lines, e.g. ``"[triple-chain] "``.
    function : callable
        Runs in the worker; its value must be picklable.
    lock : threading.Lock
        Serialises the relayed lines with this process's own (see :func:`labelled_output`).
    """

    def __init__(self, label: str, function: Callable[..., Any], *args: Any, lock: threading.Lock,
                 **kwargs: Any) -> None:
        context = mp.get_context("fork")
        self.label = label
        self._conn, child = context.Pipe(duplex=False)
        self._outcome: tuple | None = None
        out, err = sys.stdout, sys.stderr
        for stream in (out, err):
            stream.flush()  # nothing buffered here may be written twice by the child
        # not a daemon: daemons may not start processes (the FMU runs); stop() and the parent watch end it
        self._process = context.Process(target=_worker_main, args=(child, label, function, args, kwargs))
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)  # the child starts with them blocked
        try:
            self._process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
            child.close()
        self._relay = threading.Thread(target=self._relay_lines, args=(_locked_writer(out, lock),
                                                                        _locked_writer(err, lock)), daemon=True)
        self._relay.start()

    def _relay_lines(self, out: Callable[[str], None], err: Callable[[str], None]) -> None:
        while True:
            try:
                kind, payload = self._conn.recv()
            except (EOFError, OSError):
                self._outcome = ("died", None)
                return
            if kind in ("out", "err"):
                (out if kind == "out" else err)(payload)
            else:
                self._outcome = (kind, payload)
                return

    def running(self) -> bool:
        """Whether the worker has not yet sent its result (or died)."""
        return self._relay.is_alive()

    def wait(self, seconds: float) -> None:
        """Wait at most ``seconds`` for the worker's result."""
        self._relay.join(seconds)

    def result(self) -> Any:
        """Wait for the worker; its function's value, or its exception raised here."""
        while self._relay.is_alive():
            self._relay.join(0.1)  # a short wait keeps Ctrl-C responsive
        self._process.join()
        kind, payload = self._outcome
        if kind == "done":
            return payload
        if kind == "error":
            raise _decode_exception(*payload)
        raise RuntimeError(f"the worker process {self.label.strip()} ended without a result "
                           f"(exit code {self._process.exitcode})")

    def stop(self) -> None:
        """Stop the worker if it still runs, and release its pipe: SIGTERM first, which it takes as an interrupt
        and cleans up after (killed at once, a demo worker left its temporary folders behind, audit 55), then
        SIGKILL after :data:`STOP_GRACE` seconds."""
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(STOP_GRACE)
        if self._process.is_alive():
            self._process.kill()
        self._process.join()
        self._relay.join()
        self._conn.close()
