"""Whether the default training's response scales with its amplitude, and the amplitude at which it does.

The default training pulse is 100 in each input's unit whatever the model (:data:`._inputs.DEFAULT_TRAINING_INPUT`).
An export that is linear only near its operating point (a hardening spring, an end stop, a pendulum, friction) then
moves far outside that range: on a 100 N/m chain the pulse moved the masses by 1.4-2.2 m, and the ROM, fitted to
that large response, was 3-100 % of range off on small inputs, silently at 15 % extra stiffness (audit 79b, F1-F3).
A linear model's response net of its own motion scales with the amplitude; :func:`linear_amplitudes` compares the
response to the default pulse with one to the same pulse at a tenth of it the other way (:data:`DECADE`), reusing a
run of the automatic window (the one extra run is the smaller pulse's; two or three more where the pilots
integrate at a looser tolerance than the recording and that makes the two differ, :func:`accurate`), lowers the
amplitude by decades until two neighbours agree (:data:`LINEARITY_BAR`, :data:`LOWERED_BAR`), and says so; down to
:data:`LOWEST_SHARE` of the default with no agreement, it keeps the default and warns
(:func:`~._notes.warn_recording`, kept in the file for ``fit``, ``compare`` and ``export``).

Where the user chose the input (``--input``, a run table's rows), or the default training ran without this check (a
grid given without pilots, a pulse raised for a model moving on its own), :func:`check_given_input` judges the run
recorded the same way after recording, with one run of its input at -1/10, and only warns: the input stays as given.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import sys
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from .._validate import either
from ..signals import Signal
from ..sources import Source

__all__ = ["CHECK_TOLERANCE", "LINEARITY_BAR", "Reference", "accurate", "integrated_to_tolerance", "linear_amplitudes",
           "mismatch", "note_pilot", "watching_pilots"]

#: Largest mismatch (:func:`mismatch`) between the response to the default pulse and -10 times the response to a
#: tenth of it the other way, both net of the model's own motion, that counts as linear.  Measured on linear FMUs:
#: round-off (1e-16 .. 1e-13) for the default integrators, exact steps and RK4 or explicit-Euler co-simulation;
#: 5.9e-7 in single precision; model exchange with BDF or LSODA 1e-7 .. 7e-7 (at the recording's tolerance,
#: :func:`accurate`; at the pilots' 1e-6, on a chain moving on its own, 1.3e-3 .. 5e-3, and 0.2 on a chain sagging
#: to 3.7e4 m).  The bar leaves room for an FMU's own integrator at a loose tolerance; the mildest nonlinearity of
#: audit 79b (a hardening spring adding 15 % stiffness at the training's peak, its ROM 3-6 % off on small inputs,
#: no warning) gives 0.06.
LINEARITY_BAR = 1e-2

#: Mismatch to which a model found not linear at the default amplitude is lowered (while its mismatch falls): the
#: ROM of audit 79b's hardening springs is then 1e-5 .. 4e-4 of range off the exact linearization on small inputs.
LOWERED_BAR = 1e-3

#: Factor between the amplitudes compared, and by which the training amplitude is lowered per try.
DECADE = 10.0

#: Lowest training amplitude tried, as a share of the default one (three decades: 100 -> 0.1 in the input's unit).
#: A model not linear at that amplitude (friction, a contact at its rest position) has no linear range the default
#: training can find; it keeps the default amplitude, with a warning.
LOWEST_SHARE = 1e-3

#: Factor by which the mismatch must fall per decade of amplitude for the lowering to go on: a smooth nonlinearity's
#: falls 10 (quadratic) or 100 (cubic) times; friction's (measured: 0.66, then 0.92), or an integrator's error
#: (5e-3, then 1e-2), does not fall.
FALLING = 2.0

#: Outputs whose response to the larger pulse stays below this share of their own largest magnitude are not judged:
#: the pulse hardly reaches them, and what is left is round-off (or the integrator's tolerance) of that magnitude.
NEGLIGIBLE_RESPONSE = 1e-9

_LAST_PILOT: contextvars.ContextVar[dict[str, Any] | None] = contextvars.ContextVar("last_pilot", default=None)


@contextlib.contextmanager
def watching_pilots() -> Iterator[dict[str, Any]]:
    """Within this context the automatic window's pilot runs are watched: the dict yielded holds the last one's
    ``signal``, grid ``t`` and outputs ``y`` (:func:`note_pilot`), which the amplitude check reuses."""
    token = _LAST_PILOT.set({})
    try:
        yield _LAST_PILOT.get()
    finally:
        _LAST_PILOT.reset(token)


def note_pilot(signal: Any, t: np.ndarray, y: np.ndarray) -> None:
    """Keep a pilot run's ``signal``, grid ``t`` and outputs ``y`` where :func:`watching_pilots` watches (the last
    one replaces the one before)."""
    kept = _LAST_PILOT.get()
    if kept is not None:
        kept.update(signal=signal, t=t, y=y)


class Scaled(Signal):
    """``signal`` with its departure from the held inputs ``held`` scaled by ``factor``: the same pulse, on top of
    the same held values, at ``factor`` times its amplitude."""

    def __init__(self, signal: Any, held: np.ndarray, factor: float) -> None:
        self.base, self.factor = signal, float(factor)
        self.held = np.asarray(held, dtype=float).reshape(-1, 1)
        self.n_inputs = int(getattr(signal, "n_inputs", self.held.shape[0]))
        self.spec = f"{getattr(signal, 'spec', repr(signal))} scaled by {self.factor:g}"
        self.t_range = getattr(signal, "t_range", (-np.inf, np.inf))

    def _values(self, t: np.ndarray) -> np.ndarray:
        values = np.atleast_2d(np.asarray(self.base.sample(t), dtype=float))
        return self.held + self.factor * (values - self.held)


@dataclasses.dataclass
class Reference:
    """A run of the default training's pulse already made: its ``signal`` (on top of the held inputs ``held``) on
    the grid ``t``, its outputs ``y`` and the outputs ``free`` of the model without the pulse on that grid (one
    column where the model rests).  ``label`` names the runs on the progress bar; ``exact``: recorded at the
    check's accuracy rather than the pilots' (:func:`accurate`)."""

    signal: Any
    held: np.ndarray
    t: np.ndarray
    y: np.ndarray
    free: np.ndarray
    label: str = "amplitude check"
    exact: bool = False


def mismatch(big: np.ndarray, small: np.ndarray, free: np.ndarray, ratio: float) -> float:
    """How far the response ``big`` to a pulse is from ``ratio`` times the response ``small`` to the same pulse
    ``ratio`` times smaller, both net of the response ``free`` without the pulse: the largest over the outputs of
    ``max |net_big - ratio net_small| / max |net_big|`` (0 for a linear model, up to round-off).  Outputs the pulse
    hardly reaches (:data:`NEGLIGIBLE_RESPONSE`) are not judged."""
    net_big, net_small = big - free, small - free
    size = np.abs(net_big).max(axis=1)
    judged = size > NEGLIGIBLE_RESPONSE * np.maximum(np.abs(big).max(axis=1), np.abs(free).max(axis=1))
    if not np.any(judged):
        return 0.0
    off = np.abs(net_big - ratio * net_small).max(axis=1)
    return float((off[judged] / size[judged]).max())


def linear_amplitudes(source: Source, reference: Reference, amplitudes: Sequence[float],
                      quiet: bool, isolate: bool, moving: bool = False) -> list[float] | None:
    """The default training's ``amplitudes`` lowered by decades (:data:`DECADE`) to the first at which the response
    scales with the amplitude (:func:`mismatch` at most :data:`LINEARITY_BAR` against the next decade down), said
    in one line; None where the response at ``amplitudes`` scales already (one run: the reference's pulse at a
    tenth), or where it does not at the default and either no amplitude down to :data:`LOWEST_SHARE` of it does or
    the mismatch does not fall as the amplitude does (:data:`FALLING`): then a warning says so, kept in the file.

    The smaller pulse pushes the other way where the inputs' declared ranges allow (:func:`_opposite`): a model
    whose response is positively homogeneous but not odd (a contact at its rest position, which one sign never
    reaches) then fails the check too, and a linear model's response to ``-a`` is still ``-1`` times that to ``a``.

    Where the source integrates to a tolerance (:func:`integrated_to_tolerance`) and the two differ by more than
    :data:`LINEARITY_BAR`, both are recorded again at :data:`CHECK_TOLERANCE` or the recording's, the tighter
    (:func:`accurate`; the model ``moving`` on its own: its run without the pulse too) and judged from there: a
    linear model costs that only where the pilots' error exceeds the bar."""
    from ._notes import warn_recording

    sign = -1.0 if _opposite(source, amplitudes) else 1.0
    small = _run_scaled(source, reference, sign / DECADE, quiet, isolate)
    if mismatch(reference.y, small, reference.free, 1.0 / (sign / DECADE)) <= LINEARITY_BAR:
        return None
    measured, factor = _scaling_factor(source, reference, sign, small, moving, quiet, isolate)
    if factor is None:
        warn_recording(_not_linear(source, amplitudes, measured, sign), "nonlinear", stacklevel=4)
        return None
    if len(measured) == 1:
        return None
    lowered = [float(f"{amplitude * abs(factor):.3g}") for amplitude in amplitudes]
    if not quiet:
        print(_lowered_line(source, amplitudes, lowered, measured, sign), file=sys.stderr)
    return lowered


