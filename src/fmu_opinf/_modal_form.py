"""The modal normal form of a modally damped least-squares fit: a start of the output-error refinement that does not
depend on the orientation of the POD basis (rot86).

Why.  Where the training data are those of a modally damped model (Rayleigh damping, a stiff support filter driving
a chain), every mode-wise scaling of the equation of motion fits them: in the generalized eigenbasis ``Psi`` of
``(Kr, Mr)``, ``Mr' = Psi^-T diag(c m) Psi^-1`` and the same for ``Dr, Kr``, ``Br' = Psi^-T diag(c) Psi^T Br``, for
any ``c > 0``.  The SDP of eq. (16) has this flat set of optima (``trace(Mr)`` or ``Mr >= I`` fix only the common
scale) and, with data near exact, its residual is far below the solver's tolerance, so the point it returns depends
on round-off: on audit84's support chain at full order, four random rotations of the same basis gave SDP solutions
with relative equation residuals from 1.4e-12 to 2.9e-7 (the point of one rotation, rotated into another, has
1.4e-12 there), the support mode's stiffness off by up to 600 times, and refined ROMs 2.1e-6 .. 2.3e-2 of range off
the exact model.

What.  The unconstrained unit-mass least-squares fit ``q'' + Dl q' + Kl q = Bl u`` is unique and invariant (a
rotation of the basis rotates it).  Where ``Kl`` has real, non-negative, separated eigenvalues with a
well-conditioned eigenbasis and ``Dl`` is diagonal in that basis up to :data:`MODAL_DAMPING_SHARE`, the fit is taken
to its normal form: eigenvector columns of unit length ``Phi``, ``Mr = Phi^-T Phi^-1``,
``Dr = Phi^-T diag(d) Phi^-1``, ``Kr = Phi^-T diag(omega^2) Phi^-1``, ``Br = Mr Bl`` (each modal equation at unit
modal mass; the damping's off-diagonal share is dropped).  Symmetric PSD by construction, the same dynamics up to
that share, and one representative however the basis is turned.  Elsewhere (non-modal damping, complex or clustered
eigenvalues) there is no normal form and the fit keeps the SDP solution, whose pick can still follow the
orientation: the support chain with two local dashpots instead of Rayleigh damping, 6.5e-6 .. 3.0e-2 over the same
rotations (the SDP's accuracy on near-exact data, left open).
"""

from __future__ import annotations

import numpy as np

__all__ = ["modal_normal_form", "MODAL_DAMPING_SHARE"]

#: Largest off-diagonal share ``|Dm_ij| / sqrt(Dm_ii Dm_jj)`` of the damping in the stiffness's eigenbasis for
#: which a fit counts as modally damped.  audit84's support chain (Rayleigh-damped chain driven through the support
#: damper): 4.0e-3 (the support's one-way coupling; the chain's own entries 2e-12); the same chain with two local
#: dashpots instead (not proportional): 0.80.
MODAL_DAMPING_SHARE = 1e-2

#: Smallest relative gap between neighbouring ``omega^2`` (of the largest) and largest condition number of the
#: eigenbasis: below / above them the eigenvectors are not determined by the fit to round-off, so neither is the form.
MODE_SEPARATION, EIGENBASIS_CONDITION = 1e-8, 1e8


def modal_normal_form(Dl: np.ndarray, Kl: np.ndarray, Bl: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """The normal form ``(Mr, Dr, Kr, Br)`` of the unit-mass fit ``q'' + Dl q' + Kl q = Bl u`` (module docstring),
    or None where the fit is not modally damped.

    Parameters
    ----------
    Dl, Kl : (r, r) ndarray
        Damping and stiffness of the unit-mass fit (not symmetric in general).
    Bl : (r, m) ndarray
        Its input matrix.

    Returns
    -------
    (Mr, Dr, Kr, Br) or None
        Symmetric PSD ``Mr, Dr, Kr`` (``Mr`` positive definite) and ``Br``.
    """
    modes = _real_modes(Kl)
    if modes is None:
        return None
    omega2, Phi = modes
    P = np.linalg.inv(Phi)
    d = _modal_damping(P @ Dl @ Phi)
    if d is None:
        return None
    Mr, Dr, Kr = (_symmetric((P.T * s) @ P) for s in (np.ones_like(d), d, omega2))
    return Mr, Dr, Kr, Mr @ Bl


def _real_modes(Kl: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``omega^2`` (ascending) and unit-length real eigenvectors of ``Kl``, or None where they are complex,
    negative, clustered or ill-conditioned (:data:`MODE_SEPARATION`, :data:`EIGENBASIS_CONDITION`)."""
    if not np.all(np.isfinite(Kl)):
        return None
    values, vectors = np.linalg.eig(Kl)   # real arrays where LAPACK found every eigenvalue real
    scale = float(np.max(np.abs(values))) if values.size else 0.0
    if np.iscomplexobj(values) or not scale > 0:
        return None
    order = np.argsort(values)
    omega2, Phi = values[order], vectors[:, order]
    if omega2[0] < -MODE_SEPARATION * scale:
        return None
    if omega2.size > 1 and np.min(np.diff(omega2)) <= MODE_SEPARATION * scale:
        return None
    Phi = Phi / np.linalg.norm(Phi, axis=0)
    if not np.linalg.cond(Phi) < EIGENBASIS_CONDITION:
        return None
    return np.clip(omega2, 0.0, None), Phi


def _modal_damping(Dm: np.ndarray) -> np.ndarray | None:
    """The diagonal of the modal damping ``Dm``, or None where it is negative or its off-diagonal share exceeds
    :data:`MODAL_DAMPING_SHARE`."""
    d = np.diag(Dm).copy()
    scale = float(np.max(np.abs(d))) if d.size else 0.0
    if np.any(d < -MODE_SEPARATION * scale):
        return None
    d = np.clip(d, 0.0, None)
    root = np.sqrt(d)
    off = np.abs(Dm - np.diag(np.diag(Dm)))
    bound = MODAL_DAMPING_SHARE * np.outer(root, root)
    return d if np.all(off <= bound) else None


def _symmetric(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + A.T)
