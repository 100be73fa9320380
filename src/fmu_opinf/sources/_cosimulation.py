"""Co-simulation FMUs (FMI 2.0 and 3.0) driven step by step through their C functions."""

from __future__ import annotations

import contextlib
import ctypes
import errno
import math
import multiprocessing.util
import os
import re
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DimensionError, FMUError, InputSpecError
from ..signals import pulse_amplitude
from ._base import Source, StepError, check_constraint, inputs_without, nice_floor
from . import _fmu_log
from ._compile import compile_sources, has_c_sources, install_binaries
from ._resolve import resolve_variables
from ._unpack import make_unpack_folder
from ._settings import parse_assignments, typed_assignments
from .._stepping import stepping_of
from .._validate import ME, either, setting_said
from ._variables import (_FORCE_DIMENSIONS, _LOCAL_STEMS, Column, ModelInfo, ReadPlan, annotated_constraint,
                         binary_platform, description_key, slim_description,
                         declared_nominal, declared_range, fmi3_ports, held_inputs_record, is_coefficient,
                         looks_like_parameter, port_aliases, read_description, real_outputs, source_parameters_record,
                         start_value, unit_dimension, unit_kind)

def _fmi2_callbacks(target: Any) -> Any:
    """FMI 2 callbacks whose kept log messages reach ``target`` (:func:`._fmu_log.fmi2_callbacks`)."""
    return _fmu_log.fmi2_callbacks(target)[0]


__all__ = ["FMUSource", "DEFAULT_TOLERANCE", "check_tolerance", "fixed_communication_step", "offers_model_exchange",
           "warn_other_communication_step", "TERMINATED", "terminated_at", "declared_stop_at"]

#: What the error of an FMU that asked to terminate the simulation says (FMI 3 ``terminateSimulation``, FMI 2
#: ``fmi2Discard`` with ``fmi2Terminated``, a model-exchange ``terminateSimulation``); its time relative to the run's
#: start follows as ``--t-end below T`` (:func:`terminated_at`).
TERMINATED = "asked to terminate the simulation"


def terminated_at(text: str) -> float | None:
    """The time, relative to the run's start, at which an FMU asked to terminate the simulation, read from the
    error ``text`` of a run (the error crosses a process boundary as text), or None for any other error.  The
    automatic window then ends before it (audit 70, F5: the pilots ran on past a Simulink-style stop time)."""
    if TERMINATED not in text:
        return None
    found = re.search(r"--t-end (?:or t_end= )?below ([-+0-9.eE]+)", text)
    return float(found.group(1)) if found else None


#: What the error of a step that failed where it passed the FMU's declared ``DefaultExperiment/@stopTime`` says
#: before that time relative to the run's start (:meth:`FMUSource._past_declared_stop`, :func:`declared_stop_at`).
PAST_STOP_TIME = f"where the model may end its simulation: give {either('--t-end')} at or below "


def declared_stop_at(text: str) -> float | None:
    """The declared stopTime (from the run's start) that the error ``text`` of a run names as the fix (a step that
    failed where it passed it), or None for any other error (compare then names its own --t-end)."""
    found = re.search(re.escape(PAST_STOP_TIME) + r"([-+0-9.eE]+)", text)
    return float(found.group(1)) if found else None


#: The stop time given to an FMU lies this share of the run's last step after its last sample (:func:`stop_time_given`).
STOP_TIME_SLACK = 1e-6


def stop_time_given(t: np.ndarray) -> float:
    """The stopTime given to ``setupExperiment`` / ``enterInitializationMode`` for a run on the FMU times ``t``: its
    last sample plus :data:`STOP_TIME_SLACK` of its last step (and 16 ulps).

    Co-simulation steps from ``t[i - 1]`` by one uniform ``h`` (``FMUSource._steps``: FMUs with a fixed
    communication step refuse a step that differs by an ulp), so the last step ends at ``t[-2] + h``, which may
    pass ``t[-1]`` by a few ulps and by the 1e-9 h that the uniform step may differ from the grid's; model exchange
    takes an event time within ``_time_slack`` (8 ulps and 1e-12 of the step) of ``t[-1]`` as its end.  An FMU that
    enforces its stop time with no slack (``t + h > stopTime`` is an error, FMI: the run's final time) failed there
    with ``stopTime = t[-1]`` (audit 77a, F3: ``56.98 + 0.02 = 57.000000000000007``).  The slack covers both and is
    far below any step, so no FMU takes it for a longer run; it is the slack the Reference FMUs allow themselves
    (``EPSILON = 1e-6`` of their step)."""
    end = float(t[-1])
    step = float(t[-1] - t[-2]) if len(t) > 1 else 0.0
    return end + STOP_TIME_SLACK * abs(step) + 16 * math.ulp(end)


#: Relative tolerance given to FMUs and to the model-exchange integrator when none is chosen.
DEFAULT_TOLERANCE = 1e-10


def check_tolerance(tolerance: float | None) -> float:
    """The tolerance to use: :data:`DEFAULT_TOLERANCE` for ``None``; ``0`` means "the FMU's default".

    Raises :class:`~fmu_opinf.errors.InputSpecError` unless ``0 <= tolerance < 1``.
    """
    if tolerance is None:
        return DEFAULT_TOLERANCE
    value = float(tolerance)
    if not (0.0 <= value < 1.0):
        raise InputSpecError(f"--tolerance {tolerance} must lie in [0, 1), e.g. {either('--tolerance', value=1e-10)} "
                             "(relative)")
    return value


def _constant_step_only(source: Any) -> bool:
    """Whether ``source`` is driven through co-simulation by an FMU that cannot vary its communication step
    (``CoSimulation/@canHandleVariableCommunicationStepSize`` false, also where it is absent: the FMI default)."""
    cs = getattr(getattr(source, "md", None), "coSimulation", None)
    return getattr(source, "interface", None) == "cs" and cs is not None \
        and not cs.canHandleVariableCommunicationStepSize


def fixed_communication_step(source: Any) -> float | None:
    """The one communication step a co-simulation FMU accepts, or None.

    An FMU that cannot handle a variable communication step (FMI 2 and 3 attribute) and declares
    ``DefaultExperiment/@stepSize`` is driven at exactly that step: its pilots, the automatic window's step and
    every recording (a fixed-step code generator refuses any other ``h``; whether it accepts multiples cannot be
    known, so none are used).  Without a declared step the attribute only asks for one constant step per run,
    which every run on a uniform grid has (:meth:`FMUSource._steps`).
    """
    if not _constant_step_only(source):
        return None
    experiment = getattr(source.md, "defaultExperiment", None)
    try:
        step = float(experiment.stepSize)
    except (AttributeError, TypeError, ValueError):
        return None
    return step if np.isfinite(step) and step > 0 else None


def warn_other_communication_step(source: Any, dt: float, option: str = "--dt") -> None:
    """Warn, before any run, that a step ``dt`` (given as ``option``) is not the FMU's fixed communication step.

    The step asked for is used: FMI only asks such an FMU for one constant step, and some run at any constant
    step; a fixed-step code generator's FMU refuses it at the first ``doStep``, whose error then names the fixed
    step (:meth:`FMUSource._step_failure`).
    """
    fixed = fixed_communication_step(source)
    if fixed is None or _same_step(dt, fixed):
        return
    from . import warn_once

    warn_once(source, ("communication step", float(dt)),
              f"it declares one fixed communication step {fixed:g} (canHandleVariableCommunicationStepSize=false, "
              f"DefaultExperiment stepSize={fixed:g}); running at the step {dt:g} as asked: if its doStep refuses "
              f"that, {_give_fixed_step(source, fixed)}")


def declared_start_time(md: Any) -> float:
    """The FMU's ``DefaultExperiment/@startTime`` (0 where it declares none)."""
    experiment = getattr(md, "defaultExperiment", None)
    value = getattr(experiment, "startTime", None) if experiment is not None else None
    return float(value) if value not in (None, "") else 0.0


def check_start_time(start_time: float | None, md: Any) -> float:
    """The FMU time at which runs start: ``start_time`` if given (finite), else the declared one."""
    if start_time is None:
        return declared_start_time(md)
    try:
        value = float(start_time)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise InputSpecError(f"start time {start_time!r} is not a finite number; give e.g. "
                             f"{either('--start-time', value=0.0)}")
    return value


def _same_step(h: float, step: float) -> bool:
    return abs(h - step) <= 1e-9 * step


def offers_model_exchange(source: Any) -> bool:
    """Whether ``source`` is an FMU that offers model exchange (``--interface me``: fmu-opinf integrates it), the
    fix that many co-simulation problems have."""
    return getattr(getattr(source, "md", None), "modelExchange", None) is not None


def _give_fixed_step(source: Any, fixed: float) -> str:
    """The fix for a step other than the FMU's ``fixed`` communication step (said before the run and after a
    refusal), in both vocabularies (audit 81c F12)."""
    return (f"leave {either('--dt')} out or give {either('--dt', value=float(f'{fixed:g}'))}"
            + (f" (or drive its model exchange, {ME}, whose step is free)" if offers_model_exchange(source)
               else ""))


#: The status ``fmi2Discard`` / ``fmi3Discard`` (the same value): the FMU could not complete the step.
DISCARD = 2

#: ``fmi2StatusKind`` values (FMI 2.0 section 4.2.3): where the FMU's last doStep ended, and whether it terminated.
_FMI2_LAST_SUCCESSFUL_TIME, _FMI2_TERMINATED = 2, 3

#: The words every failure of a discarded ``doStep`` says (the automatic window's step search looks for them: a
#: pilot's step that the FMU discards is searched below like one where it overflows, audit 70 finding 9).
DISCARDED = "discarded the communication step"


