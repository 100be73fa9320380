"""FMUs of linear mechanical systems that behave like real third-party exports, and their exact
solution.

The benchmark FMUs of :mod:`fmu_opinf.fmus` are co-simulation-only Newmark FMUs with variables
named ``x[i], v[i], a[i]``: the easy case.  FMUs exported by Modelica tools, by generic LTI FMU
generators or written in the style of the FMI 3.0 reference FMUs follow other conventions
(``docs/../shared/spec/real-fmus.md``), and this module mimics them on demand, so that the
snapshot stage can be tested against FMUs whose exact behaviour is known:

* model exchange (FMI 2.0 and 3.0) next to, or instead of, co-simulation; co-simulation either
  one explicit Euler step per communication step (``cs_method="euler"``, inaccurate like several
  exporters), RK4 substeps whose size follows the tolerance given to ``fmi2SetupExperiment`` /
  ``fmi3EnterInitializationMode`` (``"accurate"``) or one RK4 step per communication step (``"rk4"``,
  accurate at small steps but unstable above ``2.8 / omega_max``, like fixed-substep exports);
* Modelica naming: states ``mass[i].s``, ``mass[i].v``, separate ``der(mass[i].s)`` (an alias of
  ``mass[i].v`` in FMI 2.0) and ``der(mass[i].v)`` with ``derivative`` attributes, ``mass[i].a``
  as an alias of ``der(mass[i].v)``; relative coordinates ``spring[i].s_rel``; an index-reduced
  constrained system whose dependent positions are computed locals;
* generic LTI-generator naming: states ``x1 .. xN`` (positions then velocities), derivatives
  ``der_x1 ..`` and start parameters ``x1_start ..``;
* FMI 3.0 array states ``x``, ``v`` whose size is a structural parameter ``n`` settable only in
  configuration mode (:class:`MassChain` family);
* physical parameters exposed with causality input (``mass_scale = 0`` makes the FMU fail with a
  division by zero), no inputs at all, outputs with direct feedthrough (acceleration sensors),
  a static equilibrium away from zero (constant force ``f0``) and start values off rest;
* a ``DefaultExperiment`` with ``stopTime="1"`` and no step size; SI units, optionally on the
  outputs too and on Modelica type definitions (``declaredType``);
* on request: force sensor outputs ``y = u``, FMI 3 output and input arrays, ``<Alias>`` names of
  outputs, states sorted body by body (``interleaved``, also the FMI state vector), no structural
  dependencies, derivatives one step stale after ``doStep`` (``stale_derivatives``), outputs one
  communication step late (``late_outputs``), a start at the static equilibrium under the inputs set in
  initialization mode (``steady_state_start``, Modelica's ``initial equation der(x) = 0``);
* on request, discrete events as Modelica models with ``when`` clauses have them: a force that
  switches on at a time event (:class:`TimeEvent`, announced as the next event time) and one that
  latches on when a position crosses a threshold (:class:`StateEvent`, one event indicator).

The system is ``M x'' + D x' + K x = B u + f0`` with outputs ``y = Cp x + Cv x' + Ca x'' + y0``
(:class:`LinearMechanicalModel`).  The FMU integrates it in the coordinates an exporter would
choose, ``x = T q + x_off`` (identity, relative coordinates, or the independent positions of a
constrained system), as the first-order ODE of ``z = (q, q')``; mass and stiffness scales
(parameters ``mass_scale``, ``stiffness_scale``, default 1) multiply ``M`` and ``K``.

:func:`zoh_response` is the independent reference: the exact solution under zero-order-hold
inputs from the matrix exponential of the first-order system.  :func:`build_corpus` builds one
FMU per convention with its model (:data:`CORPUS_NAMES`).
"""

from __future__ import annotations

import math
import os
import re
import uuid
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, Sequence
from xml.sax.saxutils import quoteattr

import numpy as np
import scipy.linalg

from .errors import DimensionError
from .fmus import (
    FmuBuildError,
    _c_sources_dir,
    _fmi_header_dir,
    find_build_tools,
    stamp_guid,
    write_fmu,
)

__all__ = [
    "LinearMechanicalModel",
    "MassChain",
    "TimeEvent",
    "StateEvent",
    "ZohResponse",
    "LtiFmu",
    "build_lti_fmu",
    "zoh_response",
    "build_corpus",
    "corpus_models",
    "chain_model",
    "support_chain_model",
    "CORPUS_NAMES",
    "find_build_tools",
    "FmuBuildError",
]

Naming = Literal["modelica", "generic", "array"]
CsMethod = Literal["accurate", "euler", "rk4"]

#: scalar physical parameters every FMU has (default 1): M -> mass_scale M, K -> stiffness_scale K
SCALE_PARAMETERS = ("mass_scale", "stiffness_scale")
_SOURCE_FOLDER = "LinearStateSpace"
_KERNEL_SOURCES = ("lti.c",)
_API_SOURCES = {"2.0": "lti_fmi2.c", "3.0": "lti_fmi3.c"}
_FMI_HEADERS = {
    "2.0": ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    "3.0": ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}
_GUID_PLACEHOLDER = "@GUID@"
_INDICATOR = "eventIndicator"   # FMI 3 variable of the state event's indicator
_GUID_NAMESPACE = uuid.UUID("0b7d6c1e-3f51-4f4e-a2f4-7c9d7e5b2a61")
_SLOT_KINDS = ("SlotTime", "SlotQ", "SlotQd", "SlotQdd", "SlotX", "SlotV", "SlotA", "SlotY",
               "SlotU", "SlotPar", "SlotQStart", "SlotQdStart", "SlotSize", "SlotIndicator")


def _matrix(value, rows: int, cols: int, what: str) -> np.ndarray:
    if value is None:
        return np.zeros((rows, cols))
    array = np.array(value, dtype=float)
    if array.ndim == 1 and rows == 1:
        array = array.reshape(1, -1)
    if array.shape != (rows, cols):
        raise DimensionError(f"{what} has shape {array.shape}, expected ({rows}, {cols}); "
                             "give a matrix of that shape")
    if not np.all(np.isfinite(array)):
        raise DimensionError(f"{what} contains NaN or Inf; give finite values")
    return array


def _vector(value, size: int, what: str) -> np.ndarray:
    array = np.zeros(size) if value is None else np.array(value, dtype=float).reshape(-1)
    if array.shape != (size,):
        raise DimensionError(f"{what} has {array.size} entries, expected {size}; give one per "
                             "row")
    if not np.all(np.isfinite(array)):
        raise DimensionError(f"{what} contains NaN or Inf; give finite values")
    return array


# ------------------------------------------------------------------------- the model

