"""Outputs that no linear model of the recorded states can give (audit 77a, F1).

A real FMU may record an output that is not linear in the state: an energy, a slanted cable's length
``sqrt((L + x)^2 + h^2)``, an ``atan2`` angle.  Its model description looks like a linear sensor's, and the
default selection records it.  Eq. (17) still gives it as well as a linear map can, but where the output-error
refinement, the least-squares candidate's choice and the ``--terms auto`` decision weigh it beside the others, the
learned dynamics bend toward it and every output goes off (audit 77a: linear outputs 0.9-8.7 % of their range off
and a pole at 189 rad/s against a true 9.87, where ``--no-refine`` was exact to 3e-15).

:func:`nonlinear_outputs` finds such outputs by least squares of each output from the reduced positions,
velocities, inputs and a constant on the basis the extra terms are decided on (the snapshot rank or
:data:`fmu_opinf.fit.TERM_DECISION_ORDER` modes): what is left of the output's variation is round-off for a linear
output where that basis spans the snapshots, and the projection error's share where it does not (judged against
:data:`PROJECTION_MARGIN` times that share), where products of two and three leading coordinates then explain the
miss (:data:`POLYNOMIAL_EXPLAINS`; an output of a state that was not recorded is no such function and is left to the
fit's training-miss warning, which names --positions).  The fit leaves them out of what steers the dynamics; the ROM
still gives them by eq. (17).
"""

from __future__ import annotations

import itertools
import math
from typing import Any, Sequence

import numpy as np

__all__ = ["LINEAR_OUTPUT_RESIDUAL", "PROJECTION_MARGIN", "nonlinear_outputs", "output_linear_residuals"]

#: Residual of an output's least-squares fit from ``[q; q'; u; 1]``, relative to the output's variation (its RMS
#: about its mean), above which the output is taken for one that no linear model of the recorded states gives.
#: Measured on audit 77a's FMUs (3-mass chain, exact hold step, the default recording's impulse, 1559-2851
#: samples): the linear outputs x1, x3 and the force sensor y = u 3e-16 .. 1.2e-15 (constout, energy, cable alike),
#: the cable length sqrt((2 + x3)^2 + 1) 0.47, the energy 15 x3^2 + v3^2 / 2 0.98.  1e-6 lies nine decades above
#: the one (room for outputs computed in single precision, about 6e-8) and five below the other; the cable's
#: residual shrinks with the motion (the same recording scaled: 0.015 at a tenth, 1.5e-3 at a hundredth, x3 peak
#: 0.046 against a cable of 2.2), still three decades above the bar.
LINEAR_OUTPUT_RESIDUAL = 1e-6

#: Factor on the basis' relative projection error of the snapshots (the largest of the positions', velocities' and
#: accelerations', :func:`fmu_opinf.fit._order_fit._projection_error`) by which the bar is raised where that basis
#: does not span them: a linear output misses by about the share of the state outside the basis.  Measured on a
#: 12-mass chain (``chain_model(12)``: outputs a position, a velocity, two accelerations; impulse, 1501 samples) on
#: its leading 10 / 8 / 6 position modes: projection error 0.030 / 0.11 / 0.43 (the accelerations'), the linear
#: outputs at most 0.080 / 0.15 / 0.29 of their variation (2.6 / 1.3 / 0.7 times it), the kinetic energy 0.84 /
#: 0.86 / 0.87 (not found there: the bar is above it); on an 80-mass chain (basis of 60 modes, snapshot rank 70):
#: projection error 1.2e-6 (the largest of the three), the linear outputs 4e-15 .. 5.8e-14, the kinetic energy
#: 0.068 (found).  100 is 38 times the worst ratio of a linear output.
PROJECTION_MARGIN = 100.0

#: Variation (peak to peak) relative to an output's magnitude below which it is taken for a constant (a parameter
#: echoed as an output, round-off around it): no fit judges it.
CONSTANT_OUTPUT = 1e-12


def output_linear_residuals(x: np.ndarray, xdot: np.ndarray, u: np.ndarray, y: np.ndarray) -> list[float | None]:
    """Each output's residual of its least-squares fit from ``[x; xdot; u; 1]``, relative to its variation.

    Parameters
    ----------
    x, xdot : (r, k) ndarray
        Reduced (or full) positions and velocities of all runs side by side.
    u : (m, k) ndarray
        Inputs at the same samples.
    y : (p, k) ndarray
        Outputs at the same samples.

    Returns
    -------
    list of float or None
        ``||y_j - fit_j|| / ||y_j - mean(y_j)||`` per output; None for a constant output
        (:data:`CONSTANT_OUTPUT`), which no residual can judge.

    Notes
    -----
    The columns are scaled to unit norm and the range is taken from an SVD cut at ``1e-12`` of the largest
    singular value, so a rank-deficient set (positions under a constraint, an input that is zero) does not lend a
    spurious direction to the fit.
    """
    k = y.shape[1]
    A = np.vstack([x, xdot, u, np.ones((1, k))]).T
    norms = np.linalg.norm(A, axis=0)
    A = A[:, norms > 0] / norms[norms > 0]
    U, s, _ = np.linalg.svd(A, full_matrices=False)
    Q = U[:, s > 1e-12 * s[0]] if s.size else U[:, :0]
    out: list[float | None] = []
    for row in np.asarray(y, dtype=float):
        variation = row - row.mean()
        if not np.ptp(row) > CONSTANT_OUTPUT * max(float(np.abs(row).max()), 1e-300):
            out.append(None)
            continue
        residual = row - Q @ (Q.T @ row)
        out.append(float(np.linalg.norm(residual) / np.linalg.norm(variation)))
    return out


