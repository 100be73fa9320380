"""The test input of a comparison given none (``compare`` without ``--input``).

The paper tests its ROMs on a harmonic wave after training on an impulse (spec section 5).  Without a given input,
:func:`default_test_input` makes one from what the ROM knows: a harmonic on each input the training drove, on the
operating point (``offset``) the training drove it on,

* at a frequency in the widest gap between the ROM's natural frequencies (below or above the modes where no gap is
  wide enough, :data:`WIDEST_RESONANCE`), so that no lightly damped mode is driven at resonance, kept to at least
  :data:`PERIODS` periods in the comparison and :data:`SAMPLES_PER_PERIOD` samples per period; several inputs
  spread inside that band, so that the comparison tells them apart as the training did;
* as a cosine where the ROM has a rigid-body mode (a sine from rest pushes it into a drift that grows with time);
* at an amplitude, at most the training's, whose response in the ROM over the comparison (the start transient and
  any drift included) stays within :data:`PEAK_SHARE` of the outputs' peak in the ROM's simulation of its training
  runs: the model stays in the range it was trained in (audits of 2026-12-06: the training pulse's height at a
  mode drove models 13 to 323 times past their training peak; sized by the steady response alone, a free body
  drifted 2 to 18 times past it; each time a model that asserts a range failed);
* shifted in phase where that lets it swing wider within that range: a training that began with its offsets' step
  from rest reached its peak with that step, and the same step in the test left a harmonic in phase with its
  overshoot no amplitude at all.

With two driven inputs or more, ``compare`` also runs each input's harmonic alone (:func:`each_input_alone`): the
harmonics together, each at its own frequency, are judged by one error over outputs that the strongest input fills,
and a ROM 11 % of range off the base force of a two-force chain (where that force moves little) read 0.16 % with both
forces on (audit 72 F1's twostiff10.fmu and its r = 18 ROM; tests/test_compare_each_input.py).

The exported ROM FMU carries the input chosen for its own step and four times its training end in its
provenance.json (``default_test_input``), since its matrices are not at hand where it is compared.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from ._validate import either
from .errors import FmuOpinfError, InputSpecError

if TYPE_CHECKING:
    from .rom import SecondOrderROM

__all__ = ["default_test_input", "each_input_alone", "carried_for_grid", "training_peaks", "recorded_peaks",
           "cosine_phase", "training_band_top", "band_test_input", "PERIODS", "SAMPLES_PER_PERIOD", "PEAK_SHARE",
           "BAND_POWER"]

#: The fewest periods of the test harmonic within the comparison, and its fewest samples per period.
PERIODS, SAMPLES_PER_PERIOD = 4, 20

#: The share of the outputs' training peak that the test's response in the ROM may reach.
PEAK_SHARE = 0.5

#: Pole magnitudes up to this fraction of the largest are rigid-body motion (as ``fit`` says of its poles); so are
#: modes whose period is longer than the comparison by :data:`RIGID_PERIODS`, which do not swing within it.
RIGID, RIGID_PERIODS = 1e-12, 2.5

#: The narrowest gap between two natural frequencies (their ratio) the test harmonics are put in: a narrower one
#: lies within the modes' resonance peaks.
WIDEST_RESONANCE = 1.3

#: The smallest factor on the training amplitudes the sizing keeps within half the training peak; below it, the
#: offsets use up that half, and the harmonics get what is left below the whole peak (or where the offsets go).
SMALLEST_SCALE = 0.25

#: Steps of a simulation of the ROM this module makes at most (the training runs and the sizing run).
MAX_STEPS = 1_000_000

_FIX = f"pass a test input, e.g. {either('--input', value='harmonic:amplitude=1,omega=0.2')}"


def default_test_input(rom: "SecondOrderROM", dt: float, t_end: float,
                       band: tuple[float, float, str] | None = None) -> tuple[str, str]:
    """The test input of a comparison of ``rom`` on the grid ``dt``, ``t_end`` given none, and why (a phrase).
    ``band``: ``(low, high, phrase)`` to put the harmonics between the ROM's natural frequencies within
    ``[low, high]`` instead of the widest gap anywhere (:func:`band_test_input`), said by ``phrase``.

    Raises :class:`~fmu_opinf.errors.InputSpecError` where none can be made: no training run is recorded, or the
    input of a driven input was a table that is not at hand.
    """
    drives = _training_drives(rom.provenance.get("training_runs"), rom.m, rom.input_names)
    driven = [i for i, drive in enumerate(drives) if drive is not None]
    if not driven:
        return "none", "the training drove no input: the free response from the source's start, as trained"
    floor, ceiling = 2 * math.pi * PERIODS / t_end, 2 * math.pi / (SAMPLES_PER_PERIOD * dt)
    omega, rigid = _natural_frequencies(rom, floor)
    low, high, where = _frequency_band(omega, floor, ceiling)
    if band is not None:
        (low, high), where = _widest_gap_within(omega, max(band[0], floor), min(band[1], ceiling)), band[2]
    frequencies = [float(f"{low * (high / low) ** (0.25 + 0.5 * (j + 1) / (len(driven) + 1)):.3g}")
                   for j in range(len(driven))]
    waves = {i: {"omega": frequency, "phase": cosine_phase(frequency, dt) if rigid else 0.0, "offset": drives[i][1]}
             for i, frequency in zip(driven, frequencies)}
    trained = _within_pressure_share(rom, {i: drives[i][0] for i in driven}, waves)
    capped = [rom.input_names[i] for i in driven if trained[i] < drives[i][0]]
    amplitudes, scale, offsets, shift = _sized_within_ranges(rom, waves, trained, dt, t_end, rigid)
    waves, _, moved = _within_declared_ranges(rom, waves, amplitudes)   # the offsets for the final swing
    waves = {i: dict(wave, phase=float(f"{wave['phase'] + shift:.10g}")) for i, wave in waves.items()}
    spec = _spec(rom.m, waves, amplitudes)
    what = "a harmonic" if len(driven) == 1 else "a harmonic on each input the training drove,"
    how = _sizing_phrase(scale, offsets) + (", its phase shifted to let it swing wider" if shift else "") + moved
    if capped:
        how += f", {', '.join(capped)} by at most half of its offset (a pressure)"
    cosine = ", a cosine (the ROM has a rigid-body mode)" if rigid else ""
    return spec, f"{what} {where}{cosine}, {how}"


#: Share of each output's variation power (in the ROM's simulation of its training runs) that lies below the
#: frequency :func:`training_band_top` calls the top of the band the training excited.
BAND_POWER = 0.99


def training_band_top(rom: "SecondOrderROM") -> tuple[float, int] | None:
    """The top of the band the training excited: the highest, over the outputs, of the frequency (rad/s) below
    which :data:`BAND_POWER` of an output's variation power lies in the ROM's simulation of its training runs (each
    output less the line from its first to its last sample, so that a run that ends elsewhere than it began adds
    no edge), and that output (0-based); None where no training run can be simulated or no output moves.

    The ROM's own simulation stands in for the source's outputs, which compare does not have at hand: where it
    reproduces its training outputs, their spectra agree.  Audit base82, F3: a 20-mass chain on an ``Accelerate``
    support, the default pulse: 99 % of the absolute acceleration's power lay below 4.7 rad/s, of the relative
    outputs' below 0.80 and 2.4 rad/s; the default test, in the widest gap between the natural frequencies, was at
    0.59 rad/s.
    """
    top: tuple[float, int] | None = None
    for run in rom.provenance.get("training_runs") or []:
        try:
            dt, duration = float(run["dt"]), float(run["t_end"]) - float(run.get("t0", 0.0))
            if not (0 < dt and 0 < duration / dt <= MAX_STEPS):   # (also NaN; a data file's sizes)
                continue
            y = np.atleast_2d(rom.simulate(str(run["input_spec"]), dt, dt * round(duration / dt)).y)
        except (FmuOpinfError, KeyError, TypeError, ValueError, AttributeError):
            continue
        for j, frequency in enumerate(_band_tops(y, dt)):
            if frequency is not None and (top is None or frequency > top[0]):
                top = (frequency, j)
    return top


def _band_tops(y: np.ndarray, dt: float) -> list[float | None]:
    """Per output (rows of ``y``, sampled at ``dt``), the frequency (rad/s) below which :data:`BAND_POWER` of its
    variation power lies (less the line from its first to its last sample); None for an output that does not
    move."""
    line = y[:, :1] + (y[:, -1:] - y[:, :1]) * np.linspace(0.0, 1.0, y.shape[1])
    power = np.abs(np.fft.rfft(y - line, axis=1)) ** 2
    omega = 2 * math.pi * np.fft.rfftfreq(y.shape[1], dt)
    tops: list[float | None] = []
    for row in power:
        total = float(row.sum())
        if not (total > 0 and math.isfinite(total)):
            tops.append(None)
            continue
        tops.append(float(omega[min(int(np.searchsorted(np.cumsum(row) / total, BAND_POWER)), omega.size - 1)]))
    return tops


def band_test_input(rom: "SecondOrderROM", dt: float, t_end: float, chosen: str
                    ) -> tuple[str, str, float] | None:
    """A second test input of compare given none, at the top of the band the training excited
    (:func:`training_band_top`), where that lies above the frequencies of ``chosen`` (the default test input) by
    more than :data:`WIDEST_RESONANCE`: harmonics in the octave below that top, between the ROM's natural
    frequencies, sized as the default one (:func:`default_test_input`); ``(spec, why, top)``, or None.

    The default test sits in the widest gap between the natural frequencies, often below the modes a reduced order
    truncates, where the ROM is most accurate.  Audit base82, F3: the 20-mass ``Accelerate`` chain's r = 16 ROM was
    4.5e-3 of an output's range off the exact model at the default 0.59 rad/s, 2.4e-2 at 3 rad/s, 5.8e-2 at 5 rad/s,
    and compare said nothing but its eq. (19) figure, 9.3e-5."""
    from .signals import ParametricSignal, StackedSignal, parse_signal

    signal = parse_signal(chosen, rom.m)
    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    omegas = [p.params["omega"] for p in parts if isinstance(p, ParametricSignal) and p.kind == "harmonic"]
    found = training_band_top(rom)
    ceiling = 2 * math.pi / (SAMPLES_PER_PERIOD * dt)
    if not omegas or found is None or not min(found[0], ceiling) > WIDEST_RESONANCE * max(omegas):
        return None
    top, j = min(found[0], ceiling), found[1]
    name = rom.output_names[j] if j < len(rom.output_names or []) else f"y[{j + 1}]"
    where = (f"in the octave below {top:.3g} rad/s, the top of the band the training excited ({BAND_POWER:.0%} of "
             f"{name}'s variation power below it in the ROM's simulation of its training), between the ROM's "
             "natural frequencies")
    spec, why = default_test_input(rom, dt, t_end, band=(max(top / 2, WIDEST_RESONANCE * max(omegas)), top, where))
    return spec, why, top


def each_input_alone(spec: str, m: int, names: list[str]) -> list[tuple[str, str]]:
    """For the test input ``spec`` chosen without one given (harmonics on the driven inputs among the ``m`` named
    ``names``, ``none`` on the others), one ``(name, spec)`` per driven input in which it alone swings: the other
    harmonics at amplitude 0 keep their operating point (``offset``).  Empty where fewer than two inputs swing (the
    comparison itself then tells what each does).

    Raises :class:`~fmu_opinf.errors.InputSpecError` for a spec that is not ``m`` harmonics and ``none`` (a carried
    one is data: :func:`carried_for_grid` checks it first)."""
    from .signals import NoInput, ParametricSignal, StackedSignal, harmonic, parse_signal

    signal = parse_signal(spec, m)
    parts = list(signal.parts) if isinstance(signal, StackedSignal) else [parse_signal(spec)] * m
    if not all(isinstance(p, NoInput) or isinstance(p, ParametricSignal) and p.kind == "harmonic" for p in parts):
        raise InputSpecError(f"each input alone needs harmonics or 'none' per input, not {spec!r}; {_FIX}")
    swinging = [i for i, p in enumerate(parts) if isinstance(p, ParametricSignal) and p.params["amplitude"] != 0]
    if len(swinging) < 2:
        return []

    def held(part: Any) -> str:
        return "none" if isinstance(part, NoInput) else harmonic(**{**part.params, "amplitude": 0.0}).spec

    alone = []
    for i in swinging:
        specs = [parts[j].spec if j == i else held(parts[j]) for j in range(m)]
        alone.append((str(names[i]) if i < len(names) else f"u[{i + 1}]", ";".join(specs)))
    return alone


#: The largest share of its offset a harmonic swings a pressure by.
PRESSURE_SWING_SHARE = 0.5


def _within_pressure_share(rom: "SecondOrderROM", trained: dict[int, float], waves: dict[int, dict[str, float]]
                           ) -> dict[int, float]:
    """The training amplitudes, at most :data:`PRESSURE_SWING_SHARE` of the offset (three digits, rounded down) on an
    input in a pressure's unit that the training drove about a start away from 0: an absolute pressure about 1 bar
    trained by a pulse of 100 took a harmonic of 19.4 about 1 bar, down to -18.4 bar (audit 61, finding 3).  The
    unit is the one the snapshots recorded (the source's, or one its ``UnitDefinitions`` defined)."""
    from .sources._variables import is_pressure_about_start

    recorded = rom.provenance.get("snapshots")
    recorded = recorded if isinstance(recorded, dict) else {}
    units, model = recorded.get("input_units"), _RecordedUnits(recorded.get("unit_definitions"))
    if not (isinstance(units, list) and len(units) == rom.m):
        return trained
    out = dict(trained)
    for i, amplitude in trained.items():
        offset = waves[i]["offset"]
        if is_pressure_about_start(units[i], offset, model):
            out[i] = min(amplitude, _three_digits_down(PRESSURE_SWING_SHARE * abs(offset)))
    return out


class _RecordedUnits:
    """The ``unit_dimensions`` (:class:`~fmu_opinf.sources._variables.ModelInfo`'s) of the unit definitions a
    recording kept (``{name: {"base": {"kg": 1, ...}}}``, data: anything else is left out)."""

    def __init__(self, definitions: Any) -> None:
        from .sources._variables import _normalized_unit

        self.unit_dimensions: dict[str, dict[str, int]] = {}
        for name, entry in (definitions.items() if isinstance(definitions, dict) else ()):
            base = entry.get("base") if isinstance(entry, dict) else None
            if isinstance(name, str) and isinstance(base, dict) and all(
                    isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) for k, v in base.items()):
                self.unit_dimensions[_normalized_unit(name)] = {k: v for k, v in base.items() if v}


