"""The integrators of a model-exchange source (:class:`~._model_exchange.ModelExchangeSource`, ``method=``).

Each integrator advances the source's state ``source._x`` (the deviation from the start state) from ``t0`` to ``t1``
with the inputs held, calling the FMU through ``source.rhs``, and returns the state and the time it reached (before
``t1`` only where one accepted step, or a completed integrator step at which the FMU asks for an event, ends it):

* ``dop853``: DOP853 through the compiled step loop of :mod:`._compiled_rk`, else scipy's Python loop;
* ``linear``: the exact zero-order-hold step of the FMU's identified Jacobian (:mod:`._linear_hold`), each step
  checked against the FMU's derivatives, DOP853 from the first step that departs from the linear model;
* ``lsoda``, ``bdf``, ``radau``, ``rk45``: scipy's, restarted at every communication point.

Why each one is chosen, the tolerances and the events are the source's business (:mod:`._model_exchange`); the
failures an integration raises are defined here, since every integrator raises them.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import TYPE_CHECKING, Callable

import numpy as np

from .._interrupts import check_interrupt
from .._validate import either
from . import _compiled_rk, _linear_hold

if TYPE_CHECKING:
    from ._model_exchange import ModelExchangeSource


class _IntegrationError(Exception):
    """The FMU refused a call inside the right-hand side, or the integrator gave up."""


class _Discarded(_IntegrationError):
    """The FMU discarded a call (``fmi2Discard`` / ``fmi3Discard``) or returned derivatives that are not finite: the
    instance stays usable (FMI 2.0 section 2.1.3), unlike after an error."""


class _LeftInError(_IntegrationError):
    """The FMU refused a probe of its rounding noise during a run and then refused the state it came from."""


class _ExactStepRefused(_IntegrationError):
    """The FMU refused the first exact step of a run (:func:`_linear`): the run starts again with DOP853."""


#: Fractions of the first exact step at which :func:`_varies_with_time` probes the FMU's derivative: no rational
#: fraction (an internal source periodic in the step would be zero at all of them), and within the step (an FMU may
#: refuse a time beyond where it was last told an integrator step completed).
_TIME_PROBES = (0.2763932022500210, 0.6180339887498949, 0.8541019662496845)

#: Seconds of the integrator in one run after which :meth:`ModelExchangeSource._warn_slow_run` says so.
_SLOW_RUN_INTEGRATOR_SECONDS = 30.0


def _lsoda(source: ModelExchangeSource, t0: float, t1: float, completed: bool,
           one_step: bool = False) -> tuple[np.ndarray, float]:
    """LSODA (ODEPACK) through :func:`scipy.integrate.odeint`, warm-started with the last step size; through
    :class:`scipy.integrate.LSODA` step by step where the FMU needs its completed integrator steps (``completed``)
    or one step is asked for (``one_step``), as ``odeint`` cannot call back after each step."""
    from scipy.integrate import ODEintWarning, odeint

    if completed or one_step:
        return _stepwise_lsoda(source, t0, t1, completed, one_step)

    h0 = source._h_last if math.isfinite(source._h_last) else 0.0
    failure: list[BaseException] = []
    watch, calls = _StepWatch(source, t0, t1, "LSODA"), [0]

    def f(t: float, x: np.ndarray) -> np.ndarray:
        calls[0] += 1
        if not calls[0] % _LSODA_WATCH_CALLS:   # (odeint calls back only for derivatives, not after steps)
            watch(t, math.nan, None, 0)
        try:
            return source.rhs(t, x)
        except _IntegrationError as exc:
            failure.append(exc)
            return np.full(source.nx, np.nan)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ODEintWarning)   # (its failure is read from the report; ours must pass)
        y, info = odeint(f, source._x, (t0, t1), rtol=source.tolerance, atol=source._atol(t0, t1), tfirst=True,
                         full_output=True, h0=min(h0, t1 - t0), mxstep=100_000, printmessg=False)
    if failure:
        raise _IntegrationError(str(failure[0]))
    message = str(info.get("message", ""))
    if not message.startswith("Integration successful") or not np.isfinite(y[-1]).all():
        raise _IntegrationError(f"LSODA: {message.rstrip('.')}")
    hu = info.get("hu")
    if hu is not None and len(hu) and hu[-1] > 0:
        source._h_last = float(hu[-1])
    return np.ascontiguousarray(y[-1]), t1


#: Derivative evaluations of LSODA through :func:`scipy.integrate.odeint` between looks at its pace.
_LSODA_WATCH_CALLS = 256

#: scipy's implicit methods, which a stiff model does not hold to a stability limit.
_IMPLICIT = ("BDF", "Radau", "LSODA")


def _solve_ivp(name: str) -> Callable[[ModelExchangeSource, float, float, bool, bool], tuple[np.ndarray, float]]:
    def integrate(source: ModelExchangeSource, t0: float, t1: float, completed: bool,
                  one_step: bool = False) -> tuple[np.ndarray, float]:
        """scipy's solver ``name`` step by step from ``t0`` to ``t1``; with ``completed``, the FMU's completed
        integrator step after each accepted step before ``t1``, stopping where it asks for an event; with
        ``one_step``, stopping after the first accepted step.  Returns the state and the time reached."""
        import scipy.integrate as si

        cls = getattr(si, name)
        first = source._h_last if math.isfinite(source._h_last) else None
        solver = cls(source.rhs, t0, source._x.copy(), t1, rtol=source.tolerance, atol=source._atol(t0, t1),
                     first_step=None if first is None else min(first, t1 - t0))
        watch = _StepWatch(source, t0, t1, name)   # (for DOP853 the compiled loop's stand-in)
        while solver.status == "running":
            message = solver.step()
            check_interrupt()   # (one that arrived in the FMU's logger callback is only remembered there)
            if solver.status == "failed":
                raise _IntegrationError(f"{name}: {message}")
            source._scipy_steps += 1
            atol = watch(solver.t, solver.step_size or 0.0, solver.y, source._scipy_steps)
            if atol is not None:
                solver.atol = atol   # (scipy's Runge-Kutta steps read it at every step)
            if one_step:
                break
            if completed and solver.status == "running" and _completed_inside(source, solver.t, solver.y):
                break
        # where the loop stops before t1 (one step at a time, or an event the FMU asked for) the next piece
        # starts with the step the solver proposed: from the last step taken, an FMU that asks for an event at
        # every step would never let the step grow (ninth audit: 1e-6 s from rest, 1000 events in 1 ms)
        step = getattr(solver, "h_abs", None) if one_step or solver.status == "running" else None
        if step or solver.step_size:
            source._h_last = float(step or solver.step_size)
        return np.ascontiguousarray(solver.y), (t1 if solver.status == "finished" else float(solver.t))

    return integrate


def _completed_inside(source: ModelExchangeSource, t: float, x: np.ndarray) -> bool:
    """``fmiCompletedIntegratorStep`` after an accepted step of scipy's loop, at its time and state (set again:
    the solver's last evaluation need not be there); whether the FMU asks for an event there."""
    comp, flags = source._comp, source._event_flags
    if source._c_time(comp, t) > 1 or source._set_states(x) > 1:
        raise _IntegrationError(f"the FMU returned an error setting the state of a completed step at t={t:.9g}")
    flags[:] = 0
    if source._c_completed(comp, True, flags.ctypes.data, flags.ctypes.data + flags.itemsize) > 1:
        raise _IntegrationError(f"fmiCompletedIntegratorStep failed at t={t:.9g}")
    if flags[1]:
        raise _IntegrationError(f"the FMU asked to terminate the simulation in fmiCompletedIntegratorStep at t={t:.9g}")
    return bool(flags[0])


