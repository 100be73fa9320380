"""Operator-inference SDP fit time vs reduced order: the certified dense interior-point path against Clarabel.

Data: the triple chain (n = 301, velocity constraint) excited by the paper's impulse, dt = 0.05 to t = 300
(6001 snapshots), projected on its velocity POD basis of order r.  For each r and each normalization
(``trace``, ``mass-eigenvalue`` and the default ``auto`` = both) the SDP fit of eq. (16) without refinement is
timed twice:

* ``ipm``: ``fit_operators(..., solver="auto")`` -- cone screening, the screened SDP by the dense interior-point
  method of ``fmu_opinf._sdp``, accepted only with a certified gap (else Clarabel); the full three-cone SDP goes
  to Clarabel;
* ``clarabel``: ``fit_operators(..., solver="clarabel", tol=1e-10)`` -- the same screening, every SDP by
  Clarabel through cvxpy at high accuracy (skipped above ``--clarabel-max-r``).

Columns: CPU seconds (``time.process_time``, one BLAS thread: the fit limits BLAS to one thread itself; the
machine is shared, so CPU time, not wall time), the solver and status of the reported solve, the certified gap,
the cones kept, and the relative difference of the SDP objectives ``(f_ipm - f_clarabel) / f_clarabel``
(``info["sdp_objective"]``, in the SDP's own units: after the final rescaling to ``trace(Mr) = r`` a
degenerate ``Mr >= I`` optimum could differ in scale between solvers).  For ``auto`` the two rows may have
chosen different normalizations; the difference is then not meaningful and the chosen ones are printed.

Run:  ``python benchmarks/bench_fit.py [--orders 5,10,20,35,50] [--clarabel-max-r 50]``.
"""

from __future__ import annotations

import argparse
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


def time_fit(data: list[np.ndarray], u: np.ndarray, **options) -> tuple[float, dict]:
    start = time.process_time()
    info = fit_operators(*data, u, refine=False, **options).info
    return time.process_time() - start, info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", default="5,10,20,35,50", help="comma-separated reduced orders")
    parser.add_argument("--normalizations", default="trace,mass-eigenvalue,auto")
    parser.add_argument("--clarabel-max-r", type=int, default=50, help="skip Clarabel above this r")
    args = parser.parse_args()
    orders = [int(v) for v in args.orders.split(",")]
    V, data, u, _ = reduced_data(max(orders))
    print(f"triple chain n={V.shape[0]}, k={u.shape[1]} snapshots, m={u.shape[0]}; CPU seconds")
    header = (f"{'r':>3} {'normalization':>15} | {'ipm [s]':>8} {'solver':>8} {'status':>8} {'gap':>8} "
              f"{'cones':>12} | {'clarabel [s]':>12} | {'obj rel diff':>12}")
    print(header)
    print("-" * len(header))
    for r in orders:
        sub = [a[:r] for a in data]
        for normalization in args.normalizations.split(","):
            t_ipm, fast = time_fit(sub, u, normalization=normalization, solver="auto")
            clarabel, diff = "skipped", "--"
            if r <= args.clarabel_max_r:
                t_cl, slow = time_fit(sub, u, normalization=normalization, solver="clarabel", tol=1e-10)
                clarabel = f"{t_cl:12.2f}"
                diff = f"{(fast['sdp_objective'] - slow['sdp_objective']) / slow['sdp_objective']:12.1e}"
            gap = fast.get("gap")
            label = normalization if normalization != "auto" else f"auto({fast['normalization'][:8]})"
            print(f"{r:3d} {label:>15} | "
                  f"{t_ipm:8.2f} {fast['solver'][:8]:>8} {fast['status'][:8]:>8} "
                  f"{'--' if gap is None else f'{gap:.0e}':>8} {','.join(fast['cones']) or '-':>12} | "
                  f"{clarabel:>12} | {diff:>12}", flush=True)


if __name__ == "__main__":
    main()
