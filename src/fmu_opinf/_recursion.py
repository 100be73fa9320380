"""Fast evaluation of the linear recursion ``s_{i+1} = Phi s_i + Gamma u_i + c`` (a ROM's time stepping).

A Python loop of ``k`` matrix-vector products costs ``k`` interpreter round trips (about 14 us each at
``3r = 105``), far more than the arithmetic.  Here the steps are grouped in blocks of ``L``:

* block starts ``s_{bL}``: ``s_{(b+1)L} = Phi^L s_{bL} + sum_j Phi^(L-1-j) (Gamma u_{bL+j} + c)`` -- one short
  loop over ``k / L`` blocks (the input sums of all blocks are one matrix product);
* the states inside every block at once: ``C s_{bL+l} = C Phi^l s_{bL} + sum_{j<l} C Phi^(l-1-j) (Gamma u_{bL+j}
  + c)`` for ``l = 1..L`` -- one matrix product ``[s_{bL}, u_{bL..bL+L-1}, 1] @ W`` over all blocks, with ``W``
  made of the powers ``C Phi^l``, the Markov parameters ``C Phi^d Gamma`` (``d < L``, a block-Toeplitz pattern)
  and the sums of ``C Phi^d c``.

No eigendecomposition is involved: the powers of ``Phi`` are formed by multiplication in the original
coordinates, so the result equals the step-by-step loop up to rounding for any ``Phi`` (defective, non-normal,
with zero or unstable eigenvalues alike).  They come by doubling: the squarings ``Phi^(2^j)`` give ``Phi^L``
(its binary digits) and fill the powers ``C Phi^l`` and ``Phi^d Gamma`` ``2^j`` at a time, ``log2 L`` matrix
products instead of ``2 L`` small ones, which dominated the set-up (one output evaluation at n = 20 / 70 / 200,
6001 steps: 0.35 / 0.69 / 4.1 ms instead of 0.69 / 1.0 / 4.6 ms; the refinement at r = 35 11 % faster).
With ``C`` (e.g. the output rows ``[Cp, Cv, 0]``) only ``C s_i`` is formed, never the states, which is what makes
an output-only evaluation cost ``O((n + q L) p k)`` instead of ``O(n^2 k)``. Components of ``s`` that ``Phi``
never reads (zero columns, e.g. ``q''`` of the exact step map) are left out of the block starts. The block length
is chosen from a cost model (arithmetic of the block product and of the set-up against the per-block interpreter
overhead).

The real modal form (:func:`modal_form`) would make each block start ``O(n)`` instead of ``O(n^2)``, but its
set-up (eigendecomposition, refinement in extended precision, the reproduction check) takes about 100 ms at
``r = 35``, ten times a whole output evaluation of 1e5 steps here, whose block starts take about 2 ms; it serves
the exported C kernel, which steps one step at a time.

:class:`RomStep` writes both time discretizations of a ROM in this form (Newmark reads the inputs of two grid
points, which a shift of the state by the newest input's share removes), and :func:`rom_evaluate` runs it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["linear_recursion", "block_length", "rom_step_map", "RomStep", "rom_step", "rom_evaluate",
           "modal_form", "ModalForm"]

#: Interpreter cost of one block-start step, in multiply-adds of the block product (about 2.8 us at ~16 GMAC/s,
#: measured at n = 105).
_LOOP_COST = 45_000
#: Bounds of the block length.
_MIN_BLOCK, _MAX_BLOCK = 4, 256


def block_length(n: int, q: int, rows: int, k: int) -> int:
    """Block length minimizing the modelled cost of :func:`linear_recursion`.

    Cost in multiply-adds for block length ``L``: the block product ``k rows (n + q L)``, the block starts
    ``(k / L) (n^2 + overhead)`` (one matrix-vector product and one interpreter round trip per block) and the
    set-up ``L n^2 (rows + q)`` (powers and Markov parameters).

    Parameters
    ----------
    n, q, rows, k : int
        State size, input size, rows evaluated (``n`` for states, ``p`` for outputs), number of steps.

    Returns
    -------
    int
        Between 4 and 256, never more than ``k`` (at least 1).
    """
    if k <= _MIN_BLOCK:
        return max(1, int(k))
    L = np.arange(_MIN_BLOCK, min(_MAX_BLOCK, k) + 1, dtype=float)
    cost = (k * rows * (n + max(q, 1) * L) + np.ceil(k / L) * (n * n + _LOOP_COST)
            + L * n * n * (rows + max(q, 1)))
    return int(L[np.argmin(cost)])


def _squarings(phi: np.ndarray, count: int) -> list[np.ndarray]:
    """``Phi, Phi^2, Phi^4, ..., Phi^(2^j)`` up to the first exponent ``>= count`` (at least ``Phi``)."""
    out = [phi]
    while 2 ** (len(out) - 1) < count:
        out.append(out[-1] @ out[-1])
    return out


def _power(squarings: list[np.ndarray], exponent: int) -> np.ndarray:
    """``Phi^exponent`` (``exponent >= 1``) as the product of the squarings its binary digits select."""
    bits = [j for j in range(exponent.bit_length()) if exponent >> j & 1]
    out = squarings[bits[0]]
    for j in bits[1:]:
        out = squarings[j] @ out
    return out


def _output_powers(squarings: list[np.ndarray], C: np.ndarray, count: int) -> np.ndarray:
    """``(count + 1, rows, n)``: ``C, C Phi, ..., C Phi^count`` by doubling (``[C Phi^l] Phi^(2^j)`` fills the
    next ``2^j`` powers in one matrix product: ``log2(count)`` products instead of ``count``)."""
    rows, n = C.shape
    out = np.empty((count + 1, rows, n))
    out[0] = C
    filled = 1
    for square in squarings:
        if filled > count:
            break
        take = min(filled, count + 1 - filled)
        out[filled:filled + take] = (out[:take].reshape(take * rows, n) @ square).reshape(take, rows, n)
        filled += take
    return out


def _input_powers(squarings: list[np.ndarray], gamma: np.ndarray, count: int) -> np.ndarray:
    """``(count, n, q)``: ``Gamma, Phi Gamma, ..., Phi^(count-1) Gamma`` by doubling, as :func:`_output_powers`."""
    n, q = gamma.shape
    out = np.empty((count, n, q))
    if not count:
        return out
    out[0] = gamma
    filled = 1
    for square in squarings:
        if filled >= count:
            break
        take = min(filled, count - filled)
        block = square @ out[:take].transpose(1, 0, 2).reshape(n, take * q)
        out[filled:filled + take] = block.reshape(n, take, q).transpose(1, 0, 2)
        filled += take
    return out


def _toeplitz_inputs(markov: np.ndarray) -> np.ndarray:
    """``(q L, rows L)``: row ``(j, a)``, column ``(l - 1, c)`` holds ``markov[l - 1 - j][c, a]`` (zero if ``j >= l``).

    ``markov`` is ``(L, rows, q)``: ``C Phi^d Gamma`` for ``d = 0..L-1``.
    """
    L, rows, q = markov.shape
    padded = np.concatenate([markov, np.zeros((1, rows, q))])
    lag = np.arange(L)[None, :] - np.arange(L)[:, None]          # (j, l - 1) -> l - 1 - j
    lag[lag < 0] = L                                              # the zero block
    return padded[lag].transpose(0, 3, 1, 2).reshape(L * q, L * rows)


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
                     C: np.ndarray | None = None, block: int | None = None, *,
                     offset: np.ndarray | None = None) -> np.ndarray:
    """States (or ``C`` times the states) of ``s_{i+1} = Phi s_i + Gamma u_i + c``, ``i = 0..k-1``.

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
    offset : (n,) ndarray, optional
        Constant forcing ``c`` added in every step (default zero).

    Returns
    -------
    (rows, k + 1) ndarray
        Column ``i`` is ``C s_i`` (``s_i`` without ``C``); Fortran-ordered.
    """
    phi = np.asarray(phi, dtype=float)
    n = phi.shape[0]
    s0 = np.asarray(s0, dtype=float).reshape(n)
    inputs = np.asarray(inputs, dtype=float)
    q, k = inputs.shape
    gamma = np.asarray(gamma, dtype=float).reshape(n, q)
    offset = np.zeros(n) if offset is None else np.asarray(offset, dtype=float).reshape(n)
    if C is not None and np.atleast_2d(C).shape[0] > n:         # more rows than states: form the states
        states = linear_recursion(phi, s0, gamma, inputs, None, block, offset=offset)
        return (states.T @ np.atleast_2d(np.asarray(C, dtype=float)).T).T
    C = np.eye(n) if C is None else np.atleast_2d(np.asarray(C, dtype=float))
    rows = C.shape[0]
    live = np.flatnonzero(np.any(phi != 0.0, axis=0))          # the components Phi reads
    L = block_length(live.size, q, rows, k) if block is None else int(max(1, min(block, max(k, 1))))
    nb = -(-k // L)
    out = np.empty((1 + nb * L, rows))
    out[0] = C @ s0
    if k == 0:
        return out[:1].T
    ext = np.hstack([gamma, offset[:, None]])                   # the offset is one more input, held at 1
    squarings = _squarings(phi, L)                              # Phi^(2^j), shared by the powers below
    out_powers = _output_powers(squarings, C, L)                # C Phi^l, l = 0..L
    in_powers = _input_powers(squarings, ext, L)                # Phi^d [Gamma, c], d = 0..L-1
    markov = np.matmul(out_powers[:L], ext)                     # C Phi^d [Gamma, c]
    # packed row b: [s_{bL} (live part), u_{bL}, ..., u_{bL+L-1} (zero-padded after u_{k-1}), 1]
    nl = live.size
    held = np.zeros((nb * L, q))
    held[:k] = inputs.T
    held = held.reshape(nb, L * q)
    packed = np.empty((nb, nl + q * L + 1))
    packed[:, nl:nl + q * L] = held
    packed[:, -1] = 1.0
    drive = in_powers[::-1][:, live].transpose(1, 0, 2)        # (nl, L, [q + 1]): Phi^(L-1-j) [Gamma, c]
    forcing = held @ drive[:, :, :q].reshape(nl, L * q).T + drive[:, :, q].sum(axis=1)
    phi_L = _power(squarings, L)[np.ix_(live, live)]          # = (Phi restricted to live)^L: dead columns are 0
    packed[:, :nl] = _block_starts(phi_L, s0[live], forcing)
    W = np.empty((nl + q * L + 1, L * rows))
    W[:nl] = out_powers[1:, :, live].transpose(2, 0, 1).reshape(nl, L * rows)
    W[nl:nl + q * L] = _toeplitz_inputs(markov[:, :, :q])
    W[-1] = np.cumsum(markov[:, :, q], axis=0).reshape(L * rows)
    np.matmul(packed, W, out=out[1:].reshape(nb, L * rows))
    return out[:k + 1].T


def rom_step_map(rom, dt: float, forced: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ROM's time step as one linear map ``s_{i+1} = Phi s_i + Gamma v_i``, ``s = [q; q'; q'']``.

    Parameters
    ----------
    rom : SecondOrderROM
        Its ``integrator`` picks the map: ``"exact"`` (:meth:`SecondOrderROM.step_map`, ``v_i = [u; 1]`` held over
        step ``i``) or ``"newmark"`` (:func:`fmu_opinf.newmark.step_matrices`, which also needs the input of the
        previous step for the acceleration update: ``v_i = [u_{i+1}; 1; u_i]``).  Built from :func:`rom_step`.
    dt : float
    forced : (m + 1, k + 1) ndarray
        Inputs in effect at the grid times with a last row of ones (the constant force ``fr``).

    Returns
    -------
    phi : (3r, 3r) ndarray
    gamma : (3r, q) ndarray
    drive : (q, k) ndarray
    """
    step = rom_step(rom, dt)
    gamma = np.hstack([step.gamma_next, step.offset[:, None]])   # v_i starts with [u_{i+1}; 1]
    if rom.integrator == "exact":
        return step.phi, gamma, forced[:, 1:]
    return step.phi, np.hstack([gamma, step.gamma_prev]), np.vstack([forced[:, 1:], forced[:-1, :-1]])