def _scaling_factor(source: Source, reference: Reference, sign: float, small: np.ndarray | None, moving: bool,
                    quiet: bool, isolate: bool) -> tuple[list[float], float | None]:
    """The mismatch measured at each decade tried (the reference's amplitude first) and the factor of the
    reference's amplitude at which the response scales (:data:`LINEARITY_BAR` at the first decade,
    :data:`LOWERED_BAR` below it), None where none down to :data:`LOWEST_SHARE` does or the mismatch stops falling
    (:data:`FALLING`).  ``small``: the reference's pulse at ``sign`` times a tenth, already run at the reference's
    accuracy; where the source integrates to a tolerance it is all recorded again at the check's (:func:`accurate`)
    first, so that a linear model at a loose tolerance is judged on the model and not on its integration error."""
    if not reference.exact and integrated_to_tolerance(source):
        reference, small = accurate(source, reference, moving, quiet, isolate), None
    big, big_factor, measured = reference.y, 1.0, []
    while True:
        small_factor = sign * big_factor / DECADE
        if small is None:
            small = _run_scaled(source, reference, small_factor, quiet, isolate)
        measured.append(mismatch(big, small, reference.free, big_factor / small_factor))
        if measured[-1] <= (LINEARITY_BAR if len(measured) == 1 else LOWERED_BAR):
            return measured, big_factor
        falling = len(measured) == 1 or measured[-1] <= measured[-2] / FALLING
        if not falling or abs(small_factor) < LOWEST_SHARE * (1.0 - 1e-9):
            # (at the noise of the runs, this decade scales well enough)
            return measured, (big_factor if measured[-1] <= LINEARITY_BAR else None)
        big, big_factor, small = small, small_factor, None


