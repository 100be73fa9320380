"""The common source interface: description, stepping protocol, step errors, name patterns.

See :mod:`fmu_opinf.sources` for the stepping protocol every source implements.
"""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..errors import DimensionError, FMUError, InputSpecError

__all__ = ["Source", "StepError", "EventCount", "match_names", "natural_key", "few_names", "CONSTRAINTS",
           "check_constraint", "inputs_without"]

#: Constraint kinds a source may declare.
CONSTRAINTS = ("position", "velocity", "none", "unknown")


class StepError(FMUError):
    """A step failed or produced non-finite values; ``step`` and ``time`` say where."""

    def __init__(self, message: str, step: int, time: float) -> None:
        super().__init__(message)
        self.step = int(step)
        self.time = float(time)


class EventCount(NamedTuple):
    """The events a model-exchange run had (a picklable tuple: an isolated run's child sends it).

    Attributes
    ----------
    count : int
        Events that changed the model: its states, or its derivatives or recorded values at the event time.
    first : float or None
        The run's time of the first of them.
    inert : int
        Events that changed none of those (a Boolean sensor crossing, a flag set at a threshold).
    """

    count: int
    first: float | None
    inert: int = 0


def few_names(names: Sequence[str]) -> str:
    """Up to six names, comma separated (``...`` after them if there are more), each printable: the list a one-line
    message shows (a newline in a name would break the line, as :func:`~fmu_opinf.sources._cosimulation._few`
    says)."""
    shown = ["".join(c if c.isprintable() else repr(c)[1:-1] for c in str(name)) for name in list(names)[:6]]
    return ", ".join(shown) + (", ..." if len(names) > 6 else "")


#: Types of held inputs that switch or select rather than push (audit 77a, F2: a drive's Boolean ``enable``).
_SWITCH_TYPES = ("Boolean", "Integer", "Enumeration", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64",
                 "UInt64")


def held_inputs_advice(held: dict[str, Sequence[Any]]) -> str:
    """The phrase of a one-line message that names the inputs held while the model did not move, with the values
    they were held at, and the ``--set`` that changes one (audit 77a, F2: a Boolean ``enable`` held at its start
    value false kept the force from acting, and the advice named neither).  ``held``: name -> (type, value as
    text, whether ``--set`` gave it), :meth:`FMUSource.held_input_values`.  No input is guessed to be the one: they
    are named as candidates, switches (Boolean, Integer, Enumeration) first.  "" where nothing was held."""
    if not held:
        return ""
    order = sorted(held, key=lambda name: str(held[name][0]) not in _SWITCH_TYPES)
    said = [f"{name} ({held[name][0]}, {'set to' if held[name][2] else 'held at its start value'} {held[name][1]})"
            for name in order]
    shown = few_names(said)
    first, (kind, value, _) = order[0], held[order[0]]
    example = {"true": "false", "false": "true"}.get(str(value).lower(), "VALUE") if kind == "Boolean" else "VALUE"
    return (f"inputs held while it ran, one of which may keep the force from acting: {shown}; if one does, "
            f"set it, e.g. --set {first}={example} or parameters[{first!r}]={example}")


