"""Recording snapshots from a source into self-describing HDF5 files (layout: docs/file-format.md).

Modules, one job each:

:mod:`._data`
    :class:`Run` and :class:`Snapshots`, the data model.
:mod:`._file`
    The HDF5 layout (attributes, chunked datasets, atomic writes).
:mod:`._record`
    :func:`record` / :func:`record_to_file`: drive a source into memory or a file.
:mod:`._isolation`
    Run the source in this process or in a child process (a crashing FMU binary becomes an error);
    :func:`use_fork_server` lets the child processes of this process start from a fork server.
:mod:`._rates`
    Time grid, inputs in effect, rates derived from recorded samples.
:mod:`._window`
    The automatic snapshot window (:func:`auto_window`).
"""

from __future__ import annotations

from ._data import Run, Snapshots
from ._file import ARRAYS, FILE_KIND, LAYOUT_VERSION
from ._inputs import DEFAULT_TRAINING_INPUT
from ._isolation import use_fork_server
from ._rates import (inputs_in_effect, newmark_accelerations, newmark_rates, newmark_velocities_and_accelerations,
                     time_grid)
from ._record import RecordSummary, record, record_to_file
from ._run import STREAM_THRESHOLD
from ._window import Window, auto_window, fade_time, input_activity, significant_frequency, slowest_frequency

__all__ = [
    "LAYOUT_VERSION",
    "Run",
    "Snapshots",
    "Window",
    "RecordSummary",
    "record",
    "record_to_file",
    "use_fork_server",
    "auto_window",
    "time_grid",
    "inputs_in_effect",
    "newmark_rates",
    "newmark_accelerations",
    "newmark_velocities_and_accelerations",
    "significant_frequency",
    "slowest_frequency",
    "input_activity",
    "DEFAULT_TRAINING_INPUT",
    "fade_time",
    "STREAM_THRESHOLD",
    "FILE_KIND",
    "ARRAYS",
]