#: Rounds of sizing and moving the offsets into the declared ranges (:func:`_within_declared_ranges`), and the
#: smallest factor on the amplitudes from one round to the next.
_RANGE_ROUNDS, _SMALLEST_STEP = 3, 0.25


def _sized_within_ranges(rom: "SecondOrderROM", waves: dict[int, dict[str, float]], trained: dict[int, float],
                         dt: float, t_end: float, rigid: bool) -> tuple[dict[int, float], float | None, float, float]:
    """The test amplitudes (three digits, rounded down), the scale on the training's that the phrase reports
    (:func:`_sizing_phrase`: None where no peak is known), how far the offsets go and the phase shift
    (:func:`_scale_to_training_range`), with the offsets moved into the declared input ranges
    (:func:`_within_declared_ranges`): sized again where a smaller swing lets them move less."""
    amplitudes, scale, offsets, shift = dict(trained), None, 0.0, 0.0
    for _ in range(_RANGE_ROUNDS):
        placed, amplitudes, moved = _within_declared_ranges(rom, waves, amplitudes)
        scale, offsets, shift = _scale_to_training_range(rom, placed, amplitudes, dt, t_end, rigid)
        if not moved or scale is None or scale >= 1:
            break
        # (a quarter at least: where the moved offsets alone pass the limit, a rigid body's drift, a smaller swing
        # moves them less; audit 61: scaled to 0, no input swung at all)
        amplitudes, scale = {i: max(scale, _SMALLEST_STEP) * a for i, a in amplitudes.items()}, 1.0
    factor = 1.0 if scale is None else scale
    final = {i: _three_digits_down(factor * a) for i, a in amplitudes.items()}
    if moved and not any(final.values()):   # no swing the range allows stays within the limits: the smallest tried
        final, scale = {i: _three_digits_down(a) for i, a in amplitudes.items()}, 0.0   # (compare says it goes past)
    if scale is not None and any(final[i] < _three_digits_down(a) for i, a in trained.items()):
        scale = min(final[i] / a for i, a in trained.items() if a > 0)
    return final, scale, offsets, shift


