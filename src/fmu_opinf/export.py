"""Export a learned second-order ROM as a self-contained FMI 2.0 / 3.0 co-simulation FMU.

The FMU embeds the reduced operators in a generated ``model.c`` and reuses the benchmark
FMUs' FMI glue and Newmark kernel unchanged (``fmus/src``; constraint kind none), so it
steps exactly like :meth:`SecondOrderROM.simulate`: classical Newmark (beta = 1/4,
gamma = 1/2), input held over each communication step at the value set before ``doStep``,
started from the ROM's initial state ``q0, qdot0`` (the source's start values), with the
constant force ``fr``, the feedthrough ``Dur`` and the output offset ``y0``.  At the ROM's step ``dt``
the kernel steps a real modal (2 x 2 block-diagonal) form of the step map, O(r) per step with the
outputs through the transformed output matrix and ``q, q', q''`` rebuilt only when read, if that form
reproduces the step map to 1e-12 (:func:`fmu_opinf._recursion.modal_form`); otherwise, and at other
step sizes, it solves as before.
Inputs and outputs keep the source FMU's names and order, and each input the source FMU's start value (0 where it
declares none): an input the importer leaves unconnected holds the same value on both, so the ROM FMU is a
drop-in (seventh audit, 2026-11-27: a force input preloaded with 10 N left unconnected kept the source at rest and
made the ROM FMU, which started its input at 0, oscillate by 190 % of the static deflection).  The recording
drives force inputs from 0 (and warns where an FMU's input starts elsewhere); the ROM, linear, follows either.
The inputs the training held (parameters exposed as inputs, inputs left out of ``--inputs``, ``--set`` values) are
declared too, in the source's order, each with the held value as start and as its only value (``min = max``): the FMU
refuses another with a log line naming the input and the value (audit 69: they were missing, and a ROM trained at
``--set stiffness_scale=2`` looked like the source at its default 1).  A ROM whose file does not record the held
values (snapshots recorded before 2026-12-06) exports without them, with one warning.  Optional extra outputs
reconstruct chosen full-order positions through the basis (``x_i = x_ref,i + V[i, :] q``; for a ROM in
modal coordinates ``V[i, :] (W_qq q + W_qv q')``, :attr:`fmu_opinf.rom.SecondOrderROM.coordinates`).
Each input also declares the source's ``nominal`` where the training recorded one (snapshots ``input_nominal``), so
that a ROM FMU trained by fmu-opinf gets the source's pulse size (audit 75, F7), and the FMU declares how it steps
(``newmark``, or ``exact`` for a ROM of a continuous-time source) in an fmu-opinf vendor annotation, which ``fit``
reads to pick the integrator for a recording of it (:mod:`fmu_opinf._stepping`; audit 75, F1).
The binary links only libc and libm; the sources stay in the FMU's ``sources/``.
``ModelStructure`` declares each output's dependence on the inputs (FMI: an output without ``dependencies`` depends
on every input, and a master sees algebraic loops that are not there; audit 69): exactly the inputs of its
non-negligible feedthrough entries (:func:`_feedthrough_pattern`; negligible ones are dropped from the FMU, so it
computes what it declares), none for a reconstructed position; at initialization the same, unless the FMU starts at
its static equilibrium under the inputs set then (all inputs, undeclared).

Nothing read from the ROM file becomes code: the generated C holds numbers (written by ``repr(float)``) and, for the
log line of a held input, the input names as C string literals in which every byte but letters, digits and a few
plain signs is an octal escape (:func:`fmu_opinf.fmus.c_string`), no other text from the file; names and the
description go into the XML through an attribute quoting function (TAB, LF and CR of a description as the character
references ``&#9;``, ``&#10;``, ``&#13;``), and text with characters XML 1.0 cannot hold (other control characters)
is refused, as are names with TAB, LF or CR, which FMI names cannot hold.
"""

from __future__ import annotations

import decimal
import json
import math
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ._descriptions import input_descriptions as recorded_input_texts
from ._descriptions import output_descriptions as recorded_output_texts
from ._threads import single_threaded
from ._validate import check_not_input, either
from .errors import DataError, DimensionError, FileFormatError, FMUError, FmuOpinfWarning
from .fmus import (INTEGER_RANGES, Parameter, SecondOrderFmuSpec, build_second_order_fmu, enumeration_items,
                   find_build_tools, is_type_name, is_unit_name, type_definition, unit_definition)

if TYPE_CHECKING:
    from .rom import SecondOrderROM

__all__ = ["export_fmu", "rom_fmu_spec"]

_POSITION_NAME = re.compile(r"^x\[(\d+)\]$")


# ----------------------------------------------------------------------- the ROM

def _load_rom(rom: Any) -> Any:
    """Return the ROM object; load it first if ``rom`` is a path."""
    if not isinstance(rom, (str, os.PathLike)):
        return rom
    path = Path(rom)
    from .rom import SecondOrderROM

    try:
        return SecondOrderROM.load(path)
    except (FileFormatError, DataError):  # (one line naming the file already)
        raise
    except Exception as error:  # noqa: BLE001 - any reader failure means a bad file
        raise FileFormatError(f"cannot read ROM file {path}: {error}; pass a file written by "
                              "'fmu-opinf fit'") from error


def _matrix(rom: Any, name: str, shape: tuple[int, int]) -> np.ndarray:
    value = getattr(rom, name, None)
    if value is None:
        raise DimensionError(f"the ROM has no {name}; fit the ROM before exporting it")
    array = np.asarray(value.toarray() if hasattr(value, "toarray") else value, dtype=float)
    if array.shape != shape:
        raise DimensionError(f"ROM matrix {name} has shape {array.shape}, expected {shape}")
    if not np.all(np.isfinite(array)):
        raise DataError(f"ROM matrix {name} has NaN or infinite entries; refit the ROM")
    return array


def _check_step_matrix(matrices: dict[str, np.ndarray], dt: float | None) -> None:
    """Newmark's step matrix ``Mr + dt/2 Dr + dt^2/4 Kr`` is positive definite (the FMU solves with it).

    ``Mr, Dr, Kr`` themselves are checked by :func:`fmu_opinf.rom.check_operators`, the check loading a ROM
    file runs too.
    """
    if dt is None:
        return
    M, D, K = matrices["Mr"], matrices["Dr"], matrices["Kr"]
    S = M + dt / 2 * D + dt * dt / 4 * K
    try:
        np.linalg.cholesky((S + S.T) / 2)
    except np.linalg.LinAlgError:
        raise DataError("Mr + dt/2 Dr + dt^2/4 Kr is not positive definite; the ROM is not a stable "
                        "second-order model, refit it") from None


def _sizes(rom: Any) -> tuple[int, int, int]:
    """(r, m, p) read from the shapes of Mr, Br and Cpr (m = 0 allowed: a model without inputs)."""
    shapes = {}
    for name in ("Mr", "Br", "Cpr"):
        value = getattr(rom, name, None)
        shape = np.shape(value) if value is not None else ()
        if len(shape) != 2 or shape[0] < 1 or (shape[1] < 1 and name != "Br"):
            raise DimensionError(f"ROM matrix {name} has shape {shape}, expected a 2-d array; "
                                 "fit the ROM before exporting it")
        shapes[name] = shape
    return shapes["Mr"][0], shapes["Br"][1], shapes["Cpr"][0]


def _vector(rom: Any, name: str, size: int) -> np.ndarray:
    """Optional ROM vector (zeros if the ROM predates it), checked for shape and finiteness."""
    value = getattr(rom, name, None)
    array = np.zeros(size) if value is None else np.asarray(value, dtype=float).reshape(-1)
    if array.shape != (size,):
        raise DimensionError(f"ROM vector {name} has {array.size} entries, expected {size}")
    if not np.all(np.isfinite(array)):
        raise DataError(f"ROM vector {name} has NaN or infinite entries; refit the ROM")
    return array


