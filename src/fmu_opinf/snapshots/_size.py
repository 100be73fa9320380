"""What a recording will write and how long it will take, said before it starts (audit 79a, F2).

A 300-output, 15-input FE export recorded for 13.5 min and wrote 813 MB without a word up front (with ``-q``:
nothing at all for 14.5 min).  Before the first run is written, :func:`announce` predicts the file's size (runs x
samples x recorded rows x 8 bytes, before compression) and, from the pace of the runs this source has already
recorded in this process (the automatic window's pilots: a rough guide), the time; where either passes its
bar it says so in one line with the options that cut them.  After the first run, whose pace is the recording's own,
:func:`after_first_run` says the time of the rest where the line before did not, or said under half of it.
It also compares the predicted size with the free space, so that a recording
that cannot fit stops before it starts rather than after minutes of recording (the writer's own check,
:func:`fmu_opinf._hdf5.ensure_space`, runs block by block, late).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
import weakref
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._hdf5 import SPACE_MARGIN, free_space
from .._progress import duration_text
from .._validate import DT_T_END, either, values_said
from ..errors import FileFormatError, FmuOpinfWarning

__all__ = ["LARGE_BYTES", "LONG_SECONDS", "PACE_SAMPLES", "PROBE_SHARE", "SLOW_RUN_SECONDS", "SMALLEST_COMPRESSION",
           "TOLERANCE_BOUND", "Pace", "after_first_run", "announce", "note_pace", "predict", "recorded_rows",
           "tolerance_pace"]

#: Predicted file size (before compression) from which the recording says so up front: ``fit`` loads the whole
#: recording and builds data matrices of about its size several times (audit 79a, F1: 0.96 GB of memory for a
#: 68 MB file), so a file past 1 GB is where fit outgrows a workstation's memory.
LARGE_BYTES = 1e9
#: Predicted recording time from which the recording says so up front: past 5 min, a user without the figure
#: cannot tell a long recording from a hung one (the progress bar counts one run, not the recording).
LONG_SECONDS = 300.0
#: The smallest share of its raw size the gzip-compressed file is assumed to take (level 1 with shuffle; audit 79a's
#: FE recording took 0.75 of it): a recording whose raw size times this does not fit the free space is refused up
#: front; one that fits only compressed is warned about.
SMALLEST_COMPRESSION = 0.5

#: The runs recorded so far, per source: ``{pilot: [(samples, seconds), ...]}`` (pilots of the automatic window
#: apart), the last :data:`_KEPT_RUNS` of each.
_PACE: "weakref.WeakKeyDictionary[Any, dict[bool, list[tuple[int, float]]]]" = weakref.WeakKeyDictionary()
_KEPT_RUNS = 64
#: Runs of fewer samples are mostly their start (instantiation, initialization): alone they give no pace per sample.
PACE_SAMPLES = 50
#: The time each recording's up-front line predicted, by file (None: no line), for :func:`after_first_run`.
_SAID: dict[str, float | None] = {}


def note_pace(source: Any, samples: int, seconds: float, pilot: bool = False) -> None:
    """Add one run (``samples`` samples in ``seconds`` of wall time; ``pilot``: a pilot of the automatic window) to
    ``source``'s pace."""
    if samples <= 0 or not seconds >= 0:
        return
    try:
        pace = _PACE.setdefault(source, {False: [], True: []})
    except TypeError:   # (a source that cannot be referenced weakly has no pace)
        return
    runs = pace[bool(pilot)]
    runs.append((int(samples), float(seconds)))
    del runs[:-_KEPT_RUNS]


@dataclasses.dataclass(frozen=True)
class Pace:
    """What a run of a source costs: ``per_run`` seconds (starting the FMU, in its own process where isolated) plus
    ``per_sample`` seconds per sample; ``pilots``: read from the automatic window's pilots only."""

    per_run: float
    per_sample: float
    pilots: bool

    def seconds(self, grids: Sequence[np.ndarray]) -> float:
        """The time of one run per grid."""
        return len(grids) * self.per_run + float(sum(len(t) for t in grids)) * self.per_sample


