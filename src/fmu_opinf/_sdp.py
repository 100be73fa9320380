"""Dense primal-dual interior-point solver for the operator-inference SDP (issue 16), with an independent
optimality certificate.

Problem, in the upper-triangular entries ``w`` of the symmetric blocks that keep a PSD cone
(:mod:`fmu_opinf.inference`, *Solution path*)::

    minimize  w^T S w + 2 s^T w   subject to   X_j = mat(w_j) - L_j >= 0  (each kept block j),
                                             a^T w = c                   (optional: the trace of the mass),

with ``S`` symmetric positive semidefinite and ``L_j`` either ``0`` or ``I`` (``Mr >= I``).

Method
------
Infeasible primal-dual path following with the HKM search direction and Mehrotra's predictor-corrector: each
iteration forms the upper triangle of the dense Newton matrix ``2 S + sum_j (Z_j (x)_s X_j^-1)`` (the symmetric
Kronecker products computed entry by entry, ``O(k^4)``, in one reused buffer), factors it in place once by
Cholesky (LAPACK ``dpotrf``, one BLAS thread) and solves with it two to five times: Mehrotra's predictor and
corrector, then up to three of Gondzio's centrality correctors (:func:`_centrality_targets`), each kept only where it
lengthens the step.  A solve (two BLAS ``dtrsv``) reads the factor once more, 0.3 ms at n = 1260 against 17-19 ms for
the factorization.
Clarabel solves the same problem through cvxpy, with cvxpy's compilation on top and a sparse LDL factorization
of a matrix that is dense here (the screened quadratic form); this path avoids both, which is where its speed-up
comes from (figures in ``benchmarks/bench_fit.py`` and the inference module docstring).
The iteration ends when the complementarity and the dual residual are below ``tol`` relative to the objective,
when the complementarity is and the dual residual has stalled at its round-off level, or when the Newton matrix
stops being numerically positive definite close to the optimum.  If the iterate's :func:`certificate` is not
already below 1e-7, :func:`polish` then solves the problem exactly on the face the iterate identifies, and the
caller keeps whichever point has the better certificate.

Measured and not kept (triple chain, ``cond(G) ~ 1e30``): ADMM on ``[Mr, Dr, Kr]`` with PSD projections
(r = 10: objective still 77 % above the optimum after 20,000 iterations) and an active-face method with exact
face solves (cycles: the optimal face of a PSD block is reached by rotations, not by adding or dropping
directions).  A matrix-free version of this method (2026-12-07, trace normalization, prototype outside the package):
the same HKM predictor-corrector steps on ``T = [Mr, Dr, Kr]``, each Newton system solved by projected
preconditioned CG on the operator ``dT -> 2 sym_b(dT G) + sym(X_b^-1 dT_b Z_b)`` (``O(r^3)`` per product, no Newton
matrix), with a face polish by CG and this module's certificate.  The best ``O(r^3)`` preconditioner tried, one
3 x 3 matrix per entry ``(i, j)`` coupling ``Mr, Dr, Kr`` in the POD basis, leaves the Hessian alone (no barrier)
conditioned 5.0e3 / 2.8e4 / 2.5e5 at r = 20 / 35 / 50 (the block-diagonal Lyapunov preconditioner on ``G_bb``:
1.9e6 / 4.3e6 / 5.9e6), with a spread tail (deflating its 100 smallest eigenvectors exactly still leaves
13 / 468 / 3040).  CPU seconds (one BLAS thread, loaded machine): r = 20 2.5-2.9 and r = 35 11.9-13.1 (certified,
11,300 and 30,600 CG products), r = 50 not certified in 31 s (objective 2.2e-6 above the optimum; with inner
tolerances tied to the gap 1.0e-8 above after 150 s, certificate gap 1.5e-3), r = 70 / 100 not in 150 s; the dense
path took 0.07 / 0.38 / 6.0 / 11.6 s at r = 20 / 35 / 50 / 70 in the same session.  One CG product costs
0.3-0.4 / 0.5-0.6 / 0.9-1.1 / 1.8-2.0 ms at r = 35 / 50 / 70 / 100, so 5 s at r = 100 allow about 2,500 of them.
Where ``Mr >= I`` spends its time (2026-12-07, triple chain r = 35, CPU, one BLAS thread, best of 5): 0.82 s
against 0.29 s for the trace normalization.  Its screening solved the ``Mr``-only relaxation (7 iterations,
0.06 s, stopped once ``Dr`` is clearly indefinite) and then the ``Mr, Dr`` SDP in 1260 unknowns (18 iterations,
0.58 s: each a 1260-square ``dpotrf`` of 17.5 ms, the two Kronecker blocks 6.6 ms, the solves 2.2 ms); the two
eliminations took 0.15 s, the certificate 2 ms, no polish.  The trace optimum needs the ``Dr`` cone only (630
unknowns, 2.4 ms per factorization), so the gap is the second cone, not overhead.  Since the same day (in-process
A/B against the previous code, interleaved, best of 10, machine load 5-10): 0.72 -> 0.47 s at r = 35, 0.09 ->
0.05 s at r = 20, 5.2 -> 3.6 s at r = 50, by three changes: the ``Mr``-only round is skipped where its start
shows ``Dr`` clearly indefinite (:func:`fmu_opinf._sdp_paths._predicted_cones`; same bits, 0.72 -> 0.62 s),
the ``Mr, Dr`` round starts from the least-squares ``Dr`` (:func:`fmu_opinf._sdp_paths._least_squares_start`,
a dual start centred on it; 18 -> 14 iterations, the solution moved by 1e-7 (6e-7 at r = 50) relative, objectives within
2e-10, certified), and each cone's inverse Cholesky factor is computed once per iteration (same bits).
Measured and not kept there:
the dual start ``Z = eta I`` with the start's complementarity equal to its objective (1-3 fewer iterations;
``Mr >= I`` r = 35 / 50: 0.76 / 4.35 -> 0.67 / 3.86 s together with the next one, objectives within 3.2e-10),
the ``Mr, Dr`` round's quadratic form read from the ``Mr`` round's elimination (r = 50: 0.45 -> 0.25 s, objectives
equal to 1e-15): both move the ``Mr >= I`` solution (1e-6, resp. 1e-13 .. 1e-11 relative), and the default fit's
output-error refinement turns that into a max eps_y up to 20 % different at r = 10 .. 40 (a 1e-13 congruence of
today's solution does the same: r = 15 3.77e-7 -> 3.00e-7 / 3.11e-7).  Also measured: a face polish after a
looser stop (the faces are wide, 28 and 31 of 35 eigenvalues: the polish costs 0.13 s, four iterations, while a
stop at 1e-4 saves four and polishes to an objective 1.3e-7 above the optimum), a primal start ``X = 0.1 I`` or
``10 I`` (1-2 more iterations).  Single-precision Cholesky (2026-12-07, r = 35, prototype outside the package):
``spotrf`` of the 1260-square matrix 9.6 against 18.8 ms (``dpotrf``), a float32 solve 0.8 ms, a float64 residual
(``dsymv``, the matrix in cache) 0.1 ms.  Refined to the float64 solve's residual, each solve took 3 residuals in
the first nine iterations, 4-6 in the next eight and 8-10 in the last four, and in the final iteration's two solves
refinement diverged (error 0.3-0.7 relative: ``cond * 6e-8 > 1``), so those need ``dpotrf`` anyway: at most
2.5 ms saved per iteration early, a loss later (20 instead of 18 iterations without the fallback).  Not kept.
Centrality correctors (2026-12-07, same A/B harness, CPU, one BLAS thread, best of 10 (r = 50: 2), load 2-3):
``Mr >= I`` r = 20 / 35 / 50: 12 / 14 / 16 -> 10 / 11 / 13 iterations, 0.041 / 0.425 / 3.06 -> 0.043 / 0.361 / 2.54 s
(r = 20 even: the correctors' small-matrix work costs what the two factorizations of 420 unknowns saved), objectives
within 1.6e-10, certified (gap <= 1.2e-9); the trace normalization r = 20 / 35: 16 / 17 -> 15 / 16, 0.027 / 0.202 ->
0.027 / 0.199 s.  In steps at r = 35 (then two correctors, box ``[0.1, 10]``): the correctors alone 0.447 -> 0.423 s,
with the solves by ``dtrsv`` instead of ``dpotrs`` (0.9 -> 0.3 ms each, four to five per iteration) 0.457 -> 0.397 s.
Of the 23 ``Mr >= I`` problems of the tests, 14 took fewer iterations (a round 17 -> 10 the most), 7 as many, two
exact-data ones one more (23 -> 24); all certified, objectives within 5.3e-10 (the trace normalization: 2 fewer, 21
as many, 11 of them without an SDP).  Measured and not kept there: two correctors (box ``[0.1, 10]``, aim +0.1: r = 35
12 iterations), four or six (11 iterations as with three, with 33 correctors against 28 and more: each costs a solve
and the eigenvalues of its trial point), an aim of +0.3 or +0.5 (same counts), a box ``[0.1, 5]`` or ``[0.3, 2]`` (12
/ 11), the step factor 0.995 / 0.999 instead of 0.99 and Mehrotra's exponent 2 instead of 3 (1-5 more iterations),
and with the correctors a start centred at 0.01 instead of 0.1 of the objective (:data:`_START_CENTRING`; triple
chain r = 35 / 50 one iteration fewer, but 7 of the 13 ``Mr, Dr`` test problems 1-5 more).  Where the ``Mr >= I`` path
spends its time now (r = 35, profile): 10 factorizations 0.17 s, Kronecker blocks 0.05 s, the ``Kr`` elimination 0.05
s (a 630 x 1260 triangular solve 17 ms and a 1260-square ``dsyrk`` 21 ms: already the dense minimum), the copy of
``2 S`` 0.02 s, correctors and step lengths (35-square eigenvalue problems) about 0.03 s; issue 16's 0.3 s needs
about three iterations fewer again.
The trace normalization (2026-12-07, in-process A/B, CPU, one BLAS thread, best of 5 / 3, load 5): its screened
rounds start from the screening's least squares made interior (:func:`fmu_opinf._sdp_paths._trace_start`; r = 20 / 35
15 / 16 -> 8 / 8 iterations, 0.041 / 0.231 -> 0.026 / 0.184 s), and where two blocks are indefinite and one is far
more so, its cone is tried alone first (:func:`fmu_opinf._sdp_paths._first_cones`): at r = 50 the ``Dr, Kr`` round
(2550 unknowns, 22 iterations of a 145 ms ``dpotrf``, 5.35 s) became a ``Dr`` round (1275 unknowns, 12 iterations,
1.09 s) whose ``Kr`` is positive definite, at r = 55 the three-cone SDP (20 s) a ``Dr`` round (2.6-2.9 s); objectives
within 1.5e-10 relative at r = 40 .. 55, certified.  Measured and not kept for ``Mr >= I`` at r = 35 (same day):
a mass start from the trace-normalized least squares (its eigenvalues ``c lambda`` clipped below at ``1.3``, ``c`` =
0.3 / 1 / 3, also with its ``Dr``): 10 / 11 iterations at r = 20 / 35 as now, 11-13 against 13 at r = 50, for one
more factorization of the Newton matrix's size; separate margins for the start's ``Mr`` and ``Dr``, ``Dr`` scaled to
that ``Mr`` (``Mr = 1.1 / 1.3 / 2 I``, ``Dr`` margin 0.1 / 0.3, ``Dr`` times 1 .. 2): 10-11 / 11-13 / 12-14 iterations
at r = 20 / 35 / 50 against 10 / 11 / 13; the Kronecker blocks with ``np.take`` and preallocated products
(2.00 -> 1.83 ms per 35-square cone, same bits: 3 ms of 0.36 s).  Not tried, estimated: shrinking the Newton
system to the optimal face in the last iterations.  At the optimum (7 of 35 eigenvalues of ``Mr - I``, 4 of ``Dr``
at the bound) only the directions inside the null spaces (``7 * 8 / 2 + 4 * 5 / 2 = 38`` of 1260 unknowns) have
barrier terms ``~ 1 / mu`` that decide them alone; the mixed ones (``7 * 28 + 4 * 31 = 320``) carry terms of the
size of ``S``, so an exact reduction keeps 1222 unknowns (9 % of a factorization saved), and one to the face alone
(902 unknowns) is the face polish above.

Certificate
-----------
:func:`certificate` checks a candidate ``T = [M, D, K]`` independently of the solver: the dual matrices
``Z_b = sym(grad_b f) - lambda E_b`` (``lambda`` the trace multiplier) must be PSD and complementary to the
primal blocks.  For any feasible ``T'``,
``f(T') >= f(T) - sum_b <Z_b, T_b - L_b> + sum_b min(0, lambda_min(Z_b)) trace(T'_b - L_b)``; the reported gap
is ``sum_b |<Z_b, T_b - L_b>| + max(0, -lambda_min(Z_b)) trace(T_b - L_b)`` (the bound with ``T'`` replaced
by ``T``) relative to ``f``, or to ``1e-9 ||G|| ||T||^2`` when ``f`` is smaller (exact data, where ``f = 0``:
the gap is then an absolute bound, ``f`` below ``1e-15 ||G|| ||T||^2`` at the certification level 1e-6).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.linalg

__all__ = ["ConeBlock", "IPMResult", "solve_ipm", "polish", "certificate"]


@dataclass(frozen=True)
class ConeBlock:
    """One PSD block of the variable vector: entries ``start .. start + k(k+1)/2`` (upper triangle, row-major),
    constraint ``mat(w) - lower * I >= 0``."""

    start: int
    k: int
    lower: float = 0.0


@dataclass
class IPMResult:
    """Result of :func:`solve_ipm`.

    Attributes
    ----------
    w : ndarray
        Solution (last iterate).
    status : str
        ``"optimal"`` (gap and residuals below ``tol``), ``"floor"`` (gap below ``tol``, dual residual stalled at
        round-off), ``"stopped"`` (by the caller's ``stop``), ``"max_iterations"``, ``"stalled"`` (step length
        below 1e-10) or ``"singular"``
        (Newton matrix not positive definite, typical close to the optimum); ``w`` is then
        the last interior iterate, which the caller certifies.
    iterations : int
    seconds : float
        CPU seconds (``time.process_time``).
    gap : float
        Complementarity ``sum_j <X_j, Z_j>`` relative to the objective (the stopping test of :func:`solve_ipm`).
    info : dict
        ``objective``, ``dual_residual``, ``mu``.
    """

    w: np.ndarray
    status: str
    iterations: int
    seconds: float
    gap: float
    info: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------------------
# Symmetric-matrix helpers in the upper-entry coordinates
# ----------------------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def _triu(k: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(k)``, cached: the iteration asks for them a dozen times per cone (r = 35, ``Mr >= I``:
    about 30 ms of 0.6 s CPU before)."""
    iu, ju = np.triu_indices(k)
    iu.flags.writeable = ju.flags.writeable = False  # shared by all callers
    return iu, ju


