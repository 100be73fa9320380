"""First-order solver for the compressed SPD operator-inference SDP (issue 16).

Problem (scaled units of :mod:`fmu_opinf.inference`, steps 1-3 of its module docstring)::

    minimize  f(T) = trace(T G T^T)   over   T = [M, D, K]  (r x 3r),  M, D, K symmetric PSD,
    plus      trace(M) = c            (normalization "trace")
    or        M >= I                  (normalization "mass-eigenvalue").

``G`` is the ``(3r, 3r)`` Gram matrix of the compressed data (``R22^T R22``).

Method
------
1. *ADMM* on the splitting ``X = Z`` with ``X`` free and ``Z`` in the constraint set: the ``X``-update is one
   solve with ``2 G + rho I`` (Cholesky factor kept until ``rho`` changes), the ``Z``-update three ``r x r``
   symmetric eigendecompositions (PSD clipping; for the trace normalization the mass eigenvalues are projected
   onto the scaled simplex, for ``M >= I`` clipped at 1).  Over-relaxation 1.6, ``rho`` balanced by the primal
   and dual residuals.
2. *Polish*: from the current iterate each block's eigenbasis is split into a face (eigenvalues of the
   pre-projection matrix clearly positive, i.e. above the clipping level) and its complement.  On the face
   ``T_b = V_b S_b V_b^T`` (``+ I`` for the mass with ``M >= I``) the problem is an equality-constrained
   quadratic in the symmetric ``S_b``: one dense linear solve.  The polished point is accepted only if its
   ``S_b`` are PSD (so it is feasible).
3. *Certificate*: the dual matrices ``Z_b = sym(grad_b f) - lambda E_b`` (``lambda`` the trace multiplier) must
   be PSD and complementary to the primal blocks.  For feasible ``T'``
   ``f(T') >= f(T) - sum_b <Z_b, T_b> + sum_b min(0, lambda_min(Z_b)) trace(T'_b)``; the reported ``gap`` is
   this bound with ``T'`` replaced by ``T`` (an estimate of the distance to the optimum), relative to ``f``
   (or to the problem's scale ``||G|| ||T||^2`` when ``f`` is near zero, e.g. exact data).  The status is
   ``"optimal"`` only when ``gap <= tol``.

The caller (:func:`fmu_opinf.inference.fit_operators`) falls back to Clarabel when the status is not optimal.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

__all__ = ["BlockSDPResult", "solve_block_sdp", "certificate"]

_NORMALIZATIONS = ("trace", "mass-eigenvalue")
#: Relative size below which an eigenvalue of a face block counts as zero.
_RANK_EPS = 1e-12


@dataclass
class BlockSDPResult:
    """Result of :func:`solve_block_sdp`.

    Attributes
    ----------
    blocks : tuple of three (r, r) ndarray
        ``M, D, K`` (symmetric, PSD, normalization satisfied to round-off).
    status : str
        ``"optimal"`` when the certificate holds at the requested tolerance, else ``"not_certified"``.
    objective : float
        ``trace(T G T^T)``.
    gap : float
        Relative optimality gap estimate of the certificate (see module docstring).
    iterations : int
        ADMM iterations.
    polishes : int
        Polish attempts.
    seconds : float
        CPU time (``time.process_time``).
    info : dict
        Certificate details: ``dual_eig_min`` per block, ``complementarity``, ``multiplier``, ``face_ranks``.
    """

    blocks: tuple[np.ndarray, np.ndarray, np.ndarray]
    status: str
    objective: float
    gap: float
    iterations: int
    polishes: int
    seconds: float
    info: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------------------------
# Projection onto the constraint set
# ----------------------------------------------------------------------------------------------------------
def _simplex_shift(eigs: np.ndarray, total: float) -> float:
    """``tau`` with ``sum(max(eigs - tau, 0)) = total`` (projection onto the scaled simplex)."""
    mu = np.sort(eigs)[::-1]
    cumulative = np.cumsum(mu) - total
    ranks = np.arange(1, mu.size + 1)
    active = np.nonzero(mu - cumulative / ranks > 0)[0][-1]
    return float(cumulative[active] / (active + 1))


def _project(V: np.ndarray, r: int, normalization: str, total: float) -> tuple[np.ndarray, list]:
    """Projection of ``V`` (r x 3r) onto the constraint set; also each block's ``(eigs - level, vecs)``."""
    Z = np.empty_like(V)
    spectra = []
    for b in range(3):
        block = V[:, b * r:(b + 1) * r]
        eigs, vecs = np.linalg.eigh(0.5 * (block + block.T))
        if b == 0 and normalization == "trace":
            level = _simplex_shift(eigs, total)
        elif b == 0:
            level = 1.0
        else:
            level = 0.0
        shifted = eigs - level
        clipped = np.maximum(shifted, 0.0) + (level if (b == 0 and normalization != "trace") else 0.0)
        Z[:, b * r:(b + 1) * r] = (vecs * clipped) @ vecs.T
        spectra.append((shifted, vecs))
    return Z, spectra