class _StepWatch:
    """What the integrator ``name`` does between blocks of steps over ``[t0, t1]``, called with the time, step size
    and state reached and the run's accepted steps so far: count the run's integrator seconds, for DOP853 measure
    the rounding noise again where due (returns the new absolute tolerances, else None), and say once when the run
    has been slow (:meth:`ModelExchangeSource._measure_noise_again`, :meth:`ModelExchangeSource._warn_slow_run`)."""

    def __init__(self, source: ModelExchangeSource, t0: float, t1: float, name: str = "DOP853") -> None:
        self.source, self.t0, self.t1, self.name = source, t0, t1, name
        self.started, self.spent = time.perf_counter(), source._integrator_seconds

    def __call__(self, t: float, h: float, y: np.ndarray | None, accepted: int) -> np.ndarray | None:
        source = self.source
        source._integrator_seconds = self.spent + time.perf_counter() - self.started
        atol = source._measure_noise_again(t, y, self.t0, self.t1, accepted) if self.name == "DOP853" else None
        if source._integrator_seconds > _SLOW_RUN_INTEGRATOR_SECONDS:
            source._warn_slow_run(self.name, self.t0, self.t1, t, h)
        return atol


def _dop853(source: ModelExchangeSource, t0: float, t1: float, completed: bool,
            one_step: bool = False) -> tuple[np.ndarray, float]:
    """DOP853 through the compiled step loop (:mod:`._compiled_rk`), else scipy's Python loop."""
    kernel = source._kernel
    if kernel is None:
        return _scipy_dop853(source, t0, t1, completed, one_step)
    first = min(source._h_last, t1 - t0) if math.isfinite(source._h_last) else None
    watch = _StepWatch(source, t0, t1)
    kernel.pause_at = source._noise_check_at

    def progress(t: float, h: float, y: np.ndarray) -> None:   # between blocks of steps, and after each call
        atol = watch(t, h, y, kernel.accepted)
        kernel.pause_at = source._noise_check_at
        if atol is not None:
            kernel.set_absolute_tolerance(atol)

    try:
        x, h_last, t = kernel.integrate(source._x, t0, t1, source.tolerance, source._atol(t0, t1), first,
                                        check_interrupt, completed, one_step, source._origin, progress)
    except _compiled_rk.IntegrationFailure as exc:
        raise _IntegrationError(str(exc)) from None
    progress(t, h_last, x)
    if h_last:
        source._h_last = h_last
    return x, t


