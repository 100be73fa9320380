"""Validation of untrusted input: command-line values, HDF5 structure, attribute types, array sizes.

Snapshot and ROM files are data from anywhere (docs/security.md).  Everything read from them is checked
here before it is used: no links into other files, attributes of the expected type, datasets of real
numbers whose declared size is backed by data actually stored in the file and fits into memory.  Each
check raises a one-line :class:`~fmu_opinf.errors.FileFormatError` (structure, types) or
:class:`~fmu_opinf.errors.DataError` (values, sizes) naming the problem and the fix.
"""

from __future__ import annotations

import contextlib
import difflib
import errno
import json
import math
import os
import re
import tempfile
from pathlib import Path
from collections.abc import Sequence
from typing import Any, Iterator

import h5py
import numpy as np

from .errors import DataError, FileFormatError, FmuOpinfError, InputSpecError, InputTypeError

__all__ = [
    "available_memory", "check_memory", "check_name_length", "check_not_dangling", "check_grid", "check_positive",
    "check_fraction", "check_number", "check_at_least", "check_choice", "check_keywords", "shown", "either",
    "API_KEYWORDS", "KEYWORD_OF", "ME", "DT_T_END", "POSITIONS_VELOCITIES", "setting_said", "options_said",
    "patterns_said", "values_said",
    "check_patterns", "check_writable", "check_report_directory", "check_not_input", "reject_links",
    "check_array", "read_real", "check_attr_types", "check_rom_file", "damaged_file_errors", "check_snapshot_run",
    "read_failure", "RESTORE",
    "SNAPSHOT_FILE_ATTRS", "SNAPSHOT_RUN_ATTRS", "ROM_ATTRS",
]

# -- memory ----------------------------------------------------------------------------------------------


