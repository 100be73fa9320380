"""Validation of a ROM against the model it replaces: the paper's error measure.

``compare`` runs the full-order source (FMU or builtin simulator) and the ROM (a ``rom.h5`` or an
exported ROM FMU) on the same input and time grid, computes eq. (19) and relative L2 / max
errors per output, times both, and says where the test left what the ROM was trained on.
:func:`fmu_opinf.report.write_report` writes what it measured (``metrics.json``, the paper's figures, one
self-contained ``index.html``); its names are also reached here as before (``compare.write_report``).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._hdf5 import jsonable
from .errors import DimensionError, FileFormatError, FmuOpinfError, InputSpecError

if TYPE_CHECKING:
    from .rom import SecondOrderROM
    from .signals import Signal

__all__ = ["output_error", "error_metrics", "offset_note", "scale_note", "linear_fit_note", "Comparison", "compare",
           "simulate_outputs", "DisplayUnit"]


def output_error(y_ref: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Relative output error over time, paper eq. (19).

    ``eps_y(t_i) = ||y_ref(t_i) - y(t_i)||_2^2 / max_t ||y_ref(t)||_2^2``

    Parameters
    ----------
    y_ref, y : (p, k) ndarray
        Reference (full-order) and approximate outputs on the same time grid.

    Returns
    -------
    (k,) ndarray
    """
    return _eq19(*_in_reference_units(y_ref, y)[:2])


