"""DOP853 with the step loop in C: the model-exchange integrator without Python between derivative evaluations.

Integrating a model-exchange FMU with :class:`scipy.integrate.DOP853` costs about 13 us of Python per
derivative evaluation (the solver's stage loop, three ctypes calls, array checks), 50 times what a small
model's derivatives cost in C: on the five-mass Modelica chain of the tests (tolerance 1e-10) 562,000
evaluations took 7.1 s of a 13 s chain.  ``fmus/integrator/erk.c`` runs the same method -- the Butcher
tableau and error estimators of :class:`scipy.integrate.DOP853`, passed in from that class, and its error
norm and step-size control -- calling the FMU's ``SetTime``, ``SetContinuousStates`` and
``GetDerivatives`` function pointers directly.  For an FMU that needs ``CompletedIntegratorStep`` after each
accepted integrator step (FMI 2: ``completedIntegratorStepNotNeeded`` not true; FMI 3:
``needsCompletedIntegratorStep``), the loop calls it too, and stops at the step where the FMU asks for an event.

The library is compiled once per machine into the per-user cache folder (``$FMU_OPINF_CACHE_DIR``, else e.g.
``~/.cache/fmu-opinf``), named after a digest of its source and of the build's kind, with the C compiler of
``$CC`` or the first of ``cc``, ``gcc``, ``clang`` on the path; the model-exchange source asks for it when it is
created, so the build happens in the caller's process, not in each run's.  Where no compiler is found or the
build fails, :func:`kernel` returns None and the model-exchange source keeps scipy's Python loop (same method,
same results to rounding: the error estimate's sums are added in another order, which can move a step).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import platform
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Kernel", "kernel", "IntegrationFailure"]

#: erk_advance's return codes.
_DONE, _PAUSED, _FMU_ERROR, _NOT_FINITE, _STEP_TOO_SMALL, _EVENT, _TERMINATE, _COMPLETED_ERROR = range(8)

#: Wall time one call of the C loop aims at: between calls the caller checks for Ctrl-C, so that a stiff model
#: taking millions of steps in one interval can still be interrupted.  The number of steps per call adapts.
_SECONDS_PER_CALL = 0.02

_BUILD_LOCK = threading.Lock()


class IntegrationFailure(Exception):
    """The FMU refused a call, its derivatives were not finite, or the step size fell below round-off."""


class _Model(ctypes.Structure):
    _fields_ = [("component", ctypes.c_void_p), ("set_time", ctypes.c_void_p), ("set_states", ctypes.c_void_p),
                ("get_derivatives", ctypes.c_void_p), ("n", ctypes.c_size_t), ("rtol", ctypes.c_double),
                ("atol", ctypes.c_void_p), ("completed", ctypes.c_void_p), ("fmi_version", ctypes.c_int),
                ("origin", ctypes.c_void_p), ("absolute", ctypes.c_void_p)]


class _Tableau(ctypes.Structure):
    _fields_ = [("stages", ctypes.c_int), ("estimator_order", ctypes.c_int), ("a", ctypes.c_void_p),
                ("b", ctypes.c_void_p), ("c", ctypes.c_void_p), ("e5", ctypes.c_void_p), ("e3", ctypes.c_void_p)]


class _State(ctypes.Structure):
    _fields_ = [("t", ctypes.c_double), ("h_abs", ctypes.c_double), ("h_last", ctypes.c_double),
                ("t_failed", ctypes.c_double), ("have_f", ctypes.c_int), ("evaluations", ctypes.c_long),
                ("steps", ctypes.c_long)]


class Kernel:
    """The compiled DOP853 loop bound to one FMU instance's derivative functions.

    Parameters
    ----------
    library : ctypes.CDLL
        The compiled ``erk.c``.
    component : int
        The FMU instance (``fmi2Component`` / ``fmi3Instance``) address.
    set_time, set_states, get_derivatives : ctypes function
        The FMU's ``SetTime``, ``SetContinuousStates`` and ``GetDerivatives`` (FMI 3:
        ``GetContinuousStateDerivatives``).
    n : int
        Number of continuous states.
    completed : ctypes function, optional
        The FMU's ``CompletedIntegratorStep``, for an FMU that needs it after every accepted step.
    fmi_version : int, default=2
        2 or 3: the boolean type of ``completed``'s arguments (int or bool).
    """

    def __init__(self, library: ctypes.CDLL, component: int, set_time: Any, set_states: Any, get_derivatives: Any,
                 n: int, completed: Any = None, fmi_version: int = 2) -> None:
        from scipy.integrate import DOP853

        self._advance = library.erk_advance
        self._arrays = [np.ascontiguousarray(a, dtype=float) for a in (DOP853.A, DOP853.B, DOP853.C,
                                                                       DOP853.E5, DOP853.E3)]
        a, b, c, e5, e3 = (arr.ctypes.data for arr in self._arrays)
        self._tableau = _Tableau(int(DOP853.n_stages), int(DOP853.error_estimator_order), a, b, c, e5, e3)
        self._functions = (set_time, set_states, get_derivatives, completed)  # kept alive with the pointers below
        address = [ctypes.cast(f, ctypes.c_void_p).value for f in self._functions[:3]]
        self._completed = ctypes.cast(completed, ctypes.c_void_p).value if completed is not None else None
        self._fmi_version = int(fmi_version)
        self._atol = np.zeros(n)
        self._origin = np.zeros(n)
        self._absolute = np.zeros(n)
        self._model = _Model(component, *address, n, 0.0, self._atol.ctypes.data, self._completed, 0, None,
                             self._absolute.ctypes.data)
        self._work = np.zeros((DOP853.n_stages + 4) * max(n, 1))
        self.n = n
        self.evaluations = 0
        self.accepted = 0   # accepted steps over all calls
        self.pause_at: int | None = None   # a count of accepted steps at which a call pauses (progress is called)
        self._steps_per_call = 16

    def integrate(self, y: np.ndarray, t0: float, t1: float, rtol: float, atol: np.ndarray, first_step: float | None,
                  check_interrupt: Any = None, completed: bool = False,
                  one_step: bool = False, origin: np.ndarray | None = None,
                  progress: Any = None) -> tuple[np.ndarray, float, float]:
        """Integrate ``y`` from ``t0`` to ``t1``; the new state, the size of the last step taken (0: none) and the
        time reached: ``t1``, or earlier where the FMU asked for an event in ``CompletedIntegratorStep``.

        ``first_step`` (None: chosen from the derivatives, as :func:`scipy.integrate.solve_ivp` does) must not
        exceed ``t1 - t0``.  ``check_interrupt`` is called between blocks of steps.  ``completed``: call the FMU's
        ``CompletedIntegratorStep`` after each accepted step before ``t1`` (not at ``t1``: the caller does, as it
        may go on with events there).  ``one_step``: return after the first accepted step (its time).  Raises
        :class:`IntegrationFailure` with scipy's wording for the reasons its loop fails, and when the FMU refuses the
        completed step or asks to terminate.  With ``one_step`` the second value is the size the next step would
        try (the step grows from call to call).  ``origin``: ``y`` is the states' deviation from it; the FMU is given
        ``origin + y``.  ``progress(t, h, y)`` is called between blocks of steps with the time reached, the step
        size and the state there (not to be changed), and always once :attr:`accepted` reaches :attr:`pause_at`;
        it may change the absolute tolerance (:meth:`set_absolute_tolerance`) and ``pause_at``.
        """
        y = np.array(y, dtype=float)  # a fresh array: the caller's state is not changed on failure
        self._atol[:] = atol
        self._model.rtol = max(float(rtol), 100 * np.finfo(float).eps)  # scipy's floor of the relative tolerance
        self._model.fmi_version = self._fmi_version if completed and self._completed else 0
        if origin is None:
            self._model.origin = None
        else:
            self._origin[:] = origin
            self._model.origin = self._origin.ctypes.data
        state = _State(t0, first_step or 0.0, 0.0, t0, 0, 0, 0)
        try:
            while True:
                started, before = time.perf_counter(), state.steps
                status = self._advance(ctypes.byref(self._model), ctypes.byref(self._tableau), ctypes.byref(state),
                                       ctypes.c_double(t1), y.ctypes.data, self._work.ctypes.data,
                                       1 if one_step else self._steps_until_pause())
                self.accepted += state.steps - before
                if status != _PAUSED or one_step:
                    break
                self._adapt(time.perf_counter() - started)
                if check_interrupt is not None:
                    check_interrupt()
                if progress is not None:
                    progress(state.t, state.h_abs, y)
        finally:
            self.evaluations += state.evaluations
        if status == _FMU_ERROR:
            raise IntegrationFailure(f"the FMU refused to evaluate the derivatives (an error or a discard) at "
                                     f"t={state.t_failed:.9g}")
        if status == _NOT_FINITE:
            raise IntegrationFailure(f"the derivatives are not finite at t={state.t_failed:.9g}")
        if status == _STEP_TOO_SMALL:
            raise IntegrationFailure("DOP853: Required step size is less than spacing between numbers.")
        if status == _COMPLETED_ERROR:
            raise IntegrationFailure(f"fmiSetTime or fmiCompletedIntegratorStep failed after the integrator step "
                                     f"to t={state.t:.9g}")
        if status == _TERMINATE:
            raise IntegrationFailure(f"the FMU asked to terminate the simulation in fmiCompletedIntegratorStep at "
                                     f"t={state.t:.9g}")
        # one step at a time, or stopped at an event the FMU asked for: the next one's size goes on (from the
        # last step taken, an FMU that asks at every step would never let it grow)
        step = state.h_abs if one_step or status == _EVENT else state.h_last
        return y, float(step), float(state.t) if status in (_EVENT, _PAUSED) else t1

    def _steps_until_pause(self) -> int:
        """Steps for the next call: as many as take about :data:`_SECONDS_PER_CALL`, but none past ``pause_at``
        (so that ``progress`` sees the state there whatever the machine's speed)."""
        steps = self._steps_per_call
        if self.pause_at is not None and self.pause_at > self.accepted:
            steps = min(steps, self.pause_at - self.accepted)
        return steps

    def set_absolute_tolerance(self, atol: np.ndarray) -> None:
        """The absolute tolerances from the next step on (between blocks of steps, from ``progress``)."""
        self._atol[:] = atol

    def _adapt(self, seconds: float) -> None:
        """More steps per call when a call was much shorter than the aim, fewer when it was longer."""
        if seconds < 0.25 * _SECONDS_PER_CALL:
            self._steps_per_call = min(2 * self._steps_per_call, 1 << 24)
        elif seconds > 2 * _SECONDS_PER_CALL:
            self._steps_per_call = max(self._steps_per_call // 2, 1)


def kernel(component: int, set_time: Any, set_states: Any, get_derivatives: Any, n: int, completed: Any = None,
           fmi_version: int = 2) -> Kernel | None:
    """The compiled loop for one FMU instance (``completed``, ``fmi_version``: see :class:`Kernel`), or None where
    the library cannot be built here."""
    library = _library()
    return None if library is None else Kernel(library, component, set_time, set_states, get_derivatives, n,
                                               completed, fmi_version)


def available() -> bool:
    """Whether the compiled loop is in use on this machine (builds it on the first call)."""
    return _library() is not None


def _source() -> Path:
    from ..fmus import _c_sources_dir

    return _c_sources_dir() / "integrator" / "erk.c"


@functools.lru_cache(maxsize=None)
def _library() -> ctypes.CDLL | None:
    """Load the cached build of ``erk.c``, building it first where needed; None without a working compiler.

    The file name carries a digest of the source, the compiler command, the platform, the machine and the pointer
    size (a cache folder shared by different machines keeps one build per kind).  A failed build leaves a
    ``.failed`` marker with the compiler's message, so that later runs (each isolated run is a process of its
    own) do not try again for a day or until the compiler changes (delete it to retry at once), and one warning
    names it.  A library that another user could have written is not loaded.
    """
    from ..fmus import _user_cache_dir, find_c_compiler

    try:
        source = _source()
        text = source.read_bytes()
    except Exception:
        return None
    compiler = find_c_compiler()
    if compiler is None:
        return None

    suffix = ".dll" if sys.platform == "win32" else ".dylib" if sys.platform == "darwin" else ".so"
    kind = "\0".join([*compiler, sys.platform, platform.machine(), str(struct.calcsize("P"))]).encode()
    digest = hashlib.sha256(text + b"\0" + kind).hexdigest()[:16]
    path = _user_cache_dir() / "integrator" / f"erk-{digest}{suffix}"
    with _BUILD_LOCK:
        _private(path.parent)
        for attempt in range(2):
            if not path.is_file() and (_failed_recently(path, compiler) or not _build(compiler, source, path)):
                _report_failure(path)
                return None
            library = _load(path)
            if library is not None or attempt or not _trusted(path):
                return library
            path.unlink(missing_ok=True)  # a damaged or foreign-architecture build: once more
    return None


#: How long a failed build is not tried again (unless the compiler changed since): a day.
_RETRY_AFTER = 86400.0


def _failed_recently(path: Path, compiler: list[str]) -> bool:
    """Whether a build failed within :data:`_RETRY_AFTER` with the compiler as it is now (its marker)."""
    marker = path.with_name(path.name + ".failed")
    try:
        failed = marker.stat().st_mtime
        return time.time() - failed < _RETRY_AFTER and os.stat(compiler[0]).st_mtime <= failed
    except OSError:
        return False


def _report_failure(path: Path) -> None:
    """One warning per command (not again from each run's process) naming the marker of a failed build."""
    import multiprocessing
    import warnings

    from ..errors import FmuOpinfWarning

    marker = path.with_name(path.name + ".failed")
    if multiprocessing.parent_process() is None and marker.is_file():
        warnings.warn(f"the compiled model-exchange step loop could not be built (compiler output in {marker}); "
                      "scipy's slower loop runs instead, with the same results", FmuOpinfWarning, stacklevel=3)


def _load(path: Path) -> ctypes.CDLL | None:
    if not _trusted(path):
        return None
    try:
        library = ctypes.CDLL(str(path))
    except OSError:
        return None
    library.erk_advance.restype = ctypes.c_int
    library.erk_advance.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_double,
                                    ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long]
    return library


def _private(folder: Path) -> None:
    """Create the folder, and take group and others' write permission away if this user owns it (a umask of 0002
    or an older version made it group-writable, and :func:`_trusted` would then never load the library)."""
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        status = folder.stat()
        if os.name == "posix" and status.st_uid == os.getuid() and status.st_mode & 0o022:
            folder.chmod(status.st_mode & 0o755)
    except OSError:
        pass


def _trusted(path: Path) -> bool:
    """On POSIX: the library and its folder belong to this user and nobody else may write them (a shared
    ``$FMU_OPINF_CACHE_DIR`` must not let another user plant code that fmu-opinf then runs)."""
    if os.name != "posix":
        return True
    try:
        for item in (path, path.parent):
            status = item.stat()
            if status.st_uid != os.getuid() or status.st_mode & 0o022:
                return False
    except OSError:
        return False
    return True


class _BuildFailed(Exception):
    """The compiler refused the source (its message is in the ``.failed`` marker) or was stopped."""


def _build(compiler: list[str], source: Path, path: Path) -> bool:
    """Compile ``source`` into ``path`` through a temporary file renamed into place (:func:`~fmu_opinf._hdf5.
    atomic_path`: concurrent builds are safe, an interrupted one leaves nothing); a failure is remembered next to
    it (``.failed``)."""
    from .._hdf5 import atomic_path
    from ..errors import FmuOpinfError

    if not path.parent.is_dir():
        return False
    try:
        with atomic_path(path, output=False) as temporary:
            command = [*compiler, "-O2", "-std=c99", "-shared", "-fPIC", str(source), "-o", temporary, "-lm"]
            result = subprocess.run(command, capture_output=True, timeout=120)
            if result.returncode != 0:
                if result.returncode > 0:  # the compiler's verdict, not a signal (Ctrl-C)
                    message = (result.stdout + result.stderr).decode("utf-8", "replace")
                    with contextlib.suppress(OSError):
                        path.with_name(path.name + ".failed").write_text(f"{' '.join(command)}\n{message}")
                raise _BuildFailed
        os.chmod(path, 0o755)  # atomic_path gives 0666 & ~umask; group-writable would not be trusted
        return True
    except _BuildFailed:
        return False
    except (OSError, subprocess.SubprocessError, FmuOpinfError):
        return path.is_file()  # e.g. Windows: another process loaded the file it built at the same time