def _within_declared_ranges(rom: "SecondOrderROM", waves: dict[int, dict[str, float]], amplitudes: dict[int, float]
                            ) -> tuple[dict[int, dict[str, float]], dict[int, float], str]:
    """The harmonics' offsets (the training's, in ``waves``) moved as little as lets each input swing by its
    amplitude within the range its training source declared (:meth:`SecondOrderROM.input_ranges`; where a range
    is narrower than the swing, the amplitude too), written to six digits, and a phrase that says so ("" where
    nothing moved).  The source refuses values outside, and so does the exported ROM FMU (audit 60: a harmonic
    about the training's 0 took a push-only input in [0, 30] to -0.58)."""
    low, high = rom.input_ranges()
    waves, amplitudes, moved = dict(waves), dict(amplitudes), []
    for i, wave in waves.items():
        offset = wave["offset"]
        lo, hi, given = float(low[i]), float(high[i]), amplitudes[i]
        if hi - lo < 2 * given:   # (rounded down below the half width: the samples' rounding stays inside)
            amplitude, centre = _three_digits_down(0.5 * (hi - lo) * (1 - 1e-6)), 0.5 * (lo + hi)
        else:
            amplitude, centre = given, offset
        margin = amplitude * (1 + 1e-9)   # (c - A in floating point may fall an ulp below lo)
        centre = _six_digits_inside(min(max(centre, lo + margin), hi - margin), lo + margin, hi - margin)
        waves[i], amplitudes[i] = dict(wave, offset=centre), amplitude
        if centre != offset or amplitude != given:
            moved.append(f"{rom.input_names[i]} about {centre:.6g} within its declared range [{lo:g}, {hi:g}]")
    return waves, amplitudes, (", " + "; ".join(moved) if moved else "")


