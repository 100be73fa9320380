"""The output error of a linear recursion and its gradient in the step map, for the output-error refinement.

For one training run ``z_0`` (given), ``z_i = A z_{i-1} + B u_i`` (``i = 1..k-1``), ``e_i = C z_i - t_i``:

``J = sum_i ||e_i||^2``, ``dJ/dA = sum_{i>=1} lam_i z_{i-1}^T``, ``dJ/dB = sum_{i>=1} lam_i u_i^T`` with the adjoint
``lam_{k-1} = g_{k-1}``, ``lam_i = A^T lam_{i+1} + g_i``, ``g_i = 2 C^T e_i``.

Two ways to the same numbers:

* :func:`dense_output_gradient` steps the states and the adjoint and sums the outer products: ``O(k n^2)``
  arithmetic for ``n = dim z`` (at ``n = 70``, ``k = 6001``: about 12 ms).
* :func:`modal_output_gradient` diagonalizes ``A = V diag(mu) V^-1`` and never forms a state.  In modal
  coordinates ``w = V^-1 z`` and ``nu = V^T lam`` the recursions are scalar, and every sum above becomes a
  polynomial in the eigenvalues whose coefficients are the output errors and their cross-correlation with the
  inputs (``R_pm(d) = sum_i u_mi e_p,i+d``, by FFT).  Writing ``P_c(mu) = sum_d c_d mu^d``:

  - ``N = sum_i nu_i u_i^T``: ``N_am = 2 sum_p (CV)_pa P_R_pm(mu_a)``;
  - ``E = sum_i e_i w_i^T``: ``E_pa = w0_a P_e_p(mu_a) + sum_m (V^-1 B)_am P_R_pm(mu_a)``;
  - ``S = sum_{i>=1} nu_i w_{i-1}^T`` from the Sylvester identity the two recursions give,
    ``(mu_a - mu_b) S_ab = [N (V^-1 B)^T + x w_0^T - 2 (CV)^T E]_ab`` with ``x = mu nu_1 + h_0``,
    ``x_a = 2 sum_p (CV)_pa P_e_p(mu_a)`` (the terms of ``e_0`` cancel), and on the diagonal
    ``S_aa = 2 sum_p (CV)_pa (w0_a P'_e_p(mu_a) + sum_m (V^-1 B)_am P'_R_pm(mu_a))``;
  - ``dJ/dA = V^-T S V^T``, ``dJ/dB = V^-T N``.

  Cost: one eigendecomposition (``O(n^3)``), the outputs (``O(k n p)`` by the blocked recursion of
  :mod:`fmu_opinf._recursion`), FFTs of length ``2k`` and polynomial evaluations as one matrix product of
  ``O(k n (p + p m))``: at ``n = 70``, ``k = 6001`` about 3.5 ms.  It needs a well-conditioned eigenvector basis
  and separated eigenvalues (the division by ``mu_a - mu_b``); :func:`modal_output_gradient` returns ``None``
  otherwise and the caller takes the dense way.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, wait

import numpy as np
import scipy.fft

from ._recursion import linear_recursion

__all__ = ["dense_output_gradient", "modal_output_gradient", "modal_is_faster", "Run"]

#: A training run: initial state ``z_0`` (n,), inputs ``u`` (m, k) (column 0 unused), target ``t`` (p, k).
Run = tuple[np.ndarray, np.ndarray, np.ndarray]

#: Largest condition number of the eigenvector basis for the modal way (rounding grows with it).
_MAX_CONDITION = 1e6
#: Smallest eigenvalue separation ``|mu_a - mu_b|`` for the modal way (the Sylvester division).
_MIN_GAP = 1e-6
#: Fewest states for which the modal way is the faster one (measured: at n = 8 it takes 1.1-1.5x the dense time,
#: from n = 16 on less for one input and up to three outputs; more outputs and inputs move the crossing up).
_MODAL_MIN_STATES = 14

#: Time steps per block of the dense propagation.
_STRIDE = 64


def powers(A: np.ndarray, count: int) -> np.ndarray:
    """``A, A^2, ..., A^count`` stacked, shape ``(count, n, n)``."""
    out = np.empty((max(count, 1), *A.shape))
    out[0] = A
    for j in range(1, count):
        out[j] = A @ out[j - 1]
    return out


def propagate(A: np.ndarray, f: np.ndarray, z0: np.ndarray, stride: int = _STRIDE,
              power_stack: np.ndarray | None = None) -> np.ndarray:
    """``z_0 = z0``, ``z_i = A z_{i-1} + f_i`` for ``i = 1 .. k-1`` (``f[:, 0]`` unused), blocked in time.

    Within blocks of ``stride`` steps the forcing is accumulated for all blocks at once, and only the block
    starts are stepped one by one (with ``A^stride``): ``k / stride`` Python iterations instead of ``k``.
    ``power_stack`` (``A, A^2, ...``, at least ``stride`` of them, from :func:`powers`) saves recomputing them.
    """
    return propagate_runs(A, [f], [z0], stride, power_stack)[0]


def propagate_runs(A: np.ndarray, forcings: list[np.ndarray], starts: list[np.ndarray], stride: int = _STRIDE,
                   power_stack: np.ndarray | None = None) -> list[np.ndarray]:
    """:func:`propagate` for several runs of the same ``A`` (forcing ``(n, k_j)`` and start ``(n,)`` each).

    Runs of similar length are stepped side by side, their block starts as the columns of one matrix: the
    Python iterations are those of the longest run of each group, not of every run (seventh audit: 20 runs of
    8609 steps at ``n = 10``, the interpreter's round trips were most of the refinement's 33 s).  A shorter run
    of a group is padded with zero forcing; what the padding computes is dropped.  A group's arrays stay below
    :data:`GROUP_BYTES` (:func:`_similar_lengths`).
    """
    out: list[np.ndarray | None] = [None] * len(forcings)
    for group in _similar_lengths([f.shape[1] for f in forcings], A.shape[0]):
        states = _propagate_group(A, [forcings[j] for j in group], [starts[j] for j in group], stride, power_stack)
        for j, z in zip(group, states):
            out[j] = z
    return out


#: Largest padded size of a group of runs stepped together, relative to the steps its runs have.
_PADDING = 1.25
#: Largest size of one array of a group of runs stepped together (a run longer than that is a group of its own).
GROUP_BYTES = 16_000_000


def _similar_lengths(lengths: list[int], rows: int = 1) -> list[list[int]]:
    """Indices of the runs grouped so that padding each group to its longest run costs at most
    :data:`_PADDING` times its steps and a group's ``rows`` x padded-length array stays below
    :data:`GROUP_BYTES` (longest first)."""
    columns = max(1, GROUP_BYTES // (8 * max(int(rows), 1)))
    groups: list[list[int]] = []
    steps = 0  # of the last group
    for j in sorted(range(len(lengths)), key=lambda i: -lengths[i]):
        if groups:
            padded = lengths[groups[-1][0]] * (len(groups[-1]) + 1)
            if padded <= _PADDING * (steps + lengths[j]) and padded <= columns:
                groups[-1].append(j)
                steps += lengths[j]
                continue
        groups.append([j])
        steps = lengths[j]
    return groups


def _propagate_group(A: np.ndarray, forcings: list[np.ndarray], starts: list[np.ndarray], stride: int,
                     power_stack: np.ndarray | None) -> list[np.ndarray]:
    n, runs = A.shape[0], len(forcings)
    lengths = [f.shape[1] for f in forcings]
    steps = max(lengths) - 1
    out = [np.empty((n, k)) for k in lengths]
    for z, z0 in zip(out, starts):
        z[:, 0] = z0
    if steps == 0:
        return out
    s = max(1, min(stride, steps))
    nb = -(-steps // s)
    acc = np.zeros((s, n, runs * nb))   # (s, n, runs nb): written in that layout, not copied into it
    for j, f in enumerate(forcings):
        _blocked(acc[:, :, j * nb:(j + 1) * nb], f[:, 1:], s)
    for j in range(1, s):
        acc[j] += A @ acc[j - 1]
    power_stack = powers(A, s) if power_stack is None else power_stack[:s]
    block_starts = np.empty((n, runs, nb))
    z = np.column_stack([np.asarray(z0, dtype=float) for z0 in starts])  # (n, runs)
    last = acc[s - 1].reshape(n, runs, nb)
    with np.errstate(over="ignore", invalid="ignore"):  # a padded tail of an unstable A may overflow; dropped
        for b in range(nb):
            block_starts[:, :, b] = z
            z = power_stack[s - 1] @ z + last[:, :, b]
        states = power_stack @ block_starts.reshape(n, runs * nb) + acc  # (s, n, runs nb)
    for j, z in enumerate(out):
        _unblocked(z[:, 1:], states[:, :, j * nb:(j + 1) * nb], s)
    return out


def _blocked(dst: np.ndarray, f: np.ndarray, s: int) -> None:
    """``dst[i, :, b] = f[:, b s + i]`` (``dst`` ``(s, n, nb)``, zero past ``f``'s end): a run's forcing in the
    blocks of :func:`_propagate_group`, copied once (before: a zeroed ``(n, runs, nb s)`` array, filled, then
    copied again into this layout; at 120 states and 6 runs of 3776 steps the copies were a third of the time)."""
    full = f.shape[1] // s
    if full:
        dst[:, :, :full] = f[:, :full * s].reshape(f.shape[0], full, s).transpose(2, 0, 1)
    tail = f.shape[1] - full * s
    if tail:
        dst[:tail, :, full] = f[:, full * s:].T


def _unblocked(dst: np.ndarray, states: np.ndarray, s: int) -> None:
    """The inverse of :func:`_blocked` for one run's states: ``dst[:, b s + i] = states[i, :, b]``, up to
    ``dst``'s length, copied once."""
    full = dst.shape[1] // s
    if full:
        dst[:, :full * s].reshape(dst.shape[0], full, s)[...] = states[:, :, :full].transpose(1, 2, 0)
    tail = dst.shape[1] - full * s
    if tail:
        dst[:, full * s:] = states[:tail, :, full].T


def modal_is_faster(states: int, outputs: int, inputs: int) -> bool:
    """Whether :func:`modal_output_gradient` beats :func:`dense_output_gradient` for these sizes: the dense way
    costs ``O(k n^2)``, the modal one ``O(k n p (1 + m))`` plus fixed work (FFTs, one eigendecomposition)."""
    return states >= max(_MODAL_MIN_STATES, 2 * outputs * (1 + inputs))


#: An objective of the simulated states: states of each run -> (value, its gradient in each run's states).
Misfit = Callable[[list[np.ndarray]], tuple[float, list[np.ndarray]]]


def dense_output_gradient(A: np.ndarray, B: np.ndarray, C: np.ndarray, runs: list[Run],
                          misfit: Misfit | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """``J``, ``dJ/dA``, ``dJ/dB`` summed over the runs by stepping states and adjoints (module docstring).

    ``misfit`` replaces the output error ``J`` by another objective of the simulated states (the refinement's
    re-fitted output map or state-error term); the adjoint then starts from its gradient in the states.
    """
    power_stack = powers(A, _STRIDE)  # shared by all runs, transposed for the adjoint
    states = propagate_runs(A, [B @ u for _, u, _ in runs], [z0 for z0, _, _ in runs], _STRIDE, power_stack)
    value, drives = (misfit or _output_misfit(C, runs))(states)
    shares: list[tuple[np.ndarray, np.ndarray] | None] = [None] * len(runs)
    for group in _similar_lengths([g.shape[1] for g in drives], A.shape[0]):  # one group's adjoints at a time
        adjoints = _propagate_group(A.T, [drives[j][:, ::-1] for j in group], [drives[j][:, -1] for j in group],
                                    _STRIDE, power_stack.transpose(0, 2, 1))
        for j, lam in zip(group, adjoints):
            lam = lam[:, ::-1]
            shares[j] = (lam[:, 1:] @ states[j][:, :-1].T, lam[:, 1:] @ runs[j][1][:, 1:].T)
    grad_A, grad_B = np.zeros_like(A), np.zeros_like(B)
    for share_A, share_B in shares:  # in the runs' order, whatever the groups
        grad_A += share_A
        grad_B += share_B
    return value, grad_A, grad_B


def _output_misfit(C: np.ndarray, runs: list[Run]) -> Misfit:
    """``sum ||C z_i - t_i||^2`` and its gradient ``2 C^T (C z_i - t_i)`` in the states."""
    def misfit(states: list[np.ndarray]) -> tuple[float, list[np.ndarray]]:
        value, drives = 0.0, []
        for z, (_, _, target) in zip(states, runs):
            err = C @ z - target
            value += float(np.sum(err * err))
            drives.append(2.0 * (C.T @ err))
        return value, drives
    return misfit


def modal_output_gradient(A: np.ndarray, B: np.ndarray, C: np.ndarray, runs: list[Run],
                          helper: Executor | None = None) -> tuple[float, np.ndarray, np.ndarray] | None:
    """``J``, ``dJ/dA``, ``dJ/dB`` through the eigenvalues of ``A`` (module docstring), or ``None`` when its
    eigenvector basis is ill-conditioned or two eigenvalues are closer than ``1e-6``.

    ``helper``: a one-thread executor for a core that would otherwise idle; the output errors, which need only
    ``A``, are simulated there while this thread decomposes ``A`` (the same numbers either way).
    """
    pending = helper.submit(_output_errors, A, B, C, runs) if helper is not None else None
    try:
        found = _eigenbasis(A)
    except BaseException:
        if pending is not None:
            wait([pending])  # never leave the helper running; this thread's error is the one to raise
        raise
    errors = pending.result() if pending is not None else None
    if found is None:
        return None
    mu, V, V_inv, gap = found
    modal_B, CV = V_inv @ B, C @ V
    S, N, value = np.zeros_like(gap), np.zeros(modal_B.shape, dtype=complex), 0.0
    if errors is None:
        errors = _output_errors(A, B, C, runs)
    for (z0, u, _), err in zip(runs, errors):
        value += float(np.sum(err * err))
        run_S, run_N = _modal_sums(mu, gap, V_inv @ z0, modal_B, CV, u, err)
        S += run_S
        N += run_N
    return value, (V_inv.T @ S @ V.T).real, (V_inv.T @ N).real


def _output_errors(A: np.ndarray, B: np.ndarray, C: np.ndarray, runs: list[Run]) -> list[np.ndarray]:
    """``C z_i - t_i`` of every run."""
    return [linear_recursion(A, z0, B, u[:, 1:], C) - target for z0, u, target in runs]


def _eigenbasis(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """``mu, V, V^-1`` of ``A = V diag(mu) V^-1`` and the eigenvalue differences ``mu_a - mu_b`` (ones on the
    diagonal), or ``None`` where the modal way does not apply (:func:`modal_output_gradient`)."""
    mu, V = np.linalg.eig(A)
    if not np.all(np.isfinite(mu)):
        return None
    gap = mu[:, None] - mu[None, :]
    np.fill_diagonal(gap, 1.0)
    if np.abs(gap).min() < _MIN_GAP:
        return None
    try:
        V_inv = np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return None
    if not np.linalg.norm(V, 1) * np.linalg.norm(V_inv, 1) <= _MAX_CONDITION:  # the 1-norm condition number
        return None
    return mu, V, V_inv, gap


def _modal_sums(mu: np.ndarray, gap: np.ndarray, w0: np.ndarray, modal_B: np.ndarray, CV: np.ndarray,
                u: np.ndarray, err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``S = sum_{i>=1} nu_i w_{i-1}^T`` and ``N = sum_{i>=1} nu_i u_i^T`` of one run (module docstring)."""
    p, k = err.shape
    m, n = u.shape[0], mu.size
    driven = u.copy()
    driven[:, 0] = 0.0                                  # u_0 drives no step
    R = _cross_correlation(driven, err).reshape(p * m, k)
    values = _polynomial_values(np.vstack([err, _derivative(err), R, _derivative(R)]), mu)
    P_e, dP_e = values[:p], values[p:2 * p]
    P_R, dP_R = values[2 * p:2 * p + p * m].reshape(p, m, n), values[2 * p + p * m:].reshape(p, m, n)
    N = 2.0 * np.einsum("pa,pma->am", CV, P_R)
    E = w0 * P_e + np.einsum("am,pma->pa", modal_B, P_R)
    x = 2.0 * np.einsum("pa,pa->a", CV, P_e)            # mu_a (nu_1)_a + (h_0)_a
    S = (N @ modal_B.T + np.outer(x, w0) - 2.0 * CV.T @ E) / gap
    diagonal = 2.0 * (np.einsum("pa,pa->a", CV, dP_e) * w0 + np.einsum("am,pa,pma->a", modal_B, CV, dP_R))
    np.fill_diagonal(S, diagonal)
    return S, N


def _derivative(coefficients: np.ndarray) -> np.ndarray:
    """Coefficients of ``P'`` for those of ``P`` (rows; same length, last one zero)."""
    out = np.zeros_like(coefficients)
    out[:, :-1] = coefficients[:, 1:] * np.arange(1, coefficients.shape[1])
    return out


def _cross_correlation(u: np.ndarray, err: np.ndarray) -> np.ndarray:
    """``R[p, m, d] = sum_i u[m, i] err[p, i + d]`` for ``d = 0 .. k-1`` (FFT of length >= 2k)."""
    k = err.shape[1]
    size = scipy.fft.next_fast_len(2 * k, real=True)
    spectrum = scipy.fft.rfft(err, size)[:, None, :] * np.conj(scipy.fft.rfft(u, size))[None, :, :]
    return scipy.fft.irfft(spectrum, size)[..., :k]


def _polynomial_values(coefficients: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """``(sets, n)``: ``sum_d coefficients[:, d] mu^d`` at every ``mu``, in blocks of ``s ~ sqrt(k)`` powers:
    ``sum_b (mu^s)^b sum_j c_{bs+j} mu^j``, one matrix product for the inner sums.

    The coefficients are real, so ``P(conj mu) = conj P(mu)``: of the eigenvalues of a real step map, which come in
    exactly conjugate pairs, only one of each pair is evaluated (:func:`_evaluated`), and the inner sums take the real
    and imaginary parts of the powers as two real products (a product with the complex powers converted the real
    coefficients to complex and did twice the arithmetic).  The same values to the last bit on the measured cases,
    in a quarter of the time at ``n = 52 .. 120`` (issue 16: at r = 52 / 60 the polynomials were a third of the
    refinement's time).
    """
    sets, k = coefficients.shape
    evaluated, conjugated, partners = _evaluated(mu)
    at = mu[evaluated]
    s = max(1, int(np.sqrt(k)))
    nb = -(-k // s)
    padded = np.zeros((sets, nb * s))
    padded[:, :k] = coefficients
    flat = padded.reshape(sets * nb, s)
    powers_ = at[None, :] ** np.arange(s)[:, None]
    inner = flat @ powers_.real + 1j * (flat @ powers_.imag)
    outer = np.empty((nb, at.size), dtype=complex)
    outer[0] = 1.0
    step = at ** s
    for b in range(1, nb):
        np.multiply(outer[b - 1], step, out=outer[b])
    out = np.empty((sets, mu.size), dtype=complex)
    out[:, evaluated] = np.einsum("sbn,bn->sn", inner.reshape(sets, nb, at.size), outer)
    out[:, conjugated] = np.conj(out[:, partners])
    return out


def _evaluated(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the eigenvalues :func:`_polynomial_values` evaluates, of those it takes as the conjugates of
    others (an eigenvalue in the lower half plane whose exact conjugate is among the evaluated), and of those
    others.  LAPACK returns a real matrix's complex eigenvalues as exact conjugate pairs, the upper one first."""
    paired = (mu.imag < 0) & (mu == np.conj(np.roll(mu, 1)))
    paired[0] = False
    conjugated = np.flatnonzero(paired)
    return np.flatnonzero(~paired), conjugated, conjugated - 1
