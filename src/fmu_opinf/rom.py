"""The reduced second-order model (paper eq. 11, with an offset force and output terms) learned by operator
inference, and its file.

    ``Mr q'' + Dr q' + Kr q = Br u + fr``,   ``y = Cpr q + Cvr q' + Dur u + y0``,   full states ``x ~ x_ref + V q``.

The paper's model is the case ``fr = 0, Dur = 0, y0 = 0, x_ref = 0``.  Models exported by real tools need the
extra terms (``shared/spec/real-fmus.md``): the static equilibrium under zero input is not at zero (unstretched
spring lengths, fixed flanges away from 0, gravity: ``fr``), acceleration sensors feed the input through
(``Dur``), outputs carry offsets (``y0``), and the model starts from its own start values, neither at rest nor
at equilibrium (``q0, qdot0``).

``x_ref`` is the reference state of the full positions (:mod:`fmu_opinf.fit` says which state it is and why).

Coordinates.  A ROM refined from the mechanical realization of the least-squares fit (:mod:`fmu_opinf.inference`,
*Least-squares candidate*) lives in modal coordinates ``q_m``: its ``coordinates`` matrix ``W`` (2r x 2r) gives the
POD coordinates ``[q; q'] = W [q_m; q_m']``, so ``x ~ x_ref + V (W_qq q_m + W_qv q_m')``.  Without ``W`` (every
other ROM) the ROM's coordinates are the POD ones.

A ROM is saved as one HDF5 file (layout :data:`LAYOUT_VERSION`, ``docs/file-format.md``): root attributes
``kind, layout_version, basis_kind, dt, input_names, output_names, provenance (JSON), fit_info (JSON)``; datasets
``Mr, Dr, Kr, Br, Cpr, Cvr, fr, Dur, y0, q0, qdot0, x_ref`` and optionally ``basis (n, r)``, ``singular_values``
and (layout 3) ``coordinates (2r, 2r)``.  Layout-1 files (no extra terms) still load, with the extra terms zero;
layout-2 files have no ``coordinates``.
"""

from __future__ import annotations

import functools
import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import h5py
import numpy as np
import scipy.linalg

from . import _threads
from ._hdf5 import atomic_h5, checksummed, jsonable, read_attrs, unreadable_file, write_attrs
from ._seal import check_seal
from ._validate import check_rom_file, damaged_file_errors, either
from .errors import DataError, DimensionError, FileFormatError

if TYPE_CHECKING:
    from .signals import Signal

__all__ = ["SecondOrderROM", "ROMTrajectory", "LAYOUT_VERSION"]

#: Version of the ROM file layout written by :meth:`SecondOrderROM.save`.
LAYOUT_VERSION = 3
#: Older layouts this version reads (layout 1: no ``fr, Dur, y0, q0, qdot0, x_ref``; they load as zeros; layout 2:
#: no ``coordinates``, the POD coordinates).
READABLE_LAYOUTS = (1, 2, 3)
FILE_KIND = "fmu-opinf rom"
#: The way out of a ROM file whose operators break the invariants of :func:`check_operators`.
DAMAGED_ROM_FIX = "the file is damaged or was edited: restore it from a copy or re-fit the ROM with 'fmu-opinf fit'"
_MATRICES = ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr")
_EXTRA_TERMS = ("fr", "Dur", "y0", "q0", "qdot0", "x_ref")
#: The terms beyond the paper's model that ``fmu_opinf.fit.fit_rom(terms=...)`` can fit.
TERMS = ("fr", "Dur", "y0")
#: Time discretizations of a ROM (:class:`SecondOrderROM`, ``integrator``).
INTEGRATORS = ("newmark", "exact")


class ROMTrajectory:
    """A ROM simulation: ``t (k,)``, inputs in effect ``u (m, k)``, outputs ``y (p, k)``, reduced states
    ``q, qdot, qddot (r, k)`` (same timing convention as :class:`fmu_opinf.newmark.Trajectory`).

    The states may be given, or formed on first access of ``q``, ``qdot`` or ``qddot`` by ``states`` (a
    function returning the stacked ``[q; qdot; qddot] (3r, k)``, called at most once): :meth:`SecondOrderROM.simulate`
    computes the outputs alone, which costs a fraction of forming the states.

    Parameters
    ----------
    t, u, y : ndarray
    q, qdot, qddot : (r, k) ndarray, optional
        The states; when left out, ``states`` forms them.
    states : callable, optional
        ``states() -> (3r, k) ndarray``.
    """

    def __init__(self, t: np.ndarray, u: np.ndarray, y: np.ndarray, q: np.ndarray | None = None,
                 qdot: np.ndarray | None = None, qddot: np.ndarray | None = None, *,
                 states: Callable[[], np.ndarray] | None = None) -> None:
        if (q is None or qdot is None or qddot is None) and states is None:
            raise DimensionError("ROMTrajectory needs q, qdot and qddot, or states to form them")
        self.t, self.u, self.y = t, u, y
        self._parts = None if q is None or qdot is None or qddot is None else (q, qdot, qddot)
        self._states = states

    def _part(self, i: int) -> np.ndarray:
        if self._parts is None:
            stacked = self._states()
            r = stacked.shape[0] // 3
            self._parts = (stacked[:r], stacked[r:2 * r], stacked[2 * r:])
            self._states = None                      # the step map and inputs it holds are no longer needed
        return self._parts[i]

    @property
    def q(self) -> np.ndarray:
        """Reduced positions ``(r, k)``."""
        return self._part(0)

    @property
    def qdot(self) -> np.ndarray:
        """Reduced velocities ``(r, k)``."""
        return self._part(1)

    @property
    def qddot(self) -> np.ndarray:
        """Reduced accelerations ``(r, k)``."""
        return self._part(2)

    @property
    def states_formed(self) -> bool:
        """Whether ``q, qdot, qddot`` exist yet (they are formed on first access)."""
        return self._parts is not None

    def __repr__(self) -> str:
        formed = "formed" if self.states_formed else "formed on first access"
        return f"ROMTrajectory(steps={self.t.size - 1}, m={self.u.shape[0]}, p={self.y.shape[0]}, states {formed})"