def _pace(source: Any) -> Pace | None:
    """The pace of the runs recorded with ``source`` so far, and whether they were all pilots, whose
    pace is a rough guide: model exchange runs them at a looser tolerance (:meth:`pilot_accuracy`), on other grids
    (audit 79a's FE chains: 0.79 ms per sample in the pilots and 2.5 ms in the recording at 120 outputs; 6.9 ms in
    the pilots at 300 outputs, where the audit's recording took 4.2-6.3 ms); None where none was.

    A run's time is a start (the FMU instantiated and initialized, in a process of its own where isolated) plus its
    steps: where the runs have different lengths, both are fitted (non-negative least squares); where they have one
    length, the time is put on the samples; runs shorter than :data:`PACE_SAMPLES` alone (checks of a few steps,
    whose time is their start) give no pace.  Before 2026-12-08 it was always put on the samples: a 4-sample check
    run of 1.2 s before a recording of 801 samples predicted "about 9 min at 6.8e+02 ms per sample" for a recording
    of 1.5 s (AnchoredMSD.fmu, n = 600).
    """
    pace = _PACE.get(source) if _weakly(source) else None
    if not pace:
        return None
    pilots = not pace[False]
    runs = pace[pilots]
    if not runs:
        return None
    samples = np.array([count for count, _ in runs], dtype=float)
    seconds = np.array([time for _, time in runs])
    long = samples >= PACE_SAMPLES
    if not long.any():
        return None
    if len(np.unique(samples)) < 2:
        return Pace(0.0, float(seconds[long].sum() / samples[long].sum()), pilots)
    from scipy.optimize import nnls

    (per_run, per_sample), _ = nnls(np.column_stack([np.ones_like(samples), samples]), seconds)
    return Pace(float(per_run), float(per_sample), pilots)


def recorded_rows(source: Any) -> int:
    """Rows each sample of a run writes: time, the inputs, positions, velocities and accelerations, and outputs."""
    return 3 * int(source.n) + int(source.p) + int(source.m) + 1


def predict(source: Any, grids: Sequence[np.ndarray]) -> tuple[float, float | None]:
    """The recording's size in bytes before compression and its time in seconds at the pace of the runs already
    recorded with ``source`` (None where none was)."""
    samples = float(sum(len(t) for t in grids))
    nbytes = 8.0 * samples * recorded_rows(source)
    pace = _pace(source)
    return nbytes, None if pace is None else pace.seconds(grids)


def _weakly(source: Any) -> bool:
    try:
        weakref.ref(source)
    except TypeError:
        return False
    return True


def announce(source: Any, grids: Sequence[np.ndarray], path: Path) -> None:
    """Before recording ``grids`` (one per run) into ``path``: refuse a recording that cannot fit the free space,
    and say in one line (a warning, shown with ``-q`` too) what a large or long one will write and take, and what
    cuts it."""
    nbytes, seconds = predict(source, grids)
    _check_space(path, nbytes)
    long = seconds is not None and seconds > LONG_SECONDS
    _SAID[str(path)] = None
    if nbytes <= LARGE_BYTES and not long:
        return
    _SAID[str(path)] = seconds if seconds is not None else math.inf
    warnings.warn(_line(source, grids, path, nbytes, seconds), FmuOpinfWarning, stacklevel=3)


def after_first_run(source: Any, grids: Sequence[np.ndarray], path: Path, seconds: float) -> None:
    """After the first run of a recording (``seconds`` of wall time): where the other runs, at its pace, take over
    :data:`LONG_SECONDS` and the up-front line said no time, or under half of this, say how long in one line."""
    said = _SAID.pop(str(path), None)
    rest = sum(len(t) for t in grids[1:])
    if not rest or not len(grids[0]):
        return
    remaining = seconds / len(grids[0]) * rest
    if remaining <= LONG_SECONDS or (said is not None and said >= 0.5 * (seconds + remaining)):
        return
    warnings.warn(f"{path.name}: the first run took {duration_text(seconds)} ({1e3 * seconds / len(grids[0]):.2g} ms "
                  f"per sample): the other {len(grids) - 1} run(s) take about {duration_text(remaining)} more; to cut "
                  f"them: {either('--outputs')} or {either('--positions')} to record fewer rows, {either('--inputs')} "
                  f"to drive fewer inputs, {DT_T_END} for fewer samples", FmuOpinfWarning, stacklevel=3)


def _line(source: Any, grids: Sequence[np.ndarray], path: Path, nbytes: float, seconds: float | None) -> str:
    lengths = sorted({len(t) for t in grids})
    samples = f"{lengths[0]}" if len(lengths) == 1 else f"{lengths[0]} to {lengths[-1]}"
    rows = recorded_rows(source)
    what = (f"{path.name}: {len(grids)} run(s) of {samples} samples x {rows} recorded rows (positions, velocities "
            f"and accelerations of {source.n}, {source.p} outputs, {source.m} inputs, time) x 8 bytes = "
            f"{_size(nbytes)} before compression")
    pace = _pace(source)
    if seconds is not None and pace is not None:
        runs = ("the pilot runs' (a rough guide: model exchange runs them at a looser tolerance)" if pace.pilots
                else "the runs recorded so far")
        start = f" and {duration_text(pace.per_run)} per run" if pace.per_run > 0 else ""
        what += f", about {duration_text(seconds)} at {1e3 * pace.per_sample:.2g} ms per sample{start}, {runs}"
    cuts = (f"to cut them: {either('--outputs')} or {either('--positions')} to record fewer rows, "
            f"{either('--inputs')} to drive fewer inputs (one run each), {DT_T_END} for fewer samples")
    return f"{what}; {cuts}"