# ----------------------------------------------------------------------------------------------------------
# Certificate
# ----------------------------------------------------------------------------------------------------------
def _sym(a: np.ndarray) -> np.ndarray:
    return 0.5 * (a + a.T)


def certificate(T: np.ndarray, G: np.ndarray, normalization: str, total: float) -> tuple[float, dict]:
    """Optimality gap estimate of a feasible ``T`` from its dual matrices (module docstring, step 3).

    Parameters
    ----------
    T : (r, 3r) ndarray
        Feasible point ``[M, D, K]``.
    G : (3r, 3r) ndarray
        Gram matrix of the objective ``trace(T G T^T)``.
    normalization : {"trace", "mass-eigenvalue"}
    total : float
        ``trace(M)`` of the trace normalization.

    Returns
    -------
    gap : float
        Relative gap estimate (0 at an exact KKT point).
    details : dict
        ``objective``, ``multiplier``, ``dual_eig_min`` (per block), ``complementarity``, ``scale``.
    """
    r = T.shape[0]
    grad = 2.0 * T @ G
    objective = float(np.sum((T @ G) * T))
    duals = [_sym(grad[:, b * r:(b + 1) * r]) for b in range(3)]
    multiplier = 0.0
    if normalization == "trace":
        multiplier = float(np.sum(duals[0] * T[:, :r]) / total)
        duals[0] = duals[0] - multiplier * np.eye(r)
    primal = [T[:, b * r:(b + 1) * r] - (np.eye(r) if (b == 0 and normalization != "trace") else 0.0)
              for b in range(3)]
    complementarity = sum(float(np.sum(z * p)) for z, p in zip(duals, primal))
    dual_min = [float(np.linalg.eigvalsh(z)[0]) for z in duals]
    infeasibility = sum(max(0.0, -e) * float(np.trace(T[:, b * r:(b + 1) * r])) for b, e in enumerate(dual_min))
    scale = float(np.linalg.norm(G, 2) * np.sum(T * T))
    denominator = max(objective, 1e-12 * scale, np.finfo(float).tiny)
    gap = (abs(complementarity) + infeasibility) / denominator
    return gap, {"objective": objective, "multiplier": multiplier, "dual_eig_min": dual_min,
                 "complementarity": complementarity, "scale": scale}