#: Largest finite single-precision number: an FMI 3 Float32 input beyond it would receive infinity.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_single_precision(fmu: str, names: list[str], single: np.ndarray, u: np.ndarray) -> None:
    """Refuse inputs that single-precision (Float32) input variables cannot hold (``u``: (m, k), in effect).

    Rounded to Float32 they would become infinite: numpy warned about an overflow in a cast and the FMU failed
    later with non-finite derivatives or outputs, which named neither the input nor its range.  A value refused
    is one that rounds to infinity (from about 3.4028236e38 on; :data:`FLOAT32_MAX` itself is held).
    """
    for name, values in zip((n for n, s in zip(names, single) if s), np.atleast_2d(u)[single]):
        with np.errstate(over="ignore", invalid="ignore"):
            overflow = np.isinf(values.astype(np.float32)) & np.isfinite(values)
        if overflow.any():
            largest = float(np.max(np.abs(values[overflow])))
            raise InputSpecError(f"{fmu}: input {name} is a single-precision (Float32) variable and the input "
                                 f"reaches {largest:.9g}, beyond its largest value {FLOAT32_MAX:.9g}; scale the "
                                 "input down (e.g. its amplitude)")


#: FMUs (file names) that changed the working directory in this process, said once (:meth:`FMUSource._keep_directory`).
_MOVED_DIRECTORY: set[str] = set()

#: Attributes of an :class:`FMUSource` that its copy in another process does not take (:meth:`FMUSource._handover`).
_NOT_HANDED = frozenset({"_built_keys", "_slim"})