def _reconstruction_rows(rom: Any, reconstruct: Sequence[str | int] | None,
                         r: int) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Names, (len, r) rows of ``q`` and of ``q'`` and offsets ``x_ref[i]`` of the reconstructed positions
    (``x_i = x_ref,i + V[i] q``, or ``V[i] (W_qq q + W_qv q')`` for a ROM in modal coordinates)."""
    if not reconstruct:
        return [], np.zeros((0, r)), np.zeros((0, r)), np.zeros(0)
    basis = getattr(rom, "basis", None)
    if basis is None:
        raise DimensionError("reconstruct needs the ROM's basis, but this ROM has none; refit "
                             "with the basis kept or drop reconstruct")
    basis = np.asarray(basis, dtype=float)
    n = basis.shape[0]
    if basis.ndim != 2 or basis.shape[1] != r:
        raise DimensionError(f"ROM basis has shape {basis.shape}, expected (n, {r})")
    own = _position_names(rom, n)
    names, indices = [], []
    for item in reconstruct:
        index, name = _reconstructed_position(item, own, n)
        names.append(name)
        indices.append(index)
    if len(set(indices)) != len(indices):
        raise DimensionError(f"reconstruct lists a position twice: {list(reconstruct)}")
    if not np.all(np.isfinite(basis)):
        raise DataError("the ROM basis has NaN or infinite entries; refit the ROM")
    x_ref = getattr(rom, "x_ref", None)
    x_ref = np.zeros(n) if x_ref is None or np.size(x_ref) == 0 else _vector(rom, "x_ref", n)
    rows = basis[indices]
    W = getattr(rom, "coordinates", None)
    if W is None:
        return names, rows, np.zeros_like(rows), x_ref[indices]
    W = _matrix(rom, "coordinates", (2 * r, 2 * r))
    return names, rows @ W[:r, :r], rows @ W[:r, r:], x_ref[indices]


def _reconstructed_position(item: str | int, own: list[str], n: int) -> tuple[int, str]:
    """Row (0-based) and output name of one reconstructed position: a recorded position's own name first, else
    ``x[i]`` or ``i`` for the i-th recorded position (1-based).

    Where the recorded names are themselves ``x[...]`` (a subset such as ``x[2], x[4], ...``), an ``x[i]`` that is
    not one of them is refused rather than read as a row number: ``x[4]`` would name one mass and show another
    (eleventh audit).  A number ``i`` is named by the source's name of that row, where the names were recorded.
    """
    if isinstance(item, str) and item in own:
        return own.index(item), item
    if isinstance(item, str) and item.strip().isdecimal():   # a row number from the command line
        item = int(item)
    match = _POSITION_NAME.match(item) if isinstance(item, str) else None
    index = int(match.group(1)) if match else (item if isinstance(item, int) and not isinstance(item, bool) else None)
    shown = f" (recorded: {', '.join(own[:4])}{', ...' if len(own) > 4 else ''})" if own else ""
    if match and any(_POSITION_NAME.match(name) for name in own):
        raise DimensionError(f"cannot reconstruct {item!r}: it is not a recorded position{shown}; give a recorded "
                             f"name, or the row of one as a number 1 .. {n}")
    if index is None or not 1 <= index <= n:
        hint = f" or the source's position names{shown}" if own else ""
        raise DimensionError(f"cannot reconstruct {item!r}: give full-order positions as "
                             f"'x[i]' (or i) with 1 <= i <= {n}{hint}")
    return index - 1, (own[index - 1] if own and not match else f"x[{index}]")


def _reconstruction_formula(rom: Any) -> str:
    if getattr(rom, "coordinates", None) is None:
        return "x_ref + V q"
    return "x_ref + V (Wqq q + Wqv q') (modal coordinates q, POD coordinates W [q; q'])"


def _position_names(rom: Any, n: int) -> list[str]:
    """The source's own names of the n positions (from the training provenance), if recorded."""
    snapshots = dict(getattr(rom, "provenance", None) or {}).get("snapshots")
    names = snapshots.get("position_names") if isinstance(snapshots, dict) else None
    return [str(name) for name in names] if isinstance(names, list) and len(names) == n else []


# ------------------------------------------------------------------- C generation

def _c_array(name: str, values: np.ndarray) -> str:
    flat = [repr(float(v)) for v in np.ravel(values, order="C")] or ["0.0"]
    lines = [", ".join(flat[i:i + 4]) for i in range(0, len(flat), 4)]
    body = ",\n    ".join(lines)
    return f"static const double {name}[{len(flat)}] = {{\n    {body}\n}};\n"


_STEP_MAP_CALLS = """
    addDense(assembly, MatrixPhi, stepMap, 3 * N_DOF, 3 * N_DOF);
    addDense(assembly, MatrixGamma, stepMapInput, 3 * N_DOF, N_INPUTS + 1);
    addDense(assembly, MatrixMapStep, stepMapSize, 1, 1);
"""


_MODAL_CALLS = """
    addDense(assembly, MatrixModalSize, modalSize, 1, 2);
    addDense(assembly, MatrixModalBlocks, modalBlocks, {k}, 2);
    addDense(assembly, MatrixModalInput, modalInput, {k}, N_INPUTS + 1);
    addDense(assembly, MatrixModalInputChange, modalInputChange, {k}, N_INPUTS);
    addDense(assembly, MatrixModalShape, modalShape, 3 * N_DOF, {k});
    addDense(assembly, MatrixModalProjection, modalProjection, {k}, 3 * N_DOF);
    addDense(assembly, MatrixModalRest, modalRest, 3 * N_DOF, N_INPUTS + 1);
    addDense(assembly, MatrixModalRestChange, modalRestChange, 3 * N_DOF, N_INPUTS);
    addDense(assembly, MatrixModalOutput, modalOutput, N_OUTPUTS, {k});
    addDense(assembly, MatrixModalOutputInput, modalOutputInput, N_OUTPUTS, N_INPUTS + 1);
"""


#: The fix of a step map that is not finite at the export's step, in both vocabularies.
_SMALLER_STEP = f"choose a smaller {either('--step')}"


def _modal_matrices(rom: Any, c_matrices: dict[str, np.ndarray], dt: float | None) -> dict[str, np.ndarray]:
    """The C kernel's modal step (``MatrixModal*`` in ``fmus/include/model.h``), or nothing if the step map
    has no modal form that reproduces it to 1e-12 (the kernel then keeps its Newmark solves / step map)."""
    import scipy.linalg

    from ._recursion import modal_form
    from .newmark import step_matrices

    if dt is None:
        return {}
    r = c_matrices["reducedMass"].shape[0]
    Br = c_matrices["reducedInput"]
    forced = np.hstack([Br, c_matrices["reducedForce"].reshape(r, 1)])
    if getattr(rom, "integrator", "newmark") == "exact":
        try:
            phi, gamma = rom.step_map(dt)
        except (ValueError, np.linalg.LinAlgError):
            raise DataError(f"the ROM's exact step map at dt={dt:g} is not finite; {_SMALLER_STEP}") from None
    else:
        M, D, K = (c_matrices[name] for name in ("reducedMass", "reducedDamping", "reducedStiffness"))
        try:
            phi, gamma_new, gamma_old = step_matrices(M, D, K, forced, dt)
        except (ValueError, np.linalg.LinAlgError):   # (audit 55: a ROM file's dt of 1e300)
            phi = gamma_new = gamma_old = np.full((1, 1), np.nan)
        gamma = gamma_new + gamma_old           # the kernel updates the acceleration for a new input first
    if not (np.isfinite(phi).all() and np.isfinite(gamma).all()):
        raise DataError(f"the ROM's step map at dt={dt:g} is not finite; {_SMALLER_STEP}")
    form = modal_form(phi, gamma)
    if form is None:
        return {}
    Z = scipy.linalg.solve(c_matrices["reducedMass"], Br, assume_a="sym")   # acceleration per input change
    Cp, Cv = c_matrices["reducedOutputPosition"], c_matrices["reducedOutputVelocity"]
    outputs = np.hstack([Cp, Cv, np.zeros_like(Cp)])
    rest = form.complement @ gamma
    return {
        "modalSize": np.array([float(form.size), dt]), "modalBlocks": form.blocks,
        "modalInput": form.projection @ gamma, "modalInputChange": form.projection[:, 2 * r:] @ Z,
        "modalShape": form.shape, "modalProjection": form.projection, "modalRest": rest,
        "modalRestChange": form.complement[:, 2 * r:] @ Z, "modalOutput": outputs @ form.shape,
        "modalOutputInput": outputs @ rest,
    }


def _model_source(matrices: dict[str, np.ndarray]) -> str:
    """The generated ``model.c``: numbers only (no text from the ROM file reaches the C code)."""
    arrays = "\n".join(_c_array(name, value) for name, value in matrices.items())
    step_map = _STEP_MAP_CALLS if "stepMap" in matrices else ""
    if "initialPositionInput" in matrices:
        step_map += "    addDense(assembly, MatrixX0Input, initialPositionInput, N_DOF, N_INPUTS);\n"
    if "modalSize" in matrices:
        step_map += _MODAL_CALLS.format(k=int(matrices["modalSize"][0]))
    return f"""/*
 * Generated by fmu-opinf; what the model is: modelDescription.xml and provenance.json.
 * Reduced second-order model  Mr q'' + Dr q' + Kr q = Br u + fr,  y = Cpr q + Cvr q' + Dur u + y0,
 * started at q = q0, q' = qdot0.  Matrices are stored row-major; reconstructed positions are
 * extra rows of Cpr (offsets in y0).
 */
#include "model.h"

{arrays}
static void addDense(Assembly *assembly, MatrixId id, const double values[], int rows, int cols) {{
    int i, j;

    for (i = 0; i < rows; i++) {{
        for (j = 0; j < cols; j++) {{
            if (values[i * cols + j] != 0.0) {{
                addEntry(assembly, id, i, j, values[i * cols + j]);
            }}
        }}
    }}
}}

Status assembleSystem(const double parameters[], Assembly *assembly, const char **message) {{
    (void)parameters;
    (void)message;

    addDense(assembly, MatrixM, reducedMass, N_DOF, N_DOF);
    addDense(assembly, MatrixD, reducedDamping, N_DOF, N_DOF);
    addDense(assembly, MatrixK, reducedStiffness, N_DOF, N_DOF);
    addDense(assembly, MatrixB, reducedInput, N_DOF, N_INPUTS);
    addDense(assembly, MatrixCp, reducedOutputPosition, N_OUTPUTS, N_DOF);
    addDense(assembly, MatrixCv, reducedOutputVelocity, N_OUTPUTS, N_DOF);
    addDense(assembly, MatrixF, reducedForce, N_DOF, 1);
    addDense(assembly, MatrixDu, reducedFeedthrough, N_OUTPUTS, N_INPUTS);
    addDense(assembly, MatrixY0, outputOffset, N_OUTPUTS, 1);
    addDense(assembly, MatrixX0, initialPosition, N_DOF, 1);
    addDense(assembly, MatrixV0, initialVelocity, N_DOF, 1);
{step_map}
    return OK;
}}
"""


def _identifier(path: Path) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", path.name[:-4] if path.suffix == ".fmu" else path.name)
    return name if re.match(r"^[A-Za-z_]", name) else "ROM_" + name


def _lookup(provenance: dict, keys: tuple[str, ...]) -> str:
    """First non-empty value of any of ``keys``, searching nested dicts breadth-first."""
    queue = [provenance]
    while queue:
        level = queue.pop(0)
        for key in keys:
            if level.get(key) not in (None, "", [], {}):
                value = level[key]
                return ", ".join(map(str, value)) if isinstance(value, (list, tuple)) else str(value)
        queue.extend(value for value in level.values() if isinstance(value, dict))
    return "unknown"


def _training_inputs(provenance: dict) -> str:
    """The training runs' inputs, e.g. ``impulse:amplitude=100,t0=2,width=0.5`` (``; `` between runs)."""
    runs = provenance.get("training_runs")
    if isinstance(runs, list):
        specs = [str(run.get("input_spec")) for run in runs if isinstance(run, dict) and run.get("input_spec")]
        if specs:
            return "; ".join(dict.fromkeys(specs))
    return _lookup(provenance, ("input_spec", "training_input", "signal"))


def _guid(pick: Any) -> str:
    """`` (GUID ...)`` of the source FMU for the description; "" where none is recorded (a set merged from several
    FMUs names none: :func:`fmu_opinf.snapshots._merge.merged_source`)."""
    guid = pick("fmu_guid", "guid", "source_guid")
    return "" if guid == "unknown" else f" (GUID {guid})"


def _description(rom: Any, r: int, reconstructed: list[str]) -> str:
    provenance = dict(getattr(rom, "provenance", None) or {})

    def pick(*keys: str) -> str:
        return _lookup(provenance, keys)

    dt = getattr(rom, "dt", None)
    source = pick("fmu_name", "source", "source_path")
    text = (f"Reduced second-order model (r={r}, {getattr(rom, 'basis_kind', 'unknown')} basis, "
            f"{getattr(rom, 'integrator', 'newmark')} integrator) learned by operator inference from "
            f"{Path(source).name if not source.startswith('builtin:') else source}{_guid(pick)}; "
            f"training input {_training_inputs(provenance)}; "
            f"fitted {pick('fit_date', 'date', 'created')}; training step dt="
            f"{'unknown' if dt is None else repr(float(dt))}")
    if reconstructed:
        text += f"; reconstructed positions {', '.join(reconstructed)}"
    return re.sub(r"[\x00-\x1f\x7f]", "?", text)  # provenance text is data: no control characters in XML


def rom_fmu_spec(rom: SecondOrderROM, identifier: str = "ROM",
                 reconstruct: Sequence[str | int] | None = None,
                 fmi_version: str = "2.0", step: float | None = None) -> SecondOrderFmuSpec:
    """Generator specification of the FMU of a reduced second-order model.

    Parameters
    ----------
    rom : SecondOrderROM
        Fitted ROM with ``Mr, Dr, Kr (r, r)``, ``Br (r, m)``, ``Cpr, Cvr (p, r)``, ``dt``,
        ``input_names``, ``output_names``, ``basis`` and ``provenance``.
    identifier : str, default="ROM"
        FMI model identifier.
    reconstruct : sequence of str or int, default=None
        Full-order positions (``"x[i]"`` or 1-based ``i``) added as outputs ``V[i, :] q``.
    fmi_version : {"2.0", "3.0"}, default="2.0"
        FMI version of the FMU.
    step : float, optional
        Communication step the FMU is made for (default: the training step ``dt``): the default
        experiment's step and, for an exact-integrator ROM, the step of its exact step map (the FMU then
        takes multiples of ``step``).

    Returns
    -------
    SecondOrderFmuSpec
    """
    r, m, p = _sizes(rom)
    matrices = {
        "Mr": _matrix(rom, "Mr", (r, r)),
        "Dr": _matrix(rom, "Dr", (r, r)),
        "Kr": _matrix(rom, "Kr", (r, r)),
        "Br": _matrix(rom, "Br", (r, m)),
        "Cpr": _matrix(rom, "Cpr", (p, r)),
        "Cvr": _matrix(rom, "Cvr", (p, r)),
    }
    dt = None if getattr(rom, "dt", None) is None else float(rom.dt)
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise DataError(f"ROM training step dt={dt} is not positive; refit the ROM")
    if step is not None:
        dt = _export_step(float(step), dt)
    from .rom import check_operators  # (here: the module loads without the fitting code, like _load_rom)

    check_operators(matrices["Mr"], matrices["Dr"], matrices["Kr"])
    _check_step_matrix(matrices, dt)
    names, rows, velocity_rows, offsets = _reconstruction_rows(rom, reconstruct, r)
    if names:
        _warn_if_reconstruction_is_poor(getattr(rom, "fit_info", None) or {})
    _warn_if_start_is_missed(rom)
    extra = {"fr": _vector(rom, "fr", r), "y0": _vector(rom, "y0", p), "q0": _vector(rom, "q0", r),
             "qdot0": _vector(rom, "qdot0", r),
             "Dur": np.zeros((p, m)) if getattr(rom, "Dur", None) is None else _matrix(rom, "Dur", (p, m))}
    input_names = [str(s) for s in (getattr(rom, "input_names", None) or [])] or None
    output_names = [str(s) for s in (getattr(rom, "output_names", None) or [])]
    if len(output_names) != p:
        output_names = [f"y[{i}]" for i in range(1, p + 1)]
    clash = set(names) & (set(output_names) | set(input_names or []))
    if clash:
        raise DimensionError(f"reconstructed position(s) {sorted(clash)} already name an input "
                             "or output of the ROM; drop them from reconstruct")
    description = _description(rom, r, names)
    provenance = dict(getattr(rom, "provenance", None) or {})
    if _warn_if_recording_warned(provenance):
        description += "; trained on a recording that fmu-opinf snapshots warned about (provenance.json)"
    _warn_if_merged(provenance)
    input_units, output_units = _declared_units(provenance, m, p)
    t_train_end = provenance.get("t_train_end")
    stop = float(t_train_end) if isinstance(t_train_end, (int, float)) and t_train_end > 0 else None
    if stop is not None and dt is not None:  # a whole number of steps: an importer's last step is not refused
        stop = dt * max(1, math.floor(stop / dt + 1e-9))
    start = _recorded_start_time(provenance)
    experiment = (start, None if stop is None else _round_time(start + stop, dt, start), dt)
    output_descriptions = (recorded_output_texts(provenance, output_names, "Cpr q + Cvr q' + Dur u + y0")
                           + [f"reconstructed full-order position {name}: " + _reconstruction_formula(rom)
                              for name in names])
    c_matrices = {
        "reducedMass": matrices["Mr"], "reducedDamping": matrices["Dr"],
        "reducedStiffness": matrices["Kr"], "reducedInput": matrices["Br"],
        "reducedOutputPosition": np.vstack([matrices["Cpr"], rows]),
        "reducedOutputVelocity": np.vstack([matrices["Cvr"], velocity_rows]),
        "reducedForce": extra["fr"],
        "reducedFeedthrough": np.vstack([extra["Dur"], np.zeros((len(names), m))]),
        "outputOffset": np.concatenate([extra["y0"], offsets]),
        "initialPosition": extra["q0"], "initialVelocity": extra["qdot0"],
    }
    feedthrough = _feedthrough_pattern(extra["Dur"], provenance, getattr(rom, "fit_info", None) or {})
    c_matrices["reducedFeedthrough"][:p] = np.where(feedthrough, extra["Dur"], 0.0)  # exactly what is declared
    dependencies = [[int(j) for j in np.flatnonzero(row)] for row in feedthrough] + [[] for _ in names]
    input_starts = _recorded_input_starts(provenance, m)
    start_gain = _steady_start_gain(matrices, provenance)
    if start_gain is not None:  # q = q0 + S (u - u_first): S u moves the start with the inputs initialized under
        gain, first_input = start_gain
        c_matrices.update(initialPosition=extra["q0"] - gain @ first_input, initialPositionInput=gain)
        description += ("; starts at its static equilibrium under the inputs set before initialization ends, "
                        "as the source does")
    if getattr(rom, "integrator", "newmark") == "exact":
        if dt is None:
            raise DataError("an exact-integrator ROM needs its training step dt; refit the ROM")
        try:
            phi, gamma = rom.step_map(dt)
        except (ValueError, np.linalg.LinAlgError):
            raise DataError(f"the ROM's exact step map at dt={dt:g} is not finite; {_SMALLER_STEP}") from None
        c_matrices.update(stepMap=phi, stepMapInput=gamma, stepMapSize=np.array([dt]))
    c_matrices.update(_modal_matrices(rom, c_matrices, dt))
    ranges = _declared_input_ranges(provenance, input_names or [f"u[{i}]" for i in range(1, m + 1)], input_starts)
    inputs = {"m": m, "input_names": input_names, "input_units": input_units, "input_starts": input_starts,
              "input_descriptions": recorded_input_texts(provenance, m),
              "input_display_units": _recorded_units(provenance, "input_display_units", m), "input_ranges": ranges,
              "input_nominals": _recorded_input_nominals(provenance, m),
              "input_quantities": _recorded_quantities(provenance, "input_quantities", m),
              "input_declared_types": _recorded_declared_types(provenance, "input_declared_types", m),
              **_ports(provenance, input_names or [], output_names, names, fmi_version)}
    held = _held_inputs(provenance, input_names, m)
    if held is not None:
        inputs, feedthrough = _keep_held_inputs(held, inputs, c_matrices, feedthrough, fmi_version)
        dependencies = [[int(j) for j in np.flatnonzero(row)] for row in feedthrough] + [[] for _ in names]
        if held.values:
            description += "; inputs held in training (refused at any other value): " + ", ".join(
                f"{name} = {value!r}" for name, value in held.values.items())
        provenance["rom_fmu_driven_inputs"] = [held.order[i] for i in held.position]
    parameters = _source_parameters(provenance, set(inputs["input_names"] or []) | set(output_names) | set(names),
                                    fmi_version)
    description += _parameters_text(provenance, parameters)
    _warn_if_settings_not_declared(provenance, parameters, inputs["input_names"] or [])
    state_names = rom_state_names(list(inputs["input_names"] or []) + output_names + names
                                  + [par.name for par in parameters])
    provenance["rom_fmu_states"] = list(state_names)
    provenance["default_test_input"] = _default_test_input(rom, dt, t_train_end)
    provenance["rom_fmu_order"] = _order_record(rom)
    provenance["rom_fmu_linear_fits"] = _linear_fits_record(rom)
    provenance["rom_fmu_moves_on_its_own"] = _moves_on_its_own_record(rom)
    provenance["rom_fmu_training_miss"] = _training_miss_record(rom)
    return SecondOrderFmuSpec(
        identifier=identifier, model_source=_model_source(c_matrices),
        n=r, p=p + len(names),
        output_names=output_names + names, state_names=state_names,
        state_label="reduced coordinate", description=re.sub(r"[\x00-\x1f\x7f]", "?", description),
        output_descriptions=output_descriptions, default_experiment=experiment, expose_states=True,
        extra_files={"provenance.json": _provenance_text(provenance)},
        fmi_version=fmi_version,
        output_units=output_units + [_position_unit(provenance)] * len(names),
        unit_definitions=_recorded_unit_definitions(provenance, set(input_units + output_units)),
        output_display_units=_recorded_units(provenance, "output_display_units", p) + [""] * len(names),
        step_multiple=dt if getattr(rom, "integrator", "newmark") == "exact" else None,
        stepping=getattr(rom, "integrator", "newmark"),
        output_dependencies=dependencies,
        initial_dependencies=dependencies if start_gain is None else None,   # (a steady start: y(0) follows u)
        parameters=parameters, fixed_parameters=True,
        output_ranges=_recorded_output_ranges(provenance, p, len(names)),
        output_nominals=_recorded_output_nominals(provenance, p, len(names)),
        output_quantities=_recorded_quantities(provenance, "output_quantities", p) + [""] * len(names),
        output_declared_types=_recorded_declared_types(provenance, "output_declared_types", p) + [""] * len(names),
        type_definitions=_recorded_type_definitions(provenance),
        enumeration_types=_enumeration_types(parameters, provenance, fmi_version),
        port_aliases=_port_aliases(provenance, inputs, output_names, fmi_version),
        **inputs,
    )


# ------------------------------------------------------- source parameters (audit 81b F1)

def _provenance_text(provenance: dict) -> str:
    """The FMU's ``provenance.json``: indented, but with the source's parameters (snapshots ``source_parameters``, one
    row per parameter, 5.2 MB of the file at 60,000 parameters) as a summary (:func:`_parameters_summary`).  The
    ROM file keeps the record whole and the model description declares them; neither compare nor export reads them
    back from the FMU."""
    snapshots = provenance.get("snapshots")
    if isinstance(snapshots, dict) and isinstance(snapshots.get("source_parameters"), dict):
        provenance = {**provenance, "snapshots": {**snapshots, "source_parameters": _parameters_summary(
            snapshots["source_parameters"])}}
    return json.dumps(provenance, indent=2, sort_keys=True, default=str) + "\n"


def _parameters_summary(record: dict) -> dict[str, Any]:
    """``{"count", "set", "sha256"}`` of a recorded ``source_parameters``: how many, the ``--set`` ones with their
    values, and the SHA-256 of the whole record as compact JSON (sorted keys), which tells two trainings apart."""
    import hashlib

    text = json.dumps(record, sort_keys=True, separators=(",", ":"), default=str)
    names, values = record.get("names"), record.get("values")
    given = record.get("set") if isinstance(record.get("set"), list) else []
    pairs = ({name: value for name, value in zip(names, values) if isinstance(name, str)}
             if isinstance(names, list) and isinstance(values, list) else {})
    return {"count": len(names) if isinstance(names, list) else 0, "sha256": hashlib.sha256(text.encode()).hexdigest(),
            "set": {str(name): pairs.get(name) for name in given if isinstance(name, str)}}


#: The source parameter types the ROM FMU declares as real variables (Float64; a Float32 one as Float32 on FMI 3).
_REAL_PARAMETER_TYPES = ("Real", "Float64", "Float32")


def _recorded_parameters(provenance: dict) -> dict[str, list[Any]] | None:
    """The source's parameters as the training set them (snapshots ``source_parameters``), checked as data: equal
    lengths, names strings, values finite numbers; None where none were recorded (files before 2026-12-07)."""
    snapshots = provenance.get("snapshots")
    record = snapshots.get("source_parameters") if isinstance(snapshots, dict) else None
    keys = ("names", "types", "values", "units")
    if not isinstance(record, dict) or not all(isinstance(record.get(k), list) for k in keys):
        return None
    names, types, values, units = (record[k] for k in keys)
    if not (len(names) == len(types) == len(values) == len(units)
            and all(isinstance(n, str) and isinstance(t, str) for n, t in zip(names, types))
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)):
        return None
    given = record.get("set") if isinstance(record.get("set"), list) else []
    enumerations = record.get("enumerations") if isinstance(record.get("enumerations"), dict) else {}
    return {"names": names, "types": types, "values": [float(v) for v in values], "units": units, "set": given,
            "enumerations": enumerations}


def _source_parameters(provenance: dict, taken: set[str], fmi_version: str) -> list[Parameter]:
    """The source's parameters, fixed at their training values, for the ROM FMU to declare (an importer that sets them
    as it set the source's then runs, and another value is refused in one log line): real ones as Float64 (a Float32
    one as Float32 on FMI 3), integer, Boolean and Enumeration ones with their type (:func:`_parameter_type`; an
    Enumeration with its recorded type, :func:`_enumeration_of`); one warning for those it cannot declare (a value its
    type cannot hold, an Enumeration without a checked type, a name an input or output has)."""
    record = _recorded_parameters(provenance)
    if record is None:
        return []
    kept, left_out, types = [], [], {}
    units = _units(record["units"], len(record["names"]))
    for name, kind, value, unit in zip(record["names"], record["types"], record["values"], units):
        declared = _parameter_type(kind, value, fmi_version)
        enumeration = _enumeration_of(record["enumerations"].get(name), value, fmi_version)
        if declared == "Enumeration" and (enumeration is None or types.setdefault(*enumeration) != enumeration[1]):
            declared = None   # (no checked type recorded, a value none of its items has, a type name taken)
        if declared is None or name in taken or not name.strip():
            left_out.append(name)
            continue
        given = "fixed at the value the training set" if name in record["set"] else ""   # (compact: hundreds)
        kept.append(Parameter(name, value, given, unit if declared in ("Float64", "Float32") else "", declared,
                              enumeration[0] if declared == "Enumeration" else ""))
    if left_out:
        warnings.warn(f"the ROM FMU does not declare the source parameters {_few(left_out)} (a type or value it cannot "
                      "declare, or named like an input or output): an importer that sets them on the ROM FMU fails",
                      FmuOpinfWarning, stacklevel=4)
    return kept


def _parameter_type(kind: str, value: float, fmi_version: str) -> str | None:
    """The type the ROM FMU declares a source parameter of type ``kind`` with (FMI 2 ``Integer`` and FMI 3 ``Int32``
    as ``Int32``; an FMI 3 integer type as itself on an FMI 3 ROM FMU, as ``Int32`` on an FMI 2 one; a Float32 as
    Float32 on FMI 3, as Float64 on FMI 2; an Enumeration as itself, :func:`_enumeration_of` checks its type), or None
    where it cannot: an unknown type, or a value the type cannot hold (:data:`fmu_opinf.fmus.INTEGER_RANGES`: an Int64
    beyond 2**53, an UInt32 beyond Int32 on FMI 2, a Boolean not 0 or 1)."""
    if kind == "Float32" and fmi_version == "3.0":
        return "Float32"
    if kind in _REAL_PARAMETER_TYPES:
        return "Float64"
    if kind == "Enumeration":
        return kind
    if kind == "Boolean":
        declared = "Boolean"
    elif kind == "Integer" or (kind in INTEGER_RANGES and fmi_version != "3.0"):
        declared = "Int32"
    elif kind in INTEGER_RANGES:
        declared = kind
    else:
        return None
    low, high = INTEGER_RANGES[declared]
    return declared if value == int(value) and low <= value <= high else None


def _enumeration_of(recorded: Any, value: float, fmi_version: str) -> tuple[str, list[tuple[str, int, str]]] | None:
    """``(type name, items)`` of an Enumeration parameter as the snapshots recorded its type (``source_parameters``
    ``enumerations``), checked as data (:func:`fmu_opinf.fmus.is_type_name`, :func:`fmu_opinf.fmus.enumeration_items`)
    with ``value`` one of its items'; None otherwise (files before api84 record none)."""
    if not isinstance(recorded, dict) or not is_type_name(recorded.get("type")):
        return None
    items = enumeration_items(recorded.get("items"), fmi_version)
    if items is None or value not in [number for _, number, _ in items]:
        return None
    return recorded["type"], items


def _enumeration_types(parameters: list[Parameter], provenance: dict, fmi_version: str) -> dict[str, list] | None:
    """The Enumeration types the declared parameters name (:func:`_enumeration_of`), by name; None where none do."""
    record = _recorded_parameters(provenance)
    found = {}
    for par in parameters:
        if par.type == "Enumeration" and record is not None:
            found[par.enumeration] = _enumeration_of(record["enumerations"].get(par.name), par.default, fmi_version)[1]
    return found or None


def _parameters_text(provenance: dict, parameters: list[Parameter]) -> str:
    """The description's part on the source's parameters: the ``--set`` ones with their values, and how many are
    declared fixed.  Said as what the training did, in neither vocabulary: an importer's user reads it, who may
    never run fmu-opinf, and the training may have been set from Python (``parameters=``) as well as by ``--set``."""
    record = _recorded_parameters(provenance)
    if record is None or not parameters:
        return ""
    given = [f"{name}={value!r}" for name, value in zip(record["names"], record["values"]) if name in record["set"]]
    text = f"; {len(parameters)} source parameter(s) declared fixed at their training values"
    return text + (f" (the training set {', '.join(given)})" if given else "")


def _warn_if_settings_not_declared(provenance: dict, parameters: list[Parameter], inputs: list[str]) -> None:
    """One line where the training's ``--set`` named variables that the ROM FMU does not declare (start values of
    states, ``mass[1].s``): the ROM FMU starts from the trained initial state and has no state start values."""
    snapshots = provenance.get("snapshots")
    settings = snapshots.get("fmu_settings") if isinstance(snapshots, dict) else None
    if not isinstance(settings, dict):
        return
    record = _recorded_parameters(provenance)
    declared = {par.name for par in parameters} | set(inputs) | set(record["names"] if record else [])
    missing = [str(name) for name in settings if str(name) not in declared]   # (a recorded one left out: said before)
    if missing and record is None:
        warnings.warn(f"the ROM file records no values of the source's parameters (snapshots recorded before "
                      f"2026-12-07): the ROM FMU declares none, though the training set {_few(missing)} "
                      f"({either('--set')}); record the snapshots again and refit to declare them", FmuOpinfWarning,
                      stacklevel=4)
    elif missing:
        warnings.warn(f"the training set {_few(missing)} ({either('--set')}), which the ROM FMU does not declare: it "
                      "starts from the trained initial state and has no start values of states; record and fit again "
                      f"with another {either('--set')} value to change them", FmuOpinfWarning, stacklevel=4)


# -------------------------------------------------------------- held inputs (audit 69 F4)

@dataclass(frozen=True)
class HeldInputs:
    """The source's inputs as the training recorded them (snapshots ``held_inputs``): ``order`` all of them in the
    source's order, ``position`` where each ROM input stands in it, ``values`` and ``units`` of the held ones."""

    order: list[str]
    position: list[int]
    values: dict[str, float]
    units: dict[str, str]


def _held_inputs(provenance: dict, input_names: list[str] | None, m: int) -> HeldInputs | None:
    """The held inputs to keep in the ROM FMU, or None: nothing held and the ROM's inputs in the source's order,
    a ROM without input names, or a ROM file that does not record the held values (one warning line: it fitted
    snapshots recorded before 2026-12-06, and the ROM FMU leaves the held inputs out as before)."""
    from .rom import held_input_names

    snapshots = provenance.get("snapshots")
    record = snapshots.get("held_inputs") if isinstance(snapshots, dict) else None
    held_names = held_input_names(provenance)
    input_names = list(input_names or [])
    if len(input_names) != m:
        return None
    if not isinstance(record, dict) or not _held_record_fits(record, input_names):
        if held_names:
            warnings.warn(f"the ROM file records no values for the inputs its training held ({_few(held_names)}): "
                          "the ROM FMU leaves them out; record the snapshots again and refit to keep them",
                          FmuOpinfWarning, stacklevel=4)
        return None
    values = {name: float(value) for name, value in record["values"].items()}
    varied = set(record.get("varied") or [])
    if varied:
        warnings.warn(f"the training held inputs {_few(sorted(varied))} at different values in different runs: the "
                      "ROM cannot follow them, and the ROM FMU leaves them out", FmuOpinfWarning, stacklevel=4)
    left_out = [name for name in held_names if name not in values and name not in varied]
    if left_out:
        warnings.warn(f"held inputs {_few(left_out)} are not real variables: the ROM FMU (real inputs only) does "
                      "not declare them", FmuOpinfWarning, stacklevel=4)
    order = [name for name in record["order"] if name not in varied]
    if not values and order == list(input_names):
        return None
    units = record.get("units") if isinstance(record.get("units"), dict) else {}
    return HeldInputs(order, [order.index(name) for name in input_names], values,
                      {name: _units([units.get(name)], 1)[0] for name in values})


def _held_record_fits(record: dict, input_names: list[str]) -> bool:
    """Whether a recorded ``held_inputs`` holds distinct names, the ROM's inputs among them, and a finite value for
    each of the others (data read from a file: checked before any of it is used)."""
    order, values, varied = record.get("order"), record.get("values"), record.get("varied", [])
    if not (isinstance(order, list) and all(isinstance(n, str) for n in order) and len(set(order)) == len(order)
            and isinstance(values, dict) and isinstance(varied, list)):
        return False
    return (set(input_names) <= set(order) and set(values) == set(order) - set(input_names) - set(varied)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    for v in values.values()))