def _eq19(y_ref: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Eq. (19) of outputs already in the reference's units (:func:`_in_reference_units`)."""
    scale = np.max(np.sum(y_ref**2, axis=0))
    if scale == 0:
        raise DimensionError("the reference output is identically zero; eq. (19) is undefined")
    return np.sum((y_ref - y) ** 2, axis=0) / scale


def _in_reference_units(y_ref: Any, y: Any) -> tuple[np.ndarray, np.ndarray, float]:
    """Both outputs divided by the reference's largest magnitude, and that unit (1 for a zero or non-finite
    reference): the error measures are ratios, and squaring raw outputs above about 1e154 overflowed to a NaN error
    reported as a success (audit 68)."""
    y_ref = np.atleast_2d(np.asarray(y_ref, dtype=float))
    y = np.atleast_2d(np.asarray(y, dtype=float))
    if y_ref.shape != y.shape:
        raise DimensionError(f"outputs differ in shape: reference {y_ref.shape}, ROM {y.shape}")
    unit = float(np.max(np.abs(y_ref))) if y_ref.size else 0.0
    if not (math.isfinite(unit) and unit > 0):
        return y_ref, y, 1.0
    return y_ref / unit, y / unit, unit


def error_metrics(y_ref: np.ndarray, y: np.ndarray, output_names: list[str] | None = None) -> dict[str, Any]:
    """All error figures of a comparison.

    Returns
    -------
    dict
        ``max_error`` (max over time of eq. 19), ``l2_error`` (``||Y_ref - Y||_F / ||Y_ref||_F``),
        ``max_error_variation`` (eq. 19 with each reference output's time mean removed from the scale:
        ``max_t ||y_ref - y||^2 / max_t ||y_ref - mean_t y_ref||^2``) and ``per_output``: for each output its
        relative L2 error, its max absolute error relative to the output's peak and relative to its variation
        (``relative_max_variation``, peak minus trough; NaN where the output is zero or constant, null in
        metrics.json) and its max absolute error (``absolute_max``).  Eq. (19) is the paper's measure; the figures relative to the
        variation show errors that a large static offset (``y0``, a static deflection) would hide (second audit,
        2026-11-26: eq. 19 3.3e-5 where one output's motion was 22 % off).
    """
    y_ref, y, unit = _in_reference_units(y_ref, y)
    eps = _eq19(y_ref, y)
    names = output_names or [f"y[{j + 1}]" for j in range(y_ref.shape[0])]
    per_output = {}
    for j, name in enumerate(names):
        peak = np.abs(y_ref[j]).max()
        diff = y_ref[j] - y[j]
        span = float(y_ref[j].max() - y_ref[j].min())
        per_output[name] = {
            "relative_l2": float(np.linalg.norm(diff) / np.linalg.norm(y_ref[j])) if peak > 0 else math.nan,
            "relative_max": float(np.abs(diff).max() / peak) if peak > 0 else math.nan,
            "relative_max_variation": float(np.abs(diff).max() / span) if span > 0 else math.nan,
            "absolute_max": float(np.abs(diff).max()) * unit,
        }
    moving = y_ref - y_ref.mean(axis=1, keepdims=True)
    scale = float(np.max(np.sum(moving**2, axis=0)))
    return {
        "max_error": float(eps.max()),
        "l2_error": float(np.linalg.norm(y_ref - y) / np.linalg.norm(y_ref)),
        "max_error_variation": float(np.max(np.sum((y_ref - y) ** 2, axis=0)) / scale) if scale > 0 else math.nan,
        "per_output": per_output,
    }


#: Ratio of the error relative to the outputs' variation to eq. (19) from which a comparison says that an offset
#: hides the error.
OFFSET_HIDES = 100.0


#: How many outputs one note of :func:`offset_note` or :func:`scale_note` names (the rest are counted).
MAX_NAMED = 6


def offset_note(metrics: dict[str, Any]) -> str | None:
    """A line saying that the outputs' offset hides the error in eq. (19), or None; it names the worst output by its
    error relative to its range, and beside it every other that the variation form understates
    (:func:`_understated`)."""
    varying, paper = metrics.get("max_error_variation", math.nan), metrics["max_error"]
    if not (math.isfinite(varying) and varying > OFFSET_HIDES * paper):
        return None
    relative = {name: float(np.nan_to_num(values["relative_max_variation"]))
                for name, values in metrics["per_output"].items()}
    worst = max(relative, key=lambda name: relative[name])
    above = sorted((name for name in _understated(relative, varying) if name != worst),
                   key=lambda name: -relative[name])
    others = "".join(f", {name} {relative[name]:.2g}" for name in above[:MAX_NAMED - 1])
    more = f" and {len(above) - MAX_NAMED + 1} more" if len(above) > MAX_NAMED - 1 else ""
    return (f"the outputs' offset hides the error in eq. (19): relative to the outputs' variation (mean removed) it "
            f"is {varying:.2e} (squared), and {worst} is {relative[worst]:.2g} of its range off{others}{more}")


#: Relative max error of one output below which no note says that larger outputs hide it: round-off (a ROM FMU
#: against its ROM, 1e-13 of a small output's peak) is no error worth a note.
SCALE_NOTE_FLOOR = 1e-6


def scale_note(metrics: dict[str, Any]) -> str | None:
    """A line saying that larger outputs hide the errors of some outputs in eq. (19), or None.

    Eq. (19) and its variation form weigh the outputs by their size, so with outputs in different units or scales
    (positions in mm beside accelerations in m/s2) an output can be far off while both figures are small (fifth
    audit: eq. (19) 1.7e-9, an acceleration output 3.2e-2 of its peak off).  Said when the worst output's relative
    max error, squared to compare with eq. (19), exceeds both figures :data:`OFFSET_HIDES`-fold and is above
    :data:`SCALE_NOTE_FLOOR`; beside it, worst first, every other output that eq. (19) understates
    (:func:`_understated`).
    """
    per_output = metrics.get("per_output") or {}   # a metrics dict of an older report may have none
    if not per_output:
        return None
    varying = metrics.get("max_error_variation", math.nan)
    shown = max(metrics["max_error"], varying if math.isfinite(varying) else 0.0)
    relative = {name: float(np.nan_to_num(values["relative_max"])) for name, values in per_output.items()}
    worst = max(relative, key=lambda name: relative[name])
    if not (relative[worst] ** 2 > OFFSET_HIDES * shown and relative[worst] > SCALE_NOTE_FLOOR):
        return None
    above = [worst] + sorted((name for name in _understated(relative, shown) if name != worst),
                             key=lambda name: -relative[name])
    others = "".join(f", {name} {relative[name]:.2g}" for name in above[1:MAX_NAMED])
    more = f" and {len(above) - MAX_NAMED} more" if len(above) > MAX_NAMED else ""
    return (f"larger outputs hide an error in eq. (19): {worst} is {relative[worst]:.2g} of its peak off "
            f"(squared {relative[worst] ** 2:.2e}){others}{more}; see the per-output errors")


def _understated(relative: dict[str, float], figure: float) -> list[str]:
    """The outputs whose relative max error, squared, exceeds ``figure`` (the squared figure a note quotes) and
    :data:`SCALE_NOTE_FLOOR`: the figure understates them.  A note names them beside the worst, so that it does not
    read as "the rest is fine" (audit 77a F1: the line named only a nonlinear output 0.34 of its peak off, with eq.
    (19) at 5.8e-4, and not the linear outputs beside it at 0.052 and 0.137, which the fit had bent toward it).
    Not the bar that calls the note (:data:`OFFSET_HIDES` times the figure): at 100-fold those two, 4.7 and 32
    times eq. (19), would not have been named."""
    return [name for name, value in relative.items() if value ** 2 > figure and value > SCALE_NOTE_FLOOR]


def comparison_notes(metrics: dict[str, Any]) -> list[str]:
    """The lines that say what eq. (19) hides (:func:`training_miss_note`: the fit's own miss of its training
    outputs, first; :func:`offset_note`, :func:`scale_note`) and what to try where the ROM misses
    (:func:`order_note`)."""
    notes = (training_miss_note(metrics), offset_note(metrics), scale_note(metrics), linear_fit_note(metrics),
             order_note(metrics))
    return [note for note in notes if note]


def training_miss_note(metrics: dict[str, Any]) -> str | None:
    """A line, first of the notes, where fit warned that the ROM misses its own training outputs
    (``metrics["training_miss"]``, :func:`fmu_opinf.fit._training_checks.training_miss_record`), naming that miss
    beside this comparison's figure, or None: a test input far from the training's (compare's default harmonics lie
    below the ROM's band) need not show it (audit 79a F1: 5.0e-3 here, 0.22 of range on the training impulse)."""
    from .fit._training_checks import training_miss_text

    record = metrics.get("training_miss") or {}
    per_output = metrics.get("per_output") or {}
    if not record:
        return None
    here = ""
    if per_output:
        name, worst = max(per_output.items(), key=lambda item: np.nan_to_num(item[1].get("relative_max_variation")))
        here = f" (this test: {float(np.nan_to_num(worst.get('relative_max_variation'))):.2g} of {name}'s range)"
    order = metrics.get("order") or {}
    fix = ""
    if isinstance(order.get("r"), int) and order.get("snapshot_rank", 0) > order["r"]:
        fix = (f"; a larger order may reach them (fit --r up to the snapshot rank {order['snapshot_rank']}, see "
               "fit's warning)")
    return (f"fit warned that this ROM misses its own training outputs by {training_miss_text(record)}: an input "
            f"like the training one is that far off, whatever this test shows{here}{fix}")


def linear_fit_note(metrics: dict[str, Any]) -> str | None:
    """A line naming the outputs the fit found not linear in the recorded states (``metrics["linear_fits"]``), or
    None: their error is that of a linear fit, which neither a larger order nor other training removes, and the
    other outputs' errors are the ROM's own (audit 77a F1)."""
    names = [name for name in metrics.get("linear_fits") or [] if name in (metrics.get("per_output") or {})]
    if not names:
        return None
    one = len(names) == 1
    verb, them, its = ("is", "it", "its") if one else ("are", "them", "their")
    listed = ", ".join(f"{name} ({metrics['per_output'][name]['relative_max']:.2g})" for name in names[:MAX_NAMED])
    more = f" and {len(names) - MAX_NAMED} more" if len(names) > MAX_NAMED else ""
    return (f"{listed}{more} of {its} peak off {verb} {'a linear fit' if one else 'linear fits'}: the fit found "
            f"{them} not linear in the recorded states and left {them} out of what steers the ROM, so no order or "
            f"training removes that error; record without {them} (snapshots --outputs) where not needed")


#: Relative max error of the worst output (over its range) above which a comparison of a ROM whose order came from
#: the POD energy suggests a larger one: 1 %.
ORDER_NOTE = 1e-2


def order_note(metrics: dict[str, Any]) -> str | None:
    """A line where the ROM misses an output by over :data:`ORDER_NOTE` of its range and its order came from the POD
    energy or the fit's order search below the snapshot rank, or None: it suggests a larger ``--r`` the search did
    not try, else says that the search found none and to train nearer the input.

    The energy criterion (eq. 18) counts the modes the training excited; a test input that excites others more
    needs them (audit 62: an FE bar trained with the default impulse got r = 3 from a snapshot rank of 300 and was
    1-1.6 % of the range off on a harmonic test; ``--r 6`` on the same snapshots, 0.07-0.2 %).  An order the search
    tried and did not keep fitted the training no better, so it is never suggested (audit 65, F4: ``fit --r 40`` was
    suggested after the search had found r = 40 272 times off its training outputs); where the search stopped at
    a noise floor of the snapshots' singular values, a smaller order is suggested instead.
    """
    order, per_output = metrics.get("order") or {}, metrics.get("per_output") or {}
    if order.get("chosen") not in ("energy", "search") or not order.get("snapshot_rank", 0) > order.get("r", 0) \
            or not per_output:
        return None
    fitted = set(metrics.get("linear_fits") or [])   # (their error is a linear fit's: no order removes it)
    per_output = {name: values for name, values in per_output.items() if name not in fitted}
    if not per_output:
        return None
    name, worst = max(per_output.items(), key=lambda item: np.nan_to_num(item[1].get("relative_max_variation")))
    relative = float(np.nan_to_num(worst.get("relative_max_variation")))
    if not relative > ORDER_NOTE:
        return None
    r, tried = order["r"], [int(value) for value in order.get("tried") or []]
    origin = (f"the ROM's order r={r} came from the POD energy (eq. 18)" if order["chosen"] == "energy"
              else f"the fit's order search kept r={r}" + (f" (tried r={', '.join(map(str, tried))})" if tried else ""))
    opening = f"{name} is {relative:.2g} of its range off, and {origin} on snapshots of rank {order['snapshot_rank']}"
    beyond = metrics.get("input_beyond_training") or {}
    if beyond:   # (audit 74, F1: at 100 times the training's load, fit --r 8 still missed by 2-4 %)
        return (f"{opening}: this input is {beyond['ratio']:.3g} times the training's amplitude on {beyond['input']}, "
                f"so train with an input nearer this one first (snapshots --input at these loads); a larger order "
                f"(fit --r {min(2 * r, order['snapshot_rank'])}) fits only the responses the training had")
    floor = order.get("noise_floor")
    if floor:
        return (f"{opening}: its singular values from s_{floor} on lie on a noise floor, so larger orders fit the "
                f"noise; a smaller order may follow this input better (fit --r {max(int(floor) - 1, 1)}, then "
                "compare again), and less noisy snapshots would")
    if not any(value > r for value in tried):   # (2 r, or the rank above r, was not tried)
        return (f"{opening}: a larger order may follow this input (fit --r {min(2 * r, order['snapshot_rank'])}, "
                "then compare again); if it does not, train with an input nearer this one")
    return (f"{opening}: the larger orders it tried did not fit the training outputs enough better to be kept; "
            "train with an input nearer this one (or add it as a training run)")


@dataclass(frozen=True)
class DisplayUnit:
    """An output's declared ``displayUnit`` and its conversion from the output's unit, FMI's
    ``DisplayUnit_value = factor * Unit_value + offset`` (FMI 2.0 section 2.2.2, ``fmi3Unit.xsd``).

    The report plots and lists outputs in it, as a tool reading the FMU would show them (audit 81c, F10: a rad
    output with displayUnit deg was drawn in rad); the error measures, ratios, do not depend on it.
    """

    name: str
    factor: float
    offset: float = 0.0

    def values(self, y: np.ndarray) -> np.ndarray:
        """``y`` (in the output's unit) in this display unit."""
        return self.factor * np.asarray(y, dtype=float) + self.offset

    def difference(self, dy: float) -> float:
        """A difference ``dy`` of two values in the output's unit, in this display unit (the offset cancels)."""
        return abs(self.factor) * dy


@dataclass
class Comparison:
    """Outputs of the full-order model and of the ROM on one input, with timings and provenance.

    Attributes
    ----------
    t : (k,) ndarray
    y_fom, y_rom : (p, k) ndarray
    output_names : list of str
    input_spec : str
    fom_seconds, rom_seconds : float
        Wall time of each simulation (the FOM's includes only stepping and reading outputs).
    r : int
        Reduced order.
    fom_provenance, rom_provenance : dict
    t_train_end : float or None
        Last training snapshot time, marked on the error plot when known.
    output_units : list of str, optional
        Unit of each output where the FMU declares one ("" where not), for the figure labels.
    output_display_units : list of DisplayUnit or None, optional
        Each output's declared ``displayUnit`` where its unit's definition gives it (None where not): the outputs
        figure and the page's absolute errors use it.
    input_choice : str
        Where ``compare`` chose the test input itself (none given): how and why, else "".
    driven_alone : str
        The input this comparison drove alone (the others held at their operating point), "" where it drove all.
    beyond_training : dict
        Where a given test input departs from the training's operating point by over :data:`INPUT_SIZE_NOTE` times
        the training's amplitude on some input: that ``input``, the ``ratio``, the ``given`` departure and the
        ``trained`` amplitude (:func:`input_beyond_training`); empty otherwise.
    each_input_alone : list of Comparison
        Where ``compare`` chose a test input driving two inputs or more: the same harmonics, one input swinging at a
        time (:func:`fmu_opinf._test_input.each_input_alone`), so that an input whose response the others' hide is
        judged on its own.
    linear_fits : list of str
        The outputs the fit found not linear in the recorded states and left out of what steers the ROM's dynamics
        (``fit_info["nonlinear_outputs"]``): the ROM gives them by a linear least-squares fit (:func:`linear_fit_note`).
    timed : dict
        What each time measured (``fom``, ``rom``: one sentence each; a ROM file or object: its outputs alone,
        the reduced states are not formed), whether the speed-up compares like with like (``like_with_like``:
        both sides FMUs, stepped the same way in the same kind of process) and the ``clock``.
    inputs : list of str
        The paths ``compare`` was given (the ROM, the source, an input table), which
        :func:`~fmu_opinf.report.write_report` refuses as the report folder, as the command line does.
    """

    t: np.ndarray
    y_fom: np.ndarray
    y_rom: np.ndarray
    output_names: list[str]
    input_spec: str
    fom_seconds: float
    rom_seconds: float
    r: int
    fom_provenance: dict[str, Any] = field(default_factory=dict)
    rom_provenance: dict[str, Any] = field(default_factory=dict)
    t_train_end: float | None = None
    title: str = "ROM validation"
    output_units: list[str] | None = None
    output_display_units: list[DisplayUnit | None] | None = None
    timed: dict[str, Any] = field(default_factory=dict)
    input_choice: str = ""   # why, where compare chose the test input itself (no --input)
    order: dict[str, Any] = field(default_factory=dict)   # how the ROM's order was chosen (order_note)
    driven_alone: str = ""   # the input this comparison drove alone, "" for all (compare's runs of each_input_alone)
    each_input_alone: list["Comparison"] = field(default_factory=list)
    free_response: "Comparison | None" = None   # inputs at their start values, where the FMU moves on its own
    beyond_training: dict[str, Any] = field(default_factory=dict)   # a given input far above the training's
    linear_fits: list[str] = field(default_factory=list)   # outputs the fit found not linear in the states
    training_miss: dict[str, Any] = field(default_factory=dict)   # fit's warned miss of its training outputs
    inputs: list[str] = field(default_factory=list)   # the files compare read: write_report does not write into them

    def __repr__(self) -> str:
        return (f"Comparison(input={self.input_spec!r}, r={self.r}, p={len(self.output_names)}, "
                f"steps={self.t.size - 1}, max_eps_y={float(self.eps.max()):.3g})")

    @property
    def eps(self) -> np.ndarray:
        """eq. (19) over time."""
        return output_error(self.y_fom, self.y_rom)

    def metrics(self) -> dict[str, Any]:
        """The content of ``metrics.json``."""
        out = error_metrics(self.y_fom, self.y_rom, self.output_names)
        out.update({
            "r": int(self.r),
            "fom_seconds": self.fom_seconds,
            "rom_seconds": self.rom_seconds,
            "speedup": self.fom_seconds / self.rom_seconds if self.rom_seconds > 0 else math.inf,
            "speedup_timed": dict(self.timed),
            "input": self.input_spec,
            "input_choice": self.input_choice or None,
            "dt": float(self.t[1] - self.t[0]) if self.t.size > 1 else None,
            "t_end": float(self.t[-1]),
            "steps": int(self.t.size - 1),
            "t_train_end": self.t_train_end,
            "fom": jsonable(self.fom_provenance),
            "rom": jsonable(self.rom_provenance),
            "order": dict(self.order) or None,
            "driven_alone": self.driven_alone or None,
            "each_input_alone": [alone.run_metrics() for alone in self.each_input_alone] or None,
            "free_response": self.free_response.run_metrics() if self.free_response is not None else None,
            "input_beyond_training": dict(self.beyond_training) or None,
            "linear_fits": list(self.linear_fits) or None,
            "training_miss": dict(self.training_miss) or None,
        })
        return out

    def run_metrics(self) -> dict[str, Any]:
        """:meth:`metrics` without what a comparison of several runs says once for all (provenance, what the times
        measured): those of a run of one input alone."""
        return {key: value for key, value in self.metrics().items()
                if key not in ("fom", "rom", "speedup_timed", "t_train_end", "each_input_alone", "free_response",
                               "training_miss")}




# ---------------------------------------------------------------------------------------------
# Running both sides
# ---------------------------------------------------------------------------------------------


def _load_rom_side(rom: Any):
    """A ROM object, a ROM file, or an exported ROM FMU (path ending in .fmu)."""
    from .rom import SecondOrderROM

    if isinstance(rom, SecondOrderROM):
        return rom
    path = Path(rom)
    if path.suffix.lower() == ".fmu":
        return path
    return SecondOrderROM.load(path)


def simulate_outputs(source: Any, signal: Any, t: np.ndarray, quiet: bool = True,
                     **options: Any) -> tuple[np.ndarray, float, dict[str, Any], list[str]]:
    """Outputs of any model on the grid ``t`` under the zero-order-hold input convention.

    Parameters
    ----------
    source : SecondOrderROM, or str / path
        A ROM object or ROM file (``.h5``), ``builtin:NAME``, or a co-simulation FMU (a full-order
        model or an exported ROM).  Only inputs and outputs are touched, so any FMU works.
    signal : Signal
    t : (k,) ndarray
        Uniform time grid.
    **options
        ``g``/``n1`` for builtin sources; ``inputs``/``outputs`` name patterns, ``parameters`` (``--set``),
        ``interface``, ``tolerance`` and ``start_time`` for FMUs (driven as :func:`fmu_opinf.sources.open_source` does);
        ``initial=(q0, qdot0)`` the reduced initial state of a ROM (default its stored one).

    Returns
    -------
    y : (p, k) ndarray
    seconds : float
        Wall time of the simulation loop alone (no loading or compilation).
    provenance : dict
    output_names : list of str
    """
    from .rom import SecondOrderROM

    if isinstance(source, SecondOrderROM) or (not str(source).startswith("builtin:")
                                             and Path(str(source)).suffix.lower() in (".h5", ".hdf5")):
        rom = source if isinstance(source, SecondOrderROM) else SecondOrderROM.load(source)
        q0, qdot0 = options.get("initial") or (None, None)
        start = time.perf_counter()
        y = rom.simulate(signal, float(t[1] - t[0]), float(t[-1]), q0=q0, qdot0=qdot0).y
        return np.atleast_2d(y), time.perf_counter() - start, dict(rom.provenance), list(rom.output_names)
    if str(source).startswith("builtin:"):
        return _builtin_outputs(str(source), signal, t, quiet, **options)
    return _source_outputs(source, signal, t, quiet, **options)


def _source_outputs(spec: Any, signal: Any, t: np.ndarray, quiet: bool,
                    **options: Any) -> tuple[np.ndarray, float, dict[str, Any], list[str]]:
    """Drive an FMU through :mod:`fmu_opinf.source` and keep only its outputs."""
    from ._progress import Progress
    from .newmark import applied_inputs
    from .source import open_source
    from .sources import warn_other_communication_step

    from .snapshots._isolation import deferred_interrupts, produce_inprocess, produce_isolated

    isolate, timeout = options.get("isolate", True), options.get("timeout")
    signal_inputs = options.get("signal_inputs")
    options = {k: v for k, v in options.items()
               if k in ("inputs", "outputs", "parameters", "interface", "tolerance", "method", "start_time")}
    source = open_source(spec, positions="", **options)
    if t.size > 1:  # an FMU with a fixed communication step: another step is said before any run
        warn_other_communication_step(source, float(t[1] - t[0]))
    u = _in_source_order(applied_inputs(signal, t), signal_inputs, source, spec)
    if u.shape[0] != source.m:
        raise DimensionError(f"the input has {u.shape[0]} channels but {Path(str(spec)).name} has {source.m} "
                             "inputs; compare a ROM with the model it was learned from")
    sink = _RowBuffer(256, source.width)
    y = np.empty((source.p, t.size))
    columns = source.layout["y"]
    U = np.ascontiguousarray(u.T)
    _refuse_outside_ranges(source, U, t, signal)
    # like snapshots: a crashing or hanging FMU binary ends in a one-line error, not in the tool's death
    producer = produce_isolated(source, t, U, sink, timeout) if isolate else produce_inprocess(source, t, U, sink)
    start = time.perf_counter()
    with deferred_interrupts(), Progress(t.size, f"simulating {Path(str(spec)).name}", quiet=quiet) as progress:
        try:
            for i0, count in producer:
                y[:, i0:i0 + count] = sink.rows(i0, count)[:, columns].T
                progress.update(i0 + count)
        finally:
            producer.close()
    seconds = getattr(sink, "seconds", None) or time.perf_counter() - start  # the child's own stepping time
    # the run's own report (e.g. the integrator a model-exchange run took, which auto chooses per run)
    return y, seconds, {**source.provenance(), **sink.report}, list(source.output_names)


def _in_source_order(u: np.ndarray, signal_inputs: list[str] | None, source: Any, spec: Any) -> np.ndarray:
    """The input rows ``u``, which follow ``signal_inputs`` (the ROM's inputs), moved to the order of the inputs
    ``source`` drives, by name.  ``compare --inputs F1,F2`` against a ROM trained with ``--inputs F2,F1`` drove
    the ROM's F2 and the FMU's F1 with the same channel, and said nothing (audit 63: max eps_y 0.77 and 16.6 on
    exact data).  Inputs that are not the ROM's are refused in one line: the comparison would drive another model.
    """
    names = list(getattr(source, "input_names", []) or [])
    if not signal_inputs or names == list(signal_inputs):
        return u
    name = Path(str(spec)).name
    if sorted(names) != sorted(signal_inputs):
        raise InputSpecError(f"the inputs of {name} selected here ({', '.join(names) or 'none'}) are not the ones the "
                             f"ROM was trained on ({', '.join(signal_inputs)}); compare drives the ROM's inputs: leave "
                             f"--inputs out or give --inputs {','.join(signal_inputs)}")
    return u[[list(signal_inputs).index(n) for n in names]]


def _refuse_outside_ranges(source: Any, U: np.ndarray, t: np.ndarray, signal: Any) -> None:
    """One line before the run where the input leaves an input's declared ``[min, max]``, naming the input, its
    value, the time, the range and an input within it (the words of the source's own hint, ``_outside_range``, as
    ``snapshots`` gives them after a refusal).  A source that enforces its ranges refused such an input only at
    the step it left them, after running up to there, and said neither which input nor what range (audit 61,
    finding 6); the exported ROM FMU refuses it too."""
    outside_range = getattr(source, "_outside_range", None)
    if outside_range is None or not U.size:
        return
    low, high = source.input_ranges()
    rows = np.flatnonzero(np.any((U < low) | (U > high), axis=1))
    if not rows.size:
        return
    step = int(rows[0])
    hint = outside_range(U, step)
    when = float(t[max(step - 1, 0)])   # (row k holds the input sampled at t[k - 1]: the zero-order hold)
    name = Path(str(getattr(source, "path", "the source"))).name
    raise InputSpecError(f"the input {_short(signal.spec)} leaves a declared input range of {name} at t={when:g}"
                         f"{hint}")


def _short(spec: str, most: int = 120) -> str:
    """An input spec for a message, cut short where it is long (many inputs, a table's path)."""
    return repr(spec) if len(spec) <= most else repr(spec[:most - 3] + "...")


class _RowBuffer:
    """Rows the producers of :mod:`fmu_opinf.snapshots._isolation` fill, one sample per row."""

    def __init__(self, block: int, width: int) -> None:
        self.block = block
        self.buffer = np.empty((block, width))
        self.seconds: float | None = None  # set by an isolated producer: the child's stepping time
        self.events: tuple[int, float | None] | None = None  # set by the producers (not reported by compare)
        self.report: dict[str, Any] = {}  # set by the producers: the source's run_report

    def rows(self, i0: int, count: int) -> np.ndarray:
        return self.buffer[:count]


def _builtin_outputs(spec: str, signal: Any, t: np.ndarray, quiet: bool,
                     **options: Any) -> tuple[np.ndarray, float, dict[str, Any], list[str]]:
    from ._progress import Progress
    from .newmark import NewmarkStepper, applied_inputs
    from .systems import builtin_system

    name = spec.split(":", 1)[1]
    sizes = {k: v for k, v in options.items() if k in ("g", "n1", "alpha", "beta", "v") and v is not None}
    system = builtin_system(name, **sizes)
    u = applied_inputs(signal, t)
    y = np.empty((system.p, t.size))
    start = time.perf_counter()
    stepper = NewmarkStepper(system.M, system.D, system.K, system.B, float(t[1] - t[0]),
                             G=system.G, constraint=system.constraint)
    stepper.start(u[:, 0])
    with Progress(t.size - 1, f"simulating {spec}", quiet=quiet) as progress:
        for i in range(t.size):
            if i:
                stepper.step(u[:, i])
                progress.update(i)
            y[:, i] = system.Cp @ stepper.x + system.Cv @ stepper.v
    seconds = time.perf_counter() - start
    names = [f"y[{j + 1}]" for j in range(system.p)]
    return y, seconds, {"source_kind": "builtin", "source": spec, "system_options": sizes}, names


#: The keys of ``compare(source_options=...)``: an FMU source's (:func:`_source_outputs`, ``isolate`` and ``timeout``
#: of its child process) and a builtin system's sizes (:func:`_builtin_outputs`).  Any other key is refused: one
#: dropped without a word compared another model than the one asked for (audit 81c F2).
SOURCE_OPTIONS = ("inputs", "outputs", "parameters", "interface", "tolerance", "method", "start_time", "isolate",
                  "timeout", "g", "n1", "alpha", "beta", "v")   # (the last five: sources.BUILTIN_SIZES)


def compare(rom: "SecondOrderROM | str | os.PathLike", source: str | os.PathLike,
            signal: "Signal | str | None" = None, dt: float | None = None, t_end: float | None = None, *,
            quiet: bool = False, source_options: dict[str, Any] | None = None) -> Comparison:
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
        source each; together, the input that moves the outputs most hid another's 11 % error).  Both sides start
        from the source's initial state: the ROM from the source's positions and velocities after initialization,
        projected on its basis (its stored ``q0, qdot0`` for a builtin or ROM source, or where the state cannot be
        read).
    dt, t_end : float, optional
        Grid; defaults: the ROM's training step and four times the training end time, cut before the time at which
        the training's recording found the source FMU terminating the simulation (said in a line unless ``quiet``).
    source_options : dict, optional
        Variable patterns, ``--set`` values (``parameters``), ``start_time`` or builtin size options for the
        source: the keys of :data:`SOURCE_OPTIONS` (another key is refused in one line).  For an FMU source, what
        is not given is taken from the ROM's training provenance: the force inputs and outputs by their recorded
        names, the recorded ``--set`` values and the FMU time the training runs started at (``start_time``, 0 where
        none is recorded), so a comparison drives the FMU the way the training did.  A ROM side with extra outputs
        (an FMU exported with ``--reconstruct``) is compared on the source's outputs, matched by name.

    Returns
    -------
    Comparison
    """
    from ._validate import check_keywords
    from .newmark import MAX_GRID_STEPS, time_grid
    from .sources import StepError

    check_keywords(source_options or {}, SOURCE_OPTIONS, "compare's source_options")
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
            raise DimensionError("no --t-end given and the ROM does not record a usable training end time "
                                 f"({t_train}); pass --t-end")
        t_end = dt * round(4 * float(t_train) / dt)
        capped = _before_termination(rom_info, source, dt, float(t_end))
        if capped is not None:
            t_end, end_from = capped[0], "before the termination the training recorded"
            if not quiet:
                print(capped[1], file=sys.stderr)
    t = time_grid(dt, float(t_end))
    if str(source).startswith("builtin:") and (source_options or {}).get("start_time") is not None:
        raise InputSpecError(f"--start-time applies to fmu sources, not to {source}")
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
            print(f"no --input given: comparing on {signal} ({why})", file=sys.stderr)
    alone = _each_input_alone(signal, rom_info) if why else []
    if alone and not quiet:
        print(f"then each of {', '.join(name for name, _ in alone)} alone ({len(alone)} more runs of the source: "
              "together, the input that moves the outputs most hides the others' errors)", file=sys.stderr)
    run = _Run(rom_side, rom_info, source, source_options, t, quiet)
    try:
        result = run.compared(signal, why)
        result.each_input_alone = [run.compared(spec, "", name) for name, spec in alone]
        if why and moves_on_its_own(rom_side, rom_info):
            result.free_response = _free_response(run, quiet)
    except StepError as stopped:
        raise _past_termination(stopped, float(t_end), end_given, end_from) from None
    result.inputs = [os.fspath(item) for item in (rom, source, signal) if isinstance(item, (str, os.PathLike))]
    return result


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
    """One line on the free response's comparison: eq. (19) and the largest miss over an output's range there."""
    per_output = free.metrics()["per_output"]
    misses = {name: figures["relative_max_variation"] for name, figures in per_output.items()
              if figures["relative_max_variation"] == figures["relative_max_variation"]}
    worst = max(misses, key=misses.get) if misses else None
    share = f"; largest miss {misses[worst]:.2g} of {worst}'s range there" if worst is not None else ""
    return (f"the ROM's training shows the source moving on its own from its start values: its free response (input "
            f"none) was compared as well: max eps_y {float(free.eps.max()):.3g}{share}")


def _each_input_alone(spec: str, rom_info: dict[str, Any]) -> list[tuple[str, str]]:
    """The chosen test input ``spec`` with each driven input swinging alone (:func:`fmu_opinf._test_input.
    each_input_alone`); empty where fewer than two inputs swing."""
    from ._test_input import each_input_alone

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
        from .rom import held_input_names
        from .signals import parse_signal
        from .snapshots._record import check_table_times

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
            input_choice=f"chosen without --input: {why}" if why else "",
            order=_carried_order(rom_info["provenance"]) if isinstance(rom_side, Path) else _order_chosen(rom_side),
            driven_alone=alone, beyond_training=beyond,
            linear_fits=_carried_linear_fits(rom_info) if isinstance(rom_side, Path) else _linear_fits(rom_side),
            training_miss=_training_miss(rom_side, rom_info))


#: How many times the training's amplitude on an input a given test input must depart from the training's operating
#: point before compare says so: a ROM fitted on a 100 N pulse was 35-90 % of range off at 1e4 N, and the order
#: advice alone (fit --r 8) still 2-4 % off, where training at 1e4 N gave 0.1 % (audit 74, F1).
INPUT_SIZE_NOTE = 10.0


def input_beyond_training(signal: Any, t: np.ndarray, rom_info: dict[str, Any]) -> dict[str, Any]:
    """The input on which the test input ``signal`` (sampled on ``t``) departs furthest, relative to the training's
    amplitude on it, from the training's operating point there (``training_runs`` of the ROM's provenance: the
    largest amplitude an input was driven with and that run's offset), where that is over :data:`INPUT_SIZE_NOTE`
    times: ``{"input", "ratio", "given", "trained"}``; empty where it is within, or the training is not readable.

    A linear ROM's error grows with the input where its basis misses modes the small training input hardly
    excited against the model's own motion; the cure is training at the loads meant, not a larger order."""
    from ._test_input import _training_drives

    m, names = int(rom_info["m"]), list(rom_info.get("input_names") or [])
    try:
        drives = _training_drives(rom_info["provenance"].get("training_runs"), m, names or None)
        u = np.atleast_2d(signal.sample(t))
    except (FmuOpinfError, AttributeError, TypeError, ValueError):
        return {}
    worst: dict[str, Any] = {}
    for i, drive in enumerate(drives):
        if drive is None or not drive[0] > 0 or i >= u.shape[0]:
            continue
        given = float(np.abs(u[i] - drive[1]).max())
        ratio = given / drive[0]
        if ratio > INPUT_SIZE_NOTE and ratio > worst.get("ratio", 0.0):
            name = names[i] if i < len(names) else f"input {i + 1}"
            worst = {"input": name, "ratio": ratio, "given": given, "trained": float(drive[0])}
    return worst


def _warn_beyond_training(beyond: dict[str, Any], source: Any) -> None:
    """The one line of :func:`input_beyond_training`'s finding."""
    import warnings

    from .errors import FmuOpinfWarning

    warnings.warn(f"the test input departs by {beyond['given']:.3g} on {beyond['input']}, {beyond['ratio']:.3g} "
                  f"times the training's amplitude there ({beyond['trained']:.3g}): the ROM of "
                  f"{Path(str(source)).name} learned only the responses to inputs that size; train with an input "
                  "nearer this one (snapshots --input at these loads) before trusting or enlarging it",
                  FmuOpinfWarning, stacklevel=3)


def _table_end(signal: Any, rom_info: dict[str, Any]) -> float | None:
    """The last time of an input table given as ``signal`` (None for any other input or none): the default end of
    a comparison driven by it, since it cannot be sampled beyond."""
    from .rom import held_input_names
    from .signals import parse_signal
    from .snapshots._record import input_table_end

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
    from .sources import StepError, declared_stop_at, terminated_at

    at, stop = terminated_at(str(stopped)), declared_stop_at(str(stopped))
    if end_given or (at is None and stop is None):
        return stopped
    fix = f"compare --t-end below {at:g}" if at is not None else f"compare --t-end at or below {stop:g}"
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
                  f"comparing to t_end={last:g}, before it (not four times the training's end, {t_end:g}; --t-end "
                  "chooses another end)")


