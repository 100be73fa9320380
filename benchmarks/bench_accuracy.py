"""Accuracy of the operator-inference fit against intrusive POD-Galerkin and unconstrained least squares (issue 14).

For each benchmark and reduced order the same velocity/position POD basis of the impulse training run is used by

* ``galerkin``: intrusive POD-Galerkin, ``V^T M V, V^T D V, V^T K V, V^T B`` and the exact output map ``Cp V``;
* ``lstsq``: unconstrained least squares, ``Mr = I`` and free ``Dr, Kr, Br`` (not structured, may be unstable);
* ``fit``: :func:`fmu_opinf.inference.fit_operators` (default settings, or ``--method``), ``Mr, Dr, Kr`` SPD: the
  refined SDP, or the mechanical realization of least squares where that halves the training output error
  (``path`` says ``lstsq-realized``; ``--method no-candidate`` keeps the refined SDP everywhere);

the non-intrusive fits take their output map from :func:`fmu_opinf.inference.fit_output_map` (eq. 17).  Each ROM
is simulated with the classical Newmark scheme on the training grid and compared with the full model on the test
inputs (two harmonics, a step and a chirp); the figure is the max over time and tests of eq. (19).  ``ratio`` is
``fit / min(galerkin, lstsq if stable)``: the goal of issue 14 is ``ratio <= 2`` with a stable fit.  ``pole gap`` is
the largest relative distance of a learned pole to the full model's spectrum (:func:`~fmu_opinf.inference.pole_match`):
how far the learned ``Mr, Dr, Kr`` are from carrying physical modes.

``--method refit-map`` lets the refinement re-fit the output map to the ROM's own trajectory (variable projection,
``fit_operators(refit_output_map=True)``); ``--method lm-polish`` adds the Levenberg-Marquardt polish of the
refinement (40 iterations, small orders only); ``--method equation`` refines ``log J + 0.1 log E`` with the
equation residual ``E`` (``fit_operators(equation_weight=0.1)``);
``--data exact`` samples the full model's exact solution under the held input (matrix exponential, what a
model-exchange recording of a continuous-time FMU gives) instead of its Newmark solution; every ROM is then
simulated with the exact hold step (``integrator="exact"``, no refinement: the SDP alone, or the least-squares
candidate).  The anchored chain's exact data take a few minutes to compute (1198 states).
``--floor`` prints the round-off floor of eq. (19): the full model against itself with ``M, D, K, B`` scaled by 3
(the same trajectory in exact arithmetic), about 1e-30 on both benchmarks.

Run:  ``python benchmarks/bench_accuracy.py [--case triple|anchored|both] [--orders 5,10] [--method default]
[--data newmark|exact] [--refine-iterations N]
[--solver auto|ipm|clarabel|factored]``
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from fmu_opinf import inference, newmark, systems
from fmu_opinf.basis import PODBasis
from fmu_opinf.compare import output_error
from fmu_opinf.inference import (compressed_factor, fit_operators, fit_output_map, model_poles, pole_match,
                                  refine_output_error)
from fmu_opinf.rom import SecondOrderROM

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TESTS = ("harmonic:amplitude=1,omega=0.2", "harmonic:amplitude=1,omega=1.0", "step:amplitude=1,t0=1",
         "chirp:amplitude=1,omega0=0.01,omega1=1.5,duration=300")


@dataclass(frozen=True)
class Case:
    """A benchmark: system factory, time step, training and test end times, POD snapshot kind, orders."""

    factory: str
    dt: float
    t_train: float
    t_test: float
    kind: str
    orders: tuple[int, ...]


CASES = {
    # anchored chain: periods 20-44 s, dt = 0.1 resolves the 0.5 s pulse, the slowest decay fades by 400 s
    "anchored": Case("anchored_msd", 0.1, 400.0, 400.0, "positions", tuple(range(2, 13))),
    # triple chain: frequencies up to 6.3 rad/s, dt = 0.05 gives 20 samples per shortest period
    "triple": Case("triple_chain", 0.05, 300.0, 400.0, "velocities", tuple(range(5, 61, 5))),
}


@lru_cache(maxsize=None)
def system(name: str) -> systems.SecondOrderSystem:
    return getattr(systems, CASES[name].factory)()


#: How the full model is sampled: "newmark" (its Newmark solution, the paper's) or "exact" (``--data exact``).
DATA = {"kind": "newmark"}


def _integrator() -> str:
    return "exact" if DATA["kind"] == "exact" else "newmark"


def _simulate_full(name: str, spec: str, t_end: float):
    """The full model's response: Newmark, or the exact solution under the held input (``--data exact``)."""
    case = CASES[name]
    if DATA["kind"] == "newmark":
        return newmark.simulate(system(name), spec, case.dt, t_end)
    from types import SimpleNamespace

    from fmu_opinf import lti_fmus
    from fmu_opinf.newmark import applied_inputs, time_grid
    from fmu_opinf.signals import parse_signal

    sysm = system(name)
    dense = {key: np.asarray(getattr(sysm, key).toarray()) for key in ("M", "D", "K", "B", "Cp", "Cv", "G")}
    model = lti_fmus.LinearMechanicalModel(**dense, constraint=sysm.constraint, name=name)
    t = time_grid(case.dt, t_end)
    signal = parse_signal(spec, 1)
    exact = lti_fmus.zoh_response(model, t, signal.sample(t))
    return SimpleNamespace(t=t, u=applied_inputs(signal, t), x=exact.x, xdot=exact.v, xddot=exact.a, y=exact.y)


