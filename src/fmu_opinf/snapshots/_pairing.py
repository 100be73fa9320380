"""Positions and velocities paired by the data, where nothing declares the pairing.

A row is the rate of another where its average over each step times ``h`` matches the other's increments as well
as a true rate does at this step (:func:`strict_bounds`: within a few times the trapezoidal rule's own error,
estimated from the row itself).  :data:`~fmu_opinf.snapshots._rate_tests.MISMATCH` is far too loose to discover
pairs (audit 76).  These functions find such pairs among the recorded states (:func:`pair_by_data`,
:func:`rates_among_positions`), say which states pair with none (an actuator lag, a controller state) or are not
excited, and tell a rate from a rate plus a multiple of a position (velocities of another coordinate system).
:mod:`fmu_opinf.snapshots._consistency` decides what a recording does with the answer.
"""

from __future__ import annotations

import numpy as np

from .._validate import POSITIONS_VELOCITIES, either, patterns_said
from ..sources._base import few_names
from ._rate_tests import _QUIET, MISMATCH, Repair, rate_mismatch

__all__ = ["MAX_PAIRED", "combination_misfit", "not_rates", "pair_by_data", "pairing_the_data_show",
           "partial_pairing_problem", "rates_among_positions", "step_explains", "strict_bounds", "strictly_paired",
           "weak_rows"]

#: Largest number of states paired by the data (the search compares every pair).
MAX_PAIRED = 2000
#: A pair that the data find or confirm where nothing declares it must match as well as a true rate does at this
#: step: within this many times the trapezoidal rule's own error there (:func:`step_explains`) ...
_EXPLAINED_FACTOR = 3.0
#: ... plus this (an FMU's integration tolerance).  :data:`MISMATCH` is far too loose to discover pairs: audit 76
#: F1, ``x[7..12] = v + c x[1..6]`` matched within 0.016 (c = 0.05) .. 0.18 (c = 0.3) where the step explains
#: 0.0005 .. 0.002, and was recorded as the velocities (ROM 4-69 % off); F2, wave-front positions of a 1000-mass
#: chain "were the rates" of their neighbours within 0.013-0.07.
_EXPLAINED_FLOOR = 5e-3
#: A row whose average matches another's increments within this is near its rate (a rate plus a multiple of a
#: position: 0.34 .. 0.6 at c = 1); two rows that do not move together stay above ``1 / sqrt(2)``.
_NEAR = 0.65
#: Rows whose peak is below this fraction of the largest are not excited in a recording: they take part in no pair
#: the data find and are named as such (the leading edge of a wave in a 200-mass chain, peaks 1.6e-7 and 2.4e-6 of
#: the largest, matched as a rate within 0.074 where the step explains 0.035).  Small enough that the positions of
#: modes up to 1e4 rad/s stay above it beside their velocities.
_WEAK = 1e-4



def step_explains(rates: np.ndarray) -> np.ndarray:
    """Per row taken as the rate of some position: the relative mismatch the trapezoidal rule leaves where it is
    that rate, ``||second differences|| / (12 ||averages over a step||)`` (``(omega h)^2 / 12`` for a mode
    ``omega``, and the same sum over modes), estimated from the row itself; ``inf`` for fewer than 3 samples.

    Why: a true rate's mismatch is the rule's own error, which this matches within a few per cent on exact data
    (audit 76's 6-mass chain: 0.0014 / 0.0014 at dt 0.02, 0.034 / 0.033 at dt 0.1), while a rate plus a multiple
    of a position is off by far more at a step that resolves the motion."""
    rates = np.asarray(rates, dtype=float)
    if rates.shape[1] < 3:
        return np.full(rates.shape[0], np.inf)
    curvature = np.linalg.norm(np.diff(rates, n=2, axis=1), axis=1)
    averages = np.linalg.norm(0.5 * (rates[:, :-1] + rates[:, 1:]), axis=1)
    return curvature / (12.0 * np.maximum(averages, np.finfo(float).tiny))


