"""Reference models: the two constrained mass-spring-damper benchmarks of the paper.

The tool itself never needs these matrices; they exist to generate ground truth (the
reference simulator, the intrusive POD-Galerkin ROM in tests) and are assembled exactly as
``shared/spec/benchmarks.md`` states, as ``scipy.sparse`` matrices so that sizes up to a
million degrees of freedom fit in memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from ._validate import either
from .errors import DimensionError, FmuOpinfError

__all__ = ["SecondOrderSystem", "anchored_msd", "triple_chain", "builtin_system"]

ConstraintKind = Literal["position", "velocity"]


@dataclass(frozen=True)
class SecondOrderSystem:
    """A linear constrained second-order system (paper eq. 1).

    ``M x'' + D x' + K x + G^T lambda = B u`` with ``G x = 0`` (``constraint="position"``,
    index 3) or ``G x' = 0`` (``constraint="velocity"``, index 2), output ``y = Cp x + Cv x'``.
    pyMOR calls the damping matrix ``E``; here it is ``D`` as in the paper.

    Attributes
    ----------
    M, D, K : (n, n) sparse matrices
        Mass (SPD), damping (SPSD) and stiffness (SPD).
    G : (nc, n) sparse matrix
        Constraint Jacobian; ``nc = 0`` for an unconstrained system.
    constraint : {"position", "velocity"} or None
        Which derivative ``G`` acts on; None when ``nc = 0``.
    B : (n, m) sparse matrix
    Cp, Cv : (p, n) sparse matrices
    name : str
        Short identifier used in file provenance.
    """

    M: sp.csr_matrix
    D: sp.csr_matrix
    K: sp.csr_matrix
    G: sp.csr_matrix
    constraint: ConstraintKind | None
    B: sp.csr_matrix
    Cp: sp.csr_matrix
    Cv: sp.csr_matrix
    name: str = "system"

    def __post_init__(self) -> None:
        n = self.M.shape[0]
        for label in ("M", "D", "K"):
            if getattr(self, label).shape != (n, n):
                raise DimensionError(f"{label} has shape {getattr(self, label).shape}, expected ({n}, {n})")
        if self.G.shape[1] != n or self.B.shape[0] != n:
            raise DimensionError(f"G and B must have {n} columns/rows, got G {self.G.shape}, B {self.B.shape}")
        if self.Cp.shape != self.Cv.shape or self.Cp.shape[1] != n:
            raise DimensionError(f"Cp {self.Cp.shape} and Cv {self.Cv.shape} must both be (p, {n})")
        if (self.G.shape[0] > 0) != (self.constraint is not None):
            raise DimensionError("constraint kind must be given exactly when G has rows")

    @property
    def n(self) -> int:
        """Number of degrees of freedom."""
        return self.M.shape[0]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.Cp.shape[0]

    @property
    def nc(self) -> int:
        """Number of constraint rows."""
        return self.G.shape[0]

    def output(self, x: np.ndarray, xdot: np.ndarray) -> np.ndarray:
        """Outputs ``y = Cp x + Cv x'`` for states given as (n,) or (n, k) arrays."""
        return self.Cp @ x + self.Cv @ xdot

    def kernel_basis(self) -> np.ndarray:
        """Orthonormal basis N of ker G, (n, n - nc) dense; for tests on small systems only."""
        if self.nc == 0:
            return np.eye(self.n)
        return scipy.linalg.null_space(self.G.toarray())

    def hidden_manifold_ode(self) -> tuple["SecondOrderSystem", np.ndarray]:
        """The ODE on ker G (spec section 2 identity): ``N^T M N z'' + ... = N^T B u``, x = N z.

        Returns the unconstrained system in z-coordinates and the basis N (dense; small n only).
        """
        N = self.kernel_basis()
        proj = lambda A: sp.csr_matrix(N.T @ (A @ N))  # noqa: E731
        ode = SecondOrderSystem(
            M=proj(self.M), D=proj(self.D), K=proj(self.K),
            G=sp.csr_matrix((0, N.shape[1])), constraint=None,
            B=sp.csr_matrix(N.T @ self.B.toarray()),
            Cp=sp.csr_matrix(self.Cp @ N), Cv=sp.csr_matrix(self.Cv @ N),
            name=self.name + "-hidden-manifold",
        )
        return ode, N


def _chain_matrix(link: np.ndarray, ground: np.ndarray) -> sp.csr_matrix:
    """Tridiagonal matrix of masses in a row: links between neighbours plus ties to the ground.

    ``A_ii = link_{i-1} + ground_i + link_i`` (``link_0 = link_g = 0``), ``A_{i,i+1} = -link_i``.
    """
    padded = np.concatenate(([0.0], link, [0.0]))
    diagonal = padded[:-1] + ground + padded[1:]
    return sp.diags([-link, diagonal, -link], [-1, 0, 1], format="csr")


#: Vectors of length n that building and simulating a benchmark system holds at least (its sparse matrices,
#: their factors, the Newmark state): the measure of :func:`_check_size`.
_VECTORS_PER_DOF = 40


def _check_size(n: int, what: str, fix: str) -> None:
    """One line instead of a MemoryError where ``n`` degrees of freedom cannot fit (audit 55: g = 1e11, 745 GiB)."""
    from ._validate import check_memory

    check_memory(8.0 * _VECTORS_PER_DOF * n, what, fix)