@dataclass
class LinearMechanicalModel:
    """A linear mechanical system ``M x'' + D x' + K x = B u + f0`` with outputs
    ``y = Cp x + Cv x' + Ca x'' + y0``, started at ``x(t0) = x0, x'(t0) = v0``.

    Parameters
    ----------
    M, D, K : array_like (n, n)
        Symmetric mass (positive definite on the constraint manifold), damping and stiffness.
    B : array_like (n, m), optional
        Input matrix of the force inputs; default none (m = 0: free response).
    f0 : array_like (n,), optional
        Constant force (gravity, pre-stressed springs): the static equilibrium under zero input
        solves ``K x_eq = f0``.  Default zero.
    Cp, Cv, Ca : array_like (p, n), optional
        Position, velocity and acceleration sensors; at least one row in total.  ``Ca`` gives
        the outputs a direct feedthrough from the inputs (:attr:`feedthrough`).
    y0 : array_like (p,), optional
        Output offset.
    x0, v0 : array_like (n,), optional
        Start positions and velocities (default zero); must satisfy the constraint.
    G : array_like (nc, n), optional
        Constraint matrix.
    constraint : {None, "position", "velocity"}
        ``"position"``: ``G x = 0`` (so ``G x0 = 0`` and ``G v0 = 0``); ``"velocity"``:
        ``G x' = 0`` (so ``G x = G x0`` stays constant).  An exporter reduces the index: the FMU
        integrates the ODE of the independent positions and computes the others.
    name : str
        Model name; the default model identifier of its FMU.
    ideal_sources : int, default=0
        The last ``ideal_sources`` coordinates are ideal motion sources (Modelica
        ``Translational.Sources.Position/Speed/Accelerate``, a shaker table): their rows are the source's own
        filter and do not feel the structure, so ``D`` and ``K`` are symmetric only on the leading block and the
        source rows have zeros in the structure's columns (:func:`support_chain_model`).
    """

    M: np.ndarray
    D: np.ndarray
    K: np.ndarray
    B: np.ndarray | None = None
    f0: np.ndarray | None = None
    Cp: np.ndarray | None = None
    Cv: np.ndarray | None = None
    Ca: np.ndarray | None = None
    y0: np.ndarray | None = None
    x0: np.ndarray | None = None
    v0: np.ndarray | None = None
    G: np.ndarray | None = None
    constraint: str | None = None
    name: str = "LinearMechanics"
    ideal_sources: int = 0

    def __post_init__(self) -> None:
        n = np.asarray(self.M).shape[0]
        self.M = _matrix(self.M, n, n, "M")
        self.D = _matrix(self.D, n, n, "D")
        self.K = _matrix(self.K, n, n, "K")
        if self.B is None:
            self.B = np.zeros((n, 0))
        self.B = np.array(self.B, dtype=float)
        if self.B.ndim == 1:
            self.B = self.B.reshape(n, 1)
        self.B = _matrix(self.B, n, self.B.shape[-1], "B")
        self.f0 = _vector(self.f0, n, "f0")
        p = max(0 if c is None else np.atleast_2d(c).shape[0] for c in (self.Cp, self.Cv, self.Ca))
        if p == 0:
            raise DimensionError("the model has no output; give at least one row of Cp, Cv or Ca")
        self.Cp = _matrix(self.Cp, p, n, "Cp")
        self.Cv = _matrix(self.Cv, p, n, "Cv")
        self.Ca = _matrix(self.Ca, p, n, "Ca")
        self.y0 = _vector(self.y0, p, "y0")
        self.x0 = _vector(self.x0, n, "x0")
        self.v0 = _vector(self.v0, n, "v0")
        self._check_symmetry(n)
        self._check_constraint()
        if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", self.name):
            raise FmuBuildError(f"model name {self.name!r} is not a C identifier; use letters, "
                                "digits and underscores")
        reduced_mass = self.state_map()[0].T @ self.M @ self.state_map()[0]
        if np.linalg.eigvalsh(reduced_mass).min() <= 0:
            raise DimensionError("M is not positive definite on the constraint manifold; give a "
                                 "positive definite mass matrix")

    def _check_symmetry(self, n: int) -> None:
        """M symmetric; D and K symmetric on the structure's block, the ideal sources' rows free of it."""
        if not 0 <= self.ideal_sources <= n:
            raise DimensionError(f"ideal_sources={self.ideal_sources} is not between 0 and n={n}; give the number of "
                                 "trailing source coordinates")
        s = n - self.ideal_sources
        for label, matrix in (("M", self.M), ("D", self.D[:s, :s]), ("K", self.K[:s, :s])):
            if not np.allclose(matrix, matrix.T, rtol=1e-12, atol=1e-14 * np.abs(matrix).max(initial=0.0)):
                raise DimensionError(f"{label} is not symmetric; give a symmetric matrix")
        if np.any(self.D[s:, :s]) or np.any(self.K[s:, :s]) or np.any(self.M[s:, :s]):
            raise DimensionError("an ideal source's row depends on the structure; give zeros in the structure's "
                                 "columns of the source rows (an ideal source does not feel its load)")

    def _check_constraint(self) -> None:
        if (self.G is None) != (self.constraint is None):
            raise FmuBuildError("G and constraint go together; give both (constraint "
                                "'position' or 'velocity') or neither")
        if self.G is None:
            return
        if self.constraint not in ("position", "velocity"):
            raise FmuBuildError(f"constraint {self.constraint!r} is unknown; use 'position' or "
                                "'velocity'")
        self.G = _matrix(self.G, np.atleast_2d(self.G).shape[0], self.n, "G")
        if np.linalg.matrix_rank(self.G) != self.G.shape[0]:
            raise DimensionError("G does not have full row rank; remove dependent constraint rows")
        scale = np.abs(self.G).max()
        if np.abs(self.G @ self.v0).max() > 1e-12 * scale * (1 + np.abs(self.v0).max()):
            raise DimensionError("the start velocity v0 violates the constraint G v0 = 0; give "
                                 "a consistent v0")
        if (self.constraint == "position"
                and np.abs(self.G @ self.x0).max() > 1e-12 * scale * (1 + np.abs(self.x0).max())):
            raise DimensionError("the start position x0 violates the constraint G x0 = 0; give "
                                 "a consistent x0")

    @property
    def n(self) -> int:
        """Number of degrees of freedom."""
        return self.M.shape[0]

    @property
    def m(self) -> int:
        """Number of force inputs (0: free response)."""
        return self.B.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.Cp.shape[0]

    @property
    def nc(self) -> int:
        """Number of constraint rows."""
        return 0 if self.G is None else self.G.shape[0]

    def independent_dofs(self) -> np.ndarray:
        """Degrees of freedom an index-reducing exporter keeps as states (all if unconstrained).

        The dependent ones are the pivots of a column-pivoted QR factorization of ``G`` (the
        best-conditioned block to solve for), as a dummy-derivative method would pick.
        """
        if self.G is None:
            return np.arange(self.n)
        _, _, pivots = scipy.linalg.qr(self.G, pivoting=True, mode="economic")
        return np.sort(pivots[self.nc:])

    def state_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(T, x_off)`` with ``x = T q + x_off`` for the independent positions ``q``.

        ``T`` selects the independent degrees of freedom and expresses the dependent ones
        through ``G (T q + x_off) = G x0``; ``x_off`` is zero except for velocity constraints
        with ``G x0 != 0``.
        """
        if self.G is None:
            return np.eye(self.n), np.zeros(self.n)
        keep = self.independent_dofs()
        drop = np.setdiff1d(np.arange(self.n), keep)
        T = np.zeros((self.n, keep.size))
        T[keep, np.arange(keep.size)] = 1.0
        T[drop] = -np.linalg.solve(self.G[:, drop], self.G[:, keep])
        offset = np.zeros(self.n)
        offset[drop] = np.linalg.solve(self.G[:, drop], self.G @ self.x0)
        return T, offset

    def null_space(self) -> np.ndarray:
        """Orthonormal basis ``N`` of the admissible velocities (``ker G``; identity if free)."""
        return np.eye(self.n) if self.G is None else scipy.linalg.null_space(self.G)

    @property
    def feedthrough(self) -> np.ndarray:
        """``Du`` (p, m): the direct feedthrough ``Ca a`` gives the outputs from the inputs."""
        N = self.null_space()
        return self.Ca @ N @ np.linalg.solve(N.T @ self.M @ N, N.T @ self.B)

    def equilibrium(self) -> np.ndarray:
        """Static equilibrium under zero input (n,), on the constraint manifold through ``x0``."""
        N = self.null_space()
        base = self.x0 - N @ (N.T @ self.x0)
        return base + N @ np.linalg.solve(N.T @ self.K @ N, N.T @ (self.f0 - self.K @ base))

    def scaled(self, mass_scale: float = 1.0, stiffness_scale: float = 1.0
               ) -> "LinearMechanicalModel":
        """The model with ``M`` and ``K`` multiplied by the FMU parameters of those names."""
        return replace(self, M=mass_scale * self.M, K=stiffness_scale * self.K)


@dataclass
class MassChain:
    """A family of fixed-free chains of ``n`` equal masses, the size being free.

    Mass 1 hangs on a spring and damper to the wall, mass ``i`` on one to mass ``i-1``; every
    mass carries the constant force ``force_offset`` (weight), an optional force input acts on
    the last mass.  Outputs: position of the last mass, velocity of the first, and (with
    ``acceleration_sensor``) acceleration of the last.  This is the model of the FMI 3.0 array
    FMUs whose size ``n`` is a structural parameter; :meth:`model` gives one member.

    Parameters
    ----------
    n : int, default=5
        Default number of masses.
    n_max : int, default=64
        Largest size the FMU accepts (memory is allocated for it at instantiation).
    mass, stiffness, damping : float
        Mass of each body, stiffness and damping of each spring-damper (kg, N/m, N s/m).
    force_offset : float, default=0
        Constant force on each mass (N).
    start_position, start_velocity : float, default=0
        Start value of every position and velocity.
    forced : bool, default=True
        Whether the last mass has a force input (else m = 0).
    acceleration_sensor : bool, default=False
        Add the acceleration of the last mass as third output (direct feedthrough).
    name : str, default="MassChain"
        Model name.
    """

    n: int = 5
    n_max: int = 64
    mass: float = 1.0
    stiffness: float = 25.0
    damping: float = 1.0
    force_offset: float = 0.0
    start_position: float = 0.0
    start_velocity: float = 0.0
    forced: bool = True
    acceleration_sensor: bool = False
    name: str = "MassChain"

    def __post_init__(self) -> None:
        if int(self.n) != self.n or not 1 <= self.n <= self.n_max:
            raise FmuBuildError(f"chain size n={self.n} is invalid; use an integer in "
                                f"[1, n_max={self.n_max}]")
        if self.mass <= 0 or self.stiffness <= 0 or self.damping < 0:
            raise FmuBuildError("mass and stiffness must be positive and damping non-negative; "
                                "fix the MassChain parameters")

    def model(self, n: int | None = None) -> LinearMechanicalModel:
        """The chain of ``n`` masses (default :attr:`n`) as a :class:`LinearMechanicalModel`."""
        n = self.n if n is None else int(n)
        if not 1 <= n <= self.n_max:
            raise FmuBuildError(f"chain size n={n} is outside [1, {self.n_max}]; choose a size "
                                "in that range")
        pattern = np.diag(np.r_[2.0 * np.ones(n - 1), 1.0]) if n > 1 else np.eye(1)
        if n > 1:
            pattern -= np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)
        last = np.zeros(n)
        last[-1] = 1.0
        first = np.zeros(n)
        first[0] = 1.0
        Cp = np.vstack([last, 0 * last])
        Cv = np.vstack([0 * last, first])
        Ca = np.zeros((2, n))
        if self.acceleration_sensor:
            Cp, Cv, Ca = (np.vstack([C, 0 * last]) for C in (Cp, Cv, Ca))
            Ca[2] = last
        return LinearMechanicalModel(
            M=self.mass * np.eye(n), D=self.damping * pattern, K=self.stiffness * pattern,
            B=last.reshape(n, 1) if self.forced else None, f0=self.force_offset * np.ones(n),
            Cp=Cp, Cv=Cv, Ca=Ca, x0=self.start_position * np.ones(n),
            v0=self.start_velocity * np.ones(n), name=self.name)


@dataclass(frozen=True)
class TimeEvent:
    """A constant force that switches on at a time event (a Modelica ``when time >= time``).

    The FMU announces ``time`` as its next event time and adds ``force`` only in the event
    iteration there: derivatives evaluated before the event, even at later times, use the old
    force, so an importer that ignores the announcement records the model without it.

    Parameters
    ----------
    time : float
        Event time (s).
    force : array_like (n,)
        Force added to ``f0`` from the event on (N), one value per degree of freedom.
    velocity_jump : array_like (n,), optional
        Added to the velocities in the event iteration (a Modelica ``reinit``): the continuous states
        change at the event, and the FMU says so (``valuesOfContinuousStatesChanged``).
    """

    time: float
    force: Sequence[float]
    velocity_jump: Sequence[float] | None = None


@dataclass(frozen=True)
class StateEvent:
    """A constant force latched on when a position crosses a threshold (a state event).

    The FMU has one event indicator, ``x[dof] + input_gain u[0] - threshold``; the first change of its sign
    (FMI's convention: from ``> 0`` to ``<= 0`` or back) seen in an event iteration latches
    ``force`` on for good.  Later crossings are events that change nothing.

    Parameters
    ----------
    dof : int
        Degree of freedom (0-based) whose position is watched.
    threshold : float
        Position (m) whose crossing is the event.
    force : array_like (n,)
        Force added to ``f0`` from the event on (N).
    input_gain : float, default=0
        The indicator is ``x[dof] + input_gain * u[0] - threshold``: with a gain, the input set at a communication
        point can move it across zero there.
    """

    dof: int
    threshold: float
    force: Sequence[float]
    input_gain: float = 0.0


# ------------------------------------------------------------- exact reference solution

@dataclass
class ZohResponse:
    """Exact response on a time grid: each array has one column per time point.

    Attributes
    ----------
    t : ndarray (N,)
    x, v, a : ndarray (n, N)
        Positions, velocities, accelerations.
    y : ndarray (p, N)
        Outputs.
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    y: np.ndarray


def _first_order(model: LinearMechanicalModel) -> tuple[np.ndarray, ...]:
    """``(N, base, A, Bz, c)``: ``x = base + N q``, ``z = (q, q')``, ``z' = A z + Bz u + c``."""
    N = model.null_space()
    base = model.x0 - N @ (N.T @ model.x0)
    r = N.shape[1]
    Mr = N.T @ model.M @ N
    Kr = np.linalg.solve(Mr, N.T @ model.K @ N)
    Dr = np.linalg.solve(Mr, N.T @ model.D @ N)
    A = np.block([[np.zeros((r, r)), np.eye(r)], [-Kr, -Dr]])
    Bz = np.vstack([np.zeros((r, model.m)), np.linalg.solve(Mr, N.T @ model.B)])
    c = np.r_[np.zeros(r), np.linalg.solve(Mr, N.T @ (model.f0 - model.K @ base))]
    return N, base, A, Bz, c


def _step_maps(A: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(exp(A h), int_0^h exp(A s) ds)`` from one exponential of ``[[A, I], [0, 0]]``."""
    size = A.shape[0]
    block = np.zeros((2 * size, 2 * size))
    block[:size, :size] = A * h
    block[:size, size:] = np.eye(size) * h
    E = scipy.linalg.expm(block)
    return E[:size, :size], E[:size, size:]


def _held_columns(m: int, count: int, u_held) -> np.ndarray:
    """Held inputs as an (m, count) array; an (m, count-1) array gets its last column repeated."""
    if u_held is None:
        return np.zeros((m, count))
    u = np.array(u_held, dtype=float)
    if u.ndim == 1 and m > 0:
        u = u.reshape(m, -1)
    if u.ndim != 2 or u.shape[0] != m or u.shape[1] not in (count, count - 1) or u.shape[1] == 0:
        raise DimensionError(f"u_held has shape {u.shape}, expected ({m}, {count}) or "
                             f"({m}, {count - 1}); give one column per step")
    if u.shape[1] == count - 1:
        u = np.hstack([u, u[:, -1:]])
    return u


def zoh_response(model: LinearMechanicalModel, t: Sequence[float], u_held=None, *,
                 accelerations_from: Literal["previous", "current"] = "previous",
                 mass_scale: float = 1.0, stiffness_scale: float = 1.0) -> ZohResponse:
    """Exact response under zero-order-hold inputs (matrix exponential, Van Loan).

    The state starts at ``(model.x0, model.v0)`` at ``t[0]``; over ``[t_i, t_{i+1}]`` the
    input is ``u_held[:, i]``, held constant (the convention of an importer that sets the
    inputs at ``t_i`` and then calls ``doStep`` or integrates to ``t_{i+1}``).  Each step is
    ``z_{i+1} = exp(A h) z_i + (int_0^h exp(A s) ds) (Bz u_i + c)``, exact up to round-off, for
    the first-order system of the minimal coordinates (orthonormal basis of ``ker G``, not the
    FMU's coordinates, so the reference stays independent of the builder).

    Parameters
    ----------
    model : LinearMechanicalModel
        The system.
    t : sequence of float (N,)
        Increasing time points (any spacing).
    u_held : array_like (m, N) or (m, N-1), optional
        Held inputs; column ``i`` acts on ``[t_i, t_{i+1}]`` (the last column of an (m, N)
        array only enters the accelerations with ``accelerations_from="current"``).  Default
        zero; may be omitted when m = 0.
    accelerations_from : {"previous", "current"}, default="previous"
        Input that pairs with ``a[:, i]`` and ``y[:, i]``: ``"previous"`` is the input held
        over the step that ends at ``t_i`` (``u_held[:, i-1]``; ``u_held[:, 0]`` at ``t_0``),
        i.e. the project's column convention (docs/design.md: ``u[:, 0] = u(t_0)``,
        ``u[:, i] = u(t_{i-1})``) and what a co-simulation FMU reports after ``doStep``;
        ``"current"`` uses ``u_held[:, i]``, what a model-exchange FMU reports at ``t_i``
        after the importer has set the new input.
    mass_scale, stiffness_scale : float, default=1
        Values of the FMU parameters of these names (``M`` and ``K`` are scaled).

    Returns
    -------
    ZohResponse
        ``t``, ``x``, ``v``, ``a`` (n, N) and ``y`` (p, N).
    """
    if accelerations_from not in ("previous", "current"):
        raise DimensionError(f"accelerations_from={accelerations_from!r} is unknown; use "
                             "'previous' or 'current'")
    model = model.scaled(mass_scale, stiffness_scale)
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.size < 1 or np.any(np.diff(t) <= 0):
        raise DimensionError("t must hold increasing time points; give a strictly increasing "
                             "grid")
    u = _held_columns(model.m, t.size, u_held)
    N, base, A, Bz, c = _first_order(model)
    r = N.shape[1]
    z = np.zeros((2 * r, t.size))
    z[:r, 0] = N.T @ (model.x0 - base)
    z[r:, 0] = N.T @ model.v0
    maps: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    for i, h in enumerate(np.diff(t)):
        key = float(np.round(h, 14))
        if key not in maps:
            maps[key] = _step_maps(A, h)
        Phi, Gamma = maps[key]
        z[:, i + 1] = Phi @ z[:, i] + Gamma @ (Bz @ u[:, i] + c)
    paired = u if accelerations_from == "current" else np.hstack([u[:, :1], u[:, :-1]])
    zdot = A @ z + Bz @ paired + c[:, None]
    x = base[:, None] + N @ z[:r]
    v = N @ z[r:]
    a = N @ zdot[r:]
    y = model.Cp @ x + model.Cv @ v + model.Ca @ a + model.y0[:, None]
    return ZohResponse(t=t, x=x, v=v, a=a, y=y)


# ------------------------------------------------------------- exporter coordinates

@dataclass
class _Coordinates:
    """The exporter's ODE ``q'' = (-s_k Kq q - Dq q' + Bq u + fq) / s_m``, ``x = T q + xoff``."""

    T: np.ndarray
    xoff: np.ndarray
    Kq: np.ndarray
    Dq: np.ndarray
    Bq: np.ndarray
    fq: np.ndarray
    q0: np.ndarray
    qd0: np.ndarray
    state_dofs: np.ndarray | None   # physical dof of each q (None for relative coordinates)


def _coordinates(model: LinearMechanicalModel, relative: bool) -> _Coordinates:
    if relative:
        if model.G is not None:
            raise FmuBuildError("relative coordinates of a constrained model are not supported; "
                                "use relative=False")
        difference = np.eye(model.n) - np.eye(model.n, k=-1)
        T, xoff = np.tril(np.ones((model.n, model.n))), np.zeros(model.n)
        q0, qd0, dofs = difference @ model.x0, difference @ model.v0, None
    else:
        T, xoff = model.state_map()
        dofs = model.independent_dofs()
        q0, qd0 = model.x0[dofs], model.v0[dofs]
    Mq = T.T @ model.M @ T
    return _Coordinates(
        T=T, xoff=xoff, Kq=np.linalg.solve(Mq, T.T @ model.K @ T),
        Dq=np.linalg.solve(Mq, T.T @ model.D @ T), Bq=np.linalg.solve(Mq, T.T @ model.B),
        fq=np.linalg.solve(Mq, T.T @ (model.f0 - model.K @ xoff)), q0=q0, qd0=qd0,
        state_dofs=dofs)


# ------------------------------------------------------------------ variables

@dataclass
class _Var:
    name: str
    vr: int
    causality: str = "local"
    variability: str = "continuous"
    initial: str | None = None
    start: list[float] | None = None
    unit: str | None = None
    description: str = ""
    derivative_of: str | None = None
    dimension: int | str | None = None     # fixed length, or the name of a structural parameter
    type: str = "Float64"
    minimum: int | None = None
    maximum: int | None = None
    aliases: list[str] = field(default_factory=list)   # FMI 3 <Alias> children
    dependencies: list[str] | None = None
    enumeration: str | None = None   # an Enumeration's declaredType


@dataclass
class _Layout:
    """Model variables, the C slot table (indexed by value reference) and the state order."""

    fmi3: bool
    units: bool
    variables: list[_Var] = field(default_factory=list)
    slots: list[tuple[str, int, int, int]] = field(default_factory=list)
    states: list[str] = field(default_factory=list)        # state variables in z order
    derivatives: list[str] = field(default_factory=list)   # their derivative variables
    interleaved: bool = False   # z order (q1, qd1, q2, qd2, ...) instead of (q, qd)

    def __post_init__(self) -> None:
        self.slots.append(("SlotTime", 0, 0, 0))
        if self.fmi3:
            self.variables.append(_Var("time", 0, "independent", initial=None,
                                       unit="s" if self.units else None,
                                       description="simulation time"))

    def add(self, name: str, kind: str, index: int = 0, *, array: bool = False,
            tunable: bool | int = False, **attributes) -> _Var:
        if not self.units:
            attributes.pop("unit", None)
        var = _Var(name, len(self.slots), **attributes)
        self.slots.append((kind, index, int(array), int(tunable)))
        self.variables.append(var)
        return var

    def alias(self, name: str, of: _Var, description: str = "", **attributes) -> _Var | None:
        """Same value reference: a variable of its own in FMI 2, an ``<Alias>`` in FMI 3."""
        if self.fmi3:
            of.aliases.append(name)
            return None
        if not self.units:
            attributes.pop("unit", None)
        var = _Var(name, of.vr, causality=of.causality, variability=of.variability,
                   unit=of.unit, description=description, **attributes)
        self.variables.append(var)
        return var

    def find(self, name: str) -> _Var:
        return next(v for v in self.variables if v.name == name)


@dataclass
class LtiFmu:
    """A built FMU and what it exposes.

    Attributes
    ----------
    path : Path
        The ``.fmu`` file.
    model : LinearMechanicalModel
        The system it simulates (default parameters and size); its exact response is
        :func:`zoh_response` ``(model, ...)``.
    fmi_version : str
    interfaces : tuple of str
        ``"me"`` and/or ``"cs"``.
    cs_method : str
        ``"euler"``, ``"accurate"`` (RK4 substeps following the tolerance) or ``"rk4"`` (one RK4 step).
    naming : str
    states, derivatives : list of str
        Continuous state variables in state-vector order and their derivative variables
        (FMI 3 arrays: one name each for ``x`` and ``v``; empty if not exposed).
    positions, velocities, accelerations : list of str
        Variables holding ``x_i, v_i, a_i`` of each degree of freedom (``[]`` where a naming
        does not expose them; arrays: the array name).
    inputs : list of str
        Force inputs (columns of ``B``).
    parameter_inputs : list of str
        Parameters exposed with causality input (``mass_scale``, ``stiffness_scale``).
    outputs : list of str
        Outputs (rows of ``Cp``).
    start_parameters : list of str
        Parameters setting the start state (generic naming ``x1_start ..``, arrays).
    structural_parameter : str or None
        Name of the structural size (``"n"``) of array FMUs built from a :class:`MassChain`.
    guid : str
        GUID / instantiation token.
    time_event, state_event : TimeEvent or StateEvent or None
        The events the FMU was built with (:func:`build_lti_fmu`).
    """

    path: Path
    model: LinearMechanicalModel
    fmi_version: str
    interfaces: tuple[str, ...]
    cs_method: str
    naming: str
    states: list[str]
    derivatives: list[str]
    positions: list[str]
    velocities: list[str]
    accelerations: list[str]
    inputs: list[str]
    parameter_inputs: list[str]
    outputs: list[str]
    start_parameters: list[str]
    structural_parameter: str | None
    guid: str
    time_event: TimeEvent | None = None
    state_event: StateEvent | None = None


@dataclass
class _Options:
    fmi_version: str
    interfaces: tuple[str, ...]
    cs_method: str
    naming: str
    relative: bool
    parameter_inputs: tuple[str, ...]
    expose_accelerations: bool
    units: bool
    identifier: str
    description: str
    stop_time: float
    output_units: bool = False
    declared_types: bool = False
    input_sensors: bool = False
    output_array: bool = False
    output_aliases: bool = False
    input_array: bool = False
    interleaved: bool = False
    dependencies: bool = True
    stale_derivatives: bool = False
    late_outputs: bool = False
    steady_state_start: bool = False
    time_event: TimeEvent | None = None
    state_event: StateEvent | None = None
    completed_step_gap: float | None = None
    completed_step_event_at: float | None = None
    completed_step_event_every: bool = False
    discrete_inputs: tuple[int, ...] = ()
    cs_fixed_step: float | None = None
    cs_fixed_step_enforced: bool = True
    cs_max_step: float | None = None
    cs_early_return_at: float | None = None
    cs_terminate_at: float | None = None
    me_terminate_at: float | None = None
    completed_step_terminate_at: float | None = None
    position_limit: tuple[int, float] | None = None
    position_limit_status: str = "error"
    single_precision: bool | str = False
    enable_input: bool = False
    strict_stop_time: bool = False
    discrete_parameters: bool = False
    typed_parameters: bool = False

    @property
    def needs_completed_steps(self) -> bool:
        return (self.completed_step_gap is not None or self.completed_step_event_at is not None
                or self.completed_step_terminate_at is not None)


#: ``LTI_CS_METHOD`` of the C kernel for each ``cs_method``.
_CS_METHODS = {"euler": "CsEuler", "accurate": "CsRungeKutta", "rk4": "CsOneRungeKutta"}

#: ``LTI_SINGLE_PRECISION`` of the C kernel for each value of ``single_precision``.
_SINGLE_PRECISION_CODES = {False: 0, True: 1, "partial": 2}

#: ``LTI_POSITION_LIMIT`` of the C kernel for each ``position_limit_status`` (0: no limit).
_POSITION_LIMIT_CODES = {"error": 1, "discard": 2}


def _check_options(model, options: _Options) -> None:
    if options.fmi_version not in _API_SOURCES:
        raise FmuBuildError(f"fmi_version {options.fmi_version!r} is not supported; use '2.0' "
                            "or '3.0'")
    if not options.interfaces or set(options.interfaces) - {"me", "cs"}:
        raise FmuBuildError(f"interfaces {options.interfaces!r} are invalid; give a non-empty "
                            "subset of ('me', 'cs')")
    if options.single_precision not in _SINGLE_PRECISION_CODES:
        raise FmuBuildError(f"single_precision {options.single_precision!r} is invalid; give True, False or "
                            "'partial'")
    for name in ("cs_fixed_step", "cs_max_step"):
        value = getattr(options, name)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise FmuBuildError(f"{name}={value} must be a positive step")
    value = options.cs_early_return_at
    if value is not None and (options.fmi_version != "3.0" or "cs" not in options.interfaces
                              or not np.isfinite(value)):
        raise FmuBuildError("cs_early_return_at needs FMI 3.0 co-simulation and a finite time; pass fmi_version='3.0'")
    _check_termination(options)
    if options.cs_method not in _CS_METHODS:
        raise FmuBuildError(f"cs_method {options.cs_method!r} is unknown; use 'accurate', 'euler' or 'rk4'")
    if options.naming not in ("modelica", "generic", "array"):
        raise FmuBuildError(f"naming {options.naming!r} is unknown; use 'modelica', 'generic' "
                            "or 'array'")
    if options.naming == "array" and options.fmi_version != "3.0":
        raise FmuBuildError("array naming needs FMI 3.0; pass fmi_version='3.0'")
    if isinstance(model, MassChain) and options.naming != "array":
        raise FmuBuildError("a MassChain family needs naming='array'; pass chain.model() for "
                            "a fixed size")
    if options.naming == "array" and (options.relative or getattr(model, "G", None) is not None):
        raise FmuBuildError("array naming supports neither relative coordinates nor "
                            "constraints; use naming='modelica'")
    unknown = set(options.parameter_inputs) - set(SCALE_PARAMETERS)
    if unknown:
        raise FmuBuildError(f"parameter input(s) {', '.join(sorted(unknown))} are unknown; "
                            f"choose from {', '.join(SCALE_PARAMETERS)}")
    if not options.expose_accelerations and "me" in options.interfaces:
        raise FmuBuildError("a model-exchange FMU always exposes its state derivatives; "
                            "expose_accelerations=False needs interfaces=('cs',)")
    if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", options.identifier):
        raise FmuBuildError(f"model identifier {options.identifier!r} is not a C identifier; "
                            "use letters, digits and underscores")
    if (options.output_array or options.input_array) and options.fmi_version != "3.0":
        raise FmuBuildError("input and output arrays need FMI 3.0; pass fmi_version='3.0'")
    if options.interleaved and (options.naming != "modelica" or not options.expose_accelerations):
        raise FmuBuildError("an interleaved state vector needs modelica naming with its der() variables")
    if options.declared_types and not options.units:
        raise FmuBuildError("declared_types puts the units on type definitions; it needs "
                            "units=True")
    _check_events(model, options)
    _check_completed_steps(model, options)
    _check_position_limit(model, options)
    if options.steady_state_start and isinstance(model, MassChain):
        raise FmuBuildError("steady_state_start needs a fixed size; pass chain.model() instead of the MassChain "
                            "family")


def _check_termination(options: _Options) -> None:
    """``cs_terminate_at`` needs co-simulation, ``me_terminate_at`` and ``completed_step_terminate_at`` model
    exchange; each a finite time > 0."""
    for name, interface in (("cs_terminate_at", "cs"), ("me_terminate_at", "me"),
                            ("completed_step_terminate_at", "me")):
        value = getattr(options, name)
        if value is None:
            continue
        if interface not in options.interfaces:
            raise FmuBuildError(f"{name} needs the interface {interface!r}; add it to interfaces")
        if not (np.isfinite(value) and value > 0):
            raise FmuBuildError(f"{name}={value} must be a finite time after the start, e.g. 30.0")


def _check_position_limit(model, options: _Options) -> None:
    """``position_limit`` names a degree of freedom of the model and a positive bound."""
    if options.position_limit_status not in _POSITION_LIMIT_CODES:
        raise FmuBuildError(f"position_limit_status={options.position_limit_status!r} is not known; use 'error' or "
                            "'discard'")
    if options.position_limit is None:
        return
    dof, bound = options.position_limit
    n = (model.model() if isinstance(model, MassChain) else model).n
    if not (0 <= dof < n and math.isfinite(bound) and bound > 0):
        raise FmuBuildError(f"position_limit={options.position_limit} is invalid; give (dof in [0, {n - 1}], a "
                            "positive finite bound)")


def _check_completed_steps(model, options: _Options) -> None:
    """The completed-step options need model exchange; discrete inputs must be scalar force inputs."""
    gap, at = options.completed_step_gap, options.completed_step_event_at
    if options.needs_completed_steps and "me" not in options.interfaces:
        raise FmuBuildError("completed_step_gap and completed_step_event_at need model exchange; "
                            "include 'me' in interfaces")
    if gap is not None and not (math.isfinite(gap) and gap > 0):
        raise FmuBuildError(f"completed_step_gap={gap} is invalid; give a positive finite time")
    if at is not None and not math.isfinite(at):
        raise FmuBuildError(f"completed_step_event_at={at} is invalid; give a finite time")
    m = (model.model() if isinstance(model, MassChain) else model).m
    bad = [j for j in options.discrete_inputs if not (int(j) == j and 0 <= j < m)]
    if bad or (options.discrete_inputs and options.input_array):
        raise FmuBuildError(f"discrete_inputs {options.discrete_inputs} are invalid; give indices of scalar force "
                            f"inputs in [0, {m - 1}] (not with input_array)")


def _check_per_dof(values, what: str, n: int) -> None:
    """``values`` must be ``n`` finite numbers, one per degree of freedom."""
    array = np.asarray(values, dtype=float)
    if array.shape != (n,) or not np.isfinite(array).all():
        raise DimensionError(f"{what} has shape {array.shape}; give {n} finite values, one per degree of freedom")


def _check_events(model, options: _Options) -> None:
    """Events need a fixed size (their forces have one value per degree of freedom)."""
    events = [e for e in (options.time_event, options.state_event) if e is not None]
    if not events:
        return
    if isinstance(model, MassChain):
        raise FmuBuildError("time and state events need a fixed size; pass chain.model() instead of "
                            "the MassChain family")
    for event in events:
        _check_per_dof(event.force, f"the force of {type(event).__name__}", model.n)
    if options.time_event is not None and not math.isfinite(options.time_event.time):
        raise FmuBuildError("the time of the TimeEvent is not finite; give a finite time")
    if options.time_event is not None and options.time_event.velocity_jump is not None:
        _check_per_dof(options.time_event.velocity_jump, "the velocity_jump of TimeEvent", model.n)
    state = options.state_event
    if state is not None and not (int(state.dof) == state.dof and 0 <= state.dof < model.n
                                  and math.isfinite(state.threshold) and math.isfinite(state.input_gain)):
        raise FmuBuildError(f"StateEvent dof={state.dof}, threshold={state.threshold}, input_gain={state.input_gain} "
                            f"is invalid; give a dof in [0, {model.n - 1}] and a finite threshold and gain")


def _indexed(base: str, i: int, count: int, modelica: bool) -> str:
    if modelica:
        return base if count == 1 else f"{base}[{i + 1}]"
    return f"{base}{i + 1}"


def _common_inputs(layout: _Layout, model: LinearMechanicalModel, options: _Options,
                   modelica: bool) -> tuple[list[str], list[str]]:
    force = "F" if modelica else "u"
    inputs = []
    if options.input_array and model.m:
        layout.add(force, "SlotU", array=True, dimension=model.m, tunable=True, causality="input",
                   start=[0.0] * model.m, unit="N", description="force inputs (columns of B)")
        inputs = [f"{force}[{j + 1}]" for j in range(model.m)]
    for j in range(model.m if not inputs else 0):
        discrete = j in options.discrete_inputs   # model exchange: set only in event mode (tunable 2 in C)
        var = layout.add(_indexed(force, j, model.m, modelica), "SlotU", j, tunable=2 if discrete else True,
                         causality="input", variability="discrete" if discrete else "continuous",
                         start=[0.0], unit="N", description=f"force input {j + 1} (column {j + 1} of B)")
        inputs.append(var.name)
    parameter_inputs = []
    for index, name in enumerate(SCALE_PARAMETERS):
        as_input = name in options.parameter_inputs
        what = "mass matrix" if index == 0 else "stiffness matrix"
        var = layout.add(name, "SlotPar", index, tunable=as_input,
                         causality="input" if as_input else "parameter",
                         variability="continuous" if as_input else "fixed",
                         start=[1.0], unit="1", description=f"scale factor of the {what}")
        if as_input:
            parameter_inputs.append(var.name)
    return inputs, parameter_inputs


def _sensor_unit(model: LinearMechanicalModel, k: int) -> str | None:
    """SI unit of output ``k`` if it measures one kind of quantity (positions, velocities or
    accelerations), else None."""
    kinds = [unit for unit, C in (("m", model.Cp), ("m/s", model.Cv), ("m/s2", model.Ca))
             if np.any(C[k] != 0)]
    return kinds[0] if len(kinds) == 1 else None


def _outputs(layout: _Layout, model: LinearMechanicalModel, modelica: bool,
             options: _Options | None = None) -> list[str]:
    units = [_sensor_unit(model, k) if options is not None and options.output_units else None
             for k in range(model.p)]
    if options is not None and options.output_array:
        common = units[0] if len(set(units)) == 1 else None
        var = layout.add("y", "SlotY", array=True, dimension=model.p, causality="output",
                         unit=common, description="outputs: Cp x + Cv v + Ca a + y0")
        if options.output_aliases:
            layout.alias("sensors", var, "the outputs under another name")
        return [f"y[{k + 1}]" for k in range(model.p)]
    names = []
    for k in range(model.p):
        var = layout.add(_indexed("y", k, model.p, modelica), "SlotY", k, causality="output",
                         unit=units[k],
                         description=f"output {k + 1}: Cp x + Cv v + Ca a + y0 (row {k + 1})")
        names.append(var.name)
        if options is not None and options.output_aliases:
            alias = f"sensor[{k + 1}].y" if model.p > 1 else "sensor.y"
            if layout.fmi3:
                layout.alias(alias, var)
            else:   # FMI 2: a local variable of the same value reference (Modelica connections)
                layout.alias(alias, var, f"alias of {var.name}")
                layout.variables[-1].causality = "local"
    return names


def _array_name(element: str) -> str:
    """The variable of an element ``F[2]`` of an FMI 3 array input (a scalar's own name)."""
    return re.sub(r"\[\d+\]$", "", element) if re.search(r"^[A-Za-z_]\w*\[\d+\]$", element) else element


def _input_sensors(layout: _Layout, inputs: list[str], modelica: bool,
                   options: _Options) -> list[str]:
    """One output per force input reporting it (a force sensor: direct feedthrough ``y = u``)."""
    names = []
    for j, force in enumerate(inputs):
        name = (f"forceSensor[{j + 1}].f" if len(inputs) > 1 else "forceSensor.f") if modelica \
            else f"u_meas{j + 1}"
        var = layout.add(name, "SlotU", j, causality="output",
                         unit="N" if options.output_units else None,
                         description=f"measured force {force} (direct feedthrough)")
        var.dependencies = [_array_name(force) if options.input_array else force]
        names.append(var.name)
    return names


def _modelica_states(layout: _Layout, model: LinearMechanicalModel, coords: _Coordinates,
                     options: _Options) -> dict[str, list[str]]:
    """``mass[i].s/v`` states (or ``spring[i].s_rel/v_rel``), der() variables, computed locals."""
    n, nq = model.n, coords.Kq.shape[0]
    relative = coords.state_dofs is None
    body = "spring" if relative else "mass"
    pos, vel = ("s_rel", "v_rel") if relative else ("s", "v")
    label = (lambda i: f"{body}[{i + 1}]") if n > 1 else (lambda i: body)
    dof_of_state = (list(range(nq)) if relative else [int(d) for d in coords.state_dofs])
    q_vars, qd_vars = [], []

    def position(k: int, dof: int) -> None:
        what = "relative position x_i - x_(i-1)" if relative else "position"
        q_vars.append(layout.add(f"{label(dof)}.{pos}", "SlotQ", k, initial="exact",
                                 start=[coords.q0[k]], unit="m",
                                 description=f"{what} of body {dof + 1} (state)"))

    def velocity(k: int, dof: int) -> None:
        qd_vars.append(layout.add(f"{label(dof)}.{vel}", "SlotQd", k, initial="exact",
                                  start=[coords.qd0[k]], unit="m/s",
                                  description=f"velocity of body {dof + 1} (state)"))

    if layout.interleaved:   # one body after the other, as exporters that sort by component
        for k, dof in enumerate(dof_of_state):
            position(k, dof)
            velocity(k, dof)
    else:
        for k, dof in enumerate(dof_of_state):
            position(k, dof)
        for k, dof in enumerate(dof_of_state):
            velocity(k, dof)
    derivatives_q, derivatives_qd = [], []
    if options.expose_accelerations:
        def position_derivative(k: int, var: _Var) -> None:
            name = f"der({var.name})"
            if layout.fmi3:
                der = layout.add(name, "SlotQd", k, unit="m/s", derivative_of=var.name,
                                 description=f"derivative of {var.name}")
            else:
                der = layout.alias(name, qd_vars[k], f"derivative of {var.name} (alias of "
                                   f"{qd_vars[k].name})", derivative_of=var.name)
            derivatives_q.append(der.name)

        def velocity_derivative(k: int, var: _Var) -> None:
            der = layout.add(f"der({var.name})", "SlotQdd", k, unit="m/s2",
                             derivative_of=var.name, description=f"derivative of {var.name}")
            derivatives_qd.append(der.name)
            if not relative:
                layout.alias(f"{label(dof_of_state[k])}.a", der,
                             f"acceleration of body {dof_of_state[k] + 1}")

        if layout.interleaved:
            for k in range(len(q_vars)):
                position_derivative(k, q_vars[k])
                velocity_derivative(k, qd_vars[k])
            layout.states = [v.name for pair in zip(q_vars, qd_vars) for v in pair]
            layout.derivatives = [d for pair in zip(derivatives_q, derivatives_qd) for d in pair]
        else:
            for k, var in enumerate(q_vars):
                position_derivative(k, var)
            for k, var in enumerate(qd_vars):
                velocity_derivative(k, var)
            layout.states = [v.name for v in q_vars + qd_vars]
            layout.derivatives = derivatives_q + derivatives_qd
    positions = {d: v.name for d, v in zip(dof_of_state, q_vars)} if not relative else {}
    velocities = {d: v.name for d, v in zip(dof_of_state, qd_vars)} if not relative else {}
    accelerations = ({d: f"{label(d)}.a" for d in dof_of_state}
                     if options.expose_accelerations and not relative else {})
    for dof in range(n):   # dependent or absolute coordinates: computed locals
        if dof in positions:
            continue
        positions[dof] = layout.add(f"mass[{dof + 1}].s" if n > 1 else "mass.s", "SlotX", dof,
                                    unit="m", description=f"position of body {dof + 1}").name
        velocities[dof] = layout.add(f"mass[{dof + 1}].v" if n > 1 else "mass.v", "SlotV",
                                     dof, unit="m/s",
                                     description=f"velocity of body {dof + 1}").name
        if options.expose_accelerations:
            accelerations[dof] = layout.add(f"mass[{dof + 1}].a" if n > 1 else "mass.a",
                                            "SlotA", dof, unit="m/s2",
                                            description=f"acceleration of body {dof + 1}").name
    return {"positions": [positions[d] for d in range(n)],
            "velocities": [velocities[d] for d in range(n)],
            "accelerations": [accelerations[d] for d in range(n)] if accelerations else [],
            "start_parameters": []}


def _generic_states(layout: _Layout, coords: _Coordinates,
                    options: _Options) -> dict[str, list[str]]:
    """``x1 .. xN`` (positions then velocities), ``der_x1 ..`` and ``x1_start ..``."""
    nq = coords.Kq.shape[0]
    starts = np.r_[coords.q0, coords.qd0]
    state_vars, start_names = [], []
    for k in range(2 * nq):
        kind = "SlotQ" if k < nq else "SlotQd"
        state_vars.append(layout.add(f"x{k + 1}", kind, k % nq, initial="calculated",
                                     description=f"state {k + 1}"))
    for k in range(2 * nq):
        kind = "SlotQStart" if k < nq else "SlotQdStart"
        start = layout.add(f"x{k + 1}_start", kind, k % nq, causality="parameter",
                           variability="fixed", start=[starts[k]],
                           description=f"start value of state x{k + 1}")
        start_names.append(start.name)
    derivatives = []
    if options.expose_accelerations:
        for k, var in enumerate(state_vars):
            kind = "SlotQd" if k < nq else "SlotQdd"
            der = layout.add(f"der_x{k + 1}", kind, k % nq, derivative_of=var.name,
                             description=f"derivative of x{k + 1}")
            derivatives.append(der.name)
        layout.states = [v.name for v in state_vars]
        layout.derivatives = derivatives
    return {"positions": [], "velocities": [], "accelerations": [],
            "start_parameters": start_names}


def _array_states(layout: _Layout, model: LinearMechanicalModel, chain: MassChain | None,
                  options: _Options) -> dict[str, list[str]]:
    """FMI 3 arrays ``x``, ``v``, ``der(x)``, ``der(v)`` (alias ``a``), ``x_start``, ``v_start``."""
    size: int | str = model.n
    if chain is not None:
        layout.add("n", "SlotSize", 0, type="UInt64", causality="structuralParameter",
                   variability="fixed", start=[float(chain.n)], minimum=1,
                   maximum=chain.n_max, description="number of masses of the chain")
        size = "n"
    x = layout.add("x", "SlotQ", array=True, dimension=size, unit="m",
                   initial="calculated", description="positions of the masses (state)")
    v = layout.add("v", "SlotQd", array=True, dimension=size, unit="m/s",
                   initial="calculated", description="velocities of the masses (state)")
    starts = []
    for var, kind, values, unit in ((x, "SlotQStart", model.x0, "m"),
                                    (v, "SlotQdStart", model.v0, "m/s")):
        start = layout.add(f"{var.name}_start", kind, array=True, dimension=size,
                           causality="parameter", variability="fixed", start=list(values),
                           unit=unit, description=f"start values of {var.name}")
        starts.append(start.name)
    accelerations = []
    if options.expose_accelerations:
        dx = layout.add("der(x)", "SlotQd", array=True, dimension=size, unit="m/s",
                        derivative_of="x", description="derivative of x")
        dv = layout.add("der(v)", "SlotQdd", array=True, dimension=size, unit="m/s2",
                        derivative_of="v", description="derivative of v")
        layout.alias("a", dv, "accelerations of the masses")
        layout.states, layout.derivatives = ["x", "v"], [dx.name, dv.name]
        accelerations = ["a"]
    return {"positions": ["x"], "velocities": ["v"], "accelerations": accelerations,
            "start_parameters": starts}


def _dependencies(layout: _Layout, model: LinearMechanicalModel, coords: _Coordinates,
                  inputs: list[str], parameter_inputs: list[str], outputs: list[str]) -> None:
    """Structural dependencies of outputs and derivatives on states and inputs (exact zeros)."""
    if not layout.states or layout.find(layout.states[0]).dimension is not None:
        return
    nq = coords.Kq.shape[0]
    order = list(range(2 * nq))
    if layout.interleaved:   # z index of each (q, qd) entry
        order = [2 * k for k in range(nq)] + [2 * k + 1 for k in range(nq)]
    states = [layout.states[i] for i in order]
    derivatives = [layout.derivatives[i] for i in order]
    q_names, qd_names = states[:nq], states[nq:]
    declared = {v.name for v in layout.variables}
    mass_input = "mass_scale" in parameter_inputs
    stiffness_input = "stiffness_scale" in parameter_inputs

    def names(row_q, row_qd, row_u) -> list[str]:
        deps = [q for q, value in zip(q_names, row_q) if value != 0]
        deps += [q for q, value in zip(qd_names, row_qd) if value != 0]
        forces = [u if u in declared else _array_name(u) for u, value in zip(inputs, row_u) if value != 0]
        return deps + [u for i, u in enumerate(forces) if u not in forces[:i]]

    for i in range(nq):
        layout.find(derivatives[i]).dependencies = [qd_names[i]]
        deps = names(coords.Kq[i], coords.Dq[i], coords.Bq[i])
        if mass_input:
            deps.append("mass_scale")
        if stiffness_input and np.any(coords.Kq[i] != 0):
            deps.append("stiffness_scale")
        layout.find(derivatives[nq + i]).dependencies = deps
    CaT = model.Ca @ coords.T
    dq = model.Cp @ coords.T - CaT @ coords.Kq
    dqd = model.Cv @ coords.T - CaT @ coords.Dq
    du = CaT @ coords.Bq
    for k, name in enumerate(outputs):
        deps = names(dq[k], dqd[k], du[k])
        if mass_input and np.any(CaT[k] != 0):
            deps.append("mass_scale")
        if stiffness_input and np.any((CaT @ coords.Kq)[k] != 0):
            deps.append("stiffness_scale")
        layout.find(name).dependencies = deps


# ------------------------------------------------------------------------- XML

_UNITS = {"s": {"s": 1}, "m": {"m": 1}, "m/s": {"m": 1, "s": -1},
          "m/s2": {"m": 1, "s": -2}, "N": {"kg": 1, "m": 1, "s": -2}, "1": {}}


#: Modelica type of each unit, for ``declared_types`` (units on type definitions, not variables)
_TYPE_NAMES = {"s": "Modelica.Units.SI.Time", "m": "Modelica.Units.SI.Position",
               "m/s": "Modelica.Units.SI.Velocity", "m/s2": "Modelica.Units.SI.Acceleration",
               "N": "Modelica.Units.SI.Force"}
_QUANTITIES = {"s": "Time", "m": "Length", "m/s": "Velocity", "m/s2": "Acceleration",
               "N": "Force"}


def _type_definitions(layout: _Layout, declared: bool) -> str:
    used = sorted({v.unit for v in layout.variables if v.unit in _TYPE_NAMES}) if declared else []
    if layout.fmi3:
        rows = "".join(f'    <Float64Type name="{_TYPE_NAMES[u]}" quantity="{_QUANTITIES[u]}" '
                       f'unit="{u}"/>\n' for u in used)
    else:
        rows = "".join(f'    <SimpleType name="{_TYPE_NAMES[u]}">\n      <Real '
                       f'quantity="{_QUANTITIES[u]}" unit="{u}"/>\n    </SimpleType>\n'
                       for u in used)
    if any(v.enumeration == METHOD_TYPE for v in layout.variables):
        rows += _method_type(layout.fmi3)
    return "  <TypeDefinitions>\n" + rows + "  </TypeDefinitions>\n" if rows else ""


def _method_type(fmi3: bool) -> str:
    """The Enumeration type of ``typed_parameters`` (FMI 2 ``SimpleType``, FMI 3 ``EnumerationType``)."""
    indent = "" if fmi3 else "  "
    items = "".join(f'{indent}      <Item name="{name}" value="{value}" description="{text}"/>\n'
                    for name, value, text in METHOD_ITEMS)
    if fmi3:
        return f'    <EnumerationType name="{METHOD_TYPE}">\n{items}    </EnumerationType>\n'
    return (f'    <SimpleType name="{METHOD_TYPE}">\n      <Enumeration>\n{items}      </Enumeration>\n'
            "    </SimpleType>\n")


def _unit_attribute(var: _Var, declared: bool) -> str:
    if not var.unit:
        return ""
    if declared and var.unit in _TYPE_NAMES:
        return f' declaredType="{_TYPE_NAMES[var.unit]}"'
    return f' unit="{var.unit}"'


def _number(value: float) -> str:
    return repr(float(value))


def _unit_definitions(layout: _Layout) -> str:
    used = sorted({v.unit for v in layout.variables if v.unit})
    if not used:
        return ""
    rows = []
    for unit in used:
        exponents = " ".join(f'{key}="{value}"' for key, value in _UNITS[unit].items())
        base = f"<BaseUnit {exponents}/>" if exponents else "<BaseUnit/>"
        rows.append(f'    <Unit name="{unit}">{base}</Unit>\n')
    return "  <UnitDefinitions>\n" + "".join(rows) + "  </UnitDefinitions>\n"


def _common_attributes(var: _Var) -> str:
    text = f"name={quoteattr(var.name)} valueReference=\"{var.vr}\""
    if var.description:
        text += f" description={quoteattr(var.description)}"
    text += f' causality="{var.causality}"'
    if var.causality != "independent" or var.variability != "continuous":
        text += f' variability="{var.variability}"'
    if var.initial:
        text += f' initial="{var.initial}"'
    return text


def _variable2(var: _Var, index_of: dict[str, int], declared: bool = False) -> str:
    if var.type == "Enumeration":
        return (f"    <ScalarVariable {_common_attributes(var)}>\n"
                f"      <Enumeration declaredType=\"{var.enumeration}\" start=\"{int(var.start[0])}\"/>\n"
                "    </ScalarVariable>\n")
    if var.type == "Integer":
        return (f"    <ScalarVariable {_common_attributes(var)}>\n"
                f"      <Integer start=\"{int(var.start[0])}\"/>\n"
                "    </ScalarVariable>\n")
    if var.type == "Boolean":
        return (f"    <ScalarVariable {_common_attributes(var)}>\n"
                f"      <Boolean start=\"{str(bool(var.start[0])).lower()}\"/>\n"
                "    </ScalarVariable>\n")
    inner = _unit_attribute(var, declared)
    if var.start is not None:
        inner += f' start="{_number(var.start[0])}"'
    if var.derivative_of:
        inner += f' derivative="{index_of[var.derivative_of]}"'
    return (f"    <ScalarVariable {_common_attributes(var)}>\n"
            f"      <Real{inner}/>\n"
            "    </ScalarVariable>\n")


def _variable3(var: _Var, vr_of: dict[str, int], declared: bool = False) -> str:
    attributes = _common_attributes(var)
    if var.type == "Boolean":
        return f'    <Boolean {attributes} start="{str(bool(var.start[0])).lower()}"/>\n'
    if var.type == "Int32":
        return f'    <Int32 {attributes} start="{int(var.start[0])}"/>\n'
    if var.type == "Enumeration":
        return f'    <Enumeration {attributes} declaredType="{var.enumeration}" start="{int(var.start[0])}"/>\n'
    if var.type == "Float32" and var.causality == "parameter":
        return f'    <Float32 {attributes} start="{_number(var.start[0])}"/>\n'
    if var.type == "UInt64":
        attributes += f' start="{int(var.start[0])}" min="{var.minimum}" max="{var.maximum}"'
        return f"    <UInt64 {attributes}/>\n"
    attributes += _unit_attribute(var, declared)
    if var.start is not None:
        attributes += f' start="{" ".join(_number(s) for s in var.start)}"'
    if var.derivative_of:
        attributes += f' derivative="{vr_of[var.derivative_of]}"'
    children = ""
    if isinstance(var.dimension, str):
        children += f'      <Dimension valueReference="{vr_of[var.dimension]}"/>\n'
    elif var.dimension is not None:
        children += f'      <Dimension start="{var.dimension}"/>\n'
    children += "".join(f"      <Alias name={quoteattr(alias)}/>\n" for alias in var.aliases)
    if not children:
        return f"    <Float64 {attributes}/>\n"
    return f"    <Float64 {attributes}>\n{children}    </Float64>\n"


def _initial_unknowns(layout: _Layout) -> list[_Var]:
    """Outputs, and states and derivatives whose start is calculated (FMI 2.0 / 3.0 rule)."""
    unknowns = [v for v in layout.variables if v.causality == "output"]
    for state, derivative in zip(layout.states, layout.derivatives):
        for name in (state, derivative):
            var = layout.find(name)
            if (var.initial or "calculated") in ("approx", "calculated") and var not in unknowns:
                unknowns.append(var)
    order = {id(v): i for i, v in enumerate(layout.variables)}
    return sorted(unknowns, key=lambda v: order[id(v)])


def _experiment(options: _Options) -> str:
    step = "" if options.cs_fixed_step is None else f' stepSize="{_number(options.cs_fixed_step)}"'
    return f'  <DefaultExperiment startTime="0" stopTime="{_number(options.stop_time)}"{step}/>\n'


def _variable_step(options: _Options) -> str:
    """``canHandleVariableCommunicationStepSize``: false for an FMU with a fixed communication step."""
    return "false" if options.cs_fixed_step is not None else "true"


def _model_description2(layout: _Layout, options: _Options, sources: list[str]) -> str:
    index_of = {v.name: i + 1 for i, v in enumerate(layout.variables)}
    files = "".join(f'      <File name="{s}"/>\n' for s in sources)
    interfaces = ""
    if "me" in options.interfaces:
        interfaces += (
            f'  <ModelExchange modelIdentifier="{options.identifier}" needsExecutionTool="false"'
            f' completedIntegratorStepNotNeeded="{str(not options.needs_completed_steps).lower()}"'
            ' canBeInstantiatedOnlyOncePerProcess="false"'
            ' canNotUseMemoryManagementFunctions="true" canGetAndSetFMUstate="false"'
            ' canSerializeFMUstate="false" providesDirectionalDerivative="false">\n'
            f"    <SourceFiles>\n{files}    </SourceFiles>\n  </ModelExchange>\n")
    if "cs" in options.interfaces:
        interfaces += (
            f'  <CoSimulation modelIdentifier="{options.identifier}" needsExecutionTool="false"'
            f' canHandleVariableCommunicationStepSize="{_variable_step(options)}" canInterpolateInputs="false"'
            ' maxOutputDerivativeOrder="0" canRunAsynchronuously="false"'
            ' canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="true"'
            ' canGetAndSetFMUstate="false" canSerializeFMUstate="false"'
            ' providesDirectionalDerivative="false">\n'
            f"    <SourceFiles>\n{files}    </SourceFiles>\n  </CoSimulation>\n")

    def unknown(var: _Var) -> str:
        text = f'      <Unknown index="{index_of[var.name]}"'
        if var.dependencies is not None:
            text += f' dependencies="{" ".join(str(index_of[d]) for d in var.dependencies)}"'
        return text + "/>\n"

    outputs = "".join(unknown(v) for v in layout.variables if v.causality == "output")
    derivatives = "".join(unknown(layout.find(d)) for d in layout.derivatives)
    initial = "".join(f'      <Unknown index="{index_of[v.name]}"/>\n'
                      for v in _initial_unknowns(layout))
    structure = "  <ModelStructure>\n"
    for tag, body in (("Outputs", outputs), ("Derivatives", derivatives),
                      ("InitialUnknowns", initial)):
        if body:
            structure += f"    <{tag}>\n{body}    </{tag}>\n"
    structure += "  </ModelStructure>\n"
    naming = "flat" if options.naming == "generic" else "structured"
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<fmiModelDescription fmiVersion="2.0" modelName="{options.identifier}"'
        f' guid="{_GUID_PLACEHOLDER}"\n  description={quoteattr(options.description)}\n'
        f'  generationTool="fmu-opinf lti_fmus" variableNamingConvention="{naming}"'
        f' numberOfEventIndicators="{int(options.state_event is not None)}">\n'
        f"{interfaces}{_unit_definitions(layout)}"
        f"{_type_definitions(layout, options.declared_types)}"
        "  <LogCategories>\n"
        '    <Category name="logEvents" description="resizing, information"/>\n'
        '    <Category name="logStatusError" description="calls that return fmi2Error"/>\n'
        "  </LogCategories>\n"
        f"{_experiment(options)}"
        "  <ModelVariables>\n"
        f"{''.join(_variable2(v, index_of, options.declared_types) for v in layout.variables)}"
        "  </ModelVariables>\n"
        f"{structure}"
        "</fmiModelDescription>\n")


def _model_description3(layout: _Layout, options: _Options) -> str:
    vr_of = {v.name: v.vr for v in layout.variables}
    common = (f' modelIdentifier="{options.identifier}" needsExecutionTool="false"'
              ' canBeInstantiatedOnlyOncePerProcess="false" canGetAndSetFMUState="false"'
              ' canSerializeFMUState="false" providesDirectionalDerivatives="false"'
              ' providesAdjointDerivatives="false" providesPerElementDependencies="false"')
    interfaces = ""
    if "me" in options.interfaces:
        interfaces += (f"  <ModelExchange{common} needsCompletedIntegratorStep="
                       f"\"{str(options.needs_completed_steps).lower()}\""
                       ' providesEvaluateDiscreteStates="false"/>\n')
    if "cs" in options.interfaces:
        interfaces += (f"  <CoSimulation{common} canHandleVariableCommunicationStepSize=\"{_variable_step(options)}\""
                       ' maxOutputDerivativeOrder="0" providesIntermediateUpdate="false"'
                       f' mightReturnEarlyFromDoStep="{str(options.cs_early_return_at is not None).lower()}"'
                       ' canReturnEarlyAfterIntermediateUpdate="false" hasEventMode="false"'
                       ' providesEvaluateDiscreteStates="false"/>\n')

    def unknown(tag: str, var: _Var) -> str:
        text = f'    <{tag} valueReference="{var.vr}"'
        if var.dependencies is not None:
            text += f' dependencies="{" ".join(str(vr_of[d]) for d in var.dependencies)}"'
        return text + "/>\n"

    structure = "".join(unknown("Output", v) for v in layout.variables if v.causality == "output")
    structure += "".join(unknown("ContinuousStateDerivative", layout.find(d))
                         for d in layout.derivatives)
    structure += "".join(f'    <InitialUnknown valueReference="{v.vr}"/>\n'
                         for v in _initial_unknowns(layout))
    structure += "".join(f'    <EventIndicator valueReference="{v.vr}"/>\n'
                         for v in layout.variables if v.name == _INDICATOR)
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<fmiModelDescription fmiVersion="3.0" modelName="{options.identifier}"'
        f' instantiationToken="{_GUID_PLACEHOLDER}"\n'
        f"  description={quoteattr(options.description)}\n"
        '  generationTool="fmu-opinf lti_fmus" variableNamingConvention="structured">\n'
        f"{interfaces}{_unit_definitions(layout)}"
        f"{_type_definitions(layout, options.declared_types)}"
        "  <LogCategories>\n"
        '    <Category name="logEvents" description="resizing, information"/>\n'
        '    <Category name="logStatusError" description="calls that return fmi3Error"/>\n'
        "  </LogCategories>\n"
        f"{_experiment(options)}"
        "  <ModelVariables>\n"
        f"{''.join(_variable3(v, vr_of, options.declared_types) for v in layout.variables)}"
        "  </ModelVariables>\n"
        f"  <ModelStructure>\n{structure}  </ModelStructure>\n"
        "</fmiModelDescription>\n")


