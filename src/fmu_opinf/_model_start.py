"""Where a ROM starts when every training run had its own run table ``start:`` values: the model's own start.

A run table's ``start:`` columns give a run its own initial state; the rows are one training set
(``docs/scale-out.md``), and the ROM's start (``q0, qdot0``: where ``compare`` without a source and the exported FMU
begin) is the model's own.  :mod:`fmu_opinf.fit` takes the first training run's start as the ROM's
(:mod:`fmu_opinf.basis` puts a run without start values of its own first), so a table in which every row has its
own start gave a ROM, and a ROM FMU, that started from the first row's state: audit 73 F2, the exported FMU's free
response 174-180 % of range off the model from its own start, and nothing said.

The model's own start is not in the runs' samples then, and the declared start values alone do not give it (a
state's start may be calculated from parameters, an FMI 3 array's from ``x_start``).  The source that recorded the
runs does: it is initialized once more with a row's settings but without its ``start:`` values, and its positions
and velocities after initialization are the start.  That is done when the row is recorded, where the source is at
hand (:func:`start_to_record`, called by :func:`fmu_opinf.runs.record_row`; once per source and settings in a
process), and stored with the run (datasets ``model_start_x0``, ``model_start_v0``, attribute ``model_start``:
whose settings, or why it could not be read; docs/file-format.md).  The fit maps the stored start onto the ROM's
basis (:func:`own_start`) and never opens the FMU for it: the data flow one way (source -> snapshots -> basis ->
inference -> ROM), and a fit elsewhere, or after the FMU moved or changed, starts where the model does.

A file recorded before 2026-12-07 has no stored start: for it, the fit initializes the recorded FMU as before, if
it is still there unchanged (:func:`_source_start`).  Where the start cannot be had (not stored and the FMU gone or
changed, its initialization failed, or the start lies off the basis) the ROM keeps the first run's start and the fit
says so, with the fix: a row without ``start:`` values.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ._hdf5 import sha256_of
from .errors import FmuOpinfError
from .rom import _finite_number

__all__ = ["START_OFF_BASIS", "own_start", "row_start", "sets_initial_state", "start_column_problem", "start_to_record",
           "stored_start"]

#: Largest relative part of the model's own start (``x0 - x_ref``, ``v0``) outside the ROM's basis that still counts
#: as on it (as :meth:`fmu_opinf.rom.SecondOrderROM.initial_state`'s default).
START_OFF_BASIS = 1e-6


def row_start(attrs: dict[str, Any]) -> dict[str, Any]:
    """The ``start:`` cells of the run table row a recording (file or run attributes ``attrs``) came from.

    Returns
    -------
    dict
        Variable name to value; empty for a recording that is no run table row's, or a row without them.
    """
    stamp = attrs.get("run_row") if isinstance(attrs, dict) else None
    if isinstance(stamp, bytes):
        stamp = stamp.decode("utf-8", "replace")
    if isinstance(stamp, str):
        try:
            stamp = json.loads(stamp)
        except ValueError:
            return {}
    row = stamp.get("row") if isinstance(stamp, dict) else None
    start = row.get("start") if isinstance(row, dict) else None
    return {str(name): value for name, value in start.items()} if isinstance(start, dict) else {}


def sets_initial_state(name: str, attrs: dict[str, Any]) -> bool:
    """Whether a start value for ``name`` sets an initial state of a recording with attributes ``attrs``: ``name`` is
    a recorded position or velocity, or the ``<state>_start`` parameter of one (``x_start[4]`` for ``x[4]``)."""
    states = [str(n) for key in ("position_names", "velocity_names") for n in (attrs.get(key) or [])]
    bases = {state.split("[", 1)[0] for state in states}
    return name in states or name.split("[", 1)[0] in {f"{base}_start" for base in bases}


def own_start(run: Any, attrs: dict[str, Any], basis: np.ndarray, x_ref: np.ndarray,
              isolate: bool = True) -> tuple[np.ndarray, np.ndarray | None] | str:
    """The model's own start in POD coordinates, for a ROM whose first training run ``run`` had ``start:`` values.

    The start stored with the run when it was recorded is taken; a run without one (recorded before 2026-12-07)
    has its FMU initialized here, as then.

    Parameters
    ----------
    run : Run
        The first training run (its stored ``model_start``, else its attributes: source, settings, ``start:``
        cells).
    attrs : dict
        The training set's attributes (what the run's own do not say).
    basis : (n, r) ndarray
        The ROM's position basis ``V``.
    x_ref : (n,) ndarray
        The ROM's reference position.
    isolate : bool, default True
        Initialize the FMU in a child process, as recording does.

    Returns
    -------
    (q0, qdot0) or str
        ``q0 = V^T (x0 - x_ref)`` and ``qdot0 = V^T v0`` (None where the source derives its velocities, which one
        sample does not give), or why the start cannot be had: a clause for the fit's warning.
    """
    found = stored_start(run)
    if found is None:   # a file recorded before the start was stored with the run
        found = _source_start(run, attrs, isolate)
    if isinstance(found, str):
        return found
    x0, v0 = found
    if x0.shape != (basis.shape[0],) or (v0 is not None and v0.shape != x0.shape):
        return f"the source's start has {x0.size} positions, the ROM's basis {basis.shape[0]}"
    q0, miss = _on_basis(basis, x0 - x_ref)
    qdot0, miss_v = _on_basis(basis, v0) if v0 is not None else (None, 0.0)
    if max(miss, miss_v) > START_OFF_BASIS:
        return (f"the model's own start lies off the ROM's basis (relative part outside {max(miss, miss_v):.1e}): "
                "the training runs' starts do not span it")
    return q0, qdot0


def _on_basis(basis: np.ndarray, vector: np.ndarray) -> tuple[np.ndarray, float]:
    """``V^T vector`` and the relative part of ``vector`` outside the span of ``V``."""
    reduced = basis.T @ vector
    norm = float(np.linalg.norm(vector))
    return reduced, (float(np.linalg.norm(vector - basis @ reduced)) / norm if norm > 0 else 0.0)


def stored_start(run: Any) -> tuple[np.ndarray, np.ndarray | None] | str | None:
    """The model's own start stored with ``run`` when it was recorded (positions, velocities or None where they are
    derived), why it could not be read then, or None where the run has none stored."""
    arrays = getattr(run, "model_start", None)
    provenance = (getattr(run, "attrs", None) or {}).get("model_start")
    if not arrays:
        reason = provenance.get("reason") if isinstance(provenance, dict) else None
        return f"{reason} (when the snapshots were recorded)" if isinstance(reason, str) and reason else None
    v0 = arrays.get("v0")
    return (np.asarray(arrays["x0"], dtype=float).reshape(-1),
            None if v0 is None else np.asarray(v0, dtype=float).reshape(-1))


def _source_start(run: Any, attrs: dict[str, Any], isolate: bool) -> tuple[np.ndarray, np.ndarray | None] | str:
    """Positions and velocities of the run's source after initialization without the run's ``start:`` values,
    or why they cannot be had (the fit's way for a file without a stored start)."""
    own = dict(getattr(run, "attrs", None) or {})
    path = _source_path(own, attrs)
    if isinstance(path, str):
        return path
    return _initialized(path, _start_options(own, attrs, row_start(own)), _first_step(run), isolate)


def _start_options(own: dict[str, Any], attrs: dict[str, Any], starts: dict[str, Any]) -> dict[str, Any]:
    """The source keywords of a recording (run attributes ``own``, file attributes ``attrs``) without its
    ``start:`` values ``starts``: its settings, start time, interface and exact variable names."""
    from .snapshots._data import settings_of

    settings = {name: value for name, value in settings_of(own or attrs).items() if name not in starts}
    options = {"parameters": settings or None, "start_time": _finite_number(own.get("t0", attrs.get("start_time"))),
               "interface": own.get("fmi_interface") or attrs.get("fmi_interface")}
    for key, names in (("positions", attrs.get("position_names")), ("velocities", attrs.get("velocity_names")),
                       ("inputs", attrs.get("input_names")), ("outputs", attrs.get("output_names"))):
        options[key] = _exact_names(names)
    return options


def _initialized(path: Path, options: dict[str, Any], step: np.ndarray,
                 isolate: bool) -> tuple[np.ndarray, np.ndarray | None] | str:
    """Positions and velocities (None where the source derives them) of the FMU ``path`` opened with ``options``
    after its initialization, or why they cannot be had."""
    from .signals import parse_signal
    from .snapshots._run import MemorySink, record_run
    from .source import open_source

    try:
        source = open_source(path, **options)
        try:
            signal = parse_signal("none", source.m, source.input_names)
            first, failure = record_run(source, signal, step, MemorySink, True, isolate,
                                        "the model's own start", say_events=False)
            derived = bool(source.derived.get("xdot"))
        finally:
            getattr(source, "close", lambda: None)()
    except FmuOpinfError as exc:
        return f"{path.name} could not be initialized to read it ({exc})"
    if failure is not None:
        return f"{path.name} could not be initialized to read it ({failure})"
    x0 = np.asarray(first.x0, dtype=float).reshape(-1)
    return x0, None if derived else np.asarray(first.v0, dtype=float).reshape(-1)


#: Starts read at recording time in this process, by FMU identity, settings and step (:func:`start_to_record`): a
#: table's rows with one setting initialize the FMU once.  Bounded: a few sources and settings per process.
_READ: dict[str, tuple[tuple[np.ndarray, np.ndarray | None] | str, dict[str, Any]]] = {}
_READ_LIMIT = 16


def start_to_record(source_spec: Any, recorded: Path, row: Any,
                    isolate: bool = True) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """The model's own start to store with a run table row's recording, for a row with ``start:`` values.

    The FMU is initialized with the row's settings (its ``set:`` values and the table's common ones, as recorded in
    ``recorded``) but without its ``start:`` values, at the recording's start time and first step, exactly as the
    fit did before it was stored (:func:`_source_start`); a second row with the same FMU and settings takes the
    start read for the first (once per process).

    Parameters
    ----------
    source_spec : str or path-like
        The FMU the row was recorded from (``builtin:`` sources: nothing stored).
    recorded : Path
        The row's freshly recorded snapshot file (its first run's attributes and times give the settings and step).
    row : RunRow
        The run table row (its ``start:`` values, number and name).
    isolate : bool, default True
        Initialize the FMU in a child process, as recording does.

    Returns
    -------
    (arrays, provenance) or None
        ``arrays`` ``{"x0": positions, "v0": velocities}`` (no ``v0`` where the source derives them; empty where
        the start could not be read), ``provenance`` the run attribute ``model_start``: the row whose settings were
        initialized (``row``), the ``settings`` applied, or ``reason``: why it could not be read.  None for a row
        without ``start:`` values or a builtin source.
    """
    from .snapshots import Snapshots

    text = str(source_spec)
    if not getattr(row, "start", None) or text.startswith("builtin:"):
        return None
    with Snapshots.open(recorded) as snaps:
        run, attrs = snaps.runs[0], dict(snaps.attrs)
        options, step = _start_options(dict(run.attrs), attrs, dict(row.start)), _first_step(run)
        digest = run.attrs.get("fmu_sha256") or attrs.get("fmu_sha256")   # hashed by the recording just made
    path = Path(text)
    digest = digest if isinstance(digest, str) and digest else sha256_of(path)
    key = json.dumps([str(path.resolve()), digest, options, step.tolist(), isolate], sort_keys=True, default=str)
    if key not in _READ:
        if len(_READ) >= _READ_LIMIT:
            _READ.pop(next(iter(_READ)))
        _READ[key] = (_initialized(path, options, step, isolate),
                      {"row": {"number": int(row.number), "name": str(row.name)},
                       "settings": options["parameters"] or {}})
    found, provenance = _READ[key]
    if isinstance(found, str):
        return {}, {**provenance, "reason": found}
    x0, v0 = found
    return {"x0": x0, **({} if v0 is None else {"v0": v0})}, provenance


def _first_step(run: Any) -> np.ndarray:
    """The run's first time step from 0 (the FMU's time grid: a fixed-step co-simulation takes no other)."""
    t = np.asarray(run.t[:2], dtype=float)
    return t - t[0] if t.size == 2 else np.array([0.0, 1e-3])


def _source_path(own: dict[str, Any], attrs: dict[str, Any]) -> Path | str:
    """The recorded FMU's path where it is still there unchanged, else why not."""
    text = own.get("source") or attrs.get("source")
    if not isinstance(text, str) or not text or text.startswith("builtin:"):
        return "the recording names no FMU to read it from"
    path = Path(text)
    if not path.is_file():
        return f"the FMU it was recorded from, {text}, is not there any more"
    digest = own.get("fmu_sha256") or attrs.get("fmu_sha256")
    if isinstance(digest, str) and digest and sha256_of(path) != digest:
        return f"the FMU {text} has changed since the recording"
    return path


def _exact_names(names: Any) -> str | None:
    """Recorded variable names as one pattern of exact names (as ``compare`` opens the source with them)."""
    from .compare._sides import _exact_names as exact

    listed = [str(n) for n in names] if isinstance(names, (list, tuple, np.ndarray)) else None
    return exact(listed)


_PARAMETERS = ("parameter", "calculatedParameter", "structuralParameter")


def start_column_problem(description: Any, name: str) -> str | None:
    """What is wrong with a run table column ``start:NAME`` for the FMU of model ``description``, or None.

    A ``start:`` column sets an initial state (:mod:`fmu_opinf.runs`); a parameter there changes the model, which
    is a ``set:`` column's job (audit 73 F2: ``start:mass_scale`` recorded another model without a word).  A
    parameter that is a state's start value by name, ``<state>_start`` (Modelica's and the FMI 3 array FMUs'
    convention: ``x_start`` sets ``x``), is an initial condition and accepted; a state whose start is calculated
    from such a parameter is pointed to it (``start:x[4]`` -> ``start:x_start[4]``).  Names the description does not
    hold are left to the source's own check.
    """
    variables = {v.name: v for v in getattr(description, "modelVariables", ())}
    base, _ = _split_index(name)
    variable = variables.get(name) or variables.get(base)
    if variable is None:
        return None
    own = variable.name
    if getattr(variable, "causality", None) in _PARAMETERS:
        state = own[:-len("_start")] if own.endswith("_start") else None
        if state and state in variables and variables[state].causality not in _PARAMETERS:
            return None
        return (f"{name} is a parameter, not a state: a start: column sets an initial state; give a parameter as "
                f"column set:{name}")
    starter = variables.get(f"{own}_start")
    if getattr(variable, "start", None) is None and starter is not None and starter.causality in _PARAMETERS:
        column = f"{own}_start{name[len(own):]}" if name.startswith(own) else f"{own}_start"
        return (f"the start of {own} is calculated from the parameter {own}_start (it has no start value to set): "
                f"give column start:{column}")
    return None


def _split_index(name: str) -> tuple[str, str]:
    """``"x[4]"`` -> ``("x", "[4]")``: an array element's variable and its index (``("name", "")`` without)."""
    if name.endswith("]") and "[" in name:
        cut = name.rindex("[")
        return name[:cut], name[cut:]
    return name, ""