def _opposite(source: Source, amplitudes: Sequence[float]) -> bool:
    """Whether every input's declared range allows the pulse a tenth as large the other way from its held value."""
    from ._default_training import _within_range

    return all(_within_range(source, i, -amplitude / DECADE) == -amplitude / DECADE
               for i, amplitude in enumerate(amplitudes))


#: Relative tolerance of the check's runs where the first comparison failed on a source that integrates to a
#: tolerance (:func:`accurate`).  Audit 80 F1: linear model-exchange chains moving on their own (off rest under
#: gravity; a chain sagging 1150 m, 120 times the pulse's effect) measured 0.016 .. 4.1 at the pilots' 1e-6 or a
#: given --tolerance 1e-4 .. 1e-5 with BDF or LSODA, and were called not linear.
CHECK_TOLERANCE = 1e-9


def integrated_to_tolerance(source: Source) -> bool:
    """Whether the source's runs carry an integrator's error set by a tolerance: a model-exchange FMU with a
    tolerance-driven integrator (not the exact zero-order-hold step the last run took, if it did), or a
    co-simulation FMU (its own integrator takes the tolerance given at its setup).  That error scales with the
    outputs' size, not with the pulse: on a 3-mass chain sagging to 3.7e4 m under its load, the pulse at 1e-6 and a
    tenth of it the other way differed by 0.2 of the pulse's effect, then 0.4 a decade lower (a linear model)."""
    from ..sources import FMUSource
    from ..sources._model_exchange import ModelExchangeSource

    if isinstance(source, ModelExchangeSource):
        return source.run_report().get("integrator_method") != "linear"   # (the exact step has no tolerance)
    return isinstance(source, FMUSource)


