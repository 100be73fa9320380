"""One fit at one order (:func:`_fit_order`): projection (eq. 14), extra terms, SDP (eq. 16), output map
(eq. 17), the output-error refinement and its keywords, the interval-average corrections and the stage lines; the
outputs not linear in the states are left out of what steers the dynamics (package docstring)."""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, Callable

import numpy as np

from .. import _threads
from .._linear_outputs import nonlinear_outputs
from .._validate import either
from ..basis import PODBasis, column_blocks, read_columns
from ..errors import FmuOpinfWarning, InputSpecError
from ..inference import fit_operators, fit_output_map
from ..rom import TERMS
from ._order_search import _screen
from ._run_balance import run_weights, weighted_columns
from ._terms import _choose_terms
from ._time_integrator import _derived_accelerations, _integrator
from ._training_data import (_averaged, _corrected_averages, _held_outputs, _names, _net_outputs, _reduced_data,
                             _run_length, _training_dt)
from ._training_errors import _output_errors, _peak_misses, _run_names, _training_output_error


@dataclasses.dataclass(frozen=True)
class _FitOptions:
    """The settings of :func:`fit_rom` that each single-order fit (:func:`_fit_order`) uses alike."""

    requested: dict[str, bool | None]
    lowpass: float | None
    method: str
    mass_trace: float | None
    tol: float
    normalization: str
    solver: str
    integrator: str
    refine: bool | str
    refine_iterations: int | None
    refit_output_map: bool
    least_squares_candidate: bool
    output_weighting: str
    progress: bool
    refine_integrator: str | None = None   # the step the refinement simulates, where not the ROM's own


@dataclasses.dataclass
class _OrderFit:
    """One fit at one order: its POD basis, reduced data, operators (:func:`fmu_opinf.inference.fit_operators`),
    extra terms, output map ``(Cpr, Cvr, Dur, y0)``, time integrator and fit_info."""

    pod: PODBasis
    data: dict[str, np.ndarray]
    ops: Any
    chosen: dict[str, bool]
    term_info: dict
    maps: tuple
    integrator: str
    info: dict
    linearity: dict = dataclasses.field(default_factory=dict)


