"""The order search of :func:`fmu_opinf.fit.fit_rom`: where the fit at the energy's order (eq. 18) misses its own
training outputs, refits at doubled orders and keeps the first that reproduces them, or a larger one while the
miss still falls steeply (:func:`_grow_order`), with the screen that ends the refinement of an order that still
misses grossly, the noise floor above which no order is tried, and the search's stage line."""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from .. import _threads
from .._sdp_paths import FACTORED_ABOVE
from .._validate import either
from ._training_errors import TRAINING_MISS, _in_run, _training_miss, _training_objective, output_name

if TYPE_CHECKING:   # (annotations only: _order_fit imports this module's screen)
    from ._order_fit import _OrderFit


#: Largest order the order search of :func:`fit_rom` tries (with the snapshot rank): up to it the SDP is solved by
#: the certified interior-point method; above it by the factored start, and each fit takes minutes.
ORDER_SEARCH_LIMIT = FACTORED_ABOVE


def _search_orders(start: int, rank: int) -> list[int]:
    """The orders the search tries after ``start``: doubling, up to ``min(rank, ORDER_SEARCH_LIMIT)`` (tried last
    where doubling passes it)."""
    limit, orders, order = min(rank, ORDER_SEARCH_LIMIT), [], start
    while order < limit:
        order = min(2 * order, limit)
        orders.append(order)
    return orders


