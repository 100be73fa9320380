"""The exact zero-order-hold step of a linear model-exchange FMU: the integrator for stiff models.

A finite-element model of a structure has modes far faster than anything its outputs show (a beam: 5 rad/s to
3e5 rad/s).  An explicit integrator is held to the stability limit of the fastest of them, and an implicit one
restarted at every communication point (where the held input jumps) re-estimates its Jacobian there; both crawl
(docs/real-fmus.md: 20 s per sample).  fmu-opinf's models are linear, ``der(z) = A z + g(u)``, and for a
linear model the step over an interval of held input is exact:

    z(t + h) = z(t) + P(h) f(z(t)),   P(h) = int_0^h exp(A s) ds = h phi_1(h A),

where ``f`` is the FMU's own derivative with the new input in effect, so the input never has to be identified.
``A`` is identified once per run from ``n + 1`` derivative evaluations (exact differences for a linear model);
``P`` comes with ``exp(h A)`` from one matrix exponential (Van Loan's block form) per step size.  A step costs two derivative evaluations and three ``n x n`` products, whatever the stiffness.

Nothing is taken on trust: after each step the FMU's derivative at the new state, ``f1``, and at the state
half-way (:meth:`LinearHold.step_and_midpoint`: the map of ``h / 2`` is the exponential, squared once for ``h``)
are compared with the linear model's, ``f0 + A (z - z0)``, and the first step of a run probes the derivative at
three more times at its start state (an internal source periodic in the step is zero at the step's start, middle
and end).  These are samples, not a proof: a nonlinearity the trajectory meets and leaves between them is not seen
(``--me-method dop853`` is the safe choice for a model known to have stops or contacts).  A difference ``d``
that grows linearly over the step moves the state by
``h phi_2(h A) d`` (the variation-of-constants integral of the difference); where that exceeds the integrator's
absolute tolerance beyond the FMU's own rounding, the model is not linear (or not time-invariant) there, and
:class:`LinearHold` says so, and the caller integrates that step, and the rest of the run, with DOP853.
"""

from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

__all__ = ["LinearHold", "spectral_radius", "exact_step_pays", "dop853_seconds", "STIFFNESS_RATIO", "MAX_STATES", "CARRY_MAX_STATES"]

#: ``auto`` considers the exact step where ``rho(A) h`` exceeds this: DOP853's stability bound (about 3.3 for
#: ``|h lambda|`` on the negative real axis) then forces over 70 steps of 12 evaluations per communication step.
STIFFNESS_RATIO = 250.0

#: Below :data:`STIFFNESS_RATIO` and above this, ``auto`` still weighs the exact step where DOP853 is predicted to
#: take over :data:`LONG_RUN_SECONDS` for the run: a mildly stiff model of many states (audit 62: a 600-state FE bar
#: at ``rho(A) h = 124`` ran DOP853 for 160 s of compare, 53 s with the exact step).  DOP853 then takes about 40
#: steps of 12 evaluations per sample.
MILD_STIFFNESS_RATIO = 30.0
LONG_RUN_SECONDS = 10.0

#: Largest number of states for which ``auto`` takes the exact step: its matrix exponential, of size 2n, took
#: 10-25 s and 1.1 GB at n = 2000 on the reference machine; at n = 4000 about 8 times the time, 4 times the memory.
MAX_STATES = 4000

#: Largest number of states for which a step's defect is carried to the end state exactly (:meth:`LinearHold.carry`,
#: a matrix exponential of size 3n: about 10 matrices of 72 MB at n = 1000, 9.8 GB at n = 4000); above it, by the
#: bound ``|h phi_2(h A) d| <= h |d| / 2`` of a dissipative normal ``A``, which may hand a stiff model over sooner.
CARRY_MAX_STATES = 1000

#: Seconds of the matrix exponential per ``(2n)^3`` (scipy's expm on the reference machine: 10.5 s at n = 2000 idle,
#: 25 s under load and with a larger norm).
_EXPM_SECONDS_PER_CUBE = 3e-10

#: ``auto`` takes the exact step only where it is predicted to take at most this fraction of DOP853's time: both
#: predictions are coarse (DOP853 took 32 s where 54 s were predicted, on a chain of 4000 states), and a choice near
#: the break-even gains little while the wrong one at that size costs minutes (audit of 2026-12-05: 142 s against 32).
_EXACT_STEP_MARGIN = 0.5


