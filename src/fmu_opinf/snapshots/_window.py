"""Choosing the snapshot window: the step and end time (paper section 4.2, spec section 5)."""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from .._validate import DT_T_END, ME, either
from ..errors import DataError, InputSpecError
from ..signals import NoInput
from ..sources import Source, fixed_communication_step, offers_model_exchange, open_source
from ..sources._base import held_inputs_advice, nice_floor
from ..sources._cosimulation import DISCARDED
from ._growth import growth_error, held_ratios, still_rising, unbounded_growth
from ._inputs import as_signal
from ._isolation import source_label
from ._linearity import note_pilot
from ._rates import continuous_recording, time_grid
from ._run import MemorySink, incomplete_error, record_run

__all__ = ["Window", "auto_window", "combine_windows", "follows_input", "quasi_static_pulse", "significant_frequency",
           "slowest_frequency", "fade_time", "default_window",
           "needs_auto_window", "input_activity", "check_step_convergence", "pilot_step", "StableStep",
           "check_window_step", "warn_if_step_dependent", "accelerates_under_load",
           "response_without_pulse", "drift_of", "largest_motion", "IfMoving", "probe_growth"]


#: A pulse this many times shorter than the fastest significant period only keeps the step small: once the next
#: pilot would need 1/64 of the step budget for it, the window gives up early (the default training then
#: widens its impulse).  The paper's benchmarks are far from it (triple chain: 63 times shorter).
NARROW_PULSE = 1000.0


def _pulse_holds_back(f_max: float, width: float | None, next_steps: float, max_steps: int) -> bool:
    """Whether the pulse alone makes the next pilot too long (:data:`NARROW_PULSE`)."""
    if width is None or not f_max > 0:
        return False
    narrow = f_max * width * NARROW_PULSE < 1.0
    return next_steps > (max_steps / 64.0 if narrow else max_steps)


class PulseTooNarrow(DataError):
    """The automatic window cannot settle because the training pulse keeps its step small: the model is far
    slower than the pulse (the default training widens its impulse then); ``still_moving_at``: the end of the
    last pilot, where the outputs still moved."""

    def __init__(self, message: str, still_moving_at: float) -> None:
        super().__init__(message)
        self.still_moving_at = still_moving_at


class WindowRejected(DataError):
    """The caller's ``reject`` test of :func:`auto_window` refused the window the first pilot settled on; raised
    before the step check's second run, which would be wasted (``window``: the refused window)."""

    def __init__(self, window: "Window") -> None:
        super().__init__(f"the automatic window (dt={window.dt:g}, t_end={window.t_end:g}) was refused")
        self.window = window


def follows_input(window: "Window", width: float | None) -> bool:
    """Whether the recorded response merely followed a pulse of ``width``: faded within one width after the
    input stopped, with no frequency above the pulse's own band (``2 / width``).  The model's dynamics are then
    faster than the pulse and absent from the data (audit 2026-11-26: a chain with millisecond periods under the
    default 0.5 s impulse, window dt = 0.1, t_end = 2.5, max eps_y 0.85 on a fast test input)."""
    if width is None or not math.isfinite(window.t_fade):
        return False
    return window.t_fade - window.t_input <= width and window.f_max <= 2.0 / width


#: A pulse whose band (``2 / width``) lies more than this many times below the response's fastest significant
#: frequency is quasi-static for the model (:func:`quasi_static_pulse`).
QUASI_STATIC = 3.0


def quasi_static_pulse(window: "Window", width: float | None) -> bool:
    """Whether a pulse of ``width`` only bends the model statically: the fastest significant frequency of the
    response lies more than :data:`QUASI_STATIC` times above the pulse's band (``2 / width``), so the pulse lasts
    many periods of the model's modes and sets them ringing only weakly at its edges.  The position snapshots then
    hold little more than one static deflection shape per input, the energy criterion keeps those, and the ROM
    reproduces its training run while it misses the model's dynamics (audit 62: a 300-node FE bar, first mode
    25 Hz, under the 0.5 s pulse: sigma_3 / sigma_1 = 2e-4, r = 2, 4-9 % off at its outputs, and fit could not
    see it)."""
    return width is not None and window.f_max * width > 2.0 * QUASI_STATIC


def default_window(source: Source, dt: float | None, t_end: float | None) -> tuple[float, float]:
    """Step and end time from the user and the FMU's ``DefaultExperiment`` (stepSize, stopTime).

    Raises :class:`~fmu_opinf.errors.InputSpecError` when either is still missing.
    """
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    if dt is None and experiment is not None and experiment.stepSize is not None:
        dt = float(experiment.stepSize)
    if t_end is None and experiment is not None and experiment.stopTime is not None:
        t_end = float(experiment.stopTime) - float(experiment.startTime or 0.0)  # runs start at t = 0
    if dt is None or t_end is None:
        missing = " and ".join(either(n) for n, v in (("--dt", dt), ("--t-end", t_end)) if v is None)
        raise InputSpecError(f"no {missing} given and the source has no default; pass {missing}, or "
                             f"{either('--auto-window')}")
    return float(dt), float(t_end)


def needs_auto_window(source: Source, dt: float | None, t_end: float | None, signal: Any = None) -> bool:
    """True when the automatic window must choose the grid: ``dt`` or ``t_end`` not given and the
    source declares no default step (``DefaultExperiment/@stepSize``), or ``t_end`` not given and the declared
    ``stopTime`` ends before the training ``signal`` stops changing.  A ``stopTime`` alone is not
    used: real FMUs carry ``stopTime=1`` unrelated to their dynamics (audit 2026-11-26: ``stepSize=0.001,
    stopTime=1`` with the default impulse at t = 2 recorded a zero input)."""
    if dt is not None and t_end is not None:
        return False
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    if experiment is None or experiment.stepSize is None:
        return True
    if t_end is not None or signal is None or experiment.stopTime is None:
        return False
    start = float(experiment.startTime or 0.0)
    return float(experiment.stopTime) - start <= input_activity(signal, getattr(source, "m", 1))[0]


@dataclasses.dataclass
class Window:
    """Step and end time chosen from an impulse response (see :func:`auto_window`).

    Attributes
    ----------
    dt : float
        Chosen step: ``1 / (points_per_period * f_max)`` rounded down to 1, 2 or 5 times a power of ten.
    t_end : float
        Chosen end time (a multiple of ``dt``): when the response has faded out, or, if it does not
        fade by then, ``periods`` periods of the slowest significant oscillation after the input died out.
    f_max : float
        Fastest significant frequency of the output response, in Hz (cycles per time unit).
    t_fade : float
        Time after which the output envelope stays below ``fade`` times its peak (``inf`` if not seen).
    peak : float
        Peak of ``||y(t) - y_rest||_2``.
    pilot_dt, pilot_t_end : float
        Grid of the last pilot run.
    pilots : int
        Number of pilot runs.
    points_per_period, energy, fade : float
        Thresholds used.
    f_min : float
        Slowest significant frequency of the free response, in Hz (0 if none was resolved).
    periods : float
        Number of periods of ``f_min`` after which a response that does not fade is cut.
    t_input : float
        Time from which the input stays constant (the free response starts).
    stopped_by : str
        ``"fade"`` (the vibrations faded out), ``"periods"`` (cut after ``periods`` slow periods) or ``"limit"``
        (cut at :attr:`t_limit`, which the pilots reached with the step resolved).
    stable_dt, unstable_dt, stable_difference : float
        Where the co-simulation overflowed at the first pilot's step (:func:`pilot_step`): the largest step tried
        at which it stays finite and converges (``dt`` is at most this), the smallest at which it overflowed or
        diverged, and the outputs' difference at ``stable_dt`` and half of it relative to their peak; 0 otherwise.
    t_limit : float
        The latest time the pilots could run to (:func:`auto_window`'s ``t_limit``: a given end time, an input
        table's last time, a time at which the FMU terminates); 0 where there was none.
    unstable_cause : str
        ``"discard"`` where the FMU discarded the step ``unstable_dt`` (an embedded solver's maximum step) rather than
        overflowing or diverging there; "" otherwise.
    terminates_at : float
        The time, relative to the run's start, at which the FMU terminated the simulation in a pilot run (the window
        then ends before it, :attr:`t_limit`); 0 where it did not.  Kept so that ``compare``'s default end stops
        before it too (audit 71 F8: it ran on to four times the training's end and failed there).
    growth_probe : float
        The end of the longest growth probe run where the positions still rose steadily at the end of the pilot
        that settled (:func:`probe_growth`; none grew exponentially, or the window would have been refused); 0
        where none was run.
    """

    dt: float
    t_end: float
    f_max: float
    t_fade: float
    peak: float
    pilot_dt: float
    pilot_t_end: float
    pilots: int
    points_per_period: float
    energy: float
    fade: float
    f_min: float = 0.0
    periods: float = 20.0
    t_input: float = 0.0
    stopped_by: str = "fade"
    stable_dt: float = 0.0
    unstable_dt: float = 0.0
    stable_difference: float = 0.0
    t_limit: float = 0.0
    unstable_cause: str = ""
    terminates_at: float = 0.0
    growth_probe: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (stored as the ``auto_window`` attribute)."""
        out: dict[str, Any] = {}
        for key, value in dataclasses.asdict(self).items():
            out[key] = int(value) if key == "pilots" else value if isinstance(value, str) else float(value)
        return out

    def __str__(self) -> str:
        if self.stopped_by == "limit":
            end = f"cut at t_end={self.t_end:g}, the latest the run may reach (the response goes on)"
        elif self.stopped_by == "periods":
            end = (f"the response does not fade, cut after {self.periods:g} periods of the slowest significant "
                   f"oscillation ({self.f_min:.4g} Hz) from t={self.t_input:.4g}")
        else:
            end = f"output below {self.fade:g} of its peak after t={self.t_fade:.4g}"
        return (f"dt={self.dt:g}, t_end={self.t_end:g} (fastest significant frequency {self.f_max:.4g} Hz, "
                f"{self.points_per_period:g} points per period; {end}{self._stable_note()}; {self.pilots} pilot "
                f"run(s), last dt={self.pilot_dt:g}, t_end={self.pilot_t_end:g}{self._probe_note()})")

    def _probe_note(self) -> str:
        """The growth probes (:func:`probe_growth`), where any ran."""
        if not self.growth_probe:
            return ""
        return (f"; the positions still rose at the pilot's end: probed to t={self.growth_probe:g}, no exponential "
                "growth")

    def _stable_note(self) -> str:
        """Why the step is at most :attr:`stable_dt` (empty where no step search was needed)."""
        if not self.stable_dt:
            return ""
        if self.unstable_cause == "discard":
            return (f"; the FMU discards the communication step dt={self.unstable_dt:g}: steps at most "
                    f"dt={self.stable_dt:g}, the largest tried that it takes and where it agrees with "
                    f"dt={self.stable_dt / 2:g} to {self.stable_difference:.2g} of the outputs' peak")
        return (f"; the co-simulation overflows or diverges at dt={self.unstable_dt:g}: steps at most "
                f"dt={self.stable_dt:g}, the largest tried where it is finite and agrees with "
                f"dt={self.stable_dt / 2:g} to {self.stable_difference:.2g} of the outputs' peak")


def significant_frequency(t: np.ndarray, y: np.ndarray, energy: float = 0.999) -> float:
    """Smallest frequency below which a fraction ``energy`` of the output's spectral energy lies.

    The spectrum is that of the Hann-windowed outputs without their straight-line trend (summed over outputs;
    a drifting free body, :func:`slowest_frequency`); the window
    removes the leakage of cutting the response at both ends, which would otherwise put spurious
    energy at high frequencies.

    Parameters
    ----------
    t : (k,) ndarray
        Uniform times.
    y : (p, k) ndarray
        Output response.
    energy : float, default=0.999

    Returns
    -------
    float
        Frequency in cycles per time unit (0 for a constant output).
    """
    y = np.atleast_2d(y)
    r = _without_trend(y) * np.hanning(y.shape[1])  # a drift hides oscillations: slowest_frequency
    power = (np.abs(np.fft.rfft(r, axis=1)) ** 2).sum(axis=0)
    freqs = np.fft.rfftfreq(y.shape[1], d=float(t[1] - t[0]))
    total = power.sum()
    if total <= 0:
        return 0.0
    cumulative = np.cumsum(power) / total
    return float(freqs[min(int(np.searchsorted(cumulative, energy)), len(freqs) - 1)])


def fade_time(t: np.ndarray, y: np.ndarray, fade: float = 0.01,
              t_input: float | None = None) -> tuple[float, float]:
    """Time after which ``||y(t) - y_rest||_2`` stays below ``fade`` times its peak.

    ``y_rest`` is the mean output over the last 5 % of the samples (the state the response settles
    to), or, after an input at ``t_input`` that set a free body drifting, the straight line of the drift
    (:func:`_rest`).  Returns ``(t_fade, peak)``; ``t_fade`` is ``inf`` if the envelope never falls below.
    """
    return _fade_from(t, _Envelope.of(t, y, fade, t_input), fade)


@dataclasses.dataclass
class _Envelope:
    """The outputs' distance from their rest (``deviation``), its running maximum from each sample to the end
    (``envelope``), and the ``peak`` the fade is judged against with the sample it is at (``peak_at``): computed
    once per pilot for the fade time and its extrapolation.

    The peak is the largest deviation once the input has stopped changing (``t >= t_input``), the vibrations the
    window waits for; the whole run's only where the response after the input is negligible
    (:data:`NEGLIGIBLE_AFTER_INPUT`, a model that merely follows the pulse).  While the input acts, an output it
    reaches directly (a feedthrough-only input such as a sensor bias, an acceleration sensor under a force) can
    peak far above the vibrations: judged against that peak, a response still at 36 % of its own peak had
    'faded' (seventh audit, 2026-11-27).
    """

    deviation: np.ndarray
    envelope: np.ndarray
    peak: float
    peak_at: int = 0

    @classmethod
    def of(cls, t: np.ndarray, y: np.ndarray, fade: float, t_input: float | None) -> "_Envelope":
        y = np.atleast_2d(y)
        deviation = np.linalg.norm(y - _rest(t, y, fade, t_input), axis=0)
        envelope = np.maximum.accumulate(deviation[::-1])[::-1]
        peak_at = int(np.argmax(deviation))
        stopped = 0 if t_input is None or len(t) < 2 else _held_until(t, t_input)
        if 0 < stopped < len(t):
            after = stopped + int(np.argmax(deviation[stopped:]))
            if deviation[after] >= NEGLIGIBLE_AFTER_INPUT * deviation[peak_at]:
                peak_at = after
        return cls(deviation, envelope, float(deviation[peak_at]), peak_at)


def _held_until(t: np.ndarray, t_input: float) -> int:
    """The first sample whose step lies wholly after ``t_input``: a sample holds the input of the step that ends
    at it, so the one just after ``t_input`` may still carry the input."""
    return int(np.searchsorted(t, t_input + (t[1] - t[0]) - 1e-9 * (t[1] - t[0]), side="left"))


#: Largest deviation after the input stopped, relative to the whole run's, below which the response after the
#: input counts as negligible and the fade is judged against the whole run's peak (:class:`_Envelope`).
NEGLIGIBLE_AFTER_INPUT = 1e-4


def _fade_from(t: np.ndarray, seen: _Envelope, fade: float) -> tuple[float, float]:
    if seen.peak == 0.0:
        return float(t[0]), 0.0
    below = np.nonzero(seen.envelope <= fade * seen.peak)[0]
    below = below[below >= seen.peak_at]
    return (float(t[below[0]]) if below.size else math.inf), seen.peak


def _rest(t: np.ndarray, y: np.ndarray, fade: float, t_input: float | None = None) -> np.ndarray:
    """What the outputs settle to: their mean over the last 5 % of the samples, or, for a free body that an input
    set drifting at constant speed, the straight line through the last quarter from ``t_input`` on (the value
    before the input until then).  The line is taken when its slope is the same over the last 5 % (within 10 %),
    the drift across the quarter exceeds ``fade`` of the response's size, and the outputs move away from their
    value before the input (a slow decay moves back towards it, and over a short record looks just as straight).
    Against the mean, the drift never 'faded' (second audit, 2026-11-26: a free-free chain with damping
    D = 0.01 K refused after 12 pilots and 90 s).  Free responses (no ``t_input`` after the start) keep the mean.
    """
    k = y.shape[1]
    tail, quarter = max(1, k // 20), max(1, k // 4)
    mean = y[:, -tail:].mean(axis=1, keepdims=True)
    if t_input is None or not t_input > t[0] or tail < 4 or t[-quarter] <= t_input:
        return mean
    slope_quarter, intercept = _line(t[-quarter:], y[:, -quarter:])
    slope_tail, _ = _line(t[-tail:], y[:, -tail:])
    before = y[:, :1]
    drift = np.linalg.norm(slope_quarter) * float(t[-1] - t[-quarter])
    size = float(np.linalg.norm(y - mean, axis=0).max())
    agree = np.linalg.norm(slope_tail - slope_quarter) <= 0.1 * np.linalg.norm(slope_quarter)
    away = float(slope_quarter @ (y[:, -1] - before[:, 0])) > 0
    if not (agree and away and drift > fade * size):
        return mean
    line = intercept[:, None] + slope_quarter[:, None] * t[None, :]
    return np.where(t[None, :] >= t_input, line, before)


def _line(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slope and intercept of each row's least-squares straight line in ``t``."""
    centre = t - t.mean()
    slope = (y @ centre) / max(float(centre @ centre), np.finfo(float).tiny)
    return slope, y.mean(axis=1) - slope * t.mean()