def accurate(source: Source, reference: Reference, moving: bool, quiet: bool, isolate: bool) -> Reference:
    """``reference`` recorded again at :data:`CHECK_TOLERANCE` or the recording's tolerance, the tighter
    (:func:`integrated_to_tolerance`): its pulse, and the run without it where the model ``moving`` moves on its own,
    so that the check compares the model, not the integration error of the pilots or of a loose ``--tolerance``."""
    y = _outputs(source, reference.signal, reference.t, quiet, isolate, f"{reference.label} (the pulse)")
    free = (_outputs(source, Scaled(reference.signal, reference.held, 0.0), reference.t, quiet, isolate,
                     f"{reference.label} (no pulse)") if moving else y[:, :1])
    return dataclasses.replace(reference, y=y, free=free, exact=True)


def _run_scaled(source: Source, reference: Reference, factor: float, quiet: bool, isolate: bool) -> np.ndarray:
    """The outputs of the reference's pulse at ``factor`` times its amplitude on the reference's grid, at the
    accuracy the reference was recorded at (the pilots', or the recording's: :func:`accurate`)."""
    signal = Scaled(reference.signal, reference.held, factor)
    label = f"{reference.label} (pulse x {factor:g})"
    if reference.exact:
        return _outputs(source, signal, reference.t, quiet, isolate, label)
    from ._window import _outputs_of

    return _outputs_of(source, signal, reference.t, quiet, isolate, label)


def _outputs(source: Source, signal: Any, t: np.ndarray, quiet: bool, isolate: bool, label: str) -> np.ndarray:
    """The outputs of a complete run of ``signal`` on the grid ``t`` at :func:`accurate`'s accuracy (a failure raises,
    as a pilot's does; the model's events are not said, the recording says them)."""
    from ._run import incomplete_error, record_run, MemorySink

    with source.checked_accuracy(CHECK_TOLERANCE):
        run, failure = record_run(source, signal, t, MemorySink, quiet, isolate, label, say_events=False)
    if failure is not None:
        raise incomplete_error(failure, run, None)
    return np.asarray(run.y)[:, :len(t)]


def _amplitudes_said(source: Source, amplitudes: Sequence[float]) -> str:
    """``amplitudes`` with the input each drives (``"0.1 on F"``)."""
    return ", ".join(f"{amplitude:g} on {name}" for amplitude, name in zip(amplitudes, source.input_names))


def _compared(source: Source, amplitudes: Sequence[float], sign: float) -> str:
    """What the check compares at the default ``amplitudes``, the smaller pulse ``sign`` times a tenth of them."""
    smaller = [sign * amplitude / DECADE for amplitude in amplitudes]
    return (f"the response to the default {_amplitudes_said(source, amplitudes)} and {sign * DECADE:g} times the "
            f"response to {_amplitudes_said(source, smaller)} (net of the model's own motion; a linear model's agree "
            "to round-off)")


def _lowered_line(source: Source, amplitudes: Sequence[float], lowered: Sequence[float], measured: Sequence[float],
                  sign: float) -> str:
    """The line said where the training amplitude is lowered (:func:`linear_amplitudes`)."""
    return (f"training amplitude {_amplitudes_said(source, lowered)}: {_compared(source, amplitudes, sign)} differ "
            f"by {measured[0]:.2g}: the model is linear only near its start; recording at the largest amplitude, in "
            f"decades down, whose response scales (to {measured[-1]:.2g}); give {either('--input')} "
            "impulse:amplitude=... to choose another")


def _not_linear(source: Source, amplitudes: Sequence[float], measured: Sequence[float], sign: float) -> str:
    """The warning where the response does not scale at the default amplitudes and no lower decade cures it
    (:func:`linear_amplitudes`); ``measured``: the mismatch at each decade tried, the default's first."""
    from ._isolation import source_label

    lower = f", and by {', '.join(f'{m:.2g}' for m in measured[1:])} a decade lower each" if measured[1:] else ""
    return (f"{source_label(source)}: the response does not scale with the input: "
            f"{_compared(source, amplitudes, sign)} differ by {measured[0]:.2g}{lower} (friction, a contact at the "
            "rest position, or a saturation below the smallest pulse tried): the model is not linear, and a ROM fits "
            f"it only near one amplitude; recording at the default amplitude (give {either('--input')} "
            "impulse:amplitude=... at the loads you mean)")


