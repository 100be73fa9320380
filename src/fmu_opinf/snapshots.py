"""Recording snapshots from a source into self-describing HDF5 files (layout: docs/file-format.md).

``record`` steps a :class:`~fmu_opinf.source.Source` on a uniform grid with the input held over each
step (design.md input timing), keeps ``t, u, x, xdot, xddot, y`` per run, derives velocities or
accelerations the source does not expose (Newmark-consistent, :func:`newmark_rates`), and writes
atomically.  A failing step or non-finite values end the run with a one-line error *after* the
samples so far have been stored with ``complete=False``.  ``isolate=True`` runs the source in a
child process, so that a crashing FMU binary is reported as an error instead of killing the caller.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import functools
import json
import math
import multiprocessing as mp
import os
import signal as _signal
import time as _time
from collections.abc import Iterator, Sequence
from multiprocessing import shared_memory
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from ._hdf5 import atomic_h5, read_attrs, tool_versions, write_attrs
from ._progress import Progress
from .errors import DataError, DimensionError, FileFormatError, FmuOpinfError, InputSpecError
from .source import Source, StepError, open_source

__all__ = [
    "LAYOUT_VERSION",
    "Run",
    "Snapshots",
    "Window",
    "RecordSummary",
    "record",
    "record_to_file",
    "auto_window",
    "time_grid",
    "inputs_in_effect",
    "newmark_rates",
    "significant_frequency",
    "fade_time",
    "STREAM_THRESHOLD",
]

#: Version of the HDF5 layout written by this module (docs/file-format.md).
LAYOUT_VERSION = 1
FILE_KIND = "fmu-opinf snapshots"
ARRAYS = ("t", "u", "x", "xdot", "xddot", "y")
_JSON_ATTRS = ("system_options", "fmu_parameters", "versions", "auto_window")
#: Bytes of one run above which ``record(..., path=...)`` streams blocks to disk instead of memory.
STREAM_THRESHOLD = 256 * 2**20
_BLOCK_BYTES = 4 * 2**20


# =============================================================================================
# Data objects
# =============================================================================================


@dataclasses.dataclass
class Run:
    """One recorded trajectory; arrays are ndarrays or (lazy) h5py datasets.

    Attributes
    ----------
    t : (k,) array
    u : (m, k) array
        Inputs in effect: ``u[:, 0] = u(t_0)``, ``u[:, i] = u(t_{i-1})``.
    x, xdot, xddot : (n, k) array
    y : (p, k) array
    attrs : dict
        Provenance of the run (input, step, completeness, derived flags, ...).
    """

    t: Any
    u: Any
    x: Any
    xdot: Any
    xddot: Any
    y: Any
    attrs: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def k(self) -> int:
        """Number of time samples."""
        return int(self.t.shape[0])

    @property
    def complete(self) -> bool:
        """False if the run stopped early (error, non-finite values, crash)."""
        return bool(self.attrs.get("complete", True))

    def arrays(self) -> dict[str, Any]:
        """The six arrays by name."""
        return {name: getattr(self, name) for name in ARRAYS}

    def load(self) -> "Run":
        """An in-memory copy (reads lazy datasets)."""
        return Run(**{n: np.array(a[()]) for n, a in self.arrays().items()}, attrs=dict(self.attrs))


class Snapshots:
    """Snapshot runs of one system plus file-level provenance.

    Parameters
    ----------
    runs : list of Run
    attrs : dict
        File-level attributes: sizes, variable names, constraint kind, source provenance.

    Notes
    -----
    ``Snapshots.load(path)`` reads everything into memory; ``Snapshots.open(path)`` keeps the file
    open and backs each run by h5py datasets (slice them, e.g. ``run.x[:, j0:j1]``); use it as a
    context manager or call :meth:`close`.
    """

    def __init__(self, runs: Sequence[Run] | None = None, attrs: dict[str, Any] | None = None) -> None:
        self.runs: list[Run] = list(runs or [])
        self.attrs: dict[str, Any] = dict(attrs or {})
        self._file: h5py.File | None = None

    # -- sizes -----------------------------------------------------------------------------
    def _size(self, key: str, array: str, axis: int) -> int:
        if key in self.attrs:
            return int(self.attrs[key])
        if self.runs:
            return int(getattr(self.runs[0], array).shape[axis])
        raise DataError(f"snapshots have no runs and no {key!r} attribute")

    @property
    def n(self) -> int:
        """Number of positions."""
        return self._size("n", "x", 0)

    @property
    def m(self) -> int:
        """Number of inputs."""
        return self._size("m", "u", 0)

    @property
    def p(self) -> int:
        """Number of outputs."""
        return self._size("p", "y", 0)

    @property
    def complete(self) -> bool:
        """True if every run is complete."""
        return all(r.complete for r in self.runs)

    def concatenate(self, name: str) -> np.ndarray:
        """All runs' array ``name`` side by side along time, e.g. ``(n, sum k)`` for ``"x"``."""
        if name not in ARRAYS:
            raise DataError(f"unknown array {name!r}; choose one of {', '.join(ARRAYS)}")
        return np.concatenate([np.asarray(getattr(r, name)[()]) for r in self.runs], axis=-1)

    # -- merging ---------------------------------------------------------------------------
    def append(self, other: "Snapshots | Run") -> "Snapshots":
        """Add the runs of ``other`` (same system: sizes and variable names must agree).

        Runs are taken over as they are: runs of an :meth:`open` file stay backed by that file, so
        keep it open until the merged snapshots are saved (or :meth:`Run.load` them first).

        Parameters
        ----------
        other : Snapshots or Run

        Returns
        -------
        Snapshots
            ``self``.
        """
        runs = [other] if isinstance(other, Run) else other.runs
        if isinstance(other, Snapshots):
            self._check_compatible(other.attrs)
            if not self.attrs:
                self.attrs = dict(other.attrs)
        for run in runs:
            self._check_run(run)
            self.runs.append(run)
        return self

    def _check_compatible(self, attrs: dict[str, Any]) -> None:
        keys = ("n", "m", "p", "position_names", "input_names", "output_names")
        for key in keys:
            if key in self.attrs and key in attrs and self.attrs[key] != attrs[key]:
                raise DimensionError(f"cannot merge snapshots: {key} differs ({_short(self.attrs[key])} vs "
                                     f"{_short(attrs[key])}); record both from the same system")
        mine, theirs = self.attrs.get("constraint"), attrs.get("constraint")
        if mine and theirs and mine != theirs and "unknown" not in (mine, theirs):
            raise DimensionError(f"cannot merge snapshots: constraint {mine} vs {theirs}")

    def _check_run(self, run: Run) -> None:
        if not self.runs and not self.attrs:
            return
        want = {"x": self.n, "xdot": self.n, "xddot": self.n, "u": self.m, "y": self.p}
        for name, rows in want.items():
            shape = getattr(run, name).shape
            if shape[0] != rows or shape[-1] != run.k:
                raise DimensionError(f"run array {name} has shape {shape}, expected ({rows}, {run.k})")

    # -- files -----------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write all runs atomically to ``path`` (layout :data:`LAYOUT_VERSION`).

        Parameters
        ----------
        path : str or path-like
        overwrite : bool, default=False
            Replace an existing file (the old one stays intact until the new one is complete).

        Returns
        -------
        Path
        """
        path = Path(path)
        with _atomic(path, overwrite) as f:
            _write_file_attrs(f, self.attrs)
            runs = f.create_group("runs")
            for index, run in enumerate(self.runs):
                _write_run(runs, index, run)
            f.attrs["n_runs"] = len(self.runs)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Snapshots":
        """Read a snapshot file completely into memory."""
        with cls.open(path) as lazy:
            return cls([r.load() for r in lazy.runs], dict(lazy.attrs))

    @classmethod
    def open(cls, path: str | os.PathLike) -> "Snapshots":
        """Open a snapshot file lazily: runs are backed by h5py datasets until :meth:`close`."""
        path = Path(path)
        if not path.is_file():
            raise FileFormatError(f"snapshot file {path} does not exist")
        try:
            f = h5py.File(path, "r")
        except OSError:
            raise FileFormatError(f"{path} is not an HDF5 file; give a file written by 'fmu-opinf snapshots'") from None
        try:
            snaps = cls._from_h5(f, path)
        except BaseException:
            f.close()
            raise
        snaps._file = f
        return snaps

    @classmethod
    def _from_h5(cls, f: h5py.File, path: Path) -> "Snapshots":
        attrs = _decode(read_attrs(f))
        attrs.pop("n_runs", None)  # structural: len(runs)
        if attrs.get("kind") != FILE_KIND or "layout_version" not in attrs:
            raise FileFormatError(f"{path} is not an fmu-opinf snapshot file (no kind/layout_version attributes)")
        if int(attrs["layout_version"]) > LAYOUT_VERSION:
            raise FileFormatError(f"{path} has snapshot layout {attrs['layout_version']}, newer than this tool's "
                                  f"{LAYOUT_VERSION}; upgrade fmu-opinf")
        runs = []
        group = f.get("runs")
        for name in sorted(group or {}):
            g = group[name]
            missing = [a for a in ARRAYS if a not in g]
            if missing:
                raise FileFormatError(f"{path}: run {name} lacks {', '.join(missing)}; the file is truncated")
            runs.append(Run(**{a: g[a] for a in ARRAYS}, attrs=_decode(read_attrs(g))))
        return cls(runs, attrs)

    def close(self) -> None:
        """Close the backing file of :meth:`open` (no-op for in-memory snapshots)."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> "Snapshots":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        ks = ", ".join(str(r.k) + ("" if r.complete else " (incomplete)") for r in self.runs)
        try:
            sizes = f"n={self.n}, m={self.m}, p={self.p}"
        except DataError:
            sizes = "empty"
        return f"Snapshots({sizes}, runs k=[{ks}], constraint={self.attrs.get('constraint', 'unknown')!r})"


