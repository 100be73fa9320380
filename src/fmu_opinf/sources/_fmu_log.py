"""The FMUs' log messages: the ones fmu-opinf does not keep dropped as cheaply as Python allows, but counted.

fmu-opinf instantiates every FMU with ``loggingOn = false`` and keeps only the messages of a call that failed
(status Discard or worse, :meth:`FMUSource._logger`).  An FMU may still call its logger at any time (FMI 2.0
section 2.1.5; a debug build, or one that ignores ``loggingOn``), and each call crosses from C into Python: audit
79a, F3, 100 OK messages per ``fmi2GetDerivatives`` made a recording 16 times slower.  FMI 2 forbids a NULL logger
(``fmi2CallbackFunctions.logger`` is required), and fmpy always gives FMI 3's ``fmi3Instantiate*`` a callback, so
the crossing itself stays; what follows it is made short: a message below Discard of one of our instances is
counted and dropped before its strings are converted (FMI 2: the callback's strings arrive as bare addresses),
and the count lets the slow-run warning name the logging as the cause (:func:`logging_cause`).
"""

from __future__ import annotations

import ctypes
import itertools
import time
import weakref
from collections.abc import Callable
from typing import Any

__all__ = ["DROPPED_BELOW", "register", "fmi2_callbacks", "fmi3_logger", "messages_of", "seconds_per_message",
           "logging_cause", "logging_switches", "LOGGING_SHARE"]

#: Status below which a message is counted and dropped (fmi2OK = 0, fmi2Warning = 1; Discard = 2 and worse are
#: kept, :meth:`FMUSource._logger`).
DROPPED_BELOW = 2
#: Share of a run's time that the dropped messages are estimated to take (:func:`seconds_per_message`) from which
#: the slow-run warning names the logging first.  Low on purpose: the estimate is an idle machine's and the
#: integrator's seconds a loaded one's (audit 79a's FMU, 100 messages per derivative call: about 90 % of a call
#: measured on an idle machine, 21 % estimated during a recording on a loaded one).
LOGGING_SHARE = 0.1

#: Keys of the instances of this process: an FMI 2 instance's ``componentEnvironment``, which its messages carry.
_KEYS = itertools.count(1)
#: Messages dropped per instance key (the key's presence marks the instance as ours).
_COUNTS: dict[int, int] = {}
#: The FMI 2 log messages' recipients by key (weak: a closed source is gone).
_TARGETS: dict[int, Any] = {}
#: The one FMI 2 dispatcher of the process and its cast to fmpy's logger type (kept alive: the FMUs point at it).
_DISPATCH: list[Any] = []
_PER_MESSAGE: list[float] = []

#: FMI 2 logger with the strings as bare addresses: ctypes then makes no bytes objects for a dropped message.
_RAW_FMI2_LOGGER = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p,
                                    ctypes.c_void_p)


def register(target: Callable[..., None]) -> int:
    """A new instance key whose kept messages reach ``target`` (a bound method, held weakly) and whose dropped ones
    are counted under the key."""
    key = next(_KEYS)
    _COUNTS[key] = 0
    _TARGETS[key] = weakref.WeakMethod(target)
    return key


def messages_of(key: int | None) -> int:
    """How many messages below Discard the instance ``key`` has logged (and fmu-opinf dropped) so far."""
    return _COUNTS.get(key, 0) if key is not None else 0


def _text(address: int | None) -> bytes:
    return ctypes.string_at(address) if address else b""


def _make_dispatch() -> Any:
    from fmpy.fmi2 import printLogMessage

    counts = _COUNTS

    def dispatch(env: int | None, name: int | None, status: int, category: int | None,
                 message: int | None) -> None:
        if status < DROPPED_BELOW and env in counts:   # the common case first: one comparison, one lookup
            counts[env] += 1
            return
        found = _TARGETS.get(env) if isinstance(env, int) else None
        logger = found() if found is not None else None
        (logger or printLogMessage)(env, _text(name), status, _text(category), _text(message))

    return dispatch


def fmi2_callbacks(target: Callable[..., None]) -> tuple[Any, int]:
    """FMI 2 callbacks whose kept log messages reach ``target``, through fmpy's native logger proxy, and the
    instance's key (:func:`messages_of`).

    The proxy (which formats the variadic messages) keeps the logger it was last given in one process-wide slot,
    which fmpy's default callbacks and ``fmpy.simulate_fmu(logger=...)`` use too.  A logger per source left that
    slot pointing at freed memory once the source was gone, and the next FMU that logged through the proxy crashed
    the process (found 2026-11-28: ``fmpy.simulate_fmu`` after a recording, the FMU logging an error); so does
    ``simulate_fmu``'s own logger after it returns.  The slot is set, at every instantiation, to one dispatcher
    that lives as long as the process; it finds the recipient by the ``componentEnvironment`` the FMU passes back,
    and hands other instances' messages to fmpy's default printer.
    """
    from fmpy.fmi2 import defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
    from fmpy.logging import addLoggerProxy

    if not _DISPATCH:
        raw = _RAW_FMI2_LOGGER(_make_dispatch())
        _DISPATCH.extend([raw, ctypes.cast(raw, fmi2CallbackLoggerTYPE)])
    key = register(target)
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _DISPATCH[1]
    callbacks.allocateMemory = defaultCallbacks.allocateMemory
    callbacks.freeMemory = defaultCallbacks.freeMemory
    callbacks.componentEnvironment = key
    addLoggerProxy(ctypes.byref(callbacks))   # the slot holds the dispatcher again; callbacks.logger is the proxy
    return callbacks, key