def _fit_order(pod: PODBasis, centred_runs: list, runs: list, attrs: dict, options: _FitOptions,
               say: Callable[[str], None], decided: _OrderFit | None = None, screen: bool = False) -> _OrderFit:
    """The fit at the order of ``pod``: projection (eq. 14), extra terms, SDP (eq. 16), output map (eq. 17) and
    the refinement, with their stage lines; no warnings (:func:`fit_rom` judges the fit it keeps).

    ``decided``: an earlier fit on the same decomposition whose extra terms are kept where its wide basis (on
    which they are decided) is this one's too, rather than projecting the data on it again.  ``screen``: a fit
    the order search may discard: its refinement ends at one of :data:`SCREEN_CHECKPOINTS` where the model still
    misses its training outputs grossly (:func:`_screen`).
    """
    o = options
    euler_rates = o.refine_integrator == "forward-euler" and _derived_accelerations(attrs) is True
    data = _reduced_data(centred_runs, pod, o.lowpass, euler_rates=euler_rates)
    if decided is not None and decided.pod.wide_basis_.shape[1] == pod.wide_basis_.shape[1]:
        chosen, term_info, linearity = decided.chosen, decided.term_info, decided.linearity
    else:
        decision = data if pod.wide_basis_ is pod.basis_ else _reduced_data(
            centred_runs, pod, o.lowpass, wide=True, outputs=data["y"], euler_rates=euler_rates)
        with _threads.single_threaded():  # least-squares residuals of reduced data: small kernels
            linearity = _linearity(decision, pod, attrs, centred_runs)
            chosen, term_info = _choose_terms(decision, o.requested,
                                              "f_" if euler_rates or any(_averaged(run) for run in runs) else "",
                                              judged=_judged_rows(linearity, data["y"].shape[0]))
    judged = _judged_rows(linearity, data["y"].shape[0])
    sdp = "f_" if "f_x" in data else ""
    u_fit = data[sdp + "u"]
    if chosen["fr"]:
        u_fit = np.vstack([u_fit, np.ones((1, u_fit.shape[1]))])
    extra = [name for name in TERMS if chosen[name]]
    say(f"SDP (eq. 16): {3 * pod.r_ * (pod.r_ + 1) // 2} unknowns in Mr, Dr, Kr from {data['u'].shape[1]} "
        f"snapshots{'; extra terms ' + ', '.join(extra) if extra else ''}; solving ...")
    with _threads.single_threaded():
        Cpr, Cvr, Dur, y0 = fit_output_map(data["xdot"], data["x"], data["y"], data["u"],
                                           feedthrough=chosen["Dur"], offset=chosen["y0"])
        _fit_left_out_fully(data, (Cpr, Cvr, Dur, y0), linearity)
    time_integrator = _integrator(o.integrator, attrs)
    refinement = _refinement(o.refine, o.refine_integrator or time_integrator, o.lowpass, runs, attrs, data,
                             (Cpr, Cvr, Dur, y0))
    steering = _steering(refinement, judged)
    if refinement.get("refine"):
        starts = "the SDP solution" + (" and, where it exists, the mechanical realization of least squares"
                                       if o.least_squares_candidate else "")
        say(f"output-error refinement from {starts} (L-BFGS over PSD factors) ...")
    if o.refit_output_map and not refinement.get("refine"):
        raise _refit_without_refinement()
    screened = _screen(data, u_fit, steering) if screen and not o.refit_output_map else None
    lengths = [_run_length(run) for run in runs]
    weights = run_weights(data["y"], data["u"], (Cpr, Cvr, Dur, y0), lengths, judged)
    balanced = _balanced(steering, weights, lengths)
    sdp_lengths = _sdp_lengths(runs, data, sdp)
    ops = fit_operators(*(weighted_columns(a, weights, sdp_lengths) for a in
                          (data[sdp + "xddot"], data[sdp + "xdot"], data[sdp + "x"], u_fit)),
                        method=o.method, mass_trace=o.mass_trace, tol=o.tol, normalization=o.normalization,
                        solver=o.solver, refit_output_map=o.refit_output_map,
                        least_squares_candidate=o.least_squares_candidate, refine_iterations=o.refine_iterations,
                        progress=o.progress, output_weighting=o.output_weighting, screen=screened, **balanced)
    if ops.output_map is not None:
        ops.output_map = _whole_map(ops, (Cpr, Cvr), judged)
        Cpr, Cvr = ops.output_map
    for count in range(1, 1 + (AVERAGE_CORRECTIONS if "f_h" in data and o.lowpass is None else 0)):
        ops = fit_operators(*(weighted_columns(a, weights, sdp_lengths) for a in
                              (data["f_xddot"], data["f_xdot"], _corrected_averages(ops, u_fit, data), u_fit)),
                            method=o.method, mass_trace=o.mass_trace, tol=o.tol, normalization=o.normalization,
                            solver=o.solver)
        ops.info["interval_average_corrections"] = count
    sampled_u = data["u"] if not chosen["fr"] else np.vstack([data["u"], np.ones((1, data["u"].shape[1]))])
    simulated = refinement if refinement.get("refine") else _refinement(
        "auto", o.refine_integrator or time_integrator, o.lowpass, runs, attrs,
        {key: value for key, value in data.items() if not key.startswith("f_")}, (Cpr, Cvr, Dur, y0), warn=False)
    unchecked = None if refinement.get("refine") else _training_output_error(ops, sampled_u, data,
                                                                               _steering(simulated, judged),
                                                                               o.output_weighting)
    sdp_seconds = ops.info.get("sdp_wall_seconds", ops.info.get("total_seconds", 0))
    say(f"SDP: {ops.info.get('status')} via {ops.info.get('method')} ({ops.info.get('normalization')} "
        f"normalization, {ops.info.get('solver')}) in {sdp_seconds:.2f}s"
        + _refinement_summary(ops.info.get("refinement"), ops.info.get("modal_start"))
        + f"; whole fit {ops.info.get('total_seconds', 0):.2f}s")
    candidate = ops.info.get("least_squares_candidate")
    if candidate:
        say(_candidate_summary(candidate))
    info = dict(ops.info)
    info.update(r=pod.r_, basis_kind=pod.kind_, pod_method=pod.method_, snapshot_rank=pod.rank_,
                energy_r=float(pod.energy_[pod.r_ - 1]), n=int(pod.basis_.shape[0]), k=int(data["u"].shape[1]),
                n_runs=len(runs), lowpass=o.lowpass, terms=term_info,
                output_relative_residual=_output_residual((Cpr, Cvr, Dur, y0), data, ops.coordinates))
    if unchecked is not None:
        info["training_output_error"] = unchecked
    if weights is not None:
        info["run_weights"] = [float(w) for w in weights]
    info.update(_output_errors(ops, sampled_u, data, simulated, (Cpr, Cvr), _run_names(runs), judged))
    info.update(_peak_misses(ops, sampled_u, data, simulated, (Cpr, Cvr), _run_names(runs), judged))
    return _OrderFit(pod, data, ops, chosen, term_info, (Cpr, Cvr, Dur, y0), time_integrator, info, linearity)


