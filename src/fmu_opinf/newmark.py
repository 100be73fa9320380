"""Newmark integrators: constrained (index 2 and 3) for the full model, classical for the ROM.

Average-acceleration Newmark (beta = 1/4, gamma = 1/2) with the constraint embedded at
acceleration level and scaled as Bottasso, Dopico & Trainelli (2008), spec section 3::

    xp = x + h v + h^2 (1/2 - beta) a,        vp = v + h (1 - gamma) a
    [S G^T; G 0] [a+; mu] = [f - D vp - K xp; c],   S = M + gamma h D + beta h^2 K
    c = -G xp / (beta h^2)  (position constraint),  c = -G vp / (gamma h)  (velocity constraint)
    x+ = xp + beta h^2 a+,                     v+ = vp + gamma h a+

Input timing (spec section 4): the input is held over each step at its value at the start
of the step.  Force and acceleration are linked instantaneously, so when a new input value is
applied at the start of a step the current acceleration is first made consistent with it,
``a += Z (u_new - u_old)`` with ``[M G^T; G 0] [Z; L] = [B; 0]`` (exact for a linear system),
and the step then integrates a force that is constant over the step.  This keeps the scheme
second-order accurate for the piecewise-constant (zero-order-hold) input; using the stale
acceleration instead would lose half a step of impulse whenever the input changes (first order).
The recorded acceleration at ``t_{k+1}`` is the one consistent with the input held over the
step that ends there.

The saddle-point system is solved through S (factored once per step size, sparse LU for
sparse matrices, dense LU for small ROMs) and the nc x nc Schur complement ``G S^-1 G^T``, so a
step costs one sparse solve and a few sparse products: linear in n for the benchmarks.
Without G it is the classical Newmark method of the reduced ODE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._progress import Progress
from ._validate import either
from .errors import DataError, DimensionError
from .signals import Signal, parse_signal

__all__ = ["BETA", "GAMMA", "NewmarkStepper", "Trajectory", "time_grid", "applied_inputs", "simulate",
           "step_matrices"]

BETA = 0.25
GAMMA = 0.5

Matrix = np.ndarray | sp.spmatrix | sp.sparray


class _Solver:
    """Factorization of one square matrix, sparse or dense, with a ``solve`` method."""

    def __init__(self, A: Matrix) -> None:
        if sp.issparse(A):
            self._lu = spla.splu(sp.csc_matrix(A))
            self.solve = self._lu.solve
        else:
            self._lu = scipy.linalg.lu_factor(np.asarray(A, dtype=float), check_finite=True)
            self.solve = lambda b: scipy.linalg.lu_solve(self._lu, b, check_finite=False)


class _ConstrainedSolver:
    """Solve ``[A G^T; G 0] [z; mu] = [b; c]`` via A's factor and the Schur complement."""

    def __init__(self, A: Matrix, G: Matrix | None) -> None:
        self.A = _Solver(A)
        self.G = G
        if G is not None and G.shape[0] > 0:
            Gt = G.T.toarray() if sp.issparse(G) else np.asarray(G).T
            self.W = self.A.solve(np.asfortranarray(Gt))           # A^-1 G^T, (n, nc)
            self.schur = scipy.linalg.lu_factor(np.atleast_2d(G @ self.W))
        else:
            self.G = None

    def solve(self, b: np.ndarray, c: np.ndarray | None = None) -> np.ndarray:
        z = self.A.solve(b)
        if self.G is None:
            return z
        residual = self.G @ z - (0.0 if c is None else c)
        mu = scipy.linalg.lu_solve(self.schur, residual, check_finite=False)
        return z - self.W @ mu


