"""Operator-inference SDP fit time vs reduced order: the certified dense interior-point path against Clarabel.

Data: the triple chain (n = 301, velocity constraint) excited by the paper's impulse, dt = 0.05 to t = 300
(6001 snapshots), projected on its velocity POD basis of order r.  For each r and each normalization
(``trace``, ``mass-eigenvalue`` and the default ``auto`` = both) the SDP fit of eq. (16) without refinement is
timed twice:

* ``ipm``: ``fit_operators(..., solver="auto")`` -- cone screening (for this solver round by round, the cones
  that a round's dropped blocks violate added), every SDP by the dense interior-point method of ``fmu_opinf._sdp``,
  accepted only with a certified gap (else Clarabel);
* ``clarabel``: ``fit_operators(..., solver="clarabel", tol=1e-10)`` -- the same screening, every SDP by
  Clarabel through cvxpy at high accuracy (skipped above ``--clarabel-max-r``).

Columns: CPU seconds (``time.process_time`` plus ended child processes: ``auto`` solves the ``Mr >= I``
normalization in a forked process; one BLAS thread: the fit limits BLAS to one thread itself; the
machine is shared, so CPU time, not wall time), the solver and status of the reported solve, the certified gap,
the cones kept, and the relative difference of the SDP objectives ``(f_ipm - f_clarabel) / f_clarabel``
(``info["sdp_objective"]``, in the SDP's own units: after the final rescaling to ``trace(Mr) = r`` a
degenerate ``Mr >= I`` optimum could differ in scale between solvers).  For ``auto`` the two rows may have
chosen different normalizations; the difference is then not meaningful and the chosen ones are printed.

``--total`` instead times the whole default fit that ``fmu-opinf fit`` runs on these data (``fit_operators`` with
the outputs and the step: SDP, output-error refinement, least-squares candidate with its own refinement): its
wall and CPU seconds (the second start runs in a forked process or a second thread, so CPU, which counts the
ended child process too, can exceed wall), the wall seconds of the
SDP, of the refinement from the SDP solution and of the refinement from the least-squares realization (``2nd
start``, beside the other two) as the fit reports them, the SDP start's refinement iterations, whether the
candidate was kept and the max eps_y of eq. (19) on the training run; this is the figure issue 16's target
(r = 35 in 0.3 s, r = 100 in 5 s) is about.

``--evaluation`` times one evaluation of the refinement's objective and gradient in the step map (the Newmark
step of the SDP solution, above r = 60 of the factored start as in the default fit; the output map of eq. 17), by
stepping states and adjoints (``dense``) and through the
eigenvalues of the step map (``modal``, the default where it is faster), CPU milliseconds (best of 5 rounds of
repeated calls), and the relative difference of the two gradients.

Run:  ``python benchmarks/bench_fit.py [--orders 5,10,20,35,50] [--clarabel-max-r 50] [--total | --evaluation]``.
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from fmu_opinf import newmark, systems
from fmu_opinf.basis import PODBasis
from fmu_opinf.inference import fit_operators

DT = 0.05
T_END = 300.0
TRAIN = "impulse:amplitude=100,t0=2,width=0.5"


def reduced_data(r_max: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    system = systems.triple_chain()
    run = newmark.simulate(system, TRAIN, DT, T_END)
    V = PODBasis(r=r_max, kind="velocities").fit([run]).basis_
    return V, [V.T @ a for a in (run.xddot, run.xdot, run.x)], run.u, run.y


def time_fit(data: list[np.ndarray], u: np.ndarray, **options) -> tuple[float, dict]:
    """CPU seconds of one fit without refinement, its forked second normalization's included (:func:`_cpu_seconds`;
    before 2026-12-07 the ``auto`` rows counted this process only, e.g. r = 50 1.28 s against 1.68 + 2.83 s)."""
    start = _cpu_seconds()
    info = fit_operators(*data, u, refine=False, **options).info
    return _cpu_seconds() - start, info


def total_fit(data: list[np.ndarray], u: np.ndarray, y: np.ndarray, V: np.ndarray, orders: list[int]) -> None:
    """The default fit with refinement and candidate, CPU seconds per part (``--total``)."""
    from fmu_opinf.compare import output_error
    from fmu_opinf.inference import fit_outputs
    from fmu_opinf.rom import SecondOrderROM

    print(f"{'r':>3} | {'wall [s]':>8} {'CPU [s]':>9} {'sdp wall':>8} {'refine wall':>11} {'iters':>5} {'2nd start':>9} "
          f"{'candidate':>9} | "
          f"{'path':>14} | {'train max eps_y':>15}")
    for r in orders:
        sub = [a[:r] for a in data]
        start, wall = _cpu_seconds(), time.perf_counter()
        fit = fit_operators(*sub, u, y=y, dt=DT)
        seconds, wall = _cpu_seconds() - start, time.perf_counter() - wall
        info = fit.info
        refinement = info.get("refinement", {})
        chosen = info.get("least_squares_candidate", {}).get("chosen")
        second = info.get("least_squares_candidate", {}).get("refinement", {}).get("seconds", 0.0)
        Cpr, Cvr = fit.output_map if fit.output_map is not None else fit_outputs(sub[1], sub[2], y)
        rom = SecondOrderROM(fit.Mr, fit.Dr, fit.Kr, fit.Br, Cpr, Cvr, coordinates=fit.coordinates)
        error = output_error(y, rom.simulate(TRAIN, DT, T_END).y).max()
        print(f"{r:3d} | {wall:8.2f} {seconds:9.2f} {info.get('sdp_wall_seconds', 0):8.2f} "
              f"{refinement.get('seconds', 0.0):11.2f} {refinement.get('iterations', 0):5d} {second:9.2f} "
              f"{'kept' if chosen else 'not kept':>9} | {info.get('method', '?'):>14} | "
              f"{error:15.2e}", flush=True)


def _cpu_seconds() -> float:
    """CPU seconds of this process and of its ended children (the second start may run in a forked process)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def evaluation_costs(data: list[np.ndarray], u: np.ndarray, y: np.ndarray, orders: list[int]) -> None:
    """CPU time of one objective + gradient evaluation of the refinement, both ways (``--evaluation``)."""
    from fmu_opinf._output_gradient import dense_output_gradient, modal_output_gradient
    from fmu_opinf._threads import single_threaded
    from fmu_opinf.inference import fit_outputs, newmark_step_map

    print(f"{'r':>3} | {'dense [ms]':>10} {'modal [ms]':>10} {'speed-up':>8} | {'gradient rel diff':>17}")
    for r in orders:
        sub = [a[:r] for a in data]
        fit = fit_operators(*sub, u, refine=False, solver="factored" if r > 60 else "auto")  # as the default fit
        A, B = newmark_step_map(fit.Mr, fit.Dr, fit.Kr, fit.Br, DT)
        C = np.hstack(fit_outputs(sub[1], sub[2], y))
        runs = [(np.concatenate([sub[2][:, 0], sub[1][:, 0]]), u, y)]
        with single_threaded():
            seconds = {way: _best_cpu_seconds(lambda f=f: f(A, B, C, runs))
                       for way, f in (("dense", dense_output_gradient), ("modal", modal_output_gradient))}
            dense, modal = dense_output_gradient(A, B, C, runs), modal_output_gradient(A, B, C, runs)
        if modal is None:
            print(f"{r:3d} | {1e3 * seconds['dense']:10.2f} {'declined':>10}")
            continue
        diff = max(np.linalg.norm(a - b) / np.linalg.norm(a) for a, b in zip(dense[1:], modal[1:]))
        print(f"{r:3d} | {1e3 * seconds['dense']:10.2f} {1e3 * seconds['modal']:10.2f} "
              f"{seconds['dense'] / seconds['modal']:8.1f} | {diff:17.1e}", flush=True)