def strict_bounds(rates: np.ndarray, cap: float = MISMATCH) -> np.ndarray:
    """Per row: the largest relative mismatch at which it is taken for a rate where nothing declares it
    (:data:`_EXPLAINED_FACTOR` times :func:`step_explains` plus :data:`_EXPLAINED_FLOOR`, at most ``cap``: a
    repair may exceed :data:`MISMATCH` where a mode the step does not resolve raises every mismatch)."""
    return np.minimum(cap, _EXPLAINED_FACTOR * step_explains(rates) + _EXPLAINED_FLOOR)


def _moving(rows: np.ndarray, h: float) -> np.ndarray:
    """Rows that move (their increments and averages above :data:`_QUIET` of the largest): two constant rows
    match each other."""
    increments = np.linalg.norm(np.diff(rows, axis=1), axis=1)
    averages = np.linalg.norm(0.5 * h * (rows[:, :-1] + rows[:, 1:]), axis=1)
    return ((increments > _QUIET * max(float(increments.max(initial=0.0)), np.finfo(float).tiny))
            & (averages > _QUIET * max(float(averages.max(initial=0.0)), np.finfo(float).tiny)))


def strictly_paired(rows: np.ndarray, h: float, pairs: list[tuple[int, int]]) -> bool:
    """Whether each excited ``(position, velocity)`` row pair matches as a true rate does (:func:`strict_bounds`):
    a repair by the data is recorded without a further check of its pairing."""
    weak = set(weak_rows(rows, list(range(rows.shape[0]))))
    kept = [(i, j) for i, j in pairs if i not in weak]
    if not kept:
        return True
    positions, velocities = (list(side) for side in zip(*kept))
    bounds = strict_bounds(rows[velocities], cap=np.inf)
    return bool(np.all(rate_mismatch(rows[positions], rows[velocities], h) <= bounds))


def _rates_by_data(rows: np.ndarray, h: float, near: float | None = None) -> dict[int, int]:
    """Row -> the row that is its rate by the data (its average over each step times ``h`` matches the row's
    increments within :func:`strict_bounds`, trapezoidal rule; or within ``near`` where given, to find near-rates),
    each row the rate of one row at most, the best matches first; rows that hardly move (:data:`_QUIET`) take part
    in no pair, nor do rows not excited (:data:`_WEAK`)."""
    relative = _relative_matches(rows, h)
    quiet = ~_moving(rows, h)
    quiet[weak_rows(rows, list(range(rows.shape[0])))] = True
    relative[quiet, :] = np.inf
    relative[:, quiet] = np.inf
    bounds = strict_bounds(rows) if near is None else np.full(rows.shape[0], near)
    relative[relative > bounds[None, :]] = np.inf
    rate: dict[int, int] = {}
    for flat in np.argsort(relative, axis=None):
        i, j = divmod(int(flat), relative.shape[1])
        if not np.isfinite(relative[i, j]):
            break
        if i not in rate and j not in rate.values():
            rate[i] = j
    return rate


def _chains(rate: dict[int, int], n: int) -> tuple[list[int], list[int], list[int] | None, list[int]]:
    """Positions (rows that are no row's rate), their velocities, their accelerations (where every velocity has a
    rate, else None) and the rows left over, from :func:`_rates_by_data`'s pairs of ``n`` rows."""
    positions = sorted(i for i in rate if i not in rate.values())
    velocities = [rate[i] for i in positions]
    accelerations = [rate[j] for j in velocities] if all(j in rate for j in velocities) else None
    used = set(positions) | set(velocities) | set(accelerations or [])
    return positions, velocities, accelerations, [k for k in range(n) if k not in used]


def _options_text(names: list[str], positions: list[int], velocities: list[int],
                  accelerations: list[int] | None) -> str:
    """``--positions ... --velocities ... [--accelerations ...]`` naming the rows given, or the keywords."""
    patterns = {"positions": ",".join(names[i] for i in positions),
                "velocities": ",".join(names[j] for j in velocities)}
    if accelerations:
        patterns["accelerations"] = ",".join(names[k] for k in accelerations)
    return patterns_said(**patterns)


def _few_pairs(names: list[str], positions: list[int], velocities: list[int]) -> str:
    """``v is the rate of p`` for the first three pairs."""
    shown = "; ".join(f"{names[j]} is the rate of {names[i]}" for i, j in list(zip(positions, velocities))[:3])
    return shown + ("; ..." if len(positions) > 3 else "")