def nonlinear_outputs(data: dict[str, np.ndarray], projection_error: float, names: Sequence[str],
                      held: Sequence[str] = ()) -> dict[str, Any]:
    """The outputs that no linear model of the recorded states gives, as ``fit_info["nonlinear_outputs"]``.

    Parameters
    ----------
    data : dict
        Reduced data ``x, xdot, u, y`` on the basis the extra terms are decided on.
    projection_error : float
        That basis' relative projection error of the snapshots (``sqrt(1 - E)``), which raises the bar
        (:data:`PROJECTION_MARGIN`).
    names : sequence of str
        The outputs' names (``y[j]`` where the snapshots have none).
    held : sequence of str
        Outputs held between samples: judged by their own warning (audit 73 F3), not here.

    Returns
    -------
    dict
        ``outputs`` (0-based indices of the outputs above the bar), ``names``, ``residuals`` (every output's,
        None where constant or held), ``threshold`` and ``left_out``: whether the fit leaves ``outputs`` out of
        what steers the dynamics (False where every varying output is among them: nothing would be left to judge
        a fit by).
    """
    threshold = max(LINEAR_OUTPUT_RESIDUAL, PROJECTION_MARGIN * projection_error)
    residuals = output_linear_residuals(data["x"], data["xdot"], data["u"], data["y"])
    residuals = [None if name in held else value for name, value in zip(names, residuals)]
    above = [j for j, value in enumerate(residuals) if value is not None and value > threshold]
    polynomial = _polynomial_residuals(data, above)
    found = [j for j in above if polynomial[j] <= POLYNOMIAL_EXPLAINS * residuals[j]]
    judged = [j for j, value in enumerate(residuals) if value is not None]
    return {"outputs": found, "names": [names[j] for j in found], "residuals": residuals, "all_names": list(names),
            "polynomial_residuals": {int(j): polynomial[j] for j in above},
            "threshold": threshold if math.isfinite(threshold) else None,
            "left_out": bool(found) and len(found) < len(judged)}


#: An output above the bar is taken for a nonlinear function of the recorded states where adding polynomial terms
#: of the leading coordinates (:func:`_polynomial_terms`) to its least squares leaves at most this fraction of its
#: linear residual; else the miss is no function of the recorded states (a state that was not recorded: a velocity
#: recorded in place of a position, the eighth audit's case), which the fit's training-miss warning names with its
#: fix (--positions), and the output is not left out.  Measured on audit 77a's 3-mass chain (1501 samples): the
#: energy 2.5e-15, x3 cubed 4.7e-15, the cable length sqrt((2 + x3)^2 + 1) 1.5e-3; x3 where mass 3's velocity was
#: recorded in place of its position 3.4e-2 (and the eighth audit's two masses: test_rom).
POLYNOMIAL_EXPLAINS = 0.01
#: Leading reduced positions and velocities whose products of two (300 at 12) and of three (120 at 4) join that
#: least squares, fewer where the samples are fewer than :data:`SAMPLES_PER_TERM` times the terms (so many terms
#: would fit anything).
QUADRATIC_COORDINATES, CUBIC_COORDINATES, SAMPLES_PER_TERM = 12, 4, 4


def _polynomial_terms(x: np.ndarray, xdot: np.ndarray) -> np.ndarray:
    """Products of two of the leading :data:`QUADRATIC_COORDINATES` and of three of the leading
    :data:`CUBIC_COORDINATES` positions and velocities, one row per product."""
    rows: list[np.ndarray] = []
    quadratic = QUADRATIC_COORDINATES
    while quadratic > 1 and (quadratic * (2 * quadratic + 1) + 120) * SAMPLES_PER_TERM > x.shape[1]:
        quadratic -= 1
    for count, degree in ((quadratic, 2), (min(CUBIC_COORDINATES, quadratic), 3)):
        z = np.vstack([x[:count], xdot[:count]])
        rows += [np.prod(z[list(chosen)], axis=0)
                 for chosen in itertools.combinations_with_replacement(range(z.shape[0]), degree)]
    return np.array(rows).reshape(len(rows), x.shape[1])


def _polynomial_residuals(data: dict[str, np.ndarray], rows: list[int]) -> dict[int, float]:
    """Per output in ``rows``: its residual of least squares from ``[x; xdot; u; 1]`` and :func:`_polynomial_terms`,
    relative to its variation."""
    if not rows:
        return {}
    wide = np.vstack([data["x"], _polynomial_terms(data["x"], data["xdot"])])
    values = output_linear_residuals(wide, data["xdot"], data["u"], np.asarray(data["y"])[rows])
    return {j: (value if value is not None else 0.0) for j, value in zip(rows, values)}
