"""Python ROM evaluation: time for 1e5 steps at r = 35 (triple chain, n = 301) and the error against the
step map applied step by step.

Usage: python benchmarks/bench_rom.py [--size 100] [--r 35] [--steps 100000] [--repeats 5]

The ROM is the POD-Galerkin ROM of ``bench_export.py`` (the cost per step depends on r only).  Three ways
to evaluate it on a harmonic input, for both integrators:

* ``loop``: one 3r x 3r matrix-vector product per step in Python (how ``SecondOrderROM.simulate`` stepped
  before :mod:`fmu_opinf._recursion`), the reference for the errors;
* ``simulate``: :meth:`SecondOrderROM.simulate` (all states ``q, q', q''`` and the outputs, in blocks of steps);
* ``outputs``: :func:`fmu_opinf._recursion.linear_recursion` with the output rows ``[Cp, Cv, 0]`` (the
  outputs only; the states are never formed).

Times are the minimum over ``--repeats`` runs of process CPU time (single-threaded: set OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1), which on a loaded machine leaves out the time other processes take; idle, it equals
the wall time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

SIGNAL = "harmonic:amplitude=1,omega=0.3"
TRAIN = "impulse:amplitude=10,t0=1,width=0.5"


def step_loop(phi: np.ndarray, s0: np.ndarray, gamma: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """The reference: one matrix-vector product per step."""
    forcing = gamma @ drive
    states = np.empty((phi.shape[0], drive.shape[1] + 1))
    states[:, 0] = s0
    for i in range(drive.shape[1]):
        states[:, i + 1] = phi @ states[:, i] + forcing[:, i]
    return states


def best_time(function, repeats: int):
    """Minimum process CPU time over ``repeats`` calls and the last result."""
    best, result = np.inf, None
    for _ in range(repeats):
        start = time.process_time()
        result = function()
        best = min(best, time.process_time() - start)
    return best, result


def make_rom(size: int, r: int, dt: float = 0.1):
    """POD-Galerkin ROM of the triple chain as a SecondOrderROM."""
    from bench_export import galerkin_rom

    from fmu_opinf import systems
    from fmu_opinf.rom import SecondOrderROM

    g = galerkin_rom(systems.triple_chain(size), TRAIN, dt, 60.0, r, "velocities")
    return SecondOrderROM(g.Mr, g.Dr, g.Kr, g.Br, g.Cpr, g.Cvr, dt=dt, input_names=g.input_names,
                          output_names=g.output_names)


def measure(rom, integrator: str, steps: int, repeats: int) -> dict:
    from fmu_opinf._recursion import linear_recursion, rom_step_map

    rom.integrator = integrator
    dt = rom.dt
    t_end = steps * dt
    t_sim, trajectory = best_time(lambda: rom.simulate(SIGNAL, dt, t_end), repeats)
    s0 = np.concatenate([trajectory.q[:, 0], trajectory.qdot[:, 0], trajectory.qddot[:, 0]])
    forced = np.vstack([trajectory.u, np.ones((1, trajectory.t.size))])
    phi, gamma, drive = rom_step_map(rom, dt, forced)
    C = np.hstack([rom.Cpr, rom.Cvr, np.zeros_like(rom.Cpr)])

    def outputs():
        return linear_recursion(phi, s0, gamma, drive, C=C) + rom.Dur @ trajectory.u + rom.y0[:, None]

    t_out, y_out = best_time(outputs, repeats)
    t_loop, reference = best_time(lambda: step_loop(phi, s0, gamma, drive), 1)
    r = rom.r
    y_ref = C @ reference + rom.Dur @ trajectory.u + rom.y0[:, None]

    def rel(a, b):
        return float(np.abs(a - b).max() / np.abs(b).max())

    state_error = max(rel(got, reference[i * r:(i + 1) * r])
                      for i, got in enumerate((trajectory.q, trajectory.qdot, trajectory.qddot)))
    return {"integrator": integrator, "r": r, "steps": steps, "loop": t_loop, "simulate": t_sim,
            "outputs": t_out, "state_error": state_error, "simulate_y_error": rel(trajectory.y, y_ref),
            "outputs_error": rel(y_out, y_ref)}


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=100, help="triple chain n1 (n = 3 n1 + 1)")
    parser.add_argument("--r", type=int, default=35)
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    rom = make_rom(args.size, args.r)
    rows = [measure(rom, integrator, args.steps, args.repeats) for integrator in ("newmark", "exact")]
    print(f"triple chain n = {3 * args.size + 1}, r = {args.r}, {args.steps} steps; CPU time [ms] "
          "(min of repeats); errors relative to the step-by-step loop (max over q, q', q'' blocks / outputs)")
    print(f"{'integrator':>10} {'loop':>9} {'simulate':>9} {'outputs':>9} {'loop/sim':>9} "
          f"{'state err':>10} {'y err (sim)':>12} {'y err (out)':>12}")
    for row in rows:
        print(f"{row['integrator']:>10} {row['loop'] * 1e3:>9.1f} {row['simulate'] * 1e3:>9.1f} "
              f"{row['outputs'] * 1e3:>9.1f} {row['loop'] / row['simulate']:>9.1f} {row['state_error']:>10.1e} "
              f"{row['simulate_y_error']:>12.1e} {row['outputs_error']:>12.1e}")
    return rows


if __name__ == "__main__":
    main()