def _balanced(steering: dict[str, Any], weights: np.ndarray | None, lengths: list[int]) -> dict[str, Any]:
    """The refinement's keywords (:func:`_steering`) with each run's output target times its weight
    (:mod:`._run_balance`); as they are where there is no refinement or nothing to weigh."""
    if weights is None or not steering.get("refine"):
        return steering
    return dict(steering, y=weighted_columns(steering["y"], weights, lengths))


def _sdp_lengths(runs: list, data: dict[str, np.ndarray], sdp: str) -> list[int]:
    """Columns of each run in the SDP's data: its samples, or one fewer where the run gives interval averages."""
    lengths = [_run_length(run) for run in runs]
    if "f_h" not in data or not sdp:
        return lengths
    return [k - 1 if _averaged(run) and k >= 2 else k for run, k in zip(runs, lengths)]


def _linearity(decision: dict[str, np.ndarray], pod: PODBasis, attrs: dict, centred_runs: list) -> dict:
    """:func:`fmu_opinf._linear_outputs.nonlinear_outputs` on the data the extra terms are decided on, judged
    against the projection error of that basis (none where it reaches the snapshot rank)."""
    order = int(decision["x"].shape[0])
    projection = 0.0 if order >= pod.rank_ else _projection_error(decision, centred_runs)
    p = decision["y"].shape[0]
    names = _names(attrs.get("output_names"), p) or [f"y[{j + 1}]" for j in range(p)]
    return nonlinear_outputs(decision, projection, names, held=_held_outputs(attrs))


def _fit_left_out_fully(data: dict[str, np.ndarray], maps: tuple[np.ndarray, ...], linearity: dict) -> None:
    """Give the outputs left out of the fit's judgement (:func:`_linearity`) the whole linear least squares the
    detection measured them by, from the positions, velocities, inputs and a constant, in place in ``maps``
    (``Cpr, Cvr, Dur, y0``): the extra terms were decided without them, and an energy has an offset that its
    linear fit needs whether the others have one or not."""
    rows = np.asarray(linearity.get("outputs") or [], dtype=int) if linearity.get("left_out") else None
    if rows is None or not rows.size:
        return
    for whole, part in zip(maps, fit_output_map(data["xdot"], data["x"], data["y"][rows], data["u"],
                                                feedthrough=True, offset=True)):
        whole[rows] = part


