"""The reduced second-order model (paper eq. 11) learned by operator inference, and the fit pipeline.

``Mr q'' + Dr q' + Kr q = Br u``,  ``y = Cpr q + Cvr q'``,  full states ``x ~ V q``.

:func:`fit_rom` is the one-call pipeline (POD basis eqs. 7/9 -> projection eq. 14 -> SDP eq. 16 -> outputs
eq. 17); :func:`fit_rom_file` is what ``fmu-opinf fit`` runs.  A ROM is saved as one HDF5 file (layout
:data:`LAYOUT_VERSION`): root attributes ``kind, layout_version, basis_kind, dt, input_names, output_names,
provenance (JSON), fit_info (JSON)``; datasets ``Mr, Dr, Kr, Br, Cpr, Cvr`` and optionally ``basis (n, r)`` and
``singular_values``.
"""

from __future__ import annotations

import datetime
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np
import scipy.linalg

from ._hdf5 import atomic_h5, jsonable, read_attrs, tool_versions, write_attrs
from ._validate import check_rom_file
from .basis import PODBasis, as_runs, project, read_columns, snapshot_attrs
from .errors import DataError, DimensionError, FileFormatError
from .inference import fit_operators, fit_outputs, lowpass_filter

__all__ = ["SecondOrderROM", "ROMTrajectory", "fit_rom", "fit_rom_file", "LAYOUT_VERSION"]

#: Version of the ROM file layout written by :meth:`SecondOrderROM.save`.
LAYOUT_VERSION = 1
FILE_KIND = "fmu-opinf rom"
_MATRICES = ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr")


