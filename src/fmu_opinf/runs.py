"""Run tables: many training or test runs of one source, recorded or compared sequentially or on Dask.

A run table is a CSV file with a header and one row per run (``docs/scale-out.md``)::

    name,input,set:k,start:x[1]
    base,impulse:amplitude=100,t0=2,width=0.5,,
    stiff,impulse:amplitude=100,t0=2,width=0.5,2.5,
    shifted,loads/case3.csv,,0.01

* ``input`` (required): an input specification (:mod:`fmu_opinf.signals`); a relative ``.csv`` path is
  relative to the table's folder.  Specs separated by ``;`` list the inputs in the source's order: the FMU's
  declared order, or the order of ``--inputs`` where the command is given one.  ``compare --runs`` reads them in
  the same order and hands each to the ROM's input of that name (:func:`in_rom_order`), so that a table means the
  same in ``snapshots --runs`` and in ``compare --runs`` against a ROM trained with its inputs in another order.
* ``name`` (optional): the run's name, also its file name ``NAME.h5``; default ``run-NNNN`` (row number).
* ``set:NAME``: a start value set before initialization (an FMU parameter), ``start:NAME``: an initial-state
  value (the start value of a state variable, or of its ``<state>_start`` parameter; any other parameter is refused
  with a pointer to ``set:``).  An empty cell leaves the value at the model's default.

The whole table is read and validated before anything runs; every problem is one line naming the row and
the column.  Recording writes one snapshot file per run into an output directory (``NAME.h5``, or
``NAME.incomplete.h5`` for a run that stopped early), each stamped with the row it came from (file and run
attribute ``run_row``).  A rerun skips every row whose complete file carries the same stamp.  Without ``--dt``
every row is recorded at one step, the finest of the rows' own (:func:`record_runs`), so that the runs fit
together (audit 72).

With a scheduler (``local``, ``local:N`` or ``tcp://HOST:PORT``) every row is a Dask task on a worker
process; without one the rows run one after another in this process.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import hashlib
import json
import math
import numbers
import os
import re
import sys
import time
import warnings
import weakref
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import h5py

from ._interrupts import check_interrupt
from ._seal import seal_attributes
from .errors import FmuOpinfError, InputSpecError

__all__ = [
    "RunRow", "RunOutcome", "RunTableReport", "RunTableError", "read_run_table", "validate_rows",
    "row_source_options", "source_input_names", "in_rom_order", "record_row", "row_window", "record_runs",
    "compare_runs", "dask_client", "parse_scheduler",
]

ROW_ATTR = "run_row"
INCOMPLETE_SUFFIX = ".incomplete.h5"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_PREFIXES = ("set:", "start:")


class RunTableError(InputSpecError):
    """A run table is malformed (the message names the row and the column)."""


@dataclasses.dataclass(frozen=True)
class RunRow:
    """One row of a run table.

    Attributes
    ----------
    number : int
        Data row number, 1-based (the header is row 0), as named in error messages.
    name : str
        Run name (file name stem).
    input : str
        Input specification (relative ``.csv`` paths already resolved).
    set : dict of str to float
        Start values set before initialization (``set:NAME`` columns).
    start : dict of str to float
        Initial-state values (``start:NAME`` columns).
    """

    number: int
    name: str
    input: str
    set: dict[str, float] = dataclasses.field(default_factory=dict)
    start: dict[str, float] = dataclasses.field(default_factory=dict)

    def provenance(self) -> dict[str, Any]:
        """The row as a JSON-able dict (stored with its run)."""
        return {"number": self.number, "name": self.name, "input": self.input, "set": dict(self.set),
                "start": dict(self.start)}


# ---------------------------------------------------------------------------------------------
# Reading and validating
# ---------------------------------------------------------------------------------------------
def read_run_table(path: str | os.PathLike) -> list[RunRow]:
    """Read and check a run table (CSV, header row, one row per run).

    Parameters
    ----------
    path : str or path-like
        The table; columns ``input`` (required), ``name``, ``set:NAME``, ``start:NAME``.

    Returns
    -------
    list of RunRow
        In table order.

    Raises
    ------
    RunTableError
        One line naming the table, row and column of the first problem.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            lines = [row for row in csv.reader(f) if row and any(c.strip() for c in row)
                     and not row[0].lstrip().startswith("#")]
    except FileNotFoundError:
        raise RunTableError(f"run table {path} not found; give an existing .csv file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise RunTableError(f"cannot read run table {path} ({exc}); give a utf-8 .csv file") from None
    if len(lines) < 2:
        raise RunTableError(f"run table {path} has no runs; give a header and one row per run")
    header = [c.strip() for c in lines[0]]
    _check_header(path, header)
    rows = [_parse_row(path, header, cells, number) for number, cells in enumerate(lines[1:], start=1)]
    _check_unique_names(path, rows)
    return rows


def _check_header(path: Path, header: list[str]) -> None:
    if "input" not in header:
        raise RunTableError(f"run table {path} has no 'input' column; the header needs input "
                            "(and optionally name, set:NAME, start:NAME)")
    for column in header:
        if column not in ("input", "name") and not (column.startswith(_PREFIXES) and column.split(":", 1)[1]):
            raise RunTableError(f"run table {path}: unknown column {column!r}; use input, name, set:NAME or "
                                "start:NAME")
    seen = set()
    for column in header:
        if column in seen:
            raise RunTableError(f"run table {path}: column {column!r} appears twice; keep one")
        seen.add(column)


def _parse_row(path: Path, header: list[str], cells: list[str], number: int) -> RunRow:
    where = f"run table {path} row {number}"
    if len(cells) != len(header):
        raise RunTableError(f"{where} has {len(cells)} cells but the header has {len(header)}; quote cells "
                            "that contain commas (e.g. \"impulse:amplitude=1,t0=2\")")
    values = {column: cell.strip() for column, cell in zip(header, cells)}
    spec = values["input"]
    if not spec:
        raise RunTableError(f"{where}, column 'input' is empty; give an input specification")
    name = values.get("name") or f"run-{number:04d}"
    if not _NAME.match(name) or name.endswith(INCOMPLETE_SUFFIX[:-3]):
        raise RunTableError(f"{where}, column 'name': {name!r} is not usable as a file name; use letters, "
                            "digits, '_', '-' and '.'")
    numbers: dict[str, dict[str, float]] = {"set": {}, "start": {}}
    for column, cell in values.items():
        if not column.startswith(_PREFIXES) or not cell:
            continue
        kind, variable = column.split(":", 1)
        try:
            value = float(cell)
        except ValueError:
            raise RunTableError(f"{where}, column {column!r}: {cell!r} is not a number") from None
        if not math.isfinite(value):
            raise RunTableError(f"{where}, column {column!r}: {cell!r} is not a finite number")
        numbers[kind][variable] = value
    return RunRow(number, name, _resolve_csv_paths(spec, path.parent), numbers["set"], numbers["start"])


def _resolve_csv_paths(spec: str, folder: Path) -> str:
    """Make relative ``.csv`` parts of a specification relative to the table's folder."""
    parts = [p.strip() for p in spec.split(";")]
    resolved = [str((folder / p).resolve()) if p.lower().endswith(".csv") and not Path(p).is_absolute() else p
                for p in parts]
    return ";".join(resolved)


def _check_unique_names(path: Path, rows: list[RunRow]) -> None:
    first: dict[str, int] = {}
    for row in rows:
        if row.name in first:
            raise RunTableError(f"run table {path} row {row.number}, column 'name': {row.name!r} is already the "
                                f"name of row {first[row.name]}; names must be unique")
        first[row.name] = row.number


def row_source_options(row: RunRow, options: dict[str, Any] | None = None) -> dict[str, Any]:
    """Source keywords for one row: ``options`` plus the row's start values.

    This is the one place that maps a row's ``set:`` and ``start:`` values onto the source's keywords
    (today :class:`fmu_opinf.source.FMUSource` takes them as ``parameters``: start values set before
    initialization, which covers parameters and initial states alike).
    """
    merged = dict(options or {})
    values = {**row.set, **row.start}
    if values:
        merged["parameters"] = {**(merged.get("parameters") or {}), **values}
    return merged


def validate_rows(rows: Sequence[RunRow], source_spec: str | os.PathLike,
                  source_options: dict[str, Any] | None = None) -> None:
    """Check every row against the source before anything runs: start-value names and input specifications.

    Raises
    ------
    RunTableError
        One line naming the row and the column of the first problem.
    """
    from .signals import parse_signal
    from .source import open_source

    _check_start_columns(rows, source_spec)
    for row in rows:
        try:
            source = open_source(source_spec, **row_source_options(row, source_options))
        except FmuOpinfError as exc:
            column = ", ".join([f"set:{k}" for k in row.set] + [f"start:{k}" for k in row.start]) or "source"
            raise RunTableError(f"row {row.number} ({row.name}), column {column}: {exc}") from None
        try:
            parse_signal(row.input, source.m, source.input_names)
        except FmuOpinfError as exc:
            raise RunTableError(f"row {row.number} ({row.name}), column 'input': {exc}") from None


def _check_start_columns(rows: Sequence[RunRow], source_spec: str | os.PathLike) -> None:
    """Refuse a ``start:`` column that names no initial state of the FMU ``source_spec`` (a parameter: ``set:``'s
    job), or a state whose start is calculated from a ``<state>_start`` parameter (:mod:`._model_start`)."""
    from ._model_start import start_column_problem
    from .sources._variables import read_description

    text = os.fspath(source_spec)
    if text.startswith("builtin:") or not any(row.start for row in rows):
        return
    try:
        description = read_description(Path(text))
    except FmuOpinfError:
        return   # (opening the source says what is wrong with it)
    for row in rows:
        for name in row.start:
            problem = start_column_problem(description, name)
            if problem:
                raise RunTableError(f"row {row.number} ({row.name}), column start:{name}: {problem}")


def source_input_names(source_spec: str | os.PathLike, source_options: dict[str, Any] | None = None) -> list[str]:
    """The inputs of ``source_spec`` opened with ``source_options``, in order: the order in which a run table's
    ``;``-separated specs list them (the FMU's declared order, or that of the command's ``--inputs``)."""
    from .source import open_source

    source = open_source(source_spec, **(source_options or {}))
    try:
        return list(source.input_names)
    finally:
        getattr(source, "close", lambda: None)()


def in_rom_order(row: RunRow, table_inputs: Sequence[str], rom_inputs: Sequence[str]) -> RunRow:
    """``row`` with its ``;``-separated specs, which list ``table_inputs`` (the source's inputs), moved to the
    order of ``rom_inputs``, the ROM's: each spec to the ROM input of its name.

    A spec for an input the ROM does not drive must be ``none`` (the comparison holds that input at its start
    value, as the ROM's training did) and is left out.  A row with a single spec, which drives every input or is a
    table whose header names them, is returned as it is.

    Raises
    ------
    RunTableError
        One line: the row gives a signal to an input the ROM does not drive, or has no spec for one it does.
    """
    parts = row.input.split(";")
    table_inputs, rom_inputs = list(table_inputs), list(rom_inputs)
    if len(parts) < 2 or len(parts) != len(table_inputs) or table_inputs == rom_inputs:
        return row   # (a count that does not match the source's inputs was refused by validate_rows)
    where = f"row {row.number} ({row.name}), column 'input'"
    order = ", ".join(table_inputs)
    missing = [name for name in rom_inputs if name not in table_inputs]
    if missing:
        raise RunTableError(f"{where}: its ';' specs list the source's inputs ({order}), but the ROM also drives "
                            f"{', '.join(missing)}; compare with the inputs the ROM was trained on (--inputs)")
    driven = [name for name, part in zip(table_inputs, parts)
              if name not in rom_inputs and part.strip().lower() != "none"]
    if driven:
        raise RunTableError(f"{where}: its ';' specs list the source's inputs ({order}) and give a signal to "
                            f"{', '.join(driven)}, which the ROM does not drive (its inputs: {', '.join(rom_inputs)});"
                            " give none for it, or compare a ROM trained with that input")
    return dataclasses.replace(row, input=";".join(parts[table_inputs.index(name)] for name in rom_inputs))


# ---------------------------------------------------------------------------------------------
# Outcomes
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class RunOutcome:
    """What happened to one row: ``status`` is ``"recorded"``, ``"skipped"`` (complete already) or ``"failed"``
    (``"compared"`` for :func:`compare_runs`); ``seconds`` is wall time, ``cpu_seconds`` the CPU time of the
    process that ran it (with the isolated FMU process)."""

    number: int
    name: str
    status: str
    path: str | None = None
    k: int = 0
    seconds: float = 0.0
    error: str = ""
    worker: str = ""
    cpu_seconds: float = 0.0
    retries: int = 0

    def line(self) -> str:
        """One line for progress output."""
        text = f"row {self.number} ({self.name}): {self.status}"
        again = f" (retried after {self.retries} lost worker(s))" if self.retries else ""
        if self.status != "failed":
            return (f"{text}, k={self.k} samples, {self.seconds:.2f}s" + (f" on {self.worker}" if self.worker else "")
                    + again)
        return f"{text}: {self.error}{again}"


@dataclasses.dataclass
class RunTableReport:
    """Outcomes of all rows, in table order."""

    outcomes: list[RunOutcome]
    seconds: float = 0.0

    @property
    def failed(self) -> list[RunOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    def describe(self) -> str:
        counts = {s: sum(o.status == s for o in self.outcomes) for s in ("recorded", "skipped", "failed")}
        head = (f"{len(self.outcomes)} run(s) in {self.seconds:.1f}s: {counts['recorded']} recorded, "
                f"{counts['skipped']} already complete, {counts['failed']} failed")
        return "\n".join([head] + ["  " + o.line() for o in self.outcomes])

    def raise_for_failures(self) -> None:
        """Raise one :class:`~fmu_opinf.errors.FmuOpinfError` naming the failed rows (if any)."""
        if self.failed:
            names = "; ".join(f"row {o.number} ({o.name}): {o.error}" for o in self.failed)
            raise FmuOpinfError(f"{len(self.failed)} of {len(self.outcomes)} runs failed, the others are kept: "
                                f"{names}")


# ---------------------------------------------------------------------------------------------
# Recording one row (runs on a worker, or in this process)
# ---------------------------------------------------------------------------------------------
def _stamp(source_spec: Any, row: RunRow, settings: dict[str, Any], options: dict[str, Any]) -> dict[str, Any]:
    """What must agree for an existing file to count as this row's result."""
    from ._hdf5 import jsonable

    row_stamp = {**row.provenance(), "input_identity": _input_identity(row.input)}
    return jsonable({"source": os.fspath(source_spec), "source_identity": _file_identity(source_spec),
                     "row": row_stamp, "settings": settings, "source_options": options})


@functools.lru_cache(maxsize=8)
def _hash_file(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return "sha256:" + digest.hexdigest()


def _file_identity(spec: Any) -> str:
    """A content hash of a source file (``builtin:`` sources: their name); a rebuilt FMU is a new source."""
    path = Path(os.fspath(spec))
    if not path.is_file():
        return os.fspath(spec)
    info = path.stat()
    return _hash_file(str(path), info.st_size, info.st_mtime_ns)


def _input_identity(spec: str) -> str:
    """The input specification with each ``.csv`` part replaced by a hash of its content (an edited input table
    is a new run; a study folder moved elsewhere is not)."""
    parts = []
    for part in spec.split(";"):
        path = Path(part.strip())
        if part.strip().lower().endswith(".csv") and path.is_file():
            part = "csv-" + _file_identity(path)
        parts.append(part)
    return ";".join(parts)


def _same_stamp(a: dict[str, Any], b: dict[str, Any]) -> bool:
    def key(stamp: dict[str, Any]) -> str:
        row = dict(stamp.get("row", {}))
        row.pop("number", None)  # moving a row within the table keeps its result
        row["input"] = row.get("input_identity", row.get("input", ""))
        row.pop("input_identity", None)
        rest = {k: v for k, v in stamp.items() if k != "source"} if "source_identity" in stamp else stamp
        return json.dumps({**rest, "row": row}, sort_keys=True)

    return key(a) == key(b)


def _is_done(path: Path, stamp: dict[str, Any]) -> tuple[bool, int]:
    """Whether ``path`` is a complete file of this row (and its sample count)."""
    if not path.exists():
        return False, 0
    try:
        with h5py.File(path, "r") as f:
            found = json.loads(f.attrs.get(ROW_ATTR, "{}"))
            runs = [f["runs"][key] for key in sorted(f["runs"])]
            complete = bool(runs) and all(bool(g.attrs.get("complete", False)) for g in runs)
            k = sum(int(g.attrs.get("k", 0)) for g in runs)
    except (OSError, KeyError, ValueError):
        return False, 0
    return complete and _same_stamp(found, stamp), k


def _stamp_file(path: Path, stamp: dict[str, Any], start: tuple[dict[str, Any], dict[str, Any]] | None = None) -> int:
    """Write the row's stamp (and the model's own ``start``: arrays and provenance, :func:`_model_start_of`) into
    every run of ``path`` and seal the attributes again; returns the number of samples."""
    from ._hdf5 import write_attrs
    from .snapshots._file import MODEL_START, write_model_start

    with h5py.File(path, "r+") as f:
        text = json.dumps(stamp, sort_keys=True)
        f.attrs[ROW_ATTR] = text
        k = 0
        for key in sorted(f["runs"]):
            f["runs"][key].attrs[ROW_ATTR] = text
            k += int(f["runs"][key].attrs.get("k", 0))
            if start is not None:
                write_model_start(f["runs"][key], start[0])
                write_attrs(f["runs"][key], {MODEL_START: start[1]})
        seal_attributes(f)   # the stamp changed the attributes the recording sealed
    return k


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return get_worker().address
    except (ImportError, ValueError):
        return ""


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (an isolated FMU's process)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def record_row(source_spec: Any, row: RunRow, out_dir: str | os.PathLike, settings: dict[str, Any] | None = None,
               source_options: dict[str, Any] | None = None, isolate: bool = True,
               check_linearity: bool = True) -> RunOutcome:
    """Record one row into ``out_dir/NAME.h5`` (skipped when a complete file of the same row is there).

    The file is written as ``.NAME.partial.h5``, stamped with the row (attribute ``run_row``) and renamed into
    place, so a file with the stamp is always whole.  A run that stops early keeps its samples in
    ``NAME.incomplete.h5``; errors come back in the outcome instead of being raised.

    Parameters
    ----------
    source_spec : str or path-like
        ``builtin:NAME`` or an FMU path (must be readable where this runs).
    row : RunRow
    out_dir : str or path-like
        Output directory (shared by all workers).
    settings : dict, optional
        Keywords of :func:`fmu_opinf.snapshots.record_to_file` common to all rows (``dt``, ``t_end``, ...).
    source_options : dict, optional
        Source keywords common to all rows (variable patterns, builtin sizes).
    isolate : bool, default=True
        Run an FMU in its own child process (a crashing binary then loses only its step).
    check_linearity : bool, default=True
        Check that the row's response scales with its input (``record_to_file(check_linearity=)``; not part of
        the row's stamp: a row recorded without the check is not recorded again for it).

    Returns
    -------
    RunOutcome
    """
    from .snapshots import record_to_file

    settings, options = dict(settings or {}), dict(source_options or {})
    out_dir = Path(out_dir)
    final, failed = out_dir / f"{row.name}.h5", out_dir / f"{row.name}{INCOMPLETE_SUFFIX}"
    stamp = _stamp(source_spec, row, settings, options)
    partial = out_dir / f".{row.name}.partial.h5"
    _remove_stale_temporaries(partial)
    done, k = _is_done(final, stamp)
    if done:
        return RunOutcome(row.number, row.name, "skipped", str(final), k, worker=_worker_name())
    started, cpu, error = time.perf_counter(), _cpu_seconds(), ""
    try:
        record_to_file(source_spec, partial, row.input, overwrite=True, quiet=True, isolate=isolate,
                       check_linearity=check_linearity, **settings, **row_source_options(row, options))
    except FmuOpinfError as exc:
        error = str(exc)
    try:
        start = None if error or not partial.exists() else _model_start_of(source_spec, partial, row, isolate)
    except BaseException:   # interrupted while the model's start is read: the row's previous result stays
        _discard_intermediate(partial)
        raise
    seconds, cpu = time.perf_counter() - started, _cpu_seconds() - cpu
    if not partial.exists():
        final.unlink(missing_ok=True)  # a result of an earlier version of this row is not this row's result
        return RunOutcome(row.number, row.name, "failed", None, 0, seconds, error, _worker_name(), cpu)
    target = failed if error else final
    k = _move_into_place(partial, target, stamp, start)
    error = error.replace(str(partial), str(target))
    (final if error else failed).unlink(missing_ok=True)
    return RunOutcome(row.number, row.name, "failed" if error else "recorded", str(target), k, seconds, error,
                      _worker_name(), cpu)


def _model_start_of(source_spec: Any, partial: Path, row: RunRow,
                    isolate: bool) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """The model's own start to store with a row that has ``start:`` values (:func:`._model_start.start_to_record`:
    the FMU initialized without them, so that the fit need not open it); None for other rows.  A failure to read
    it is stored as its reason, not raised: the row's recording stands."""
    from ._model_start import start_to_record

    try:
        return start_to_record(source_spec, partial, row, isolate)
    except FmuOpinfError as exc:
        return {}, {"row": {"number": row.number, "name": row.name}, "reason": f"it could not be read ({exc})"}


def _move_into_place(partial: Path, target: Path, stamp: dict[str, Any],
                     start: tuple[dict[str, Any], dict[str, Any]] | None = None) -> int:
    """Stamp the row's intermediate file (with the model's own ``start`` where given) and rename it to ``target``;
    the list of written outputs (:data:`fmu_opinf._hdf5.REPLACED`) names ``target``, not the hidden intermediate
    (audit 68).  Interrupted before the rename, the intermediate is removed and the row's previous result stays."""
    from ._hdf5 import REPLACED

    try:
        k = _stamp_file(partial, stamp, start)
        check_interrupt()  # a Ctrl-C swallowed in an h5py finalizer: the row's previous result stays
        os.replace(partial, target)
    except BaseException:
        _discard_intermediate(partial)
        raise
    _discard_intermediate(partial)   # (renamed: only its name in the list of written outputs)
    REPLACED.append(target)
    return k


def _discard_intermediate(partial: Path) -> None:
    """Remove a row's hidden intermediate file and its name from the list of written outputs
    (:data:`fmu_opinf._hdf5.REPLACED`): an interrupted row names no file it did not leave (audit 68)."""
    from ._hdf5 import REPLACED

    partial.unlink(missing_ok=True)
    while partial in REPLACED:
        REPLACED.remove(partial)


def _remove_stale_temporaries(partial: Path) -> None:
    """Remove what an earlier attempt at this row left: the intermediate ``partial`` and the temporary files
    that :func:`fmu_opinf._hdf5.atomic_path` makes for it (``.NAME.partial.h5.XXXXXXXX.tmp``).  A worker killed by
    its nanny after a Ctrl-C, or lost and retried by Dask, cannot remove its own (audit 68).  Only names of exactly
    that pattern, of this row, are touched."""
    from ._hdf5 import _TEMPORARY_PREFIX

    pattern = re.compile(re.escape(partial.name[:_TEMPORARY_PREFIX] + ".") + r"[a-z0-9_]{8}\.tmp")
    try:
        entries = list(os.scandir(partial.parent))
    except OSError:
        return
    for entry in entries:
        if (entry.name == partial.name or pattern.fullmatch(entry.name)) and entry.is_file(follow_symlinks=False):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)


# ---------------------------------------------------------------------------------------------
# Schedulers
# ---------------------------------------------------------------------------------------------
def parse_scheduler(text: str) -> tuple[str, int | None]:
    """``"local"`` / ``"local:N"`` -> ``("local", N or None)``; ``"tcp://HOST:PORT"`` -> (address, None)."""
    text = text.strip()
    if text == "local":
        return "local", None
    if text.startswith("local:"):
        count = text.split(":", 1)[1]
        if not count.isdigit() or int(count) < 1:
            raise InputSpecError(f"--scheduler {text}: {count!r} is not a positive number of workers; "
                                 "use e.g. local:4")
        return "local", int(count)
    if re.match(r"^(tcp|tls|inproc|ucx)://\S+$", text):
        return text, None
    raise InputSpecError(f"--scheduler {text!r} is not understood; use local, local:N or tcp://HOST:PORT")


def _require_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise FmuOpinfError("--scheduler needs dask and distributed; install them with "
                            "pip install 'fmu-opinf[dask]'") from None
    return distributed


@contextlib.contextmanager
def dask_client(scheduler: Any, isolate: bool = False) -> Iterator[Any]:
    """A ``distributed.Client`` for a scheduler spec (or the given client, left open), closed afterwards.

    ``local[:N]`` starts a local cluster of N single-threaded worker processes (default: one per core).  Its
    workers are not daemonic, so that a worker can start the recorder's isolated child process for an FMU;
    workers of a running cluster (``tcp://...``) need the same setting (``DASK_DISTRIBUTED__WORKER__DAEMON=False``
    in their environment) to record FMUs with isolation.  With ``isolate`` (FMU runs in child processes), the
    workers of a given client or address are checked for that once per client, before any row runs.
    """
    distributed = _require_distributed()
    if isinstance(scheduler, distributed.Client):
        _check_workers_can_isolate(scheduler, isolate)
        yield scheduler
        return
    address, workers = parse_scheduler(str(scheduler))
    if address == "local":
        with _local_cluster_client(distributed, workers) as client:
            yield client
        return
    try:
        client = distributed.Client(address, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise FmuOpinfError(f"cannot reach the dask scheduler at {address} ({exc}); start it or check "
                            "the address") from None
    except TypeError as exc:  # tls:// without TLS settings: distributed asks for an ssl_context
        raise FmuOpinfError(f"cannot connect to the dask scheduler at {address} ({exc}); for tls:// set "
                            "distributed's distributed.comm.tls configuration (ca-file, client cert and key), "
                            "or pass a distributed.Client with its Security in Python") from None
    with client:
        _check_workers_can_isolate(client, isolate)
        yield client


@contextlib.contextmanager
def _local_cluster_client(distributed: Any, workers: int | None) -> Iterator[Any]:
    """A client of a new local cluster, closed when the block ends (also on Ctrl-C, before the interpreter's exit).

    Ctrl-C from a terminal reaches the whole process group: the workers printed ``KeyboardInterrupt`` tracebacks
    (in the middle of their imports, too), and a Ctrl-C while the cluster started left it half made, for
    distributed's exit hook to fail on (audit 68).  So a Ctrl-C while the cluster starts is deferred until the
    cluster and its client are ready to be closed, and each worker ignores SIGINT once it runs (the client acts on
    it).  The workers close their running rows cleanly
    (:class:`fmu_opinf._dask_plugin.StopRowsOnClose`), and distributed logs only errors (the table's outcome
    names a row that was retried after a lost worker).
    """
    import logging

    import dask

    from ._dask_plugin import StopRowsOnClose

    # Workers are not daemonic (an FMU's isolated child process), and their glibc keeps its dynamic mmap threshold:
    # distributed's default MALLOC_TRIM_THRESHOLD_ disables it, so that every array above 128 kB of a simulation
    # step is mapped and page-faulted afresh (measured: 1.8x the CPU time of a g = 2e4 recording).
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ").items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    # The workers' statistical profiler (a stack sample every 10 ms) costs a run ~10% CPU: off.
    settings = {"distributed.worker.daemon": False, "distributed.nanny.pre-spawn-environ": environ,
                "distributed.worker.profile.enabled": False}
    logger = logging.getLogger("distributed")
    level = logger.level
    try:
        with dask.config.set(settings), contextlib.ExitStack() as stack:
            with _interrupts_after():  # a Ctrl-C meanwhile is raised once both are ready to be closed
                cluster = stack.enter_context(distributed.LocalCluster(
                    n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                    dashboard_address=None, silence_logs=logging.ERROR))
                client = stack.enter_context(distributed.Client(cluster))
                client.register_plugin(StopRowsOnClose())
            try:
                yield client
            except KeyboardInterrupt:  # closing after a Ctrl-C: the cluster's complaints about it are no news
                logger.setLevel(logging.CRITICAL)
                raise
    finally:
        logger.setLevel(level)


@contextlib.contextmanager
def _interrupts_after() -> Iterator[None]:
    """SIGINT and SIGTERM only noted while the block runs, and raised as
    :class:`~fmu_opinf.errors.Interrupted` when it ends, also when the block failed meanwhile (workers that a
    Ctrl-C to the process group hit in their imports make the cluster fail to start).  Main thread only."""
    import signal
    import threading

    from .errors import Interrupted

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []
    previous = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(signum) not in (signal.SIG_IGN, None)}
    for signum in previous:
        signal.signal(signum, lambda number, frame: noted.append(number))
    try:
        yield
    except Exception as exc:
        if noted:
            raise Interrupted(noted[0]) from exc
        raise
    finally:
        for signum, old in previous.items():
            signal.signal(signum, old)
    if noted:
        raise Interrupted(noted[0])


def _worker_is_daemonic() -> bool:
    import multiprocessing

    return bool(multiprocessing.current_process().daemon)


def _check_workers_can_isolate(client: Any, isolate: bool) -> None:
    """Stop with one line if the client's workers are daemonic processes and FMU runs are to be isolated: every
    row would fail with a bare ``AssertionError: daemonic processes are not allowed to have children`` (audit 68,
    a ``LocalCluster`` made with Dask's defaults)."""
    if not isolate or client in _ISOLATION_CHECKED:
        return
    daemonic = sorted(address for address, flag in client.run(_worker_is_daemonic).items() if flag)
    if daemonic:
        raise FmuOpinfError(f"the Dask workers {', '.join(daemonic)} are daemonic processes, which cannot start the "
                            "FMU's isolated child process; start them with DASK_DISTRIBUTED__WORKER__DAEMON=False "
                            "(or dask.config distributed.worker.daemon=False), or pass isolate=False "
                            "(command line: --in-process)")
    _ISOLATION_CHECKED.add(client)


#: Clients whose workers were found able to start isolated FMU processes (a client is checked once).
_ISOLATION_CHECKED: weakref.WeakSet = weakref.WeakSet()


# ---------------------------------------------------------------------------------------------
# Recording a table
# ---------------------------------------------------------------------------------------------
def _progress_printer(quiet: bool) -> Callable[[RunOutcome, int, int], None]:
    def show(outcome: RunOutcome, done: int, total: int) -> None:
        if not quiet:
            print(f"[{done}/{total}] {outcome.line()}", file=sys.stderr, flush=True)

    return show


def record_runs(
    source_spec: str | os.PathLike,
    runs: str | os.PathLike | Sequence[RunRow],
    output: str | os.PathLike,
    *,
    scheduler: Any = None,
    dt: float | None = None,
    t_end: float | None = None,
    auto_window: bool = False,
    isolate: bool = True,
    quiet: bool = False,
    progress: Callable[[RunOutcome, int, int], None] | None = None,
    check_linearity: bool = True,
    **source_options: Any,
) -> RunTableReport:
    """Record every row of a run table into its own snapshot file in ``output`` (a directory).

    Parameters
    ----------
    source_spec : str or path-like
        ``builtin:NAME`` or an FMU path.
    runs : path or list of RunRow
        The run table (:func:`read_run_table`) or its rows.
    output : str or path-like
        Output directory (created); ``NAME.h5`` per complete run, ``NAME.incomplete.h5`` per failed run.
        With a cluster it must be on a file system all workers share.
    scheduler : None, str or distributed.Client
        None: the rows run one after another in this process.  ``"local"``, ``"local:N"``,
        ``"tcp://HOST:PORT"`` or a client: one Dask task per row.
    dt, t_end, auto_window
        As for :func:`fmu_opinf.snapshots.record_to_file` (the same for every row).  Without ``dt``, each row's
        step is chosen first (its pilot runs, or the FMU's declared step) and every row is recorded at the finest
        of them, to its own end (:func:`_at_one_step`): the runs then fit together.
    isolate : bool, default=True
        Crash isolation of FMUs (the recorder's child process), on the workers too.
    quiet : bool, default=False
        No progress lines on stderr.
    progress : callable, optional
        ``progress(outcome, done, total)`` after each row (default: a line on stderr unless quiet).
    check_linearity : bool, default=True
        Check that the response scales with the input (``record_to_file(check_linearity=)``) on the rows that
        drive some input furthest among the rows of the same ``set:``/``start:`` values (:func:`_rows_to_check`:
        one extra run each, not one per row); False: on none.
    **source_options
        Source keywords common to all rows (variable patterns, ``constraint``, builtin sizes such as ``g``).

    Returns
    -------
    RunTableReport
        One outcome per row in table order; failed rows do not stop the others (see
        :meth:`RunTableReport.raise_for_failures`).
    """
    rows = list(runs) if not isinstance(runs, (str, os.PathLike)) else read_run_table(runs)
    source_options = {k: v for k, v in source_options.items() if v is not None}
    validate_rows(rows, source_spec, source_options)
    out_dir, made = _output_directory(output)
    try:
        source_spec = _shared_spec(source_spec)
        settings = {k: v for k, v in {"dt": _as_float(dt), "t_end": _as_float(t_end),
                                      "auto_window": auto_window or None}.items() if v is not None}
        from .snapshots._inputs import is_free_response

        forced = any(not is_free_response(row.input) for row in rows)

        def row_settings(row: RunRow) -> dict[str, Any]:
            """A free-response row beside forced ones keeps the force inputs, held (only its own stamp changes)."""
            return {**settings, "keep_inputs": True} if forced and is_free_response(row.input) else settings

        show = progress or _progress_printer(quiet)
        checked = _rows_to_check(rows, source_spec, source_options, t_end) if check_linearity else set()
        started = time.perf_counter()
        outputs = {path: path for row in rows for path in (out_dir / f"{row.name}.h5", out_dir / f"{row.name}"
                                                           f"{INCOMPLETE_SUFFIX}")}
        shared = dt is None and len(rows) > 1   # rows at their own automatic steps would not fit together (audit 72)

        def windows(map_rows: Callable[[list[RunRow], Callable, Callable], list]) -> dict[int, dict[str, Any]]:
            if not shared:
                return {row.number: row_settings(row) for row in rows}
            found = {row.number: _recorded_window(source_spec, row, row_settings(row), source_options, out_dir)
                     for row in rows}
            missing = [row for row in rows if found[row.number] is None]   # rows done already: no pilots again
            if missing:
                found.update(zip([row.number for row in missing], map_rows(
                    missing, row_window, lambda row: (source_spec, row, row_settings(row), source_options, isolate))))
            return _at_one_step(rows, [row_settings(row) for row in rows], [found[row.number] for row in rows], quiet)

        with _written_named_on_interrupt(outputs):
            if scheduler is None:
                chosen = windows(lambda some, function, arguments: [function(*arguments(row)) for row in some])
                outcomes = []
                for i, row in enumerate(rows):
                    outcomes.append(record_row(source_spec, row, out_dir, chosen[row.number], source_options, isolate,
                                               row.number in checked))
                    show(outcomes[-1], i + 1, len(rows))
            else:
                with dask_client(scheduler, isolate=isolate and _is_fmu(source_spec)) as client:
                    chosen = windows(lambda some, function, arguments: _gather_rows(client, function, some, arguments))
                    outcomes = _map_rows(client, record_row, rows, show,
                                         lambda row: (source_spec, row, str(out_dir), chosen[row.number],
                                                      source_options, isolate, row.number in checked))
        return RunTableReport(outcomes, time.perf_counter() - started)
    except BaseException:   # failed or interrupted: a folder this call made and left empty goes again
        _remove_empty_folders(made)
        raise


#: Horizon over which a row's input is sampled to size it where neither the row's table nor ``t_end`` ends it (as
#: :func:`fmu_opinf.snapshots._window.input_activity` samples an input), and the samples taken.
SIZING_HORIZON, SIZING_SAMPLES = 1000.0, 200_001


def _rows_to_check(rows: Sequence[RunRow], source_spec: Any, source_options: dict[str, Any],
                   t_end: float | None) -> set[int]:
    """The numbers of the rows whose response is checked for scaling with the input: among the rows of the same
    ``set:`` and ``start:`` values (one model, one operating point), those that drive some input furthest from its
    start value (:func:`fmu_opinf.snapshots._linearity.largest_runs`; each input sampled over its table, else to
    ``t_end``, else :data:`SIZING_HORIZON`).  A model that scales at the largest input does at the smaller ones of
    its group, so a table of many rows costs one extra run per input and group, not one per row.  A group whose
    source or inputs cannot be read here is checked on every row (its rows then fail with their own message)."""
    groups: dict[str, list[RunRow]] = {}
    for row in rows:
        groups.setdefault(json.dumps([row.set, row.start], sort_keys=True), []).append(row)
    checked: set[int] = set()
    for group in groups.values():
        try:
            departures = _row_departures(group, source_spec, source_options, t_end)
        except FmuOpinfError:
            checked.update(row.number for row in group)
            continue
        from .snapshots._linearity import largest_runs

        checked.update(group[i].number for i in largest_runs(departures))
    return checked


def _row_departures(group: Sequence[RunRow], source_spec: Any, source_options: dict[str, Any],
                    t_end: float | None) -> list[Any]:
    """Each row's largest departure from the inputs' start values, per input (the source opened once, with the
    group's start values)."""
    import numpy as np

    from .snapshots._linearity import input_departures
    from .snapshots._inputs import as_signal
    from .source import open_source

    source = open_source(source_spec, **row_source_options(group[0], source_options))
    try:
        found = []
        for row in group:
            signal = as_signal(row.input, source.m, source)
            own = float(getattr(signal, "t_range", (0.0, math.inf))[1])
            end = own if math.isfinite(own) else (t_end or SIZING_HORIZON)
            found.append(input_departures(source, signal, np.linspace(0.0, end, SIZING_SAMPLES)))
        return found
    finally:
        getattr(source, "close", lambda: None)()


def row_window(source_spec: Any, row: RunRow, settings: dict[str, Any], source_options: dict[str, Any],
               isolate: bool = True) -> tuple[float, float, dict[str, Any] | None] | None:
    """The step, end and automatic window (``as_dict``) the row would be recorded with on its own, from its pilot
    runs (:func:`fmu_opinf.snapshots.recording_window`); None where they fail (the row's recording then fails
    with its own message, and the other rows go on).

    Parameters
    ----------
    source_spec : str or path-like
        ``builtin:NAME`` or an FMU path.
    row : RunRow
    settings : dict
        Keywords of :func:`fmu_opinf.snapshots.record_to_file` common to all rows.
    source_options : dict
        Source keywords common to all rows.
    isolate : bool, default=True

    Returns
    -------
    tuple or None
        ``(dt, t_end, window)``; ``window`` None where no pilots chose the grid.
    """
    from .snapshots._plan import recording_window

    try:
        dt, t_end, window = recording_window(source_spec, row.input, isolate=isolate, **settings,
                                             **row_source_options(row, source_options))
    except FmuOpinfError:
        return None
    return dt, t_end, None if window is None else window.as_dict()


def _recorded_window(source_spec: Any, row: RunRow, settings: dict[str, Any], source_options: dict[str, Any],
                     out_dir: Path) -> tuple[float, float, dict[str, Any]] | None:
    """The step, end and window of the row's complete file where it was recorded at a table's one step with these
    settings (:func:`_at_one_step`), else None: a rerun then needs no pilots for that row."""
    path = out_dir / f"{row.name}.h5"
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r") as f:
            window = json.loads(f.attrs.get(ROW_ATTR, "{}")).get("settings", {}).get("window")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(window, dict) or not _is_done(path, _stamp(source_spec, row, {**settings, "window": window},
                                                                 source_options))[0]:
        return None
    return float(window["dt"]), float(window["t_end"]), window


def _gather_rows(client: Any, function: Callable, rows: Sequence[RunRow],
                 arguments: Callable[[RunRow], tuple]) -> list[Any]:
    """``function(*arguments(row))`` for every row as Dask tasks, in table order; a row whose task failed: None.
    The tasks' warnings are said here (once each)."""
    futures = [client.submit(_warnings_returned, function, *arguments(row), pure=False,
                             key=f"{function.__name__}-{row.name}-{time.time_ns()}") for row in rows]
    found = []
    for future in futures:
        try:
            result, said = future.result()
            _warn_here(said)
        except Exception:  # a lost worker: the row's recording says what went wrong
            result = None
        found.append(result)
    return found


def _at_one_step(rows: Sequence[RunRow], settings: Sequence[dict[str, Any]], found: Sequence[Any],
                 quiet: bool) -> dict[int, dict[str, Any]]:
    """Each row's recording settings with the table's one step: the finest of the rows' own steps (``found``, from
    :func:`row_window`); each row keeps its own end and its window's description, with the step replaced.

    Runs of one table are fitted together, and the fit's output-error refinement, order search and training
    check simulate every run at one step: rows at their own automatic steps (an impulse at 0.02, a harmonic at
    0.1) turned them off, and the ROM was 15-51 % of range off its own training inputs (audit 72, F2).  The
    finest step resolves every row's fastest significant frequency; the end stays each row's own (where its
    response faded, or its input table ends), since runs of different lengths fit together and a later end would
    only cost samples.  The pilots run once: the row is recorded with its window (``record_to_file(window=)``).
    """
    steps = [item[0] for item in found if item is not None]
    step = min(steps) if steps else None
    chosen: dict[int, dict[str, Any]] = {}
    for row, own, item in zip(rows, settings, found):
        if item is None or step is None:
            chosen[row.number] = own
            continue
        dt, t_end, window = item
        if window is not None:
            chosen[row.number] = {**own, "window": {**window, "dt": step, "t_end": t_end}}
        else:
            chosen[row.number] = {**own, "dt": step, "t_end": t_end} if dt != step else own
    if not quiet and step is not None and len(set(steps)) > 1:
        listed = ", ".join(f"{row.name} {item[0]:g}" for row, item in zip(rows, found) if item is not None)
        print(f"run table: every row recorded at dt={step:g}, the finest of the rows' own steps ({listed}), so that "
              f"they fit together; each row to its own end", file=sys.stderr)
    return chosen


def _as_float(value: Any) -> Any:
    """A recording setting as the command line gives it: an integer (``t_end=150`` from Python) as a float.

    The row stamps compare settings as JSON text: ``150`` and ``150.0`` (the command line's) differed, and a
    table recorded from Python was recorded again, row by row, by the same command line (audit 68).

    Parameters
    ----------
    value : Any
        ``dt`` or ``t_end`` as given, or None.

    Returns
    -------
    Any
        ``float(value)`` for an integer (not a bool), else ``value`` unchanged (checked where it is used).
    """
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        return float(value)
    return value


def _is_fmu(source_spec: Any) -> bool:
    """Whether runs of the source are isolated in a child process when asked (FMUs; not ``builtin:`` ones)."""
    return not os.fspath(source_spec).startswith("builtin:")


def _identity(path: Path) -> tuple[int, ...] | None:
    try:
        info = path.stat()
    except OSError:
        return None
    return info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, info.st_ctime_ns


@contextlib.contextmanager
def _written_named_on_interrupt(outputs: dict[Path, Path]) -> Iterator[None]:
    """On Ctrl-C, add to :data:`fmu_opinf._hdf5.REPLACED` each output (key) whose file (value) was written or
    replaced since the block began, for the command's last line: workers write rows that this process never hears
    of once it is interrupted (audit 68: "no output file was written or replaced" after two rows were).  The block
    must hold the cluster's closing, so that no worker writes after the check."""
    before = {shown: _identity(probe) for shown, probe in outputs.items()}
    try:
        yield
    except KeyboardInterrupt:
        from ._hdf5 import REPLACED

        for shown, probe in outputs.items():
            now = _identity(probe)
            if now is not None and now != before[shown] and shown not in REPLACED:
                REPLACED.append(shown)
        raise


def _shared_spec(source_spec: Any) -> str:
    text = os.fspath(source_spec)
    return text if text.startswith("builtin:") else str(Path(text).resolve())


def _output_directory(output: str | os.PathLike) -> tuple[Path, list[Path]]:
    """The run table's output folder, made where missing, and the folders this call made (deepest first), which
    :func:`_remove_empty_folders` takes back if the table fails or is interrupted before writing into them."""
    out_dir = Path(output).resolve()
    if out_dir.suffix.lower() in (".h5", ".hdf5") or (out_dir.exists() and not out_dir.is_dir()):
        raise InputSpecError(f"-o {output}: a run table writes one file per run into a directory; give a "
                             "directory (fit reads it as one data set)")
    made = [folder for folder in (out_dir, *out_dir.parents) if not folder.exists()]
    out_dir.mkdir(parents=True, exist_ok=True)
    return out_dir, made


def _remove_empty_folders(made: list[Path]) -> None:
    """Remove the folders of ``made`` (deepest first) that are still empty: a table stopped before its first row
    leaves no trace but what it says it wrote (audit 76, F6: an empty folder stayed after "no output file was
    written")."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:   # not empty (a row was written, or someone else's file): kept, and so are its parents
            return


def _map_rows(client: Any, function: Callable, rows: Sequence[RunRow], show: Callable,
              arguments: Callable[[RunRow], tuple]) -> list[RunOutcome]:
    """One task per row; outcomes in table order, each shown as it arrives; a lost task fails only its row."""
    from distributed import as_completed

    futures = {client.submit(_warnings_returned, function, *arguments(row), pure=False,
                             key=f"{function.__name__}-{row.name}-{time.time_ns()}"): row for row in rows}
    outcomes: dict[int, RunOutcome] = {}
    for done, future in enumerate(as_completed(futures), start=1):
        row = futures[future]
        try:
            outcome, said = future.result()
            _warn_here(said)
        except Exception as exc:  # a crashed worker or an unexpected error: report it with its row
            outcome = RunOutcome(row.number, row.name, "failed", error=f"{type(exc).__name__}: {exc}")
        _note_retries(client, future, outcome)
        outcomes[row.number] = outcome
        show(outcome, done, len(rows))
    return [outcomes[row.number] for row in rows]


def _lost_worker_count(key: str, dask_scheduler: Any = None) -> int:
    """On the scheduler: how often the task's worker was lost while it ran the task (Dask then runs it again)."""
    task = dask_scheduler.tasks.get(key)
    return int(getattr(task, "suspicious", 0)) if task is not None else 0


def _note_retries(client: Any, future: Any, outcome: Any) -> None:
    """Put in the row's outcome how often Dask ran it again after a lost worker (one round trip to the scheduler;
    nothing if the scheduler does not answer)."""
    target = outcome[0] if isinstance(outcome, tuple) else outcome
    with contextlib.suppress(Exception):  # a note only: a scheduler that refuses to run it leaves it out
        target.retries = int(client.run_on_scheduler(_lost_worker_count, future.key))


def _warnings_returned(function: Callable, *arguments: Any) -> tuple[Any, list[tuple[bool, str]]]:
    """``function(*arguments)`` on a worker, with the warnings it gave returned instead of printed in the worker's
    log (``(is an FmuOpinfWarning, message)``), so that the caller says them the way it says its own."""
    from .errors import FmuOpinfWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = function(*arguments)
    return result, [(issubclass(w.category, FmuOpinfWarning), str(w.message)) for w in caught]


def _warn_here(said: list[tuple[bool, str]]) -> None:
    """Say again in this process what a worker's task warned (the same text of many rows: once)."""
    from .errors import FmuOpinfWarning

    for ours, message in said:
        if message not in _RELAYED:
            _RELAYED.add(message)
            warnings.warn(message, FmuOpinfWarning if ours else UserWarning, stacklevel=3)


#: Worker warnings said already in this process.
_RELAYED: set[str] = set()


# ---------------------------------------------------------------------------------------------
# Validation on many inputs
# ---------------------------------------------------------------------------------------------
def compare_row(rom: str, source_spec: str, row: RunRow, out_dir: str, dt: float | None, t_end: float | None,
                source_options: dict[str, Any] | None = None) -> tuple[RunOutcome, dict[str, Any] | None]:
    """Compare the ROM with its source on one row's input; write the row's report to ``out_dir/NAME/``."""
    from .compare import compare
    from .report import write_report

    started = time.perf_counter()
    try:
        result = compare(rom, source_spec, row.input, dt=dt, t_end=t_end, quiet=True,
                         source_options=row_source_options(row, source_options))
        _check_finite(result)
        page = write_report(result, Path(out_dir) / row.name)
    except FmuOpinfError as exc:
        return RunOutcome(row.number, row.name, "failed", seconds=time.perf_counter() - started,
                          error=str(exc), worker=_worker_name()), None
    return (RunOutcome(row.number, row.name, "compared", str(page), len(result.t), time.perf_counter() - started,
                       worker=_worker_name()), result.metrics())


def _check_finite(result: Any) -> None:
    """A comparison whose source (or ROM) left the finite numbers has no meaningful error: a failed row."""
    import numpy as np

    for label, y in (("the source", result.y_fom), ("the ROM", result.y_rom)):
        bad = ~np.isfinite(np.asarray(y)).all(axis=0)
        if bad.any():
            i = int(np.argmax(bad))
            raise FmuOpinfError(f"{label} produced non-finite outputs at step {i} (t={result.t[i]:g}); check the "
                                "input's size and the model on this input")


def compare_runs(
    rom: str | os.PathLike,
    source_spec: str | os.PathLike,
    runs: str | os.PathLike | Sequence[RunRow],
    output: str | os.PathLike,
    *,
    scheduler: Any = None,
    dt: float | None = None,
    t_end: float | None = None,
    quiet: bool = False,
    **source_options: Any,
) -> tuple[RunTableReport, str]:
    """Validate a ROM on every row of a run table (in parallel with a scheduler); one summary for all.

    Each row's report goes to ``output/NAME/``; ``output/index.html`` and ``output/summary.txt`` hold the
    summary table (:func:`fmu_opinf.report.summary_table`) with links to the rows' reports.  A row's
    ``;``-separated specs list the source's inputs in its order, as ``snapshots --runs`` reads them, and go to the
    ROM's inputs by name (:func:`in_rom_order`).

    Returns
    -------
    (RunTableReport, str)
        The outcomes and the plain-text summary table.
    """
    from .compare._sides import _load_rom_side, _rom_side_info
    from .report import summary_table

    rows = list(runs) if not isinstance(runs, (str, os.PathLike)) else read_run_table(runs)
    source_options = {k: v for k, v in source_options.items() if v is not None}
    validate_rows(rows, source_spec, source_options)
    table_inputs = source_input_names(source_spec, source_options)
    rom_inputs = _rom_side_info(_load_rom_side(rom))["input_names"]
    rows = [in_rom_order(row, table_inputs, rom_inputs) for row in rows]
    out_dir, made = _output_directory(output)
    try:
        rom, source_spec = str(Path(rom).resolve()), _shared_spec(source_spec)
        metrics: dict[int, dict[str, Any]] = {}

        def task(row: RunRow) -> tuple:
            return rom, source_spec, row, str(out_dir), dt, t_end, source_options

        def unpack(pair: Any) -> RunOutcome:
            outcome, values = pair
            if values is not None:
                metrics[outcome.number] = values
            return outcome

        show = _progress_printer(quiet)
        started = time.perf_counter()
        if scheduler is None:
            outcomes = []
            for i, row in enumerate(rows):
                outcomes.append(unpack(compare_row(*task(row))))
                show(outcomes[-1], i + 1, len(rows))
        else:
            isolate = bool(source_options.get("isolate", True)) and _is_fmu(source_spec)
            reports = {out_dir / row.name: out_dir / row.name / "index.html" for row in rows}
            with _written_named_on_interrupt(reports), dask_client(scheduler, isolate=isolate) as client:
                pairs = _map_rows(client, compare_row, rows, lambda *a: None, task)
            outcomes = []
            for i, pair in enumerate(pairs):
                outcomes.append(unpack(pair) if isinstance(pair, tuple) else pair)
                show(outcomes[-1], i + 1, len(rows))
        table = summary_table([(row.name, metrics[row.number]) for row in rows if row.number in metrics])
        _write_summary(out_dir, rows, outcomes, table)
        return RunTableReport(outcomes, time.perf_counter() - started), table
    except BaseException:   # failed or interrupted: a folder this call made and left empty goes again
        _remove_empty_folders(made)
        raise


def _write_summary(out_dir: Path, rows: Sequence[RunRow], outcomes: Sequence[RunOutcome], table: str) -> None:
    import html

    from ._hdf5 import replace_together

    items = []
    for row, outcome in zip(rows, outcomes):
        target = f'<a href="{html.escape(row.name)}/index.html">{html.escape(row.name)}</a>' \
            if outcome.status == "compared" else html.escape(row.name)
        note = "" if outcome.status == "compared" else f" &mdash; failed: {html.escape(outcome.error)}"
        items.append(f"<li>{target}: input <code>{html.escape(row.input)}</code>{note}</li>")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>fmu-opinf run table comparison</title>"
            "</head><body><h1>ROM vs source on a run table</h1><pre>" + html.escape(table) + "</pre><ul>"
            + "".join(items) + "</ul></body></html>\n")
    replace_together(out_dir, {"summary.txt": (table + "\n").encode(), "index.html": page.encode()})
