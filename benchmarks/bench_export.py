"""ROM FMU vs full-order FMU: time per communication step for both benchmarks (per-step time table).

Usage: python benchmarks/bench_export.py [--anchored 600 10000 100000] [--triple 100 1000 10000]
                                         [--steps 2000] [--repeats 3]

For every size the full-order benchmark FMU is built, a reduced model is made from a POD basis
of its reference trajectory (intrusive Galerkin projection: r = 5 positions basis for the anchored
chain, r = 35 velocities basis for the triple chain, the orders of the paper; the cost per step
of the ROM FMU depends on r only, not on how the ROM was fitted) and exported with
:func:`fmu_opinf.export.export_fmu`.  The ROM FMU steps the modal (2 x 2 block-diagonal) form of its
step map; the same ROM exported without it (Newmark solves in the shared kernel, the path before the
modal form) is timed too.  All FMUs are timed by a small C importer (dlopen, fmi2SetReal + fmi2DoStep
per step, median of ``--repeats`` runs after a warm-up step) in process CPU time, so the figures are the
FMUs' own cost without Python call overhead and without time lost to other processes on a loaded
machine; the FMPy-driven wall time per step (what a Python importer sees) is printed alongside.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from unittest import mock

import numpy as np

TIMER = r"""
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                   fmi2String m, ...) {
    (void)e; (void)n; (void)c;
    fprintf(stderr, "[%d] %s\n", (int)s, m);
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(library, #name); if (!name) return 2;

int main(int argc, char *argv[]) {
    fmi2CallbackFunctions callbacks = { logger, calloc, free, NULL, NULL };
    fmi2ValueReference input = 1;
    fmi2Real u, t = 0.0, h;
    fmi2Component c;
    void *library;
    long steps, k;
    int repeats, r;

    if (argc != 6 || !(library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL))) return 1;
    h = atof(argv[3]);
    steps = atol(argv[4]);
    repeats = atoi(argv[5]);
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2DoStep) LOAD(fmi2FreeInstance)

    c = fmi2Instantiate("timer", fmi2CoSimulation, argv[2], "", &callbacks, fmi2False, fmi2False);
    if (!c || fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) return 3;
    if (fmi2DoStep(c, t, h, fmi2True) != fmi2OK) return 4;
    t += h;
    for (r = 0; r < repeats; r++) {
        struct timespec start, stop;
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &start);
        for (k = 0; k < steps; k++) {
            u = sin(0.3 * t);
            if (fmi2SetReal(c, &input, 1, &u) != fmi2OK || fmi2DoStep(c, t, h, fmi2True) != fmi2OK)
                return 5;
            t += h;
        }
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &stop);
        printf("%.6e\n", ((stop.tv_sec - start.tv_sec) + 1e-9 * (stop.tv_nsec - start.tv_nsec)) / steps);
    }
    fmi2FreeInstance(c);
    return 0;
}
"""


def compile_timer(folder: Path) -> Path:
    """Compile the C timing importer."""
    import fmpy

    from fmu_opinf.fmus import find_build_tools

    source = folder / "timer.c"
    source.write_text(TIMER)
    program = folder / "timer"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([find_build_tools()[1], "-std=c99", "-O2", "-I", str(headers), str(source), "-o",
                    str(program), "-ldl", "-lm"], check=True)
    return program


def c_time_per_step(timer: Path, fmu: Path, folder: Path, h: float, steps: int,
                    repeats: int) -> float:
    """Median seconds per (fmi2SetReal, fmi2DoStep) measured in C."""
    from fmpy import extract, read_model_description

    unzipped = Path(extract(str(fmu), str(folder / fmu.stem)))
    md = read_model_description(str(unzipped))
    binary = unzipped / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"
    out = subprocess.run([str(timer), str(binary), md.guid, repr(h), str(steps), str(repeats)],
                         check=True, capture_output=True, text=True).stdout
    return statistics.median(float(line) for line in out.split())


def fmpy_time_per_step(fmu: Path, h: float, steps: int) -> float:
    """Seconds per (setReal, doStep, getReal) when driven from Python by FMPy."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    folder = extract(str(fmu))
    md = read_model_description(folder)
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    slave = FMU2Slave(guid=md.guid, unzipDirectory=folder,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="py")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.doStep(0.0, h)
    start = time.perf_counter()
    for k in range(1, steps + 1):
        slave.setReal([1], [np.sin(0.3 * k * h)])
        slave.doStep(k * h, h)
        slave.getReal(outputs)
    elapsed = (time.perf_counter() - start) / steps
    slave.freeInstance()
    return elapsed