def _projection_error(reduced: dict[str, np.ndarray], runs: list) -> float:
    """The largest relative projection error of the positions, velocities and accelerations of ``runs`` on the
    orthonormal basis of their ``reduced`` data (``1 - ||V^T X||^2 / ||X||^2``, rooted), one pass over the runs.
    All three count: a linear output of accelerations (or of a stiff part's positions) lies in the high modes,
    whose share of the accelerations can be far above their share of the positions that the POD energy measures."""
    worst = 0.0
    for name in ("x", "xdot", "xddot"):
        full = 0.0
        for i, run in enumerate(runs):
            array = getattr(run, name)
            for part in column_blocks(*array.shape):
                block = read_columns(array, part.start, part.stop, f"{name} of run {i}")
                full += float(np.sum(block * block))
        kept = float(np.sum(reduced[name] ** 2))
        if full > 0:
            worst = max(worst, math.sqrt(max(0.0, 1.0 - kept / full)))
    return worst


def _judged_rows(linearity: dict, p: int) -> np.ndarray:
    """The rows of the outputs that steer the dynamics: all but those :func:`_linearity` leaves out."""
    left_out = set(linearity.get("outputs") or []) if linearity.get("left_out") else set()
    return np.array([j for j in range(p) if j not in left_out], dtype=int)


def _steering(refinement: dict[str, Any], judged: np.ndarray) -> dict[str, Any]:
    """The keywords of :func:`_refinement` restricted to the ``judged`` outputs: what the refinement, the
    least-squares candidate's choice and the order search's screen weigh (audit 77a F1: an output not linear in
    the state, weighed there, bent the dynamics of every output)."""
    if not refinement.get("refine") or judged.size == refinement["y"].shape[0]:
        return refinement
    Cpr, Cvr = refinement["output_map"]
    return dict(refinement, y=refinement["y"][judged], output_map=(Cpr[judged], Cvr[judged]))


