"""Input signals and their textual form.

A signal maps times to input values, ``sample(t) -> (m, k)``.  Simulators hold the input
constant over each step at its value at the start of the step (zero-order hold, spec
section 4), so a signal is only ever evaluated at the step starts.

Textual form (used by the command line), one spec per input separated by ``;`` (a single
spec drives every input)::

    impulse:amplitude=100,t0=2,width=0.5     raised-cosine pulse centred at t0, total width `width`
    harmonic:amplitude=1,omega=0.2           amplitude * sin(omega t + phase)
    step:amplitude=1,t0=0                    amplitude for t >= t0, 0 before
    chirp:amplitude=1,omega0=0.01,omega1=1   sine sweeping linearly from omega0 to omega1 over `duration`
    ...,offset=10                            any of these on top of a constant (an operating point)
    path/to/table.csv                        time column plus one column per input, held between rows;
                                             where the header names the model's inputs, by name
    none                                     no forcing: every input zero (the free response of a model);
                                             as one of several ';' specs, that input alone is not driven
"""

from __future__ import annotations

import csv
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ._validate import either
from .errors import DimensionError, FmuOpinfWarning, InputSpecError

__all__ = [
    "Signal", "ParametricSignal", "TableSignal", "StackedSignal", "NoInput",
    "impulse", "harmonic", "step", "chirp", "table", "parse_signal", "pulse_amplitude", "by_input_names",
]


class Signal:
    """Base class: an input signal with ``n_inputs`` channels and a textual ``spec``."""

    n_inputs: int = 1
    spec: str = ""
    #: Times outside this closed interval cannot be sampled.
    t_range: tuple[float, float] = (-math.inf, math.inf)

    def sample(self, t: np.ndarray | float) -> np.ndarray:
        """Input values at times ``t``, shape ``(n_inputs, len(t))``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        lo, hi = self.t_range
        tol = 1e-9 * max(1.0, abs(hi) if math.isfinite(hi) else 1.0)
        if t.size and (t.min() < lo - tol or t.max() > hi + tol):
            raise InputSpecError(
                f"input {self.spec!r} is defined on [{lo:g}, {hi:g}] but the simulation needs "
                f"[{t.min():g}, {t.max():g}]; extend the table or shorten {either('--t-end')}")
        return self._values(t)

    def _values(self, t: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def is_identically_zero(self) -> bool | None:
        """Whether the signal is zero at all times by construction (zero amplitude, an all-zero table), None
        where that is not known.  A recorder refuses a signal that is not, yet zero at every sample it takes."""
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.spec!r})"


@dataclass(repr=False)
class ParametricSignal(Signal):
    """A scalar signal given by a formula and its named parameters."""

    kind: str
    params: dict[str, float]
    formula: Callable[..., np.ndarray] = field(compare=False)

    def __post_init__(self) -> None:
        self.n_inputs = 1
        shown = {k: v for k, v in self.params.items() if not (k == "offset" and v == 0 and self.kind != "harmonic")}
        self.spec = self.kind + ":" + ",".join(f"{k}={_number(v)}" for k, v in shown.items())

    def is_identically_zero(self) -> bool:
        return self.params.get("amplitude", 1.0) == 0 and self.params.get("offset", 0.0) == 0

    def activity(self) -> tuple[float, float | None] | None:
        """Exactly when the input stops changing and its pulse width, ``(t_off, width)``, for an impulse
        (``(t0 + width / 2, width)``) or a step (``(t0, None)``); None for the others, which never settle."""
        if self.kind == "impulse":
            end = self.params["t0"] + 0.5 * self.params["width"]
            return (end, self.params["width"]) if end > 0 else None
        if self.kind == "step":
            return max(self.params["t0"], 0.0), None
        return None

    def _values(self, t: np.ndarray) -> np.ndarray:
        return np.asarray(self.formula(t, **self.params), dtype=float).reshape(1, -1)


def _number(value: float) -> str:
    """A parameter in a spec: short (``%g``) where that reads back exactly, else every digit (an operating
    point such as a start value of 9.80665 N must come back as it was)."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def _impulse(t, amplitude, t0, width, offset):
    phase = 2.0 * np.pi * (t - t0) / width
    return offset + np.where(np.abs(t - t0) <= width / 2, amplitude * 0.5 * (1.0 + np.cos(phase)), 0.0)


def _harmonic(t, amplitude, omega, phase, offset):
    return offset + amplitude * np.sin(omega * t + phase)