def _grow_order(first: _OrderFit, fit_at: Callable[[int], _OrderFit], judge_unrefined: bool,
                say: Callable[[str], None],
                refit: Callable[[int], _OrderFit] | None = None,
                names: Sequence[str] | None = ()) -> tuple[_OrderFit, list[dict]]:
    """The order search: where the fit at the energy order (eq. 18) misses its own training outputs (the
    criterion of :func:`_warn_if_training_outputs_missed`) and the snapshots hold more modes, refit at the orders
    of :func:`_search_orders` and keep the first that reproduces them, else the one with the smallest training
    output error.  An order that reproduces them whose miss is still above :data:`CONVERGED` and fell
    :data:`STILL_FALLING`-fold from the order before does not end the search: the next order is tried and kept
    where it lowers the miss :data:`ORDER_HELPS`-fold again (one more fit; a larger order that misses ends it).
    Judged by :func:`_training_miss`: the mean over the outputs, or the worst output in its worst run, relative to
    that run's own variation, where that is larger (the line names that output and run).  The search goes on while
    each order lowers that error :data:`ORDER_HELPS`-fold, and whatever it gained while it stays above
    :data:`GROSS_MISS`.

    ``fit_at(order)`` fits an order the search may discard: its refinement ends early where the model still
    misses grossly (:func:`_screen`; ``first`` too, where the search can follow it).  Such an order is judged by
    its screened fit, which cannot pass, and is refitted in full by ``refit(order)`` (the same fit as without
    the screen; default ``fit_at``) before the search keeps it or lets its figure decide what the screen may have
    changed: where the next order's miss is not gross (:data:`ORDER_HELPS` decides on this order's figure) unless
    the next one helps enough whatever the full figure (:func:`_helps_surely`), and where no order reproduces the
    outputs.  That a screened order would not have reproduced the outputs in full is taken from
    :data:`SCREEN_CHECKPOINTS` (the figures there).

    The energy measures how much of the snapshots' norm the basis spans, not which modes the outputs need: a
    fixed-free bar of 300 nodes driven by a 10 ms pulse kept r = 2 of a rank of 28 and its ROM missed its own
    training outputs by 5 % RMS, while r = 8 was 1e-3 off (audit 62).

    Returns
    -------
    fit : _OrderFit
        The fit kept (``first`` where no search ran).
    search : list of dict
        One entry per order tried, ``{"r", "training_output_error", "worst_output_error", "judged", "seconds",
        "worst_output", "worst_run", "worst_run_name", "n_runs"}``
        (the refinement's objective, None where it could not be simulated; the worst output's relative squared
        error in its worst run; the larger of the two, which the search judges; :func:`fmu_opinf.inference.
        fit_operators`' time; that output and run, 0-based, the run's name, and the number of runs); empty where no
        search ran.
    """
    objective = _training_miss(first.info, judge_unrefined)
    orders = _search_orders(first.pod.r_, first.pod.rank_)
    if objective is None or objective <= TRAINING_MISS or not orders:
        return _judged_in_full((first, objective), refit or fit_at, judge_unrefined)[0], []
    floor = _noise_floor(first.pod.svdvals_, first.pod.rank_, first.info.get("n"), first.info.get("k"))
    judge = functools.partial(_judged_in_full, refit=refit or fit_at, judge_unrefined=judge_unrefined)
    tried = [(first, objective)]
    for order in orders:
        if floor is not None and tried[-1][0].pod.r_ >= floor - 1:
            break   # the modes beyond lie on the noise floor: a larger fit follows the noise (and costs the most)
        fit = fit_at(order)
        objective = _training_miss(fit.info, judge_unrefined)
        tried.append((fit, objective))
        if _reproduces(objective) and not _still_falling(tried[-2][1], objective):
            break
        if _reproduces(tried[-2][1]) and not _reproduces(objective):
            break   # past an order that reproduces them (STILL_FALLING), a larger one that does not: no more
        if objective is not None and objective <= GROSS_MISS and not _helps_surely(tried[-2], objective):
            tried[-2] = judge(tried[-2])   # the previous order's figure decides (ORDER_HELPS): the full one
        if not (_order_helps(tried[-2][1], objective) or _still_gross(tried[-2][1], objective)):
            break   # the miss is not the order's (a nonlinearity, noise, a wrong selection): no larger fits
    if not (tried[-1][1] is not None and tried[-1][1] <= TRAINING_MISS):
        tried = [judge(entry) for entry in tried]   # none reproduces them: the closest is chosen on full fits
    first = tried[0][0]
    # the one that reproduces them (the first, or a larger one that still lowered the error ORDER_HELPS-fold), else
    # the closest where the order helped, else the first
    kept = _reproducing(tried) or min(
        tried, key=lambda entry: entry[1] if entry[1] is not None and entry[1] == entry[1] else math.inf)[0]
    best = _objective_of(tried, kept)
    if not (best is not None and best <= TRAINING_MISS) and not _order_helps(_objective_of(tried, first), best):
        kept = first
    search = [{"r": fit.pod.r_, "training_output_error": _training_objective(fit.info, judge_unrefined),
               "worst_output_error": fit.info.get("worst_output_error"), "judged": objective,
               "worst_output": fit.info.get("worst_output"), "worst_run": fit.info.get("worst_run"),
               "worst_run_name": fit.info.get("worst_run_name"), "n_runs": fit.info.get("n_runs"),
               "seconds": fit.info.get("total_seconds"),
               **({"screened": True, "iterations": fit.info["refinement"].get("iterations")} if _screened(fit) else {})}
              for fit, objective in tried]
    if floor is not None and tried[-1][0].pod.r_ >= floor - 1:
        search[-1]["noise_floor"] = floor
    say(_search_summary(search, kept.pod.r_, names))
    return kept, search


def _reproduces(objective: float | None) -> bool:
    """Whether a training miss (:func:`_training_miss`) reproduces the training outputs (:data:`TRAINING_MISS`)."""
    return objective is not None and objective <= TRAINING_MISS


#: Training miss (squared, as :data:`TRAINING_MISS`: 0.32 % relative RMS) above which an order of the search that
#: reproduces its training outputs is not yet taken for converged where the doubling to it lowered the miss
#: :data:`STILL_FALLING`-fold: the search tries the next order.  Audit base82, F3: a 20-mass chain on a Modelica
#: ``Accelerate`` support (relative outputs) fell 59 -> 11 -> 1.3 % RMS at r = 4, 8, 16; r = 16 passed and was kept,
#: and was 6.3 % of an output's range off the exact model on a 5 rad/s harmonic (2.2 % on a pulse), while r = 21
#: (the rank) was exact.  A miss still falling steeply is the truncation's, and the training's pulse shows only part
#: of it: what the training excites little (the faster modes) is reproduced worse on other inputs.
CONVERGED = 1e-2 * TRAINING_MISS