def _six_digits_inside(value: float, low: float, high: float) -> float:
    """``value`` (in ``[low, high]``) to six significant digits, rounded towards the inside of the interval where
    the nearest six digits leave it (3.9800000000000004 in ``[3.9800000000000004, 30]``: 3.98001, audit 61: the
    spec printed the raw float); more digits where the interval is narrower than the sixth's unit."""
    for digits in range(6, 18):
        short = float(f"{value:.{digits}g}")
        if low <= short <= high:
            return short
        unit = 10.0 ** (math.floor(math.log10(abs(short))) - digits + 1)
        inward = float(f"{short + (unit if short < low else -unit):.{digits}g}")
        if low <= inward <= high:
            return inward
    return float(value)


def _three_digits_down(value: float) -> float:
    """``value >= 0`` to three significant digits, rounded towards zero (the sizing's largest amplitude is on the
    limit: rounded up, the response would pass it)."""
    if value <= 0:
        return 0.0
    unit = 10.0 ** (math.floor(math.log10(value)) - 2)
    return float(f"{math.floor(value / unit * (1 + 1e-12)) * unit:.3g}")


def _spec(m: int, waves: dict[int, dict[str, float]], amplitudes: dict[int, float]) -> str:
    """The input spec of harmonics ``waves`` (omega, phase, offset by input) at ``amplitudes``, ``none`` on the other
    inputs; one spec where every input gets the same."""
    from .signals import harmonic

    parts = [harmonic(amplitude=amplitudes.get(i, 0.0), **waves[i]).spec if i in waves else "none" for i in range(m)]
    return ";".join(parts) if len(set(parts)) > 1 else parts[0]