def _linear_fits(rom_side: Any) -> list[str]:
    """The outputs a ROM object's fit left out of its judgement as not linear in the states (their names, from
    ``fit_info["nonlinear_outputs"]``); empty for a fit that left none out, an older one or an exported FMU."""
    found = (getattr(rom_side, "fit_info", None) or {}).get("nonlinear_outputs")
    if not isinstance(found, dict) or not found.get("left_out"):
        return []
    return [str(name) for name in found.get("names") or []]


def _carried_linear_fits(rom_info: dict[str, Any]) -> list[str]:
    """:func:`_linear_fits` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_linear_fits``).  A data file: only names of the FMU's own outputs are taken."""
    carried = rom_info["provenance"].get("rom_fmu_linear_fits")
    outputs = set(rom_info.get("output_names") or [])
    if not isinstance(carried, list):
        return []
    return [name for name in carried if isinstance(name, str) and name in outputs][:1000]


def _training_miss_of(rom_side: Any) -> dict[str, Any] | None:
    """What fit warned about a ROM object's miss of its own training outputs (from its ``fit_info``: :func:`fmu_opinf.
    fit._training_checks.training_miss_record`), None where it did not warn or the ROM does not say."""
    from .fit._training_checks import training_miss_record

    info = getattr(rom_side, "fit_info", None)
    settings = (getattr(rom_side, "provenance", None) or {}).get("fit_settings")
    unrefined = isinstance(settings, dict) and settings.get("refine") is False
    return training_miss_record(info, list(getattr(rom_side, "output_names", None) or ()), unrefined)