def partial_pairing_problem(rows: np.ndarray, h: float, names: list[str], where: str) -> str | None:
    """Where the guessed pairing is wrong and the data pair some of the states but not all as positions and
    velocities: the problem naming the pairs, the states left over (neither positions nor velocities) and the
    options that record the mechanical states; None where the data pair none.  Audit 75 F6: generic names
    ``x1 .. x10`` (x5..x8 the rates of x1..x4, x9 and x10 a controller's integrator and an actuator lag) were
    refused saying "the data pair no states"; F4: ``q``, ``qdot``, ``qddot`` split in halves, likewise."""
    positions, velocities, accelerations, left = _chains(_rates_by_data(rows, h), len(names))
    if not positions:
        return None
    options = _options_text(names, positions, velocities, accelerations)
    if not left:
        return (f"cannot tell positions from velocities: {where}, but the data pair all states otherwise "
                f"({_few_pairs(names, positions, velocities)}); pass {options}")
    weak = _not_excited_rows(rows, h, left)
    if len(weak) == len(left):
        return (f"cannot tell positions from velocities: {where}; by the data "
                f"{_few_pairs(names, positions, velocities)}, but {_shown(names, weak)} are not excited in this "
                f"recording (they or the rows they match peak below {_WEAK:g} of the largest): excite them (an input "
                f"or a start that moves them) or pass the pairing with {POSITIONS_VELOCITIES}")
    return (f"cannot tell positions from velocities: {where}; by the data {_few_pairs(names, positions, velocities)}"
            f", but {_shown(names, [k for k in left if k not in weak])} pair with none: neither positions nor "
            "velocities (an actuator lag, a filter or a controller state?), which a reduced model of the mechanical "
            f"states cannot follow{_not_excited(names, weak)}; to record the mechanical states anyway, pass {options}")


def _not_excited(names: list[str], weak: list[int]) -> str:
    """`` (and ... not excited in this recording)`` naming the weak rows, or nothing."""
    return f" (and {_shown(names, weak)} are not excited in this recording)" if weak else ""


def _shown(names: list[str], rows: list[int]) -> str:
    """The first six of the rows' names (:func:`fmu_opinf.sources._base.few_names`)."""
    return few_names([names[k] for k in rows])


def _not_excited_rows(rows: np.ndarray, h: float, which: list[int]) -> list[int]:
    """Of ``which``, the rows not excited in the recording (:func:`weak_rows`) and those whose best match either
    way (as a rate or as the row a rate belongs to) is such a row: the velocity of a mass at a wave's leading edge
    is above :data:`_WEAK` before its position is."""
    weak = set(weak_rows(rows, list(range(rows.shape[0]))))
    relative = _relative_matches(rows, h)
    return [k for k in which if k in weak or int(np.argmin(relative[k])) in weak
            or int(np.argmin(relative[:, k])) in weak]


def weak_rows(rows: np.ndarray, which: list[int]) -> list[int]:
    """Of ``which``, the rows whose peak is below :data:`_WEAK` of the largest peak of all rows: not excited in the
    recording (audit 76 F2: masses a wave had not reached were called controller states)."""
    peaks = np.max(np.abs(rows), axis=1) if rows.shape[1] else np.zeros(rows.shape[0])
    top = max(float(peaks.max(initial=0.0)), np.finfo(float).tiny)
    return [k for k in which if peaks[k] < _WEAK * top]