def _sizing_phrase(scale: float | None, offsets: float) -> str:
    """How the amplitudes were sized (:func:`_scale_to_training_range`), for the line ``compare`` prints."""
    if scale is None:
        return "at the training amplitude (no training peak is known to size it by: a fit of today records them)"
    longer = f" over this comparison (a shorter {either('--t-end')} keeps them nearer)" if abs(offsets) > 1 else ""
    if offsets < 0:
        return (f"its response in the ROM within the training peak or where the offsets alone take the outputs, "
                f"{-offsets:.2g} times it{longer}")
    if offsets <= PEAK_SHARE:
        text = "its response in the ROM within half of the outputs' training peak"
    else:
        text = (f"its response in the ROM within where the offsets alone take the outputs, {offsets:.2g} times their "
                f"training peak{longer}")
    return text + (", at the training amplitude" if scale == 1.0 else "")


def cosine_phase(omega: float, dt: float) -> float:
    """The phase that makes the held samples of a sine a cosine centred on each step, ``cos(omega (t_k + dt/2))``:
    their sums have no mean, so a rigid-body mode does not drift (held from ``cos(omega t_k)`` it drifted by
    ``A dt / 2m`` per unit time)."""
    return float(f"{math.pi / 2 + omega * dt / 2:.10g}")


def _natural_frequencies(rom: "SecondOrderROM", floor: float) -> tuple[np.ndarray, bool]:
    """The ROM's natural frequencies (pole magnitudes, a complex pair once), sorted, without its rigid-body modes,
    and whether it has one."""
    from .inference import model_poles

    poles = model_poles(rom.Mr, rom.Dr, rom.Kr) if rom.r else np.zeros(0, dtype=complex)
    omega = np.sort(np.abs(poles[np.isfinite(poles) & (poles.imag >= 0)]))
    rigid = omega <= max(RIGID * float(omega.max(initial=0.0)), floor / (PERIODS * RIGID_PERIODS))
    if not omega.size:
        raise InputSpecError(f"no test input given, and the ROM has no pole to choose one by; {_FIX}")
    return omega[~rigid], bool(rigid.any())


