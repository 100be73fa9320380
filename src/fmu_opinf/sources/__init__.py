"""Where snapshot data come from: the reference simulator or a co-simulation FMU, stepped one step at a time.

Modules: :mod:`._base` (the interface), :mod:`._builtin` (reference simulator), :mod:`._variables`
(model description and variable discovery), :mod:`._settings` (``--set`` values), :mod:`._resolve`
(what an FMU records, from its description alone), :mod:`._cosimulation` (co-simulation FMUs),
:mod:`._model_exchange` (model-exchange FMUs, integrated by fmu-opinf under the same stepping
interface) with its integrators in :mod:`._integrators` (the exact hold step of :mod:`._linear_hold`, DOP853's
compiled step loop of :mod:`._compiled_rk`, scipy's methods).

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

import os
from pathlib import Path
from typing import Any

from .._validate import ME, check_keywords, either, patterns_said
from ..errors import InputSpecError
from ._base import EventCount, Source, StepError, inputs_without, match_names, natural_key
from ._base import few_names as _few_names
from ._builtin import BUILTIN_SYSTEMS, BuiltinSource
from ._cosimulation import (DEFAULT_TOLERANCE, TERMINATED, FMUSource, declared_stop_at, fixed_communication_step,
                            offers_model_exchange, terminated_at, warn_other_communication_step)
from ._model_exchange import METHODS, ModelExchangeSource
from ._resolve import Resolved, resolve_variables
from ._settings import parse_assignments
from ._variables import element_names, fmi3_ports, warn_if_not_strict

__all__ = [
    "Source",
    "BuiltinSource",
    "FMUSource",
    "ModelExchangeSource",
    "StepError",
    "EventCount",
    "INTERFACES",
    "DEFAULT_TOLERANCE",
    "fixed_communication_step",
    "offers_model_exchange",
    "warn_other_communication_step",
    "TERMINATED",
    "terminated_at",
    "declared_stop_at",
    "METHODS",
    "choose_interface",
    "open_source",
    "at_start_time",
    "match_names",
    "natural_key",
    "BUILTIN_SYSTEMS",
    "parse_assignments",
    "resolve_variables",
    "Resolved",
    "element_names",
    "fmi3_ports",
]


#: Values of ``--interface``.
INTERFACES = ("auto", "me", "cs")


def choose_interface(path: str | os.PathLike, interface: str | None = "auto") -> str:
    """The FMI interface to drive: ``"me"`` or ``"cs"``.

    ``auto`` prefers model exchange when the FMU offers it (with a binary for this platform, or C sources and
    no binary for either interface, compiled here):
    fmu-opinf then integrates with its own tolerance, whereas several exporters' co-simulation is one
    explicit Euler step per communication step.  A co-simulation-only FMU is driven through
    co-simulation.

    Parameters
    ----------
    path : str or path-like
        The ``.fmu`` (or extracted directory).
    interface : {"auto", "me", "cs"}, default="auto"

    Returns
    -------
    str
    """
    from ._variables import binary_platform, read_description

    value = "auto" if interface is None else str(interface).lower()
    if value not in INTERFACES:
        raise InputSpecError(f"{either('--interface', value=interface)} is not one of {', '.join(INTERFACES)}")
    if value != "auto":
        return value
    from pathlib import Path

    md = read_description(Path(path))
    if md.modelExchange is None:
        return "cs"
    if md.coSimulation is None:
        return "me"
    platform = binary_platform(str(md.fmiVersion))
    if _has_file(path, f"binaries/{platform}/{md.modelExchange.modelIdentifier}."):
        return "me"
    # no binary for either interface, but sources: both are compiled here (sources._compile), so model exchange
    return "me" if not _has_file(path, f"binaries/{platform}/{md.coSimulation.modelIdentifier}.") \
        and _has_file(path, "sources/") else "cs"


def _has_file(path: str | os.PathLike, prefix: str) -> bool:
    import zipfile
    from pathlib import Path

    root = Path(path)
    if root.is_dir():
        return any(str(p.relative_to(root)).replace(os.sep, "/").startswith(prefix) for p in root.rglob("*"))
    with zipfile.ZipFile(root) as zf:
        return any(name.startswith(prefix) for name in zf.namelist())


def open_source(spec: str | os.PathLike | Source, **options: Any) -> Source:
    """Build a source from ``"builtin:anchored-msd"``, ``"builtin:triple-chain"`` or an FMU path.

    Parameters
    ----------
    spec : str, path-like or Source
        ``builtin:NAME`` (options: the system's size options) or the path of an ``.fmu``
        (options: :class:`FMUSource` keywords, ``interface`` (``"auto"``, ``"me"``, ``"cs"``, see
        :func:`choose_interface`) and, for model exchange, ``method``).  A :class:`Source` is
        returned as is.
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
        options.pop("interface", None)  # a builtin source is exact: no interface and no tolerance to choose
        options.pop("tolerance", None)
        for key in _FMU_OPTIONS + ("method",):
            if key in options:
                raise InputSpecError(f"{either('--' + _FLAG.get(key, key))} applies to fmu sources, not to {text}")
        return BuiltinSource(name=text.split(":", 1)[1], **options)
    sizes = sorted(set(options) & set(BUILTIN_SIZES))
    if sizes:
        raise InputSpecError(f"{either('--' + sizes[0])} applies to builtin sources, not to the fmu {text}")
    # (audit 81c F8: a misspelt keyword was said to apply to builtin sources)
    check_keywords(options, _FMU_OPTIONS + ("interface", "tolerance", "method"),
                   f"an fmu source ({os.path.basename(text)})", "keyword")
    interface = choose_interface(text, options.pop("interface", "auto"))
    if interface != "me" and "method" in options:
        raise InputSpecError(f"{either('--me-method', value=options['method'])} applies to model exchange, but "
                             f"{os.path.basename(text)} is driven through co-simulation; give {ME} (if it offers "
                             f"model exchange) or leave out {either('--me-method')}")
    source = ModelExchangeSource(text, **options) if interface == "me" else FMUSource(text, **options)
    warn_if_not_strict(Path(text))  # here, not in read_description: child processes rebuild sources silently
    if getattr(source, "compiled", None):
        warn_once(source, ("compiled",), source.compiled, stacklevel=3)
    _warn_parameter_like(source)
    _warn_unrecorded_states(source)
    _warn_outputs_left_out(source)
    _warn_held_outputs(source)
    return source


#: (FMU path, what about) of the warnings :func:`warn_once` said in this process
_REPORTED: set[tuple[str, tuple[Any, ...]]] = set()


def _warn_parameter_like(source: Source) -> None:
    """At most one warning each (per process and FMU: a run table opens the source per row) naming the inputs the
    default selection holds for their non-zero start values or a coefficient's unit (offering to drive only those
    whose unit is none or not known: one in N/m or kg is a parameter), and the inputs chosen to be driven although
    they look like parameters (a parameter exposed as an input, driven, records a model that changes with it; audit
    2026-11-27: ``--inputs F,stiffness_scale`` without a word, the ROM 120 % off)."""
    held = list(getattr(source, "parameter_like_input_names", []) or [])
    forces = list(getattr(source, "input_names", []) or [])
    driven = [name for name in getattr(source, "driven_parameter_like_names", []) or [] if name in forces]
    coefficients = set(getattr(source, "coefficient_input_names", []) or [])
    if coefficients & set(driven + held):
        _warn_coefficients(source, [name for name in driven + held if name in coefficients], forces,
                           [name for name in driven if name in coefficients])
        driven, held = ([name for name in names if name not in coefficients] for names in (driven, held))
    pressures = _driven_pressures(source, driven, forces)
    if pressures:
        shown = ", ".join(f"{name} ({unit}, start {start:g})" for name, unit, start in pressures)
        names = [name for name, _, _ in pressures]
        warn_once(source, ("pressures", tuple(names), tuple(forces)),
                  f"{shown} {'is' if len(names) == 1 else 'are'} driven as a pressure load about its start (the "
                  "default training pulses it by a tenth of the start, compare's default harmonic by at most half "
                  f"of it); hold it with {inputs_without(forces, names)} and give its value with {either('--set')} "
                  "if it is a parameter (a modulus)")
        driven = [name for name in driven if name not in names]
    if driven:
        warn_once(source, ("driven", tuple(driven), tuple(forces)),
                   f"the driven input(s) {', '.join(driven)} start at non-zero values (the default training pulses "
                   f"them on top of those, an input ({either('--input')}) sets them to its own values): if they are "
                   "parameters exposed "
                   "as inputs, the recording is of a model that changes with them; "
                   f"record with {inputs_without(forces, driven)} and give their values with {either('--set')}")
    if held:
        shown = _few_names(held)
        # (one in N/m, kg or 1 is a parameter: driving it is not offered)
        unknown = [name for name in getattr(source, "maybe_force_names", held) if name in held]
        drive = (f", or drive those that are forces with {either('--inputs', value=','.join(forces + unknown))}"
                 if unknown else "")
        warn_once(source, ("held", tuple(held), tuple(forces)),
                   f"input(s) {shown} start at non-zero values (parameters exposed as inputs?) and are held at them, "
                   f"not driven{'; force inputs: ' + ', '.join(forces) if forces else '; no force input is left'}; "
                   f"give their values with {either('--set')}{drive}")


def _driven_pressures(source: Source, driven: list[str], forces: list[str]) -> list[tuple[str, str, float]]:
    """``(name, unit, start)`` of the ``driven`` inputs in a pressure's unit that start away from 0: driven about
    that start as a load, though the unit cannot tell an ambient pressure from a modulus (audit 61, findings 2 and
    3); what the default training and test inputs do with them is sized by the start."""
    from ._variables import is_pressure_about_start

    units = list(getattr(source, "input_units", None) or [])
    starts = getattr(source, "input_starts", None)
    if not driven or len(units) != len(forces) or starts is None:
        return []
    values = list(starts())
    model = getattr(source, "model", None)
    return [(name, unit, float(start)) for name, unit, start in zip(forces, units, values)
            if name in driven and is_pressure_about_start(unit, start, model)]


def _warn_coefficients(source: Source, names: list[str], forces: list[str], driven: list[str]) -> None:
    """One warning (per process and FMU) naming the inputs in a coefficient's unit (a damping in N.s/m, a mass in
    kg): held at their start values, or driven as asked, which records a model that changes with them."""
    shown = _few_names(names)
    if driven:
        text = (f"the driven input(s) {', '.join(driven)} are in the unit of a stiffness, a damping or a mass "
                "(parameters exposed as inputs?): driven, they record a model that changes with them; record with "
                f"{inputs_without(forces, driven)} and give their values with {either('--set')}")
    else:
        text = (f"input(s) {shown} are in the unit of a stiffness, a damping or a mass (parameters exposed as "
                "inputs?) and are held at their start values, not driven"
                f"{'; force inputs: ' + ', '.join(forces) if forces else '; no force input is left'}; give their "
                f"values with {either('--set')}, or drive any that is a load with "
                f"{either('--inputs', value=','.join(forces + names))}")
    warn_once(source, ("coefficients", tuple(names), tuple(forces)), text)


#: What a reduced model of the mechanical states misses under a controller's integral action (audit 75 F6: a 4-mass
#: chain under a PID, its integrator and actuator lag left out: 24.5 % of range off at a 100 N step and 34 % at a
#: 0.5 rad/s load, while compare's default test, a harmonic between the ROM's frequencies, showed 1.0-1.6 %).
_INTEGRATOR_MISS = ("; where one is a controller's integrator, the reduced model misses the static and low-frequency "
                    "response it sets (a step or a slow load), which a test input between the model's frequencies "
                    "hardly shows: check with a step (compare --input step:t0=1, scaled to the load)")


def _warn_unrecorded_states(source: Source) -> None:
    """One warning (per process and FMU) naming the continuous states that the given ``--positions`` and
    ``--velocities`` leave out (without them the selection refuses such states: sixth audit, an actuator lag)."""
    selection = getattr(source, "selection", None)
    followers = dict(getattr(selection, "followers", {}) or {})
    if followers:
        moves = "; ".join(f"{state} moves with the recorded velocity {velocity}"
                          for state, velocity in list(followers.items())[:3])
        warn_once(source, ("followers", tuple(followers)),
                  f"its continuous state(s) {', '.join(list(followers)[:6])} are not recorded: {moves} (a rigid "
                  "connection), so each differs from the position of that velocity by a constant, which the outputs' "
                  "offsets absorb")
    others = [name for name in getattr(selection, "unrecorded_states", []) or [] if name not in followers]
    if not others:
        return
    shown = _few_names(others)
    if _velocities_are_derivatives(selection):
        # the rate check of snapshots records so only where these states are the positions' rates scaled (audit 74
        # F4: the lag wording below, on an exact ROM of an FMU whose velocity states are 10 v)
        text = (f"its continuous state(s) {shown} are not recorded (the velocities recorded are the positions' "
                "derivative variables): where they are those velocities in other units, as snapshots' rate check "
                "finds in the data, nothing is lost; where they are dynamic (an actuator lag, a filter, a controller "
                "state), the reduced model cannot follow them")
    else:
        text = (f"its continuous state(s) {shown} are recorded neither as positions nor as velocities: if they are "
                "dynamic (an actuator lag, a filter, a controller state), the reduced model cannot follow them"
                f"{_INTEGRATOR_MISS}")
    warn_once(source, ("unrecorded states", tuple(others)), text)


def _velocities_are_derivatives(selection: Any) -> bool:
    """Whether the recorded velocities are exactly the recorded positions' derivative variables (states' ``der``)."""
    velocities = [column.name for column in getattr(selection, "velocities", []) or []]
    derivatives = list(getattr(selection, "position_derivatives", []) or [])
    return bool(velocities) and velocities == derivatives


def _warn_outputs_left_out(source: Source) -> None:
    """One line (per process and FMU) naming the declared outputs the default selection does not record: those held
    between samples (discrete variability or clocked), with why and the ``--outputs`` that records them anyway, and
    those that are not real (Boolean, Integer, ...), which the ROM and its exported FMU have no port for (audit 73
    F3: a sampled output fitted beside continuous ones threw them 9-60 % of their range off)."""
    left_out = dict(getattr(source, "outputs_left_out", {}) or {})
    if not left_out:
        return
    held = [name for name, why in left_out.items() if why == "discrete"]
    other = [f"{name} ({why})" for name, why in left_out.items() if why != "discrete"]
    parts = []
    if held:
        insist = ",".join(getattr(source, "real_output_names", []) or held)
        parts.append(f"output(s) {_few_names(held)} are held between samples (discrete variability) and are not "
                     "recorded: the ROM's outputs are continuous maps of its state (eq. 17), which cannot follow a "
                     "staircase (fitted, one bends the ROM's dynamics and throws the continuous outputs off); record "
                     "them anyway with "
                     + patterns_said(outputs=insist))
    if other:
        parts.append(f"output(s) {_few_names(other)} are not real signals and are not recorded (the ROM and its "
                     "exported FMU have no port for them)")
    warn_once(source, ("outputs left out", tuple(left_out)), "; ".join(parts))


def _warn_held_outputs(source: Source) -> None:
    """One warning (per process and FMU) naming the recorded outputs that ``--outputs`` chose although they are held
    between samples: eq. 17's continuous output map cannot fit them, the fit bends the ROM toward their steps, and
    their jumps set the automatic window's step."""
    held = list(getattr(source, "held_output_names", []) or [])
    if not held:
        return
    others = [name for name in getattr(source, "output_names", []) if name not in held]
    fix = (patterns_said(outputs=",".join(others)) if others else
           f"{either('--outputs')} naming continuous outputs (or positions)")
    warn_once(source, ("held outputs", tuple(held)),
              f"output(s) {_few_names(held)} are held between samples (discrete variability) but recorded as asked: "
              "eq. 17's continuous output map cannot follow their steps, the fit bends the ROM's dynamics toward "
              f"them{' and throws the other outputs off' if others else ''}, and their jumps set the automatic "
              f"window's step; for a ROM of the continuous outputs record with {fix}")


def first_report(key: tuple[Any, ...]) -> bool:
    """True the first time this process asks about ``key``: what a warning said once is not said again."""
    if key in _REPORTED:
        return False
    _REPORTED.add(key)
    return True


def said_key(category: str, text: str) -> tuple[str, str, str]:
    """The key under which :func:`first_report` knows a warning by its words (the same words from a child
    process and from this one are one warning)."""
    return ("said", category, text)


def warn_once(source: Source, about: tuple[Any, ...], text: str, stacklevel: int = 4) -> None:
    """``text`` as a warning about ``source``'s FMU, unless this process said one ``about`` the same thing of the
    same FMU already (a run table opens the source once per row, and every row's runs would repeat it)."""
    import warnings

    from ..errors import FmuOpinfWarning

    path = str(getattr(source, "path", "")) or type(source).__name__
    said = f"{os.path.basename(path)}: {text}"
    if first_report((os.path.abspath(path), about)) and first_report(said_key(FmuOpinfWarning.__name__, said)):
        warnings.warn(said, FmuOpinfWarning, stacklevel=stacklevel)


_FMU_OPTIONS = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "parameters",
                "settings", "start_time")
#: The size options of the builtin systems (:class:`BuiltinSource`), which an FMU source does not take.
BUILTIN_SIZES = ("g", "n1", "alpha", "beta", "v")
_FLAG = {"parameters": "set", "settings": "set", "method": "me-method", "start_time": "start-time"}


def at_start_time(source: Source, start_time: float | None) -> Source:
    """``source`` run from the FMU time ``start_time`` (a copy; ``source`` itself when it starts there already or
    ``start_time`` is None).

    Parameters
    ----------
    source : Source
        An FMU source (a builtin source has no start time: giving one is an error).
    start_time : float or None

    Returns
    -------
    Source
    """
    if start_time is None:
        return source
    if source.kind != "fmu":
        raise InputSpecError(f"{either('--start-time')} applies to fmu sources, not to {source!r}")
    if getattr(source, "start_time", None) == float(start_time):
        return source
    cls, kwargs = source.recipe()
    return cls(**{**kwargs, "start_time": float(start_time)})
