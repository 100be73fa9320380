"""The time grid, the inputs in effect on it, and rates derived from recorded samples."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._validate import check_grid
from ..errors import DimensionError, InputSpecError

__all__ = ["time_grid", "inputs_in_effect", "newmark_rates"]


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
    if not (dt > 0 and math.isfinite(dt)):
        raise InputSpecError(f"step dt={dt} must be positive and finite")
    if not (t_end > t0 and math.isfinite(t_end)):
        raise InputSpecError(f"end time {t_end} must be finite and after the start time {t0}")
    check_grid(dt, t_end, t0)  # e.g. an FMU's default step of 1e-300: one line instead of a MemoryError
    k = int(math.floor((t_end - t0) / dt * (1 + 1e-12) + 1e-9)) + 1
    if k < 2:
        raise InputSpecError(f"step dt={dt} is longer than the time window {t_end - t0}; decrease --dt")
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
        raise DimensionError(f"the input signal has {sampled.shape[0]} channels but the source has m={m} inputs; "
                             f"give a signal with {m} channels")
    if sampled.shape[1] != len(t):
        raise DimensionError(f"signal.sample returned {sampled.shape[1]} samples for {len(t)} times")
    if not np.all(np.isfinite(sampled)):
        raise InputSpecError("the input signal has non-finite values; check --input")
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
