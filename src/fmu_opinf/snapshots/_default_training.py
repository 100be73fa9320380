"""The default training's window and pulse size, chosen from pilot runs.

``_default_training_window`` chooses the automatic window for the default impulse (``_impulse_window``: the
impulse widened or shrunk until it suits the model's time scale, judged net of the model's own motion where the
model moves without the pulse), raises the pulse where its effect is lost in that motion (``_raised_amplitudes``;
``_sized_on_grid`` on a grid chosen without pilots), lowers it where the response does not scale with it
(``_linear_amplitudes``) and adds a run without the pulse where the model moves on its own (``_with_free_run``).
Where no window can be found, one-line refusals say why (``_load_error``, ``_pushed_without_rest``).
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import DT_T_END, either
from ..errors import DataError, FmuOpinfError, FmuOpinfWarning
from ..signals import NoInput, Signal, StackedSignal, parse_signal, pulse_amplitude
from ..sources import Source, StepError
from ._inputs import (DEFAULT_TRAINING_INPUT, _DEFAULT_AMPLITUDE, _on_start, as_signal, default_amplitudes,
                      default_training_inputs, held_starts)
from ._isolation import source_label
from ._linearity import Reference, linear_amplitudes, watching_pilots
from ._rates import time_grid
from ._run import MemorySink, record_run

if TYPE_CHECKING:
    from ._window import Window

__all__ = ["RESCALE", "RESCALE_TRIES", "FREE_RUN_SHARE", "PULSE_EFFECT_SHARE", "RAISED_PULSE_SHARE", "LOAD_SAMPLES"]


#: Factor by which the default impulse (``t0`` and ``width``) shrinks or widens per try when it does not suit the
#: model's time scale, and how many tries each way: down to a millionth (2 us wide) or up a millionfold.
RESCALE, RESCALE_TRIES = 100.0, 3


def _default_training_window(source: Source, thresholds: dict[str, Any],
                             outcome: dict[str, Any] | None = None) -> tuple[Any, list[Any]]:
    """The window and signals of the default training (:func:`_impulse_window`), its pulse raised where its effect
    on the outputs is lost in the model's own motion (:func:`_raised_amplitudes`): the window is then chosen again
    for the raised pulse.  A model at rest (the first pilot tells, from its samples before the pulse) costs no extra
    run for that.  Where the pulse was not raised, its response must scale with its amplitude
    (:func:`_linear_amplitudes`, one run more): where it does not, the amplitudes are lowered by decades and the
    window chosen again for them (audit 79b, F1-F3).  ``outcome``, where given, receives ``checked``: whether that
    check ran (not where the pulse was raised: the recording's own check judges it then,
    :func:`_check_inputs_scale`)."""
    amplitudes = default_amplitudes(source)
    try:
        with watching_pilots() as pilot:
            window, signals, baseline = _impulse_window(source, thresholds, amplitudes)
    except StepError as error:
        raise _with_smaller_pulse_advice(error, source, amplitudes) from None
    if source.m == 0:
        return window, signals
    seen: dict[str, Any] = {}
    if baseline.may_move:
        raised = _raised_amplitudes(source, time_grid(window.dt, window.t_end), signals, amplitudes, thresholds, seen)
        if raised is not None:   # (sized by the model's own motion, not by the input's unit: not lowered again)
            window, signals, _ = _impulse_window(source, thresholds, raised)
            return window, _with_free_run(source, signals, seen, bool(thresholds.get("quiet", True)))
    if outcome is not None:
        outcome["checked"] = True
    lowered = _linear_amplitudes(source, window, pilot, seen, amplitudes, thresholds)
    if lowered is not None:
        window, signals, _ = _impulse_window(source, thresholds, lowered)
        if "motion_share" in seen:   # the pulse's effect is smaller by that factor
            seen["motion_share"] *= abs(amplitudes[0] / lowered[0])
    return window, _with_free_run(source, signals, seen, bool(thresholds.get("quiet", True)))


def _with_smaller_pulse_advice(error: StepError, source: Source, amplitudes: Sequence[float]) -> StepError:
    """A pilot of the default pulse that failed, with the cause its integrator cannot tell: a model linear only near
    rest, driven out of its range by the pulse of 100 in the input's unit, escapes (audit 80 F2: a softening spring;
    the advice named --dt and --t-end, then a looser tolerance, then the interface, and a smaller pulse recorded)."""
    if source.m == 0:
        return error
    text, tail = str(error), "; no file was written"
    head, end = (text[:-len(tail)], tail) if text.endswith(tail) else (text, "")
    smaller = DEFAULT_TRAINING_INPUT.replace("amplitude=100", f"amplitude={abs(amplitudes[0]) / 100:g}")
    said = ", ".join(f"{a:g}" for a in amplitudes)
    return StepError(f"{head}; if the model is linear only near rest, the default pulse (amplitude {said}) may "
                     f"drive it out of its range: give a smaller one, e.g. {either('--input', value=smaller)}{end}",
                     error.step,
                     error.time)


def _linear_amplitudes(source: Source, window: Any, pilot: dict[str, Any], seen: dict[str, Any],
                       amplitudes: Sequence[float], thresholds: dict[str, Any]) -> list[float] | None:
    """The default training's amplitudes lowered where the model's response does not scale with them
    (:func:`~._linearity.linear_amplitudes`), judged on a run already made: the last pilot where the model rests
    (its outputs without the pulse are those at its start), else the pulse's run of :func:`_raised_amplitudes`
    beside its run without the pulse (recorded again at the check's tolerance where the source integrates to one and
    their error fails the check, :func:`~._linearity.accurate`).  None where they stay, no such run is at hand, or a
    run of the check fails."""
    held = held_starts(source)
    if "reference" in seen:
        i, y = seen["reference"]
        reference = Reference(seen["signals"][i], held, seen["t"], y, seen["free"])
    elif pilot.get("y") is not None and pilot["y"].size:
        keep = pilot["t"] <= window.t_end * (1.0 + 1e-12)   # (a run is causal: its start is the shorter run's)
        t, y = pilot["t"][keep], pilot["y"][:, keep]
        reference = Reference(pilot["signal"], held, t, y, y[:, :1])
    else:
        return None
    quiet, isolate = bool(thresholds.get("quiet", True)), bool(thresholds.get("isolate", False))
    try:
        return linear_amplitudes(source, reference, amplitudes, quiet, isolate, moving="reference" in seen)
    except FmuOpinfError:   # a run of the check that fails says nothing: the amplitudes stay, as without it
        return None


#: The model's own motion (each output's range in a run without the pulse), as a share of the pulse's effect on the
#: outputs, above which the default training records that run beside the pulse's (:func:`_with_free_run`).  Audit
#: 77b, F2: a chain started off rest moved by 2.7-4.9 on its own where the 100 N pulse moved it by 587-966; trained
#: on the pulse alone, the ROM's start transient was 27-104 % of its range off (POD-Galerkin on its basis 21-34 %);
#: with the free run beside it, 8e-3 and 4e-13 (the order search raised r to 18 and 31).  Far below it the motion is
#: round-off or an integrator's drift at an equilibrium, and the training stays the pulse's alone.
FREE_RUN_SHARE = 1e-6


def _with_free_run(source: Source, signals: list[Any], seen: dict[str, Any], quiet: bool) -> list[Any]:
    """The default training ``signals`` and, where the model moves on its own from its start values by more than
    :data:`FREE_RUN_SHARE` of the pulse's effect (``seen``: what :func:`_raised_amplitudes` measured), a run without
    the pulse (every input held at its start value, ``none``): trained on the pulse alone, the fit weighs that motion
    by its size beside the pulse's response (1/200 .. 1/350 in audit 77b, F2) and the ROM's start transient is
    lost; as a run of its own, the order search judges it against its own variation.  Said in one line."""
    share = seen.get("motion_share")
    if share is None or not share > FREE_RUN_SHARE:
        return signals
    if not quiet:
        print(f"the outputs move without the pulse ({seen['motion']}, {share:.2g} of the pulse's effect): recording "
              "a run without it as well (inputs held at their start values), so that the fit learns the model's "
              "own motion from its start values", file=sys.stderr)
    return [*signals, as_signal("none", source.m, source)]


#: Below this share of the model's own motion (per output, its range over the window without the pulse) the default
#: pulse's effect on the outputs, net of that motion, is raised: a 100 N pulse moved a heavy chain under gravity by
#: 3e-4 of its 96 m swing, and the ROM was 35-90 % of range off at 1e4 N loads (audit 74, F1).
PULSE_EFFECT_SHARE = 1e-2

#: The share of the model's own motion the raised pulse's effect is sized to (a linear model's response scales with
#: the amplitude): the pulse then shapes the snapshots' basis beside the motion without dwarfing it.
RAISED_PULSE_SHARE = 0.1


def _raised_amplitudes(source: Source, t: np.ndarray, signals: Sequence[Any], amplitudes: Sequence[float],
                       thresholds: dict[str, Any], seen: dict[str, Any] | None = None) -> list[float] | None:
    """The default pulse's amplitudes raised, on each input whose pulse moves the outputs, net of the model's own motion
    (a run without the pulse on the recording's grid ``t``), by less than :data:`PULSE_EFFECT_SHARE` of that motion, to
    :data:`RAISED_PULSE_SHARE` of it, within the input's declared range; said in one line (a warning where the range
    allows no larger pulse).  None where no input is raised: the model rests (no run but the one without the pulse), or
    every pulse is seen.  ``seen``, where given, receives where the model moves ``motion`` (:func:`largest_motion`)
    and ``motion_share``, its largest range over the outputs as a share of the largest effect of a pulse on them."""
    from ._window import _outputs_of, largest_motion

    quiet, isolate = bool(thresholds.get("quiet", True)), bool(thresholds.get("isolate", False))
    free = _outputs_of(source, _held_only(source), t, True, isolate, "the run without the pulse")
    moving = largest_motion(source, t, free)
    if moving is None:
        return None   # at rest: the pulse is all there is
    motion = np.ptp(free, axis=1)
    raised, said, effect, strongest = list(amplitudes), [], 0.0, None
    for i, signal in enumerate(signals):
        y = _outputs_of(source, signal, t, True, isolate, "a pilot of the default pulse")
        net = y - free
        if strongest is None or float(np.abs(net).max(initial=0.0)) > effect:
            strongest = (i, y)   # (the amplitude check's reference: :func:`_linear_amplitudes`)
        effect = max(effect, float(np.abs(net).max(initial=0.0)))
        share = _effect_share(net, motion)
        if not share < PULSE_EFFECT_SHARE:
            continue
        wanted = float(f"{amplitudes[i] * RAISED_PULSE_SHARE / max(share, 1e-300):.2g}")
        raised[i] = _within_range(source, i, wanted)
        said.append(_raised_phrase(source.input_names[i], amplitudes[i], raised[i], wanted, share))
    if seen is not None:
        seen.update(motion=moving, motion_share=float(motion.max()) / effect if effect > 0 else math.inf)
        seen.update(t=t, free=free, signals=list(signals), reference=strongest)
    if not said:
        return None
    _say_raised(source, said, any(a != b for a, b in zip(raised, amplitudes)), quiet)
    return raised if raised != list(amplitudes) else None


def _sized_on_grid(source: Source, signals: list[Any], t: np.ndarray, quiet: bool, isolate: bool) -> list[Any]:
    """The default training's ``signals`` on a grid ``t`` chosen without pilots (``--dt`` and ``--t-end``, the
    FMU's declared experiment), their pulses raised as :func:`_raised_amplitudes` raises them where the model moves
    on its own.  Whether it moves is told by a run without the pulse up to the pulse (or over ``t`` where fewer
    than two samples precede it): a model at rest costs that short run only and keeps its amplitudes.  Where a run of
    the check fails (a step the FMU refuses), the signals are kept: the recording then fails with its own message and
    keeps what it recorded, as without the check."""
    from ._window import input_activity, largest_motion

    t_input, width = input_activity(signals[0], source.m)
    before = t[t < t_input - (width or 0.0)]
    if before.size >= 2:   # (at the tolerance asked, as the recording: a grid given means no pilots)
        run, failure = record_run(source, _held_only(source), before, MemorySink, True, isolate,
                                  "the run without the pulse")
        if failure is not None or largest_motion(source, before, np.asarray(run.y)[:, :before.size]) is None:
            return signals
    amplitudes, seen = default_amplitudes(source), {}
    try:
        raised = _raised_amplitudes(source, t, signals, amplitudes, {"quiet": quiet, "isolate": isolate}, seen)
    except FmuOpinfError:
        return signals
    if raised is not None:
        specs = default_training_inputs(source.m, DEFAULT_TRAINING_INPUT, raised, held_starts(source))
        signals = [as_signal(spec, source.m, source) for spec in specs]
    return _with_free_run(source, signals, seen, quiet)


def _effect_share(net: np.ndarray, motion: np.ndarray) -> float:
    """The largest share, over the outputs, of a pulse's effect ``net`` (outputs net of the run without it) in the
    model's own motion ``motion`` (each output's range in that run); inf where an output that does not move on its
    own feels the pulse."""
    effect = np.abs(net).max(axis=1)
    shares = np.where(motion > 0, effect / np.where(motion > 0, motion, 1.0), np.where(effect > 0, np.inf, 0.0))
    return float(shares.max())


def _within_range(source: Source, i: int, amplitude: float) -> float:
    """``amplitude`` for input ``i``'s pulse from its held value, lowered to what its declared range allows (as
    :func:`default_amplitudes` lowers the default)."""
    low, high = (np.asarray(bound, dtype=float) for bound in source.input_ranges())
    start = float(held_starts(source)[i])
    room = (high[i] - start) if amplitude > 0 else (start - low[i])
    return math.copysign(pulse_amplitude(float(room), abs(amplitude)), amplitude)


def _raised_phrase(name: str, old: float, new: float, wanted: float, share: float) -> str:
    """One input's part of the line of :func:`_say_raised`."""
    capped = "" if new == wanted else f" (what its declared range allows; {wanted:.2g} wanted)"
    return (f"amplitude {new:.3g} on {name}{capped}: the {old:g} pulse moved the outputs by {share:.1g} of the model's "
            "own motion")


