"""Running a comparison (:func:`compare`): the grid and its end, both sides on one input, the default test input,
each input alone and the free response."""

from __future__ import annotations

import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import either
from ..errors import DimensionError, InputSpecError
from ._alone import given_each_input_alone, hidden_input_line
from ._alone import largest_miss as _largest_miss
from ._alone import worst_of as _worst_of
from ._comparison import Comparison
from ._declared import _declared_display_units, _declared_units
from ._sides import _fmu_path, _held_at_start_values, _load_rom_side, _matching_outputs, _rom_side_info, _source_start
from ._simulate import simulate_outputs
from ._timing import _timed
from ._training import (_carried_linear_fits, _carried_order, _compared_interface, _linear_fits, _order_chosen,
                        _past_training, _trained_input_names, _training_miss, _training_settings,
                        _warn_beyond_training, _warn_if_another_fmu, _warn_if_merged, _warn_if_recording_warned,
                        _warn_if_training_missed, input_beyond_training)

if TYPE_CHECKING:
    from ..rom import SecondOrderROM
    from ..signals import Signal


#: The source's options :func:`compare` takes, as keywords (``inputs=``, ..., a builtin system's sizes ``g=``, ...)
#: or as the keys of ``source_options``: an FMU source's (:func:`~fmu_opinf.compare._simulate._source_outputs`,
#: ``isolate`` and ``timeout`` of its child process) and a builtin system's sizes
#: (:func:`~fmu_opinf.compare._simulate._builtin_outputs`).  Any other key is refused: one dropped without a word
#: compared another model than the one asked for (audit 81c F2).
SOURCE_OPTIONS = ("inputs", "outputs", "parameters", "interface", "tolerance", "method", "start_time", "isolate",
                  "timeout", "g", "n1", "alpha", "beta", "v")   # (the last five: sources.BUILTIN_SIZES)

#: The options that choose how a source is opened: an opened source (a :class:`~fmu_opinf.sources.Source` given as
#: ``source``) is compared as opened, so they are refused with it, as :func:`~fmu_opinf.snapshots.record` refuses
#: its own.
OPENING_OPTIONS = ("inputs", "outputs", "parameters", "interface", "tolerance", "method", "g", "n1", "alpha", "beta",
                   "v")