#: Factor by which the doubling to an order that reproduces its training outputs must have lowered the training
#: miss (squared: the RMS halves) for the search to try the next order while the miss is above :data:`CONVERGED`.
STILL_FALLING = 4.0


def _still_falling(before: float | None, after: float | None) -> bool:
    """Whether an order that reproduces its training outputs with the miss ``after`` (the order before it: ``before``)
    leaves the search going on: the miss is above :data:`CONVERGED` and fell :data:`STILL_FALLING`-fold."""
    return (before is not None and after is not None and after > CONVERGED
            and after * STILL_FALLING <= before)


def _reproducing(tried: list[tuple[Any, float | None]]) -> Any:
    """The fit the search keeps among those that reproduce their training outputs: the first, or a later one that
    lowered the miss of the one kept so far :data:`ORDER_HELPS`-fold (a larger order that gains less is not worth its
    cost); None where none reproduces them."""
    kept = None
    for fit, objective in tried:
        if _reproduces(objective) and (kept is None or _order_helps(kept[1], objective)):
            kept = (fit, objective)
    return kept[0] if kept else None


#: At least this many singular values must lie on the floor for :func:`_noise_floor` to call it one (a few equal
#: singular values are as likely a symmetry of the model).
NOISE_TAIL = 5

#: Factor above the Marchenko-Pastur spread of white noise within which :func:`_noise_floor` takes singular values
#: for noise.
NOISE_MARGIN = 2.0


def _noise_floor(sigma: np.ndarray, rank: int, n: int | None, k: int | None) -> int | None:
    """The (1-based) index of the first singular value of the snapshots that lies on a noise floor, or None.

    White noise of one size on an ``n x k`` snapshot matrix has singular values within ``(sqrt(b) + sqrt(a)) /
    (sqrt(b) - sqrt(a))`` of each other (``a, b`` = the smaller and larger of ``n, k``; Marchenko-Pastur): 1.5
    for 40 positions and 1001 samples.  Those from :data:`NOISE_MARGIN` times that above the smallest down to the
    rank are taken for noise, where at least :data:`NOISE_TAIL` of them are and the matrix is long enough (``b >=
    4 a``, a spread of at most 3).  Audit 65, F3: with 5 % noise on a 40-node bar, eq. (18) kept r = 33 of the
    rank 40, the singular values from the 4th on lay within 1.6-fold of the smallest, and the search's one trial,
    at r = 40, made the fit 47 s instead of 15 s and missed its training outputs by 272 relative RMS (r = 33: 0.11).
    Clean data decay by orders of magnitude to the rank (1e14 on that bar), and get None.
    """
    if not (n and k) or rank < NOISE_TAIL or len(sigma) < rank:
        return None
    small, big = sorted((int(n), int(k)))
    if big < 4 * small:
        return None
    spread = (math.sqrt(big) + math.sqrt(small)) / (math.sqrt(big) - math.sqrt(small))
    values = np.asarray(sigma[:rank], dtype=float)
    if not values[-1] > 0:   # unresolved (streamed POD)
        return None
    on_floor = values <= NOISE_MARGIN * spread * values[-1]
    first = int(np.argmax(on_floor)) + 1
    return first if rank - first + 1 >= NOISE_TAIL and np.all(on_floor[first - 1:]) else None


#: Factor by which a doubled order must lower the training output error (a mean squared relative error: its RMS
#: falls by the square root, 1.4) for the order search to go on, and for a larger order that still misses to be
#: kept: where the miss comes from a nonlinearity, noise or a wrong variable selection, larger orders fit a little
#: better and cost more (up to minutes at r = 60) without following the model.
ORDER_HELPS = 2.0


def _order_helps(before: float | None, after: float | None) -> bool:
    """Whether a larger order lowered the training output error from ``before`` to ``after`` by :data:`ORDER_HELPS`."""
    return before is not None and after is not None and after == after and after * ORDER_HELPS <= before


