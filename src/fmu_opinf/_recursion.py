"""Fast evaluation of the linear recursion ``s_{i+1} = Phi s_i + Gamma u_i`` (a ROM's time stepping).

A Python loop of ``k`` matrix-vector products costs ``k`` interpreter round trips (about 14 us each at
``3r = 105``), far more than the arithmetic.  Here the steps are grouped in blocks of ``L``:

* block starts ``s_{bL}``: ``s_{(b+1)L} = Phi^L s_{bL} + sum_j Phi^(L-1-j) Gamma u_{bL+j}`` -- one short loop over
  ``k / L`` blocks (the input sums of all blocks are one matrix product);
* the states inside every block at once: ``C s_{bL+l} = C Phi^l s_{bL} + sum_{j<l} C Phi^(l-1-j) Gamma u_{bL+j}``
  for ``l = 1..L`` -- one matrix product ``[s_{bL}, u_{bL..bL+L-1}] @ W`` over all blocks, with ``W`` made of the
  powers ``C Phi^l`` and the Markov parameters ``C Phi^d Gamma`` (``d < L``).

No eigendecomposition is involved: the powers of ``Phi`` are formed by repeated multiplication in the original
coordinates, so the result equals the step-by-step loop up to rounding for any ``Phi`` (defective, non-normal,
with zero or unstable eigenvalues alike).  With ``C`` (e.g. the output rows ``[Cp, Cv, 0]``) only ``C s_i`` is
formed, never the states, which is what makes an output-only evaluation cost ``O((p + q L) k)`` instead of
``O(n^2 k)``.  The block length is chosen from a cost model (arithmetic of the block product against the
per-block interpreter overhead).
"""

from __future__ import annotations

import numpy as np

__all__ = ["linear_recursion", "block_length"]

#: Interpreter cost of one block-start step, in multiply-adds of the block product (about 3 us at ~5 GFlop/s).
_LOOP_COST = 15_000
#: Bounds of the block length.
_MIN_BLOCK, _MAX_BLOCK = 4, 128


def block_length(n: int, q: int, rows: int, k: int) -> int:
    """Block length minimizing ``k rows (n + q L) + (k / L) * overhead`` (arithmetic plus interpreter cost).

    Parameters
    ----------
    n, q, rows, k : int
        State size, input size, rows evaluated (``n`` for states, ``p`` for outputs), number of steps.

    Returns
    -------
    int
        Between 4 and 128, never more than ``k``.
    """
    ideal = np.sqrt((_LOOP_COST + n * n) / max(rows * max(q, 1), 1))
    return int(max(1, min(k, max(_MIN_BLOCK, min(_MAX_BLOCK, round(ideal))))))


def _powers(phi: np.ndarray, count: int) -> list[np.ndarray]:
    """``[I, Phi, Phi^2, ..., Phi^count]`` by repeated multiplication."""
    out = [np.eye(phi.shape[0])]
    for _ in range(count):
        out.append(phi @ out[-1])
    return out


def _block_matrix(powers: list[np.ndarray], gamma: np.ndarray, C: np.ndarray) -> np.ndarray:
    """``W ((n + q L), L rows)``: column block ``l - 1`` maps ``[s_{bL}; u_{bL}; ...; u_{bL+L-1}]`` to ``C s_{bL+l}``."""
    n, q = gamma.shape
    L = len(powers) - 1
    rows = C.shape[0]
    markov = [C @ (P @ gamma) for P in powers[:L]]          # C Phi^d Gamma, d = 0..L-1
    W = np.zeros((n + q * L, L * rows))
    for l in range(1, L + 1):
        cols = slice((l - 1) * rows, l * rows)
        W[:n, cols] = (C @ powers[l]).T
        for j in range(l):
            W[n + j * q:n + (j + 1) * q, cols] = markov[l - 1 - j].T
    return W


def _block_starts(phi_L: np.ndarray, s0: np.ndarray, forcing: np.ndarray) -> np.ndarray:
    """Rows ``s_{bL}`` for ``b = 0..nb-1`` from ``s_{(b+1)L} = Phi^L s_{bL} + forcing[b]``."""
    nb, n = forcing.shape
    starts = np.empty((nb, n))
    starts[0] = s0
    step = np.ascontiguousarray(phi_L.T)
    for b in range(nb - 1):
        np.dot(starts[b], step, out=starts[b + 1])
        starts[b + 1] += forcing[b]
    return starts


def linear_recursion(phi: np.ndarray, s0: np.ndarray, gamma: np.ndarray, inputs: np.ndarray,
                     C: np.ndarray | None = None, block: int | None = None) -> np.ndarray:
    """States (or ``C`` times the states) of ``s_{i+1} = Phi s_i + Gamma u_i``, ``i = 0..k-1``.

    Equal to the step-by-step loop up to rounding (no change of coordinates).

    Parameters
    ----------
    phi : (n, n) ndarray
        Step map.
    s0 : (n,) ndarray
        Initial state.
    gamma : (n, q) ndarray
        Input map (``q = 0`` allowed).
    inputs : (q, k) ndarray
        ``u_0 .. u_{k-1}``; column ``i`` drives the step from ``s_i`` to ``s_{i+1}``.
    C : (rows, n) ndarray, optional
        Evaluate only ``C s_i`` (e.g. outputs); default: the states themselves.
    block : int, optional
        Block length (default: :func:`block_length`).

    Returns
    -------
    (rows, k + 1) ndarray
        Column ``i`` is ``C s_i`` (``s_i`` without ``C``); Fortran-ordered.
    """
    phi = np.asarray(phi, dtype=float)
    n = phi.shape[0]
    s0 = np.asarray(s0, dtype=float).reshape(n)
    inputs = np.asarray(inputs, dtype=float)
    gamma = np.asarray(gamma, dtype=float).reshape(n, inputs.shape[0])
    q, k = inputs.shape
    C = np.eye(n) if C is None else np.atleast_2d(np.asarray(C, dtype=float))
    rows = C.shape[0]
    L = block_length(n, q, rows, k) if block is None else int(max(1, min(block, max(k, 1))))
    nb = -(-k // L)
    out = np.empty((1 + nb * L, rows))
    out[0] = C @ s0
    if k == 0:
        return out[:1].T
    # block inputs: row b holds u_{bL}, ..., u_{bL+L-1} (zero-padded after u_{k-1})
    held = np.zeros((nb * L, q))
    held[:k] = inputs.T
    packed = np.empty((nb, n + q * L))
    packed[:, n:] = held.reshape(nb, q * L)
    powers = _powers(phi, L)
    drive = np.hstack([powers[L - 1 - j] @ gamma for j in range(L)]) if q else np.zeros((n, 0))
    packed[:, :n] = _block_starts(powers[L], s0, packed[:, n:] @ drive.T)
    W = _block_matrix(powers, gamma, C)
    used = np.flatnonzero(np.any(W != 0.0, axis=1))        # e.g. the q'' columns of an exact step map are zero
    if used.size < W.shape[0]:
        packed, W = packed[:, used], W[used]
    np.matmul(packed, W, out=out[1:].reshape(nb, L * rows))
    return out[:k + 1].T
