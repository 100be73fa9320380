"""The snapshot data model: runs of ``t, u, x, xdot, xddot, y`` plus provenance."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._hdf5 import read_attrs, unreadable_file
from .._seal import SEAL_ATTR, check_seal
from .._validate import (SNAPSHOT_FILE_ATTRS, SNAPSHOT_RUN_ATTRS, check_attr_types, check_memory, check_snapshot_run,
                         damaged_file_errors, reject_links)
from ..errors import DataError, DimensionError, FileFormatError
from ._file import (ARRAYS, FILE_KIND, INITIAL, LAYOUT_VERSION, atomic, decode, read_model_start, write_file_attrs,
                    write_run)
from ._merge import MERGED_PARTS, SOURCE_KEYS, merged_parts, merged_source, mixed_interfaces, same_setting
from ._notes import VERDICTS, texts

__all__ = ["Run", "Snapshots"]


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
    x0, v0 : (n,) ndarray
        The source's initial state (positions and velocities at ``t[0]``, not necessarily at rest or
        at equilibrium); default: the first samples of ``x`` and ``xdot``.  Layout 2 stores them.
    model_start : dict or None
        A run table row with ``start:`` values: the model's own start, its source initialized without them when the
        row was recorded (``{"x0": positions, "v0": velocities}``, no ``v0`` where the velocities are derived;
        provenance in ``attrs["model_start"]``; :mod:`fmu_opinf._model_start`).  None: not recorded.
    """

    t: Any
    u: Any
    x: Any
    xdot: Any
    xddot: Any
    y: Any
    attrs: dict[str, Any] = dataclasses.field(default_factory=dict)
    x0: Any = None
    v0: Any = None
    model_start: dict[str, np.ndarray] | None = None

    def __post_init__(self) -> None:
        self.x0 = _initial(self.x0, self.x)
        self.v0 = _initial(self.v0, self.xdot)

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
        return Run(**{n: np.array(a[()]) for n, a in self.arrays().items()}, attrs=dict(self.attrs),
                   x0=np.array(self.x0), v0=np.array(self.v0),
                   model_start=None if self.model_start is None else {k: np.array(v) for k, v in
                                                                      self.model_start.items()})


def settings_of(attrs: dict[str, Any]) -> dict[str, Any]:
    """The FMU settings a snapshot file was recorded with (``--set`` values, a run table row's ``set:``/``start:``
    cells); empty when it has none."""
    settings = attrs.get("fmu_settings")
    return dict(settings) if isinstance(settings, dict) else {}


def shared_settings(settings: list[dict[str, Any]]) -> dict[str, Any]:
    """The settings (name and value) that all of ``settings`` have (values compared by meaning: ``2`` = ``"2"``)."""
    return {key: value for key, value in settings[0].items()
            if all(key in s and same_setting(s[key], value) for s in settings[1:])}


def shared_parameters(mine: Any, theirs: Any) -> dict[str, Any] | None:
    """``source_parameters`` of merged snapshots: the parameters both parts recorded at the same value and type (one
    at different values is not a value the merged ROM was trained at: the exported ROM FMU leaves it out); None
    where either part has none; the Enumeration types of the shared ones both recorded alike (``enumerations``)."""
    if not isinstance(mine, dict) or not isinstance(theirs, dict):
        return None
    keys = ("names", "types", "values", "units", "quantities")
    try:
        other = {row[0]: row for row in zip(*(theirs[k] for k in keys))}
        rows = [row for row in zip(*(mine[k] for k in keys)) if other.get(row[0]) == row]
    except (KeyError, TypeError):
        return None
    shared: dict[str, Any] = {k: [row[i] for row in rows] for i, k in enumerate(keys)}
    given = set(mine.get("set") or []) | set(theirs.get("set") or [])
    shared["set"] = [name for name in shared["names"] if name in given]
    types = _shared_enumerations(mine.get("enumerations"), theirs.get("enumerations"), shared["names"])
    if types:
        shared["enumerations"] = types
    return shared