def compare(rom: "SecondOrderROM | str | os.PathLike", source: str | os.PathLike,
            signal: "Signal | str | None" = None, dt: float | None = None, t_end: float | None = None, *,
            quiet: bool = False, inputs: str | None = None, outputs: str | None = None,
            parameters: dict[str, Any] | None = None, interface: str | None = None, tolerance: float | None = None,
            method: str | None = None, start_time: float | None = None, isolate: bool | None = None,
            timeout: float | None = None, source_options: dict[str, Any] | None = None,
            **sizes: Any) -> Comparison:
    """Simulate the full-order ``source`` and the ROM on the same input and grid.

    Parameters
    ----------
    rom : SecondOrderROM, or path to a ROM ``.h5`` file or an exported ROM ``.fmu``
    source : str or path
        An FMU path or ``builtin:anchored-msd`` / ``builtin:triple-chain``; an exported ROM FMU
        may also stand here (e.g. to compare a ROM with its own export).
    signal : Signal or str, optional
        Test input (see :mod:`fmu_opinf.signals`).  Default: for a ROM without inputs ``"none"`` (the free response
        from the initial state; the source's inputs, if any, held at their start values), else a harmonic on
        each input the training drove, at the training's amplitude and operating point and at a frequency between
        the ROM's natural frequencies (:mod:`fmu_opinf._test_input`); with two driven inputs or more, the same
        harmonics once more per input, it alone swinging (``each_input_alone`` of the result: one more run of the
        source each; together, the input that moves the outputs most hid another's 11 % error).  A given spec that
        drives two inputs or more alike (one harmonic, impulse, step or chirp for all) is likewise run with each
        input alone, up to :data:`~fmu_opinf.compare._alone.ALONE_AT_MOST` inputs (above, a line says how to run
        one; a ``;``-separated spec or a table is compared as given), and a line names an input the joint run hides
        (:func:`~fmu_opinf.compare._alone.hidden_input_line`, ``alone_note`` of the result).  Both sides start
        from the source's initial state: the ROM from the source's positions and velocities after initialization,
        projected on its basis (its stored ``q0, qdot0`` for a builtin or ROM source, or where the state cannot be
        read).
    dt, t_end : float, optional
        Grid; defaults: the ROM's training step and four times the training end time, cut before the time at which
        the training's recording found the source FMU terminating the simulation (said in a line unless ``quiet``).
    inputs, outputs, parameters, interface, tolerance, method, start_time : optional
        How the source FMU is driven, as :func:`~fmu_opinf.snapshots.record` and ``record_to_file`` take them (the
        command line's ``--inputs``, ``--outputs``, ``--set``, ``--interface``, ``--tolerance``, ``--me-method``,
        ``--start-time``).  What is not given is taken from the ROM's training provenance: the force inputs and
        outputs by their recorded names, the recorded ``--set`` values and the FMU time the training runs started at
        (``start_time``, 0 where none is recorded), so a comparison drives the FMU the way the training did.  A ROM
        side with extra outputs (an FMU exported with ``--reconstruct``) is compared on the source's outputs, matched
        by name.  With an opened source (a :class:`~fmu_opinf.sources.Source`, compared as opened) they are refused
        but ``start_time``.
    isolate, timeout : optional
        Run the source FMU in a child process (default True; the command line's ``--in-process`` is
        ``isolate=False``), and the seconds it may take per run (``--timeout``).
    source_options : dict, optional
        The same options as a dict (the keys of :data:`SOURCE_OPTIONS`; another key is refused in one line), as
        compare took them before it took keywords; a key given both ways must have the same value.
    **sizes
        A builtin system's size options (``g=``, ``n1=``, ``alpha=``, ``beta=``, ``v=``); another keyword is refused
        in one line naming the closest one.

    Returns
    -------
    Comparison
    """
    from .._validate import check_keywords
    from ..newmark import MAX_GRID_STEPS, time_grid
    from ..sources import StepError

    given = {"inputs": inputs, "outputs": outputs, "parameters": parameters, "interface": interface,
             "tolerance": tolerance, "method": method, "start_time": start_time, "isolate": isolate,
             "timeout": timeout}
    check_keywords(sizes, SOURCE_OPTIONS, "compare", "keyword")
    source_options = _source_options(source, source_options, {**given, **sizes})
    rom_side = _load_rom_side(rom)
    rom_info = _rom_side_info(rom_side)
    dt = float(dt if dt is not None else rom_info["dt"])
    end_given, end_from = t_end is not None, "the input table's last time"
    if t_end is None:   # an input table's last time (audit 70, F3: four times the training ran past it)
        t_end = _table_end(signal, rom_info)
    if t_end is None:
        end_from = "four times the training's end"
        t_train = rom_info.get("t_train_end")
        if not (t_train and math.isfinite(float(t_train)) and 0 < 4 * float(t_train) / dt <= MAX_GRID_STEPS):
            raise DimensionError(f"no {either('--t-end')} given and the ROM does not record a usable training "
                                 f"end time ({t_train}); pass {either('--t-end')}")
        t_end = dt * round(4 * float(t_train) / dt)
        capped = _before_termination(rom_info, source, dt, float(t_end))
        if capped is not None:
            t_end, end_from = capped[0], "before the termination the training recorded"
            if not quiet:
                print(capped[1], file=sys.stderr)
    t = time_grid(dt, float(t_end))
    if str(source).startswith("builtin:") and source_options.get("start_time") is not None:
        raise InputSpecError(f"{either('--start-time')} applies to fmu sources, not to {source}")
    source_options = _training_settings(rom_info, source, source_options)
    _warn_if_another_fmu(rom_info, source)
    _warn_if_recording_warned(rom_info, _compared_interface(source, source_options))
    _warn_if_merged(rom_info)
    _warn_if_training_missed(rom_side, rom_info)
    if rom_info["m"] == 0:
        signal = signal or "none"
        source_options.setdefault("inputs", "none")  # every source input held at its start value
    why = ""
    if not signal:
        signal, why = _default_test_input(rom_side, rom_info, dt, float(t_end))
        if not quiet:
            print(f"no {either('--input')} given: comparing on {signal} ({why})", file=sys.stderr)
    alone, skipped = (_each_input_alone(signal, rom_info), "") if why else given_each_input_alone(
        signal, int(rom_info["m"]), list(rom_info["input_names"] or []))
    if skipped and not quiet:
        print(skipped, file=sys.stderr)
    if alone and not quiet:
        print(f"then each of {', '.join(name for name, _ in alone)} alone ({len(alone)} more runs of the source: "
              "together, the input that moves the outputs most hides the others' errors)", file=sys.stderr)
    run = _Run(rom_side, rom_info, source, source_options, t, quiet)
    try:
        result = run.compared(signal, why)
        result.each_input_alone = [run.compared(spec, "", name) for name, spec in alone]
        hidden = hidden_input_line(result, result.each_input_alone)
        if hidden and not quiet:
            print(hidden, file=sys.stderr)
        result.alone_note = hidden or skipped
        if why and moves_on_its_own(rom_side, rom_info):
            result.free_response = _free_response(run, quiet)
        if why and not isinstance(rom_side, Path):
            result.training_band = _training_band(run, result, signal, quiet)
    except StepError as stopped:
        raise _past_termination(stopped, float(t_end), end_given, end_from) from None
    result.inputs = [os.fspath(item) for item in (rom, source, signal) if isinstance(item, (str, os.PathLike))]
    return result


