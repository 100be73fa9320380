"""The time grid, the inputs in effect on it, and rates derived from recorded samples."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._stepping import recorded_stepping
from .._validate import check_grid, check_number, either
from ..errors import DimensionError, InputSpecError

__all__ = ["time_grid", "inputs_in_effect", "newmark_rates", "newmark_accelerations",
           "newmark_velocities_and_accelerations", "constant_input_pieces", "continuous_accelerations",
           "interval_averages", "continuous_recording", "hermite_rule_corrections", "HERMITE_POINTS"]

#: Points of the Hermite stencils of :func:`continuous_accelerations` and :func:`interval_averages`
#: (polynomial degree ``2 * HERMITE_POINTS - 1`` through positions and velocities).
HERMITE_POINTS = 6


def time_grid(dt: float, t_end: float, t0: float = 0.0) -> np.ndarray:
    """Uniform grid ``t0, t0+dt, ...`` up to ``t_end`` (the last point is the largest ``<= t_end``).

    Parameters
    ----------
    dt : float
        Step, positive.
    t_end : float
        End time, greater than ``t0``.
    t0 : float, default=0.0

    Returns
    -------
    (k,) ndarray
        ``t0 + dt * arange(k)`` (no accumulated round-off).
    """
    for value, name in ((dt, "dt"), (t_end, "t_end"), (t0, "t0")):   # (audit 81c F7: "'>' not supported ...")
        check_number(value, name)
    if not (dt > 0 and math.isfinite(dt)):
        raise InputSpecError(f"step dt={dt} must be positive and finite")
    if not (t_end > t0 and math.isfinite(t_end)):
        raise InputSpecError(f"end time {t_end} must be finite and after the start time {t0}")
    check_grid(dt, t_end, t0)  # e.g. an FMU's default step of 1e-300: one line instead of a MemoryError
    k = int(math.floor((t_end - t0) / dt * (1 + 1e-12) + 1e-9)) + 1
    if k < 2:
        raise InputSpecError(f"step dt={dt} is longer than the time window {t_end - t0}; decrease {either('--dt')}")
    return t0 + dt * np.arange(k)


def inputs_in_effect(signal: Any, t: np.ndarray, m: int) -> np.ndarray:
    """The inputs in effect ``(m, k)``: ``u[:, 0] = u(t_0)``, ``u[:, i] = u(t_{i-1})`` (design.md).

    Parameters
    ----------
    signal : Signal
        Anything with ``sample(t) -> (m, k)``.
    t : (k,) ndarray
    m : int
        Number of inputs the source expects.
    """
    sampled = np.atleast_2d(np.asarray(signal.sample(np.asarray(t)), dtype=float))
    if sampled.shape[0] != m:
        fix = (f"give a signal with {m} channels" if m else
               f"give {either('--input', 'signal', 'none')} (the free response from the start state)")
        raise DimensionError(f"the input signal has {sampled.shape[0]} channel(s) but the source has "
                             f"{f'm={m} inputs' if m else 'no inputs'}; {fix}")
    if sampled.shape[1] != len(t):
        raise DimensionError(f"signal.sample returned {sampled.shape[1]} samples for {len(t)} times")
    if not np.all(np.isfinite(sampled)):
        raise InputSpecError(f"the input signal has non-finite values; check {either('--input')}")
    held = np.empty_like(sampled)
    held[:, 0] = sampled[:, 0]
    held[:, 1:] = sampled[:, :-1]
    return held


def newmark_rates(x: np.ndarray, h: float) -> np.ndarray:
    """Rates ``r`` of samples ``x`` consistent with Newmark (beta=1/4, gamma=1/2).

    Solves ``x_{i+1} - x_i = h/2 (r_i + r_{i+1})`` for all ``i`` (velocities from positions:
    ``x_{i+1} = x_i + h v_i + h^2/4 (a_i + a_{i+1})`` with ``v_{i+1} = v_i + h/2 (a_i + a_{i+1})``
    gives exactly this relation; accelerations from velocities are the second one).  The relation
    fixes ``r`` up to an alternating sequence ``alpha (-1)^i`` per row; ``alpha`` is chosen to make
    ``r`` as smooth as possible (least squares on its first differences).

    Parameters
    ----------
    x : (n, k) ndarray
    h : float
        Uniform step.

    Returns
    -------
    (n, k) ndarray
    """
    x = np.asarray(x, dtype=float)
    n, k = x.shape
    if k < 2:
        return np.zeros_like(x)
    s = (2.0 / h) * np.diff(x, axis=1)  # r_i + r_{i+1}
    sign = np.where(np.arange(k) % 2 == 0, 1.0, -1.0)
    c = np.zeros_like(x)
    c[:, 1:] = -sign[1:] * np.cumsum(sign[:-1] * s, axis=1)  # particular solution with r_0 = 0
    d = np.diff(c, axis=1)
    alpha = (d @ sign[:-1]) / (2.0 * (k - 1))
    return c + alpha[:, None] * sign


def _alternating_solution(rhs: np.ndarray, sign: np.ndarray) -> np.ndarray:
    """The solution of ``r_i + r_{i+1} = rhs_i`` with ``r_0 = 0`` (rows independent)."""
    out = np.zeros((rhs.shape[0], rhs.shape[1] + 1))
    out[:, 1:] = -sign[1:] * np.cumsum(sign[:-1] * rhs, axis=1)
    return out


def newmark_accelerations(xdot: np.ndarray, h: float, x: np.ndarray, u: np.ndarray | None = None,
                          rank_tol: float = 1e-9) -> np.ndarray:
    """Accelerations of Newmark data (beta=1/4, gamma=1/2) recorded with the project's input convention.

    The recorded ``a_i`` pairs with the input in effect ``u_i`` (design.md); at the start of step
    ``i -> i+1`` the integrator updates it to ``a_i^+ = a_i + Z (u_{i+1} - u_i)`` for the new input,
    then ``v_{i+1} = v_i + h/2 (a_i^+ + a_{i+1})``.  So ``(2/h)(v_{i+1} - v_i) = a_i + a_{i+1} +
    Z (u_{i+1} - u_i)``: the trapezoid relation of :func:`newmark_rates` breaks at every input change.
    Per degree of freedom this fixes ``a`` up to the alternating sequence ``(-1)^i`` and the unknown row
    ``Z`` (m values).  Both are chosen so that ``a - Z' u`` lies in the span of the recorded time series
    ``x_j(t)``, ``v_j(t)`` and 1 for some row ``Z'`` (least squares), which holds exactly for a linear model
    ``a = P x + Q v + Z' u + c``, constrained or not.  ``Z`` and ``Z'`` are separate unknowns, so data of an
    integrator without the update (``Z = 0``) are recovered as well.  When that span is too large to tell (fewer samples
    than about twice its dimension), the smoothest solution of :func:`newmark_rates` with the jumps is used.

    Parameters
    ----------
    xdot : (n, k) ndarray
        Velocities.
    h : float
        Uniform step.
    x : (n, k) ndarray
        Positions (they span, with the velocities, the time series ``a - Z u`` lies in).
    u : (m, k) ndarray, optional
        Inputs in effect (``u[:, i]`` pairs with ``a[:, i]``).
    rank_tol : float, default=1e-9
        Singular values of the (block-normalized) time series below ``rank_tol`` times the largest are
        treated as zero.

    Returns
    -------
    (n, k) ndarray
    """
    xdot = np.asarray(xdot, dtype=float)
    if xdot.shape[1] < 2:
        return np.zeros_like(xdot)
    return _accelerations(xdot, h, np.asarray(x, dtype=float), u, rank_tol, velocity_mode=False)[1]


def newmark_velocities_and_accelerations(x: np.ndarray, h: float, u: np.ndarray | None = None,
                                         rank_tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Velocities and accelerations of Newmark positions (a source exposing positions only).

    The velocities follow from ``x_{i+1} - x_i = h/2 (v_i + v_{i+1})`` up to an alternating sequence
    per degree of freedom; its size is fixed together with the unknowns of :func:`newmark_accelerations`
    (an alternating error ``b (-1)^i`` in ``v`` puts ``-(4/h) b i (-1)^i`` into ``a``, far from the
    span of the states).

    Parameters
    ----------
    x : (n, k) ndarray
    h : float
    u : (m, k) ndarray, optional
        Inputs in effect.
    rank_tol : float, default=1e-9

    Returns
    -------
    xdot, xddot : (n, k) ndarray
    """
    x = np.asarray(x, dtype=float)
    if x.shape[1] < 2:
        return np.zeros_like(x), np.zeros_like(x)
    xdot = _accelerations(newmark_rates(x, h), h, x, u, rank_tol, velocity_mode=True)[0]
    return xdot, _accelerations(xdot, h, x, u, rank_tol, velocity_mode=False)[1]  # again, on the corrected span


