"""Benchmark FMU speed: time per doStep of AnchoredMSD.fmu vs the Python reference simulator.

Usage: python benchmarks/bench_fmus.py [--sizes 600 10000 100000 1000000] [--steps 200] [--repeats 3]

For each chain length g the FMU is generated and compiled (states not listed in the
modelDescription above n = 20000), driven by FMPy's FMU2Slave exactly as an importer does
(set u, doStep, get y every step), and compared with ``fmu_opinf.newmark.NewmarkStepper``
on the same input.  Reported: median over ``--repeats`` runs of the time per step, and the
one-off cost (assembly + factorization happen at the first step / at start).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _input(k: int) -> float:
    return 100.0 if k < 2 else 0.0


def fmu_time_per_step(path: Path, g: int, steps: int, repeats: int) -> tuple[float, float]:
    """Median seconds per (setReal, doStep, getReal) cycle, and the start-up time."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from fmu_opinf.fmus import anchored_msd_spec, value_references

    spec = anchored_msd_spec(g)
    spec.expose_states = False
    vr = value_references(spec)
    folder = extract(str(path))
    md = read_model_description(folder)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    fmu.instantiate()
    h = 0.5
    timings, startup = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.setReal(vr["u"], [_input(0)])
        fmu.doStep(0.0, h)
        startup.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for k in range(1, steps + 1):
            fmu.setReal(vr["u"], [_input(k)])
            fmu.doStep(k * h, h)
            fmu.getReal(vr["y"])
        timings.append((time.perf_counter() - t0) / steps)
        fmu.reset()
    fmu.freeInstance()
    return statistics.median(timings), statistics.median(startup)


def python_time_per_step(g: int, steps: int, repeats: int) -> tuple[float, float]:
    """Median seconds per NewmarkStepper.step, and the factorization + start time."""
    from fmu_opinf import newmark, systems

    system = systems.anchored_msd(g=g)
    t0 = time.perf_counter()
    stepper = newmark.NewmarkStepper(system.M, system.D, system.K, system.B, 0.5, G=system.G,
                                     constraint=system.constraint)
    stepper.start(np.array([_input(0)]))
    startup = time.perf_counter() - t0
    timings = []
    for _ in range(repeats):
        stepper.start(np.array([_input(0)]))
        t0 = time.perf_counter()
        for k in range(1, steps + 1):
            stepper.step(np.array([_input(k)]))
            system.Cp @ stepper.x
        timings.append((time.perf_counter() - t0) / steps)
    return statistics.median(timings), startup


def main(argv: list[str] | None = None) -> list[dict]:
    from fmu_opinf.fmus import anchored_msd_spec, build_second_order_fmu

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[600, 10_000, 100_000, 1_000_000])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for g in args.sizes:
            spec = anchored_msd_spec(g)
            spec.expose_states = g <= 20_000
            path = build_second_order_fmu(spec, Path(tmp) / f"AnchoredMSD_{g}.fmu")
            fmu_step, fmu_start = fmu_time_per_step(path, g, args.steps, args.repeats)
            py_step, py_start = python_time_per_step(g, args.steps, args.repeats)
            rows.append({"g": g, "fmu_step": fmu_step, "fmu_start": fmu_start,
                         "py_step": py_step, "py_start": py_start})
    print(f"{'g':>9} {'FMU step [us]':>14} {'FMU ns/dof':>11} {'FMU start [s]':>14} "
          f"{'Python step [us]':>17} {'Python start [s]':>17} {'speed-up':>9}")
    for row in rows:
        print(f"{row['g']:>9} {row['fmu_step'] * 1e6:>14.1f} {row['fmu_step'] / row['g'] * 1e9:>11.2f} "
              f"{row['fmu_start']:>14.3f} {row['py_step'] * 1e6:>17.1f} {row['py_start']:>17.3f} "
              f"{row['py_step'] / row['fmu_step']:>9.1f}")
    return rows


if __name__ == "__main__":
    main()