def _say_raised(source: Source, said: list[str], raised: bool, quiet: bool) -> None:
    """The line of :func:`_raised_amplitudes`: what was raised (printed), or, where the declared ranges allow no
    larger pulse, a warning with the fix."""
    text = "; ".join(said)
    if raised and not quiet:
        print(f"{text} (net of a run without the pulse): recording with the larger pulse; give "
              f"{either('--input')} at the loads you mean to choose them", file=sys.stderr)
    elif not raised:
        warnings.warn(f"{source_label(source)}: {text} (net of a run without the pulse), and the declared range "
                      f"allows no larger pulse: the ROM may miss larger loads; give {either('--input')} at the loads "
                      "you mean",
                      FmuOpinfWarning, stacklevel=4)


def _impulse_window(source: Source, thresholds: dict[str, Any],
                    amplitudes: Sequence[float]) -> tuple[Any, list[Any], Any]:
    """The window and signals of the default training at ``amplitudes``, and the pilots' baseline (whether the
    model moves on its own), the impulse rescaled (``t0`` and ``width`` by
    :data:`RESCALE` per try) while it does not suit the model: widened while the model is too slow for the pulse
    to be resolved within the pilots' step budget (:class:`~fmu_opinf.snapshots._window.PulseTooNarrow`; audit
    2026-11-26: a chain with periods of about 1000 s refused after 48 s), shrunk while the response only follows
    the pulse (:func:`~fmu_opinf.snapshots._window.follows_input`: a model faster than the 0.5 s pulse shows none
    of its dynamics; a millisecond chain at max eps_y 0.85) or only bends the model statically
    (:func:`~fmu_opinf.snapshots._window.quasi_static_pulse`: an FE bar with its first mode at 25 Hz, r = 2 and
    4-9 % off; the impulse is then shrunk to one period of the fastest significant frequency).  Says what it did.

    The first pilot's samples before its pulse acts tell whether the model rests
    (:class:`~fmu_opinf.snapshots._window.IfMoving`).  Where the pilots as they are find no window (the pulse too
    narrow, or a step that steps over it) and the model moves on its own (a constant load inside the model, a
    non-zero input start or a ``--set`` value), the same impulse is tried again with every pilot judged net of a run
    without the pulse on its grid (``baseline``, :func:`_armed_now`), so that the loaded model gets the window of
    the model without the load: a free body accelerating under the load (audit 70, finding 2: the drift, growing
    like ``t**2``, kept the response 'moving', the impulse was widened to t0 = 2e6 s and refused after 70-118 s),
    and an anchored slow model sagging under it (audit 71, F5: a 660 s mode sagging by thousands of metres set the
    window, dt = 20, on which the 0.5 s pulse was never sampled).  A model at rest costs no extra run."""
    from ..signals import parse_signal
    from ._window import IfMoving, PulseTooNarrow, WindowRejected, auto_window, check_window_step, input_activity

    default = parse_signal(DEFAULT_TRAINING_INPUT).params

    def impulse(factor: float, weight: float = 1.0) -> str:
        return (f"impulse:amplitude={default['amplitude'] * weight:g},t0={default['t0'] * factor:g},"
                f"width={default['width'] * factor:g}")

    factor, tries, said = 1.0, {"wider": 0, "narrower": 0}, []
    scales = [a / _DEFAULT_AMPLITUDE for a in amplitudes]

    def pilot_of(factor: float) -> Signal:
        return _pilot_signal([impulse(factor, weight * scale)
                              for weight, scale in zip(_pilot_weights(source.m), scales)], source)

    baseline = IfMoving(_held_only(source))   # armed where the pilots as they are find no window (_armed_now)
    while True:
        pulse = impulse(factor)
        signals = [as_signal(spec, source.m, source)
                   for spec in default_training_inputs(source.m, pulse, amplitudes, held_starts(source))]
        pilot = pilot_of(factor)
        width = input_activity(signals[0], source.m)[1]

        def too_wide(window: Any) -> bool:
            return (tries["narrower"] < RESCALE_TRIES and not tries["wider"]
                    and _narrower_width(window, width, thresholds) is not None)

        try:
            window = auto_window(source, pilot, **thresholds, check_chosen_step=False, reject=too_wide,
                                 baseline=baseline)
        except PulseTooNarrow as slow:
            if _armed_now(baseline):
                continue
            _say_moving(baseline, said, thresholds)
            if tries["wider"] == RESCALE_TRIES or tries["narrower"]:
                if baseline.armed and baseline.moves:
                    raise DataError(_load_error(source, slow.still_moving_at, thresholds)) from None
                pushing = _held_at_bounds(source)   # (an anchored slow model settles under it: audit 65)
                if pushing:
                    raise DataError(_pushed_without_rest(pushing, slow)) from None
                raise
            tries["wider"] += 1
            factor *= RESCALE
            why = "the model is too slow for the default impulse to be resolved"
        except WindowRejected as rejected:
            _say_moving(baseline, said, thresholds)
            tries["narrower"] += 1
            factor *= _narrower_width(rejected.window, width, thresholds) / width
            why = _why_narrower(rejected.window, width)
        else:
            steps_over = _steps_over_pulse(source, pilot, window)
            if steps_over and _armed_now(baseline):
                continue
            _say_moving(baseline, said, thresholds)
            if not (steps_over and tries["wider"] < RESCALE_TRIES and not tries["narrower"]):
                check_window_step(source, pilot, window, quiet=thresholds.get("quiet", True),
                                  isolate=thresholds.get("isolate", False), max_dt=thresholds.get("max_dt"),
                                  exact_dt=thresholds.get("exact_dt", False))
                return window, signals, baseline
            tries["wider"] += 1
            factor *= RESCALE
            why = (f"the window's step dt={window.dt:g}, set by the model's slow motion, steps over the default "
                   f"impulse (width {width:g}): the model is too slow for it")
        if not thresholds.get("quiet"):
            print(f"{why}; trying {impulse(factor)}", file=sys.stderr)


