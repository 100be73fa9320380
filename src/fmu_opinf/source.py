"""Where snapshot data come from: the reference simulator or a co-simulation FMU, stepped one step at a time.

Both sources describe themselves the same way (sizes ``n, m, p``, variable names, constraint kind,
provenance) and share one stepping interface, so the recorder in :mod:`fmu_opinf.snapshots` does not
care which one it drives:

``start(t, U)``
    Prepare a run on the time grid ``t`` (k,) with the inputs in effect ``U`` (k, m), time-major:
    ``U[i]`` is the input that produced the state at ``t[i]`` (design.md: ``U[0] = u(t_0)``,
    ``U[i] = u(t_{i-1})``).  The state at ``t[0]`` is consistent with ``U[0]``.
``advance(rows, i0, count)``
    Fill ``rows[j]`` (one sample per row, layout ``[x, xdot, xddot, y]``, see :attr:`Source.layout`)
    with the samples ``i0 + j``, stepping the model from ``t[i-1]`` to ``t[i]`` with ``U[i]`` held.
``read(out)`` / ``step(t, h, u)``
    The same one sample / one step at a time.
``close()``
    Release the model.

A failing step raises :class:`StepError` carrying the sample index and time; samples before it are
already in ``rows``.
"""

from __future__ import annotations

import ctypes
import os
import re
import shutil
import weakref
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .errors import DimensionError, FMUError, InputSpecError

__all__ = [
    "Source",
    "BuiltinSource",
    "FMUSource",
    "StepError",
    "open_source",
    "match_names",
    "natural_key",
    "BUILTIN_SYSTEMS",
]

#: Names accepted by :class:`BuiltinSource` (and ``builtin:NAME`` in :func:`open_source`).
BUILTIN_SYSTEMS = ("anchored-msd", "triple-chain")

_CONSTRAINTS = ("position", "velocity", "none", "unknown")


class StepError(FMUError):
    """A step failed or produced non-finite values; ``step`` and ``time`` say where."""

    def __init__(self, message: str, step: int, time: float) -> None:
        super().__init__(message)
        self.step = int(step)
        self.time = float(time)


# ---------------------------------------------------------------------------------------------
# Names and patterns
# ---------------------------------------------------------------------------------------------


def natural_key(name: str) -> list[Any]:
    """Sort key ordering embedded numbers numerically (``x[2]`` before ``x[10]``)."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _pattern_regex(pattern: str) -> re.Pattern[str]:
    """Translate a name pattern: ``*`` any text, ``?`` one character, everything else literal.

    Unlike :func:`fnmatch.fnmatch`, brackets are literal, so ``x[*]`` means "x[ anything ]".
    """
    body = "".join(".*" if c == "*" else "." if c == "?" else re.escape(c) for c in pattern)
    return re.compile(body + r"\Z")


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
        patterns = [p for p in patterns.split(",")]
    found: list[str] = []
    seen: set[str] = set()
    for pattern in (p.strip() for p in patterns):
        if not pattern:
            continue
        regex = _pattern_regex(pattern)
        for name in sorted((n for n in names if regex.match(n)), key=natural_key):
            if name not in seen:
                seen.add(name)
                found.append(name)
    return found


# ---------------------------------------------------------------------------------------------
# Common base
# ---------------------------------------------------------------------------------------------


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
        desc.update(self.provenance())
        return desc

    def provenance(self) -> dict[str, Any]:
        """Where the data come from (source kind, path, checksums, ...)."""
        raise NotImplementedError

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
        return (_rebuild, (cls, kwargs, self._shared_state()))

    def _shared_state(self) -> dict[str, Any]:
        """Resources a copy in another process may borrow (not own), e.g. an unpacked FMU."""
        return {}

    def _borrow(self, state: dict[str, Any]) -> None:
        """Take over :meth:`_shared_state` of the original."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, m={self.m}, p={self.p}, constraint={self.constraint!r})"