def _source_options(source: Any, dictionary: dict[str, Any] | None, keywords: dict[str, Any]) -> dict[str, Any]:
    """The source's options of a :func:`compare` call: its keywords (None: not given) and its ``source_options``
    (checked against :data:`SOURCE_OPTIONS`) together; a key given both ways with two values is refused in one line,
    and so is an option that opens the source (:data:`OPENING_OPTIONS`) with an opened source, which is compared as
    opened (:func:`~fmu_opinf.sources.open_source` returns it as is: the option would be dropped without a word)."""
    from .._validate import check_keywords
    from ..sources import Source

    check_keywords(dictionary or {}, SOURCE_OPTIONS, "compare's source_options")
    options = dict(dictionary or {})
    for key, value in keywords.items():
        if value is None:
            continue
        if options.get(key, value) != value:
            raise InputSpecError(f"compare got {key}={value!r} and source_options[{key!r}]={options[key]!r}; give "
                                 f"{key}= alone")
        options[key] = value
    opening = [key for key in OPENING_OPTIONS if options.get(key) is not None]
    if isinstance(source, Source) and opening:
        raise InputSpecError(f"{opening[0]}= applies where the source is given as a path or spec, but {source!r} is an "
                             f"opened source, compared as opened; give the source as its path or spec, or open it "
                             f"with open_source(spec, {opening[0]}=...)")
    return options


#: How compare names its run of the free response (``driven_alone`` of :attr:`Comparison.free_response`).
FREE_RESPONSE = "free response (none)"


def _free_response(run: "_Run", quiet: bool) -> "Comparison | None":
    """The comparison of the free response (input ``none``), said in one line; None, also said, where the source's
    free response is zero throughout: it rests without input, and eq. (19) has no scale (audit 80 F4: a training
    whose step acted from t = 0 counted as motion of its own, and the whole comparison stopped with "the reference
    output is identically zero")."""
    free = run.compared("none", "", FREE_RESPONSE)
    if not np.any(free.y_fom):
        if not quiet:
            print("the source's free response (input none) stays at zero: it rests without input; not compared",
                  file=sys.stderr)
        return None
    if not quiet:
        print(free_response_line(free), file=sys.stderr)
    return free


#: How compare names its run at the top of the band the training excited (``driven_alone`` of
#: :attr:`Comparison.training_band`).
TRAINING_BAND = "top of the training band"

#: Factor by which the largest miss over an output's range at the top of the training band must exceed the default
#: test's for compare to say that the default test hides it.
BAND_WORSE = 2.0


def _training_band(run: "_Run", result: Comparison, chosen: str, quiet: bool) -> "Comparison | None":
    """The comparison on a second default test input, at the top of the band the training excited
    (:func:`fmu_opinf._test_input.band_test_input`), said in one line (:func:`training_band_line`): where it drives
    several inputs, also each alone, and the run with the largest miss is kept and set against the default test's
    worst run (of it and its runs of each input alone); None where the
    default test already lies there, or the ROM is not reduced (its order is the snapshot rank: no mode the
    snapshots hold is truncated, and the run would cost an FMU run for nothing).  A ROM object only: an exported ROM
    FMU carries no matrices to find the band by.

    Audit base82, F3: an r = 16 ROM of a 20-mass chain on an ``Accelerate`` support was 5.8 % of an output's range off
    the exact model at 5 rad/s, while compare's default test at 0.59 rad/s read 9.3e-5 (eq. 19) and said nothing else;
    at the band's top it reads 3.4 % of range (0.74 % at the default test)."""
    from .._test_input import band_test_input

    rom = run.rom_side
    rank = (getattr(rom, "fit_info", None) or {}).get("snapshot_rank")
    if not isinstance(rank, (int, np.integer)) or not int(rank) > int(rom.r):
        return None
    try:
        found = band_test_input(rom, float(run.t[1] - run.t[0]), float(run.t[-1]), chosen)
    except InputSpecError:   # (an extra test: where none can be made, the default one stands alone)
        found = None
    if found is None:
        return None
    spec, why, top = found
    band = _worst_of([run.compared(spec, why, TRAINING_BAND)]
                     + [run.compared(alone, why, f"{TRAINING_BAND}, {name} alone")
                        for name, alone in _each_input_alone(spec, run.rom_info)])
    if not quiet:
        print(training_band_line(_worst_of([result] + list(result.each_input_alone)), band, top, int(rank)),
              file=sys.stderr)
    return band