def _few(names: list[str]) -> str:
    return ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")


#: The generated matrices with a column per input (``m``, or ``m + 1`` with the constant force last).
_INPUT_COLUMNS = ("reducedInput", "reducedFeedthrough", "initialPositionInput", "stepMapInput", "modalInput",
                  "modalInputChange", "modalRest", "modalRestChange", "modalOutputInput")


def _spread_columns(matrix: np.ndarray, position: list[int], total: int) -> np.ndarray:
    """``matrix`` with its first ``len(position)`` (input) columns moved to ``position`` among ``total`` input
    columns, zero for the held inputs; any further column (the constant force) stays last."""
    m = len(position)
    out = np.zeros((matrix.shape[0], total + matrix.shape[1] - m), dtype=matrix.dtype)
    out[:, position] = matrix[:, :m]
    out[:, total:] = matrix[:, m:]
    return out


def _keep_held_inputs(held: HeldInputs, inputs: dict[str, Any], c_matrices: dict[str, np.ndarray],
                      feedthrough: np.ndarray, fmi_version: str) -> tuple[dict[str, Any], np.ndarray]:
    """Every source input in the source's order: the held ones act on nothing (zero columns) and declare their
    held value as start and as their only allowed value (``min = max``), which the FMU enforces with a log line
    naming the input and the value (``spec.held_inputs``).  Returns the spec's input fields and the spread
    feedthrough pattern; ``c_matrices`` are spread in place."""
    total = len(held.order)
    for name in _INPUT_COLUMNS:
        if name in c_matrices:
            c_matrices[name] = _spread_columns(np.atleast_2d(c_matrices[name]), held.position, total)

    def spread(values: list[Any] | None, default: Any, of_held: Any) -> list[Any]:
        out = [of_held(name) if name in held.values else default for name in held.order]
        for j, i in enumerate(held.position):
            out[i] = values[j] if values is not None else default
        return out

    starts = spread(inputs["input_starts"], 0.0, held.values.get)
    fields = {
        "m": total, "input_names": list(held.order), "input_starts": starts,
        "input_units": spread(inputs["input_units"], "", held.units.get),
        "input_display_units": spread(inputs["input_display_units"], "", lambda name: ""),
        "input_ranges": spread(inputs["input_ranges"], (-math.inf, math.inf), lambda n: (held.values[n],) * 2),
        "input_nominals": spread(inputs["input_nominals"], math.nan, lambda name: math.nan),
        "input_quantities": spread(inputs["input_quantities"], "", lambda name: ""),
        "input_declared_types": spread(inputs["input_declared_types"], "", lambda name: ""),
        "held_inputs": [name in held.values for name in held.order],
        "input_descriptions": spread(inputs.get("input_descriptions"), None, lambda name: (
            f"input held at {held.values[name]!r} in training: the ROM is valid at that value only and refuses "
            "another")),
    }
    if fmi_version == "3.0":
        fields["input_ports"] = _spread_ports(inputs.get("input_ports"), held)
        fields["output_ports"] = inputs.get("output_ports")
    return fields, _spread_columns(feedthrough, held.position, total)