def _rebuild(cls: type, kwargs: dict[str, Any], state: dict[str, Any] | None = None) -> "Source":
    source = cls(**kwargs)
    source._borrow(state or {})
    return source


def _check_constraint(constraint: str | None, default: str) -> str:
    value = default if constraint is None else str(constraint).lower()
    if value not in _CONSTRAINTS:
        raise InputSpecError(f"constraint {constraint!r} is not one of {', '.join(_CONSTRAINTS)}")
    return value


# ---------------------------------------------------------------------------------------------
# Reference simulator
# ---------------------------------------------------------------------------------------------


class BuiltinSource(Source):
    """The reference Python simulator (:mod:`fmu_opinf.newmark`) on a benchmark system.

    Parameters
    ----------
    name : {"anchored-msd", "triple-chain"}
        Benchmark system (spec sections 1-2).
    **size_options
        Passed to the system factory: ``g`` for ``anchored-msd``; ``n1, alpha, beta, v`` for
        ``triple-chain``.
    """

    kind = "builtin"

    def __init__(self, name: str, **size_options: Any) -> None:
        from . import systems

        if name not in BUILTIN_SYSTEMS:
            raise InputSpecError(f"unknown builtin system {name!r}; choose one of {', '.join(BUILTIN_SYSTEMS)}")
        try:
            self.system = systems.builtin_system(name, **size_options)
        except TypeError as exc:
            raise InputSpecError(f"bad option for builtin:{name}: {exc}") from None
        self.name = name
        self.options = dict(size_options)
        sysm = self.system
        n, m, p = sysm.n, sysm.m, sysm.p
        self.position_names = [f"x[{i}]" for i in range(1, n + 1)]
        self.velocity_names = [f"v[{i}]" for i in range(1, n + 1)]
        self.acceleration_names = [f"a[{i}]" for i in range(1, n + 1)]
        self.input_names = ["u"] if m == 1 else [f"u[{j}]" for j in range(1, m + 1)]
        self.output_names = [f"y[{j}]" for j in range(1, p + 1)]
        self.constraint = sysm.constraint if sysm.constraint else "none"
        self._stepper: Any = None

    def provenance(self) -> dict[str, Any]:
        return {
            "source_kind": "builtin",
            "source": f"builtin:{self.name}",
            "model_name": getattr(self.system, "name", self.name),
            "system_options": dict(self.options),
        }

    def recipe(self) -> tuple[type, dict[str, Any]]:
        return BuiltinSource, {"name": self.name, **self.options}

    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        from .newmark import NewmarkStepper

        self._plan(t, U)
        steps = np.diff(self._t)
        h = float(steps[0])
        if not np.allclose(steps, h, rtol=1e-9, atol=0.0):
            raise InputSpecError("the builtin source needs a uniform time grid")
        sysm = self.system
        self._stepper = NewmarkStepper(sysm.M, sysm.D, sysm.K, sysm.B, h, G=sysm.G, constraint=sysm.constraint)
        self._stepper.start(self._U[0], t0=float(self._t[0]))

    def read(self, out: np.ndarray) -> None:
        st, n, p = self._stepper, self.n, self.p
        out[:n] = st.x
        out[n:2 * n] = st.v
        out[2 * n:3 * n] = st.a
        out[3 * n:3 * n + p] = self.system.output(st.x, st.v)

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        if abs(h - self._stepper.h) > 1e-12 * abs(h):
            self._stepper.set_step(h)
        self._stepper.step(u)

    def close(self) -> None:
        self._stepper = None


# ---------------------------------------------------------------------------------------------
# FMU
# ---------------------------------------------------------------------------------------------

_REAL_TYPES = ("Real", "Float64")