class NewmarkStepper:
    """Advance ``M a + D v + K x (+ G^T mu) = B u`` step by step with the held input.

    Parameters
    ----------
    M, D, K : (n, n) sparse matrix or ndarray
        Mass, damping, stiffness.  S = M + h/2 D + h^2/4 K must be invertible.
    B : (n, m) sparse matrix or ndarray
        Input matrix.
    h : float
        Step size (> 0); change it with :meth:`set_step`.
    G : (nc, n) sparse matrix or ndarray, optional
        Constraint Jacobian; omit for an ODE (the classical Newmark method).
    constraint : {"position", "velocity"}, optional
        Which level ``G`` constrains (index 3 or index 2); required with G.

    Attributes
    ----------
    x, v, a : (n,) ndarray
        Current positions, velocities, accelerations.
    t : float
        Current time.
    """

    def __init__(self, M: Matrix, D: Matrix, K: Matrix, B: Matrix, h: float,
                 G: Matrix | None = None, constraint: str | None = None) -> None:
        self.M, self.D, self.K, self.B = M, D, K, B
        if G is not None and G.shape[0] == 0:
            G = None
        if G is not None and constraint not in ("position", "velocity"):
            raise DimensionError(f"constraint must be 'position' or 'velocity' with G, got {constraint!r}")
        self.G, self.constraint = G, constraint if G is not None else None
        self.n = M.shape[0]
        self.x = np.zeros(self.n)
        self.v = np.zeros(self.n)
        self.a = np.zeros(self.n)
        self.u = np.zeros(B.shape[1])
        self.t = 0.0
        self.h = 0.0
        self._mass_solver: _ConstrainedSolver | None = None
        self._input_response: np.ndarray | None = None
        self.set_step(h)

    def set_step(self, h: float) -> None:
        """Use step size ``h`` from now on; refactors S only when h changes."""
        if not h > 0:
            raise DimensionError(f"step size must be positive, got {h}")
        if h == self.h:
            return
        self.h = float(h)
        S = self.M + (GAMMA * h) * self.D + (BETA * h * h) * self.K
        self._step_solver = _ConstrainedSolver(S, self.G)

    def start(self, u0: np.ndarray, x0: np.ndarray | None = None, v0: np.ndarray | None = None,
              t0: float = 0.0) -> None:
        """Set a consistent initial state: x0, v0 (default zero) and the matching acceleration.

        Solves ``[M G^T; G 0] [a0; lambda0] = [B u0 - D v0 - K x0; 0]`` (spec section 3).
        x0 and v0 must satisfy the constraint.
        """
        self.x = np.zeros(self.n) if x0 is None else np.array(x0, dtype=float)
        self.v = np.zeros(self.n) if v0 is None else np.array(v0, dtype=float)
        if self.G is not None:
            scale = max(np.abs(self.x).max(), np.abs(self.v).max(), 1.0)
            violation = max(np.abs(self.G @ self.x).max(), np.abs(self.G @ self.v).max())
            if violation > 1e-12 * scale:
                raise DataError(f"initial state violates the constraint (|G x|, |G v| up to "
                                f"{violation:.2e}); start from a state in ker G")
        rhs = self._force(u0) - self.D @ self.v - self.K @ self.x
        self.a = self._mass_factor().solve(rhs)
        self.u = np.array(u0, dtype=float).reshape(-1)
        self.t = float(t0)

    def apply_input(self, u: np.ndarray) -> None:
        """Hold input ``u`` from now on: update the acceleration to be consistent with it."""
        u = np.asarray(u, dtype=float).reshape(-1)
        change = u - self.u
        if not np.all(np.isfinite(change)):
            raise DataError(f"input at t={self.t:g} is NaN or infinite; check the input signal")
        if np.any(change != 0.0):
            if self._input_response is None:
                B = self.B.toarray() if sp.issparse(self.B) else np.asarray(self.B, dtype=float)
                self._input_response = self._mass_factor().solve(B.reshape(self.n, -1))
            self.a = self.a + self._input_response @ change
            self.u = u

    def _mass_factor(self) -> _ConstrainedSolver:
        if self._mass_solver is None:
            self._mass_solver = _ConstrainedSolver(self.M, self.G)
        return self._mass_solver

    def step(self, u: np.ndarray) -> None:
        """Advance one step of size h with the input ``u`` held over the step."""
        self.apply_input(u)
        h = self.h
        xp = self.x + h * self.v + (h * h * (0.5 - BETA)) * self.a
        vp = self.v + (h * (1.0 - GAMMA)) * self.a
        rhs = self._force(self.u) - self.D @ vp - self.K @ xp
        c = None
        if self.constraint == "position":
            c = -(self.G @ xp) / (BETA * h * h)
        elif self.constraint == "velocity":
            c = -(self.G @ vp) / (GAMMA * h)
        self.a = self._step_solver.solve(rhs, c)
        self.x = xp + (BETA * h * h) * self.a
        self.v = vp + (GAMMA * h) * self.a
        self.t += h

    def _force(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float).reshape(-1)
        if not np.all(np.isfinite(u)):
            raise DataError(f"input at t={self.t:g} is NaN or infinite; check the input signal")
        return np.asarray(self.B @ u).reshape(-1)