def anchored_msd(g: int = 600, mass: float = 100.0, k1: float = 2.0, d1: float = 5.0,
                 k2: float = 2.0, d2: float = 5.0) -> SecondOrderSystem:
    """Anchored chain of ``g`` masses whose two ends are joined by a rigid bar (index 3).

    Mehrmann & Stykel (2005), spec section 1: masses ``mass``; neighbour springs/dampers
    ``k1, d1``; ground springs/dampers ``k2, d2`` doubled at both ends; ``G = e_1^T - e_g^T``
    acting on positions; force on mass 1; outputs the positions of masses 1, 2 and g-1.
    """
    if g < 4:
        raise DimensionError(f"the anchored chain needs g >= 4 masses, got g={g}")
    _check_size(g, f"the anchored chain with g={g}", f"give a smaller {either('--g')}")
    link_k = np.full(g - 1, k1)
    link_d = np.full(g - 1, d1)
    ground_k = np.full(g, k2)
    ground_d = np.full(g, d2)
    ground_k[[0, -1]] *= 2
    ground_d[[0, -1]] *= 2
    G = sp.csr_matrix(([1.0, -1.0], ([0, 0], [0, g - 1])), shape=(1, g))
    B = sp.csr_matrix(([1.0], ([0], [0])), shape=(g, 1))
    Cp = sp.csr_matrix((np.ones(3), ([0, 1, 2], [0, 1, g - 2])), shape=(3, g))
    return SecondOrderSystem(
        M=sp.diags(np.full(g, mass), format="csr"),
        D=_chain_matrix(link_d, ground_d),
        K=_chain_matrix(link_k, ground_k),
        G=G, constraint="position", B=B, Cp=Cp, Cv=sp.csr_matrix((3, g)),
        name=f"anchored-msd(g={g})",
    )


def _triple_chain_constraint(n1: int) -> sp.csr_matrix:
    """Truhar-Veselic pattern: each half chain's two ends move together (6 rows, +1/-1)."""
    half = n1 // 2
    pairs = []
    for c in range(3):
        pairs.append((c * n1, c * n1 + half - 1))
        pairs.append((c * n1 + half, (c + 1) * n1 - 1))
    rows = np.repeat(np.arange(len(pairs)), 2)
    cols = np.array(pairs).ravel()
    vals = np.tile([1.0, -1.0], len(pairs))
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(pairs), 3 * n1 + 1))


def triple_chain(n1: int = 100, alpha: float = 0.01, beta: float = 0.01, v: float = 5.0,
                 masses: tuple[float, float, float] = (1.0, 2.0, 3.0), m0: float = 10.0,
                 stiffness: tuple[float, float, float] = (10.0, 20.0, 1.0), k0: float = 50.0,
                 ) -> SecondOrderSystem:
    """Triple chain with a velocity constraint (index 2), n = 3 n1 + 1; spec section 2.

    Truhar & Veselic (2009), Example 2: three chains of ``n1`` masses tied to a wall at their
    first mass and to a common mass ``m0`` at their last; ``D = alpha M + beta K + v (e_1 e_1^T
    + e_{n1} e_{n1}^T + e_{2n1+1} e_{2n1+1}^T)``; velocity constraint tying the two ends of each
    half chain; force on every mass; output the sum of all positions.
    """
    if n1 < 2 or n1 % 2:
        raise DimensionError(f"the triple chain needs an even n1 >= 2, got n1={n1}")
    _check_size(3 * n1 + 1, f"the triple chain with n1={n1}", f"give a smaller {either('--n1')}")
    n = 3 * n1 + 1
    mass = np.concatenate([np.full(n1, mc) for mc in masses] + [np.array([m0])])
    block = sp.diags([-np.ones(n1 - 1), 2 * np.ones(n1), -np.ones(n1 - 1)], [-1, 0, 1])
    K = sp.block_diag([kc * block for kc in stiffness] + [sp.csr_matrix([[0.0]])], format="lil")
    for c, kc in enumerate(stiffness):
        last = (c + 1) * n1 - 1
        K[last, n - 1] = -kc
        K[n - 1, last] = -kc
    K[n - 1, n - 1] = sum(stiffness) + k0
    K = K.tocsr()
    M = sp.diags(mass, format="csr")
    dampers = np.zeros(n)
    dampers[[0, n1 - 1, 2 * n1]] = v
    D = (alpha * M + beta * K + sp.diags(dampers)).tocsr()
    return SecondOrderSystem(
        M=M, D=D, K=K, G=_triple_chain_constraint(n1), constraint="velocity",
        B=sp.csr_matrix(np.ones((n, 1))), Cp=sp.csr_matrix(np.ones((1, n))),
        Cv=sp.csr_matrix((1, n)), name=f"triple-chain(n1={n1})",
    )


def builtin_system(name: str, **size_options: float) -> SecondOrderSystem:
    """Benchmark system by name: ``"anchored-msd"`` (option ``g``) or ``"triple-chain"`` (``n1``, ...)."""
    factories = {"anchored-msd": anchored_msd, "triple-chain": triple_chain}
    if name not in factories:
        raise FmuOpinfError(f"unknown builtin model {name!r}; choose one of {', '.join(factories)}")
    return factories[name](**size_options)