def _spread_ports(ports: list[dict[str, Any]] | None, held: HeldInputs) -> list[dict[str, Any]] | None:
    """The FMI 3 input variables with the held inputs: each recorded port where its elements stand together in the
    source's order, a held input a Float64 scalar; None (every input a Float64 scalar) where they do not."""
    if ports is None:
        return None
    from .sources import element_names

    driven = [held.order[i] for i in held.position]
    port_at, first = {}, 0
    for port in ports:
        size = math.prod(port["shape"]) if port["shape"] else 1
        members = element_names(port["name"], port["shape"]) if port["shape"] else [driven[first]]
        start = held.order.index(members[0])
        if held.order[start:start + size] != members:
            return None
        port_at[start] = (port, size)
        first += size
    out, i = [], 0
    while i < len(held.order):
        port, size = port_at.get(i, ({"name": held.order[i], "shape": [], "type": "Float64"}, 1))
        out.append(port)
        i += size
    return out


#: A feedthrough entry ``Dur[i, j]`` whose part of output ``i`` at the training inputs' size is at most this fraction
#: of that output's training motion is a least-squares round-off (1e-17 .. 1e-15 of it where the true entry is
#: zero), not a dependence: the exported FMU drops it and declares no dependence of output ``i`` on input ``j``.
NEGLIGIBLE_FEEDTHROUGH = 1e-10


