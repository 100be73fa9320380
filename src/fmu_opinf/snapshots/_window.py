"""Choosing the snapshot window: the step and end time (paper section 4.2, spec section 5)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..errors import DataError, InputSpecError
from ..sources import Source, open_source
from ._rates import time_grid
from ._record import MemorySink, as_signal, incomplete_error, record_run

__all__ = ["Window", "auto_window", "significant_frequency", "fade_time", "default_window"]


def default_window(source: Source, dt: float | None, t_end: float | None) -> tuple[float, float]:
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    if dt is None and experiment is not None and experiment.stepSize is not None:
        dt = float(experiment.stepSize)
    if t_end is None and experiment is not None and experiment.stopTime is not None:
        t_end = float(experiment.stopTime)
    if dt is None or t_end is None:
        missing = " and ".join(n for n, v in (("--dt", dt), ("--t-end", t_end)) if v is None)
        raise InputSpecError(f"no {missing} given and the source has no default; pass {missing} or --auto-window")
    return float(dt), float(t_end)


@dataclasses.dataclass
class Window:
    """Step and end time chosen from an impulse response (see :func:`auto_window`).

    Attributes
    ----------
    dt : float
        Chosen step: ``1 / (points_per_period * f_max)`` rounded down to 1, 2 or 5 times a power of ten.
    t_end : float
        Chosen end time: the fade-out time rounded up to a multiple of ``dt``.
    f_max : float
        Fastest significant frequency of the output response, in Hz (cycles per time unit).
    t_fade : float
        Time after which the output envelope stays below ``fade`` times its peak.
    peak : float
        Peak of ``||y(t) - y_rest||_2``.
    pilot_dt, pilot_t_end : float
        Grid of the last pilot run.
    pilots : int
        Number of pilot runs.
    points_per_period, energy, fade : float
        Thresholds used.
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

    def as_dict(self) -> dict[str, float]:
        """Plain dict (stored as the ``auto_window`` attribute)."""
        return {k: (int(v) if k == "pilots" else float(v)) for k, v in dataclasses.asdict(self).items()}

    def __str__(self) -> str:
        return (f"dt={self.dt:g}, t_end={self.t_end:g} (fastest significant frequency {self.f_max:.4g} Hz, "
                f"{self.points_per_period:g} points per period; output below {self.fade:g} of its peak after "
                f"t={self.t_fade:.4g}; {self.pilots} pilot run(s), last dt={self.pilot_dt:g}, "
                f"t_end={self.pilot_t_end:g})")