def _steps_over_pulse(source: Source, pilot: Signal, window: Any) -> bool:
    """Whether the window's grid misses the pulse of ``pilot`` on some input it drives: the input is held at every
    sample that drives a step (all but the last), so a recording would never feel that pulse.  The pilots judge
    the response, not the input: a slow mode far above the pulse's response in energy sets a step of seconds, and
    the recording was refused with 'is zero at every sample of the grid' (audit 71, F5: dt = 5 against a 0.5 s
    pulse on an anchored chain with a 160 s mode, loaded or not); the default training widens its impulse then."""
    from ._window import input_activity

    t_input, width = input_activity(pilot, source.m)
    held = held_starts(source)
    if width is None or held.shape != (source.m,):
        return False
    driven = np.any(np.atleast_2d(pilot.sample(np.linspace(0.0, t_input, 2001))) != held[:, None], axis=1)
    acting = time_grid(window.dt, window.t_end)[:-1]
    felt = np.any(np.atleast_2d(pilot.sample(acting)) != held[:, None], axis=1)
    return bool(np.any(driven & ~felt))


def _held_only(source: Source) -> Signal:
    """The pilots' input without its pulses: every input held at the value the training runs hold it at."""
    return NoInput(source.m, held_starts(source))


def _armed_now(baseline: Any) -> bool:
    """Arm ``baseline`` (:class:`~fmu_opinf.snapshots._window.IfMoving`) where the pilots, judged as they are,
    found no window (the pulse too narrow, or a step that steps over it) and the model moves on its own or no pilot
    could tell: True where it was armed now, and the caller tries the same impulse again, judged net of the model's
    own motion.  Armed only then, so that a model that found a window before keeps it (audit 71, F5: the loaded
    slow chain's sag set dt = 20; a start off rest or a load elsewhere changed windows that were right)."""
    if baseline.armed or not baseline.may_move:
        return False
    baseline.armed = True
    return True