def _best_cpu_seconds(call, rounds: int = 5, repeat: int = 5) -> float:
    call()
    best = float("inf")
    for _ in range(rounds):
        start = time.process_time()
        for _ in range(repeat):
            call()
        best = min(best, (time.process_time() - start) / repeat)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", default="5,10,20,35,50", help="comma-separated reduced orders")
    parser.add_argument("--normalizations", default="trace,mass-eigenvalue,auto")
    parser.add_argument("--clarabel-max-r", type=int, default=50, help="skip Clarabel above this r")
    parser.add_argument("--total", action="store_true", help="time the whole default fit (SDP + refinement)")
    parser.add_argument("--evaluation", action="store_true",
                        help="time one objective + gradient evaluation of the refinement, dense and modal")
    args = parser.parse_args()
    orders = [int(v) for v in args.orders.split(",")]
    V, data, u, y = reduced_data(max(orders))
    if args.evaluation:
        print(f"triple chain n={V.shape[0]}, k={u.shape[1]} snapshots; one refinement evaluation, CPU ms")
        evaluation_costs(data, u, y, orders)
        return
    if args.total:
        print(f"triple chain n={V.shape[0]}, k={u.shape[1]} snapshots, m={u.shape[0]}; default fit, wall and CPU seconds")
        total_fit(data, u, y, V, orders)
        return
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