def _carried_training_miss(provenance: dict[str, Any]) -> dict[str, Any]:
    """:func:`_training_miss_of` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_training_miss``).  A data file: the figures only as finite shares, the names only as short
    printable strings; else nothing."""
    carried = provenance.get("rom_fmu_training_miss")
    if not isinstance(carried, dict):
        return {}
    found: dict[str, Any] = {}
    for key in ("rms", "peak"):
        value = carried.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value < 1e12:
            found[key] = float(value)
    for key in ("output", "run", "peak_output", "peak_run"):
        value = carried.get(key)
        if isinstance(value, str) and len(value) <= 200 and value.isprintable():
            found[key] = value
    return found if "rms" in found or "peak" in found else {}


def _training_miss(rom_side: Any, rom_info: dict[str, Any]) -> dict[str, Any]:
    """The fit's warned training miss of either kind of ROM side (empty where none)."""
    if isinstance(rom_side, Path):
        return _carried_training_miss(rom_info["provenance"])
    return _training_miss_of(rom_side) or {}


def _warn_if_training_missed(rom_side: Any, rom_info: dict[str, Any]) -> None:
    """fit's warning that the ROM misses its own training outputs, again (as export repeats the start miss): a
    comparison on another input must not make such a ROM look validated (audit 79a F1)."""
    import warnings

    from .errors import FmuOpinfWarning
    from .fit._training_checks import training_miss_text

    record = _training_miss(rom_side, rom_info)
    if record:
        warnings.warn(f"fit warned that this ROM misses its own training outputs by {training_miss_text(record)}: "
                      "an input like the training one is that far off, whatever the test below shows; see fit's "
                      "warning for the causes (a larger --r first where its order search kept lowering the miss)"
                      + _replay_hint(record, rom_info), FmuOpinfWarning, stacklevel=3)


