"""The test input of a comparison given none (``compare`` without ``--input``).

The paper tests its ROMs on a harmonic wave after training on an impulse (spec section 5).  Without a given input,
:func:`default_test_input` makes one from what the ROM knows: a harmonic on each input the training drove, on the
operating point (``offset``) the training drove it on,

* at a frequency in the widest gap between the ROM's natural frequencies (below the one mode of a single-mode ROM),
  so that no lightly damped mode is driven at resonance, kept to at least :data:`PERIODS` periods in the comparison
  and :data:`SAMPLES_PER_PERIOD` samples per period; several inputs spread inside the gap, so that the comparison
  tells them apart as the training did;
* at an amplitude whose steady response, by the ROM's frequency response, reaches about half the outputs'
  training peak (split among the inputs), at most the training amplitude: the model stays in the range it was
  trained in (audit of 2026-12-06: the training pulse's height as a harmonic's amplitude at a mode drove a model
  13 to 323 times past its training peak, and an FMU that asserts a range failed).

The exported ROM FMU carries the input chosen for its training step and end in its provenance.json
(``default_test_input``), since its matrices are not at hand where it is compared.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import FmuOpinfError, InputSpecError

if TYPE_CHECKING:
    from .rom import SecondOrderROM

__all__ = ["default_test_input", "PERIODS", "SAMPLES_PER_PERIOD"]

#: The fewest periods of the test harmonic within the comparison, and its fewest samples per period.
PERIODS, SAMPLES_PER_PERIOD = 4, 20

#: The share of the outputs' training peak that the test's steady response reaches (the start adds a transient).
PEAK_SHARE = 0.5

#: Pole magnitudes up to this fraction of the largest are rigid-body motion, not a natural frequency (as ``fit``
#: says of its poles).
RIGID = 1e-12

_FIX = "pass --input SPEC, e.g. 'harmonic:amplitude=1,omega=0.2'"


def default_test_input(rom: "SecondOrderROM", dt: float, t_end: float) -> tuple[str, str]:
    """The test input of a comparison of ``rom`` on the grid ``dt``, ``t_end`` given none, and why (a phrase).

    Raises :class:`~fmu_opinf.errors.InputSpecError` where none can be made: no training run is recorded, or the
    input of a driven input was a table that is not at hand.
    """
    drives = _training_drives(rom.provenance.get("training_runs"), rom.m)
    driven = [i for i, drive in enumerate(drives) if drive is not None]
    if not driven:
        return "none", "the training drove no input: the free response from the source's start, as trained"
    poles = _poles(rom)
    omega = np.sort(np.abs(poles[poles.imag >= 0]))   # (a complex pair is one natural frequency)
    omega = omega[np.isfinite(omega) & (omega > RIGID * max(float(omega.max(initial=0.0)), 1e-300))]
    floor, ceiling = 2 * math.pi * PERIODS / t_end, 2 * math.pi / (SAMPLES_PER_PERIOD * dt)
    if not omega.size:
        raise InputSpecError(f"no test input given, and the ROM has no natural frequency to choose one by; {_FIX}")
    low, high, where = _frequency_gap(omega, floor, ceiling)
    peaks = _training_peaks(rom)
    specs = ["none"] * rom.m
    for j, i in enumerate(driven):
        frequency = low * (high / low) ** (0.25 + 0.5 * (j + 1) / (len(driven) + 1))
        amplitude, offset = drives[i]
        if peaks is not None:
            amplitude = _sized(rom, i, frequency, amplitude, peaks / len(driven))
        specs[i] = f"harmonic:amplitude={amplitude:.3g},omega={frequency:.3g}" + (
            f",offset={offset:.15g}" if offset else "")
    what = "a harmonic" if len(driven) == 1 else "a harmonic on each input the training drove,"
    size = (f"sized to {PEAK_SHARE:g} of the outputs' training peak" if peaks is not None
            else "at the training input's amplitude")
    return (";".join(specs) if len(set(specs)) > 1 else specs[0]), f"{what} {where}, {size}"


def _poles(rom: "SecondOrderROM") -> np.ndarray:
    from .inference import model_poles

    return model_poles(rom.Mr, rom.Dr, rom.Kr) if rom.r else np.zeros(0, dtype=complex)


def _frequency_gap(omega: np.ndarray, floor: float, ceiling: float) -> tuple[float, float, str]:
    """The ends of the frequency band the test harmonics take, and where that is (a phrase): the widest gap (on a
    log scale) between two natural frequencies inside ``[floor, ceiling]``, where a limit with modes beyond it
    counts as one; for one mode, the band just below it (above it if that is below ``floor``); by ``floor`` or
    ``ceiling`` where every mode lies outside."""
    band = f"the ROM's natural frequencies {omega.min():.3g} .. {omega.max():.3g} rad/s"
    inside = omega[(omega >= floor) & (omega <= ceiling)]
    if inside.size:
        points = np.concatenate([[floor] if omega.min() < floor else [], inside,
                                 [ceiling] if omega.max() > ceiling else []])
    if inside.size and points.size >= 2:
        k = int(np.argmax(np.diff(np.log(points))))
        return float(points[k]), float(points[k + 1]), f"in the widest gap between {band}"
    if inside.size:
        mode = float(inside[0])
        if mode / 2 >= floor:
            return mode / 2, mode / 1.2, f"below the ROM's one natural frequency, {mode:.3g} rad/s"
        return mode * 1.2, min(mode * 2, ceiling), f"above the ROM's one natural frequency, {mode:.3g} rad/s"
    if omega.max() < floor:   # every mode is slower than the comparison holds periods of
        return floor, min(floor * 2, ceiling), f"the slowest with {PERIODS} periods in the comparison ({band})"
    return max(ceiling / 2, floor), ceiling, f"the fastest with {SAMPLES_PER_PERIOD} samples per period ({band})"


def _sized(rom: "SecondOrderROM", i: int, omega: float, amplitude: float, peaks: np.ndarray) -> float:
    """``amplitude`` lowered until the steady response to input ``i`` alone at ``omega`` reaches at most
    :data:`PEAK_SHARE` of ``peaks`` in every output."""
    try:
        gain = np.abs(_frequency_response(rom, omega)[:, i])
    except np.linalg.LinAlgError:   # (an undamped mode at exactly this frequency: no steady response)
        return amplitude
    return min([amplitude] + [PEAK_SHARE * peak / g for peak, g in zip(peaks, gain) if g > 0 and peak > 0])


def _frequency_response(rom: "SecondOrderROM", omega: float) -> np.ndarray:
    """``H(i omega) = (Cp + i omega Cv) (K - omega^2 M + i omega D)^-1 B + Du``, (p, m) complex."""
    s = 1j * omega
    states = np.linalg.solve(rom.Kr + s * rom.Dr + s * s * rom.Mr, rom.Br.astype(complex))
    return (rom.Cpr + s * rom.Cvr) @ states + rom.Dur


def _training_peaks(rom: "SecondOrderROM") -> np.ndarray | None:
    """Each output's largest departure from its start in the ROM's simulation of its training runs (None where no
    run can be simulated here: a table no longer at hand)."""
    peaks = None
    for run in rom.provenance.get("training_runs") or []:
        try:
            duration = float(run["t_end"]) - float(run.get("t0", 0.0))
            y = rom.simulate(str(run["input_spec"]), float(run["dt"]), duration).y
        except (FmuOpinfError, KeyError, TypeError, ValueError):
            continue
        peak = np.abs(y - y[:, :1]).max(axis=1)
        peaks = peak if peaks is None else np.maximum(peaks, peak)
    return peaks


def _training_drives(runs: Any, m: int) -> list[tuple[float, float] | None]:
    """Per input, the largest amplitude the training runs drove it with and that run's offset (None: never
    driven)."""
    if not isinstance(runs, list) or not runs:
        raise InputSpecError(f"no test input given, and the ROM records no training run to choose one by; {_FIX}")
    drives: list[tuple[float, float] | None] = [None] * m
    for run in runs:
        parts = str(run.get("input_spec", "none") if isinstance(run, dict) else "none").split(";")
        for i in range(m):
            part = (parts[0] if len(parts) == 1 else parts[i] if i < len(parts) else "none").strip()
            if part.lower() == "none":
                continue
            drive = _drive_of(part, i if len(parts) == 1 else 0)
            if drive[0] > 0 and (drives[i] is None or drive[0] > drives[i][0]):
                drives[i] = drive
    return drives


def _drive_of(part: str, column: int) -> tuple[float, float]:
    """(amplitude, offset) of one input's training spec ``part``; a table's (its ``column``) are its largest
    departure from its first value and that value."""
    from .signals import ParametricSignal, TableSignal, parse_signal

    try:
        signal = parse_signal(part)
    except FmuOpinfError:   # (a table no longer at hand)
        signal = None
    if isinstance(signal, ParametricSignal) and "amplitude" in signal.params:
        return abs(signal.params["amplitude"]), float(signal.params.get("offset", 0.0))
    if isinstance(signal, TableSignal):
        values = signal.values[min(column, signal.values.shape[0] - 1)]
        return float(np.abs(values - values[0]).max()), float(values[0])
    raise InputSpecError(f"no test input given, and the training input {part!r} has no amplitude to take one from "
                         f"here; {_FIX}")