#: Fewest samples of a leading part of the free response that :func:`_fastest_early_or_late` analyses on its own.
EARLY_SAMPLES = 64


def _fastest_early_or_late(t: np.ndarray, y: np.ndarray, energy: float) -> float:
    """The fastest significant frequency of the free response and of its leading quarter, sixteenth, ... (down to
    :data:`EARLY_SAMPLES` samples).  The Hann window of the whole response nearly hides a fast mode that has died
    out early (a 1.6 Hz mode with a 2 s decay in a 90 s window gave dt = 0.2, 3 samples per period); a leading part
    holds it in full.  A part's frequency counts only if the part resolves it (three periods or more, as in
    :func:`slowest_frequency`: its lowest bins are the slower modes cut short) and with energy above ``1 - energy``
    of the whole response's (per sample, as both are sampled alike)."""
    freqs, power = _energy_spectrum(t, y)
    whole = float(power.sum())
    if whole <= 0:
        return 0.0
    f_max, k = _frequency_below(freqs, power, (1.0 - energy) * whole), t.size
    while k // 4 >= EARLY_SAMPLES:
        k //= 4
        freqs, power = _energy_spectrum(t[:k], y[:, :k])
        early = _frequency_below(freqs, power, (1.0 - energy) * max(whole, float(power.sum())))
        if early >= 3.0 * freqs[1]:
            f_max = max(f_max, early)
    return f_max