def _mat(v: np.ndarray, k: int) -> np.ndarray:
    """Symmetric ``k x k`` matrix from its upper-triangular entries (row-major)."""
    iu, ju = _triu(k)
    out = np.zeros((k, k))
    out[iu, ju] = v
    out[ju, iu] = v
    return out


def _adjoint(Z: np.ndarray) -> np.ndarray:
    """``mat^*(Z)``: gradient of ``<Z, mat(v)>`` in ``v`` (off-diagonal entries counted twice)."""
    iu, ju = _triu(Z.shape[0])
    return np.where(iu == ju, 1.0, 2.0) * 0.5 * (Z[iu, ju] + Z[ju, iu])


def _add_kron_upper(out: np.ndarray, Y: np.ndarray, Z: np.ndarray) -> None:
    """Add the upper triangle (column index >= row index) of the matrix of ``v -> mat^*(sym(Y mat(v) Z))`` (the
    symmetric Kronecker product, ``Y, Z`` symmetric ``k x k``) to the ``k(k+1)/2``-square ``out`` in place.

    Entry ``(pq, st)`` is ``<E_pq, sym(Y E_st Z)>`` with ``E_pq = e_p e_q^T + e_q e_p^T`` (``e_p e_p^T`` on the
    diagonal); expanding the placements, the eight products reduce to the four terms
    ``(Y_ps Z_qt + Y_qs Z_pt) + (Y_pt Z_qs + Y_qt Z_ps)``, halved on diagonal pairs.  The Cholesky factorization
    of the Newton matrix reads one triangle only, so half of the ``O(k^4)`` entries suffice: the rows
    ``(p, q), q >= p`` of one ``p`` are contiguous and need only the columns ``(s, t)`` with ``s >= p``, where
    with ``M[q, s, t] = Y_qs Z_pt + Z_qt Y_ps`` (``q, s, t >= p``) the entry is ``M[q, s, t] + M[q, t, s]``.
    Row group by row group the gathers act on ``(k - p)^3`` arrays; measured 4x faster (k = 35 .. 60) than
    gathering the full block from the rows ``p, q`` of ``Y`` and ``Z``.  Entries left of the diagonal inside a
    row group are written too (correct values, which the factorization does not read).
    """
    k = Y.shape[0]
    start = 0
    for p in range(k):
        m = k - p
        upper, lower, diagonal = _upper_positions(m)
        Yq, Zq = Y[p:, p:], Z[p:, p:]
        M = np.multiply(Yq[:, :, None], Z[p, p:])
        M += Zq[:, None, :] * Y[p, p:, None]
        M = M.reshape(m, m * m)
        rows = M[:, upper]
        rows += M[:, lower]  # M[q, s, t] + M[q, t, s], without forming M + M^T
        rows[:, diagonal] *= 0.5
        rows[0] *= 0.5
        out[start:start + m, start:] += rows
        start += m