def _accelerations(xdot: np.ndarray, h: float, x: np.ndarray, u: np.ndarray | None, rank_tol: float,
                   velocity_mode: bool) -> tuple[np.ndarray, np.ndarray]:
    n, k = xdot.shape
    u = np.zeros((0, k)) if u is None else np.asarray(u, dtype=float).reshape(-1, k)
    sign = np.where(np.arange(k) % 2 == 0, 1.0, -1.0)
    m = u.shape[0]
    c = _alternating_solution((2.0 / h) * np.diff(xdot, axis=1), sign)
    columns = [sign]  # unknowns per row: the alternating mode of a, ...
    if velocity_mode:  # ... the alternating mode of v, ...
        columns.append(_alternating_solution((2.0 / h) * np.diff(sign)[None, :], sign)[0])
    jumps = _alternating_solution(-np.diff(u, axis=1), sign) if m else np.zeros((0, k))
    columns += [jumps[j] for j in range(m)]  # ... the jumps Z in the velocity relation, ...
    used = len(columns)
    columns += [-u[j] for j in range(m)]  # ... and the feedthrough Z' of the input in a
    modes = np.column_stack(columns)
    span = _time_series_span(x, xdot, rank_tol)
    if span is not None and k - span.shape[1] >= 2 * modes.shape[1] + 8:
        def residual(Y: np.ndarray) -> np.ndarray:
            return Y - span @ (span.T @ Y)
        A, b = residual(modes), -residual(c.T)
    else:  # the smoothest solution: least squares on first differences
        A, b = np.diff(modes, axis=0), -np.diff(c, axis=1).T
    theta = np.linalg.lstsq(A, b, rcond=None)[0]
    xddot = c + (modes[:, :used] @ theta[:used]).T
    if velocity_mode:
        xdot = xdot + theta[1][:, None] * sign
    return xdot, xddot