#: Training output error (the judged relative squared error: 0.32 relative RMS) above which a ROM follows its
#: training outputs so poorly that the order search goes on to the next order whatever this one gained, not only
#: where it gained :data:`ORDER_HELPS`-fold.  Audit 69, F1: a 30-mass chain under a constant load, started neither
#: at rest nor at equilibrium, kept the energy's r = 4 at 0.99 relative RMS because r = 8 reached 0.95 only (the
#: sag to the equilibrium took 99.8 % of the snapshot energy); r = 16 reached 0.29 and the rank, 30, reproduced
#: the outputs.  Judged with the free response from the start values (F2) the errors were 10.4, 3.1 and 3.5 at
#: r = 4, 8, 16 and 0 at r = 30: a gross miss need not fall from one doubling to the next.  Where none
#: reproduces them, the energy's order is kept unless one lowered the error :data:`ORDER_HELPS`-fold.
GROSS_MISS = 0.1


def _still_gross(before: float | None, after: float | None) -> bool:
    """Whether a larger order still misses its training outputs grossly (above :data:`GROSS_MISS`)."""
    return before is not None and after is not None and after == after and after > GROSS_MISS


#: The order search's screen (:func:`_screen`): after each of these numbers of L-BFGS iterations, the training miss
#: (the figure the search judges, :func:`_training_miss`: the worst output's relative squared error, whole runs or
#: free responses) above which the refinement of an order the search may discard ends there.  Issue 16: the search
#: refined every order it tried to the full budget and spent most of a fit on orders it then discarded (a 30-mass
#: chain under a load, started off rest: r = 4, 8, 16 took 24 of the 53 s before r = 30 reproduced the outputs; 5
#: outputs of a 40-mass chain: r = 13 took 6.6 of 17 s).  Judged after 0 / 20 / 40 / 60 / 100 / 300 iterations:
#: the 40-mass chain at r = 13: 0.68 / 0.52 / 0.44 / 0.47 / 0.54 / 0.55; the loaded chain at r = 4: 11.8 / 7.6 / 7.4
#: / 10.9 / 9.7 / 10.4, at r = 8: 8.3 / 8.1 / 7.1 / 6.1 / 4.7 / 3.1, at r = 16: 0.82 / 0.85 / 0.81 / 0.88 / 1.39 /
#: 3.5 (truncation: a gross miss stays one).  But a bar with two rigid links at r = 10 (audit 69's Bars): 0.48 / 0.47
#: / 0.38 / 0.19 / 0.086 / 0.020 (the optimizer: a plateau, then a steep fall), so 0.3 after 40 iterations is no
#: proof; the checkpoints ask for a miss of 100 % RMS after 40 iterations, or 55 % after 100.
SCREEN_CHECKPOINTS = ((40, 1.0), (100, 3 * GROSS_MISS))


def _screen(data: dict[str, np.ndarray], u_fit: np.ndarray,
            refinement: dict[str, Any]) -> tuple[int, Callable[..., bool]] | None:
    """The ``screen`` of :func:`fmu_opinf.inference.fit_operators` for a fit the order search may discard: at each
    of :data:`SCREEN_CHECKPOINTS` the refinement ends where the model's worst training output (whole runs or free
    responses, :func:`fmu_opinf.refinement.output_errors`, as :func:`_output_errors` judges it) misses by more than
    that checkpoint's figure; None where no refinement runs."""
    from ..refinement import output_errors

    if not refinement.get("refine"):
        return None

    limits = dict(SCREEN_CHECKPOINTS)

    def hopeless(iterations: int, Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray) -> bool:
        errors = output_errors(Mr, Dr, Kr, Br, data["xdot"], data["x"], u_fit, refinement["y"], refinement["dt"],
                               output_map=refinement["output_map"], run_lengths=refinement["run_lengths"],
                               integrator=refinement["integrator"])
        judged = np.fmax(errors.whole, errors.free_response)
        judged = judged[~np.isnan(judged)]
        return bool(judged.size and judged.max() > limits[iterations])

    return tuple(limits), hopeless


def _screened(fit: Any) -> bool:
    """Whether the refinement of ``fit`` was ended by the order search's screen (:func:`_screen`)."""
    return (fit.info.get("refinement") or {}).get("status") == "screened out"