def rates_among_positions(x: np.ndarray, h: float, names: list[str]) -> Repair | str | None:
    """Positions guessed by name (``x[*]`` recorded without velocities, or paired by name with ``xdot[*]``, in a
    model that declares no states) of which the data make some the rates of others: a :class:`Repair` recording
    them as positions and velocities (accelerations derived) where that pairs them all, as a guessed split in halves
    is repaired; otherwise the problem naming them; None where no position is another's rate.  Audit 75 F5: an
    FMI 3 model-exchange FMU whose ``der(x)`` lost its ``derivative=`` was recorded silently with its 6 velocities
    as positions, and the ROM was 24-1000 % off; recorded as the data pair it, it is the exact model's (1e-9)."""
    if len(names) > MAX_PAIRED or len(names) < 2 or x.shape[1] < 3:
        return None
    positions, velocities, accelerations, left = _chains(_rates_by_data(x, h), len(names))
    if not positions:
        return _near_rates_among_positions(x, h, names)
    pairs = _few_pairs(names, positions, velocities)
    if left:
        return (f"velocities among the positions: {pairs} by the data, and {_shown(names, left)} pair with none; pass "
                f"{_options_text(names, positions, velocities, accelerations)} (the states left out, if dynamic, "
                f"the reduced model cannot follow), or the positions alone with {either('--positions')}")
    return Repair([names[i] for i in positions], [names[j] for j in velocities],
                  ",".join(names[k] for k in accelerations) if accelerations else "",
                  f"velocities among the positions guessed by name (the FMU declares no states): {pairs} by the "
                  "data; recorded as positions and velocities")


def _near_rates_among_positions(x: np.ndarray, h: float, names: list[str]) -> Repair | str | None:
    """Where no position is another's rate, half of them near the rates of the other half (within :data:`_NEAR`:
    a rate plus a multiple of its position, velocities of another coordinate system): the positions alone
    (velocities and accelerations derived) where those rows are combinations of them and their rates to what the
    step explains, else the problem naming them; None where they are not (audit 76 F1: at c = 1 nothing paired
    and all 12 rows were recorded as positions, a ROM 2100 % off; the positions alone give 3e-6)."""
    positions, near, _, left = _chains(_rates_by_data(x, h, near=_NEAR), len(names))
    if not positions or left:
        return None
    misfit = combination_misfit(x[positions], x[near], h)
    bounds = strict_bounds(x[near])
    offsets = "; ".join(f"{names[j]} near the rate of {names[i]} (relative mismatch "
                        f"{_relative_matches(x[[i, j]], h)[0, 1]:.2g}, a rate leaves {step_explains(x[[j]])[0]:.1g})"
                        for i, j in list(zip(positions, near))[:2])
    if np.all(misfit <= bounds):
        return Repair([names[i] for i in positions], "", "",
                      f"{offsets}{'; ...' if len(positions) > 2 else ''}: no rates but combinations of the positions "
                      "and their rates (velocities of another coordinate system, like v + c x); recorded: "
                      f"{_shown(names, positions)} as the positions, velocities and accelerations derived")
    return (f"positions that may hold velocities of another coordinate system: {offsets}, but no rate; pass "
            f'{patterns_said(positions=",".join(names[i] for i in positions))} (velocities derived) if those are the '
            f"positions, or {POSITIONS_VELOCITIES} naming the mechanical states")


def combination_misfit(p: np.ndarray, w: np.ndarray, h: float) -> np.ndarray:
    """Per row of ``w``: how far its average over each step (times ``h``) is from the best combination of the
    increments of ``p`` and of ``p``'s averages (times ``h``), relative to it (least squares)."""
    targets = (0.5 * h) * (w[:, :-1] + w[:, 1:]).T
    basis = np.hstack([np.diff(p, axis=1).T, (0.5 * h) * (p[:, :-1] + p[:, 1:]).T])
    coefficients = np.linalg.lstsq(basis, targets, rcond=None)[0]
    norms = np.maximum(np.linalg.norm(targets, axis=0), np.finfo(float).tiny)
    return np.linalg.norm(basis @ coefficients - targets, axis=0) / norms