def fmi3_logger(target: Callable[..., None]) -> tuple[Callable[..., None], int]:
    """An FMI 3 ``logMessage`` for fmpy's ``instantiate`` that counts and drops messages below Discard and hands
    the others to ``target(env, status, message)``, and the instance's key."""
    key = register(target)
    counts = _COUNTS

    def log_message(env: Any, status: int, category: bytes, message: bytes) -> None:
        if status < DROPPED_BELOW:
            counts[key] += 1
            return
        found = _TARGETS[key]()
        if found is not None:
            found(env, status, message)

    return log_message, key


def seconds_per_message() -> float:
    """An estimate of the seconds one dropped message costs: fmpy's native proxy (which formats the message and
    calls the dispatcher, taking Python's lock) called a few thousand times with a message of 50 characters, the
    fastest of five rounds (a loaded machine stretches some).  Measured once per process.  On an idle machine it
    gave 1.0 us where audit 79a's FMU spent 0.75 to 0.9 us per message (its derivative call with 100 messages
    against the same FMU without them); on a loaded one the FMU's share is larger than this estimate says."""
    if not _PER_MESSAGE:
        callbacks, key = fmi2_callbacks(_Calibration().log)
        message = b"solver trace 12 at t=0.12345678901234567: residual ok"
        rounds, calls = [], 2000
        try:
            for _ in range(5):
                started = time.perf_counter()
                for _ in range(calls):
                    callbacks.logger(key, b"calibration", 0, b"logAll", message)
                rounds.append((time.perf_counter() - started) / calls)
        finally:
            _COUNTS.pop(key, None)
            _TARGETS.pop(key, None)
        _PER_MESSAGE.append(min(rounds))
    return _PER_MESSAGE[0]


class _Calibration:
    """The recipient of :func:`seconds_per_message`'s messages (none arrives: they are all dropped)."""

    def log(self, *args: Any) -> None:
        """Ignore a message."""


def logging_cause(name: str, messages: int, seconds: float, per_call: float | None, per: str,
                  advice: str) -> str:
    """The slow-run warning's first cause where the FMU's dropped log messages are estimated to take at least
    :data:`LOGGING_SHARE` of the run's ``seconds`` (:func:`seconds_per_message`), else "".

    Parameters
    ----------
    name : str
        The FMU's file name.
    messages : int
        Messages below Discard the FMU logged in the run so far.
    seconds : float
        Wall seconds of the run so far (the integrator's).
    per_call : float or None
        Messages per derivative call (or per step, see ``per``) where measured.
    per : str
        What ``per_call`` counts: ``"derivative call"`` or ``"step"``.
    advice : str
        The FMU's own ways to turn its logging off (:func:`logging_switches`), or "".

    Returns
    -------
    str
        One sentence naming the count, the estimated share and the fix, ending in ``"; "``, or "".
    """
    if messages <= 0 or not seconds > 0:
        return ""
    cost = messages * seconds_per_message()
    share = min(cost / seconds, 1.0)
    if share < LOGGING_SHARE:
        return ""
    rate = f" ({per_call:.3g} per {per})" if per_call else ""
    taken = ("nearly all of the run's time" if share > 0.9 else
             f"an estimated {100 * share:.0f} % of the run's time (more on a loaded machine)")
    return (f"{name} logged {messages:,} messages in this run{rate} although fmu-opinf instantiates it with logging "
            f"off, and passing them to Python (about {cost / messages * 1e6:.2g} us each) takes {taken}: ask its "
            f"exporter for a build without debug logging, or turn its logging off{advice}; ")


def logging_switches(md: Any) -> str:
    """Where the FMU's model description offers a way to turn its logging off: its declared log categories and
    its parameters whose name says log/debug/trace/verbose (each to be set with ``--set NAME=...``)."""
    categories = [getattr(c, "name", str(c)) for c in (getattr(md, "logCategories", None) or [])]
    from ._variables import LOGGING_WORDS   # (a source's copy in a child process keeps these: slim_description)

    switches = [v.name for v in getattr(md, "modelVariables", [])
                if v.causality in ("parameter", "structuralParameter")
                and any(w in v.name.lower() for w in LOGGING_WORDS)]
    parts = []
    if switches:
        shown = ", ".join(switches[:4]) + (", ..." if len(switches) > 4 else "")
        parts.append(f" with --set or parameters= (its parameters {shown})")
    if categories:
        shown = ", ".join(categories[:6]) + (", ..." if len(categories) > 6 else "")
        parts.append(f" (it declares the log categories {shown}; check which are debug ones)")
    return "".join(parts)