def _alone_said(comparison: Comparison) -> str:
    """`` (F[1] alone)`` for a comparison that drove one input alone, else ""."""
    name = comparison.driven_alone.removeprefix(TRAINING_BAND).removeprefix(", ").removesuffix(" alone")
    return f" ({name} alone)" if name else ""


def training_band_line(default: Comparison, band: Comparison, top: float, rank: int) -> str:
    """One line on the comparison at the top of the training band beside the default test's: its input, eq. (19),
    the largest miss over an output's range there and in the default test, and, where the band's is
    :data:`BAND_WORSE` times larger, that the default test hides it and what to do."""
    name, miss = _largest_miss(band)
    default_name, default_miss = _largest_miss(default)
    line = (f"the training excited the outputs up to {top:.3g} rad/s, above this test: compared near that top as "
            f"well, on {band.input_spec}: max eps_y {float(band.eps.max()):.3g}")
    if name is None:
        return line
    line += (f"; largest miss {miss:.2g} of {name}'s range there{_alone_said(band)} (this test: {default_miss:.2g} of "
             f"{default_name}'s{_alone_said(default)})")
    if miss > BAND_WORSE * default_miss:
        line += (f": the ROM follows the top of its training band {miss / max(default_miss, 1e-300):.2g} times worse "
                 f"than this test shows; its order r={band.r} leaves out modes the training excited, a larger one "
                 f"may follow them (fit {either('--r')} up to the snapshot rank {rank})")
    return line


def moves_on_its_own(rom_side: Any, rom_info: dict[str, Any] | None = None) -> bool:
    """Whether the ROM's training showed its source moving on its own from its start values, the inputs held
    (``fit_info["own_motion"]``, :func:`fmu_opinf.fit.own_motion`): compare's default test, a harmonic sized to the
    training, then hides the start transient (audit 77b, F2: eq. 19 said 6e-5 .. 8e-5 where the free response was
    27-104 % of its range off), so the free response is compared as well.  For an exported ROM FMU (``rom_side`` a
    path) its provenance.json says so (``rom_fmu_moves_on_its_own``, exactly ``true``: a data file)."""
    if isinstance(rom_side, Path):
        info = rom_info or {}
        return (info.get("provenance") or {}).get("rom_fmu_moves_on_its_own") is True and int(info.get("m", 0)) > 0
    info = getattr(rom_side, "fit_info", None)
    return isinstance(info, dict) and isinstance(info.get("own_motion"), dict) and int(getattr(rom_side, "m", 0)) > 0


def free_response_line(free: "Comparison") -> str:
    """One line on the free response's comparison: eq. (19) and the largest miss over an output's range there, or
    over its training motion for an output that rests there (``at_rest``: audit86 F4b, round-off taken as a range
    read 2.7e6 off)."""
    metrics = free.metrics()
    per_output = metrics["per_output"]
    misses = {name: figures["relative_max_variation"] for name, figures in per_output.items()
              if figures["relative_max_variation"] == figures["relative_max_variation"]}
    worst = max(misses, key=misses.get) if misses else None
    share = ""
    if worst is not None:
        over = "training motion (it rests there)" if per_output[worst]["scale"] == "training" else "range there"
        share = f"; largest miss {misses[worst]:.2g} of {worst}'s {over}"
    resting = [name for name in metrics["at_rest"] or [] if name != worst]
    if resting:
        listed = ", ".join(f"{name} {misses.get(name, math.nan):.2g}" for name in resting)
        share += f"; resting there, judged against their training motion: {listed}"
    return (f"the ROM's training shows the source moving on its own from its start values: its free response (input "
            f"none) was compared as well: max eps_y {float(free.eps.max()):.3g}{share}")