def _frequency_band(omega: np.ndarray, floor: float, ceiling: float) -> tuple[float, float, str]:
    """The ends of the band the test harmonics take, and where that is (a phrase): the widest gap (on a log scale)
    between two natural frequencies inside ``[floor, ceiling]``, where a limit with modes beyond it counts as one,
    if it is wider than :data:`WIDEST_RESONANCE`; else the band just below the lowest mode there (above the
    highest if that is below ``floor``); by ``floor`` or ``ceiling`` where every mode lies outside."""
    band = ("" if not omega.size else f"the ROM's natural frequency {omega[0]:.3g} rad/s" if omega.size == 1
            else f"the ROM's natural frequencies {omega.min():.3g} .. {omega.max():.3g} rad/s")
    inside = omega[(omega >= floor) & (omega <= ceiling)]
    if inside.size:
        points = np.concatenate([[floor] if omega.min() < floor else [], inside,
                                 [ceiling] if omega.max() > ceiling else []])
        k = int(np.argmax(np.diff(np.log(points)))) if points.size >= 2 else 0
        if points.size >= 2 and points[k + 1] / points[k] > WIDEST_RESONANCE:
            return float(points[k]), float(points[k + 1]), f"in the widest gap between {band}"
        if inside[0] / 2 >= floor:
            return inside[0] / 2, inside[0] / 1.2, f"below {band}"
        return inside[-1] * 1.2, max(min(inside[-1] * 2, ceiling), inside[-1] * 1.2), f"above {band}"
    if not omega.size or omega.max() < floor:   # every mode slower than the comparison holds periods of
        return floor, min(floor * 2, ceiling), (f"at the slowest frequency with {PERIODS} periods in the comparison"
                                                + (f" ({band})" if band else ""))
    return max(ceiling / 2, floor), ceiling, (f"at the fastest frequency with {SAMPLES_PER_PERIOD} samples per "
                                              f"period ({band})")


def _widest_gap_within(omega: np.ndarray, low: float, high: float) -> tuple[float, float]:
    """The widest gap (on a log scale) between the natural frequencies ``omega`` inside ``[low, high]``, the band's
    ends counted as ones: where the band is full of modes, the test stays in it however narrow the gaps (the sizing
    keeps a resonance's response within the training's range), unlike :func:`_frequency_band`, which leaves it."""
    points = np.concatenate([[low], omega[(omega > low) & (omega < high)], [high]])
    k = int(np.argmax(np.diff(np.log(points))))
    return float(points[k]), float(points[k + 1])


def _scale_to_training_range(rom: "SecondOrderROM", waves: dict[int, dict[str, float]],
                             amplitudes: dict[int, float], dt: float, t_end: float,
                             rigid: bool) -> tuple[float | None, float, float]:
    """The factor ``k`` (at most 1) on the training amplitudes that keeps the ROM's response to the test input over
    the comparison, its offsets' step response included (audit 52: left out, 1.3 times the training peak), within
    :data:`PEAK_SHARE` of each output's training peak, or within where the offsets alone take it if that is
    farther; None where no training peak is known.  Also how far the offsets alone go (times the peak), negative
    where that left less than :data:`SMALLEST_SCALE` and the limit is the whole peak (audit 53: half the peak on
    top of the offsets reached 1.3 times it); and the shift of the harmonics' phases that allows the largest
    ``k`` where the unshifted ones need ``k < 1`` (:func:`_best_shift`)."""
    peaks = training_peaks(rom)
    if peaks is None:
        return None, 0.0, 0.0
    grid = dt * min(round(t_end / dt), MAX_STEPS)
    base = _departure(rom, _spec(rom.m, waves, {}), dt, grid)
    swing = _departure(rom, _spec(rom.m, waves, amplitudes), dt, grid) - base
    reach = np.abs(base).max(axis=1)
    peaks = np.where(peaks > 0, peaks, np.inf)
    offsets = float((reach / peaks).max())
    quadrature: list[np.ndarray] = []

    def shifted() -> Iterator[tuple[float, np.ndarray]]:
        if rigid:   # (only a half turn keeps each held cosine centred on its step)
            yield math.pi, -swing
            return
        if not quadrature:   # the response to the harmonics a quarter period ahead
            ahead = {i: dict(wave, phase=wave["phase"] + math.pi / 2) for i, wave in waves.items()}
            quadrature.append(_departure(rom, _spec(rom.m, ahead, amplitudes), dt, grid) - base)
        for shift in _PHASE_SHIFTS[1:]:
            yield shift, math.cos(shift) * swing + math.sin(shift) * quadrature[0]

    scale, shift = _best_shift(base, swing, shifted, np.maximum(PEAK_SHARE * peaks, reach))
    if scale < SMALLEST_SCALE and offsets > PEAK_SHARE / 2:   # the offsets use up half the range: what is left of all
        scale, shift = _best_shift(base, swing, shifted, np.maximum(peaks, reach))
        return scale, -offsets, shift
    return scale, offsets, shift


