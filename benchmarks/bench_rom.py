"""Python ROM evaluation: CPU time for 1e5 steps at r = 10, 35, 100 (triple chain, n = 301) and the errors against
the step map applied step by step.

Usage: python benchmarks/bench_rom.py [--size 100] [--r 10 35 100] [--steps 100000] [--repeats 5]

The ROM is the POD-Galerkin ROM of ``bench_export.py`` (the cost per step depends on r and the number of outputs,
here p = 1, not on how the ROM was fitted).  Three ways to evaluate it on a harmonic input, for both integrators:

* ``loop``: today's step map (:func:`fmu_opinf._recursion.rom_step_map`, one 3r x 3r matrix-vector product per
  step in Python, how ``SecondOrderROM.simulate`` stepped before :mod:`fmu_opinf._recursion`), the reference for
  the errors;
* ``outputs``: :meth:`SecondOrderROM.simulate` as ``compare`` calls it (the outputs ``y``; the states are not
  formed), from parsing the input signal to the finished ``y``;
* ``states``: the same plus the first access of ``trajectory.q`` (which forms ``q, q', q''``).

Times are the minimum over ``--repeats`` runs of process CPU time (single-threaded: set OMP_NUM_THREADS=1
OPENBLAS_NUM_THREADS=1), which on a loaded machine leaves out the time other processes take; idle, it equals
the wall time.  The loop runs once.  Errors are ``max |a - b| / max |b|`` against the loop: for the outputs, and
the largest over the three blocks ``q, q', q''``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg

sys.path.insert(0, str(Path(__file__).parent))

SIGNAL = "harmonic:amplitude=1,omega=0.3"
TRAIN = "impulse:amplitude=10,t0=1,width=0.5"
INTEGRATORS = ("newmark", "exact")


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


def loop_reference(rom, u: np.ndarray) -> np.ndarray:
    """States ``(3r, k + 1)`` by today's step map applied step by step, from the consistent start."""
    from fmu_opinf._recursion import rom_step_map

    forced = np.vstack([u, np.ones((1, u.shape[1]))])
    qddot0 = scipy.linalg.solve(rom.Mr, rom.Br @ u[:, 0] + rom.fr - rom.Dr @ rom.qdot0 - rom.Kr @ rom.q0)
    phi, gamma, drive = rom_step_map(rom, rom.dt, forced)
    return step_loop(phi, np.concatenate([rom.q0, rom.qdot0, qddot0]), gamma, drive)


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def measure(rom, integrator: str, steps: int, repeats: int) -> dict:
    """Times and errors of the three evaluations for one integrator."""
    rom.integrator = integrator
    dt, r = rom.dt, rom.r
    t_out, trajectory = best_time(lambda: rom.simulate(SIGNAL, dt, steps * dt), repeats)

    def with_states():
        result = rom.simulate(SIGNAL, dt, steps * dt)
        result.q
        return result

    t_states, formed = best_time(with_states, repeats)
    t_loop, reference = best_time(lambda: loop_reference(rom, trajectory.u), 1)
    C = np.hstack([rom.Cpr, rom.Cvr, np.zeros_like(rom.Cpr)])
    y_ref = C @ reference + rom.Dur @ trajectory.u + rom.y0[:, None]
    state_error = max(_relative(got, reference[i * r:(i + 1) * r])
                      for i, got in enumerate((formed.q, formed.qdot, formed.qddot)))
    return {"integrator": integrator, "r": r, "steps": steps, "loop": t_loop, "outputs": t_out, "states": t_states,
            "y_error": _relative(trajectory.y, y_ref), "state_error": state_error}


def table(rows: list[dict]) -> str:
    """The printed table."""
    lines = [f"{'r':>4} {'integrator':>10} {'loop':>9} {'outputs':>9} {'states':>9} {'loop/out':>9} "
             f"{'loop/st':>8} {'y err':>9} {'state err':>10}"]
    for row in rows:
        lines.append(f"{row['r']:>4} {row['integrator']:>10} {row['loop'] * 1e3:>9.1f} {row['outputs'] * 1e3:>9.1f} "
                     f"{row['states'] * 1e3:>9.1f} {row['loop'] / row['outputs']:>9.1f} "
                     f"{row['loop'] / row['states']:>8.1f} {row['y_error']:>9.1e} {row['state_error']:>10.1e}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=100, help="triple chain n1 (n = 3 n1 + 1)")
    parser.add_argument("--r", type=int, nargs="+", default=[10, 35, 100])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    rows = []
    for r in args.r:
        rom = make_rom(args.size, r)
        rows += [measure(rom, integrator, args.steps, args.repeats) for integrator in INTEGRATORS]
    print(f"triple chain n = {3 * args.size + 1}, p = 1 output, {args.steps} steps; CPU time [ms] (min of "
          f"{args.repeats} repeats, loop: 1 run); loop = today's step map step by step, outputs = simulate "
          "(y only), states = simulate + q, q', q''; errors max|a - b| / max|b| against the loop")
    print(table(rows))
    return rows


if __name__ == "__main__":
    main()