@lru_cache(maxsize=None)
def training(name: str):
    return _simulate_full(name, TRAIN, CASES[name].t_train)


@lru_cache(maxsize=None)
def references(name: str) -> tuple[np.ndarray, ...]:
    return tuple(_simulate_full(name, spec, CASES[name].t_test).y for spec in TESTS)


@lru_cache(maxsize=None)
def full_basis(name: str) -> np.ndarray:
    order = max(max(CASES[name].orders), DATA.get("max_order", 0))  # --orders may go beyond the case's range
    return PODBasis(r=order, kind=CASES[name].kind).fit([training(name)]).basis_


@lru_cache(maxsize=None)
def full_poles(name: str) -> np.ndarray:
    """Spectrum of the full model on its hidden manifold (the constraint eliminated by a kernel basis)."""
    ode, _ = system(name).hidden_manifold_ode()
    return model_poles(*(A.toarray() for A in (ode.M, ode.D, ode.K)))


def pole_gap(name: str, rom: SecondOrderROM) -> float:
    """Largest relative distance of a learned pole to the full model's spectrum (:func:`pole_match`)."""
    return float(pole_match(model_poles(rom.Mr, rom.Dr, rom.Kr), full_poles(name)).max())


def reduced_data(name: str, r: int) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    """Basis of order ``r`` and the projected training data ``[xddot_r, xdot_r, x_r]``, ``u``, ``y``."""
    V = full_basis(name)[:, :r]
    run = training(name)
    return V, [V.T @ a for a in (run.xddot, run.xdot, run.x)], run.u, run.y


def max_error(name: str, rom: SecondOrderROM) -> float:
    """Max over time and test inputs of eq. (19)."""
    case = CASES[name]
    errors = [output_error(ref, rom.simulate(spec, case.dt, case.t_test).y).max()
              for spec, ref in zip(TESTS, references(name))]
    return float(max(errors))


def galerkin_rom(name: str, r: int) -> SecondOrderROM:
    V = full_basis(name)[:, :r]
    sysm = system(name)
    mats = [V.T @ (A @ V) for A in (sysm.M, sysm.D, sysm.K)]
    return SecondOrderROM(*(0.5 * (A + A.T) for A in mats), V.T @ sysm.B.toarray(), np.asarray(sysm.Cp @ V),
                          np.asarray(sysm.Cv @ V), integrator=_integrator())


def _with_outputs(name: str, r: int, Mr, Dr, Kr, Br, info=None) -> SecondOrderROM:
    _, (_, xdot, x), u, y = reduced_data(name, r)
    Cpr, Cvr, _, _ = fit_output_map(xdot, x, y)
    return SecondOrderROM(Mr, Dr, Kr, Br, Cpr, Cvr, fit_info=info, integrator=_integrator())


