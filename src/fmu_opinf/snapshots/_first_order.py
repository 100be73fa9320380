"""Velocities that are the rates of first-order states: a check of a guessed pairing on the recorded data.

A mechanical velocity is a state of its own: it is not determined by its position and the inputs at the same
instant, since it carries the history of the forces (under a force its acceleration jumps, not its velocity).  The
rate of a first-order state is a function of that state and the input: a chamber pressure ``p`` with
``pdot = der(p) = (F - p) / tau`` has ``pdot`` in the span of ``p``, ``F`` and a constant at every sample (and
moves in the same step as an input step).  Audit 76 F3: a stateless FMU exposing ``p`` and ``pdot`` beside the
masses' ``q[i]`` / ``qdot[i]`` was recorded with ``p`` as a mass coordinate (the names pair, and ``pdot`` is the
rate of ``p``, so the rate check agrees) without a word; the ROM was 0.5-1.4 % of range off and had a 3.15e7 rad/s
pole, where the mechanical states alone reduce to round-off.

:func:`first_order_rates` finds such "velocities" in a recorded run: each velocity is fitted by least squares on its
own position, the inputs (in effect at the sample and at the next one, so either convention of reading the FMU's
rate fits) and a constant; a velocity that this fits to round-off while its position and a constant alone do not
(the input is needed: an overdamped mode's velocity can be proportional to its position in a free response) is the
rate of a first-order state.  Rows that hardly move, and runs whose inputs do not move, are not judged.

:func:`first_order_problem` turns the finding into the refusal :func:`fmu_opinf.snapshots._consistency.judge_run`
raises for a guessed pairing, with the options that record the mechanical states.  A pairing the FMU declares
(derivative links, model structure) is not judged: there the model says the pair is a state and its rate, and a
declared first-order state is refused where the states are read (:mod:`fmu_opinf.sources._variables`).
"""

from __future__ import annotations

import numpy as np

from .._validate import POSITIONS_VELOCITIES, either, patterns_said
from ..errors import FMUError
from ..sources._base import few_names

__all__ = ["FIRST_ORDER_FIT", "INPUT_NEEDED", "first_order_problem", "first_order_rates", "refuse_first_order_rates"]

#: A velocity fitted by its position, the inputs and a constant to this relative residual (of its variation about
#: its mean) or better is the rate of a first-order state.  Exact first-order rates fit to the recording's accuracy
#: (1e-9 and below from a model-exchange or exact co-simulation recording); a mass's velocity misses by order one,
#: since it is not a function of the instant's position and force.  A mass so light that its inertia does not show
#: at the step (``m / c`` far below ``dt``) behaves like a first-order state at that step and would fit too: the bar
#: sits far below what such a mass leaves at any step that resolves it (measured on exact ZOH data: one mass
#: m = 1, k = 100 with damping c = 100 at dt = 0.05 leaves 2e-3 .. 6e-5 under a pulse, a step, a harmonic; c = 1000
#: leaves round-off at dt = 0.05, where its fast pole decays by e^-50 within a step, and still 3e-8 / 3e-7 at
#: dt = 0.01 under a harmonic / a raised-cosine pulse (9e-6 / 3e-6 under a rectangular pulse / a step): at such
#: steps it is a first-order state, and the refusal says to record at a smaller --dt; a 50-mass chain, a free
#: body, undamped and lightly damped masses leave 0.03 .. 1).
FIRST_ORDER_FIT = 1e-6
#: ... provided its position and a constant alone miss it by at least this (the input is needed to explain it): the
#: velocity of an overdamped or a single real mode can be proportional to its position where no input acts.
INPUT_NEEDED = 1e-2
#: Rows whose velocity varies less than this fraction of the most varying velocity are not judged (numerically
#: still).
_QUIET = 1e-8
#: Rows judged at a time (each block's temporaries: ``4 x _ROWS x k`` doubles, 33 MB at 4000 samples).
_ROWS = 256


def _orthonormal(columns: np.ndarray) -> np.ndarray:
    """An orthonormal basis (as columns) of the span of ``columns`` (``(k, c)``), dropping dependent ones."""
    Q, R = np.linalg.qr(columns)
    diagonal = np.abs(np.diag(R))
    keep = diagonal > 1e-12 * max(float(diagonal.max(initial=0.0)), 1e-300)
    return Q[:, keep]