# ----------------------------------------------------------------------------------------------------------
# Face solve: exact minimizer with each block restricted to a subspace
# ----------------------------------------------------------------------------------------------------------
def _upper(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the upper triangle (the face parameters of a ``k x k`` symmetric block)."""
    return np.triu_indices(k)


def _offset(r: int, normalization: str) -> np.ndarray:
    """Fixed part of ``T`` on every face: ``M = I + V S V^T`` for ``M >= I``, nothing for the trace."""
    offset = np.zeros((r, 3 * r))
    if normalization != "trace":
        offset[:, :r] = np.eye(r)
    return offset


def _face_system(G: np.ndarray, bases: list, offset: np.ndarray) -> tuple:
    """Quadratic ``f(offset + L(u)) = u^T Q u + g^T u + const`` on the face parameters ``u`` (upper entries of
    the symmetric ``S_b``, off-diagonal ones counted for both positions).

    With ``T_b = V_b S_b V_b^T``: ``trace(T_b G_bc T_c^T) = sum S_b[p,q] S_c[s,t] B[p,t] A[q,s]`` for
    ``B = V_b^T V_c`` and ``A = V_b^T G_bc V_c``; each entry of ``Q`` gathers the four placements of a pair of
    upper entries (``O(k^4)`` work, no Kronecker product is formed).
    """
    r = offset.shape[0]
    uppers = [_upper(V.shape[1]) for V in bases]
    starts = np.cumsum([0] + [iu.size for iu, _ in uppers])
    Q = np.zeros((starts[-1], starts[-1]))
    g = np.zeros(starts[-1])
    grad_offset = 2.0 * offset @ G
    for b, (Vb, (p, q)) in enumerate(zip(bases, uppers)):
        gb = Vb.T @ grad_offset[:, b * r:(b + 1) * r] @ Vb
        g[starts[b]:starts[b + 1]] = np.where(p == q, 1.0, 2.0) * 0.5 * (gb[p, q] + gb[q, p])
        for c in range(b, 3):
            Vc, (s_, t) = bases[c], uppers[c]
            A = Vb.T @ G[b * r:(b + 1) * r, c * r:(c + 1) * r] @ Vc
            B = Vb.T @ Vc
            P, Qi, S_, T_ = p[:, None], q[:, None], s_[None, :], t[None, :]
            block = B[P, T_] * A[Qi, S_] + B[Qi, T_] * A[P, S_] + B[P, S_] * A[Qi, T_] + B[Qi, S_] * A[P, T_]
            block *= np.where(p == q, 0.5, 1.0)[:, None] * np.where(s_ == t, 0.5, 1.0)[None, :]
            Q[starts[b]:starts[b + 1], starts[c]:starts[c + 1]] += block
            if c != b:
                Q[starts[c]:starts[c + 1], starts[b]:starts[b + 1]] += block.T
    return 0.5 * (Q + Q.T), g, uppers, starts


def _face_solve(G: np.ndarray, bases: list, r: int, normalization: str, total: float) -> list | None:
    """Minimizer of ``f`` over ``T_b = V_b S_b V_b^T`` (``+ I`` for the mass with ``M >= I``), ``S_b`` symmetric
    but not constrained to be PSD, and ``trace(M) = total`` for the trace normalization.  Returns the ``S_b``
    (None if the face leaves the trace unconstrained)."""
    offset = _offset(r, normalization)
    Q, g, uppers, starts = _face_system(G, bases, offset)
    n = int(starts[-1])
    if normalization == "trace":
        if not bases[0].shape[1]:
            return None
        a = np.zeros(n)
        a[starts[0]:starts[1]] = (uppers[0][0] == uppers[0][1]).astype(float)
        # (a^T u)^2 is constant on the constraint set: Q + s a a^T has the same minimizer and stays definite
        # along the solution for exact data (zero objective), where Q alone is singular
        weight = max(float(np.trace(Q)) / max(n, 1), np.finfo(float).tiny)
        sol = _solve_bordered(Q + weight * np.outer(a, a), 0.5 * g, a, total)
    else:
        sol = _solve_psd(Q, -0.5 * g)
    if sol is None or not np.all(np.isfinite(sol)):
        return None
    out = []
    for b, (V, (p, q)) in enumerate(zip(bases, uppers)):
        S = np.zeros((V.shape[1], V.shape[1]))
        S[p, q] = sol[starts[b]:starts[b + 1]]
        S[q, p] = sol[starts[b]:starts[b + 1]]
        out.append(S)
    return out


def _solve_psd(Q: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """``Q x = rhs`` for positive semidefinite ``Q``: Cholesky, least squares if ``Q`` is singular."""
    if not Q.size:
        return np.zeros(0)
    try:
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(Q, check_finite=False), rhs, check_finite=False)
    except np.linalg.LinAlgError:
        return scipy.linalg.lstsq(Q, rhs, check_finite=False)[0]


def _solve_bordered(Q: np.ndarray, half_g: np.ndarray, a: np.ndarray, total: float) -> np.ndarray | None:
    """Minimizer of ``u^T Q u + 2 half_g^T u`` subject to ``a^T u = total``."""
    x0 = _solve_psd(Q, -half_g)
    xa = _solve_psd(Q, a)
    denominator = float(a @ xa)
    if x0 is None or xa is None or not denominator > 0:
        return None
    return x0 + xa * ((total - float(a @ x0)) / denominator)


def _assemble(bases: list, S: list, r: int, normalization: str) -> np.ndarray:
    T = _offset(r, normalization)
    for b, (V, Sb) in enumerate(zip(bases, S)):
        T[:, b * r:(b + 1) * r] += V @ (0.5 * (Sb + Sb.T)) @ V.T
    return T


# ----------------------------------------------------------------------------------------------------------
# Active-face iteration
# ----------------------------------------------------------------------------------------------------------
def _complement(V: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of the orthonormal columns ``V``."""
    r, k = V.shape
    if k == 0:
        return np.eye(r)
    q = scipy.linalg.qr(V, mode="full", check_finite=False)[0]
    return q[:, k:]


def _faces_of(T: np.ndarray, r: int, normalization: str) -> tuple[list, list]:
    """Faces of a feasible ``T``: each block's eigenvectors with clearly positive eigenvalues (of ``M - I`` for
    the mass with ``M >= I``) and the block in those coordinates."""
    bases, S = [], []
    for b in range(3):
        block = _sym(T[:, b * r:(b + 1) * r]) - (np.eye(r) if (b == 0 and normalization != "trace") else 0.0)
        eigs, vecs = np.linalg.eigh(block)
        keep = eigs > _RANK_EPS * max(float(np.abs(eigs).max(initial=0.0)), 1.0)
        bases.append(vecs[:, keep])
        S.append(np.diag(eigs[keep]))
    return bases, S


def _max_step(S: list, delta: list) -> float:
    """Largest ``alpha`` in [0, 1] with every ``S_b + alpha delta_b`` PSD (``S_b`` PSD)."""
    def feasible(alpha: float) -> bool:
        return all(Sb.size == 0 or np.linalg.eigvalsh(Sb + alpha * db)[0] >= -_RANK_EPS * max(
            float(np.abs(Sb).max()), 1.0) for Sb, db in zip(S, delta))

    if feasible(1.0):
        return 1.0
    low, high = 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if feasible(mid) else (low, mid)
    return low


def _drop(bases: list, S: list) -> tuple[list, list]:
    """Faces without the directions whose eigenvalue reached zero."""
    scale = max([float(np.abs(Sb).max()) for Sb in S if Sb.size] + [1.0])
    new_bases, new_S = [], []
    for V, Sb in zip(bases, S):
        eigs, vecs = np.linalg.eigh(_sym(Sb)) if Sb.size else (np.zeros(0), np.zeros((0, 0)))
        keep = eigs > _RANK_EPS * scale
        new_bases.append(V @ vecs[:, keep])
        new_S.append(np.diag(eigs[keep]))
    return new_bases, new_S


def _grow(V: np.ndarray, Sb: np.ndarray, Z: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Face plus the complement part of the dual matrix's negative eigenvectors (None if ``Z`` is PSD).

    At a face optimum ``V^T Z V = 0``, but the cross term ``V^T Z N`` (rotations of the face) can make ``Z``
    indefinite too, so the full eigenvectors are projected on the complement ``N``.
    """
    N = _complement(V)
    if not N.shape[1]:
        return None
    eigs, vecs = np.linalg.eigh(Z)
    negative = vecs[:, :1] if eigs[0] < -eps else vecs[:, :0]  # the most negative direction only
    if not negative.shape[1]:
        return None
    left, sing, _ = np.linalg.svd(N.T @ negative, full_matrices=False)
    directions = N @ left[:, sing > 1e-8]
    if not directions.shape[1]:
        return None
    k, extra = V.shape[1], directions.shape[1]
    grown = np.zeros((k + extra, k + extra))
    grown[:k, :k] = Sb
    return np.hstack([V, directions]), grown


def _start(G: np.ndarray, r: int, normalization: str, total: float) -> np.ndarray:
    """Feasible start: the minimizer without cones (mass fixed at ``I`` for ``M >= I``), blocks clipped to PSD."""
    eye = np.eye(r)
    bases = [eye if normalization == "trace" else eye[:, :0], eye, eye]
    S = _face_solve(G, bases, r, normalization, total)
    T = _offset(r, normalization) if S is None else _assemble(bases, S, r, normalization)
    for b in range(3):
        level = 1.0 if (b == 0 and normalization != "trace") else 0.0
        eigs, vecs = np.linalg.eigh(_sym(T[:, b * r:(b + 1) * r]))
        T[:, b * r:(b + 1) * r] = (vecs * np.maximum(eigs, level)) @ vecs.T
    if normalization == "trace":
        mass = float(np.trace(T[:, :r]))
        T = T * (total / mass) if mass > 0 else _offset(r, "mass-eigenvalue") * (total / r)
    return T


def _dual_matrices(T: np.ndarray, G: np.ndarray, normalization: str, total: float) -> list[np.ndarray]:
    r = T.shape[0]
    grad = 2.0 * T @ G
    duals = [_sym(grad[:, b * r:(b + 1) * r]) for b in range(3)]
    if normalization == "trace":
        duals[0] = duals[0] - float(np.sum(duals[0] * T[:, :r]) / total) * np.eye(r)
    return duals


def solve_block_sdp(
    G: np.ndarray,
    r: int,
    *,
    normalization: str = "trace",
    total: float | None = None,
    tol: float = 1e-9,
    max_rounds: int = 40,
) -> BlockSDPResult:
    """Solve ``min trace(T G T^T)`` over PSD blocks ``T = [M, D, K]`` by active faces (module docstring).

    Parameters
    ----------
    G : (3r, 3r) ndarray
        Symmetric positive semidefinite Gram matrix.
    r : int
        Block size.
    normalization : {"trace", "mass-eigenvalue"}, default="trace"
        ``trace(M) = total`` or ``M >= I``.
    total : float, optional
        Trace of ``M`` for the trace normalization; default ``r``.
    tol : float, default=1e-9
        Relative gap of the certificate required for status ``"optimal"``.
    max_rounds : int, default=40
        Face solves before giving up (status ``"not_certified"``).

    Returns
    -------
    BlockSDPResult
    """
    if normalization not in _NORMALIZATIONS:
        raise ValueError(f"normalization={normalization!r} is not known; use 'trace' or 'mass-eigenvalue'")
    clock = time.process_time()
    total = float(r if total is None else total)
    G = _sym(np.asarray(G, dtype=float))
    g_norm = max(float(np.linalg.norm(G, 2)), np.finfo(float).tiny)
    G = G / g_norm  # the faces and the relative gap do not depend on the scale of G
    eye = np.eye(r)
    T, best, rounds = _start(G, r, normalization, total), None, 0
    bases, S = _faces_of(T, r, normalization)
    for rounds in range(1, max_rounds + 1):
        target = _face_solve(G, bases, r, normalization, total)
        if target is None:
            break
        delta = [St - Sb for St, Sb in zip(target, S)]
        alpha = _max_step(S, delta)
        S = [Sb + alpha * db for Sb, db in zip(S, delta)]
        if alpha < 1.0:  # blocked: the directions that reached zero leave the face
            bases, S = _drop(bases, S)
            continue
        T = _assemble(bases, S, r, normalization)
        gap, details = certificate(T, G, normalization, total)
        if best is None or gap < best[1]:
            best = (T, gap, details, [V.shape[1] for V in bases])
        if gap <= tol:
            break
        duals = _dual_matrices(T, G, normalization, total)
        eps = 1e-12 * max(float(np.linalg.norm(z)) for z in duals)
        grown = [_grow(V, Sb, z, eps) for V, Sb, z in zip(bases, S, duals)]
        if all(g is None for g in grown):
            break
        bases = [V if g is None else g[0] for V, g in zip(bases, grown)]
        S = [Sb if g is None else g[1] for Sb, g in zip(S, grown)]
    if best is None:
        return BlockSDPResult(blocks=(eye * 0, eye * 0, eye * 0), status="failed", objective=float("nan"),
                              gap=float("inf"), iterations=rounds, polishes=rounds,
                              seconds=time.process_time() - clock)
    T, gap, details, ranks = best
    blocks = tuple(_sym(T[:, b * r:(b + 1) * r]) for b in range(3))
    return BlockSDPResult(blocks=blocks, status="optimal" if gap <= tol else "not_certified",  # type: ignore
                          objective=details["objective"] * g_norm, gap=gap, iterations=rounds, polishes=rounds,
                          seconds=time.process_time() - clock, info=dict(details, face_ranks=ranks))