def _check_space(path: Path, nbytes: float) -> None:
    """Refuse up front a recording that cannot fit even compressed (:data:`SMALLEST_COMPRESSION`)."""
    free = free_space(path)
    if free >= nbytes + SPACE_MARGIN:
        return
    if free < SMALLEST_COMPRESSION * nbytes + SPACE_MARGIN:
        raise FileFormatError(f"cannot write {path}: the recording needs about {_size(nbytes)} before compression "
                              f"(at least {_size(SMALLEST_COMPRESSION * nbytes)} compressed) and only "
                              f"{_size(free)} are free; free space, choose another -o location, or record fewer "
                              f"rows ({either('--outputs')}, {either('--positions')}) or samples ({DT_T_END})")
    warnings.warn(f"{path.name}: the recording needs about {_size(nbytes)} before compression and {_size(free)} "
                  "are free: it fits only if compression saves enough; free space or choose another -o location",
                  FmuOpinfWarning, stacklevel=4)


def _size(nbytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes:.0f} bytes"


#: A run of a co-simulation FMU at a tolerance fmu-opinf passes it that takes longer than this (wall seconds) is
#: timed again over its first samples at the FMU's own tolerance (:func:`tolerance_pace`): the step check's first run
#: and the first pilots take seconds on a chain (audit86 F7: 183 s for the step check of an FMU whose RK4 substeps
#: follow the tolerance, 1e-10 by default, then pilots projected at about 50 min, with progress lines only).
SLOW_RUN_SECONDS = 10.0
#: Share of the slow run's samples (at least :data:`PACE_SAMPLES`) that :func:`tolerance_pace` runs again: at most
#: about a tenth of the slow run's time where the tolerance does not matter.
PROBE_SHARE = 0.1
#: Factor by which the run at the FMU's own tolerance must be faster per sample for :func:`tolerance_pace` to say
#: that the tolerance passed holds the FMU back (audit86's ``stiff_cs``: 30 ms and 1 ms per 0.05 s step).
TOLERANCE_BOUND = 4.0
#: The sources :func:`tolerance_pace` has timed (once per source and process).
_TIMED: "weakref.WeakSet[Any]" = weakref.WeakSet()


def tolerance_pace(source: Any, samples: int, seconds: float, what: str,
                   probe: Callable[[int], float | None]) -> str | None:
    """After a run of ``source`` (``samples`` in ``seconds`` of wall time; ``what`` names it, e.g. the step check's
    run): where the source is a co-simulation FMU given a tolerance (``--tolerance``, default 1e-10, passed to its
    ``setupExperiment``; docs/real-fmus.md: on purpose) and the run took over :data:`SLOW_RUN_SECONDS`, time
    ``probe(n)`` (the run's first ``n`` samples at the FMU's own tolerance, seconds or None where it failed), once per
    source; where that is :data:`TOLERANCE_BOUND` times faster per sample, warn in one line naming the FMU, the
    tolerance, both paces and the fixes, and return the line (None otherwise).

    The probe's time includes the FMU's start, so it understates the gain: the line is said only where the gain is
    plain.  An FMU whose embedded solver ignores the tolerance is not faster at its own and is not named."""
    tolerance = getattr(source, "tolerance", None)
    if (getattr(source, "interface", None) != "cs" or not isinstance(tolerance, float) or not tolerance > 0
            or not seconds > SLOW_RUN_SECONDS or samples < 2 * PACE_SAMPLES or not _weakly(source)
            or source in _TIMED):
        return None
    _TIMED.add(source)
    n = max(PACE_SAMPLES, int(PROBE_SHARE * samples))
    own = probe(n)
    if own is None or not own > 0:
        return None
    asked, loose = seconds / samples, own / n
    if not asked > TOLERANCE_BOUND * loose:
        return None
    from ._isolation import source_label

    line = (f"{source_label(source)}: its co-simulation integrates at the tolerance fmu-opinf passes it "
            f"({tolerance:g}, {either('--tolerance')}): {what} took {duration_text(seconds)} for {samples} steps, "
            f"{1e3 * asked:.4g} ms per step, against {1e3 * loose:.2g} ms per step over its first {n} at the FMU's own "
            f"tolerance; the automatic window's pilots and the recording go at that pace. Where a looser tolerance "
            f"is accurate enough: {either('--tolerance', value=1e-6)} ({values_said(('--tolerance', 0))}: the FMU's "
            f"own); or fewer steps: {DT_T_END}")
    warnings.warn(line, FmuOpinfWarning, stacklevel=3)
    return line