def available_memory() -> int:
    """Bytes of memory available to this process (``MemAvailable``; physical memory as fallback)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 2**40


def _gib(nbytes: float) -> str:
    return f"{nbytes / 2**30:.3g} GiB"


def check_memory(nbytes: float, what: str, fix: str) -> None:
    """Raise :class:`DataError` if ``nbytes`` exceed the memory available now.

    Parameters
    ----------
    nbytes : float
        Bytes about to be allocated.
    what : str
        What needs them (start of the message).
    fix : str
        How the user avoids the allocation (end of the message).
    """
    free = available_memory()
    if nbytes > free:
        raise DataError(f"{what} needs {_gib(nbytes)} of memory but only {_gib(free)} are available; {fix}")


# -- command-line values ---------------------------------------------------------------------------------


def shown(option: str, value: Any) -> str:
    """``--dt 0.1`` for a command-line option (``option`` starts with ``-``), ``dt=0.1`` for a Python keyword: the
    checks below serve both (audit 81c F7: the functions raised built-in errors where the CLI said one line)."""
    return f"{option} {value}" if option.startswith("-") else f"{option}={value!r}"


#: The Python keyword of each command-line option a message names as a fix (README, "Python": the table of names).
#: A keyword holding ``=`` is the keyword's value that a flag stands for (``--no-refine`` is ``refine=False``).
KEYWORD_OF = {
    "--input": "signal", "--dt": "dt", "--t-end": "t_end", "--start-time": "start_time", "--set": "parameters",
    "--positions": "positions", "--velocities": "velocities", "--accelerations": "accelerations",
    "--inputs": "inputs", "--outputs": "outputs", "--constraint": "constraint", "--interface": "interface",
    "--tolerance": "tolerance", "--me-method": "method", "--auto-window": "auto_window=True",
    "--no-linearity-check": "check_linearity=False", "--in-process": "isolate=False", "--force": "overwrite=True",
    "--r": "r", "--energy": "energy", "--no-refine": "refine=False", "--terms": "terms",
    "--refit-output-map": "refit_output_map=True", "--g": "g", "--n1": "n1", "--alpha": "alpha", "--beta": "beta",
    "--v": "v", "--basis": "basis", "--integrator": "integrator", "--lowpass": "lowpass", "--timeout": "timeout",
    "--step": "step",
}

_NO_VALUE = object()
_BARE = re.compile(r"[A-Za-z0-9_.:+,-]+")   # (what a shell passes as one word: no brackets, quotes, ';', '=')


def either(option: str, keyword: str | None = None, value: Any = _NO_VALUE) -> str:
    """A fix said for both callers, the option first: ``--input none or signal='none'``, ``--dt 0.02 or dt=0.02``,
    ``--dt or dt=`` (no value), ``--no-refine or refine=False`` (a flag).  Messages raised below the command line
    and the functions alike named only the option to a Python caller (audit 81c F8, F12); ``keyword`` defaults to
    the option's in :data:`KEYWORD_OF`.  A string value the shell would split is quoted on the option's side."""
    keyword = KEYWORD_OF[option] if keyword is None else keyword
    if value is _NO_VALUE or "=" in keyword:
        return f"{option} or {keyword}" if "=" in keyword else f"{option} or {keyword}="
    return f"{option} {_on_command_line(value)} or {shown(keyword, value)}"


def _on_command_line(value: Any) -> Any:
    """``value`` as the command line takes it: a float as ``%g``, a string the shell would split double-quoted."""
    return (f"{value:g}" if isinstance(value, float) else value if not isinstance(value, str) or _BARE.fullmatch(value)
            else f'"{value}"')


def values_said(*pairs: tuple[str, Any]) -> str:
    """Several options with their values, in both vocabularies, the options first: ``--input "impulse:t0=2" --t-end
    60 or signal='impulse:t0=2', t_end=60.0`` (one command, one call; :func:`either` said twice reads as two)."""
    options = " ".join(f"{option} {_on_command_line(value)}" for option, value in pairs)
    return options + " or " + ", ".join(shown(KEYWORD_OF[option], value) for option, value in pairs)


def options_said(*options: str) -> str:
    """Several options a fix names, in both vocabularies: ``--dt and --t-end or dt= and t_end=``."""
    keywords = [KEYWORD_OF[option] for option in options]
    return (" and ".join(options) + " or "
            + " and ".join(word if "=" in word else f"{word}=" for word in keywords))


def patterns_said(**patterns: str) -> str:
    """Variable patterns a fix names, in both vocabularies: ``--positions "x[1]" --velocities "v[1]" or
    positions='x[1]', velocities='v[1]'`` (keywords of :func:`~fmu_opinf.snapshots.record` and ``record_to_file``)."""
    options = " ".join(f'--{key} "{value}"' for key, value in patterns.items())
    return options + " or " + ", ".join(f"{key}={value!r}" for key, value in patterns.items())


#: The fix "drive its model exchange" in both vocabularies.
ME = either("--interface", value="me")
#: The step and end a fix names, in both vocabularies.
DT_T_END = options_said("--dt", "--t-end")
#: The variable patterns a fix names, in both vocabularies.
POSITIONS_VELOCITIES = options_said("--positions", "--velocities")


def setting_said(name: str, value: Any = _NO_VALUE) -> str:
    """A start value as both callers give it: ``--set k=1000 or parameters['k']=1000`` (``--set k or
    parameters['k']`` without a value): the command line's ``--set`` is the keyword ``parameters`` in Python."""
    if value is _NO_VALUE:
        return f"--set {name} or parameters[{name!r}]"
    return f"--set {name}={value} or parameters[{name!r}]={value!r}"


def check_number(value: Any, option: str) -> None:
    """A real number (None: not given): a string or another object given to a Python keyword is refused in one line
    (an :class:`~fmu_opinf.errors.InputTypeError`, also a ``TypeError`` as Python's own was)."""
    if value is None or (not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))):
        return
    try:
        example = f", e.g. {shown(option, float(value))}"
    except (TypeError, ValueError):
        example = ""
    raise InputTypeError(f"{shown(option, value)} is a {type(value).__name__}, not a number; give a number{example}")