def galerkin_rom(system, signal: str, dt: float, t_end: float, r: int, kind: str):
    """POD-Galerkin ROM with the SecondOrderROM attributes used by the exporter."""
    from fmu_opinf import newmark

    run = newmark.simulate(system, signal, dt, t_end)
    data = run.x if kind == "positions" else run.xdot
    V = np.linalg.svd(data, full_matrices=False)[0][:, :r]

    def project(A):
        P = V.T @ (A @ V)
        return (P + P.T) / 2

    return SimpleNamespace(
        Mr=project(system.M), Dr=project(system.D), Kr=project(system.K),
        Br=np.asarray(V.T @ system.B.toarray()), Cpr=np.asarray(system.Cp @ V),
        Cvr=np.asarray(system.Cv @ V), basis=V, basis_kind=kind, dt=dt,
        input_names=["u"], output_names=[f"y[{i}]" for i in range(1, system.Cp.shape[0] + 1)],
        provenance={"source": system.name, "training_input": signal,
                    "fit_date": "benchmark (POD-Galerkin)"},
    )


CASES = {
    # name: (spec factory, system factory, training input, dt, t_end, r, basis kind)
    "AnchoredMSD": ("anchored_msd_spec", "anchored_msd", "impulse:amplitude=100,t0=2,width=0.5",
                    0.5, 200.0, 5, "positions"),
    "TripleChainMSD": ("triple_chain_spec", "triple_chain", "impulse:amplitude=10,t0=1,width=0.5",
                       0.1, 60.0, 35, "velocities"),
}


def measure(name: str, size: int, tmp: Path, timer: Path, steps: int, repeats: int) -> dict:
    from fmu_opinf import export, fmus, systems

    spec_factory, system_factory, signal, dt, t_end, r, kind = CASES[name]
    spec = getattr(fmus, spec_factory)(size)
    fom = fmus.build_second_order_fmu(spec, tmp / f"{name}_{size}.fmu")
    rom = galerkin_rom(getattr(systems, system_factory)(size), signal, dt, t_end, r, kind)
    rom_path = export.export_fmu(rom, tmp / f"{name}ROM_{size}.fmu", overwrite=True)
    with mock.patch.object(export, "_modal_matrices", lambda *args: {}):   # the kernel without the modal form
        solve_path = export.export_fmu(rom, tmp / f"{name}ROMsolve_{size}.fmu", overwrite=True)
    fom_c = c_time_per_step(timer, fom, tmp, dt, steps, repeats)
    rom_c = c_time_per_step(timer, rom_path, tmp, dt, steps, repeats)
    return {"model": name, "n": spec.n, "r": r, "fom_c": fom_c, "rom_c": rom_c,
            "rom_solve_c": c_time_per_step(timer, solve_path, tmp, dt, steps, repeats),
            "fom_py": fmpy_time_per_step(fom, dt, min(steps, 500)),
            "rom_py": fmpy_time_per_step(rom_path, dt, min(steps, 500))}


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--anchored", type=int, nargs="*", default=[600, 10_000, 100_000])
    parser.add_argument("--triple", type=int, nargs="*", default=[100, 1_000, 10_000])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        timer = compile_timer(tmp)
        for name, sizes in (("AnchoredMSD", args.anchored), ("TripleChainMSD", args.triple)):
            for size in sizes:
                rows.append(measure(name, size, tmp, timer, args.steps, args.repeats))
    print("C importer, process CPU time per fmi2SetReal + fmi2DoStep; ROM: modal kernel, ROM solve: Newmark "
          "solves (no modal form); FMPy: wall time per setReal + doStep + getReal")
    print(f"{'model':>15} {'n':>8} {'r':>3} {'FOM [us]':>10} {'ROM [us]':>9} {'speed-up':>9}"
          f" {'ROM solve [us]':>15} {'FOM fmpy [us]':>14} {'ROM fmpy [us]':>14} {'fmpy speed-up':>14}")
    for row in rows:
        print(f"{row['model']:>15} {row['n']:>8} {row['r']:>3} {row['fom_c'] * 1e6:>10.2f} "
              f"{row['rom_c'] * 1e6:>9.3f} {row['fom_c'] / row['rom_c']:>9.1f} {row['rom_solve_c'] * 1e6:>15.2f} "
              f"{row['fom_py'] * 1e6:>14.1f} {row['rom_py'] * 1e6:>14.1f} "
              f"{row['fom_py'] / row['rom_py']:>14.1f}")
    return rows


if __name__ == "__main__":
    main()
