"""Output-error refinement of the SDP solution (stage 3 of the pipeline, after eq. 16).

Starting from the SDP operators, ``Mr = LM LM^T``, ``Dr = LD LD^T``, ``Kr = LK LK^T`` and ``Br`` are refined to
minimize the training runs' output error with the ROM's own step, classical Newmark or the exact hold step
(L-BFGS, :mod:`fmu_opinf._lbfgs`, with the adjoint gradient, evaluated through the eigenvalues of the step map
where that is possible and faster, :mod:`fmu_opinf._output_gradient`; for Newmark an optional Levenberg-Marquardt
polish with the exact Jacobian).
The factors keep the operators symmetric PSD, so the refined ROM is stable by construction.  Why, what was
measured and what was not kept: the docstring of :mod:`fmu_opinf.inference`, section *Output-error refinement*.
:func:`fmu_opinf.inference.fit_operators` calls :func:`refine_output_error`; both public functions are also
importable from :mod:`fmu_opinf.inference`.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg

from ._background import checkpoint
from ._lbfgs import minimize_lbfgs
from ._output_gradient import _STRIDE, dense_output_gradient, modal_is_faster, modal_output_gradient, propagate
from ._progress import Progress
from .basis import column_blocks
from .errors import DimensionError

__all__ = ["refine_output_error", "newmark_step_map", "output_error_objective", "output_scales",
           "check_output_weighting", "zero_order_hold_step"]

def newmark_step_map(Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The classical Newmark step (beta = 1/4, gamma = 1/2) on ``z = [q; q']`` with the input held over the step.

    Average-acceleration Newmark is the trapezoidal rule of the first-order form, so with ``u_i`` held over the
    step that ends at ``t_i`` (the convention of the recorded data, see :class:`fmu_opinf.newmark.Trajectory`)
    ``E z_i = F z_{i-1} + [0; dt Br] u_i`` with ``E = [[I, -dt/2 I], [dt/2 Kr, Mr + dt/2 Dr]]`` and
    ``F = [[I, dt/2 I], [-dt/2 Kr, Mr - dt/2 Dr]]``: the same trajectory as :meth:`SecondOrderROM.simulate`
    (tested).

    Returns
    -------
    Ad : (2r, 2r) ndarray
    Bd : (2r, m) ndarray
        ``z_i = Ad z_{i-1} + Bd u_i``.
    """
    return _newmark_discrete(Mr, Dr, Kr, Br, dt)[1:]


def _newmark_discrete(Mr, Dr, Kr, Br, dt) -> tuple:
    r = Mr.shape[0]
    eye, half = np.eye(r), 0.5 * dt
    E = np.block([[eye, -half * eye], [half * Kr, Mr + half * Dr]])
    F = np.block([[eye, half * eye], [-half * Kr, Mr - half * Dr]])
    lu = scipy.linalg.lu_factor(E, check_finite=False)
    forcing = np.vstack([np.zeros_like(Br), dt * Br])
    return lu, scipy.linalg.lu_solve(lu, F, check_finite=False), scipy.linalg.lu_solve(lu, forcing, check_finite=False)