def lstsq_rom(name: str, r: int) -> SecondOrderROM:
    """``Mr = I``; ``xddot = -Dr xdot - Kr x + Br u`` by least squares (block-scaled columns)."""
    _, (xddot, xdot, x), u, _ = reduced_data(name, r)
    blocks = [xdot, x, u]
    scales = [float(np.sqrt(np.mean(b * b))) or 1.0 for b in blocks]
    A = np.vstack([b / s for b, s in zip(blocks, scales)]).T
    coef = np.linalg.lstsq(A, xddot.T, rcond=None)[0].T
    Dr, Kr, Br = -coef[:, :r] / scales[0], -coef[:, r:2 * r] / scales[1], coef[:, 2 * r:] / scales[2]
    return _with_outputs(name, r, np.eye(r), Dr, Kr, Br)


def fit_rom_default(name: str, r: int, **options) -> SecondOrderROM:
    _, data, u, y = reduced_data(name, r)
    ops = fit_operators(*data, u, y=y, **options)
    if ops.output_map is not None:  # the refinement's or the realization's map replaces eq. 17
        return SecondOrderROM(ops.Mr, ops.Dr, ops.Kr, ops.Br, *ops.output_map, fit_info=ops.info,
                              integrator=_integrator())
    return _with_outputs(name, r, ops.Mr, ops.Dr, ops.Kr, ops.Br, ops.info)


def fit_rom_polished(name: str, r: int, polish: int = 40) -> SecondOrderROM:
    """SDP start, then the refinement with its default budget and ``polish`` Levenberg-Marquardt iterations."""
    _, (xddot, xdot, x), u, y = reduced_data(name, r)
    ops = fit_operators(xddot, xdot, x, u, refine=False)
    _, scales = compressed_factor(xddot, xdot, x, u)
    *mats, report = refine_output_error(ops.Mr, ops.Dr, ops.Kr, ops.Br, xdot, x, u, y, CASES[name].dt,
                                        max_iterations=300 if r <= 40 else 20 * r, polish_iterations=polish,
                                        unit_scales=[scales[key] for key in ("xddot", "xdot", "x", "u")])
    info = dict(ops.info, refinement=report, method=ops.info.get("method"))
    return _with_outputs(name, r, *mats, info)


def roundoff_floor(name: str) -> float:
    """Max eq. (19) of the full model against itself with ``M, D, K, B`` scaled by 3: round-off alone."""
    case, sysm = CASES[name], system(name)
    scaled = dataclasses.replace(sysm, M=sysm.M * 3.0, D=sysm.D * 3.0, K=sysm.K * 3.0, B=sysm.B * 3.0)
    return float(max(output_error(ref, newmark.simulate(scaled, spec, case.dt, case.t_test).y).max()
                     for spec, ref in zip(TESTS, references(name))))


def fit_options(name: str, method: str) -> dict:
    """Keyword arguments of ``fit_operators`` for a named variant (the outputs ``y`` are always passed)."""
    if DATA["kind"] == "exact" and method in ("default", "no-candidate"):
        return {"dt": CASES[name].dt, "integrator": "exact", "least_squares_candidate": method == "default"}
    if method == "default":
        return {"dt": CASES[name].dt}
    if method == "sdp-paper":
        return {"normalization": "trace", "refine": False}
    if method == "equation-error":
        return {"refine": False}
    if method == "lm-polish":
        return {}
    if method == "refit-map":
        return {"dt": CASES[name].dt, "refit_output_map": True}
    if method == "no-candidate":
        return {"dt": CASES[name].dt, "least_squares_candidate": False}
    if method == "equation":
        return {"dt": CASES[name].dt, "equation_weight": 0.1}
    raise ValueError(f"unknown method {method!r}")