def _helps_surely(entry: tuple[Any, float | None], after: float) -> bool:
    """Whether an order missing by ``after`` lowers the figure of a screened order ``entry`` ``(fit, figure)``
    :data:`ORDER_HELPS`-fold whatever the screened order's full figure.  The screen takes a full refinement to
    lower a figure above a checkpoint's limit by less than ``limit / TRAINING_MISS`` (the fall that would make the
    weakest screened order reproduce the outputs), so the full figure is at least ``figure * TRAINING_MISS /
    limit`` (the 100-mass loaded chain at r = 26: 18.7 after 40 iterations, at least 0.019; 87.7 in full)."""
    fit, figure = entry
    limit = dict(SCREEN_CHECKPOINTS).get((fit.info.get("refinement") or {}).get("iterations"))
    return (_screened(fit) and limit is not None and figure is not None
            and figure * TRAINING_MISS / limit >= ORDER_HELPS * after)


def _judged_in_full(entry: tuple[Any, float | None], refit: Callable[[int], Any],
                    judge_unrefined: bool) -> tuple[Any, float | None]:
    """``(fit, judged figure)`` of the order search, with a fit whose refinement the screen ended refitted in
    full (:func:`_screen`); others as they are."""
    fit = entry[0]
    if not _screened(fit):
        return entry
    fit = refit(fit.pod.r_)
    return fit, _training_miss(fit.info, judge_unrefined)


def _objective_of(tried: list[tuple[Any, float | None]], fit: Any) -> float | None:
    """The training output error recorded for ``fit`` among ``tried``."""
    return next(objective for candidate, objective in tried if candidate is fit)


def _search_summary(search: list[dict], kept: int, names: Sequence[str] | None = ()) -> str:
    """The order search's stage line: each order tried with its training outputs' relative RMS error, the worst
    output named by ``names`` (the recorded output names)."""
    def rms(entry: dict) -> str:
        error = entry["judged"]
        return "not simulated" if error is None else f"{math.sqrt(error):.2g}"

    def where(entry: dict, named: bool = False) -> str:
        if entry["judged"] is None or entry.get("worst_output") is None or entry["judged"] != entry.get(
                "worst_output_error"):
            return ""
        run = entry.get("worst_run_name") if named else f"run {entry.get('worst_run')}"
        return f" on {output_name(entry['worst_output'], names)}{_in_run(run, entry.get('n_runs'))}"

    def screened(entry: dict) -> str:
        return f" after {entry['iterations']} refinement iterations" if entry.get("screened") else ""

    first, rest = search[0], search[1:]
    found = any(entry["r"] == kept and entry["judged"] is not None and entry["judged"] <= TRAINING_MISS
                for entry in search)
    return (f"order search: r={first['r']} from eq. (18) misses its training outputs ({rms(first)} relative RMS"
            f"{where(first, True)}{screened(first)})" + ("; " if rest else "")
            + ", ".join(f"r={entry['r']}: {rms(entry)}{where(entry)}{screened(entry)}"
                        + (", kept" if entry["r"] == kept and found else "") for entry in rest)
            + ("" if found else f"; none reproduces them within {math.sqrt(TRAINING_MISS):.2g}: kept r={kept}"
                                + (", the closest" if kept != first["r"] else _why_not_larger(search[-1]))))


def _why_not_larger(last: dict) -> str:
    """The end of the search's stage line where the first order was kept: why no larger order was."""
    floor = last.get("noise_floor")
    if floor is None:
        return f", larger orders lowered the error less than {ORDER_HELPS:g}-fold (squared)"
    return (f"; the singular values from s_{floor} on lie on a noise floor, so no order above r={last['r']} was "
            f"tried (it would fit the noise); with noisy snapshots a smaller order, about "
            f"{either('--r', value=max(floor - 1, 1))}, "
            "may follow other inputs better")


#: Singular value of the row-scaled reduced positions and inputs ``[x; u]`` (each row scaled to unit norm), relative
#: to the largest, below which a reduced coordinate counts as fixed by the others and the inputs at every sample
#: (:func:`quasi_static_coordinates`).  Measured on audit86 F2's model (a 1e-4 kg mass on a 1e4 N/m spring, the
#: force acting on it, sampled at dt = 0.1 s): 2.7e-12 of 1.41, the next singular value 1.0; exact data of models
#: whose coordinates all move dynamically have none below.
QUASI_STATIC_GAP = 1e-6


