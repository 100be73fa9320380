"""What a recording records, decided before its first run: the source opened, the inputs, the grid.

:func:`open_recorded_source` opens the source with the user's choices (:data:`SOURCE_KEYWORDS`); ``_plan_recording``
(its ``_Plan``) turns the given inputs, or the default training's, into signals and chooses the grid: a given
``dt``/``t_end``, an input table's end (:data:`TABLE_END`, ``_run_grids``), the FMU's declared step
(``_too_many_samples``, ``_declared_step_multiple``) or the automatic window from pilot runs
(``_window_before_termination``: ended before the FMU terminates the simulation).  :func:`recording_window` gives
that choice alone, for a run table's shared step.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import ME, either
from ..errors import FmuOpinfWarning, InputSpecError
from ..signals import Signal
from ..sources import (Source, StepError, at_start_time, fixed_communication_step, offers_model_exchange,
                       open_source, terminated_at, warn_other_communication_step)
from ..sources._base import nice_floor
from ._default_training import _default_training_window, _sized_on_grid
from ._inputs import (_impulse_said, _lowered_amplitudes, _on_start_values, as_signal, check_table_times,
                      default_amplitudes, default_training_inputs, held_starts, input_table_end, is_free_response,
                      runs_by_inputs_driven)
from ._isolation import source_label
from ._rates import time_grid

if TYPE_CHECKING:
    from ._window import Window

__all__ = ["SOURCE_KEYWORDS", "open_recorded_source", "TABLE_END", "recording_window", "DECLARED_STEP_SAMPLES"]


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