class FMUSource(Source):
    """A co-simulation FMU (FMI 2.0 or 3.0) driven step by step through its C functions.

    The model description is read and the variables resolved at construction; the binary is
    loaded only by :meth:`start`.  Per step the recorder makes three raw C calls (set inputs,
    do step, get all recorded values into one pre-allocated row); FMI 3 Float32 inputs and outputs take one
    call more each.

    Parameters
    ----------
    path : str or path-like
        The ``.fmu`` file (or an extracted FMU directory).
    positions : str, optional
        Name patterns of the positions (``*`` wildcard, comma lists, brackets literal, index ranges
        ``x[1:30]``; wildcards and ranges match only continuous-time variables).  Default: found
        from the model structure (:func:`~fmu_opinf.sources._variables.discover`: derivative links
        and aliases, else first-order states split in halves, else ``x[*]``).  An empty string reads
        no states at all (inputs and outputs only, as :func:`fmu_opinf.compare.compare` does).
    velocities, accelerations : str, optional
        Name patterns; default: from the derivative links, else ``v[*]`` / ``a[*]``, else derived
        from the data (also with ``"none"``).
    inputs : str, optional
        Name patterns of the force inputs; default: every real continuous input except those with a
        ``settings`` value and those that look like parameters exposed as inputs (a non-zero start value in no
        force unit, or a unit such as N/m, N.s/m or kg).  Other inputs are
        held at their start (or ``settings``) values; ``"none"`` drives no input (m = 0).
    outputs : str, optional
        Name patterns; default: all real variables with causality output.
    constraint : {"position", "velocity", "none", "unknown"}, default="unknown"
        Constraint kind, stored for the later stages (an FMU does not say).
    parameters : dict, optional
        The ``--set`` values: ``{name: value}`` for parameters, start values, held inputs and (FMI 3)
        structural parameters; values may be strings (typed by the variable), numbers, booleans or
        sequences for arrays; ``"x[2]"`` sets one element of an array.
    settings : dict, optional
        Same as ``parameters`` (merged after it).
    tolerance : float, optional
        Relative tolerance passed to the FMU (``fmi2SetupExperiment`` / ``fmi3EnterInitializationMode``):
        co-simulation FMUs with an internal variable-step solver follow it.  Default
        :data:`DEFAULT_TOLERANCE`; ``0`` passes none (the FMU's own default).
    start_time : float, optional
        The FMU time at which every run starts: the FMU is run at ``start_time + t`` for the run's time ``t``
        (which starts at 0, as the inputs, windows, snapshot files and ROMs do).  Default: the FMU's
        ``DefaultExperiment/@startTime``, else 0 (:func:`declared_start_time`).
    """

    kind = "fmu"
    #: FMI interface this class drives (``"cs"`` co-simulation, ``"me"`` model exchange).
    interface = "cs"

    def __init__(
        self,
        path: str | os.PathLike,
        positions: str | None = None,
        velocities: str | None = None,
        accelerations: str | None = None,
        inputs: str | None = None,
        outputs: str | None = None,
        constraint: str | None = None,
        parameters: dict[str, Any] | None = None,
        settings: dict[str, Any] | None = None,
        tolerance: float | None = None,
        start_time: float | None = None,
    ) -> None:
        self.path = Path(path).absolute()  # the same file after a change of directory (fmpy chdirs to load)
        self.tolerance = check_tolerance(tolerance)
        self._options = {
            "positions": positions,
            "velocities": velocities,
            "accelerations": accelerations,
            "inputs": inputs,
            "outputs": outputs,
            "constraint": constraint,
            "parameters": {**parse_assignments(parameters), **parse_assignments(settings)} or None,
            "tolerance": tolerance,
            "start_time": start_time,
        }
        md = read_description(self.path)
        self.constraint = check_constraint(constraint, annotated_constraint(self.path) or "unknown")
        self._sha256: str | None = None   # read once, where first needed (compiling sources, provenance)
        self._check_interface(md)
        self.md = md
        self.start_time = check_start_time(start_time, md)
        self.fmi_version = str(md.fmiVersion)
        self.model_identifier = self._interface_of(md).modelIdentifier
        self.model = ModelInfo.from_path(self.path)
        self._resolve(positions, velocities, accelerations, inputs, outputs, self._options["parameters"] or {})
        self._fmu: Any = None
        self._unzipdir: str | None = None

    # -- description ------------------------------------------------------------------------
    @staticmethod
    def _interface_of(md: Any) -> Any:
        """The model description's entry of the interface this class drives (None if absent)."""
        return md.coSimulation

    def _check_interface(self, md: Any) -> None:
        version = str(md.fmiVersion)
        if not (version.startswith("2") or version.startswith("3")):
            raise FMUError(f"{self.path.name} is an FMI {version} fmu; fmu-opinf supports FMI 2.0 and 3.0")
        if self._interface_of(md) is None:
            other = "model exchange" if self.interface == "cs" else "co-simulation"
            mine = "co-simulation" if self.interface == "cs" else "model exchange"
            raise FMUError(f"{self.path.name} offers no {mine}, only {other}; use "
                           f"{either('--interface', value='me' if self.interface == 'cs' else 'cs')} (or auto)")
        plat = binary_platform(version)
        binary = f"binaries/{plat}/{self._interface_of(md).modelIdentifier}"
        if self.path.is_dir():
            files = [str(p.relative_to(self.path)).replace(os.sep, "/") for p in self.path.rglob("*")]
        else:
            with zipfile.ZipFile(self.path) as zf:
                files = zf.namelist()
        self._compiled: dict[str, Path] = {}
        self.compiled = ""   # what was compiled here, for the one warning of open_source
        if not any(f.startswith(binary + ".") for f in files):
            have = sorted({f.split("/")[1] for f in files if f.startswith("binaries/") and f.count("/") >= 2})
            if has_c_sources(files) and not self.path.is_dir():
                self._compile_sources(md, plat, have)
                return
            other = self._other_binary(md, plat, files)
            if other:
                raise FMUError(other)
            raise FMUError(f"{self.path.name} has no binary for this platform ({plat}; it has: "
                           f"{', '.join(have) or 'none'}); export or compile it for {plat}")

    def _other_binary(self, md: Any, plat: str, files: list[str]) -> str:
        """The message for an FMU whose other interface has a binary for this platform under another model
        identifier (FMI allows one per interface), "" otherwise: the binary is there, only not for the interface
        asked (audit 81a, F3: "no binary for this platform (linux64; it has: linux64)")."""
        other = md.modelExchange if self.interface == "cs" else md.coSimulation
        mine = self._interface_of(md)
        if other is None or other.modelIdentifier == mine.modelIdentifier:
            return ""
        theirs = [f for f in files if f.startswith(f"binaries/{plat}/{other.modelIdentifier}.")]
        if not theirs:
            return ""
        names = ("co-simulation", "model exchange") if self.interface == "cs" else ("model exchange", "co-simulation")
        flag = "me" if self.interface == "cs" else "cs"
        return (f"{self.path.name} has no {names[0]} binary for this platform (binaries/{plat}/"
                f"{mine.modelIdentifier}.* is missing; it has {theirs[0].rsplit('/', 1)[-1]}, the {names[1]} binary): "
                f"use {either('--interface', value=flag)} (or auto)")

    def _compile_sources(self, md: Any, plat: str, have: list[str]) -> None:
        """Compile the FMU's C sources into the cache (once per machine), for :meth:`_extracted` to install;
        :attr:`compiled` says so (:func:`fmu_opinf.sources.open_source` warns, child processes stay silent)."""
        from .._hdf5 import sha256_of
        from ._variables import model_xml

        identifiers = [i.modelIdentifier for i in (md.modelExchange, md.coSimulation) if i is not None]
        self._sha256 = sha256_of(self.path)   # also the provenance's, which then need not read the file again
        self._compiled = compile_sources(self.path, model_xml(self.path), list(dict.fromkeys(identifiers)),
                                         self._sha256)
        self.compiled = (f"has no binary for this platform ({plat}; it has: {', '.join(have) or 'none'}); compiled "
                         "from its C sources with this machine's C compiler, once, into "
                         f"{next(iter(self._compiled.values())).parent}")

    def _resolve(self, positions: str | None, velocities: str | None, accelerations: str | None,
                 inputs: str | None, outputs: str | None, settings: dict[str, Any]) -> None:
        """Type the settings, expand arrays (sizes may depend on settings), find the recorded variables."""
        model = self.model
        resolved = resolve_variables(model, positions, velocities, accelerations, inputs, outputs, settings)
        self._settings, structural = resolved.settings, resolved.structural
        self._typed_settings = typed_assignments(model, settings, structural)
        selection, forces, held, out_elements = resolved.selection, resolved.forces, resolved.held, resolved.outputs
        out_columns = [Column(e, e.sign) for e in out_elements]
        if not out_columns and outputs is None and selection.positions:
            out_columns = _positions_as_outputs(selection.positions)
            out_elements = [c.element for c in out_columns]
            declared = ("no continuous real output" if "discrete" in resolved.outputs_left_out.values()
                        else "no outputs")
            selection.how["outputs"] = (f"{len(out_columns)} of the positions (the FMU declares {declared}; "
                                        "--outputs chooses others)")
        self.selection = selection
        self.position_names = [c.name for c in selection.positions]
        self.velocity_names = [c.name for c in selection.velocities]
        self.acceleration_names = [c.name for c in selection.accelerations]
        self.input_names = [e.name for e in forces]
        self.held_input_names = [e.name for e in held]
        self._held_elements = list(held)
        #: the held inputs' values and the source's input order, for the exported ROM FMU (audit 69 F4)
        self.held_inputs = held_inputs_record(model.elements(structural), forces, held, self._settings)
        #: the source's parameters at their training values, and the FMI 3 ``<Alias>`` names of the recorded inputs
        #: and outputs: the exported ROM FMU declares both (audit 81b F1, F2)
        self.source_parameters = source_parameters_record(model, self._settings)
        self.port_aliases = port_aliases(model, forces, out_elements)
        self._interface_elements = (list(forces), list(out_elements))
        #: held inputs that look like parameters (default selection, looks_like_parameter): open_source warns
        self.parameter_like_input_names = [e.name for e in resolved.parameter_like]
        #: those of them whose unit is none or not known (a force, perhaps: the warning offers to drive them)
        self.maybe_force_names = [e.name for e in resolved.parameter_like if unit_kind(e.var, model) == "unknown"]
        self.output_names = [e.name for e in out_elements]
        #: declared outputs the default selection left out, name -> why (``"discrete"``, ``"Boolean"``, ...):
        #: open_source says so in one line
        self.outputs_left_out = dict(resolved.outputs_left_out)
        #: recorded outputs held between samples (named by --outputs): open_source warns that eq. 17 cannot fit them
        self.held_output_names = [e.name for e in resolved.held_outputs]
        #: every declared real output, held ones included: the --outputs that line offers
        self.real_output_names = real_outputs(model.elements(structural))
        #: the FMI 3 variables behind the inputs and outputs (arrays, Float32): the exported ROM FMU declares them
        self.ports = ({"inputs": fmi3_ports(model, forces, structural),
                       "outputs": fmi3_ports(model, out_elements, structural)} if model.fmi3 else {})
        self.input_units = [e.var.unit or "" for e in forces]
        #: which force inputs are FMI 3 Float32 (the recorder rounds what it records of them to what they receive)
        self.single_precision_inputs = [e.var.type == "Float32" for e in forces]
        self.output_units = [e.var.unit or "" for e in out_elements]
        self.input_display_units = [e.var.display_unit or "" for e in forces]
        #: the modelDescription's descriptions of the inputs and outputs (provenance: the ROM FMU repeats them)
        self.input_descriptions = [e.var.description or "" for e in forces]
        self.output_descriptions = [e.var.description or "" for e in out_elements]
        self.output_display_units = [e.var.display_unit or "" for e in out_elements]
        columns = selection.positions + selection.velocities + selection.accelerations + out_columns
        self._read = ReadPlan(model, columns, structural)
        # a negated alias input takes -u at its value reference (FMI 2 alias="negatedAlias")
        self._write = ReadPlan(model, [Column(e, e.sign) for e in forces], structural, settings=self._settings)
        #: driven (force) inputs that look like parameters exposed as inputs (looks_like_parameter)
        self.driven_parameter_like_names = [e.name for e in forces if looks_like_parameter(e, model)]
        #: those of both in the unit of a coefficient (N.s/m, kg): told apart in the warning
        self.coefficient_input_names = [e.name for e in [*forces, *resolved.parameter_like]
                                        if is_coefficient(e.var, model)]

    def reselect(self, positions: Any, velocities: Any, accelerations: str | None, reason: str) -> None:
        """Record other positions, velocities or accelerations from the next run on (the recorder's rate check
        found the guessed ones inconsistent with the data, :mod:`fmu_opinf.snapshots._consistency`); ``None``
        keeps a choice's default rule, ``""`` derives the rate from the data.  ``reason`` goes into the
        selection's provenance (``how``)."""
        opts = self._options
        opts.update(positions=positions if positions is not None else opts["positions"],
                    velocities=velocities if velocities is not None else opts["velocities"],
                    accelerations=accelerations)
        self._resolve(opts["positions"], opts["velocities"], opts["accelerations"], opts["inputs"], opts["outputs"],
                      opts["parameters"] or {})
        self.selection.how["positions"] = f"rate check on the data: {reason}"

    def _settings_provenance(self) -> dict[str, Any]:
        from .._hdf5 import jsonable

        return jsonable(self._typed_settings)

    def _stem_pairs(self) -> str:
        """The first pairs found by name, ``x / v / a`` each (the rule of :data:`_LOCAL_STEMS` by example)."""
        groups = list(zip(self.position_names, self.velocity_names or [""] * len(self.position_names),
                          self.acceleration_names or [""] * len(self.position_names)))
        shown = ", ".join(" / ".join(name for name in group if name) for group in groups[:3])
        return shown + (", ..." if len(groups) > 3 else "")

    def selection_text(self) -> str:
        """One line: what is recorded and how it was chosen (printed by the recorder)."""
        how = self.selection.how
        parts = []
        for what, names in (("positions", self.position_names), ("velocities", self.velocity_names),
                            ("accelerations", self.acceleration_names)):
            shown = _few(names) if names else "none"
            rule = how.get(what, "")
            if what != "positions" and rule and rule == how.get("positions"):
                rule = "the same rule"   # audit 76 F5: a 200-character rule said once, not three times per line
            elif rule == _LOCAL_STEMS:
                rule = f"guessed: continuous local variables paired by name: {self._stem_pairs()}; no states declared"
            parts.append(f"{what} {shown} ({rule})")
        parts.append(self._inputs_said())
        if "outputs" in how:
            parts.append(f"outputs {_few(self.output_names)} ({how['outputs']})")
        if self.held_input_names:
            parts.append(f"held inputs {_few(self.held_input_names)}")
        return f"{self.path.name}: " + "; ".join(parts)

    def _inputs_said(self) -> str:
        """``force inputs F[1], F[2]``; ``driven inputs F[1] (N), F[3] (m)`` with units where one declares a unit
        that is no force or torque (a support's position, speed or acceleration: audit84 F5 read "force inputs"
        beside an input in m)."""
        if not self.input_names:
            return "force inputs none"
        units = list(getattr(self, "input_units", None) or [])   # (a source opened without its units: none)
        if not any(unit and unit_dimension(unit, self.model) not in (None, *_FORCE_DIMENSIONS) for unit in units):
            return f"force inputs {_few(self.input_names)}"
        return "driven inputs " + _few([f"{name} ({unit})" if unit else name
                                        for name, unit in zip(self.input_names, units)])

    def held_input_values(self) -> dict[str, list[Any]]:
        """Each held input, real or not: ``name -> [type, value as text, whether --set gave it]``, the value its
        ``--set`` value where given, else its declared start value (what the advice of a run whose outputs did not
        move names, :func:`~fmu_opinf.sources._base.held_inputs_advice`; audit 77a, F2)."""
        given = {setting.var.name: setting.values for setting in self._settings}
        values = {}
        for element in getattr(self, "_held_elements", []):
            var, chosen = element.var, given.get(element.var.name)
            if chosen is not None:
                value = chosen[element.offset] if element.offset < len(chosen) else chosen[0]
            else:
                parts = (var.start or "").split()
                value = parts[element.offset] if element.offset < len(parts) else (parts[0] if parts else "0")
            values[element.name] = [var.type, _value_text(var.type, value), chosen is not None]
        return values

    def declared_interface_attributes(self) -> dict[str, list[Any]]:
        """The file attributes ``output_min``, ``output_max``, ``output_nominal`` (each only where any output declares
        one: infinite / 0 where it does not) and ``input_quantities``, ``output_quantities`` (only where any is
        declared): the exported ROM FMU declares them as the source did (audit 81b F4)."""
        forces, outputs = getattr(self, "_interface_elements", ([], []))
        desc: dict[str, list[Any]] = {}
        ranges = [declared_range(e) for e in outputs]   # (a negated alias's own, as the value recorded)
        if any(math.isfinite(v) for bounds in ranges for v in bounds):
            desc["output_min"] = [float(low) for low, _ in ranges]
            desc["output_max"] = [float(high) for _, high in ranges]
        nominals = [declared_nominal(e) for e in outputs]
        if any(not math.isnan(v) for v in nominals):
            desc["output_nominal"] = [0.0 if math.isnan(v) else float(v) for v in nominals]
        for key, elements in (("input_quantities", forces), ("output_quantities", outputs)):
            quantities = [e.var.quantity or "" for e in elements]
            if any(quantities):
                desc[key] = quantities
        known = getattr(self.model, "type_definitions", {})
        for key, elements in (("input_declared_types", forces), ("output_declared_types", outputs)):
            names = [e.var.declared_type if e.var.declared_type in known else "" for e in elements]
            if any(names):
                desc[key] = names
                desc.setdefault("type_definitions", {}).update({name: dict(known[name]) for name in names if name})
        return desc

    def description(self) -> dict[str, Any]:
        desc = super().description()
        desc["variable_selection"] = dict(self.selection.how)
        desc["held_input_names"] = list(self.held_input_names)
        if self.held_input_names:   # with their types and values, for the advice of a run that did not move
            desc["held_input_values"] = self.held_input_values()
        desc["held_inputs"] = dict(self.held_inputs)
        if self.source_parameters["names"]:
            desc["source_parameters"] = dict(self.source_parameters)
        if self.port_aliases:
            desc["port_aliases"] = dict(self.port_aliases)
        if any(self.input_units) or any(self.output_units):  # declared units (the exported ROM FMU keeps them)
            desc["input_units"] = list(self.input_units)
            desc["output_units"] = list(self.output_units)
        if any(self.input_descriptions) or any(self.output_descriptions):   # (audit 79a, F4)
            desc["input_descriptions"] = list(self.input_descriptions)
            desc["output_descriptions"] = list(self.output_descriptions)
        if any(self.input_display_units) or any(self.output_display_units):
            desc["input_display_units"] = list(self.input_display_units)
            desc["output_display_units"] = list(self.output_display_units)
        desc.update(self.declared_interface_attributes())
        starts = self.input_starts()
        if np.any(starts != 0):   # the exported ROM FMU's inputs start there too
            desc["input_starts"] = [float(v) for v in starts]
        position_units = {c.element.var.unit or "" for c in self.selection.positions}
        if len(position_units) == 1 and "" not in position_units:   # reconstructed positions in the ROM FMU
            desc["position_unit"] = next(iter(position_units))
        used = set(self.input_units) | set(self.output_units) | position_units
        known = self.model.unit_definitions   # (the XML reader compare's report reads display units with, too)
        definitions = {name: known[name] for name in sorted(used - {""}) if name in known}
        if definitions:
            desc["unit_definitions"] = definitions
        if any(port["shape"] or port["type"] != "Float64" for ports in self.ports.values() for port in ports):
            desc["fmi3_ports"] = dict(self.ports)
        negated = [c.name for c in self._read.columns if c.sign < 0]
        if negated:
            desc["negated_columns"] = negated
        if self.outputs_left_out:   # declared outputs not recorded, and why (discrete, Boolean, ...)
            desc["outputs_left_out"] = dict(self.outputs_left_out)
        if self.held_output_names:   # recorded outputs held between samples (named by --outputs)
            desc["held_outputs"] = list(self.held_output_names)
        return desc

    def input_starts(self) -> np.ndarray:
        """Start values of the force inputs (their ``--set`` values where given)."""
        given = {s.var.name: s.values for s in self._settings}
        out = []
        for column in self._write.columns:
            element = column.element
            values = given.get(element.var.name)
            out.append(float(values[element.offset]) if values is not None else start_value(element))
        return np.array(out, dtype=float)

    def input_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """The force inputs' declared ``[min, max]`` (their variable's or its declared type's); infinite where none
        is declared.  A negated alias's own ``min`` / ``max`` bound its own value, the one recorded, as its own
        ``start`` is its start (audit 60: flipped, an alias in [0, 10] starting at 2 was pulsed down to -8)."""
        ranges = [declared_range(column.element) for column in self._write.columns]
        return (np.array([low for low, _ in ranges], dtype=float), np.array([high for _, high in ranges], dtype=float))

    def input_nominals(self) -> np.ndarray:
        """The force inputs' declared ``nominal`` (their variable's or its declared type's), NaN where none is
        declared or it is not a number above 0 (:func:`~._variables.declared_nominal`)."""
        return np.array([declared_nominal(column.element) for column in self._write.columns], dtype=float)

    def failure_hint(self, U: np.ndarray, step: int, message: str = "") -> str:
        """Why a step may have failed.

        Force inputs with non-zero start values set to 0 look like parameters; non-finite values from a
        co-simulation FMU are typical of an explicit (Euler) step that is unstable at this step size; other
        non-finite values get the usual causes (audit of 2026-12-06: the message named neither them nor a fix).
        """
        hint = self._cause_of(U, step, message)
        if not hint and "non-finite" in message:
            hint = (f"; check the {either('--set')} values and the inputs (a mass or a stiffness at 0, a parameter "
                    "exposed as an input driven to 0)")
        return hint

    def _cause_of(self, U: np.ndarray, step: int, message: str) -> str:
        if "non-finite" in message and self.interface == "cs" and step > 0:   # (at step 0 no step was taken)
            other = (f"drive its model exchange ({ME})" if offers_model_exchange(self)
                     else f"pass a smaller step ({either('--dt')})")
            return ("; the FMU's co-simulation may be an explicit step (e.g. one Euler step per communication step) "
                    f"that is unstable at this step: {other}")
        outside = self._outside_range(U, step)
        if outside:
            return outside
        if not self.driven_parameter_like_names or U is None or not len(U):
            return ""
        row = U[min(max(step, 0), len(U) - 1)]
        starts = self.input_starts()
        zeroed = [n for n in self.driven_parameter_like_names
                  if row[self.input_names.index(n)] == 0.0 and starts[self.input_names.index(n)] != 0.0]
        if not zeroed:
            return ""
        fix = inputs_without(self.input_names, self.driven_parameter_like_names)
        others = [n for n in self.driven_parameter_like_names if n not in zeroed]  # would fail or change the model next
        alike = ("start at non-zero values" if all(starts[self.input_names.index(n)] != 0.0 for n in others)
                 else "look like parameters")
        also = f" (and {', '.join(others)}, which {alike} too)" if others else ""
        return (f"; the inputs {', '.join(zeroed)} were set to 0 but have non-zero start values (parameters exposed "
                f"as inputs?): exclude them{also} with {fix} and give their values with {either('--set')}")

    def _outside_range(self, U: np.ndarray | None, step: int) -> str:
        """A hint naming the first input the run takes outside its declared range, with the fix; "" if none."""
        if U is None or not len(U) or not self.m:
            return ""
        lo, hi = self.input_ranges()
        row = U[min(max(step, 0), len(U) - 1)]
        for j in np.flatnonzero((row < lo) | (row > hi)):
            peak = float(np.max(np.abs(U[:, j])))
            bound = f"above its declared max {hi[j]:g}" if row[j] > hi[j] else f"below its declared min {lo[j]:g}"
            example = ";".join(_example_pulse(U[:, k], float(lo[k]), float(hi[k]), k == j) for k in range(self.m))
            return (f"; input {self.input_names[j]} is {row[j]:.6g} there, {bound}: give an input within "
                    f"[{lo[j]:g}, {hi[j]:g}] (this one reaches {peak:.6g} in magnitude; e.g. "
                    f"{either('--input', value=example)})")
        return ""

    def provenance(self) -> dict[str, Any]:
        from .._hdf5 import sha256_of

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
            "fmu_stepping": self.model.declared_stepping,  # how an fmu-opinf FMU steps (_stepping)
            "fmu_settings": self._settings_provenance(),
            "fmi_interface": self.interface,
            "tolerance": self.tolerance,
            **({"start_time": self.start_time} if self.start_time else {}),
        }

    def recipe(self) -> tuple[type, dict[str, Any]]:
        return type(self), {"path": str(self.path), **self._options}

    def _handover(self) -> dict[str, Any]:
        """What construction found (the attributes it set, before any run), for a copy in a child process: the
        copy takes them instead of reading the model description again and choosing the variables anew (audit
        81a F1: a 17 MB description read again in every isolated run, 11 s each).  The descriptions go slimmed to
        the chosen variables (:meth:`ModelInfo.subset`, :func:`slim_description`), which is all a run reads of
        them; the description's file state goes along, so that a changed FMU is read again."""
        built = self.__dict__.get("_built_keys") or frozenset(self.__dict__)
        state = {key: value for key, value in self.__dict__.items() if key in built and key not in _NOT_HANDED}
        names = frozenset(self._variable_names())
        slim = self.__dict__.get("_slim")
        if slim is None or slim[0] != names or slim[1] is not self.model or slim[2] is not self.md:
            # once per choice of variables: a scan of 60,000 variables takes 0.2 s
            slim = (names, self.model, self.md, self.model.subset(names), slim_description(self.md, names))
            self._slim = slim
        state["model"], state["md"] = slim[3:]
        return {"key": description_key(self.path), "state": state}

    @classmethod
    def _from_handover(cls, handover: Any) -> "FMUSource | None":
        state = handover.get("state") if isinstance(handover, dict) else None
        if not state or handover.get("key") is None or description_key(Path(state["path"])) != handover["key"]:
            return None   # the FMU changed since (or is gone): read it again
        source = cls.__new__(cls)
        source.__dict__.update(state)
        return source

    def _variable_names(self) -> set[str]:
        """The declared variables this source reads, writes or holds, and the states its derivatives belong to."""
        columns = [*self.selection.positions, *self.selection.velocities, *self.selection.accelerations,
                   *self._read.columns, *self._write.columns]
        variables = [c.element.var for c in columns] + [e.var for e in self._held_elements]
        names = {v.name for v in variables} | {v.derivative for v in variables if v.derivative}
        names |= {s.var.name for s in self._settings}
        return names | {name for name in self.model.state_derivatives}

    def _mark_built(self) -> None:
        """Remember which attributes construction set (before the first run adds its own): :meth:`_handover`."""
        if "_built_keys" not in self.__dict__:
            self._built_keys = frozenset(self.__dict__) - _NOT_HANDED

    # -- loading ----------------------------------------------------------------------------
    def start(self, t: np.ndarray, U: np.ndarray) -> None:
        self._mark_built()
        self._plan(t, U)
        self.close()
        self._open_binary()
        try:
            self._initialize()
        except BaseException:
            self.close()
            raise
        finally:
            self._keep_directory()

    def _open_binary(self) -> None:
        cls, kwargs = self._fmpy_class()
        cwd = self._cwd = os.getcwd()
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
            raise FMUError(f"{self.path.name} failed to instantiate ({self._last_log() or exc})"
                           f"{_escaped_location_advice(self._extracted(), self.path.is_dir(), self.fmi_version)}"
                           ) from None
        finally:
            self._keep_directory()

    def _keep_directory(self) -> None:
        """Go back to the working directory the run started in if the FMU changed it (a ``chdir`` in its
        instantiate or initialization: FMI's guide forbids it, some exports do it), so that the command's relative
        paths keep their meaning; said once per FMU where the run is in this process (audit 81a, F2)."""
        cwd = getattr(self, "_cwd", None)
        try:
            if cwd is None or os.getcwd() == cwd:
                return
        except OSError:   # (its folder was removed)
            pass
        os.chdir(cwd)
        if multiprocessing.parent_process() is None and self.path.name not in _MOVED_DIRECTORY:
            import warnings

            from ..errors import FmuOpinfWarning

            _MOVED_DIRECTORY.add(self.path.name)
            warnings.warn(f"{self.path.name} changed the working directory while it ran; fmu-opinf changed it back "
                          f"to {cwd} (files the FMU writes by relative names may land in either)", FmuOpinfWarning,
                          stacklevel=2)

    def _shared_state(self) -> dict[str, Any]:
        # unpack here, so that a copy in a child process neither unpacks again nor leaves a
        # temporary folder behind when its binary crashes; the tolerance of the moment (checked_accuracy)
        return {"unzipdir": self._extracted(), "tolerance": self.tolerance}

    def _borrow(self, state: dict[str, Any]) -> None:
        if "tolerance" in state:
            self.tolerance = state["tolerance"]
        unzipdir = state.get("unzipdir")
        if unzipdir and Path(unzipdir).is_dir() and self._unzipdir is None and not self.path.is_dir():
            self._unzipdir = unzipdir  # owned (and removed) by the original

    def _extracted(self) -> str:
        """The unpacked FMU, extracted once per source object and removed with it."""
        if self.path.is_dir():
            return str(self.path)
        if self._unzipdir is None:
            from fmpy import extract

            folder = make_unpack_folder(_unpack_parent(self.path))
            try:
                _check_room_to_unpack(self.path, folder)
                extract(str(self.path), unzipdir=folder)
                if self._compiled:
                    install_binaries(Path(folder), binary_platform(self.fmi_version), self._compiled)
            except FMUError:
                shutil.rmtree(folder, ignore_errors=True)
                raise
            except Exception as exc:   # (fmpy raises a bare Exception for a member name it refuses)
                shutil.rmtree(folder, ignore_errors=True)
                raise _unpack_error(self.path, folder, exc) from None
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
            self._unzipdir = folder
            # multiprocessing's finalizer, not weakref.finalize: it also runs when a worker process of
            # multiprocessing ends (they leave by os._exit, past atexit), and a forked child never runs the
            # finalizers it inherited, so it cannot remove its parent's folder
            multiprocessing.util.Finalize(self, shutil.rmtree, args=(folder,), kwargs={"ignore_errors": True},
                                          exitpriority=0)
        return self._unzipdir

    def _fmpy_class(self) -> tuple[type, dict[str, Any]]:
        if self.fmi_version.startswith("2"):
            from fmpy.fmi2 import FMU2Slave

            return FMU2Slave, {}
        from fmpy.fmi3 import FMU3Slave

        return FMU3Slave, {}

    def _bind_raw_functions(self) -> None:
        """Own prototypes of the per-step C functions taking raw addresses (no marshalling)."""
        vp, sz = ctypes.c_void_p, ctypes.c_size_t
        if self.fmi_version.startswith("2"):
            self._c_set, self._c_get = self._bind(("fmi2SetReal", [vp, vp, sz, vp]), ("fmi2GetReal", [vp, vp, sz, vp]))
        else:
            self._c_set, self._c_get = self._bind(("fmi3SetFloat64", [vp, vp, sz, vp, sz]),
                                                  ("fmi3GetFloat64", [vp, vp, sz, vp, sz]))
            if self._read.nvalues32 or self._write.nvalues32:  # bound only where needed
                self._c_set32, self._c_get32 = self._bind(("fmi3SetFloat32", [vp, vp, sz, vp, sz]),
                                                          ("fmi3GetFloat32", [vp, vp, sz, vp, sz]))
        self._bind_interface_functions()

    def _bind_interface_functions(self) -> None:
        """The C functions of the interface: ``doStep`` for co-simulation."""
        vp, dbl = ctypes.c_void_p, ctypes.c_double
        if self.fmi_version.startswith("2"):
            (self._c_step,) = self._bind(("fmi2DoStep", [vp, dbl, dbl, ctypes.c_int]))
            self._c_status = self._bind_status()
        else:
            (self._c_step,) = self._bind(("fmi3DoStep", [vp, dbl, dbl, ctypes.c_bool, vp, vp, vp, vp]))
        # fmi3DoStep's out-arguments: eventHandlingNeeded, terminateSimulation, earlyReturn (one byte each), then
        # lastSuccessfulTime (a double at byte 8).  Zero until an FMU sets one, which ends the run (_flag_failure).
        # eventHandlingNeeded is not read: fmu-opinf instantiates with eventModeUsed=false, so an FMU with
        # hasEventMode handles its events inside fmi3DoStep (FMI 3.0, co-simulation without event mode).
        self._flags = np.zeros(2, dtype=np.float64)
        self._returned = memoryview(self._flags).cast("B")   # its bytes, read as ints after each step

    def _bind_status(self) -> list[Any]:
        """``fmi2GetBooleanStatus`` and ``fmi2GetRealStatus`` (asked only after a discarded step), or an empty list
        where the binary lacks them (a discard is then read as a step too long)."""
        vp = ctypes.c_void_p
        try:
            return self._bind(("fmi2GetBooleanStatus", [vp, ctypes.c_int, vp]),
                              ("fmi2GetRealStatus", [vp, ctypes.c_int, vp]))
        except AttributeError:
            return []

    def _bind(self, *prototypes: tuple[str, list[Any]]) -> list[Any]:
        """Fresh function objects of the binary with the given argument types, returning int."""
        funcs = []
        for name, argtypes in prototypes:
            f = self._fmu.dll[name]  # a fresh function object: fmpy's cached one keeps its own prototype
            f.argtypes, f.restype = argtypes, ctypes.c_int
            funcs.append(f)
        return funcs

    def _logger(self, *args: Any) -> None:
        status, message = args[-3] if len(args) == 5 else args[1], args[-1]
        text = message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message)
        if status >= 2:
            self._log = (self._log + [text.strip()])[-5:]

    @contextlib.contextmanager
    def checked_accuracy(self, tolerance: float) -> Iterator[None]:
        """Runs at the relative ``tolerance`` where a looser one was asked (``0``, the FMU's own default, is kept):
        the FMU's integrator in co-simulation (its ``setupExperiment`` tolerance), the importer's in model exchange
        (:meth:`~fmu_opinf.sources.Source.checked_accuracy`; audit 80 F1: a linear chain moving on its own,
        recorded at ``--tolerance 1e-4``, differed from its pulse's scaled response by 0.03 of the pulse's effect
        and was called not linear)."""
        asked = self.tolerance
        if not asked or asked <= tolerance:
            yield
            return
        self.tolerance = tolerance
        try:
            yield
        finally:
            self.tolerance = asked

    def quiet_messages(self) -> int:
        """How many messages below Discard (OK, Warning) the FMU has logged so far, which fmu-opinf drops
        (:mod:`._fmu_log`): an FMU that logs on every call despite ``loggingOn = false`` is slow for it."""
        return _fmu_log.messages_of(getattr(self, "_log_key", None))

    def _last_log(self) -> str:
        return self._log[-1] if getattr(self, "_log", None) else ""

    def _instantiate(self) -> None:
        fmu = self._fmu
        if self.fmi_version.startswith("2"):   # (callbacks kept: the FMU holds a pointer to them)
            self._callbacks, self._log_key = _fmu_log.fmi2_callbacks(self._logger)
            fmu.instantiate(callbacks=self._callbacks)
        else:
            log_message, self._log_key = _fmu_log.fmi3_logger(self._logger)
            fmu.instantiate(logMessage=log_message)
        self._comp = fmu.component if isinstance(fmu.component, int) else fmu.component.value

    def _at(self, t: float) -> str:
        """A time of the FMU in messages: ``t=...`` when runs start at FMU time 0, else ``FMU time ...`` (the run's
        own time is that minus :attr:`start_time`)."""
        return f"FMU time {t:g}" if self.start_time else f"t={t:g}"

    def _initialize(self) -> None:
        fmu, t0 = self._fmu, float(self._t[0])
        t_stop = stop_time_given(self._t)
        tolerance = self.tolerance or None
        try:
            if self.fmi_version.startswith("2"):
                fmu.setupExperiment(tolerance=tolerance, startTime=t0, stopTime=t_stop)
                self._apply_settings(structural=False)
                fmu.enterInitializationMode()
                self._set_inputs(0)
                fmu.exitInitializationMode()
            else:
                if any(s.structural for s in self._settings):
                    fmu.enterConfigurationMode()
                    self._apply_settings(structural=True)
                    fmu.exitConfigurationMode()
                self._apply_settings(structural=False)
                fmu.enterInitializationMode(tolerance=tolerance, startTime=t0, stopTime=t_stop)
                self._set_inputs(0)
                fmu.exitInitializationMode()
            self._after_initialization()
        except StepError:
            raise
        except Exception as exc:
            raise StepError(f"{self.path.name} failed to initialize at {self._at(t0)} ({self._last_log() or exc})"
                            f"{self._start_hint(t0)}", 0, t0) from None
        self._set_inputs(0)

    def _start_hint(self, t0: float) -> str:
        """Where initialization failed at another time than the FMU's declared start: that start and the option."""
        declared = declared_start_time(self.md)
        if declared == t0:
            return ""
        return (f"; it declares DefaultExperiment startTime={declared:g}: leave out {either('--start-time')} to "
                "start there, or give another")

    def _after_initialization(self) -> None:
        """Hook run right after ``exitInitializationMode`` (model exchange: event iteration)."""

    def _apply_settings(self, structural: bool) -> None:
        """Set the user's values (structural parameters: in configuration mode, FMI 3 only)."""
        for setting in self._settings:
            if setting.structural != structural:
                continue
            kind = setting.var.type
            if self.fmi_version.startswith("2"):
                kind = {"Real": "Real", "Boolean": "Boolean", "String": "String"}.get(kind, "Integer")
            elif kind == "Enumeration":
                kind = "Int64"
            values = list(setting.values)
            if setting.var.negated and kind in ("Real", "Integer"):  # the value reference holds -value
                values = [-value for value in values]
            try:
                getattr(self._fmu, "set" + kind)([setting.var.vr], values)
            except Exception as exc:
                raise FMUError(f"{self.path.name} refused {setting_said(setting.var.name)} "
                               f"({self._last_log() or str(exc).splitlines()[0]})") from None

    def _set_inputs(self, i: int) -> None:
        if not self.m:
            return
        if self._call_set(self._Uraw[i], self._Uraw32[i]) > 1:
            raise StepError(self._fail_text("setting the input", i), i, float(self._t[i]))

    def _call_set(self, raw: np.ndarray, single: np.ndarray | None = None) -> int:
        """Write one row of raw input values (:meth:`_raw_inputs`): the Float64 ones, then the Float32 ones
        (``single``: those already in single precision, as :meth:`_plan` keeps them; else converted here)."""
        plan = self._write
        vr, nvr = plan.vrs.ctypes.data, len(plan.vrs)
        if self.fmi_version.startswith("2"):
            return self._c_set(self._comp, vr, nvr, raw.ctypes.data)
        status = self._c_set(self._comp, vr, nvr, raw.ctypes.data, plan.nvalues) if nvr else 0
        if plan.nvalues32 and status <= 1:
            if single is None:
                single = np.ascontiguousarray(raw[plan.nvalues:], dtype=np.float32)
            status = max(status, self._c_set32(self._comp, plan.vrs32.ctypes.data, len(plan.vrs32),
                                               single.ctypes.data, plan.nvalues32))
        return status

    def _fail_text(self, what: str, i: int) -> str:
        t = self._t
        when = f"{self._at(t[i - 1])} -> {t[i]:g}" if i else self._at(t[0])
        log = self._last_log()
        return f"{self.path.name} returned an error {what} at step {i} ({when})" + (f": {log}" if log else "")

    def _step_failure(self, status: int, what: str, i: int) -> str:
        """The line for a ``doStep`` to ``t[i]`` that returned ``status`` > warning: a discard (the FMU could not
        take a step this long, e.g. its embedded solver's maximum step) says so and what to give instead; an
        error or fatal status is the FMU's error (:meth:`_fail_text`)."""
        t, h = self._t, self._h_list[i]
        ended = self._fmi2_termination() if status == DISCARD else None
        if ended is not None:
            return self._fmi2_terminated_line(float(t[i - 1]), float(t[i]), ended)
        stop = self._past_declared_stop(float(t[i - 1]), float(t[i]))
        if status != DISCARD:
            fixed = fixed_communication_step(self)
            hint = "" if fixed is None or _same_step(h, fixed) else (
                f"; it declares the fixed communication step {fixed:g}: {_give_fixed_step(self, fixed)}")
            if fixed is None and _constant_step_only(self):  # eighth audit: a Simulink-style FMU refused h=0.0125
                hint = ("; it cannot vary its communication step (canHandleVariableCommunicationStepSize=false) and "
                        "declares no DefaultExperiment stepSize: a fixed-step FMU takes only multiples of its "
                        f"internal step (its log may name it); give {either('--dt')} as such a multiple, e.g. "
                        f"{nice_floor(h):g}, and {either('--t-end')}")
            return self._fail_text(f"in {what}", i) + (stop or hint)
        log = self._last_log()
        told = f"; its log: {log}" if log else ""
        return (f"{self.path.name} {DISCARDED} {h:g} in {what} at step {i} "
                f"({self._at(t[i - 1])} -> {t[i]:g}{told}){stop}{self._discard_fix(h, log)}")

    def _past_declared_stop(self, t0: float, t1: float) -> str:
        """Where a failed step from FMU time ``t0`` to ``t1`` is the one that crosses the FMU's declared
        ``DefaultExperiment/@stopTime``: that the model may end there and the ``--t-end`` that stays before it
        (audit 75, F2: a Simulink-style FMU with a compiled-in stop time returned an error there, and the line
        named no fix); else "".  Only a hint: a declared stopTime is often a tool's default (1 s), which
        fmu-opinf otherwise ignores, so no run is cut at it without the user's --t-end."""
        experiment = getattr(self.md, "defaultExperiment", None)
        try:
            stop = float(experiment.stopTime)
        except (AttributeError, TypeError, ValueError):
            return ""
        slack = 1e-9 * max(abs(t1), 1.0)
        if not (math.isfinite(stop) and t0 <= stop + slack < t1):
            return ""
        return (f"; the step passes its DefaultExperiment stopTime={stop:g}, "
                f"{PAST_STOP_TIME}{stop - self.start_time:.12g}")

    def _fmi2_termination(self) -> float | None:
        """After an FMI 2 ``fmi2Discard``: where the FMU ended its simulation, when it says it did
        (``fmi2GetBooleanStatus(fmi2Terminated)`` true: a Modelica ``terminate()``, a Simulink stop time; FMI 2.0
        section 4.2.3), from ``fmi2GetRealStatus(fmi2LastSuccessfulTime)`` (NaN where it refuses that); None where
        it answers false or refuses the query, as many exporters' FMUs do: the discard then stays a step too long.
        The FMU's last log line is kept (a refused query logs its own)."""
        if not self.fmi_version.startswith("2") or not getattr(self, "_c_status", None):
            return None
        boolean, real = self._c_status
        kept = list(getattr(self, "_log", []))
        flag, last = ctypes.c_int(0), ctypes.c_double(math.nan)
        try:
            if boolean(self._comp, _FMI2_TERMINATED, ctypes.byref(flag)) > 1 or not flag.value:
                return None
            if real(self._comp, _FMI2_LAST_SUCCESSFUL_TIME, ctypes.byref(last)) > 1:
                return math.nan
            return float(last.value)
        finally:
            self._log = kept

    def _fmi2_terminated_line(self, t0: float, t1: float, ended: float) -> str:
        """The line for an ``fmi2DoStep`` from FMU time ``t0`` to ``t1`` that the FMU discarded because it ended its
        simulation at FMU time ``ended`` (NaN: not said; the step's end is taken)."""
        inside = math.isfinite(ended) and t0 - 1e-9 * max(abs(t0), 1.0) <= ended <= t1
        at = ended if inside else t1
        said = f"last successful time {ended:g}" if math.isfinite(ended) else "no last successful time"
        return self._termination_line(f"in fmi2DoStep at {self._at(t0)} -> {t1:g} (fmi2Discard with "
                                      f"fmi2Terminated true, {said})", at)

    def _termination_line(self, where: str, at: float) -> str:
        """The line for an FMU that asked to terminate the simulation at FMU time ``at`` (``where``: in which call,
        from when): the time, the FMU's last log line, and the end of a run that works, which :func:`terminated_at`
        reads back (the automatic window then ends before it, compare's default end too)."""
        log = self._last_log()
        told = f"; its log: {log}" if log else ""
        return (f"{self.path.name} {TERMINATED} {where}{told}; end the run before it: {either('--t-end')} below "
                f"{at - self.start_time:.12g}")

    def _terminated_at_run_end(self, i: int) -> bool:
        """Whether the discarded ``fmi2DoStep`` to sample ``i`` is the run's last step and the FMU ended its
        simulation at its end (or later): its samples are then complete, as a terminating FMI 3 step there is."""
        t = self._t_list
        if i != len(t) - 1:
            return False
        ended = self._fmi2_termination()
        return ended is not None and ended >= t[i] - 1e-9 * max(abs(t[i]), 1.0)

    def _flag_failure(self, t: float, h: float) -> str:
        """The line for an ``fmi3DoStep`` from FMU time ``t`` over ``h`` that asked to terminate the simulation or
        returned early, which fmu-opinf never allows (it instantiates with earlyReturnAllowed=false)."""
        if self._returned[1]:
            return self._termination_line(f"in fmi3DoStep at {self._at(t)} -> {t + h:g}", t + h)
        log = self._last_log()
        told = f"; its log: {log}" if log else ""
        last = float(self._flags[1])
        fix = (f"drive its model exchange ({ME})" if offers_model_exchange(self) else
               "it offers no model exchange: ask its exporter for an FMU that keeps to the standard")
        return (f"{self.path.name} returned early from fmi3DoStep at {self._at(t)} -> {t + h:g} (lastSuccessfulTime "
                f"{last:.9g}), although early return was not allowed: the FMU breaks FMI 3.0 and its samples would "
                f"be wrong{told}; {fix}")

    def _discard_fix(self, h: float, log: str = "") -> str:
        """What to do about a discarded step ``h``: a smaller ``--dt`` (the automatic window's pilots then run
        at it), unless the FMU has a fixed communication step, which no option changes.  The example is the
        largest step below ``h`` that the FMU's ``log`` line names (tenth audit: "exceeds the maximum step size
        0.01" was quoted beside the advice 0.02), else half of ``h``."""
        fixed = fixed_communication_step(self)
        if fixed is not None and not _same_step(h, fixed):
            return f": it declares the fixed communication step {fixed:g}: {_give_fixed_step(self, fixed)}"
        if fixed is not None:
            return ": the FMU rejects its own fixed communication step" + (
                f"; drive its model exchange ({ME})" if offers_model_exchange(self)
                else "; it offers no model exchange to use instead")
        named = [value for value in _numbers(log) if 0 < value < h * (1 - 1e-9)]
        smaller = float(f"{nice_floor(max(named)) if named else nice_floor(h / 2):g}")
        return f": give a smaller step, e.g. {either('--dt', value=smaller)}"

    # -- stepping ---------------------------------------------------------------------------
    def read(self, out: np.ndarray) -> None:
        plan = self._read
        if out.dtype != np.float64 or not out.flags.c_contiguous or out.size < len(plan):
            raise DimensionError(f"read needs a contiguous float64 buffer of {len(plan)} values")
        target = out if plan.identity else self._raw
        if self._get(target.ctypes.data) > 1:
            raise StepError(f"{self.path.name} returned an error reading values", -1, float("nan"))
        if not plan.identity:
            np.multiply(self._raw[plan.gather], plan.signs, out=out[:len(plan)])

    def _get(self, address: int) -> int:
        """Read the raw values into ``address`` (the Float32 ones, when there are any, into ``self._raw``)."""
        plan = self._read
        vr, nvr = plan.vrs.ctypes.data, len(plan.vrs)
        if self.fmi_version.startswith("2"):
            return self._c_get(self._comp, vr, nvr, address)
        status = self._c_get(self._comp, vr, nvr, address, plan.nvalues) if nvr else 0
        if plan.nvalues32 and status <= 1:
            status = max(status, self._read_single())
        return status

    def _read_single(self) -> int:
        """Read the Float32 values and put them after the Float64 ones in ``self._raw``."""
        plan, single = self._read, self._raw32
        status = self._c_get32(self._comp, plan.vrs32.ctypes.data, len(plan.vrs32), single.ctypes.data,
                               plan.nvalues32)
        self._raw[plan.nvalues:] = single[:plan.nvalues32]
        return status

    def step(self, t: float, h: float, u: np.ndarray) -> None:
        self.refuse_single_precision_overflow(np.reshape(u, (self.m, 1)))
        u = np.ascontiguousarray(self._raw_inputs(np.atleast_2d(np.asarray(u, dtype=float)))[0])
        t = self.start_time + t   # the FMU's time
        if self.m and self._call_set(u) > 1:
            raise StepError(f"{self.path.name} returned an error setting the input at {self._at(t)}", -1, t)
        status = self._do_step(t, h)
        if self.fmi_version.startswith("3") and (self._returned[1] or self._returned[2]):
            raise StepError(self._flag_failure(t, h), -1, t)
        ended = self._fmi2_termination() if status == DISCARD else None
        if ended is not None:
            raise StepError(self._fmi2_terminated_line(t, t + h, ended), -1, t)
        if status == DISCARD:
            raise StepError(f"{self.path.name} {DISCARDED} {h:g} at {self._at(t)}"
                            f"{self._discard_fix(h)}", -1, t)
        if status > 1:
            raise StepError(f"{self.path.name} returned an error in doStep at {self._at(t)}", -1, t)

    def _do_step(self, t: float, h: float) -> int:
        if self.fmi_version.startswith("2"):
            return self._c_step(self._comp, t, h, 1)
        f = self._flags.ctypes.data
        return self._c_step(self._comp, t, h, True, f, f + 1, f + 2, f + 8)

    def advance(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None = None,
                offset: int = 0) -> None:
        if rows.dtype != np.float64 or not rows.flags.c_contiguous or rows.shape[1] != len(self._read):
            raise DimensionError(f"advance needs a C-contiguous float64 (c, {len(self._read)}) buffer")
        loop = self._advance2 if self.fmi_version.startswith("2") else self._advance3
        loop(rows, i0, count, published, offset)

    def _advance2(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        read, write = self._read, self._write
        in_vr, m = write.vrs.ctypes.data, len(write.vrs)  # FMI 2: scalars only, one value per reference
        out_vr, nv = read.vrs.ctypes.data, len(read.vrs)
        direct, raw, gather, signs = read.identity, self._raw, read.gather, read.signs
        rbase, rstride = (rows.ctypes.data, rows.strides[0]) if direct else (raw.ctypes.data, 0)
        ubase, ustride = self._Uraw.ctypes.data, self._Uraw.strides[0]
        t, h, changed, refresh = self._t_list, self._h_list, self._changed, self._refresh
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and c_set(comp, in_vr, m, ubase + i * ustride) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                status = c_step(comp, t[i - 1], h[i], 1)
                if status > 1:   # a discard at the run's end by the model's termination keeps the samples
                    if not (status == DISCARD and self._terminated_at_run_end(i)):
                        raise StepError(self._step_failure(status, "fmi2DoStep", i), i, t[i])
                elif refresh and c_set(comp, in_vr, m, ubase + i * ustride) > 1:
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
            if c_get(comp, out_vr, nv, rbase + j * rstride) > 1:
                raise StepError(self._fail_text("in fmi2GetReal", i), i, t[i])
            if not direct:
                np.multiply(raw[gather], signs, out=rows[j])
            if published is not None:
                published[0] = offset + j + 1

    def _advance3(self, rows: np.ndarray, i0: int, count: int, published: np.ndarray | None,
                   offset: int) -> None:
        c_set, c_get, c_step, comp = self._c_set, self._c_get, self._c_step, self._comp
        read, write = self._read, self._write
        in_vr, m, m_values = write.vrs.ctypes.data, len(write.vrs), write.nvalues
        out_vr, nv, n_values = read.vrs.ctypes.data, len(read.vrs), read.nvalues
        direct, raw, gather, signs = read.identity, self._raw, read.gather, read.signs
        rbase, rstride = (rows.ctypes.data, rows.strides[0]) if direct else (raw.ctypes.data, 0)
        ubase, ustride = self._Uraw.ctypes.data, self._Uraw.strides[0]
        # Float32 inputs and outputs (FMI 3 single precision): one more call each, addresses worked out here
        c_set32, c_get32 = getattr(self, "_c_set32", None), getattr(self, "_c_get32", None)
        in32, out32 = write.nvalues32 > 0, read.nvalues32 > 0
        in_vr32, m32, m_values32 = write.vrs32.ctypes.data, len(write.vrs32), write.nvalues32
        u32base, u32stride = self._Uraw32.ctypes.data, (self._Uraw32.strides[0] if in32 else 0)
        out_vr32, nv32, n_values32 = read.vrs32.ctypes.data, len(read.vrs32), read.nvalues32
        raw32, r32base = self._raw32, self._raw32.ctypes.data
        f, returned = self._flags.ctypes.data, self._returned
        t, h, changed, refresh = self._t_list, self._h_list, self._changed, self._refresh
        last = len(t) - 1   # a step to the run's end may ask to terminate: nothing is asked of the FMU after it
        for j in range(count):
            i = i0 + j
            if i:
                if changed[i] and ((m and c_set(comp, in_vr, m, ubase + i * ustride, m_values) > 1)
                                   or (in32 and c_set32(comp, in_vr32, m32, u32base + i * u32stride, m_values32) > 1)):
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
                status = c_step(comp, t[i - 1], h[i], True, f, f + 1, f + 2, f + 8)
                if (returned[1] and i < last) or returned[2]:   # terminateSimulation (before the end), earlyReturn
                    raise StepError(self._flag_failure(t[i - 1], h[i]), i, t[i])
                if status > 1:
                    raise StepError(self._step_failure(status, "fmi3DoStep", i), i, t[i])
                if refresh and ((m and c_set(comp, in_vr, m, ubase + i * ustride, m_values) > 1)
                                or (in32 and c_set32(comp, in_vr32, m32, u32base + i * u32stride, m_values32) > 1)):
                    raise StepError(self._fail_text("setting the input", i), i, t[i])
            if nv and c_get(comp, out_vr, nv, rbase + j * rstride, n_values) > 1:
                raise StepError(self._fail_text("in fmi3GetFloat64", i), i, t[i])
            if out32:
                if c_get32(comp, out_vr32, nv32, r32base, n_values32) > 1:
                    raise StepError(self._fail_text("in fmi3GetFloat32", i), i, t[i])
                raw[n_values:] = raw32
            if not direct:
                np.multiply(raw[gather], signs, out=rows[j])
            if published is not None:
                published[0] = offset + j + 1

    def _plan(self, t: np.ndarray, U: np.ndarray) -> None:
        super()._plan(t, U)
        if self.start_time:   # from here on the run's times are the FMU's (start_time + t)
            self._t = self.start_time + self._t
        self._t_list = self._t.tolist()
        self._h_list = [0.0] + self._steps().tolist()
        # inputs keep their values between steps: set them only when they change
        changed = np.ones(len(self._t), dtype=bool)
        if self.m:
            changed[1:] = np.any(self._U[1:] != self._U[:-1], axis=1)
        else:
            changed[:] = False
        self._changed = changed.tolist()
        # Some generated FMUs update what they publish (e.g. their der(x)) only when an input is set, so after
        # doStep they return the values of the step before (shared/spec/real-fmus.md): set the input in effect
        # again after each step.  fmu-opinf's own FMUs publish at the end of doStep and are spared the call.
        self._refresh = bool(self.m) and stepping_of(self.md.generationTool or "", "") == "continuous"
        self._Uraw = self._raw_inputs(self._U)
        self._raw = np.zeros(max(self._read.nvalues + self._read.nvalues32, 1))
        self._raw32 = np.zeros(max(self._read.nvalues32, 1), dtype=np.float32)
        # Float32 inputs as the FMU takes them, one row per sample (their doubles are in _Uraw)
        self.refuse_single_precision_overflow(self._U.T)
        self._Uraw32 = np.ascontiguousarray(self._Uraw[:, self._write.nvalues:], dtype=np.float32)

    def _steps(self) -> np.ndarray:
        """The communication steps of the planned grid: on a uniform grid one constant value (the FMU's fixed
        communication step, or the grid's step), not the grid's differences, which vary by the rounding of ``t``:
        an FMU that cannot vary its step may refuse that, and one with a maximum step equal to ``dt`` discarded
        ``h = 0.02000000000002558`` at t = 256 (audit 2026-11-27).  Its time then follows ``t`` to rounding."""
        steps = np.diff(self._t)
        if not steps.size:
            return steps
        h, fixed = float(f"{steps[0]:.12g}"), fixed_communication_step(self)
        if fixed is not None and _same_step(h, fixed):
            h = fixed
        rounding = 1e-9 * h + 4 * math.ulp(float(np.abs(self._t).max()))  # t = i dt rounds, more so on long runs
        return np.full(steps.size, h) if np.all(np.abs(steps - h) <= rounding) else steps

    def refuse_single_precision_overflow(self, u: np.ndarray) -> None:
        """:func:`check_single_precision` for this FMU's Float32 inputs (``u``: (m, k), in effect): what
        :meth:`start` and :meth:`step` check, and the recorder before it rounds the inputs it records."""
        if any(self.single_precision_inputs):  # a plain list: step() asks at every call
            check_single_precision(self.path.name, self.input_names,
                                   np.asarray(self.single_precision_inputs, dtype=bool), u)

    def _raw_inputs(self, U: np.ndarray) -> np.ndarray:
        """Inputs as the values of one set call: array inputs carry their held elements too."""
        plan = self._write
        if plan.identity:
            return np.ascontiguousarray(U)
        raw = np.tile(plan.base, (len(U), 1))
        raw[:, plan.gather] = U * plan.signs
        return raw

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
            self._keep_directory()   # (also after its steps and its termination)


def _escaped(folder: str | Path) -> bool:
    """Whether the ``file://`` URI of ``folder`` (an FMI 2 resource location) holds %-escapes: a space or a
    character outside plain ASCII letters, digits and ``-._~/``."""
    return "%" in Path(folder).absolute().as_uri()


def _unpack_parent(path: Path) -> str | None:
    """The folder to unpack an FMU into: the temporary folder, unless its path would reach the FMU's resource
    location with %-escapes and ``/tmp`` or ``/var/tmp`` would not and has room (the FMUs of some exporters do not
    decode them: audit 81a, F4); None is the temporary folder."""
    default = tempfile.gettempdir()
    if not _escaped(default):
        return None
    from .._hdf5 import SPACE_MARGIN, free_space

    try:
        with zipfile.ZipFile(path) as archive:
            needed = sum(member.file_size for member in archive.infolist())
    except (OSError, zipfile.BadZipFile):
        return None
    for candidate in ("/tmp", "/var/tmp"):
        if (os.path.isdir(candidate) and os.access(candidate, os.W_OK | os.X_OK) and not _escaped(candidate)
                and free_space(Path(candidate) / "member") > needed + SPACE_MARGIN):
            return candidate
    return None


def _escaped_location_advice(folder: str, given: bool, fmi_version: str) -> str:
    """The clause a failed instantiation gets where the FMU's FMI 2 resource location (a ``file://`` URI) holds
    %-escapes (space or non-ASCII in ``folder``): FMUs that do not decode them (OpenModelica's before its fix, older
    Reference-FMUs) cannot find their resources there (audit 81a, F4).  ``given``: the folder is the user's unpacked
    FMU, not fmu-opinf's.  FMI 3 passes a plain path: nothing to add."""
    if not fmi_version.startswith("2") or not _escaped(folder):
        return ""
    where = "unpack the FMU into a folder" if given else "set TMPDIR (where fmu-opinf unpacks it) to a folder"
    return (f"; its resource location {Path(folder).absolute().as_uri()}/resources holds %-escapes for the spaces or "
            f"non-ASCII letters of {folder}, which some exporters' FMUs do not decode: {where} whose path has "
            "neither")


def _check_room_to_unpack(path: Path, folder: str) -> None:
    """Refuse an archive whose members unpack to more than the temporary folder can hold (audit 55: a 1 MB zip
    bomb filled 1 GiB of the temporary folder on every run)."""
    from .._hdf5 import SPACE_MARGIN, free_space

    with zipfile.ZipFile(path) as archive:
        needed = sum(member.file_size for member in archive.infolist())
    room = free_space(Path(folder) / "member")
    if needed + SPACE_MARGIN > room:
        raise FMUError(f"{path.name} unpacks to {needed / 2**30:.3g} GiB, more than the temporary folder "
                       f"{Path(folder).parent} can take now ({max(room, 0.0) / 2**30:.3g} GiB: its free space, or a "
                       "file size limit); free space there, lift the limit or set TMPDIR to a larger folder")


def _unpack_error(path: Path, folder: str, exc: Exception) -> FMUError:
    """One line for an FMU that cannot be unpacked: no room, a member name fmpy refuses, or a damaged archive."""
    text = " ".join(str(exc).split())[:200]
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
        return FMUError(f"{path.name} cannot be unpacked into the temporary folder {Path(folder).parent}: "
                        f"{exc.strerror} (a full disk or a file size limit); free space there or set TMPDIR")
    if text.startswith("Illegal path"):   # (fmpy: an absolute member name, or one with ':' or '\\')
        return FMUError(f"{path.name} cannot be unpacked: {text}; repack the FMU with plain relative member names")
    return FMUError(f"{path.name} cannot be unpacked ({type(exc).__name__}: {text}); the file is damaged or "
                    "incomplete: copy or export the FMU again")


def _value_text(kind: str, value: Any) -> str:
    """A held input's value as a user writes it with --set: ``true``/``false`` for a Boolean, ``%g`` for numbers."""
    if kind == "Boolean":
        return "true" if str(value).strip().lower() in ("true", "1", "1.0") else "false"
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return str(value)


def _few(names: list[str], limit: int = 4) -> str:
    """``a, b, c, d, ... (n)`` for long lists, each name printable (audit 55: a newline in a name broke the line)."""
    names = ["".join(c if c.isprintable() else repr(c)[1:-1] for c in name) for name in names]
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit - 1]) + f", ..., {names[-1]} ({len(names)})"


