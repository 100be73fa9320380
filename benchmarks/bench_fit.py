"""Operator-inference SDP fit time vs reduced order: compressed formulation vs the direct one.

Data: the triple chain (n = 301, velocity constraint) excited by the paper's impulse, dt = 0.05 to t = 300
(6001 snapshots), projected on its velocity POD basis of order r.  For each r the fit (eq. 16) is timed as

* ``compressed sdp``: (3r+m)-square triangular factor, Br eliminated, quadratic form on the free entries,
  always solved by Clarabel (``method="sdp"``);
* ``compressed auto``: the same, but the cone-free minimizer is accepted when it is already PSD (certified
  optimum; otherwise the SDP as above);
* ``direct``: the full (r, k) reduced data matrices handed to cvxpy as ``sum_squares(Mr Xr'' + ...)``.

These three use the trace normalization, so their optima are comparable.  ``default`` is ``fit_operators``
without outputs (``normalization="auto"``: both normalizations, the smaller acceleration residual kept);
``refined`` adds the output-error refinement (``fit_operators(..., dt=, y=)``, one timed run) and ``refine``
is the part of it spent refining (the default budget: 300 L-BFGS iterations up to r = 40, 20 r above).

Times are wall-clock medians over ``--repeats`` runs and include everything from the reduced data to the
operators (cvxpy compilation and Clarabel).  Run:  ``python benchmarks/bench_fit.py [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from fmu_opinf import newmark, systems
from fmu_opinf.basis import PODBasis
from fmu_opinf.inference import fit_operators


DT = 0.05


def reduced_data(r_max: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    system = systems.triple_chain()
    run = newmark.simulate(system, "impulse:amplitude=100,t0=2,width=0.5", DT, 300.0)
    V = PODBasis(r=r_max, kind="velocities").fit([run]).basis_
    return V, [V.T @ a for a in (run.xddot, run.xdot, run.x)], run.u, run.y


def time_fit(data: list[np.ndarray], u: np.ndarray, repeats: int, **options) -> tuple[float, dict]:
    times, info = [], {}
    for _ in range(repeats):
        start = time.perf_counter()
        info = fit_operators(*data, u, **options).info
        times.append(time.perf_counter() - start)
    return statistics.median(times), info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", default="5,20,35,50", help="comma-separated reduced orders")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measurement (median)")
    parser.add_argument("--direct-repeats", type=int, default=1, help="runs of the slow direct formulation")
    parser.add_argument("--direct-max-r", type=int, default=35, help="skip the direct formulation above this r")
    args = parser.parse_args()
    orders = [int(v) for v in args.orders.split(",")]
    V, data, u, y = reduced_data(max(orders))
    print(f"triple chain n={V.shape[0]}, k={u.shape[1]} snapshots, m={u.shape[0]}")
    header = (f"{'r':>3} {'unknowns':>8} | {'sdp [s]':>8} {'setup':>6} {'solve':>6} {'it':>3} | "
              f"{'auto [s]':>8} {'path':>16} | {'direct [s]':>10} {'setup':>6} {'solve':>6} | {'obj rel diff':>12} | "
              f"{'default [s]':>8} {'normalization':>16} | {'refined [s]':>11} {'refine':>6} {'it':>3}")
    print(header)
    print("-" * len(header))
    for r in orders:
        sub = [a[:r] for a in data]
        t_sdp, i_sdp = time_fit(sub, u, args.repeats, method="sdp", normalization="trace")
        t_auto, i_auto = time_fit(sub, u, args.repeats, method="auto", normalization="trace")
        t_default, i_default = time_fit(sub, u, args.repeats)
        t_refined, i_refined = time_fit(sub, u, 1, dt=DT, y=y)
        refinement = i_refined["refinement"]
        direct = "skipped"
        if r <= args.direct_max_r:
            t_dir, i_dir = time_fit(sub, u, args.direct_repeats, method="sdp", compressed=False,
                                    normalization="trace")
            diff = abs(i_dir["objective"] - i_sdp["objective"]) / i_sdp["objective"]
            direct = f"{t_dir:10.2f} {i_dir['setup_seconds']:6.2f} {i_dir['solve_seconds']:6.2f} | {diff:12.2e}"
        unknowns = 3 * r * (r + 1) // 2 + r * u.shape[0]
        print(f"{r:3d} {unknowns:8d} | {t_sdp:8.2f} {i_sdp['setup_seconds']:6.2f} {i_sdp['solve_seconds']:6.2f} "
              f"{i_sdp['iterations']:3d} | {t_auto:8.2f} {i_auto['method']:>16} | {direct} | "
              f"{t_default:8.2f} {i_default['normalization']:>16} | {t_refined:11.2f} {refinement['seconds']:6.2f} "
              f"{refinement['iterations']:3d}", flush=True)


if __name__ == "__main__":
    main()