def exact_step_pays(n: int, rho_h: float, samples: int, evaluation_seconds: float) -> bool:
    """Whether ``auto`` takes the exact step: a stiff model (``rho(A) h`` above :data:`STIFFNESS_RATIO`, or above
    :data:`MILD_STIFFNESS_RATIO` where DOP853 would take over :data:`LONG_RUN_SECONDS`) of at most
    :data:`MAX_STATES` states whose predicted recording time is shorter than DOP853's.

    DOP853 is held to about ``rho(A) h / 3.3`` steps of 12 derivative evaluations per sample; the exact step costs
    ``n + 4`` evaluations and one matrix exponential of size ``2n`` to set up, then three evaluations per sample;
    it must be predicted to take at most :data:`_EXACT_STEP_MARGIN` of DOP853's time.
    """
    dop853 = samples * dop853_seconds(rho_h, evaluation_seconds)
    stiff = rho_h > STIFFNESS_RATIO or (rho_h > MILD_STIFFNESS_RATIO and dop853 > LONG_RUN_SECONDS)
    if n > MAX_STATES or not stiff:
        return False
    exact = (n + 4 + 3 * samples) * evaluation_seconds + _EXPM_SECONDS_PER_CUBE * (2.0 * n) ** 3
    return exact < _EXACT_STEP_MARGIN * dop853


def dop853_seconds(rho_h: float, evaluation_seconds: float) -> float:
    """Predicted seconds of DOP853 over a step ``h`` of a model whose Jacobian has spectral radius ``rho``: its
    stability bound (about 3.3 for ``|h lambda|`` on the negative real axis) holds it to about ``rho h / 3.3``
    steps of 12 derivative evaluations."""
    return 12.0 * (rho_h / 3.3) * evaluation_seconds


#: :meth:`LinearHold.identify` probes a column again where its rounding exceeds this fraction of its entries ...
_COLUMN_ACCURACY = 1e-13
#: ... with a move at most this many times the first.
_LARGEST_REPROBE = 1e6

#: Differences of the FMU's derivative from the linear model within this many times its rounding are rounding.
_NOISE_FACTOR = 64.0

#: Maps of step sizes other than the pinned one kept at most (an entry: four ``n x n`` matrices) ...
_CACHED_MAPS = 8
#: ... and bytes they may take (n = 4000: one entry of 512 MB).
_CACHED_BYTES = 256 * 2**20