def _each_input_alone(spec: str, rom_info: dict[str, Any]) -> list[tuple[str, str]]:
    """The chosen test input ``spec`` with each driven input swinging alone (:func:`fmu_opinf._test_input.
    each_input_alone`); empty where fewer than two inputs swing."""
    from .._test_input import each_input_alone

    return each_input_alone(spec, int(rom_info["m"]), list(rom_info["input_names"] or []))


@dataclass
class _Run:
    """One comparison's two sides, the grid and the source's options: :meth:`compared` runs both on an input."""

    rom_side: Any
    rom_info: dict[str, Any]
    source: Any
    source_options: dict[str, Any]
    t: np.ndarray
    quiet: bool

    def compared(self, spec: Any, why: str, alone: str = "") -> Comparison:
        """The source and the ROM on the input ``spec`` (``why``: how compare chose it, "" where given; ``alone``:
        the input it drives alone, "" for all)."""
        from ..rom import held_input_names
        from ..signals import parse_signal
        from ..snapshots._inputs import check_table_times

        rom_side, rom_info, source, options, t = self.rom_side, self.rom_info, self.source, self.source_options, self.t
        held = held_input_names(rom_info["provenance"])
        signal = _held_at_start_values(parse_signal(spec, rom_info["m"], rom_info["input_names"], held), source,
                                       options)
        check_table_times([signal], float(options.get("start_time") or 0.0))
        trained = _trained_input_names(rom_info)
        by_name = {"signal_inputs": trained} if _fmu_path(source) and trained else {}
        y_fom, fom_seconds, fom_prov, fom_outputs = simulate_outputs(source, signal, t, quiet=self.quiet, **options,
                                                                     **by_name)
        rows = _matching_outputs(list(fom_outputs), rom_info["output_names"], by_name=isinstance(rom_side, Path))
        # an exported ROM FMU is driven (and timed) exactly as the source FMU: same process isolation
        isolate = bool(options.get("isolate", True))
        rom_options: dict[str, Any] = ({"isolate": isolate, **rom_info.get("fmu_options", {})}
                                       if isinstance(rom_side, Path) else {})
        if not isinstance(rom_side, Path):
            rom_options["initial"] = _source_start(rom_side, source, signal, t, options)
        y_rom, rom_seconds, _, _ = simulate_outputs(rom_side, signal, t, quiet=True, **rom_options)
        y_rom = np.atleast_2d(y_rom)[rows]
        if why:
            why += _past_training(y_fom, y_rom, list(fom_outputs), rom_info, source)
        beyond = {} if why or alone else input_beyond_training(signal, t, rom_info)
        if beyond:
            _warn_beyond_training(beyond, source)
        return Comparison(
            t=t, y_fom=y_fom, y_rom=np.atleast_2d(y_rom), output_names=list(fom_outputs),
            output_units=_declared_units(source, list(fom_outputs)),
            output_display_units=_declared_display_units(source, list(fom_outputs)),
            input_spec=signal.spec, fom_seconds=fom_seconds, rom_seconds=rom_seconds, r=rom_info["r"],
            fom_provenance=fom_prov, rom_provenance=rom_info["provenance"], t_train_end=rom_info.get("t_train_end"),
            timed=_timed(source, rom_side, isolate, fom_prov),
            input_choice=f"chosen without {either('--input')}: {why}" if why else "",
            order=_carried_order(rom_info["provenance"]) if isinstance(rom_side, Path) else _order_chosen(rom_side),
            driven_alone=alone, beyond_training=beyond,
            linear_fits=_carried_linear_fits(rom_info) if isinstance(rom_side, Path) else _linear_fits(rom_side),
            training_miss=_training_miss(rom_side, rom_info), training_peaks=_training_peaks(rom_info, rows))


def _training_peaks(rom_info: dict[str, Any], rows: list[int]) -> list[float] | None:
    """The training's output peaks (:func:`fmu_opinf._test_input.recorded_peaks`) of the ROM outputs ``rows`` that
    the comparison holds, None where the ROM's provenance lacks them."""
    from .._test_input import recorded_peaks

    peaks = recorded_peaks(rom_info["provenance"], len(rom_info["output_names"]))
    return None if peaks is None else [float(peaks[row]) for row in rows]


def _table_end(signal: Any, rom_info: dict[str, Any]) -> float | None:
    """The last time of an input table given as ``signal`` (None for any other input or none): the default end of
    a comparison driven by it, since it cannot be sampled beyond."""
    from ..rom import held_input_names
    from ..signals import parse_signal
    from ..snapshots._inputs import input_table_end

    if signal is None:
        return None
    if isinstance(signal, str):
        held = held_input_names(rom_info["provenance"])
        signal = parse_signal(signal, rom_info["m"], rom_info["input_names"], held) if rom_info["m"] else None
    return input_table_end([signal]) if signal is not None else None