def _small_singular_values(rows: np.ndarray) -> int:
    """How many singular values of ``rows`` (each row scaled to unit norm, zero rows left out) lie below
    :data:`QUASI_STATIC_GAP` of the largest; from the triangle of a QR factorization of the samples, whose size
    is the number of rows."""
    norms = np.linalg.norm(rows, axis=1)
    scaled = rows[norms > 0] / norms[norms > 0, None]
    if scaled.shape[0] == 0:
        return 0
    with _threads.single_threaded():
        sigma = np.linalg.svd(np.linalg.qr(scaled.T, mode="r"), compute_uv=False)
    return int(np.sum(sigma < QUASI_STATIC_GAP * sigma[0]))


def quasi_static_coordinates(data: dict[str, np.ndarray]) -> int:
    """How many reduced coordinates the reduced training data ``data`` (``x (r, k)``, ``u (m, k)``) show fixed by
    the other coordinates and the inputs at every sample: a DOF much faster than the sampling, which the samples
    see only in its static balance with the input.  Its mass and damping are then not in the data, and the SDP
    (eq. 16) fits them from round-off (audit86 F2: 0.81 relative RMS off its own training outputs at r = 3, the
    snapshot rank); statically condensed (one coordinate fewer, the input's direct share of the outputs as the
    feedthrough ``Dur``), the fit reproduced them to 2.8e-5.  Counted as the small singular values of the
    row-scaled ``[x; u]`` (:data:`QUASI_STATIC_GAP`) beyond those of ``x`` alone: a dependency that involves an
    input."""
    x, u = np.asarray(data["x"], dtype=float), np.asarray(data["u"], dtype=float)
    if u.shape[0] == 0 or x.shape[0] == 0:
        return 0
    return max(0, _small_singular_values(np.vstack([x, u])) - _small_singular_values(x))


def _condensed(fit: _OrderFit, refit: Callable[[int], _OrderFit] | None, judge_unrefined: bool,
               say: Callable[[str], None]) -> _OrderFit:
    """Where ``fit`` at the snapshot rank misses its training outputs grossly (:data:`GROSS_MISS`) and its data
    show coordinates fixed statically by the others and the inputs (:func:`quasi_static_coordinates`), the record
    ``fit.info["quasi_static"]`` for the warning, and with ``refit`` (fits at a given order with the feedthrough
    ``Dur``) one fit with those coordinates fewer, kept where it misses its training outputs less, said in one line
    (audit86 F2: 0.81 relative RMS at r = 3, 2.8e-5 at r = 2 with ``Dur``).  A fit that is fine is not touched."""
    miss = _training_miss(fit.info, judge_unrefined)
    if miss is None or not miss > GROSS_MISS or fit.pod.r_ < fit.pod.rank_:
        return fit
    count = quasi_static_coordinates(fit.data)
    if not 0 < count < fit.pod.r_:
        return fit
    record: dict[str, Any] = {"coordinates": count, "r": fit.pod.r_ - count,
                              "terms": [name for name, chosen in fit.chosen.items() if chosen]}
    fit.info["quasi_static"] = record
    if refit is None:
        return fit
    other = refit(fit.pod.r_ - count)
    other_miss = _training_miss(other.info, judge_unrefined)
    record["miss"] = other_miss
    better = other_miss is not None and other_miss < miss
    say(f"{count} reduced coordinate(s) fixed statically by the others and the inputs at every sample (a DOF faster "
        f"than the sampling): refitted at r={fit.pod.r_ - count} with the feedthrough Dur, worst relative RMS "
        f"{math.sqrt(other_miss) if other_miss is not None else float('nan'):.2g} against {math.sqrt(miss):.2g} at "
        f"r={fit.pod.r_}; kept r={fit.pod.r_ - count if better else fit.pod.r_}")
    if not better:
        return fit
    other.info["quasi_static"] = {**record, "kept": True, "replaced": {"r": fit.pod.r_, "miss": miss}}
    return other
