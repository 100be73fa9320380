"""Mechanical (symmetric positive definite) realization of a stable linear second-order model.

A model ``q'' + D q' + K q = B u``, ``y = Cp q + Cv q'`` with *arbitrary* real ``D, K`` (for example the
unconstrained least-squares fit of operator inference, ``Mr = I``) is, in first-order form ``z = [q; q']``,

    z' = A z + [0; B] u,   A = [[0, I], [-K, -D]],   y = [Cp, Cv] z.

If every eigenvalue of ``A`` has a negative real part and the input reaches each pole pair through one
direction (always so for one input), the same input-output map has a realization

    q_m'' + diag(d) q_m' + diag(k) q_m = Bm u,   y = Cpm q_m + Cvm q_m',   z = W [q_m; q_m'],

with one oscillator per pole pair (``d = -(lambda_1 + lambda_2) > 0``, ``k = lambda_1 lambda_2 > 0``): mass
``I``, damping and stiffness diagonal and positive definite, so it is stable by the energy argument of the
structured fit, and it is related to the original model by the similarity ``W`` of the first-order form.  Any
time discretization that commutes with a change of the first-order state (Newmark's trapezoidal rule, the exact
zero-order-hold step) therefore gives the same outputs step for step.

Per pair, with ``A_p`` the 2x2 restriction of ``A`` to the pair's real invariant subspace and ``e`` a local
direction with ``e, A_p e`` independent, the local state ``xi = q (d e + A_p e) + q' e`` turns
``xi' = A_p xi + e beta^T u`` into ``q'' + d q' + k q = beta^T u`` (Cayley-Hamilton: ``A_p^2 + d A_p + k I = 0``).
The input must therefore enter the pair along one direction ``e`` (rank one), which is how ``e`` is chosen.

Rigid-body poles.  A body driven by an ideal acceleration source (Modelica ``Translational.Sources.Accelerate``,
a support whose acceleration is the input) or a free body has a pole at zero; a least-squares fit of its data
puts it within round-off of zero (measured: +-4e-9 i against a largest pole of 9 rad/s), on either side.
Eigenvalues within :data:`_RIGID` of the largest modulus count as zero: a pair of them is an undamped free
body ``q'' = beta^T u`` (``d = k = 0``; the pair is defective, a Jordan block, so its two columns span the
pair's invariant subspace from an ordered Schur form instead of eigenvectors), one of them beside a negative
real pole a damped free body (``k = 0``).  Without this the fit refused the realization as unstable and kept an
SDP model 0.1-0.8 % of range off (audit base82, F1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["MechanicalRealization", "mechanical_realization", "first_order_matrix"]

#: A pair whose input block has a second singular value above this fraction of the first is not rank one.
_RANK_ONE = 1e-9
#: Realizations whose similarity is worse conditioned than this are refused (nearly defective models).
_MAX_CONDITION = 1e10
#: Eigenvalues of modulus below this fraction of the largest one are rigid-body (zero) poles (module docstring).
_RIGID = 1e-6


@dataclass
class MechanicalRealization:
    """``q_m'' + diag(d) q_m' + diag(k) q_m = B u``, ``y = Cp q_m + Cv q_m'``, original ``z = W [q_m; q_m']``."""

    d: np.ndarray
    k: np.ndarray
    B: np.ndarray
    Cp: np.ndarray
    Cv: np.ndarray
    W: np.ndarray


def mechanical_realization(D: np.ndarray, K: np.ndarray, B: np.ndarray, Cp: np.ndarray,
                           Cv: np.ndarray) -> MechanicalRealization | None:
    """The diagonal SPD realization of ``q'' + D q' + K q = B u``, ``y = Cp q + Cv q'`` (module docstring).

    Parameters
    ----------
    D, K : (r, r) ndarray
        Damping and stiffness of a model with unit mass; need not be symmetric.
    B : (r, m) ndarray
        Input matrix (``m = 0`` allowed).
    Cp, Cv : (p, r) ndarray
        Output map.

    Returns
    -------
    MechanicalRealization or None
        None when no such realization exists or it would be ill-conditioned: an eigenvalue with a real part
        >= 0 (zero poles of free bodies aside, module docstring), an input reaching a pole pair through two
        directions, or a nearly defective model.
    """
    r, m = B.shape
    A = first_order_matrix(D, K)
    if not np.all(np.isfinite(A)):
        return None
    lam, X = np.linalg.eig(A)
    bound = _RIGID * np.max(np.abs(lam), initial=np.finfo(float).tiny)
    zero = np.abs(lam) <= bound
    if not np.all((lam.real < 0) | zero):
        return None
    lam = np.where(zero, 0.0, lam)
    pairs = _pole_pairs(lam)
    if pairs is None:
        return None
    U = _pair_bases(A, X, pairs, zero, bound)  # (2r, 2r): two columns per pair
    if U is None or np.linalg.cond(U) > _MAX_CONDITION:
        return None
    Y = np.linalg.inv(U)
    Bf = np.vstack([np.zeros((r, m)), B])
    d, k, beta = np.empty(r), np.empty(r), np.zeros((r, m))
    Wq, Wv = np.empty((2 * r, r)), np.empty((2 * r, r))
    for j, pair in enumerate(pairs):
        Up, Yp = U[:, 2 * j:2 * j + 2], Y[2 * j:2 * j + 2]
        Ap, Bp = Yp @ A @ Up, Yp @ Bf
        rigid = int(np.count_nonzero(zero[list(pair)]))  # zero poles in the pair (zeros are real pairs here)
        d[j], k[j] = (0.0 if rigid == 2 else -np.trace(Ap)), (0.0 if rigid else np.linalg.det(Ap))
        local = _input_direction(Bp, Ap, len(pair) == 1)
        if local is None:
            return None
        e, beta[j] = local
        position, velocity = Up @ (d[j] * e + Ap @ e), Up @ e
        scale = 1.0 / np.linalg.norm(position)  # coordinates of the size of the original ones
        Wq[:, j], Wv[:, j], beta[j] = position * scale, velocity * scale, beta[j] / scale
    W = np.hstack([Wq, Wv])
    rigid_pairs = np.array([bool(np.any(zero[list(pair)])) for pair in pairs])
    positive = np.where(rigid_pairs, (d >= 0) & (k >= 0), (d > 0) & (k > 0))
    if not np.all(positive) or np.linalg.cond(W) > _MAX_CONDITION:
        return None
    C = np.hstack([Cp, Cv]) @ W
    return MechanicalRealization(d=d, k=k, B=beta, Cp=C[:, :r], Cv=C[:, r:], W=W)


def first_order_matrix(D: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``[[0, I], [-K, -D]]``: the first-order matrix of the unit-mass model ``q'' + D q' + K q``."""
    r = D.shape[0]
    return np.block([[np.zeros((r, r)), np.eye(r)], [-K, -D]])


def _pole_pairs(lam: np.ndarray) -> list[tuple[int, ...]] | None:
    """Index groups: ``(i,)`` for a complex pair (upper half plane), ``(i, j)`` for two real poles."""
    scale = np.abs(lam) + np.finfo(float).tiny
    real = np.abs(lam.imag) <= 1e-10 * scale
    upper = [(int(i),) for i in np.flatnonzero(~real & (lam.imag > 0))]
    reals = sorted(np.flatnonzero(real), key=lambda i: lam[i].real)
    if len(reals) % 2 or 2 * len(upper) + len(reals) != lam.size:
        return None
    return upper + [(int(a), int(b)) for a, b in zip(reals[0::2], reals[1::2])]


def _pair_bases(A: np.ndarray, X: np.ndarray, pairs: list[tuple[int, ...]], zero: np.ndarray,
                bound: float) -> np.ndarray | None:
    """Two real columns per pair spanning its invariant subspace: eigenvectors, except for a pair of zero poles
    (an undamped free body, defective), whose columns are the ordered Schur basis of the zero poles' subspace
    (poles of modulus <= ``bound``).
    None for more than one such pair (several free bodies share one Jordan structure that this does not split)."""
    columns = []
    for pair in pairs:
        if np.count_nonzero(zero[list(pair)]) == 2:
            basis = _zero_subspace(A, bound) if np.count_nonzero(zero) == 2 else None
            if basis is None:
                return None
            columns.append(basis)
        else:
            columns.append(_real_basis(X, pair))
    return np.hstack(columns)


def _zero_subspace(A: np.ndarray, bound: float) -> np.ndarray | None:
    """Orthonormal basis (2r, 2) of the invariant subspace of ``A``'s two zero poles, those of modulus <= ``bound``
    (real Schur form ordered to put them first); None if the ordering does not separate exactly two."""
    _, Z, count = scipy.linalg.schur(A, output="real", sort=lambda re, im: np.hypot(re, im) <= bound)
    return Z[:, :2] if count == 2 else None


def _real_basis(X: np.ndarray, pair: tuple[int, ...]) -> np.ndarray:
    """Two real columns spanning the pair's invariant subspace."""
    if len(pair) == 1:
        x = X[:, pair[0]]
        return np.column_stack([x.real, x.imag])
    return np.column_stack([X[:, pair[0]].real, X[:, pair[1]].real])


def _input_direction(Bp: np.ndarray, Ap: np.ndarray, complex_pair: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """Local direction ``e`` and input gains ``beta`` with ``Bp = e beta^T``; None if the input is not rank one
    or ``e, Ap e`` are dependent (the input reaches only one of two real modes)."""
    if Bp.size and np.any(Bp):
        left, sv, right = scipy.linalg.svd(Bp, full_matrices=False)
        if sv.size > 1 and sv[1] > _RANK_ONE * sv[0]:
            return None
        e, beta = left[:, 0], sv[0] * right[0]
    else:  # no input reaches the pair: any direction that is not an eigenvector
        e, beta = (np.array([1.0, 0.0]) if complex_pair else np.array([1.0, 1.0]) / np.sqrt(2.0)), np.zeros(Bp.shape[1])
    companion = np.column_stack([e, Ap @ e])
    if abs(np.linalg.det(companion)) <= 1e-8 * np.linalg.norm(Ap) * (e @ e):
        return None
    return e, beta