def significant_frequency(t: np.ndarray, y: np.ndarray, energy: float = 0.999) -> float:
    """Smallest frequency below which a fraction ``energy`` of the output's spectral energy lies.

    The spectrum is that of the Hann-windowed, mean-free outputs (summed over outputs); the window
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
    r = (y - y.mean(axis=1, keepdims=True)) * np.hanning(y.shape[1])
    power = (np.abs(np.fft.rfft(r, axis=1)) ** 2).sum(axis=0)
    freqs = np.fft.rfftfreq(y.shape[1], d=float(t[1] - t[0]))
    total = power.sum()
    if total <= 0:
        return 0.0
    cumulative = np.cumsum(power) / total
    return float(freqs[min(int(np.searchsorted(cumulative, energy)), len(freqs) - 1)])


def fade_time(t: np.ndarray, y: np.ndarray, fade: float = 0.01) -> tuple[float, float]:
    """Time after which ``||y(t) - y_rest||_2`` stays below ``fade`` times its peak.

    ``y_rest`` is the mean output over the last 5 % of the samples (the state the response settles
    to).  Returns ``(t_fade, peak)``; ``t_fade`` is ``inf`` if the envelope never falls below.
    """
    y = np.atleast_2d(y)
    tail = max(1, y.shape[1] // 20)
    rest = y[:, -tail:].mean(axis=1, keepdims=True)
    e = np.linalg.norm(y - rest, axis=0)
    peak = float(e.max())
    if peak == 0.0:
        return float(t[0]), 0.0
    envelope = np.maximum.accumulate(e[::-1])[::-1]  # max over the rest of the run
    below = np.nonzero(envelope <= fade * peak)[0]
    below = below[t[below] >= t[int(np.argmax(e))]]
    return (float(t[below[0]]) if below.size else math.inf), peak


def _nice_floor(value: float) -> float:
    """Largest 1, 2 or 5 times a power of ten not above ``value``."""
    exponent = math.floor(math.log10(value))
    for mantissa in (5.0, 2.0, 1.0):
        candidate = mantissa * 10.0 ** exponent
        if candidate <= value * (1 + 1e-12):
            return float(f"{candidate:.12g}")
    return float(f"{10.0 ** exponent:.12g}")


def auto_window(
    source: Source | str,
    signal: Any,
    *,
    points_per_period: float = 20.0,
    energy: float = 0.999,
    fade: float = 0.01,
    pilot_dt: float | None = None,
    pilot_t_end: float | None = None,
    min_pilot_points: float = 8.0,
    growth: float = 4.0,
    max_pilots: int = 8,
    max_steps: int = 400_000,
    isolate: bool = False,
    quiet: bool = True,
) -> Window:
    """Choose step and end time from the response to an impulse-like input (paper sec. 4.2).

    Pilot runs record the outputs; the step resolves the fastest significant oscillation with
    ``points_per_period`` samples and the end time is when the vibrations have faded out:

    * ``f_max``: smallest frequency below which a fraction ``energy`` of the spectral energy of the
      outputs lies (Hann-windowed FFT of the pilot's free response, from when the input pulse has
      died out to ``t_fade``, :func:`significant_frequency`);
    * ``t_fade``: the envelope ``max_{s >= t} ||y(s) - y_rest||_2`` stays below ``fade`` times its
      peak afterwards (:func:`fade_time`).

    A pilot is refined (step / 4) while ``f_max`` has fewer than ``min_pilot_points`` samples per
    period, and extended (same step, so that the input pulse stays resolved) until ``t_fade`` lies
    in its first half: to twice the fade-out time extrapolated from the envelope's exponential decay,
    at least doubled and at most ``growth**2`` times longer.

    Parameters
    ----------
    source : Source or str
    signal : Signal or str
        Impulse-like training input.
    points_per_period : float, default=20
    energy : float, default=0.999
    fade : float, default=0.01
    pilot_dt, pilot_t_end : float, optional
        First pilot grid; default: the FMU's default experiment, else ``t_end=100``, ``dt=t_end/1000``.
    min_pilot_points : float, default=8
    growth : float, default=4
        Without a decaying envelope a pilot is extended ``growth`` times; never more than ``growth**2``.
    max_pilots : int, default=8
    max_steps : int, default=400000
        Largest pilot run.
    isolate : bool, default=False
        Run the pilots in a child process.
    quiet : bool, default=True

    Returns
    -------
    Window
    """
    source = open_source(source)
    signal = as_signal(signal, source.m)
    for name, value, low, high in (("energy", energy, 0.0, 1.0), ("fade", fade, 0.0, 1.0)):
        if not low < value < high:
            raise InputSpecError(f"{name}={value} must lie strictly between {low:g} and {high:g}")
    if points_per_period < 2:
        raise InputSpecError(f"points_per_period={points_per_period} must be at least 2 (Nyquist)")
    if source.p == 0:
        raise DataError("the source has no outputs; auto window needs outputs to analyse (pass --outputs)")
    T, dt = _pilot_start(source, pilot_dt, pilot_t_end)
    for pilot in range(1, max_pilots + 1):
        t = time_grid(dt, T)
        if len(t) > max_steps:
            break
        run, failure = record_run(source, signal, t, MemorySink, quiet, isolate)
        if failure is not None:
            raise incomplete_error(failure, run, None)
        t_fade, peak = fade_time(t, run.y, fade)
        free = _free_response(t, run.u)
        faded = int(np.searchsorted(t, t_fade, side="right")) if math.isfinite(t_fade) else len(t)
        segment = slice(free, faded) if faded - free >= 16 else slice(0, len(t))
        f_max = significant_frequency(t[segment], run.y[:, segment], energy)
        if peak == 0.0:
            raise DataError("the outputs do not respond to the input; use an impulse-like input that excites "
                            "the system")
        if f_max * dt * min_pilot_points > 1.0:
            dt /= 4.0
        elif not t_fade <= t[0] + 0.5 * (T - t[0]):
            T = float(f"{t[0] + _next_length(t, run.y, fade, growth):.6g}")
        else:
            f_use = max(f_max, 1.0 / max(t_fade - t[0], dt))
            step = _nice_floor(1.0 / (points_per_period * f_use))
            end = t[0] + math.ceil((t_fade - t[0]) / step - 1e-9) * step
            return Window(dt=step, t_end=float(f"{end:.12g}"), f_max=f_max, t_fade=t_fade, peak=peak, pilot_dt=dt,
                          pilot_t_end=T, pilots=pilot, points_per_period=points_per_period, energy=energy, fade=fade)
    raise DataError(f"auto window: the output does not settle or is not resolved within {max_pilots} pilot runs "
                    f"of at most {max_steps} steps (last dt={dt:g}, t_end={T:g}); pass --dt and --t-end")


def _next_length(t: np.ndarray, y: np.ndarray, fade: float, growth: float) -> float:
    """Length of the next pilot: twice the fade-out time extrapolated from the exponential decay of
    the envelope over the second half of this pilot, between 2 and ``growth**2`` times this length."""
    length = float(t[-1] - t[0])
    y = np.atleast_2d(y)
    rest = y[:, -max(1, y.shape[1] // 20):].mean(axis=1, keepdims=True)
    e = np.linalg.norm(y - rest, axis=0)
    envelope = np.maximum.accumulate(e[::-1])[::-1]
    half = slice(len(t) // 2, len(t) - max(1, len(t) // 20))
    tt, ee = t[half], envelope[half]
    keep = ee > 0
    if keep.sum() < 8 or e.max() == 0:
        return growth * length
    slope, intercept = np.polyfit(tt[keep], np.log(ee[keep]), 1)
    if slope >= 0:
        return growth * length
    t_fade = (math.log(fade * e.max()) - intercept) / slope
    return float(min(max(2.0 * (t_fade - t[0]), 2.0 * length), growth**2 * length))


def _free_response(t: np.ndarray, u: np.ndarray) -> int:
    """Index from which the input has died out (below 1e-3 of its peak), so the output shows the
    system's own vibrations; 0 if the input never dies out (then the whole pilot is analysed)."""
    magnitude = np.abs(u).max(axis=0) if u.size else np.zeros(len(t))
    top = magnitude.max() if magnitude.size else 0.0
    active = np.nonzero(magnitude > 1e-3 * top)[0] if top > 0 else np.array([], dtype=int)
    if active.size == 0:
        return 0
    start = int(active[-1]) + 1
    return start if len(t) - start >= max(16, len(t) // 4) else 0


def _pilot_start(source: Source, pilot_dt: float | None, pilot_t_end: float | None) -> tuple[float, float]:
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    T = pilot_t_end
    if T is None and experiment is not None and experiment.stopTime is not None:
        T = float(experiment.stopTime)
    T = 100.0 if T is None else float(T)
    dt = pilot_dt
    if dt is None and experiment is not None and experiment.stepSize is not None:
        dt = float(experiment.stepSize)
    return T, (T / 1000.0 if dt is None else float(dt))
