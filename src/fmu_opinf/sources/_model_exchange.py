"""Model-exchange FMUs (FMI 2.0 and 3.0): fmu-opinf integrates ``der(x) = f(x, u)`` itself.

The recording convention is the one of co-simulation (docs/design.md, input timing): the input
``U[i]`` is set at ``t[i-1]`` and held while the state is integrated to ``t[i]``; the integration
is restarted at every communication point (the input jumps there).  The sample at ``t[i]`` is read
with ``U[i]`` still in effect, so accelerations (``der`` of the velocity states) and outputs with
direct feedthrough pair with the same input as a co-simulation FMU's values after ``doStep``.

The integrator is chosen by ``method`` (:data:`METHODS`).  The default ``auto`` takes the exact hold step of the
FMU's identified Jacobian (``linear``, :mod:`._linear_hold`) for a stiff model (through its events too), where every explicit
method crawls and the implicit ones restart at each communication point, and DOP853 for everything else.  Before
``auto`` (2026-11-28) the default was scipy's DOP853 (explicit
Runge-Kutta of order 8 with step-size control): on the corpus and benchmark FMUs it was both the
fastest and the most accurate of the candidates measured in ``benchmarks/bench_me.py`` (LSODA
through :func:`scipy.integrate.odeint`, BDF, Radau; their global error is 100 to 1000 times the
tolerance, DOP853's below it), also on a stiff model (a mode at 1.4e5 rad/s: 1.2 s against 16 s for
LSODA and 153 s for BDF; the implicit methods re-estimate their Jacobian at every restart, i.e. every
communication point; docs/real-fmus.md).  The others stay available (``method=``).  The relative
tolerance is the source's ``tolerance``; the absolute tolerance is that times each state's largest
deviation from its start value so far, floored at 1e-6 of its nominal value where that is below 1 (a nominal may
tighten the floor, never loosen it: exporters set nominals carelessly, and a nominal of 1e9 on a state moving by 0.05
made a recording 37 times less accurate, 3.8e-9 against 1.0e-10, tests/test_nominals.py).

Large start values.  The integrators work on each state's deviation from its value after initialization, and the
FMU is given ``start + deviation``.  Positions in global coordinates (6.4e6 m, moving by millimetres) keep every
digit of their motion that way; integrating the states themselves, each step added a few ulps of 6.4e6 m, the
tolerance followed the 6.4e6 m instead of the motion, and a 10 s recording was 2.2e-3 of the motion off (now
1.4e-6, about ten ulps of the positions; audit 2026-11-27, X).  The absolute tolerance is never below what the FMU
can resolve there (:meth:`ModelExchangeSource._atol`).

Events.  Time events: the next event time that the FMU announces in an event iteration (the one
that ends initialization included) splits the integration there; the event iteration runs at that
time, the continuous states are read again, and the integration goes on with the same inputs.  State
events: an FMU with event indicators has them read at the end of every integration interval (one
communication step, or the part of it up to an event) and, where inputs were set, again at its start;
a change of sign (FMI's
convention: from ``> 0`` to ``<= 0`` or back) is located by regula falsi (Illinois) with bisection
as a safeguard, re-integrating from the last state before the crossing with the inputs held, to
``1e-12`` of the interval plus a few ulps of t, and the event is handled just after it; a change of
sign across a communication point (the inputs set there moved an indicator) is an event at that
point.  A sample at an event time holds the values after the event, like a co-simulation ``doStep``
that ends there.  A failure in event mode (the FMU refuses a call, or its event
iteration does not end) is a step error, like any other failure of a step.  A model that ends its simulation (it asks
to terminate in an event iteration or in ``fmiCompletedIntegratorStep``, as Modelica's ``terminate()`` does) ends a
run at the run's last point with its samples complete; before it, it is a step error that names the time, the FMU's
log line and ``--t-end below`` it, which the automatic window and compare read like FMI 3 co-simulation's
``terminateSimulation`` (audit 75, F3).
FMUs without event indicators and without an announced time event take the plain path: no call more
per step.  With indicators that never fire, a step of the test FMUs costs 17 us instead of 14 us (26 us
before the start-of-interval check was limited to steps whose inputs changed; 2026-11-27).

Completed integrator steps.  An FMU that needs ``fmiCompletedIntegratorStep`` after every accepted integrator step
(FMI 2 unless ``completedIntegratorStepNotNeeded="true"``, FMI 3 if ``needsCompletedIntegratorStep="true"``; a
``delay()`` buffer advances there) gets it from the integrator's loop after each accepted step inside an interval,
and, like every FMU, at the interval's end.  An event it asks for there is handled at that step.  With event
indicators it is integrated one accepted step at a time and each step is completed only once its indicators show
no crossing, so that a crossing search (whose trials do not call it) never goes back before a completed step.

Discrete inputs.  Model exchange may change an input of discrete variability only in event mode (FMI 2.0 section
3.2.3): a step where one changes sets the inputs in event mode, before an event iteration (not counted as an event
of the model).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import re
import time
from collections.abc import Iterator, Sequence
from typing import Any, Callable

import numpy as np

from .._interrupts import check_interrupt
from .._progress import duration_text
from .._validate import DT_T_END, either
from ..errors import FMUError, InputSpecError
from . import _compiled_rk, _fmu_log, _integrators, _linear_hold
from ._base import EventCount, StepError
from ._cosimulation import DEFAULT_TOLERANCE, DISCARD, TERMINATED, FMUSource
from ._integrators import (_COMPILED_DOP853_TEXT, _IMPLICIT, _INTEGRATOR_TEXT, _INTEGRATORS, _Discarded,
                           _ExactStepRefused, _IntegrationError, _LeftInError)

__all__ = ["ModelExchangeSource", "METHODS"]

#: The fix "record by co-simulation" in both vocabularies.
CS = either("--interface", value="cs")


class _TerminationAsked(FMUError):
    """The FMU asked to terminate the simulation in an event iteration (a Modelica ``terminate()`` at an event);
    at initialization it is the error, during a run :meth:`ModelExchangeSource._handle_event` says where."""

#: Integrators of :class:`ModelExchangeSource` (``"auto"`` is the default: ``"linear"`` for a stiff model that
#: qualifies, else ``"dop853"``).
METHODS = ("auto", "dop853", "linear", "lsoda", "bdf", "radau", "rk45")

#: A run that DOP853 is predicted to take longer than this (seconds) on a stiff model too large for the exact step
#: is warned about (:meth:`ModelExchangeSource._warn_if_slow`).
_SLOW_RUN_SECONDS = 60.0

#: Bytes the exact step's matrix exponential (size 2n) takes per n^2: 1.1 GB at n = 2000 (docs/real-fmus.md).
_EXPM_BYTES_PER_SQUARE = 275.0

#: Event iterations allowed at one time instant before giving up.
_MAX_EVENT_ITERATIONS = 100

#: Events (time events and located crossings) handled within one communication step before giving up.
_MAX_EVENTS_PER_STEP = 1000

#: Events the FMU asks for in its completed integrator steps within one communication step before giving up.
#: Such an FMU may ask at every step (FMI allows it); each one ends an accepted step, so time advances.
_MAX_ASKED_EVENTS_PER_STEP = 100_000

#: Trial integrations of one crossing search at most (bisection alone narrows any double interval to the
#: tolerance in fewer than 80; the regula falsi takes about 12).
_MAX_CROSSING_TRIALS = 200


class _ReplayWithoutLooks(Exception):
    """:meth:`ModelExchangeSource.advance` starts the run again without looks at the rounding noise
    (:meth:`ModelExchangeSource._replay_without_looks`)."""


class ModelExchangeSource(FMUSource):
    """A model-exchange FMU (FMI 2.0 or 3.0), integrated under zero-order-hold inputs.

    Takes the keywords of :class:`~fmu_opinf.sources.FMUSource` (variables, ``--set`` values,
    constraint, ``tolerance``) and:

    Parameters
    ----------
    method : {"auto", "dop853", "linear", "lsoda", "bdf", "radau", "rk45"}, default="auto"
        Integrator (see the module docstring): ``auto`` is ``linear`` for a stiff model (:meth:`_choose_integrator`),
        else ``dop853``; the run's ``integrator`` attribute says which ran.
    **options
        Keywords of :class:`~fmu_opinf.sources.FMUSource`.

    Notes
    -----
    Events (module docstring): time events are met exactly; state events are located to
    ``1e-12`` of the interval (plus a few ulps of t) and handled just after the crossing; an FMU
    asking for an event from ``fmiCompletedIntegratorStep`` gets its event iteration where it asks:
    at the end of the interval (a communication step, or the part of it up to an event), or, for an FMU that
    needs the call after every integrator step, at that step.  The signs
    of the event indicators are compared only at the ends of each interval, so two crossings of one
    indicator inside one interval (a communication step or shorter) cancel and are missed: record with
    a smaller dt when a threshold may be crossed and re-crossed within one step.  Events may change the
    continuous states (they are read again) and the nominals; they cannot change the inputs, which
    stay held over the whole step.
    """

    interface = "me"

    def __init__(self, path: Any, *, method: str = "auto", **options: Any) -> None:
        method = str(method).lower()
        if method not in METHODS:
            raise InputSpecError(f"integrator {method!r} is unknown; choose one of {', '.join(METHODS)}")
        if options.get("tolerance") == 0:
            raise InputSpecError(f"{either('--tolerance', value=0)} is not allowed for model exchange (fmu-opinf's "
                                 f"integrator needs one); give e.g. {either('--tolerance', value=DEFAULT_TOLERANCE)}")
        super().__init__(path, **options)
        self.method = method
        self._options["method"] = method
        self._pilot_of: float | None = None   # the tolerance asked, while a pilot runs at a looser one
        if method in ("auto", "dop853", "linear"):
            _compiled_rk.available()  # build the step loop here, once, not in every isolated run's process

    @staticmethod
    def _interface_of(md: Any) -> Any:
        return md.modelExchange

    def provenance(self) -> dict[str, Any]:
        prov = super().provenance()
        prov["integrator"] = self._integrator_text(self.method)
        return prov

    @contextlib.contextmanager
    def pilot_accuracy(self) -> Iterator[None]:
        """The automatic window's pilot runs at the relative tolerance :data:`PILOT_TOLERANCE` where more was asked:
        they only look for the response's frequencies and its fade time, which that resolves many times over, and
        a model whose steps the tolerance holds back (rounding inside the FMU, a stiff one without the exact step)
        took most of its recording's time there (a single-precision block: pilots 40 s, the recording 18 s; audit
        of 2026-12-05)."""
        if self._pilot_of is not None:
            yield
            return
        asked = self.tolerance
        self.tolerance, self._pilot_of = max(asked, PILOT_TOLERANCE), asked
        try:
            yield
        finally:
            self.tolerance, self._pilot_of = asked, None

    def _shared_state(self) -> dict[str, Any]:
        state = super()._shared_state()   # (with the tolerance of the moment: a pilot's in a pilot)
        if self._pilot_of is not None:   # (a pilot in a child process knows itself one, for its messages)
            state["pilot_of"] = self._pilot_of
        return state

    def _borrow(self, state: dict[str, Any]) -> None:
        super()._borrow(state)
        if "pilot_of" in state:
            self._pilot_of = state["pilot_of"]

    def _integrator_text(self, method: str) -> str:
        if method == "dop853" and _compiled_rk.available():
            return _COMPILED_DOP853_TEXT
        return _INTEGRATOR_TEXT[method]

    def run_report(self) -> dict[str, Any]:
        """The integrator this run took (``auto`` chooses per run, a linear step may hand over to DOP853)."""
        active = getattr(self, "_active", None)
        if active is None:
            return {}
        text = self._integrator_text(active)
        if self.method == "auto":
            text = f"auto: {text}"
        refused = getattr(self, "_exact_refused", None)
        if refused is not None and self.method in ("auto", "linear"):
            text += f"; no exact zero-order-hold step: {refused}"
        pieces = getattr(self, "_pieces_by_dop853", 0)
        if pieces and active == "linear":
            text += f"; {pieces} piece(s) of steps cut by events by DOP853 (cheaper there than another exponential)"
        noise_refused = getattr(self, "_noise_refused", None)
        if noise_refused is not None:
            text += f"; started again, without looking at the derivatives' rounding during the run: {noise_refused}"
        handover = getattr(self, "_handover", None)
        if handover is not None:
            text += f"; from t={handover[0] - self.start_time:.9g} DOP853, {handover[1]}"
        rounding = self._rounding_summary()
        if rounding is not None:
            text += f"; {rounding[0]}"
        return {"integrator": text, "integrator_method": active}

    def recorded_integrator(self, methods: Sequence[str]) -> str:
        """The file's ``integrator`` attribute once its runs took ``methods`` (each run's ``integrator_method``).

        ``auto`` chooses per run, so before the runs the source can only say the rule; a file of ``auto`` runs
        named the rule, not the method used (audit of 2026-12-06, F7).  It now names the method all its runs took,
        marked as chosen by ``auto``, or, where runs differ, which run took which.

        Parameters
        ----------
        methods : sequence of str
            The method each run took, in order (``"linear"``, ``"dop853"``; any of :data:`METHODS` but ``auto``).

        Returns
        -------
        str
            :meth:`provenance`'s text for an explicit method or no runs, else e.g. ``"exact zero-order-hold step
            ... (chosen by auto: linear for a stiff model, else DOP853)"``.
        """
        if self.method != "auto" or not methods:
            return self._integrator_text(self.method)
        rule = _INTEGRATOR_TEXT["auto"].removeprefix("auto ")
        taken = list(dict.fromkeys(methods))
        if len(taken) == 1:
            return f"{self._integrator_text(taken[0])} (chosen by auto: {rule.strip('()')})"
        runs = "; ".join(f"{self._integrator_text(method)} in run(s) "
                         + ", ".join(str(i) for i, m in enumerate(methods) if m == method) for method in taken)
        return f"auto {rule}, per run (each run's integrator says which): {runs}"

    def events_seen(self) -> EventCount | None:
        """Events handled since :meth:`start`: how many changed the model, the run's time (not the FMU's) of the
        first of them, and how many changed nothing (:meth:`_handle_event`)."""
        seen = getattr(self, "_events", EventCount(0, None, 0))
        return seen._replace(first=None if seen.first is None else seen.first - self.start_time)

    # -- loading ----------------------------------------------------------------------------
    def _fmpy_class(self) -> tuple[type, dict[str, Any]]:
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import FMU2Model

            return FMU2Model, {}
        from fmpy.fmi3 import FMU3Model

        return FMU3Model, {}

    def _bind_interface_functions(self) -> None:
        vp, sz, dbl = ctypes.c_void_p, ctypes.c_size_t, ctypes.c_double
        v = "2" if self.fmi_version.startswith("2") else "3"
        derivatives = "fmi2GetDerivatives" if v == "2" else "fmi3GetContinuousStateDerivatives"
        flag = ctypes.c_int if v == "2" else ctypes.c_bool
        (self._c_time, self._c_set_x, self._c_get_x, self._c_dx, self._c_completed,
         self._c_indicators) = self._bind(
            (f"fmi{v}SetTime", [vp, dbl]),
            (f"fmi{v}SetContinuousStates", [vp, vp, sz]),
            (f"fmi{v}GetContinuousStates", [vp, vp, sz]),
            (derivatives, [vp, vp, sz]),
            (f"fmi{v}CompletedIntegratorStep", [vp, flag, vp, vp]),
            (f"fmi{v}GetEventIndicators", [vp, vp, sz]),
        )
        self._event_flags = np.zeros(2, dtype=np.int32)  # enterEventMode, terminateSimulation

    def _after_initialization(self) -> None:
        """Leave initialization through an event iteration, then read the start state."""
        import scipy.integrate  # noqa: F401  (loaded here, not inside the first step)

        self._t_next = math.inf
        self._event_iteration()
        self._fmu.enterContinuousTimeMode()
        self._events = EventCount(0, None, 0)   # handled during the run (initialization's not)
        self.nx = self._state_count()
        self.nz = self._indicator_count()
        self._z = np.zeros(self.nz)       # event indicators at the start of the current interval
        self._z_end = np.zeros(self.nz)   # ... and at its end
        self._x = np.zeros(self.nx)
        self._dx = np.zeros(self.nx)
        if self.nx and self._c_get_x(self._comp, self._x.ctypes.data, self.nx) > 1:
            raise FMUError(f"{self.path.name} returned an error reading its continuous states")
        if self.nz and self._c_indicators(self._comp, self._z.ctypes.data, self.nz) > 1:
            # some exports declare indicators they cannot return: record as before events were handled
            from . import warn_once

            warn_once(self, ("event indicators",), f"reading its {self.nz} event indicators failed, so its state "
                      "events are not located (a change of its discrete state then waits for the next communication "
                      f"point); check the results, or record with {CS}", stacklevel=3)
            self.nz = 0
        self._floor = _floor(self._nominals())
        self._origin, self._x = self._x, np.zeros(self.nx)   # integrated: the deviation from the start state
        self._absolute_x = np.zeros(self.nx)
        self._scale = np.zeros(self.nx)
        self._resolution = np.where(self._origin != 0, np.spacing(np.abs(self._origin)), 0.0)
        self._probe_refusal: str | None = None   # why the FMU refused a probe of its derivatives in this start
        self._probe_left_in_error = False   # ... and whether with an error (not a discard): then start again
        self._no_probes: bool = getattr(self, "_no_probes", False)   # kept over restarts (:meth:`start`)
        self._noise = self._rounding_noise()
        self._noise_measured_size = np.abs(self._origin)   # the states' size where the noise was last measured
        self._noise_refused: str | None = getattr(self, "_noise_refused", None)   # kept over restarts (_replay)
        # DOP853's accepted steps in the run at the next look at the rounding (none after a refused look)
        self._noise_check_at = _NOISE_CHECK_STEPS if self._noise_refused is None else _NEVER
        self._scipy_steps = 0   # accepted steps of scipy's DOP853 loop in the run
        self._h_last = math.nan
        self._needs_completed = _needs_completed_steps(self.md)
        self._searching = False   # in a crossing search: no completed integrator steps
        self._kernel = (_compiled_rk.kernel(self._comp, self._c_time, self._c_set_x, self._c_dx, self.nx,
                                            self._c_completed if self._needs_completed else None,
                                            2 if self.fmi_version.startswith("2") else 3)
                        if self.method in ("auto", "dop853", "linear") and self.nx else None)
        self._handover: tuple[float, str] | None = None   # (time, why) where a linear step handed over
        self._exact_refused: str | None = getattr(self, "_exact_refused", None)   # kept over restarts
        self._hold: _linear_hold.LinearHold | None = None
        self._nominal_step = math.nan   # the planned grid's step (_choose_integrator)
        self._stiffness_seen: tuple[float, float] | None = None   # (rho, seconds per evaluation) measured by auto
        self._integrator_seconds = 0.0   # wall seconds the integrator took in this run (:meth:`_warn_slow_run`)
        self._pieces_by_dop853 = 0   # pieces cut by events that _integrators._linear left to DOP853
        self._time_probed = False   # whether _integrators._linear probed the FMU's derivative at other times
        self._f_end: tuple[np.ndarray, float, np.ndarray] | None = None   # (state, time, derivative) of _linear
        self._active = self._choose_integrator()
        self._messages_at_start = self.quiet_messages()   # (after the probes: the run's messages follow)

    def _call_set(self, raw: np.ndarray, single: np.ndarray | None = None) -> int:
        self._f_end = None   # the derivative where the last step ended is that of the former input
        self._inputs_in_effect = (raw, single)   # (a restart sets them again)
        return super()._call_set(raw, single)

    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        self._mark_built()
        self._run_grid = (t, U)
        self._probe_refusal, self._probe_left_in_error = None, False
        try:
            super().start(t, U)
        except StepError:
            if self._probe_refusal is None or self._no_probes or not self._probe_left_in_error:
                raise   # (an FMU in error after a refused probe may fail what follows its initialization)
        if self._probe_refusal is not None and not self._no_probes:
            if self._probe_left_in_error:
                self._restart_without_probes()
            else:   # a discard leaves the instance usable: no new instance (one per process may be all it allows)
                self._exact_refused = (f"the FMU discarded a probe of its derivatives off the start state "
                                       f"({self._probe_refusal})")

    def _restart_without_probes(self) -> None:
        """Start the run again, without probing the derivatives off the start state and with DOP853, after the FMU
        refused a probe: an FMU that returned an error may take no further call (FMI 2.0 section 2.1.3), and one
        whose ``assert`` on a range failed stays in error (an audit's FMU then failed the run at its first step,
        with a message blaming the tolerance, while DOP853 recorded it correctly)."""
        self._no_probes = True
        self._noise_kept = self._noise   # (the noise probes' tiny moves passed, unless they were the ones refused)
        self._exact_refused = f"the FMU refused a probe of its derivatives off the start state ({self._probe_refusal})"
        try:
            super().start(*self._run_grid)
        except (StepError, FMUError) as exc:
            raise FMUError(f"{self.path.name} refused a probe of its derivatives ({self._probe_refusal}) and could not "
                           f"be started again after it ({exc}); record with {either('--me-method', value='dop853')}"
                           ) from None

    def _restart_without_exact_step(self, reason: str) -> None:
        """Start the run again and set the inputs of its first step again, after the FMU refused the exact step
        there: an FMU that returned an error may take no further call (FMI 2.0 section 2.1.3), and the
        run had not moved yet.  This source then records with DOP853 (:meth:`_choose_integrator`)."""
        self._exact_refused = f"the FMU refused it at the first step ({reason})"
        inputs = getattr(self, "_inputs_in_effect", None)   # none for an FMU without inputs
        inputs = None if inputs is None else (inputs[0].copy(), None if inputs[1] is None else inputs[1].copy())
        super().start(*self._run_grid)
        if inputs is not None and self._call_set(*inputs) > 1:
            raise StepError(f"{self.path.name} returned an error setting the input again after its restart", 0,
                            float(self._t[0]))

    def _choose_integrator(self) -> str:
        """The integrator of this run: ``method``, where ``auto`` and ``linear`` are resolved.

        ``linear`` (:mod:`._linear_hold`) needs a model whose Jacobian can be identified, without discrete inputs
        (the exact step is one accepted step: where event indicators and completed integrator steps make the
        integration go one accepted step at a time, it is the whole piece); ``auto`` takes it only for a stiff
        model, where the fastest mode's stability bound would hold DOP853 to over 70 steps per communication step
        (``rho(A) h > 250``), on a uniform grid, up to :data:`~._linear_hold.MAX_STATES` states, and where its
        set-up (a matrix exponential of size 2n) is predicted to cost less than DOP853's steps
        (:func:`~._linear_hold.exact_step_pays`).  Everything else takes DOP853, as before ``auto``.  Events split
        steps: a piece of another length takes the exact step where its own matrix exponential is predicted to cost
        less than DOP853 there (:func:`~._integrators._exact_piece_pays`).
        """
        if self.method not in ("auto", "linear"):
            return self.method
        if (getattr(self, "_exact_refused", None) is not None or self._probe_refusal is not None or not self.nx
                or self._discrete.any()):
            return "dop853"
        steps = _grid_steps(self._t)
        self._nominal_step = float((self._t[steps.size] - self._t[0]) / max(steps.size, 1))   # t[-1] with all steps
        uniform = steps.size and np.ptp(steps) <= 1e-9 * float(steps.max()) + 16 * math.ulp(float(self._t[-1]))
        if self.method == "auto":
            if self.nx > _linear_hold.MAX_STATES or not uniform:
                if uniform:
                    self._warn_if_slow(float(steps.max()), len(steps))
                return "dop853"   # (a grid of many step sizes would need one matrix exponential for each)
            rho, seconds = self._stiffness()
            if self._probe_refusal is not None:
                return "dop853"
            if not _linear_hold.exact_step_pays(self.nx, rho * float(steps.max()), len(steps), seconds):
                return "dop853"
            self._stiffness_seen = (rho, seconds)
        self._hold = self._identify_jacobian()
        if self._hold is None:
            return "dop853"
        self._hold.pin(self._nominal_step)
        return "linear"

    def _warn_if_slow(self, h: float, samples: int) -> None:
        """Warn, once per FMU, where a model too large for the exact step is stiff enough that DOP853 is predicted to
        take over :data:`_SLOW_RUN_SECONDS` for the run (an FE model of 10,000 states: hours, with nothing said but
        the progress lines), and name what helps."""
        if self._no_probes or self._probe_refusal is not None:
            return
        rho, seconds = self._stiffness()
        rho_h = rho * h
        if not rho_h > _linear_hold.STIFFNESS_RATIO:
            return
        predicted = samples * _linear_hold.dop853_seconds(rho_h, seconds)
        if predicted <= _SLOW_RUN_SECONDS:
            return
        from . import warn_once

        cs = f"record by co-simulation ({CS}) if the FMU's own solver is implicit, " if (
            self.md.coSimulation is not None) else ""
        memory = _EXPM_BYTES_PER_SQUARE * self.nx**2 / 2**30
        warn_once(self, ("stiff beyond the exact step",), f"a stiff model of {self.nx} states (spectral radius about "
                  f"{rho:.2g} 1/s, {rho_h:.3g} times the step): DOP853 is held to its stability limit and predicted to "
                  f"take about {duration_text(predicted)} for a run of {samples} steps, and the exact hold step takes "
                  f"at most {_linear_hold.MAX_STATES} states; {cs}reduce the model's states, or force the exact step "
                  f"with {either('--me-method', value='linear')} if the machine has about {memory:.2g} GiB to spare",
                  stacklevel=3)

    def _warn_slow_run(self, name: str, t0: float, t1: float, t: float, h: float) -> None:
        """Say once, while the integrator ``name`` is still at it, that it has spent over
        :data:`~._integrators._SLOW_RUN_INTEGRATOR_SECONDS` on this run, where it is, its step size, the time the
        run takes at this pace, and the likely causes (audits of 2026-12-05: Coulomb friction ``sign(v)`` without
        event indicators, a single-precision FMU starting at zero, and BDF on a stiff model at rest each ran for
        minutes in silence)."""
        from . import warn_once

        start, end = float(self._t[0]), float(self._t[-1])
        done = (t - start) / (end - start) if end > start else 0.0
        pace = f", about {duration_text(self._integrator_seconds / done)} for the run at this pace" if done > 0 else ""
        steps = f", with steps of {h:.2g} s" if math.isfinite(h) else ""
        limit = _integrators._SLOW_RUN_INTEGRATOR_SECONDS
        logged = _fmu_log.messages_of(getattr(self, "_log_key", None)) - getattr(self, "_messages_at_start", 0)
        advice = _fmu_log.logging_cause(
            self.path.name, logged, self._integrator_seconds,
            getattr(self, "_messages_per_call", None), "derivative call", _fmu_log.logging_switches(self.md))
        if advice:   # (audit 79a, F3: the integrator and the model are not the cause; fewer samples only help)
            advice += f"{DT_T_END} shorten the run, but the integrator and the model are not what is slow"
        else:
            advice = _slow_run_advice(name, self.md.coSimulation is not None, self.nx, t1 - t0, h,
                                      getattr(self, "_stiffness_measured", None))
        warn_once(self, ("slow run",), f"{name} has spent over {limit:g} s on this run and is "
                  f"at t={t - self.start_time:.9g} of {end - self.start_time:g}{pace}{steps} in a communication step "
                  f"of {t1 - t0:.3g} s: {advice}", stacklevel=2)

    def _probe_deltas(self) -> np.ndarray:
        """State moves for probing the Jacobian: a state's nominal value, or 1e-3 of a large start value (the
        difference is exact for a linear model, and large moves keep rounding small against it)."""
        return np.maximum(self._nominals(), 1e-3 * np.abs(self._origin))

    def _stiffness(self) -> tuple[float, float]:
        """An estimate of the spectral radius of the FMU's Jacobian (a few dozen derivative evaluations; 0 where the
        FMU refuses the probes) and the seconds one evaluation takes: the fastest of them, as a context switch or a
        loaded machine stretches some (their mean, over 2 ms in all, once tripled the estimate at 4000 states and
        made ``auto`` choose the slower integrator: audit of 2026-12-05)."""
        t, deltas = float(self._t[0]), self._probe_deltas()
        fastest, calls, messages = [math.inf], [0], self.quiet_messages()

        def timed(x: np.ndarray) -> np.ndarray:
            started = time.perf_counter()
            derivative = self._derivatives(t, x)
            fastest[0] = min(fastest[0], time.perf_counter() - started)
            calls[0] += 1
            return derivative

        def product(v: np.ndarray) -> np.ndarray:
            return (timed(deltas * v) - base) / deltas

        try:
            base = timed(np.zeros(self.nx))
            rho = _linear_hold.spectral_radius(product, self.nx)
        except _IntegrationError as exc:
            self._refused_probe(exc)
            rho = 0.0
        finally:
            self._end_probes()
        seconds = fastest[0] if math.isfinite(fastest[0]) else 0.0
        if calls[0]:   # (the log messages of a derivative call: the slow-run warning's first suspect)
            self._messages_per_call = (self.quiet_messages() - messages) / calls[0]
        if rho > 0.0:   # (kept for the slow-run warning, which cannot probe during a run)
            self._stiffness_measured = (rho, seconds)
        return rho, seconds

    def _identify_jacobian(self) -> _linear_hold.LinearHold | None:
        """The FMU's Jacobian at its start state (``n + 1`` derivative evaluations), None where it refuses."""
        t = float(self._t[0])
        try:
            return _linear_hold.LinearHold.identify(lambda x: self._derivatives(t, x), np.zeros(self.nx),
                                                    self._probe_deltas(), self._origin)
        except _IntegrationError as exc:
            self._refused_probe(exc)
            return None
        finally:
            self._end_probes()

    def _refused_probe(self, exc: _IntegrationError) -> None:
        """Remember the first probe the FMU refused and whether any refusal was an error: :meth:`start` then starts
        the run again without probes (after a discard the instance stays usable and the run goes on with DOP853)."""
        if self._probe_refusal is None:
            self._probe_refusal = self._last_log() or str(exc)
        self._probe_left_in_error = self._probe_left_in_error or not isinstance(exc, _Discarded)

    def _end_probes(self) -> None:
        """Back to the start state and time after probing the derivatives, and without the messages the FMU logged
        for probes it refused (a later failure must not be explained by them)."""
        self._set_states(np.zeros(self.nx))
        self._c_time(self._comp, float(self._t[0]))
        self._log = []

    def _atol(self, t0: float, t1: float) -> np.ndarray:
        """Absolute tolerance over ``[t0, t1]``: the relative one times each state's largest deviation from its
        start value so far (at least 1e-6 of its nominal value where that is below 1, :func:`_floor`), so that small
        responses are resolved as well as large ones, also about a large start value.  No state is asked for less
        than the FMU can tell apart: one ulp of its start value (the FMU sees ``start + deviation`` rounded), and
        what the derivatives' rounding noise (:meth:`_rounding_noise`) adds up to over the interval.  Asked for
        less, the steps shrink until the noise fits: a chain at 6.4e6 m took 2.7 million derivative evaluations
        for 2 s instead of 5,400 (tests/test_global_coordinates.py)."""
        atol = self.tolerance * np.maximum(self._scale, self._floor)
        np.maximum(atol, self._resolution, out=atol)
        return np.maximum(atol, (t1 - t0) * self._noise, out=atol)

    def _rounding_noise(self) -> np.ndarray:
        """The derivatives' rounding noise at the start state (:meth:`_measure_noise`; 0 where the FMU refuses the
        probes, and the noise measured before a restart after a refused probe)."""
        if self._no_probes:   # (started again after a refused probe: the noise measured before it)
            return getattr(self, "_noise_kept", np.zeros(self.nx)).copy()
        try:
            noise = self._measure_noise(float(self._t[0]), np.zeros(self.nx))   # (the FMU's time after initialization)
        except _IntegrationError as exc:
            self._refused_probe(exc)
            noise = np.zeros(self.nx)
        self._end_probes()
        return noise

    def _measure_noise(self, t: float, x: np.ndarray, coarse_only: bool = False) -> np.ndarray:
        """How far the derivatives at time ``t`` and deviation ``x`` are rounded: the most they move when the
        states move by one or two ulps (:data:`_NOISE_TRIALS` random trials), and where the second differences of
        moves of a few ulps of single precision show more, that.

        The FMU sees the states rounded to their ulps and computes with values of their size: at 6.4e6 m,
        ``K x - f0`` cancels 1e9 N to a few N, and the accelerations are noisy at 1e-6 m/s^2.  An FMU computing in
        ``float`` rounds the ulps away, and its derivatives are noisy at 6e-8 of their terms, which DOP853 asked
        for 1e-10 chased for ever (audit of 2026-12-05).  The second difference counts as noise only for a
        derivative that follows no ulp move (rounded to ``float``), and only where it is at most
        :data:`_ROUNDING_SHARE` of the derivative's response to the larger moves (float rounding is about 0.05 of it,
        6e-8 of the terms against their change of 1.2e-6, while a jump within reach, a relay or a table's step,
        moves the second difference as much as the response), or at most :data:`_FLOAT_ULPS` float ulps of the
        derivative's value (gravity summed in float with a weak spring's force: rounding far above the response to
        the moves, but a few ulps of the value).  A derivative that follows the ulps is taken as double precision
        even where one of its terms is rounded to ``float`` (one single-precision block beside double ones): two
        audits of 2026-12-05 found no test that tells that block's rounding from a jump near the state (a force
        step 0.1 mm away at 1000 m, beside a stiff link, passed every one and loosened a velocity's tolerance to
        0.77 m/s); such a model records at the tolerance's pace, with the slow-run warning.
        ``coarse_only``: only that rounding, without the response to ulp moves (a double model's)."""
        absolute = self._origin + x
        ulps = np.where(absolute != 0, np.spacing(np.abs(absolute)), 0.0)
        noise = np.zeros(self.nx)
        if not ulps.any():
            return noise
        rng = np.random.default_rng(0)
        base = self._derivatives(t, x)
        for row in rng.choice([-2.0, -1.0, 1.0, 2.0], size=(_NOISE_TRIALS, self.nx)):
            np.maximum(noise, np.abs(self._derivatives(t, x + row * ulps) - base), out=noise)
        signs = rng.choice([-1.0, 1.0], size=(_NOISE_TRIALS // 2, self.nx))
        small, slopes, sizes = np.zeros(self.nx), np.zeros(self.nx), np.abs(base)
        for factor in (1.0, _NOISE_MOVE_GROWTH):   # the second differences, then the response to larger moves
            for move in factor * _SINGLE_PRECISION_MOVE * np.abs(absolute) * signs:
                # unequal moves ahead and behind, exact for a linear model: equal ones of a value that float
                # represents exactly (0.375) land on the float grid symmetrically and hide its rounding
                ahead, behind = self._derivatives(t, x + move), self._derivatives(t, x - _BEHIND * move)
                if factor == 1.0:
                    bent = _BEHIND * ahead + behind - (1.0 + _BEHIND) * base
                    np.maximum(small, np.abs(bent) / (1.0 + _BEHIND), out=small)
                else:
                    np.maximum(slopes, 0.5 * np.abs(ahead - behind), out=slopes)
                np.maximum(sizes, np.maximum(np.abs(ahead), np.abs(behind)), out=sizes)
        float_ulps = _FLOAT_ULPS * np.finfo(np.float32).eps * sizes   # (a constant term rounded with the rest)
        rounded = (noise == 0) & ((small <= _ROUNDING_SHARE * slopes) | (small <= float_ulps))
        rounding = np.where(rounded, small, 0.0)
        return rounding if coarse_only else np.maximum(noise, rounding, out=noise)

    def _measure_noise_again(self, t: float, x: np.ndarray, t0: float, t1: float,
                             accepted: int) -> np.ndarray | None:
        """Measure the rounding noise again where DOP853 has taken another :data:`_NOISE_CHECK_STEPS` accepted
        steps in the run (``accepted`` so far) since the last look and a state has grown to twice the size it had at
        the last measurement (an FMU computing in ``float`` from rest at zero shows no noise at the start: 11-13 s
        per 0.2 s step in an audit).  Counted in steps, not seconds, so that the looks fall on the same states
        whatever the machine's load (a float FMU's results moved with it by up to 3x).  Leaves the FMU at ``t``
        and ``x``.  Returns the absolute tolerances over ``[t0, t1]`` where the noise now raises them, else None.
        Only rounding to ``float`` counts (``coarse_only``), not the response to ulp moves: a double model's steps,
        and so its results, stay those of a run without the looks (tested to the bit)."""
        if accepted < self._noise_check_at:   # (also after a restart without the Jacobian's probes: these are tiny)
            return None
        self._noise_check_at = accepted + _NOISE_CHECK_STEPS
        size = np.abs(self._origin + x)
        if not np.any(size > 2.0 * self._noise_measured_size):
            return None
        np.maximum(self._noise_measured_size, size, out=self._noise_measured_size)
        try:
            noise = self._measure_noise(t, x, coarse_only=True)
        except _IntegrationError as exc:
            self._noise_check_at = _NEVER   # (no more probes in this run)
            self._check_after_refused_probe(t, x, self._last_log() or str(exc))
            return None
        finally:
            self._set_states(x)
            self._c_time(self._comp, t)
        before = self._atol(t0, t1)
        binding = (t1 - t0) * noise > before
        if not binding.any():
            return None
        self._noise[binding] = noise[binding]
        return self._atol(t0, t1)

    def _check_after_refused_probe(self, t: float, x: np.ndarray, refusal: str) -> None:
        """After the FMU refused a probe of its rounding noise at ``t``: go on where it still takes the state it came
        from; raise :class:`_LeftInError`, naming the probe, where it stays in error (FMI 2.0 section 2.1.3: an
        FMU that returned an error may take no further call; a range assert at a state's bound does)."""
        try:
            self._derivatives(t, x)
        except _IntegrationError:
            raise _LeftInError(f"the FMU refused a probe of its derivatives at t={t - self.start_time:.9g}, the states "
                               f"moved by up to {_NOISE_MOVE_GROWTH * _SINGLE_PRECISION_MOVE:.2g} of their values to "
                               f"measure their rounding ({refusal}), and stays in error since") from None

    def _rounding_summary(self) -> tuple[str, str | None] | None:
        """What the derivatives' rounding noise (:meth:`_measure_noise`, at the start and during the run) did to this
        run's tolerances, as ``(clause for the run report, warning)``, or None where it set none.

        Said at the end of the run, with the run's whole noise and motion: said at the first loosening, the figure
        understated later ones by up to 33,000x, and a loosening at the start was not said at all (audit of
        2026-12-05).  The report names the state whose tolerance was loosened most against its largest deviation in
        the run; it does not give that as a share of the motion, which would overstate the error: a stiff model's
        steps are held far below the noise's pace by stability (a float chain's velocities were 1.5e-3 off at a
        tolerance of 0.16 of their motion, and as far off with one 1000 times tighter).  The warning's words are the
        same for every run, since each run in a process of its own says it and the user is to hear it once.  No
        warning where no tolerance exceeds :data:`_NOTABLE_LOOSENING` of its state's motion, or of its nominal value
        up to 1 where it moved less (a double model's stiff link at rest: 5e-8; after the one step of a steady-start
        check, 1.9e-5 of the floor of 1e-6, which an audit saw said as a warning for double models).
        """
        noise = getattr(self, "_noise", None)
        if noise is None or not noise.any() or len(self._t) < 2:
            return None
        held = float(np.max(np.diff(self._t))) * noise
        asked = np.maximum(self.tolerance * np.maximum(self._scale, self._floor), self._resolution)
        loosened = held > asked
        if not loosened.any():
            return None
        motion = np.maximum(self._scale, np.minimum(self._nominals(), 1.0))   # (a run of one step hardly moves)
        share = np.where(loosened, held / motion, -1.0)
        worst = int(np.argmax(share))
        name = self._state_name(worst)
        clause = (f"the derivatives' rounding noise (up to {noise[worst]:.2g} in {name}'s derivative) set the absolute "
                  f"tolerance of {int(loosened.sum())} state(s); the loosest against its motion is {name}'s, "
                  f"{held[worst]:.2g} in its unit")
        if share[worst] < _NOTABLE_LOOSENING:
            return clause, None
        warning = ("its derivatives change irregularly under the smallest moves of the states, as rounding in single "
                   "precision or large terms cancelling does: the recorded states carry that rounding, and states "
                   f"were integrated to the absolute tolerance it allows, not to the relative tolerance "
                   f"{self._pilot_of or self.tolerance:g} asked (each such run's integrator attribute gives the noise "
                   "and the loosest tolerance)")
        return clause, warning

    def _state_name(self, index: int) -> str:
        """The name of continuous state ``index`` from the model description, else ``"state <index + 1>"``."""
        unknowns = getattr(self.md, "derivatives", None) or []
        if len(unknowns) == self.nx:   # (an FMI 3 array state counts once there)
            state = getattr(getattr(unknowns[index], "variable", None), "derivative", None)
            if getattr(state, "name", None):
                return str(state.name)
        return f"state {index + 1}"

    def _absolute(self, x: np.ndarray) -> np.ndarray:
        """The FMU's states for the deviation ``x`` from the start state (in a buffer reused by the next call)."""
        return np.add(self._origin, x, out=self._absolute_x)

    def _set_states(self, x: np.ndarray) -> int:
        """Give the FMU the states of the deviation ``x``; the FMU's status."""
        return self._c_set_x(self._comp, self._absolute(x).ctypes.data, self.nx)

    def _state_count(self) -> int:
        if self.fmi_version.startswith("2"):
            return len(self.md.derivatives)
        return int(self._fmu.getNumberOfContinuousStates())

    def _indicator_count(self) -> int:
        """Number of event indicators (FMI 3: asked of the instance, as sizes may be structural)."""
        declared = int(getattr(self.md, "numberOfEventIndicators", 0) or 0)
        if self.fmi_version.startswith("2"):
            return declared
        try:
            return int(self._fmu.getNumberOfEventIndicators())
        except Exception:
            return declared

    def _nominals(self) -> np.ndarray:
        nominals = np.ones(self.nx)
        if self.nx:
            try:
                self._fmu.getNominalsOfContinuousStates(nominals.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
                                                        self.nx)
            except Exception:
                nominals[:] = 1.0
        nominals = np.abs(nominals)
        nominals[~np.isfinite(nominals) | (nominals == 0)] = 1.0
        return nominals

    def _event_iteration(self) -> bool:
        """Update the discrete states until the FMU needs no more (the FMU is in event mode); remember
        the next time event it announces.  Returns whether the nominals of the states changed."""
        update = (self._fmu.newDiscreteStates if self.fmi_version.startswith("2")
                  else self._fmu.updateDiscreteStates)
        nominals = False
        for _ in range(_MAX_EVENT_ITERATIONS):
            needed, terminate, nominals_changed, _, next_defined, next_time = update()[:6]
            nominals = nominals or bool(nominals_changed)
            if terminate:
                raise _TerminationAsked(f"{self.path.name} {TERMINATED} during an event iteration")
            if not needed:
                self._t_next = float(next_time) if next_defined else math.inf
                return nominals
        raise FMUError(f"{self.path.name} did not finish its event iteration after {_MAX_EVENT_ITERATIONS} rounds")

    # -- stepping ---------------------------------------------------------------------------
    def _plan(self, t: np.ndarray, U: np.ndarray) -> None:
        super()._plan(t, U)
        self._discrete = discrete = _discrete_inputs(self.md, self.input_names)
        self._last_discrete: np.ndarray | None = None   # step(): the first call of a run sets them in event mode
        in_event = np.zeros(len(self._t), dtype=bool)
        if discrete.any():
            in_event[1:] = np.any(self._U[1:, discrete] != self._U[:-1, discrete], axis=1)
        self._inputs_in_event_mode = in_event.tolist()

    def advance(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None = None,
                offset: int = 0) -> None:
        t = self._t_list
        for j in range(count):
            i = i0 + j
            if i:
                try:
                    self._take_step(i)
                except _ReplayWithoutLooks as exc:
                    self._replay_without_looks(i, str(exc))
                    self._take_step(i)
            self.read(rows[j])
            if published is not None:
                published[0] = offset + j + 1
        if i0 + count == len(t):
            self._warn_rounding()

    def _take_step(self, i: int) -> None:
        """From sample ``i - 1`` to sample ``i`` of the run: the inputs of step ``i``, then the integration."""
        t, changed = self._t_list, self._changed
        if self._inputs_in_event_mode[i]:
            self._handle_event(i, t[i - 1], lambda: self._set_inputs(i))
        elif changed[i]:
            self._set_inputs(i)
        self._integrate(i, t[i - 1], t[i], bool(changed[i]))

    def _replay_without_looks(self, i: int, refusal: str) -> None:
        """Start the run again and take its steps up to sample ``i - 1`` once more, without looking at the rounding
        noise again, after the FMU refused such a look in step ``i`` and stayed in error (:class:`_LeftInError`).

        An FMU that returned an error may take no further call (FMI 2.0 section 2.1.3), and the looks move the
        states by a few ulps of single precision: a model at rest exactly on the bound of a range it asserts
        failed there, and the message named BDF, which never finished on a stiff model at rest (audit of
        2026-12-05).  The samples already recorded stay; the run's second pass recomputes the state they reached
        (the same integrator, only without the looks)."""
        self._noise_refused = refusal
        try:
            self.start(*self._run_grid)
            for step in range(1, i):
                self._take_step(step)
        except (StepError, FMUError) as exc:
            raise StepError(f"{self.path.name}: {refusal}; started again without such probes, it failed ({exc})",
                            i, self._t_list[i]) from None

    def _warn_rounding(self) -> None:
        """At the end of a run, say once for this FMU where rounding noise loosened a tolerance
        (:meth:`_rounding_summary`)."""
        rounding = self._rounding_summary()
        if rounding is not None and rounding[1] is not None:
            from . import warn_once

            warn_once(self, ("rounding noise",), rounding[1], stacklevel=4)

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        self.refuse_single_precision_overflow(np.reshape(u, (self.m, 1)))
        discrete = np.reshape(np.asarray(u, dtype=float), self.m)[self._discrete]
        u = np.ascontiguousarray(self._raw_inputs(np.atleast_2d(np.asarray(u, dtype=float)))[0])

        t = self.start_time + t   # the FMU's time

        def set_input() -> None:
            if self._call_set(u) > 1:
                raise StepError(f"{self.path.name} returned an error setting the input at {self._at(t)}", -1, t)

        last = self._last_discrete
        if discrete.size and (last is None or np.any(discrete != last)):   # they may change only in event mode
            self._handle_event(-1, t, set_input)
            self._last_discrete = discrete
        elif self.m:
            set_input()
        self._integrate(-1, t, t + h)

    def _integrate(self, i: int, t0: float, t1: float, inputs_set: bool = True) -> None:
        """Integrate the state from ``t0`` to ``t1`` with the inputs held, and leave the FMU there;
        ``inputs_set``: whether inputs were set at ``t0`` (which may move an event indicator there)."""
        if self.nz or self._t_next != math.inf:
            self._integrate_with_events(i, t0, t1, inputs_set)
            return
        t = self._piece(i, t0, t1)
        if t < t1:   # the FMU asked for an event in a completed integrator step inside the interval
            self._handle_event(i, t)
            self._integrate_with_events(i, t, t1, False)
            return
        self._completed_step(i, t1)

    def _piece(self, i: int, t0: float, t1: float, one_step: bool = False) -> float:
        """Integrate from ``t0`` to ``t1`` (no event inside) and set the FMU's state and time there.

        For an FMU that needs them, ``fmiCompletedIntegratorStep`` is called after each accepted step before ``t1``
        (not in the trials of a crossing search, which go back in time).  Returns the time reached: ``t1``, or that
        of the completed step where the FMU asked for an event (the caller handles it).  ``one_step``: stop after
        one accepted step, not completed (:meth:`_advance_step_by_step` completes it once its indicators are read).
        """
        t = t1
        if self.nx:
            try:
                completed = self._needs_completed and not self._searching and not one_step
                self._x, t = _INTEGRATORS[self._active](self, t0, t1, completed, one_step)
                np.maximum(self._scale, np.abs(self._x), out=self._scale)
            except _ExactStepRefused as exc:
                self._restart_without_exact_step(str(exc))
                return self._piece(i, t0, t1, one_step)
            except _LeftInError as exc:
                if i > 0 and self._noise_refused is None:   # (the run's grid is known: it can be replayed)
                    raise _ReplayWithoutLooks(str(exc)) from None
                raise StepError(f"{self.path.name}: {exc}", i, t1) from None
            except _IntegrationError as exc:
                raise StepError(self._terminated_inside(str(exc))
                                or self._integration_failure(i, t0, t1, str(exc)), i, t1) from None
            self._set_states(self._x)
        if self._c_time(self._comp, t) > 1:
            raise StepError(self._integration_failure(i, t0, t1, "fmiSetTime failed"), i, t1)
        return t

    def _integrate_with_events(self, i: int, t0: float, t1: float, inputs_set: bool) -> None:
        """:meth:`_integrate` through the time events and the located state events in ``(t0, t1]``.

        An event time within :func:`_time_slack` of ``t1`` is taken as ``t1`` (the FMU's time is then the
        event's), so that neither a zero-length integration nor a skipped event results from round-off.
        """
        slack = _time_slack(t0, t1)
        t = t0
        if self.nz and inputs_set:   # the inputs just set may have moved an indicator across zero: an event here
            self._indicators_at(i, t, self._z_end)
            if _sign_changed(self._z, self._z_end):
                self._handle_event(i, t)
            else:
                self._z, self._z_end = self._z_end, self._z
        events = asked_events = 0
        while events < _MAX_EVENTS_PER_STEP and asked_events < _MAX_ASKED_EVENTS_PER_STEP:
            timed = self._t_next <= t1 + slack
            end = max(self._t_next, t) if timed else t1
            t, crossed, asked = self._advance_to(i, t, end)
            if asked:   # in a completed integrator step before the end, which was called there
                self._handle_event(i, t)
                asked_events += 1
            elif not self._completed_step(i, t) and (crossed or timed):
                self._handle_event(i, t)
                events += 1
            if t1 - t <= slack:
                return
        cs = f"; or try {CS}" if self.md.coSimulation is not None else ""
        if asked_events:
            raise StepError(f"{self.path.name}: it asked for an event in more than {asked_events} completed "
                            f"integrator steps between {self._at(t0)} and {t1:g}; check the model's "
                            f"fmiCompletedIntegratorStep{cs}", i, t1)
        raise StepError(f"{self.path.name}: more than {events} events between {self._at(t0)} and {t1:g} (an event "
                        f"indicator chatters or time events do not advance); fix the model{cs}", i, t1)

    def _advance_to(self, i: int, t0: float, t1: float) -> tuple[float, bool, bool]:
        """Integrate towards ``t1``; with event indicators, stop just after the first change of sign; stop where
        the FMU asks for an event in a completed integrator step.  Returns the time reached, whether an
        indicator crossed zero, and whether the FMU asked for an event there (a crossing before it comes first)."""
        if t1 <= t0:   # an event due at once
            return t0, False, False
        if self.nz and self._needs_completed:
            return self._advance_step_by_step(i, t0, t1)
        start = self._x.copy() if self.nz else None
        t = self._piece(i, t0, t1)
        if not self.nz:
            return t, False, t < t1
        self._read_indicators(i, t, self._z_end)
        if not _sign_changed(self._z, self._z_end):
            self._z, self._z_end = self._z_end, self._z
            return t, False, t < t1
        return self._locate_crossing(i, t0, t, start), True, False

    def _advance_step_by_step(self, i: int, t0: float, t1: float) -> tuple[float, bool, bool]:
        """:meth:`_advance_to` for an FMU with event indicators that needs its completed integrator steps: one
        accepted step at a time, its indicators read before the step is completed, so that a crossing is searched
        for within the last step, after the last completed point (FMI never takes a completed step back: a search
        over the whole interval went back before steps already completed)."""
        t = t0
        while t < t1:
            check_interrupt()   # (the step loop pauses for it only between blocks of many steps)
            start = self._x.copy()
            reached = self._piece(i, t, t1, one_step=True)
            self._read_indicators(i, reached, self._z_end)
            if _sign_changed(self._z, self._z_end):
                return self._locate_crossing(i, t, reached, start), True, False
            self._z, self._z_end = self._z_end, self._z
            if reached < t1 and self._completed_asks_event(i, reached):
                return reached, False, True
            t = reached
        return t, False, False

    def _locate_crossing(self, i: int, a: float, b: float, x_a: np.ndarray) -> float:
        """The first zero crossing of an event indicator in ``(a, b]``, bracketed to
        ``1e-12 (b - a)`` plus a few ulps: regula falsi on the earliest crossing (Illinois variant); an
        estimate within half the tolerance of an end moves a whole tolerance inside (a converged one-sided
        secant then closes the bracket in one trial); a bisection when two trials did not halve the
        bracket.  Each trial re-integrates from the last state before the crossing with the inputs held.
        Ends when the bracket is that narrow, within rounding of it, or after :data:`_MAX_CROSSING_TRIALS`
        trials (a bracket of the crossing all the same).  Leaves the FMU (and ``self._x``) at the right end."""
        tolerance = 1e-12 * (b - a) + 4 * math.ulp(max(abs(a), abs(b)))
        g_a, g_b, x_b = self._z.copy(), self._z_end.copy(), self._x.copy()
        w_a, w_b = g_a.copy(), g_b.copy()   # Illinois: the values the secant uses
        h_last = self._h_last   # the next interval starts from the step size before the search
        moved, bisect, widths = 0, False, [b - a] * 3
        for _ in range(_MAX_CROSSING_TRIALS):
            if not b - a > tolerance:
                break
            t_m = 0.5 * (a + b) if bisect else _earliest_secant(a, b, g_a, g_b, w_a, w_b)
            if t_m - a < 0.5 * tolerance or b - t_m < 0.5 * tolerance:
                t_m = a + tolerance if t_m - a < b - t_m else b - tolerance
            if not a < t_m < b:  # the bracket is within rounding of the tolerance: as narrow as it gets
                break
            self._x = x_a.copy()
            self._searching = True
            try:
                self._piece(i, a, t_m)
            finally:
                self._searching = False
            g_m = np.empty(self.nz)
            self._read_indicators(i, t_m, g_m)
            if _sign_changed(g_a, g_m):
                b, g_b, w_b, x_b = t_m, g_m, g_m.copy(), self._x.copy()
                if moved == -1:
                    w_a *= 0.5
                moved = -1
            else:
                a, g_a, w_a, x_a = t_m, g_m, g_m.copy(), self._x.copy()
                if moved == 1:
                    w_b *= 0.5
                moved = 1
            widths = widths[1:] + [b - a]
            bisect = b - a > 0.5 * widths[0] and not bisect
        self._x, self._h_last = x_b, h_last
        if self.nx:
            self._set_states(self._x)
        self._c_time(self._comp, b)
        self._z_end = g_b
        return b

    def _indicators_at(self, i: int, t: float, out: np.ndarray) -> None:
        """The event indicators at time ``t`` and the current state (the FMU is left there)."""
        if self.nx:
            self._set_states(self._x)
        self._c_time(self._comp, t)
        self._read_indicators(i, t, out)

    def _read_indicators(self, i: int, t: float, out: np.ndarray) -> None:
        if self._c_indicators(self._comp, out.ctypes.data, self.nz) > 1:
            raise StepError(self._integration_failure(i, t, t, "fmiGetEventIndicators failed"), i, t)

    def _completed_step(self, i: int, t1: float) -> bool:
        """``fmiCompletedIntegratorStep`` at ``t1``; handles the event it may ask for (returns whether)."""
        asked = self._completed_asks_event(i, t1)
        if asked:
            self._handle_event(i, t1)
        return asked

    def _completed_asks_event(self, i: int, t1: float) -> bool:
        """``fmiCompletedIntegratorStep`` at ``t1`` (the FMU's time and state): whether the FMU asks for an event."""
        flags = self._event_flags
        flags[:] = 0
        address = flags.ctypes.data
        if self._c_completed(self._comp, True, address, address + flags.itemsize) > 1:
            raise StepError(self._integration_failure(i, t1, t1, "fmiCompletedIntegratorStep failed"), i, t1)
        if flags[1] and not self._at_run_end(i, t1):
            raise StepError(self._termination_line(f"in fmiCompletedIntegratorStep at {self._at(t1)}", t1), i, t1)
        return bool(flags[0]) and not flags[1]

    def _terminated_inside(self, reason: str) -> str | None:
        """The termination line where an integrator's ``reason`` is the FMU asking to terminate in a completed
        integrator step inside an interval (:func:`._integrators._completed_inside`, the compiled DOP853), else None:
        a model's end, not an integration failure."""
        found = re.search(rf"{TERMINATED} in fmiCompletedIntegratorStep at t=([-+0-9.eE]+)", reason)
        if found is None:
            return None
        t = float(found.group(1))
        return self._termination_line(f"in fmiCompletedIntegratorStep at {self._at(t)}", t)

    def _at_run_end(self, i: int, t: float) -> bool:
        """Whether FMU time ``t`` of step ``i`` is the run's last sample: a termination asked there ends the run with
        its samples complete (audit 75, F3: ``--t-end`` at a model's ``terminate()`` time failed)."""
        times = self._t_list
        return 0 < i == len(times) - 1 and abs(t - times[i]) <= _time_slack(times[i - 1], times[i])

    def _handle_event(self, i: int, t: float, set_inputs: Callable[[], None] | None = None) -> None:
        """Event mode at the FMU's current time ``t`` (of step ``i``): iterate, then read the (possibly changed)
        states, their nominals when they changed, and the event indicators as the reference of the next interval.
        ``set_inputs``: set the inputs in event mode, before the iteration (a change of a discrete input, which
        the FMU may take only there); such an event is not one of the model's, so it is not counted.
        The model's events are counted apart when they change nothing: the same states, and the same derivatives
        and recorded values there before and after (a Boolean sensor, a threshold that only drives a flag); a
        linear ROM follows such a model exactly (audit 2026-11-27, finding 11: 51 events, the ROM exact).
        Whatever goes wrong is a :class:`StepError`, so the recorder keeps the samples before it."""
        from fmpy.fmi1 import FMICallException

        before = self._observed(t) if set_inputs is None else None
        try:
            self._fmu.enterEventMode()
            if set_inputs is not None:
                set_inputs()
            nominals_changed = self._event_iteration()
            self._fmu.enterContinuousTimeMode()
        except _TerminationAsked:
            if self._at_run_end(i, t):   # the samples up to it are complete: the run ends there (in event mode)
                return
            raise StepError(self._termination_line(f"in its event iteration at {self._at(t)}", t), i, t) from None
        except FMUError as exc:
            raise StepError(f"{exc} (at {self._at(t)})", i, t) from None
        except FMICallException as exc:  # the FMU refused a call of the event iteration
            raise StepError(self._integration_failure(i, t, t, f"the event iteration failed: {exc}"), i, t) from None
        self._f_end = None   # the event may have changed the derivatives where the last step ended
        states_changed = bool(self.nx) and self._read_states_after_event(i, t)
        if self.nx and nominals_changed:
            self._floor = _floor(self._nominals())
        if set_inputs is None:
            self._count_event(t, states_changed or not _same(before, self._observed(t)))
        if self.nz:
            self._read_indicators(i, t, self._z)

    def _observed(self, t: float) -> np.ndarray | None:
        """The derivatives and the recorded values at time ``t`` and the current states: what an event may
        change (None where the FMU refuses to evaluate them, which then counts as a change)."""
        values = np.empty(len(self._read))
        try:
            self.read(values)
            derivatives = self._derivatives(t, self._x) if self.nx else np.empty(0)
        except (StepError, _IntegrationError):
            return None
        return np.concatenate([derivatives, values])

    def _count_event(self, t: float, changed: bool) -> None:
        seen = self._events
        if changed:
            self._events = seen._replace(count=seen.count + 1, first=t if seen.first is None else seen.first)
        else:
            self._events = seen._replace(inert=seen.inert + 1)

    def _read_states_after_event(self, i: int, t: float) -> bool:
        """Read the states after an event; the deviation is kept to every digit where the event left them as they
        were (most events), and taken from the states where it changed them (returns whether)."""
        states = np.zeros(self.nx)
        if self._c_get_x(self._comp, states.ctypes.data, self.nx) > 1:
            raise StepError(self._integration_failure(i, t, t, "reading the states after an event failed"), i, t)
        if np.array_equal(states, self._absolute(self._x)):
            return False
        self._x = states - self._origin
        return True

    def _integration_failure(self, i: int, t0: float, t1: float, reason: str) -> str:
        """One line: where and why the integration failed, the FMU's last error message, and what may help."""
        where = f"step {i} ({self._at(t0)} -> {t1:g})" if i >= 0 else f"{self._at(t0)} -> {t1:g}"
        log = self._last_log()
        cs = f", or {CS}" if self.md.coSimulation is not None else ""
        in_pilot = self._pilot_of is not None
        looser = (f"give {DT_T_END} to record without the automatic window's pilot runs" if in_pilot else
                  f"try a looser {either('--tolerance')}{cs}")
        if log:   # the FMU said why: the tolerance is only one possible cause
            hint = (f"the FMU reported: {log}; where that is a range the model asserts, the motion leaves it (a "
                    f"smaller input or another start state); if the tolerance is the cause, {looser}")
        elif "not finite" in reason:   # (audit 58: a damping exposed as an input, driven below 0, was blamed on
            # the tolerance alone)
            hint = ("the motion grew without bound, as an unstable model's does (a stiffness or a damping that is "
                    f"driven as an input or set below 0 ({either('--set')}): {either('--inputs')} names the "
                    "forces); if the tolerance is the cause, "
                    f"{looser}")
        else:
            hint = looser
        method = getattr(self, "_active", self.method)
        pilot = ", in a pilot run of the automatic window" if in_pilot else ""
        return (f"{self.path.name}: model-exchange integration ({method}, tolerance {self.tolerance:g}{pilot}) "
                f"failed at {where}: {reason}; {hint}")

    def rhs(self, t: float, x: np.ndarray) -> np.ndarray:
        """``der(x)`` of the FMU at time ``t`` and the states of the deviation ``x`` from the start state, with
        the current inputs (the integrators' right-hand side)."""
        return self._derivatives(t, x)

    def _derivatives(self, t: float, x: np.ndarray) -> np.ndarray:
        comp, dx = self._comp, self._dx
        status = self._c_time(comp, t)
        if status < DISCARD:
            status = self._set_states(x)
        if status < DISCARD:
            status = self._c_dx(comp, dx.ctypes.data, self.nx)
        if status == DISCARD:
            raise _Discarded(f"the FMU refused to evaluate the derivatives (a discard) at t={t:.9g}")
        if status > DISCARD:
            raise _IntegrationError(f"the FMU refused to evaluate the derivatives (an error) at t={t:.9g}")
        if not np.isfinite(dx).all():
            raise _Discarded(f"the derivatives are not finite at t={t:.9g}")
        return dx.copy()


def _grid_steps(t: np.ndarray) -> np.ndarray:
    """The steps of the grid ``t`` that choose a run's integrator: all, but for a last step shorter than half the one
    before, which is then a piece of another length (:func:`~._integrators._exact_piece_pays`).  The recorder's
    direct evaluation of stale-looking accelerations runs a uniform grid up to a sample and one step of 1e-6 of it
    past (:func:`fmu_opinf.snapshots._run._accelerations_after`): that grid took DOP853, 3 s for one step of a
    stiff FE beam that the exact step takes in milliseconds."""
    steps = np.diff(np.asarray(t, dtype=float))
    return steps[:-1] if steps.size > 1 and steps[-1] < 0.5 * steps[-2] else steps


# ---------------------------------------------------------------------------------------- events

#: ``rho h`` (spectral radius times the communication step) below which an explicit integrator is not held back by
#: stability: its steps are bounded by the communication step anyway (audit 77b F3: 0.016 on a 1198-state chain).
_NOT_STIFF = 1.0
#: Derivative evaluations per DOP853 step (12 stages, the last reused by the next step).
_DOP853_CALLS = 12
_JUMPS = ("derivatives that jump without event indicators (Coulomb friction sign(v), a relay, a table) or are rounded "
          "inside the FMU (single precision) make its steps collapse: ")
_JUMP_WAYS = (f"loosen {either('--tolerance')} (1e-6 for single precision), or give the model event indicators or "
              "smooth friction; a linear model of many states that is none of these records faster by the exact hold "
              f"step ({either('--me-method', value='linear')})")


def _slow_run_advice(name: str, cosimulation: bool, nx: int, step: float, h: float,
                     measured: tuple[float, float] | None) -> str:
    """The causes and remedies a slow run's warning names, by what the stiffness probe measured.

    Parameters
    ----------
    name : str
        The integrator (``"DOP853"``, ``"BDF"`` ...).
    cosimulation : bool
        Whether the FMU offers co-simulation.
    nx : int
        Number of continuous states.
    step : float
        The communication step of the run.
    h : float
        The integrator's current step size (nan where unknown).
    measured : tuple of float or None
        ``(rho, seconds)``: the Jacobian's spectral radius estimate and the seconds one derivative call takes
        (:meth:`ModelExchangeSource._stiffness`), None where not measured.

    Returns
    -------
    str
        Causes, then remedies.  Where ``rho step`` is small and the steps are near the communication step, the time
        is the derivative's cost times the samples, so stiffness, friction and co-simulation are not named (audit 77b
        F3: they were, for a chain of 1198 states at ``rho h`` = 0.016, and co-simulation took twice as long).
    """
    cs = f"record by co-simulation ({CS}), " if cosimulation else ""
    if name in _IMPLICIT:   # (stiffness does not hold these back; the default integrator may do better)
        return f"{_JUMPS}{cs}record with {either('--me-method', value='auto')}, {_JUMP_WAYS}"
    if measured is None or not measured[0] * step < _NOT_STIFF:
        return f"a stiff model holds it to its stability limit, and {_JUMPS}{cs}{_JUMP_WAYS}"
    rho, seconds = measured
    stiffness = f"the model is not stiff (spectral radius about {rho:.2g} 1/s, {rho * step:.2g} times the step)"
    if math.isfinite(h) and h < step / 10:
        return f"{stiffness}, but {_JUMPS}{cs}{_JUMP_WAYS}"
    return (f"{stiffness} and its steps are near the communication step: the time is the FMU's derivative, "
            f"{nx} states at {seconds * 1e3:.2g} ms per call, {_DOP853_CALLS} calls per {name} step, times the "
            f"samples; give {DT_T_END} (the automatic window's pilot runs, fine-step runs of the whole "
            "response, are then skipped), or record a linear model by the exact hold step "
            f"({either('--me-method', value='linear')}); co-simulation does not help (the FMU's own solver calls the "
            "same derivative)")


def _discrete_inputs(md: Any, input_names: list[str]) -> np.ndarray:
    """Which force inputs have discrete variability: model exchange may change them only in event mode (FMI 2.0
    section 3.2.3, FMI 3.0 likewise); an element ``F[2]`` of an FMI 3 array is its array's."""
    variability = {v.name: v.variability for v in md.modelVariables}
    return np.array([variability.get(name, variability.get(name.split("[")[0])) == "discrete"
                     for name in input_names], dtype=bool)


def _needs_completed_steps(md: Any) -> bool:
    """Whether the FMU needs ``fmiCompletedIntegratorStep`` after every accepted integrator step: FMI 2 unless
    ``completedIntegratorStepNotNeeded="true"`` (the default is false: needed, FMI 2.0 section 3.2.2), FMI 3 when
    ``needsCompletedIntegratorStep="true"`` (default false).  Others get it only at the end of each interval.

    fmpy reads FMI 2's attribute into ``needsCompletedIntegratorStep`` (its negation) and leaves
    ``completedIntegratorStepNotNeeded`` at its default, so that one attribute answers for both versions."""
    return bool(getattr(md.modelExchange, "needsCompletedIntegratorStep", False))


#: Relative tolerance of the automatic window's pilot runs where a tighter one was asked
#: (:meth:`ModelExchangeSource.pilot_accuracy`).
PILOT_TOLERANCE = 1e-6

#: Trials of :meth:`ModelExchangeSource._rounding_noise` (one derivative evaluation each, once per run).
_NOISE_TRIALS = 8

#: Relative moves of the states for the second differences of :meth:`ModelExchangeSource._measure_noise`: a few
#: ulps of single precision (6e-8), which an FMU computing in ``float`` rounds to its grid.
_SINGLE_PRECISION_MOVE = 3e-7

#: The move behind the state in the second differences of :meth:`ModelExchangeSource._measure_noise`, relative to
#: the move ahead (incommensurate with float's grid).
_BEHIND = 0.618

#: The larger moves of :meth:`ModelExchangeSource._measure_noise`, relative to :data:`_SINGLE_PRECISION_MOVE`,
#: whose response the second differences are compared with (a jump within reach moves both alike).
_NOISE_MOVE_GROWTH = 4.0

#: The largest share of a derivative's response to the larger moves of :meth:`ModelExchangeSource._measure_noise`
#: that its second difference may have to count as rounding: float rounding is about 0.05 of it (6e-8 of the terms
#: against a change of 1.2e-6 of them), a jump within reach about 1.
_ROUNDING_SHARE = 0.25

#: Float ulps of a derivative's value (``2**-23`` of it each) up to which its second difference counts as rounding
#: whatever the response to the moves (:meth:`ModelExchangeSource._measure_noise`): a result rounded to float is
#: within half an ulp.
_FLOAT_ULPS = 4.0

#: Share of a state's largest deviation in the run above which a tolerance the rounding noise loosened is warned
#: about (:meth:`ModelExchangeSource._rounding_summary`): about eight ulps of single precision, where its rounding
#: starts to show; below, a double model's cancelling terms, said only in the run report.
_NOTABLE_LOOSENING = 1e-6

#: Accepted DOP853 steps in a run between looks at whether the states have grown enough to measure the rounding
#: noise again (:meth:`ModelExchangeSource._measure_noise_again`; 12,000 derivative evaluations, a measurement 25).
_NOISE_CHECK_STEPS = 1000

#: A count of accepted steps no run reaches: no more looks.
_NEVER = 1 << 62


def _floor(nominals: np.ndarray) -> np.ndarray:
    """The magnitudes below which the absolute tolerance stops following a state: 1e-6 of its nominal value, at most
    1e-6 (a nominal above 1 would loosen the tolerance of a state whose motion stays below 1e-6 of it)."""
    return 1e-6 * np.minimum(nominals, 1.0)


def _time_slack(t0: float, t1: float) -> float:
    """Times closer than this to a communication point ``t1`` are ``t1`` (round-off of event times)."""
    return 8 * math.ulp(max(abs(t0), abs(t1))) + 1e-12 * (t1 - t0)


def _same(before: np.ndarray | None, after: np.ndarray | None) -> bool:
    """Whether an event left the derivatives and recorded values as they were, to rounding (1e-12 relative)."""
    if before is None or after is None:
        return False
    return bool(np.all(np.abs(after - before) <= 1e-12 * np.maximum(np.abs(before), np.abs(after))))


def _sign_changed(before: np.ndarray, after: np.ndarray) -> bool:
    """Whether an event indicator crossed zero (FMI: from ``> 0`` to ``<= 0`` or back); a few indicators are
    compared as Python floats (0.5 us against NumPy's 2.8 us, twice per step)."""
    if before.size <= 32:
        return any((p > 0) != (q > 0) for p, q in zip(before.tolist(), after.tolist()))
    return bool(np.any((before > 0) != (after > 0)))


def _earliest_secant(a: float, b: float, g_a: np.ndarray, g_b: np.ndarray, w_a: np.ndarray,
                     w_b: np.ndarray) -> float:
    """Regula falsi estimate of the earliest crossing in ``(a, b)`` among the indicators whose sign
    differs at the ends (``w``: their Illinois-weighted values); the midpoint if none is usable."""
    changed = (g_a > 0) != (g_b > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        times = a + (b - a) * w_a[changed] / (w_a[changed] - w_b[changed])
    times = times[np.isfinite(times) & (times >= a) & (times <= b)]  # at an end: moved inside by the caller
    return float(times.min()) if times.size else 0.5 * (a + b)