def _step(t, amplitude, t0, offset):
    return offset + np.where(t >= t0, amplitude, 0.0)


def _chirp(t, amplitude, omega0, omega1, duration, t0, offset):
    s = np.clip(t - t0, 0.0, None)
    sweep = np.minimum(s, duration)
    angle = omega0 * sweep + (omega1 - omega0) * sweep**2 / (2.0 * duration) + omega1 * (s - sweep)
    return offset + np.where(t >= t0, amplitude * np.sin(angle), 0.0)


# name -> (formula, default parameters, parameters that must be > 0)
_KINDS: dict[str, tuple[Callable[..., np.ndarray], dict[str, float], tuple[str, ...]]] = {
    "impulse": (_impulse, {"amplitude": 1.0, "t0": 1.0, "width": 0.5, "offset": 0.0}, ("width",)),
    "harmonic": (_harmonic, {"amplitude": 1.0, "omega": 1.0, "phase": 0.0, "offset": 0.0}, ()),
    "step": (_step, {"amplitude": 1.0, "t0": 0.0, "offset": 0.0}, ()),
    "chirp": (_chirp, {"amplitude": 1.0, "omega0": 0.01, "omega1": 1.0, "duration": 100.0, "t0": 0.0, "offset": 0.0},
              ("duration",)),
}


def _make(kind: str, **params: float) -> ParametricSignal:
    formula, defaults, positive = _KINDS[kind]
    unknown = set(params) - set(defaults)
    if unknown:
        raise InputSpecError(f"unknown key {sorted(unknown)[0]!r} for {kind} input; "
                             f"valid keys: {', '.join(defaults)}")
    values = {**defaults, **{k: float(v) for k, v in params.items()}}
    for key, value in values.items():
        if not math.isfinite(value):
            raise InputSpecError(f"{kind} input: {key}={value} is not a finite number")
    for key in positive:
        if values[key] <= 0:
            raise InputSpecError(f"{kind} input: {key} must be positive, got {values[key]:g}")
    return ParametricSignal(kind, values, formula)


def impulse(amplitude: float = 1.0, t0: float = 1.0, width: float = 0.5, offset: float = 0.0) -> ParametricSignal:
    """Impulse-like pulse: a raised cosine of peak ``amplitude`` centred at ``t0``, total ``width``, on top of
    ``offset``.

    Smooth and short, it excites the system's own dynamics (the paper's training input).
    Keep ``t0`` on the time grid and ``dt <= width`` so the sampled pulse is not missed.
    """
    return _make("impulse", amplitude=amplitude, t0=t0, width=width, offset=offset)


def harmonic(amplitude: float = 1.0, omega: float = 1.0, phase: float = 0.0,
             offset: float = 0.0) -> ParametricSignal:
    """Harmonic wave ``offset + amplitude * sin(omega t + phase)`` (the paper's test input)."""
    return _make("harmonic", amplitude=amplitude, omega=omega, phase=phase, offset=offset)


def step(amplitude: float = 1.0, t0: float = 0.0, offset: float = 0.0) -> ParametricSignal:
    """Step of height ``amplitude`` switched on at ``t0``, on top of ``offset``."""
    return _make("step", amplitude=amplitude, t0=t0, offset=offset)


def chirp(amplitude: float = 1.0, omega0: float = 0.01, omega1: float = 1.0,
          duration: float = 100.0, t0: float = 0.0, offset: float = 0.0) -> ParametricSignal:
    """Linear chirp: instantaneous frequency from ``omega0`` at ``t0`` to ``omega1`` at ``t0 + duration``, on
    top of ``offset``."""
    return _make("chirp", amplitude=amplitude, omega0=omega0, omega1=omega1, duration=duration, t0=t0,
                 offset=offset)


class TableSignal(Signal):
    """Input read from a table: times ``(k,)`` and values ``(m, k)``, held between rows."""

    def __init__(self, times: np.ndarray, values: np.ndarray, names: Sequence[str], spec: str) -> None:
        self.times = np.asarray(times, dtype=float)
        self.values = np.atleast_2d(np.asarray(values, dtype=float))
        self.names = list(names)
        self.n_inputs = self.values.shape[0]
        self.spec = spec
        self.t_range = (float(self.times[0]), float(self.times[-1]))

    def is_identically_zero(self) -> bool:
        return not np.any(self.values)

    def _values(self, t: np.ndarray) -> np.ndarray:
        tol = 1e-9 * max(1.0, abs(self.times[-1]))
        index = np.searchsorted(self.times, t + tol, side="right") - 1
        return self.values[:, np.clip(index, 0, self.times.size - 1)]