def _build_description3(options: _Options, sources: list[str]) -> str:
    files = "".join(f'      <SourceFile name="{s}"/>\n' for s in sources)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiBuildDescription fmiVersion="3.0">\n'
            f'  <BuildConfiguration modelIdentifier="{options.identifier}">\n'
            f'    <SourceFileSet language="C99">\n{files}    </SourceFileSet>\n'
            "  </BuildConfiguration>\n"
            "</fmiBuildDescription>\n")


# ------------------------------------------------------------------------ C model

def _c_array(name: str, values: np.ndarray, static: bool = True) -> str:
    """A C array definition (one 0.0 if empty, as C has no empty arrays); ``static=False`` for the
    arrays that lti.h declares extern."""
    flat = np.asarray(values, dtype=float).reshape(-1)
    body = ", ".join(_number(v) for v in flat) if flat.size else "0.0"
    return f"{'static ' if static else ''}const double {name}[] = {{{body}}};\n"


def _fixed_assembly(coords: _Coordinates, model: LinearMechanicalModel) -> str:
    arrays = {"KQ": coords.Kq, "DQ": coords.Dq, "BQ": coords.Bq, "FQ": coords.fq, "TX": coords.T,
              "XOFF": coords.xoff, "CP": model.Cp, "CV": model.Cv, "CA": model.Ca, "Y0": model.y0,
              "Z0": np.r_[coords.q0, coords.qd0]}
    text = "".join(_c_array(name, value) for name, value in arrays.items())
    targets = {"KQ": "Kq", "DQ": "Dq", "BQ": "Bq", "FQ": "fq", "TX": "T", "XOFF": "xoff",
               "CP": "Cp", "CV": "Cv", "CA": "Ca", "Y0": "y0", "Z0": "zStart"}
    copies = "".join(f"    copy(inst->{targets[name]}, {name}, {np.asarray(value).size});\n"
                     for name, value in arrays.items())
    return (text + "\nstatic void copy(double *target, const double *source, size_t count) {\n"
            "    size_t i;\n    for (i = 0; i < count; i++) target[i] = source[i];\n}\n\n"
            "void ltiAssemble(LtiInstance *inst) {\n" + copies + "}\n")