def _shared_enumerations(mine: Any, theirs: Any, names: list[str]) -> dict[str, Any]:
    """The Enumeration types (``source_parameters`` ``enumerations``, api84) of the shared parameters ``names`` that
    both parts recorded alike; one recorded differently is left out (the exported ROM FMU then leaves its parameter
    out, with a warning)."""
    if not isinstance(mine, dict) or not isinstance(theirs, dict):
        return {}
    return {name: mine[name] for name in names if name in mine and mine[name] == theirs.get(name)}


def shared_held_inputs(mine: Any, theirs: Any) -> Any:
    """``held_inputs`` of merged snapshots: a held input whose value differs between the parts (a run table's
    per-row ``set:``) was not held at one value; it moves to ``"varied"``, which the exported ROM FMU leaves out
    with a warning.  Parts that do not both record them: none (the ROM FMU then exports without held inputs)."""
    if not (isinstance(mine, dict) and isinstance(theirs, dict) and mine.get("order") == theirs.get("order")
            and isinstance(mine.get("values"), dict) and isinstance(theirs.get("values"), dict)):
        return None
    values = dict(mine["values"])
    varied = sorted(set(mine.get("varied") or []) | set(theirs.get("varied") or [])
                    | {name for name, value in values.items() if theirs["values"].get(name) != value})
    return {**mine, "values": {name: value for name, value in values.items() if name not in varied}, "varied": varied}


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
    context manager or call :meth:`close`.  ``path`` is the file they were read from (None for snapshots made in
    memory); merging names each part by it.
    """

    def __init__(self, runs: Sequence[Run] | None = None, attrs: dict[str, Any] | None = None) -> None:
        self.runs: list[Run] = list(runs or [])
        self.attrs: dict[str, Any] = dict(attrs or {})
        self.path: Path | None = None
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

        The attributes keep a summary of every merged part (``merged_parts``: file, FMU name and hash, interface,
        settings, recording verdicts; :mod:`._merge`), from which ``fit`` says where the parts differ.

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
                self.attrs[MERGED_PARTS] = {"parts": merged_parts(other.attrs, other._part_name(1))}
            else:
                self._keep_common_settings(other.attrs)
                self._keep_parts(other)
        for run in runs:
            self._check_run(run)
            self.runs.append(run)
        return self

    def _keep_common_settings(self, attrs: dict[str, Any]) -> None:
        """``fmu_settings`` of merged snapshots: the settings every part was recorded with (a run table row's own
        ``set:``/``start:`` values belong to its runs, not to the data set, whose settings ``compare`` applies)."""
        if "fmu_settings" in self.attrs or "fmu_settings" in attrs:
            self.attrs["fmu_settings"] = shared_settings([settings_of(self.attrs), settings_of(attrs)])
        if "held_inputs" in self.attrs:
            shared = shared_held_inputs(self.attrs.pop("held_inputs"), attrs.get("held_inputs"))
            if shared is not None:
                self.attrs["held_inputs"] = shared
        if "source_parameters" in self.attrs:
            shared = shared_parameters(self.attrs.pop("source_parameters"), attrs.get("source_parameters"))
            if shared is not None:
                self.attrs["source_parameters"] = shared
        mine = texts(self.attrs.get("recording_warnings"))   # any part's warning is repeated for the whole set
        joined = mine + [text for text in texts(attrs.get("recording_warnings")) if text not in mine]
        if joined:
            self.attrs["recording_warnings"] = joined

    def _part_name(self, number: int) -> str:
        """How a merge names these snapshots: their file's name, else ``part <number>``."""
        return self.path.name if self.path is not None else f"part {number}"

    def _keep_parts(self, other: "Snapshots") -> None:
        """The summaries of all merged parts (:mod:`._merge`: file, FMU and its hash, interface, settings, verdicts),
        the set's FMU named as several where the parts come from different FMUs (:func:`._merge.merged_source`) and
        no interface where they differ in it, and as ``recording_verdicts`` only those every part carries: one
        part's Euler verdict does not make the fit treat every run as Euler steps (audit 72 F3); the fit says which
        parts carry which."""
        parts = merged_parts(self.attrs, self._part_name(1))
        parts += merged_parts(other.attrs, other._part_name(len(parts) + 1))
        self.attrs[MERGED_PARTS] = {"parts": parts}
        source = merged_source(parts)
        if source is not None:   # (no part's FMU stands for all: audit 72 F3)
            self.attrs.update(fmu_name=source, source=source)
            for key in SOURCE_KEYS:
                self.attrs.pop(key, None)
        if mixed_interfaces(parts):
            self.attrs.pop("fmi_interface", None)
        every = set(texts(self.attrs.pop("recording_verdicts", None)))   # (each side's: those all its parts carry)
        every &= set(texts(other.attrs.get("recording_verdicts")))
        if every:
            self.attrs["recording_verdicts"] = [verdict for verdict in VERDICTS if verdict in every]

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
        with atomic(path, overwrite) as f:
            write_file_attrs(f, self.attrs)
            runs = f.create_group("runs")
            for index, run in enumerate(self.runs):
                write_run(runs, index, run)
            f.attrs["n_runs"] = len(self.runs)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Snapshots":
        """Read a snapshot file completely into memory."""
        with cls.open(path) as lazy:
            check_memory(8.0 * sum(a.size for r in lazy.runs for a in r.arrays().values()),
                         f"loading {path} into memory", "open it lazily with Snapshots.open instead")
            with damaged_file_errors(Path(path)):   # (a chunk failing its checksum)
                loaded = cls([r.load() for r in lazy.runs], dict(lazy.attrs))
                loaded.path = lazy.path
                return loaded

    @classmethod
    def open(cls, path: str | os.PathLike) -> "Snapshots":
        """Open a snapshot file lazily: runs are backed by h5py datasets until :meth:`close`."""
        path = Path(path)
        if path.is_dir():
            raise FileFormatError(f"snapshot file {path} is a directory; give the .h5 file that "
                                  "'fmu-opinf snapshots' wrote")
        if not path.is_file():
            raise FileFormatError(f"snapshot file {path} " + ("is not a regular file; give the .h5 file that "
                                  "'fmu-opinf snapshots' wrote" if path.exists() else "does not exist"))
        try:
            f = h5py.File(path, "r")
        except OSError as exc:
            raise unreadable_file(path, "snapshot", "fmu-opinf snapshots", exc) from None
        try:
            with damaged_file_errors(path):
                snaps = cls._from_h5(f, path)
        except BaseException:
            f.close()
            raise
        snaps._file = f
        snaps.path = path
        return snaps

    @classmethod
    def _from_h5(cls, f: h5py.File, path: Path) -> "Snapshots":
        reject_links(f)
        attrs = decode(read_attrs(f))
        attrs.pop("n_runs", None)  # structural: len(runs)
        attrs.pop(SEAL_ATTR, None)  # describes this file only: a file saved from these attributes gets its own
        if "kind" not in attrs or "layout_version" not in attrs:
            raise FileFormatError(f"{path} is not an fmu-opinf snapshot file (no kind/layout_version attributes)")
        if attrs["kind"] != FILE_KIND:
            raise FileFormatError(f"{path} is not an fmu-opinf snapshot file (kind={attrs['kind']!r}, not "
                                  f"{FILE_KIND!r})")
        check_attr_types(attrs, SNAPSHOT_FILE_ATTRS, str(path))
        if int(attrs["layout_version"]) > LAYOUT_VERSION:
            raise FileFormatError(f"{path} has snapshot layout {attrs['layout_version']}, newer than this tool's "
                                  f"{LAYOUT_VERSION}; upgrade fmu-opinf")
        if int(attrs["layout_version"]) < 1:   # the first layout is 1 (a ROM file's 0 was refused, this one read)
            raise FileFormatError(f"{path} has snapshot layout {attrs['layout_version']}, which no fmu-opinf wrote "
                                  "(layouts start at 1); the file is damaged or not this tool's")
        group = f.get("runs")
        if group is not None and not isinstance(group, h5py.Group):
            raise FileFormatError(f"{path}: 'runs' is not a group; the file is damaged")
        sizes = {key: attrs.get(key) for key in ("n", "m", "p")}
        runs = []
        for name in sorted(group or {}):
            g = group[name]
            sizes = check_snapshot_run(g, f"{path}: run {name}", sizes)
            run_attrs = decode(read_attrs(g))
            check_attr_types(run_attrs, SNAPSHOT_RUN_ATTRS, f"{path}: run {name}")
            _check_step(g["t"], run_attrs.get("dt"), f"{path}: run {name}: its attribute dt")
            if not runs:
                _check_step(g["t"], attrs.get("dt"), f"{path}: the file's attribute dt")
            initial = {a: np.array(g[a][()]) for a in INITIAL if a in g}  # layout 1 has none: first samples
            start = read_model_start(g, run_attrs, int(sizes["n"]), f"{path}: run {name}")
            runs.append(Run(**{a: g[a] for a in ARRAYS}, attrs=run_attrs, **initial, model_start=start))
        _check_per_column(attrs, sizes, path)
        check_seal(f, path)   # last: a change the checks above name is said in their words, any other here
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