def check_positive(value: float | None, option: str) -> None:
    """A finite number > 0 (None: not given)."""
    check_number(value, option)
    if value is not None and not (math.isfinite(value) and value > 0):
        raise InputSpecError(f"{shown(option, value)} must be a positive finite number")


def check_fraction(value: float | None, option: str) -> None:
    """A number strictly between 0 and 1 (None: not given)."""
    check_number(value, option)
    example = f"{option} 0.9999" if option.startswith("-") else f"{option}=0.9999"
    if value is not None and not (0.0 < value < 1.0):
        raise InputSpecError(f"{shown(option, value)} must lie strictly between 0 and 1, e.g. {example}")


def check_at_least(value: int | None, option: str, least: int) -> None:
    """A number of at least ``least`` (None: not given)."""
    check_number(value, option)
    if value is not None and value < least:
        raise InputSpecError(f"{shown(option, value)} must be at least {least}")


def check_choice(value: Any, option: str, choices: Sequence[str]) -> None:
    """One of ``choices`` (None: not given), refused in one line naming them and the closest one."""
    if value is None or value in choices:
        return
    close = difflib.get_close_matches(str(value), list(choices), n=1)
    hint = f" (did you mean {shown(option, close[0])}?)" if close else ""
    raise InputSpecError(f"{shown(option, value)} is not known; use one of {', '.join(map(repr, choices))}{hint}")


#: Command-line options whose Python keyword is another word (a user who knows the CLI types them).
API_KEYWORDS = {"set": "parameters", "me_method": "method", "me-method": "method"}


def check_keywords(given: Any, valid: Sequence[str], where: str, noun: str = "key") -> None:
    """Refuse a key of ``given`` that ``where`` does not take, in one line naming it, the closest valid key
    (``difflib``) or the Python keyword of a command-line word (``set`` is ``parameters``), and the valid keys.

    A key that is dropped without a word compares or records another model than the one asked for (audit 81c F2:
    ``source_options={"parameter": ...}`` ran the FMU at its training values and said the ROM fits)."""
    unknown = [key for key in given if key not in valid]
    if not unknown:
        return
    key = unknown[0]
    if API_KEYWORDS.get(str(key)) in valid:
        hint = f"the command line's --{key} is {API_KEYWORDS[str(key)]!r} in Python"
    else:
        close = difflib.get_close_matches(str(key), list(valid), n=1)
        hint = f"did you mean {close[0]!r}?" if close else "it is not one of them"
    raise InputSpecError(f"{where} takes no {noun} {key!r}; {hint} (valid: {', '.join(valid)})")


def check_patterns(value: str | None, option: str) -> None:
    """Name patterns must not be empty (None: not given)."""
    if value is not None and not value.strip(" ,"):
        raise InputSpecError(f"{option} is empty; give name patterns such as 'x[*]' or leave the option out")


def check_grid(dt: float, t_end: float, t0: float = 0.0, channels: int = 1) -> int:
    """Number of samples of the grid ``t0, t0 + dt, ..., t_end``, refused if absurd.

    The time grid and ``channels`` input rows of float64 must fit into the available memory.

    Returns
    -------
    int
        The number of samples ``k``.
    """
    check_positive(dt, "--dt")
    if not (math.isfinite(t_end) and t_end > t0):
        raise InputSpecError(f"end time {t_end} must be finite and after the start time {t0}")
    samples = (t_end - t0) / dt + 1
    if not math.isfinite(samples):
        samples = math.inf
    nbytes = 8.0 * samples * (1 + max(channels, 1))
    check_memory(nbytes, f"a grid of {samples:.3g} samples (dt={dt:g}, t_end={t_end:g})",
                 f"increase {either('--dt')} or decrease {either('--t-end')}")
    return int(samples)


# -- output paths ----------------------------------------------------------------------------------------