def zero_order_hold_step(Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray,
                         dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The exact step of ``Mr q'' + Dr q' + Kr q = Br u`` on ``z = [q; q']`` with ``u`` held over the step.

    ``z_i = E z_{i-1} + F u_i`` with ``E = exp(A dt)`` and ``F = int_0^dt exp(A s) ds [0; Mr^-1 Br]`` for the
    first-order matrix ``A = [[0, I], [-Mr^-1 Kr, -Mr^-1 Dr]]``, both from one exponential of Van Loan's block
    matrix.  ``Dr, Kr`` need not be symmetric.

    Returns
    -------
    E : (2r, 2r) ndarray
    F : (2r, m) ndarray
    """
    step = _ExactStep(Mr, Dr, Kr, Br, dt)
    return step.Ad, step.Bd


#: Order from which on the refinement works in the start's modal coordinates by default (module docstring of
#: :mod:`fmu_opinf.inference`; until 2026-11-25 it was above 40: r = 40 went from ratio 2.03 to 1.80).
_WHITEN_FROM = 40

#: How the refinement computes its gradient (``gradient`` of :func:`refine_output_error`).
_GRADIENTS = ("auto", "modal", "dense")

#: How the outputs are weighed against each other in the refinement's objective (:func:`output_scales`).
OUTPUT_WEIGHTINGS = ("per-output", "lumped")

#: RMS, relative to the largest output's, below which an output is weighted as if it were that large
#: (:func:`output_scales`).
OUTPUT_FLOOR = 1e-3

#: Training objective (relative squared output error) at or below which the start already reproduces the data
#: and is returned unrefined: 1e-10 in relative amplitude, the accuracy of a recording at the default tolerance.
#: Below it the L-BFGS fits the recording's round-off; with each output relative to its own size, that moved an
#: exact 12-mode model's small output from 3e-13 to 9e-11 of its variation (2026-11-27).
REPRODUCED = 1e-20


@dataclass(frozen=True)
class Extension:
    """Iterations past the refinement's budget while its objective still falls fast: in blocks of ``block``
    iterations, the refinement goes on while the last block lowered the objective by at least a factor
    ``factor``, up to ``cap`` iterations in all.

    Why: on balanced multi-run fits (:mod:`fmu_opinf.fit._run_balance`) the objective's Hessian in the L-BFGS
    variables has a condition number of 1e7 at the start and 1e10 after 300 iterations (audit84's model with an
    accelerated support, r = 7), so a fixed budget stops in the middle of a descent that still gains a decade every
    100 iterations (module docstring of :mod:`fmu_opinf.inference`, *Budget of multi-run fits*)."""

    block: int
    factor: float
    cap: int


class _EquationResidual:
    """The relative acceleration residual ``E = ||Xr'' + Mr^-1 (Dr Xr' + Kr Xr - Br U)||_F^2 / ||Xr''||_F^2`` of
    eq. (16) in explicit form, measured in the data's given coordinates, and its gradient in the operators.

    The data enter through the triangular factor ``R`` of ``[Xr''; Xr'; Xr; U]^T = Q R`` (no squared Gram
    matrix: on the anchored chain the data are ill-conditioned).  ``weight`` is ``T`` of a change of coordinates
    ``q_given = T q`` when the refinement works in other coordinates (the residual is then ``T`` times the one of
    the transformed operators and data), else ``None``.
    """

    def __init__(self, xddot_r: np.ndarray, xdot_r: np.ndarray, x_r: np.ndarray, u: np.ndarray,
                 weight: np.ndarray | None = None) -> None:
        self.R = np.linalg.qr(np.vstack([xddot_r, xdot_r, x_r, u]).T, mode="r")
        given = xddot_r if weight is None else weight @ xddot_r
        self.norm = max(float(np.sum(given * given)), 1e-300)
        self.weight = weight

    def value_and_gradients(self, Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray,
                            Br: np.ndarray) -> tuple[float, tuple[np.ndarray, ...]]:
        """``E`` and its gradients in ``Mr, Dr, Kr, Br``."""
        r = Mr.shape[0]
        Q = np.hstack([Dr, Kr, -Br])
        P = np.hstack([np.eye(r), np.linalg.solve(Mr, Q)])  # [I, Mr^-1 Dr, Mr^-1 Kr, -Mr^-1 Br]
        res = P @ self.R.T
        if self.weight is not None:
            res = self.weight @ res
        value = float(np.sum(res * res)) / self.norm
        back = res if self.weight is None else self.weight.T @ res
        gP = 2.0 * (back @ self.R) / self.norm
        gQ = np.linalg.solve(Mr.T, gP[:, r:])
        gM = -gQ @ P[:, r:].T  # d(Mr^-1 Q) = -Mr^-1 dMr (Mr^-1 Q)
        return value, (gM, gQ[:, :r], gQ[:, r:2 * r], -gQ[:, 2 * r:])


@dataclass
class _Trajectories:
    """Training runs for the output-error objective: states ``z = [q; q']``, inputs, weighted output target."""

    z: list[np.ndarray]
    u: list[np.ndarray]
    target: list[np.ndarray]
    C: np.ndarray
    dt: float
    scales: np.ndarray  # physical operator = factor product / scale, for M, D, K, B
    columns: np.ndarray | None = None  # (3, r): column scaling of the factors of M, D, K (default ones)
    free_output_map: bool = False  # C re-fitted to each simulation by least squares (variable projection)
    integrator: str = "newmark"  # the step simulated: classical Newmark or the exact hold step
    state_weight: float = 0.0  # weight of the relative state error next to the output error
    equation: _EquationResidual | None = None  # the acceleration residual of eq. (16), for equation_weight
    equation_weight: float = 0.0  # exponent of the acceleration residual in the log objective
    gradient: str = "auto"  # "modal" (through the eigenvalues), "dense" (stepping states) or "auto" (modal if it can)
    helper: Executor | None = None  # a thread on a spare core for the modal gradient's output simulation
    unreached: float = 0.0  # the target's part outside the range of a compressed map (_training_problem)
    divisor: np.ndarray | None = None  # (p, 1): what the outputs and the map's rows were divided by

    def loss(self, params: np.ndarray, r: int, m: int) -> tuple[float, np.ndarray]:
        """``sum_runs ||C z_sim - target||^2`` and its gradient in the factors (adjoint method).

        With ``free_output_map`` the map ``C`` is first re-fitted to the simulated states; the gradient is then
        the same expression, since ``C`` is optimal (variable projection).
        """
        factors, Bs = _split_factors(params, r, m)
        columns = np.ones((3, r)) if self.columns is None else self.columns
        LM, LD, LK = (L * c for L, c in zip(factors, columns))
        sa, sv, sx, su = self.scales
        step = _step(self.integrator)(LM @ LM.T / sa, LD @ LD.T / sv, LK @ LK.T / sx, Bs / su, self.dt)
        value, grad_A, grad_B = self._step_map_gradient(step.Ad, step.Bd, r)
        gM, gD, gK, gB = step.operator_gradients(grad_A, grad_B)
        grads = [(((g + g.T) @ L) * c / scale).ravel()
                 for g, L, c, scale in zip((gM, gD, gK), (LM, LD, LK), columns, (sa, sv, sx))]
        return value + self.unreached, np.concatenate(grads + [(gB / su).ravel()])


    def _step_map_gradient(self, Ad: np.ndarray, Bd: np.ndarray, r: int) -> tuple[float, np.ndarray, np.ndarray]:
        """The objective and its gradient in the step map: through the eigenvalues when the output map is fixed
        and no state error is weighted (:mod:`fmu_opinf._output_gradient`), else by stepping the states."""
        runs = [(z[:, 0], u, target) for z, u, target in zip(self.z, self.u, self.target)]
        scale, mu = self._state_scaling(r)
        outputs, states = self.C.shape
        wanted = self.gradient == "modal" or (self.gradient == "auto"
                                              and modal_is_faster(states, outputs, Bd.shape[1]))
        if wanted and not self.free_output_map and not mu:
            result = modal_output_gradient(Ad, Bd, self.C, runs, self.helper)
            if result is not None:
                return result
            if self.gradient == "modal":
                raise ValueError("gradient='modal' needs a step map with separated eigenvalues and a "
                                 "well-conditioned eigenvector basis; use gradient='auto'")
        if not self.free_output_map and not mu:
            return dense_output_gradient(Ad, Bd, self.C, runs)

        def misfit(sims: list[np.ndarray]) -> tuple[float, list[np.ndarray]]:
            """The output error with the re-fitted map and / or the weighted state error."""
            if self.free_output_map:
                self.C = _least_squares_output_map(sims, self.target, self.C)
            value, drives = 0.0, []
            for z, target, z_data in zip(sims, self.target, self.z):
                err = self.C @ z - target
                value += float(np.sum(err * err))
                g = 2.0 * (self.C.T @ err)
                if mu:
                    dz = (z - z_data) * scale[:, None]
                    value += mu * float(np.sum(dz * dz))
                    g = g + 2.0 * mu * dz * scale[:, None]
                drives.append(g)
            return value, drives

        return dense_output_gradient(Ad, Bd, self.C, runs, misfit)

    def log_loss(self, params: np.ndarray, r: int, m: int) -> tuple[float, np.ndarray, float, float]:
        """``log J + w log E`` (``J`` of :meth:`loss`, ``E`` the acceleration residual, ``w`` the
        ``equation_weight``) and its gradient, then ``J`` and ``E``: invariant to a common scale of either."""
        value, grad = self.loss(params, r, m)
        factors, Bs = _split_factors(params, r, m)
        columns = np.ones((3, r)) if self.columns is None else self.columns
        Ls = [L * c for L, c in zip(factors, columns)]
        sa, sv, sx, su = self.scales
        E, (gM, gD, gK, gB) = self.equation.value_and_gradients(*(L @ L.T / s for L, s in zip(Ls, (sa, sv, sx))),
                                                                  Bs / su)
        grads = [(((g + g.T) @ L) * c / scale).ravel()
                 for g, L, c, scale in zip((gM, gD, gK), Ls, columns, (sa, sv, sx))]
        w = self.equation_weight
        if not (value > 0 and E > 0):
            return float("inf"), np.zeros_like(grad), value, E
        grad_E = np.concatenate(grads + [(gB / su).ravel()])
        return float(np.log(value) + w * np.log(E)), grad / value + w * grad_E / E, value, E

    def _state_scaling(self, r: int) -> tuple[np.ndarray, float]:
        """Row scales of the state error (positions and velocities each by their RMS) and its weight ``mu``, so
        that ``mu * sum ||scale (z_sim - z_data)||^2`` is ``state_weight`` times the relative state error."""
        if not self.state_weight:
            return np.ones(2 * r), 0.0
        data = np.hstack(self.z)
        rms = [max(float(np.sqrt(np.mean(block * block))), 1e-300) for block in (data[:r], data[r:])]
        scale = np.concatenate([np.full(r, 1.0 / rms[0]), np.full(r, 1.0 / rms[1])])
        return scale, self.state_weight / max(float(np.sum((data * scale[:, None]) ** 2)), 1e-300)


class _NewmarkStep:
    """``Ad = E^-1 F``, ``Bd = E^-1 G`` of :func:`newmark_step_map` and the way back to ``Mr, Dr, Kr, Br``."""

    def __init__(self, Mr, Dr, Kr, Br, dt: float) -> None:
        self.dt, self.r = dt, Mr.shape[0]
        self.lu, self.Ad, self.Bd = _newmark_discrete(Mr, Dr, Kr, Br, dt)

    def operator_gradients(self, grad_A: np.ndarray, grad_B: np.ndarray) -> tuple[np.ndarray, ...]:
        """Gradients in ``Mr, Dr, Kr, Br`` from those in ``Ad, Bd`` (through the solve to ``E, F, G``)."""
        YA = scipy.linalg.lu_solve(self.lu, grad_A, trans=1, check_finite=False)
        YB = scipy.linalg.lu_solve(self.lu, grad_B, trans=1, check_finite=False)
        WE = YA @ self.Ad.T + YB @ self.Bd.T
        r = self.r
        lo, hi, half = slice(0, r), slice(r, 2 * r), 0.5 * self.dt
        gM = YA[hi, hi] - WE[hi, hi]
        gD = -half * (YA[hi, hi] + WE[hi, hi])
        gK = -half * (YA[hi, lo] + WE[hi, lo])
        return gM, gD, gK, self.dt * YB[hi]


class _ExactStep:
    """``[Ad, Bd]`` of :func:`zero_order_hold_step`, the top rows of ``expm(X)`` for Van Loan's block ``X = dt
    [[A, Bc], [0, 0]]`` with ``A = [[0, I], [-Mr^-1 Kr, -Mr^-1 Dr]]``, ``Bc = [0; Mr^-1 Br]``, and the way back:
    the gradient in ``X`` is the Frechet derivative of the exponential at ``X^T`` applied to the gradient in
    ``expm(X)`` (the adjoint of ``L(X, .)`` is ``L(X^T, .)``), then the chain rule through ``Mr^-1``."""

    def __init__(self, Mr, Dr, Kr, Br, dt: float) -> None:
        self.dt, self.r, self.m = dt, Mr.shape[0], Br.shape[1]
        self.Minv = np.linalg.inv(Mr)
        self.unit = self.Minv @ np.hstack([Kr, Dr, Br])  # Mr^-1 [Kr, Dr, Br]
        r = self.r
        self.X = np.zeros((2 * r + self.m, 2 * r + self.m))
        self.X[:r, r:2 * r] = np.eye(r) * dt
        self.X[r:2 * r, :2 * r] = -self.unit[:, :2 * r] * dt
        self.X[r:2 * r, 2 * r:] = self.unit[:, 2 * r:] * dt
        expo = scipy.linalg.expm(self.X)
        self.Ad, self.Bd = expo[:2 * r, :2 * r], expo[:2 * r, 2 * r:]

    def operator_gradients(self, grad_A: np.ndarray, grad_B: np.ndarray) -> tuple[np.ndarray, ...]:
        """Gradients in ``Mr, Dr, Kr, Br`` from those in ``Ad, Bd``."""
        r = self.r
        G = np.zeros_like(self.X)
        G[:2 * r, :2 * r], G[:2 * r, 2 * r:] = grad_A, grad_B
        gX = scipy.linalg.expm_frechet(self.X.T, G, compute_expm=False) * self.dt
        g_unit = np.hstack([-gX[r:2 * r, :2 * r], gX[r:2 * r, 2 * r:]])  # gradient in Mr^-1 [Kr, Dr, Br]
        return _through_unit_mass(self.Minv, self.unit, g_unit)


def _through_unit_mass(Minv: np.ndarray, unit: np.ndarray, g_unit: np.ndarray) -> tuple[np.ndarray, ...]:
    """Gradients in ``Mr, Dr, Kr, Br`` from the gradient ``g_unit`` in ``unit = Mr^-1 [Kr, Dr, Br]`` (the steps
    that are functions of the unit-mass operators): ``d unit = Mr^-1 (d[Kr, Dr, Br] - dMr unit)``."""
    r = Minv.shape[0]
    gK, gD, gB = (Minv.T @ part for part in (g_unit[:, :r], g_unit[:, r:2 * r], g_unit[:, 2 * r:]))
    return -Minv.T @ g_unit @ unit.T, gD, gK, gB


class _ForwardEulerStep:
    """``Ad = I + dt A``, ``Bd = dt [0; Mr^-1 Br]`` for ``A = [[0, I], [-Mr^-1 Kr, -Mr^-1 Dr]]``: one explicit Euler
    step of the first-order form with the input held, the step of a co-simulation that takes one per
    communication step (Simulink's ode1; audit 70 F1: such recordings follow it, and the model is what makes it
    reproduce them), and the way back to ``Mr, Dr, Kr, Br`` (the chain rule through ``Mr^-1``)."""

    def __init__(self, Mr, Dr, Kr, Br, dt: float) -> None:
        self.dt, self.r, self.m = dt, Mr.shape[0], Br.shape[1]
        self.Minv = np.linalg.inv(Mr)
        self.unit = self.Minv @ np.hstack([Kr, Dr, Br])  # Mr^-1 [Kr, Dr, Br]
        r = self.r
        self.Ad = np.eye(2 * r)
        self.Ad[:r, r:] += dt * np.eye(r)
        self.Ad[r:, :] -= dt * self.unit[:, :2 * r]
        self.Bd = np.vstack([np.zeros((r, self.m)), dt * self.unit[:, 2 * r:]])

    def operator_gradients(self, grad_A: np.ndarray, grad_B: np.ndarray) -> tuple[np.ndarray, ...]:
        """Gradients in ``Mr, Dr, Kr, Br`` from those in ``Ad, Bd``."""
        r = self.r
        g_unit = self.dt * np.hstack([-grad_A[r:, :2 * r], grad_B[r:]])  # gradient in Mr^-1 [Kr, Dr, Br]
        return _through_unit_mass(self.Minv, self.unit, g_unit)


#: The time steps the refinement can model (``integrator`` of :func:`refine_output_error`): the ROM's own
#: (classical Newmark, the exact hold step), or the explicit Euler step a recording followed (``"forward-euler"``:
#: the refined operators are then the continuous model's, which the ROM simulates with its own step).
_STEPS = {"newmark": _NewmarkStep, "exact": _ExactStep, "forward-euler": _ForwardEulerStep}


def _step(integrator: str) -> type:
    if integrator not in _STEPS:
        raise ValueError(f"integrator={integrator!r} is not known; use one of {', '.join(_STEPS)}")
    return _STEPS[integrator]


def _least_squares_output_map(states: list[np.ndarray], targets: list[np.ndarray],
                              fallback: np.ndarray) -> np.ndarray:
    """The ``C`` minimizing ``sum_runs ||C z - target||^2`` (QR-based least squares: the simulated states are
    as ill-conditioned as the data, 1e7 on the anchored chain, so the normal equations would lose 14 digits);
    ``fallback`` when a simulation diverged."""
    Z = np.hstack(states).T
    if not np.all(np.isfinite(Z)):
        return fallback
    return scipy.linalg.lstsq(Z, np.hstack(targets).T, check_finite=False, lapack_driver="gelsy")[0].T


def _residuals_and_jacobian(problem: _Trajectories, params: np.ndarray, r: int, m: int,
                            chunk: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Output residuals ``C z_sim - target`` of all runs (stacked) and their Jacobian in the parameters.

    Forward sensitivities: with ``E z_i = F z_{i-1} + G u_i`` (:func:`newmark_step_map`) a parameter change gives
    ``E dz_i = F dz_{i-1} + s_i`` with ``s_i = [0; dM (v_{i-1} - v_i) - dt/2 dD (v_{i-1} + v_i) - dt/2 dK (q_{i-1} +
    q_i) + dt dB u_i]``, and ``dM w = (e_a (L^T w)_b + L_b w_a) c_b / s`` for the factor entry ``L_ab``.  All
    ``3 r^2 + r m`` sensitivities are stepped together: ``O(k r^4)``, for small orders only.
    """
    factors, Bs = _split_factors(params, r, m)
    columns = np.ones((3, r)) if problem.columns is None else problem.columns
    Le = [L * c for L, c in zip(factors, columns)]
    sa, sv, sx, su = problem.scales
    dt, half = problem.dt, 0.5 * problem.dt
    lu, Ad, Bd = _newmark_discrete(*(L @ L.T / s for L, s in zip(Le, (sa, sv, sx))), Bs / su, dt)
    n = 2 * r
    lower = scipy.linalg.lu_solve(lu, np.vstack([np.zeros((r, r)), np.eye(r)]), check_finite=False)  # E^-1 [0; I]
    mapped = [lower @ L for L in Le]  # E^-1 [0; L]
    residuals, jacobians = [], []
    for z_data, u, target in zip(problem.z, problem.u, problem.target):
        k = u.shape[1]
        z = propagate(Ad, Bd @ u, z_data[:, 0], _STRIDE)
        residuals.append((problem.C @ z - target).T.ravel())  # time-major: (k, p)
        q, v = z[:r], z[r:]
        w = [v[:, :-1] - v[:, 1:], -half * (v[:, :-1] + v[:, 1:]), -half * (q[:, :-1] + q[:, 1:])]
        jac = np.zeros((k, problem.C.shape[0], 3 * r * r + r * m))
        dz = np.zeros((n, 3 * r * r + r * m))
        for lo in range(0, k - 1, chunk):
            hi = min(lo + chunk, k - 1)
            blocks = []
            for wb, L, P, c, scale in zip(w, Le, mapped, columns, (sa, sv, sx)):
                wc = wb[:, lo:hi]  # (r, t)
                t = (L.T @ wc) * c[:, None] / scale  # (r: b, t)
                # column (a, b): lower[:, a] t_b + P[:, b] c_b w_a / scale
                first = lower[:, :, None, None] * t[None, None, :, :]  # (n, a, b, t)
                second = P[:, None, :, None] * (c[None, :, None] / scale * wc[:, None, :])[None]  # (n, a, b, t)
                blocks.append((first + second).reshape(n, r * r, -1))
            ub = u[:, lo + 1:hi + 1]
            blocks.append((lower[:, :, None, None] * (dt / su) * ub[None, None, :, :]).reshape(n, r * m, -1))
            forcing = np.concatenate(blocks, axis=1)  # (n, P, t)
            for j in range(hi - lo):
                dz = Ad @ dz + forcing[:, :, j]
                jac[lo + j + 1] = problem.C @ dz
        jacobians.append(jac.reshape(k * problem.C.shape[0], -1))
    return np.concatenate(residuals), np.vstack(jacobians)


def _levenberg_marquardt(problem: _Trajectories, x: np.ndarray, r: int, m: int, iterations: int,
                         rtol: float = 1e-3) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Levenberg-Marquardt on the output residuals (exact Jacobian, :func:`_residuals_and_jacobian`).

    Returns the last iterate and the ``(objective, damping)`` of each accepted step."""
    e, J = _residuals_and_jacobian(problem, x, r, m)
    value = float(e @ e) + problem.unreached  # the objective of problem.loss
    steps: list[tuple[float, float]] = []
    mu = None
    for _ in range(iterations):
        A, g = J.T @ J, J.T @ e
        diag = np.diag(A).copy()
        diag[diag <= 0] = diag.max() * 1e-12 + 1e-300
        mu = 1e-3 if mu is None else mu
        improved = False
        for _ in range(12):
            try:
                step = -np.linalg.solve(A + mu * np.diag(diag), g)
            except np.linalg.LinAlgError:
                mu *= 10.0
                continue
            trial = problem.loss(x + step, r, m)[0]
            if np.isfinite(trial) and trial < value:
                improved = True
                break
            mu *= 10.0
        if not improved:
            break
        decrease = (value - trial) / value
        x, value = x + step, trial
        steps.append((value, mu))
        mu = max(mu / 10.0, 1e-12)
        if decrease < rtol:
            break
        e, J = _residuals_and_jacobian(problem, x, r, m)
    return x, steps


def _run_lbfgs(problem: _Trajectories, start: np.ndarray, value0: float, r: int, m: int, max_iterations: int,
               window: int, rtol: float, report: dict[str, Any], progress: bool = False,
               label: str = "output-error refinement",
               screen: tuple[tuple[int, ...], Callable[[int, np.ndarray], bool]] | None = None,
               memory: int = 100, extension: Extension | None = None) -> np.ndarray:
    """L-BFGS on the output error from ``start`` (objective ``value0``), relative to ``value0`` (the L-BFGS
    gradient test is absolute), or with ``problem.equation_weight`` on ``log(J / J0) + w log(E / E0)``
    (:meth:`_Trajectories.log_loss`); fills ``report`` (``objective`` and ``history`` are the output error
    ``J`` either way) and returns the last iterate.  ``screen``: ``(checkpoints, test)``, the iterate after each
    of those iteration counts is handed to ``test(iterations, x)`` and the run ends there where it returns True
    (status ``"screened out"``).  ``memory``: L-BFGS correction pairs kept; ``extension``: iterations past
    ``max_iterations`` while the objective falls fast (:class:`Extension`)."""
    history = [1.0]
    stop = _Stagnation(history, window, rtol)
    stop.screen = screen
    extended = extension is not None and 0 < max_iterations < extension.cap
    stop.budget = (max_iterations, extension) if extended else None
    stop.bar = Progress(max_iterations, f"{label} (L-BFGS iterations)", quiet=not progress)
    if problem.equation_weight > 0:
        recent: list[tuple[np.ndarray, float, float]] = []  # (params, J, E) of the last evaluations
        shift, _, _, equation0 = problem.log_loss(start, r, m)

        def fun(p: np.ndarray) -> tuple[float, np.ndarray]:
            value, grad, J, E = problem.log_loss(p, r, m)
            recent.append((p.copy(), J, E))
            del recent[:-4]
            return value - shift, grad

        def output_error(p: np.ndarray) -> float:
            for q, J, _ in reversed(recent):
                if np.array_equal(q, p):
                    return J
            return problem.loss(p, r, m)[0]

        stop.transform = lambda result: output_error(result.x) / value0
    else:
        def fun(p: np.ndarray) -> tuple[float, np.ndarray]:
            return tuple(v / value0 for v in problem.loss(p, r, m))

    rejected = [0]
    with stop.bar:
        most = max_iterations if stop.budget is None else extension.cap
        result = minimize_lbfgs(_finite_or_rejected(fun, rejected), start, max_iterations=most,
                                memory=memory, ftol=1e-13, gtol=1e-12, callback=stop)
    if rejected[0]:
        report["non_finite_trials"] = rejected[0]
    if problem.free_output_map:
        problem.loss(result.x, r, m)  # leaves problem.C at the map of the final iterate
    status = ("screened out" if stop.screened else "stagnated" if stop.stopped
              else "iteration limit" if stop.budget_spent else "converged" if result.success
              else "line search failed" if result.message == "line search failed" else "iteration limit")
    objective = float(result.fun) * value0
    if problem.equation_weight > 0:
        objective = output_error(result.x)
        equation = problem.log_loss(result.x, r, m)[3]
        report["acceleration_residual"] = (float(np.sqrt(equation0)), float(np.sqrt(equation)))
    report.update(objective=objective, iterations=int(result.nit), evaluations=int(result.nfev),
                  status=status, history=np.asarray(history) * value0)
    return result.x


#: What a trial point whose step map overflows raises on its way through the matrix exponential, its Frechet
#: derivative or a solve (scipy refuses non-finite arrays with a ValueError naming "infs or NaNs"; a singular
#: mass factor makes a solve raise LinAlgError).
_NON_FINITE_ERRORS = (ValueError, FloatingPointError, np.linalg.LinAlgError)


def _finite_or_rejected(fun: Callable[[np.ndarray], tuple[float, np.ndarray]],
                        rejected: list[int]) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """``fun`` with a trial point whose objective or gradient is not finite turned into ``(inf, 0)``, counted in
    ``rejected[0]``: the line search of :func:`fmu_opinf._lbfgs.minimize_lbfgs` takes an infinite value as no
    decrease and shrinks the step, so L-BFGS only ever moves to finite points and ends at the best one it reached.
    Audit 76 F1: on a first-order state vector recorded as 12 positions, a trial step of the order search's r = 12
    fit overflowed the exact step's exponential and ``fit`` died in scipy's ``expm_frechet`` with a traceback."""
    def guarded(p: np.ndarray) -> tuple[float, np.ndarray]:
        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
                value, grad = fun(p)
        except _NON_FINITE_ERRORS as error:
            if isinstance(error, ValueError) and "inf" not in str(error).lower():
                raise  # a wrong setting (gradient='modal' on a step map it cannot decompose), not an overflow
            value, grad = np.inf, None
        if grad is None or not np.isfinite(value) or not np.all(np.isfinite(grad)):
            rejected[0] += 1
            return float("inf"), np.zeros_like(p)
        return value, grad

    return guarded


class _Stagnation:
    """L-BFGS callback: records the objective and stops once it fell by less than a factor ``1 + rtol`` over the
    last ``window`` iterations, tested from iteration ``2 window`` on (``rtol = 0``: never)."""

    def __init__(self, history: list[float], window: int, rtol: float) -> None:
        self.history, self.window, self.rtol, self.stopped = history, int(window), float(rtol), False
        self.transform = None  # the recorded objective from L-BFGS's intermediate result (default: its fun)
        self.bar: Progress | None = None  # labelled progress of the iterations on a terminal
        self.screen: tuple[tuple[int, ...], Callable[[int, np.ndarray], bool]] | None = None  # (checkpoints, test)
        self.screened = False  # the screen's test ended the run
        self.budget: tuple[int, Extension] | None = None  # (the budget, its extension) when it may be extended
        self.budget_spent = False  # the budget (or its extension) ended the run

    def __call__(self, intermediate_result: Any) -> None:
        value = intermediate_result.fun if self.transform is None else self.transform(intermediate_result)
        self.history.append(float(value))
        checkpoint(len(self.history) - 1)  # a refinement in a background thread: follow it, stop it on request
        if self.bar is not None:
            self.bar.update(len(self.history) - 1)
        iterations = len(self.history) - 1
        if self.screen is not None and iterations in self.screen[0] and self.screen[1](iterations,
                                                                                      intermediate_result.x):
            self.screened = True
            raise StopIteration
        if self.rtol > 0 and len(self.history) > 2 * self.window:
            if self.history[-1 - self.window] <= (1.0 + self.rtol) * self.history[-1]:
                self.stopped = True
                raise StopIteration
        if self.budget is not None and self._budget_spent(iterations):
            self.budget_spent = True
            raise StopIteration

    def _budget_spent(self, iterations: int) -> bool:
        """At the budget and at each block past it: whether the last block lowered the objective by less than
        the extension's factor (or the cap is reached)."""
        budget, extension = self.budget
        if iterations < budget or (iterations - budget) % extension.block:
            return False
        if iterations >= extension.cap:
            return True
        block_start = self.history[max(len(self.history) - 1 - extension.block, 0)]
        return not block_start >= extension.factor * self.history[-1]


def _split_factors(params: np.ndarray, r: int, m: int) -> tuple[list[np.ndarray], np.ndarray]:
    n = r * r
    return [params[b * n:(b + 1) * n].reshape(r, r) for b in range(3)], params[3 * n:].reshape(r, m)


def _psd_factor(mat: np.ndarray) -> np.ndarray:
    """A square ``L`` with ``L L^T = mat`` (symmetric eigen-square root; works for singular PSD ``mat``)."""
    eigs, vecs = np.linalg.eigh(0.5 * (mat + mat.T))
    return vecs * np.sqrt(np.clip(eigs, 0.0, None))


def refine_output_error(
    Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray,
    xdot_r: np.ndarray, x_r: np.ndarray, u: np.ndarray, y: np.ndarray, dt: float, *,
    output_map: tuple[np.ndarray, np.ndarray] | None = None, run_lengths: list[int] | None = None,
    max_iterations: int = 300, unit_scales: Any = None, whiten: bool | str = "auto", rtol: float = 0.0,
    window: int = 25, polish_iterations: int = 0, refit_output_map: bool = False, integrator: str = "newmark",
    state_weight: float = 0.0, equation_weight: float = 0.0, xddot_r: np.ndarray | None = None,
    progress: bool = False, gradient: str = "auto", progress_label: str = "output-error refinement",
    spare_core: bool = False, output_weighting: str = "per-output",
    screen: tuple[tuple[int, ...], Callable[..., bool]] | None = None,
    memory: int = 100, extension: Extension | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Output-error (trajectory) refinement of a structured fit (module docstring, *Output-error refinement*).

    Minimizes ``sum_j sum_i (Cpr q_i + Cvr q'_i - y_i)_j^2 / (p ||y_j||^2)`` (the mean over the ``p`` outputs of
    each one's relative squared error; ``output_weighting``) over the training runs simulated with the
    classical Newmark step (:func:`newmark_step_map`) or the exact hold step (:func:`zero_order_hold_step`) from
    each run's recorded initial state, over
    ``Mr = LM LM^T, Dr = LD LD^T, Kr = LK LK^T`` and ``Br`` (L-BFGS, adjoint gradient): the operators stay
    symmetric positive semidefinite, so the refined model is stable by construction.

    Parameters
    ----------
    Mr, Dr, Kr, Br
        Starting point (the SDP solution), symmetric PSD.
    xdot_r, x_r : (r, k) ndarray
        Reduced velocities and positions of the runs side by side.
    u : (m, k) ndarray
        Input in effect at each snapshot (the one held over the step ending there).
    y : (p, k) ndarray
        Output target (measured outputs minus any feedthrough / offset part).
    dt : float
        Time step of the training data (constant within each run).
    output_map : (Cpr, Cvr), optional
        Default: :func:`fit_outputs` on the data (eq. 17).
    run_lengths : list of int, optional
        Snapshots per run, summing to ``k``; default one run.
    max_iterations : int, default=300
        L-BFGS iterations at most.
    unit_scales : sequence of 4 floats, optional
        Units of the factors: ``Mr = LM LM^T / s[0]``, ``Dr = ... / s[1]``, ``Kr = ... / s[2]``, ``Br = Bs / s[3]``
        (:func:`fit_operators` passes the block scales of the SDP); default ones.
    whiten : {"auto", True, False}, default="auto"
        Refine in the start's modal coordinates (module docstring); ``"auto"``: from r = 40 on, where it reached
        the goal at r = 40 / 55 / 60 and the plain coordinates did not.
    rtol, window : float, int, default=0.0, 25
        Stagnation stop: L-BFGS ends once the objective fell by less than a factor ``1 + rtol`` over the last
        ``window`` iterations, tested from iteration ``2 window`` on; ``rtol=0`` (default) runs the full budget
        (module docstring: with ``rtol=0.1`` the anchored chain lost accuracy).
    polish_iterations : int, default=0
        Levenberg-Marquardt iterations on the output residuals after L-BFGS, with the exact Jacobian by forward
        sensitivities (``O(k r^4)`` per iteration: small orders only; module docstring).
    refit_output_map : bool, default=False
        Re-fit ``[Cpr, Cvr]`` to the simulated states by least squares at every evaluation (variable
        projection) instead of keeping ``output_map``; the refined map is returned in ``report["refitted_map"]``
        and must replace ``output_map`` in the ROM.  Module docstring of :mod:`fmu_opinf.inference`, *Output
        map*: far more accurate on the anchored chain, less accurate on the triple chain, so off by default.
    integrator : {"newmark", "exact"}, default="newmark"
        The ROM's time step, which the simulated training runs use: classical Newmark, or the exact solution
        under the held input (continuous-time sources; the gradient goes through the Frechet derivative of the
        matrix exponential).  The polish models Newmark only.
    state_weight : float, default=0
        Weight of the relative error of the simulated reduced states ``[q; q']`` against the data's (positions
        and velocities each scaled by their RMS) beside the relative output error; 0 (default) fits the outputs
        alone.  Measured with 1e-5 and not made the default (module docstring of :mod:`fmu_opinf.inference`,
        *State-error term*).  The polish's Jacobian is that of the outputs alone.
    equation_weight : float, default=0
        ``w > 0`` minimizes ``log J + w log E`` instead of the output error ``J``, with ``E`` the relative
        acceleration residual ``||Xr'' + Mr^-1 (Dr Xr' + Kr Xr - Br U)||_F^2 / ||Xr''||_F^2`` of eq. (16) in the
        data's coordinates (needs ``xddot_r``): a 10x larger equation residual must buy a ``10^w`` times smaller
        output error.  Invariant to the units of both terms.  Measured and not made the default (module docstring
        of :mod:`fmu_opinf.inference`, *Candidates against the swing*).  Not with ``refit_output_map``; the
        polish's Jacobian is that of the outputs alone.
    xddot_r : (r, k) ndarray, optional
        Reduced accelerations of the runs, for ``equation_weight``.
    progress : bool, default=False
        A labelled progress bar of the L-BFGS iterations on stderr, when it is a terminal and the refinement takes
        over a second (``fmu-opinf fit`` at r = 50: 1000 iterations, about 40 s).
    progress_label : str, default="output-error refinement"
        What the progress bar calls the refinement.
    gradient : {"auto", "modal", "dense"}, default="auto"
        How each evaluation computes the objective's gradient in the step map (:mod:`fmu_opinf._output_gradient`):
        ``"modal"`` through the eigenvalues of the step map without forming a state (``O(k r)`` per evaluation
        beside one ``O(r^3)`` eigendecomposition), ``"dense"`` by stepping the states and the adjoint
        (``O(k r^2)``), ``"auto"`` the modal way where it is the faster one (from ``r = 7`` for one input and
        up to three outputs) and the step map has separated eigenvalues and a well-conditioned eigenvector
        basis.  Both give the same objective and gradient up to rounding.  With ``refit_output_map`` or
        ``state_weight`` the states are needed: always dense.
    output_weighting : {"per-output", "lumped"}, default="per-output"
        ``"per-output"``: each output's error relative to its own size (:func:`output_scales`), so that larger
        outputs do not buy their accuracy with a small one's (module docstring of :mod:`fmu_opinf.inference`,
        *Outputs of different size*); ``"lumped"``: all outputs' errors relative to ``||y||``, the measure of
        eq. (19).  The same with one output.
    spare_core : bool, default=False
        A second core is free (:func:`fmu_opinf.inference.fit_operators` says so when no second start runs beside
        this one, from ``SIDE_BY_SIDE_FROM`` = 15 on: below, the hand-over costs more than it gains): the modal
        gradient simulates the outputs in a second thread while this one decomposes the step map.  The same
        numbers; triple chain r = 100: 13.3 instead of 16.0 s for 600 iterations.
    screen : (sequence of int, callable), optional
        ``(checkpoints, test)``: after each of those numbers of L-BFGS iterations ``test(iterations, Mr, Dr, Kr,
        Br)`` gets the iterate's operators (in the given coordinates, ``Mr`` as the factors make it, not yet
        symmetrized) and ends the refinement there where it returns True (status ``"screened out"``): the order
        search of :func:`fmu_opinf.fit.fit_rom` stops refining an order that still misses its training outputs
        grossly, which it discards (:data:`fmu_opinf.fit.SCREEN_CHECKPOINTS`).  Otherwise the refinement goes on
        as without it, to the same iterates.
    memory : int, default=100
        L-BFGS correction pairs kept (:func:`fmu_opinf._lbfgs.minimize_lbfgs`).
    extension : Extension, optional
        Iterations past ``max_iterations`` while the objective still falls by ``extension.factor`` per
        ``extension.block`` iterations, up to ``extension.cap`` in all (:class:`Extension`); default none.

    Returns
    -------
    Mr, Dr, Kr, Br : ndarray
    report : dict
        ``objective_start``, ``objective`` (relative squared output error on the training runs, per output as
        ``output_weighting`` says), ``iterations``,
        ``evaluations``, ``seconds``, ``coordinates`` (``"modal"`` or ``"given"``), ``status`` (``"converged"``,
        ``"stagnated"``, ``"iteration limit"``, ``"line search failed"``, ``"kept start"`` or ``"exact start"``:
        the start reproduced the data, objective at most :data:`REPRODUCED`), ``history``
        (objective after each L-BFGS iteration), ``output_map`` (``"fixed"`` or ``"refitted"``), ``refitted_map``
        (``(Cpr, Cvr)``, when refitted) and, when polishing, ``polish`` (objective and damping of each accepted
        Levenberg-Marquardt step); with ``equation_weight``, ``acceleration_residual`` (``sqrt(E)`` at the start and
        at the end);
        ``non_finite_trials`` where trial points made the model overflow (rejected: the refinement ends at its best
        finite point; a start that overflows is kept, status ``"kept start"``).
    """
    t0 = time.perf_counter()
    r, m, k = Mr.shape[0], Br.shape[1], x_r.shape[1]
    _step(integrator)  # an unknown integrator is refused before any work
    if polish_iterations and integrator != "newmark":
        raise ValueError("polish_iterations needs the Newmark step (its Jacobian models Newmark)")
    lengths = _run_lengths(run_lengths, k, dt)
    if equation_weight and (xddot_r is None or refit_output_map):
        raise ValueError("equation_weight needs xddot_r and a fixed output map (refit_output_map=False)")
    if not equation_weight >= 0:
        raise ValueError(f"equation_weight={equation_weight} must be >= 0")
    Cpr, Cvr = _output_map(output_map, xdot_r, x_r, y)
    scales = np.ones(4) if unit_scales is None else np.asarray(unit_scales, dtype=float)
    T, T_inv, columns = np.eye(r), np.eye(r), None
    if whiten not in ("auto", True, False):
        raise ValueError(f"whiten={whiten!r} is not known; use 'auto', True or False")
    if whiten == "auto":
        whiten = r >= _WHITEN_FROM and np.linalg.eigvalsh(0.5 * (Mr + Mr.T))[0] > 0
    if whiten:
        T, T_inv, columns = _modal_coordinates(Mr, Dr, Kr)
        scales = np.ones(4)
        Mr, Dr, Kr, Br = T.T @ Mr @ T, T.T @ Dr @ T, T.T @ Kr @ T, T.T @ Br
        Cpr, Cvr, x_r, xdot_r = Cpr @ T, Cvr @ T, T_inv @ x_r, T_inv @ xdot_r
        xddot_r = None if xddot_r is None else T_inv @ xddot_r
    problem = _training_problem(xdot_r, x_r, u, y, dt, (Cpr, Cvr), lengths, scales, output_weighting,
                                compress=not refit_output_map)
    problem.columns, problem.free_output_map, problem.integrator = columns, bool(refit_output_map), integrator
    problem.state_weight = float(state_weight)
    if gradient not in _GRADIENTS:
        raise ValueError(f"gradient={gradient!r} is not known; use one of {', '.join(_GRADIENTS)}")
    problem.gradient = gradient
    if equation_weight:
        problem.equation = _EquationResidual(xddot_r, xdot_r, x_r, u, T if whiten else None)
        problem.equation_weight = float(equation_weight)
    cols = np.ones((3, r)) if columns is None else columns
    start = np.concatenate([(_psd_factor(A * s) / c).ravel() for A, s, c in zip((Mr, Dr, Kr), scales[:3], cols)]
                           + [(Br * scales[3]).ravel()])
    start_rejected = [0]
    value0 = _finite_or_rejected(lambda p: problem.loss(p, r, m), start_rejected)(start)[0]
    report = {"objective_start": value0, "objective": value0, "iterations": 0, "evaluations": 1,
              "status": "exact start", "coordinates": "modal" if whiten else "given",
              "output_map": "refitted" if refit_output_map else "fixed"}
    if start_rejected[0]:   # the start itself overflows: nothing to refine from
        report.update(status="kept start", non_finite_trials=1)
    elif value0 > REPRODUCED:
        screened = None if screen is None else (tuple(int(i) for i in screen[0]),
                                                _operator_test(screen[1], r, m, cols, scales, T_inv))
        with _helper_thread(spare_core) as problem.helper:
            x = _run_lbfgs(problem, start, value0, r, m, max_iterations, window, rtol, report, progress,
                           progress_label, screened, memory, extension)
        problem.helper = None
        if polish_iterations > 0:
            problem.free_output_map = False  # the Jacobian holds C fixed: polish with the map L-BFGS ended at
            x, report["polish"] = _levenberg_marquardt(problem, x, r, m, polish_iterations)
            report["objective"] = problem.loss(x, r, m)[0]
        factors, Bs = _split_factors(x, r, m)
        mats = [(L * c) @ (L * c).T / s for L, c, s in zip(factors, cols, scales[:3])]
        if report["objective"] < value0 and np.linalg.eigvalsh(mats[0])[0] > 0:
            Mr, Dr, Kr, Br = (*mats, Bs / scales[3])
            if refit_output_map:
                C = problem.C * problem.divisor  # p = T^-1 q: the map of q is C T^-1
                report["refitted_map"] = (C[:, :r] @ T_inv, C[:, r:] @ T_inv)
        else:
            report["status"] = "kept start"
            report["output_map"] = "fixed"
    report["seconds"] = time.perf_counter() - t0
    back = T_inv.T  # q = T p: the operators of q are T^-T (.) T^-1
    Mr, Dr, Kr = (0.5 * (back @ A @ T_inv + (back @ A @ T_inv).T) for A in (Mr, Dr, Kr))
    return Mr, Dr, Kr, back @ Br, report


def _operator_test(test: Callable[..., bool], r: int, m: int, columns: np.ndarray, scales: np.ndarray,
                   T_inv: np.ndarray) -> Callable[[np.ndarray], bool]:
    """``test(iterations, Mr, Dr, Kr, Br)`` (given coordinates ``q = T p``) as a test of the refinement's
    parameters."""
    def on_parameters(iterations: int, params: np.ndarray) -> bool:
        factors, Bs = _split_factors(params, r, m)
        mats = [(L * c) @ (L * c).T / s for L, c, s in zip(factors, columns, scales[:3])]
        back = T_inv.T
        return bool(test(iterations, *(back @ A @ T_inv for A in mats), back @ (Bs / scales[3])))
    return on_parameters


@contextlib.contextmanager
def _helper_thread(wanted: bool) -> Iterator[Executor | None]:
    """A one-thread executor while the refinement runs (``wanted``), else ``None``."""
    if not wanted:
        yield None
        return
    with ThreadPoolExecutor(1, thread_name_prefix="fmu-opinf-refinement") as pool:
        yield pool


def output_error_objective(
    Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray,
    xdot_r: np.ndarray, x_r: np.ndarray, u: np.ndarray, y: np.ndarray, dt: float, *,
    output_map: tuple[np.ndarray, np.ndarray] | None = None, run_lengths: list[int] | None = None,
    integrator: str = "newmark", output_weighting: str = "per-output",
) -> float:
    """The training objective of :func:`refine_output_error` for any model, structured or not.

    ``sum_j sum_i (Cpr q_i + Cvr q'_i - y_i)_j^2 / s_j^2`` (``s`` from :func:`output_scales`) over the training
    runs, each simulated from its recorded
    initial state with the classical Newmark step (``integrator="newmark"``) or the exact step under the held
    input (``"exact"``, :func:`zero_order_hold_step`).  ``Mr, Dr, Kr`` may be any real matrices with ``Mr`` and
    the Newmark matrix invertible (e.g. the unconstrained least-squares fit), so candidates of different structure
    are compared on one measure.  Other parameters as in :func:`refine_output_error`.

    Returns
    -------
    float
        The relative squared output error (inf if the simulation overflows).
    """
    k = x_r.shape[1]
    problem = _training_problem(xdot_r, x_r, u, y, dt, _output_map(output_map, xdot_r, x_r, y),
                                _run_lengths(run_lengths, k, dt), np.ones(4), output_weighting)
    step = _step(integrator)(Mr, Dr, Kr, Br, float(dt))
    Ad, Bd = step.Ad, step.Bd
    with np.errstate(over="ignore", invalid="ignore"):
        value = 0.0
        for z_data, inputs, target in zip(problem.z, problem.u, problem.target):
            err = problem.C @ propagate(Ad, Bd @ inputs, z_data[:, 0], _STRIDE) - target
            value += float(np.sum(err * err))
    value += problem.unreached
    return value if np.isfinite(value) else float("inf")


#: RMS, relative to the largest output's, at or below which :func:`output_errors` does not judge an output: what it
#: holds is the recording's round-off (1e-10 relative tolerance), not a response.
SILENT_OUTPUT = 1e-8


class OutputErrors(NamedTuple):
    """Each training output's relative squared errors (:func:`output_errors`): over whole runs and over the runs'
    free responses, each the worst run's, with that run's index (-1 where the output was not judged)."""

    whole: np.ndarray
    free_response: np.ndarray
    whole_run: np.ndarray
    free_response_run: np.ndarray


#: Samples a run's free response (:func:`output_errors`) must span to be judged on its own.
FREE_RESPONSE_SAMPLES = 10
#: RMS of a free response's variation, relative to the output's RMS over all training samples, at or below which
#: :func:`output_errors` does not judge it: a source started at rest at its equilibrium has none.
FREE_RESPONSE_SIZE = 1e-2
#: RMS of an output's variation in one run, relative to its largest variation in any training run, below which
#: :func:`output_errors` measures that run's error against this fraction of the largest variation instead: a run
#: that hardly moves an output (an input far from it) is judged to 3 % of its own variation only down to 3e-5 of
#: the output's size, so that a ROM need not follow the recording's round-off there (audit 72, F1).
RUN_VARIATION_FLOOR = 1e-3


def output_errors(
    Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, Br: np.ndarray,
    xdot_r: np.ndarray, x_r: np.ndarray, u: np.ndarray, y: np.ndarray, dt: float, *,
    output_map: tuple[np.ndarray, np.ndarray], run_lengths: list[int] | None = None, integrator: str = "newmark",
) -> OutputErrors:
    """Each output's relative squared error over the training runs, simulated as :func:`output_error_objective`
    simulates them (one simulation per run), each run's output relative to that run's own variation, the worst
    run counting: over whole runs (``max_i ||(C z)_j - y_j||_i^2 / ||y_j - mean_i(y_j)||_i^2``) and over their
    *free responses*.

    The objective weighs an output below :data:`OUTPUT_FLOOR` of the largest one as if it had that size, which
    suits a near-silent output but not outputs in different units: beside a tip acceleration of RMS 4e7 the
    displacements (RMS 700) counted 3400 times less, and a ROM 7 % off on one of them met the objective to 0.7 %
    (audit 65, F2).  Here no output is measured against another; one whose variation in every run is at or below
    :data:`SILENT_OUTPUT` of the largest output's is not judged (NaN).

    Nor is one run measured against another: pooled over the runs (each output's squared error summed over all
    runs, relative to its size over all of them) a run that hardly moves an output counts for nothing beside one
    that moves it 200 times more, and a ROM 56 % RMS off a tip displacement in the run of a force at the base
    passed at 2 % (audit 72, F1); and an output's size, not its variation, let a static deflection hide the
    transient (a step's ROM 3.5 % RMS off its variation passed at 0.8 %).  So each run's output is judged against
    its variation about the run's mean (floored at :data:`RUN_VARIATION_FLOOR` of the output's largest variation
    in any run), and the worst run counts: for a given ROM, a run added can only raise the figure, unless it moves
    an output over 1000 times more than every other run does (the floor rises).

    A run's free response is its stretch from the start until its inputs first change, where the source moves from
    its own start values alone: an FMU starts there, neither at rest nor at equilibrium, and the ROM FMU is first
    run with nothing connected.  Pooled over whole runs that motion counts for little beside a 100 N training
    pulse: a ROM 22 % of an acceleration's range off the free response passed at 1e-5 (audit 69, F2).  Each free
    stretch is measured against its own variation about its mean (an output's offset is not motion); the worst run
    counts.  Stretches shorter than :data:`FREE_RESPONSE_SAMPLES`, and outputs whose variation there is at or below
    :data:`FREE_RESPONSE_SIZE` of their RMS over all samples, are not judged.

    Returns
    -------
    OutputErrors
        ``whole`` and ``free_response``, each ``(p,)`` (inf where the simulation overflows, NaN where an output was
        not judged), and the 0-based index of the run each comes from (-1 where not judged).
    """
    k = x_r.shape[1]
    cuts = np.cumsum([0] + _run_lengths(run_lengths, k, dt))
    y = np.atleast_2d(y)
    C = np.hstack(output_map)
    norms = np.array([float(np.dot(row, row)) for row in y])
    squared, variation = np.zeros((len(cuts) - 1, y.shape[0])), np.zeros((len(cuts) - 1, y.shape[0]))
    free, free_run = np.full(y.shape[0], np.nan), np.full(y.shape[0], -1)
    with np.errstate(over="ignore", invalid="ignore"):   # an overflowing model is judged inf, said by its figure
        step = _step(integrator)(Mr, Dr, Kr, Br, float(dt))
        for run, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
            z = propagate(step.Ad, step.Bd @ u[:, a:b], np.concatenate([x_r[:, a], xdot_r[:, a]]), _STRIDE)
            squared[run], variation[run] = _run_squares(C, z, y[:, a:b])
            _worst_free_response((free, free_run, run), C @ z[:, :_free_length(u[:, a:b])], y[:, a:b], norms / k)
        whole, whole_run = _worst_run(squared, variation, np.diff(cuts).astype(float))
    return OutputErrors(whole, free, whole_run, free_run)


def _run_squares(C: np.ndarray, z: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One run's squared output errors ``sum (C z - y)^2`` and squared variations ``sum (y - mean y)^2``, each
    ``(p,)``, formed in column blocks."""
    squared, variation, mean = np.zeros(y.shape[0]), np.zeros(y.shape[0]), y.mean(axis=1)
    for part in column_blocks(*y.shape):
        err = C @ z[:, part] - y[:, part]
        motion = y[:, part] - mean[:, None]
        squared += np.sum(err * err, axis=1)
        variation += np.sum(motion * motion, axis=1)
    return squared, variation


def _worst_run(squared: np.ndarray, variation: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each output's worst run of ``squared / variation`` (``(runs, p)`` sums over each run of ``lengths``
    samples; the variation floored at :data:`RUN_VARIATION_FLOOR` of the output's largest in any run, per sample)
    and that run's index; NaN and -1 for an output whose variation is at or below :data:`SILENT_OUTPUT` of the
    largest output's in every run."""
    per_sample = variation / lengths[:, None]
    largest = per_sample.max(axis=0, initial=0.0)
    judged = largest > (SILENT_OUTPUT ** 2) * largest.max(initial=0.0)
    divisor = np.maximum(per_sample, (RUN_VARIATION_FLOOR ** 2) * largest)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        figures = np.where(np.isfinite(squared), squared / lengths[:, None] / divisor, np.inf)
    whole, whole_run = np.full(variation.shape[1], np.nan), np.full(variation.shape[1], -1)
    whole[judged] = figures[:, judged].max(axis=0)
    whole_run[judged] = np.argmax(figures[:, judged], axis=0)
    return whole, whole_run


def _free_length(u: np.ndarray) -> int:
    """Samples of a run before its inputs first change (0 where that is shorter than FREE_RESPONSE_SAMPLES)."""
    changed = np.flatnonzero(np.any(u != u[:, :1], axis=0))
    length = int(changed[0]) if changed.size else u.shape[1]
    return length if length >= FREE_RESPONSE_SAMPLES else 0


def _worst_free_response(worst: tuple[np.ndarray, np.ndarray, int], simulated: np.ndarray, y: np.ndarray,
                         mean_square: np.ndarray) -> None:
    """Raise ``worst = (errors, runs, run)`` (in place) to one run's free-response errors, ``runs`` to that run's
    index where it raised them: ``simulated`` the ROM's outputs over the free stretch, ``y`` the run's recorded
    outputs, ``mean_square`` each output's mean square over all samples."""
    length = simulated.shape[1]
    if not length:
        return
    recorded = y[:, :length]
    motion = recorded - recorded.mean(axis=1, keepdims=True)
    size = np.sum(motion * motion, axis=1)
    judged = size > (FREE_RESPONSE_SIZE ** 2) * mean_square * length
    err = simulated - recorded
    errors = np.sum(err * err, axis=1)[judged] / size[judged]
    errors[~np.isfinite(errors)] = np.inf
    figures, runs, run = worst
    raised = np.zeros(len(figures), dtype=bool)
    raised[judged] = ~(errors <= figures[judged])   # NaN (not judged yet) is raised too
    figures[judged] = np.fmax(figures[judged], errors)
    runs[raised] = run


def _run_lengths(run_lengths: list[int] | None, k: int, dt: float) -> list[int]:
    lengths = [k] if run_lengths is None else [int(v) for v in run_lengths]
    if sum(lengths) != k or min(lengths) < 2:
        raise DimensionError(f"run_lengths {lengths} must be >= 2 each and sum to the {k} snapshots")
    if not dt > 0:
        raise ValueError(f"dt={dt} must be positive")
    return lengths


def _output_map(output_map: tuple[np.ndarray, np.ndarray] | None, xdot_r: np.ndarray, x_r: np.ndarray,
                y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if output_map is None:
        from .inference import fit_outputs  # the output map of eq. 17 (inference imports this module)

        return fit_outputs(xdot_r, x_r, y)
    return output_map


def check_output_weighting(output_weighting: str) -> None:
    """Refuse an ``output_weighting`` that is not one of :data:`OUTPUT_WEIGHTINGS`."""
    from ._validate import check_choice

    check_choice(output_weighting, "output_weighting", OUTPUT_WEIGHTINGS)


def output_scales(y: np.ndarray, output_weighting: str = "per-output") -> np.ndarray:
    """The divisor of each output row in the refinement's objective (:func:`refine_output_error`).

    ``"per-output"``: ``sqrt(p) ||y_j||``, each output relative to its own size, so that the objective is the mean
    over the ``p`` outputs of their relative squared errors and a small output (a far-end displacement beside
    large ones) is fitted as well as the large ones.  An output below :data:`OUTPUT_FLOOR` of the largest one
    (in RMS) is weighted as if it had that size: a near-silent output is mostly the recording's round-off.
    ``"lumped"``: ``||y||`` for every row (the objective of eq. (19), the form before 2026-11-27).  With one
    output both are ``||y||``.
    """
    check_output_weighting(output_weighting)
    y = np.atleast_2d(y)
    if output_weighting == "lumped" or y.shape[0] == 1:
        return np.full(y.shape[0], float(np.linalg.norm(y)) or 1.0)
    norms = np.array([float(np.linalg.norm(row)) for row in y])
    if not norms.max() > 0:
        return np.ones(y.shape[0])
    return np.sqrt(y.shape[0]) * np.maximum(norms, OUTPUT_FLOOR * norms.max())


def _training_problem(xdot_r: np.ndarray, x_r: np.ndarray, u: np.ndarray, y: np.ndarray, dt: float,
                      output_map: tuple[np.ndarray, np.ndarray], lengths: list[int],
                      scales: np.ndarray, output_weighting: str, compress: bool = True) -> _Trajectories:
    """The runs split at ``lengths``, the output target and the map's rows divided by :func:`output_scales`
    (relative objective); with ``compress`` (a fixed map), more outputs than states are reduced to as many
    (:func:`_compressed_target`)."""
    divisor = output_scales(y, output_weighting)[:, None]
    cuts = np.cumsum([0] + lengths)
    z = np.vstack([x_r, xdot_r])
    C = np.hstack(output_map) / divisor
    Q = None
    if compress and C.shape[0] > C.shape[1]:
        Q, C = np.linalg.qr(C)
    targets, unreached = [], 0.0
    for a, b in zip(cuts[:-1], cuts[1:]):  # run by run: no divided copy of all outputs at once
        if Q is None:
            targets.append(y[:, a:b] / divisor)
            continue
        target, missed = _compressed_target(Q, y[:, a:b], divisor)
        targets.append(target)
        unreached += missed
    return _Trajectories(
        z=[z[:, a:b] for a, b in zip(cuts[:-1], cuts[1:])], u=[u[:, a:b] for a, b in zip(cuts[:-1], cuts[1:])],
        target=targets, C=C, dt=float(dt), scales=scales, unreached=unreached, divisor=divisor)


def _compressed_target(Q: np.ndarray, outputs: np.ndarray, divisor: np.ndarray) -> tuple[np.ndarray, float]:
    """``p`` outputs of a fixed map ``C`` (``p`` larger than the ``2r`` states) reduced to ``2r``: with ``C = Q R``
    (``Q`` orthonormal columns), ``||C z - t||^2 = ||R z - Q^T t||^2 + ||t - Q Q^T t||^2`` for every ``z``, the
    last term a constant.  Returns the target ``Q^T t`` of the map ``R`` and that constant, for the target
    ``t = outputs / divisor``, which is formed only in column blocks.  Each evaluation of the objective then costs
    ``O(k r^2)`` instead of ``O(k p r)``, and the targets take ``2r`` rows instead of ``p`` (seventh audit,
    2026-11-27: 200 outputs, r = 5, 172,000 samples: the refinement took 113 s and 2.3 GB).  Exact: no difference
    of squares is formed."""
    reduced = (Q / divisor).T @ outputs
    unreached = 0.0
    for part in column_blocks(*outputs.shape):
        block = outputs[:, part] / divisor
        block -= Q @ reduced[:, part]
        unreached += float(np.sum(block * block))
    return reduced, unreached


def _modal_coordinates(Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``T`` with ``T^T Mr T = I``, ``T^T Kr T = diag(omega^2)`` (modal coordinates of the start), its inverse,
    and the column scales of the factors there: 1 for the mass, ``omega`` for the stiffness, ``sqrt`` of the
    diagonal for the damping (each floored at 1e-6 of its largest, so that no column is frozen)."""
    L = np.linalg.cholesky(0.5 * (Mr + Mr.T))
    L_inv = scipy.linalg.solve_triangular(L, np.eye(Mr.shape[0]), lower=True)
    omega2, Q = np.linalg.eigh(L_inv @ Kr @ L_inv.T)
    T, T_inv = L_inv.T @ Q, Q.T @ L.T
    damping = np.sqrt(np.clip(np.diag(T.T @ Dr @ T), 0.0, None))
    omega = np.sqrt(np.clip(omega2, 0.0, None))
    columns = np.vstack([np.ones_like(omega)] + [np.maximum(c, 1e-6 * max(c.max(), 1e-300)) for c in (damping, omega)])
    return T, T_inv, columns
