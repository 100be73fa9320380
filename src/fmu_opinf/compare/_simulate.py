"""One model's outputs on a time grid (:func:`simulate_outputs`): a ROM, a builtin system, or an FMU run in this or a
child process."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import either
from ..errors import DimensionError, InputSpecError


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
    from ..rom import SecondOrderROM

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
    from .._progress import Progress
    from ..newmark import applied_inputs
    from ..source import open_source
    from ..sources import warn_other_communication_step

    from ..snapshots._isolation import deferred_interrupts, produce_inprocess, produce_isolated

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
                             f"out {either('--inputs')}, or give {either('--inputs', value=','.join(signal_inputs))}")
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
    from .._progress import Progress
    from ..newmark import NewmarkStepper, applied_inputs
    from ..systems import builtin_system

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