def _say_moving(baseline: Any, said: list[str], thresholds: dict[str, Any]) -> None:
    """Say once (unless quiet) that the first pilot showed the model moving without the pulse
    (:class:`~fmu_opinf.snapshots._window.IfMoving`), so that the pilots are judged net of that motion; ``said``
    keeps what was said."""
    if baseline.armed and baseline.moves and not said:
        said.append(baseline.moving)
        if not thresholds.get("quiet"):
            print(f"the outputs move without the pulse ({baseline.moving}: a constant load inside the model, a "
                  f"non-zero input start or a {either('--set')} value): judging the response to the default impulse "
                  "net of that "
                  "motion", file=sys.stderr)


#: Samples of the run without the pulse that :func:`_load_error` judges (as :func:`accelerates_under_load`).
LOAD_SAMPLES = 2000


def _load_error(source: Source, still_moving_at: float, thresholds: dict[str, Any]) -> str:
    """The one-line refusal where no widening of the default impulse finds a window even net of the model's own
    motion under its constant load: one run without the pulse up to where the last pilot still moved
    (``still_moving_at``) tells a free body accelerating under it (:func:`_accelerates_error`) from a model whose
    response to the load dominates the pulse's (its size said)."""
    from ._window import drift_of, largest_motion, response_without_pulse

    t = time_grid(still_moving_at / LOAD_SAMPLES, still_moving_at)
    held = response_without_pulse(source, _held_only(source), t, quiet=thresholds.get("quiet", True),
                                  isolate=thresholds.get("isolate", False))
    drift = None if held is None else drift_of(source, *held)
    if drift:
        return _accelerates_error(source, drift)
    size = (None if held is None else largest_motion(source, *held)) or f"over t <= {still_moving_at:g}"
    return (f"{source_label(source)}: the response to the constant load dominates (without the pulse the outputs "
            f"move, {size}: a load inside the model, a non-zero input start or a {either('--set')} value), and no "
            f"widening of the default impulse finds a window even net of it; give {DT_T_END} for the window to "
            "record (the fit learns the constant force); no file was written")