def _replay_hint(record: dict[str, Any], rom_info: dict[str, Any]) -> str:
    """How to compare on the training run the miss was found in (its input spec, as fit names the run: "run 0
    (SPEC)", and the training's end), "" where the run's spec or the end is not known.  Not run by default: fit's
    figure is that comparison's already (audit 79a F1: 0.25 of y74's range in both), and the run costs one more
    FMU run over the training window (17.8 s there, against 57.5 s for compare's default test)."""
    import re

    name, end = record.get("peak_run") or record.get("run") or "", rom_info.get("t_train_end")
    found = re.fullmatch(r"run \d+ \(([^()'\\]+)\)", str(name))
    if not found or not isinstance(end, (int, float)) or not math.isfinite(end) or end <= 0:
        return ""
    return f"; compare --input '{found.group(1)}' --t-end {float(end):g} replays that training run"


def _order_chosen(rom_side: Any) -> dict[str, Any]:
    """How a ROM object's order was chosen (for :func:`order_note`): ``r``; ``"given"``, ``"energy"`` where the fit
    took it from the POD energy (eq. 18) and judged it good enough, or ``"search"`` where its order search ran (and
    grew it, or kept the energy's after trying larger ones); the snapshot rank that bounds it; the orders the search
    tried (``fit_info["order_search"]``), and ``noise_floor`` where it stopped at one of the singular values
    (:func:`fmu_opinf.fit._order_search._noise_floor`).  Empty for a ROM that does not say (an exported FMU carries it:
    :func:`_carried_order`)."""
    info = getattr(rom_side, "fit_info", None) or {}
    settings = (getattr(rom_side, "provenance", None) or {}).get("fit_settings")
    rank = info.get("snapshot_rank")
    if not isinstance(settings, dict) or "r" not in settings or not isinstance(rank, (int, np.integer)):
        return {}
    search = info.get("order_search") or []
    how = "given" if settings["r"] is not None else "search" if search else "energy"
    chosen = {"r": int(rom_side.r), "chosen": how, "snapshot_rank": int(rank),
              "tried": [int(entry["r"]) for entry in search if "r" in entry]}
    floor = next((entry["noise_floor"] for entry in search if isinstance(entry.get("noise_floor"), int)), None)
    if floor is not None:
        chosen["noise_floor"] = floor
    return chosen


def _carried_order(provenance: dict[str, Any]) -> dict[str, Any]:
    """:func:`_order_chosen` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_order``, since 2026-12-06; audit 69 F6: compare on a ROM FMU gave no order note).  A data file:
    taken only if every field has the form :func:`_order_chosen` gives it, else nothing."""
    carried = provenance.get("rom_fmu_order")
    if not isinstance(carried, dict) or carried.get("chosen") not in ("given", "energy", "search"):
        return {}

    def count(value: Any) -> bool:
        return isinstance(value, int) and not isinstance(value, bool) and 0 < value < 1_000_000

    tried = carried.get("tried")
    if not (count(carried.get("r")) and count(carried.get("snapshot_rank")) and isinstance(tried, list)
            and all(count(value) for value in tried) and len(tried) <= 64):
        return {}
    chosen = {"r": carried["r"], "chosen": carried["chosen"], "snapshot_rank": carried["snapshot_rank"],
              "tried": list(tried)}
    if count(carried.get("noise_floor")):
        chosen["noise_floor"] = carried["noise_floor"]
    return chosen


