"""The snapshot stage's entry points: :func:`record` into memory (and a file) and :func:`record_to_file`.

Both plan the recording (:mod:`._plan`: the source, the inputs of :mod:`._inputs`, the grid), record each run
(:mod:`._run`) and, for a file, write and check the runs (:mod:`._write`); :func:`record` on a grid it is given
records one run in memory and writes it atomically.  A failing step or non-finite values end the run with a one-line
error *after* the samples so far have been stored with ``complete=False``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputSpecError
from ..signals import Signal
from ..sources import Source, at_start_time
from ._data import Snapshots
from ._growth import warn_if_grows
from ._inputs import as_signal, check_input_acts
from ._notes import collecting_recording_notes, current_recording_notes
from ._plan import TABLE_END, _plan_recording, _run_grids, open_recorded_source
from ._rates import time_grid
from ._run import STREAM_THRESHOLD, MemorySink, _run_bytes, incomplete_error, record_run
from ._write import (RecordSummary, _file_attrs, _integrator_taken, _record_file, _runs_still, _warn_still,
                     fixed_step_attrs)

if TYPE_CHECKING:
    from ._window import Window

__all__ = ["record", "record_to_file"]


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