def _chain_assembly(chain: MassChain, model: LinearMechanicalModel) -> str:
    """C assembly of the chain for the runtime size nq (the same matrices as MassChain.model)."""
    return f"""
void ltiAssemble(LtiInstance *inst) {{
    const size_t n = inst->nq, ny = LTI_NY, nu = LTI_NU;
    const double mass = {_number(chain.mass)}, k = {_number(chain.stiffness)};
    const double d = {_number(chain.damping)}, force = {_number(chain.force_offset)};
    size_t i;

    memset(inst->Kq, 0, n * n * sizeof(double));
    memset(inst->Dq, 0, n * n * sizeof(double));
    memset(inst->Bq, 0, n * (nu ? nu : 1) * sizeof(double));
    memset(inst->T, 0, n * n * sizeof(double));
    memset(inst->Cp, 0, ny * n * sizeof(double));
    memset(inst->Cv, 0, ny * n * sizeof(double));
    memset(inst->Ca, 0, ny * n * sizeof(double));
    for (i = 0; i < n; i++) {{
        double diagonal = i + 1 < n ? 2.0 : 1.0;
        inst->Kq[i * n + i] = diagonal * k / mass;
        inst->Dq[i * n + i] = diagonal * d / mass;
        if (i + 1 < n) {{
            inst->Kq[i * n + i + 1] = inst->Kq[(i + 1) * n + i] = -k / mass;
            inst->Dq[i * n + i + 1] = inst->Dq[(i + 1) * n + i] = -d / mass;
        }}
        inst->fq[i] = force / mass;
        inst->T[i * n + i] = 1.0;
        inst->xoff[i] = 0.0;
        inst->zStart[i] = {_number(chain.start_position)};
        inst->zStart[n + i] = {_number(chain.start_velocity)};
    }}
    if (nu) inst->Bq[(n - 1) * nu] = 1.0 / mass;
    inst->Cp[0 * n + n - 1] = 1.0;
    inst->Cv[1 * n + 0] = 1.0;
    if (ny > 2) inst->Ca[2 * n + n - 1] = 1.0;
    for (i = 0; i < ny; i++) inst->y0[i] = 0.0;
}}
"""