def _linear(source: ModelExchangeSource, t0: float, t1: float, completed: bool,
            one_step: bool = False) -> tuple[np.ndarray, float]:
    """The exact step of the FMU's linear model over ``[t0, t1]`` (:mod:`._linear_hold`), verified against its
    derivative at ``t1``; DOP853 from the first step whose defect exceeds the absolute tolerance, to the end of
    the run (the model is not linear there).  The step is the whole interval, also where one accepted step is
    asked for (``one_step``): an FMU that needs completed integrator steps gets its call at the interval's end, as
    from any integrator's last step.  An FMU that refuses
    the step (an error status) may take no further call: at the run's first step the run starts again with DOP853
    (:class:`_ExactStepRefused`), later the run ends with a one-line error naming ``--me-method dop853``.  One that
    discards it stays usable: DOP853 takes over with the same instance (one per process may be all it allows)."""
    hold = source._hold
    if hold is None or source._handover is not None:
        return _dop853(source, t0, t1, completed, one_step)
    if not _exact_piece_pays(source, hold, t0, t1):
        source._pieces_by_dop853 += 1
        return _dop853(source, t0, t1, completed, one_step)
    try:
        if not source._time_probed:
            source._time_probed = True
            if _varies_with_time(source, hold, t0, t1):
                source._handover = (t0, "the FMU's derivatives changing with time at a fixed state and input (an "
                                        "internal source or a time-varying parameter, which the exact step cannot "
                                        "follow)")
        if source._handover is None:
            x1, ratio = _exact_step(source, hold, t0, t1)
    except _IntegrationError as exc:
        # e.g. an FMU with a delay buffer refuses a time beyond a gap after its last completed integrator step;
        # an FMU in error may take no further call: at the run's first step it starts again, else the run ends
        reason = source._last_log() or str(exc)
        if isinstance(exc, _Discarded):   # the instance stays usable: DOP853 goes on with it, no new instance
            source._log = []
            source._handover = (t0, f"the FMU having discarded the exact step's check ({reason})")
            return _dop853(source, t0, t1, completed, one_step)
        if t0 == source._t_list[0] and not source._x.any():
            raise _ExactStepRefused(reason) from None
        raise _IntegrationError(f"the FMU refused the exact zero-order-hold step ({reason}); record with "
                                f"{either('--me-method', value='dop853')}") from None
    if source._handover is not None:
        return _dop853(source, t0, t1, completed, one_step)
    if ratio > 1.0:
        source._handover = (t0, f"the FMU's derivatives having departed from the linear model by {ratio:.2g} of "
                                "the absolute tolerance")
        return _dop853(source, t0, t1, completed, one_step)
    return x1, t1


def _varies_with_time(source: ModelExchangeSource, hold: _linear_hold.LinearHold, t0: float, t1: float) -> bool:
    """Whether the FMU's derivative at the current state moves with time alone over ``[t0, t1]`` (probed at the
    fractions :data:`_TIME_PROBES`), by more than a step may be off (:meth:`~._linear_hold.LinearHold.defect`).
    The exact step evaluates the FMU only at the middle and the end of each step: an internal force
    ``sin(2 pi t / h)`` is zero at all of them, and a recording took it for a linear model, 0.7 % off (audit of
    2026-12-05).  Probed once, at the first exact step of a run: three evaluations."""
    x, h = source._x, t1 - t0
    f0 = source.rhs(t0, x)
    allowed = source._atol(t0, t1) + source.tolerance * np.abs(x)
    return any(hold.defect(x, x, f0, source.rhs(t0 + fraction * h, x), source._origin, h, allowed) > 1.0
               for fraction in _TIME_PROBES)