def _past_termination(stopped: Any, t_end: float, end_given: bool,
                      end_from: str = "four times the training's end") -> Any:
    """The error of a source run that the FMU ended by terminating the simulation, where the run went to
    compare's default end (``end_from`` says which: four times the training's, an input table's last time, or
    before the termination the training recorded): the fix is compare's ``--t-end`` (audit 70, F5: the source's
    advice said "record a shorter run").  Likewise a step that failed where it passed the FMU's declared stopTime,
    whose line names --t-end at or below it (audit 75, F2: a compiled-in stop time failed compare's default end)."""
    from ..sources import StepError, declared_stop_at, terminated_at

    at, stop = terminated_at(str(stopped)), declared_stop_at(str(stopped))
    if end_given or (at is None and stop is None):
        return stopped
    fix = (f"compare {either('--t-end')} below {at:g}" if at is not None
           else f"compare {either('--t-end')} at or below {stop:g}")
    return StepError(f"{stopped} (compare ran to its default t_end={t_end:g}, {end_from}; give {fix})",
                     stopped.step, stopped.time)


def _recorded_termination(rom_info: dict[str, Any]) -> float | None:
    """The time (from the run's start) at which the training's FMU terminated the simulation in a pilot run of the
    automatic window, as the snapshot provenance of a ROM (``.h5``) or of an exported ROM FMU records it
    (``auto_window["terminates_at"]``); None where it records none (older files, FMUs that do not terminate)."""
    snapshots = rom_info["provenance"].get("snapshots")
    window = snapshots.get("auto_window") if isinstance(snapshots, dict) else None
    if isinstance(window, str):   # (as a snapshot file's attribute: JSON text)
        try:
            window = json.loads(window)
        except ValueError:
            return None
    at = window.get("terminates_at") if isinstance(window, dict) else None
    try:
        at = float(at) if at is not None else None
    except (TypeError, ValueError):   # (a damaged file's)
        return None
    return at if at is not None and math.isfinite(at) and at > 0 else None


def _before_termination(rom_info: dict[str, Any], source: Any, dt: float, t_end: float) -> tuple[float, str] | None:
    """compare's default end ``t_end`` (four times the training's) cut to the last point of its grid before the time
    at which the training found the source FMU terminating the simulation, and the line saying so; None where the
    training found no termination, the source is no FMU, or ``t_end`` lies before it.

    The training's recording ends there itself (its automatic window stops before the termination); compare ran on
    to four times the training's end and failed with an error naming ``--t-end`` (audit 71 F8)."""
    at = _recorded_termination(rom_info)
    if at is None or not _fmu_path(source) or t_end < at * (1.0 - 1e-6):
        return None
    last = dt * math.floor(at * (1.0 - 1e-6) / dt * (1.0 + 1e-12) + 1e-9)   # the step ending at ``at`` is refused
    if last < 2 * dt:
        return None
    last = float(f"{last:.12g}")
    return last, (f"{Path(str(source)).name} terminated the simulation at t={at:g} in the training's recording: "
                  f"comparing to t_end={last:g}, before it (not four times the training's end, {t_end:g}; "
                  f"{either('--t-end')} chooses another end)")


def _default_test_input(rom_side: Any, rom_info: dict[str, Any], dt: float, t_end: float) -> tuple[str, str]:
    """The test input without one given (:mod:`fmu_opinf._test_input`): chosen from the ROM, or the one an exported
    ROM FMU carries for its training grid (a data file: taken only as a string, parsed like any --input)."""
    from .._test_input import _FIX, carried_for_grid, default_test_input

    if not isinstance(rom_side, Path):
        return default_test_input(rom_side, dt, t_end)
    carried = rom_info["provenance"].get("default_test_input")
    if not (isinstance(carried, list) and len(carried) == 2 and all(isinstance(v, str) for v in carried)):
        raise InputSpecError(f"no test input given, and {rom_side.name} carries none (exported before 2026-12-06); "
                             + _FIX)
    spec, why = ("".join(c for c in text if c.isprintable()) for text in carried)   # (no terminal controls)
    spec = carried_for_grid(spec, rom_side.name, int(rom_info["m"]), dt, t_end)
    return spec, f"{why}; chosen at export for the FMU's own step and four times its training end"