def _event_source(options: _Options, model: LinearMechanicalModel, coords: _Coordinates) -> str:
    """The C constants of the optional events (zeros and one-element arrays when off)."""
    def in_q(force) -> np.ndarray:   # the force's contribution to q'' (before mass_scale), as fq
        T = coords.T
        return np.linalg.solve(T.T @ model.M @ T, T.T @ np.asarray(force, dtype=float))

    def velocity_in_q(jump) -> np.ndarray:   # the jump of q' that gives the jump of the velocities T q'
        return np.linalg.lstsq(coords.T, np.asarray(jump, dtype=float), rcond=None)[0]

    timed, state = options.time_event, options.state_event
    jump = timed.velocity_jump if timed is not None else None
    return (
        f"const int LTI_TIME_EVENT = {int(timed is not None)};\n"
        f"const double LTI_TIME_EVENT_AT = {_number(timed.time if timed else 0.0)};\n"
        + _c_array("LTI_TIME_EVENT_FQ", in_q(timed.force) if timed else np.zeros(0), static=False)
        + f"const int LTI_TIME_EVENT_JUMP = {int(jump is not None)};\n"
        + _c_array("LTI_TIME_EVENT_DQD", velocity_in_q(jump) if jump is not None else np.zeros(0), static=False)
        + f"const int LTI_STATE_EVENT = {int(state is not None)};\n"
        f"const size_t LTI_STATE_EVENT_DOF = {int(state.dof) if state else 0};\n"
        f"const double LTI_STATE_EVENT_THRESHOLD = {_number(state.threshold if state else 0.0)};\n"
        f"const double LTI_STATE_EVENT_INPUT_GAIN = {_number(state.input_gain if state else 0.0)};\n"
        + _c_array("LTI_STATE_EVENT_FQ", in_q(state.force) if state else np.zeros(0), static=False))