def _short(value: Any) -> str:
    text = str(value)
    return text if len(text) < 60 else text[:57] + "..."


# =============================================================================================
# HDF5 helpers
# =============================================================================================


@contextlib.contextmanager
def _atomic(path: Path, overwrite: bool) -> Iterator[h5py.File]:
    """:func:`atomic_h5` with an existing file reported as a one-line :class:`FileFormatError`."""
    if path.exists() and not overwrite:
        raise FileFormatError(f"{path} exists; pass overwrite=True (--force) to replace it")
    with atomic_h5(path, overwrite=overwrite) as f:
        yield f


def _decode(attrs: dict[str, Any]) -> dict[str, Any]:
    """Parse the JSON-valued attributes back into dicts."""
    for key in _JSON_ATTRS:
        if isinstance(attrs.get(key), str):
            try:
                attrs[key] = json.loads(attrs[key])
            except ValueError:
                raise FileFormatError(f"attribute {key!r} is not valid JSON; the file is damaged") from None
    return attrs


def _write_file_attrs(f: h5py.File, attrs: dict[str, Any]) -> None:
    attrs = dict(attrs)
    attrs["kind"] = FILE_KIND
    attrs["layout_version"] = LAYOUT_VERSION
    write_attrs(f, attrs)


def _chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    """About 1 MiB chunks holding whole columns (time samples) when possible."""
    shape = tuple(max(int(d), 1) for d in shape)
    if len(shape) == 1:
        return (min(shape[0], 131072),)
    rows, k = shape
    cols = max(1, min(k, 2**20 // (8 * rows)))
    return (min(rows, max(1, 2**20 // (8 * cols))), cols)


def _create(group: h5py.Group, name: str, shape: tuple[int, ...]) -> h5py.Dataset:
    """A chunked, gzip-compressed float64 dataset resizable along time."""
    return group.create_dataset(name, shape=shape, dtype="f8", maxshape=shape[:-1] + (None,), chunks=_chunks(shape),
                                compression="gzip", compression_opts=1, shuffle=True)


def _write_run(runs: h5py.Group, index: int, run: Run) -> None:
    g = runs.create_group(f"{index:04d}")
    for name, array in run.arrays().items():
        ds = _create(g, name, tuple(array.shape))
        k = array.shape[-1]
        step = max(1, ds.chunks[-1] * 64) if ds.chunks else k
        for j0 in range(0, k, step):
            ds[..., j0:j0 + step] = np.ascontiguousarray(array[..., j0:j0 + step])
    write_attrs(g, run.attrs)


# =============================================================================================
# Time grid, inputs, derived rates
# =============================================================================================


def time_grid(dt: float, t_end: float, t0: float = 0.0) -> np.ndarray:
    """Uniform grid ``t0, t0+dt, ...`` up to ``t_end`` (the last point is the largest ``<= t_end``).

    Parameters
    ----------
    dt : float
        Step, positive.
    t_end : float
        End time, greater than ``t0``.
    t0 : float, default=0.0

    Returns
    -------
    (k,) ndarray
        ``t0 + dt * arange(k)`` (no accumulated round-off).
    """
    if not (dt > 0 and math.isfinite(dt)):
        raise InputSpecError(f"step dt={dt} must be positive and finite")
    if not (t_end > t0 and math.isfinite(t_end)):
        raise InputSpecError(f"end time {t_end} must be finite and after the start time {t0}")
    k = int(math.floor((t_end - t0) / dt * (1 + 1e-12) + 1e-9)) + 1
    if k < 2:
        raise InputSpecError(f"step dt={dt} is longer than the time window {t_end - t0}; decrease --dt")
    return t0 + dt * np.arange(k)


def inputs_in_effect(signal: Any, t: np.ndarray, m: int) -> np.ndarray:
    """The inputs in effect ``(m, k)``: ``u[:, 0] = u(t_0)``, ``u[:, i] = u(t_{i-1})`` (design.md).

    Parameters
    ----------
    signal : Signal
        Anything with ``sample(t) -> (m, k)``.
    t : (k,) ndarray
    m : int
        Number of inputs the source expects.
    """
    sampled = np.atleast_2d(np.asarray(signal.sample(np.asarray(t)), dtype=float))
    if sampled.shape[0] != m:
        raise DimensionError(f"the input signal has {sampled.shape[0]} channels but the source has m={m} inputs; "
                             f"give a signal with {m} channels")
    if sampled.shape[1] != len(t):
        raise DimensionError(f"signal.sample returned {sampled.shape[1]} samples for {len(t)} times")
    if not np.all(np.isfinite(sampled)):
        raise InputSpecError("the input signal has non-finite values; check --input")
    held = np.empty_like(sampled)
    held[:, 0] = sampled[:, 0]
    held[:, 1:] = sampled[:, :-1]
    return held


def newmark_rates(x: np.ndarray, h: float) -> np.ndarray:
    """Rates ``r`` of samples ``x`` consistent with Newmark (beta=1/4, gamma=1/2).

    Solves ``x_{i+1} - x_i = h/2 (r_i + r_{i+1})`` for all ``i`` (velocities from positions:
    ``x_{i+1} = x_i + h v_i + h^2/4 (a_i + a_{i+1})`` with ``v_{i+1} = v_i + h/2 (a_i + a_{i+1})``
    gives exactly this relation; accelerations from velocities are the second one).  The relation
    fixes ``r`` up to an alternating sequence ``alpha (-1)^i`` per row; ``alpha`` is chosen to make
    ``r`` as smooth as possible (least squares on its first differences).

    Parameters
    ----------
    x : (n, k) ndarray
    h : float
        Uniform step.

    Returns
    -------
    (n, k) ndarray
    """
    x = np.asarray(x, dtype=float)
    n, k = x.shape
    if k < 2:
        return np.zeros_like(x)
    s = (2.0 / h) * np.diff(x, axis=1)  # r_i + r_{i+1}
    sign = np.where(np.arange(k) % 2 == 0, 1.0, -1.0)
    c = np.zeros_like(x)
    c[:, 1:] = -sign[1:] * np.cumsum(sign[:-1] * s, axis=1)  # particular solution with r_0 = 0
    d = np.diff(c, axis=1)
    alpha = (d @ sign[:-1]) / (2.0 * (k - 1))
    return c + alpha[:, None] * sign


# =============================================================================================
# Sinks: where the samples go
# =============================================================================================


class _Sink:
    """Provides row buffers for the source to fill (one sample per row) and assembles a :class:`Run`.

    ``rows(i0, count)`` is where samples ``i0 ..`` are written; ``commit(i0, count)`` marks them
    valid.  ``block`` is the largest ``count`` the sink accepts at once.
    """

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray) -> None:
        self.layout = source.layout
        self.width = source.width
        self.n, self.p, self.k = source.n, source.p, len(t)
        self.derived = source.derived
        self.t, self.u = t, u
        self.count = 0
        self.block = _block_rows(self.width, self.k)

    def rows(self, i0: int, count: int) -> np.ndarray:
        raise NotImplementedError

    def commit(self, i0: int, count: int) -> None:
        self.count = i0 + count

    def finish(self, attrs: dict[str, Any]) -> Run:
        raise NotImplementedError

    def _h(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 1.0


class _MemorySink(_Sink):
    """All samples in one (k, width) array, filled in place by the source (no copies).

    The run's ``x, xdot, xddot, y`` are ``(n, k)`` views of it (column ``i`` = sample ``i``).
    """

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray) -> None:
        super().__init__(source, t, u)
        self.samples = np.empty((self.k, self.width))
        self.block = max(self.block, 1)

    def rows(self, i0: int, count: int) -> np.ndarray:
        return self.samples[i0:i0 + count]

    def finish(self, attrs: dict[str, Any]) -> Run:
        c = self.count
        view = self.samples[:c].T
        arrays = {name: view[self.layout[name]] for name in ("x", "xdot", "xddot", "y")}
        if self.derived["xdot"]:
            arrays["xdot"] = newmark_rates(arrays["x"], self._h())
        if self.derived["xddot"]:
            arrays["xddot"] = newmark_rates(arrays["xdot"], self._h())
        return Run(t=self.t[:c].copy(), u=np.ascontiguousarray(self.u[:, :c]), **arrays, attrs=attrs)


class _H5Sink(_Sink):
    """Streams blocks into the (chunked, compressed) datasets of one run group."""

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray, group: h5py.Group) -> None:
        super().__init__(source, t, u)
        self.group = group
        self.scratch = np.empty((self.block, self.width))
        self.ds = {name: _create(group, name, (rows, self.k)) for name, rows in
                   (("x", self.n), ("xdot", self.n), ("xddot", self.n), ("y", self.p))}

    def rows(self, i0: int, count: int) -> np.ndarray:
        return self.scratch[:count]

    def commit(self, i0: int, count: int) -> None:
        for name, ds in self.ds.items():
            part = self.layout[name]
            if part.stop > part.start and count:
                ds[:, i0:i0 + count] = np.ascontiguousarray(self.scratch[:count, part].T)
        super().commit(i0, count)

    def finish(self, attrs: dict[str, Any]) -> Run:
        c = self.count
        for ds in self.ds.values():
            ds.resize(c, axis=1)
        if self.derived["xdot"]:
            self._derive("x", "xdot")
        if self.derived["xddot"]:
            self._derive("xdot", "xddot")
        for name, array in (("t", self.t[:c]), ("u", self.u[:, :c])):
            _create(self.group, name, array.shape)[...] = array
        write_attrs(self.group, attrs)
        return Run(**{a: self.group[a] for a in ARRAYS}, attrs=attrs)

    def _derive(self, src: str, dst: str) -> None:
        """Rows (DOFs) are independent: derive in row blocks without loading the whole run."""
        block = max(1, (64 * 2**20) // (8 * max(self.count, 1)))
        for r0 in range(0, self.n, block):
            self.ds[dst][r0:r0 + block, :] = newmark_rates(self.ds[src][r0:r0 + block, :], self._h())


# =============================================================================================
# Producers: drive the source in process or in a child process
# =============================================================================================


def _block_rows(width: int, k: int) -> int:
    return int(max(1, min(k, max(16, _BLOCK_BYTES // (8 * max(width, 1))))))


def _produce_inprocess(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink) -> Iterator[tuple[int, int]]:
    """Fill the sink's rows block by block, yielding ``(i0, count)`` of each filled block.

    A :class:`StepError` is raised after the block holding the valid samples before it is yielded.
    """
    k = len(t)
    source.start(t, U)
    try:
        i = 0
        while i < k:
            count = min(sink.block, k - i)
            try:
                source.advance(sink.rows(i, count), i, count)
            except StepError as exc:
                valid = max(0, exc.step - i) if exc.step >= 0 else 0
                if valid:
                    yield i, valid
                raise
            yield i, count
            i += count
    finally:
        source.close()


_HEADER = 64  # bytes before the row buffer in shared memory: int64 count of valid rows


def _child_main(conn: Any, shm_name: str, cap: int, source: Source, t: np.ndarray, U: np.ndarray) -> None:
    """Child process: run the source, fill the shared buffer, report through ``conn``."""
    shm = shared_memory.SharedMemory(name=shm_name)
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, source.width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    try:
        _child_loop(conn, source, t, U, count, rows)
    finally:
        del count, rows
        shm.close()


def _child_loop(conn: Any, source: Source, t: np.ndarray, U: np.ndarray, count: np.ndarray, rows: np.ndarray) -> None:
    """Fill the shared buffer block by block, publishing the number of finished rows after every sample."""
    k, cap = len(t), len(rows)
    try:
        source.start(t, U)
    except StepError as exc:
        conn.send(("fail", str(exc), exc.step, exc.time))
        return
    except FmuOpinfError as exc:  # nothing recorded yet: the parent raises the same kind of error
        conn.send(("error", type(exc).__name__, str(exc)))
        return
    i = 0
    try:
        while i < k:
            c = min(cap, k - i)
            count[0] = 0
            try:
                source.advance(rows, i, c, published=count)
            except StepError as exc:
                conn.send(("fail", str(exc), exc.step, exc.time))
                return
            i += c
            conn.send(("block", c))
            conn.recv()
        conn.send(("done",))
    finally:
        source.close()


def _produce_isolated(source: Source, t: np.ndarray, U: np.ndarray, sink: _Sink) -> Iterator[tuple[int, int]]:
    """Like :func:`_produce_inprocess`, with the source in a spawned child process.

    The child writes samples into shared memory and publishes after each sample how many rows are
    complete, so when it dies (a crashing binary) every sample it finished is still taken over.
    """
    k, width = len(t), source.width
    cap = sink.block
    shm = shared_memory.SharedMemory(create=True, size=_HEADER + 8 * cap * max(width, 1))
    count = np.ndarray((1,), dtype=np.int64, buffer=shm.buf[:8])
    rows = np.ndarray((cap, width), dtype=np.float64, buffer=shm.buf[_HEADER:])
    count[0] = 0
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    proc = ctx.Process(target=_child_main, args=(there, shm.name, cap, source, t, U), daemon=True)
    i0 = 0
    try:
        proc.start()
        there.close()
        while True:
            message = _receive(here, proc)
            valid = _valid_rows(message, int(count[0]))
            if valid:
                sink.rows(i0, valid)[:] = rows[:valid]
                yield i0, valid
            if message is None:  # the child died without a word
                proc.join(5)  # reap it, so that its exit code (the signal) is known
                i = i0 + valid
                raise StepError(_crash_text(source, proc.exitcode, i, t), i, float(t[min(i, k - 1)]))
            if message[0] == "fail":
                raise StepError(message[1], message[2], message[3])
            if message[0] == "error":
                raise _error_class(message[1])(message[2])
            if message[0] == "done":
                return
            i0 += valid
            here.send("ack")
    finally:
        if proc.is_alive():
            proc.kill()
        if proc.pid is not None:
            proc.join(5)
        here.close()
        del count, rows
        shm.close()
        shm.unlink()


def _error_class(name: str) -> type:
    """The fmu-opinf error class called ``name`` (FMUError if unknown)."""
    from . import errors, source

    cls = getattr(errors, name, None) or getattr(source, name, None)
    return cls if isinstance(cls, type) and issubclass(cls, FmuOpinfError) else errors.FMUError


def _valid_rows(message: tuple | None, published: int) -> int:
    """Rows of the shared buffer to take over: a full block, or what was published before a failure."""
    if message is None or message[0] == "fail":
        return published
    return message[1] if message[0] == "block" else 0


def _receive(conn: Any, proc: Any) -> tuple | None:
    """Next message from the child, or None once it has exited without one."""
    while True:
        if conn.poll(0.05):
            try:
                return conn.recv()
            except (EOFError, OSError):
                return None
        if not proc.is_alive():
            if conn.poll(0):
                continue
            return None


def _crash_text(source: Source, exitcode: int | None, i: int, t: np.ndarray) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            how = f"signal {_signal.Signals(-exitcode).name}"
        except ValueError:
            how = f"signal {-exitcode}"
    else:
        how = f"exit code {exitcode}"
    when = f"t={t[i - 1]:g} -> {t[i]:g}" if 0 < i < len(t) else f"t={t[min(i, len(t) - 1)]:g}"
    return f"{_source_label(source)} crashed the simulation process ({how}) at step {i} ({when})"


# =============================================================================================
# Recording
# =============================================================================================


def _signal_spec(signal: Any) -> str:
    value = getattr(signal, "spec", None)
    return value if isinstance(value, str) and value else repr(signal)


def _first_bad_row(rows: np.ndarray) -> int | None:
    """Index of the first row with a NaN/inf, or None (fast path: one sum over the block)."""
    if math.isfinite(float(rows.sum())):
        return None
    bad = ~np.isfinite(rows).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else None


def _record_run(source: Source, signal: Any, t: np.ndarray, sink_factory: Any, quiet: bool,
                isolate: bool) -> tuple[Run, StepError | None]:
    """Drive one run into a sink; return the run and the error that ended it early (if any)."""
    u = inputs_in_effect(signal, t, source.m)
    U = np.ascontiguousarray(u.T)
    sink = sink_factory(source, t, u)
    producer = (_produce_isolated if isolate else _produce_inprocess)(source, t, U, sink)
    failure: StepError | None = None
    started = _time.perf_counter()
    with Progress(len(t), "recording", quiet=quiet) as bar:
        try:
            for i0, count in producer:
                first = _first_bad_row(sink.rows(i0, count)[:count])
                if first is not None:
                    sink.commit(i0, first)
                    i = i0 + first
                    raise StepError(f"{_source_label(source)} produced non-finite values at step {i} "
                                    f"(t={t[i]:g})", i, float(t[i]))
                sink.commit(i0, count)
                bar.update(sink.count)
        except StepError as exc:
            failure = exc
        finally:
            producer.close()
    attrs = _run_attrs(source, signal, t, sink, failure, _time.perf_counter() - started, isolate)
    return sink.finish(attrs), failure


def _source_label(source: Source) -> str:
    path = getattr(source, "path", None)
    return Path(path).name if path else type(source).__name__


def _run_attrs(source: Source, signal: Any, t: np.ndarray, sink: _Sink, failure: StepError | None,
               seconds: float, isolate: bool) -> dict[str, Any]:
    attrs = dict(source.provenance())
    attrs.update({
        "input_spec": _signal_spec(signal),
        "dt": float(t[1] - t[0]),
        "t0": float(t[0]),
        "t_end": float(t[-1]),
        "k_planned": len(t),
        "k": sink.count,
        "complete": failure is None and sink.count == len(t),
        "derived_xdot": bool(sink.derived["xdot"]),
        "derived_xddot": bool(sink.derived["xddot"]),
        "derived_method": "newmark_rates (beta=1/4, gamma=1/2; alternating mode by least roughness)"
        if any(sink.derived.values()) else "",
        "isolated": bool(isolate),
        "wall_seconds": round(seconds, 6),
        "versions": _versions(),
    })
    attrs["created"] = attrs["versions"]["created"]
    if failure is not None:
        attrs["error"] = str(failure)
    return attrs


@functools.lru_cache(maxsize=1)
def _library_versions() -> tuple[tuple[str, str], ...]:
    return tuple((k, v) for k, v in tool_versions().items() if k != "created")


def _versions() -> dict[str, str]:
    """Tool and library versions (looked up once per process) and the creation time (now)."""
    versions = dict(_library_versions())
    versions["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return versions


def _file_attrs(source: Source) -> dict[str, Any]:
    attrs = source.description()
    attrs.update({"kind": FILE_KIND, "layout_version": LAYOUT_VERSION, "versions": _versions()})
    attrs["created"] = attrs["versions"]["created"]
    attrs["derived_xdot"] = bool(source.derived["xdot"])
    attrs["derived_xddot"] = bool(source.derived["xddot"])
    return attrs


def _incomplete_error(failure: StepError, run: Run, path: Path | None) -> StepError:
    where = f" in {path}" if path else ""
    text = f"{failure}; the {run.k} samples before it are kept{where} (complete=False)"
    return StepError(text, failure.step, failure.time)


def _run_bytes(source: Source, k: int) -> int:
    return 8 * k * (3 * source.n + source.p + source.m + 1)


def record(source: Source | str, signal: Any, dt: float, t_end: float, path: str | os.PathLike | None = None,
           quiet: bool = False, *, overwrite: bool = False, isolate: bool = False, t0: float = 0.0,
           stream: bool | None = None) -> Snapshots:
    """Record one run of ``source`` driven by ``signal`` on the grid ``t0, t0+dt, ..., <= t_end``.

    Parameters
    ----------
    source : Source or str
        A source or a spec for :func:`~fmu_opinf.source.open_source`.
    signal : Signal or str
        Input (``sample(t) -> (m, k)``) or a spec for :func:`fmu_opinf.signals.parse_signal`.
    dt : float
        Communication step.
    t_end : float
        End time.
    path : str or path-like, optional
        Also write the snapshots there (atomically).
    quiet : bool, default=False
        No progress bar.
    overwrite : bool, default=False
        Replace an existing ``path``.
    isolate : bool, default=False
        Run the source in a child process (a crash becomes an :class:`~fmu_opinf.errors.FMUError`).
    t0 : float, default=0.0
    stream : bool, optional
        Write blocks to ``path`` during the run instead of keeping them in memory; default: when the
        run exceeds :data:`STREAM_THRESHOLD` bytes.  Streamed snapshots are returned opened lazily.

    Returns
    -------
    Snapshots
        One run.  If the run stopped early, the samples so far are stored (``complete=False``)
        and :class:`~fmu_opinf.source.StepError` is raised afterwards.
    """
    source = open_source(source)
    signal = _as_signal(signal, source.m)
    t = time_grid(dt, t_end, t0)
    streaming = path is not None and (stream if stream is not None else _run_bytes(source, len(t)) > STREAM_THRESHOLD)
    if not streaming:
        run, failure = _record_run(source, signal, t, _MemorySink, quiet, isolate)
        snaps = Snapshots([run], {**_file_attrs(source), "dt": float(t[1] - t[0])})
        if path is not None:
            snaps.save(path, overwrite=overwrite)
        if failure is not None:
            raise _incomplete_error(failure, run, Path(path) if path else None)
        return snaps
    summary = _record_file(source, [signal], t, Path(path), quiet, isolate, overwrite, None)
    del summary
    return Snapshots.open(path)


def _as_signal(signal: Any, m: int | None = None) -> Any:
    """A signal object from a spec (one spec drives every one of the ``m`` inputs) or as is."""
    if isinstance(signal, str):
        from .signals import parse_signal

        return parse_signal(signal, m) if m else parse_signal(signal)
    if not hasattr(signal, "sample"):
        raise InputSpecError(f"input {signal!r} is neither a signal nor a signal specification")
    return signal


def _record_file(source: Source, signals: Sequence[Any], t: np.ndarray, path: Path, quiet: bool, isolate: bool,
                 overwrite: bool, window: "Window | None") -> "RecordSummary":
    """Stream every signal's run into one new file; stop at the first failing run (kept, incomplete)."""
    failure: StepError | None = None
    summary = RecordSummary(path=path, n=source.n, m=source.m, p=source.p, window=window)
    with _atomic(path, overwrite) as f:
        attrs = _file_attrs(source)
        attrs["dt"] = float(t[1] - t[0])
        if window is not None:
            attrs["auto_window"] = window.as_dict()
        _write_file_attrs(f, attrs)
        runs = f.create_group("runs")
        for index, signal in enumerate(signals):
            group = runs.create_group(f"{index:04d}")

            def factory(src: Source, tt: np.ndarray, uu: np.ndarray, g: h5py.Group = group) -> _H5Sink:
                return _H5Sink(src, tt, uu, g)

            run, failure = _record_run(source, signal, t, factory, quiet, isolate)
            if window is not None:
                group.attrs["auto_window"] = json.dumps(window.as_dict())
            summary.runs.append((run.k, run.complete, run.attrs["input_spec"]))
            if failure is not None:
                failure = _incomplete_error(failure, run, path)
                break
        f.attrs["n_runs"] = len(summary.runs)
    if failure is not None:
        raise failure
    return summary


@dataclasses.dataclass
class RecordSummary:
    """What :func:`record_to_file` wrote: ``str()`` is the file name, :meth:`describe` the details."""

    path: Path
    n: int
    m: int
    p: int
    window: "Window | None" = None
    runs: list[tuple[int, bool, str]] = dataclasses.field(default_factory=list)

    def __str__(self) -> str:
        return str(self.path)

    def __fspath__(self) -> str:
        return str(self.path)

    def describe(self) -> str:
        """Several lines: sizes, one line per run, the automatic window."""
        lines = [f"{self.path}: n={self.n}, m={self.m}, p={self.p}, {len(self.runs)} run(s)"]
        for index, (k, complete, spec) in enumerate(self.runs):
            lines.append(f"  run {index:04d}: k={k} samples, input {spec}" + ("" if complete else " (INCOMPLETE)"))
        if self.window is not None:
            lines.append(f"  auto window: {self.window}")
        return "\n".join(lines)


def record_to_file(
    source_spec: str | os.PathLike | Source,
    output: str | os.PathLike,
    input_spec: str | Sequence[str],
    dt: float | None = None,
    t_end: float | None = None,
    auto_window: bool = False,
    positions: str | None = None,
    velocities: str | None = None,
    accelerations: str | None = None,
    inputs: str | None = None,
    outputs: str | None = None,
    constraint: str | None = None,
    parameters: dict[str, float] | None = None,
    points_per_period: float = 20.0,
    energy: float = 0.999,
    fade: float = 0.01,
    overwrite: bool = False,
    quiet: bool = False,
    isolate: bool = True,
    **size_options: Any,
) -> RecordSummary:
    """Command-line entry: record one run per input specification into ``output``.

    Parameters
    ----------
    source_spec : str, path-like or Source
        ``builtin:anchored-msd``, ``builtin:triple-chain`` or an ``.fmu`` path.
    output : str or path-like
        HDF5 file to create (atomically).
    input_spec : str or sequence of str
        Input signal specification(s) (:func:`fmu_opinf.signals.parse_signal`; a single-channel
        spec drives every input) or signal objects; one run each.
    dt, t_end : float, optional
        Step and end time; default: from ``auto_window`` or the FMU's default experiment.
    auto_window : bool, default=False
        Choose ``dt`` and ``t_end`` from a pilot run with the first input (:func:`auto_window`);
        an explicitly given ``dt``/``t_end`` wins over the automatic choice.
    positions, velocities, accelerations, inputs, outputs : str, optional
        Variable name patterns (FMU sources only; see :class:`~fmu_opinf.source.FMUSource`).
    constraint : {"position", "velocity", "none", "unknown"}, optional
        Constraint kind of an FMU (stored for the later stages).
    parameters : dict of str to float, optional
        FMU start values set before initialization.
    points_per_period, energy, fade : float
        Thresholds of :func:`auto_window`.
    overwrite : bool, default=False
    quiet : bool, default=False
    isolate : bool, default=True
        Run FMUs in a child process so that a crashing binary cannot take the data with it.
    **size_options
        Sizes of a builtin system (``g`` for anchored-msd; ``n1, alpha, beta, v`` for triple-chain).

    Returns
    -------
    RecordSummary
        ``str()`` gives the file name, :meth:`RecordSummary.describe` the runs and the window.
    """
    source = open_source(source_spec, positions=positions, velocities=velocities, accelerations=accelerations,
                         inputs=inputs, outputs=outputs, constraint=constraint, parameters=parameters,
                         **size_options)
    specs = [input_spec] if isinstance(input_spec, str) else list(input_spec)
    if not specs:
        raise InputSpecError("no input given; pass --input SPEC (an impulse-like input for training)")
    signals = [_as_signal(s, source.m) for s in specs]
    isolate = isolate and source.kind == "fmu"
    window = None
    if auto_window:
        window = globals()["auto_window"](source, signals[0], points_per_period=points_per_period, energy=energy,
                                          fade=fade, isolate=isolate, quiet=quiet)
        dt = window.dt if dt is None else dt
        t_end = window.t_end if t_end is None else t_end
    dt, t_end = _default_window(source, dt, t_end)
    return _record_file(source, signals, time_grid(dt, t_end), Path(output), quiet, isolate, overwrite, window)


def _default_window(source: Source, dt: float | None, t_end: float | None) -> tuple[float, float]:
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    if dt is None and experiment is not None and experiment.stepSize is not None:
        dt = float(experiment.stepSize)
    if t_end is None and experiment is not None and experiment.stopTime is not None:
        t_end = float(experiment.stopTime)
    if dt is None or t_end is None:
        missing = " and ".join(n for n, v in (("--dt", dt), ("--t-end", t_end)) if v is None)
        raise InputSpecError(f"no {missing} given and the source has no default; pass {missing} or --auto-window")
    return float(dt), float(t_end)


# =============================================================================================
# Automatic snapshot window (paper section 4.2, spec section 5)
# =============================================================================================


@dataclasses.dataclass
class Window:
    """Step and end time chosen from an impulse response (see :func:`auto_window`).

    Attributes
    ----------
    dt : float
        Chosen step: ``1 / (points_per_period * f_max)`` rounded down to 1, 2 or 5 times a power of ten.
    t_end : float
        Chosen end time: the fade-out time rounded up to a multiple of ``dt``.
    f_max : float
        Fastest significant frequency of the output response, in Hz (cycles per time unit).
    t_fade : float
        Time after which the output envelope stays below ``fade`` times its peak.
    peak : float
        Peak of ``||y(t) - y_rest||_2``.
    pilot_dt, pilot_t_end : float
        Grid of the last pilot run.
    pilots : int
        Number of pilot runs.
    points_per_period, energy, fade : float
        Thresholds used.
    """

    dt: float
    t_end: float
    f_max: float
    t_fade: float
    peak: float
    pilot_dt: float
    pilot_t_end: float
    pilots: int
    points_per_period: float
    energy: float
    fade: float

    def as_dict(self) -> dict[str, float]:
        """Plain dict (stored as the ``auto_window`` attribute)."""
        return {k: (int(v) if k == "pilots" else float(v)) for k, v in dataclasses.asdict(self).items()}

    def __str__(self) -> str:
        return (f"dt={self.dt:g}, t_end={self.t_end:g} (fastest significant frequency {self.f_max:.4g} Hz, "
                f"{self.points_per_period:g} points per period; output below {self.fade:g} of its peak after "
                f"t={self.t_fade:.4g}; {self.pilots} pilot run(s), last dt={self.pilot_dt:g}, "
                f"t_end={self.pilot_t_end:g})")


def significant_frequency(t: np.ndarray, y: np.ndarray, energy: float = 0.999) -> float:
    """Smallest frequency below which a fraction ``energy`` of the output's spectral energy lies.

    The spectrum is that of the Hann-windowed, mean-free outputs (summed over outputs); the window
    removes the leakage of cutting the response at both ends, which would otherwise put spurious
    energy at high frequencies.

    Parameters
    ----------
    t : (k,) ndarray
        Uniform times.
    y : (p, k) ndarray
        Output response.
    energy : float, default=0.999

    Returns
    -------
    float
        Frequency in cycles per time unit (0 for a constant output).
    """
    y = np.atleast_2d(y)
    r = (y - y.mean(axis=1, keepdims=True)) * np.hanning(y.shape[1])
    power = (np.abs(np.fft.rfft(r, axis=1)) ** 2).sum(axis=0)
    freqs = np.fft.rfftfreq(y.shape[1], d=float(t[1] - t[0]))
    total = power.sum()
    if total <= 0:
        return 0.0
    cumulative = np.cumsum(power) / total
    return float(freqs[min(int(np.searchsorted(cumulative, energy)), len(freqs) - 1)])


def fade_time(t: np.ndarray, y: np.ndarray, fade: float = 0.01) -> tuple[float, float]:
    """Time after which ``||y(t) - y_rest||_2`` stays below ``fade`` times its peak.

    ``y_rest`` is the mean output over the last 5 % of the samples (the state the response settles
    to).  Returns ``(t_fade, peak)``; ``t_fade`` is ``inf`` if the envelope never falls below.
    """
    y = np.atleast_2d(y)
    tail = max(1, y.shape[1] // 20)
    rest = y[:, -tail:].mean(axis=1, keepdims=True)
    e = np.linalg.norm(y - rest, axis=0)
    peak = float(e.max())
    if peak == 0.0:
        return float(t[0]), 0.0
    envelope = np.maximum.accumulate(e[::-1])[::-1]  # max over the rest of the run
    below = np.nonzero(envelope <= fade * peak)[0]
    below = below[t[below] >= t[int(np.argmax(e))]]
    return (float(t[below[0]]) if below.size else math.inf), peak


def _nice_floor(value: float) -> float:
    """Largest 1, 2 or 5 times a power of ten not above ``value``."""
    exponent = math.floor(math.log10(value))
    for mantissa in (5.0, 2.0, 1.0):
        candidate = mantissa * 10.0 ** exponent
        if candidate <= value * (1 + 1e-12):
            return float(f"{candidate:.12g}")
    return float(f"{10.0 ** exponent:.12g}")


def auto_window(
    source: Source | str,
    signal: Any,
    *,
    points_per_period: float = 20.0,
    energy: float = 0.999,
    fade: float = 0.01,
    pilot_dt: float | None = None,
    pilot_t_end: float | None = None,
    min_pilot_points: float = 8.0,
    growth: float = 4.0,
    max_pilots: int = 8,
    max_steps: int = 400_000,
    isolate: bool = False,
    quiet: bool = True,
) -> Window:
    """Choose step and end time from the response to an impulse-like input (paper sec. 4.2).

    Pilot runs record the outputs; the step resolves the fastest significant oscillation with
    ``points_per_period`` samples and the end time is when the vibrations have faded out:

    * ``f_max``: smallest frequency below which a fraction ``energy`` of the spectral energy of the
      outputs lies (Hann-windowed FFT of the pilot's free response, from when the input pulse has
      died out to ``t_fade``, :func:`significant_frequency`);
    * ``t_fade``: the envelope ``max_{s >= t} ||y(s) - y_rest||_2`` stays below ``fade`` times its
      peak afterwards (:func:`fade_time`).

    A pilot is refined (step / 4) while ``f_max`` has fewer than ``min_pilot_points`` samples per
    period, and extended (same step, so that the input pulse stays resolved) until ``t_fade`` lies
    in its first half: to twice the fade-out time extrapolated from the envelope's exponential decay,
    at least doubled and at most ``growth**2`` times longer.

    Parameters
    ----------
    source : Source or str
    signal : Signal or str
        Impulse-like training input.
    points_per_period : float, default=20
    energy : float, default=0.999
    fade : float, default=0.01
    pilot_dt, pilot_t_end : float, optional
        First pilot grid; default: the FMU's default experiment, else ``t_end=100``, ``dt=t_end/1000``.
    min_pilot_points : float, default=8
    growth : float, default=4
        Without a decaying envelope a pilot is extended ``growth`` times; never more than ``growth**2``.
    max_pilots : int, default=8
    max_steps : int, default=400000
        Largest pilot run.
    isolate : bool, default=False
        Run the pilots in a child process.
    quiet : bool, default=True

    Returns
    -------
    Window
    """
    source = open_source(source)
    signal = _as_signal(signal, source.m)
    for name, value, low, high in (("energy", energy, 0.0, 1.0), ("fade", fade, 0.0, 1.0)):
        if not low < value < high:
            raise InputSpecError(f"{name}={value} must lie strictly between {low:g} and {high:g}")
    if points_per_period < 2:
        raise InputSpecError(f"points_per_period={points_per_period} must be at least 2 (Nyquist)")
    if source.p == 0:
        raise DataError("the source has no outputs; auto window needs outputs to analyse (pass --outputs)")
    T, dt = _pilot_start(source, pilot_dt, pilot_t_end)
    for pilot in range(1, max_pilots + 1):
        t = time_grid(dt, T)
        if len(t) > max_steps:
            break
        run, failure = _record_run(source, signal, t, _MemorySink, quiet, isolate)
        if failure is not None:
            raise _incomplete_error(failure, run, None)
        t_fade, peak = fade_time(t, run.y, fade)
        free = _free_response(t, run.u)
        faded = int(np.searchsorted(t, t_fade, side="right")) if math.isfinite(t_fade) else len(t)
        segment = slice(free, faded) if faded - free >= 16 else slice(0, len(t))
        f_max = significant_frequency(t[segment], run.y[:, segment], energy)
        if peak == 0.0:
            raise DataError("the outputs do not respond to the input; use an impulse-like input that excites "
                            "the system")
        if f_max * dt * min_pilot_points > 1.0:
            dt /= 4.0
        elif not t_fade <= t[0] + 0.5 * (T - t[0]):
            T = float(f"{t[0] + _next_length(t, run.y, fade, growth):.6g}")
        else:
            f_use = max(f_max, 1.0 / max(t_fade - t[0], dt))
            step = _nice_floor(1.0 / (points_per_period * f_use))
            end = t[0] + math.ceil((t_fade - t[0]) / step - 1e-9) * step
            return Window(dt=step, t_end=float(f"{end:.12g}"), f_max=f_max, t_fade=t_fade, peak=peak, pilot_dt=dt,
                          pilot_t_end=T, pilots=pilot, points_per_period=points_per_period, energy=energy, fade=fade)
    raise DataError(f"auto window: the output does not settle or is not resolved within {max_pilots} pilot runs "
                    f"of at most {max_steps} steps (last dt={dt:g}, t_end={T:g}); pass --dt and --t-end")


def _next_length(t: np.ndarray, y: np.ndarray, fade: float, growth: float) -> float:
    """Length of the next pilot: twice the fade-out time extrapolated from the exponential decay of
    the envelope over the second half of this pilot, between 2 and ``growth**2`` times this length."""
    length = float(t[-1] - t[0])
    y = np.atleast_2d(y)
    rest = y[:, -max(1, y.shape[1] // 20):].mean(axis=1, keepdims=True)
    e = np.linalg.norm(y - rest, axis=0)
    envelope = np.maximum.accumulate(e[::-1])[::-1]
    half = slice(len(t) // 2, len(t) - max(1, len(t) // 20))
    tt, ee = t[half], envelope[half]
    keep = ee > 0
    if keep.sum() < 8 or e.max() == 0:
        return growth * length
    slope, intercept = np.polyfit(tt[keep], np.log(ee[keep]), 1)
    if slope >= 0:
        return growth * length
    t_fade = (math.log(fade * e.max()) - intercept) / slope
    return float(min(max(2.0 * (t_fade - t[0]), 2.0 * length), growth**2 * length))


def _free_response(t: np.ndarray, u: np.ndarray) -> int:
    """Index from which the input has died out (below 1e-3 of its peak), so the output shows the
    system's own vibrations; 0 if the input never dies out (then the whole pilot is analysed)."""
    magnitude = np.abs(u).max(axis=0) if u.size else np.zeros(len(t))
    top = magnitude.max() if magnitude.size else 0.0
    active = np.nonzero(magnitude > 1e-3 * top)[0] if top > 0 else np.array([], dtype=int)
    if active.size == 0:
        return 0
    start = int(active[-1]) + 1
    return start if len(t) - start >= max(16, len(t) // 4) else 0


def _pilot_start(source: Source, pilot_dt: float | None, pilot_t_end: float | None) -> tuple[float, float]:
    experiment = getattr(getattr(source, "md", None), "defaultExperiment", None)
    T = pilot_t_end
    if T is None and experiment is not None and experiment.stopTime is not None:
        T = float(experiment.stopTime)
    T = 100.0 if T is None else float(T)
    dt = pilot_dt
    if dt is None and experiment is not None and experiment.stepSize is not None:
        dt = float(experiment.stepSize)
    return T, (T / 1000.0 if dt is None else float(dt))