@dataclass
class RomStep:
    """A ROM's time step ``s_{i+1} = Phi s_i + Gamma_prev u_i + Gamma_next u_{i+1} + c``, ``s = [q; q'; q'']``.

    ``u_i`` is the input in effect at grid time ``t_i`` (:func:`fmu_opinf.newmark.applied_inputs`); ``c`` collects
    the constant force ``fr``.  The exact step reads ``u_{i+1}`` only (the input held over the step), Newmark
    both (its acceleration update for the new input).

    Attributes
    ----------
    phi : (n, n) ndarray
    gamma_prev, gamma_next : (n, m) ndarray
    offset : (n,) ndarray
    """

    phi: np.ndarray
    gamma_prev: np.ndarray
    gamma_next: np.ndarray
    offset: np.ndarray


def rom_step(rom, dt: float) -> RomStep:
    """The step of ``rom`` (its :attr:`~fmu_opinf.rom.SecondOrderROM.integrator`) with step ``dt``.

    Parameters
    ----------
    rom : SecondOrderROM
    dt : float

    Returns
    -------
    RomStep
        ``Phi``, the input matrices of the new and the previous grid point, and the constant force ``c``.
    """
    from .newmark import step_matrices

    m = rom.m
    if rom.integrator == "exact":
        phi, gamma = rom.step_map(dt)
        return RomStep(phi, np.zeros_like(gamma[:, :m]), gamma[:, :m], gamma[:, m].copy())
    B = np.hstack([rom.Br, rom.fr[:, None]])
    phi, gamma_new, gamma_old = step_matrices(rom.Mr, rom.Dr, rom.Kr, B, dt)
    return RomStep(phi, gamma_old[:, :m], gamma_new[:, :m], gamma_new[:, m] + gamma_old[:, m])