def _accelerates_error(source: Source, drift: str) -> str:
    """The one-line refusal where no widening of the impulse finds a window even net of the model's drift under its
    own constant load (:func:`~fmu_opinf.snapshots._window.accelerates_under_load`: ``drift`` says how it grows)."""
    return (f"{source_label(source)}: the model accelerates under its own constant load (a free body under gravity "
            f"or thrust: {drift}), and no widening of the default impulse finds a window even net of that drift; "
            f"give {DT_T_END} for the window to record (the fit learns the constant force); no file was written")


def _held_at_bounds(source: Source) -> list[str]:
    """The inputs the recordings hold at a bound of their declared range instead of their start, which lies
    outside it (:func:`held_starts`), each as ``"F1 at -5, the nearest bound of its declared range [-30, -5]
    (its start 0 lies outside)"``."""
    held, starts = held_starts(source), np.asarray(source.input_starts(), dtype=float)
    if not hasattr(source, "input_ranges") or held.shape != starts.shape:
        return []
    low, high = source.input_ranges()
    return [f"{name} at {value:g}, the nearest bound of its declared range [{lo:g}, {hi:g}] (its start {start:g} "
            "lies outside)" for name, value, start, lo, hi in zip(source.input_names, held, starts, low, high)
            if value != start and value != 0.0]