def _default_test_input(rom_side: Any, rom_info: dict[str, Any], dt: float, t_end: float) -> tuple[str, str]:
    """The test input without one given (:mod:`fmu_opinf._test_input`): chosen from the ROM, or the one an exported
    ROM FMU carries for its training grid (a data file: taken only as a string, parsed like any --input)."""
    from ._test_input import carried_for_grid, default_test_input

    if not isinstance(rom_side, Path):
        return default_test_input(rom_side, dt, t_end)
    carried = rom_info["provenance"].get("default_test_input")
    if not (isinstance(carried, list) and len(carried) == 2 and all(isinstance(v, str) for v in carried)):
        raise InputSpecError(f"no test input given, and {rom_side.name} carries none (exported before 2026-12-06); "
                             "pass --input SPEC, e.g. 'harmonic:amplitude=1,omega=0.2'")
    spec, why = ("".join(c for c in text if c.isprintable()) for text in carried)   # (no terminal controls)
    spec = carried_for_grid(spec, rom_side.name, int(rom_info["m"]), dt, t_end)
    return spec, f"{why}; chosen at export for the FMU's own step and four times its training end"


#: How far past its largest departure in the training an output must go under compare's own test input before that
#: is said: a test at the training size adds a hair to a large free swing (a 100 N harmonic on a 96 m gravity swing:
#: ratio 1.0004, printed "1 times", with the ROM at 1.0 warned "may miss a mode" while 0.5 % of range off; audit 74,
#: F1).  5 % past is a departure the training did not show.
PAST_TRAINING_MARGIN = 1.05


def _past_training(y: np.ndarray, y_rom: np.ndarray, names: list[str], rom_info: dict[str, Any],
                   source: Any) -> str:
    """Where the test input ``compare`` chose drove the source's outputs past their training peak: a warning, and
    the same words for the report ("" where they stayed within).  The input was sized by the ROM: where the ROM
    went past as well, the input's offsets did it; where it did not, the ROM misses a mode of the model there
    (audit 52: an r = 1 ROM beside a lightly damped mode it did not learn, 4.3 times).  Only past
    :data:`PAST_TRAINING_MARGIN` times the training's departure."""
    from ._test_input import recorded_peaks

    peaks = recorded_peaks(rom_info["provenance"], y.shape[0])
    if peaks is None:
        return ""
    scale = np.where(peaks > 0, peaks, np.inf)
    ratios = np.abs(y - y[:, :1]).max(axis=1) / scale
    worst = int(np.argmax(ratios))
    if not ratios[worst] > PAST_TRAINING_MARGIN:
        return ""
    rom_ratio = float(np.abs(y_rom[worst] - y_rom[worst, 0]).max() / scale[worst])
    cause = ("the input's offsets take it there in the ROM too: a shorter --t-end keeps them nearer" if rom_ratio > 1.0
             else _growth_cause() if _grew(rom_info)
             else "the ROM stays within it: it may miss a mode of the model there; pass --input with a smaller "
                  "amplitude or another frequency")
    text = (f"{Path(str(source)).name}'s {names[worst]} went to {ratios[worst]:.3g} times its largest departure in the "
            f"training; {cause}")
    import warnings

    from .errors import FmuOpinfWarning

    warnings.warn(f"under the test input compare chose, {text}", FmuOpinfWarning, stacklevel=3)
    return f"; {text}"


def _grew(rom_info: dict[str, Any]) -> bool:
    """Whether ``snapshots`` found the ROM's training source growing without bound (verdict ``unbounded-growth``)."""
    from .snapshots._notes import recorded_verdicts

    return "unbounded-growth" in recorded_verdicts(rom_info["provenance"].get("snapshots"))


def _growth_cause() -> str:
    """Why the source left its training range where its recording grew without bound (audit 79b F4: compare advised
    a smaller test amplitude for a source 4.9e36 times past it, which no amplitude would have kept in range)."""
    return ("the source grows without bound once its inputs are held (snapshots warned: it is unstable at its "
            "operating point), and no stable ROM follows it, whatever the test input")


def _held_at_start_values(signal: "Signal", source: Any, options: dict[str, Any]) -> "Signal":
    """``signal`` with its ``none`` channels held at the FMU source's start (or ``--set``) values, on both sides,
    as ``snapshots`` holds them and as the exported ROM FMU starts them.  Before, they were 0 here: a preload
    F = 10 N was compared at 0 N, away from the operating point of the training, and a parameter exposed as an
    input and driven in the training was set to 0 (audit of 2026-12-06: the stiffness, eps_y 1.45)."""
    from .signals import NoInput, StackedSignal

    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    if (not any(isinstance(part, NoInput) and part.n_inputs for part in parts) or str(source).startswith("builtin:")
            or Path(str(source)).suffix.lower() in (".h5", ".hdf5")):
        return signal
    from .snapshots._record import as_signal
    from .source import open_source

    keep = {k: v for k, v in options.items() if k in ("inputs", "parameters", "interface", "start_time")}
    fom = open_source(source, positions="", **keep)
    try:
        return as_signal(signal.spec, signal.n_inputs, fom) if fom.m == signal.n_inputs else signal
    finally:
        fom.close()