def _residuals(x: np.ndarray, v: np.ndarray, common: np.ndarray) -> np.ndarray:
    """Per row ``i``: ``||v_i - fit_i|| / ||v_i - mean v_i||``, ``fit_i`` the least-squares fit of ``v_i`` by
    ``x_i`` and the columns ``common`` (``(k, c)``, orthonormal, a constant among them)."""
    v_perp = v - (v @ common) @ common.T
    x_perp = x - (x @ common) @ common.T
    x_norms = np.einsum("ij,ij->i", x_perp, x_perp)
    weights = np.divide(np.einsum("ij,ij->i", v_perp, x_perp), x_norms, out=np.zeros(len(x_norms)),
                        where=x_norms > 0)
    left = v_perp - weights[:, None] * x_perp
    centred = v - v.mean(axis=1, keepdims=True)
    spread = np.sqrt(np.einsum("ij,ij->i", centred, centred))
    return np.sqrt(np.einsum("ij,ij->i", left, left)) / np.maximum(spread, 1e-300)


def first_order_rates(x: np.ndarray, v: np.ndarray, u: np.ndarray | None) -> list[int]:
    """The rows ``i`` whose velocity ``v_i`` is the rate of a first-order state (module docstring): fitted by
    ``x_i``, the inputs and a constant to :data:`FIRST_ORDER_FIT`, by ``x_i`` and a constant alone no better than
    :data:`INPUT_NEEDED`.  ``x``, ``v``: ``(n, k)`` positions and their recorded velocities; ``u``: ``(m, k)`` inputs
    in effect at each sample.  Empty where there are no inputs, they do not move, or the run is too short."""
    if u is None or u.size == 0 or x.shape[1] < 4 * (2 * u.shape[0] + 2):
        return []
    u = np.asarray(u, dtype=float)
    if not np.any(np.ptp(u, axis=1) > 0):
        return []
    k = x.shape[1]
    ones = np.ones((k, 1))
    following = np.hstack([u[:, 1:], u[:, -1:]])   # the input of the next step: the FMU may read its new value
    with_inputs = _orthonormal(np.hstack([ones, u.T, following.T]))
    constant = ones / np.sqrt(k)
    x, v = np.asarray(x, dtype=float), np.asarray(v, dtype=float)
    spread = np.ptp(v, axis=1)
    judged = spread > _QUIET * max(float(spread.max(initial=0.0)), 1e-300)
    fit, alone = np.ones(len(x)), np.ones(len(x))
    with np.errstate(over="ignore", invalid="ignore"):
        for start in range(0, len(x), _ROWS):   # blocks of rows: 2000 positions x 4000 samples stay small
            rows = slice(start, start + _ROWS)
            fit[rows] = _residuals(x[rows], v[rows], with_inputs)
            alone[rows] = _residuals(x[rows], v[rows], constant)
    found = judged & (fit <= FIRST_ORDER_FIT) & (alone >= INPUT_NEEDED)
    return [int(i) for i in np.flatnonzero(found)]


def first_order_problem(rows: list[int], names: dict[str, list[str]], how: str) -> str:
    """The refusal for positions ``rows`` whose "velocities" are the rates of first-order states: names them, says
    why and gives the options that record the other pairs (the mechanical states), where any are left.  ``names``:
    ``{"positions": [...], "velocities": [...]}`` of the recorded run; ``how``: how the pairing was made ("paired by
    a guess", "paired by the data")."""
    positions, velocities = names["positions"], names["velocities"]
    shown = "; ".join(f"{velocities[i]}, {how} as the velocity of {positions[i]}, is a function of "
                      f"{positions[i]} and the inputs at each sample" for i in rows[:3]) + ("; ..." if len(rows) > 3
                                                                                          else "")
    states = few_names([positions[i] for i in rows])
    verb = "is" if len(rows) == 1 else "are"
    kept = [i for i in range(len(positions)) if i not in set(rows)]
    every = patterns_said(positions=",".join(positions), velocities=",".join(velocities))
    mechanical = patterns_said(positions=",".join(positions[i] for i in kept),
                               velocities=",".join(velocities[i] for i in kept))
    advice = (f"to record the mechanical states, pass {mechanical} (the ROM then lacks {states}'s lag where it "
              f"drives the masses); to keep {states} as a coordinate, approximated by a stiff mass, pass {every}"
              if kept else f"pass {POSITIONS_VELOCITIES} naming the mechanical states")
    return (f"{shown} (a mass's velocity is not: it carries the history of the forces): {states} {verb} a "
            "first-order state, neither positions nor velocities (an actuator lag, a filter or a controller state?), "
            f"which a reduced model of the mechanical states cannot follow; {advice} (a mass so damped that its "
            f"velocity settles within one step looks the same: if that is one, record at a smaller {either('--dt')})")


def refuse_first_order_rates(label: str, x: np.ndarray, v: np.ndarray, u: np.ndarray | None,
                             names: dict[str, list[str]], how: str) -> None:
    """Raise :class:`FMUError` (``label: ...``, :func:`first_order_problem`) where a guessed pairing's velocities
    include rates of first-order states (:func:`first_order_rates`); nothing otherwise."""
    rows = first_order_rates(x, v, u)
    if rows:
        raise FMUError(f"{label}: {first_order_problem(rows, names, how)}")