def input_departures(source: Source, signal: Any, t: np.ndarray) -> np.ndarray:
    """How far ``signal`` drives each input from the value the recordings hold it at (its start value,
    :func:`~._inputs.held_starts`) on the grid ``t``: ``(m,)``, the largest ``|u - held|`` per input."""
    from ._rates import inputs_in_effect
    from ._inputs import held_starts

    if not source.m:
        return np.zeros(0)
    u = inputs_in_effect(signal, t, source.m)
    return np.abs(u - held_starts(source)[:, None]).max(axis=1, initial=0.0)


def largest_runs(departures: Sequence[np.ndarray]) -> list[int]:
    """The runs (indices into ``departures``, each :func:`input_departures`) that the check of given inputs
    judges: on each input, the first run that drives it furthest.  A run no larger than another on every input
    drives the model less far and costs no run of its own (an amplitude sweep: its largest run alone; one run per
    input: each of them): a smooth nonlinearity (a hardening spring, a pendulum, an end stop) weighs most at the
    largest input; friction or a dead zone, which weigh most at small inputs, are found as far as the largest run
    shows them."""
    chosen: set[int] = set()
    if not departures:
        return []
    sizes = np.vstack([np.asarray(d, dtype=float).reshape(-1) for d in departures])
    for column in sizes.T:
        if column.size and column.max() > 0:
            chosen.add(int(np.argmax(column)))
    return sorted(chosen)


def check_given_input(source: Source, signal: Any, t: np.ndarray, y: np.ndarray, free: np.ndarray | None,
                      quiet: bool, isolate: bool, given: bool = True) -> None:
    """Warn where the response recorded (outputs ``y`` of ``signal`` on the grid ``t``) does not scale with its
    input, which stays as given (the user chose it: it is not lowered).

    One run of the same input, its departure from the inputs' start values scaled by -1/10 (:data:`DECADE`; +1/10
    where the inputs' declared ranges do not allow the other way), at the recording's accuracy: a linear model
    resting under its start inputs matches -10 times it to round-off (:func:`mismatch`, :data:`LINEARITY_BAR`).
    Where it does not, the model's own motion is taken out: ``free`` (a run of the recording without any input
    departure, on the same grid), else one run with the inputs held.  Where it still does not, on a source
    integrating to a tolerance, the runs are made again at :data:`CHECK_TOLERANCE` (:func:`accurate`: a linear
    ME/CS FMU moving on its own at a loose tolerance is no false alarm), then the input is scaled down by decades
    to the first factor at which the response scales (one run each, down to :data:`LOWEST_SHARE`), and the
    ``nonlinear`` recording warning names the input, the figures and that factor (kept in the file: ``fit``,
    ``compare`` and ``export`` repeat it).  A run of the check that fails says nothing: the recording stands.
    ``given``: the user chose the input (else it is the default training's, on a grid given without pilots or
    raised for the model's own motion, where the default training's own check did not run), said so."""
    from ._notes import warn_recording
    from ._window import largest_motion

    held = _held(source)
    departure = np.atleast_2d(np.asarray(signal.sample(t), dtype=float)) - held[:, None]
    sign = -1.0 if _within_ranges(source, held, -departure / DECADE) else 1.0
    exact = not integrated_to_tolerance(source)
    label = "the input's linearity check"
    small = _recorded_outputs(source, Scaled(signal, held, sign / DECADE), t, quiet, isolate,
                              f"{label} (input x {sign / DECADE:g})")
    rest = y[:, :1] if free is None else free
    if mismatch(y, small, rest, sign * DECADE) <= LINEARITY_BAR:
        return
    if free is None:
        free = _recorded_outputs(source, Scaled(signal, held, 0.0), t, quiet, isolate, f"{label} (no input)")
        if mismatch(y, small, free, sign * DECADE) <= LINEARITY_BAR:
            return
    moving = largest_motion(source, t, free) is not None
    reference = Reference(signal, held, t, y, free if moving else y[:, :1], label, exact)
    measured, factor = _scaling_factor(source, reference, sign, small, moving, quiet, isolate)
    if factor is not None and len(measured) == 1:
        return   # (the two differed by the integrator's error at the recording's tolerance: a linear model)
    warn_recording(_given_not_linear(source, signal, held, measured, factor, sign, given), "nonlinear",
                   stacklevel=3)


