"""Whether an FMU's start state follows the inputs it is initialized under (a steady-state initialization).

Modelica models often start at the static equilibrium under whatever input initialization sees (``initial
equation der(x) = 0``, the ``SteadyState`` init of the standard library's components).  The recording then starts
at the equilibrium under the training's first input value, and so did the exported ROM FMU, whatever input it was
initialized under: under another one it swung about the new equilibrium while the source stayed at rest (seventh
audit, E3: a 10 N preload initialized under 5 N).  :func:`initialization_of` tells such a source from one whose
start values are fixed, with two initializations that differ only in the inputs' values; the recording stores
what it found (``initialization`` in the file), and the exported ROM FMU starts at its own static response to the
inputs it is initialized under (:mod:`fmu_opinf.export`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import FmuOpinfError
from ..sources import Source

__all__ = ["initialization_of", "STEADY_STATE"]

#: The ``kind`` of :func:`initialization_of` for a start state that follows the inputs.
STEADY_STATE = "steady-state"

#: Largest change of the start positions, relative to their size, that still counts as none (a fixed start gives
#: the same bits; a steady-state solve moves by the static deflection).
UNCHANGED = 1e-10


def initialization_of(source: Source, t: np.ndarray, first_input: np.ndarray, first_position: np.ndarray,
                      isolate: bool) -> dict[str, Any] | None:
    """``{"kind": "steady-state", "input": first_input}`` when the source's positions after initialization change
    with the inputs' values, else None (fixed start values, no inputs, not an FMU, or a probe that failed).

    Two initializations, one step of ``t`` each: the inputs held at their start values, and moved by the default
    training amplitude with the window's distinct pilot weights (inputs placed symmetrically do not cancel), down
    instead of up where the declared ``max`` leaves no room.  ``first_input`` and ``first_position`` are the input
    the recording's first run starts under and its start positions (the ROM's start): where that input is the start
    values, as in the default training, the first initialization is that run's and is not repeated.  A probe the
    FMU refuses says nothing.
    """
    if getattr(source, "kind", None) != "fmu" or not source.m or len(t) < 2:
        return None
    from ._default_training import _pilot_weights
    from ._inputs import HeldInputs, default_amplitudes, held_starts
    from ._run import MemorySink, record_run

    starts = held_starts(source)
    low, high = source.input_ranges()
    moves = np.asarray(default_amplitudes(source), dtype=float) * _pilot_weights(source.m)
    moves = np.where((starts + moves > high) & (starts - moves >= low), -moves, moves)
    first_input = np.asarray(first_input, dtype=float).reshape(-1)
    recorded = np.array_equal(first_input, starts)
    positions = [np.asarray(first_position, dtype=float)] if recorded else []
    for values in ([] if recorded else [starts]) + [starts + moves]:
        try:
            run, failure = record_run(source, HeldInputs(values), t[:2], MemorySink, True, isolate,
                                      "initial state under another input", say_events=False)
        except (FmuOpinfError, OSError, RuntimeError, ValueError):
            return None
        if failure is not None:
            return None
        positions.append(np.asarray(run.x0, dtype=float))
    size = max(float(np.abs(positions[0]).max(initial=0.0)), float(np.abs(positions[1]).max(initial=0.0)))
    change = float(np.abs(positions[1] - positions[0]).max(initial=0.0))
    if not change > UNCHANGED * size:
        return None
    return {"kind": STEADY_STATE, "input": [float(v) for v in first_input]}