def _feedthrough_pattern(Dur: np.ndarray, provenance: dict, fit_info: dict) -> np.ndarray:
    """Which entries of ``Dur`` (p, m) make an output depend on an input (``ModelStructure`` dependencies).

    A fitted ``Dur`` holds round-off where the source has no feedthrough.  An entry counts when
    ``|Dur[i, j]| * s_u > NEGLIGIBLE_FEEDTHROUGH * s_i``, with ``s_u`` the training inputs' RMS
    (``fit_info["scales"]["u"]``) and ``s_i`` output ``i``'s largest departure from its start over the training
    runs (``training_runs[*].output_peak``).  Where either is not recorded (a ROM built by hand, an older file),
    every non-zero entry counts: declaring a dependence that is not there is safe, leaving one out is not.
    """
    nonzero = Dur != 0
    scales = fit_info.get("scales") if isinstance(fit_info, dict) else None
    u_scale = scales.get("u") if isinstance(scales, dict) else None
    y_scale = _training_output_motion(provenance, Dur.shape[0])
    if (not isinstance(u_scale, (int, float)) or isinstance(u_scale, bool) or not math.isfinite(u_scale)
            or u_scale <= 0 or y_scale is None):
        return nonzero
    return nonzero & (np.abs(Dur) * float(u_scale) > NEGLIGIBLE_FEEDTHROUGH * y_scale[:, None])


