"""The runs of a recording written into one new snapshot file, and the checks after them.

``_record_file`` streams each run into its group of a file written atomically (the file's attributes:
``_file_attrs``, :func:`fixed_step_attrs`, ``_integrator_taken``), stops at the first failing run (kept,
incomplete), then checks the recording: whether any run moves (``_runs_still``, ``_warn_still``) and whether the
response scales with the inputs (``_check_inputs_scale``).  :class:`RecordSummary` says what was written.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from .._hdf5 import write_attrs
from ..errors import FmuOpinfError, FmuOpinfWarning
from ..sources import Source, StepError, fixed_communication_step
from ..sources._base import held_inputs_advice
from ._file import FILE_KIND, LAYOUT_VERSION, atomic, write_file_attrs
from ._growth import warn_if_grows
from ._initialization import initialization_of
from ._isolation import source_label
from ._linearity import check_given_input, input_departures, largest_runs
from ._notes import current_recording_notes
from ._run import STREAM_THRESHOLD, _H5Sink, _run_bytes, _versions, incomplete_error, record_run
from ._size import after_first_run, announce

if TYPE_CHECKING:
    from ._window import Window

__all__ = ["RecordSummary", "fixed_step_attrs"]


def _file_attrs(source: Source) -> dict[str, Any]:
    attrs = source.description()
    attrs.update({"kind": FILE_KIND, "layout_version": LAYOUT_VERSION, "versions": _versions()})
    attrs["created"] = attrs["versions"]["created"]
    attrs["derived_xdot"] = bool(source.derived["xdot"])
    attrs["derived_xddot"] = bool(source.derived["xddot"])
    return attrs


def fixed_step_attrs(source: Source, dt: float) -> dict[str, float]:
    """The file attribute ``fixed_communication_step`` where the recording step ``dt`` is the one communication
    step the FMU accepts (:func:`~fmu_opinf.sources.fixed_communication_step`), else {}: the fit then knows that no
    finer recording is possible and does not advise one (audit 70, F10: "record with --dt 0.02" for an FMU that
    refuses every step but 0.05)."""
    fixed = fixed_communication_step(source)
    if fixed is None or abs(dt - fixed) > 1e-9 * fixed:
        return {}
    return {"fixed_communication_step": float(fixed)}


def _integrator_taken(source: Source, runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The file attribute ``integrator`` saying which method the runs (their attributes ``runs``) took, for a source
    that chooses per run (:meth:`~fmu_opinf.sources.ModelExchangeSource.recorded_integrator`, ``--me-method
    auto``); {} for any other source or a run that does not say (the file then keeps the source's own text)."""
    recorded = getattr(source, "recorded_integrator", None)
    methods = [attrs.get("integrator_method") for attrs in runs]
    if recorded is None or not methods or not all(isinstance(method, str) for method in methods):
        return {}
    return {"integrator": recorded(methods)}