def _source_start(rom: Any, source: Any, signal: Any, t: np.ndarray,
                  options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """The ROM's reduced initial state for the source's own start (its positions and velocities at ``t[0]`` after
    initialization, with the comparison's settings), or None to keep the ROM's stored one: a builtin or ROM
    source, a ROM without basis, a source whose training variables cannot be read, or a start the ROM cannot
    represent (then one warning).

    Without it the ROM started from the first training run's state while the source might start elsewhere
    (another ``--set`` start value, a ``start:`` column of a run table): third audit, 2026-11-26, a right ROM
    reported at max eps_y 9.8e-2 and 3.5e-3 where it reproduces the source to 1e-22.
    """
    if (str(source).startswith("builtin:") or Path(str(source)).suffix.lower() in (".h5", ".hdf5")
            or rom.basis is None):
        return None
    from .snapshots._record import MemorySink, record_run
    from .source import open_source

    keep = {k: v for k, v in options.items()
            if k in ("inputs", "outputs", "parameters", "interface", "tolerance", "start_time")}
    recorded = rom.provenance.get("snapshots") or {}
    for key, field_name in (("positions", "position_names"), ("velocities", "velocity_names")):
        pattern = _exact_names(recorded.get(field_name))  # the variables the training recorded: the basis rows
        if pattern:
            keep[key] = pattern
    try:  # a source whose state cannot be read this way (an exported ROM FMU) starts where the ROM does
        fom = open_source(source, **keep)
        run, failure = record_run(fom, signal, t[:2], MemorySink, True, bool(options.get("isolate", True)),
                                  "initial state of the source", say_events=False)  # isolated like compare's run
        fom.close()
    except FmuOpinfError:
        return None
    if failure is not None:
        return None
    x0, v0 = np.asarray(run.x0), None if fom.derived["xdot"] else np.asarray(run.v0)
    if x0.size != rom.basis.shape[0]:
        return None
    try:
        return rom.initial_state(x0, v0)
    except FmuOpinfError as exc:
        import warnings

        from .errors import FmuOpinfWarning

        warnings.warn(f"the ROM starts from its training start, not the source's: {exc}", FmuOpinfWarning,
                      stacklevel=3)
        return None


def _exact_names(names: Any) -> str | None:
    """Recorded variable names as one pattern (exact names are patterns without wildcards), None if there are none
    or one could be read as a wildcard or does not come back whole from the patterns' own splitting (commas inside
    brackets, ``sensor[1,1]``, do)."""
    from .sources._base import split_patterns

    if not (isinstance(names, list) and names and all(isinstance(n, str) and not set(n) & set("*?") for n in names)):
        return None
    joined = ",".join(names)
    return joined if split_patterns(joined) == names else None


#: Recording verdicts about the model itself, not about how the FMU integrated it: a comparison with the same FMU
#: does not share them (its own events; a response that grows without bound, audit 79b F4; a response that does not
#: scale with the training's amplitude, audit 79b F1).
MODEL_VERDICTS = frozenset({"internal-events", "unbounded-growth", "nonlinear"})


def _warn_if_recording_warned(rom_info: dict[str, Any], interface: str | None) -> None:
    """The warning ``snapshots`` gave on the ROM's training recording, again (audit 70 F4: a recording that
    followed the FMU's integrator, compared against the same FMU at the same step: 7.6e-7 and no word, the ROM
    28-72 % of range off the model).  Where the fit made the ROM stand for the model, the FMU's own integration
    error is part of the difference only when this comparison drives the FMU by co-simulation (``interface``
    ``"cs"``; audit 72 F3: said of an FMU driven by model exchange, where the error was the ROM's)."""
    import warnings

    from .errors import FmuOpinfWarning
    from .snapshots._notes import recorded_verdicts, recorded_warning

    message = recorded_warning(rom_info["provenance"].get("snapshots"))
    if not message:
        return
    settings = rom_info["provenance"].get("fit_settings")
    modelled = isinstance(settings, dict) and (settings.get("recording_integrator") in (
        "forward-euler", "backward-euler", "euler-substeps", "step-dependent")
        or settings.get("mixed_recordings") is True)
    if modelled and interface == "cs":
        message += ("; the ROM stands for the model (fitted through the FMU's Euler steps or from its derivatives), "
                    "so the difference to this FMU's co-simulation includes the FMU's own integration error")
    elif modelled:
        message += ("; the ROM stands for the model (fitted through the FMU's Euler steps or from its derivatives), "
                    "and this comparison ran no co-simulation: the difference is the ROM's")
    elif not (verdicts := recorded_verdicts(rom_info["provenance"].get("snapshots"))) or verdicts - MODEL_VERDICTS:
        message += "; a comparison with the same FMU shares what the recording followed"
    warnings.warn(message, FmuOpinfWarning, stacklevel=4)


def _warn_if_merged(rom_info: dict[str, Any]) -> None:
    """The warning ``fit`` gave where the ROM's merged snapshot files differ (FMU, interface, settings), again, from
    the ROM's provenance: a ROM of several models compared against one of them measures that blend (audit 72 F3,
    F4: ``fit`` warned, ``compare`` said nothing)."""
    import warnings

    from .errors import FmuOpinfWarning
    from .snapshots._merge import repeated_merge_warning

    message = repeated_merge_warning(rom_info["provenance"].get("snapshots"))
    if message:
        warnings.warn(message, FmuOpinfWarning, stacklevel=4)


def _compared_interface(source: Any, options: dict[str, Any]) -> str | None:
    """The FMI interface this comparison drives ``source`` by (``"me"``, ``"cs"``), None for a builtin source or a
    ROM file (no FMU integrator) or where the FMU's description cannot be read (the run then says why)."""
    text = str(source)
    if text.startswith("builtin:") or Path(text).suffix.lower() in (".h5", ".hdf5"):
        return None
    from .errors import FmuOpinfError
    from .sources import choose_interface

    try:
        return choose_interface(text, options.get("interface") or "auto")
    except (FmuOpinfError, OSError, ValueError):
        return None


def _warn_if_another_fmu(rom_info: dict[str, Any], source: Any) -> None:
    """One warning when the source FMU is not the one the ROM was learned from (its GUID differs from the one the
    training recorded): with the same variable names the comparison runs and measures another model (third
    audit, 2026-11-26: max eps_y 0.99 and no word)."""
    snapshots = rom_info["provenance"].get("snapshots")
    trained = _trained_guids(snapshots)
    path = Path(str(source))
    if not trained or str(source).startswith("builtin:") or path.suffix.lower() in (".h5", ".hdf5"):
        return
    try:
        from .sources._variables import read_description

        md = read_description(path)
    except Exception:  # noqa: BLE001 - the run itself reports an unreadable FMU
        return
    # a ROM exported from that FMU's training names its GUID in the description
    exported = any(f"(GUID {guid})" in (md.description or "") for guid in trained)
    if md.guid and md.guid not in trained and not exported:
        import warnings

        from .errors import FmuOpinfWarning

        learned = ", ".join(f"{name}, GUID {guid}" for guid, name in trained.items())
        warnings.warn(f"{path.name} is not the FMU the ROM was learned from ({learned}; this one has {md.guid}): the "
                      "comparison measures another model", FmuOpinfWarning, stacklevel=3)


def _trained_guids(snapshots: Any) -> dict[str, str]:
    """The GUIDs of the FMUs the training recorded, each with its FMU's name: the recording's, or each merged part's
    (a set merged from different FMUs names no GUID of its own; audit 72 F3)."""
    if not isinstance(snapshots, dict):
        return {}
    from .snapshots._merge import merged_parts

    parts = [snapshots] if snapshots.get("fmu_guid") else merged_parts(snapshots, "")
    return {str(part["fmu_guid"]): str(part.get("fmu_name") or "FMU") for part in parts if part.get("fmu_guid")}


def _training_settings(rom_info: dict[str, Any], source: Any, given: dict[str, Any] | None) -> dict[str, Any]:
    """Source options for an FMU source: the user's, completed from the ROM's training provenance.  A value given
    for an initial state (:func:`fmu_opinf._model_start.sets_initial_state`) is no model change: not warned about
    (audit 73 F2: ``compare --runs`` with a table's ``start:`` rows said a ROM describes the model it was trained on).
    """
    from ._model_start import sets_initial_state

    options = dict(given or {})
    snapshots = rom_info["provenance"].get("snapshots")
    if str(source).startswith("builtin:") or not isinstance(snapshots, dict) or snapshots.get("source_kind") != "fmu":
        return options
    for key, names in (("inputs", snapshots.get("input_names")), ("outputs", snapshots.get("output_names"))):
        pattern = _exact_names(names)
        if key not in options and pattern:
            options[key] = pattern
    if options.get("start_time") is None and not _is_rom_fmu(source):   # the FMU time the training started at
        options["start_time"] = float(snapshots.get("start_time") or 0.0)
    settings = snapshots.get("fmu_settings")
    settings = dict(settings) if isinstance(settings, dict) else {}
    given_settings = options.get("parameters")
    if not isinstance(given_settings, dict):
        if settings:
            options.setdefault("parameters", dict(settings))
        return options
    # what the training ran with: its --set values, else the FMU's start values (tenth audit: --set gear=2 against
    # a ROM recorded at the start value gear=1 was 0.44 off without a word)
    starts = _declared_starts(source) if any(name not in settings for name in given_settings) else {}
    trained = {name: (settings[name], "") if name in settings else (starts[name], " (its start value)")
               for name in given_settings if name in settings or name in starts}
    ports = set(snapshots.get("input_names") or [])   # (a ROM input's value is the test input's, not a setting)
    changed = {name: value for name, value in given_settings.items()
               if name in trained and name not in ports and not _same_setting(value, trained[name][0])
               and not sets_initial_state(name, snapshots)}
    if changed:
        import warnings

        from .errors import FmuOpinfWarning

        warnings.warn("compared with " + ", ".join(f"{name}={value}" for name, value in changed.items())
                      + ", but the ROM was trained with "
                      + ", ".join(f"{name}={trained[name][0]}{trained[name][1]}" for name in changed)
                      + ": a ROM describes the model it was trained on", FmuOpinfWarning, stacklevel=3)
    options["parameters"] = {**settings, **given_settings}  # the training's other settings stay as trained
    return options


def _declared_starts(source: Any) -> dict[str, str]:
    """The start values that the FMU ``source`` declares, by variable name ({} where it cannot be read)."""
    from .sources._variables import read_description

    try:
        md = read_description(Path(str(source)))
    except FmuOpinfError:
        return {}
    return {v.name: v.start for v in md.modelVariables if v.start is not None}


def _same_setting(value: Any, trained: Any) -> bool:
    """Whether a --set value equals the training's, as numbers where both are numbers."""
    try:
        return float(value) == float(trained)
    except (TypeError, ValueError):
        return str(value).strip().lower() == str(trained).strip().lower()


def _trained_input_names(rom_info: dict[str, Any]) -> list[str] | None:
    """The names of the FMU inputs the ROM was trained on, in the ROM's input order, as the snapshots recorded
    them (None where none were recorded: a ROM built in Python with placeholder names ``u[1]``, ...)."""
    snapshots = rom_info["provenance"].get("snapshots")
    names = snapshots.get("input_names") if isinstance(snapshots, dict) else None
    if isinstance(names, list) and len(names) == rom_info["m"] > 0 and all(isinstance(n, str) for n in names):
        side = list(rom_info.get("input_names") or [])   # an exported FMU's: in the source's order (audit 69 F4)
        return side if sorted(side) == sorted(names) else list(names)
    return None


def _fmu_path(source: Any) -> bool:
    """Whether ``source`` names an FMU, packed or unpacked (not a builtin model, not a ROM file)."""
    return not str(source).startswith("builtin:") and Path(str(source)).suffix.lower() not in (".h5", ".hdf5")


def _is_rom_fmu(source: Any) -> bool:
    """Whether ``source`` is an FMU that 'fmu-opinf export' wrote (time-invariant, run from its own start)."""
    path = Path(str(source))
    return path.suffix.lower() == ".fmu" and path.is_file() and _bundled_provenance(path) is not None


def _bundled_provenance(path: Path) -> Any:
    """The provenance.json that 'fmu-opinf export' bundles in a ROM FMU (parsed), or None where there is none."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.endswith("provenance.json")]
            return json.loads(archive.read(names[0])) if names else None
    except (OSError, zipfile.BadZipFile, ValueError, RecursionError):   # (a file nested past Python's limit)
        return None


def _declared_model(source: Any) -> Any:
    """The source FMU's :class:`~fmu_opinf.sources._variables.ModelInfo`, None for another source or an unreadable
    description (units are decoration: without them the figures are drawn in plain numbers)."""
    path = Path(str(source))
    if str(source).startswith("builtin:") or path.suffix.lower() != ".fmu" or not path.is_file():
        return None
    try:
        from .sources._variables import ModelInfo

        return ModelInfo.from_path(path)
    except Exception:  # noqa: BLE001 - units are decoration: an unreadable description just has none
        return None


def _declared_variable(variables: dict[str, Any], name: str) -> Any:
    """The variable a recorded output name designates: itself, or the FMI 3 array ``y`` of an element ``y[2]``."""
    var = variables.get(name)
    if var is None and name.endswith("]") and "[" in name:  # an element of an array variable
        array = variables.get(name[:name.rindex("[")])
        var = array if array is not None and array.dims else None
    return var


def _printable(text: Any) -> str:
    return "".join(c for c in str(text or "") if c.isprintable())


def _declared_units(source: Any, names: list[str]) -> list[str] | None:
    """Units the source FMU declares for the named variables (its own or its type's), "" where none.

    Names are element names as recorded: an element ``y[2]`` of an FMI 3 array ``y`` has the array's unit.
    """
    model = _declared_model(source)
    if model is None:
        return None
    return [_printable(getattr(_declared_variable(model.by_name, name), "unit", None)) for name in names]


def _declared_display_units(source: Any, names: list[str]) -> list[DisplayUnit | None] | None:
    """The ``displayUnit`` the source FMU declares for each named variable (its own or its type's) where its unit's
    ``DisplayUnit`` definition gives the conversion, None where not (FMI: a display unit not defined is ignored).

    A ``relativeQuantity`` variable (a temperature difference) ignores the offset, as FMI says.
    """
    model = _declared_model(source)
    if model is None:
        return None

    def display(name: str) -> DisplayUnit | None:
        var = _declared_variable(model.by_name, name)
        defined = model.display_units.get(getattr(var, "unit", None) or "", {})
        chosen = getattr(var, "display_unit", None) or ""
        if chosen not in defined or not _printable(chosen):
            return None
        factor, offset = defined[chosen]
        return DisplayUnit(_printable(chosen), factor, 0.0 if var.relative_quantity else offset)

    found = [display(name) for name in names]
    return found if any(found) else None


def _matching_outputs(fom_names: list[str], rom_names: list[str], by_name: bool) -> list[int]:
    """Rows of the ROM side's outputs that correspond to the source's: by position, or (an exported FMU with
    extra reconstructed outputs) by name."""
    if len(fom_names) == len(rom_names):
        return list(range(len(rom_names)))
    if by_name and set(fom_names) <= set(rom_names):
        return [rom_names.index(name) for name in fom_names]
    raise DimensionError(f"the source has {len(fom_names)} outputs but the ROM has {len(rom_names)}, and their "
                         "names do not match; compare a ROM with the model it was learned from")


def _timed_description(side: Any, isolate: bool = True, provenance: dict | None = None) -> str:
    """What :func:`simulate_outputs` times for a model (the loop only: no loading, compilation or set-up);
    ``provenance`` of the run, if known, says how an FMU was driven."""
    from .rom import SecondOrderROM

    if isinstance(side, SecondOrderROM) or Path(str(side)).suffix.lower() in (".h5", ".hdf5"):
        return ("ROM simulated in Python, in this process (SecondOrderROM.simulate, outputs only: the step map "
                "applied in blocks of steps as matrix products, the reduced states not formed; input sampling "
                "and step-map set-up included)")
    if str(side).startswith("builtin:"):
        return f"{side} simulated in Python (the reference Newmark stepper, one sparse solve per step)"
    where = "in a separate process, its stepping loop alone" if isolate else "in this process"
    provenance = provenance or {}
    if provenance.get("fmi_interface") == "me":
        return (f"FMU {Path(str(side)).name} integrated by model exchange from Python {where} (per step: input "
                f"set, {provenance.get('integrator', 'the ODE integrated')}, outputs read)")
    from ._stepping import stepping_of

    tool = provenance.get("fmu_generation_tool", "fmu-opinf")
    again = ", input set again" if stepping_of(tool, provenance.get("fmu_stepping")) == "continuous" else ""
    return (f"FMU {Path(str(side)).name} stepped through FMI from Python {where} (per step: input set when "
            f"changed, one step{again}, outputs read)")


def _timed(source: Any, rom_side: Any, isolate: bool = True, fom_provenance: dict | None = None) -> dict[str, Any]:
    """What each side's time measured; like with like when both are FMUs stepped by co-simulation (a full model
    integrated by model exchange against the ROM FMU's co-simulation steps is not: eleventh audit, F9)."""
    fmu = [not str(side).startswith("builtin:") and Path(str(side)).suffix.lower() == ".fmu"
           for side in (source, rom_side)]
    model_exchange = (fom_provenance or {}).get("fmi_interface") == "me"
    return {"fom": _timed_description(source, isolate, fom_provenance), "rom": _timed_description(rom_side, isolate),
            "like_with_like": all(fmu) and not model_exchange, "clock": "wall time (time.perf_counter)"}


def _rom_side_info(rom_side: Any) -> dict[str, Any]:
    """Sizes, step, training end and provenance of a ROM object or exported ROM FMU."""
    if isinstance(rom_side, Path):
        from .source import FMUSource

        meta = _rom_fmu_metadata(rom_side)
        driven = meta.get("rom_fmu_driven_inputs")   # an FMU that keeps its training's held inputs: not driven
        pattern = "none" if driven == [] else _exact_names(driven)
        chosen = {"inputs": pattern} if pattern else {}
        fmu = FMUSource(rom_side, **_rom_fmu_variables(meta.get("rom_fmu_states")), **chosen)
        return {"m": fmu.m, "p": fmu.p, "r": fmu.n, "dt": meta.get("dt"), "output_names": list(fmu.output_names),
                "fmu_options": chosen,
                "input_names": list(fmu.input_names),
                "t_train_end": meta.get("t_train_end"), "provenance": {**fmu.provenance(), **meta}}
    prov = dict(getattr(rom_side, "provenance", {}) or {})
    return {"m": rom_side.m, "p": rom_side.p, "r": rom_side.r, "dt": rom_side.dt,
            "output_names": list(rom_side.output_names), "input_names": list(rom_side.input_names),
            "t_train_end": _training_end(prov), "provenance": prov}


#: Variable patterns of an exported ROM FMU (its reduced coordinates stand where positions would), for FMUs
#: exported before the names were recorded in their provenance.json (``rom_fmu_states``).
ROM_FMU_VARIABLES = {"positions": "q[*]", "velocities": "qdot[*]", "accelerations": "qddot[*]"}


def _rom_fmu_variables(states: Any) -> dict[str, str]:
    """The patterns of an exported ROM FMU's states from the base names its provenance.json records, if any."""
    if isinstance(states, list) and len(states) == 3 and all(isinstance(s, str) and s for s in states):
        return {kind: f"{base}[*]" for kind, base in zip(ROM_FMU_VARIABLES, states)}
    return dict(ROM_FMU_VARIABLES)


def _training_end(provenance: dict[str, Any]) -> float | None:
    """Last training time recorded in a ROM's provenance, if any."""
    for key in ("t_train_end", "t_end"):
        if provenance.get(key) is not None:
            try:
                return float(provenance[key])
            except (TypeError, ValueError):   # (a damaged file's)
                return None
    snaps = provenance.get("snapshots")
    if isinstance(snaps, dict):
        return _training_end(snaps)
    return None


def _rom_fmu_metadata(path: Path) -> dict[str, Any]:
    """Step and training end of an exported ROM FMU (default experiment, bundled provenance.json); refuses an FMU
    that 'fmu-opinf export' did not write (a full model given where the ROM belongs)."""
    from .sources._variables import read_description

    md = read_description(path)
    if md.generationTool != "fmu-opinf":
        raise FileFormatError(f"{path} is not a ROM FMU exported by fmu-opinf (generationTool "
                              f"{md.generationTool!r}); give the ROM (.h5 from 'fmu-opinf fit' or .fmu from "
                              "'fmu-opinf export') first and the full model second")
    meta: dict[str, Any] = {"rom_fmu": str(path), "rom_fmu_guid": md.guid}
    if md.defaultExperiment is not None and md.defaultExperiment.stepSize:
        meta["dt"] = float(md.defaultExperiment.stepSize)
    provenance = _bundled_provenance(path)
    if isinstance(provenance, dict):
        meta["t_train_end"] = _training_end(provenance)
        meta["rom_fmu_states"] = provenance.get("rom_fmu_states")
        meta["rom_fmu_driven_inputs"] = provenance.get("rom_fmu_driven_inputs")
        if isinstance(provenance.get("snapshots"), dict):
            meta["snapshots"] = provenance["snapshots"]  # the training's variable selection
        meta["default_test_input"] = provenance.get("default_test_input")
        meta["training_runs"] = provenance.get("training_runs")   # (their output peaks: the check after the run)
        if isinstance(provenance.get("fit_settings"), dict):   # (how the fit read a warned recording: audit 71 F7)
            meta["fit_settings"] = provenance["fit_settings"]
        # what the fit found, for the notes and rows of a compare on the FMU (each judged where it is read)
        for key in ("rom_fmu_order", "rom_fmu_linear_fits", "rom_fmu_moves_on_its_own",
                    "rom_fmu_training_miss"):
            meta[key] = provenance.get(key)
    return meta


_REPORT_NAMES = ("write_report", "prepare_report_directory", "summary_table", "plotted_outputs", "MAX_OUTPUT_PANELS")


def __getattr__(name: str) -> Any:
    """The report's names (:mod:`fmu_opinf.report`, where they moved) as they were reached before:
    ``compare.write_report``."""
    if name in _REPORT_NAMES:
        from . import report

        return getattr(report, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