def table(path: str | os.PathLike) -> TableSignal:
    """Read a CSV input table: a header row, a time column first, then one column per input.

    Times must increase strictly; every value must be a finite number.  Between rows the
    value of the earlier row holds (zero-order hold).
    """
    path = Path(path)
    if not path.is_file():
        raise InputSpecError(f"input table {path} not found; give an existing .csv file")
    try:
        with open(path, newline="") as f:
            rows = [row for row in csv.reader(f) if row and any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise InputSpecError(f"cannot read input table {path}: {exc}") from None
    if len(rows) < 3:
        raise InputSpecError(f"input table {path} needs a header row and at least two data rows")
    header = [c.strip() for c in rows[0]]
    if len(header) < 2:
        separator = next((name for mark, name in ((";", "semicolons"), ("\t", "tabs")) if mark in rows[0][0]), None)
        if separator:
            raise InputSpecError(f"input table {path} is separated by {separator}; write it with commas (a time "
                                 "column, then one column per input)")
        raise InputSpecError(f"input table {path} needs a time column and at least one input column")
    data = np.empty((len(rows) - 1, len(header)))
    for line, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise InputSpecError(f"{path}:{line}: {len(row)} columns, header has {len(header)}")
        try:
            data[line - 2] = [float(c) for c in row]
        except ValueError:
            raise InputSpecError(f"{path}:{line}: not a number in {row!r}") from None
    if not np.all(np.isfinite(data)):
        bad = int(np.argwhere(~np.isfinite(data))[0, 0]) + 2
        raise InputSpecError(f"{path}:{bad}: NaN or infinite value; every entry must be finite")
    if np.any(np.diff(data[:, 0]) <= 0):
        bad = int(np.argmax(np.diff(data[:, 0]) <= 0)) + 3
        raise InputSpecError(f"{path}:{bad}: time does not increase; sort the rows by time")
    return TableSignal(data[:, 0], data[:, 1:].T, header[1:], spec=str(path))


class StackedSignal(Signal):
    """Several signals side by side, one block of inputs each."""

    def __init__(self, parts: Sequence[Signal]) -> None:
        self.parts = list(parts)
        self.n_inputs = sum(p.n_inputs for p in self.parts)
        self.spec = ";".join(p.spec for p in self.parts)
        self.t_range = (max(p.t_range[0] for p in self.parts), min(p.t_range[1] for p in self.parts))

    def _values(self, t: np.ndarray) -> np.ndarray:
        return np.vstack([p.sample(t) for p in self.parts])


class _Broadcast(Signal):
    """One scalar signal driving ``n_inputs`` inputs alike."""

    def __init__(self, base: Signal, n_inputs: int) -> None:
        self.base, self.n_inputs, self.spec, self.t_range = base, n_inputs, base.spec, base.t_range

    def is_identically_zero(self) -> bool | None:
        return self.base.is_identically_zero()

    def _values(self, t: np.ndarray) -> np.ndarray:
        return np.repeat(self.base.sample(t), self.n_inputs, axis=0)


class NoInput(Signal):
    """``none``: no forcing, every one of ``n_inputs`` channels held at ``values`` (default zero; ``n_inputs = 0``:
    a model without inputs).

    A ROM simulated with it gives its free response from the initial state.  (An FMU recorded with
    ``--input none``, or with ``none`` for one input among several specs, holds those inputs at their start
    values instead, see :mod:`fmu_opinf.snapshots`.)
    """

    spec = "none"

    def __init__(self, n_inputs: int = 0, values: Sequence[float] | None = None) -> None:
        self.n_inputs = int(n_inputs)
        self.values = np.zeros(self.n_inputs) if values is None else np.asarray(values, dtype=float).reshape(-1)
        if self.values.size != self.n_inputs:
            raise DimensionError(f"NoInput: {self.values.size} held values for {self.n_inputs} inputs")

    def _values(self, t: np.ndarray) -> np.ndarray:
        return np.repeat(self.values[:, None], t.size, axis=1)


def _parse_one(spec: str) -> Signal:
    spec = spec.strip()
    if not spec:
        raise InputSpecError("empty input specification; e.g. 'impulse:amplitude=100,t0=2,width=0.5'")
    if spec.lower().endswith(".csv"):
        return table(spec)
    if spec.lower() == "none":
        return NoInput(1)
    given, _, body = spec.partition(":")
    kind = given.strip().lower()
    if kind not in _KINDS:
        raise InputSpecError(f"unknown input kind {given.strip()!r}; use one of {', '.join(_KINDS)} "
                             "or a path to a .csv table")
    params: dict[str, float] = {}
    for item in filter(None, (s.strip() for s in body.split(","))):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise InputSpecError(f"malformed {kind} parameter {item!r}; write key=value, "
                                 f"e.g. {kind}:{next(iter(_KINDS[kind][1]))}=1")
        if key in params:
            raise InputSpecError(f"{kind} parameter {key!r} given twice")
        try:
            params[key] = float(value)
        except ValueError:
            raise InputSpecError(f"{kind} parameter {key}={value.strip()!r} is not a number") from None
    return _make(kind, **params)


def parse_signal(spec: str | Signal, n_inputs: int | None = None, input_names: Sequence[str] | None = None,
                 held_names: Sequence[str] = ()) -> Signal:
    """Signal from its textual form (see module docstring), checked against ``n_inputs``.

    A single scalar spec drives all ``n_inputs`` inputs; ``;`` separates one spec per input.  With the model's
    ``input_names`` (and the names of its inputs held, not driven), a table whose header names inputs gives each
    its own column (:func:`by_input_names`).
    """
    if not isinstance(spec, Signal) and str(spec).strip().lower() == "none":
        return NoInput(n_inputs or 0)
    signal = spec if isinstance(spec, Signal) else _stack([_parse_one(s) for s in str(spec).split(";")])
    if input_names is not None:
        signal = by_input_names(signal, input_names, held_names)
    if n_inputs is None or signal.n_inputs == n_inputs:
        return signal
    if n_inputs == 0:  # broadcast to no channel it would vanish, and a report would name an input never applied
        raise DimensionError(f"input {signal.spec!r} given, but the model has no inputs; give "
                             f"{either('--input', 'signal', 'none')} (the free response from the start state)")
    if signal.n_inputs == 1:
        return _Broadcast(signal, n_inputs)
    raise DimensionError(f"input {signal.spec!r} has {signal.n_inputs} channels but the model has "
                         f"{n_inputs} inputs; give one spec per input separated by ';'")


def _stack(parts: list[Signal]) -> Signal:
    return parts[0] if len(parts) == 1 else StackedSignal(parts)


def by_input_names(signal: Signal, input_names: Sequence[str], held_names: Sequence[str] = ()) -> Signal:
    """``signal`` with the columns of its tables put where the header names them among ``input_names``.

    A table's header is the one place a user names inputs: read by position, a table whose columns came in
    another order than the model's inputs drove each input with another's values, and a one-column table named
    for one input drove all of them (audit 58: ``time,F_kN,F_mN`` for inputs ``F_mN, F_kN``; compare then agreed
    to 1e-25 on inputs nobody had asked for).  A header cell names an input as written, or apart from quotes,
    blanks, case and a unit in brackets after a blank (``"f_kn [kN]"``; audit 59: such near misses were read by
    position).  A header that names none of the inputs (``time,u``) keeps the columns in their order, said in a
    warning where that order decides which input gets which column; one that names some of them and not the
    others, or an input held at its start value (``held_names``: not driven, audit 59), is refused.

    Raises
    ------
    InputSpecError
        A header naming inputs that are not where the table's columns go, naming some inputs and not others, or
        naming a held input.
    """
    names = list(input_names)
    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    if not any(isinstance(part, TableSignal) for part in parts):
        return signal
    for part in parts:
        if isinstance(part, TableSignal):
            _refuse_held_columns(part, names, list(held_names))
    whole = len(parts) == 1 and parts[0].n_inputs < len(names)   # one table meant for every input
    if not whole and signal.n_inputs != len(names):
        return signal   # (the count of channels is refused where the signal is checked against the model)
    matched, start = [], 0
    for part in parts:
        wanted = names if whole else names[start:start + part.n_inputs]
        matched.append(_table_by_names(part, wanted, names) if isinstance(part, TableSignal) else part)
        start += part.n_inputs
    return _stack(matched) if len(matched) > 1 else matched[0]


def _bare(text: str) -> str:
    """A header cell without quotes, surrounding blanks and a unit in brackets after a blank (``F_kN [kN]``, not
    the index of ``F[2]``)."""
    text = text.strip().strip("\"'").strip()
    return re.sub(r"\s+[\[(][^\[\]()]*[\])]$", "", text)


def _named_inputs(header: list[str], names: list[str]) -> list[str | None]:
    """The input each header cell names (:func:`by_input_names`), None where it names none: as written, or bare
    (:func:`_bare`), or bare but for case where that matches one input only (inputs ``F`` and ``f``: each its own,
    audit 60)."""
    folded: dict[str, list[str]] = {}
    for name in names:
        folded.setdefault(name.casefold(), []).append(name)
    found: list[str | None] = []
    for cell in header:
        bare = _bare(cell)
        matches = [cell] if cell in names else [bare] if bare in names else folded.get(bare.casefold(), [])
        found.append(matches[0] if len(matches) == 1 else None)
    return found


def _refuse_held_columns(table: TableSignal, names: list[str], held: list[str]) -> None:
    """One line where ``table``'s header names an input that is held, not driven: its column would drive another."""
    columns = [name for name in _named_inputs(table.names, names + held) if name in held and name not in names]
    if columns:
        raise InputSpecError(f"input table {table.spec} has a column for {', '.join(columns)}, held at its start "
                             f"value, not driven (the driven inputs: {', '.join(names) or 'none'}); leave its column "
                             f"out, or record snapshots with {either('--inputs', value=','.join(names + columns))} to "
                             "drive it (and fit "
                             "again: a ROM has ports for the inputs it was trained on only)")


#: The tables whose columns :func:`_table_by_names` said it takes in order (one warning per table and inputs).
_SAID_IN_ORDER: set[tuple[str, tuple[str, ...]]] = set()


def _table_by_names(table: TableSignal, wanted: list[str], names: list[str]) -> TableSignal:
    """``table`` with its columns in the order of ``wanted`` (the inputs its columns go to), or as it is where its
    header names none of the model's ``names``."""
    resolved = _named_inputs(table.names, names)
    listed = ", ".join(names)
    if not any(resolved):
        _warn_in_order(table, wanted, names)
        return table
    if None in resolved:
        others = ", ".join(cell for cell, name in zip(table.names, resolved) if name is None)
        raise InputSpecError(f"input table {table.spec} has columns {others} beside the model's inputs ({listed}); "
                             "name every column after an input, or none of them to take the columns in order")
    if len(set(resolved)) != len(resolved):
        raise InputSpecError(f"input table {table.spec} names an input twice ({', '.join(table.names)}); give each "
                             "input one column")
    if set(resolved) < set(wanted):
        missing = ", ".join(name for name in wanted if name not in resolved)
        raise InputSpecError(f"input table {table.spec} has no column for {missing}; give a column for each input "
                             f"({listed}), or one spec per input separated by ';' (none holds an input at its start "
                             "value)")
    if sorted(resolved) != sorted(wanted):
        raise InputSpecError(f"input table {table.spec} gives {', '.join(resolved)} in the place of "
                             f"{', '.join(wanted)} among the ';' specs (the model's inputs in order: {listed}); put "
                             "it where its inputs are")
    if resolved == wanted:
        return table if table.names == wanted else TableSignal(table.times, table.values, wanted, table.spec)
    order = [resolved.index(name) for name in wanted]
    return TableSignal(table.times, table.values[order], wanted, table.spec)


def _warn_in_order(table: TableSignal, wanted: list[str], names: list[str]) -> None:
    """Say once which input takes which column of a table whose header names none of them, where that is a choice
    (two inputs or more)."""
    key = (table.spec, tuple(wanted))
    if len(names) < 2 or key in _SAID_IN_ORDER:
        return
    _SAID_IN_ORDER.add(key)
    if table.n_inputs == 1:
        pairs = f"{table.names[0]} drives each of {', '.join(wanted)}"
    else:
        pairs = ", ".join(f"{cell} -> {name}" for cell, name in zip(table.names, wanted))
    warnings.warn(f"input table {table.spec}: its header ({', '.join(table.names)}) names none of the inputs "
                  f"({', '.join(names)}), so its columns are taken in order: {pairs}; name the columns after the "
                  "inputs to have them matched by name", FmuOpinfWarning, stacklevel=4)


def pulse_amplitude(high: float, default: float) -> float:
    """The largest pulse amplitude up to ``default`` whose pulse, rising from 0, stays at or below ``high`` (an
    input's declared ``max``), written with at most six significant digits; ``default`` where ``high`` leaves
    no room (not above 0) or is not below it."""
    if not 0 < high < default:
        return default
    value = float(f"{high:g}")
    return value if value <= high else float(f"{high * (1 - 1e-5):g}")