@dataclass
class ROMTrajectory:
    """A ROM simulation: ``t (k,)``, inputs in effect ``u (m, k)``, outputs ``y (p, k)``, reduced states
    ``q, qdot, qddot (r, k)`` (same timing convention as :class:`fmu_opinf.newmark.Trajectory`)."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    qddot: np.ndarray


class SecondOrderROM:
    """Reduced second-order model ``Mr q'' + Dr q' + Kr q = Br u``, ``y = Cpr q + Cvr q'`` (eq. 11).

    Parameters
    ----------
    Mr, Dr, Kr : (r, r) ndarray
        Reduced mass, damping and stiffness (symmetric positive (semi)definite when learned by eq. 16).
    Br : (r, m) ndarray
    Cpr, Cvr : (p, r) ndarray
    basis : (n, r) ndarray, optional
        POD modes ``V``; ``x ~ V q`` (or None when not kept).
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
    ) -> None:
        self.Mr, self.Dr, self.Kr = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (Mr, Dr, Kr))
        self.Br = np.asarray(Br, dtype=float).reshape(self.Mr.shape[0], -1)
        self.Cpr = np.atleast_2d(np.asarray(Cpr, dtype=float))
        self.Cvr = np.atleast_2d(np.asarray(Cvr, dtype=float))
        self.basis = None if basis is None else np.asarray(basis, dtype=float)
        self.basis_kind = basis_kind
        self.input_names = list(input_names) if input_names is not None else [f"u[{i + 1}]" for i in range(self.m)]
        self.output_names = list(output_names) if output_names is not None else [f"y[{i + 1}]" for i in range(self.p)]
        self.dt = None if dt is None else float(dt)
        self.provenance = dict(provenance or {})
        self.fit_info = dict(fit_info or {})
        self.singular_values = None if singular_values is None else np.asarray(singular_values, dtype=float)
        self._check()

    def _check(self) -> None:
        r, m, p = self.r, self.m, self.p
        expected = {"Mr": (r, r), "Dr": (r, r), "Kr": (r, r), "Br": (r, m), "Cpr": (p, r), "Cvr": (p, r)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if value.shape != shape:
                raise DimensionError(f"{name} has shape {value.shape}; expected {shape} for r={r}, m={m}, p={p}")
            if not np.all(np.isfinite(value)):
                raise DataError(f"{name} contains NaN/Inf; the ROM is unusable, refit it")
        if self.basis is not None and (self.basis.ndim != 2 or self.basis.shape[1] != r):
            raise DimensionError(f"basis has shape {self.basis.shape}; expected (n, {r})")
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
        return f"SecondOrderROM(r={self.r}, m={self.m}, p={self.p}, basis_kind={self.basis_kind!r}, dt={self.dt})"

    # --- simulation ----------------------------------------------------------------------------------------
    def simulate(self, signal: Any, dt: float, t_end: float) -> ROMTrajectory:
        """Classical Newmark (beta=1/4, gamma=1/2) from rest, input held over each step (zero-order hold).

        Parameters
        ----------
        signal : fmu_opinf.signals.Signal or str
            Input; strings are parsed by :func:`fmu_opinf.signals.parse_signal`.
        dt, t_end : float
            Step and end time (a whole number of steps).

        Returns
        -------
        ROMTrajectory
            ``t (k,)``, ``u (m, k)``, ``y (p, k)``, ``q, qdot, qddot (r, k)``.
        """
        from .newmark import NewmarkStepper, applied_inputs, step_matrices, time_grid
        from .signals import parse_signal

        signal = parse_signal(signal, self.m)
        if signal.n_inputs != self.m:
            raise DimensionError(f"signal has {signal.n_inputs} inputs; the ROM has m={self.m}")
        t = time_grid(dt, t_end)
        u = applied_inputs(signal, t)
        stepper = NewmarkStepper(self.Mr, self.Dr, self.Kr, self.Br, dt)
        stepper.start(u[:, 0])
        # the step is one linear map (newmark.step_matrices): a 3r x 3r product per step instead of solves
        phi, gamma_new, gamma_old = step_matrices(self.Mr, self.Dr, self.Kr, self.Br, dt)
        forcing = gamma_new @ u[:, 1:] + gamma_old @ u[:, :-1]
        states = np.empty((3 * self.r, t.size))
        states[:, 0] = np.concatenate([stepper.x, stepper.v, stepper.a])
        for i in range(1, t.size):
            states[:, i] = phi @ states[:, i - 1] + forcing[:, i - 1]
        q, qdot, qddot = states[:self.r], states[self.r:2 * self.r], states[2 * self.r:]
        y = self.Cpr @ q + self.Cvr @ qdot
        return ROMTrajectory(t=t, u=u, y=y, q=q, qdot=qdot, qddot=qddot)

    def reconstruct(self, q: np.ndarray) -> np.ndarray:
        """Full-order states ``V q``.

        Parameters
        ----------
        q : (r,) or (r, k) ndarray

        Returns
        -------
        (n,) or (n, k) ndarray
        """
        if self.basis is None:
            raise DimensionError("this ROM was saved without its basis; refit it to reconstruct full states")
        q = np.asarray(q, dtype=float)
        if q.shape[0] != self.r:
            raise DimensionError(f"q has {q.shape[0]} rows; expected r={self.r}")
        return self.basis @ q

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

    def is_stable(self, tol: float = 0.0) -> bool:
        """True if every finite eigenvalue has real part ``<= tol`` times the largest magnitude (and none is
        infinite).  With Mr SPD and Dr, Kr SPD the model is asymptotically stable."""
        lam = self.eigenvalues()
        if not np.all(np.isfinite(lam)):
            return False
        scale = max(float(np.abs(lam).max()), np.finfo(float).tiny)
        return bool(np.all(lam.real <= tol * scale))

    # --- files ---------------------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the ROM to an HDF5 file atomically (layout :data:`LAYOUT_VERSION`).

        Parameters
        ----------
        path : str or PathLike
        overwrite : bool, default=False
            Replace an existing file (otherwise ``FileExistsError``).

        Returns
        -------
        Path
        """
        path = Path(path)
        with atomic_h5(path, overwrite=overwrite) as f:
            for name in _MATRICES:
                f.create_dataset(name, data=getattr(self, name))
            if self.basis is not None:
                f.create_dataset("basis", data=self.basis)
            if self.singular_values is not None:
                f.create_dataset("singular_values", data=self.singular_values)
            write_attrs(f, {
                "kind": FILE_KIND,
                "layout_version": LAYOUT_VERSION,
                "basis_kind": self.basis_kind,
                "dt": self.dt,
                "input_names": self.input_names,
                "output_names": self.output_names,
                "provenance": json.dumps(jsonable(self.provenance)),
                "fit_info": json.dumps(jsonable(self.fit_info)),
            })
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SecondOrderROM":
        """Read a ROM written by :meth:`save`.

        Raises
        ------
        FileFormatError
            Missing, unreadable or truncated file, wrong kind or layout version, missing or inconsistent data.
        DataError
            NaN/Inf in the stored matrices.
        """
        path = Path(path)
        if not path.is_file():
            raise FileFormatError(f"ROM file {path} does not exist; write one with 'fmu-opinf fit'")
        try:
            with h5py.File(path, "r") as f:
                return cls._from_h5(f, path)
        except OSError as exc:
            raise FileFormatError(f"cannot read ROM file {path} ({exc}); it is not HDF5 or is truncated") from None

    @classmethod
    def _from_h5(cls, f: h5py.File, path: Path) -> "SecondOrderROM":
        check_rom_file(f, path)  # links, attribute types, sizes vs data and memory, finite values, Mr > 0
        attrs = read_attrs(f)
        if attrs.get("kind") != FILE_KIND:
            raise FileFormatError(f"{path} is not an fmu-opinf ROM file (kind={attrs.get('kind')!r})")
        version = attrs.get("layout_version")
        if version != LAYOUT_VERSION:
            raise FileFormatError(f"{path} has ROM layout version {version}; this tool reads version "
                                  f"{LAYOUT_VERSION}, refit the ROM or use a matching fmu-opinf")
        missing = [name for name in _MATRICES if name not in f]
        if missing:
            raise FileFormatError(f"{path} lacks {', '.join(missing)}; the ROM file is truncated or damaged")
        try:
            mats = {name: np.array(f[name][()], dtype=float) for name in _MATRICES}
            basis = np.array(f["basis"][()]) if "basis" in f else None
            sv = np.array(f["singular_values"][()]) if "singular_values" in f else None
            provenance, fit_info = (json.loads(attrs.get(key, "{}")) for key in ("provenance", "fit_info"))
        except (OSError, ValueError, TypeError, KeyError) as exc:
            raise FileFormatError(f"cannot read ROM data from {path} ({exc}); the file is damaged") from None
        for name, value in mats.items():
            if not np.all(np.isfinite(value)):
                raise DataError(f"{path}: {name} contains NaN/Inf; the ROM is unusable, refit it")
        try:
            return cls(**mats, basis=basis, basis_kind=attrs.get("basis_kind", "positions"),
                       input_names=attrs.get("input_names"), output_names=attrs.get("output_names"),
                       dt=attrs.get("dt"), provenance=provenance, fit_info=fit_info, singular_values=sv)
        except DimensionError as exc:
            raise FileFormatError(f"{path}: inconsistent ROM data ({exc})") from None




# ----------------------------------------------------------------------------------------------------------
# The pipeline
# ----------------------------------------------------------------------------------------------------------
def _run_data(run: Any, i: int, basis: np.ndarray, chunk: int) -> dict[str, np.ndarray]:
    """Reduced states (eq. 14), inputs and outputs of one run, with completeness, shape and value checks."""
    if not bool(getattr(run, "attrs", {}).get("complete", True)):
        raise DataError(f"run {i} is incomplete (the recording stopped early); re-record it or drop it")
    k = int(np.shape(run.t)[0])
    out = {name: project(basis, getattr(run, name), chunk, label=f"{name} of run {i}")
           for name in ("xddot", "xdot", "x")}
    for name, array in out.items():
        if array.shape[1] != k:
            raise DimensionError(f"{name} of run {i} has {array.shape[1]} columns; t has {k}")
    for name in ("u", "y"):
        array = getattr(run, name)
        if len(array.shape) != 2 or array.shape[1] != k:
            raise DimensionError(f"{name} of run {i} has shape {tuple(array.shape)}; expected ({name[0]}, {k})")
        out[name] = read_columns(array, 0, k, f"{name} of run {i}")
    return out


def _reduced_data(runs: list, pod: PODBasis, lowpass: float | None = None) -> dict[str, np.ndarray]:
    """Reduced data of all runs side by side: ``xddot, xdot, x (r, k)``, ``u (m, k)``, ``y (p, k)``.

    With ``lowpass`` the entries ``"f_xddot", "f_xdot", "f_x", "f_u"`` hold low-pass filtered copies (each
    run filtered separately) for the SDP; the plain entries are always present (outputs fit, eq. 17).
    """
    chunk = pod.columns_per_chunk(pod.basis_.shape[0])
    per_run = [_run_data(run, i, pod.basis_, chunk) for i, run in enumerate(runs)]
    for name in ("u", "y"):
        rows = sorted({d[name].shape[0] for d in per_run})
        if len(rows) != 1:
            raise DimensionError(f"runs disagree in the number of rows of {name}: {rows}")
    if lowpass is not None:
        names = ("xddot", "xdot", "x", "u")
        for run, d in zip(runs, per_run):
            step = float(np.diff(np.asarray(run.t[:2], dtype=float))[0])
            d.update(zip(("f_" + n for n in names), lowpass_filter([d[n] for n in names], step, lowpass)))
    return {name: np.hstack([d[name] for d in per_run]) for name in per_run[0]}


def _training_dt(runs: list, attrs: dict) -> float | None:
    if attrs.get("dt") is not None:
        return float(attrs["dt"])
    t = np.asarray(runs[0].t[:2], dtype=float)
    return float(t[1] - t[0]) if t.size == 2 else None


def fit_rom(
    snapshots: Any,
    r: int | None = None,
    energy: float | None = None,
    basis: str = "auto",
    *,
    method: str = "auto",
    mass_trace: float | None = None,
    tol: float = 1e-9,
    lowpass: float | None = None,
    keep_basis: bool = True,
    max_memory: float = 1e9,
    chunk_size: int | None = None,
    streamed: bool | None = None,
    normalization: str = "auto",
    log: Callable[[str], None] | None = None,
) -> SecondOrderROM:
    """Learn a reduced second-order model from snapshots: POD (eqs. 7/9), projection (eq. 14), SDP (eq. 16),
    output least squares (eq. 17).

    Parameters
    ----------
    snapshots : Snapshots, list of runs, or one run
        Runs with ``t (k,)``, ``u (m, k)``, ``x, xdot, xddot (n, k)``, ``y (p, k)`` (ndarrays or h5py datasets);
        ``snapshots.attrs`` (if any) supplies ``constraint``, ``input_names``, ``output_names``, ``dt``.
    r : int, optional
        Reduced order; else chosen from the cumulative energy with threshold ``energy``.
    energy : float, optional
        Neglected-energy threshold, see :class:`fmu_opinf.basis.PODBasis`.
    basis : {"auto", "positions", "velocities"}, default="auto"
        Snapshots spanning the basis; ``"auto"`` uses velocities only if the metadata say the constraint is
        on velocities (unknown, e.g. a black-box FMU: positions).
    method, mass_trace, tol, normalization
        Passed to :func:`fmu_opinf.inference.fit_operators`.
    log : callable, optional
        Called with one line per stage (POD, SDP start, SDP result), e.g. ``print``; the CLI shows them.
    lowpass : float, optional
        Cutoff (rad/s) of a zero-phase low-pass filter applied to the reduced data and inputs of each run before
        the SDP (:func:`fmu_opinf.inference.lowpass_filter`): a frequency weighting of the residual of eq. (16)
        that keeps exact relations exact but keeps the closure error of truncated high-frequency modes out of
        the fit.  Default None: the paper's unweighted eq. (16).  Set it above the band the ROM must serve.
    keep_basis : bool, default=True
        Store ``V`` in the ROM (needed for :meth:`SecondOrderROM.reconstruct`).
    max_memory, chunk_size, streamed
        Passed to :class:`fmu_opinf.basis.PODBasis` (dense vs streamed POD, chunked projection).

    Returns
    -------
    SecondOrderROM
    """
    runs = as_runs(snapshots)
    attrs = snapshot_attrs(snapshots)
    say = log or (lambda line: None)
    start = time.perf_counter()
    pod = PODBasis(r=r, energy=energy, kind=basis, max_memory=max_memory, chunk_size=chunk_size,
                   streamed=streamed).fit(runs, attrs)
    say(f"POD of the {pod.kind_} ({pod.method_}, {time.perf_counter() - start:.2f}s): r={pod.r_}, "
        f"cumulative energy E_r={pod.energy_[pod.r_ - 1]:.4f}, snapshot rank {pod.rank_}")
    data = _reduced_data(runs, pod, lowpass)
    sdp = "f_" if lowpass is not None else ""
    say(f"SDP (eq. 16): {3 * pod.r_ * (pod.r_ + 1) // 2} unknowns in Mr, Dr, Kr from {data['u'].shape[1]} "
        "snapshots; solving ...")
    ops = fit_operators(data[sdp + "xddot"], data[sdp + "xdot"], data[sdp + "x"], data[sdp + "u"], method=method,
                        mass_trace=mass_trace, tol=tol, normalization=normalization)
    say(f"SDP: {ops.info.get('status')} via {ops.info.get('method')} ({ops.info.get('normalization')} "
        f"normalization) in {ops.info.get('total_seconds', 0):.2f}s")
    Cpr, Cvr = fit_outputs(data["xdot"], data["x"], data["y"])
    info = dict(ops.info)
    info.update(r=pod.r_, basis_kind=pod.kind_, pod_method=pod.method_, snapshot_rank=pod.rank_,
                energy_r=float(pod.energy_[pod.r_ - 1]), n=int(pod.basis_.shape[0]), k=int(data["u"].shape[1]),
                n_runs=len(runs), output_relative_residual=_output_residual(Cpr, Cvr, data), lowpass=lowpass)
    settings = {"r": r, "energy": energy, "basis": basis, "method": method, "mass_trace": mass_trace, "tol": tol, "normalization": normalization,
                "lowpass": lowpass}
    return SecondOrderROM(
        ops.Mr, ops.Dr, ops.Kr, ops.Br, Cpr, Cvr,
        basis=pod.basis_ if keep_basis else None, basis_kind=pod.kind_,
        input_names=_names(attrs.get("input_names"), data["u"].shape[0]),
        output_names=_names(attrs.get("output_names"), data["y"].shape[0]),
        dt=_training_dt(runs, attrs), provenance=_provenance(attrs, settings, runs), fit_info=info,
        singular_values=pod.svdvals_,
    )


def _provenance(attrs: dict, settings: dict, runs: list) -> dict:
    """Snapshot provenance + fit settings + last training time + fit date + tool versions."""
    return {
        "snapshots": jsonable(attrs),
        "fit_settings": settings,
        "t_train_end": max(float(np.asarray(run.t)[-1]) for run in runs),
        "fit_date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "versions": tool_versions(),
    }


def _names(names: Any, count: int) -> list[str] | None:
    if isinstance(names, (list, tuple)) and len(names) == count:
        return [str(v) for v in names]
    return None


def _output_residual(Cpr: np.ndarray, Cvr: np.ndarray, data: dict[str, np.ndarray]) -> float:
    resid = Cpr @ data["x"] + Cvr @ data["xdot"] - data["y"]
    return float(np.linalg.norm(resid) / (np.linalg.norm(data["y"]) or 1.0))


def fit_rom_file(
    snapshots: str | os.PathLike,
    output: str | os.PathLike,
    r: int | None = None,
    energy: float | None = None,
    basis: str = "auto",
    figures: str | os.PathLike | None = None,
    overwrite: bool = False,
    quiet: bool = False,
    **options: Any,
) -> SecondOrderROM:
    """``fmu-opinf fit``: read a snapshot file lazily, fit, save the ROM, optionally write the POD figures.

    Parameters
    ----------
    snapshots : path or list of paths
        Snapshot file written by :meth:`fmu_opinf.snapshots.Snapshots.save`, a directory of them (one data set,
        e.g. from a run table) or a list of files (:func:`fmu_opinf.basis.open_snapshot_set`).
    output : path
        ROM file to write (atomic; refuses to overwrite unless ``overwrite``).
    r, energy, basis
        As for :func:`fit_rom`.
    figures : path, optional
        Directory for the singular-value and cumulative-energy figures (paper Figs. 4, 6).
    overwrite, quiet : bool
        Replace an existing ROM file; no stage lines on stderr.
    **options
        Further keywords of :func:`fit_rom`.

    Returns
    -------
    SecondOrderROM
    """
    from .basis import open_snapshot_set

    output = Path(output)
    if output.exists() and not overwrite:
        raise FileExistsError(f"{output} exists; pass overwrite=True (--force) to replace it")
    log = None if quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    with open_snapshot_set(snapshots, max_memory=options.get("max_memory", 1e9)) as snaps:
        rom = fit_rom(snaps, r=r, energy=energy, basis=basis, log=log, **options)
        rom.provenance["snapshot_file"] = ", ".join(str(p.resolve()) for p in snaps.files)
        if figures is not None:
            from .plots import pod_figures

            pod_figures(snaps, rom, figures, max_memory=options.get("max_memory", 1e9))
    rom.save(output, overwrite=overwrite)
    return rom