def rom_evaluate(step: RomStep, s0: np.ndarray, inputs: np.ndarray, C: np.ndarray | None = None) -> np.ndarray:
    """``C s_i`` (the states without ``C``) at the grid times, by :func:`linear_recursion`.

    A step reading both ``u_i`` and ``u_{i+1}`` becomes one reading ``u_i`` only in the shifted state
    ``z_i = s_i - Gamma_next u_i``: ``z_{i+1} = Phi z_i + (Phi Gamma_next + Gamma_prev) u_i + c``, and
    ``C s_i = C z_i + C Gamma_next u_i`` (an exact identity; the values differ from the unshifted loop by rounding).

    Parameters
    ----------
    step : RomStep
    s0 : (n,) ndarray
        ``s_0``.
    inputs : (m, k + 1) ndarray
        ``u_0 .. u_k`` (inputs in effect at the grid times).
    C : (rows, n) ndarray, optional
        Rows to evaluate (e.g. ``[Cp, Cv, 0]`` for outputs); default: the states.

    Returns
    -------
    (rows, k + 1) ndarray
    """
    inputs = np.asarray(inputs, dtype=float)
    s0 = np.asarray(s0, dtype=float)
    if not np.any(step.gamma_prev):
        return linear_recursion(step.phi, s0, step.gamma_next, inputs[:, 1:], C, offset=step.offset)
    if not np.any(step.gamma_next):
        return linear_recursion(step.phi, s0, step.gamma_prev, inputs[:, :-1], C, offset=step.offset)
    gamma = step.phi @ step.gamma_next + step.gamma_prev
    z0 = s0 - step.gamma_next @ inputs[:, 0]
    lead = step.gamma_next if C is None else np.atleast_2d(C) @ step.gamma_next
    out = linear_recursion(step.phi, z0, gamma, inputs[:, :-1], C, offset=step.offset)
    rowwise, chunk = out.T, 8192                                 # out is Fortran-ordered: add row-major, in chunks
    for i in range(0, rowwise.shape[0], chunk):
        rowwise[i:i + chunk] += inputs[:, i:i + chunk].T @ lead.T
    return out


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
    # numpy has no BLAS for long doubles: einsum's loop is 1.6x faster than matmul's, the real map times the real
    # and imaginary parts of V half the work of a complex product (r = 189, 567 states: 18.7 -> about 6 s)
    wide = phi.astype(np.longdouble)
    product = (_wide_product(wide, right.real.astype(np.longdouble))
               + 1j * _wide_product(wide, right.imag.astype(np.longdouble)))
    R = _wide_product(left.astype(np.clongdouble), product)
    quotient = np.diagonal(R).copy()
    gap = quotient[None, :] - quotient[:, None]
    scale = max(float(np.abs(quotient).max()), np.finfo(float).tiny)
    separated = np.abs(gap) > 1e-8 * scale
    X = np.where(separated, R / np.where(separated, gap, 1.0), 0.0)
    np.fill_diagonal(X, 0.0)
    # X is of the order of the eigenvectors' rounding: its products in double add errors of that order squared
    step = X.astype(complex)
    v = right.astype(np.clongdouble) + right @ step
    w = left.astype(np.clongdouble) - step @ left
    out = quotient.astype(complex)
    out[lam.imag == 0] = out[lam.imag == 0].real
    return out, v.astype(complex), w.astype(complex)


def _wide_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,jk->ik", a, b)


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