def _whole_map(ops: Any, maps: tuple[np.ndarray, np.ndarray], judged: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The output map of every output in the coordinates of ``ops``, where :func:`fmu_opinf.inference.fit_operators`
    returned one of the ``judged`` outputs only (a refitted map, or the least-squares realization's): the others
    keep eq. 17's map ``maps`` of the POD coordinates, taken to the model's (``[q; q'] = W z``: ``C W``)."""
    Cp, Cv = ops.output_map
    if Cp.shape[0] == maps[0].shape[0]:
        return Cp, Cv
    r = Cp.shape[1]
    C = np.hstack(maps)
    if ops.coordinates is not None:
        C = C @ ops.coordinates
    C[judged] = np.hstack([Cp, Cv])
    return C[:, :r], C[:, r:]


#: Refits of a fit from interval averages with the positions' means corrected by the previous fit's model.
AVERAGE_CORRECTIONS = 2


def _refit_without_refinement() -> InputSpecError:
    return InputSpecError(f"{either('--refit-output-map')} needs the output-error refinement: no lowpass, one "
                          "training time step, sampled states, refine not False; drop the option or enable the "
                          "refinement")


def _refinement(refine: bool | str, integrator: str, lowpass: float | None, runs: list, attrs: dict,
                data: dict[str, np.ndarray], maps: tuple, warn: bool = True) -> dict[str, Any]:
    """Keywords of :func:`fmu_opinf.inference.fit_operators` for what compares simulated training outputs: the
    output-error refinement and the least-squares candidate.

    Both need unweighted data (``lowpass`` off) sampled with one training step, and sampled states (interval
    averages are no samples: their runs keep the SDP solution); the output target excludes the fitted
    feedthrough and offset.  The refinement simulates the ROM's own step (Newmark, or the exact hold step of a
    continuous-time source).  ``refine=False`` keeps the SDP solution: neither.  Runs of different steps turn
    both off, and with them the order search and the training-miss check: said in one warning (``warn``) with its
    fix (audit 72, F2: runs of a run table at their own automatic steps gave a ROM 15-51 % of range off its own
    training inputs, without a word).
    """
    if refine not in ("auto", True, False):
        raise InputSpecError(f"refine={refine!r} is not known; use 'auto', True or False")
    dt = _training_dt(runs, attrs)
    steps = {round(float(np.diff(np.asarray(run.t[:2], dtype=float))[0]), 12) for run in runs
             if _run_length(run) > 1}
    lengths = [_run_length(run) for run in runs]
    possible = lowpass is None and dt is not None and len(steps) == 1 and min(lengths) >= 2 and "f_h" not in data
    if refine is True and not possible:
        raise InputSpecError("refine=True needs no lowpass, one training step dt and sampled states (not interval "
                         "averages)")
    if refine is False or not possible:
        if warn and refine == "auto" and len(steps) > 1:
            _warn_different_steps(steps)
        return {}
    Cpr, Cvr, Dur, y0 = maps
    target = data["y"] if not (np.any(Dur) or np.any(y0)) else _net_outputs(data["y"], data["u"], Dur, y0)
    return {"dt": float(dt), "y": target, "output_map": (Cpr, Cvr), "run_lengths": lengths, "refine": True,
            "integrator": integrator}


def _warn_different_steps(steps: set[float]) -> None:
    """Say that runs of different steps (``steps``) leave the SDP solution unchecked, and how to record them.

    The refinement, the least-squares candidate, the order search and the training-miss check all simulate the
    ROM at one step over every run, so they need one; each run at its own step would need a ROM per step.
    """
    listed = ", ".join(f"{step:g}" for step in sorted(steps))
    warnings.warn(f"the training runs have different steps ({listed}): no output-error refinement, least-squares "
                  f"candidate, order search or training-miss check (the ROM is the SDP solution, unchecked); "
                  f"record every run at one step (snapshots {either('--dt')})", FmuOpinfWarning, stacklevel=4)


def _refinement_summary(report: Any, modal_start: Any = None) -> str:
    if not isinstance(report, dict) or "objective" not in report:
        return ""
    start = (" (from the modal normal form of the least-squares fit: modally damped data, fmu_opinf._modal_form)"
             if isinstance(modal_start, dict) and modal_start.get("chosen") else "")
    screened = (" (screened out: the order still misses its training outputs grossly)"
                if report.get("status") == "screened out" else "")
    rejected = report.get("non_finite_trials")
    overflow = (f" ({rejected} trial step(s) made the model overflow and were rejected: kept the best finite point)"
                if rejected else "")
    return (f"; output-error refinement{start}: training output error "
            f"{report.get('objective_start', float('nan')):.2e} -> {report['objective']:.2e} in "
            f"{report.get('iterations', 0)} iterations{screened}{overflow}, {report.get('seconds', 0):.1f}s")


def _candidate_summary(report: dict) -> str:
    if report.get("status") != "realized":
        return f"least-squares candidate: {report.get('status')}; kept the SDP solution"
    refined = "refinement" in report
    if report["chosen"]:
        kept = f"its {'refined ' if refined else ''}mechanical realization (modal coordinates)"
    else:
        kept = "the SDP solution"
    return (f"least-squares candidate{' (refined)' if refined else ''}: training output error "
            f"{report['objective']:.2e} against "
            f"{report['kept_objective']:.2e} for the {'refined ' if report.get('refined') else ''}SDP solution; "
            f"kept {kept}")


def _output_residual(maps: tuple, data: dict[str, np.ndarray], coordinates: np.ndarray | None = None) -> float:
    """Relative residual of the output map on the training data (in their POD coordinates)."""
    Cpr, Cvr, Dur, y0 = maps
    if coordinates is not None:  # the map of the modal coordinates, taken back to the POD ones
        r = Cpr.shape[1]
        C = np.linalg.solve(coordinates.T, np.hstack([Cpr, Cvr]).T).T
        Cpr, Cvr = C[:, :r], C[:, r:]
    y, squares = data["y"], 0.0
    for part in column_blocks(*y.shape):  # in blocks: y may be the largest array of the fit
        resid = Cpr @ data["x"][:, part] + Cvr @ data["xdot"][:, part] + Dur @ data["u"][:, part] + y0[:, None]
        resid -= y[:, part]
        squares += float(np.sum(resid * resid))
    return float(np.sqrt(squares) / (np.linalg.norm(y) or 1.0))
