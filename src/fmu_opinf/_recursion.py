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

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["linear_recursion", "block_length", "rom_step_map", "modal_form", "ModalForm"]

#: Interpreter cost of one block-start step, in multiply-adds of the block product (about 2.8 us at ~16 GMAC/s,
#: measured at n = 105).
_LOOP_COST = 45_000
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


def rom_step_map(rom, dt: float, forced: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ROM's time step as one linear map ``s_{i+1} = Phi s_i + Gamma v_i``, ``s = [q; q'; q'']``.

    Parameters
    ----------
    rom : SecondOrderROM
        Its ``integrator`` picks the map: ``"exact"`` (:meth:`SecondOrderROM.step_map`, ``v_i = [u; 1]`` held over
        step ``i``) or ``"newmark"`` (:func:`fmu_opinf.newmark.step_matrices`, which also needs the input of the
        previous step for the acceleration update: ``v_i = [u_{i+1}; 1; u_i; 1]``).
    dt : float
    forced : (m + 1, k + 1) ndarray
        Inputs in effect at the grid times with a last row of ones (the constant force ``fr``).

    Returns
    -------
    phi : (3r, 3r) ndarray
    gamma : (3r, q) ndarray
    drive : (q, k) ndarray
    """
    from .newmark import step_matrices

    if rom.integrator == "exact":
        phi, gamma = rom.step_map(dt)
        return phi, gamma, forced[:, 1:]
    B = np.hstack([rom.Br, rom.fr[:, None]])
    phi, gamma_new, gamma_old = step_matrices(rom.Mr, rom.Dr, rom.Kr, B, dt)
    return phi, np.hstack([gamma_new, gamma_old]), np.vstack([forced[:, 1:], forced[:, :-1]])


@dataclass
class ModalForm:
    """Real block-diagonal (modal) form of ``s+ = Phi s + Gamma v``, as the exported C kernel steps it.

    ``w = P s`` (``P = projection``, ``k`` rows, ``k`` even), ``w+ = Lambda w + P Gamma v`` with ``Lambda``
    block diagonal (2 x 2 blocks: one complex-conjugate pair of eigenvalues, or two real ones), and after a step
    ``s = shape w + rest v`` (``rest = (I - shape P) Gamma``: the part of the state in the eigenspace of the
    eigenvalue 0, which depends on the last input only).

    Attributes
    ----------
    blocks : (k, 2) ndarray
        Row ``i``: the entries of ``Lambda`` in row ``i``, columns ``2 (i // 2)`` and ``2 (i // 2) + 1``.
    shape : (n, k) ndarray
    projection : (k, n) ndarray
    complement : (n, n) ndarray
        ``I - shape @ projection``: the projector onto the eigenspace of the eigenvalue 0.
    """

    blocks: np.ndarray
    shape: np.ndarray
    projection: np.ndarray
    complement: np.ndarray

    @property
    def size(self) -> int:
        """Number of modal coordinates ``k``."""
        return self.blocks.shape[0]

    def step_matrix(self) -> np.ndarray:
        """``Lambda`` as a dense (k, k) matrix."""
        k = self.size
        out = np.zeros((k, k))
        for i in range(k):
            out[i, 2 * (i // 2):2 * (i // 2) + 2] = self.blocks[i]
        return out


def _real_modes(lam: np.ndarray, right: np.ndarray, left: np.ndarray) -> tuple[list, list, list]:
    """2 x 2 blocks, shape columns and projection rows of the modes with nonzero eigenvalues."""
    blocks, shape, projection = [], [], []
    reals = []
    for j in np.flatnonzero(lam.imag > 0):          # one of each conjugate pair: z = y s, s += 2 Re(v z)
        a, b = lam[j].real, lam[j].imag
        blocks.append(np.array([[a, -b], [b, a]]))
        shape += [2 * right[:, j].real, -2 * right[:, j].imag]
        projection += [left[j].real, left[j].imag]
    reals = list(np.flatnonzero(lam.imag == 0))
    if len(reals) % 2:
        reals.append(None)                            # pad: a coordinate with no dynamics and no effect
    n = right.shape[0]
    for pair in zip(reals[::2], reals[1::2]):
        blocks.append(np.diag([0.0 if j is None else lam[j].real for j in pair]))
        for j in pair:
            shape.append(np.zeros(n) if j is None else right[:, j].real)
            projection.append(np.zeros(n) if j is None else left[j].real)
    return blocks, shape, projection


def _refined(phi: np.ndarray, lam: np.ndarray, right: np.ndarray,
             left: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One first-order refinement of ``Phi = V diag(lam) W`` in extended precision (``W = V^-1``).

    With ``R = W Phi V`` (should be diagonal): ``lam = diag(R)`` (two-sided Rayleigh quotients, error second
    order in the eigenvector errors; an eigenvalue error would grow with the number of steps) and
    ``V <- V (I + X)``, ``W <- (I - X) W`` with ``X_ij = R_ij / (lam_j - lam_i)`` off the diagonal (pairs within
    the eigenvalue-0 cluster left alone: that cluster only enters through its projector).  Conjugate pairs stay
    conjugate because every step is real-equivariant.
    """
    wide = phi.astype(np.longdouble)
    v, w = right.astype(np.clongdouble), left.astype(np.clongdouble)
    R = w @ (wide @ v)
    quotient = np.diagonal(R).copy()
    gap = quotient[None, :] - quotient[:, None]
    scale = max(float(np.abs(quotient).max()), np.finfo(float).tiny)
    separated = np.abs(gap) > 1e-8 * scale
    X = np.where(separated, R / np.where(separated, gap, 1.0), 0.0)
    np.fill_diagonal(X, 0.0)
    v, w = v @ (np.eye(len(lam)) + X), (np.eye(len(lam)) - X) @ w
    out = quotient.astype(complex)
    out[lam.imag == 0] = out[lam.imag == 0].real
    return out, v.astype(complex), w.astype(complex)


def modal_form(phi: np.ndarray, gamma: np.ndarray, steps: int = 2000, tol: float = 1e-12) -> ModalForm | None:
    """Real modal form of the step map, or None if it does not reproduce the map to ``tol``.

    Eigenvalues below ``1e-13`` times the largest in magnitude are treated as zero (their part of the state
    is forgotten in one step); the result is checked by running ``steps`` steps of a random input from a
    random state both ways (relative difference at most ``tol``), which rejects defective or ill-conditioned
    eigenvector bases.

    Parameters
    ----------
    phi : (n, n) ndarray
    gamma : (n, q) ndarray
    steps : int, default=2000
    tol : float, default=1e-12

    Returns
    -------
    ModalForm or None
    """
    phi = np.asarray(phi, dtype=float)
    n = phi.shape[0]
    lam, right = scipy.linalg.eig(phi)
    scale = max(float(np.abs(lam).max()), np.finfo(float).tiny)
    keep = np.abs(lam) > 1e-13 * scale
    try:
        left = np.linalg.inv(right)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(left)) or np.linalg.cond(right) > 1e10:
        return None
    lam, right, left = _refined(phi, lam, right, left)
    lam, right, left = lam[keep], right[:, keep], left[keep]
    blocks, shape, projection = _real_modes(lam, right, left)
    if not blocks:
        return None
    blocks = np.vstack(blocks)
    shape, projection = np.array(shape).T, np.array(projection)
    form = ModalForm(blocks=blocks, shape=shape, projection=projection, complement=np.eye(n) - shape @ projection)
    return form if _reproduces(form, phi, np.asarray(gamma, dtype=float), steps, tol) else None


def _reproduces(form: ModalForm, phi: np.ndarray, gamma: np.ndarray, steps: int, tol: float) -> bool:
    """Random run through the modal form (as the C kernel steps) against :func:`linear_recursion`."""
    rng = np.random.default_rng(0)
    n, q = gamma.shape
    s0, inputs = rng.standard_normal(n), rng.standard_normal((q, steps))
    reference = linear_recursion(phi, s0, gamma, inputs)
    lam, rest = form.step_matrix(), form.complement @ gamma
    w = form.projection @ s0
    got = np.empty((n, steps))
    for i in range(steps):
        w = lam @ w + form.projection @ (gamma @ inputs[:, i])
        got[:, i] = form.shape @ w + rest @ inputs[:, i]
    error = np.abs(got - reference[:, 1:]).max() / max(float(np.abs(reference).max()), np.finfo(float).tiny)
    return bool(np.isfinite(error) and error <= tol)