#: Largest relative difference of a ``dt`` attribute from the mean step of the samples it describes (the times are
#: ``t0 + i dt``, exact to rounding).
STEP_TOL = 1e-9


def _check_step(t: Any, dt: Any, what: str) -> None:
    """Refuse a ``dt`` attribute that is not the step of the stored times ``t`` (a checked dataset): the fit
    and the ROM take the step from it, and attributes carry no HDF5 checksum (audit 63: one flipped bit made
    dt 0.01049 beside times 0.01 apart, and the ROM was 3.0e-2 off with no word)."""
    if dt is None or t.shape[0] < 2:
        return
    first, last = (float(value) for value in t[[0, -1]])
    step = (last - first) / (t.shape[0] - 1)
    if abs(step - float(dt)) > STEP_TOL * abs(step):
        raise FileFormatError(f"{what} is {float(dt):.10g}, but the stored times are {step:.10g} apart; the file "
                              "is damaged: restore it from a copy or record it again with 'fmu-opinf snapshots'")


#: Per-input number attributes and what each entry must be: start values finite, declared bounds any number but
#: NaN (infinite where the source declares none), declared nominals finite and not negative (0 where none).
_PER_INPUT_NUMBERS = {"input_starts": "finite number", "input_min": "number", "input_max": "number",
                      "input_nominal": "finite number >= 0"}