def not_rates(x: np.ndarray, v: np.ndarray, h: float) -> list[int]:
    """Rows of ``v`` whose average over each step is no combination of the positions' rates (their increments
    over ``h``; within :data:`_COMBINATION_MISFIT` relative, the trapezoidal rule), by least squares; rows that hardly
    move (:data:`_QUIET`) pass.  Absolute velocities beside relative positions (``v_i`` the sum of the rates of
    ``s_rel_1 .. s_rel_i``) and velocity states scaled by the exporter are such combinations; the states of a
    state space in other coordinates are not.  Above :data:`_SPANNED` positions nothing is judged (an empty list:
    an FE export's thousands of states would make the product large)."""
    if x.shape[0] > _SPANNED or x.shape[1] < 3:
        return []
    increments = np.diff(x, axis=1).T
    averages = (0.5 * h) * (v[:, :-1] + v[:, 1:]).T
    norms = np.linalg.norm(averages, axis=0)
    moving = norms > _QUIET * max(float(norms.max(initial=0.0)), np.finfo(float).tiny)
    coefficients = np.linalg.lstsq(increments, averages[:, moving], rcond=None)[0]
    misfit = np.linalg.norm(increments @ coefficients - averages[:, moving], axis=0) / norms[moving]
    return [int(j) for j, off in zip(np.flatnonzero(moving), misfit) if off > _COMBINATION_MISFIT]


#: Positions at most that :func:`not_rates` judges.
_SPANNED = 500
#: Relative misfit above which a state is no combination of the positions' rates: a right combination leaves
#: about ``(omega h)^2 / 12`` (1e-4 on a 3-mass chain at dt = 0.05, 8e-3 at the window's 20 points per period,
#: 0.1 at 6 points); the states of a state space in other coordinates 0.12 .. 0.39 (random transformations).
_COMBINATION_MISFIT = 0.1


def _relative_matches(states: np.ndarray, h: float) -> np.ndarray:
    """``[i, j]``: how far row ``j``'s average over each step times ``h`` is from row ``i``'s increments, relative
    to the larger of the two (trapezoidal rule); ``inf`` on the diagonal."""
    increments = np.diff(states, axis=1)
    averages = h * 0.5 * (states[:, :-1] + states[:, 1:])
    # ||d_i - a_j||^2 for all i, j from one product
    squared = (np.sum(increments ** 2, axis=1)[:, None] + np.sum(averages ** 2, axis=1)[None, :]
               - 2.0 * increments @ averages.T)
    scale = np.maximum(np.linalg.norm(increments, axis=1)[:, None], np.linalg.norm(averages, axis=1)[None, :])
    relative = np.sqrt(np.maximum(squared, 0.0)) / np.maximum(scale, np.finfo(float).tiny)
    np.fill_diagonal(relative, np.inf)
    return relative


def pair_by_data(states: np.ndarray, h: float) -> tuple[list[tuple[int, int]], float] | None:
    """``(position, velocity)`` row pairs, each velocity row's average over a step times ``h`` the best match of its
    position row's increments (trapezoidal rule), and the largest relative mismatch of a pair (the caller judges
    it); None unless the pairs use every row once.  Of the rows, the half with the better best matches are the
    positions: a velocity row's increments are ``h`` times an acceleration, which matches no state as well."""
    relative = _relative_matches(states, h)
    best = np.argmin(relative, axis=1)
    # a position's best match is its velocity; a velocity's increments (h times an acceleration) match no state
    # as well: of each row and its best match, the row with the better match is the position
    order = np.argsort(relative[np.arange(best.size), best])
    pairs, used = [], set()
    for i in order[: states.shape[0] // 2]:
        pairs.append((int(i), int(best[i])))
        used.update((int(i), int(best[i])))
    if len(used) != states.shape[0]:
        return None
    pairs.sort()  # positions in the order the states are listed
    return pairs, float(max(relative[i, j] for i, j in pairs))


def pairing_the_data_show(x: np.ndarray, v: np.ndarray, h: float,
                           names: dict[str, list[str]]) -> tuple[list[str], list[str]] | None:
    """Positions and velocities as the data pair the given states (within :data:`MISMATCH`), where that differs
    from the given pairing; None where the data pair them as given (the step is then what fails) or not at all.
    A user's velocities in the wrong order were a warning, and ``fit`` then learned a model 400 times off (audit of
    pythonfmu FMUs, 2026-11-26)."""
    states = names["positions"] + names["velocities"]
    if len(states) > MAX_PAIRED or len(set(states)) != len(states):
        return None
    found = pair_by_data(np.vstack([x, v]), h)
    n = len(names["positions"])
    if found is None or found[1] > MISMATCH or sorted(found[0]) == [(i, n + i) for i in range(n)]:
        return None
    return [states[i] for i, _ in found[0]], [states[j] for _, j in found[0]]