def _read_description(path: Path) -> Any:
    """Parse the model description, turning every failure into a one-line :class:`FMUError`."""
    from fmpy import read_model_description

    if not path.exists():
        raise FMUError(f"fmu {path} does not exist; check the path")
    if path.is_dir():
        if not (path / "modelDescription.xml").is_file():
            raise FMUError(f"{path} is a directory without modelDescription.xml; give an .fmu file")
    elif not zipfile.is_zipfile(path):
        raise FMUError(f"{path} is not an fmu (not a zip archive); give a co-simulation .fmu file")
    else:
        with zipfile.ZipFile(path) as zf:
            if "modelDescription.xml" not in zf.namelist():
                raise FMUError(f"{path} is not an fmu (no modelDescription.xml inside)")
    try:
        return read_model_description(str(path), validate=False)
    except Exception as exc:  # fmpy raises plain Exception / lxml errors
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FMUError(f"{path}: cannot read modelDescription.xml ({first})") from None


def _annotated_constraint(path: Path) -> str | None:
    """Constraint kind declared by the exporter, if any.

    Read from ``<VendorAnnotations><Tool name="fmu-opinf"><... constraint="position|velocity|none"/>``;
    FMUs from other tools do not say, so the kind is then "unknown" unless the user gives it.
    """
    import xml.etree.ElementTree as ET

    try:
        if path.is_dir():
            root = ET.parse(path / "modelDescription.xml").getroot()
        else:
            with zipfile.ZipFile(path) as zf:
                root = ET.fromstring(zf.read("modelDescription.xml"))
    except (OSError, KeyError, ET.ParseError, zipfile.BadZipFile):
        return None
    for tool in root.iter("Tool"):
        if tool.get("name") == "fmu-opinf":
            for element in tool.iter():
                kind = element.get("constraint")
                if kind in _CONSTRAINTS:
                    return kind
    return None


def _binary_platform(fmi_version: str) -> str:
    import fmpy

    return fmpy.platform if fmi_version.startswith("2") else fmpy.platform_tuple


class _VariableSelection:
    """Resolve positions/velocities/accelerations/inputs/outputs of a model description."""

    def __init__(self, md: Any, path: Path) -> None:
        self.path = path
        self.reals = {v.name: v for v in md.modelVariables if v.type in _REAL_TYPES}
        self.names = list(self.reals)
        # derivative links: state name -> its derivative variable
        self.der = {v.derivative.name: v for v in md.modelVariables if getattr(v, "derivative", None) is not None}

    def pattern(self, what: str, patterns: str | Sequence[str], required: bool) -> list[str]:
        names = match_names(patterns, self.names)
        if not names and required:
            examples = ", ".join(sorted(self.names, key=natural_key)[:6]) or "none"
            raise FMUError(f"{what} pattern {_show(patterns)} matches no real variable of {self.path.name} "
                           f"(variables: {examples}, ...); pass --{what} with a matching pattern")
        return names

    def derivatives_of(self, names: list[str]) -> list[str]:
        """Derivative names of ``names`` if every one of them is a state, else []."""
        if names and all(n in self.der for n in names):
            return [self.der[n].name for n in names]
        return []

    def structural_positions(self) -> list[str]:
        """States whose derivative is itself a state (Modelica: q with der(q) = qd, qd a state)."""
        return sorted((s for s, d in self.der.items() if d.name in self.der), key=natural_key)


def _show(patterns: str | Sequence[str]) -> str:
    return repr(patterns if isinstance(patterns, str) else ",".join(patterns))