def _check_per_column(attrs: dict[str, Any], sizes: dict[str, Any], path: Path) -> None:
    """One name per position, input and output, one finite start value, one declared bound (``input_min``,
    ``input_max``, not NaN) and, where recorded, one declared nominal (``input_nominal``, 0 for none) per input
    (audit 55: a damaged file's extra output name went unseen and the report labelled the outputs wrongly; NaN start
    values made the exported ROM FMU's inputs start at 0 without a word)."""
    for key, size in (("position_names", "n"), ("input_names", "m"), ("output_names", "p"), ("input_starts", "m"),
                      ("input_min", "m"), ("input_max", "m"), ("input_nominal", "m")):
        values, count = attrs.get(key), sizes.get(size)
        if values is None or count is None:
            continue
        values = list(np.ravel(values)) if isinstance(values, np.ndarray) else values
        wrong = not isinstance(values, (list, tuple)) or len(values) != int(count)
        if not wrong and key in _PER_INPUT_NUMBERS:
            finite = key in ("input_starts", "input_nominal")
            wrong = not all(_is_number(v, finite=finite) and (key != "input_nominal" or v >= 0) for v in values)
        if wrong:
            raise FileFormatError(f"{path}: its {key.replace('_', ' ')} do not give one "
                                  f"{_PER_INPUT_NUMBERS.get(key, 'name')} for each of its {count} "
                                  "columns; the file is damaged: record the snapshots again")


def _is_number(value: Any, finite: bool) -> bool:
    """Whether an attribute's entry is a number (not NaN; finite too where ``finite``)."""
    if not isinstance(value, (int, float, np.number)) or np.isnan(value):
        return False
    return bool(np.isfinite(value)) or not finite


def _short(value: Any) -> str:
    text = str(value)
    return text if len(text) < 60 else text[:57] + "..."


def _initial(value: Any, samples: Any) -> np.ndarray:
    """The given initial values, else the first column of ``samples`` (zeros for an empty run)."""
    if value is not None:
        return np.asarray(value, dtype=float).reshape(-1)
    rows, k = samples.shape[0], samples.shape[-1]
    return np.array(samples[:, 0], dtype=float) if k and rows else np.zeros(rows)