def _energy_spectrum(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies and spectral energy of the Hann-windowed outputs without their straight-line trend, summed over
    outputs and scaled by ``1 / k`` (Parseval: the sum is the windowed signal's sum of squares, comparable between
    records of different length on the same step)."""
    windowed = _without_trend(np.atleast_2d(y)) * np.hanning(t.size)
    power = (np.abs(np.fft.rfft(windowed, axis=1)) ** 2).sum(axis=0) / t.size
    return np.fft.rfftfreq(t.size, d=float(t[1] - t[0])), power


def _frequency_below(freqs: np.ndarray, power: np.ndarray, budget: float) -> float:
    """The smallest frequency above which at most ``budget`` of the energy lies."""
    above = np.cumsum(power[::-1])[::-1]  # energy at and above each frequency
    first = int(np.searchsorted(-above, -budget, side="left"))  # first index with at most budget at and above it
    return float(freqs[max(first - 1, 0)])


def slowest_frequency(t: np.ndarray, y: np.ndarray, energy: float = 0.999) -> float:
    """Slowest significant frequency: the smallest one above which a fraction ``energy`` of the
    spectral energy of the (mean-free, Hann-windowed) outputs lies.

    Returns 0 when that lies within the lowest three frequency bins (not resolved by this record:
    an oscillation slower than a third of the record).  A straight-line trend is removed first: a free body
    (an unanchored chain after an impulse) drifts at constant speed while its oscillations die out, and the
    drift's energy would otherwise sit in the lowest bins and hide them (before 2026-11-26 such a model ran
    12 pilot runs for 90 s and stopped with an error).
    """
    y = np.atleast_2d(y)
    if y.shape[1] < 16:
        return 0.0
    r = _without_trend(y) * np.hanning(y.shape[1])
    power = (np.abs(np.fft.rfft(r, axis=1)) ** 2).sum(axis=0)
    total = power.sum()
    if total <= 0:
        return 0.0
    index = int(np.searchsorted(np.cumsum(power) / total, 1.0 - energy))
    if index < 3:
        return 0.0
    return float(np.fft.rfftfreq(y.shape[1], d=float(t[1] - t[0]))[index])


def _without_trend(y: np.ndarray) -> np.ndarray:
    """Each row minus its least-squares straight line over the sample index (mean and drift removed; scipy.signal's
    detrend would cost its 0.5 s import in every process)."""
    index = np.arange(y.shape[1], dtype=float)
    slope, intercept = _line(index, y)
    return y - intercept[:, None] - slope[:, None] * index


@dataclasses.dataclass
class _Pilot:
    """What one pilot run shows."""

    t_fade: float
    peak: float
    f_max: float
    f_min: float
    resolved_periods: float  # record length after the input died out, in periods of f_min
    fade_estimate: float  # fade-out time extrapolated from the envelope's decay (inf if not decaying)
    held: np.ndarray | None = None  # the positions' quarter ratios once the inputs are held (_growth.held_ratios)


def auto_window(
    source: Source | str,
    signal: Any,
    *,
    points_per_period: float = 20.0,
    energy: float = 0.999,
    fade: float = 0.01,
    periods: float = 20.0,
    pilot_dt: float | None = None,
    pilot_t_end: float | None = None,
    max_dt: float | None = None,
    exact_dt: bool = False,
    min_pilot_points: float = 8.0,
    growth: float = 4.0,
    max_pilots: int = 12,
    max_steps: int = 400_000,
    isolate: bool = False,
    quiet: bool = True,
    check_chosen_step: bool = True,
    reject: Callable[[Window], bool] | None = None,
    t_limit: float | None = None,
    baseline: Any = None,
) -> Window:
    """Choose step and end time from the response to an impulse-like input (paper sec. 4.2).

    Pilot runs record the outputs; the step resolves the fastest significant oscillation with
    ``points_per_period`` samples and the end time is when the vibrations have faded out, or, for
    undamped and lightly damped systems whose vibrations do not fade by then, ``periods`` periods of
    the slowest significant oscillation after the input has died out:

    * ``f_max``: smallest frequency below which a fraction ``energy`` of the spectral energy of the
      outputs lies (Hann-windowed FFT of the pilot's free response, from when the input has died
      out, :func:`significant_frequency`); ``f_min``: smallest frequency above which that fraction
      lies (:func:`slowest_frequency`);
    * ``t_fade``: the envelope ``max_{s >= t} ||y(s) - y_rest||_2`` stays below ``fade`` times its
      peak afterwards (:func:`fade_time`).

    The pilots are independent of the FMU's ``stopTime``: the first one covers the input's active
    part (found by sampling the signal) and ten times its width, with ten samples across it.  A pilot
    is refined (step / 4) while ``f_max`` has fewer than ``min_pilot_points`` samples per period,
    and extended until the response has faded in its first half or ``f_min`` is resolved over four
    periods and the response will not fade before ``periods`` periods: to twice the fade-out time
    extrapolated from the envelope's exponential decay, at least doubled and at most ``growth**2``
    times longer.  An extended pilot is coarsened (step x 4) when ``f_max`` and the input pulse stay
    resolved, so that slow decays do not hit ``max_steps``.  A pilot that settles at the first pilot's step is
    run again at a quarter of it (:func:`_alias_check`, counted as a pilot): a mode above the first step's Nyquist
    frequency is folded onto a slower frequency in its samples and would set neither step nor pulse; where the
    finer run shows it, the pilots go on from there.  A co-simulation FMU whose outputs depend on
    the communication step (one explicit step per ``doStep``) is refused first (:func:`check_step_convergence`);
    one that overflows at the first pilot's step is run at the largest smaller step at which it is finite and
    converges, which bounds the pilots' and the window's step (:func:`pilot_step`; refused where there is none).

    Parameters
    ----------
    source : Source or str
    signal : Signal or str
        Impulse-like training input (``"none"``: the free response from the start state).
    points_per_period : float, default=20
    energy : float, default=0.999
    fade : float, default=0.01
    periods : float, default=20
        Periods of the slowest significant oscillation after which a non-fading response is cut.
    pilot_dt, pilot_t_end : float, optional
        First pilot grid (default: from the input, see above).
    max_dt : float, optional
        The step the recording will use (an FMU's declared ``stepSize``): no pilot is coarser, since a longer
        communication step may be refused or discarded by the FMU (an embedded solver's maximum step).
    exact_dt : bool, default=False
        Every pilot and the window's step are exactly ``max_dt`` (a ``--dt`` the user gave: the recording uses
        it; pilots at other steps could be refused where the user's step is not): no refinement or coarsening,
        and the step check is the caller's (:func:`warn_if_step_dependent`).  An FMU with a fixed communication
        step (:func:`~fmu_opinf.sources.fixed_communication_step`) is run this way at its step unless the caller
        gives an exact step of its own.
    min_pilot_points : float, default=8
    growth : float, default=4
    max_pilots : int, default=12
    max_steps : int, default=400000
        Largest pilot run.
    isolate : bool, default=False
        Run the pilots in a child process.
    quiet : bool, default=True
    check_chosen_step : bool, default=True
        Also check the chosen step when it is coarser than the first pilot's (:func:`check_window_step`).  A
        caller that may still reject the window passes False and checks the window it keeps.
    reject : callable, optional
        The caller's test of a window it would not keep (the default training: a response that only followed
        the pulse).  Where the step check's first run, which is also the first pilot, settles on such a window,
        :class:`WindowRejected` is raised before the step check's second run (on a millisecond chain under the
        default 0.5 s impulse that run took 14 of 30 s).
    t_limit : float, optional
        The latest time any pilot may run to: a given end time, the last time of an input table (which cannot be
        sampled beyond it), a time at which the FMU terminates the simulation.  Pilots longer than that are cut
        there, and a pilot that reaches it with its step resolved settles: the window ends there
        (``stopped_by="limit"``; audit 70, F3/F5: the pilots ran to t = 550 past a table ending at 120 and past an
        FMU's termination at t = 30, whatever --t-end said).
    baseline : Signal or IfMoving, optional
        An input (the inputs held, no pulse) whose response is subtracted from every pilot's outputs before they
        are judged: the window follows the response to ``signal`` net of what the model does on its own, a free
        body's drift under its own constant load (:func:`accelerates_under_load`; audit 70, finding 2), an anchored
        slow model's sag (audit 71, F5).  Each pilot then costs a second run on its grid.  An :class:`IfMoving`
        applies only where the first pilot shows the model moving before the pulse acts.

    Returns
    -------
    Window

    Raises
    ------
    WindowRejected
        ``reject`` refused the first pilot's window.
    """
    source = open_source(source)
    signal = as_signal(signal, source.m, source)
    for name, value, low, high in (("energy", energy, 0.0, 1.0), ("fade", fade, 0.0, 1.0)):
        if not low < value < high:
            raise InputSpecError(f"{name}={value} must lie strictly between {low:g} and {high:g}")
    if points_per_period < 2:
        raise InputSpecError(f"points_per_period={points_per_period} must be at least 2 (Nyquist)")
    if not periods > 0:
        raise InputSpecError(f"periods={periods} must be positive")
    if source.p == 0:
        raise DataError(f"the source has no outputs; auto window needs outputs to analyse (pass {either('--outputs')})")
    t_input, width = input_activity(signal, source.m)
    max_dt, exact_dt = _step_limit(source, max_dt, exact_dt)
    T, dt = _first_pilot(source, t_input, width, pilot_dt, pilot_t_end, max_dt, exact_dt)
    if t_limit is not None:
        if not (t_limit > 0 and math.isfinite(t_limit)):
            raise InputSpecError(f"t_limit={t_limit} must be positive and finite")
        T = min(T, float(t_limit))
    internal = fixed_internal_step(source)

    def needs_finer(seen: _Pilot, dt: float) -> bool:
        return not exact_dt and seen.f_max * dt * min_pilot_points > 1.0 and (internal is None or dt > internal)

    def settled(seen: _Pilot, t: np.ndarray, dt: float, T: float, pilot: int) -> Window | None:
        """The window pilot number ``pilot`` settles on, or None: it needs a finer or a longer pilot."""
        if needs_finer(seen, dt):
            return None
        t_cut = t_input + periods / seen.f_min if seen.f_min > 0 else math.inf
        faded = seen.t_fade <= t[0] + 0.5 * (T - t[0])
        cut = seen.resolved_periods >= 4.0 and not seen.fade_estimate < t_cut
        reached = t_limit is not None and T >= t_limit * (1.0 - 1e-9)
        if not (faded or cut or reached):
            return None
        stopped_by = "limit" if not (faded or cut) else "fade" if seen.t_fade <= t_cut else "periods"
        t_stop = min(seen.t_fade, t_cut) if stopped_by != "limit" else T
        window = _window(seen, t_stop, t[0], dt, T, pilot, points_per_period, energy, fade, periods, t_input,
                         stopped_by, internal, dt if exact_dt else None, stable)
        return window if t_limit is None else _within_limit(window, t[0], float(t_limit))

    checked: list[_AliasCheck | None] = []   # the one check run, once made
    unrefined = dt

    def aliased(dt: float, T: float) -> _AliasCheck | None:
        """The check run of a pilot that settled at the step ``dt`` (:func:`_alias_check`), made once and only at
        the step the pilots started from: a step that a pilot refined to follows the model's own spectrum, and a
        step coarsened to was resolved twice over by a finer pilot."""
        if exact_dt or dt != unrefined:
            return None
        if not checked:
            checked.append(_alias_check(source, signal, dt, T, t_input, energy, fade, quiet, isolate, internal,
                                        max_steps, baseline))
        return checked[0]

    def reject_first_pilot(run: Any) -> None:
        t = time_grid(dt, T)
        if isinstance(baseline, IfMoving) and baseline.tell(source, signal, t, np.asarray(run.y), quiet, isolate):
            return  # a run without the pulse would be needed first: the pilots judge (and reject) it
        try:
            seen = _analyse_pilot(source, signal, t, t_input, energy, fade, growth, quiet, isolate, run=run,
                                  baseline=baseline)
        except DataError:
            return  # the pilots say it again, after the step check has had its say
        window = settled(seen, t, dt, T, 1)
        if window is not None and reject(window):  # before the alias check: a pulse too wide for the modes the
            raise WindowRejected(window)             # pilot saw is too wide for any it missed

    recorded, stable = None, None
    if not exact_dt:
        recorded, stable = pilot_step(source, signal, dt, T, quiet=quiet, isolate=isolate, max_steps=max_steps,
                                      inspect=reject_first_pilot if reject else None)
    if stable is not None:  # the pilots start at, and stay within, the step where the co-simulation is stable
        dt, max_dt = stable.dt, stable.dt if max_dt is None else min(max_dt, stable.dt)
        unrefined = dt
        if reject is not None:
            reject_first_pilot(recorded)
    for pilot in range(1, max_pilots + 1):
        t = time_grid(dt, T)
        if len(t) > max_steps:
            break
        seen = _analyse_pilot(source, signal, t, t_input, energy, fade, growth, quiet, isolate,
                              label=f"auto window: pilot run {pilot} (dt={dt:g}, t_end={T:g})", run=recorded,
                              baseline=baseline)
        recorded = None
        if needs_finer(seen, dt):
            dt = on_internal_steps(dt / 4.0, internal)
            continue
        window = settled(seen, t, dt, T, pilot)
        if window is not None and reject is not None and reject(window):
            raise WindowRejected(window)
        alias = None if window is None else aliased(dt, T)
        if alias is not None and alias.aliased:  # a faster mode was missed: go on from the check run, at its step
            if not quiet:
                print(f"auto window: {alias.describe(dt)}; refining the pilots", file=sys.stderr)
            dt = alias.dt
            recorded = alias.run if np.array_equal(np.asarray(alias.run.t), time_grid(dt, T)) else None
            continue
        if window is not None:
            if alias is not None:   # the check run counts as a pilot
                window = dataclasses.replace(window, pilots=window.pilots + 1)
            if still_rising(seen.held):
                window = probe_growth(source, signal, window, dt, T, seen.held, quiet=quiet, isolate=isolate,
                                      max_steps=max_steps, t_limit=t_limit)
            if check_chosen_step:
                check_window_step(source, signal, window, pilot_dt=pilot_dt, pilot_t_end=pilot_t_end, quiet=quiet,
                                  isolate=isolate, max_dt=max_dt, exact_dt=exact_dt)
            return window
        T_next = _next_length(t, seen, growth)
        while not exact_dt and _coarsen_ok(seen.f_max, 4.0 * dt, min_pilot_points, width) \
                and (max_dt is None or 4.0 * dt <= max_dt * (1.0 + 1e-9)):
            dt *= 4.0
        if not exact_dt and _pulse_holds_back(seen.f_max, width, (T_next - t[0]) / dt, max_steps) \
                and _coarsen_ok(seen.f_max, 4.0 * dt, min_pilot_points, None):
            raise PulseTooNarrow(f"auto window: the training pulse (width {width:g}) is far shorter than the model's "
                                 f"dynamics (fastest significant frequency {seen.f_max:.3g}, still moving at "
                                 f"t={t[-1]:g}): resolving it would take over {max_steps / 64:g} steps per pilot; give an input on the "
                                 f"model's time scale (a wider impulse, later t0), or {DT_T_END}", float(t[-1]))
        T = float(f"{T_next:.6g}") if t_limit is None else min(float(f"{T_next:.6g}"), float(t_limit))
    fix = (f"pass {either('--t-end')} (every pilot ran at the step dt={dt:g})" if exact_dt else
           f"pass {DT_T_END}, or an input on the model's time scale (a wider impulse, later t0: a narrow pulse "
           "keeps the step small)" if source.m else
           f"pass {DT_T_END} (the model has no inputs: its free response from the start state is recorded)")
    raise DataError(f"auto window: the output does not settle or is not resolved within {max_pilots} pilot runs "
                    f"of at most {max_steps} steps (last dt={dt:g}, t_end={T:g}); {fix}")


#: Largest difference (relative to the peak) between the outputs of a co-simulation run at a step and at half
#: that step, under the same held input, that counts as converged.  Measured on the first pilot of the impulse
#: input (tests/test_exporter_combinations.py): RK4 substeps that follow the tolerance 1e-10, 1.9e-14; one explicit
#: Euler step per communication step, 3.3e3 at the pilot step 0.0485 (unstable) and 0.07 at 0.005.
STEP_CONVERGENCE = 1e-3


class _HeldOn:
    """``signal`` sampled on the coarse grid ``t`` and held: a finer run sees the coarse run's inputs."""

    def __init__(self, signal: Any, t: np.ndarray) -> None:
        self.t, self.values = t, np.atleast_2d(np.asarray(signal.sample(t), dtype=float))

    def sample(self, t: Any) -> np.ndarray:
        h = self.t[1] - self.t[0] if len(self.t) > 1 else 1.0
        j = np.searchsorted(self.t, np.asarray(t, dtype=float) + 1e-9 * h, side="right") - 1
        return self.values[:, np.clip(j, 0, len(self.t) - 1)]


def check_step_convergence(source: Source, signal: Any, dt: float, T: float, *, quiet: bool = True,
                           isolate: bool = False, threshold: float = STEP_CONVERGENCE,
                           inspect: Callable[[Any], None] | None = None) -> Any:
    """Refuse a co-simulation FMU whose results depend on the communication step.

    Several exporters' co-simulation is one explicit Euler step per ``doStep`` (spec: real FMUs): inaccurate or
    unstable at the steps the automatic window chooses, and no step makes it accurate.  The outputs of a run on
    ``[0, T]`` at step ``dt`` are compared with a run at ``dt / 2`` under the same held input.  Sources that are
    not co-simulation FMUs of continuous-time models (model exchange, fmu-opinf's Newmark FMUs, builtins) are
    not checked.

    Parameters
    ----------
    source : Source
    signal : Signal
        The training input (held on the ``dt`` grid for both runs).
    dt, T : float
        Step and end of the coarse run.
    quiet, isolate : bool
        Progress bar; run in a child process.
    threshold : float, default=STEP_CONVERGENCE
        Largest accepted max-norm difference of the outputs relative to their peak.
    inspect : callable, optional
        Called with the complete run at ``dt`` before the run at ``dt / 2``; what it raises ends the check.

    Raises
    ------
    DataError
        The outputs differ by more than ``threshold`` or turn non-finite: one line naming the steps, the
        difference and what to do.

    Returns
    -------
    run or None
        The complete run at ``dt`` (a pilot on the same grid need not repeat it), or None when the source is not
        checked.
    """
    check = _step_dependence(source, signal, dt, T, quiet, isolate, threshold, inspect)
    if check.found is None:
        return check.run
    raise _step_dependence_error(source, check, T)


def _step_dependence_error(source: Source, check: _StepCheck, T: float, before: str = "") -> DataError:
    """The one-line refusal of :func:`check_step_convergence` for what ``check`` found over ``t <= T`` (``before``:
    what coarser steps did, ahead of it)."""
    offers_me = offers_model_exchange(source)
    remedy = (f"use its model exchange ({ME}), or give {DT_T_END}" if offers_me else
              f"it offers no model exchange: give {DT_T_END}")
    if check.late:
        return DataError(f"{source_label(source)}: its co-simulation outputs lag its states by one communication "
                         f"step ({check.found} over t <= {T:g}), so a recording's outputs are dt late; {remedy} to "
                         "record at a step small against the motion; no file was written")
    return DataError(f"{source_label(source)}: the co-simulation depends on the communication step ({before}"
                     f"{check.found} over t <= {T:g}; one explicit step per doStep?), so no step chosen by the "
                     f"automatic window is accurate; {remedy} to record at a step of your choice; no file was written")


#: Steps of the 1-2-5 ladder below the first pilot's that :func:`pilot_step` tries where the co-simulation overflows
#: at the first pilot's step: down to about a hundredth of it (0.05 -> 0.0005).
STABLE_STEP_TRIES = 6

#: Outputs at a step off by more than this many times their peak (against a run at half the step) diverge: the
#: search of :func:`pilot_step` goes on past such a step as past one that overflowed (it never keeps one).
DIVERGED = 1.0

#: A first pilot whose outputs' peak exceeds this many times the peak of the run at half its step, which itself
#: does not grow once the input is constant, diverges at that step like one that overflows (audit 60: one RK4 step
#: per doStep at h omega = 2.9 reached 4e13 while the run at half the step stayed at 1.6): :func:`pilot_step`
#: searches for a smaller step.  Explicit Euler at the pilot steps grows at both (4e3 times, and 8 times the
#: model's peak at half the step): it stays refused at once, as diverging at both steps
#: (:func:`_diverges_at_both_error`).
DIVERGED_GROWTH = 1e3

#: Order of convergence above which the search of :func:`pilot_step` goes on past a step where the runs stay
#: bounded but differ by more than the threshold: the difference must fall at least ``(step ratio)**2`` from the
#: previous such step (RK4 just below its stability limit: 0.0167 at 0.02, 0.0015 at 0.01, 9.8e-5 at 0.005);
#: explicit Euler's falls about in proportion to the step (0.19 at 0.01, 0.07 at 0.005) and is refused there.
CONVERGENCE_ORDER = 2.0


@dataclasses.dataclass(frozen=True)
class StableStep:
    """The step :func:`pilot_step` found below the first pilot's, where the co-simulation overflowed or diverged.

    Attributes
    ----------
    dt : float
        The largest step tried at which the runs at ``dt`` and ``dt / 2`` are finite and agree.
    unstable_dt : float
        The smallest step tried at which they overflowed or diverged (:data:`DIVERGED`, :data:`DIVERGED_GROWTH`);
        steps between it and ``dt`` kept the runs bounded but not yet within the threshold.
    difference : float
        The outputs' largest difference at ``dt`` and ``dt / 2``, relative to their peak.
    run : Run
        The complete run at ``dt`` (the first pilot).
    discarded : bool
        The FMU discarded the step ``unstable_dt`` (``fmi2Discard``: an embedded solver's maximum step).
    """

    dt: float
    unstable_dt: float
    difference: float
    run: Any
    discarded: bool = False

    def window_fields(self) -> dict[str, Any]:
        """The :class:`Window` attributes that say where the step search ended."""
        return dict(stable_dt=self.dt, unstable_dt=self.unstable_dt, stable_difference=self.difference,
                    unstable_cause="discard" if self.discarded else "")


def pilot_step(source: Source, signal: Any, dt: float, T: float, *, quiet: bool = True, isolate: bool = False,
               threshold: float = STEP_CONVERGENCE, inspect: Callable[[Any], None] | None = None,
               max_steps: int = 400_000, tries: int = STABLE_STEP_TRIES) -> tuple[Any, StableStep | None]:
    """:func:`check_step_convergence` at the first pilot's step ``dt``, or, where the co-simulation diverges there,
    the largest step below it at which it is stable and converges.

    A co-simulation of a fixed number of explicit steps per ``doStep`` (RK4 substeps) is accurate at small
    communication steps and overflows above its stability limit (audit 58: four RK4 substeps of a chain with a
    1e6 N/m link, stable below dt = 0.011, was refused at the pilot steps 0.05 and 0.025 while ``--dt 0.01`` gave
    an exact ROM).  It diverges at ``dt`` where a run there turns non-finite, or grows beyond
    :data:`DIVERGED_GROWTH` times the peak of the run at ``dt / 2`` while that run does not grow once the input is
    constant (audit 60: 4e13 times, stable at half the step).  Then the steps 1, 2, 5 times a power of ten below
    ``dt`` are tried in turn (at most ``tries``, the runs within ``max_steps``), each checked against half of it
    like ``dt``: the first within ``threshold`` is the pilots' step and the window's largest; a step whose runs
    overflow or diverge (:data:`DIVERGED`) is passed, and so is one whose runs stay bounded but differ by more than
    ``threshold`` while that difference falls faster than :data:`CONVERGENCE_ORDER` (the first such step always:
    the next one tells how fast).  A difference that falls more slowly (explicit Euler) is refused there: no step
    within reach makes it accurate.

    Parameters
    ----------
    source, signal, dt, T, quiet, isolate, threshold, inspect
        As for :func:`check_step_convergence` (``inspect`` sees the run at ``dt`` only).
    max_steps : int, default=400000
        Largest run of the search (its runs at half a step).
    tries : int, default=STABLE_STEP_TRIES

    Returns
    -------
    run : Run or None
        The complete run at the pilots' step (None where the source is not checked).
    stable : StableStep or None
        The step found below ``dt``; None where ``dt`` itself passed.

    Raises
    ------
    DataError
        One line: the outputs depend on the step where they stay bounded and no smaller step within reach makes
        them accurate, or every step tried overflowed, diverged or had not converged yet, or the runs at ``dt`` and
        ``dt / 2`` both grow (the fix names a step below the smallest).
    """
    t_quiet = input_activity(signal, source.m)[0]
    check = _step_dependence(source, signal, dt, T, quiet, isolate, threshold, inspect, t_quiet=t_quiet,
                             search=True)
    if check.found is None:
        return check.run, None
    if check.both_grow:
        raise _diverges_at_both_error(source, check, T)
    if not (math.isinf(check.difference) or check.diverged):
        raise _step_dependence_error(source, check, T)
    step, unstable, bounded = dt, check, None
    for _ in range(tries):
        step = nice_floor(step / 2.0)
        if len(time_grid(step / 2.0, T)) > max_steps:
            break
        check = _step_dependence(source, signal, step, T, quiet, isolate, threshold, search=True)
        if check.found is None:
            return check.run, StableStep(step, unstable.dt, check.difference, check.run, unstable.discarded)
        if check.difference > DIVERGED:
            unstable = check
            continue
        if bounded is not None and not _converges(bounded, check):
            raise _step_dependence_error(source, check, T, before=f"{unstable.found}; {bounded.found}; ")
        bounded = check
    if bounded is not None:
        raise _unconverged_error(source, unstable, bounded, T)
    raise _unstable_error(source, unstable, T)


def _converges(before: _StepCheck, check: _StepCheck) -> bool:
    """Whether the outputs' difference fell from the step check ``before`` to ``check`` (a smaller step) faster than
    :data:`CONVERGENCE_ORDER`: a step smaller still is worth trying."""
    return check.difference * (before.dt / check.dt) ** CONVERGENCE_ORDER <= before.difference


def _unconverged_error(source: Source, unstable: _StepCheck, check: _StepCheck, T: float) -> DataError:
    """The one-line refusal of :func:`pilot_step` where the search ended (``tries``, ``max_steps``) at a step whose
    runs stay bounded and converge, but not yet within the threshold: the fix names a step below it."""
    step = check.dt
    remedy = f"use its model exchange ({ME}), or " if offers_model_exchange(source) else ""
    return DataError(f"{source_label(source)}: the co-simulation diverges at dt={unstable.dt:g} ({unstable.found}) "
                     f"and converges at smaller steps, but not yet at the smallest the automatic window tried "
                     f"({check.found} over t <= {T:g}); {remedy}give {either('--dt')} below {step:g} (e.g. "
                     f"{nice_floor(step / 2.0):g}) and {either('--t-end')} to record at a step of your choice; no file "
                     "was written")


def _diverges_at_both_error(source: Source, check: _StepCheck, T: float) -> DataError:
    """The one-line refusal of :func:`pilot_step` where the runs at the first pilot's step and at half of it both
    grow once the input is constant (explicit Euler per ``doStep``): a divergence, not a dependence on the step
    (audit 63, finding 8: 'differ by 6.5e+21 of their peak' was called step dependence); the fix names a step
    below both."""
    step = check.dt / 2.0
    remedy = (f"use its model exchange ({ME}), or give {either('--dt')}" if offers_model_exchange(source) else
              f"it offers no model exchange: give {either('--dt')}")
    return DataError(f"{source_label(source)}: the co-simulation diverges at both communication steps the automatic "
                     f"window tried ({check.found} over t <= {T:g}; explicit steps per doStep?); {remedy} below "
                     f"{step:g} (e.g. {nice_floor(step / 2.0):g}) and {either('--t-end')} to record at a step where "
                     "it stays "
                     "bounded; no file was written")


def _unstable_error(source: Source, check: _StepCheck, T: float) -> DataError:
    """The one-line refusal of :func:`pilot_step` where every step tried overflowed or diverged, the last one as
    ``check`` found it: the fix names a step below it."""
    step = check.dt
    remedy = f"use its model exchange ({ME}), or " if offers_model_exchange(source) else ""
    return DataError(f"{source_label(source)}: the co-simulation overflows or diverges at every communication step "
                     f"the automatic window tried, down to dt={step:g} ({check.found} over t <= {T:g}); {remedy}give "
                     f"{either('--dt')} below {step:g} (e.g. {nice_floor(step / 2.0):g}) and {either('--t-end')} to "
                     "record at a step of your choice; no file was written")


class _StepCheck(NamedTuple):
    """What :func:`_step_dependence` found between runs at ``dt`` and ``dt / 2``.

    ``found``: a phrase for a message (None: within the threshold, or a source that is not checked); ``run``: the
    complete run at ``dt`` (None if there is none); ``late``: only the outputs differ, one step late; ``difference``:
    the outputs' largest difference relative to their peak (``inf`` where a run turned non-finite, 0 unchecked);
    ``dt``: the coarser step compared; ``diverged``: the run at ``dt`` grew beyond :data:`DIVERGED_GROWTH` times the
    peak of the run at ``dt / 2``, which does not grow (judged only where the caller says when the input settles);
    ``both_grow``: it did, and the run at ``dt / 2`` grows too once the input is constant (the same proviso);
    ``discarded``: the FMU discarded the step ``dt`` (``difference`` is then ``inf``: searched below like an overflow).
    """

    found: str | None
    run: Any
    late: bool = False
    difference: float = 0.0
    dt: float = 0.0
    diverged: bool = False
    both_grow: bool = False
    discarded: bool = False


def _step_dependence(source: Source, signal: Any, dt: float, T: float, quiet: bool, isolate: bool,
                     threshold: float, inspect: Callable[[Any], None] | None = None,
                     t_quiet: float | None = None, search: bool = False) -> _StepCheck:
    """Compare runs at ``dt`` and ``dt / 2`` on ``[0, T]`` under the same held input (:class:`_StepCheck`); a source
    that is not a co-simulation FMU of a continuous-time model, or has a fixed step, is not checked.  ``t_quiet``:
    when the input stops changing, from which the run at ``dt / 2`` must not grow for the run at ``dt`` to count as
    diverged (None: not judged); ``search``: the caller is the step search of :func:`pilot_step`, which takes a step
    the FMU discards at ``dt`` as one to search below (elsewhere the discard is the error it was: a step the user
    gave)."""
    if getattr(source, "interface", None) != "cs" or not continuous_recording(source.provenance()) \
            or fixed_internal_step(source) is not None or fixed_communication_step(source) is not None:
        return _StepCheck(None, None)  # a fixed step: the results cannot depend on a step that cannot be changed
    coarse = time_grid(dt, T)
    runs = []
    for t, held in ((coarse, signal), (time_grid(dt / 2.0, T), _HeldOn(signal, coarse))):
        run, failure = record_run(source, held, t, MemorySink, quiet, isolate,
                                  label=f"step check (dt={t[1] - t[0]:g}, t_end={T:g})", pilot=True)
        if failure is not None and search and not runs and DISCARDED in str(failure):   # audit 70, finding 9
            return _StepCheck(f"it discarded the communication step {dt:g}", None, False, math.inf, dt,
                              discarded=True)
        if failure is not None and "non-finite" not in str(failure):
            raise incomplete_error(failure, run, None)   # an FMU error: its own message (and hint) tells more
        runs.append(run if failure is None else None)
        if inspect is not None and len(runs) == 1 and failure is None:
            inspect(run)
    if runs[0] is None or runs[1] is None:
        steps = " and ".join(f"dt={step:g}" for step, run in ((dt, runs[0]), (dt / 2.0, runs[1])) if run is None)
        return _StepCheck(f"it produced non-finite values at {steps}", runs[0], False, math.inf, dt)
    y, y_fine = (np.asarray(run.y)[:, :run.k] for run in runs)
    difference = _relative_difference(y, y_fine[:, ::2])
    if difference <= threshold:
        return _StepCheck(None, runs[0], False, difference, dt)
    found = f"its outputs at dt={dt:g} and dt={dt / 2:g} differ by {difference:.2g} of their peak"
    if _outputs_one_step_late(runs, threshold):
        return _StepCheck(f"{found}, its states agree, and each output is the one of the communication point before",
                          runs[0], True, difference, dt)
    growth = _growth(y, y_fine)
    if t_quiet is not None and growth > DIVERGED_GROWTH and not _grows(runs[1], t_quiet):
        found = f"its outputs at dt={dt:g} grow to {growth:.2g} times the peak of those at dt={dt / 2:g}"
        return _StepCheck(found, runs[0], False, difference, dt, True)
    if t_quiet is not None and growth > DIVERGED_GROWTH and _grows(runs[1], t_quiet, unknown=False):
        found = (f"its outputs at dt={dt:g} grow to {growth:.2g} times the peak of those at dt={dt / 2:g}, which "
                 "grow too once the input is constant")
        return _StepCheck(found, runs[0], False, difference, dt, both_grow=True)
    return _StepCheck(found, runs[0], False, difference, dt)


def _growth(y: np.ndarray, y_fine: np.ndarray) -> float:
    """The peak of ``y`` over the peak of ``y_fine`` (``inf`` where that is 0 and ``y`` is not)."""
    peak, fine_peak = (float(np.abs(a).max()) if a.size else 0.0 for a in (y, y_fine))
    return peak / fine_peak if fine_peak > 0 else (math.inf if peak > 0 else 1.0)


def _grows(run: Any, t_quiet: float, samples: int = 20, unknown: bool = True) -> bool:
    """Whether ``run``'s outputs are larger in the second half of the time after ``t_quiet`` (the input constant)
    than in the first: a run that is itself unstable (``unknown`` where it is too short after the input to tell)."""
    t, y = np.asarray(run.t)[:run.k], np.asarray(run.y)[:, :run.k]
    after = np.nonzero(t >= t_quiet)[0]
    if after.size < samples or not y.size:
        return unknown
    middle = 0.5 * (t[after[0]] + t[-1])
    early, late = (np.abs(y[:, after[part]]).max() for part in (t[after] < middle, t[after] >= middle))
    return bool(late > early)


def _relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    """``max |a - b|`` relative to ``max |b|`` over their common columns (0 where ``b`` is 0)."""
    k = min(a.shape[1], b.shape[1])
    peak = float(np.abs(b[:, :k]).max()) if b.size else 0.0
    with np.errstate(over="ignore"):  # a run diverging near 1e308: inf, no NumPy warning
        return float(np.abs(a[:, :k] - b[:, :k]).max()) / peak if peak > 0 else 0.0


def _outputs_one_step_late(runs: Sequence[Any], threshold: float) -> bool:
    """Whether runs at ``dt`` and ``dt / 2`` have the same states at the coarse points while each coarse output is
    the fine run's half a step before it: outputs computed at the start of each ``doStep``, so that after it they
    belong to the point before (seventh audit: an FMU refused as "one explicit step per doStep?", its states exact)."""
    x, x_fine = (np.asarray(run.x)[:, :run.k] for run in runs)
    if not x.size or _relative_difference(x, x_fine[:, ::2]) > threshold:
        return False
    y, y_fine = (np.asarray(run.y)[:, :run.k] for run in runs)
    return y.shape[1] > 1 and _relative_difference(y[:, 1:], y_fine[:, 1::2]) <= threshold


def combine_windows(windows: Sequence[Window]) -> Window:
    """One window for several runs' windows: the finest step and the latest end, rounded up to that step's grid
    (the window that ends last speaks for the rest: its fade and stop rule); the fastest and slowest frequencies of
    all, their pilots counted together, and the smallest stable step of any (:class:`StableStep`)."""
    if len(windows) == 1:
        return windows[0]
    finest = min(windows, key=lambda w: w.dt)
    last = max(windows, key=lambda w: w.t_end)
    end = math.ceil(last.t_end / finest.dt - 1e-9) * finest.dt
    slowest = [w.f_min for w in windows if w.f_min > 0]
    limited = [w for w in windows if w.stable_dt]
    stable = min(limited, key=lambda w: w.stable_dt) if limited else last  # the tightest limit speaks for the rest
    return dataclasses.replace(last, dt=finest.dt, stable_dt=stable.stable_dt, unstable_dt=stable.unstable_dt,
                               stable_difference=stable.stable_difference, unstable_cause=stable.unstable_cause,
                               t_end=float(f"{end:.12g}"),
                               f_max=max(w.f_max for w in windows),
                               f_min=min(slowest) if slowest else 0.0, pilots=sum(w.pilots for w in windows),
                               pilot_dt=finest.pilot_dt, pilot_t_end=finest.pilot_t_end)


def fixed_internal_step(source: Source) -> float | None:
    """The step a co-simulation FMU declares it integrates with (FMI 3 ``CoSimulation/@fixedInternalStepSize``),
    or None.

    Communication steps should be whole multiples of it: the automatic window's pilots and its chosen step are
    (:func:`on_internal_steps`), a user's ``--dt`` that is not gets a warning.  The step check
    (:func:`check_step_convergence`) is skipped for such an FMU: with a fixed internal step its results do not
    depend on the communication step, whatever the accuracy of its integrator, which only model exchange
    (``--interface me``) puts in fmu-opinf's hands.
    """
    if getattr(source, "interface", None) != "cs":
        return None
    declared = getattr(getattr(getattr(source, "md", None), "coSimulation", None), "fixedInternalStepSize", None)
    try:
        step = float(declared)
    except (TypeError, ValueError):
        return None
    return step if math.isfinite(step) and step > 0 else None


def on_internal_steps(dt: float, internal: float | None) -> float:
    """``dt`` rounded down to a whole multiple of the FMU's fixed ``internal`` step (at least one; ``dt`` as it is
    without one)."""
    if internal is None:
        return dt
    return float(f"{max(1, math.floor(dt / internal + 1e-9)) * internal:.12g}")


def is_whole_multiple(dt: float, internal: float) -> bool:
    """Whether ``dt`` is a whole multiple of ``internal`` (to 1e-9 relative)."""
    ratio = dt / internal
    return ratio >= 1.0 - 1e-9 and abs(ratio - round(ratio)) <= 1e-9 * max(1.0, ratio)


def check_window_step(source: Source, signal: Any, window: Window, *, pilot_dt: float | None = None,
                      pilot_t_end: float | None = None, quiet: bool = True, isolate: bool = False,
                      max_dt: float | None = None, exact_dt: bool = False) -> None:
    """Refuse a co-simulation FMU whose results depend on the step recorded (``window.dt``, or ``max_dt`` where
    given) when it is coarser than the first pilot's, which :func:`check_step_convergence` checked before the pilots ran
    (the same span, at least 20 steps).  ``pilot_dt, pilot_t_end, max_dt, exact_dt``: as given to
    :func:`auto_window` (with ``exact_dt`` the check is the caller's)."""
    max_dt, exact_dt = _step_limit(source, max_dt, exact_dt)
    if exact_dt:
        return
    t_input, width = input_activity(signal, source.m)
    first_T, first_dt = _first_pilot(source, t_input, width, pilot_dt, pilot_t_end, max_dt, exact_dt)
    step = window.dt if max_dt is None else max_dt
    span = max(first_T, 20.0 * step)
    if window.t_limit:   # no check run past the latest time the pilots could reach
        span = min(span, window.t_limit)
    if step > first_dt * (1.0 + 1e-9):
        check_step_convergence(source, signal, step, span, quiet=quiet, isolate=isolate)


#: Share of a recording that :func:`warn_if_step_dependent` checks (at least 20 steps): its runs at ``dt`` and
#: ``dt / 2`` cost three times that share of the recording's steps.
STEP_CHECK_SHARE = 0.1


def warn_if_step_dependent(source: Source, signal: Any, dt: float, t_end: float, *, quiet: bool = True,
                           isolate: bool = False, threshold: float = STEP_CONVERGENCE) -> None:
    """Warn (one line) when a co-simulation FMU recorded at the user's own ``dt`` depends on that step.

    The automatic window refuses such FMUs (:func:`check_step_convergence`); with ``--dt`` given the user chose
    the step, so the recording goes on, but the data then follow the FMU's integrator, not the model (an
    explicit-Euler FMU at dt = 0.002 gave learned damping ratios 15-20 % off).  The check runs on the first
    :data:`STEP_CHECK_SHARE` of the window (at least 20 steps).
    """
    import warnings

    from ..errors import FmuOpinfWarning
    from ._notes import warn_recording

    internal = fixed_internal_step(source)
    if internal is not None and not is_whole_multiple(dt, internal):
        warnings.warn(f"{source_label(source)}: dt={dt:g} is not a whole multiple of the step the FMU integrates with "
                      f"(fixedInternalStepSize={internal:g}): its communication points fall between its own steps; "
                      f"give {either('--dt')} as a multiple, e.g. {on_internal_steps(dt, internal):g}", FmuOpinfWarning,
                      stacklevel=3)
    T = min(t_end, max(20.0 * dt, STEP_CHECK_SHARE * t_end))
    found, _, late, *_ = _step_dependence(source, signal, dt, T, quiet, isolate, threshold)
    if found is None:
        return
    if late:
        warn_recording(f"{source_label(source)}: the co-simulation's outputs lag by one communication step ({found} "
                       f"over t <= {T:g}): the recorded outputs are those of t - dt, and the ROM learns that lag; "
                       f"{f'record by model exchange ({ME}), or ' if offers_model_exchange(source) else ''}"
                       f"keep {either('--dt')} small against the motion", "late-outputs", stacklevel=3)
        return

    offers_me = offers_model_exchange(source)
    remedy = f"record by model exchange ({ME}) or at a smaller {either('--dt')}" if offers_me else \
        f"record at a smaller {either('--dt')} (it offers no model exchange)"
    warn_recording(f"{source_label(source)}: the co-simulation depends on the communication step ({found} over "
                   f"t <= {T:g}): the recording follows the FMU's integrator, not the model; {remedy}",
                   "step-dependent", stacklevel=3)


def _within_limit(window: Window, t0: float, t_limit: float) -> Window:
    """``window`` ending at the latest point of its grid at or before ``t_limit`` (:func:`auto_window`): its end is
    rounded up to its step, which may lie past the limit (a step that ends at an FMU's termination fails)."""
    last = t0 + math.floor((t_limit - t0) / window.dt * (1 + 1e-12) + 1e-9) * window.dt
    return dataclasses.replace(window, t_end=float(f"{min(window.t_end, last):.12g}"), t_limit=t_limit)


def _window(seen: _Pilot, t_stop: float, t0: float, dt: float, T: float, pilots: int, points_per_period: float,
            energy: float, fade: float, periods: float, t_input: float, stopped_by: str,
            internal: float | None = None, exact: float | None = None, stable: StableStep | None = None) -> Window:
    f_use = max(seen.f_max, 1.0 / max(t_stop - t0, dt))
    step = exact or on_internal_steps(nice_floor(1.0 / (points_per_period * f_use)), internal)
    if stable is not None:
        step = min(step, stable.dt)
    end = t0 + math.ceil((t_stop - t0) / step - 1e-9) * step
    return Window(dt=step, t_end=float(f"{end:.12g}"), f_max=seen.f_max, t_fade=seen.t_fade, peak=seen.peak,
                  pilot_dt=dt, pilot_t_end=T, pilots=pilots, points_per_period=points_per_period, energy=energy,
                  fade=fade, f_min=seen.f_min, periods=periods, t_input=t_input, stopped_by=stopped_by,
                  **({} if stable is None else stable.window_fields()))


#: Factor by which :func:`_alias_check` refines the step of a pilot that settled, and the steps of that pilot
#: after the input stopped that the check covers (a fast mode rings, and dies out, first).
ALIAS_REFINE, ALIAS_SPAN = 4.0, 256


class _AliasCheck(NamedTuple):
    """A check run (:func:`_alias_check`): its step ``dt``, the run, its fastest significant frequency ``f_max``,
    and whether that lies above the Nyquist frequency of the pilot's step (``aliased``)."""

    dt: float
    run: Any
    f_max: float
    aliased: bool

    def describe(self, coarse: float) -> str:
        """What the check found, for the progress line."""
        return (f"a pilot at dt={self.dt:g} shows significant content up to {self.f_max:.4g} Hz, above the "
                f"{0.5 / coarse:.4g} Hz that the pilot at dt={coarse:g} resolves (a fast mode was aliased there)")


def _alias_check(source: Source, signal: Any, dt: float, T: float, t_input: float, energy: float, fade: float,
                 quiet: bool, isolate: bool, internal: float | None, max_steps: int,
                 baseline: Any = None) -> _AliasCheck | None:
    """Run the pilot that settled at step ``dt`` again at :data:`ALIAS_REFINE` times smaller a step, and say whether
    its fastest significant frequency lies above the Nyquist frequency of ``dt`` (None where the step cannot be
    refined: an FMU's fixed internal step, or more than ``max_steps`` steps; or where the run at the finer step
    fails, which the recording at the pilot's step does not take).

    The samples of a pilot are exact whatever its step, so a mode above its Nyquist frequency is not missing from
    them: it is folded onto a slower frequency (aliased), and the spectrum cannot tell.  Audit 64, finding 2: an FE
    bar with its first mode at 100 Hz and 0.5 % damping, pilot step 0.05 (Nyquist 10 Hz): the mode ringed at
    0.001 Hz in the samples, the window took 1.8 Hz (dt = 0.02), neither rule that shrinks the training pulse fired,
    and the ROM was 57-253 % off.  At a step four times smaller the same ringing lies at 20 Hz, above the coarse
    Nyquist frequency; a resolved model shows the same spectrum at both steps and keeps its window.  A mode whose
    frequency is a whole multiple of ``ALIAS_REFINE / dt`` aliases to zero at both steps and is still missed.  The
    check ends :data:`ALIAS_SPAN` steps of ``dt`` after the input stopped (or at ``T``): a slow, lightly damped
    model's pilots run on for hundreds of periods (the paper's triple chain: its window ends at t = 884.5), and a
    check of the whole pilot would cost four times its steps."""
    fine = on_internal_steps(dt / ALIAS_REFINE, internal)
    t = time_grid(fine, min(T, t_input + ALIAS_SPAN * dt))
    if fine >= dt * (1.0 - 1e-9) or len(t) > max_steps:
        return None
    run, failure = record_run(source, signal, t, MemorySink, quiet, isolate,
                              f"auto window: alias check (dt={fine:g}, t_end={t[-1]:g})", pilot=True)
    if failure is not None:  # a check that cannot run says nothing: the pilot's window, at its step, stands
        return None
    seen = _analyse_pilot(source, signal, t, t_input, energy, fade, 0.0, quiet, isolate, run=run, baseline=baseline)
    return _AliasCheck(fine, run, seen.f_max, seen.f_max > 0.5 / dt)


class IfMoving:
    """A ``baseline`` for :func:`auto_window` that applies only where the model moves on its own (a constant load
    inside the model, a non-zero input start, a ``--set`` value): the first pilot run analysed tells it, from its
    samples before the pulse acts (the inputs are held there: a run without the pulse, at no extra run), or, where
    fewer than two samples precede the pulse, from one run of ``held`` on that pilot's grid.

    Attributes
    ----------
    held : Signal
        The pilots' input without its pulses (every input held).
    moving : str or None
        How the outputs moved without the pulse (:func:`largest_motion`), None where the model rests; ``...``
        (Ellipsis) until a pilot has told.
    armed : bool
        Whether the pilots are judged net of that motion.  Until armed the pilots are judged as they are, and a
        pilot tells :attr:`moving` only from its own samples before the pulse (no extra run): the default training
        arms it where those pilots find no window and the model moves (or may move), so that a model that found
        one before keeps it (a start off rest, a load whose response the pulse's dominates).
    """

    def __init__(self, held: Any, armed: bool = False) -> None:
        self.held = held
        self.moving: Any = ...
        self.armed = armed
        self._outputs: dict[tuple[float, float, int], np.ndarray] = {}

    @property
    def moves(self) -> bool:
        """Whether a pilot has told that the model moves on its own."""
        return self.moving is not ... and bool(self.moving)

    @property
    def may_move(self) -> bool:
        """Whether the model moves on its own, or no pilot could tell yet."""
        return self.moving is ... or bool(self.moving)

    def tell(self, source: Source, signal: Any, t: np.ndarray, y: np.ndarray, quiet: bool, isolate: bool) -> Any:
        """Whether the pilots are judged net of the model's own motion: :attr:`moving` where :attr:`armed`, else
        None.  Told once, by the first pilot that can: ``y``, the outputs of ``signal`` on the grid ``t``."""
        if self.moving is ...:
            before = _samples_before_pulse(signal, self.held, t)
            if before >= 2:
                self.moving = largest_motion(source, t[:before], np.atleast_2d(y)[:, :before])
            elif self.armed:
                run = response_without_pulse(source, self.held, t, quiet=quiet, isolate=isolate)
                self.moving = None if run is None else largest_motion(source, *run)
        return self.moving if self.armed and self.moving is not ... else None

    def net(self, source: Source, signal: Any, t: np.ndarray, y: np.ndarray, quiet: bool, isolate: bool,
            label: str) -> np.ndarray:
        """The outputs ``y`` of a pilot of ``signal`` on ``t`` net of a run of ``held`` on the same grid where the
        model moves on its own (that run made once per grid), as they are where it rests."""
        if not self.tell(source, signal, t, y, quiet, isolate):
            return y
        key = (float(t[0]), float(t[1] - t[0]), len(t))
        if key not in self._outputs:
            self._outputs[key] = _outputs_of(source, self.held, t, quiet, isolate, label)
        return y - self._outputs[key]


def _samples_before_pulse(signal: Any, held: Any, t: np.ndarray) -> int:
    """How many leading samples of a run of ``signal`` on ``t`` are those of a run of ``held``: every input takes its
    held value at them (an output at a sample may feel the input at that sample directly, so the first sample at
    which the pulse acts is not counted)."""
    u = np.atleast_2d(np.asarray(signal.sample(t), dtype=float))
    h = np.atleast_2d(np.asarray(held.sample(t[:1]), dtype=float))
    if u.shape[0] != h.shape[0]:
        return 0
    acting = np.nonzero(np.any(u != h, axis=0))[0]
    return int(acting[0]) if acting.size else len(t)


def _analyse_pilot(source: Source, signal: Any, t: np.ndarray, t_input: float, energy: float, fade: float,
                   growth: float, quiet: bool, isolate: bool, label: str = "auto window: pilot run",
                   run: Any = None, baseline: Any = None) -> _Pilot:
    """What a pilot on grid ``t`` shows; ``run``: a complete run of ``signal`` already recorded (the step check's
    first run), used where it is on the grid ``t``, otherwise the pilot is recorded here; ``baseline``: an input
    whose response on ``t`` is subtracted from the pilot's outputs first (:func:`auto_window`)."""
    if run is None or not np.array_equal(np.asarray(run.t), t):
        run, failure = record_run(source, signal, t, MemorySink, quiet, isolate, label, pilot=True)
        if failure is not None:
            refuse_growth(source, run, t_input)   # (a run that overflowed: say why, where it grew first)
            raise incomplete_error(failure, run, None)
    refuse_growth(source, run, t_input)
    held = _held_ratios(run, t_input)
    # only outputs that pass the input through (y = u) move: the model does not, and its spectrum is the pulse's
    if _rows_still(np.asarray(run.x)) and not _rows_still(np.asarray(run.y)):
        raise DataError(_motionless(source, signal, t, "positions"))
    y = np.asarray(run.y)
    note_pilot(signal, t, y)   # (the default training's amplitude check reuses the last one)
    if isinstance(baseline, IfMoving):
        y = baseline.net(source, signal, t, y, quiet, isolate, f"{label}: its drift without the pulse")
    elif baseline is not None:
        y = y - _outputs_of(source, baseline, t, quiet, isolate, f"{label}: its drift without the pulse")
    with np.errstate(over="ignore", invalid="ignore"):
        return dataclasses.replace(_judged_pilot(source, signal, t, y, t_input, energy, fade), held=held)


def _held_ratios(run: Any, t_input: float) -> np.ndarray | None:
    """:func:`~._growth.held_ratios` on the recorded samples of a pilot ``run``."""
    k = int(getattr(run, "k", len(run.t)))
    with np.errstate(over="ignore", invalid="ignore"):
        return held_ratios(np.asarray(run.t)[:k], np.asarray(run.x)[:, :k], np.asarray(run.y)[:, :k], t_input)


#: Each growth probe (:func:`probe_growth`) lasts this many times longer after the inputs are held than the run
#: before it, and the longest ends :data:`PROBE_REACH` times the window's (or the pilot's, if longer) held part after
#: the inputs are held.  An exponential growth's quarter ratios rise to the power 4 with each probe, a drift's stay
#: (2, 1.5, 1.33 from a pulse).  Over the reach, a growth passes :func:`~._growth.unbounded_growth` where
#: ``sigma >= 4 ln 3 / (16 S)`` (``S``: the window's held part), i.e. where it grows the response by 1.3 times or more
#: over the window; slower ones are not seen.
PROBE_FACTOR, PROBE_REACH = 4.0, 16.0


def probe_growth(source: Source, signal: Any, window: Window, dt: float, T: float, held: np.ndarray | None = None,
                 *, quiet: bool = True, isolate: bool = False, max_steps: int = 400_000,
                 t_limit: float | None = None) -> Window:
    """Run ever longer pilots of ``signal`` at the step ``dt`` where the pilot that settled on ``window`` (its end
    ``T``) shows positions that still rise steadily (:func:`~._growth.still_rising`), and refuse the window where
    one grows exponentially (:func:`refuse_growth`); ``window``, its probes counted, where none does.

    A growth too slow to pass the growth test within the pilot is not seen there, and the window, cut on the outputs
    alone, can end before it shows (audit 80, F3: an unstable direction at ``sigma = 0.1`` barely in the outputs,
    a window of 17.9 s, quarter ratios 0.95, 1.49, 1.50 in the positions; the ROM, stable by construction, was
    0.43-0.83 of range off the model over 60 s and nothing said so).  Each probe is :data:`PROBE_FACTOR` times
    longer after the inputs are held than the run before, up to :data:`PROBE_REACH` times the window's held part.
    The probes stop where the positions stop rising (steadily, or more than in the run before), where a probe would
    exceed ``max_steps`` or ``t_limit``, or where one fails (a probe that cannot run says nothing: the window
    stands, as after the alias check).  The window itself is kept: the probes only judge the growth.

    Parameters
    ----------
    source : Source
    signal : Signal
        The pilots' input.
    window : Window
        The window the pilot settled on.
    dt, T : float
        The settled pilot's step and end.
    held : (3,) ndarray, optional
        The settled pilot's quarter ratios (:func:`~._growth.held_ratios`): a probe goes on where the next one's
        last ratio rose above it (:func:`~._growth.still_rising`).
    quiet, isolate : bool
        As :func:`auto_window`'s.
    max_steps : int, default=400000
        Largest probe run.
    t_limit : float, optional
        The latest time a probe may run to (:func:`auto_window`'s).

    Returns
    -------
    Window
        ``window`` with the probes counted among its pilots and :attr:`Window.growth_probe` set.

    Raises
    ------
    GrowsWithoutBound
        A probe grows exponentially once the inputs are held.
    """
    t_input = window.t_input
    reach = t_input + PROBE_REACH * (max(window.t_end, T) - t_input)
    if t_limit is not None:
        reach = min(reach, float(t_limit))
    probes, end = 0, 0.0
    while T < reach * (1.0 - 1e-9):
        T = min(float(f"{t_input + PROBE_FACTOR * (T - t_input):.6g}"), reach)
        t = time_grid(dt, T)
        if len(t) > max_steps:
            break
        run, failure = record_run(source, signal, t, MemorySink, quiet, isolate,
                                  f"auto window: growth probe (dt={dt:g}, t_end={T:g})", pilot=True)
        probes += 1
        refuse_growth(source, run, t_input)
        end = float(t[min(int(getattr(run, "k", len(t))), len(t)) - 1])
        now = _held_ratios(run, t_input)
        if failure is not None or not still_rising(now, held):
            break
        held = now
    if not probes:
        return window
    return dataclasses.replace(window, pilots=window.pilots + probes, growth_probe=end)


def refuse_growth(source: Source, run: Any, t_input: float) -> None:
    """Refuse a pilot ``run`` whose response grows without bound once the inputs are held at ``t_input``
    (:func:`~._growth.unbounded_growth`): no window can wait for it, and no stable ROM follows it (audit 79b, F4:
    judged 'faded' against its own huge end value, the default impulse was narrowed twice and the window stopped
    after 28 s with advice on the pulse's width)."""
    k = int(getattr(run, "k", len(run.t)))
    with np.errstate(over="ignore", invalid="ignore"):
        growth = unbounded_growth(np.asarray(run.t)[:k], np.asarray(run.x)[:, :k], np.asarray(run.y)[:, :k], t_input)
    if growth is not None:
        raise growth_error(source, growth)


def _outputs_of(source: Source, signal: Any, t: np.ndarray, quiet: bool, isolate: bool, label: str) -> np.ndarray:
    """The outputs of a complete run of ``signal`` on the grid ``t`` (a failure raises, as a pilot's does)."""
    run, failure = record_run(source, signal, t, MemorySink, quiet, isolate, label, pilot=True)
    if failure is not None:
        raise incomplete_error(failure, run, None)
    return np.asarray(run.y)[:, :len(t)]


#: A drift fits a parabola over the second half of a run to this fraction of the output's range (a mode of period
#: P fits it to about ``(2 pi T / P)**2 / 12`` over a run of length T: only modes far slower than the run pass).
DRIFT_FIT = 1e-3

#: A drift still grows: the second half of the run holds at least this share of the output's range (a free body
#: accelerated from rest: 3/4; a model that settled by then: round-off).
DRIFT_SHARE = 0.5

#: The parabola's curvature must make at least this share of the output's change over the second half: a body that
#: accelerates (a free body under a constant force: 1/3), not one that coasts at a constant speed (0).
DRIFT_CURVATURE = 0.05


def accelerates_under_load(source: Source, signal: Any, t_end: float, *, quiet: bool = True,
                           isolate: bool = False, samples: int = 2000) -> str | None:
    """Whether the model, under the input ``signal`` (its inputs held: no pulse), accelerates away on its own over
    ``[0, t_end]``: a free body (a rigid-body mode, no spring to ground) under a constant load inside the model, a
    non-zero input start value or a ``--set`` value.  Its outputs then grow like ``t**2`` and never settle, and
    the automatic window, judging the response to its pulse, widened the pulse to t0 = 2e6 s and ran for a minute
    before refusing (audit 70, finding 2).

    The run is judged over its second half (:func:`drift_of`).  Outputs that are only velocities (growing like
    ``t``) are not seen.

    Returns
    -------
    str or None
        A phrase naming the output and its growth, or None where the model does not drift so (or the run failed).
    """
    held = response_without_pulse(source, signal, time_grid(t_end / samples, t_end), quiet=quiet, isolate=isolate)
    return None if held is None else drift_of(source, *held)


def response_without_pulse(source: Source, signal: Any, t: np.ndarray, *, quiet: bool = True,
                           isolate: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The times and outputs of a run of ``signal`` (the inputs held, no pulse) on the grid ``t``: what the model
    does on its own under a constant load.  None where the run failed (the pilots then meet, and report, the same
    failure)."""
    label = f"auto window: the response without the pulse (dt={t[1] - t[0]:g}, t_end={t[-1]:g})"
    run, failure = record_run(source, signal, t, MemorySink, quiet, isolate, pilot=True, label=label)
    if failure is not None:
        return None
    return np.asarray(t[:run.k]), np.asarray(run.y)[:, :run.k]


def drift_of(source: Source, t: np.ndarray, y: np.ndarray) -> str | None:
    """How the outputs ``y`` of a run without the pulse accelerate away (:func:`accelerates_under_load`), or None.

    Some output whose range is at least :data:`OUTPUT_FLOOR` of the largest changes over the run's second half by
    :data:`DRIFT_SHARE` of its range, fits a parabola to :data:`DRIFT_FIT` of it, bends by at least
    :data:`DRIFT_CURVATURE` of its change there (accelerates, does not coast), and moves away faster at the end
    (the acceleration and the velocity agree in sign: not a decay towards rest).  A model far slower than the run
    may pass as well."""
    ranges = np.ptp(y, axis=1) if y.size else np.zeros(0)
    if not ranges.size or not ranges.max() > 0:
        return None
    half = t >= 0.5 * t[-1]
    for i in np.argsort(-ranges):
        if ranges[i] >= OUTPUT_FLOOR * ranges.max() and _parabolic(t[half], y[i, half], ranges[i]):
            return f"{_output_names(source, len(ranges))[i]} grows like t^2, by {ranges[i]:.3g} over t <= {t[-1]:g}"
    return None


def largest_motion(source: Source, t: np.ndarray, y: np.ndarray) -> str | None:
    """The output that moves most in a run without the pulse, and by how much (``"y by 0.77 over t <= 10"``), or
    None where every output stays constant: the model rests at an equilibrium (the test of a motionless pilot,
    :func:`_judged_pilot`: a change above 1e-12 of the outputs' largest magnitude)."""
    if not y.size:
        return None
    ranges = np.ptp(y, axis=1)
    if not np.any(ranges > 1e-12 * max(float(np.abs(y).max()), 1e-300)):
        return None
    i = int(np.argmax(ranges))
    return f"{_output_names(source, len(ranges))[i]} by {ranges[i]:.3g} over t <= {t[-1]:g}"


def _output_names(source: Source, p: int) -> list[str]:
    """The source's output names, or ``y[i]`` where it gives none."""
    names = list(getattr(source, "output_names", None) or [])
    return names if len(names) == p else [f"y[{i}]" for i in range(p)]


def _parabolic(t: np.ndarray, y: np.ndarray, span: float) -> bool:
    """Whether ``y(t)`` accelerates away like a parabola (:func:`accelerates_under_load`); ``span``: its range."""
    if t.size < 16 or not span > 0:
        return False
    s = (t - t[0]) / (t[-1] - t[0])
    c, b, a = np.polyfit(s, y, 2)
    residual = float(np.abs(y - (a + b * s + c * s * s)).max())
    change = float(np.ptp(y))
    return (change >= DRIFT_SHARE * span and residual <= DRIFT_FIT * span and abs(c) >= DRIFT_CURVATURE * change
            and (b + 2.0 * c) * c > 0)


def _judged_pilot(source: Source, signal: Any, t: np.ndarray, y: np.ndarray, t_input: float, energy: float,
                  fade: float) -> _Pilot:
    """What the outputs ``y`` of a pilot on grid ``t`` show (:func:`_analyse_pilot`).  Called without NumPy's
    overflow warnings: the step check hands over its first run before it has judged whether the co-simulation
    diverges at that step, and squares of outputs near 1e200 overflowed to 'fmu-opinf: warning: overflow
    encountered in dot' three times before the search found a stable step (audit 63, finding 8)."""
    if y.size and not np.any(np.ptp(y, axis=1) > 1e-12 * max(float(np.abs(y).max()), 1e-300)):
        raise DataError(_motionless(source, signal, t))
    envelope = _Envelope.of(t, y, fade, t_input)
    t_fade, peak = _fade_from(t, envelope, fade)
    if peak == 0.0:
        raise DataError("the outputs do not respond to the input; use an impulse-like input that excites "
                        "the system")
    free = int(np.searchsorted(t, t_input - 1e-12 * max(1.0, abs(t_input))))
    free = free if len(t) - free >= 16 else 0
    faded = int(np.searchsorted(t, t_fade, side="right")) if math.isfinite(t_fade) else len(t)
    segment = slice(free, faded) if faded - free >= 16 else slice(free, len(t))
    own = in_own_units(y)
    f_max = _fastest_early_or_late(t[segment], own[:, segment], energy)
    f_min = slowest_frequency(t[free:], own[:, free:], energy)
    resolved = (t[-1] - t[free]) * f_min if f_min > 0 else 0.0
    return _Pilot(t_fade=t_fade, peak=peak, f_max=f_max, f_min=f_min, resolved_periods=float(resolved),
                  fade_estimate=_fade_estimate(t, envelope, fade))


def _rows_still(x: np.ndarray) -> bool:
    """Whether every row of a pilot's recorded positions or outputs ``x`` (rows, k) stays constant (within 1e-12 of
    their size, as :func:`_judged_pilot` judges outputs).  Positions that stay while outputs move: the model did not
    move, only outputs of direct feedthrough did (audit 77a, F2: with a force sensor y = u beside a Boolean enable
    held at false, the window took the pulse's own spectrum for the model's and chose dt = 5e-8)."""
    if x.ndim != 2 or not x.shape[0] or x.shape[1] < 2:
        return False
    return spread_is_round_off(x.min(axis=1), x.max(axis=1))


def spread_is_round_off(low: np.ndarray, high: np.ndarray) -> bool:
    """Whether rows that range over ``[low, high]`` all stay within 1e-12 of the largest magnitude among them: no
    row moves (the pilots' rule for outputs, :func:`_judged_pilot`, and the recording's, ``_write._runs_still``)."""
    size = max(float(np.max(np.maximum(np.abs(low), np.abs(high)), initial=0.0)), 1e-300)
    return not np.any(high - low > 1e-12 * size)


def _motionless(source: Source, signal: Any, t: np.ndarray, what: str = "outputs") -> str:
    """Why a pilot whose outputs (or positions: ``what``) stay constant cannot choose a window, and what to do
    (seventh audit, 2026-11-27: a model at rest at its equilibrium, its only input held as a parameter-like preload,
    went through twelve pilots to 'the output does not settle ... pass --dt and --t-end', which would record a
    constant).  The inputs held while it ran are named with their values and the ``--set`` that changes one
    (audit 77a, F2: a Boolean ``enable`` held at false was never named)."""
    values = held_values(source)
    real = [name for name, (kind, _, _) in values.items() if kind in ("Real", "Float64", "Float32")]
    what = (f"the {what} stay constant over t <= {t[-1]:g} (the model rests at an equilibrium and nothing "
            "moves it), so no window can be chosen and a recording would teach the fit nothing")
    driven = source.m and not isinstance(signal, NoInput)
    if not driven:
        fix = (f"drive an input: {either('--inputs', value=real[0])} (it is held at its start value now)" if real
               else f"start the model away from its equilibrium ({either('--set')} a start value) or give it an "
                    "input")
        values = {name: value for name, value in values.items() if name not in real}   # (--inputs names them)
    else:
        fix = "give an input that reaches the outputs (its amplitude, its channel)"
    if values:   # audit 77a, F2: a Boolean enable held at false was never named
        fix = f"{held_inputs_advice(values)}; or {fix}"
    return f"auto window: {what}; {fix}"


def held_values(source: Source) -> dict[str, list]:
    """The source's held inputs with their types and values (:meth:`FMUSource.held_input_values`); none for a
    source that holds no inputs (the built-in models)."""
    values = getattr(source, "held_input_values", None)
    return values() if callable(values) else {}


#: Outputs whose range is below this fraction of the largest one keep their size: a channel of round-off or
#: solver noise is not blown up to the size of the others.
OUTPUT_FLOOR = 1e-3


def in_own_units(y: np.ndarray) -> np.ndarray:
    """Each output divided by its range over the pilot, so that every output counts alike in the spectrum, whatever
    its units: a mode seen in one output only is not lost in the energy of another (two oscillators of 0.16 and
    1.6 Hz, each in an output of its own, ranges 43 and 2.8).  Outputs with a range below :data:`OUTPUT_FLOOR` of
    the largest are divided by the largest instead (kept as they are): an output of noise at 1e-7 scaled to full
    size set the step to its Nyquist frequency until the pilots gave up.  The fade keeps the outputs as they are: judged per output, a slowly fading position next to an
    acceleration sensor doubled the window and its pilots (an 8-mass chain: 147 -> 263 s, ROM exact either way)."""
    y = np.atleast_2d(y)
    ranges = np.ptp(y, axis=1) if y.size else np.zeros(y.shape[0])
    top = float(ranges.max()) if ranges.size else 0.0
    if top == 0.0:
        return y
    return y / np.where(ranges >= OUTPUT_FLOOR * top, ranges, top)[:, None]


def _coarsen_ok(f_max: float, dt: float, min_pilot_points: float, width: float | None) -> bool:
    """A pilot may take step ``dt`` if it resolves ``f_max`` twice over and the input pulse (if any)."""
    if f_max <= 0 or f_max * dt * 2.0 * min_pilot_points > 1.0:
        return False
    return width is None or dt <= width / 4.0


def _fade_estimate(t: np.ndarray, seen: _Envelope, fade: float) -> float:
    """Fade-out time extrapolated from the exponential decay of the envelope over the second half of
    the record; ``inf`` if it does not decay."""
    half = slice(len(t) // 2, len(t) - max(1, len(t) // 20))
    tt, ee = t[half], seen.envelope[half]
    keep = ee > 0
    if keep.sum() < 8 or seen.peak == 0:
        return math.inf
    slope, intercept = np.polyfit(tt[keep], np.log(ee[keep]), 1)
    if slope >= 0:
        return math.inf
    return float((math.log(fade * seen.peak) - intercept) / slope)


def _next_length(t: np.ndarray, seen: _Pilot, growth: float) -> float:
    """End of the next pilot: twice the extrapolated fade-out time, between 2 and ``growth**2`` times
    this pilot's length (``growth`` times when the envelope does not decay)."""
    length = float(t[-1] - t[0])
    if not math.isfinite(seen.fade_estimate):
        return t[0] + growth * length
    return t[0] + float(min(max(2.0 * (seen.fade_estimate - t[0]), 2.0 * length), growth**2 * length))


def input_activity(signal: Any, m: int, horizon: float = 1000.0, samples: int = 200_001) -> tuple[float, float | None]:
    """When the input stops changing, and the width of its pulse.

    The signal is sampled on ``[0, horizon]`` (a table: its own time range); the input is still changing
    where it differs from its final value by more than 1e-3 of the largest difference.

    Returns
    -------
    t_input : float
        Time from which the input stays constant (0 for a constant input or one that never settles).
    width : float or None
        Length of the pulse, where the input differs from both its first and its final value (None for a
        constant input, a step or an input that never settles).
    """
    exact = _exact_activity(signal)
    if exact is not None and m > 0:
        return exact
    t_range = getattr(signal, "t_range", None)
    end = float(t_range[1]) if t_range and math.isfinite(float(t_range[1])) and t_range[1] > 0 else horizon
    t = np.linspace(0.0, end, samples)
    try:
        u = np.atleast_2d(np.asarray(signal.sample(t), dtype=float))
    except Exception:  # a signal that cannot be sampled ahead: analyse the whole pilot
        return 0.0, None
    if m == 0 or u.size == 0:
        return 0.0, None
    from_end = np.abs(u - u[:, -1:]).max(axis=0)
    top = float(from_end.max())
    if top == 0.0:
        return 0.0, None
    changing = np.nonzero(from_end > 1e-3 * top)[0]
    t_off = float(t[min(changing[-1] + 1, len(t) - 1)])
    if t_off >= 0.99 * end:  # never settles (harmonic, chirp): no free response to wait for
        return 0.0, None
    from_start = np.abs(u - u[:, :1]).max(axis=0)
    pulse = np.nonzero((from_end > 1e-3 * top) & (from_start > 1e-3 * max(float(from_start.max()), 1e-300)))[0]
    if pulse.size == 0:  # a step: nothing to resolve
        return t_off, None
    return t_off, max(float(t[pulse[-1] + 1] - t[pulse[0]]), end / (samples - 1))


def _exact_activity(signal: Any) -> tuple[float, float | None] | None:
    """:func:`input_activity` from the parameters of impulses and steps (one, or several side by side: the
    latest end, the narrowest pulse; ``none`` channels do not count), None where any part must be sampled.

    Sampling on ``[0, 1000]`` at 5 ms missed a pulse of 0.5 ms (audit 2026-11-26: a model on a millisecond time
    scale, window chosen from a 'constant' input, max eps_y 0.51).
    """
    from ..signals import NoInput, StackedSignal

    base = getattr(signal, "base", signal)  # one spec driving every input
    parts = [p for p in (base.parts if isinstance(base, StackedSignal) else [base]) if not isinstance(p, NoInput)]
    found = [getattr(p, "activity", lambda: None)() for p in parts]
    if not found or any(f is None for f in found):
        return None
    widths = [w for _, w in found if w is not None]
    return max(t for t, _ in found), (min(widths) if widths else None)


def _step_limit(source: Source, max_dt: float | None, exact_dt: bool) -> tuple[float | None, bool]:
    """``max_dt, exact_dt`` of :func:`auto_window`; an FMU's fixed communication step takes their place unless the
    caller asks for an exact step of its own (a user's ``--dt``, warned about when it is not the FMU's step)."""
    if exact_dt and max_dt is None:
        raise InputSpecError("exact_dt needs the step: give max_dt")
    fixed = fixed_communication_step(source)
    if fixed is not None and not exact_dt:
        return fixed, True
    return (None if max_dt is None else float(max_dt)), exact_dt


def _first_pilot(source: Source, t_input: float, width: float | None, pilot_dt: float | None,
                 pilot_t_end: float | None, max_dt: float | None, exact_dt: bool) -> tuple[float, float]:
    """End and step of the first pilot: :func:`_pilot_start`, its step then exactly ``max_dt`` (``exact_dt``),
    or at most ``max_dt``, and a whole multiple of the FMU's fixed internal step."""
    T, dt = _pilot_start(t_input, width, pilot_dt, pilot_t_end)
    if exact_dt:
        return max(T, 100.0 * max_dt), max_dt  # a coarse given step: still enough samples to analyse
    dt = dt if max_dt is None else min(dt, max_dt)
    return T, on_internal_steps(dt, fixed_internal_step(source))


def _pilot_start(t_input: float, width: float | None, pilot_dt: float | None,
                 pilot_t_end: float | None) -> tuple[float, float]:
    """First pilot: the input's active part plus ten widths (at least 10 time units, or ``4 t_input + 20 width``
    where that is shorter: inputs on a millisecond scale), ten samples across the pulse (no pulse: 1000
    samples)."""
    if width is None:
        T = max(2.0 * t_input, 10.0) if pilot_t_end is None else float(pilot_t_end)
        return T, (T / 1000.0 if pilot_dt is None else float(pilot_dt))
    floor = min(10.0, 4.0 * t_input + 20.0 * width)
    T = max(t_input + 10.0 * width, floor) if pilot_t_end is None else float(pilot_t_end)
    dt = min(width / 10.0, T / 200.0) if pilot_dt is None else float(pilot_dt)
    return T, dt
