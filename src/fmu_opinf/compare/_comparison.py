"""The result of a comparison: :class:`Comparison` (both sides' outputs, timings, provenance), its metrics.json."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._hdf5 import jsonable
from ._declared import DisplayUnit
from ._metrics import error_metrics, output_error


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
        Where a given test input departs from the training's operating point by over
        :data:`~fmu_opinf.compare._training.INPUT_SIZE_NOTE` times the training's amplitude on some input: that
        ``input``, the ``ratio``, the ``given`` departure and the ``trained`` amplitude
        (:func:`~fmu_opinf.compare._training.input_beyond_training`); empty otherwise.
    each_input_alone : list of Comparison
        Where ``compare`` chose a test input driving two inputs or more: the same harmonics, one input swinging at a
        time (:func:`fmu_opinf._test_input.each_input_alone`), so that an input whose response the others' hide is
        judged on its own; likewise where the given test input is one spec driving up to
        :data:`~fmu_opinf.compare._alone.ALONE_AT_MOST` inputs alike
        (:func:`~fmu_opinf.compare._alone.given_each_input_alone`).
    alone_note : str
        The line saying that the run of all inputs together hides an input's error (its miss alone over
        :data:`~fmu_opinf.compare._alone.HIDDEN_FACTOR` times the joint one's), or why a given input driving more
        inputs alike was not run per input; "" otherwise.  ``metrics.json``: ``each_input_alone_note``.
    training_band : Comparison or None
        Where ``compare`` chose the test input of a reduced ROM and the training excited the outputs well above it:
        a second default test near the top of that band (:func:`fmu_opinf._test_input.band_test_input`), where a
        truncated order misses most (``driven_alone``: ``"top of the training band"``).
    linear_fits : list of str
        The outputs the fit found not linear in the recorded states and left out of what steers the ROM's dynamics
        (``fit_info["nonlinear_outputs"]``): the ROM gives them by a linear least-squares fit
        (:func:`~fmu_opinf.compare._metrics.linear_fit_note`).
    timed : dict
        What each time measured (``fom``, ``rom``: one sentence each; a ROM file or object: its outputs alone,
        the reduced states are not formed), whether the speed-up compares like with like (``like_with_like``:
        both sides FMUs, stepped the same way in the same kind of process) and the ``clock``.
    training_peaks : list of float or None
        Each output's largest departure from its start over the ROM's training runs, as fit recorded it
        (``provenance["training_runs"][*]["output_peak"]``), None where not recorded: an output that rests in this
        run is judged against it (:func:`~fmu_opinf.compare._metrics.error_metrics`).
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
    input_choice: str = ""   # why, where compare chose the test input itself (no --input or signal=)
    order: dict[str, Any] = field(default_factory=dict)   # how the ROM's order was chosen (order_note)
    driven_alone: str = ""   # the input this comparison drove alone, "" for all (compare's runs of each_input_alone)
    each_input_alone: list["Comparison"] = field(default_factory=list)
    alone_note: str = ""   # where the joint run hides an input's error, or why none was run alone (compare._alone)
    free_response: "Comparison | None" = None   # inputs at their start values, where the FMU moves on its own
    training_band: "Comparison | None" = None   # a second default test at the top of the band the training excited
    beyond_training: dict[str, Any] = field(default_factory=dict)   # a given input far above the training's
    linear_fits: list[str] = field(default_factory=list)   # outputs the fit found not linear in the states
    training_miss: dict[str, Any] = field(default_factory=dict)   # fit's warned miss of its training outputs
    training_peaks: list[float] | None = None   # each output's training motion: the scale of one at rest here
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
        out = error_metrics(self.y_fom, self.y_rom, self.output_names, self.training_peaks)
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
            "each_input_alone_note": self.alone_note or None,
            "free_response": self.free_response.run_metrics() if self.free_response is not None else None,
            "training_band": self.training_band.run_metrics() if self.training_band is not None else None,
            "input_beyond_training": dict(self.beyond_training) or None,
            "linear_fits": list(self.linear_fits) or None,
            "training_miss": dict(self.training_miss) or None,
        })
        return out

    def run_metrics(self) -> dict[str, Any]:
        """:meth:`metrics` without what a comparison of several runs says once for all (provenance, what the times
        measured): those of a run of one input alone."""
        return {key: value for key, value in self.metrics().items()
                if key not in ("fom", "rom", "speedup_timed", "t_train_end", "each_input_alone",
                               "each_input_alone_note", "free_response", "training_band", "training_miss")}
