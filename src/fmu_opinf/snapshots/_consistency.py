"""Checks that recorded velocities are the rates of the positions and accelerations those of the velocities.

Which states of an FMU are positions and which their velocities is read from the model structure where it says
so (derivative aliases, dependencies, units), and otherwise guessed (first-order states split in halves).  A
guess can be wrong (states listed body by body, relative positions with absolute velocities), and a co-simulation
FMU without inputs can return derivatives one step stale.  Either way the recording looks fine and the fitted
model is silently wrong.  The data tell: over a step ``h`` a position moves by ``h`` times its velocity
(trapezoidal rule for an accurate integration; the forward or backward rule for an FMU's explicit Euler steps),
so a mismatch of order one per step, where a right pairing leaves ``(omega h)^2``, shows a wrong pairing, and
accelerations that fit the velocities' increments far better when shifted by one sample are stale, once the FMU's
own value just after a sample confirms it (:func:`confirmed_stale`: where the step leaves modes unresolved, the
increments cannot tell; audit 71 F6).

:func:`check_rates` judges one run's arrays and proposes a repair: positions and velocities paired by the data
(each position's increments matched with the state whose average over the step fits them), or the positions'
derivative variables as velocities (when no other state is their rate) or accelerations derived from the data.
:func:`judge_run` applies it to a recorded run of an FMU source (the recorder then records the run again with the
repair, :func:`fmu_opinf.snapshots._run.record_run`), or turns what cannot be repaired into an error.

The numbers behind the verdicts live beside it: :mod:`._rate_tests` (the mismatch and stale tests, summed while a run
is recorded), :mod:`._pairing` (pairs found by the data where nothing declares them) and :mod:`._integrator_checks`
(a co-simulation that follows its own Euler steps: warned, not repaired).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from .._validate import POSITIONS_VELOCITIES, either, patterns_said
from ..errors import FMUError, FmuOpinfWarning
from ..sources._variables import _DEPENDENCIES, _LOCAL_STEMS, _PATTERN_X
from ._first_order import refuse_first_order_rates
from ._integrator_checks import warn_if_euler_steps, warn_if_internal_steps
from ._isolation import source_label
from ._notes import warn_recording
from ._pairing import (
    MAX_PAIRED,
    combination_misfit,
    not_rates,
    pair_by_data,
    pairing_the_data_show,
    partial_pairing_problem,
    rates_among_positions,
    step_explains,
    strict_bounds,
    strictly_paired,
    weak_rows,
)
from ._rate_tests import (
    MISMATCH,
    RateSums,
    Repair,
    evaluation_sample,
    evaluation_verdict,
    rate_mismatch,
    rate_mismatch_over,
    stale_rates,
)

__all__ = ["MAX_REPAIRS", "STALE_REASON", "check_rates", "confirmed_stale", "judge_run", "live_rate_sums"]

#: The reason of the repair of stale accelerations (:func:`check_rates`).
STALE_REASON = ("the accelerations lag the velocities by one sample (derivatives read before the FMU updated them): "
                "derived from the data instead")
#: Samples used by the checks (the first ones of a run).
_SAMPLES = 4000


def confirmed_stale(repair: Repair, a: np.ndarray, u: np.ndarray, t: np.ndarray,
                    evaluate: Callable[[int], np.ndarray | None]) -> Repair | None:
    """``repair`` (stale accelerations, judged from the data) where a direct evaluation confirms it or cannot tell,
    None where the FMU's value just after a sample is the one recorded there (current derivatives).

    Parameters
    ----------
    a, u : ndarray
        The recorded accelerations of the judged rows and the inputs in effect, over the judged samples.
    t : ndarray
        The run's time grid.
    evaluate : callable
        ``evaluate(i)``: the FMU's accelerations of those rows at the state of sample ``i``, read just after it (None
        where it cannot run so)."""
    i = evaluation_sample(a, u)
    evaluated = evaluate(i) if i is not None else None
    stale = None if evaluated is None else evaluation_verdict(np.asarray(evaluated, dtype=float), a[:, i], a[:, i + 1])
    if stale is False:
        return None
    if stale:
        return Repair(repair.positions, repair.velocities, repair.accelerations,
                      f"{repair.reason} (the FMU's own value just after t={t[i]:g} is the one recorded at the next "
                      "sample)")
    return repair



def check_rates(x: np.ndarray, v: np.ndarray | None, a: np.ndarray | None, h: float, names: dict[str, list[str]],
                guessed: bool, derivative_names: list[str | None],
                u: np.ndarray | None = None, sums: RateSums | None = None, declared: bool = False
                ) -> Repair | str | None:
    """Judge one run's rates; None if consistent, a :class:`Repair` to record again, or a one-line problem.

    Parameters
    ----------
    x, v, a : (n, k) ndarray
        Recorded positions, velocities and accelerations (None where derived from the data).
    h : float
        Sample step.
    names : dict
        ``"positions"`` and ``"velocities"``: the recorded variables' names.
    guessed : bool
        Whether the pairing was guessed (split in halves, dependencies, units) rather than given or linked.
    derivative_names : list
        Per position, the name of its derivative variable (None where the model has none).
    u : (m, k) ndarray, optional
        Inputs in effect (steps next to their changes do not count in :func:`stale_rates`).
    sums : RateSums, optional
        The sums of both tests, fed while the run was recorded (:func:`live_rate_sums`); default: summed here.
    declared : bool, default=False
        Whether the FMU's model structure pairs them (``der(position)`` depends on its velocity alone): a mismatch
        is then no wrong guess but the step's (a one-line problem), unless the velocities are the positions'
        rates scaled (:func:`_scaled_velocities`); a motion that settles between the input's changes
        (:func:`settles_between_input_changes`, a fast source filter) is the step's even where its factor looks
        scaled (audit84 F1: an FMI 3 Position filter read "times 0.074" at dt = 0.02 and stopped the recording).

    The caller chooses the samples (:func:`judge_run`: the first :data:`_SAMPLES`).
    """
    if v is not None and x.shape[1] >= 3:
        mismatch = rate_mismatch(x, v, h) if sums is None else sums.mismatch()
        worst = int(np.argmax(mismatch)) if mismatch.size else 0
        if mismatch.size and mismatch[worst] > MISMATCH:
            where = (f"{names['velocities'][worst]} is not the rate of {names['positions'][worst]} (relative mismatch "
                     f"{mismatch[worst]:.2g} per step)")
            if declared and u is not None and settles_between_input_changes(x, v, h, u):
                return f"velocities do not match the positions: {where}"   # a fast filter, not scaled states
            if declared:
                return _scaled_velocities(x, v, h, sums, mismatch, names, derivative_names, where)
            if not guessed:
                return f"velocities do not match the positions: {where}"
            return _repair(x, v, h, names, derivative_names, where, float(mismatch[worst]))
        if guessed and not declared:
            near = _near_rates(x, v, h, names, derivative_names, mismatch)
            if near is not None:
                return near
    if a is not None and v is not None and (stale_rates(v, a, h, u) if sums is None else sums.stale(v, u)):
        return Repair(None, None, "", STALE_REASON)
    return None


#: How many times better a velocity's increments fit as a combination of the positions and their rates than as its
#: position's rate alone before its miss counts as an offset (``v + c x``), not as the step's: near-rates of the
#: builder's chain and a single mode (c = 0.05 .. 1) fit 17 .. 1e9 times better; a true rate under a fast mode the step
#: does not resolve (m = 1, c = k = 100 at dt = 0.02) 1.0 .. 6.4 times (audit 76 F1; guard: test_first_order_rates).
_OFFSET_EXPLAINS = 10.0


def _near_rates(x: np.ndarray, v: np.ndarray, h: float, names: dict[str, list[str]],
                derivative_names: list[str | None], mismatch: np.ndarray) -> Repair | str | None:
    """A guessed pairing whose excited velocities match within :data:`MISMATCH` but not as well as true rates do at
    this step (:func:`strict_bounds`): the positions' derivative variables as velocities, or the positions alone
    (velocities derived) where the velocities are combinations of the positions and their rates, else the problem;
    None where every pair passes.  Audit 76 F1: first-order states ``x[7..12] = v + 0.3 x[1..6]`` split in halves
    were recorded as velocities without a word (mismatch 0.1-0.2, the step's own 0.001; ROM 4-11 % off)."""
    weak = set(weak_rows(x, list(range(x.shape[0]))))
    bounds = strict_bounds(v)
    off = [int(j) for j in np.flatnonzero(mismatch > bounds) if int(j) not in weak]
    if not off:
        return None
    misfit = combination_misfit(x, v, h)
    # a rate plus an offset: the positions explain the miss; where they do not, it is the step's (a fast mode the
    # step does not resolve, e.g. a heavily damped mass, misses by 0.025 where the rule's own error reads 0.003)
    off = [j for j in off if misfit[j] * _OFFSET_EXPLAINS <= mismatch[j]]
    if not off:
        return None
    j = int(max(off, key=lambda k: mismatch[k]))
    what = (f"{names['velocities'][j]} matches the increments of {names['positions'][j]} within {mismatch[j]:.2g}, "
            f"where a velocity (a smooth rate) leaves {step_explains(v[[j]])[0]:.1g} at this step")
    if np.any(misfit[off] > bounds[off]):
        return (f"the guessed pairing is wrong: {what} (a rate plus an offset, or a first-order state that jumps "
                f"with an input?); pass {POSITIONS_VELOCITIES} naming the mechanical states, or the positions "
                f"alone with {either('--positions')} (velocities derived)")
    states = set(names["positions"]) | set(names["velocities"])
    if all(derivative_names) and not set(derivative_names) & states:
        return Repair(list(names["positions"]), list(derivative_names), "",  # type: ignore[arg-type]
                      f"the guessed pairing is wrong: {what}, a combination of the positions and their rates "
                      "(velocities of another coordinate system, like v + c x); the positions' derivative variables "
                      "are the velocities, accelerations derived from the data")
    return Repair(list(names["positions"]), "", "",
                  f"the guessed pairing is wrong: {what}, a combination of the positions and their rates "
                  "(velocities of another coordinate system, like v + c x); the positions recorded alone, velocities "
                  "and accelerations derived from the data")


#: A declared velocity whose least-squares factor to its position's rate is off 1 by this factor or more (and which
#: fits within :data:`MISMATCH` once scaled) is a scaled state: a step too coarse for the motion makes the factor
#: ``tan(w h / 2) / (w h / 2)``, which exceeds 10 only within 7 % of the Nyquist frequency and is never below 1.
_SCALED = 10.0


def _scaled_velocities(x: np.ndarray, v: np.ndarray, h: float, sums: RateSums | None, mismatch: np.ndarray,
                       names: dict[str, list[str]], derivative_names: list[str | None], where: str) -> Repair | str:
    """A mismatch of velocities that the model structure pairs with the positions: a :class:`Repair` recording the
    positions' derivative variables as velocities where some velocity is its position's rate times a constant
    (states scaled by the exporter, e.g. by their nominal values: audit 2026-11-27, an FE-like export whose
    ``x440`` is the rate of ``x190`` times 3.3e-9), else the problem, which is then the step's.  ``sums``: those of the
    run (default: summed here)."""
    if sums is None:
        sums = RateSums(x.shape[0], x.shape[1], h, mismatch=True, stale=False)
        sums.feed(x, v, None, x.shape[1])
    squares = sums.squares
    inner = 0.5 * (squares[0] + squares[1] - squares[2])  # <dx, h v_trapezoid>, from the norms of the rule's terms
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = inner / squares[1]
        fitted = np.sqrt(np.maximum(squares[0] - inner * factor, 0.0) / squares[0])
    scaled = ((mismatch > MISMATCH) & np.isfinite(factor) & (factor > 0)
              & (np.abs(np.log10(np.where(factor > 0, factor, 1.0))) >= math.log10(_SCALED)) & (fitted <= MISMATCH))
    states = names["positions"] + names["velocities"]
    if scaled.any() and all(derivative_names) and not set(derivative_names) & set(states):
        row = int(np.flatnonzero(scaled)[np.argmax(mismatch[scaled])])
        return Repair(list(names["positions"]), list(derivative_names), "",  # type: ignore[arg-type]
                      f"{names['velocities'][row]} is the rate of {names['positions'][row]} times "
                      f"{1 / factor[row]:.2g}, not the rate itself (scaled states); the positions' derivative "
                      "variables are the velocities, accelerations derived from the data")
    return f"velocities do not match the positions: {where}"


def _repair(x: np.ndarray, v: np.ndarray, h: float, names: dict[str, list[str]],
            derivative_names: list[str | None], where: str, guessed_mismatch: float) -> Repair | str | None:
    """Positions and velocities paired by the data among the recorded states (within :data:`MISMATCH`, or at
    least twice better than the guess: a fast mode the step does not resolve raises every mismatch), else the
    positions' derivative variables as velocities, else the problem; None when the data's best pairing is the
    guessed one (the mismatch is then the step's own, not a wrong pairing)."""
    states = names["positions"] + names["velocities"]
    if len(states) <= MAX_PAIRED and len(set(states)) == len(states):
        found = pair_by_data(np.vstack([x, v]), h)
        n = len(names["positions"])
        if found is not None and sorted(found[0]) == [(i, n + i) for i in range(n)]:
            return None
        if (found is not None and found[1] <= max(MISMATCH, 0.5 * guessed_mismatch)
                and strictly_paired(np.vstack([x, v]), h, found[0])):
            pairs = found[0]
            return Repair([states[i] for i, _ in pairs], [states[j] for _, j in pairs], None,
                          f"the guessed pairing is wrong ({where}); positions and velocities paired by the data")
    if all(derivative_names) and not set(derivative_names) & set(states):
        left_out = not_rates(x, v, h)
        if not left_out:
            return Repair(list(names["positions"]), list(derivative_names), "",  # type: ignore[arg-type]
                          f"the guessed pairing is wrong ({where}); the positions' derivative variables are the "
                          "velocities, accelerations derived from the data")
        partly = partial_pairing_problem(np.vstack([x, v]), h, states, where)
        if partly is not None:
            return partly
        # the derivative variables would stand in for states that are no velocities: those would be lost, and the
        # data are no M x'' + D x' + K x = B u (ninth audit: a state space in other coordinates, a ROM 128 % off)
        shown = ", ".join(names["velocities"][j] for j in left_out[:6]) + (", ..." if len(left_out) > 6 else "")
        return (f"cannot tell positions from velocities: {where}, the data pair no states, and the states {shown} "
                "are no combination of the positions' rates: the states are no positions and velocities (a state "
                "space in other coordinates, or non-mechanical states), and fmu-opinf learns M x'' + D x' + K x = "
                "B u from those; export the model with its mechanical states (positions and their velocities), or, "
                f"where some states are, pass {POSITIONS_VELOCITIES} naming them")
    if len(states) <= MAX_PAIRED:
        partly = partial_pairing_problem(np.vstack([x, v]), h, states, where)
        if partly is not None:
            return partly
    why = ("the data pair no states" if len(states) <= MAX_PAIRED else
           f"too many states ({len(states)}) to pair by the data")
    return f"cannot tell positions from velocities: {where}, and {why}; pass {POSITIONS_VELOCITIES}"


#: Repairs of one run at most: a pairing and then stale accelerations (a co-simulation FMU without inputs whose
#: states are listed body by body needs both).
MAX_REPAIRS = 2


def live_rate_sums(source: Any, t: np.ndarray) -> RateSums | None:
    """The :class:`RateSums` that :func:`judge_run` will need for a run of ``source`` on the grid ``t``, to be fed
    while it is recorded, or None where the run will not be judged (or its velocities are derived)."""
    if getattr(source, "selection", None) is None or not source.n or len(t) < 3 or source.derived["xdot"]:
        return None
    rows = _checked_rows(source.n)
    n = source.n if isinstance(rows, slice) else len(rows)
    return RateSums(n, min(len(t), _SAMPLES), float(t[1] - t[0]), mismatch=True,
                    stale=not source.derived["xddot"], rows=rows)


#: ``evaluate(rows, i)``: the accelerations of the judged ``rows`` as the FMU gives them at the state of sample ``i``
#: of the run judged, read just after it (:func:`judge_run`); None where it cannot tell.
Evaluate = Callable[[Any, int], "np.ndarray | None"]


def judge_run(source: Any, run: Any, t: np.ndarray, repairs: int = 0, strict: bool = True,
              sums: RateSums | None = None, evaluate: Evaluate | None = None) -> Repair | None:
    """The repair :func:`check_rates` proposes for a run of an FMU source (None if its rates are consistent); a
    problem it cannot repair (any after a repair, or after :data:`MAX_REPAIRS`) is an :class:`FMUError`, a
    mismatch of velocities the user chose a warning.  ``strict=False`` (pilot runs of the automatic window, whose
    step may not resolve the model: audit 2026-11-26, warnings of mismatched velocities from pilots at an aliasing
    step) proposes repairs but leaves what it cannot repair to the recording itself.  ``sums``: those of
    :func:`live_rate_sums`, fed with the whole run as it was recorded.  ``evaluate``: the FMU's accelerations just
    after a sample (:data:`Evaluate`), which overrule the data's verdict of stale accelerations where they tell
    (:func:`confirmed_stale`)."""
    selection = getattr(source, "selection", None)
    if selection is None or not source.n or len(t) < 3:
        return None
    window = slice(None, min(len(t), _SAMPLES))
    rows = _checked_rows(source.n)
    x = np.asarray(run.x[rows, window])
    v = None if source.derived["xdot"] else np.asarray(run.xdot[rows, window])
    a = None if source.derived["xddot"] else np.asarray(run.xddot[rows, window])
    picked = np.arange(source.n)[rows]
    names = {"positions": [source.position_names[i] for i in picked],
             "velocities": [source.velocity_names[i] for i in picked] if source.velocity_names else []}
    derivatives = [selection.position_derivatives[i] for i in picked] if selection.position_derivatives else []
    rule = selection.how.get("positions")
    if not repairs and len(picked) == source.n and (v is None and rule == _PATTERN_X or rule == _LOCAL_STEMS):
        among = rates_among_positions(x, float(t[1] - t[0]), names["positions"])
        if isinstance(among, str):
            if strict:
                raise FMUError(f"{source_label(source)}: {among}")
            return None
        if among is not None:
            return among
    structure = _paired_by_structure(selection) and not repairs
    guessed = selection.guessed and not structure
    repaired = repairs or str(selection.how.get("positions", "")).startswith("rate check on the data")
    if strict and v is not None and guessed and not repaired:   # a first-order state's rate is a rate too: said
        # as such before the rate test judges it a near-rate (audit 76 F3: pdot of a pressure)
        refuse_first_order_rates(source_label(source), x, v, np.asarray(run.u[:, window]), names, "paired by a guess")
    verdict = check_rates(x, v, a, float(t[1] - t[0]), names, guessed and not repairs, derivatives,
                          np.asarray(run.u[:, window]), sums, declared=structure)
    if isinstance(verdict, Repair) and verdict.reason == STALE_REASON and evaluate is not None:
        verdict = confirmed_stale(verdict, a, np.asarray(run.u[:, window]), t, lambda i: evaluate(rows, i))
    if verdict is None and strict and v is not None and repaired:   # (a pairing the data made, judged as recorded)
        refuse_first_order_rates(source_label(source), x, v, np.asarray(run.u[:, window]), names, "paired by the data")
    if verdict is None:
        if strict and getattr(source, "interface", None) == "cs":
            if v is not None:
                warn_if_euler_steps(source, x, v, float(t[1] - t[0]), sums)
            warn_if_internal_steps(source, x, v, a, np.asarray(run.u[:, window]), float(t[1] - t[0]))
        return None
    whole = len(picked) == source.n
    if isinstance(verdict, Repair) and repairs < MAX_REPAIRS and (whole or verdict.velocities is None):
        return verdict
    if not strict:
        return None
    message = verdict
    if isinstance(verdict, Repair):
        cause = verdict.reason.split("; ")[0]
        message = (f"{cause}, also after {repairs} repairs" if repairs >= MAX_REPAIRS else
                   f"{cause}; too many positions ({source.n}) to pair by the data")
        message += f"; pass {POSITIONS_VELOCITIES}"
    if guessed or repairs:
        raise FMUError(f"{source_label(source)}: {message}")
    if whole and v is not None and not structure:   # the data do not overrule the FMU's model structure
        pairing = pairing_the_data_show(x, v, float(t[1] - t[0]), names)
        if pairing is not None:  # the user's pairing is contradicted by one the data make at this very step
            raise FMUError(f"{source_label(source)}: {message}, but the data pair them at this step: pass "
                           + patterns_said(positions=",".join(pairing[0]), velocities=",".join(pairing[1])))
    if (getattr(selection, "linked", False) or structure) and not isinstance(verdict, Repair):
        # the FMU itself declares each velocity the derivative of its position: the step is what fails
        declares = ("declares each velocity the derivative of its position" if not structure else
                    "pairs them in its model structure (der(position) depends on its velocity alone)")
        if v is not None and settles_between_input_changes(x, v, float(t[1] - t[0]), np.asarray(run.u[:, window])):
            warnings.warn(f"{source_label(source)}: {message}, though the FMU {declares}: the position moves only "
                          f"within {SETTLE_STEPS} steps of each change of the input and rests between them, faster "
                          f"than the step dt={float(t[1] - t[0]):g} (a fast filter, such as a Modelica Position or "
                          "Speed source with exact=false, or a stiff damper); the fit takes each held step exactly, "
                          "so the ROM is not spoiled; a smaller --dt only shows that motion",
                          FmuOpinfWarning, stacklevel=3)
            return None
        warn_recording(f"{source_label(source)}: {message}, though the FMU {declares}: the step dt="
                       f"{float(t[1] - t[0]):g} is too coarse for the motion (a mode near or above half the sampling "
                       f"rate); record at a smaller {either('--dt')}", "coarse-step", stacklevel=3)
        return None
    warnings.warn(f"{source_label(source)}: {message}; the fitted model will be wrong unless {either('--velocities')} "
                  "name the positions' rates", FmuOpinfWarning, stacklevel=3)
    return None


#: Steps after each change of the held input within which a fast state may settle
#: (:func:`settles_between_input_changes`): Modelica's Position(exact=false) filter (double pole at -2 pi 50 /s)
#: moves by 1.4 % of its jump one step of 0.02 after it and by 5e-5 two steps after (audit base82 F2).
SETTLE_STEPS = 3


def settles_between_input_changes(x: np.ndarray, v: np.ndarray, h: float, u: np.ndarray) -> bool:
    """Whether velocities that miss their positions' rates (:func:`check_rates`) match them once the
    :data:`SETTLE_STEPS` steps from each change of the held input on are left out: a motion faster than the step
    that follows the input and dies out before the next change (a critically damped source filter, a stiff damper),
    not a mode the step aliases, which goes on ringing.  False where the input changes at nearly every step (nothing
    left to judge by: at least a quarter of the steps must remain) or never changes."""
    k = x.shape[1]
    if u.size == 0 or k < 4:
        return False
    held = u[:, 1:]                                               # interval j holds u[:, j + 1] (design.md)
    change = np.r_[np.any(held[:, 0] != u[:, 0]), np.any(held[:, 1:] != held[:, :-1], axis=0)]
    if not change.any():
        return False
    near = change.copy()
    for shift in range(1, SETTLE_STEPS + 1):
        near[shift:] |= change[:-shift]
    keep = np.flatnonzero(~near)
    if keep.size < max(3, (k - 1) // 4):
        return False
    # each row judged against at least 1e-6 of its motion over the whole run (a fast state rests between changes)
    dx, trapezoid = np.diff(x, axis=1), 0.5 * h * (v[:, 1:] + v[:, :-1])
    overall = np.sqrt(np.maximum(np.einsum("ij,ij->i", dx, dx), np.einsum("ij,ij->i", trapezoid, trapezoid)))
    return bool(np.all(rate_mismatch_over(x, v, h, keep, floor=1e-6 * overall) <= MISMATCH))


def _paired_by_structure(selection: Any) -> bool:
    """Whether the FMU's model structure pairs the positions with the velocities (``der(position)`` depends on its
    velocity state alone) and both were recorded by that rule (not by patterns)."""
    how = getattr(selection, "how", {})
    return bool(selection.velocities) and how.get("positions") == how.get("velocities") == _DEPENDENCIES


#: Positions the rate check reads at most (evenly spaced beyond): a run of 1e5 positions is not read whole.
_CHECKED_ROWS = 2000


def _checked_rows(n: int) -> slice | np.ndarray:
    """The rows (positions) the rate check reads: all up to :data:`_CHECKED_ROWS`, else that many evenly
    spaced (a guessed pairing is then only judged, not re-paired by the data)."""
    if n <= _CHECKED_ROWS:
        return slice(None)
    return np.unique(np.linspace(0, n - 1, _CHECKED_ROWS).round().astype(int))