def natural_key(name: str) -> list[Any]:
    """Sort key ordering embedded numbers numerically (``x[2]`` before ``x[10]``)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _pattern_regex(pattern: str) -> re.Pattern[str]:
    """Translate a name pattern: ``*`` any text, ``?`` one character, everything else literal.

    Unlike :func:`fnmatch.fnmatch`, brackets are literal, so ``x[*]`` means "x[ anything ]".
    """
    body = "".join(".*" if c == "*" else "." if c == "?" else re.escape(c) for c in pattern)
    return re.compile(body + r"\Z")


def split_patterns(text: str) -> list[str]:
    """The comma-separated patterns of ``text``, stripped, without empty ones; commas inside brackets or Modelica
    quotes belong to the name (``sensor[1,1]``, ``'a,b'.s``: 2-D component arrays, FMI 3 array elements),
    unless the brackets or quotes do not close (then every comma separates)."""
    pieces, current, depth, quoted = [], [], 0, False
    for char in text:
        if char == "'":
            quoted = not quoted
        elif not quoted and char == "[":
            depth += 1
        elif not quoted and char == "]":
            depth = max(depth - 1, 0)
        if char == "," and depth == 0 and not quoted:
            pieces.append("".join(current))
            current = []
        else:
            current.append(char)
    pieces.append("".join(current))
    if depth or quoted:
        pieces = text.split(",")
    return [p.strip() for p in pieces if p.strip()]


def match_names(patterns: str | Sequence[str], names: Sequence[str]) -> list[str]:
    """Names matching the patterns, each pattern's hits in natural order, without repeats.

    Parameters
    ----------
    patterns : str or sequence of str
        Comma-separated patterns (``"x[*]"``, ``"u1,u2"``); ``*`` and ``?`` are wildcards,
        brackets are literal.
    names : sequence of str
        Candidate names.

    Returns
    -------
    list of str
        Matches; empty if nothing matched.
    """
    if isinstance(patterns, str):
        patterns = split_patterns(patterns)
    found: list[str] = []
    seen: set[str] = set()
    known: set[str] | None = None
    for pattern in (p.strip() for p in patterns):
        if not pattern:
            continue
        if "*" in pattern or "?" in pattern:
            regex = _pattern_regex(pattern)
            hits = sorted((n for n in names if regex.match(n)), key=natural_key)
        else:   # a literal name: a set lookup, not a scan (thousands of listed names on a large model)
            known = set(names) if known is None else known
            hits = [pattern] if pattern in known else []
        for name in hits:
            if name not in seen:
                seen.add(name)
                found.append(name)
    return found


class Source:
    """Common description and stepping interface of every snapshot source.

    Subclasses set the attributes below in their constructor (without loading any model) and
    implement :meth:`start`, :meth:`read`, :meth:`step` and :meth:`close`; :meth:`advance` has a
    generic implementation that fast sources override.

    Attributes
    ----------
    kind : str
        ``"builtin"`` or ``"fmu"``.
    position_names, velocity_names, acceleration_names : list of str
        Names of the recorded x, xdot, xddot; velocity/acceleration lists are empty when the
        source does not expose them (the recorder then derives them, see :attr:`derived`).
    input_names, output_names : list of str
    constraint : str
        ``"position"``, ``"velocity"``, ``"none"`` or ``"unknown"``.
    """

    kind = "abstract"
    position_names: list[str]
    velocity_names: list[str]
    acceleration_names: list[str]
    input_names: list[str]
    output_names: list[str]
    constraint: str

    # -- description ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of positions (full order)."""
        return len(self.position_names)

    @property
    def m(self) -> int:
        """Number of inputs."""
        return len(self.input_names)

    @property
    def p(self) -> int:
        """Number of outputs."""
        return len(self.output_names)

    @property
    def derived(self) -> dict[str, bool]:
        """Which of ``xdot``/``xddot`` the source does not provide (so they are derived)."""
        return {"xdot": not self.velocity_names, "xddot": not self.acceleration_names}

    @property
    def layout(self) -> dict[str, slice]:
        """Where ``x, xdot, xddot, y`` sit in one sample row (absent ones are empty slices)."""
        n, out, pos = self.n, {}, 0
        for name, size in (
            ("x", n),
            ("xdot", 0 if self.derived["xdot"] else n),
            ("xddot", 0 if self.derived["xddot"] else n),
            ("y", self.p),
        ):
            out[name] = slice(pos, pos + size)
            pos += size
        return out

    @property
    def width(self) -> int:
        """Number of values in one sample row."""
        return self.layout["y"].stop

    def description(self) -> dict[str, Any]:
        """Names, sizes and provenance, as stored in the snapshot file's attributes."""
        desc = {
            "n": self.n,
            "m": self.m,
            "p": self.p,
            "constraint": self.constraint,
            "position_names": list(self.position_names),
            "velocity_names": list(self.velocity_names),
            "acceleration_names": list(self.acceleration_names),
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
        }
        desc.update(self.declared_input_ranges())
        desc.update(self.declared_input_nominals())
        desc.update(self.provenance())
        return desc

    def declared_input_ranges(self) -> dict[str, list[float]]:
        """The file attributes ``input_min`` and ``input_max`` (:meth:`input_ranges`, infinite where none is declared),
        or none where no input declares a finite bound.

        The fit carries them into the ROM's provenance and the exported ROM FMU declares them (and refuses values
        outside), so that a master learns the range the ROM was trained in and the source accepts (audit 58,
        finding 6: the source's ``F`` took ``[-20, 20]`` only, the ROM FMU's ``F`` declared no range).
        """
        if not self.m:
            return {}
        low, high = (np.asarray(bound, dtype=float) for bound in self.input_ranges())
        if not (np.isfinite(low).any() or np.isfinite(high).any()):
            return {}
        return {"input_min": [float(v) for v in low], "input_max": [float(v) for v in high]}

    def declared_input_nominals(self) -> dict[str, list[float]]:
        """The file attribute ``input_nominal``: each input's declared ``nominal`` (:meth:`input_nominals`), 0 where
        none is declared; none where no input declares one.

        The fit carries it into the ROM's provenance and the exported ROM FMU declares it, so that the ROM FMU's
        inputs are sized like the source's (audit 75, F7: the ROM FMU was pulsed at 100, the source at its declared
        1000).  0 stands for "none" (a nominal is above 0), so the attribute stays a list of plain numbers.
        """
        if not self.m:
            return {}
        nominals = np.asarray(self.input_nominals(), dtype=float)
        if nominals.shape != (self.m,):
            return {}
        declared = np.isfinite(nominals) & (nominals > 0)
        if not declared.any():
            return {}
        return {"input_nominal": [float(v) if ok else 0.0 for v, ok in zip(nominals, declared)]}

    def input_starts(self) -> np.ndarray:
        """Values the inputs hold when not driven (``--input none``): zeros unless the source knows better."""
        return np.zeros(self.m)

    def input_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds the inputs may take (an FMU's declared ``min`` / ``max``), infinite where none
        is known."""
        return np.full(self.m, -np.inf), np.full(self.m, np.inf)

    def input_nominals(self) -> np.ndarray:
        """The inputs' declared magnitudes (an FMU's ``nominal``), NaN where none is known: the default training
        pulse is sized by them (:func:`fmu_opinf.snapshots._inputs.default_amplitudes`)."""
        return np.full(self.m, np.nan)

    def provenance(self) -> dict[str, Any]:
        """Where the data come from (source kind, path, checksums, ...)."""
        raise NotImplementedError

    def events_seen(self) -> EventCount | None:
        """Events the model had since :meth:`start` (:class:`EventCount`), or None where the source cannot see
        them (a co-simulation FMU handles its events inside ``doStep``)."""
        return None

    def run_report(self) -> dict[str, Any]:
        """Provenance of the last run that only the run could tell (a picklable dict of file attributes, e.g. the
        integrator a model-exchange run chose); empty by default."""
        return {}

    def pilot_accuracy(self) -> contextlib.AbstractContextManager[None]:
        """Within this context the source runs the automatic window's pilot runs, which only look for the
        response's frequencies and fade time: a source may trade accuracy for speed there (model exchange loosens
        its tolerance, :meth:`~._model_exchange.ModelExchangeSource.pilot_accuracy`).  Unchanged by default."""
        return contextlib.nullcontext()

    def checked_accuracy(self, tolerance: float) -> contextlib.AbstractContextManager[None]:
        """Within this context the source runs at the relative ``tolerance`` where it was asked for less: the
        default training's amplitude check (:mod:`fmu_opinf.snapshots._linearity`) must see the model, not the
        integration error of a run at a loose tolerance.  Unchanged by default (a source with exact steps)."""
        return contextlib.nullcontext()

    def recipe(self) -> tuple[type, dict[str, Any]]:
        """Class and keywords that rebuild this source in another process."""
        raise NotImplementedError

    # -- stepping ---------------------------------------------------------------------------
    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        """Load the model and bring it to ``t[0]`` with input ``U[0]`` (consistent acceleration).

        Parameters
        ----------
        t : (k,) ndarray
            Time grid of the run.
        U : (k, m) ndarray
            Inputs in effect, time-major (``U[i]`` produced the state at ``t[i]``).
        """
        raise NotImplementedError

    def read(self, out: np.ndarray) -> None:
        """Write the current sample ``[x, xdot, xddot, y]`` into ``out`` (width,)."""
        raise NotImplementedError

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        """Hold input ``u`` (m,) and advance from ``t`` to ``t + h``."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the model; safe to call twice."""

    def advance(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None = None,
                offset: int = 0) -> None:
        """Fill ``rows[:count]`` with the samples ``i0 .. i0+count-1`` of the planned run.

        Parameters
        ----------
        rows : (c, width) ndarray
            C-contiguous float64 buffer, one sample per row, ``c >= count``.
        i0 : int
            Index of the first sample; sample 0 is the start state.
        count : int
            Number of samples to produce.
        published : (1,) int64 ndarray, optional
            Set to ``offset + j + 1`` as soon as row ``j`` is complete (crash-safe recording: a
            process watching shared memory knows every finished sample even if this one dies).
        offset : int, default=0
        """
        t, U = self._t, self._U
        for j in range(count):
            i = i0 + j
            if i:
                self.step(float(t[i - 1]), float(t[i] - t[i - 1]), U[i])
            self.read(rows[j])
            if published is not None:
                published[0] = offset + j + 1

    def _plan(self, t: np.ndarray, U: np.ndarray) -> None:
        """Check and keep the run plan (shared by subclasses' :meth:`start`)."""
        t = np.ascontiguousarray(t, dtype=float)
        U = np.ascontiguousarray(U, dtype=float).reshape(len(t), -1) if self.m else np.zeros((len(t), 0))
        if U.shape != (len(t), self.m):
            raise DimensionError(f"input has {U.shape[1]} channels but the source has m={self.m} inputs "
                                 f"({', '.join(self.input_names)}); give a signal with {self.m} channels")
        self._t, self._U = t, U

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __reduce__(self) -> tuple[Any, ...]:
        cls, kwargs = self.recipe()
        handover = self._handover()
        return (_rebuild, (cls, kwargs, self._shared_state()) + ((handover,) if handover is not None else ()))

    def _handover(self) -> Any:
        """What construction found, for a copy in another process to take instead of constructing again (None:
        the copy is built from :meth:`recipe`); see :meth:`_from_handover`."""
        return None

    @classmethod
    def _from_handover(cls, handover: Any) -> "Source | None":
        """The copy :meth:`_handover` describes, or None where it no longer applies (the copy is then built from
        :meth:`recipe`)."""
        return None

    def _shared_state(self) -> dict[str, Any]:
        """Resources a copy in another process may borrow (not own), e.g. an unpacked FMU."""
        return {}

    def _borrow(self, state: dict[str, Any]) -> None:
        """Take over :meth:`_shared_state` of the original."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, m={self.m}, p={self.p}, constraint={self.constraint!r})"


def _rebuild(cls: type, kwargs: dict[str, Any], state: dict[str, Any] | None = None,
             handover: Any = None) -> "Source":
    source = cls._from_handover(handover) if handover is not None else None
    if source is None:
        source = cls(**kwargs)
    source._borrow(state or {})
    return source


def check_constraint(constraint: str | None, default: str) -> str:
    value = default if constraint is None else str(constraint).lower()
    if value not in CONSTRAINTS:
        raise InputSpecError(f"constraint {constraint!r} is not one of {', '.join(CONSTRAINTS)}")
    return value


def inputs_without(inputs: list[str], excluded: list[str]) -> str:
    """The ``--inputs`` option (and keyword) that drives ``inputs`` but ``excluded`` (``--input none`` when none is
    left)."""
    from .._validate import either

    rest = [name for name in inputs if name not in excluded]
    return either("--inputs", value=",".join(rest)) if rest else either("--input", value="none")


def nice_floor(value: float) -> float:
    """Largest 1, 2 or 5 times a power of ten not above ``value``: a step to suggest or choose."""
    exponent = math.floor(math.log10(value))
    for mantissa in (5.0, 2.0, 1.0):
        candidate = mantissa * 10.0 ** exponent
        if candidate <= value * (1 + 1e-12):
            return float(f"{candidate:.12g}")
    return float(f"{10.0 ** exponent:.12g}")