#: The shifts of the harmonics' phases the sizing tries where the unshifted ones leave the amplitude below the
#: training's: none, then sixteen, a sixteenth of a turn apart, to four digits (none within a thirty-second of a
#: turn of a quarter or three quarters of a turn: a phase just past those is a step-centred cosine to
#: :func:`carried_for_grid`).
_PHASE_SHIFTS = (0.0,) + tuple(round((2 * j + 1) * math.pi / 16, 4) for j in range(16))


def _best_shift(base: np.ndarray, swing: np.ndarray, shifted: Any, limit: np.ndarray) -> tuple[float, float]:
    """The largest ``k`` in [0, 1] with ``|base + k s| <= limit`` (per output) over the window, for the response
    ``s`` to the harmonics as they are or shifted in phase, and the shift that gives it (0 where ``k = 1`` without
    one, and on a tie).  A training that began with its offsets' step from rest reached its peak with that step
    alone: unshifted, the harmonic on top of the same step got no amplitude at all; a harmonic that swings the
    other way during the step's overshoot got the training's (audit 53's case)."""
    scale = _largest_scale(base, swing, limit)
    if scale == 1.0:
        return 1.0, 0.0
    best = (scale, 0.0)
    for shift, response in shifted():
        candidate = _largest_scale(base, response, limit)
        if candidate > best[0]:
            best = (candidate, shift)
    return best


def _largest_scale(base: np.ndarray, swing: np.ndarray, limit: np.ndarray) -> float:
    """The largest ``k`` in [0, 1] with ``|base + k swing| <= limit`` at every sample, where ``|base| <= limit``
    (``limit`` per output): each sample bounds ``k`` by ``(limit - sign(swing) base) / |swing|``."""
    room = limit[:, None] - np.sign(swing) * base
    moving = swing != 0
    if not moving.any():
        return 1.0
    return float(np.clip(np.min(np.maximum(room[moving], 0.0) / np.abs(swing[moving])), 0.0, 1.0))


def _departure(rom: "SecondOrderROM", spec: str, dt: float, t_end: float) -> np.ndarray:
    y = rom.simulate(spec, dt, t_end).y
    return y - y[:, :1]


def training_peaks(rom: "SecondOrderROM") -> np.ndarray | None:
    """Each output's largest departure from its start in the training runs: as recorded by ``fit`` (the source's
    own outputs, fits since 2026-12-06), else in the ROM's simulation of the runs' inputs; None where neither is
    at hand (a table no longer there, a run without its grid)."""
    recorded = recorded_peaks(rom.provenance, rom.p)
    if recorded is not None:
        return recorded
    return _simulated_peaks(rom, [run for run in rom.provenance.get("training_runs") or [] if isinstance(run, dict)])


def recorded_peaks(provenance: dict[str, Any], p: int) -> np.ndarray | None:
    """Each of the ``p`` outputs' largest departure from its start over the training runs, as ``fit`` recorded it
    in ``provenance`` (``training_runs[*].output_peak``); None where a run lacks it."""
    runs = provenance.get("training_runs")
    recorded = [run.get("output_peak") if isinstance(run, dict) else None for run in runs or []]
    if not recorded or not all(isinstance(peak, list) and len(peak) == p for peak in recorded):
        return None
    try:
        peaks = np.max(np.asarray(recorded, dtype=float), axis=0)
    except (TypeError, ValueError):   # (a damaged file's)
        return None
    return peaks if np.isfinite(peaks).all() else None


def _simulated_peaks(rom: "SecondOrderROM", runs: list[dict]) -> np.ndarray | None:
    peaks = None
    for run in runs:
        try:
            dt, duration = float(run["dt"]), float(run["t_end"]) - float(run.get("t0", 0.0))
            if not (0 < dt and 0 < duration / dt <= MAX_STEPS):   # (also NaN; a data file's sizes)
                continue
            peak = np.abs(_departure(rom, str(run["input_spec"]), dt, dt * round(duration / dt))).max(axis=1)
        except (FmuOpinfError, KeyError, TypeError, ValueError, AttributeError):
            continue
        peaks = peak if peaks is None else np.maximum(peaks, peak)
    return peaks