def spectral_radius(jvp: Callable[[np.ndarray], np.ndarray], n: int, iterations: int = 40,
                    seed: int = 0) -> float:
    """Estimate the largest modulus of the eigenvalues of ``A`` from products ``jvp(v) = A v`` (power iteration).

    Parameters
    ----------
    jvp : callable
        ``v -> A v`` (here a directional difference of the FMU's derivatives).
    n : int
        Size of ``A``.
    iterations : int, default=40
        Products computed.
    seed : int, default=0
        Seed of the random start vector (the estimate is reproducible).

    Returns
    -------
    float
        The geometric mean growth of ``||A^k v||`` over the last half of the iterations, a estimate within a small
        factor of the spectral radius: enough to tell a stiff model from a mild one.
    """
    v = np.random.default_rng(seed).standard_normal(n)
    v /= np.linalg.norm(v)
    logs = []
    for _ in range(iterations):
        w = jvp(v)
        norm = float(np.linalg.norm(w))
        if not np.isfinite(norm) or norm == 0.0:
            return 0.0 if norm == 0.0 else np.inf
        logs.append(np.log(norm))
        v = w / norm
    tail = logs[len(logs) // 2:]
    return float(np.exp(np.mean(tail)))


class LinearHold:
    """Exact steps of ``der(z) = A z + g`` under held inputs, for a Jacobian ``A`` identified from the FMU.

    Parameters
    ----------
    A : ndarray (n, n)
        Jacobian of the FMU's derivatives with respect to its continuous states.
    """

    def __init__(self, A: np.ndarray) -> None:
        self.A = np.ascontiguousarray(A, dtype=float)
        self._abs_A = np.abs(self.A)
        self._maps: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._carries: dict[float, np.ndarray] = {}
        self._pinned: set[float] = set()
        #: seconds the last step map took (the cost of a map for another step size, which events ask for)
        self.map_seconds = math.nan

    def pin(self, h: float) -> None:
        """Keep the maps of the step ``h`` (the grid's) however many other step sizes events ask for."""
        self._pinned = {_key(h)}

    def has_map(self, h: float) -> bool:
        """Whether the map of the step ``h`` is at hand (no matrix exponential needed)."""
        return _key(h) in self._maps

    @classmethod
    def identify(cls, derivatives: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                 deltas: np.ndarray, origin: np.ndarray | None = None) -> "LinearHold":
        """Identify ``A`` column by column: ``(f(x + delta_j e_j) - f(x)) / delta_j``.

        For a linear model the difference is exact whatever ``delta_j``, up to the rounding of the two derivatives
        (in row ``i`` about ``eps (|A_i| |origin + x| + |f_i|)``, large about a large ``origin``) divided by
        ``delta_j``.  A column whose rounding so found exceeds :data:`_COLUMN_ACCURACY` of the largest entry of a
        row it is in is probed again with a larger move (at most :data:`_LARGEST_REPROBE` times the first): an
        inaccurate ``A`` is a real error of the step, which :meth:`defect` would see and hand over for (a chain at
        1e8 m with nominal moves of 1 m).  Each row's rounding is weighed against that row's entries, whose terms
        it sits among: weighed against the column's own entries, a stiff link's rounding in its rows made the soft
        columns beside it look inaccurate, and their second probe moved a state by 1665 times its nominal value,
        out of the range the model asserts, so that model never got the exact step (audit of 2026-12-05).
        """
        f0 = derivatives(x)
        deltas = np.asarray(deltas, dtype=float)
        A, largest = cls._columns(derivatives, x, f0, deltas, range(x.size))
        states = np.abs(x if origin is None else origin + x)
        rounding = 2.0 * np.finfo(float).eps * (np.abs(A) @ (states + deltas) + largest)   # per row
        row_scale = np.abs(A).max(axis=1)
        rows = row_scale > 0
        wanted = float(np.max(rounding[rows] / (_COLUMN_ACCURACY * row_scale[rows]), initial=0.0))
        again = np.flatnonzero((wanted > deltas) & np.abs(A).any(axis=0))
        if again.size:
            moves = deltas.copy()
            moves[again] = np.minimum(wanted, _LARGEST_REPROBE * deltas[again])
            A[:, again] = cls._columns(derivatives, x, f0, moves, again)[0][:, again]
        return cls(A)

    @staticmethod
    def _columns(derivatives: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                 deltas: np.ndarray, columns) -> tuple[np.ndarray, np.ndarray]:
        """The difference quotients of ``columns`` (others zero) and the largest derivatives met."""
        n = x.size
        A = np.zeros((n, n))
        largest = np.abs(f0)
        probe = x.copy()
        for j in columns:
            probe[j] = x[j] + deltas[j]
            column = derivatives(probe)
            np.maximum(largest, np.abs(column), out=largest)
            A[:, j] = (column - f0) / (probe[j] - x[j])
            probe[j] = x[j]
        return A, largest

    def maps(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        """``(exp(h A), h phi_1(h A))`` for the step ``h`` (computed once per step size, with those of ``h / 2``:
        :meth:`step_and_midpoint`)."""
        return self._step_maps(h)[:2]

    def _step_maps(self, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``exp(h A), h phi_1(h A)`` and the same for ``h / 2``, from one matrix exponential (of ``h / 2``)."""
        key = _key(h)
        found = self._maps.get(key)
        if found is None:
            n = self.A.shape[0]
            started = time.perf_counter()
            row = self._top_row(0.5 * key, 2)   # blocks exp(hA/2) and int_0^(h/2) exp(As) ds
            E, P = np.ascontiguousarray(row[:, :n]), np.ascontiguousarray(row[:, n:])
            # [[E, P], [0, I]] squared is [[E E, P + E P], [0, I]]: the last squaring of the exponential itself
            found = (E @ E, P + E @ P, E, P)
            self.map_seconds = time.perf_counter() - started
            self._remember(self._maps, key, found)
        else:
            self._maps[key] = self._maps.pop(key)   # most recently used last
        return found

    def step_and_midpoint(self, x0: np.ndarray, f0: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
        """The states after ``h / 2`` and after ``h`` from ``x0`` (:meth:`step`): the caller checks the FMU at
        both, so that a nonlinearity the step passes through between its ends is seen (audit of 2026-12-05: an
        end stop reached only between two samples went unnoticed, the recording 2 % off)."""
        _, P, _, P_half = self._step_maps(h)
        return x0 + P_half @ f0, x0 + P @ f0

    def carry(self, h: float) -> np.ndarray:
        """``h phi_2(h A)``: a difference ``(s / h) d`` of the derivative growing over the step moves the end state by
        ``h phi_2(h A) d``.  Needed only where a step's defect is not plainly small, so computed then."""
        key = _key(h)
        found = self._carries.get(key)
        if found is None:
            n = self.A.shape[0]
            found = np.ascontiguousarray(self._top_row(key, 3)[:, 2 * n:]) / key   # h^2 phi_2(hA) / h
            self._remember(self._carries, key, found)
        return found

    def _top_row(self, h: float, blocks: int) -> np.ndarray:
        """The first block row of the exponential of ``h [[A, I, 0, ..], [0, 0, I, ..], .., [0, .., 0]]`` (size
        ``blocks n``): ``exp(hA), h phi_1(hA), h^2 phi_2(hA), ..`` (Van Loan's block form)."""
        from scipy.linalg import expm

        n = self.A.shape[0]
        block = np.zeros((blocks * n, blocks * n))
        block[:n, :n] = h * self.A
        for k in range(1, blocks):
            block[(k - 1) * n:k * n, k * n:(k + 1) * n] = h * np.eye(n)
        return expm(block)[:n]

    def _remember(self, cache: dict, key: float, value) -> None:
        """Cache ``value``, dropping the least recently used entries beyond :data:`_CACHED_MAPS` and beyond
        :data:`_CACHED_BYTES`, never the pinned step's (an event splits a step into two of other sizes; a crossing
        search tries a dozen)."""
        entry = sum(part.nbytes for part in (value if isinstance(value, tuple) else (value,)))
        keep = max(1, min(_CACHED_MAPS, _CACHED_BYTES // max(entry, 1)))
        if key not in cache:
            for old in [k for k in cache if k not in self._pinned][:max(0, len(cache) + 1 - keep)]:
                del cache[old]
        cache[key] = value

    def step(self, x0: np.ndarray, f0: np.ndarray, h: float) -> np.ndarray:
        """The state after ``h`` from ``x0``, where the FMU's derivative with the held input is ``f0``."""
        return x0 + self.maps(h)[1] @ f0

    def defect(self, x0: np.ndarray, x1: np.ndarray, f0: np.ndarray, f1: np.ndarray, origin: np.ndarray,
               h: float, allowed: np.ndarray) -> float:
        """How far a step from ``x0`` to ``x1`` (deviations from ``origin``) is off where the FMU is not the
        linear model, as a multiple of ``allowed`` (per state; 0: no difference above rounding).

        The FMU's derivatives ``f0, f1`` at the ends differ from the linear model's by
        ``d = f1 - f0 - A (x1 - x0)``; the part of ``d`` above the derivatives' rounding, growing over the step,
        moves the end state by ``h phi_2(h A) d`` (:meth:`carry`), which is at most about ``h |d|`` where ``A`` is
        dissipative, the plain case checked first.  Zero for a linear model (the matrix exponential's own rounding
        is not measured here: it is that of the exact solution, tests/test_linear_hold.py)."""
        difference = f1 - f0 - self.A @ (x1 - x0)
        states = np.abs(origin + x0) + np.abs(origin + x1)
        rounding = _NOISE_FACTOR * np.finfo(float).eps * (self._abs_A @ states + np.abs(f0) + np.abs(f1))
        difference[np.abs(difference) <= rounding] = 0.0
        if not difference.any():
            return 0.0
        if h * float(np.abs(difference).max()) <= 0.5 * float(allowed.min()):
            return 0.0
        if self.A.shape[0] > CARRY_MAX_STATES:
            return float(np.max(0.5 * h * np.abs(difference) / allowed))
        return float(np.max(np.abs(self.carry(h) @ difference) / allowed))


def _key(h: float) -> float:
    """The step size a map is computed and cached for: steps of one grid differ in their last bits."""
    return float(f"{h:.13g}")