#: Most positions that stand in for the outputs of an FMU that declares none (evenly spaced beyond).
MAX_POSITION_OUTPUTS = 20


def _positions_as_outputs(positions: list[Column]) -> list[Column]:
    """The outputs of an FMU without declared outputs: its positions (at most :data:`MAX_POSITION_OUTPUTS`, evenly
    spaced), so that the window, the output map, ``compare`` (eq. 19) and the exported FMU have something to
    measure (Modelica examples often declare no outputs)."""
    if len(positions) <= MAX_POSITION_OUTPUTS:
        return list(positions)
    picks = np.unique(np.linspace(0, len(positions) - 1, MAX_POSITION_OUTPUTS).round().astype(int))
    return [positions[i] for i in picks]


def _example_pulse(column: np.ndarray, low: float, high: float, failed: bool) -> str:
    """The example input of :meth:`FMUSource._outside_range` for one input, whose values in the failed run are
    ``column``: a pulse within ``[low, high]`` up to its own peak where the run drove it or it is the input that
    left its range (``failed``), else ``none``, held as the run held it (audit 63, finding 2: a run that drove F1
    alone was advised a pulse of 130, F1's peak, on F2 as well)."""
    if not failed and np.all(column == column[0]):
        return "none"
    return _pulse_within(low, high, float(np.max(np.abs(column))) or 1.0)


