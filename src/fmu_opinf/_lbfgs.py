"""Limited-memory BFGS for the output-error refinement, with the inverse Hessian in compact form (issue 16).

SciPy's L-BFGS-B spent 1.5 ms of its own per iteration at 3710 unknowns and 100 correction pairs (the refinement
at r = 35: a quarter of its time) and holds the GIL meanwhile, so the refinement's second start could not run
beside the first.  Here the direction ``d = -H g`` comes from the compact representation of the inverse BFGS
matrix (Byrd, Nocedal, Schnabel 1994) of the last ``memory`` pairs ``s_i = x_(i+1) - x_i``,
``y_i = g_(i+1) - g_i`` with ``H_0 = gamma I``, ``gamma = s^T y / y^T y`` of the newest pair::

    H g = gamma g + S p - gamma Y t,   t = R^-1 (S^T g),   p = R^-T ((D + gamma Y^T Y) t - gamma Y^T g)

(``R`` the upper triangle of ``S^T Y`` in the order the pairs came, ``D`` its diagonal): three passes over the
stored pairs per iteration (:class:`_Pairs`), all in NumPy, which releases the GIL.
For an unconstrained problem this is the direction of L-BFGS-B (its Cauchy point has no breakpoints, and its
subspace step is the full quasi-Newton step); the step length follows the same strong Wolfe conditions
(sufficient decrease 1e-3, curvature 0.9), trying the unit step first (the first iteration a step of unit
length), the same test of positive curvature decides whether a pair is kept, and a failed line search forgets
the pairs once.  The stopping tests are L-BFGS-B's but for one change: the relative decrease is measured against
the objective itself, not against ``max(|f|, 1)``, so an objective that goes to zero (exact data) is followed to
its rounding floor (a test case with a wrong start map: training error 1e-28 instead of 1e-21, outputs to 2e-13
instead of 2e-10).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["LBFGSResult", "minimize_lbfgs"]

#: Sufficient-decrease and curvature constants of the strong Wolfe conditions (those of L-BFGS-B).
_DECREASE, _CURVATURE = 1e-3, 0.9
#: Relative width of the step bracket at which the zoom ends with its best point (L-BFGS-B's ``xtol``).
_BRACKET_WIDTH = 0.1
#: Function evaluations per line search at most.
_MAX_LINE_EVALUATIONS = 20


@dataclass
class LBFGSResult:
    """Where :func:`minimize_lbfgs` ended: ``x``, ``fun``, ``jac``, ``nit`` iterations, ``nfev`` evaluations,
    ``success`` (a stopping test held, not the iteration limit or a failed line search) and ``message``."""

    x: np.ndarray
    fun: float
    jac: np.ndarray
    nit: int
    nfev: int
    success: bool
    message: str


class _Pairs:
    """The last ``memory`` correction pairs, stacked as rows ``[S; Y]`` of one array, with ``S^T Y`` and
    ``Y^T Y`` kept up to date.

    Large problems are bound by the passes over the stored pairs (r = 100: 200 rows of 30100 values, 48 MB), so
    an iteration makes three of them instead of four: :meth:`add` projects the step and the new gradient, takes
    ``[S; Y] y`` as the difference of the new and the previous gradient's projections (the one :meth:`direction`
    made), and keeps the new gradient's projection for the next :meth:`direction`, whose one pass forms the
    direction.
    """

    def __init__(self, n: int, memory: int) -> None:
        self.memory = memory
        self.rows = np.zeros((2 * memory, n))  # S in rows 0..memory-1, Y in rows memory..2 memory-1
        self.SY = np.zeros((memory, memory))
        self.YY = np.zeros((memory, memory))
        self.order: list[int] = []  # slots, oldest first
        self._projected: tuple[np.ndarray, np.ndarray] | None = None  # (g, rows @ g) of the last gradient

    def _projection(self, g: np.ndarray) -> np.ndarray:
        if self._projected is None or self._projected[0] is not g:
            self._projected = (g, self.rows @ g)
        return self._projected[1]

    def add(self, s: np.ndarray, y: np.ndarray, gradient: np.ndarray | None = None,
            previous: np.ndarray | None = None) -> None:
        """Store the pair ``(s, y)``; ``y = gradient - previous`` where both gradients are given, which saves a
        pass when ``previous`` is the one the last :meth:`direction` was asked for."""
        slot = self.order.pop(0) if len(self.order) == self.memory else len(self.order)
        known = self._projected is not None and previous is not None and self._projected[0] is previous
        if known and gradient is not None:
            with_s, with_g = self.rows @ s, self.rows @ gradient  # two products: one of two columns is slower
            with_y = with_g - self._projected[1]
        else:
            with_s, with_y = self.rows @ s, self.rows @ y  # [S^T s; Y^T s], [S^T y; Y^T y]
            with_g = None
        self.rows[slot], self.rows[self.memory + slot] = s, y
        with_s[slot], with_s[self.memory + slot] = s @ s, y @ s
        with_y[slot], with_y[self.memory + slot] = s @ y, y @ y
        S_y, Y_s, Y_y = with_y[:self.memory], with_s[self.memory:], with_y[self.memory:]
        self.SY[:, slot], self.SY[slot, :] = S_y, Y_s
        self.YY[:, slot] = self.YY[slot, :] = Y_y
        self.order.append(slot)
        if with_g is None:
            self._projected = None
        else:
            with_g[slot], with_g[self.memory + slot] = s @ gradient, y @ gradient
            self._projected = (gradient, with_g)

    def direction(self, g: np.ndarray) -> np.ndarray:
        """``-H g``."""
        if not self.order:
            return -g
        idx = np.array(self.order)
        newest = idx[-1]
        gamma = self.SY[newest, newest] / self.YY[newest, newest]
        projections = self._projection(g)
        a, b = projections[idx], projections[self.memory + idx]
        SY = self.SY[np.ix_(idx, idx)]
        R = np.triu(SY)
        t = _solve_upper(R, a)
        p = _solve_upper(R.T, (np.diag(SY) * t + gamma * (self.YY[np.ix_(idx, idx)] @ t)) - gamma * b, lower=True)
        weights = np.zeros(2 * self.memory)
        weights[idx], weights[self.memory + idx] = p, -gamma * t
        return -(gamma * g + weights @ self.rows)


def _solve_upper(R: np.ndarray, b: np.ndarray, lower: bool = False) -> np.ndarray:
    return scipy.linalg.solve_triangular(R, b, lower=lower, check_finite=False)


def minimize_lbfgs(fun: Callable[[np.ndarray], tuple[float, np.ndarray]], x0: np.ndarray, *, max_iterations: int,
                   memory: int = 100, ftol: float = 1e-13, gtol: float = 1e-12,
                   callback: Callable[[LBFGSResult], None] | None = None) -> LBFGSResult:
    """Minimize ``fun`` (value and gradient) from ``x0`` by L-BFGS (module docstring).

    Stops when the largest gradient entry is at most ``gtol``, when the objective fell by at most ``ftol`` times
    ``max(|f_old|, |f_new|)`` in an iteration (relative also below 1, unlike L-BFGS-B's test: an objective that
    converges to zero, as on exact data, goes on until its rounding floor), after ``max_iterations`` iterations, or when ``callback``
    (called with the iterate after each iteration) raises ``StopIteration``.
    """
    x = np.array(x0, dtype=float)
    f, g = fun(x)
    state = LBFGSResult(x, float(f), g, 0, 1, False, "iteration limit")
    pairs = _Pairs(x.size, memory)
    if np.max(np.abs(g), initial=0.0) <= gtol:
        state.success, state.message = True, "gradient below gtol"
        return state
    while state.nit < max_iterations:
        d = pairs.direction(state.jac)
        slope = float(state.jac @ d)
        if not slope < 0:  # round-off made the direction useless: start the memory again
            pairs = _Pairs(x.size, memory)
            d, slope = -state.jac, -float(state.jac @ state.jac)
        first = 1.0 if pairs.order else min(1.0 / float(np.linalg.norm(d)), 1e10)
        found, evaluations = _line_search(fun, state, d, slope, first)
        state.nfev += evaluations
        if found is None:
            if not pairs.order:
                state.message = "line search failed"
                return state
            pairs = _Pairs(x.size, memory)  # as L-BFGS-B: forget the pairs, try the steepest descent once
            continue
        step, f_new, g_new = found
        s, y = step * d, g_new - state.jac
        if float(s @ y) > np.finfo(float).eps * step * -slope:  # L-BFGS-B's test of positive curvature
            pairs.add(s, y, gradient=g_new, previous=state.jac)
        f_old = state.fun
        state.x, state.fun, state.jac, state.nit = state.x + s, float(f_new), g_new, state.nit + 1
        if callback is not None:
            try:
                callback(state)
            except StopIteration:
                state.message = "stopped by callback"
                return state
        if np.max(np.abs(g_new)) <= gtol:
            state.success, state.message = True, "gradient below gtol"
            return state
        if f_old - state.fun <= ftol * max(abs(f_old), abs(state.fun)):
            state.success, state.message = True, "relative reduction below ftol"
            return state
    return state


def _line_search(fun, state: LBFGSResult, d: np.ndarray, slope: float,
                 step: float) -> tuple[tuple[float, float, np.ndarray] | None, int]:
    """A step along ``d`` meeting the strong Wolfe conditions: bracket, then zoom by safeguarded cubic
    interpolation (Nocedal and Wright, algorithms 3.5 and 3.6).

    Like L-BFGS-B's line search, the zoom also ends once the bracket is narrower than a tenth of its larger end
    (there the curvature condition is not worth more evaluations), with the best point of sufficient decrease.
    Returns ``((step, f, g), evaluations)``; ``None`` instead of the point when no trial decreased ``f``
    sufficiently within :data:`_MAX_LINE_EVALUATIONS` evaluations.
    """
    f0 = state.fun
    previous = (0.0, f0, slope)
    best = None
    lo = hi = None
    for evaluation in range(1, _MAX_LINE_EVALUATIONS + 1):
        f, g = fun(state.x + step * d)
        f = float(f)
        dphi = float(g @ d)
        decrease = f <= f0 + _DECREASE * step * slope and np.isfinite(f)
        if decrease and (best is None or f < best[1]):
            best = (step, f, g)
        if decrease and abs(dphi) <= _CURVATURE * abs(slope):
            return (step, f, g), evaluation
        point = (step, f if np.isfinite(f) else np.inf, dphi if np.isfinite(dphi) else np.inf)
        if lo is None:
            if not decrease or (evaluation > 1 and f >= previous[1]):
                lo, hi = previous, point
            elif dphi >= 0:
                lo, hi = point, previous
            else:
                previous, step = point, 4.0 * step
                continue
        else:
            if not decrease or f >= lo[1]:
                hi = point
            else:
                if dphi * (hi[0] - lo[0]) >= 0:
                    hi = lo
                lo = point
        if best is not None and abs(hi[0] - lo[0]) <= _BRACKET_WIDTH * max(lo[0], hi[0]):
            return best, evaluation
        step = _cubic_step(lo, hi)
    return best, _MAX_LINE_EVALUATIONS


def _cubic_step(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> float:
    """The minimizer of the cubic through the bracket ends (value and slope at each), kept at least a tenth of
    the interval away from both ends; a tenth of the way from ``lo`` where ``hi`` has no finite value (so that
    an overflowing trial step shrinks tenfold per evaluation), the midpoint where the cubic has no minimizer."""
    (a, fa, da), (b, fb, db) = lo, hi
    left, right = min(a, b), max(a, b)
    margin = 0.1 * (right - left)
    if not (np.isfinite(fb) and np.isfinite(db)):
        return a + 0.1 * (b - a)
    d1 = da + db - 3.0 * (fa - fb) / (a - b)
    radicand = d1 * d1 - da * db
    if radicand < 0:
        return 0.5 * (left + right)
    d2 = np.copysign(np.sqrt(radicand), b - a)
    denominator = db - da + 2.0 * d2
    if denominator == 0:
        return 0.5 * (left + right)
    step = b - (b - a) * (db + d2 - d1) / denominator
    return float(min(max(step, left + margin), right - margin))
