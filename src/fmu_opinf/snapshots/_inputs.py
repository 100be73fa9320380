"""What drives the runs: signals from the user's specifications, and the default training's inputs.

:func:`as_signal` turns a specification into a signal (``none``: :class:`HeldInputs`, every input held at the value
:func:`held_starts` gives); :func:`default_training_inputs` gives the runs recorded without ``--input`` (one per
input, the impulse :data:`DEFAULT_TRAINING_INPUT` at the amplitude :func:`default_amplitudes` sizes from what the
inputs declare) and the words the recording says about them; :func:`check_input_acts`, :func:`check_table_times` and
:func:`input_table_end` check given inputs against the grid; :func:`runs_by_inputs_driven` picks the runs whose
inputs the automatic window's pilots follow.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._validate import either
from ..errors import InputSpecError
from ..signals import NoInput, StackedSignal, parse_signal, pulse_amplitude
from ..sources import Source

__all__ = ["DEFAULT_TRAINING_INPUT", "HeldInputs", "is_free_response", "as_signal", "default_training_inputs",
           "default_amplitudes", "held_starts", "input_table_end", "check_table_times", "runs_by_inputs_driven",
           "check_input_acts"]


#: Training input when none is given for a model with inputs: the paper's impulse-like pulse (the one of
#: the demo): a raised cosine of 100 (force units) centred at t=2, 0.5 time units wide; its amplitude on each
#: input is the one :func:`default_amplitudes` gives (a declared nominal or range sizes it).
DEFAULT_TRAINING_INPUT = "impulse:amplitude=100,t0=2,width=0.5"


class HeldInputs(NoInput):
    """``--input none``: the free response, every force input held at its start (or ``--set``) value.

    With no force inputs (m = 0) it has no channel at all.
    """

    def __init__(self, values: Any) -> None:
        values = np.asarray(values, dtype=float).reshape(-1)
        super().__init__(values.size, values)

    def __repr__(self) -> str:
        return "HeldInputs(" + ", ".join(f"{v:g}" for v in self.values) + ")"


def is_free_response(spec: Any) -> bool:
    """True for the input specification ``none`` (or a :class:`HeldInputs`)."""
    return isinstance(spec, HeldInputs) or (isinstance(spec, str) and spec.strip().lower() == "none")


def as_signal(signal: Any, m: int | None = None, source: Source | None = None) -> Any:
    """A signal object from a spec (one spec drives every one of the ``m`` inputs) or as is.

    ``"none"`` holds every input at the source's start values (zeros without a source).
    """
    if is_free_response(signal) and isinstance(signal, str):
        starts = held_starts(source) if source is not None else np.zeros(m or 0)
        return HeldInputs(starts)
    if isinstance(signal, str):
        from ..signals import parse_signal

        names = source.input_names if source is not None and len(source.input_names) == m else None
        held = getattr(source, "held_input_names", ()) if names is not None else ()
        parsed = parse_signal(signal, m, names, held) if m else parse_signal(signal)
        return _undriven_held(parsed, source) if source is not None else parsed
    if not hasattr(signal, "sample"):
        raise InputSpecError(f"input {signal!r} is neither a signal nor a signal specification")
    return signal


def default_training_inputs(m: int, impulse: str = DEFAULT_TRAINING_INPUT,
                            amplitudes: Sequence[float] | None = None,
                            starts: Sequence[float] | None = None) -> list[str]:
    """The training runs recorded without ``--input``: the free response for a model without inputs, else one
    run per input, each driving that input alone with ``impulse`` (default :data:`DEFAULT_TRAINING_INPUT`;
    ``none`` on the others, which holds them at their start values), at ``amplitudes[i]`` on input ``i`` where
    given (:func:`default_amplitudes`), on top of its start value ``starts[i]`` where that is not 0.

    One impulse on every input at once would make the inputs indistinguishable in the data: the fitted ``Br``
    then has equal columns (audit 2026-11-26: eight inputs, max eps_y 9.1 on independent test inputs).  The pulse
    sits on the input's start value, the operating point of the model as exported: a preloaded model that starts
    at its equilibrium under that load (or is initialized there, Modelica's steady state) starts at rest, as it
    does for the ROM FMU, whose inputs start at the same values (seventh audit, E3: trained from 0, the ROM FMU
    oscillated by 190 % of the static deflection where the source stayed at rest).
    """
    if m == 0:
        return ["none"]
    pulses = [impulse if amplitudes is None else _with_amplitude(impulse, amplitudes[i]) for i in range(m)]
    if starts is not None:
        pulses = [_on_start(pulse, start) for pulse, start in zip(pulses, starts)]
    return [";".join(pulses[i] if j == i else "none" for j in range(m)) for i in range(m)]


def _on_start(pulse: str, start: float) -> str:
    """``pulse`` on top of an input's start value (as it is where that is 0)."""
    return pulse if start == 0 else parse_signal(f"{pulse},offset={float(start)!r}").spec


def _with_amplitude(impulse: str, amplitude: float) -> str:
    return re.sub(r"amplitude=[^,]*", f"amplitude={amplitude:g}", impulse)


#: Amplitude of :data:`DEFAULT_TRAINING_INPUT`.
_DEFAULT_AMPLITUDE = float(parse_signal(DEFAULT_TRAINING_INPUT).params["amplitude"])


def default_amplitudes(source: Source) -> list[float]:
    """The default impulse's amplitude on each input (:func:`_unbounded_amplitudes`), lowered where the input
    declares a ``max`` below it (a Dymola FMU refuses a value outside ``[min, max]``: the seventh audit's force
    input with ``max=50`` stopped the default recording at its first pulse).  The training runs and the window's
    pilots add the pulse to the input's undriven value (:func:`held_starts`, within the range), so the room upwards
    is ``max`` minus that value and the room downwards that value minus ``min``.  An input with no room upwards
    but room downwards gets a negative pulse, within its ``min``: one held at its ``max`` (its start lay above the
    range) is pulsed down into the range (audit 63, finding 2: the rooms were measured from 0 where the value lay
    on the other side of it, so from a held 30 in [5, 30] none was seen downwards and the pulse of +100 failed)."""
    low, high = source.input_ranges()
    starts = held_starts(source)
    up, down = high - starts, starts - low
    # an input with no room upwards but room downwards (a cable that only pulls, max = 0) is pulsed downwards
    # (tenth audit: the default pulse of +100 was refused at once)
    return [-pulse_amplitude(float(d), a) if u <= 0 < d else pulse_amplitude(float(u), a)
            for u, d, a in zip(up, down, _unbounded_amplitudes(source))]


#: The default pulse on a pressure that starts away from 0, as a share of its start.
PRESSURE_PULSE_SHARE = 0.1

#: The default pulse on an input that declares a finite ``[min, max]`` and no nominal, as a share of the range's
#: width, where that share is above the default amplitude (a narrower range keeps the default, lowered to fit).
RANGE_PULSE_SHARE = 0.1

#: A declared bound beyond this magnitude is an unbounded range written out (``1e60``, ``DBL_MAX``), never a size
#: to pulse by (it still bounds the pulse).
PLACEHOLDER_BOUND = 1e15


def _unbounded_amplitudes(source: Source) -> list[float]:
    """The default impulse's amplitude on each input before its declared range is heeded (:func:`_sized_amplitudes`)."""
    return [amplitude for amplitude, _ in _sized_amplitudes(source)]


def _sized_amplitudes(source: Source) -> list[tuple[float, str]]:
    """The default impulse's amplitude on each input before its declared range caps it, and what sized it:

    * ``"pressure"``: :data:`PRESSURE_PULSE_SHARE` of the start (three digits) for an input in a pressure's unit
      that starts away from 0.  A pressure driven about an ambient or a working pressure was pulsed by 100 whatever
      its unit: from 1 to 101 bar, or by 0.1 % of 101325 Pa (audit 61, finding 3);
    * ``"nominal"``: the input's declared ``nominal`` (FMI 2 ``Real``, FMI 3 ``Float64`` / ``Float32``; its own or
      its declared type's), the size the exporter gives its values.  A nominal of exactly 1 is FMI's default
      written out and sizes nothing.  A force declared ``nominal="1e5"`` on a heavy structure under gravity was
      pulsed by 100 N, a response 3e-4 of the gravity swing, and the ROM was 3-8 times the output range off at
      loads of 1e5 N (audit 73, F1);
    * ``"range"``: :data:`RANGE_PULSE_SHARE` of the width of a finite declared ``[min, max]`` (three digits) where
      no nominal is declared and that is above 100: a range far wider than the default says the input takes loads
      far above it; a narrower one keeps the default, lowered to fit (:func:`default_amplitudes`).  Bounds beyond
      :data:`PLACEHOLDER_BOUND` are no size;
    * ``"default"``: 100 in the input's own unit (:data:`DEFAULT_TRAINING_INPUT`).
    """
    from ..sources._variables import is_pressure_about_start

    starts = held_starts(source)
    units = list(getattr(source, "input_units", None) or [])
    model = getattr(source, "model", None)
    nominals, widths = _declared_nominals(source, len(starts)), _range_widths(source, len(starts))
    out: list[tuple[float, str]] = []
    for i, start in enumerate(starts):
        if len(units) == len(starts) and is_pressure_about_start(units[i], start, model):
            out.append((float(f"{PRESSURE_PULSE_SHARE * abs(start):.3g}"), "pressure"))
        elif math.isfinite(nominals[i]) and nominals[i] != 1.0:
            out.append((float(f"{nominals[i]:g}"), "nominal"))
        elif RANGE_PULSE_SHARE * widths[i] > _DEFAULT_AMPLITUDE:
            out.append((float(f"{RANGE_PULSE_SHARE * widths[i]:.3g}"), "range"))
        else:
            out.append((_DEFAULT_AMPLITUDE, "default"))
    return out


def _declared_nominals(source: Source, m: int) -> np.ndarray:
    """The inputs' declared nominals (``Source.input_nominals``), NaN where none is declared or known (a
    duck-typed source of the API that declares none)."""
    nominals = np.asarray(getattr(source, "input_nominals", lambda: np.full(m, np.nan))(), dtype=float)
    return nominals if nominals.shape == (m,) else np.full(m, np.nan)


def _range_widths(source: Source, m: int) -> np.ndarray:
    """The widths of the inputs' declared ranges, 0 where a bound is missing, beyond :data:`PLACEHOLDER_BOUND` or
    the range is crossed."""
    if not hasattr(source, "input_ranges"):
        return np.zeros(m)
    low, high = (np.asarray(bound, dtype=float) for bound in source.input_ranges())
    if low.shape != (m,) or high.shape != (m,):
        return np.zeros(m)
    sized = (np.abs(low) < PLACEHOLDER_BOUND) & (np.abs(high) < PLACEHOLDER_BOUND) & (low < high)
    return np.where(sized, high - low, 0.0)


def _on_start_values(source: Source) -> str:
    """What the default training says about inputs whose pulse sits on a non-zero start value, and about starts
    moved into the declared range (:func:`held_starts`); "" if none."""
    held, declared = held_starts(source), np.asarray(source.input_starts(), dtype=float)
    starts = [f"{name}={value:g}" for name, value in zip(source.input_names, held) if value != 0]
    text = f" on top of the start value{'s' if len(starts) > 1 else ''} {', '.join(starts)}" if starts else ""
    low, high = source.input_ranges()
    moved = [f"{name} from its declared start {start:g} to {value:g}, the nearest bound of its range [{lo:g}, {hi:g}]"
             for name, start, value, lo, hi in zip(source.input_names, declared, held, low, high) if value != start]
    return text + (f" (moved into the declared range: {'; '.join(moved)})" if moved else "")


def held_starts(source: Source) -> np.ndarray:
    """The values the recordings hold the inputs at where they do not drive them, and drive them about: their
    start (or ``--set``) values, each moved to the nearest bound of its declared ``[min, max]`` where it lies
    outside.  A source whose start lies outside its own range (not FMI-conformant, but seen) refuses that start
    at step 0: the default training pulse from it failed, and the example in its error started there again
    (audit 60, finding 8: F1 in [5, 30] with start 0)."""
    starts = np.asarray(source.input_starts(), dtype=float)
    if not hasattr(source, "input_ranges"):   # a duck-typed source of the API that declares no ranges
        return starts
    low, high = (np.asarray(bound, dtype=float) for bound in source.input_ranges())
    if starts.shape != low.shape or starts.shape != high.shape:
        return starts
    ordered = low <= high   # (a crossed range bounds nothing)
    return np.where(ordered, np.clip(starts, np.where(ordered, low, -np.inf), np.where(ordered, high, np.inf)), starts)


def _impulse_said(amplitudes: Sequence[float]) -> str:
    """The default impulse as the line of the default training names it: :data:`DEFAULT_TRAINING_INPUT` where every
    input takes its amplitude, else the pulse's shape without one (each input's amplitude follows in brackets)."""
    if all(a == _DEFAULT_AMPLITUDE for a in amplitudes):
        return DEFAULT_TRAINING_INPUT
    return "the impulse " + ",".join(part for part in DEFAULT_TRAINING_INPUT.split(":", 1)[1].split(",")
                                     if not part.startswith("amplitude="))


def _lowered_amplitudes(source: Source, amplitudes: Sequence[float]) -> str:
    """What the default training says about amplitudes other than 100: changed to fit the inputs' declared ranges,
    or sized by a pressure's start, a declared nominal or a declared range (:func:`_sized_amplitudes`); "" if
    none.  Where the inputs declare different units, every amplitude is said with its unit, the default 100 too:
    100 kN beside 100 N, or 100 m of support travel, is not what a reader of "100" pictures (audit84 F5)."""
    why = {"lowered": "what its declared range allows", "pressure": "a tenth of its start, a pressure",
           "nominal": "its declared nominal", "range": "a tenth of its declared range's width",
           "default": "100 in the input's own unit"}
    units = _mixed_units(source)
    groups: dict[str, list[str]] = {key: [] for key in why}
    for name, amplitude, (sized, origin), unit in zip(source.input_names, amplitudes, _sized_amplitudes(source),
                                                      units or [""] * len(amplitudes)):
        said = f"{amplitude:g}{' ' + unit if unit else ''} on {name}"
        if amplitude != sized:
            groups["lowered"].append(said + (f" (its declared nominal {sized:g})" if origin == "nominal" else ""))
        elif origin != "default" or units:
            groups[origin].append(said)
    parts = [f"{', '.join(entries)}: {why[key]}" for key, entries in groups.items() if entries]
    return f" (amplitude {'; '.join(parts)})" if parts else ""


def _mixed_units(source: Source) -> list[str] | None:
    """The inputs' declared units where they differ from one input to another (printable), else None."""
    units = [str(unit or "") for unit in (getattr(source, "input_units", None) or [])]
    if len(units) != len(source.input_names) or len(set(units)) < 2:
        return None
    return ["".join(c for c in unit if c.isprintable()) for unit in units]


def _undriven_held(signal: Any, source: Source) -> Any:
    """``signal`` with every ``none`` among several ``;`` specs held at that input's start (or ``--set``) value,
    as ``--input none`` holds all of them, instead of zero."""
    if not isinstance(signal, StackedSignal) or not any(isinstance(p, NoInput) for p in signal.parts):
        return signal
    starts, parts, first = held_starts(source), [], 0
    if len(starts) != signal.n_inputs:
        return signal  # a channel count that does not fit: refused with its own message where it is used
    for part in signal.parts:
        held = isinstance(part, NoInput)
        parts.append(NoInput(part.n_inputs, starts[first:first + part.n_inputs]) if held else part)
        first += part.n_inputs
    return StackedSignal(parts)


def input_table_end(signals: Sequence[Any]) -> float | None:
    """The earliest last time of the input tables among ``signals`` (their ``t_range``), None where no signal
    ends: a table cannot be sampled beyond its last time, so that is the default end of a run driven by it and
    the latest time of any run with it (audit 70, F3: pilots to t = 550 on a table ending at 120)."""
    ends = [float(getattr(signal, "t_range", (0.0, math.inf))[1]) for signal in signals]
    ends = [end for end in ends if math.isfinite(end)]
    return min(ends) if ends else None


def check_table_times(signals: Sequence[Any], start_time: float) -> None:
    """Refuse an input table that does not start at t = 0, saying that table times count from the run's start
    (README, Inputs), and, for one that starts at the FMU's start time ``start_time``, by how much to shift it.

    A table written in the FMU's own time (a result export of a model with startTime 10, from 10 to 130) is not
    shifted silently: the same file would then mean other times beside another start (``--start-time``), and
    ``compare`` on the ROM, which counts from 0, would read it as given (audit 70, F3: it was refused with
    "defined on [10, 130] but the simulation needs [0, 10]")."""
    for signal in signals:
        low = float(getattr(signal, "t_range", (-math.inf, math.inf))[0])
        if not math.isfinite(low) or low <= 1e-9 * max(1.0, abs(low)):
            continue
        spec = getattr(signal, "spec", repr(signal))
        if start_time and abs(low - start_time) <= 1e-9 * max(1.0, abs(start_time)):
            raise InputSpecError(f"input {spec!r} starts at t={low:g}, the FMU's start time: table times count from "
                                 f"the run's start (t = 0 is FMU time {start_time:g}), not in FMU time; subtract "
                                 f"{start_time:g} from its time column")
        raise InputSpecError(f"input {spec!r} starts at t={low:g}: table times count from the run's start (t = 0"
                             + (f", FMU time {start_time:g}" if start_time else "") + "); give it from t = 0")


def runs_by_inputs_driven(signals: Sequence[Any]) -> list[Any]:
    """The first of the user's runs for each set of inputs that runs drive (the automatic window's pilots follow
    each of them, :func:`~fmu_opinf.snapshots._window.combine_windows`); a free response, or a run that drives no
    input, only when every run is.

    A mode that only a later run's input reaches sets the step too: ``--input "impulse;none" --input
    "none;impulse"`` on two oscillators of 1 and 10 rad/s, one per input, gave dt = 0.2 from the first run
    alone (3 samples per fast period), now 0.02; and a free response given first stopped the recording ('the
    outputs do not respond').  Runs that drive the same inputs (amplitude sweeps) share the first one's window,
    as before.
    """
    firsts: dict[Any, Any] = {}
    for signal in signals:
        driven = _inputs_driven(signal)
        if driven:
            firsts.setdefault(driven, signal)
    return list(firsts.values()) or [signals[0]]


def _inputs_driven(signal: Any) -> Any:
    """A key of the inputs ``signal`` drives: the indices of its channels that are not held (``none``), ``"all"``
    for one spec driving every input or a signal that cannot say, an empty tuple for a free response."""
    if isinstance(signal, NoInput):
        return ()
    base = getattr(signal, "base", signal)
    if not isinstance(base, StackedSignal):
        return "all"
    driven, first = [], 0
    for part in base.parts:
        count = getattr(part, "n_inputs", 1)
        if not isinstance(part, NoInput):
            driven.extend(range(first, first + count))
        first += count
    return tuple(driven)


def check_input_acts(signal: Any, t: np.ndarray) -> None:
    """Refuse a forcing that is zero at every sample of the grid ``t`` on some input it is meant to drive.

    The input is held over each step at its value at the step's start, so a pulse outside ``[t_0, t_end]`` or
    narrower than the step between two samples never reaches the FMU: the run would be a free response labelled
    as a forced one, and the fitted ``Br`` exactly zero (audit 2026-11-26: an FMU declaring ``stepSize=0.001,
    stopTime=1`` recorded with the default impulse at t = 2, compare then at max eps_y 1.07).  Channels given as
    ``none``, free responses and signals zero by construction (``amplitude=0``, an all-zero table: a user's
    deliberate choice) are not checked, nor signal objects that cannot say (no ``is_identically_zero``).
    """
    if isinstance(signal, NoInput) or not hasattr(signal, "sample") or t.size < 2:
        return
    acting = t[:-1]  # the value at t_i drives the step to t_(i+1): the last sample's never acts
    values, first = np.atleast_2d(np.asarray(signal.sample(acting), dtype=float)), 0
    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    for part in parts:
        count = getattr(part, "n_inputs", values.shape[0])  # any object with sample() is a signal
        rows = values[first:first + count]
        first += count
        meant_to_act = getattr(part, "is_identically_zero", lambda: None)() is False
        if meant_to_act and not isinstance(part, NoInput) and rows.size and not np.any(rows):
            step = t[1] - t[0] if t.size > 1 else 0.0
            raise InputSpecError(
                f"input {getattr(part, 'spec', repr(part))!r} is zero at every sample of the grid dt={step:g}, "
                f"t_end={t[-1]:g}: it acts "
                "outside the window or between two samples, so the FMU would never be driven; give "
                f"{either('--t-end')} past its active part and {either('--dt')} that resolves it, or scale the input "
                "(t0, width) to the model's time "
                "scale; no file was written")