def _pulse_within(low: float, high: float, amplitude: float) -> str:
    """The example impulse of :meth:`FMUSource._outside_range` for one input declared within ``[low, high]``: up to
    ``amplitude`` upwards where the range allows (a pulse rising from 0), else downwards (a pull-only input,
    ``max = 0``: the tenth audit was advised the pulse that had just failed), else ``none``.  A range that leaves
    out 0 gets the pulse on its nearest bound (audit 60: for ``[5, 30]`` the example rose from 0, and the source
    refused it at step 0 as it had refused the input it replaced)."""
    if low > 0 or high < 0:
        base = low if low > 0 else high
        room = pulse_amplitude(high - low, amplitude) if high > low else 0.0
        return f"impulse:amplitude={room if low > 0 else -room:g},t0=2,width=0.5,offset={base:g}"
    if high > 0:
        return f"impulse:amplitude={pulse_amplitude(high, amplitude):g},t0=2,width=0.5"
    if low < 0:
        return f"impulse:amplitude={-pulse_amplitude(-low, amplitude):g},t0=2,width=0.5"
    return "none"


def _numbers(text: str) -> list[float]:
    """The decimal numbers written in ``text`` (an FMU's log line), as floats."""
    import re

    return [float(match) for match in re.findall(r"(?<![\w.])\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", text or "")]