def _existing_ancestor(path: Path) -> Path:
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_name_length(path: str | os.PathLike, option: str) -> None:
    """A one-line error for a path the file system refuses as too long (it ended in a traceback, audit 55)."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise FileFormatError(f"{option} names a path too long for the file system ({_too_long(path)}); choose "
                                  "a shorter one") from None


def _too_long(path: str | os.PathLike) -> str:
    """What makes ``path`` too long: its longest name (a file system takes 255 bytes in one, mostly), else its
    length.  (The command line makes paths absolute; the length of the path as given is not the one refused.)"""
    longest = max(Path(path).parts, key=lambda part: len(os.fsencode(part)), default="")
    size = len(os.fsencode(longest))
    return f"{size} bytes in one name" if size > 255 else f"{len(os.fsencode(os.fspath(path)))} bytes"


def check_not_dangling(path: str | os.PathLike, option: str) -> None:
    """Refuse a symbolic link to nothing as an output (audit 57: ``--figures`` ended after the fit with "File
    exists", ``build-fmus`` created the folders the link named)."""
    if os.path.islink(path) and not os.path.exists(path):
        raise FileFormatError(f"{option} {path} is a symbolic link to nothing ({os.readlink(path)}); give an "
                              "existing path or a new name")


def check_writable(path: str | os.PathLike, what: str, directory: bool = False, option: str = "-o") -> None:
    """Fail now, not after the work, if ``path`` (a file, or with ``directory`` a folder) cannot be written.

    A file's folder must exist; a folder may be created later, so its nearest existing ancestor is probed.
    The probe creates and removes one temporary file (``os.access`` is meaningless for root).
    """
    path = Path(path)
    if directory and path.exists() and not path.is_dir():
        raise FileFormatError(f"{what} {path} is an existing file; choose another {option} path")
    if directory:
        folder = path if path.is_dir() else _existing_ancestor(path)
    else:
        folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileFormatError(f"cannot write {what} {path}: directory {folder} does not exist; create it first")
    try:
        fd, probe = tempfile.mkstemp(prefix=".fmu-opinf-probe-", dir=folder)
    except OSError as exc:
        raise FileFormatError(f"cannot write {what} {path}: {exc.strerror} in {folder}; "
                              f"choose a writable location with {option}") from None
    os.close(fd)
    os.unlink(probe)


def check_report_directory(path: str | os.PathLike, option: str = "-o") -> None:
    """A report goes into a new or empty folder, or replaces an earlier report (one with ``metrics.json``);
    a folder holding other files is refused rather than silently mixed with the report.  ``option``: how the
    folder was given (``-o``, or the Python keyword ``out_dir``, whose fix also names ``overwrite=True``)."""
    from ._hdf5 import check_folder_entries

    path = Path(path)
    if path.is_dir() and any(path.iterdir()) and not (path / "metrics.json").is_file():
        fix = f"choose a new {option} path" if option.startswith("-") else \
            f"give {option}= a new path, or overwrite=True to write the report among them"
        raise FileFormatError(f"report directory {path} exists and holds other files; {fix} "
                              "(an earlier report in it would be replaced)")
    check_folder_entries(path)


def check_not_input(output: str | os.PathLike, inputs: list[Any], what: str, option: str = "-o") -> None:
    """Refuse an output path that is one of the inputs (``--force`` would destroy the input).  ``option``: how the
    output was given (``-o``, or a Python keyword such as ``output``: the functions check too, audit 81c F3:
    ``fit_rom_file("x.h5", "x.h5", overwrite=True)`` replaced its training data)."""
    out = Path(output)
    for item in inputs:
        if item is None or str(item).startswith("builtin:"):
            continue
        source = Path(str(item))
        if not source.exists():  # an input specification, not a file
            continue
        same = (out.exists() and source.exists() and os.path.samefile(out, source)) or \
            out.absolute() == source.absolute()
        if same:
            fix = f"of this command; choose another {option} path" if option.startswith("-") else \
                f"of this call; give {option}= another path"
            raise FileFormatError(f"{what} {out} is also an input {fix}")


# -- HDF5 structure --------------------------------------------------------------------------------------


def _where(obj: h5py.HLObject) -> str:
    return f"{obj.file.filename}:{obj.name}"


def reject_links(group: h5py.Group) -> None:
    """Refuse soft and external links, external storage and virtual datasets anywhere below ``group``.

    fmu-opinf never writes them; following them would read other files than the one the user named.
    """
    for key in list(group.keys()):
        link = group.get(key, getlink=True)
        if not isinstance(link, h5py.HardLink):
            raise FileFormatError(f"{group.file.filename}: {group.name.rstrip('/')}/{key} is a "
                                  f"{type(link).__name__}; fmu-opinf files contain no links, the file was altered")
        obj = group[key]
        if isinstance(obj, h5py.Group):
            reject_links(obj)
        elif isinstance(obj, h5py.Dataset) and (obj.is_virtual or obj.external):
            raise FileFormatError(f"{_where(obj)} refers to data in other files; fmu-opinf files are "
                                  "self-contained, the file was altered")


def _data_present(ds: h5py.Dataset) -> bool:
    """True if every element of ``ds`` is backed by stored data (not HDF5 fill values)."""
    if ds.size == 0:
        return True
    layout = ds.id.get_create_plist().get_layout()
    if layout == h5py.h5d.CHUNKED:
        needed = math.prod(-(-s // c) for s, c in zip(ds.shape, ds.chunks))
        return ds.id.get_num_chunks() >= needed
    if layout == h5py.h5d.COMPACT:
        return True
    return ds.id.get_storage_size() >= ds.size * ds.dtype.itemsize


def check_array(ds: Any, label: str, ndim: int | None = None, rows: int | None = None,
                cols: int | None = None) -> h5py.Dataset:
    """``ds`` is a dataset of real numbers of the expected shape whose data are stored in the file.

    Parameters
    ----------
    ds : object
        What the file holds under the name.
    label : str
        Where it is (for the message).
    ndim, rows, cols : int, optional
        Expected number of dimensions, first and last dimension.

    Returns
    -------
    h5py.Dataset
    """
    if not isinstance(ds, h5py.Dataset):
        raise FileFormatError(f"{label} is a {type(ds).__name__}, expected a dataset of numbers; the file is damaged")
    if ds.dtype.kind not in "fiu":
        raise FileFormatError(f"{label} has type {ds.dtype}, expected real numbers (float64); the file is damaged")
    if ndim is not None and ds.ndim != ndim:
        raise FileFormatError(f"{label} has {ds.ndim} dimensions {ds.shape}, expected {ndim}; the file is damaged")
    if rows is not None and ds.shape[0] != rows:
        raise FileFormatError(f"{label} has {ds.shape[0]} rows, expected {rows}; the file is damaged")
    if cols is not None and ds.shape[-1] != cols:
        raise FileFormatError(f"{label} has {ds.shape[-1]} columns, expected {cols}; the file is damaged")
    if not _data_present(ds):
        raise FileFormatError(f"{label} declares shape {ds.shape} but the file holds data for only part of it; "
                              "the file is truncated or damaged")
    return ds


#: The way out of a damaged file.
RESTORE = "restore it from a copy or write it again"


def read_failure(exc: BaseException) -> str:
    """HDF5's reason for a failed read, shortened, in words where it is a failed filter.

    A chunk whose Fletcher-32 checksum (written since audit 62) or gzip stream does not match its bytes makes
    HDF5 say only "filter returned failure during read": the bytes changed after the file was written.
    """
    text = " ".join(str(exc).split())[:200]
    if "filter returned failure" in text:
        return "its stored bytes fail HDF5's checksum or decompression: they changed after the file was written"
    return text


def read_real(ds: Any, label: str, ndim: int | None = None) -> np.ndarray:
    """Read a checked dataset into a finite float64 array (memory checked before reading)."""
    check_array(ds, label, ndim)
    check_memory(8.0 * ds.size, f"reading {label}", "the file declares more data than this machine holds")
    try:
        values = np.array(ds[()], dtype=float)
    except (OSError, ValueError, TypeError) as exc:
        raise FileFormatError(f"cannot read {label} ({read_failure(exc)}); the file is damaged, {RESTORE}") from None
    if not np.all(np.isfinite(values)):
        raise DataError(f"{label} contains NaN/Inf; the file is unusable, re-create it")
    return values


# -- attribute types -------------------------------------------------------------------------------------


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_float(v: Any) -> bool:
    return (_is_int(v) or isinstance(v, (float, np.floating))) and math.isfinite(float(v))


_KINDS = {
    "int": (lambda v: _is_int(v) and v >= 0, "a non-negative integer"),
    "float": (_is_float, "a finite number"),
    "positive": (lambda v: _is_float(v) and v > 0, "a positive finite number"),
    "str": (lambda v: isinstance(v, str), "text"),
    "bool": (lambda v: isinstance(v, (bool, np.bool_)), "a boolean"),
    "names": (lambda v: isinstance(v, list) and all(isinstance(s, str) for s in v), "a list of names"),
    "json": (lambda v: isinstance(v, dict), "a JSON object"),
    "json_text": (None, "JSON text of an object"),
}

_NAMES = ("position_names", "velocity_names", "acceleration_names", "input_names", "output_names")
#: Expected types of the known file-level snapshot attributes.
SNAPSHOT_FILE_ATTRS = {"kind": "str", "layout_version": "int", "n": "int", "m": "int", "p": "int", "dt": "positive",
                       "constraint": "str", "source": "str", "source_kind": "str", "model_name": "str",
                       "derived_xdot": "bool", "derived_xddot": "bool", **{k: "names" for k in _NAMES},
                       **{k: "json" for k in ("system_options", "fmu_parameters", "fmu_settings",
                                                  "variable_selection", "versions", "auto_window",
                                                  "initialization", "fmi3_ports", "held_inputs", "merged_parts")}}
#: Expected types of the known per-run snapshot attributes.
SNAPSHOT_RUN_ATTRS = {"complete": "bool", "k": "int", "k_planned": "int", "dt": "positive", "t0": "float",
                      "t_end": "float", "input_spec": "str", "isolated": "bool", "error": "str",
                      "derived_xdot": "bool", "derived_xddot": "bool", "events": "int", "first_event_t": "float",
                      "inert_events": "int", "integrator_method": "str"}
#: Expected types of the ROM file attributes.
ROM_ATTRS = {"kind": "str", "layout_version": "int", "basis_kind": "str", "dt": "positive",
             "input_names": "names", "output_names": "names", "provenance": "json_text", "fit_info": "json_text"}


def check_attr_types(attrs: dict[str, Any], schema: dict[str, str], where: str) -> None:
    """Every attribute named in ``schema`` that is present has the expected kind of value."""
    for key, kind in schema.items():
        if key not in attrs:
            continue
        value = attrs[key]
        test, text = _KINDS[kind]
        if kind == "json_text":
            ok = isinstance(value, str) and isinstance(_json(value), dict)
        else:
            ok = test(value)
        if not ok:
            raise FileFormatError(f"{where}: attribute {key!r} is {_short(value)}, expected {text}; "
                                  "the file is damaged or was not written by fmu-opinf")


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return None


def _short(value: Any) -> str:
    text = " ".join(repr(value).split())
    text = text if len(text) <= 40 else text[:37] + "..."
    return f"{type(value).__name__} {text}"


# -- snapshot files --------------------------------------------------------------------------------------


def check_snapshot_run(g: Any, label: str, sizes: dict[str, int | None]) -> dict[str, int]:
    """Check one run group: arrays present, real, of consistent shapes, ``t`` finite and increasing.

    Parameters
    ----------
    g : object
        The run group.
    label : str
        ``file: run NAME`` for messages.
    sizes : dict
        Declared ``n``, ``m``, ``p`` (None: not declared; then taken from the first run).

    Returns
    -------
    dict
        The sizes ``n, m, p`` of this run.
    """
    if not isinstance(g, h5py.Group):
        raise FileFormatError(f"{label} is not a group; the file is damaged")
    missing = [a for a in ("t", "u", "x", "xdot", "xddot", "y") if a not in g]
    if missing:
        raise FileFormatError(f"{label} lacks {', '.join(missing)}; the file is truncated")
    t = read_real(g["t"], f"{label} t", ndim=1)
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise DataError(f"{label}: the times t are not strictly increasing; the file is damaged, re-record it")
    k = t.size
    n = sizes.get("n") if sizes.get("n") is not None else check_array(g["x"], f"{label} x", 2).shape[0]
    m = sizes.get("m") if sizes.get("m") is not None else check_array(g["u"], f"{label} u", 2).shape[0]
    p = sizes.get("p") if sizes.get("p") is not None else check_array(g["y"], f"{label} y", 2).shape[0]
    for name, rows in (("u", m), ("x", n), ("xdot", n), ("xddot", n), ("y", p)):
        check_array(g[name], f"{label} {name}", 2, rows, k)
    for name in ("x0", "v0"):
        if name in g:
            read_real(check_array(g[name], f"{label} {name}", 1, n), f"{label} {name}")
    return {"n": n, "m": m, "p": p}


# -- ROM files -------------------------------------------------------------------------------------------


def check_rom_file(f: h5py.File, path: Path) -> None:
    """Validate a ROM file before :meth:`SecondOrderROM._from_h5 <fmu_opinf.rom.SecondOrderROM>` reads it.

    Checks links, attribute types, that every dataset holds finite real numbers actually stored in the file
    and fitting into memory, and that the matrices' shapes agree.  That ``Mr, Dr, Kr`` are the operators of a
    second-order ROM is checked once they are read, by :func:`fmu_opinf.rom.check_operators` (the check
    ``export`` runs too).
    """
    with damaged_file_errors(path):
        _check_rom_file(f, path)


@contextlib.contextmanager
def damaged_file_errors(path: Path) -> Iterator[None]:
    """Report low-level HDF5 failures (corrupt headers, bad addresses) as one-line :class:`FileFormatError`."""
    try:
        yield
    except FmuOpinfError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        raise FileFormatError(f"cannot read {path} ({type(exc).__name__}: {read_failure(exc)}); the file is damaged, "
                              f"{RESTORE}") from None


#: Expected shapes of the ROM matrices in terms of ``r``, ``m``, ``p``, ``n`` (None: any).
_ROM_SHAPES = {"Mr": ("r", "r"), "Dr": ("r", "r"), "Kr": ("r", "r"), "Br": ("r", "m"), "Cpr": ("p", "r"),
               "Cvr": ("p", "r"), "basis": ("n", "r"), "singular_values": ("N",), "coordinates": ("s", "s")}


def _check_rom_shapes(mats: dict[str, np.ndarray], path: Path) -> None:
    """Every known matrix has the dimensions its shape formula and the others' sizes imply."""
    sizes: dict[str, int] = {}
    for name, formula in _ROM_SHAPES.items():
        value = mats.get(name)
        if value is None:
            continue
        if value.ndim != len(formula):
            raise FileFormatError(f"{path}: {name} has shape {value.shape}, expected {len(formula)} dimensions "
                                  f"({', '.join(formula)}); the file is damaged")
        for size, symbol in zip(value.shape, formula):
            if sizes.setdefault(symbol, size) != size:
                raise FileFormatError(f"{path}: {name} has shape {value.shape}, inconsistent with {symbol}="
                                      f"{sizes[symbol]} of the other matrices; the file is damaged")


def _check_rom_file(f: h5py.File, path: Path) -> None:
    from ._hdf5 import read_attrs

    reject_links(f)
    check_attr_types(read_attrs(f), ROM_ATTRS, str(path))
    datasets = {name: check_array(obj, f"{path}: {name}") for name, obj in f.items()
                if isinstance(obj, h5py.Dataset)}
    check_memory(8.0 * sum(ds.size for ds in datasets.values()), f"ROM file {path}",
                 "the file declares more data than this machine holds; it is damaged or not a ROM")
    mats = {name: read_real(ds, f"{path}: {name}") for name, ds in datasets.items()}
    _check_rom_shapes(mats, path)
