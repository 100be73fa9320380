"""Recording snapshots from a source into self-describing HDF5 files (layout: docs/file-format.md).

The stage in one read: :mod:`._record` (:func:`record`, :func:`record_to_file`) plans a recording in :mod:`._plan`
(the source opened with the user's choices; the inputs of :mod:`._inputs`, given or the default training's; the grid:
given, declared by the FMU, or the automatic window of :mod:`._window` from pilot runs, for the default training
with the pulse sized in :mod:`._default_training`), records each run with :mod:`._run` (the run loop into memory or
into the file, in this process or a child, :mod:`._isolation`) and writes the runs into one file with
:mod:`._write` (the file's attributes, the checks after the runs), in the layout of :mod:`._file`.

Modules, one job each:

:mod:`._data`
    :class:`Run` and :class:`Snapshots`, the data model.
:mod:`._file`
    The HDF5 layout (attributes, chunked datasets, atomic writes).
:mod:`._record`
    :func:`record` / :func:`record_to_file`: drive a source into memory or a file.
:mod:`._plan`
    Before the first run: the source opened, the inputs as signals, the grid and who chose it
    (:func:`~._plan.recording_window`: that choice alone).
:mod:`._inputs`
    What drives the runs: signals from specifications, the default training's inputs and their amplitudes, the
    checks of given inputs against the grid.
:mod:`._default_training`
    The default training's window and pulse size from pilot runs (widened, shrunk, raised, lowered, a free run
    beside it).
:mod:`._run`
    One run: the sinks (memory, file), the run loop, the rates derived and checked, the run's attributes.
:mod:`._write`
    The runs into one new file, its attributes, the checks after the runs; :class:`RecordSummary`.
:mod:`._isolation`
    Run the source in this process or in a child process (a crashing FMU binary becomes an error);
    :func:`use_fork_server` lets the child processes of this process start from a fork server.
:mod:`._rates`
    Time grid, inputs in effect, rates derived from recorded samples.
:mod:`._window`
    The automatic snapshot window (:func:`auto_window`).

The checks a recording makes, each in its own module: :mod:`._consistency`, :mod:`._rate_tests`, :mod:`._pairing`
and :mod:`._first_order` (recorded rates that contradict the positions, repaired where they can be),
:mod:`._integrator_checks` (a co-simulation that follows its Euler steps), :mod:`._growth` (a response that grows
without bound), :mod:`._linearity` (a response that does not scale with the input), :mod:`._initialization` (a start
state that follows the inputs); :mod:`._notes` keeps their warnings in the file, :mod:`._size` says a recording's
size and time before it starts, :mod:`._merge` what the parts of a merged data set were recorded from.
"""

from __future__ import annotations

from ._data import Run, Snapshots
from ._file import ARRAYS, FILE_KIND, LAYOUT_VERSION
from ._inputs import DEFAULT_TRAINING_INPUT
from ._isolation import use_fork_server
from ._rates import (inputs_in_effect, newmark_accelerations, newmark_rates, newmark_velocities_and_accelerations,
                     time_grid)
from ._record import record, record_to_file
from ._run import STREAM_THRESHOLD
from ._window import Window, auto_window, fade_time, input_activity, significant_frequency, slowest_frequency
from ._write import RecordSummary

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