class SecondOrderROM:
    """Reduced second-order model ``Mr q'' + Dr q' + Kr q = Br u + fr``, ``y = Cpr q + Cvr q' + Dur u + y0``.

    Eq. (11) of the paper plus the terms real models need (module docstring); full states ``x ~ x_ref + V q``.

    Parameters
    ----------
    Mr, Dr, Kr : (r, r) ndarray
        Reduced mass, damping and stiffness (symmetric positive (semi)definite when learned by eq. 16).
    Br : (r, m) ndarray
        Reduced input matrix (``m = 0``: a model without inputs).
    Cpr, Cvr : (p, r) ndarray
    basis : (n, r) ndarray, optional
        POD modes ``V`` (or None when not kept).
    basis_kind : {"positions", "velocities"}, default="positions"
        Which snapshots spanned the basis.
    input_names, output_names : list of str, optional
        Default ``u[1..m]``, ``y[1..p]``.
    dt : float, optional
        Training time step.
    provenance : dict, optional
        Snapshot provenance, fit settings, fit date.
    fit_info : dict, optional
        Solver report of the fit.
    singular_values : (N,) ndarray, optional
        Singular values of the training snapshot matrix the basis came from.
    fr : (r,) ndarray, optional
        Constant reduced force (equilibrium away from ``x_ref``); default zero.
    Dur : (p, m) ndarray, optional
        Direct feedthrough; default zero.
    y0 : (p,) ndarray, optional
        Output offset; default zero.
    q0, qdot0 : (r,) ndarray, optional
        Initial reduced state: where :meth:`simulate` starts by default (the source's initial state); default rest.
    x_ref : (n,) ndarray, optional
        Reference position of the reduced coordinates (needs ``basis`` to be useful); default zero.
    integrator : {"newmark", "exact"}, default="newmark"
        Time discretization of :meth:`simulate` (and of the exported FMU): the paper's classical Newmark
        scheme, which reproduces a Newmark full-order model exactly, or the exact solution of the reduced ODE
        under zero-order-hold inputs (matrix exponential), for continuous-time sources (see
        :func:`fmu_opinf.fit.fit_rom`).
    coordinates : (2r, 2r) ndarray, optional
        ``W`` with ``[q_pod; q_pod'] = W [q; q']``: the POD coordinates of the ROM's state (module docstring,
        *Coordinates*); default None, the ROM's coordinates are the POD ones.
    """

    def __init__(
        self,
        Mr: np.ndarray,
        Dr: np.ndarray,
        Kr: np.ndarray,
        Br: np.ndarray,
        Cpr: np.ndarray,
        Cvr: np.ndarray,
        basis: np.ndarray | None = None,
        basis_kind: str = "positions",
        input_names: list[str] | None = None,
        output_names: list[str] | None = None,
        dt: float | None = None,
        provenance: dict | None = None,
        fit_info: dict | None = None,
        singular_values: np.ndarray | None = None,
        *,
        fr: np.ndarray | None = None,
        Dur: np.ndarray | None = None,
        y0: np.ndarray | None = None,
        q0: np.ndarray | None = None,
        qdot0: np.ndarray | None = None,
        x_ref: np.ndarray | None = None,
        integrator: str = "newmark",
        coordinates: np.ndarray | None = None,
    ) -> None:
        self.Mr, self.Dr, self.Kr = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (Mr, Dr, Kr))
        r = self.Mr.shape[0]
        self.Br = np.asarray(Br, dtype=float).reshape(r, -1)
        self.Cpr = np.atleast_2d(np.asarray(Cpr, dtype=float))
        self.Cvr = np.atleast_2d(np.asarray(Cvr, dtype=float))
        self.basis = None if basis is None else np.asarray(basis, dtype=float)
        self.basis_kind = basis_kind
        m, p = self.Br.shape[1], self.Cpr.shape[0]
        self.fr = _vector(fr, r)
        Dur = np.zeros((p, m)) if Dur is None else np.asarray(Dur, dtype=float)
        self.Dur = Dur.reshape(p, m) if Dur.size == p * m else Dur
        self.y0 = _vector(y0, p)
        self.q0, self.qdot0 = _vector(q0, r), _vector(qdot0, r)
        n = self.basis.shape[0] if self.basis is not None and self.basis.ndim == 2 else 0
        self.x_ref = _vector(x_ref, n) if x_ref is not None or n else np.zeros(0)
        if integrator not in INTEGRATORS:
            raise DimensionError(f"integrator={integrator!r} is not known; use one of {', '.join(INTEGRATORS)}")
        self.integrator = integrator
        self.coordinates = None if coordinates is None else np.atleast_2d(np.asarray(coordinates, dtype=float))
        self.input_names = list(input_names) if input_names is not None else [f"u[{i + 1}]" for i in range(self.m)]
        self.output_names = list(output_names) if output_names is not None else [f"y[{i + 1}]" for i in range(self.p)]
        self.dt = None if dt is None else float(dt)
        self.provenance = dict(provenance or {})
        self.fit_info = dict(fit_info or {})
        self.singular_values = None if singular_values is None else np.asarray(singular_values, dtype=float)
        self._check()

    def _check(self) -> None:
        r, m, p = self.r, self.m, self.p
        expected = {"Mr": (r, r), "Dr": (r, r), "Kr": (r, r), "Br": (r, m), "Cpr": (p, r), "Cvr": (p, r),
                    "fr": (r,), "Dur": (p, m), "y0": (p,), "q0": (r,), "qdot0": (r,)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if value.shape != shape:
                raise DimensionError(f"{name} has shape {value.shape}; expected {shape} for r={r}, m={m}, p={p}")
            if not np.all(np.isfinite(value)):
                raise DataError(f"{name} contains NaN/Inf; the ROM is unusable, refit it")
        if self.basis is not None and (self.basis.ndim != 2 or self.basis.shape[1] != r):
            raise DimensionError(f"basis has shape {self.basis.shape}; expected (n, {r})")
        if self.basis is not None and self.x_ref.shape != (self.basis.shape[0],):
            raise DimensionError(f"x_ref has shape {self.x_ref.shape}; expected ({self.basis.shape[0]},) like the basis")
        if not np.all(np.isfinite(self.x_ref)):
            raise DataError("x_ref contains NaN/Inf; the ROM is unusable, refit it")
        if self.coordinates is not None:
            if self.coordinates.shape != (2 * r, 2 * r):
                raise DimensionError(f"coordinates has shape {self.coordinates.shape}; expected {(2 * r, 2 * r)}")
            if not np.all(np.isfinite(self.coordinates)) or np.linalg.cond(self.coordinates) > 1e12:
                raise DataError("coordinates is not a finite invertible map; the ROM is unusable, refit it")
        if len(self.input_names) != m or len(self.output_names) != p:
            raise DimensionError(f"{len(self.input_names)} input / {len(self.output_names)} output names "
                                 f"for m={m} inputs and p={p} outputs")
        if self.basis_kind not in ("positions", "velocities"):
            raise DimensionError(f"basis_kind={self.basis_kind!r}; expected 'positions' or 'velocities'")

    # --- sizes ---------------------------------------------------------------------------------------------
    @property
    def r(self) -> int:
        """Reduced order."""
        return self.Mr.shape[0]

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self.Br.shape[1]

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self.Cpr.shape[0]

    def __repr__(self) -> str:
        extra = [name for name in TERMS if np.any(getattr(self, name))]
        terms = f", terms={extra}" if extra else ""
        return (f"SecondOrderROM(r={self.r}, m={self.m}, p={self.p}, basis_kind={self.basis_kind!r}, "
                f"dt={self.dt}{terms})")

    # --- simulation ----------------------------------------------------------------------------------------
    def initial_state(self, x0: np.ndarray | None = None, v0: np.ndarray | None = None,
                      tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Reduced initial state of a full-order initial state: ``q0 = V^T (x0 - x_ref)``, ``qdot0 = V^T v0``.

        Parameters
        ----------
        x0, v0 : (n,) ndarray, optional
            Full-order initial positions and velocities; each one not given keeps the ROM's own (:attr:`q0`,
            :attr:`qdot0`, the training source's initial state).
        tol : float, default=1e-6
            Largest relative part of ``x0 - x_ref`` (and ``v0``) outside the span of the basis.  A state with
            more lies off the training data's subspace, e.g. it violates the position constraint, which every
            basis vector satisfies.

        Returns
        -------
        q0, qdot0 : (r,) ndarray
            In the ROM's coordinates (the POD ones mapped by :attr:`coordinates`, if any).
        """
        q0, qdot0 = self._pod_state(self.q0, self.qdot0)
        for label, value, ref in (("positions", x0, self.x_ref), ("velocities", v0, None)):
            if value is None:
                continue
            if self.basis is None:
                raise DimensionError("this ROM was saved without its basis; give the reduced initial state instead")
            value = np.asarray(value, dtype=float).reshape(-1)
            if value.shape != (self.basis.shape[0],):
                raise DimensionError(f"initial {label} have {value.size} entries; expected n={self.basis.shape[0]}")
            shifted = value - ref if ref is not None else value
            reduced = self.basis.T @ shifted
            outside = float(np.linalg.norm(shifted - self.basis @ reduced))
            if outside > tol * max(float(np.linalg.norm(value)), float(np.linalg.norm(shifted)), 1e-300):
                raise DataError(f"the initial {label} lie off the ROM's subspace (relative part outside "
                                f"{outside / max(np.linalg.norm(shifted), 1e-300):.1e}): they violate the constraint, "
                                f"were never in the training data, or need more than the ROM's r={self.r} basis "
                                "vectors (a start the training shared but the truncated basis misses); start from a "
                                f"consistent state, or fit with a larger r ({either('--r')}, {either('--energy')})")
            if ref is not None:
                q0 = reduced
            else:
                qdot0 = reduced
        if self.coordinates is None:
            return q0, qdot0
        state = np.linalg.solve(self.coordinates, np.concatenate([q0, qdot0]))
        return state[:self.r], state[self.r:]

    def _pod_state(self, q: np.ndarray, qdot: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """POD coordinates of the ROM state ``(q, q')`` (the same arrays without :attr:`coordinates`)."""
        if self.coordinates is None:
            return q, qdot
        if qdot is None:
            raise DimensionError("this ROM lives in modal coordinates (coordinates is set): positions need the "
                                 "velocities too; pass qdot")
        W, r = self.coordinates, self.r
        return W[:r, :r] @ q + W[:r, r:] @ qdot, W[r:, :r] @ q + W[r:, r:] @ qdot

    def simulate(self, signal: Signal | str, dt: float, t_end: float, q0: np.ndarray | None = None,
                 qdot0: np.ndarray | None = None) -> ROMTrajectory:
        """Simulate from the initial state, input held over each step, with the ROM's :attr:`integrator`:
        classical Newmark (beta=1/4, gamma=1/2) or the exact solution under the held input.

        Parameters
        ----------
        signal : fmu_opinf.signals.Signal or str
            Input; strings are parsed by :func:`fmu_opinf.signals.parse_signal` (``"none"``: no forcing).
        dt, t_end : float
            Step and end time (a whole number of steps).
        q0, qdot0 : (r,) ndarray, optional
            Reduced initial state; default :attr:`q0`, :attr:`qdot0` (the training source's initial state,
            rest for the paper's benchmarks), moved to the static equilibrium under the first input where the
            source starts at its equilibrium under whatever inputs it is initialized under
            (:meth:`steady_start`; as the exported FMU does).  Use :meth:`initial_state` for a full-order one.

        Returns
        -------
        ROMTrajectory
            ``t (k,)``, ``u (m, k)``, ``y (p, k)``, ``q, qdot, qddot (r, k)``.  Only the outputs are computed
            here; the states are formed on first access of ``q``, ``qdot`` or ``qddot`` (the same values as if
            formed here; at r = 35 they cost about ten times the outputs, ``benchmarks/bench_rom.py``).
        """
        from ._recursion import rom_evaluate

        t, u, step, s0 = self._prepared_run(signal, dt, t_end, q0, qdot0)
        # the step is one linear map, evaluated in blocks of steps (fmu_opinf._recursion); the outputs alone
        # are far cheaper than the states, which are formed only if asked for; small matrices: one BLAS thread
        with _threads.single_threaded():
            outputs = np.hstack([self.Cpr, self.Cvr, np.zeros_like(self.Cpr)])
            y = rom_evaluate(step, s0, u, outputs) + self.Dur @ u + self.y0[:, None]
        states = functools.partial(_threads.run_single_threaded, rom_evaluate, step, s0, u)  # picklable
        return ROMTrajectory(t=t, u=u, y=y, states=states)

    def _prepared_run(self, signal: Signal | str, dt: float, t_end: float, q0: np.ndarray | None = None,
                      qdot0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, Any, np.ndarray]:
        """The grid, the inputs in effect, the step map and the initial state ``[q; q'; q'']`` of
        :meth:`simulate` (whose docstring says how the initial state is chosen)."""
        from ._recursion import rom_step
        from .newmark import applied_inputs, time_grid
        from .signals import parse_signal

        signal = parse_signal(signal, self.m, self.input_names, held_input_names(self.provenance))
        if signal.n_inputs != self.m:
            raise DimensionError(f"signal has {signal.n_inputs} inputs; the ROM has m={self.m}")
        t = time_grid(dt, t_end)
        u = applied_inputs(signal, t)
        if q0 is None and qdot0 is None and isinstance(following := self.steady_start(), tuple):
            gain, first_input = following   # the source's start follows the inputs it is initialized under
            q0 = self.q0 + gain @ (u[:, 0] - first_input)
        q0 = self.q0 if q0 is None else _vector(q0, self.r)
        qdot0 = self.qdot0 if qdot0 is None else _vector(qdot0, self.r)
        qddot0 = scipy.linalg.solve(self.Mr, self.Br @ u[:, 0] + self.fr - self.Dr @ qdot0 - self.Kr @ q0,
                                    assume_a="sym")
        with _threads.single_threaded():
            step = rom_step(self, dt)
        return t, u, step, np.concatenate([q0, qdot0, qddot0])

    def step_map(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Exact zero-order-hold step of the reduced ODE (``integrator="exact"``) as one linear map.

        ``s+ = Phi s + Gamma [u; 1]`` for ``s = [q; q'; q'']`` with the input ``u`` held over the step: ``q, q'``
        from the matrix exponential of the first-order system (Van Loan's block form gives the input integral),
        ``q''`` from the equation of motion at the end of the step.  ``Phi`` has zero columns for ``q''``, so an
        input change needs no acceleration update.

        Returns
        -------
        Phi : (3r, 3r) ndarray
        Gamma : (3r, m + 1) ndarray
            The last column multiplies the constant 1 of the force ``fr``.
        """
        from .refinement import zero_order_hold_step

        r = self.r
        B = np.hstack([self.Br, self.fr[:, None]])
        Minv = scipy.linalg.solve(self.Mr, np.hstack([self.Kr, self.Dr, B]), assume_a="sym")
        E, F = zero_order_hold_step(self.Mr, self.Dr, self.Kr, B, dt)
        acc = -Minv[:, :2 * r]                      # q'' = acc [q; q'] + Minv_B [u; 1]
        phi = np.zeros((3 * r, 3 * r))
        phi[:2 * r, :2 * r] = E
        phi[2 * r:, :2 * r] = acc @ E
        gamma = np.vstack([F, acc @ F + Minv[:, 2 * r:]])
        return phi, gamma

    def reconstruct(self, q: np.ndarray, qdot: np.ndarray | None = None) -> np.ndarray:
        """Full-order positions ``x_ref + V q`` (``x_ref + V (W_qq q + W_qv q')`` with :attr:`coordinates`).

        Parameters
        ----------
        q : (r,) or (r, k) ndarray
        qdot : (r,) or (r, k) ndarray, optional
            Needed only by a ROM in modal coordinates (:attr:`coordinates` set).

        Returns
        -------
        (n,) or (n, k) ndarray
        """
        if self.basis is None:
            raise DimensionError("this ROM was saved without its basis; refit it to reconstruct full states")
        q = np.asarray(q, dtype=float)
        if q.shape[0] != self.r:
            raise DimensionError(f"q has {q.shape[0]} rows; expected r={self.r}")
        if qdot is not None and np.shape(qdot) != q.shape:
            raise DimensionError(f"qdot has shape {np.shape(qdot)}; expected {q.shape} like q")
        q_pod, _ = self._pod_state(q, None if qdot is None else np.asarray(qdot, dtype=float))
        shift = self.x_ref if q.ndim == 1 else self.x_ref[:, None]
        return self.basis @ q_pod + shift

    def steady_start(self) -> tuple[np.ndarray, np.ndarray] | str | None:
        """How the start follows the inputs at initialization, where the training source starts at its static
        equilibrium under whatever inputs it is initialized under (``initialization`` of the snapshots,
        :mod:`fmu_opinf.snapshots._initialization`; seventh audit, E3: a 10 N preload initialized under 5 N rests
        at the 5 N equilibrium).

        Returns
        -------
        (S, u_first) : ((r, m) ndarray, (m,) ndarray), str or None
            ``S = Kr^-1 Br`` and the first training run's start input: the start under inputs ``u`` is
            ``q0 + S (u - u_first)``.  A string says why the ROM cannot follow (a rigid-body mode, a recorded
            start input that does not fit); None where the source's start does not follow its inputs.
        """
        return steady_start(self.provenance, self.Kr, self.Br)

    def input_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``[min, max]`` the training source declared for each input: the range the ROM was trained in and the
        source accepts, which the exported ROM FMU declares (audit 58, finding 6).

        Read from the snapshots' ``input_min`` / ``input_max`` in the provenance (fits since 2026-12-06; a ROM
        fitted before has none, and its inputs are unbounded here and on its FMU as before).

        Returns
        -------
        (low, high) : ((m,) ndarray, (m,) ndarray)
            The bounds, ``-inf`` / ``inf`` where none was declared or recorded.
        """
        return input_ranges(self.provenance, self.m)

    def equilibrium(self) -> np.ndarray:
        """Static equilibrium under zero input: ``q_eq = Kr^-1 fr``, in full coordinates ``x_ref + V q_eq`` if the
        basis is kept (reduced coordinates otherwise).  Raises if ``Kr`` is singular (a mechanism)."""
        try:
            q_eq = scipy.linalg.solve(self.Kr, self.fr, assume_a="sym")
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            raise DataError("Kr is singular: the ROM has a rigid-body mode and no static equilibrium") from None
        return q_eq if self.basis is None else self.reconstruct(q_eq, np.zeros_like(q_eq))

    # --- stability -----------------------------------------------------------------------------------------
    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of the first-order form: ``det(lambda^2 Mr + lambda Dr + Kr) = 0``.

        Returns
        -------
        (2r,) complex ndarray
            Eigenvalues of ``[[0, I], [-Mr^-1 Kr, -Mr^-1 Dr]]`` (computed as a generalized problem, so a
            singular ``Mr`` gives infinite eigenvalues instead of an error).
        """
        r = self.r
        eye, zero = np.eye(r), np.zeros((r, r))
        A = np.block([[zero, eye], [-self.Kr, -self.Dr]])
        E = np.block([[eye, zero], [zero, self.Mr]])
        return scipy.linalg.eigvals(A, E)

    def is_stable(self, tol: float = 0.0, zero: float = 0.0) -> bool:
        """True if every finite eigenvalue has real part ``<= tol`` times the largest magnitude (and none is
        infinite); eigenvalues within ``zero`` times it of 0 count as zero poles (rigid-body motion, a drift that
        does not grow: an undamped rigid-body mode's double pole at 0 comes out as a pair ``+-1e-9`` of the scale,
        round-off of a defective eigenvalue, ``sqrt(eps)``).  With Mr SPD and Dr, Kr SPD the model is
        asymptotically stable."""
        lam = self.eigenvalues()
        if not np.all(np.isfinite(lam)):
            return False
        scale = max(float(np.abs(lam).max()), np.finfo(float).tiny)
        return bool(np.all((lam.real <= tol * scale) | (np.abs(lam) <= zero * scale)))

    # --- files ---------------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the ROM to an HDF5 file atomically (layout :data:`LAYOUT_VERSION`).

        Parameters
        ----------
        path : str or PathLike
        overwrite : bool, default=False
            Replace an existing file (otherwise ``FileExistsError``; ``--force`` on the command line).

        Returns
        -------
        Path
        """
        path = Path(path)
        with atomic_h5(path, overwrite=overwrite) as f:
            for name in _MATRICES + _EXTRA_TERMS + ("basis", "singular_values", "coordinates"):
                value = getattr(self, name)
                if value is not None:
                    f.create_dataset(name, data=value, **checksummed(np.shape(value)))
            write_attrs(f, {
                "kind": FILE_KIND,
                "layout_version": LAYOUT_VERSION,
                "basis_kind": self.basis_kind,
                "integrator": self.integrator,
                "dt": self.dt,
                "input_names": self.input_names,
                "output_names": self.output_names,
                "provenance": json.dumps(jsonable(self.provenance)),
                "fit_info": json.dumps(jsonable(self.fit_info)),
            })
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SecondOrderROM":
        """Read a ROM written by :meth:`save` (this layout or an older one, :data:`READABLE_LAYOUTS`).

        Raises
        ------
        FileFormatError
            Missing, unreadable or truncated file, wrong kind or layout version, missing or inconsistent data.
        DataError
            NaN/Inf in the stored matrices; ``Mr, Dr, Kr`` not symmetric, ``Mr`` not positive definite or
            ``Dr, Kr`` not positive semidefinite (:func:`check_operators`: the invariants ``export`` needs).
        """
        path = Path(path)
        if path.is_dir():
            raise FileFormatError(f"ROM file {path} is a directory; give the .h5 file that 'fmu-opinf fit' wrote")
        if not path.is_file():
            raise FileFormatError(f"ROM file {path} does not exist; write one with 'fmu-opinf fit'")
        try:
            with h5py.File(path, "r") as f:
                return cls._from_h5(f, path)
        except OSError as exc:
            raise unreadable_file(path, "ROM", "fmu-opinf fit", exc) from None

    @classmethod
    def _from_h5(cls, f: h5py.File, path: Path) -> "SecondOrderROM":
        check_rom_file(f, path)  # links, attribute types, sizes vs data and memory, finite values, shapes
        attrs = read_attrs(f)
        if attrs.get("kind") != FILE_KIND:
            raise FileFormatError(f"{path} is not an fmu-opinf ROM file (kind={attrs.get('kind')!r})")
        version = attrs.get("layout_version")
        if isinstance(version, bool) or version not in READABLE_LAYOUTS:
            raise FileFormatError(f"{path} has ROM layout version {version!r}; this tool reads versions "
                                  f"{', '.join(map(str, READABLE_LAYOUTS))}, refit the ROM or use a matching fmu-opinf")
        required = _MATRICES + (_EXTRA_TERMS if version >= 2 else ())
        missing = [name for name in required if name not in f]
        if missing:
            raise FileFormatError(f"{path} lacks {', '.join(missing)}; the ROM file is truncated or damaged")
        try:
            mats = {name: np.array(f[name][()], dtype=float) for name in required}
            basis = np.array(f["basis"][()], dtype=float) if "basis" in f else None
            sv = np.array(f["singular_values"][()], dtype=float) if "singular_values" in f else None
            coordinates = np.array(f["coordinates"][()], dtype=float) if "coordinates" in f and version >= 3 else None
            provenance, fit_info = (json.loads(attrs.get(key, "{}")) for key in ("provenance", "fit_info"))
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise FileFormatError(f"cannot read ROM data from {path} ({exc}); the file is damaged") from None
        if not isinstance(provenance, dict) or not isinstance(fit_info, dict):
            raise FileFormatError(f"{path}: provenance and fit_info must be JSON objects; the file is damaged")
        for name, value in mats.items():
            if not np.all(np.isfinite(value)):
                raise DataError(f"{path}: {name} contains NaN/Inf; the ROM is unusable, refit it")
        check_operators(mats["Mr"], mats["Dr"], mats["Kr"], where=f"{path}: ROM", fix=DAMAGED_ROM_FIX)
        with damaged_file_errors(path):
            check_seal(f, path)   # last: a change the checks above name is said in their words, any other here
        extra = {name: mats.pop(name) for name in _EXTRA_TERMS if name in mats}
        if "x_ref" in extra and extra["x_ref"].size == 0:
            extra["x_ref"] = None
        try:
            return cls(**mats, basis=basis, basis_kind=attrs.get("basis_kind", "positions"),
                       input_names=attrs.get("input_names"), output_names=attrs.get("output_names"),
                       dt=attrs.get("dt"), provenance=provenance, fit_info=fit_info, singular_values=sv,
                       integrator=attrs.get("integrator", "newmark"), coordinates=coordinates, **extra)
        except (DimensionError, ValueError) as exc:
            raise FileFormatError(f"{path}: inconsistent ROM data ({exc})") from None


#: Largest ``|A - A^T|`` of ``Mr, Dr, Kr`` relative to their largest entry: round-off (a fit stores them exactly
#: symmetric; a flipped byte or a hand edit breaks it, audit 62, finding 5).
SYMMETRY_TOL = 1e-10
#: Smallest eigenvalue of ``Mr`` relative to its largest one: below it ``Mr`` is not positive definite.
DEFINITE_TOL = 1e-12
#: Most negative eigenvalue of ``Dr``, ``Kr`` relative to their largest one: round-off of the SDP solver's
#: semidefinite iterate.
SEMIDEFINITE_TOL = 1e-6
#: Most negative eigenvalue of ``Dr``, ``Kr`` relative to the scale the other operators give them (``sqrt(|Mr| |Kr|)``
#: for a damping, ``|Dr|^2 / |Mr|`` for a stiffness; :func:`_semidefinite_tolerances`): round-off of an operator that
#: is (nearly) zero, such as the ``Dr`` of an undamped ROM, whose own largest eigenvalue is round-off too.
ROUNDOFF_TOL = 1e-12


def check_operators(Mr: np.ndarray, Dr: np.ndarray, Kr: np.ndarray, where: str = "ROM",
                    fix: str = "refit the ROM") -> None:
    """Refuse ``Mr, Dr, Kr`` that are not the operators of a second-order ROM (eq. 16).

    The one check of these invariants: loading a ROM file (:meth:`SecondOrderROM.load`) and exporting a ROM
    (:func:`fmu_opinf.export.rom_fmu_spec`) both run it, so a file ``export`` refuses is not simulated by
    ``compare`` either (audit 62, finding 5: a ROM file with flipped bytes in ``Kr`` was compared without a
    word).

    Parameters
    ----------
    Mr, Dr, Kr : ndarray
        Finite square matrices of one size ``(r, r)``, ``r >= 1``; symmetric to :data:`SYMMETRY_TOL`, ``Mr``
        positive definite (:data:`DEFINITE_TOL`), ``Dr``, ``Kr`` positive semidefinite
        (:func:`_semidefinite_tolerances`).
    where : str, default="ROM"
        What holds them, at the start of the message (a file name: ``"rom.h5: ROM"``).
    fix : str, default="refit the ROM"
        The way out the message ends with.

    Raises
    ------
    DataError
        One line naming ``where``, the matrix, the problem and ``fix``.
    """
    mats = {"Mr": np.asarray(Mr, dtype=float), "Dr": np.asarray(Dr, dtype=float), "Kr": np.asarray(Kr, dtype=float)}
    shape = mats["Mr"].shape
    for name, value in mats.items():
        if value.ndim != 2 or value.shape[0] != value.shape[1] or value.shape[0] == 0 or value.shape != shape:
            raise DataError(f"{where} matrix {name} has shape {value.shape}, expected a square (r, r) matrix like "
                            f"Mr {shape}; {fix}")
        if not np.all(np.isfinite(value)):
            raise DataError(f"{where} matrix {name} has NaN or infinite entries; {fix}")
    for name, value in mats.items():
        _check_symmetric(value, name, where, fix)
    eigs = {name: np.linalg.eigvalsh(0.5 * (value + value.T)) for name, value in mats.items()}
    tolerances = _semidefinite_tolerances(*(float(np.abs(eigs[name]).max()) for name in ("Mr", "Dr", "Kr")))
    for name, eig in eigs.items():
        _check_eigenvalues(eig, name, where, fix, tolerances.get(name, 0.0))


def _semidefinite_tolerances(m: float, d: float, k: float) -> dict[str, float]:
    """The most negative eigenvalue ``Dr`` and ``Kr`` may have, from the largest eigenvalue magnitudes ``m, d, k``
    of ``Mr, Dr, Kr``: :data:`SEMIDEFINITE_TOL` of its own, or :data:`ROUNDOFF_TOL` of the scale the other two
    give it where that is larger.

    A relative test alone refuses an operator that is round-off as a whole: the ``Dr`` of an undamped ROM (largest
    eigenvalue 7.7e-14 beside a ``Kr`` of 900) with an eigenvalue of -7.7e-17 was refused as damaged (audit 63,
    finding 9).  The scales are those of ``M s^2 + D s + K``: a damping's is ``sqrt(m k)`` (critical damping) and
    a stiffness's ``d^2 / m``, so both floors have their operator's units.  Below them a negative eigenvalue
    ``-e`` gives a growth rate ``e / 2m`` of at most 1e-12 of the fastest frequency ``sqrt(k / m)`` (damping), or
    ``sqrt(e / m)`` of at most 1e-6 of the fastest decay rate ``d / m`` (stiffness): round-off, not a model that
    grows.  Where the other operators are 0 the floor is 0 and the relative test stands as it was."""
    return {"Dr": max(SEMIDEFINITE_TOL * d, ROUNDOFF_TOL * np.sqrt(m * k)),
            "Kr": max(SEMIDEFINITE_TOL * k, ROUNDOFF_TOL * d * d / m if m > 0 else 0.0)}


def _check_symmetric(value: np.ndarray, name: str, where: str, fix: str) -> None:
    """``value`` equals its transpose to :data:`SYMMETRY_TOL` of its largest entry."""
    scale = max(float(np.abs(value).max()), np.finfo(float).tiny)
    asymmetry = float(np.abs(value - value.T).max())
    if asymmetry > SYMMETRY_TOL * scale:
        raise DataError(f"{where} matrix {name} is not symmetric (|{name} - {name}^T| = {asymmetry:.3g}, "
                        f"{asymmetry / scale:.2g} of its largest entry); a second-order ROM has symmetric operators, "
                        f"{fix}")


def _check_eigenvalues(eig: np.ndarray, name: str, where: str, fix: str, tolerance: float) -> None:
    """``Mr`` positive definite, ``Dr`` and ``Kr`` positive semidefinite: their eigenvalues ``eig`` not below
    ``-tolerance`` (:func:`_semidefinite_tolerances`)."""
    scale = float(np.abs(eig).max())
    if name == "Mr" and not (scale > 0 and eig.min() > DEFINITE_TOL * scale):
        raise DataError(f"{where} matrix Mr is not positive definite (eigenvalues {eig.min():.3g} .. "
                        f"{eig.max():.3g}); a second-order ROM has a positive definite mass, {fix}")
    if name != "Mr" and eig.min() < -tolerance:
        raise DataError(f"{where} matrix {name} has a negative eigenvalue {eig.min():.3g}; a learned {name} is "
                        f"positive semidefinite (eq. 16), {fix}")


def _vector(value: Any, size: int) -> np.ndarray:
    """``value`` as a float vector of ``size`` entries (zeros for None)."""
    if value is None:
        return np.zeros(size)
    array = np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (size,):
        raise DimensionError(f"vector has {array.size} entries; expected {size}")
    return array


def steady_start(provenance: dict, Kr: np.ndarray, Br: np.ndarray) -> tuple[np.ndarray, np.ndarray] | str | None:
    """:meth:`SecondOrderROM.steady_start` from a ROM's provenance and matrices (also of a ROM-like object)."""
    from .snapshots._initialization import STEADY_STATE

    m = Br.shape[1]
    snapshots = provenance.get("snapshots")
    found = snapshots.get("initialization") if isinstance(snapshots, dict) else None
    if not isinstance(found, dict) or found.get("kind") != STEADY_STATE or not m:
        return None
    try:
        first_input = np.asarray(found.get("input"), dtype=float).reshape(-1)
    except (TypeError, ValueError):
        first_input = np.empty(0)
    if first_input.shape != (m,) or not np.all(np.isfinite(first_input)):
        return (f"the training snapshots say the source starts at its static equilibrium, but their recorded "
                f"start input {found.get('input')!r} does not fit the ROM's {m} inputs")
    if np.linalg.cond(Kr) > 1e12:
        return ("the source starts at its static equilibrium under the inputs it is initialized under, but the "
                "ROM has a rigid-body mode (Kr singular) and no equilibrium")
    return scipy.linalg.solve(Kr, Br, assume_a="sym"), first_input


def held_input_names(provenance: dict) -> list[str]:
    """The inputs the training source held at their start values (not the ROM's inputs), from the snapshots in
    ``provenance``: a table column named after one of them is refused (:func:`fmu_opinf.signals.by_input_names`;
    audit 60: compare drove the force with it).  Data from a file: only a list of text counts."""
    snapshots = provenance.get("snapshots")
    names = snapshots.get("held_input_names") if isinstance(snapshots, dict) else None
    return [name for name in names if isinstance(name, str)] if isinstance(names, list) else []


def input_ranges(provenance: dict, m: int) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`SecondOrderROM.input_ranges` from a ROM's provenance (also of a ROM-like object).

    The provenance is data read from a file: only finite numbers are bounds; anything else (the text ``"inf"`` of a
    side the source left open, a list that does not fit the ``m`` inputs) is no bound, and an input whose recorded
    ``min`` lies above its ``max`` gets neither.
    """
    snapshots = provenance.get("snapshots")
    snapshots = snapshots if isinstance(snapshots, dict) else {}
    low = _recorded_bounds(snapshots.get("input_min"), m, -np.inf)
    high = _recorded_bounds(snapshots.get("input_max"), m, np.inf)
    crossed = low > high
    low[crossed], high[crossed] = -np.inf, np.inf
    return low, high


def _recorded_bounds(value: Any, m: int, default: float) -> np.ndarray:
    """One bound per input from a recorded list: its finite numbers, ``default`` for any other entry and for a
    list that does not have ``m`` entries."""
    out = np.full(m, default)
    if isinstance(value, (list, tuple)) and len(value) == m:
        for i, entry in enumerate(value):
            number = _finite_number(entry)
            if number is not None:
                out[i] = number
    return out


def _finite_number(value: Any) -> float | None:
    """``value`` as a float if it is a finite int or float (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    try:
        number = float(value)
    except OverflowError:   # an integer beyond the float range
        return None
    return number if math.isfinite(number) else None


def __getattr__(name: str) -> Any:
    """``fmu_opinf.rom.fit_rom`` and ``fit_rom_file``, where the fit stage lived before :mod:`fmu_opinf.fit`."""
    if name in ("fit_rom", "fit_rom_file"):
        from . import fit
        return getattr(fit, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
