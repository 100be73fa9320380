"""Benchmark: cost of recording all x, v, a (+ y) of the 600-mass FMU against the FMU's own doStep.

Measures, per communication step (best of ``--repeats`` runs, so that noise from other processes on a
shared machine only ever makes the figures worse):

* ``doStep``        the bare ``fmi2DoStep`` loop through ctypes (the FMU's own work);
* ``GetReal``       one ``fmi2GetReal`` of all recorded values per step, no stepping (the FMU's getter);
* ``loop``          the recording loop alone into already touched memory (no allocation, no checks);
* ``record``        :func:`fmu_opinf.snapshots.record` in memory: set input + doStep + one
                    ``fmi2GetReal`` of all 3n + p values per step, finite check, assembling the run;
* ``record (h5)``   the same, streamed chunk by chunk into a compressed HDF5 file;
* ``record (iso)``  the same in a child process (the command line's default; includes process start, from the
                    fork server that the command line uses on Linux);
* ``simulate_fmu``  ``fmpy.simulate_fmu`` with the same step, input and output variables.

Run: ``python benchmarks/bench_snapshots.py [--g 600] [--t-end 2000] [--dt 0.5] [--repeats 5]``.
Exit status 1 if recording costs more than 1.5 times the doStep loop (best of each, the usual estimate of
the intrinsic cost; on a loaded machine compare also the "loop" and "GetReal" lines, which show where the
time goes).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def best_of(repeats: int, func) -> float:
    """Smallest wall time of ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        times.append(time.perf_counter() - start)
    return min(times)


def dostep_loop(source, t: np.ndarray, U: np.ndarray) -> float:
    """Time of the bare doStep loop (inputs set once before; the FMU's own stepping cost)."""
    source.start(t, U)
    try:
        step, comp, times = source._c_step, source._comp, [float(v) for v in t]
        h = times[1] - times[0]
        start = time.perf_counter()
        for i in range(1, len(times)):
            step(comp, times[i - 1], h, 1)
        return time.perf_counter() - start
    finally:
        source.close()


def getreal_loop(source, t: np.ndarray, U: np.ndarray) -> float:
    """Time of one fmi2GetReal of all recorded values per step, without stepping (the FMU's getter)."""
    row = np.empty(source.width)
    source.start(t, U)
    try:
        get, comp, vr, nv, out = source._c_get, source._comp, source._read.vrs.ctypes.data, len(source._read.vrs), \
            row.ctypes.data
        start = time.perf_counter()
        for _ in range(1, len(t)):
            get(comp, vr, nv, out)
        return time.perf_counter() - start
    finally:
        source.close()


def advance_loop(source, t: np.ndarray, U: np.ndarray, rows: np.ndarray) -> float:
    """Time of the recording loop alone (set input if changed + doStep + GetReal) into touched memory."""
    source.start(t, U)
    try:
        start = time.perf_counter()
        source.advance(rows, 0, len(t))
        return time.perf_counter() - start
    finally:
        source.close()


def run_simulate_fmu(path: Path, names: list[str], signal, dt: float, t_end: float) -> None:
    """fmpy's own driver with the same outputs (input given as a table at the grid points)."""
    import fmpy

    t = np.arange(0.0, t_end + dt / 2, dt)
    table = np.zeros(len(t), dtype=[("time", np.float64), ("u", np.float64)])
    table["time"] = t
    table["u"] = signal.sample(t)[0]
    fmpy.simulate_fmu(str(path), start_time=0.0, stop_time=t_end, step_size=dt, output_interval=dt,
                      input=table, output=names, fmi_type="CoSimulation", validate=False)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--g", type=int, default=600, help="masses of the anchored chain (n = g)")
    parser.add_argument("--dt", type=float, default=0.5)
    parser.add_argument("--t-end", type=float, default=2000.0)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--fmu", help="use this FMU instead of building AnchoredMSD")
    args = parser.parse_args(argv)

    from fmu_opinf import fmus, signals, snapshots
    from fmu_opinf.source import FMUSource
    from fmu_opinf.snapshots._isolation import use_fork_server

    use_fork_server(True)  # as the command line does: isolated runs fork from a fork server (Linux)

    with tempfile.TemporaryDirectory() as tmp:
        if args.fmu:
            path = Path(args.fmu)
        elif args.g == 600:
            path = fmus.bundled_fmu("AnchoredMSD")
        else:
            path = fmus.build_fmus(tmp, models=("AnchoredMSD",), g=args.g)[0]
        source = FMUSource(path)
        signal = signals.parse_signal("impulse:amplitude=100,t0=2,width=0.5")
        t = snapshots.time_grid(args.dt, args.t_end)
        U = np.ascontiguousarray(snapshots.inputs_in_effect(signal, t, source.m).T)
        steps = len(t) - 1
        names = source.position_names + source.velocity_names + source.acceleration_names + source.output_names

        rows = np.ones((len(t), source.width))
        times: dict[str, list[float]] = {}

        def timed(label: str, func) -> None:
            start = time.perf_counter()
            func()
            times.setdefault(label, []).append(time.perf_counter() - start)

        h5file = Path(tmp) / "bench.h5"
        for _ in range(args.repeats):  # interleaved, so that load from other processes hits all alike
            times.setdefault("dostep", []).append(dostep_loop(source, t, U))
            times.setdefault("getreal", []).append(getreal_loop(source, t, U))
            times.setdefault("advance", []).append(advance_loop(source, t, U, rows))
            timed("record", lambda: snapshots.record(source, signal, args.dt, args.t_end, quiet=True))
            timed("streamed", lambda: snapshots.record(source, signal, args.dt, args.t_end, path=h5file, quiet=True,
                                                        overwrite=True, stream=True).close())
        for _ in range(args.repeats):  # the first also starts the fork server
            timed("isolated", lambda: snapshots.record(source, signal, args.dt, args.t_end, quiet=True, isolate=True))
        for _ in range(max(1, args.repeats // 2)):
            timed("fmpy", lambda: run_simulate_fmu(path, names, signal, args.dt, args.t_end))
        best = {label: min(values) for label, values in times.items()}
        dostep, record, fmpy_time = best["dostep"], best["record"], best["fmpy"]

    us = 1e6 / steps
    print(f"FMU {path.name}: n={source.n}, {len(names)} recorded values per step, {steps} steps "
          f"(dt={args.dt:g}, t_end={args.t_end:g}); best of {args.repeats}")
    table = [("doStep loop only", dostep),
             ("  fmi2GetReal of all values only", best["getreal"]),
             ("  recording loop, touched memory", best["advance"]),
             ("record, in memory", record),
             ("record, streamed to HDF5 (gzip)", best["streamed"]),
             ("record, isolated child process", best["isolated"]),
             ("fmpy.simulate_fmu, same outputs", fmpy_time)]
    for label, seconds in table:
        print(f"  {label:34s} {seconds:8.3f} s  {seconds * us:8.1f} us/step  {seconds / dostep:6.2f} x doStep")
    paired = sorted(r / d for r, d in zip(times["record"], times["dostep"]))
    print(f"paired record/doStep ratios (each repeat back to back; spread shows machine load): "
          f"median {float(np.median(paired)):.2f}, range {paired[0]:.2f} .. {paired[-1]:.2f}")
    ratio = record / dostep
    print(f"recording (in memory) / doStep = {ratio:.2f} (best of each; target <= 1.5); "
          f"recording overhead = {(record - dostep) / dostep:.2f} x doStep; "
          f"simulate_fmu / record = {fmpy_time / record:.1f}")
    return 0 if ratio <= 1.5 else 1


if __name__ == "__main__":
    sys.exit(main())