def _held(source: Source) -> np.ndarray:
    """The inputs' start values as the recordings hold them (:func:`~._inputs.held_starts`)."""
    from ._inputs import held_starts

    return held_starts(source)


def _within_ranges(source: Source, held: np.ndarray, departure: np.ndarray) -> bool:
    """Whether ``held + departure`` stays within every input's declared range at every sample."""
    low, high = (np.asarray(bound, dtype=float).reshape(-1, 1) for bound in source.input_ranges())
    values = held[:, None] + departure
    return bool(np.all((values >= low) & (values <= high)))


def _recorded_outputs(source: Source, signal: Any, t: np.ndarray, quiet: bool, isolate: bool,
                      label: str) -> np.ndarray:
    """The outputs of a complete run of ``signal`` on the grid ``t`` at the recording's accuracy (a failure raises;
    the model's events are not said, the recording says them)."""
    from ._run import incomplete_error, record_run, MemorySink

    run, failure = record_run(source, signal, t, MemorySink, quiet, isolate, label, say_events=False)
    if failure is not None:
        raise incomplete_error(failure, run, None)
    return np.asarray(run.y)[:, :len(t)]


def _scaled_spec(signal: Any, held: np.ndarray, factor: float) -> str | None:
    """The specification of ``signal`` at ``factor`` times its amplitude, where it can be written as one: every
    part a parametric signal without an offset (or ``none``), on inputs held at 0; else None."""
    from ..signals import NoInput, ParametricSignal, StackedSignal, _Broadcast, _make

    base = signal.base if isinstance(signal, _Broadcast) else signal
    parts = base.parts if isinstance(base, StackedSignal) else [base]
    if np.any(held != 0.0) or not all(isinstance(p, NoInput) or (isinstance(p, ParametricSignal)
                                      and not p.params.get("offset", 0.0)) for p in parts):
        return None
    specs = []
    for part in parts:
        if isinstance(part, NoInput):
            specs.append("none")
            continue
        amplitude = float(f"{part.params['amplitude'] * factor:.3g}")
        specs.append(_make(part.kind, **{**part.params, "amplitude": amplitude}).spec)
    return ";".join(specs)


def _given_not_linear(source: Source, signal: Any, held: np.ndarray, measured: Sequence[float],
                      factor: float | None, sign: float, given: bool = True) -> str:
    """The warning where the response to a given input does not scale with it (:func:`check_given_input`);
    ``given``: the user's input (else the default training's)."""
    from ._isolation import source_label

    spec = getattr(signal, "spec", repr(signal))
    what = "the input" if given else "the default training input"
    recorded = ("recorded as given" if given else "recorded at the default training's amplitude (not lowered where "
                "the grid is given or the pulse was raised for the model's own motion)")
    head = (f"{source_label(source)}: the response to {what} {spec} does not scale with it: it and "
            f"{sign * DECADE:g} times the response to the same input scaled by {sign / DECADE:g} (net of the model's "
            f"own motion; a linear model's agree to round-off) differ by {measured[0]:.2g}")
    if factor is None:
        lower = f", and by {', '.join(f'{m:.2g}' for m in measured[1:])} a decade lower each" if measured[1:] else ""
        return (f"{head}{lower} (friction, a contact at the rest position, or a saturation below the smallest input "
                f"tried): the model is not linear, and a ROM fits it only near this amplitude; {recorded} (give "
                f"{either('--input')} at the loads the ROM is meant for)")
    smaller = _scaled_spec(signal, held, abs(factor))
    example = f", e.g. '{smaller}'" if smaller else ""
    return (f"{head}: the model is linear only near its start, and a ROM fitted to this recording fits that large "
            f"response, not the model near its start; the response scales at {abs(factor):.3g} times this input "
            f"(to {measured[-1]:.2g}): {recorded}; give a smaller input{example}")