def _record_file(source: Source, signals: Sequence[Any], grids: Sequence[np.ndarray], path: Path, quiet: bool,
                 isolate: bool, overwrite: bool, window: "Window | None", check: str | None = None) -> "RecordSummary":
    """Stream every signal's run (on its grid in ``grids``: one step, each run's own end) into one new file; stop
    at the first failing run (kept, incomplete).  ``check``: where the response to the inputs recorded must be
    checked for scaling with them (:func:`_check_inputs_scale`, its warning kept in the file), whose inputs they
    are: ``"given"`` (the user's) or ``"default"`` (the default training's); None: not checked."""
    failure: StepError | None = None
    still = False
    t = grids[0]
    summary = RecordSummary(path=path, n=source.n, m=source.m, p=source.p, window=window,
                            dt=float(t[1] - t[0]) if len(t) > 1 else None)
    with atomic(path, overwrite) as f:
        announce(source, grids, path)   # (audit 79a, F2: the size and time up front)
        attrs = _file_attrs(source)
        attrs["dt"] = float(t[1] - t[0])
        attrs.update(fixed_step_attrs(source, attrs["dt"]))
        if window is not None:
            attrs["auto_window"] = window.as_dict()
        write_file_attrs(f, attrs)
        runs = f.create_group("runs")
        recorded: list[dict[str, Any]] = []   # (each run's attributes: its samples stay in the file)
        for index, signal in enumerate(signals):
            group = runs.create_group(f"{index:04d}")

            def factory(src: Source, tt: np.ndarray, uu: np.ndarray, g: h5py.Group = group) -> _H5Sink:
                return _H5Sink(src, tt, uu, g, path)

            run, failure = record_run(source, signal, grids[index], factory, quiet, isolate)
            recorded.append(run.attrs)
            if failure is None:   # (audit 79b, F4: a model unstable at its operating point; fit and export repeat it)
                warn_if_grows(source, signal, run)
            if index == 0 and run.k == 0:
                raise failure or StepError(f"{source_label(source)} recorded no sample in its first run", 0,
                                           float(t[0]))
            if index == 0:
                after_first_run(source, grids, path, run.attrs["wall_seconds"])
                first_input = np.asarray(run.u[:, 0], dtype=float) if source.m else np.zeros(0)
                first_position = np.asarray(run.x0, dtype=float)
            if window is not None:
                group.attrs["auto_window"] = json.dumps(window.as_dict())
            summary.runs.append((run.k, run.complete, run.attrs["input_spec"]))
            summary.events.append(run.attrs.get("events"))
            if failure is not None:
                failure = incomplete_error(failure, run, path)
                break
        if failure is None:  # the input the first run started under, as recorded (Float32 inputs rounded)
            summary.initialization = initialization_of(source, t, first_input, first_position, isolate)
            write_attrs(f, {"initialization": summary.initialization})
            still = _runs_still([runs[name] for name in runs])
            if check and not still:
                _check_inputs_scale(source, signals, grids, [runs[name] for name in runs], quiet, isolate,
                                    check == "given")
        f.attrs["n_runs"] = len(summary.runs)
        write_attrs(f, _integrator_taken(source, recorded))
        write_attrs(f, current_recording_notes())   # (audit 70 F4: fit, compare and export repeat them)
    if failure is not None:
        raise failure
    if still:
        _warn_still(source, path)
    return summary


def _check_inputs_scale(source: Source, signals: Sequence[Any], grids: Sequence[np.ndarray], groups: Sequence[Any],
                        quiet: bool, isolate: bool, given: bool = True) -> None:
    """Warn where the model's response to an input recorded does not scale with it
    (:func:`~._linearity.check_given_input`): the inputs stay as given, the warning is kept in the file.  Only the
    runs that drive some input furthest are judged (:func:`~._linearity.largest_runs`: one extra run each, where
    the model rests); a run without any input departure on the same grid (``none``) is the model's own motion.  A run
    above :data:`STREAM_THRESHOLD` bytes is not judged (the check holds its runs in memory), said in one line.
    ``given``: the inputs are the user's (else the default training's, named so in the warning)."""
    departures = [input_departures(source, signal, t) for signal, t in zip(signals, grids)]
    for index in largest_runs(departures):
        t = grids[index]
        size = _run_bytes(source, len(t))
        if size > STREAM_THRESHOLD:
            if not quiet:
                print(f"run {index:04d} is not checked for a response that scales with its input: its "
                      f"{size / 2**20:.0f} MiB exceed what the check holds in memory "
                      f"({STREAM_THRESHOLD / 2**20:.0f} MiB); check a shorter run of the same input", file=sys.stderr)
            continue
        free = next((np.asarray(groups[j]["y"][:, :len(t)]) for j, d in enumerate(departures)
                     if not np.any(d) and len(grids[j]) == len(t) and np.array_equal(grids[j], t)), None)
        try:
            check_given_input(source, signals[index], t, np.asarray(groups[index]["y"]), free, quiet, isolate,
                              given)
        except FmuOpinfError:   # a run of the check that fails says nothing: the recording stands, as without it
            continue