def _time_series_span(x: np.ndarray, xdot: np.ndarray, rank_tol: float) -> np.ndarray | None:
    """Orthonormal basis (k, q) of the span of the rows of x, xdot and a constant (each block scaled to
    unit norm); None when there is nothing to span."""
    k = x.shape[1]
    blocks = [b / np.linalg.norm(b) for b in (x, xdot) if b.size and np.linalg.norm(b) > 0]
    blocks.append(np.ones((1, k)) / math.sqrt(k))
    W = np.vstack(blocks)
    if W.shape[0] <= k:
        _, s, vt = np.linalg.svd(W, full_matrices=False)
        return vt[s > rank_tol * s[0]].T
    values, vectors = np.linalg.eigh(W.T @ W)  # more rows than samples: the k x k Gram
    keep = values > (rank_tol * math.sqrt(max(values.max(), 0.0))) ** 2
    return vectors[:, keep]


# ------------------------------------------------------------------ continuous-time recordings

def continuous_recording(provenance: dict[str, Any]) -> bool:
    """True for samples of a continuous-time model: another tool's FMU, or an fmu-opinf FMU that declares the exact
    hold step (an exported ROM of a continuous-time source); False for ``builtin:`` sources and fmu-opinf's Newmark
    FMUs, and for an fmu-opinf FMU that declares nothing (written before the declaration: the rule then was
    Newmark).  The rule of ``fit_rom(integrator="auto")`` (:func:`fmu_opinf._stepping.recorded_stepping`)."""
    return recorded_stepping(provenance) in ("continuous", "exact")


def constant_input_pieces(u: np.ndarray) -> list[tuple[int, int]]:
    """The smooth pieces of a recording under the zero-order-hold input convention.

    Interval ``[t_j, t_{j+1}]`` holds the input ``u[:, j+1]`` (design.md); a piece is a maximal run of
    intervals with the same held input, over which a linear model's response is analytic.

    Parameters
    ----------
    u : (m, k) ndarray
        Inputs in effect.

    Returns
    -------
    list of (start, end)
        Sample indices: piece ``(s, e)`` covers the samples ``s .. e`` (intervals ``s .. e-1``).
    """
    u = np.asarray(u, dtype=float)
    k = u.shape[1]
    if k < 2:
        return []
    held = u[:, 1:]
    breaks = (np.flatnonzero(np.any(np.diff(held, axis=1) != 0, axis=0)) + 1).tolist() if u.shape[0] else []
    starts = [0] + breaks
    return list(zip(starts, breaks + [k - 1]))