def step_matrices(M: np.ndarray, D: np.ndarray, K: np.ndarray, B: np.ndarray,
                  h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The classical Newmark step of a small dense ODE as one linear map.

    For constant h the step of :class:`NewmarkStepper` (input update included) is linear:
    ``s+ = Phi s + Gamma_new u + Gamma_old u_old`` with ``s = [x; v; a]`` (3r,), ``u`` the input held over the
    step and ``u_old`` the one held over the previous step.  The matrices are built by applying the stepper's
    own formulas to unit vectors, so the map is the same scheme, evaluated as three matrix products.

    Returns
    -------
    Phi : (3r, 3r) ndarray
    Gamma_new, Gamma_old : (3r, m) ndarray
    """
    r, m = M.shape[0], B.shape[1]
    S = M + (GAMMA * h) * D + (BETA * h * h) * K
    lu_S = scipy.linalg.lu_factor(S)
    Z = scipy.linalg.solve(M, B)

    def step(x, v, a, u, u_old):
        a = a + Z @ (u - u_old)
        xp = x + h * v + (h * h * (0.5 - BETA)) * a
        vp = v + (h * (1.0 - GAMMA)) * a
        a_new = scipy.linalg.lu_solve(lu_S, B @ u - D @ vp - K @ xp)
        return np.vstack([xp + (BETA * h * h) * a_new, vp + (GAMMA * h) * a_new, a_new])

    unit = np.eye(3 * r)
    no_input = np.zeros((m, 3 * r))
    Phi = step(unit[:r], unit[r:2 * r], unit[2 * r:], no_input, no_input)
    rest = np.zeros((r, m))
    gamma_new = step(rest, rest, rest, np.eye(m), np.zeros((m, m)))
    gamma_old = step(rest, rest, rest, np.zeros((m, m)), np.eye(m))
    return Phi, gamma_new, gamma_old


@dataclass
class Trajectory:
    """A simulated run: times ``t (k,)``, applied inputs ``u (m, k)``, states ``(n, k)``, outputs ``y (p, k)``.

    Column ``i`` of ``u`` is the input in effect when the state at ``t[i]`` was computed
    (``u[:, 0] = u(t_0)``, ``u[:, i] = u(t_{i-1})``), so it pairs with ``xddot[:, i]``.
    """

    t: np.ndarray
    u: np.ndarray
    x: np.ndarray
    xdot: np.ndarray
    xddot: np.ndarray
    y: np.ndarray


#: Steps of one time grid at most (800 MB for its times alone): more is a mistake in ``--dt`` or ``--t-end``, or a
#: damaged file's (audit of 2026-12-06: a ROM file's training end of 1e15 s ended compare in a MemoryError).
MAX_GRID_STEPS = 100_000_000


def time_grid(dt: float, t_end: float, t0: float = 0.0) -> np.ndarray:
    """Equidistant grid ``t0, t0 + dt, ..., t_end``; t_end - t0 must be a whole number of steps, at most
    :data:`MAX_GRID_STEPS`."""
    if not (dt > 0 and math.isfinite(dt)):
        raise DimensionError(f"time step must be positive and finite, got dt={dt}")
    if not (t_end > t0 and math.isfinite(t_end)):
        raise DimensionError(f"end time must be finite and exceed the start time {t0}, got t_end={t_end}")
    if (t_end - t0) / dt > MAX_GRID_STEPS:
        raise DimensionError(f"t_end={t_end:g} at dt={dt:g} makes {(t_end - t0) / dt:.3g} steps, more than "
                             f"{MAX_GRID_STEPS:.0e}; pass a shorter {either('--t-end')} or a larger {either('--dt')}")
    steps = round((t_end - t0) / dt)
    if steps < 1 or abs(steps * dt - (t_end - t0)) > 1e-9 * max(1.0, abs(t_end)):
        raise DimensionError(f"t_end - t0 = {t_end - t0:g} is not a whole number of steps dt={dt:g}; "
                             f"adjust {either('--t-end')} or {either('--dt')}")
    return t0 + dt * np.arange(steps + 1)


def applied_inputs(signal: Signal, t: np.ndarray) -> np.ndarray:
    """Inputs in effect at each grid time under the zero-order hold: ``[u(t0), u(t0), ..., u(t_{k-2})]``."""
    held = signal.sample(t[:-1])
    if not np.all(np.isfinite(held)):
        raise DataError(f"input {signal.spec!r} has NaN or infinite values on the time grid")
    return np.concatenate([held[:, :1], held], axis=1)


def simulate(system, signal: Signal | str, dt: float, t_end: float,
             x0: np.ndarray | None = None, v0: np.ndarray | None = None, quiet: bool = True,
             on_step: Callable[[int, NewmarkStepper], None] | None = None) -> Trajectory:
    """Simulate a :class:`~fmu_opinf.systems.SecondOrderSystem` (or any object with M, D, K, G,
    constraint, B, Cp, Cv) on the grid ``0, dt, ..., t_end`` and record everything.

    Parameters
    ----------
    system : SecondOrderSystem
    signal : Signal or str
        Input; a string is parsed by :func:`fmu_opinf.signals.parse_signal`.
    dt, t_end : float
        Step and end time; ``t_end`` must be a whole number of steps.
    x0, v0 : (n,) ndarray, optional
        Consistent initial state (default zero).
    on_step : callable, optional
        Called as ``on_step(i, stepper)`` after each state ``i`` (including ``i = 0``).

    Returns
    -------
    Trajectory
    """
    signal = parse_signal(signal, system.B.shape[1])
    t = time_grid(dt, t_end)
    u = applied_inputs(signal, t)
    stepper = NewmarkStepper(system.M, system.D, system.K, system.B, dt,
                             G=getattr(system, "G", None), constraint=getattr(system, "constraint", None))
    n, k = system.M.shape[0], t.size
    x, xdot, xddot = (np.empty((n, k)) for _ in range(3))
    stepper.start(u[:, 0], x0, v0)
    with Progress(k - 1, "simulating", quiet=quiet) as progress:
        for i in range(k):
            if i > 0:
                stepper.step(u[:, i])
                progress.update(i)
            x[:, i], xdot[:, i], xddot[:, i] = stepper.x, stepper.v, stepper.a
            if on_step is not None:
                on_step(i, stepper)
    y = np.asarray(system.Cp @ x + system.Cv @ xdot)
    return Trajectory(t=t, u=u, x=x, xdot=xdot, xddot=xddot, y=y)
