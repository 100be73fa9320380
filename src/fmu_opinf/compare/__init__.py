"""Validation of a ROM against the model it replaces: the paper's error measure.

``compare`` runs the full-order source (FMU or builtin simulator) and the ROM (a ``rom.h5`` or an
exported ROM FMU) on the same input and time grid, computes eq. (19) and relative L2 / max
errors per output, times both, and says where the test left what the ROM was trained on.
:func:`fmu_opinf.report.write_report` writes what it measured (``metrics.json``, the paper's figures, one
self-contained ``index.html``); its names are also reached here as before (``compare.write_report``).

Modules, one job each:

:mod:`._metrics`
    The error measure: :func:`output_error` (eq. 19), :func:`error_metrics`, and the notes on what it hides
    (:func:`comparison_notes`: :func:`offset_note`, :func:`scale_note`, :func:`linear_fit_note`, :func:`order_note`,
    :func:`training_miss_note`).
:mod:`._comparison`
    :class:`Comparison`, the result, and its ``metrics.json``.
:mod:`._run`
    :func:`compare`: the grid and its end, both sides on one input, the default test input, each input alone, the
    free response (:func:`moves_on_its_own`).
:mod:`._alone`
    Each input alone on a given test input that drives several alike, and the line where the joint run hides one.
:mod:`._simulate`
    :func:`simulate_outputs`: one model's outputs on a grid (ROM, builtin system, FMU in or out of process).
:mod:`._sides`
    The ROM side (object, file or exported FMU), the source's start state and held inputs, the outputs matched.
:mod:`._training`
    The training provenance: the source driven as trained, what the fit found (order, linear fits, training miss),
    and the warnings where a comparison leaves what the ROM was trained on (:func:`input_beyond_training`).
:mod:`._declared`
    What the files declare: units, display units (:class:`DisplayUnit`) and start values of the source FMU, an
    exported ROM FMU's description and provenance.json.
:mod:`._timing`
    What each side's time measured.

The public names of those modules are re-exported here; other modules of the package import the private helpers
they share from the module that defines them.  Each module reads its own names, so a test that patches one
patches it in the module that uses it (``fmu_opinf.compare._run._rom_side_info`` for :func:`compare`): a patch of
``fmu_opinf.compare.NAME`` changes a copy that the functions do not read.
"""

from __future__ import annotations

from typing import Any

from ._comparison import Comparison as Comparison
from ._declared import DisplayUnit as DisplayUnit
from ._metrics import (MAX_NAMED as MAX_NAMED, OFFSET_HIDES as OFFSET_HIDES, ORDER_NOTE as ORDER_NOTE,
                       SCALE_NOTE_FLOOR as SCALE_NOTE_FLOOR, comparison_notes as comparison_notes,
                       error_metrics as error_metrics, linear_fit_note as linear_fit_note, offset_note as offset_note,
                       order_note as order_note, output_error as output_error, scale_note as scale_note,
                       training_miss_note as training_miss_note)
from ._run import (FREE_RESPONSE as FREE_RESPONSE, SOURCE_OPTIONS as SOURCE_OPTIONS, compare as compare,
                   free_response_line as free_response_line, moves_on_its_own as moves_on_its_own)
from ._sides import ROM_FMU_VARIABLES as ROM_FMU_VARIABLES
from ._simulate import simulate_outputs as simulate_outputs
from ._training import (INPUT_SIZE_NOTE as INPUT_SIZE_NOTE, MODEL_VERDICTS as MODEL_VERDICTS,
                        PAST_TRAINING_MARGIN as PAST_TRAINING_MARGIN, input_beyond_training as input_beyond_training)

__all__ = ["output_error", "error_metrics", "offset_note", "scale_note", "linear_fit_note", "Comparison", "compare",
           "simulate_outputs", "DisplayUnit"]


_REPORT_NAMES = ("write_report", "prepare_report_directory", "summary_table", "plotted_outputs", "MAX_OUTPUT_PANELS")


def __getattr__(name: str) -> Any:
    """The report's names (:mod:`fmu_opinf.report`, where they moved) as they were reached before:
    ``compare.write_report``."""
    if name in _REPORT_NAMES:
        from .. import report

        return getattr(report, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