def _model_source(layout: _Layout, options: _Options, model: LinearMechanicalModel,
                  coords: _Coordinates, chain: MassChain | None) -> str:
    slots = ",\n    ".join(f"{{{kind}, {index}, {array}, {tunable}}}"
                           for kind, index, array, tunable in layout.slots)
    nq = coords.Kq.shape[0]
    assembly = _chain_assembly(chain, model) if chain else _fixed_assembly(coords, model)
    limit = options.position_limit or (0, 0.0)
    return (
        f"/* Generated by fmu_opinf.lti_fmus for {options.identifier}; do not edit. */\n"
        "#include <string.h>\n\n#include \"lti.h\"\n\n"
        f'const char *const LTI_INSTANTIATION_TOKEN = "{_GUID_PLACEHOLDER}";\n'
        f"const int LTI_CS_METHOD = {_CS_METHODS[options.cs_method]};\n"
        f"const int LTI_STALE_DERIVATIVES = {int(options.stale_derivatives)};\n"
        f"const int LTI_LATE_OUTPUTS = {int(options.late_outputs)};\n"
        f"const double LTI_CS_FIXED_STEP = {_c_step(_enforced_step(options))};\n"
        f"const double LTI_CS_MAX_STEP = {_c_step(options.cs_max_step)};\n"
        f"const int LTI_CS_EARLY_RETURN = {int(options.cs_early_return_at is not None)};\n"
        f"const double LTI_CS_EARLY_RETURN_AT = {_number(options.cs_early_return_at or 0.0)};\n"
        f"const int LTI_CS_TERMINATE = {int(options.cs_terminate_at is not None)};\n"
        f"const double LTI_CS_TERMINATE_AT = {_number(options.cs_terminate_at or 0.0)};\n"
        f"const int LTI_ME_TERMINATE = {int(options.me_terminate_at is not None)};\n"
        f"const double LTI_ME_TERMINATE_AT = {_number(options.me_terminate_at or 0.0)};\n"
        f"const int LTI_COMPLETED_TERMINATE = {int(options.completed_step_terminate_at is not None)};\n"
        f"const double LTI_COMPLETED_TERMINATE_AT = {_number(options.completed_step_terminate_at or 0.0)};\n"
        f"const int LTI_HAS_ME = {int('me' in options.interfaces)};\n"
        f"const int LTI_HAS_CS = {int('cs' in options.interfaces)};\n"
        f"const size_t LTI_NQ_DEFAULT = {nq};\n"
        f"const size_t LTI_NQ_MAX = {chain.n_max if chain else nq};\n"
        f"const size_t LTI_NX_FIXED = {model.n};\n"
        f"const int LTI_X_FOLLOWS_Q = {int(chain is not None)};\n"
        f"const int LTI_INTERLEAVED = {int(layout.interleaved)};\n"
        f"const size_t LTI_NU = {model.m};\n"
        f"const size_t LTI_NY = {model.p};\n"
        "const double LTI_PAR_DEFAULTS[2] = {1.0, 1.0};\n"
        f"{_event_source(options, model, coords)}"
        f"{_steady_source(options, coords)}"
        f"const double LTI_COMPLETED_GAP = {_number(options.completed_step_gap or 0.0)};\n"
        f"const int LTI_COMPLETED_EVENT = {int(options.completed_step_event_at is not None)};\n"
        f"const double LTI_COMPLETED_EVENT_AT = {_number(options.completed_step_event_at or 0.0)};\n"
        f"const int LTI_COMPLETED_EVENT_EVERY = {int(options.completed_step_event_every)};\n"
        f"const int LTI_SINGLE_PRECISION = {_SINGLE_PRECISION_CODES[options.single_precision]};\n"
        f"const int LTI_POSITION_LIMIT = "
        f"{0 if options.position_limit is None else _POSITION_LIMIT_CODES[options.position_limit_status]};\n"
        f"const size_t LTI_POSITION_LIMIT_DOF = {limit[0]};\n"
        f"const double LTI_POSITION_LIMIT_BOUND = {_number(limit[1])};\n"
        f"const int LTI_ENABLE_INPUT = {int(options.enable_input)};\n"
        f"const unsigned int LTI_ENABLE_VR = {_enable_vr(layout)};\n"
        f"const int LTI_STRICT_STOP = {int(options.strict_stop_time)};\n"
        f"const int LTI_DISCRETE_PARAMETERS = {int(options.discrete_parameters)};\n"
        f"const unsigned int LTI_ORDER_VR = {_discrete_vr(layout, ORDER_PARAMETER)};\n"
        f"const unsigned int LTI_CACHE_VR = {_discrete_vr(layout, CACHE_PARAMETER)};\n"
        f"const int LTI_ORDER_START = {ORDER_START};\n"
        f"const int LTI_CACHE_START = {int(CACHE_START)};\n"
        f"const int LTI_TYPED_PARAMETERS = {int(options.typed_parameters)};\n"
        f"const unsigned int LTI_METHOD_VR = {_discrete_vr(layout, METHOD_PARAMETER)};\n"
        f"const unsigned int LTI_TOLERANCE_VR = {_discrete_vr(layout, TOLERANCE_PARAMETER)};\n"
        f"const int LTI_METHOD_START = {METHOD_START};\n"
        f"const int LTI_METHOD_ITEMS = {len(METHOD_ITEMS)};\n"
        f"const double LTI_TOLERANCE_START = {_number(TOLERANCE_START)};\n"
        f"const size_t LTI_N_SLOTS = {len(layout.slots)};\n"
        f"const LtiSlot LTI_SLOTS[] = {{\n    {slots}\n}};\n\n"
        f"{assembly}")


def _steady_source(options: _Options, coords: _Coordinates) -> str:
    """The C constants of ``steady_state_start``: the equilibrium ``q = Kq^-1 (Bq u + fq)`` as ``LTI_STEADY_Q0 +
    LTI_STEADY_QU u`` (row-major ``nq x nu``; stiffness_scale 1)."""
    on = options.steady_state_start
    return (f"const int LTI_STEADY_START = {int(on)};\n"
            + _c_array("LTI_STEADY_Q0", np.linalg.solve(coords.Kq, coords.fq) if on else np.zeros(0), static=False)
            + _c_array("LTI_STEADY_QU", np.linalg.solve(coords.Kq, coords.Bq) if on and coords.Bq.size
                       else np.zeros(0), static=False))


def _enforced_step(options: _Options) -> float | None:
    """The fixed communication step the FMU's ``doStep`` enforces (none where it is only declared)."""
    return options.cs_fixed_step if options.cs_fixed_step_enforced else None


def _c_step(step: float | None) -> str:
    """A step as a C constant, 0 for none."""
    return "0.0" if step is None else repr(float(step))


# --------------------------------------------------------------------- building

def _lti_sources_dir() -> Path:
    """The C sources of these FMUs (``fmus/LinearStateSpace``), found like the benchmarks'."""
    folder = _c_sources_dir() / _SOURCE_FOLDER
    if not (folder / "lti.c").is_file():
        raise FmuBuildError(f"C sources not found in {folder}; run from a source checkout of "
                            "fmu-opinf (pip install -e .)")
    return folder


def _layout(model: LinearMechanicalModel, coords: _Coordinates, chain: MassChain | None,
            options: _Options) -> tuple[_Layout, dict[str, list[str]]]:
    layout = _Layout(fmi3=options.fmi_version == "3.0", units=options.units,
                     interleaved=options.interleaved)
    modelica = options.naming != "generic"
    if chain is not None:   # the structural parameter comes first, as in the reference FMUs
        names = _array_states(layout, model, chain, options)
        inputs, parameter_inputs = _common_inputs(layout, model, options, False)
        outputs = _outputs(layout, model, False, options)
    else:
        inputs, parameter_inputs = _common_inputs(layout, model, options,
                                                  modelica and options.naming != "array")
        outputs = _outputs(layout, model, modelica and options.naming != "array", options)
        if options.naming == "modelica":
            names = _modelica_states(layout, model, coords, options)
        elif options.naming == "generic":
            names = _generic_states(layout, coords, options)
        else:
            names = _array_states(layout, model, None, options)
    sensors = (_input_sensors(layout, inputs, options.naming == "modelica", options)
               if options.input_sensors else [])
    if options.state_event is not None and layout.fmi3:   # FMI 3 names a variable per event indicator
        layout.add(_INDICATOR, "SlotIndicator",
                   description=f"event indicator: x[{options.state_event.dof + 1}] - "
                               f"{_number(options.state_event.threshold)}")
    if options.dependencies:
        _dependencies(layout, model, coords, inputs, parameter_inputs,
                      [] if options.output_array else outputs)
    else:
        for var in layout.variables:
            var.dependencies = None
    if options.enable_input:
        _enable_input(layout, inputs)
    if options.discrete_parameters:
        _discrete_parameters(layout)
    if options.typed_parameters:
        _typed_parameters(layout)
    names.update(inputs=inputs, parameter_inputs=parameter_inputs, outputs=outputs + sensors)
    return layout, names


#: Name of the Boolean input of ``enable_input``.
ENABLE_INPUT = "enable"


def _enable_input(layout: _Layout, inputs: list[str]) -> None:
    """Add the Boolean input ``enable`` (start false) without which the force inputs do not act; added last, with
    the value reference after the C slot table (no slot: the kernel serves it in its Boolean get/set), and named
    in the declared dependencies of every unknown that depends on a force input."""
    forces = set(inputs) | {_array_name(u) for u in inputs}
    for var in layout.variables:
        deps = set(var.dependencies or ())
        if forces & deps and not deps <= forces:   # (a force sensor, y = u, reports the force, enabled or not)
            var.dependencies = var.dependencies + [ENABLE_INPUT]
    layout.variables.append(_Var(ENABLE_INPUT, len(layout.slots), causality="input", variability="discrete",
                                 start=[0.0], type="Boolean",
                                 description="drive enable: the force inputs act only while it is true"))


#: Names and start values of the parameters of ``discrete_parameters``.
ORDER_PARAMETER, ORDER_START = "solverOrder", 4
CACHE_PARAMETER, CACHE_START = "useCache", True


def _discrete_parameters(layout: _Layout) -> None:
    """Add an Integer (FMI 3: Int32) and a Boolean parameter without effect on the model, after every other variable
    (value references after the C slot table and the enable input: the kernel serves them in its Integer and Boolean
    get/set), as exporters declare solver settings."""
    first = len(layout.slots) + 1   # (len(slots) is the enable input's, whether it is there or not)
    layout.variables.append(_Var(ORDER_PARAMETER, first, causality="parameter", variability="fixed",
                                 start=[float(ORDER_START)], type="Int32" if layout.fmi3 else "Integer",
                                 description="order of the exporter's solver (no effect on the model)"))
    layout.variables.append(_Var(CACHE_PARAMETER, first + 1, causality="parameter", variability="fixed",
                                 start=[float(CACHE_START)], type="Boolean",
                                 description="the exporter's cache switch (no effect on the model)"))


#: The parameters of ``typed_parameters``: an Enumeration (its type and items) and, FMI 3, a Float32.
METHOD_PARAMETER, METHOD_TYPE, METHOD_START = "solverMethod", "Solvers.Method", 2
METHOD_ITEMS = (("euler", 1, "explicit Euler"), ("rk4", 2, "classical Runge-Kutta"), ("dassl", 3, "DASSL"))
TOLERANCE_PARAMETER, TOLERANCE_START = "relTol", 1e-4


def _typed_parameters(layout: _Layout) -> None:
    """Add an Enumeration parameter (type :data:`METHOD_TYPE`) and, FMI 3, a Float32 one, without effect on the model,
    after every other variable (value references after those of ``discrete_parameters``, whether they are there or
    not: the kernel serves them in its Integer / Int64 and Float32 get/set), as exporters declare solver settings."""
    first = len(layout.slots) + 3
    layout.variables.append(_Var(METHOD_PARAMETER, first, causality="parameter", variability="fixed",
                                 start=[float(METHOD_START)], type="Enumeration", enumeration=METHOD_TYPE,
                                 description="the exporter's solver (no effect on the model)"))
    if layout.fmi3:
        layout.variables.append(_Var(TOLERANCE_PARAMETER, first + 1, causality="parameter", variability="fixed",
                                     start=[TOLERANCE_START], type="Float32",
                                     description="the exporter's solver tolerance (no effect on the model)"))