def _training_drives(runs: Any, m: int, names: list[str] | None = None) -> list[tuple[float, float] | None]:
    """Per input, the largest amplitude the training runs drove it with and that run's offset (None: never
    driven); a table's columns are the inputs its header names among ``names``."""
    if not isinstance(runs, list) or not runs:
        raise InputSpecError(f"no test input given, and the ROM records no training run to choose one by; {_FIX}")
    drives: list[tuple[float, float] | None] = [None] * m
    for run in runs:
        parts = str(run.get("input_spec", "none") if isinstance(run, dict) else "none").split(";")
        for i in range(m):
            part = (parts[0] if len(parts) == 1 else parts[i] if i < len(parts) else "none").strip()
            if part.lower() == "none":
                continue
            drive = _drive_of(part, i if len(parts) == 1 else 0, names if len(parts) == 1 else None)
            if drive[0] > 0 and (drives[i] is None or drive[0] > drives[i][0]):
                drives[i] = drive
    return drives


def _drive_of(part: str, column: int, names: list[str] | None = None) -> tuple[float, float]:
    """(amplitude, offset) of one input's training spec ``part``; a table's (its ``column``, after its header put
    the columns where it names ``names``) are its largest departure from its first value and that value (to six
    digits)."""
    from .signals import ParametricSignal, TableSignal, by_input_names, parse_signal

    try:
        signal = parse_signal(part)
        signal = by_input_names(signal, names) if names is not None else signal
    except FmuOpinfError as exc:   # (a table no longer at hand)
        raise InputSpecError(f"no test input given, and the training input {part!r} cannot be read here ({exc}); "
                             f"{_FIX}") from None
    if isinstance(signal, ParametricSignal) and "amplitude" in signal.params:
        return abs(signal.params["amplitude"]), float(signal.params.get("offset", 0.0))
    if isinstance(signal, TableSignal):
        values = signal.values[min(column, signal.values.shape[0] - 1)]
        amplitude = float(np.abs(values - values[0]).max())
        start = float(f"{values[0]:.6g}")
        return amplitude, start if abs(start) > 1e-9 * amplitude else 0.0
    raise InputSpecError(f"no test input given, and the training input {part!r} has no amplitude to take one from; "
                         f"{_FIX}")


def carried_for_grid(spec: str, name: str, m: int, dt: float, t_end: float) -> str:
    """The test input an exported ROM FMU carries, its cosines' phases made for the step ``dt`` (a cosine centred on
    each step keeps a rigid-body mode from drifting; with the export's step it drifted at another one, audit 52).
    Refused unless it is harmonics (and ``none``) for its ``m`` inputs whose frequencies the grid resolves: the
    file is data, and its input was chosen for the FMU's own grid."""
    from .signals import NoInput, ParametricSignal, StackedSignal, harmonic, parse_signal

    try:
        short, tabled = len(spec) < 100 * max(m, 1) + 100, ".csv" in spec.lower()   # (no file is read for it)
        signal = parse_signal(spec, m) if short and not tabled else None
    except FmuOpinfError:
        signal = None
    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    if signal is None or not all(isinstance(p, NoInput) or isinstance(p, ParametricSignal) and p.kind == "harmonic"
                                 for p in parts):
        raise InputSpecError(f"no test input given, and the one {name} carries is not a harmonic test input for its "
                             f"{m} input(s); {_FIX}")
    omegas = [p.params["omega"] for p in parts if isinstance(p, ParametricSignal)]
    low, high = 0.99 * 2 * math.pi * PERIODS / t_end, 1.01 * 2 * math.pi / (SAMPLES_PER_PERIOD * dt)  # (3 digits)
    if any(not low <= w <= high for w in omegas):
        raise InputSpecError(f"no test input given, and the one {name} carries ({spec}) was chosen for its own step "
                             f"and training end: at dt={dt:g} up to t={t_end:g} it has fewer than {PERIODS} periods "
                             f"or {SAMPLES_PER_PERIOD} samples per period; {_FIX}")
    return ";".join("none" if isinstance(p, NoInput) else harmonic(**{
        **p.params, "phase": _for_step(p.params["phase"], p.params["omega"], dt)}).spec for p in parts)


def _for_step(phase: float, omega: float, dt: float) -> float:
    """A carried harmonic's phase for the step ``dt``: a step-centred cosine (:func:`cosine_phase`, made for the
    export's step: a phase past a quarter or three quarters of a turn by at most half of the twentieth of a turn
    that a step of at least :data:`SAMPLES_PER_PERIOD` per period gives) centred on ``dt``'s steps, with its
    half turn; any other phase as it is."""
    for turn in (0.0, math.pi):
        if 0.0 < phase - turn - math.pi / 2 <= 1.01 * math.pi / SAMPLES_PER_PERIOD:
            return float(f"{cosine_phase(omega, dt) + turn:.10g}")
    return phase
