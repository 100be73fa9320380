"""The SDP of eq. (16) on the compressed data factor: quadratic form, cone screening, normalizations, solvers.

:func:`fmu_opinf.inference.fit_operators` calls :func:`fit_compressed` (or :func:`fit_factored` above r = 60, or
:func:`solve_sdp_direct` for ``compressed=False``) with the triangular factor ``R`` of
:func:`fmu_opinf.inference.compressed_factor`; the choices (cone screening, the two normalizations, the dense
interior-point method with its certificate, Clarabel, the factored start) are explained in the inference module
docstring, sections *Solution path*, *Normalization* and *Solvers*.  The interior-point method itself and the
optimality certificate are in :mod:`fmu_opinf._sdp`.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from ._lbfgs import LBFGSResult, minimize_lbfgs
from ._progress import Progress
from .errors import SolverError

#: Tolerance of the second solve when the first ends ``optimal_inaccurate`` (inference module docstring, *Solver
#: status*).
_TOL_RETRY = 1e-8

# ----------------------------------------------------------------------------------------------------------
# Quadratic form on the upper-triangular entries
# ----------------------------------------------------------------------------------------------------------
def _sym_index(r: int) -> np.ndarray:
    """``(r, r)`` int array: position of entry (i, j) in the upper-triangular (row-major) vector."""
    iu = np.triu_indices(r)
    idx = np.empty((r, r), dtype=int)
    idx[iu] = np.arange(iu[0].size)
    idx[iu[1], iu[0]] = np.arange(iu[0].size)
    return idx


def _hessian(G: np.ndarray, r: int) -> np.ndarray:
    """Dense ``H`` with ``sum_i t_i^T G t_i = w^T H w``, ``w`` the upper entries of ``Mr, Dr, Kr`` stacked."""
    ns = r * (r + 1) // 2
    sym = _sym_index(r)
    rows = np.hstack([sym, sym + ns, sym + 2 * ns])  # (r, 3r): variable index of Ts[i, c]
    H = np.zeros((3 * ns, 3 * ns))
    for i in range(r):  # within one row the 3r indices are distinct, so fancy-index += is exact
        H[np.ix_(rows[i], rows[i])] += G
    return H


def _unpack(w: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ns = r * (r + 1) // 2
    sym = _sym_index(r)
    return tuple(w[b * ns : (b + 1) * ns][sym] for b in range(3))  # type: ignore[return-value]


def _mass_indicator(r: int) -> np.ndarray:
    """Vector ``a`` with ``a @ w = trace(Mr)``."""
    a = np.zeros(3 * r * (r + 1) // 2)
    a[np.diag(_sym_index(r))] = 1.0
    return a


# ----------------------------------------------------------------------------------------------------------
# Solution paths
# ----------------------------------------------------------------------------------------------------------
def _solve_unconstrained(H: np.ndarray, a: np.ndarray, trace: float, root: np.ndarray | None = None,
                         order: tuple[int, int, int] = (0, 1, 2)) -> tuple[np.ndarray | None, _OrderedFactor | None]:
    """Minimizer of ``w^T H w`` subject to ``a^T w = trace`` (None if it is not unique), and the Cholesky factor
    of ``H + a a^T`` with its blocks in ``order`` (None where it does not exist), which :func:`_reduced_quadratic`
    reuses.

    ``(a^T w)^2`` is constant on the constraint set, so ``H + a a^T`` gives the same minimizer; unlike ``H`` it
    stays positive definite for exact data, where ``H`` is singular along the true operators.  The copy of ``H``
    is factored in place (through its transpose, Fortran order): r = 60, ``H`` of 241 MB, one copy instead of two.
    With ``root`` (``G = root^T root``, the data's triangular factor that ``H`` is assembled from) the solution is
    refined by :func:`_refine_through_root`.
    """
    solve, factor = _semidefinite_solver(H, a, order)
    h_inv_a = None if solve is None else solve(a)
    if h_inv_a is None or not float(a @ h_inv_a) > 0:
        return None, factor
    w = trace * h_inv_a / float(a @ h_inv_a)
    return (w if root is None else _refine_through_root(w, a, trace, h_inv_a, root, solve)), factor


@dataclass(frozen=True)
class _OrderedFactor:
    """Lower Cholesky factor ``lower`` (Fortran order; its upper triangle is not cleared) of ``H + a a^T`` with
    the ``ns``-square blocks of ``Mr, Dr, Kr`` permuted into ``blocks`` (for :func:`_reduced_quadratic`)."""

    blocks: tuple[int, int, int]
    lower: np.ndarray


def _semidefinite_solver(H: np.ndarray, a: np.ndarray, order: tuple[int, int, int] = (0, 1, 2)
                         ) -> tuple[Callable[[np.ndarray], np.ndarray] | None, _OrderedFactor | None]:
    """``b -> (H + a a^T)^-1 b`` and the factor behind it: Cholesky of the matrix with its blocks in ``order``
    (a permuted copy of ``H``, factored in place), else the minimum-norm solution (:func:`_pseudo_solver`, no
    factor)."""
    ns = H.shape[0] // 3
    perm = np.concatenate([np.arange(b * ns, (b + 1) * ns) for b in order])
    A = _add_outer(_blocks(H, list(order), list(order), ns), a[perm])
    lower, info = scipy.linalg.lapack.dpotrf(A.T, lower=True, clean=False, overwrite_a=True)
    if info != 0:
        return _pseudo_solver(_add_outer(H.copy(), a)), None

    def solve(b: np.ndarray) -> np.ndarray:
        out = np.empty_like(b)
        out[perm] = scipy.linalg.cho_solve((lower, True), b[perm], check_finite=False)
        return out

    return solve, _OrderedFactor(tuple(order), lower)  # type: ignore[arg-type]


#: Steps of :func:`_refine_through_root` (the second changed the solution by 3e-16 relative in the case measured).
_REFINEMENT_STEPS = 2


def _refine_through_root(w: np.ndarray, a: np.ndarray, trace: float, x: np.ndarray, root: np.ndarray,
                         solve: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Corrected semi-normal equations: Newton steps on the optimality conditions ``H w = -mu a``, ``a^T w =
    trace`` whose residual forms ``H w`` through ``root`` (``sum_i P_i^T root^T (root P_i w)``), never through the
    assembled ``H``: assembling ``G = root^T root`` squared the data's conditioning, and on exact data the certified
    least-squares operators were 4.4e-11 off where the SDP's were 5e-15 (a comparison's max eps_y 1.7e-21 against
    1.3e-24; with two steps 1.4e-24).  ``x = (H + a a^T)^-1 a``; ``solve`` applies that inverse."""
    r = root.shape[1] // 3
    ns = r * (r + 1) // 2
    sym = _sym_index(r)
    rows = np.hstack([sym, sym + ns, sym + 2 * ns])  # (r, 3r): variable index of row i of [Mr, Dr, Kr]
    mu = trace - trace / float(a @ x)  # (H + a a^T) w = (trace - mu) a at the first solution
    for _ in range(_REFINEMENT_STEPS):
        Hw = np.zeros_like(w)
        np.add.at(Hw, rows, (w[rows] @ root.T) @ root)
        stationarity, feasibility = -mu * a - Hw, trace - float(a @ w)
        y = solve(stationarity + a * feasibility)
        step = (float(a @ y) - feasibility) / float(a @ x)
        w, mu = w + y - step * x, mu + step
    return w


def _add_outer(A: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``A += a a^T`` in place, on the entries where ``a`` is nonzero only (the trace row has ``r`` nonzeros
    among ``3 ns``; the dense 5490-square outer product and sum took 0.4 s at r = 60)."""
    nonzero = np.flatnonzero(a)
    A[np.ix_(nonzero, nonzero)] += np.outer(a[nonzero], a[nonzero])
    return A


#: Eigenvalues of a semidefinite system below this fraction of the largest count as zero in :func:`_pseudo_solver`.
_NULL_LEVEL = 1e-13


def _pseudo_solver(A: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
    """``b ->`` the minimum-norm solution of ``A x = b`` for a symmetric semidefinite ``A`` (None if ``A`` is zero).

    Exact data with a degenerate model (e.g. proportional damping: ``S (M, D, K)`` with ``S`` a polynomial in
    ``M^-1 K`` fits as well as ``(M, D, K)``) leave ``H`` a null space of several dimensions, where the Cholesky
    factorization breaks down on round-off; the minimum-norm minimizer is the best-conditioned one of that face.
    """
    eigs, vecs = np.linalg.eigh(A)
    kept = eigs > _NULL_LEVEL * max(eigs[-1], np.finfo(float).tiny)
    if not np.any(kept):
        return None
    basis, inverse = vecs[:, kept], 1.0 / eigs[kept]
    return lambda b: basis @ ((basis.T @ b) * inverse)


def _clarabel_settings(tol: float, verbose: bool) -> dict[str, Any]:
    settings = dict(tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol, tol_ktratio=1e-7, verbose=verbose)
    if _clarabel_has_thread_limit():
        # one thread: Clarabel 0.11's factorization (faer) otherwise starts a native thread pool, which a process
        # forked later (the fit's second start, fmu_opinf._background) inherits without its threads: the next
        # Clarabel solve there waited for them for ever (a second fit in one process hung, 2026-12-05)
        settings["max_threads"] = 1
    return settings


@functools.cache
def _clarabel_has_thread_limit() -> bool:
    """Whether the installed Clarabel takes ``max_threads`` (0.10 on; older ones run one thread anyway)."""
    import clarabel

    return hasattr(clarabel.DefaultSettings(), "max_threads")


_BLOCKS = ("Mr", "Dr", "Kr")


def _reduced_quadratic(H: np.ndarray, a: np.ndarray, trace: float, keep: tuple[int, ...], r: int,
                       factor: _OrderedFactor | None = None) -> tuple:
    """Eliminate the blocks not in ``keep`` from ``min w^T H w, a^T w = trace`` (their cones dropped).

    Returns ``(idx_keep, idx_elim, S, s, recover)``: over the kept entries ``w_A`` the objective is
    ``w_A^T S w_A + 2 s^T w_A + const`` and the eliminated entries are ``w_F = recover(w_A)`` (affine).  If the
    mass block is eliminated, the trace constraint is eliminated with it (bordered KKT system).

    With the Cholesky factor ``L L^T`` of ``H_FF`` (plus ``a_F a_F^T`` with the constraint ``a_F^T w_F = trace``:
    same minimizer on it, but positive definite for exact data), ``W = L^-1 H_FA`` and ``u = L^-1 a_F``:
    ``S = H_AA - W^T W + (W^T u)(u^T W) / u^T u`` (without the constraint the first two terms),
    ``s = (W^T u) trace / u^T u`` and ``w_F = L^-T (-W w_A + u (u^T W w_A + trace) / u^T u)``.  One triangular
    solve and one symmetric product, half the operations of solving for ``X = -H_FF^-1 H_FA`` and forming
    ``H_FA^T X`` (r = 60: 0.74 .. 1.06 s instead of 1.4 .. 2.4 s); the blocks of ``H`` are copied by slices
    (:func:`_blocks`) and ``w_F`` is only ever needed for single vectors.

    Measured and not kept: eliminating one block through the eigenvectors ``Q`` of its ``G_bb`` (its part of
    ``H`` is the Lyapunov operator ``T -> T G_bb + G_bb T``, diagonal in ``Q``; ``O(r^3)`` per column, r = 60:
    0.34 s instead of 0.74 s).  Its round-off grows with ``cond(G_bb)`` where the Cholesky factorization stays
    backward stable: exact-data fits lost their exactness (``test_exporter_combinations``: errors 6e-17 and
    1.6e-10 where 1e-18 and 1.5e-20 are required), and the same elimination in :func:`_solve_unconstrained` moved
    a sensitive r = 4 fit by 1.2e-4 (``test_scaleout``, tolerance 1e-4).

    ``factor``: the Cholesky factor of the whole ``H + a a^T`` from the screening's unconstrained solve
    (:func:`_solve_unconstrained`).  Where its leading blocks are the eliminated ones, mass block among them, its
    leading part is ``L``, its lower-left part ``W^T`` and its trailing part ``L22`` gives ``H_AA - W^T W = L22
    L22^T``: no factorization and no triangular solve of its own (:func:`_leading_elimination`; triple chain r = 35,
    trace normalization, ``Dr`` kept: 0.09 s of the 0.37 s of the SDP path).
    """
    ns = r * (r + 1) // 2
    free = [b for b in range(3) if b not in keep]
    idx_a = np.concatenate([np.arange(b * ns, (b + 1) * ns) for b in keep])
    idx_f = np.concatenate([np.arange(b * ns, (b + 1) * ns) for b in free])
    a_f = a[idx_f]
    constrained = 0 in free
    reused = _leading_elimination(H, factor, free, keep, ns) if constrained else None
    if reused is not None:
        L, W, S = reused
    else:
        H_ff, H_fa = _blocks(H, free, free, ns), _blocks(H, free, list(keep), ns)
        if constrained:
            _add_outer(H_ff, a_f)
        L = scipy.linalg.cholesky(H_ff, lower=True, overwrite_a=True, check_finite=False)
        W = scipy.linalg.solve_triangular(L, H_fa, lower=True, overwrite_b=True, check_finite=False)
        S = _blocks(H, list(keep), list(keep), ns) - W.T @ W
    if not constrained:
        lin = np.zeros(idx_a.size)

        def recover(w_a: np.ndarray) -> np.ndarray:
            return -scipy.linalg.solve_triangular(L, W @ w_a, lower=True, trans="T", check_finite=False)
    else:  # w_F = -Y w_A - z mu (Y = H_FF^-1 H_FA, z = H_FF^-1 a_F) with the multiplier mu of the constraint
        u = scipy.linalg.solve_triangular(L, a_f, lower=True, check_finite=False)
        beta = float(u @ u)
        Wu = W.T @ u
        S += np.outer(Wu, Wu / beta)
        lin = Wu * (trace / beta)

        def recover(w_a: np.ndarray) -> np.ndarray:
            Ww = W @ w_a
            return scipy.linalg.solve_triangular(L, u * ((u @ Ww + trace) / beta) - Ww, lower=True, trans="T",
                                                 check_finite=False)
    return idx_a, idx_f, 0.5 * (S + S.T), lin, recover


def _leading_elimination(H: np.ndarray, factor: _OrderedFactor | None, free: list[int], keep: tuple[int, ...],
                         ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(L, W, H_AA - W^T W)`` of :func:`_reduced_quadratic` read from the factor of the whole ``H + a a^T``
    (None unless its leading blocks are ``free`` in that order, which must hold the mass block: ``a a^T`` then lies
    in the eliminated part, as :func:`_reduced_quadratic` adds it).

    With ``P (H + a a^T) P^T = [L 0; W^T L22] [L^T W; 0 L22^T]`` (eliminated blocks first), ``L`` factors
    ``H_FF + a_F a_F^T``, ``W = L^-1 H_FA`` and ``H_AA - W^T W = L22 L22^T`` (the Schur complement, positive
    semidefinite by construction); ``W`` and the Schur complement come in the factor's order of the kept blocks
    and are permuted to ``keep``'s.  ``L22 L22^T`` costs ``n_A^3`` operations against ``n_A^2 n_F`` for ``H_AA -
    W^T W`` (``n_A, n_F`` the kept and eliminated sizes), so the latter is formed where fewer blocks are eliminated
    than kept (``Dr, Kr`` kept: r = 60, 1.7 s more CPU through ``L22``; still without the factorization of
    ``H_FF`` and the triangular solve for ``W``).
    """
    if factor is None or list(factor.blocks[:len(free)]) != free or 0 not in free:
        return None
    nf = len(free) * ns
    trailing = list(factor.blocks[len(free):])
    local = np.concatenate([np.arange(trailing.index(b) * ns, (trailing.index(b) + 1) * ns) for b in keep])
    L = np.asfortranarray(factor.lower[:nf, :nf])  # contiguous: else every triangular solve copied it
    W = factor.lower[nf:, :nf].T[:, local]
    if len(free) < len(keep):
        return L, W, _blocks(H, list(keep), list(keep), ns) - W.T @ W
    L22 = np.tril(factor.lower[nf:, nf:])[local]
    return L, W, L22 @ L22.T


def _blocks(H: np.ndarray, rows: list[int], cols: list[int], ns: int) -> np.ndarray:
    """Copy of the ``ns``-square blocks ``rows x cols`` of ``H`` (by slices: the same entries gathered with
    ``np.ix_`` took 0.13 s at r = 50)."""
    return np.block([[H[b * ns:(b + 1) * ns, c * ns:(c + 1) * ns] for c in cols] for b in rows])


def _solve_sdp_compressed(
    H: np.ndarray, r: int, trace: float, tol: float, verbose: bool, keep: tuple[int, ...] = (0, 1, 2),
    normalization: str = "trace", solver: str = "clarabel", G: np.ndarray | None = None, progress: bool = False,
    factor: _OrderedFactor | None = None, reduced: tuple | None = None, least_squares: np.ndarray | None = None,
) -> tuple[np.ndarray, dict]:
    """SDP over the upper-triangular entries with PSD cones on the blocks in ``keep`` (others eliminated).

    ``normalization="trace"`` fixes ``trace(Mr) = trace``; ``"mass-eigenvalue"`` requires ``Mr >= I`` (the mass
    block must then be in ``keep``).  ``solver="ipm"`` uses the dense interior-point method of
    :mod:`fmu_opinf._sdp` and reports its certificate (``G`` needed); ``"auto"`` does the same and falls back to
    Clarabel when the certificate fails (inference module docstring, *Solvers*); ``"clarabel"`` goes through
    cvxpy.  ``progress``: a labelled progress bar of the interior-point iterations on a terminal.  ``factor``: the
    screening's factor of ``H + a a^T``, for :func:`_reduced_quadratic`; ``reduced``: that function's result for
    ``keep``, where the caller has it already (:func:`_predicted_cones`); ``least_squares``: the screening's solution
    without cones (all three blocks), from which a trace-normalized interior-point solve starts (:func:`_trace_start`).
    """
    eliminated = time.perf_counter()  # the elimination counts as setup time, as it did inside either solver path
    if len(keep) < 3 and reduced is None:
        reduced = _reduced_quadratic(H, _mass_indicator(r), trace, keep, r, factor)
    eliminated = time.perf_counter() - eliminated
    if solver in ("ipm", "auto"):
        w, report = _solve_sdp_ipm(H, r, trace, tol, keep, normalization, G, progress, reduced, least_squares)
        report["setup_seconds"] += eliminated
        if report["status"] in ("optimal", _CONE_VIOLATED) or solver == "ipm":
            return w, report
        w, fallback = _solve_sdp_compressed(H, r, trace, tol, verbose, keep, normalization, reduced=reduced)
        fallback["fallback"] = {key: report[key] for key in ("status", "gap", "iterations", "solve_seconds")}
        for key in ("setup_seconds", "solve_seconds"):
            fallback[key] += report[key]
        return w, fallback
    import cvxpy as cp

    t0 = time.perf_counter()
    ns = r * (r + 1) // 2
    sym = _sym_index(r)
    select = sp.csr_matrix((np.ones(r * r), (np.arange(r * r), sym.ravel(order="F"))), shape=(r * r, ns))
    if len(keep) == 3:
        idx_a, S, lin = np.arange(3 * ns), H, None
    else:
        idx_a, idx_f, S, lin, recover = reduced
    w = cp.Variable(idx_a.size)
    mats = {b: cp.reshape(select @ w[j * ns : (j + 1) * ns], (r, r), order="F") for j, b in enumerate(keep)}
    constraints = [mat >> (np.eye(r) if (b == 0 and normalization == "mass-eigenvalue") else 0)
                   for b, mat in mats.items()]
    if 0 in keep and normalization == "trace":
        constraints.append(cp.trace(mats[0]) == trace)
    objective = cp.quad_form(w, cp.psd_wrap(sp.csc_matrix(S) if len(keep) == 3 else S))
    if lin is not None:
        objective = objective + 2 * lin @ w
    report = _run(cp.Problem(cp.Minimize(objective), constraints), t0 - eliminated, tol, verbose)
    full = np.empty(3 * ns)
    full[idx_a] = np.asarray(w.value)
    if len(keep) < 3:
        full[idx_f] = recover(full[idx_a])
    return full, report


#: Relative gap of the certificate below which the interior-point result is accepted: the goal of issue 16 is
#: the optimum to 1e-6 relative (measured differences to Clarabel at tol 1e-10: <= 4e-8).
_CERTIFY_GAP = 1e-6
#: Eigenvalue thresholds (relative to the largest) of the face polish after the interior-point solve.
_POLISH_LEVELS = (1e-5, 1e-8)
#: The face polish (a dense ``P^T S P``, 1 s CPU per level at r = 50) runs when the interior-point iterate's
#: certificate is above this gap and the method did not stop by its own test (status ``optimal`` or ``floor``:
#: complementarity below ``tol``), or when the iterate is not certified.  Measured with a polish after every solve
#: (tests of ``test_sdp``, ``test_inference``, ``test_accuracy``, ``test_exporter_combinations``; triple chain
#: r = 20 .. 50): after such a stop the polished objective never differed in the first 7 digits, while after
#: ``singular`` / ``max_iterations`` ends (exact data) the polish lowered gaps of 1.5e-7 .. 2.2e-7 to 6.6e-8 ..
#: 1e-7.
_POLISH_ABOVE = 1e-7


def _solve_sdp_ipm(H: np.ndarray, r: int, trace: float, tol: float, keep: tuple[int, ...], normalization: str,
                   G: np.ndarray | None, progress: bool = False, reduced: tuple | None = None,
                   least_squares: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """The SDP of :func:`_solve_sdp_compressed` by :func:`fmu_opinf._sdp.solve_ipm`, certified on ``G``
    (``reduced``: :func:`_reduced_quadratic`'s result for ``keep``, given whenever a block is eliminated;
    ``least_squares``: the screening's solution without cones, the start of a trace-normalized solve)."""
    from ._sdp import ConeBlock, certificate, polish, solve_ipm

    t0 = time.perf_counter()  # wall time, like the Clarabel path's report
    ns = r * (r + 1) // 2
    a_full = _mass_indicator(r)
    if len(keep) == 3:
        idx_a, S, lin = np.arange(3 * ns), H, np.zeros(3 * ns)
        recover = idx_f = None
    else:
        idx_a, idx_f, S, lin, recover = reduced
    cones = [ConeBlock(j * ns, r, 1.0 if (b == 0 and normalization == "mass-eigenvalue") else 0.0)
             for j, b in enumerate(keep)]
    a = a_full[idx_a] if (0 in keep and normalization == "trace") else None

    def expand(w_a: np.ndarray) -> np.ndarray:
        full = np.empty(3 * ns)
        full[idx_a] = w_a
        if idx_f is not None:
            full[idx_f] = recover(w_a)
        return full

    zero = expand(np.zeros(idx_a.size))
    t_solve = time.perf_counter()
    label = f"SDP {normalization}, cones {'/'.join(_BLOCKS[b] for b in keep)} (interior point, % to tol)"
    dropped = [b for b in range(3) if b not in keep]
    # a diverging iterate may overflow on its way out: the certificate below judges the result, so no warnings
    with Progress(100, label, quiet=not progress) as bar, np.errstate(over="ignore", invalid="ignore"):
        start = _solve_start(S, lin, r, keep, normalization, least_squares)
        result = solve_ipm(S, lin, cones, a=a, c=trace, constant=float(zero @ H @ zero), tol=tol,
                           callback=_share_of_the_way(bar, tol),
                           stop=_dropped_cone_violated(expand, r, dropped) if dropped else None, start=start)
        if result.status in ("optimal", "floor", "stopped"):  # its own stopping test held: the whole way
            bar.update(100)
    t_solve = time.perf_counter() - t_solve
    w, gap, polished = expand(result.w), float("inf"), False
    if result.status == "stopped":  # a relaxation whose dropped cone is violated: the caller adds that cone
        seconds = time.perf_counter() - t0
        return w, {"status": _CONE_VIOLATED, "solver": "IPM", "setup_seconds": seconds - t_solve,
                   "solve_seconds": t_solve, "iterations": result.iterations, "tol": tol, "gap": gap,
                   "ipm_status": result.status, "polished": False}
    if G is not None:
        gap = certificate(np.hstack(_unpack(w, r)), G, normalization, trace)[0]
        for level in _POLISH_LEVELS if _polish_wanted(gap, result.status) else ():
            candidate = polish(S, lin, cones, result.w, a=a, c=trace, threshold=level)
            if candidate is None:
                continue
            full = expand(candidate)
            value = certificate(np.hstack(_unpack(full, r)), G, normalization, trace)[0]
            if value < gap:
                w, gap, polished = full, value, True
    certified = gap <= _CERTIFY_GAP and not _ran_away(result.info["objective"], G, r, trace)
    status = "optimal" if certified else "not_certified"
    seconds = time.perf_counter() - t0
    return w, {"status": status, "solver": "IPM", "setup_seconds": seconds - t_solve,
               "solve_seconds": t_solve, "iterations": result.iterations, "tol": tol, "gap": gap,
               "ipm_status": result.status, "polished": polished}


def _ran_away(objective: float, G: np.ndarray | None, r: int, trace: float) -> bool:
    """Whether the interior-point objective (of the reduced form, :func:`_reduced_quadratic`) is clearly negative:
    the form is positive semidefinite in exact arithmetic, so the iterate has followed its round-off (exact data,
    a numerically indefinite elimination) and is not certified, whatever :func:`fmu_opinf._sdp.certificate` says.

    The certificate's floor ``1e-9 ||G|| ||T||^2`` grows with such an iterate: on one ``Mr``-only test problem
    (r = 11, exact data) 100 iterations ran to ``|T| ~ 2e7``, reduced objective -0.2, whose certificate on ``G``
    passed (gap 3e-8 at an objective 0.04 .. 0.13 against the optimum's 3.3e-10) or not (then Clarabel), depending
    on round-off.  The threshold is the certificate's own test for a negative objective, at the normalization's
    scale.
    """
    if G is None:
        return False
    return objective < -1e-12 * float(np.linalg.norm(G, 2)) * max(trace, r)


def _solve_start(S: np.ndarray, lin: np.ndarray, r: int, keep: tuple[int, ...], normalization: str,
                 least_squares: np.ndarray | None) -> np.ndarray | None:
    """Primal start of the interior-point solve (None: its default start): for ``Mr >= I`` with the ``Mr, Dr``
    cones :func:`_least_squares_start`, for the trace normalization :func:`_trace_start`."""
    if normalization == "mass-eigenvalue":
        return _least_squares_start(S, lin, r) if keep == (0, 1) else None
    return _trace_start(least_squares, keep, r)


#: Margin of :func:`_least_squares_start`: ``Mr = (1 + margin) I`` and ``Dr``'s eigenvalues raised by ``margin``
#: times their largest magnitude (triple chain, r = 20 / 35 / 50, iterations of the ``Mr, Dr`` round: margin 0.1 ->
#: 11 / 14 / 19, 0.3 -> 12 / 14 / 16, 1 -> - / 17 / -; 17 / 18 / 18 from the default start; 2026-12-07).
_START_MARGIN = 0.3


def _least_squares_start(S: np.ndarray, lin: np.ndarray, r: int) -> np.ndarray | None:
    """Interior start of the ``Mr >= I`` SDP with the ``Mr, Dr`` cones (``Kr`` eliminated, ``w^T S w + 2 lin^T w``
    over the entries of ``Mr, Dr``): the least-squares ``Dr`` with ``Mr = I`` (the start that
    :func:`_predicted_cones` reads) with its eigenvalues clipped at zero and raised by :data:`_START_MARGIN`
    times their largest magnitude, and ``Mr = (1 + margin) I`` (None where the ``Dr`` block is singular).

    The default start (``Mr = 2 I``, ``Dr = I``) has an objective about 200x the optimum on the triple chain, and
    the first eight iterations mostly bring it down; from this one the round takes 12 / 14 / 16 instead of
    17 / 18 / 18 iterations at r = 20 / 35 / 50, to the same certified optimum (objectives within 2e-10); with the
    centrality correctors of :func:`fmu_opinf._sdp.solve_ipm` 10 / 11 / 13.
    """
    ns = r * (r + 1) // 2
    iu = np.triu_indices(r)
    mass = np.eye(r)[iu]
    try:
        factor = scipy.linalg.cho_factor(S[ns:, ns:], lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    damping = scipy.linalg.cho_solve(factor, -(S[ns:, :ns] @ mass + lin[ns:]), check_finite=False)
    raised = _raised_block(damping, r, _START_MARGIN)
    return None if raised is None else np.concatenate([(1.0 + _START_MARGIN) * mass, raised])


def _raised_block(upper: np.ndarray, r: int, margin: float) -> np.ndarray | None:
    """Upper entries of the symmetric ``r x r`` block given by its upper entries ``upper``, with its eigenvalues
    clipped at zero and raised by ``margin`` times their largest magnitude: a positive definite block near it, an
    interior start for its cone (None where the block is zero or not finite)."""
    iu = np.triu_indices(r)
    full = np.zeros((r, r))
    full[iu] = upper
    values, vectors = np.linalg.eigh(full + np.triu(full, 1).T)
    top = float(np.abs(values).max())
    if not np.isfinite(top) or top <= 0:
        return None
    raised = (vectors * (np.maximum(values, 0.0) + margin * top)) @ vectors.T
    return 0.5 * (raised + raised.T)[iu]


#: Margin of :func:`_trace_start` (module figures there).
_TRACE_START_MARGIN = 0.03


def _trace_start(least_squares: np.ndarray | None, keep: tuple[int, ...], r: int) -> np.ndarray | None:
    """Interior start of a screened trace-normalized SDP with the cones ``keep``: the screening's least-squares
    solution ``least_squares`` (all three blocks, from :func:`_solve_unconstrained`) restricted to the kept blocks,
    each made interior by :func:`_raised_block` with :data:`_TRACE_START_MARGIN` (None without a least-squares
    solution or where a kept block is zero).

    Over the kept blocks (the others eliminated, :func:`_reduced_quadratic`) the least-squares solution is the
    minimizer of the reduced objective without cones, so this start sits next to the relaxation's optimum where the
    default one (identity blocks, ``Z = I``) has an objective far above it.  Triple chain, 2026-12-07, iterations
    of the screened round (``Dr`` at r = 20 / 35, ``Dr, Kr`` at r = 50): margin 0.01 -> 8 / 8 / 14, 0.03 -> 8 / 8 / 13,
    0.1 -> 8 / 9 / 17, 0.3 -> - / - / 16, 1 -> - / - / 18; 15 / 16 / 22 from the default start ("-" not
    measured), objectives within 3e-10 relative, certified.  Not for the full SDP (all three cones): on exact data
    whose optimal face is degenerate, a path from this start ends on the face away from its centre (the refit of an
    exact ROM FMU in tests/test_stepping_and_nominals.py: ``Mr`` collapsed to a mass ratio 3.9e-10, acceleration
    residual 6e-8 against 7e-16 from the default start; the default fit then kept ``Mr >= I`` at 1.5e-12 of range
    against 1e-14).
    """
    if least_squares is None:
        return None
    ns = r * (r + 1) // 2
    blocks = [_raised_block(least_squares[b * ns:(b + 1) * ns], r, _TRACE_START_MARGIN) for b in keep]
    return None if any(block is None for block in blocks) else np.concatenate(blocks)


#: Report status of a screened interior-point solve ended by :func:`_dropped_cone_violated`.
_CONE_VIOLATED = "dropped_cone_violated"
#: :func:`_dropped_cone_violated` looks at iterates whose residual measure (relative complementarity and dual
#: residual, :func:`fmu_opinf._sdp.solve_ipm`) is below this level ...
_PROBE_MEASURE = 1e-2
#: ... and ends the solve when a dropped block's smallest eigenvalue is below ``-_PROBE_MARGIN`` times its largest
#: magnitude.
_PROBE_MARGIN = 1e-2


def _dropped_cone_violated(expand: Callable[[np.ndarray], np.ndarray], r: int,
                           dropped: list[int]) -> Callable[[np.ndarray, float], bool]:
    """``stop`` of :func:`fmu_opinf._sdp.solve_ipm` for a screened SDP (cones ``dropped`` left out): whether the
    first iterate close to the relaxation's optimum (:data:`_PROBE_MEASURE`) already has a dropped block that is
    clearly indefinite (:data:`_PROBE_MARGIN`); after that one look the solve goes on to its own end.

    The screening (:func:`_fit_mass_eigenvalue`, :func:`_fit_screened`) then adds that block's cone and solves again,
    as it would after the relaxation's optimum; solving the relaxation to 1e-9 only to discard it was a quarter of
    the ``Mr >= I`` path (triple chain r = 35: 0.21 of 0.85 s CPU; the ``Mr``-only relaxation took 14 iterations, its
    ``Dr`` had the eigenvalue ratio -0.38 from the first iterate on; now it stops after 7).  Correctness does not
    depend on the guess: a result is returned only when every dropped block of the final solve is PSD, which makes
    it optimal for the full SDP; a cone added in error costs time, not accuracy.
    """
    looked = False

    def stop(w_a: np.ndarray, measure: float) -> bool:
        nonlocal looked
        if looked or not measure <= _PROBE_MEASURE:
            return False
        looked = True  # one look: each costs a recovery of the dropped blocks (r = 35: 3 ms, 17 iterations)
        return bool(_clearly_indefinite(_unpack(expand(w_a), r), dropped))

    return stop


def _clearly_indefinite(mats: tuple, blocks: Any) -> list[int]:
    """The blocks among ``blocks`` whose smallest eigenvalue is below ``-_PROBE_MARGIN`` times their largest
    magnitude (:func:`_dropped_cone_violated`, :func:`_predicted_cones`)."""
    # a block near the apex of its cone (all eigenvalues ~ 0: an undamped model's Dr) is judged against the
    # others' size: its own ratio there is round-off, and it stopped every relaxation of such data
    floor = _APEX * max(float(np.abs(np.linalg.eigvalsh(block)).max()) for block in mats)
    out = []
    for b in blocks:
        eigs = np.linalg.eigvalsh(mats[b])
        if eigs[0] < -_PROBE_MARGIN * max(float(np.abs(eigs).max()), floor, np.finfo(float).tiny):
            out.append(b)
    return out


def _share_of_the_way(bar: Progress, tol: float) -> Callable[[int, float], None]:
    """Callback of :func:`fmu_opinf._sdp.solve_ipm` that sets ``bar`` to the percentage of the way, on a log scale,
    from the first iterate's residual measure to ``tol`` (the iteration count is not known in advance; the
    measure falls roughly geometrically), never moving back."""
    first = None

    def report(iteration: int, measure: float) -> None:
        nonlocal first
        if not math.isfinite(measure):  # a diverging iterate: the solver's own tests judge it, not the bar
            return
        if first is None:
            first = max(measure, 10.0 * tol)
        share = np.log(first / max(measure, tol)) / np.log(first / tol)
        bar.update(max(bar.done, int(100 * min(max(share, 0.0), 1.0))))

    return report


def _polish_wanted(gap: float, ipm_status: str) -> bool:
    """Whether the face polish may improve the interior-point iterate: an iterate from the method's own stopping
    test only when it is not certified, any other (``singular``, ``max_iterations``) above :data:`_POLISH_ABOVE`."""
    return gap > (_CERTIFY_GAP if ipm_status in ("optimal", "floor") else _POLISH_ABOVE)


def _run(problem: Any, t0: float, tol: float, verbose: bool) -> dict:
    import cvxpy as cp

    with warnings.catch_warnings():  # cvxpy's own warnings become one line in fit_operators (and fit_info)
        warnings.simplefilter("ignore")
        try:
            problem.solve(solver=cp.CLARABEL, **_clarabel_settings(tol, verbose))
            if str(problem.status) == cp.OPTIMAL_INACCURATE and tol < _TOL_RETRY:
                tol = _TOL_RETRY  # inference module docstring, *Solver status*: the same optimum, certified at 1e-8
                problem.solve(solver=cp.CLARABEL, **_clarabel_settings(tol, verbose))
        except cp.error.SolverError as exc:
            raise SolverError(f"clarabel failed on the operator-inference SDP ({exc}); try a smaller r") from exc
    total = time.perf_counter() - t0
    stats = problem.solver_stats
    status = str(problem.status)
    if status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
        raise SolverError(f"clarabel returned status '{status}' for the operator-inference SDP; try a smaller r")
    solve = float(stats.solve_time or 0.0)
    return {
        "status": status,
        "solver": "CLARABEL",
        "setup_seconds": total - solve,
        "solve_seconds": solve,
        "iterations": stats.num_iters,
        "tol": tol,
    }


def solve_sdp_direct(zs: np.ndarray, r: int, m: int, trace: float, tol: float, verbose: bool) -> tuple:
    """Uncompressed formulation: the full scaled data matrix goes to cvxpy (benchmark baseline)."""
    import cvxpy as cp

    t0 = time.perf_counter()
    mats = [cp.Variable((r, r), PSD=True) for _ in range(3)]
    b = cp.Variable((r, m)) if m else None
    resid = mats[0] @ zs[m : m + r] + mats[1] @ zs[m + r : m + 2 * r] + mats[2] @ zs[m + 2 * r :]
    if m:
        resid = resid - b @ zs[:m]
    problem = cp.Problem(cp.Minimize(cp.sum_squares(resid)), [cp.trace(mats[0]) == trace])
    report = _run(problem, t0, tol, verbose)
    values = [np.asarray(mat.value) for mat in mats]
    return values, (np.asarray(b.value) if m else np.zeros((r, 0))), report



def fit_compressed(R: np.ndarray, r: int, m: int, method: str, tol: float, verbose: bool,
                   normalization: str = "auto", solver: str = "auto", progress: bool = False,
                   side_by_side: bool = False) -> tuple:
    """Steps 3-4 of the inference module docstring; returns scaled ``Ms, Ds, Ks`` and the report (with
    ``sdp_objective``, the SDP's objective ``trace(T G T^T)`` in its own units, comparable between solvers).
    ``progress``: labelled progress bars of the interior-point solves on a terminal.

    ``normalization="auto"`` solves both normalizations and keeps one (:func:`choose_normalization`); they are
    independent problems, and with ``side_by_side`` the ``Mr >= I`` one runs in a forked process
    (:mod:`fmu_opinf._background`) while this one solves the trace one: the same bits as one after the other.
    """
    if normalization != "auto":
        return _with_objective(R, r, m, _fit_compressed_paths(R, r, m, method, tol, verbose, normalization, solver,
                                                              progress))
    from ._background import Background

    second = (Background(fit_compressed, R, r, m, method, tol, False, "mass-eigenvalue", solver,
                         label="SDP normalized by Mr >= I, beside the trace one", mode="process")
              if side_by_side else None)
    try:
        trace_fit = _solved_or_error(fit_compressed, R, r, m, method, tol, verbose, "trace", solver, progress)
        eig_fit = (_solved_or_error(second.result, progress) if second is not None
                   else _solved_or_error(fit_compressed, R, r, m, method, tol, verbose, "mass-eigenvalue", solver,
                                         progress))
    except BaseException:
        if second is not None:
            second.cancel()
        raise
    return choose_normalization(R, m, trace_fit, eig_fit)


def _solved_or_error(solve: Callable[..., tuple], *args: Any) -> tuple | SolverError:
    """``solve(*args)``, or the :class:`SolverError` it raised (the other normalization may still succeed)."""
    try:
        return solve(*args)
    except SolverError as error:
        return error


def _with_objective(R: np.ndarray, r: int, m: int, fit: tuple) -> tuple:
    """``fit`` with ``info["sdp_objective"]``, ``trace(T G T^T)`` in the SDP's own units."""
    *mats, info = fit
    R22 = R[m:, m:] / max(np.linalg.norm(R[m:, m:]) / np.sqrt(3 * r), np.finfo(float).tiny)
    info["sdp_objective"] = float(np.linalg.norm(np.hstack(mats) @ R22.T) ** 2)
    return (*mats, info)


def choose_normalization(R: np.ndarray, m: int, trace_fit: tuple | SolverError,
                         eig_fit: tuple | SolverError) -> tuple:
    """``normalization="auto"``: of the two fits, the one with the smaller acceleration residual (inference
    docstring, *Normalization*); its report carries the two solves' summed times and both residuals.  Where one
    normalization's solve failed (a :class:`SolverError` instead of a fit), the other is kept and its report says
    why in ``normalization_failed``; where both failed, the trace one's error is raised.  (An undamped free-free
    chain's free response: the ``Mr >= I`` solve was not certified and Clarabel failed on it, audit 2026-11-27.)"""
    if isinstance(trace_fit, SolverError) and isinstance(eig_fit, SolverError):
        raise trace_fit
    for failed, kept in ((trace_fit, eig_fit), (eig_fit, trace_fit)):
        if isinstance(failed, SolverError):
            info = dict(kept[3])
            other = "mass-eigenvalue" if info["normalization"] == "trace" else "trace"
            info["normalization_failed"] = {other: str(failed)}
            return (*kept[:3], info)
    residuals = {fit[3]["normalization"]: _acceleration_residual(R, m, fit[:3]) for fit in (trace_fit, eig_fit)}
    # differences below 1e-12 (of a relative residual) are round-off, e.g. both ~1e-15 on exact data: keep trace
    chosen = eig_fit if residuals["mass-eigenvalue"] < residuals["trace"] - _RESIDUAL_TIE else trace_fit
    info = dict(chosen[3])
    for key in ("setup_seconds", "solve_seconds", "iterations"):
        info[key] = trace_fit[3].get(key, 0) + eig_fit[3].get(key, 0)
    info["acceleration_residual"] = residuals
    info["trace_mass_ratio"] = _mass_ratio(trace_fit[0])
    return (*chosen[:3], info)


#: ``solver="auto"`` starts the refinement from :func:`fit_factored` above this order (inference module docstring,
#: *Solvers*): up to r = 60 the certified SDP start is slower (r = 60: 20 s CPU, 225 s before 2026-11-26) but
#: gave far better refined ROMs (r = 55 / 60: ratio 1.18 / 0.08 against 2.86 / 5.54); above, the dense method's
#: O(r^6) Newton matrices
#: make it slow (r = 75: 142 s certified since 2026-11-26, before not in 20 minutes; the whole fit 184 s against
#: 44 s from the factored start, the same ROM since the least-squares start is kept there).
FACTORED_ABOVE = 60

#: L-BFGS iterations of :func:`fit_factored`, and the exponent of its preconditioner (:func:`_factor_preconditioners`).
#: Triple chain, 2026-11-27, max eps_y of the refined ROM (600 refinement iterations), whole fit in wall seconds
#: (two fits sharing the machine):
#:
#: ==========================  =========  =========  =========  =========  =========
#: start                       r = 65     r = 85     r = 90     r = 100    fit [s] at r = 65 / 85 / 100
#: ==========================  =========  =========  =========  =========  =========
#: 3000, exponent 0.2          7.3e-8     1.1e-8     2.6e-8     8.4e-8     11 / 19 / 30
#: 3000, exponent 0.15         1.1e-7     9.3e-9                5.1e-8     10 / 18 / 27
#: 5000, exponent 0.2          1.1e-7     9.2e-9                2.6e-8     12 / 23 / 33
#: 10000, exponent 0.2         1.6e-7     4.6e-9                1.6e-9     18 / 35 / 49
#: 10000, no preconditioner    8.9e-8     3.1e-8     4.2e-8     9.7e-8     14 / 28 / 44-48 (alone)
#: 3000, no preconditioner     5.7e-7     3.1e-7                1.9e-7     12 / 21 / 27 (alone)
#: ==========================  =========  =========  =========  =========  =========
#:
#: The SDP objective the start reaches (certified optimum at r = 65: 0.02298): r = 65 0.02803 with 3000
#: preconditioned iterations, 0.02932 with 10000 plain ones; r = 100 3.8e-3 against 7.9e-3.  3000 preconditioned
#: iterations are better than 10000 plain ones at every order measured, in a third of the start's time; more of
#: them helped r = 100 further but not r = 65 (the refinement's local optimum moves).  From r = 45 to 60 the
#: preconditioned start was not better than the certified one (ratio to POD-Galerkin at r = 60: 2.5 against 0.31).
_FACTORED_ITERATIONS = 3000
_PRECONDITION_EXPONENT = 0.2


def factored_start(solver: str, r: int, refine: bool, method: str) -> bool:
    """Whether :func:`fmu_opinf.inference.fit_operators` solves eq. (16) by :func:`fit_factored` instead of the
    certified SDP."""
    if solver == "factored":
        return True
    return solver == "auto" and method == "auto" and refine and r > FACTORED_ABOVE


def fit_factored(R: np.ndarray, r: int, m: int, iterations: int = _FACTORED_ITERATIONS,
                 progress: bool = False, exponent: float = _PRECONDITION_EXPONENT) -> tuple:
    """Eq. (16) normalized by ``Mr >= I`` (scaled units), by L-BFGS over PSD factors (inference module docstring,
    *Solvers*).

    ``Ms = I + LM LM^T``, ``Ds = LD LD^T``, ``Ks = LK LK^T`` are feasible whatever the factors, so every iterate is
    a stable model; the objective ``trace(T G T^T)`` (``T = [Ms, Ds, Ks]``, ``Br`` eliminated) and its gradient
    cost ``O(r^3)`` per iteration instead of the interior-point method's ``O(r^6)``.  Not certified: the result
    is an approximate optimum that serves as the start of the output-error refinement.  Start: least squares with
    ``Ms = I``, ``Ds, Ks`` symmetrized, their eigenvalues floored at ``_START_FLOOR`` of the largest, and
    ``LM = _START_MASS I``: every factor has full rank (a zero column has zero gradient and would never move).
    The iterations run on preconditioned factors (:func:`_factor_preconditioners`, ``exponent``; 0 for none).
    ``progress``: a labelled progress bar of the L-BFGS iterations on a terminal.
    """
    t0 = time.perf_counter()
    R22 = R[m:, m:]
    R22 = R22 / max(np.linalg.norm(R22) / np.sqrt(3 * r), np.finfo(float).tiny)
    G = R22.T @ R22
    free, *_ = np.linalg.lstsq(G[r:, r:], -G[r:, :r], rcond=None)  # [Ds Ks]^T with Ms = I
    eye = np.eye(r)
    P = _factor_preconditioners(G, r, exponent)
    factors0 = [_START_MASS * eye] + [_psd_square_root(free[b * r:(b + 1) * r].T).reshape(r, r) for b in (0, 1)]
    start = np.concatenate([np.linalg.solve(P[b], factors0[b]).ravel() for b in range(3)])

    def blocks(params: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        factors = [P[b] @ x for b, x in enumerate(params.reshape(3, r, r))]
        return factors, np.hstack([eye + factors[0] @ factors[0].T] + [f @ f.T for f in factors[1:]])

    def objective(params: np.ndarray) -> tuple[float, np.ndarray]:
        factors, T = blocks(params)
        TG = T @ G
        grads = [P[b].T @ (TG[:, b * r:(b + 1) * r] + TG[:, b * r:(b + 1) * r].T) @ factors[b] for b in range(3)]
        return float(np.sum(TG * T)), 2.0 * np.concatenate([g.ravel() for g in grads])

    label = "SDP Mr >= I, factored start (L-BFGS iterations)"
    with Progress(iterations, label, quiet=not progress) as bar:
        def advance(state: LBFGSResult) -> None:
            bar.update(state.nit)

        result = minimize_lbfgs(objective, start, max_iterations=iterations, memory=50, ftol=1e-15, gtol=1e-14,
                                callback=advance)
    _, T = blocks(result.x)
    Ms, Ds, Ks = (T[:, b * r:(b + 1) * r] for b in range(3))
    info = {"status": "approximate", "method": "factored", "solver": "L-BFGS (PSD factors, not certified)",
            "normalization": "mass-eigenvalue", "cones": list(_BLOCKS), "iterations": int(result.nit),
            "setup_seconds": 0.0, "solve_seconds": time.perf_counter() - t0, "sdp_objective": float(result.fun),
            "start_objective": objective(start)[0], "preconditioner_exponent": exponent}
    return Ms, Ds, Ks, info


def _factor_preconditioners(G: np.ndarray, r: int, exponent: float) -> list[np.ndarray]:
    """``P_b = Q_b (Lambda_b / lambda_max)^-exponent`` for the blocks ``b = M, D, K``: :func:`fit_factored` iterates
    on ``X_b`` with the factor ``L_b = P_b X_b``, ``G_bb = Q_b Lambda_b Q_b^T`` the block of the quadratic form.

    In ``G_bb``'s eigenbasis the objective's curvature in the entry ``(i, j)`` of ``L_b L_b^T`` is
    ``(lambda_i + lambda_j) / 2``: its condition grows with that of ``G_bb`` (6e10 for ``Kr`` at r = 100 on the
    triple chain), and L-BFGS, whose first inverse Hessian is a multiple of the identity, crawls.  With
    ``L_b = Q_b Lambda_b^-1/4 X_b`` the diagonal entries of ``X_b X_b^T`` get unit curvature and the off-diagonal ones
    ``(lambda_i + lambda_j) / (2 sqrt(lambda_i lambda_j))``, the square root of the condition at worst.  Measured
    on the triple chain (SDP objective after 3000 iterations, 2026-11-27): r = 65, exponent 0 / 0.1 / 0.2 / 0.25 /
    0.3 / 0.5: 0.0477 / 0.0294 / 0.0280 / 0.0292 / 0.0316 / 8.71 (the optimum 0.0230); r = 100, 0 / 0.15 / 0.2 /
    0.25: 0.0235 / 0.0036 / 0.0038 / 0.0072, hence 0.2 (:data:`_PRECONDITION_EXPONENT`).  Eigenvalues are floored
    at ``1e-14`` of the largest.
    """
    if exponent == 0:
        return [np.eye(r)] * 3
    out = []
    for b in range(3):
        lam, Q = np.linalg.eigh(G[b * r:(b + 1) * r, b * r:(b + 1) * r])
        top = max(float(lam[-1]), np.finfo(float).tiny)
        out.append(Q * (np.maximum(lam, 1e-14 * top) / top) ** -exponent)
    return out


#: Start of :func:`fit_factored`: ``LM = _START_MASS I`` and eigenvalues of ``Ds, Ks`` floored at this fraction of
#: the largest, so that every factor starts with full rank.
_START_MASS = 0.1
_START_FLOOR = 1e-3


def _psd_square_root(A: np.ndarray) -> np.ndarray:
    """``(r*r,)`` full-rank factor ``L`` with ``L L^T`` the PSD part of ``sym(A)``, its eigenvalues floored at
    ``_START_FLOOR`` times the largest magnitude."""
    eigs, vecs = np.linalg.eigh(0.5 * (A + A.T))
    floor = _START_FLOOR * max(float(np.abs(eigs).max()), np.finfo(float).tiny)
    return (vecs * np.sqrt(np.maximum(eigs, floor))).ravel()


def _fit_compressed_paths(R: np.ndarray, r: int, m: int, method: str, tol: float, verbose: bool,
                          normalization: str, solver: str, progress: bool = False) -> tuple:
    """The solution paths of :func:`fit_compressed` for one normalization (``"trace"`` or ``"mass-eigenvalue"``)."""
    R22 = R[m:, m:]
    R22 = R22 / max(np.linalg.norm(R22) / np.sqrt(3 * r), np.finfo(float).tiny)
    G = R22.T @ R22
    H = _hessian(G, r)
    sdp = {"solver": solver, "G": G, "progress": progress}
    if normalization == "mass-eigenvalue":
        return _fit_mass_eigenvalue(H, r, tol, verbose, full=(method == "sdp"), sdp=sdp)
    if method == "sdp":
        w, info = _solve_sdp_compressed(H, r, float(r), tol, verbose, **sdp)
        info.update(method="sdp", cones=list(_BLOCKS))
        trace_fit = (*_unpack(w, r), info)
    else:
        trace_fit = _fit_screened(H, r, tol, verbose, sdp=sdp, root=R22)
    trace_fit[3]["normalization"] = "trace"
    return trace_fit


#: Acceleration residuals closer than this are a tie (round-off), resolved in favour of the trace normalization.
_RESIDUAL_TIE = 1e-12


def _acceleration_residual(R: np.ndarray, m: int, mats: tuple) -> float:
    """``||Xr'' + Mr^-1 (Dr Xr' + Kr Xr - Br U)||_F / ||Xr''||_F`` in the block-scaled units (inf if ``Mr`` is
    numerically singular: the undamped audit model's trace fit had rcond 4.8e-19 and LAPACK's warning reached the
    user): the residual of the explicit form that a simulation integrates, invariant to the common scale."""
    Ts = np.hstack(mats)
    theta = np.hstack([-input_matrix(R, m, Ts), Ts])
    try:
        with warnings.catch_warnings():  # numerically singular (rcond below eps): no explicit form, and no warning
            warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
            explicit = scipy.linalg.solve(mats[0], theta @ R.T, assume_a="sym", check_finite=False)
    except (np.linalg.LinAlgError, ValueError, scipy.linalg.LinAlgWarning):
        return float("inf")
    if not np.all(np.isfinite(explicit)):
        return float("inf")
    r = mats[0].shape[0]
    return float(np.linalg.norm(explicit) / max(np.linalg.norm(R[:, m:m + r]), np.finfo(float).tiny))


def _mass_ratio(mass: np.ndarray) -> float:
    """``lambda_min / lambda_max`` of a symmetric matrix (0 for a zero matrix)."""
    eigs = np.linalg.eigvalsh(mass)
    return float(eigs[0] / eigs[-1]) if eigs[-1] > 0 else 0.0


def _fit_mass_eigenvalue(H: np.ndarray, r: int, tol: float, verbose: bool, full: bool = False,
                         sdp: dict | None = None) -> tuple:
    """Eq. (16) normalized by ``Mr >= I`` (scaled units), with the same exact cone screening.

    The mass cone is always kept (it carries the normalization); the damping and stiffness blocks are eliminated
    without their cones and added only if they come out indefinite (all three cones with ``full``).  The first
    round starts with the cones that :func:`_predicted_cones` reads from the ``Mr``-only relaxation's start.
    """
    spent = {"setup_seconds": 0.0, "solve_seconds": 0.0, "iterations": 0}
    keep, reduced = ((0, 1, 2), None) if full else _predicted_cones(H, r)
    while True:
        try:
            w, info = _solve_sdp_compressed(H, r, float(r), tol, verbose, keep, normalization="mass-eigenvalue",
                                            **(sdp or {}), reduced=reduced)
        except np.linalg.LinAlgError:  # a singular eliminated block (as in _fit_screened): keep every cone
            if len(keep) == 3:
                raise
            keep, reduced = (0, 1, 2), None
            continue
        reduced = None
        for key in spent:
            spent[key] += info.get(key, 0)
        mats = _unpack(w, r)
        bad = _indefinite(mats, [b for b in range(3) if b not in keep])
        clipped = _certified_clip(mats, bad, sdp, "mass-eigenvalue", float(r)) if bad else None
        if not bad or clipped is not None:
            info.update(spent, method="sdp" if len(keep) == 3 else "sdp-screened",
                        cones=[_BLOCKS[b] for b in keep], normalization="mass-eigenvalue")
            if clipped is not None:
                info.update(status="optimal", clipped=[_BLOCKS[b] for b in bad])
            return (*(clipped or mats), info)
        keep = tuple(sorted(set(keep) | set(bad)))


def _predicted_cones(H: np.ndarray, r: int) -> tuple[tuple[int, ...], tuple | None]:
    """Cones of the first ``Mr >= I`` screening round, and :func:`_reduced_quadratic`'s result for them where it
    was computed here (else None).

    The ``Mr``-only relaxation starts at ``Mr = 2 I`` with ``Dr, Kr`` eliminated, i.e. at twice the least squares in
    ``Dr, Kr`` with ``Mr = I``; where that start has ``Dr`` or ``Kr`` clearly indefinite (:func:`_clearly_indefinite`,
    the probe's test), the relaxation is skipped and those cones are kept from the start.  The start is read from
    the elimination of ``Kr`` alone (one Cholesky factorization of the ``Dr`` block of the reduced form), which the
    round with the ``Mr, Dr`` cones uses as it is.  On the 23 ``Mr >= I`` problems of ``test_sdp``,
    ``test_inference`` and ``test_accuracy`` and the triple chain at r = 10 .. 50 (2026-12-07), the start's blocks
    had the signs of the cones the screening ended with: 10 needed ``Mr`` only (the start's ``Dr, Kr`` PSD: the
    relaxation is solved as before, the same bits, after this function's 2 factorizations), 13 ``Mr, Dr`` and
    four all three cones (skipped round, same bits where the last round keeps its cones).  One of the latter had
    ``Kr`` at -6.8e-3 of its magnitude, below the margin: it solved ``Mr, Dr`` first, one round more than before.  A
    wrong guess costs time, not accuracy: a result is returned only from a round whose dropped blocks are PSD.
    """
    try:
        reduced = _reduced_quadratic(H, _mass_indicator(r), float(r), (0, 1), r)
        idx_a, idx_f, S, lin, recover = reduced
        ns = r * (r + 1) // 2
        mass = np.eye(r)[np.triu_indices(r)]
        factor = scipy.linalg.cho_factor(S[ns:, ns:], lower=True, check_finite=False)
    except np.linalg.LinAlgError:  # a singular block: the relaxation's own round decides, as before
        return (0,), None
    start = np.empty(3 * ns)
    start[idx_a] = np.concatenate([mass, scipy.linalg.cho_solve(factor, -(S[ns:, :ns] @ mass + lin[ns:]),
                                                                check_finite=False)])
    start[idx_f] = recover(start[idx_a])
    keep = (0, *_clearly_indefinite(_unpack(start, r), (1, 2)))
    return keep, (reduced if keep == (0, 1) else None)


def _indefinite(mats: tuple, blocks: Any) -> list[int]:
    """Indices of the blocks among ``blocks`` with a negative eigenvalue."""
    return [b for b in blocks if np.linalg.eigvalsh(mats[b])[0] < 0]


#: A relaxation's dropped block whose smallest eigenvalue lies within this fraction of the largest magnitude of all
#: blocks below zero is tried clipped to PSD (:func:`_certified_clip`) before its cone is added; the probe of
#: :func:`_dropped_cone_violated` judges a block no smaller than this fraction of the largest (the apex of a cone).
_NEAR_PSD = _APEX = 1e-6


def _certified_clip(mats: tuple, dropped: list[int], sdp: dict | None, normalization: str, trace: float
                    ) -> tuple | None:
    """The relaxation's blocks with the ``dropped`` ones clipped to PSD, where they are indefinite only within
    :data:`_NEAR_PSD` and the clipped point is certified optimal for the full SDP (:func:`fmu_opinf._sdp.certificate`
    on the objective's Gram matrix); else None (the caller adds their cones).

    Exact data whose optimum lies at a cone's apex (an undamped model: ``Dr = 0``) left the relaxation's ``Dr`` at
    -1e-9 .. 1e-9 or so, and the SDP with that cone, degenerate at the apex, was neither certified by the
    interior-point method nor solved by Clarabel beyond 1.5e-6 relative (an undamped chain off rest whose training
    held a free run beside the pulse: a ROM 5.6e-6 off where the pulse alone gave 3.7e-11)."""
    from ._sdp import certificate

    G = (sdp or {}).get("G")
    if G is None or (normalization == "trace" and 0 in dropped):   # (clipping Mr would move its trace)
        return None
    clipped = list(mats)
    scale = max(float(np.abs(np.linalg.eigvalsh(block)).max()) for block in mats)
    for b in dropped:
        values, vectors = np.linalg.eigh(mats[b])
        if values[0] < -_NEAR_PSD * max(scale, np.finfo(float).tiny):
            return None
        block = (vectors * np.maximum(values, 0.0)) @ vectors.T
        clipped[b] = 0.5 * (block + block.T)
    gap = certificate(np.hstack(clipped), G, normalization, trace)[0]
    return tuple(clipped) if gap <= _CERTIFY_GAP else None


#: Block order of the screening's factorization of ``H + a a^T`` (:func:`_fit_screened`): mass, stiffness, damping,
#: so that its leading part eliminates ``Mr, Kr`` for a kept ``Dr`` and ``Mr`` for kept ``Dr, Kr`` -- the two cone
#: sets that the triple chain's screening kept at every order measured (r = 15 .. 50), here without a second
#: factorization (:func:`_leading_elimination`).
_SCREENING_ORDER = (0, 2, 1)


def _fit_screened(H: np.ndarray, r: int, tol: float, verbose: bool, sdp: dict | None = None,
                  root: np.ndarray | None = None) -> tuple:
    """Cone screening: solve with only the cones that a relaxation violates (exact, see inference module docstring).

    Round 0 drops all cones (one linear solve).  If one block comes out indefinite, its cone alone is kept and
    the other two blocks are eliminated (a dense but three times smaller SDP); a relaxation whose dropped blocks
    come out PSD is optimal for the full SDP.  Otherwise the full SDP is solved: with two cones, eliminating
    the third block would turn the sparse quadratic form dense and cost Clarabel more than keeping it.  The dense
    interior-point method (``solver`` other than ``"clarabel"``) factors a dense matrix anyway, so for it the
    screening goes on cone by cone (:func:`_first_cones`: where two blocks are indefinite, the cone of the more
    indefinite one first), adding the cones that a round's dropped blocks violate.
    """
    t0 = time.perf_counter()
    spent = {"setup_seconds": 0.0, "solve_seconds": 0.0, "iterations": 0}
    w, factor = _solve_unconstrained(H, _mass_indicator(r), float(r), root, order=_SCREENING_ORDER)
    least_squares = w  # the interior-point rounds below start from it (:func:`_trace_start`)
    if w is not None:
        mats = _unpack(w, r)
        bad = _indefinite(mats, range(3))
        clipped = _certified_clip(mats, bad, sdp, "trace", float(r)) if bad else None
        if not bad or clipped is not None:
            info = {"status": "optimal", "solver": "none (cone constraints inactive)", "setup_seconds": 0.0,
                    "solve_seconds": time.perf_counter() - t0, "iterations": 0}
            if clipped is not None:
                info["clipped"] = [_BLOCKS[b] for b in bad]
            return (*(clipped or mats), dict(info, method="lstsq-certified", cones=[]))
        dense_ipm = (sdp or {}).get("solver", "clarabel") != "clarabel"
        keep = _first_cones(mats, bad, dense_ipm)
        while len(keep) < 3:
            try:
                w, info = _solve_sdp_compressed(H, r, float(r), tol, verbose, keep, **(sdp or {}), factor=factor,
                                                least_squares=least_squares)
            except np.linalg.LinAlgError:  # singular block: only the full SDP is well posed
                break
            for key in spent:
                spent[key] += info.get(key, 0)
            mats = _unpack(w, r)
            worse = _indefinite(mats, [b for b in range(3) if b not in keep])
            clipped = _certified_clip(mats, worse, sdp, "trace", float(r)) if worse else None
            if not worse or clipped is not None:
                extra = {"status": "optimal", "clipped": [_BLOCKS[b] for b in worse]} if clipped else {}
                return (*(clipped or mats), dict(info, **spent, method="sdp-screened",
                                                 cones=[_BLOCKS[b] for b in keep], **extra))
            if not dense_ipm:  # inference docstring, *Solvers*: Clarabel takes the full SDP after one screened round
                break
            keep = tuple(sorted(set(keep) | set(worse)))
    # (from the default start: an interior-point path from it ends at the centre of a degenerate optimal face; the
    # least-squares start ended an exact recording's full SDP at a collapsed Mr, mass ratio 3.9e-10 against 0.26)
    w, info = _solve_sdp_compressed(H, r, float(r), tol, verbose, **(sdp or {}))
    for key in spent:
        info[key] += spent[key]
    return (*_unpack(w, r), dict(info, method="sdp", cones=list(_BLOCKS)))


#: :func:`_first_cones` tries the cone of one of several indefinite blocks alone where that block's eigenvalue ratio
#: is at least this factor more negative than every other's.
_ONE_CONE_FIRST = 10.0


def _first_cones(mats: tuple, bad: list[int], dense_ipm: bool) -> tuple[int, ...]:
    """Cones of the first screened round of :func:`_fit_screened` after the least-squares round found the blocks
    ``bad`` indefinite: one indefinite block's cone; where two or three are, all three for Clarabel (the full SDP,
    which costs it no more than two cones), and for the dense interior-point method the cone of the clearly most
    indefinite block alone (ratio of smallest to largest-magnitude eigenvalue :data:`_ONE_CONE_FIRST` times more
    negative than the next), else the cones of all of them.

    Triple chain, 2026-12-07: from r = 40 on ``Dr`` and ``Kr`` of least squares are both indefinite (at r = 55 ``Mr``
    too, -1.6e-5), ``Dr`` far more (ratios r = 40 / 45 / 50 / 55 / 60: -0.47 / -0.50 / -1.0 / -1.0 / -1.0 against
    ``Kr``'s -1.3e-2 / -3.7e-2 / -1.8e-3 / -1.3e-2 / -3.4e-3), and with the ``Dr`` cone alone the relaxation's
    other blocks come out positive definite at each of these orders (at r = 50 ``Kr``'s smallest eigenvalue 0.06 of
    25): a round with 1275 unknowns instead of 2550 with two cones (an eighth of each factorization; r = 50, trace
    normalization: 5.4-5.7 s -> 1.1-1.2 s CPU, the start of :func:`_trace_start` included) or 3825 with three
    (r = 55: 20 s -> 2.2-2.9 s; r = 60, ``Dr, Kr`` before: 12.3 -> 3.2 s; one run each, objectives within 1e-10).
    The test problems with two indefinite blocks have ratios within a factor 1.2 .. 8.5
    of each other, and one cone alone was not enough in any of them (a round more: 3 .. 7 iterations of the smaller
    problem), hence the factor.  A wrong guess costs one round (stopped early by :func:`_dropped_cone_violated` where
    the dropped block becomes clearly indefinite), not accuracy.
    """
    if len(bad) == 1:
        return (bad[0],)
    if not dense_ipm:
        return (0, 1, 2)
    (first, low), (_, high), *_ = sorted(((b, _eigenvalue_ratio(mats[b])) for b in bad), key=lambda pair: pair[1])
    return (first,) if low < _ONE_CONE_FIRST * high else tuple(bad)


def _eigenvalue_ratio(block: np.ndarray) -> float:
    """Smallest over largest-magnitude eigenvalue of a symmetric block (0 for a zero block)."""
    eigs = np.linalg.eigvalsh(block)
    top = float(np.abs(eigs).max())
    return float(eigs[0]) / top if top > 0 else 0.0


def input_matrix(R: np.ndarray, m: int, Ts: np.ndarray) -> np.ndarray:
    """``Br`` (scaled) minimizing the input part of the residual: ``Br R11^T = Ts R12^T`` (step 3)."""
    r = Ts.shape[0]
    if m == 0:
        return np.zeros((r, 0))
    R11, R12 = R[:m, :m], R[:m, m:]
    bt, *_ = np.linalg.lstsq(R11, R12 @ Ts.T, rcond=None)
    return bt.T