@functools.lru_cache(maxsize=256)
def _upper_positions(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat positions of the upper triangle (row-major) in an ``m x m`` array, of the transposed entries, and the
    mask of its diagonal entries (cached: :func:`_add_kron_upper` asks for every ``m <= k`` in every iteration)."""
    su, tu = np.triu_indices(m)
    upper, lower, diagonal = su * m + tu, tu * m + su, su == tu
    upper.flags.writeable = lower.flags.writeable = diagonal.flags.writeable = False  # shared by all callers
    return upper, lower, diagonal


def _max_step(Li: np.ndarray, dX: np.ndarray) -> float:
    """Largest ``alpha`` (capped at 1e6) with ``X + alpha dX`` PSD, for positive definite ``X`` given by its
    inverse Cholesky factor ``Li`` (:func:`_inverse_factor`)."""
    smallest = float(np.linalg.eigvalsh(Li @ dX @ Li.T)[0])
    return 1e6 if smallest >= 0 else min(1e6, -1.0 / smallest)


# ----------------------------------------------------------------------------------------------------------
# Interior-point method
# ----------------------------------------------------------------------------------------------------------
#: Stagnation test of :func:`_dual_at_floor`: the dual residual fell by less than this factor in one iteration.
_FLOOR_DECREASE = 0.5
#: ... while its relative size was already below this multiple of ``tol`` (1e-6 at the default 1e-9: the level
#: the certificate asks for, which judges the result anyway).
_FLOOR_LEVEL = 1e3


#: Dual start of :func:`solve_ipm` from a given primal start: ``Z_j = mu X_j^-1`` with ``mu`` this fraction of the
#: start's objective per cone dimension (triple chain, ``Mr >= I``, ``Mr, Dr`` cones from the least-squares start of
#: :func:`fmu_opinf._sdp_paths._least_squares_start`, r = 20 / 35 / 50: 0.03 -> 12 / - / 15, 0.1 -> 12 / 14 / 16,
#: 0.3 -> 12 / - / 16, 1 -> - / 16 / -, 10 -> - / 17 / - iterations, "-" not measured; 17 / 18 / 18 from the
#: default start; 2026-12-07).
_START_CENTRING = 0.1

#: Gondzio's multiple centrality correctors (Gondzio 1996, here in the scaled product of the HKM direction,
#: :func:`_centrality_targets`): after Mehrotra's corrector, at most this many further solves with the same
#: Cholesky factor, each aiming at a step :data:`_CORRECTOR_REACH` longer and kept only if the step grows by at least
#: :data:`_CORRECTOR_GAIN` of that.
_CORRECTORS = 3
_CORRECTOR_REACH = 0.2
_CORRECTOR_GAIN = 0.1
#: Eigenvalues of the trial point's scaled product are pushed into this box times the target ``sigma mu``.
_CORRECTOR_BOX = (0.1, 2.0)


def _dual_at_floor(residual: float, previous: float, relative: float, tol: float) -> bool:
    """Whether the dual residual has stopped decreasing at its round-off level.

    Each step solves the Newton system with a matrix whose entries grow like ``1 / mu``; once the
    complementarity is below ``tol`` the dual residual ``||2 (S w + s) - a y - mat^*(Z)||`` stalls at the
    round-off of that solve, which can sit just above ``tol`` times the objective (triple chain r = 50: at
    1.1e-9 .. 7e-9 for 16 more iterations, each one Cholesky factorization of a 2550-square matrix, until the
    Newton matrix lost definiteness; the point hardly moves and the certificate of the caller judges it).
    """
    return relative <= _FLOOR_LEVEL * tol and residual > _FLOOR_DECREASE * previous


def solve_ipm(
    S: np.ndarray,
    s: np.ndarray,
    cones: list[ConeBlock],
    *,
    a: np.ndarray | None = None,
    c: float = 0.0,
    constant: float = 0.0,
    tol: float = 1e-9,
    max_iterations: int = 100,
    callback: Callable[[int, float], None] | None = None,
    stop: Callable[[np.ndarray, float], bool] | None = None,
    start: np.ndarray | None = None,
) -> IPMResult:
    """Minimize ``w^T S w + 2 s^T w`` with ``mat(w_j) - lower_j I`` PSD and optionally ``a^T w = c``.

    Parameters
    ----------
    S : (n, n) ndarray
        Symmetric positive semidefinite.
    s : (n,) ndarray
    cones : list of ConeBlock
        Disjoint blocks of ``w`` constrained to be PSD (entries outside any block are free).
    a : (n,) ndarray, optional
        Equality constraint ``a^T w = c``.
    c : float
    constant : float, default=0
        Constant added to the objective (the full problem's value when ``S, s`` come from an elimination); the
        stopping test is relative to the full objective.
    tol : float, default=1e-9
        Stop when the complementarity ``sum <X_j, Z_j>`` and the dual residual times ``1 + ||w||`` (what it
        can change the objective by) are below ``tol`` times the objective (floor ``1e-12`` with ``S`` scaled
        to ``max(diag(S)) = 1``), or when the complementarity is below it and the dual residual has reached
        its round-off floor (status ``"floor"``, :func:`_dual_at_floor`).
    max_iterations : int, default=100
    callback : callable, optional
        ``callback(iteration, measure)`` after each iteration's residuals, ``measure`` the larger of the relative
        complementarity and dual residual that the stopping test compares with ``tol`` (for progress reports).
    stop : callable, optional
        ``stop(w, measure)`` after the callback; ``True`` ends the iteration with status ``"stopped"`` (the
        caller has learnt what it needed from the iterate, e.g. the cone screening of
        :mod:`fmu_opinf._sdp_paths` that a dropped cone is violated).
    start : (n,) ndarray, optional
        Primal start, interior (every ``mat(w_j) - lower_j I`` positive definite; ``a^T w = c`` is not needed: the
        method is infeasible-start), with the dual start centred on it: ``Z_j = mu X_j^-1``, ``mu`` a tenth of the
        start's objective per cone dimension (:data:`_START_CENTRING`).  Default: :func:`_initial_point` and
        ``Z_j = I``.

    Returns
    -------
    IPMResult
    """
    clock = time.process_time()
    n = S.shape[0]
    S = 0.5 * (S + S.T)
    scale_s = max(float(np.max(np.diag(S), initial=0.0)), np.finfo(float).tiny)
    S, s = S / scale_s, s / scale_s  # same minimizer; residuals relative to max diag(S) = 1 (~ ||S||, PSD S)
    S2, work = 2.0 * S, np.empty_like(S)
    m = sum(cone.k for cone in cones)
    if start is None:
        w, Z = _initial_point(n, cones, a, c), [np.eye(cone.k) for cone in cones]
    else:
        w = np.array(start, dtype=float)
        mu = _START_CENTRING * max(float(w @ S @ w + 2.0 * s @ w) + constant / scale_s, 0.0) / max(m, 1)
        Z = [mu * _spd_inverse(_mat(w[cone.start:cone.start + cone.k * (cone.k + 1) // 2], cone.k)
                               - cone.lower * np.eye(cone.k)) if mu > 0 else np.eye(cone.k) for cone in cones]
    y = 0.0
    status, iteration, gap, dual_norm, previous = "max_iterations", 0, np.inf, np.inf, np.inf
    for iteration in range(1, max_iterations + 1):
        X = [_mat(w[cone.start:cone.start + cone.k * (cone.k + 1) // 2], cone.k) - cone.lower * np.eye(cone.k)
             for cone in cones]
        Sw = S @ w  # one pass over S for the gradient and the objective
        grad = 2.0 * (Sw + s)
        dual = grad - (a * y if a is not None else 0.0)
        for cone, Zj in zip(cones, Z):
            dual[cone.start:cone.start + cone.k * (cone.k + 1) // 2] -= _adjoint(Zj)
        complementarity = sum(float(np.sum(Xj * Zj)) for Xj, Zj in zip(X, Z))
        objective = float(w @ Sw + 2.0 * s @ w) + constant / scale_s
        floor = max(abs(objective), 1e-12)
        gap = complementarity / floor
        residual = float(np.linalg.norm(dual))
        dual_norm = residual * (1.0 + float(np.linalg.norm(w))) / floor
        if callback is not None:
            callback(iteration, max(gap, dual_norm))
        if stop is not None and stop(w, max(gap, dual_norm)):
            status = "stopped"
            break
        if gap <= tol and dual_norm <= tol:
            status = "optimal"
            break
        if gap <= tol and _dual_at_floor(residual, previous, dual_norm, tol):
            status = "floor"
            break
        previous = residual
        try:
            step = _newton(S2, w, X, Z, cones, a, c, dual, complementarity / max(m, 1), work)
        except np.linalg.LinAlgError:  # numerically singular near the end: the caller certifies the iterate
            status = "singular"
            break
        if step[0] < 1e-10:
            status = "stalled"
            break
        w, Z, y = w + step[0] * step[1], [Zj + step[0] * dZ for Zj, dZ in zip(Z, step[2])], y + step[0] * step[3]
    objective = float(w @ S @ w + 2.0 * s @ w) * scale_s + constant
    return IPMResult(w=w, status=status, iterations=iteration, seconds=time.process_time() - clock, gap=gap,
                     info={"objective": objective, "dual_residual": dual_norm})


def polish(S: np.ndarray, s: np.ndarray, cones: list[ConeBlock], w: np.ndarray, *, a: np.ndarray | None = None,
           c: float = 0.0, threshold: float = 1e-6) -> np.ndarray | None:
    """Exact minimizer on the face of an interior-point iterate ``w`` (None if it leaves the cone).

    Each cone block ``X_j = mat(w_j) - L_j`` is split into the eigenvectors ``V_j`` with eigenvalues above
    ``threshold`` times the largest and the rest; on the face ``mat(w_j) = L_j + V_j U_j V_j^T`` the problem is an
    equality-constrained quadratic in the symmetric ``U_j``: one dense solve.  Near an optimum with strict
    complementarity this lands on the optimum up to round-off, where the interior-point iterate is only
    ``O(mu)`` close.  Every entry of ``w`` must belong to a cone block.
    """
    n = w.size
    columns, offset = [], np.zeros(n)
    for cone in cones:
        size = cone.k * (cone.k + 1) // 2
        X = _mat(w[cone.start:cone.start + size], cone.k) - cone.lower * np.eye(cone.k)
        eigs, vecs = np.linalg.eigh(X)
        V = vecs[:, eigs > threshold * max(float(eigs[-1]), np.finfo(float).tiny)]
        iu, ju = _triu(cone.k)
        pa, pb = np.triu_indices(V.shape[1])
        outer = V[iu][:, pa] * V[ju][:, pb] + V[iu][:, pb] * V[ju][:, pa]  # upper(v_a v_b^T + v_b v_a^T)
        outer[:, pa == pb] *= 0.5
        block = np.zeros((n, pa.size))
        block[cone.start:cone.start + size] = outer
        columns.append(block)
        offset[cone.start:cone.start + size] = np.where(iu == ju, cone.lower, 0.0)
    P = np.hstack(columns)
    if not P.shape[1]:
        return None
    Q = P.T @ S @ P
    g = P.T @ (S @ offset + s)
    try:
        factor = scipy.linalg.cho_factor(0.5 * (Q + Q.T), check_finite=False)
    except np.linalg.LinAlgError:
        return None
    u = scipy.linalg.cho_solve(factor, -g, check_finite=False)
    if a is not None:
        b = P.T @ a
        v = scipy.linalg.cho_solve(factor, b, check_finite=False)
        u = u + v * ((c - float(a @ offset) - float(b @ u)) / float(b @ v))
    polished = offset + P @ u
    for cone in cones:
        size = cone.k * (cone.k + 1) // 2
        X = _mat(polished[cone.start:cone.start + size], cone.k) - cone.lower * np.eye(cone.k)
        if np.linalg.eigvalsh(X)[0] < -1e-12 * max(float(np.abs(X).max()), 1.0):
            return None
    return polished


def _initial_point(n: int, cones: list[ConeBlock], a: np.ndarray | None, c: float) -> np.ndarray:
    """Interior start: each cone block ``(lower + 1) I``, free entries 0, scaled onto ``a^T w = c``."""
    w = np.zeros(n)
    for cone in cones:
        iu, ju = _triu(cone.k)
        w[cone.start:cone.start + iu.size] = np.where(iu == ju, cone.lower + 1.0, 0.0)
    if a is not None:
        value = float(a @ w)
        if value > 0 and c > 0 and all(cone.lower == 0 for cone in cones):
            w *= c / value
        else:
            w += a * ((c - value) / float(a @ a))
    return w


def _newton(S2: np.ndarray, w: np.ndarray, X: list, Z: list, cones: list[ConeBlock], a: np.ndarray | None,
            c: float, dual: np.ndarray, mu: float, work: np.ndarray) -> tuple:
    """Mehrotra predictor-corrector HKM step from ``S2 = 2 S``: returns ``(alpha, dw, dZ, dy)``.

    ``work`` (shaped like ``S2``) receives the Newton matrix and then its Cholesky factor: one buffer for all
    iterations instead of a fresh 52 MB array each (r = 50, two cones).
    """
    # inverse Cholesky factors, each computed once: the inverses and the step lengths of both directions use them
    Xf, Zf = [_inverse_factor(Xj) for Xj in X], [_inverse_factor(Zj) for Zj in Z]
    Xinv = [Li.T @ Li for Li in Xf]  # symmetric and PSD by construction even when X is ill-conditioned
    factor = _regularized_cholesky(lambda: _newton_matrix(S2, Xinv, Z, cones, work))
    primal = (float(a @ w) - c) if a is not None else 0.0

    def rhs(target: float, second: list | None) -> np.ndarray:
        # dZ_j = target X^-1 - Z - sym(X^-1 dX Z) - sym(X^-1 dX_aff dZ_aff);  stationarity residual -dual
        out = -dual
        for j, (cone, Xi, Zj) in enumerate(zip(cones, Xinv, Z)):
            sl = slice(cone.start, cone.start + cone.k * (cone.k + 1) // 2)
            extra = target * Xi - Zj
            if second is not None:
                extra = extra - _sym(Xi @ second[j])
            out[sl] += _adjoint(extra)
        return out

    def direction(u: np.ndarray, target: float, second: list | None, centring: list | None = None) -> tuple:
        # u = N^-1 rhs; bordered system [N, -a; a^T, 0] [dw; dy] = [rhs; -primal] with v = N^-1 a.  With
        # ``centring`` (a corrector, :func:`_centrality_targets`) the change of the direction: no residuals, and
        # dZ_j = E_j - sym(X^-1 dX Z)
        dw, dy = u, 0.0
        if a is not None:
            dy = (-(primal if centring is None else 0.0) - float(a @ u)) / float(a @ v)
            dw = u + v * dy
        dX = [_mat(dw[cone.start:cone.start + cone.k * (cone.k + 1) // 2], cone.k) for cone in cones]
        dZ = []
        for j, (Xi, Zj, dXj) in enumerate(zip(Xinv, Z, dX)):
            dz = (centring[j] if centring is not None else target * Xi - Zj) - _sym(Xi @ dXj @ Zj)
            if second is not None:
                dz = dz - _sym(Xi @ second[j])
            dZ.append(_sym(dz))
        return dw, dX, dZ, dy

    def step_length(dX, dZ) -> float:
        lengths = [1.0] + [_max_step(Li, d) for Li, d in zip(Xf, dX)] + [_max_step(Li, d) for Li, d in zip(Zf, dZ)]
        return min(lengths)

    m = max(sum(cone.k for cone in cones), 1)
    v = None
    if a is None:
        u = _cho_solve(factor, rhs(0.0, None))
    else:  # the predictor's right-hand side and a in one solve (reads the factor once)
        u, v = _cho_solve(factor, np.column_stack([rhs(0.0, None), a])).T
    dw, dX, dZ, dy = direction(u, 0.0, None)
    alpha = step_length(dX, dZ)
    mu_aff = sum(float(np.sum((Xj + alpha * a_) * (Zj + alpha * b_))) for Xj, a_, Zj, b_ in zip(X, dX, Z, dZ)) / m
    sigma = min(1.0, (mu_aff / mu) ** 3) if mu > 0 else 0.0
    second = [dXj @ dZj for dXj, dZj in zip(dX, dZ)]
    dw, dX, dZ, dy = direction(_cho_solve(factor, rhs(sigma * mu, second)), sigma * mu, second)
    alpha = step_length(dX, dZ)
    if _CORRECTORS:
        Lx = [np.linalg.cholesky(Xj) for Xj in X]
        for _ in range(_CORRECTORS):
            if alpha >= 1.0:
                break
            aim = min(1.0, alpha + _CORRECTOR_REACH)
            E = _centrality_targets(Lx, Xf, X, Z, dX, dZ, aim, sigma * mu)
            correction = direction(_cho_solve(factor, _corrector_rhs(dual.size, cones, E)), 0.0, None, E)
            trial = (dw + correction[0], [p + q for p, q in zip(dX, correction[1])],
                     [p + q for p, q in zip(dZ, correction[2])], dy + correction[3])
            longer = step_length(trial[1], trial[2])
            if longer < alpha + _CORRECTOR_GAIN * (aim - alpha):
                break
            (dw, dX, dZ, dy), alpha = trial, longer
    return min(1.0, 0.99 * alpha), dw, dZ, dy


def _centrality_targets(Lx: list, Xf: list, X: list, Z: list, dX: list, dZ: list, aim: float, mu: float
                        ) -> list[np.ndarray]:
    """Right-hand sides ``E_j`` (in the ``dZ`` equation) of one Gondzio centrality corrector for the step ``aim``.

    In the scaling of the current ``X = L L^T`` the product ``X Z`` is ``L^T Z L`` (symmetric); at the trial point
    ``X + aim dX, Z + aim dZ`` it is ``(L^-1 X_t L^-T)(L^T Z_t L)``, whose symmetric part has eigenvalues ``lambda``
    (``Q`` its eigenvectors).  Those below ``0.1 mu`` are raised to it, those above ``10 mu`` lowered to it (by at
    most ``10 mu``; ``mu`` the predictor-corrector's target, :data:`_CORRECTOR_BOX`); the change ``T = Q diag(delta)
    Q^T`` of the scaled product is, back in the ``dZ`` equation ``X dZ + dX Z = L T L^-1``,
    ``E_j = L^-T T L^-1``.
    """
    low, high = _CORRECTOR_BOX[0] * mu, _CORRECTOR_BOX[1] * mu
    out = []
    for L, Li, Xj, Zj, dXj, dZj in zip(Lx, Xf, X, Z, dX, dZ):
        product = (Li @ (Xj + aim * dXj) @ Li.T) @ (L.T @ (Zj + aim * dZj) @ L)
        values, vectors = np.linalg.eigh(_sym(product))
        delta = np.where(values < low, low - values, np.where(values > high, np.maximum(high - values, -high), 0.0))
        out.append(Li.T @ ((vectors * delta) @ vectors.T) @ Li)
    return out


def _corrector_rhs(n: int, cones: list[ConeBlock], E: list[np.ndarray]) -> np.ndarray:
    """Newton right-hand side of a corrector: ``mat^*(E_j)`` on each cone block, zero elsewhere."""
    out = np.zeros(n)
    for cone, Ej in zip(cones, E):
        out[cone.start:cone.start + cone.k * (cone.k + 1) // 2] = _adjoint(Ej)
    return out


def _newton_matrix(S2: np.ndarray, Xinv: list, Z: list, cones: list[ConeBlock], out: np.ndarray) -> np.ndarray:
    """Newton matrix ``2 S + sum_j (Z_j (x)_s X_j^-1)`` written into ``out``, valid in its upper triangle only
    (what :func:`_regularized_cholesky` reads; :func:`_add_kron_upper`)."""
    np.copyto(out, S2)
    for cone, Xi, Zj in zip(cones, Xinv, Z):
        sl = slice(cone.start, cone.start + cone.k * (cone.k + 1) // 2)
        _add_kron_upper(out[sl, sl], Xi, Zj)
    return out


def _spd_inverse(X: np.ndarray) -> np.ndarray:
    """Inverse of a positive definite matrix as ``Li^T Li`` (:func:`_inverse_factor`): symmetric and PSD by
    construction even when ``X`` is ill-conditioned near the boundary of the cone."""
    Li = _inverse_factor(X)
    return Li.T @ Li


def _inverse_factor(X: np.ndarray) -> np.ndarray:
    """``Li = L^-1`` for the Cholesky factor ``L`` of a positive definite ``X`` (``X^-1 = Li^T Li``)."""
    L = np.linalg.cholesky(X)
    return scipy.linalg.solve_triangular(L, np.eye(X.shape[0]), lower=True, check_finite=False)


def _regularized_cholesky(build: Callable[[], np.ndarray]) -> np.ndarray:
    """Cholesky factor of the Newton matrix ``build()`` (upper triangle read); when round-off (in the Schur
    complement ``S`` or in the barrier term, whose entries grow like ``1 / mu`` near the optimum) makes it
    numerically indefinite, shift the diagonal by 1e-15 .. 1e-11 of its largest entry (an inexact Newton step;
    the certificate judges the result).

    LAPACK ``dpotrf`` factors the C-ordered matrix in place through its transpose (Fortran order, lower
    triangle = the upper triangle of the C-ordered matrix): no copy, no symmetric fill.  A failed attempt
    leaves the matrix partly overwritten, so each retry builds it again (failures happen only near the end).
    Returns the factor for :func:`_cho_solve`.
    """
    N = build()
    top = float(np.max(np.diagonal(N)))
    for shift in (0.0, 1e-15, 1e-13, 1e-11):
        if shift:
            N = build()
            N[np.diag_indices_from(N)] += shift * top
        factor, info = scipy.linalg.lapack.dpotrf(N.T, lower=True, clean=False, overwrite_a=True)
        if info == 0:
            return factor
    raise np.linalg.LinAlgError("Newton matrix not positive definite")


def _cho_solve(factor: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``N^-1 b`` from the factor of :func:`_regularized_cholesky` (``b`` a vector or its columns).

    Two triangular matrix-vector solves (BLAS ``dtrsv``) per column: LAPACK ``dpotrs`` goes through the
    matrix-matrix ``dtrsm``, which for one right-hand side took 0.8-0.9 ms against 0.3 ms at n = 1260 (2026-12-07,
    one thread; the factor of 12.7 MB is read twice either way), the same solution to 1e-15 relative.
    """
    if b.ndim == 2:
        return np.column_stack([_cho_solve(factor, column) for column in b.T])
    forward = scipy.linalg.blas.dtrsv(factor, b, lower=1)
    return scipy.linalg.blas.dtrsv(factor, forward, lower=1, trans=1, overwrite_x=1)


def _sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + a.T)


# ----------------------------------------------------------------------------------------------------------
# Certificate
# ----------------------------------------------------------------------------------------------------------
def certificate(T: np.ndarray, G: np.ndarray, normalization: str, total: float) -> tuple[float, dict]:
    """Relative optimality gap estimate of a feasible ``T = [M, D, K]`` from its dual matrices (module doc).

    Parameters
    ----------
    T : (r, 3r) ndarray
        Candidate ``[M, D, K]`` (PSD blocks; ``trace(M) = total`` or ``M >= I``).
    G : (3r, 3r) ndarray
        Gram matrix of the objective ``f(T) = trace(T G T^T)``.
    normalization : {"trace", "mass-eigenvalue"}
    total : float
        ``trace(M)`` of the trace normalization.

    Returns
    -------
    gap : float
        Relative gap estimate (0 at an exact KKT point).
    details : dict
        ``objective``, ``multiplier``, ``dual_eig_min`` (per block), ``primal_eig_min`` (of ``T_b - L_b``),
        ``complementarity``.
    """
    r = T.shape[0]
    eye = np.eye(r)
    grad = 2.0 * T @ G
    objective = float(np.sum((T @ G) * T))
    duals = [_sym(grad[:, b * r:(b + 1) * r]) for b in range(3)]
    multiplier = 0.0
    if normalization == "trace":
        multiplier = float(np.sum(duals[0] * T[:, :r]) / total)
        duals[0] = duals[0] - multiplier * eye
    primal = [_sym(T[:, b * r:(b + 1) * r]) - (eye if (b == 0 and normalization != "trace") else 0.0)
              for b in range(3)]
    complementarity = sum(abs(float(np.sum(z * p))) for z, p in zip(duals, primal))
    dual_min = [float(np.linalg.eigvalsh(z)[0]) for z in duals]
    primal_min = [float(np.linalg.eigvalsh(p)[0]) for p in primal]
    infeasibility = sum(max(0.0, -e) * max(float(np.trace(p)), 0.0) for e, p in zip(dual_min, primal))
    # A clearly negative objective (measured at the normalization's scale, trace(M) = total or M >= I, i.e.
    # ||T||^2 ~ r, not at T itself) means the iterate exploited round-off of a numerically indefinite G and ran
    # away (M ~ 1e14, objective -8e12 on exact continuous-time data): never certified, whatever T's size.
    if objective < -1e-12 * float(np.linalg.norm(G, 2) * max(total, r)):
        return float("inf"), {"objective": objective, "multiplier": multiplier, "dual_eig_min": dual_min,
                              "primal_eig_min": primal_min, "complementarity": complementarity}
    scale = float(np.linalg.norm(G, 2) * np.sum(T * T))
    gap = (complementarity + infeasibility) / max(objective, 1e-9 * scale, np.finfo(float).tiny)
    return gap, {"objective": objective, "multiplier": multiplier, "dual_eig_min": dual_min,
                 "primal_eig_min": primal_min, "complementarity": complementarity}