def _training_output_motion(provenance: dict, p: int) -> np.ndarray | None:
    """Each output's largest departure from its start over the training runs (``training_runs[*].output_peak``),
    or None where a run lacks it or it does not fit (data read from a file: checked)."""
    runs = provenance.get("training_runs")
    if not isinstance(runs, list) or not runs:
        return None
    peaks = []
    for run in runs:
        peak = run.get("output_peak") if isinstance(run, dict) else None
        if (not isinstance(peak, list) or len(peak) != p
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
                           for v in peak)):
            return None
        peaks.append(peak)
    return np.max(np.asarray(peaks, dtype=float), axis=0)


#: ``export --reconstruct`` warns where the ROM's reconstructed training positions are more than this many times as
#: far off as their projection on its basis (and over 1e-3 relative RMS).
RECONSTRUCTION_MISS = 2.0


def _default_test_input(rom: Any, dt: float | None, t_train_end: Any) -> list[str] | None:
    """``compare``'s test input for this ROM on its default grid (training step, four times the training end) and
    why, for the FMU's provenance.json: where the FMU stands for the ROM, its matrices are not at hand."""
    from ._test_input import default_test_input
    from .errors import FmuOpinfError

    if not dt or not t_train_end:
        return None
    try:
        return list(default_test_input(rom, float(dt), float(dt) * round(4 * float(t_train_end) / float(dt))))
    except (FmuOpinfError, np.linalg.LinAlgError, TypeError, ValueError):
        return None


def _warn_if_reconstruction_is_poor(fit_info: dict) -> None:
    """One warning where the ROM reconstructs its own training positions much worse than its basis allows
    (``fit_info``'s ``training_position_error`` against ``training_projection_error``, fits since 2026-11-28):
    the output-error refinement fits the outputs, not the basis's coordinates (twelfth audit: the triple chain at
    r = 10, outputs to 4e-8, positions 14 % off where the basis allows 2.1 %; the SDP solution 2.2 %)."""
    error, best = fit_info.get("training_position_error"), fit_info.get("training_projection_error")
    if not isinstance(error, (int, float)) or not isinstance(best, (int, float)):
        return
    if error > 1e-3 and error > RECONSTRUCTION_MISS * best:
        warnings.warn(f"this ROM's reconstructed positions miss its training positions by {error:.2g} relative RMS, "
                      f"where its basis allows {best:.2g}: the output-error refinement fitted the outputs, not the "
                      "basis's coordinates; for reconstructed positions refit with --no-refine (the SDP solution, in "
                      "the basis's coordinates) or a larger --r", FmuOpinfWarning, stacklevel=3)


def _warn_if_recording_warned(provenance: dict) -> bool:
    """The warning ``snapshots`` gave on the ROM's training recording, again (audit 70 F4); whether there was one."""
    from .snapshots._notes import recorded_warning

    message = recorded_warning(provenance.get("snapshots"))
    if message:
        warnings.warn(message, FmuOpinfWarning, stacklevel=4)
    return bool(message)


def _warn_if_merged(provenance: dict) -> None:
    """The warning ``fit`` gave where the ROM's merged snapshot files differ (FMU, interface, settings), again: the
    exported FMU is one model fitted to all of them (audit 72 F3, F4: ``fit`` warned, ``export`` said nothing)."""
    from .snapshots._merge import repeated_merge_warning

    message = repeated_merge_warning(provenance.get("snapshots"))
    if message:
        warnings.warn(message, FmuOpinfWarning, stacklevel=4)


def _warn_if_start_is_missed(rom: Any) -> None:
    """The fit's warnings that the ROM's outputs at its start (:func:`fmu_opinf.fit.start_miss_warning`) or its
    free response from the start values (:func:`fmu_opinf.fit.free_response_warning`) miss the source's, again at
    export: the ROM FMU run with nothing connected shows those misses first (audit 69 F3, audit 77b F2)."""
    from .fit import free_response_warning, start_miss_warning

    info, names = getattr(rom, "fit_info", None) or {}, list(getattr(rom, "output_names", None) or ())
    for message in (start_miss_warning(info, names), free_response_warning(info, names)):
        if message:
            warnings.warn(message, FmuOpinfWarning, stacklevel=3)