def row(name: str, r: int, method: str = "default") -> dict:
    """All figures of one (case, r): errors of the three ROMs, stability, fit time and path."""
    gal = max_error(name, galerkin_rom(name, r))
    ls_rom = lstsq_rom(name, r)
    ls_stable = ls_rom.is_stable()
    ls = max_error(name, ls_rom) if ls_stable else float("nan")
    start = time.perf_counter()
    options = fit_options(name, method)
    if DATA.get("refine_iterations") is not None and "dt" in options:
        options["refine_iterations"] = DATA["refine_iterations"]
    if DATA.get("solver") is not None:
        options["solver"] = DATA["solver"]
    rom = fit_rom_polished(name, r) if method == "lm-polish" else fit_rom_default(name, r, **options)
    seconds = time.perf_counter() - start
    fit = max_error(name, rom)
    best = min(gal, ls) if ls_stable else gal
    return {"case": name, "r": r, "galerkin": gal, "lstsq": ls, "lstsq_stable": ls_stable, "fit": fit,
            "ratio": fit / best, "fit_stable": rom.is_stable(), "seconds": seconds, "pole_gap": pole_gap(name, rom),
            "path": _path(rom.fit_info)}


def _path(info: dict) -> str:
    """SDP path / refinement status, and ``lstsq-realized`` where the least-squares candidate was kept."""
    if (info.get("least_squares_candidate") or {}).get("chosen"):
        return "lstsq-realized"
    refinement = info.get("refinement", {})
    return f"{info.get('method')}/{refinement.get('status', '-')} {refinement.get('iterations', '')}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="both", choices=["both", *CASES])
    parser.add_argument("--orders", default=None, help="comma-separated orders (default: the case's range)")
    parser.add_argument("--method", default="default",
                        help="default (SDP + output-error refinement), sdp-paper (eq. 16, trace normalization) or "
                             "equation-error (the SDP without refinement), lm-polish (default + Levenberg-Marquardt), "
                             "refit-map (default with the output map re-fitted by the refinement), equation (default "
                             "with the equation-residual term, equation_weight=0.1)")
    parser.add_argument("--data", default="newmark", choices=["newmark", "exact"],
                        help="sample the full model by Newmark (default) or exactly under the held input")
    parser.add_argument("--floor", action="store_true", help="print the round-off floor of eq. (19) and exit")
    parser.add_argument("--refine-iterations", type=int, default=None,
                        help="L-BFGS budget of each refinement start (default: fit_operators' own)")
    parser.add_argument("--stall-rtol", type=float, default=None,
                        help="the refinement's stall stop (inference.STALL_RTOL; 0: the whole iteration budget)")
    parser.add_argument("--solver", default=None, choices=["auto", "ipm", "clarabel", "factored"],
                        help="SDP solver of the fit (default: fit_operators' own; 'ipm' certifies above r = 60 too)")
    args = parser.parse_args()
    DATA["kind"] = args.data
    DATA["refine_iterations"] = args.refine_iterations
    DATA["solver"] = args.solver
    if args.stall_rtol is not None:
        inference.STALL_RTOL = args.stall_rtol
    names = list(CASES) if args.case == "both" else [args.case]
    if args.floor:
        for name in names:
            print(f"{name}: round-off floor of max eps_y = {roundoff_floor(name):.1e}")
        return
    header = (f"{'case':>8} {'r':>3} | {'galerkin':>9} {'lstsq':>9} {'ls stable':>9} | {'fit':>9} {'stable':>6} "
              f"| {'ratio':>7} | {'pole gap':>8} | {'fit [s]':>7} {'path':>26}")
    print(f"max eps_y (eq. 19) over {', '.join(TESTS)}; impulse training; fit = {args.method}; data = {args.data}")
    print(header)
    print("-" * len(header))
    for name in names:
        orders = CASES[name].orders if args.orders is None else [int(v) for v in args.orders.split(",")]
        DATA["max_order"] = max(orders)
        for r in orders:
            f = row(name, r, args.method)
            print(f"{name:>8} {r:3d} | {f['galerkin']:9.2e} {f['lstsq']:9.2e} {str(f['lstsq_stable']):>9} | "
                  f"{f['fit']:9.2e} {str(f['fit_stable']):>6} | {f['ratio']:7.2f} | {f['pole_gap']:8.1e} | "
                  f"{f['seconds']:7.2f} "
                  f"{f['path']:>26}", flush=True)


if __name__ == "__main__":
    main()