def _exact_piece_pays(source: ModelExchangeSource, hold: _linear_hold.LinearHold, t0: float, t1: float) -> bool:
    """Whether the piece ``[t0, t1]`` takes the exact step: its map is at hand, or ``auto`` predicts its matrix
    exponential (timed like the grid step's, of the same size) to cost less than DOP853 over the piece.  Pieces
    of other lengths come from events (a time event splits a step in two; a crossing search tries a dozen
    lengths); ``linear`` takes the exact step for each."""
    h = _step_size(source, t0, t1)
    measured = source._stiffness_seen
    if measured is None or hold.has_map(h) or not math.isfinite(hold.map_seconds):
        return True
    rho, evaluation_seconds = measured
    return hold.map_seconds < _linear_hold.dop853_seconds(rho * h, evaluation_seconds)


def _step_size(source: ModelExchangeSource, t0: float, t1: float) -> float:
    """``t1 - t0``, or the grid's nominal step where they differ by rounding: a uniform grid at a large time
    (1e7 s) has steps that differ by ulps of the time; the nominal step keeps the sum of the steps, where rounding
    each would drift (1.3e-7 of the motion in 60 steps)."""
    h = t1 - t0
    return source._nominal_step if abs(h - source._nominal_step) <= 16 * math.ulp(max(abs(t0), abs(t1))) else h


def _exact_step(source: ModelExchangeSource, hold: _linear_hold.LinearHold, t0: float,
                t1: float) -> tuple[np.ndarray, float]:
    """The state at ``t1`` by the exact step from the source's state at ``t0``, and its defect as a multiple of
    what the integrator allows (:meth:`~._linear_hold.LinearHold.defect`): the larger of those over the step's
    first half and over the whole step, so that the FMU is checked at the step's middle too (one evaluation more:
    an end stop reached only between two samples is seen there)."""
    h = _step_size(source, t0, t1)
    end = source._f_end   # the derivative where the last step ended, if no input was set since
    x0 = source._x
    f0 = end[2] if end is not None and end[0] is x0 and end[1] == t0 else source.rhs(t0, x0)
    x_mid, x1 = hold.step_and_midpoint(x0, f0, h)
    f_mid = source.rhs(t0 + 0.5 * h, x_mid)
    f1 = source.rhs(t1, x1)
    source._f_end = (x1, t1, f1)
    # allowed as DOP853 measures its error: the absolute tolerance plus the relative one of the state
    atol = source._atol(t0, t1)
    allowed = atol + source.tolerance * np.maximum(np.abs(x0), np.abs(x1))
    allowed_mid = atol + source.tolerance * np.maximum(np.abs(x0), np.abs(x_mid))
    return x1, max(hold.defect(x0, x_mid, f0, f_mid, source._origin, 0.5 * h, allowed_mid),
                   hold.defect(x0, x1, f0, f1, source._origin, h, allowed))


_scipy_dop853 = _solve_ivp("DOP853")
_stepwise_lsoda = _solve_ivp("LSODA")

_INTEGRATORS: dict[str, Callable[[ModelExchangeSource, float, float, bool, bool], tuple[np.ndarray, float]]] = {
    "lsoda": _lsoda,
    "bdf": _solve_ivp("BDF"),
    "radau": _solve_ivp("Radau"),
    "dop853": _dop853,
    "linear": _linear,
    "rk45": _solve_ivp("RK45"),
}

_INTEGRATOR_TEXT = {
    "lsoda": "LSODA (scipy.integrate.odeint), restarted at every communication point",
    "bdf": "BDF (scipy.integrate.BDF), restarted at every communication point",
    "radau": "Radau IIA (scipy.integrate.Radau), restarted at every communication point",
    "dop853": "DOP853 (scipy.integrate.DOP853), restarted at every communication point",
    "rk45": "RK45 (scipy.integrate.RK45), restarted at every communication point",
    "linear": ("exact zero-order-hold step of the FMU's Jacobian (matrix exponential; identified by differences "
               "at the start, every step checked against the FMU's derivatives)"),
    "auto": "auto (linear for a stiff model, else DOP853)",
}

_COMPILED_DOP853_TEXT = ("DOP853 (scipy.integrate.DOP853's method, step loop compiled from fmus/integrator/erk.c), "
                         "restarted at every communication point")