class FMUSource(Source):
    """A co-simulation FMU (FMI 2.0 or 3.0) driven step by step through its C functions.

    The model description is read and the variables resolved at construction; the binary is
    loaded only by :meth:`start`.  Per step the recorder makes three raw C calls (set inputs,
    do step, get all recorded values into one pre-allocated row).

    Parameters
    ----------
    path : str or path-like
        The ``.fmu`` file (or an extracted FMU directory).
    positions : str, optional
        Name patterns of the positions (``*`` wildcard, comma lists, brackets literal).  Default:
        ``x[*]`` if it matches, else the states whose derivative is a state (Modelica-style
        ``der(...)`` links of the model structure).  An empty string reads no states at all
        (inputs and outputs only, as :func:`fmu_opinf.compare.compare` does).
    velocities, accelerations : str, optional
        Name patterns; default: the derivatives of the positions (velocities) if the model
        structure links them, else ``v[*]`` / ``a[*]``, else derived from the data.
    inputs, outputs : str, optional
        Name patterns; default: all real variables with causality input / output.
    constraint : {"position", "velocity", "none", "unknown"}, default="unknown"
        Constraint kind, stored for the later stages (an FMU does not say).
    parameters : dict of str to float, optional
        Start values set before initialization (real or integer variables).
    """

    kind = "fmu"

    def __init__(
        self,
        path: str | os.PathLike,
        positions: str | None = None,
        velocities: str | None = None,
        accelerations: str | None = None,
        inputs: str | None = None,
        outputs: str | None = None,
        constraint: str | None = None,
        parameters: dict[str, float] | None = None,
    ) -> None:
        self.path = Path(path)
        self._options = {
            "positions": positions,
            "velocities": velocities,
            "accelerations": accelerations,
            "inputs": inputs,
            "outputs": outputs,
            "constraint": constraint,
            "parameters": dict(parameters) if parameters else None,
        }
        md = _read_description(self.path)
        self.constraint = _check_constraint(constraint, _annotated_constraint(self.path) or "unknown")
        self._check_interface(md)
        self.md = md
        self.fmi_version = str(md.fmiVersion)
        self.model_identifier = md.coSimulation.modelIdentifier
        self._resolve(md, positions, velocities, accelerations, inputs, outputs)
        self._parameters = self._resolve_parameters(md, parameters or {})
        self._fmu: Any = None
        self._unzipdir: str | None = None
        self._sha256: str | None = None

    # -- description ------------------------------------------------------------------------
    def _check_interface(self, md: Any) -> None:
        version = str(md.fmiVersion)
        if not (version.startswith("2") or version.startswith("3")):
            raise FMUError(f"{self.path.name} is an FMI {version} fmu; fmu-opinf supports FMI 2.0 and 3.0")
        if md.coSimulation is None:
            raise FMUError(f"{self.path.name} is a model-exchange-only fmu; fmu-opinf needs co-simulation "
                           "(export the model with co-simulation enabled)")
        plat = _binary_platform(version)
        binary = f"binaries/{plat}/{md.coSimulation.modelIdentifier}"
        if self.path.is_dir():
            files = [str(p.relative_to(self.path)).replace(os.sep, "/") for p in self.path.rglob("*")]
        else:
            with zipfile.ZipFile(self.path) as zf:
                files = zf.namelist()
        if not any(f.startswith(binary + ".") for f in files):
            have = sorted({f.split("/")[1] for f in files if f.startswith("binaries/") and f.count("/") >= 2})
            raise FMUError(f"{self.path.name} has no binary for this platform ({plat}; it has: "
                           f"{', '.join(have) or 'none'}); export or compile it for {plat}")

    def _resolve(self, md: Any, positions: str | None, velocities: str | None, accelerations: str | None,
                 inputs: str | None, outputs: str | None) -> None:
        sel = _VariableSelection(md, self.path)
        if positions == "":  # outputs only (validation runs): no states are read
            pos, vel, acc = [], [], []
        elif positions is not None:
            pos = sel.pattern("positions", positions, required=True)
        else:
            pos = sel.pattern("positions", "x[*]", required=False) or sel.structural_positions()
            if not pos:
                raise FMUError(f"{self.path.name} has no x[*] variables and no second-order states; "
                               "pass --positions with the position variables' names")
        if pos:
            vel = self._second(sel, "velocities", velocities, pos, "v[*]")
            acc = self._second(sel, "accelerations", accelerations, vel, "a[*]") if (vel or accelerations) else []
            if not vel and accelerations is None:
                acc = []
        for what, names in (("velocities", vel), ("accelerations", acc)):
            if names and len(names) != len(pos):
                raise FMUError(f"{len(pos)} positions but {len(names)} {what} in {self.path.name}; "
                               f"give --positions/--{what} patterns that match the same number of variables")
        if acc and not vel:
            raise FMUError("accelerations without velocities are not supported; pass --velocities too")
        self.position_names, self.velocity_names, self.acceleration_names = pos, vel, acc
        if inputs is None:
            self.input_names = sorted((v.name for v in md.modelVariables
                                       if v.causality == "input" and v.type in _REAL_TYPES), key=natural_key)
        else:
            self.input_names = self._inputs(sel, md, inputs)
        if outputs is None:
            self.output_names = sorted((v.name for v in md.modelVariables
                                        if v.causality == "output" and v.type in _REAL_TYPES), key=natural_key)
        else:
            self.output_names = sel.pattern("outputs", outputs, required=True)
        refs = {v.name: v.valueReference for v in md.modelVariables}
        self._in_vrs = [refs[n] for n in self.input_names]
        self._out_vrs = [refs[n] for n in pos + vel + acc + self.output_names]

    @staticmethod
    def _second(sel: _VariableSelection, what: str, patterns: str | None, base: list[str], default: str) -> list[str]:
        if patterns is not None:
            return sel.pattern(what, patterns, required=True)
        return sel.derivatives_of(base) or sel.pattern(what, default, required=False)

    def _inputs(self, sel: _VariableSelection, md: Any, patterns: str) -> list[str]:
        names = match_names(patterns, sel.names)
        if not names:
            available = [v.name for v in md.modelVariables if v.causality == "input"]
            raise FMUError(f"input {_show(patterns)} is not a real variable of {self.path.name} "
                           f"(its inputs: {', '.join(available) or 'none'}); pass --inputs with an input name")
        causal = {v.name: v.causality for v in md.modelVariables}
        bad = [n for n in names if causal[n] != "input"]
        if bad:
            raise FMUError(f"{bad[0]} has causality {causal[bad[0]]!r} in {self.path.name}, not 'input'; "
                           "pass --inputs with input variables")
        return names

    def _resolve_parameters(self, md: Any, parameters: dict[str, float]) -> list[tuple[Any, float]]:
        variables = {v.name: v for v in md.modelVariables}
        out = []
        for name, value in parameters.items():
            if name not in variables:
                raise FMUError(f"parameter {name!r} is not a variable of {self.path.name}")
            out.append((variables[name], value))
        return out

    def provenance(self) -> dict[str, Any]:
        from ._hdf5 import sha256_of

        if self._sha256 is None:
            self._sha256 = sha256_of(self.path) if self.path.is_file() else ""
        return {
            "source_kind": "fmu",
            "source": str(self.path.resolve()),
            "model_name": self.md.modelName,
            "fmu_name": self.path.name,
            "fmu_guid": self.md.guid,
            "fmu_sha256": self._sha256,
            "fmi_version": self.fmi_version,
            "fmu_generation_tool": self.md.generationTool or "",
            "fmu_parameters": {v.name: value for v, value in self._parameters},
        }

    def recipe(self) -> tuple[type, dict[str, Any]]:
        return FMUSource, {"path": str(self.path), **self._options}

    # -- loading ----------------------------------------------------------------------------
    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        self._plan(t, U)
        self.close()
        self._open_binary()
        try:
            self._initialize()
        except BaseException:
            self.close()
            raise

    def _open_binary(self) -> None:
        cls, kwargs = self._fmpy_class()
        cwd = os.getcwd()
        try:
            self._fmu = cls(guid=self.md.guid, unzipDirectory=self._extracted(),
                            modelIdentifier=self.model_identifier, instanceName="fmu_opinf")
        except Exception as exc:
            raise FMUError(f"cannot load the binary of {self.path.name}: {str(exc).splitlines()[0]}") from None
        finally:
            # fmpy changes into the binary's folder to load it and stays there when loading fails; that
            # folder is deleted with the extraction, which would leave the process without a working directory
            os.chdir(cwd)
        self._log: list[str] = []
        self._bind_raw_functions()
        try:
            self._instantiate(**kwargs)
        except Exception as exc:
            self._fmu = None
            raise FMUError(f"{self.path.name} failed to instantiate ({self._last_log() or exc})") from None

    def _shared_state(self) -> dict[str, Any]:
        # unpack here, so that a copy in a child process neither unpacks again nor leaves a
        # temporary folder behind when its binary crashes
        return {"unzipdir": self._extracted()}

    def _borrow(self, state: dict[str, Any]) -> None:
        unzipdir = state.get("unzipdir")
        if unzipdir and Path(unzipdir).is_dir() and self._unzipdir is None and not self.path.is_dir():
            self._unzipdir = unzipdir  # owned (and removed) by the original

    def _extracted(self) -> str:
        """The unpacked FMU, extracted once per source object and removed with it."""
        if self.path.is_dir():
            return str(self.path)
        if self._unzipdir is None:
            from fmpy import extract

            self._unzipdir = str(extract(str(self.path)))
            weakref.finalize(self, shutil.rmtree, self._unzipdir, True)
        return self._unzipdir

    def _fmpy_class(self) -> tuple[type, dict[str, Any]]:
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import FMU2Slave

            return FMU2Slave, {}
        from fmpy.fmi3 import FMU3Slave

        return FMU3Slave, {}

    def _bind_raw_functions(self) -> None:
        """Own prototypes of the per-step C functions taking raw addresses (no marshalling)."""
        dll = self._fmu.dll
        vp, sz = ctypes.c_void_p, ctypes.c_size_t
        if self.fmi_version.startswith("2"):
            names = ("fmi2SetReal", "fmi2GetReal", "fmi2DoStep")
            protos = ([vp, vp, sz, vp], [vp, vp, sz, vp], [vp, ctypes.c_double, ctypes.c_double, ctypes.c_int])
        else:
            names = ("fmi3SetFloat64", "fmi3GetFloat64", "fmi3DoStep")
            protos = ([vp, vp, sz, vp, sz], [vp, vp, sz, vp, sz],
                      [vp, ctypes.c_double, ctypes.c_double, ctypes.c_bool, vp, vp, vp, vp])
        funcs = []
        for name, argtypes in zip(names, protos):
            f = dll[name]  # a fresh function object: fmpy's cached one keeps its own prototype
            f.argtypes, f.restype = argtypes, ctypes.c_int
            funcs.append(f)
        self._c_set, self._c_get, self._c_step = funcs
        self._in_vr_arr = np.array(self._in_vrs, dtype=np.uint32)
        self._out_vr_arr = np.array(self._out_vrs, dtype=np.uint32)
        self._flags = np.zeros(4, dtype=np.float64)  # fmi3DoStep out-arguments (3 booleans + 1 double)

    def _logger(self, *args: Any) -> None:
        status, message = args[-3] if len(args) == 5 else args[1], args[-1]
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        if status >= 2:
            self._log = (self._log + [text.strip()])[-5:]

    def _last_log(self) -> str:
        return self._log[-1] if getattr(self, "_log", None) else ""

    def _instantiate(self) -> None:
        fmu = self._fmu
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, defaultCallbacks
            from fmpy.logging import addLoggerProxy

            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(
                lambda env, name, status, category, message: self._logger(env, name, status, category, message))
            cb.allocateMemory = defaultCallbacks.allocateMemory
            cb.freeMemory = defaultCallbacks.freeMemory
            addLoggerProxy(ctypes.byref(cb))
            self._callbacks = cb
            fmu.instantiate(callbacks=cb)
        else:
            fmu.instantiate(logMessage=lambda env, status, cat, msg: self._logger(env, status, msg))
        self._comp = fmu.component if isinstance(fmu.component, int) else fmu.component.value

    def _initialize(self) -> None:
        fmu, t0 = self._fmu, float(self._t[0])
        t_stop = float(self._t[-1])
        try:
            if self.fmi_version.startswith("2"):
                fmu.setupExperiment(startTime=t0, stopTime=t_stop)
                self._set_parameters()
                fmu.enterInitializationMode()
                self._set_inputs(0)
                fmu.exitInitializationMode()
            else:
                self._set_parameters()
                fmu.enterInitializationMode(startTime=t0, stopTime=t_stop)
                self._set_inputs(0)
                fmu.exitInitializationMode()
        except StepError:
            raise
        except Exception as exc:
            raise StepError(f"{self.path.name} failed to initialize at t={t0:g} ({self._last_log() or exc})",
                            0, t0) from None
        self._set_inputs(0)

    def _set_parameters(self) -> None:
        for var, value in self._parameters:
            if var.type in _REAL_TYPES:
                (self._fmu.setReal if self.fmi_version.startswith("2") else self._fmu.setFloat64)(
                    [var.valueReference], [float(value)])
            elif self.fmi_version.startswith("2"):
                self._fmu.setInteger([var.valueReference], [int(value)])
            else:
                setter = getattr(self._fmu, "set" + var.type)
                setter([var.valueReference], [int(value)])

    def _set_inputs(self, i: int) -> None:
        if not self.m:
            return
        row = self._U[i]
        status = self._call_set(row.ctypes.data)
        if status > 1:
            raise StepError(self._fail_text("setting the input", i), i, float(self._t[i]))

    def _call_set(self, address: int) -> int:
        vr = self._in_vr_arr.ctypes.data
        if self.fmi_version.startswith("2"):
            return self._c_set(self._comp, vr, self.m, address)
        return self._c_set(self._comp, vr, self.m, address, self.m)

    def _fail_text(self, what: str, i: int) -> str:
        t = self._t
        when = f"t={t[i - 1]:g} -> {t[i]:g}" if i else f"t={t[0]:g}"
        log = self._last_log()
        return f"{self.path.name} returned an error {what} at step {i} ({when})" + (f": {log}" if log else "")

    # -- stepping ---------------------------------------------------------------------------
    def read(self, out: np.ndarray) -> None:
        if out.dtype != np.float64 or not out.flags.c_contiguous or out.size < len(self._out_vrs):
            raise DimensionError(f"read needs a contiguous float64 buffer of {len(self._out_vrs)} values")
        if self._get(out.ctypes.data) > 1:
            raise StepError(f"{self.path.name} returned an error reading values", -1, float("nan"))

    def _get(self, address: int) -> int:
        vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        if self.fmi_version.startswith("2"):
            return self._c_get(self._comp, vr, nv, address)
        return self._c_get(self._comp, vr, nv, address, nv)

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        u = np.ascontiguousarray(u, dtype=float)
        if self.m and self._call_set(u.ctypes.data) > 1:
            raise StepError(f"{self.path.name} returned an error setting the input at t={t:g}", -1, t)
        if self._do_step(t, h) > 1:
            raise StepError(f"{self.path.name} returned an error in doStep at t={t:g}", -1, t)

    def _do_step(self, t: float, h: float) -> int:
        if self.fmi_version.startswith("2"):
            return self._c_step(self._comp, t, h, 1)
        f = self._flags.ctypes.data
        return self._c_step(self._comp, t, h, True, f, f + 1, f + 2, f + 8)

    def advance(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None = None,
                offset: int = 0) -> None:
        if rows.dtype != np.float64 or not rows.flags.c_contiguous or rows.shape[1] != len(self._out_vrs):
            raise DimensionError(f"advance needs a C-contiguous float64 (c, {len(self._out_vrs)}) buffer")
        loop = self._advance2 if self.fmi_version.startswith("2") else self._advance3
        loop(rows, i0, count, published, offset)

    def _advance2(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        in_vr, m = self._in_vr_arr.ctypes.data, self.m
        out_vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        rbase, rstride = rows.ctypes.data, rows.strides[0]
        ubase, ustride = self._U.ctypes.data, self._U.strides[0]
        t, h, changed = self._t_list, self._h_list, self._changed
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and c_set(comp, in_vr, m, ubase + i * ustride) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                if c_step(comp, t[i - 1], h[i], 1) > 1:
                    raise StepError(self._fail_text("in fmi2DoStep", i), i, t[i])
            if c_get(comp, out_vr, nv, rbase + j * rstride) > 1:
                raise StepError(self._fail_text("in fmi2GetReal", i), i, t[i])
            if published is not None:
                published[0] = offset + j + 1

    def _advance3(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        in_vr, m = self._in_vr_arr.ctypes.data, self.m
        out_vr, nv = self._out_vr_arr.ctypes.data, len(self._out_vrs)
        rbase, rstride = rows.ctypes.data, rows.strides[0]
        ubase, ustride = self._U.ctypes.data, self._U.strides[0]
        f = self._flags.ctypes.data
        t, h, changed = self._t_list, self._h_list, self._changed
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and c_set(comp, in_vr, m, ubase + i * ustride, m) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                if c_step(comp, t[i - 1], h[i], True, f, f + 1, f + 2, f + 8) > 1:
                    raise StepError(self._fail_text("in fmi3DoStep", i), i, t[i])
            if c_get(comp, out_vr, nv, rbase + j * rstride, nv) > 1:
                raise StepError(self._fail_text("in fmi3GetFloat64", i), i, t[i])
            if published is not None:
                published[0] = offset + j + 1

    def _plan(self, t: np.ndarray, U: np.ndarray) -> None:
        super()._plan(t, U)
        self._t_list = self._t.tolist()
        self._h_list = [0.0] + np.diff(self._t).tolist()
        # inputs keep their values between steps: set them only when they change
        changed = np.ones(len(self._t), dtype=bool)
        if self.m:
            changed[1:] = np.any(self._U[1:] != self._U[:-1], axis=1)
        else:
            changed[:] = False
        self._changed = changed.tolist()

    def close(self) -> None:
        fmu, self._fmu = self._fmu, None
        if fmu is not None:
            try:
                fmu.terminate()
            except Exception:  # an FMU in error state may refuse; freeing is what matters
                pass
            try:
                fmu.freeInstance()
            except Exception:
                pass


# ---------------------------------------------------------------------------------------------
# Specification strings
# ---------------------------------------------------------------------------------------------


def open_source(spec: str | os.PathLike | Source, **options: Any) -> Source:
    """Build a source from ``"builtin:anchored-msd"``, ``"builtin:triple-chain"`` or an FMU path.

    Parameters
    ----------
    spec : str, path-like or Source
        ``builtin:NAME`` (options: the system's size options) or the path of an ``.fmu``
        (options: :class:`FMUSource` keywords).  A :class:`Source` is returned as is.
    **options
        Keywords for the source; ``None`` values are ignored.

    Returns
    -------
    Source
    """
    if isinstance(spec, Source):
        return spec
    options = {k: v for k, v in options.items() if v is not None}
    text = os.fspath(spec)
    if text.startswith("builtin:"):
        name = text.split(":", 1)[1]
        for key in _FMU_OPTIONS:
            if key in options:
                raise InputSpecError(f"--{key} applies to fmu sources, not to {text}")
        return BuiltinSource(name, **options)
    unknown = sorted(set(options) - set(_FMU_OPTIONS))
    if unknown:
        raise InputSpecError(f"--{unknown[0]} applies to builtin sources, not to the fmu {text}")
    return FMUSource(text, **options)


_FMU_OPTIONS = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "parameters")