def _discrete_vr(layout: _Layout, name: str) -> int:
    """The value reference of a parameter of ``discrete_parameters`` or ``typed_parameters`` (that of no variable
    where there is none)."""
    return next((v.vr for v in layout.variables if v.name == name), len(layout.slots) + 5)


def _enable_vr(layout: _Layout) -> int:
    """The value reference of the ``enable`` input (that of no slot where there is none)."""
    return next((v.vr for v in layout.variables if v.name == ENABLE_INPUT and v.type == "Boolean"), len(layout.slots))


def _source_tree(layout: _Layout, options: _Options, model: LinearMechanicalModel,
                 coords: _Coordinates, chain: MassChain | None) -> tuple[dict[str, bytes], str]:
    folder = _lti_sources_dir()
    files: dict[str, bytes] = {}
    api = _API_SOURCES[options.fmi_version]
    for name in _KERNEL_SOURCES + (api, "lti.h"):
        files["sources/" + name] = (folder / name).read_bytes()
    for header in _FMI_HEADERS[options.fmi_version]:
        files["sources/" + header] = (_fmi_header_dir() / header).read_bytes()
    sources = list(_KERNEL_SOURCES) + [api, "lti_model.c"]
    templates = {"sources/lti_model.c": _model_source(layout, options, model, coords, chain)}
    if options.fmi_version == "2.0":
        templates["modelDescription.xml"] = _model_description2(layout, options, sources)
    else:
        templates["modelDescription.xml"] = _model_description3(layout, options)
        files["sources/buildDescription.xml"] = _build_description3(options, sources).encode()
    return files, stamp_guid(files, templates, _GUID_NAMESPACE)


def _existing_guid(path: Path) -> str | None:
    try:
        with zipfile.ZipFile(path) as archive:
            text = archive.read("modelDescription.xml").decode("utf-8", "replace")
    except (OSError, KeyError, zipfile.BadZipFile):
        return None
    match = re.search(r'\b(?:guid|instantiationToken)="([^"]*)"', text)
    return match.group(1) if match else None


def build_lti_fmu(model: LinearMechanicalModel | MassChain, path: str | os.PathLike, *,
                  fmi_version: Literal["2.0", "3.0"] = "2.0",
                  interfaces: Sequence[str] = ("me", "cs"),
                  cs_method: CsMethod = "accurate", naming: Naming = "modelica",
                  relative: bool = False, parameter_inputs: Sequence[str] = (),
                  expose_accelerations: bool = True, units: bool | None = None,
                  identifier: str | None = None, description: str | None = None,
                  stop_time: float = 1.0, output_units: bool = False,
                  declared_types: bool = False, input_sensors: bool = False,
                  output_array: bool = False, output_aliases: bool = False,
                  input_array: bool = False, interleaved: bool = False,
                  dependencies: bool = True, stale_derivatives: bool = False, late_outputs: bool = False,
                  steady_state_start: bool = False,
                  time_event: TimeEvent | None = None, state_event: StateEvent | None = None,
                  completed_step_gap: float | None = None, completed_step_event_at: float | None = None,
                  completed_step_event_every: bool = False,
                  discrete_inputs: Sequence[int] = (), cs_fixed_step: float | None = None,
                  cs_fixed_step_enforced: bool = True, cs_max_step: float | None = None,
                  cs_early_return_at: float | None = None, cs_terminate_at: float | None = None,
                  me_terminate_at: float | None = None, completed_step_terminate_at: float | None = None,
                  position_limit: tuple[int, float] | None = None, position_limit_status: str = "error",
                  single_precision: bool | str = False, enable_input: bool = False,
                  strict_stop_time: bool = False, discrete_parameters: bool = False,
                  typed_parameters: bool = False, reuse: bool = True) -> LtiFmu:
    """Generate and compile an FMU of a linear mechanical system in an exporter's style.

    Parameters
    ----------
    model : LinearMechanicalModel or MassChain
        The system; a :class:`MassChain` (with ``naming="array"``) gives an FMU whose size is
        the structural parameter ``n``.
    path : str or PathLike
        The ``.fmu`` file to write.
    fmi_version : {"2.0", "3.0"}, default="2.0"
    interfaces : sequence of {"me", "cs"}, default=("me", "cs")
        Model exchange and/or co-simulation (one binary serves both).
    cs_method : {"accurate", "euler", "rk4"}, default="accurate"
        Co-simulation: RK4 substeps with ``w h_sub = tol^(1/4)`` (``w`` a bound of the
        largest frequency, ``tol`` the tolerance given to setupExperiment /
        enterInitializationMode, 1e-4 if none), ONE explicit Euler step per
        communication step, or ONE RK4 step per communication step (stable only for steps
        below about ``2.8 / omega_max``: an FMU that overflows at coarse steps and converges at fine ones).
    naming : {"modelica", "generic", "array"}, default="modelica"
        Variable conventions (module docstring); "array" needs FMI 3.0.
    relative : bool, default=False
        Modelica naming only: states are ``spring[i].s_rel = x_i - x_(i-1)`` and ``v_rel``;
        absolute positions, velocities, accelerations are computed locals ``mass[i].s/v/a``.
    parameter_inputs : sequence of {"mass_scale", "stiffness_scale"}, default=()
        Scale parameters exposed with causality input (continuous), as some exporters do;
        the others are ordinary fixed parameters.  ``mass_scale = 0`` is a division by zero.
    expose_accelerations : bool, default=True
        If False (co-simulation only), no ``der()`` variables, no accelerations and no
        ``Derivatives`` in the model structure: the importer must derive accelerations.
    units : bool, default=None
        Declare SI units; default: all namings but "generic".
    identifier : str, default=None
        Model identifier; default ``model.name``.
    description : str, default=None
        Model description.
    stop_time : float, default=1
        ``DefaultExperiment/@stopTime`` (deliberately unrelated to the dynamics; no step size unless
        ``cs_fixed_step``).
    output_units : bool, default=False
        Declare the unit of each output that measures one kind of quantity (``m``, ``m/s``,
        ``m/s2``; ``N`` for force sensors); needs ``units``.
    declared_types : bool, default=False
        Modelica style: units sit on type definitions (``Modelica.Units.SI.Position`` ...) that
        the variables name in ``declaredType``, not on the variables.
    input_sensors : bool, default=False
        One more output per force input that reports it (``forceSensor.f``, or ``u_meas1 ..``):
        a direct feedthrough ``y = u``, listed after the outputs of the model in
        :attr:`LtiFmu.outputs`.
    output_array : bool, default=False
        FMI 3.0: the outputs are one array variable ``y`` of fixed size p (elements
        ``y[1] .. y[p]``).
    output_aliases : bool, default=False
        Every output also has an alias ``sensor[k].y`` (FMI 3: an ``<Alias>`` child; FMI 2: a
        local variable of the same value reference); an output array gets the alias
        ``sensors``.
    input_array : bool, default=False
        FMI 3.0: the force inputs are one array variable of fixed size m (elements ``F[1] ..``).
    interleaved : bool, default=False
        Modelica naming: the states, their ``der()`` variables and the state vector go body by
        body (``mass[1].s, mass[1].v, mass[2].s, ...``), as tools that sort states by component.
    dependencies : bool, default=True
        Declare the structural ``dependencies`` of outputs and state derivatives (exact zeros);
        False leaves them out (every unknown may depend on everything).
    stale_derivatives : bool, default=False
        Co-simulation: after ``doStep`` the derivative variables of the velocity states return their values
        from before the step until an input is set (a defect of some generated LTI FMUs, spec
        ``real-fmus.md``; without inputs nothing refreshes them).
    steady_state_start : bool, default=False
        Leave initialization at the static equilibrium under the inputs set in initialization mode (velocities 0),
        whatever the start values (Modelica's steady-state initialization): the start state depends on the initial
        input.
    late_outputs : bool, default=False
        Co-simulation: the outputs are computed at the start of each ``doStep`` only, so after it they are the
        values of the communication point before (one step late; the states are not).
    time_event : TimeEvent, optional
        A force that switches on at a time event.  Model exchange: announced as the next event
        time and applied in the event iteration there.  Co-simulation meets it exactly (the
        ``doStep`` that contains it is split there).
    state_event : StateEvent, optional
        A force latched on when a position first crosses a threshold (one event indicator).
        Model exchange: applied in the event iteration after the crossing, which the importer
        must locate.  Co-simulation looks at the indicator only at the end of each ``doStep``
        (the force starts at the communication point after the crossing, as simple exporters do).
    completed_step_gap : float, optional
        Model exchange: the FMU declares that it needs ``fmiCompletedIntegratorStep`` after every integrator
        step (FMI 2: ``completedIntegratorStepNotNeeded="false"``, FMI 3: ``needsCompletedIntegratorStep="true"``)
        and refuses ``fmiSetTime`` more than this many seconds after the last one, as the buffer of a Modelica
        ``delay()`` would: an importer that calls it once per communication step fails at a step longer than this.
        It also refuses a time before the last completed step (FMI: a completed step is never taken back).
    completed_step_event_at : float, optional
        Model exchange: the first completed integrator step at or after this time asks for event mode (whose event
        iteration changes nothing); also declares the need for completed steps.
    completed_step_event_every : bool, default=False
        With ``completed_step_event_at``: every completed step from then on asks for event mode, not only the
        first (FMI allows it; some exports do it to re-check their discrete state).
    discrete_inputs : sequence of int, default=()
        Force inputs (indices) declared with ``variability="discrete"``, which model exchange may change only in
        event mode (FMI 2.0 section 3.2.3): the FMU refuses a new value in continuous-time mode.
    cs_fixed_step : float, optional
        Co-simulation at one fixed communication step, as fixed-step code generators export: declared as
        ``DefaultExperiment/@stepSize`` with ``canHandleVariableCommunicationStepSize="false"``, and
        ``doStep`` returns an error for any other step (also for its multiples).
    cs_fixed_step_enforced : bool, default=True
        With ``cs_fixed_step``: ``False`` declares the fixed step but runs at any constant step (FMI asks no more
        of an FMU that cannot vary its step).
    cs_max_step : float, optional
        Co-simulation with an embedded solver's maximum step: ``doStep`` returns ``fmi2Discard`` /
        ``fmi3Discard`` (and logs why) for a longer step; the FMU stays usable.
    cs_early_return_at : float, optional
        FMI 3 co-simulation that breaks the standard, as some exporters' do: the ``fmi3DoStep`` whose step
        contains this time stops there and returns ``earlyReturn = true`` with that ``lastSuccessfulTime``, although
        the importer did not allow early return (the FMU declares ``mightReturnEarlyFromDoStep="true"``).
    cs_terminate_at : float, optional
        Co-simulation of a model that ends its simulation at this time (a Simulink stop time, a Modelica
        ``terminate()``): FMI 3 ``fmi3DoStep`` sets ``terminateSimulation`` once its time reaches this one; FMI 2
        ``fmi2DoStep`` stops there, logs why and returns ``fmi2Discard``, and then
        ``fmi2GetBooleanStatus(fmi2Terminated)`` answers true and ``fmi2GetRealStatus(fmi2LastSuccessfulTime)`` this
        time (without the option the FMU refuses ``fmi2GetBooleanStatus``, as many exporters' FMUs do).
    me_terminate_at : float, optional
        Model exchange (FMI 2 and 3) of a model that calls ``terminate()`` at a time event, as Modelica's
        ``when time >= T then terminate("...")``: the event is announced, and its event iteration logs the model's
        message and sets ``terminateSimulation``.
    completed_step_terminate_at : float, optional
        Model exchange (FMI 2 and 3) of a model whose stop is checked in its accepted integrator steps: it needs
        ``fmiCompletedIntegratorStep``, and the first completed step at or after this time logs the model's message
        and sets ``terminateSimulation`` (inside a communication interval, wherever the importer's integrator put
        that step).
    position_limit : (int, float), optional
        ``(dof, bound)``: every evaluation of the model asserts ``|x[dof]| <= bound`` (m), as a Modelica ``assert``
        on a variable's range does; beyond it the call returns an error and the instance stays in error (FMI 2.0
        section 2.1.3), whatever is called next.
    position_limit_status : {"error", "discard"}, default="error"
        What a call beyond ``position_limit`` returns: ``"error"`` as above, or ``"discard"``: ``fmi2Discard`` /
        ``fmi3Discard`` (and logs why), the instance staying usable, as a model does for a state outside its domain.
    single_precision : bool or "partial", default=False
        The derivatives are computed from the state rounded to ``float`` and returned rounded to ``float``, as an
        export for an embedded target may compute (the rounding noise is 6e-8 of their terms).  ``"partial"``:
        only the stiffness forces on the first half of the degrees of freedom are, from the positions rounded to
        ``float`` (one single-precision block beside double-precision ones, whose derivatives follow every move).
    enable_input : bool, default=False
        A Boolean input ``enable`` (start false, discrete) without which the force inputs do not act, as a drive's
        enable or a Simulink enabled subsystem: the model rests until an importer sets it true.  It is not in
        :attr:`LtiFmu.inputs` (the force inputs).
    strict_stop_time : bool, default=False
        Keep the stop time given to ``fmi2SetupExperiment`` / ``fmi3EnterInitializationMode`` with no slack, as
        some generated FMUs do: a ``doStep`` whose end (``currentCommunicationPoint + communicationStepSize``), or
        a model-exchange ``SetTime``, past it returns an error and logs why (audit 77a, F3).
    discrete_parameters : bool, default=False
        Two more parameters without effect on the model, as exporters declare solver settings: the Integer (FMI 3:
        Int32) ``solverOrder`` (start 4) and the Boolean ``useCache`` (start true), set by ``fmi2SetInteger`` /
        ``fmi3SetInt32`` and ``fmi2SetBoolean`` / ``fmi3SetBoolean``.
    typed_parameters : bool, default=False
        More parameters without effect on the model, of the types exporters declare solver choices with: the
        Enumeration ``solverMethod`` (type ``Solvers.Method``, items euler = 1, rk4 = 2, dassl = 3; start 2), set by
        ``fmi2SetInteger`` / ``fmi3SetInt64`` and refused at a value no item has, and, FMI 3, the Float32 ``relTol``
        (start 1e-4), set by ``fmi3SetFloat32``.
    reuse : bool, default=True
        Keep an existing file at ``path`` whose GUID (a hash of every generated file) matches.

    Returns
    -------
    LtiFmu
        The path and the names of what the FMU exposes.

    Raises
    ------
    FmuBuildError
        Invalid options, missing CMake or compiler, or a compilation error.
    """
    chain = model if isinstance(model, MassChain) else None
    concrete = chain.model() if chain else model
    options = _Options(
        fmi_version=fmi_version, interfaces=tuple(interfaces), cs_method=cs_method,
        naming=naming, relative=relative, parameter_inputs=tuple(parameter_inputs),
        expose_accelerations=expose_accelerations,
        units=naming != "generic" if units is None else bool(units),
        identifier=identifier or concrete.name,
        description=description or _default_description(concrete, chain, naming, relative),
        stop_time=float(stop_time), output_units=bool(output_units),
        declared_types=bool(declared_types), input_sensors=bool(input_sensors),
        output_array=bool(output_array), output_aliases=bool(output_aliases),
        input_array=bool(input_array), interleaved=bool(interleaved),
        dependencies=bool(dependencies), stale_derivatives=bool(stale_derivatives),
        late_outputs=bool(late_outputs), steady_state_start=bool(steady_state_start),
        time_event=time_event, state_event=state_event,
        completed_step_gap=None if completed_step_gap is None else float(completed_step_gap),
        completed_step_event_at=None if completed_step_event_at is None else float(completed_step_event_at),
        completed_step_event_every=bool(completed_step_event_every), discrete_inputs=tuple(discrete_inputs),
        cs_fixed_step=None if cs_fixed_step is None else float(cs_fixed_step),
        cs_fixed_step_enforced=bool(cs_fixed_step_enforced),
        cs_max_step=None if cs_max_step is None else float(cs_max_step),
        cs_early_return_at=None if cs_early_return_at is None else float(cs_early_return_at),
        cs_terminate_at=None if cs_terminate_at is None else float(cs_terminate_at),
        me_terminate_at=None if me_terminate_at is None else float(me_terminate_at),
        completed_step_terminate_at=None if completed_step_terminate_at is None else float(completed_step_terminate_at),
        position_limit=None if position_limit is None else (int(position_limit[0]), float(position_limit[1])),
        position_limit_status=str(position_limit_status),
        single_precision=single_precision if isinstance(single_precision, str) else bool(single_precision),
        enable_input=bool(enable_input), strict_stop_time=bool(strict_stop_time),
        discrete_parameters=bool(discrete_parameters), typed_parameters=bool(typed_parameters))
    _check_options(model, options)
    coords = _coordinates(concrete, relative)
    layout, names = _layout(concrete, coords, chain, options)
    files, guid = _source_tree(layout, options, concrete, coords, chain)
    path = Path(path)
    result = LtiFmu(path=path, model=concrete, fmi_version=fmi_version,
                    interfaces=options.interfaces, cs_method=cs_method, naming=naming,
                    states=list(layout.states), derivatives=list(layout.derivatives),
                    structural_parameter="n" if chain else None, guid=guid, time_event=time_event,
                    state_event=state_event, **names)
    if reuse and path.is_file() and _existing_guid(path) == guid:
        return result
    write_fmu(files, path)
    return result