def _runs_still(runs: Sequence[Any]) -> bool:
    """Whether no recorded position or output moves in any run (:func:`~._window.spread_is_round_off`, as the
    automatic window's pilots judge): a recording the fit cannot
    learn from.  ``runs``: :class:`Run` objects or run groups of a file, read in column blocks.  Runs of one sample
    show nothing either way: False where no run has two."""
    from ._window import spread_is_round_off

    seen = False
    for run in runs:
        for name in ("x", "y"):
            array = run[name] if isinstance(run, h5py.Group) else getattr(run, name)
            rows, k = array.shape
            if not rows or k < 2:
                continue
            seen = True
            low, high = np.full(rows, np.inf), np.full(rows, -np.inf)
            step = max(1, (8 * 2**20) // (8 * rows))
            for j0 in range(0, k, step):
                block = np.asarray(array[:, j0:j0 + step], dtype=float)
                np.minimum(low, block.min(axis=1), out=low)
                np.maximum(high, block.max(axis=1), out=high)
                if np.any(high - low > 1e-6 * np.maximum(np.abs(low), np.abs(high)).max()):
                    return False   # clearly moving: the rest of a long recording is not read
            if not spread_is_round_off(low, high):
                return False
    return seen


def _warn_still(source: Source, path: Path | str | None) -> None:
    """Warn that a recording on a given window stayed constant, naming the inputs held while it ran (audit 77a, F2:
    a Boolean enable held at false made a file of constants without a word, and fit then said only "all snapshots
    are zero")."""
    from ._window import held_values

    advice = held_inputs_advice(held_values(source)) or "give an input that reaches the outputs"
    where = f" in {path}" if path is not None else ""
    warnings.warn(f"{source_label(source)}: the positions and outputs recorded{where} stay constant in every run (the "
                  f"model rests and nothing moves it), so the fit can learn nothing from them; {advice}",
                  FmuOpinfWarning, stacklevel=3)


@dataclasses.dataclass
class RecordSummary:
    """What :func:`record_to_file` wrote: ``str()`` is the file name, :meth:`describe` the details."""

    path: Path
    n: int
    m: int
    p: int
    window: "Window | None" = None
    runs: list[tuple[int, bool, str]] = dataclasses.field(default_factory=list)
    dt: float | None = None  # the step recorded (a given one may stand beside the window's)
    events: list[int | None] = dataclasses.field(default_factory=list)  # per run; None: not seen (co-simulation)
    step_from: str | None = None  # who set the step beside an automatic window (--dt, the FMU), if not the window
    initialization: dict | None = None  # a start that follows the inputs (snapshots._initialization), else None
    t_end_from: str | None = None  # who set the end beside an automatic window (--t-end, a table, a termination)

    window_end: float = 0.0  # the last recorded time (the window's own end may differ: ``t_end_from``)

    def __str__(self) -> str:
        return str(self.path)

    def __fspath__(self) -> str:
        return str(self.path)

    def describe(self) -> str:
        """Several lines: sizes, one line per run, the automatic window."""
        lines = [f"{self.path}: n={self.n}, m={self.m}, p={self.p}, {len(self.runs)} run(s)"]
        for index, (k, complete, spec) in enumerate(self.runs):
            events = self.events[index] if index < len(self.events) else None
            lines.append(f"  run {index:04d}: k={k} samples, input {spec}" + ("" if complete else " (INCOMPLETE)")
                         + (f", {events} event(s)" if events else ""))
        if self.window is not None and self.step_from is not None:
            lines.append(f"  auto window for t_end only: dt={self.dt:g} ({self.step_from}); the window's own: "
                         f"{self.window}")
        elif self.window is not None:
            lines.append(f"  auto window: {self.window}")
        if self.window is not None and self.t_end_from is not None:
            lines.append(f"  recorded to t_end={self.window_end:g} ({self.t_end_from})")
        if self.initialization:
            lines.append("  start: the FMU starts at its static equilibrium under the inputs it is initialized under "
                         "(its start positions move with them); an exported ROM FMU will do the same")
        return "\n".join(lines)