def _hermite_functional(points: int, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``(wx, wv)`` with ``L(p) = wx @ p(0..points-1) + wv @ p'(0..points-1)`` for the polynomial
    ``p`` of degree ``2 points - 1``, given ``values[q] = L(s^q)`` (scaled time, unit spacing)."""
    o = np.arange(points, dtype=float)
    q = np.arange(2 * points)
    vander = np.vstack([o[:, None] ** q, q * o[:, None] ** np.maximum(q - 1, 0)])
    w = np.linalg.solve(vander.T, values)
    return w[:points], w[points:]


def _stencil_apply(x: np.ndarray, xdot: np.ndarray, h: float, piece: tuple[int, int], targets: np.ndarray,
                   points: int, weights) -> np.ndarray:
    """``sum_j wx_j x[lo + j] + h wv_j xdot[lo + j]`` for each target, with the stencil of ``points`` samples
    inside ``piece`` as centred on the target as the piece allows; ``weights(L, offset)`` gives ``(wx, wv)``
    for a stencil of ``L`` points whose first one is ``offset`` steps before the target."""
    s, e = piece
    L = min(points, e - s + 1)
    lo = np.clip(targets - (L - 1) // 2, s, e + 1 - L)
    out = np.empty((x.shape[0], targets.size))
    for offset in np.unique(targets - lo):
        chosen = targets - lo == offset
        wx, wv = weights(L, int(offset))
        index = lo[chosen][:, None] + np.arange(L)
        out[:, chosen] = x[:, index] @ wx + h * (xdot[:, index] @ wv)
    return out


def _second_derivative_weights(points: int, offset: int) -> tuple[np.ndarray, np.ndarray]:
    q = np.arange(2 * points, dtype=float)
    values = q * (q - 1) * float(offset) ** np.maximum(q - 2, 0)
    values[q < 2] = 0.0
    return _hermite_functional(points, values)


def _average_weights(points: int, offset: int) -> tuple[np.ndarray, np.ndarray]:
    q = np.arange(2 * points, dtype=float)
    return _hermite_functional(points, ((offset + 1.0) ** (q + 1) - float(offset) ** (q + 1)) / (q + 1))


def continuous_accelerations(xdot: np.ndarray, h: float, x: np.ndarray, u: np.ndarray | None = None,
                             points: int = HERMITE_POINTS) -> np.ndarray:
    """Accelerations of a continuous-time recording (exact solution samples) under the zero-order hold.

    Within each piece of constant held input (:func:`constant_input_pieces`) the response is smooth; the
    acceleration at a sample is the second derivative of the Hermite polynomial (degree ``2 points - 1``)
    through the positions and velocities of ``points`` samples of the same piece.  Sample ``i >= 1`` pairs
    with the input held over ``[t_{i-1}, t_i]`` (the left limit, design.md), so it takes the piece of that
    interval.  Error ``O(h^(2L-2))`` with ``L`` the stencil size: ``L = points`` inside long pieces, but only
    ``L = 2`` (cubic, ``O(h^2)``) where the input changes at every step.  The fit does not use these values
    for such recordings: see :func:`interval_averages`.

    Parameters
    ----------
    xdot : (n, k) ndarray
        Velocities.
    h : float
        Uniform step.
    x : (n, k) ndarray
        Positions.
    u : (m, k) ndarray, optional
        Inputs in effect (default: no input, one piece).
    points : int, default=HERMITE_POINTS

    Returns
    -------
    (n, k) ndarray
    """
    x, xdot = np.asarray(x, dtype=float), np.asarray(xdot, dtype=float)
    k = x.shape[1]
    if k < 2:
        return np.zeros_like(x)
    u = np.zeros((0, k)) if u is None else np.asarray(u, dtype=float).reshape(-1, k)
    a = np.empty_like(x)
    for s, e in constant_input_pieces(u):
        targets = np.arange(s if s == 0 else s + 1, e + 1)
        a[:, targets] = _stencil_apply(x, xdot, h, (s, e), targets, points, _second_derivative_weights) / h ** 2
    return a


def interval_averages(x: np.ndarray, xdot: np.ndarray, u: np.ndarray, h: float,
                      points: int = HERMITE_POINTS) -> tuple[np.ndarray, ...]:
    """Interval-averaged triples of a continuous-time recording: exact equation-of-motion data without accelerations.

    Over ``[t_j, t_{j+1}]`` with the input ``u_j`` held, the averages of ``M a + D v + K x = B u + f`` give
    ``M (v_{j+1} - v_j)/h + D (x_{j+1} - x_j)/h + K xbar_j = B u_j + f`` exactly, with ``xbar_j`` the mean of
    ``x`` over the interval.  ``xbar_j`` is the integral of the Hermite polynomial through the positions and
    velocities of up to ``points`` samples of the interval's piece (:func:`constant_input_pieces`): error
    ``O(h^(2L))``, at worst the Hermite rule ``h/2 (x_j + x_{j+1}) + h^2/12 (v_j - v_{j+1})`` (``O(h^4)``)
    where the input changes at every step.  Averages are linear in time, so they may be taken of reduced
    (projected, centred) data.

    Parameters
    ----------
    x, xdot : (n, k) ndarray
        Positions and velocities at the samples.
    u : (m, k) ndarray
        Inputs in effect (``u[:, j+1]`` is held over interval ``j``).
    h : float
        Uniform step.
    points : int, default=HERMITE_POINTS

    Returns
    -------
    abar, vbar, xbar : (n, k-1) ndarray
        Mean acceleration, velocity and position over each interval.
    u_held : (m, k-1) ndarray
        The input held over each interval.
    """
    x, xdot = np.asarray(x, dtype=float), np.asarray(xdot, dtype=float)
    u = np.asarray(u, dtype=float).reshape(-1, x.shape[1])
    xbar = np.empty((x.shape[0], max(x.shape[1] - 1, 0)))
    for s, e in constant_input_pieces(u):
        xbar[:, s:e] = _stencil_apply(x, xdot, h, (s, e), np.arange(s, e), points, _average_weights)
    return np.diff(xdot, axis=1) / h, np.diff(x, axis=1) / h, xbar, u[:, 1:]


def hermite_rule(x0: np.ndarray, x1: np.ndarray, v0: np.ndarray, v1: np.ndarray, h: float) -> np.ndarray:
    """The two-point Hermite rule for the mean of ``x`` over an interval of length ``h``:
    ``(x0 + x1) / 2 + h (v0 - v1) / 12`` (exact for cubics, error ``O(h^4)``)."""
    return 0.5 * (x0 + x1) + h / 12.0 * (v0 - v1)


def hermite_rule_corrections(M: np.ndarray, D: np.ndarray, K: np.ndarray, force: np.ndarray, x0: np.ndarray,
                             v0: np.ndarray, h: float) -> np.ndarray:
    """What the two-point Hermite rule misses of the interval mean of ``x``, for a given linear model.

    For each interval ``j`` the model ``M x'' + D x' + K x = force_j`` (force held) starts at ``(x0_j, v0_j)``;
    the result is its exact mean position over ``[0, h]`` minus ``h/2 (x_0 + x_h) + h^2/12 (v_0 - v_h)``
    (divided by ``h``) of the same trajectory.  Added to the Hermite rule of recorded data, it corrects the
    ``O(h^4)`` quadrature error up to the model's own error (a deferred correction: the fit supplies the model).

    Parameters
    ----------
    M, D, K : (r, r) ndarray
        The model (``M`` invertible).
    force : (r, q) ndarray
        Force held over each interval.
    x0, v0 : (r, q) ndarray
        State at the start of each interval.
    h : float
        Interval length.

    Returns
    -------
    (r, q) ndarray
    """
    import scipy.linalg  # only the fit needs it, not the recorder's start-up

    r = M.shape[0]
    A = np.block([[np.zeros((r, r)), np.eye(r)], [-np.linalg.solve(M, K), -np.linalg.solve(M, D)]])
    size = 2 * r
    block = np.zeros((3 * size, 3 * size))
    block[:size, :size] = A * h
    block[:size, size:2 * size] = np.eye(size) * h
    block[size:2 * size, 2 * size:] = np.eye(size) * h
    E = scipy.linalg.expm(block)
    phi, gamma, delta = E[:size, :size], E[:size, size:2 * size], E[:size, 2 * size:]  # int_0^h (h - s) e^(As) ds
    z0 = np.vstack([x0, v0])
    w = np.vstack([np.zeros_like(force), np.linalg.solve(M, force)])
    mean = (gamma @ z0 + delta @ w)[:r] / h
    end = phi @ z0 + gamma @ w
    return mean - hermite_rule(x0, end[:r], v0, end[r:], h)
