"""Recording runs of a source into memory or straight into a snapshot file.

``record`` steps a :class:`~fmu_opinf.sources.Source` on a uniform grid with the input held over each
step (design.md input timing), keeps ``t, u, x, xdot, xddot, y`` per run, derives velocities or
accelerations the source does not expose (:mod:`._rates`), and writes atomically.  A failing step or
non-finite values end the run with a one-line error *after* the samples so far have been stored
with ``complete=False``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from .._hdf5 import write_attrs
from .._validate import ME, either
from ..errors import FmuOpinfError, FmuOpinfWarning, InputSpecError
from ..signals import Signal
from ..sources import (Source, StepError, at_start_time, fixed_communication_step, offers_model_exchange,
                       open_source, terminated_at, warn_other_communication_step)
from ..sources._base import held_inputs_advice, nice_floor
from ._data import Snapshots
from ._file import FILE_KIND, LAYOUT_VERSION, atomic, write_file_attrs
from ._initialization import initialization_of
from ._linearity import (check_given_input, input_departures, largest_runs)
from ._isolation import source_label
from ._growth import warn_if_grows
from ._notes import collecting_recording_notes, current_recording_notes
from ._size import after_first_run, announce
from ._rates import time_grid
from ._default_training import _default_training_window, _sized_on_grid
from ._inputs import (as_signal, check_input_acts, check_table_times, default_amplitudes, default_training_inputs,
                      held_starts, input_table_end, is_free_response, runs_by_inputs_driven, _impulse_said,
                      _lowered_amplitudes, _on_start_values)
from ._run import MemorySink, STREAM_THRESHOLD, incomplete_error, record_run, _H5Sink, _run_bytes, _versions

if TYPE_CHECKING:
    from ..signals import Signal
    from ._window import Window

__all__ = ["record", "record_to_file", "RecordSummary"]


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


#: The keywords of :func:`record` and :func:`record_to_file` that choose what an FMU source records (its
#: command-line options ``--positions``, ..., ``--set``, ``--interface``, ``--tolerance``): one meaning, one check.
SOURCE_KEYWORDS = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "parameters",
                   "interface", "tolerance")


def open_recorded_source(spec: Source | str | os.PathLike, options: dict[str, Any]) -> Source:
    """:func:`~fmu_opinf.sources.open_source` of ``spec`` with ``options`` (:data:`SOURCE_KEYWORDS`, sizes), for
    :func:`record` and :func:`record_to_file` alike; an opened :class:`Source` with such an option given is refused
    in one line: it would be recorded as opened, the option dropped without a word.  ``start_time`` is applied to
    an opened source (:func:`~fmu_opinf.sources.at_start_time`: a copy run from that FMU time; a builtin source is
    refused), as :func:`record` on a given grid applies it: ``record_to_file`` recorded an opened FMU from its
    declared start time and dropped ``start_time=`` without a word."""
    given = [key for key, value in options.items() if value is not None and key != "start_time"]
    if isinstance(spec, Source) and given:
        raise InputSpecError(f"{given[0]}= applies where the source is given as a path or spec, but "
                             f"{source_label(spec)} is an opened source, recorded as opened; give the source as its "
                             f"path or spec, or open it with open_source(spec, {given[0]}=...)")
    if isinstance(spec, Source):
        return at_start_time(spec, options.get("start_time"))
    return open_source(spec, **options)


@collecting_recording_notes
def record(source: Source | str, signal: Signal | str | None = None, dt: float | None = None,
           t_end: float | None = None, path: str | os.PathLike | None = None,
           quiet: bool = False, *, overwrite: bool = False, isolate: bool = False, t0: float | None = None,
           stream: bool | None = None, start_time: float | None = None, positions: str | None = None,
           velocities: str | None = None, accelerations: str | None = None, inputs: str | None = None,
           outputs: str | None = None, constraint: str | None = None, parameters: dict[str, Any] | None = None,
           interface: str | None = None, tolerance: float | None = None) -> Snapshots:
    """Record one run of ``source`` driven by ``signal`` on the grid ``t0, t0+dt, ..., <= t_end``; without
    ``signal``, ``dt`` or ``t_end``, record what ``fmu-opinf snapshots`` records (:func:`record_to_file`).

    Parameters
    ----------
    source : Source or str
        A source or a spec for :func:`~fmu_opinf.source.open_source`.
    signal : Signal or str, optional
        Input (``sample(t) -> (m, k)``) or a spec for :func:`fmu_opinf.signals.parse_signal`.  Default: the
        command line's default training (:func:`record_to_file` without ``signal``): one run per force input with
        the default impulse at an amplitude checked for linearity, and a free run where the model moves on its own.
    dt : float, optional
        Communication step; default (with ``t_end``): the FMU's default experiment, else the automatic window.
        The paper's benchmarks used 0.5 with ``t_end`` 300: values of those models, not general ones.
    t_end : float, optional
        End time; default as for ``dt``.
    path : str or path-like, optional
        Also write the snapshots there (atomically).
    quiet : bool, default=False
        No progress bar.
    overwrite : bool, default=False
        Replace an existing ``path``.
    isolate : bool, default=False
        Run the source in a child process (a crash becomes an :class:`~fmu_opinf.errors.FMUError`).
    t0 : float, optional
        An absolute start of the grid: an FMU is run at the grid's times themselves (from FMU time ``t0``; its
        declared start time is not applied) and the run's ``t`` starts at ``t0``.  Default: the grid starts at 0
        and an FMU runs from its start time (``start_time``).
    stream : bool, optional
        Write blocks to ``path`` during the run instead of keeping them in memory; default: when the
        run exceeds :data:`STREAM_THRESHOLD` bytes.  Streamed snapshots are returned opened lazily.
    start_time : float, optional
        The FMU time of the run's ``t = 0`` (:class:`~fmu_opinf.sources.FMUSource`); default: the source's (an FMU's
        ``DefaultExperiment/@startTime``, else 0).  Not with ``t0``.
    positions, velocities, accelerations, inputs, outputs : str, optional
        Variable name patterns of an FMU given by its path (``fmu-opinf snapshots --positions`` ...; see
        :class:`~fmu_opinf.source.FMUSource`), as in :func:`record_to_file`.
    constraint, parameters, interface, tolerance : optional
        As in :func:`record_to_file` (``parameters``: ``--set``'s start values, e.g. ``{"k": 1000.0}``).  Each of
        these and the patterns needs ``source`` as a path or spec: an opened source is refused with them.

    Returns
    -------
    Snapshots
        One run (given ``signal``, ``dt`` and ``t_end``), else the runs :func:`record_to_file` records, in memory.
        If the run stopped early, the samples so far are stored (``complete=False``) and
        :class:`~fmu_opinf.source.StepError` is raised afterwards.  Its ``attrs`` (and the file's) keep the
        recording's warnings as :func:`record_to_file` does (``recording_warnings``, ``recording_verdicts``), so
        that fit, compare and export repeat them and fit handles, e.g., an FMU's Euler steps.
    """
    options = dict(positions=positions, velocities=velocities, accelerations=accelerations, inputs=inputs,
                   outputs=outputs, constraint=constraint, parameters=parameters, interface=interface,
                   tolerance=tolerance)   # (audit 81c F12: record() had none of record_to_file's)
    if signal is None or dt is None or t_end is None:
        return _record_like_cli(source, signal, dt, t_end, path, quiet=quiet, overwrite=overwrite, isolate=isolate,
                                t0=t0, start_time=start_time, options=options)
    if path is not None and isinstance(source, (str, os.PathLike)):
        from .._validate import check_not_input

        check_not_input(path, [source, signal], "path", "path")   # (as record_to_file: overwrite=True kept no FMU)
    if t0 is not None and start_time is not None:
        raise InputSpecError("give either t0 (an absolute start of the grid) or start_time (the FMU time of t = 0)")
    source = open_recorded_source(source, options)
    if t0 is not None and source.kind == "fmu":
        start_time = 0.0   # the grid's times are the FMU's, as before start times existed
    source = at_start_time(source, start_time)
    signal = as_signal(signal, source.m, source)
    t = time_grid(dt, t_end, t0 or 0.0)
    check_input_acts(signal, t)
    streaming = path is not None and (stream if stream is not None else _run_bytes(source, len(t)) > STREAM_THRESHOLD)
    if not streaming:
        run, failure = record_run(source, signal, t, MemorySink, quiet, isolate)
        if failure is None:   # as _record_file does (a streamed run, record_to_file): the growth's verdict is kept
            warn_if_grows(source, signal, run)
        attrs = {**_file_attrs(source), "dt": float(t[1] - t[0]), **fixed_step_attrs(source, float(t[1] - t[0])),
                 **_integrator_taken(source, [run.attrs]), **current_recording_notes()}   # (audit 81c F1)
        snaps = Snapshots([run], attrs)
        if path is not None:
            snaps.save(path, overwrite=overwrite)
        if failure is not None:
            raise incomplete_error(failure, run, Path(path) if path else None)
        if _runs_still([run]):
            _warn_still(source, path)
        return snaps
    summary = _record_file(source, [signal], [t], Path(path), quiet, isolate, overwrite, None)
    del summary
    return Snapshots.open(path)


def _record_like_cli(source: Source | str, signal: Any, dt: float | None, t_end: float | None,
                     path: str | os.PathLike | None, *, quiet: bool, overwrite: bool, isolate: bool,
                     t0: float | None, start_time: float | None, options: dict[str, Any]) -> Snapshots:
    """:func:`record` where ``signal``, ``dt`` or ``t_end`` is left out: :func:`record_to_file`, the code of
    ``fmu-opinf snapshots``, into ``path`` (or a temporary file), read back into memory.

    One code path for both (audit 81c, F4-F6): the README's ``record(fmu, impulse, dt=0.5, t_end=300)`` drove two
    inputs with one pulse, skipped the amplitude check and took the paper's window on other models; its ROMs were
    0.71 and 0.33 of range off where the command line's defaults gave 1e-12.
    """
    import tempfile

    if t0 is not None:
        raise InputSpecError("t0 (an absolute start of the grid) needs a given grid: give signal, dt and t_end, or "
                             "start_time= for the FMU time of t = 0")
    if path is not None:
        record_to_file(source, path, signal, dt, t_end, start_time=start_time, overwrite=overwrite, quiet=quiet,
                       isolate=isolate, **options)
        return Snapshots.load(path)
    with tempfile.TemporaryDirectory(prefix="fmu-opinf-record-") as folder:
        file = Path(folder) / "snapshots.h5"
        record_to_file(source, file, signal, dt, t_end, start_time=start_time, quiet=quiet, isolate=isolate,
                       **options)
        snaps = Snapshots.load(file)
        snaps.path = None
        return snaps


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


#: Where the end of a run without --t-end comes from when an input table drives it.
TABLE_END = "the input table's last time"


def _run_grids(signals: Sequence[Any], dt: float, t_end: float, to_table_ends: bool) -> list[np.ndarray]:
    """Each run's time grid: to ``t_end``, or, where the end is the input tables' (``to_table_ends``: no --t-end),
    each table-driven run to its own table's last time.

    The end of a file's runs is the earliest of its tables' last times (:func:`input_table_end`: no run may go
    past its table); a longer table was cut there without a word (audit 72, F6: a 60 s table beside a 30 s one
    lost its second half).  Runs of one file may differ in length: the fit takes them so.
    """
    def end(signal: Any) -> float:
        own = float(getattr(signal, "t_range", (0.0, math.inf))[1])
        return own if to_table_ends and math.isfinite(own) else t_end

    return [time_grid(dt, end(signal)) for signal in signals]


def _renamed(options: dict[str, Any], old: str, new: str, value: Any) -> Any:
    """``options[old]`` (popped, with a DeprecationWarning naming ``new``) where an older keyword was given."""
    if old not in options:
        return value
    warnings.warn(f"record_to_file({old}=...) is now {new}=...", DeprecationWarning, stacklevel=3)
    return options.pop(old)


@collecting_recording_notes
def record_to_file(
    source_spec: str | os.PathLike | Source,
    output: str | os.PathLike,
    signal: "str | Signal | Sequence[str | Signal] | None" = None,
    dt: float | None = None,
    t_end: float | None = None,
    auto_window: bool = False,
    positions: str | None = None,
    velocities: str | None = None,
    accelerations: str | None = None,
    inputs: str | None = None,
    outputs: str | None = None,
    constraint: str | None = None,
    parameters: dict[str, Any] | None = None,
    interface: str | None = None,
    tolerance: float | None = None,
    start_time: float | None = None,
    points_per_period: float = 20.0,
    window_energy: float = 0.999,
    fade: float = 0.01,
    overwrite: bool = False,
    quiet: bool = False,
    isolate: bool = True,
    keep_inputs: bool = False,
    window: "Window | dict | None" = None,
    check_linearity: bool = True,
    **size_options: Any,
) -> RecordSummary:
    """Command-line entry: record one run per input specification into ``output``.

    Parameters
    ----------
    source_spec : str, path-like or Source
        ``builtin:anchored-msd``, ``builtin:triple-chain`` or an ``.fmu`` path.
    output : str or path-like
        HDF5 file to create (atomically).
    signal : str, Signal or sequence of them, optional
        Input signal specification(s) (:func:`fmu_opinf.signals.parse_signal`; a single-channel
        spec drives every input) or signal objects; one run each; the name :func:`record` and
        :func:`fmu_opinf.compare.compare` give it (``input_spec=`` still works, with a
        DeprecationWarning).  Default (None or empty):
        :func:`default_training_inputs`: :data:`DEFAULT_TRAINING_INPUT` on each input in a run of its own, at the
        amplitude the input declares (:func:`default_amplitudes`: its nominal, else a wide range's tenth, else 100,
        within its range), or the free response of a model without inputs.
    dt, t_end : float, optional
        Step and end time; default: the FMU's ``DefaultExperiment`` when it declares a ``stepSize``,
        else the automatic window.
    auto_window : bool, default=False
        Choose ``dt`` and ``t_end`` from pilot runs (:func:`auto_window`) even when the source has a default
        experiment; an explicitly given ``dt``/``t_end`` wins over the automatic choice.  With several runs, one
        window per group of runs that drive the same inputs, combined (:func:`runs_by_inputs_driven`); for the
        default training, pilots that drive every input at once.
    positions, velocities, accelerations, inputs, outputs : str, optional
        Variable name patterns (FMU sources only; see :class:`~fmu_opinf.source.FMUSource`).
    constraint : {"position", "velocity", "none", "unknown"}, optional
        Constraint kind of an FMU (stored for the later stages).
    parameters : dict of str to float, optional
        FMU start values set before initialization.
    interface : {"auto", "me", "cs"}, optional
        FMI interface (:func:`fmu_opinf.sources.choose_interface`; default auto: model exchange when offered).
    tolerance : float, optional
        Relative tolerance of the model-exchange integration, also passed to the FMU (default 1e-10).
    start_time : float, optional
        FMU time at which every run (pilots included) starts; the recorded times start at 0.  Default: the FMU's
        ``DefaultExperiment/@startTime``, else 0.
    points_per_period, window_energy, fade : float
        Thresholds of :func:`auto_window` (``window_energy`` is its ``energy``, the share of the pilots' spectral
        energy below the fastest significant frequency; named apart from the POD energy of
        :func:`fmu_opinf.fit.fit_rom`; ``energy=`` still works, with a DeprecationWarning).
    overwrite : bool, default=False
    quiet : bool, default=False
    isolate : bool, default=True
        Run FMUs in a child process so that a crashing binary cannot take the data with it (a fresh
        interpreter per run, about 0.4 s; :func:`~fmu_opinf.snapshots.use_fork_server` makes it about 25 ms).
    keep_inputs : bool, default=False
        Keep the force inputs (held at their start values) when every run is a free response, instead of
        recording no input channel (m = 0): a run table's ``none`` row beside forced rows, so that the files
        merge into one data set.
    window : Window or dict, optional
        An automatic window chosen beforehand (:func:`recording_window`, with its step and end replaced as
        wanted; a dict: its ``as_dict()``): recorded at its ``dt`` and ``t_end`` as the automatic window, without
        pilot runs (a run table's rows at the table's one step, :func:`fmu_opinf.runs.record_runs`).
    check_linearity : bool, default=True
        After recording, check that the response scales with the inputs recorded (:func:`_check_inputs_scale`:
        one extra run of the same input at -1/10 per run that drives some input furthest, more only where it
        does not scale), and warn where it does not, naming the input and the amplitude at which it scales; the
        inputs are recorded as given.  Not repeated where the default training's amplitude check ran on the
        automatic window's pilots.  False skips it (a run of hours, a model known to be linear).
    **size_options
        Sizes of a builtin system (``g`` for anchored-msd; ``n1, alpha, beta, v`` for triple-chain).

    Returns
    -------
    RecordSummary
        ``str()`` gives the file name, :meth:`RecordSummary.describe` the runs and the window.
    """
    from .._validate import check_not_input
    from ._window import warn_if_step_dependent

    signals = signal if isinstance(signal, (list, tuple)) else [signal]
    check_not_input(output, [source_spec, *signals], "output", "output")   # (audit 81c F3: it replaced the FMU)
    plan = _plan_recording(source_spec, signal, dt, t_end, auto_window, window, quiet, isolate, keep_inputs,
                           dict(positions=positions, velocities=velocities, accelerations=accelerations,
                                inputs=inputs, outputs=outputs, constraint=constraint, parameters=parameters,
                                interface=interface, tolerance=tolerance, start_time=start_time),
                           dict(points_per_period=points_per_period, window_energy=window_energy, fade=fade),
                           size_options)
    source, signals, window, dt, t_end = plan.source, plan.signals, plan.window, plan.dt, plan.t_end
    dt_given, fixed, representatives = plan.dt_given, plan.fixed, plan.representatives
    step_declared, step_multiple, t_end_from = plan.step_declared, plan.step_multiple, plan.t_end_from
    isolate = plan.isolate   # only an FMU runs in a child process (a builtin source in this one)
    grids = _run_grids(signals, dt, t_end, plan.t_end_from == TABLE_END)
    for signal, t in zip(signals, grids):
        check_input_acts(signal, t)
    if window is None or dt_given:  # the user's own step: the automatic window's step check becomes a warning
        warn_if_step_dependent(source, representatives[0], dt, t_end, quiet=quiet, isolate=isolate)
    check = None if not check_linearity or not source.m or plan.linearity_checked else (
        "default" if plan.by_default else "given")
    summary = _record_file(source, signals, grids, Path(output), quiet, isolate, overwrite, window, check)
    ends = sorted({float(t[-1]) for t in grids})
    summary.window_end = ends[-1]
    summary.t_end_from = t_end_from if len(ends) == 1 else (
        f"each run to its input table's last time: {', '.join(f'{t[-1]:g}' for t in grids)}")
    summary.step_from = ("--dt as given" if dt_given else "the FMU's fixed communication step" if fixed is not None
                         else "a multiple of the FMU's DefaultExperiment stepSize" if step_multiple
                         else "the FMU's DefaultExperiment stepSize" if step_declared else None)
    return summary


@dataclasses.dataclass
class _Plan:
    """What :func:`record_to_file` records: the opened source, the signals, the grid and who chose it, and
    whether its runs are isolated (``isolate`` as asked, for an FMU only: a builtin source runs in this process)."""

    source: Source
    signals: list[Any]
    representatives: list[Any]
    window: "Window | None"
    dt: float
    t_end: float
    dt_given: bool
    fixed: float | None
    step_declared: bool
    step_multiple: bool
    t_end_from: str | None
    isolate: bool
    linearity_checked: bool = False   # the default training's amplitude check ran on the pilots
    by_default: bool = False   # the default training's inputs, not given ones


def recording_window(source_spec: str | os.PathLike, signal: Any = None, dt: float | None = None,
                     t_end: float | None = None, auto_window: bool = False, *, isolate: bool = True,
                     keep_inputs: bool = False, **options: Any) -> tuple[float, float, "Window | None"]:
    """The step, end and automatic window :func:`record_to_file` would record ``signal`` with, from its pilot runs
    alone (nothing recorded, nothing printed).

    A run table's rows are recorded at one step (:func:`fmu_opinf.runs.record_runs`): each row's window is chosen
    first, the finest step of all is the table's, and each row is then recorded with its window at that step
    (``record_to_file(window=...)``, without running its pilots again).

    Parameters
    ----------
    source_spec : str or path-like
        ``builtin:NAME`` or an FMU path.
    signal : str, optional
        The run's input specification (one run).
    dt, t_end, auto_window, isolate, keep_inputs
        As for :func:`record_to_file`.
    **options
        The other keywords of :func:`record_to_file` (variable patterns, parameters, thresholds, sizes).

    Returns
    -------
    dt, t_end : float
        The step and end the run would be recorded with.
    window : Window or None
        The automatic window behind them (None where no pilots chose them: given or declared by the FMU).
    """
    names = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "parameters",
             "interface", "tolerance", "start_time")
    thresholds = {key: options.pop(key) for key in ("points_per_period", "window_energy", "fade") if key in options}
    plan = _plan_recording(source_spec, signal, dt, t_end, auto_window, None, True, isolate, keep_inputs,
                           {key: options.pop(key, None) for key in names},
                           {"points_per_period": 20.0, "window_energy": 0.999, "fade": 0.01, **thresholds}, options)
    close = getattr(plan.source, "close", None)
    if callable(close):
        close()
    return plan.dt, plan.t_end, plan.window


def _preset_window(window: "Window | dict | None") -> "Window | None":
    """A window chosen beforehand (:func:`recording_window`), as a :class:`Window` (a dict: its ``as_dict``)."""
    from ._window import Window

    if window is None or isinstance(window, Window):
        return window
    try:
        return Window(**dict(window))
    except (TypeError, ValueError) as exc:
        raise InputSpecError(f"window={window!r} is not an automatic window ({exc}); give Window.as_dict() of "
                             f"recording_window's window") from None


def _plan_recording(source_spec: Any, signal: Any, dt: float | None, t_end: float | None, auto_window: bool,
                    window: "Window | dict | None", quiet: bool, isolate: bool, keep_inputs: bool,
                    names: dict[str, Any], limits: dict[str, float], size_options: dict[str, Any]) -> _Plan:
    """Open the source and choose the run's grid (:func:`record_to_file`'s steps before recording): a given
    ``dt``/``t_end``, an input table's end, the FMU's declared step, or the automatic window from pilot runs; a
    ``window`` chosen beforehand (:func:`recording_window`) is taken as the automatic window, without pilots."""
    from ._window import default_window, needs_auto_window

    positions, velocities, accelerations, inputs, outputs, constraint, parameters, interface, tolerance, \
        start_time = (names[key] for key in ("positions", "velocities", "accelerations", "inputs", "outputs",
                                             "constraint", "parameters", "interface", "tolerance", "start_time"))
    points_per_period, fade = limits["points_per_period"], limits["fade"]
    preset = _preset_window(window)
    outcome: dict[str, Any] = {}

    signal = _renamed(size_options, "input_spec", "signal", signal)
    window_energy = _renamed(size_options, "energy", "window_energy", limits["window_energy"])
    specs = [signal] if isinstance(signal, (str, Signal)) else list(signal or [])
    if specs and all(is_free_response(s) for s in specs) and inputs is None and not keep_inputs \
            and not isinstance(source_spec, Source):   # (an opened source is recorded as opened)
        inputs = "none"  # only free responses: no force inputs at all (m = 0), every input held
    source = open_recorded_source(source_spec, dict(positions=positions, velocities=velocities,
                                                    accelerations=accelerations, inputs=inputs, outputs=outputs,
                                                    constraint=constraint, parameters=parameters,
                                                    interface=interface, tolerance=tolerance, start_time=start_time,
                                                    **size_options))
    by_default = not specs
    if not specs:
        amplitudes = default_amplitudes(source)
        specs = default_training_inputs(source.m, amplitudes=amplitudes, starts=held_starts(source))
        if not quiet:
            lowered = _lowered_amplitudes(source, amplitudes) + _on_start_values(source)
            held = list(getattr(source, "held_input_names", []) or [])
            none = (f"no force inputs: {', '.join(held)} held at their start values" if held
                    else "the model has no inputs")
            what = (f"the free response from the start state ({none})" if not source.m
                    else f"the impulse training input {specs[0]}{lowered}" if source.m == 1
                    else f"one run per input, each driving that input alone with {_impulse_said(amplitudes)}"
                         f"{lowered} (the others held at their start values)")
            print(f"no {either('--input')} given: recording {what}", file=sys.stderr)
    signals = [as_signal(s, source.m, source) for s in specs]
    if not quiet and hasattr(source, "selection_text"):
        print(source.selection_text(), file=sys.stderr)
    isolate = isolate and source.kind == "fmu"
    dt_given = dt is not None
    check_table_times(signals, float(getattr(source, "start_time", 0.0) or 0.0))
    table_end = input_table_end(signals)
    t_end_from = "--t-end as given" if t_end is not None else None
    if t_end is None and table_end is not None:   # a table's last time is the default end (audit 70, F3)
        t_end, t_end_from = table_end, TABLE_END
    if dt_given:
        warn_other_communication_step(source, float(dt))  # not the FMU's fixed communication step: said
    fixed = fixed_communication_step(source)
    declared_step = getattr(getattr(getattr(source, "md", None), "defaultExperiment", None), "stepSize", None)
    step_declared = (preset is None and dt is None and declared_step is not None
                     and (not auto_window or fixed is not None))
    step_multiple = False
    if step_declared:
        dt = float(declared_step)  # the FMU's own step; only a stopTime before the input acts is replaced
        if fixed is None and _too_many_samples(source, dt, t_end):
            step_declared, dt, auto_window = False, None, True   # the automatic window chooses, as --auto-window
    representatives = [signals[0]] if by_default else runs_by_inputs_driven(signals)
    if preset is not None:   # chosen beforehand (a run table's step shared by its rows): no pilots again
        window = preset
        dt = preset.dt if dt is None else dt
        t_end = preset.t_end if t_end is None else t_end
    elif auto_window or any(needs_auto_window(source, dt, t_end, signal) for signal in representatives):
        # pilots never coarser than the step recorded (a longer one may be refused or discarded), and exactly at
        # a step the user gave or the FMU's fixed communication step
        # (model exchange has no communication step: a declared one bounds nothing there, and at 1 ms the pilots
        # of a slow model took 1e7 steps)
        bound = None if step_declared and getattr(source, "interface", None) == "me" else dt
        limits = [end for end in (t_end, table_end) if end is not None]   # no pilot runs past these
        thresholds = dict(points_per_period=points_per_period, energy=window_energy, fade=fade, isolate=isolate,
                          quiet=quiet, max_dt=bound, exact_dt=dt_given or fixed is not None,
                          t_limit=min(limits) if limits else None)
        window, signals, terminated = _window_before_termination(source, signals, representatives, by_default,
                                                                 thresholds, t_end, outcome)
        if terminated is not None and t_end is None:
            t_end_from = f"before the FMU terminates the simulation at t={terminated:g}"
        if step_declared and dt > window.dt:
            warnings.warn(f"{source_label(source)}: the FMU's DefaultExperiment stepSize={dt:g} is the step recorded, "
                          f"coarser than the automatic window's dt={window.dt:g} ({window.points_per_period:g} points "
                          f"per period of the fastest significant frequency {window.f_max:.4g} Hz); pass "
                          f"{either('--dt', value=float(f'{window.dt:g}'))} to resolve it", FmuOpinfWarning,
                          stacklevel=2)
        elif fixed is not None or dt_given:
            _warn_if_unresolved(source, window, dt, fixed is not None and not dt_given)
        if step_declared and fixed is None and (t_end or window.t_end) / dt > DECLARED_STEP_SAMPLES:
            dt = _declared_step_multiple(source, dt, window.dt, t_end or window.t_end)
        elif step_declared and getattr(source, "interface", None) == "me" and window.dt >= 2.0 * dt:
            dt, step_multiple = _declared_step_multiple(source, dt, window.dt, t_end or window.t_end, "me"), True
        dt = window.dt if dt is None else dt
        t_end = window.t_end if t_end is None else t_end
    dt, t_end = default_window(source, dt, t_end)
    if by_default and source.m and window is None:   # a grid given or declared: no pilots told whether it rests
        signals = _sized_on_grid(source, signals, time_grid(dt, t_end), quiet, isolate)
    return _Plan(source, signals, representatives, window, dt, t_end, dt_given, fixed, step_declared, step_multiple,
                 t_end_from, isolate, bool(outcome.get("checked")), by_default)


def _window_before_termination(source: Source, signals: list[Any], representatives: list[Any], by_default: bool,
                               thresholds: dict[str, Any], t_end: float | None,
                               outcome: dict[str, Any] | None = None) -> tuple[Any, list[Any], float | None]:
    """The automatic window (and the default training's signals), with the time at which the FMU terminated the
    simulation in a pilot (None where it did not): the pilots are then run again, none past that time, and the
    window ends before it (audit 70, F5: a Simulink-style FMU that stops itself at t = 30 was refused whatever
    --t-end said, the pilots running on to their own horizon).  Said in a warning, since the recording ends there
    and not where the response would have faded.  Where the end ``t_end`` is set already (``--t-end``, an input
    table's last time), a termination before it is the error, whose message names the --t-end that works.
    ``outcome``: as for :func:`_default_training_window`."""
    from ._window import auto_window as choose_window, combine_windows

    def choose(limits: dict[str, Any]) -> tuple[Any, list[Any]]:
        if by_default and source.m:
            if outcome is not None:
                outcome.pop("checked", None)   # (this try's, not an earlier one's)
            return _default_training_window(source, limits, outcome)
        return combine_windows([choose_window(source, signal, **limits) for signal in representatives]), signals

    try:
        window, chosen = choose(thresholds)
        return window, chosen, None
    except StepError as stopped:
        at = terminated_at(str(stopped))
        if at is None or t_end is not None:
            raise
    below = at * (1.0 - 1e-6)   # the step that ends at ``at`` is the one refused
    warnings.warn(f"{source_label(source)}: terminates the simulation at t={at:g} (seen in a pilot run of the "
                  f"automatic window): the window ends before it", FmuOpinfWarning, stacklevel=3)
    window, chosen = choose({**thresholds, "t_limit": below})
    return dataclasses.replace(window, t_end=min(window.t_end, below), terminates_at=at), chosen, at


#: Samples per run above which the FMU's DefaultExperiment stepSize (where the FMU can take other steps) is not
#: the recording step: Simulink-style exports declare their solver's step (1 ms) beside a stopTime of 1e4 s, and
#: the recording took 1e7 samples (tenth audit: killed after 400 s at 1.2 GB; the automatic window 8.5 s).
DECLARED_STEP_SAMPLES = 1_000_000


def _too_many_samples(source: Source, dt: float, t_end: float | None) -> bool:
    """Whether the declared step ``dt`` over ``t_end`` (default: the declared stopTime) makes more than
    :data:`DECLARED_STEP_SAMPLES` samples per run; then a warning says that the automatic window chooses the step."""
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    end = t_end
    if end is None and experiment is not None and experiment.stopTime is not None:
        end = float(experiment.stopTime) - float(experiment.startTime or 0.0)
    if end is None or end / dt <= DECLARED_STEP_SAMPLES:
        return False
    warnings.warn(f"{source_label(source)}: its DefaultExperiment stepSize={dt:g} up to t={end:g} would make "
                  f"{end / dt:.3g} samples per run; the automatic window chooses the step instead (pass "
                  f"{either('--dt', value=float(f'{dt:g}'))} to keep it)", FmuOpinfWarning, stacklevel=3)
    return True


def _declared_step_multiple(source: Source, declared: float, window_dt: float, t_end: float,
                            reason: str = "samples") -> float:
    """The largest multiple of the declared step ``declared`` within the automatic window's ``window_dt`` (a
    multiple keeps the grid the FMU's own step divides), said in a warning naming ``--dt`` to keep the declared
    step.  Used where the declared step over the window's end ``t_end`` would make more than
    :data:`DECLARED_STEP_SAMPLES` samples per run (``reason="samples"``), and in model exchange (``"me"``), where
    the importer's integrator controls the accuracy and a declared step bounds nothing: OpenModelica declares
    ``stopTime / 500`` (2 ms beside ``stopTime="1"``), and a slow model was recorded with 25 times the window's
    samples, its default chain 4 times as long, for no accuracy (audit 62, finding 2)."""
    step = declared * max(1, math.floor(window_dt / declared + 1e-9))
    why = (f"up to the window's end t={t_end:g} would make {t_end / declared:.3g} samples per run"
           if reason == "samples" else "bounds nothing in model exchange (the integrator chooses its own steps)")
    warnings.warn(f"{source_label(source)}: its DefaultExperiment stepSize={declared:g} {why}; recording at "
                  f"dt={step:g}, the multiple of it within the automatic window's dt={window_dt:g} (pass "
                  f"{either('--dt', value=float(f'{declared:g}'))} to keep it)", FmuOpinfWarning, stacklevel=3)
    return step


def _warn_if_unresolved(source: Source, window: Any, dt: float, fixed: bool) -> None:
    """One warning when the step ``dt`` that the pilots had to use (the FMU's ``fixed`` communication step, else
    the user's ``--dt``) gives fewer samples per period of the fastest significant frequency they saw than the
    window asks for: the data, and the ROM, may miss that mode."""
    points = 1.0 / (window.f_max * dt) if window.f_max > 0 else math.inf
    if points >= window.points_per_period:
        return
    if fixed:
        what = f"the FMU's fixed communication step {dt:g}"
        fix = (f"; its model exchange ({ME}) has no fixed step"
               if offers_model_exchange(source) else
               "; no other step is possible: compare the ROM on the modes it resolves")
    else:
        what = f"the step dt={dt:g}"
        smaller = float(f"{nice_floor(1.0 / (window.points_per_period * window.f_max)):g}")
        fix = f"; a smaller step resolves it, e.g. {either('--dt', value=smaller)}"
    warnings.warn(f"{source_label(source)}: {what} gives {points:.3g} samples per period of the fastest significant "
                  f"frequency {window.f_max:.4g} Hz seen at that step (the automatic window asks for "
                  f"{window.points_per_period:g}){fix}", FmuOpinfWarning, stacklevel=3)