def _pushed_without_rest(pushing: list[str], slow: Any) -> str:
    """Why a default training whose held inputs push the model cannot find a window even with its widest impulse
    (audit 63, finding 5: a free body held at -5 N drifted; the impulse was widened twice, to 500000 s, and the
    refusal asked for a wider one still).  Said only then: an anchored slow model settles under the push and is
    recorded with a wider impulse (audit 65, finding 1: refused at the first try, it was called a free body)."""
    return (f"the default training holds {'; '.join(pushing)}: a constant force, and the response keeps moving "
            f"under it (a free body drifts; it still moved at t={slow.still_moving_at:g}), so no window can wait "
            f"for it to settle; give {DT_T_END} for the window to record (the fit learns the constant force), "
            f"or an input per run ({either('--input')})")


def _narrower_width(window: "Window", width: float | None, thresholds: dict[str, Any]) -> float | None:
    """The width the default impulse (now ``width``) shrinks to, or None where it suits the model or cannot shrink:
    :data:`RESCALE` times narrower where the response only followed it, one period of the fastest significant
    frequency (two significant digits) where it only bent the model statically.

    Where the pilots run at one exact step (the user's ``--dt``, an FMU's fixed communication step) a pulse needs
    ten samples of it: no shrink below that where the response only followed the pulse; a quasi-static pulse is
    shrunk to it where one period is shorter (at that step the fastest frequency seen may be an alias near
    Nyquist: audit 64, ``--dt 0.002`` on a 25 Hz bar kept the 0.5 s pulse, 23-31 % off), if that still halves it.
    """
    from ._window import follows_input, quasi_static_pulse

    if width is None:
        return None
    floor = _shortest_pulse(thresholds)
    if follows_input(window, width):
        return width / RESCALE if width / RESCALE >= floor else None
    if quasi_static_pulse(window, width):
        target = max(float(f"{1.0 / window.f_max:.2g}"), floor)
        return target if 2.0 * target <= width else None
    return None