def _steady_start_gain(matrices: dict[str, np.ndarray], provenance: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """:meth:`SecondOrderROM.steady_start` for the FMU's initialization, with a warning where the source's start
    follows its inputs but the ROM's cannot (its C start then stays the training start)."""
    from .rom import steady_start

    found = steady_start(provenance, matrices["Kr"], matrices["Br"])
    if isinstance(found, str):
        warnings.warn(f"{found}: the ROM FMU starts where the training started, whatever its inputs at "
                      "initialization", FmuOpinfWarning, stacklevel=3)
        return None
    return found


#: Base names of the exported FMU's reduced coordinates, their rates and their accelerations (``q[1]``, ...).
ROM_STATE_NAMES = ("q", "qdot", "qddot")


def rom_state_names(taken: Sequence[str]) -> tuple[str, str, str]:
    """Base names for the exported FMU's reduced states that no variable in ``taken`` collides with.

    ``q, qdot, qddot`` unless a source variable is itself called ``q[i]`` (robot joints often are); then
    ``rom.q, rom.qdot, rom.qddot``, else ``rom2.q``, ... .  The names chosen are stored in the FMU's
    ``provenance.json`` (``rom_fmu_states``), where ``compare`` reads them.

    Parameters
    ----------
    taken : sequence of str
        The inputs, outputs and reconstructed positions the FMU declares.

    Returns
    -------
    tuple of 3 str
    """
    for attempt in range(len(taken) + 1):
        prefix = ("", "rom.")[attempt] if attempt < 2 else f"rom{attempt}."
        bases = tuple(prefix + base for base in ROM_STATE_NAMES)
        if not any(name.startswith(tuple(f"{base}[" for base in bases)) for name in taken):
            return bases  # type: ignore[return-value]
    raise AssertionError("unreachable: each name blocks at most one prefix")


#: ``export --step`` within this factor of the training step (either way): beyond, the step map over- or
#: underflows, or an importer's step needs more than a billion ROM steps.
_STEP_RANGE = 1e6


def _export_step(step: float, dt: float | None) -> float:
    """The communication step of ``export --step``, checked against the ROM's training step ``dt``."""
    if not (np.isfinite(step) and step > 0):
        raise DataError(f"export step {step} is not a positive number; give the communication step in seconds")
    if dt is not None and not dt / _STEP_RANGE <= step <= dt * _STEP_RANGE:
        raise DataError(f"export step {step:g} is more than {_STEP_RANGE:g} times away from the ROM's training "
                        f"step {dt:g}; give a step between {dt / _STEP_RANGE:g} and {dt * _STEP_RANGE:g}")
    return step


def _units(value: Any, count: int) -> list[str]:
    """A recorded unit list if it is one unit name (or "") per variable, else no units; provenance is data, so
    anything but a plain unit name is dropped (:func:`fmu_opinf.fmus.is_unit_name`), with one warning each: an
    FMU shipped without a unit its source declared should not be a surprise (audit 68)."""
    if not isinstance(value, list) or len(value) != count:
        return [""] * count
    for unit in value:
        if unit not in ("", None) and not is_unit_name(unit):
            warnings.warn(f"the recorded unit {str(unit)[:60]!r} is not a plain unit name (1 to 40 letters, digits, "
                          "'_./*^()%+-' or printable non-ASCII signs): the ROM FMU declares its variable without "
                          "a unit", FmuOpinfWarning, stacklevel=2)
    return [u if is_unit_name(u) else "" for u in value]


def _declared_units(provenance: dict, m: int, p: int) -> tuple[list[str], list[str]]:
    """Units of the source's force inputs and outputs as recorded with the training snapshots."""
    return _recorded_units(provenance, "input_units", m), _recorded_units(provenance, "output_units", p)


def _recorded_units(provenance: dict, key: str, count: int) -> list[str]:
    """One unit name (or "") per variable as recorded with the training snapshots under ``key``."""
    snapshots = provenance.get("snapshots")
    snapshots = snapshots if isinstance(snapshots, dict) else {}
    return _units(snapshots.get(key), count)


#: Most dimensions of a recorded array port (a bound on data read from a file, before any product is formed).
_MAX_DIMENSIONS = 32


def _ports(provenance: dict, input_names: list[str], output_names: list[str], reconstructed: list[str],
           fmi_version: str) -> dict[str, Any]:
    """``input_ports`` and ``output_ports`` of an FMI 3 ROM FMU: the source's variables (arrays, Float32), so that
    the ROM FMU connects where the source did; reconstructed positions are Float64 scalars after them."""
    if fmi_version != "3.0":
        return {}
    inputs = _recorded_ports(provenance, "inputs", input_names)
    outputs = _recorded_ports(provenance, "outputs", output_names)
    if outputs is not None:
        outputs += [{"name": name, "shape": [], "type": "Float64"} for name in reconstructed]
    return {"input_ports": inputs, "output_ports": outputs}


def _recorded_ports(provenance: dict, key: str, names: list[str]) -> list[dict[str, Any]] | None:
    """The FMI 3 variables (arrays, Float32) that held ``names`` in the source, as recorded with the training
    snapshots (``fmi3_ports[key]``, :func:`fmu_opinf.sources.fmi3_ports`); None where none were recorded or they do not
    hold exactly these names in this order (the FMU then declares Float64 scalars).  Data, not code: every entry
    is checked."""
    from .sources import element_names

    snapshots = provenance.get("snapshots")
    recorded = snapshots.get("fmi3_ports") if isinstance(snapshots, dict) else None
    recorded = recorded.get(key) if isinstance(recorded, dict) else None
    if not isinstance(recorded, list):
        return None
    ports, expanded = [], []
    for port in recorded:
        if not isinstance(port, dict):
            return None
        name, shape, kind = port.get("name"), port.get("shape"), port.get("type")
        if (not isinstance(name, str) or kind not in ("Float64", "Float32") or not isinstance(shape, list)
                or len(shape) > _MAX_DIMENSIONS
                or not all(isinstance(d, int) and not isinstance(d, bool) and 1 <= d <= len(names) for d in shape)
                or math.prod(shape) > len(names)):
            return None
        ports.append({"name": name, "shape": list(shape), "type": kind})
        expanded += element_names(name, shape)
    return ports if expanded == list(names) else None


def _port_aliases(provenance: dict, inputs: dict[str, Any], output_names: list[str],
                  fmi_version: str) -> dict[str, list[str]] | None:
    """The source's FMI 3 ``<Alias>`` names of its scalar inputs and outputs (snapshots ``port_aliases``), for the FMI
    3 ROM FMU to declare on the same variables (audit 81b F2), checked as data: lists of strings keyed by a scalar
    port of the ROM FMU.  An FMI 2 export says in one line that it leaves them out (FMI 2 has no ``<Alias>``)."""
    snapshots = provenance.get("snapshots")
    recorded = snapshots.get("port_aliases") if isinstance(snapshots, dict) else None
    if not isinstance(recorded, dict):
        return None
    scalars = set()
    for ports, names in ((inputs.get("input_ports"), inputs["input_names"] or []),
                         (inputs.get("output_ports"), output_names)):
        scalars |= set(names) if ports is None else {port["name"] for port in ports if not port["shape"]}
    found = {name: [str(a) for a in names] for table in recorded.values() if isinstance(table, dict)
             for name, names in table.items()
             if name in scalars and isinstance(names, list) and all(isinstance(a, str) for a in names)}
    if found and fmi_version != "3.0":
        shown = [a for names in found.values() for a in names]
        warnings.warn(f"the source's FMI 3 alias names {_few(shown)} are not declared on the FMI 2 ROM FMU (FMI 2 has "
                      "no <Alias>); export with --fmi-version 3.0 to keep them", FmuOpinfWarning, stacklevel=3)
        return None
    return found or None


def _recorded_start_time(provenance: dict) -> float:
    """The FMU time at which the training runs started (snapshots ``start_time``, the source's
    ``DefaultExperiment/@startTime`` or ``--start-time``), 0 where none is recorded: the ROM FMU's default experiment
    starts there, as the source's does (audit 81b F3)."""
    snapshots = provenance.get("snapshots")
    value = snapshots.get("start_time") if isinstance(snapshots, dict) else None
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return 0.0


def _round_time(value: float, *steps: float | None) -> float:
    """``value`` rounded to the most decimals any of ``steps`` has (0.03: two), so that the XML says ``99.48``, not
    ``99.47999999999999`` (``repr`` of a product of steps; audit 81b F3); as it is where none has decimals to go by
    or one has more than 15."""
    places = [_decimals(step) for step in steps if step is not None]
    decimals = max(places, default=None)
    return round(value, decimals) if decimals is not None and 0 < decimals <= 15 else value


def _decimals(value: float) -> int:
    """The decimals of ``repr(value)`` (``0.03``: 2, ``2.0``: 0, ``1e-05``: 5)."""
    exponent = decimal.Decimal(repr(float(value))).normalize().as_tuple().exponent
    return max(0, -exponent) if isinstance(exponent, int) else 0


def _recorded_output_ranges(provenance: dict, p: int, extra: int) -> list[tuple[float, float]] | None:
    """The ``[min, max]`` the source declared for each output (snapshots ``output_min`` / ``output_max``), open for
    ``extra`` reconstructed positions after them, for the ROM FMU to declare (audit 81b F4: a ROM output outside
    them has left the source's range); None where no finite bound was recorded.  Read as the input ranges are
    (:func:`fmu_opinf.rom.input_ranges`: only finite numbers are bounds, a crossed pair none)."""
    from .rom import input_ranges

    snapshots = provenance.get("snapshots")
    snapshots = snapshots if isinstance(snapshots, dict) else {}
    low, high = input_ranges({"snapshots": {"input_min": snapshots.get("output_min"),
                                            "input_max": snapshots.get("output_max")}}, p)
    if not (np.isfinite(low).any() or np.isfinite(high).any()):
        return None
    return [(float(a), float(b)) for a, b in zip(low, high)] + [(-math.inf, math.inf)] * extra


def _recorded_output_nominals(provenance: dict, p: int, extra: int) -> list[float] | None:
    """The ``nominal`` the source declared for each output (snapshots ``output_nominal``, 0 for none), NaN where
    none and for the ``extra`` reconstructed positions; None where none were recorded."""
    snapshots = provenance.get("snapshots")
    values = snapshots.get("output_nominal") if isinstance(snapshots, dict) else None
    if not isinstance(values, list) or len(values) != p:
        return None
    return [float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf else math.nan
            for v in values] + [math.nan] * extra


def _recorded_quantities(provenance: dict, key: str, count: int) -> list[str]:
    """The ``quantity`` of each input or output the source declared (its own or its declared type's, e.g. ``Force``;
    snapshots ``input_quantities`` / ``output_quantities``), ``""`` where none or where the text is not a printable
    one of at most 100 characters (data read from a file)."""
    snapshots = provenance.get("snapshots")
    values = snapshots.get(key) if isinstance(snapshots, dict) else None
    if not isinstance(values, list) or len(values) != count:
        return [""] * count
    return [v if isinstance(v, str) and len(v) <= 100 and v.isprintable() else "" for v in values]


def _recorded_declared_types(provenance: dict, key: str, count: int) -> list[str]:
    """The ``declaredType`` of each input or output of the source (snapshots ``input_declared_types`` /
    ``output_declared_types``, e.g. ``Modelica.Units.SI.Force``), ``""`` where none or where the text is not a type
    name :func:`fmu_opinf.fmus.is_type_name` allows (data read from a file)."""
    snapshots = provenance.get("snapshots")
    values = snapshots.get(key) if isinstance(snapshots, dict) else None
    if not isinstance(values, list) or len(values) != count:
        return [""] * count
    return [v if is_type_name(v) else "" for v in values]


def _recorded_type_definitions(provenance: dict) -> dict[str, dict[str, str]]:
    """The source's real type definitions its ports name (snapshots ``type_definitions``), each checked again where
    the FMU is written (:func:`fmu_opinf.fmus.type_definition`); entries that are not of the recorded form dropped."""
    snapshots = provenance.get("snapshots")
    recorded = snapshots.get("type_definitions") if isinstance(snapshots, dict) else None
    if not isinstance(recorded, dict):
        return {}
    return {name: clean for name, value in recorded.items()
            if is_type_name(name) and (clean := type_definition(value)) is not None}


def _recorded_input_starts(provenance: dict, count: int) -> list[float] | None:
    """The source's input start values as recorded with the training snapshots (None where none were recorded,
    or they do not fit: the inputs then start at 0)."""
    snapshots = provenance.get("snapshots")
    recorded = snapshots.get("input_starts") if isinstance(snapshots, dict) else None
    if not isinstance(recorded, list) or len(recorded) != count:
        return None
    try:
        values = [float(v) for v in recorded]
    except (TypeError, ValueError):
        return None
    return values if all(math.isfinite(v) for v in values) else None


def _recorded_input_nominals(provenance: dict, count: int) -> list[float] | None:
    """The ``nominal`` the training source declared for each input (snapshots ``input_nominal``), NaN where it
    declared none, for the FMU to declare: fmu-opinf (or a master) then sizes the ROM FMU's inputs as the source's
    (audit 75, F7: the ROM FMU was pulsed at 100 where the source declared 1000).  None where no input has one (a
    ROM fitted before they were recorded).  The provenance is data read from a file: only a number above 0 counts."""
    snapshots = provenance.get("snapshots")
    values = snapshots.get("input_nominal") if isinstance(snapshots, dict) else None
    if not isinstance(values, (list, tuple)) or len(values) != count:
        return None
    out = [float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf else math.nan
           for v in values]
    return out if any(not math.isnan(v) for v in out) else None


def _declared_input_ranges(provenance: dict, names: list[str],
                           starts: list[float] | None) -> list[tuple[float, float]] | None:
    """The ``[min, max]`` the training source declared for each input (:func:`fmu_opinf.rom.input_ranges`), for the
    FMU to declare and enforce; None where no input has a finite bound (a ROM fitted before they were recorded:
    the FMU is as before).  A range that does not hold the input's start value (FMI requires it to) is left out
    with a warning."""
    from .rom import input_ranges

    low, high = input_ranges(provenance, len(names))
    for i, start in enumerate(starts or [0.0] * len(names)):
        if not low[i] <= start <= high[i]:
            warnings.warn(f"the training source declared input {names[i]} within [{low[i]:g}, {high[i]:g}], which "
                          f"does not hold its start value {start:g}: the ROM FMU declares no range for it",
                          FmuOpinfWarning, stacklevel=3)
            low[i], high[i] = -math.inf, math.inf
    if not (np.isfinite(low).any() or np.isfinite(high).any()):
        return None
    return [(float(a), float(b)) for a, b in zip(low, high)]


def _recorded_unit_definitions(provenance: dict, used: set[str] | None = None) -> dict[str, dict]:
    """The source's definitions of its units (base and display units) as recorded with the training snapshots;
    each is checked again when written (:func:`fmu_opinf.fmus.unit_definition`), and one of a unit in ``used``
    (the units the FMU's variables declare; only theirs are written) that fails it is said in one warning."""
    snapshots = provenance.get("snapshots")
    recorded = snapshots.get("unit_definitions") if isinstance(snapshots, dict) else None
    if not isinstance(recorded, dict):
        return {}
    kept = {name: value for name, value in recorded.items() if isinstance(name, str)}
    for name, value in kept.items():
        if unit_definition(value) is None and is_unit_name(name) and (used is None or name in used):
            warnings.warn(f"the recorded definition of unit {name!r} is not of the form fmu-opinf records (SI base "
                          "units with integer exponents, finite factor and offset, plain display unit names): the "
                          "ROM FMU declares the unit without its base units and display units", FmuOpinfWarning,
                          stacklevel=2)
    return kept


def _order_record(rom: SecondOrderROM) -> dict[str, Any]:
    """How the ROM's order was chosen (:func:`fmu_opinf.compare._training._order_chosen`), for ``compare`` on the
    FMU: its order note needs it, and the FMU does not carry the fit's report (audit 69 F6)."""
    from .compare._training import _order_chosen

    return _order_chosen(rom)


def _linear_fits_record(rom: SecondOrderROM) -> list[str]:
    """The outputs the fit found not linear in the states (:func:`fmu_opinf.compare._training._linear_fits`), for
    ``compare`` on the FMU: its note on them needs it, and the FMU does not carry the fit's report (audit 77a F1)."""
    from .compare._training import _linear_fits

    return _linear_fits(rom)


def _training_miss_record(rom: SecondOrderROM) -> dict[str, Any] | None:
    """What fit warned about the ROM's miss of its own training outputs
    (:func:`fmu_opinf.compare._training._training_miss_of`), for ``compare`` on the FMU to repeat it (audit 79a F1);
    None where fit did not warn."""
    from .compare._training import _training_miss_of

    return _training_miss_of(rom)


def _moves_on_its_own_record(rom: SecondOrderROM) -> bool:
    """Whether the ROM's training showed its source moving on its own (:func:`fmu_opinf.compare.moves_on_its_own`),
    for ``compare`` on the FMU: its default comparison then adds the free response (audit 77b F2)."""
    from .compare import moves_on_its_own

    return moves_on_its_own(rom)


def _position_unit(provenance: dict) -> str:
    """Unit of reconstructed positions: the one unit of all the source's positions if recorded, else none."""
    snapshots = provenance.get("snapshots")
    unit = snapshots.get("position_unit") if isinstance(snapshots, dict) else None
    return _units([unit], 1)[0]


# ------------------------------------------------------------------------- export

def check_output_name(path: Path, overwrite: bool) -> None:
    """Refuse an output name that is not ``.fmu``, a folder, or an existing file without ``overwrite``."""
    if path.suffix != ".fmu":
        raise FMUError(f"output path {path} must end in .fmu")
    if path.is_dir():
        raise FMUError(f"output path {path} is a directory; give a file name ending in .fmu")
    if path.exists() and not overwrite:
        raise FMUError(f"{path} exists; pass {either('--force')} to replace it")


def _prepare_output_folder(path: Path) -> None:
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise FMUError(f"cannot create the output folder {parent}: {error.strerror}; choose a "
                       "writable path") from error
    if not os.access(parent, os.W_OK | os.X_OK):
        raise FMUError(f"output folder {parent} is not writable; choose a writable path")


def export_fmu(rom: SecondOrderROM | str | os.PathLike, path: str | os.PathLike, fmi_version: str = "2.0",
               reconstruct: Sequence[str | int] | None = None, *, overwrite: bool = False,
               step: float | None = None) -> Path:
    """Export a reduced second-order model as a co-simulation FMU.

    Parameters
    ----------
    rom : SecondOrderROM or str or PathLike
        The fitted ROM, or the path of a ROM file (``SecondOrderROM.load``).
    path : str or PathLike
        The ``.fmu`` file to write; its stem becomes the model identifier.
    fmi_version : {"2.0", "3.0"}, default="2.0"
        FMI version of the co-simulation FMU.  FMI 3.0 declares the inputs and outputs as the source FMU did
        (recorded with the snapshots): an array recorded whole is one array variable, a Float32 variable stays
        Float32; FMI 2.0 has neither and names each value (``F[1]``).
    reconstruct : sequence of str or int, default=None
        Full-order positions to add as outputs, e.g. ``["x[1]", "x[300]"]`` or the source's own
        names (``"mass[3].s"``, ``"x10"``), computed through the basis as ``x_i = x_ref,i + V[i, :] q``.
    overwrite : bool, default=False
        Replace an existing file (``--force`` on the command line).
    step : float, optional
        Communication step the FMU is made for (``--step``; default: the training step).  A ROM of a
        continuous-time source steps by the exact step map of this step and accepts its multiples only,
        so an importer that runs at a finer step needs the FMU exported with that step.

    The FMU's default experiment runs over the training horizon (stopTime = last training time) with
    the training step.  Its inputs start at the source's start values and declare the source's units and
    ranges (:meth:`SecondOrderROM.input_ranges`): a value set outside a range is refused with fmi2Error /
    fmi3Error and a log line, as the source refused it (the ROM was trained within it).

    Returns
    -------
    Path
        The written FMU.  Without a C compiler or CMake the FMU holds sources only and a
        :class:`~fmu_opinf.errors.FmuOpinfWarning` says that it still needs compiling.

    Raises
    ------
    FileFormatError
        Missing or unreadable ROM file.
    DimensionError, DataError
        Inconsistent shapes, non-finite or non-definite matrices, bad ``reconstruct``.
    FMUError
        Unsupported FMI version (not 2.0 or 3.0), existing file without ``overwrite``, unwritable path,
        compilation failure.
    """
    if str(fmi_version) not in ("2.0", "3.0"):
        raise FMUError(f"fmi_version {fmi_version!r} is not supported; export with "
                       "fmi_version='2.0' or '3.0'")
    path = Path(path)
    check_not_input(path, [rom], "output", "path")   # (a ROM FMU given as the ROM: audit 81c F3)
    check_output_name(path, overwrite)
    with single_threaded():   # dense kernels of a few hundred rows: two BLAS threads collapse under load
        spec = rom_fmu_spec(_load_rom(rom), _identifier(path), reconstruct, str(fmi_version), step)
    _prepare_output_folder(path)   # created only once the arguments are known to be good
    if find_build_tools() is None:
        build_second_order_fmu(spec, path, compile=False)
        warnings.warn(f"{path} holds C sources only and still needs compiling: no C compiler or "
                      "CMake was found (install them and export again, or run "
                      "'fmpy compile' on the FMU)", FmuOpinfWarning, stacklevel=2)
        return path
    return build_second_order_fmu(spec, path)