def _default_description(model: LinearMechanicalModel, chain: MassChain | None, naming: str,
                         relative: bool) -> str:
    if chain is not None:
        return (f"chain of n masses (default {chain.n}, at most {chain.n_max}), FMI 3 arrays "
                "sized by a structural parameter")
    text = f"linear mechanical system, n={model.n} m={model.m} p={model.p}, {naming} naming"
    if relative:
        text += ", relative coordinates"
    if model.G is not None:
        text += f", {model.nc} {model.constraint} constraint(s) reduced to an ODE"
    return text


# ------------------------------------------------------------------------ corpus

#: FMUs of :func:`build_corpus`, one per exporter convention of the spec
CORPUS_NAMES = (
    "me-only", "cs-euler", "modelica-der-aliases", "generic-lti", "relative-coordinates",
    "parameters-as-inputs", "fmi3-array-structural", "no-inputs", "no-accelerations",
    "offset-equilibrium", "start-off-rest", "acceleration-output", "constrained-bar",
)


def chain_model(n: int = 5, *, inputs: Sequence[int] = (-1,), force_offset: float = 0.0,
                x0=None, v0=None, acceleration_outputs: Sequence[int] = (),
                output_offset: float = 0.0, name: str = "Chain") -> LinearMechanicalModel:
    """A fixed-free chain of ``n`` unequal masses with Rayleigh damping, periods of a few seconds.

    Masses ``1 + 0.25 sin(i)``-like values (0.8 .. 1.5 kg), springs of 15 .. 30 N/m,
    ``D = 0.05 M + 0.01 K`` (modal damping about 1.5 .. 5 %).  Outputs: position of the last
    mass, velocity of the first, then accelerations of the given masses (direct feedthrough
    if an input acts there).

    Parameters
    ----------
    n : int, default=5
        Number of masses.
    inputs : sequence of int, default=(-1,)
        Masses (Python indices) with a force input; ``()`` for none.
    force_offset : float, default=0
        Constant force on every mass (N): equilibrium away from zero.
    x0, v0 : array_like (n,), optional
        Start values (default zero).
    acceleration_outputs : sequence of int, default=()
        Masses whose acceleration is an output.
    output_offset : float, default=0
        Offset added to every output.
    name : str, default="Chain"
        Model name.

    Returns
    -------
    LinearMechanicalModel
    """
    masses = np.array([1.0, 1.5, 0.8, 1.2, 1.0, 0.9, 1.3, 1.1])[np.arange(n) % 8]
    springs = np.array([30.0, 25.0, 20.0, 25.0, 15.0, 22.0, 18.0, 28.0])[np.arange(n) % 8]
    K = np.diag(springs + np.r_[springs[1:], 0.0])
    K -= np.diag(springs[1:], 1) + np.diag(springs[1:], -1)
    M = np.diag(masses)
    B = np.zeros((n, len(inputs)))
    for j, dof in enumerate(inputs):
        B[dof, j] = 1.0
    rows = 2 + len(acceleration_outputs)
    Cp, Cv, Ca = np.zeros((rows, n)), np.zeros((rows, n)), np.zeros((rows, n))
    Cp[0, -1] = 1.0
    Cv[1, 0] = 1.0
    for k, dof in enumerate(acceleration_outputs):
        Ca[2 + k, dof] = 1.0
    return LinearMechanicalModel(M=M, D=0.05 * M + 0.01 * K, K=K, B=B,
                                 f0=force_offset * np.ones(n), Cp=Cp, Cv=Cv, Ca=Ca,
                                 y0=output_offset * np.ones(rows), x0=x0, v0=v0, name=name)


def support_chain_model(n: int = 6, *, source: Literal["position", "speed", "accelerate"] = "position",
                        f_crit: float = 50.0, name: str | None = None) -> LinearMechanicalModel:
    """:func:`chain_model`'s chain (no force input) whose first spring and damper attach to a moving support, an
    ideal motion source whose input is the support's motion (base excitation), as Modelica models it.

    The support is coordinate ``n + 1`` (``ideal_sources=1``): it drives the chain and does not feel it.
    ``"position"``: ``Translational.Sources.Position(exact=false)``, the critically damped filter
    ``s'' + 2 w s' + w^2 s = w^2 s_ref`` (``w = 2 pi f_crit``, input in m); ``"speed"``: ``Speed(exact=false)``,
    ``v' = w (v_ref - v)``, ``s' = v`` (input in m/s; the support's position is free: a rigid-body mode);
    ``"accelerate"``: ``Accelerate``, ``s'' = a_ref`` (input in m/s2; an undamped free body).
    Outputs: the last mass relative to the support, the first spring's elongation (mass 1 relative to the
    support), the last mass's absolute acceleration.

    Parameters
    ----------
    n : int, default=6
        Number of masses.
    source : {"position", "speed", "accelerate"}, default="position"
        The motion source.
    f_crit : float, default=50
        The filter's critical frequency (Hz), Modelica's default; ignored for ``"accelerate"``.
    name : str, optional
        Model name; default ``Support_<source>``.

    Returns
    -------
    LinearMechanicalModel
    """
    chain = chain_model(n, inputs=())
    k0 = chain.K[0, 0] + (chain.K[0, 1] if n > 1 else 0.0)  # the first spring (to the wall in chain_model)
    d0 = chain.D[0, 0] + (chain.D[0, 1] if n > 1 else 0.0) - 0.05 * chain.M[0, 0]
    M, D, K = (np.zeros((n + 1, n + 1)) for _ in range(3))
    M[:n, :n], D[:n, :n], K[:n, :n], M[n, n] = chain.M, chain.D, chain.K, 1.0
    K[0, n], D[0, n] = -k0, -d0
    w, B = 2.0 * np.pi * f_crit, np.zeros((n + 1, 1))
    if source == "position":
        D[n, n], K[n, n], B[n, 0] = 2.0 * w, w * w, w * w
    elif source == "speed":
        D[n, n], B[n, 0] = w, w
    elif source == "accelerate":
        B[n, 0] = 1.0
    else:
        raise DimensionError(f"source={source!r} is unknown; use 'position', 'speed' or 'accelerate'")
    Cp, Ca = np.zeros((3, n + 1)), np.zeros((3, n + 1))
    Cp[0, n - 1], Cp[0, n], Cp[1, 0], Cp[1, n], Ca[2, n - 1] = 1.0, -1.0, 1.0, -1.0, 1.0
    return LinearMechanicalModel(M=M, D=D, K=K, B=B, Cp=Cp, Ca=Ca, ideal_sources=1,
                                 name=name or f"Support_{source}")


def corpus_models() -> dict[str, tuple[LinearMechanicalModel | MassChain, dict]]:
    """The model and the :func:`build_lti_fmu` options of each corpus FMU.

    Returns
    -------
    dict
        ``name -> (model, options)`` for every name of :data:`CORPUS_NAMES`.
    """
    off_rest = dict(x0=[0.05, -0.02, 0.03, 0.0, 0.04], v0=[0.0, 0.1, 0.0, -0.05, 0.0])
    bar = np.zeros((1, 5))
    bar[0, 1], bar[0, 3] = 1.0, -1.0    # masses 2 and 4 tied by a rigid bar: x_2 = x_4
    both = ("mass_scale", "stiffness_scale")
    return {
        "me-only": (chain_model(name="MeOnly"), dict(interfaces=("me",))),
        "cs-euler": (chain_model(name="CsEuler", **off_rest),
                     dict(interfaces=("cs",), cs_method="euler")),
        "modelica-der-aliases": (chain_model(inputs=(1, -1), name="DerAliases", **off_rest), {}),
        "generic-lti": (chain_model(force_offset=0.5, name="GenericLti", **off_rest),
                        dict(naming="generic")),
        "relative-coordinates": (chain_model(name="Relative", **off_rest), dict(relative=True)),
        "parameters-as-inputs": (chain_model(name="ParameterInputs"),
                                 dict(parameter_inputs=both)),
        "fmi3-array-structural": (MassChain(n=5, n_max=64, force_offset=0.2,
                                            start_position=0.01, acceleration_sensor=True,
                                            name="ArrayChain"),
                                  dict(fmi_version="3.0", naming="array")),
        "no-inputs": (chain_model(inputs=(), name="FreeResponse", **off_rest), {}),
        "no-accelerations": (chain_model(name="NoAccelerations", **off_rest),
                             dict(interfaces=("cs",), expose_accelerations=False)),
        "offset-equilibrium": (chain_model(force_offset=1.0, name="OffsetEquilibrium"),
                               dict(fmi_version="3.0")),
        "start-off-rest": (chain_model(name="StartOffRest", **off_rest), {}),
        "acceleration-output": (chain_model(acceleration_outputs=(-1, 0), output_offset=0.1,
                                            name="AccelerationOutput"), {}),
        "constrained-bar": (replace(chain_model(name="RigidBar"), G=bar, constraint="position",
                                    x0=[0.05, 0.02, 0.0, 0.02, 0.03]), {}),
    }


def build_corpus(out_dir: str | os.PathLike, names: Sequence[str] | None = None, *,
                 jobs: int | None = None) -> dict[str, LtiFmu]:
    """Build the corpus FMUs ``<out_dir>/<name>.fmu`` (existing up-to-date files are kept).

    =========================  =======  ==========  ================================================
    name                       FMI      interfaces  convention
    =========================  =======  ==========  ================================================
    me-only                    2.0      me          model exchange only
    cs-euler                   2.0      cs          one explicit Euler step per doStep
    modelica-der-aliases       2.0      me, cs      der(mass[i].s) alias of mass[i].v, mass[i].a, m=2
    generic-lti                2.0      me, cs      x1..x10, der_x1.., x1_start.., offset force
    relative-coordinates       2.0      me, cs      spring[i].s_rel/v_rel states, mass[i].s locals
    parameters-as-inputs       2.0      me, cs      mass_scale, stiffness_scale with causality input
    fmi3-array-structural      3.0      me, cs      arrays x, v (size = structural parameter n)
    no-inputs                  2.0      me, cs      m = 0, free response from start values
    no-accelerations           2.0      cs          no der() variables, no Derivatives
    offset-equilibrium         3.0      me, cs      f0 != 0, <Alias> mass[i].a
    start-off-rest             2.0      me, cs      x0, v0 != 0
    acceleration-output        2.0      me, cs      outputs a_5, a_1 (feedthrough from F), y0
    constrained-bar            2.0      me, cs      x_2 = x_4 reduced to an ODE, mass[4] computed
    =========================  =======  ==========  ================================================

    Parameters
    ----------
    out_dir : str or PathLike
        Target folder.
    names : sequence of str, optional
        Subset of :data:`CORPUS_NAMES` (default all).
    jobs : int, optional
        Parallel builds (default: the number of CPUs).

    Returns
    -------
    dict
        ``name -> LtiFmu`` (with its :class:`LinearMechanicalModel` in ``.model``).
    """
    definitions = corpus_models()
    names = CORPUS_NAMES if names is None else tuple(names)
    unknown = [name for name in names if name not in definitions]
    if unknown:
        raise FmuBuildError(f"unknown corpus FMU(s) {', '.join(unknown)}; choose from "
                            f"{', '.join(CORPUS_NAMES)}")
    def build(name: str) -> LtiFmu:
        model, options = definitions[name]
        return build_lti_fmu(model, Path(out_dir) / f"{name}.fmu", **options)

    workers = max(1, min(int(jobs) if jobs else (os.cpu_count() or 1), len(names)))
    with ThreadPoolExecutor(max_workers=workers) as pool:   # compilers run as subprocesses
        return dict(zip(names, pool.map(build, names)))