def _why_narrower(window: "Window", width: float) -> str:
    """Why the default impulse of ``width`` is shrunk (:func:`_narrower_width`), for the progress line."""
    from ._window import follows_input

    if follows_input(window, width):
        return (f"the response only followed the default impulse (faded {window.t_fade - window.t_input:.3g} after "
                "it, no frequency above its band): the model is faster")
    return (f"the default impulse lasts {window.f_max * width:.3g} periods of the fastest significant frequency "
            f"{window.f_max:.4g} Hz and only bends the model statically: its dynamics would be missing from the data")


def _shortest_pulse(thresholds: dict[str, Any]) -> float:
    """The narrowest pulse the recording can follow: ten samples where the pilots run at one exact step (the
    user's ``--dt``, an FMU's fixed communication step), else no limit (the window chooses the step)."""
    step = thresholds.get("max_dt")
    return 10.0 * step if thresholds.get("exact_dt") and step is not None else 0.0


def _pilot_weights(m: int) -> np.ndarray:
    """Amplitudes, relative to the default impulse, with which the window's pilot runs drive all ``m`` inputs at
    once: one pilot sees every mode that any input excites (a mode that the first input does not reach set no
    step before: two oscillators of 0.16 and 1.6 Hz, one per input, were recorded at dt = 0.2).  Distinct
    weights from 1 down to 1/2, so that inputs placed symmetrically do not cancel a mode between them."""
    return 1.0 - 0.5 * np.arange(m) / max(m - 1, 1)


def _pilot_signal(pulses: Sequence[str], source: Source) -> Signal:
    """The pilots' input: ``pulses[j]`` on input ``j``, on top of the value the training runs hold it at when they
    do not drive it (its start or ``--set`` value), as the training runs' own pulses are (:func:`_on_start`), so
    that the pilots stay at the training runs' operating point (a parameter exposed as an input is not driven
    through zero there)."""
    starts = held_starts(source)
    if len(starts) != len(pulses):
        starts = np.zeros(len(pulses))
    return StackedSignal([parse_signal(_on_start(pulse, start), 1) for pulse, start in zip(pulses, starts)])
