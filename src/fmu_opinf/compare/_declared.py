"""What the files of a comparison declare: the source FMU's units, display units and start values, and an exported
ROM FMU's description and bundled provenance.json."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FileFormatError, FmuOpinfError


@dataclass(frozen=True)
class DisplayUnit:
    """An output's declared ``displayUnit`` and its conversion from the output's unit, FMI's
    ``DisplayUnit_value = factor * Unit_value + offset`` (FMI 2.0 section 2.2.2, ``fmi3Unit.xsd``).

    The report plots and lists outputs in it, as a tool reading the FMU would show them (audit 81c, F10: a rad
    output with displayUnit deg was drawn in rad); the error measures, ratios, do not depend on it.
    """

    name: str
    factor: float
    offset: float = 0.0

    def values(self, y: np.ndarray) -> np.ndarray:
        """``y`` (in the output's unit) in this display unit."""
        return self.factor * np.asarray(y, dtype=float) + self.offset

    def difference(self, dy: float) -> float:
        """A difference ``dy`` of two values in the output's unit, in this display unit (the offset cancels)."""
        return abs(self.factor) * dy


def _declared_starts(source: Any) -> dict[str, str]:
    """The start values that the FMU ``source`` declares, by variable name ({} where it cannot be read)."""
    from ..sources._variables import read_description

    try:
        md = read_description(Path(str(source)))
    except FmuOpinfError:
        return {}
    return {v.name: v.start for v in md.modelVariables if v.start is not None}


def _is_rom_fmu(source: Any) -> bool:
    """Whether ``source`` is an FMU that 'fmu-opinf export' wrote (time-invariant, run from its own start)."""
    path = Path(str(source))
    return path.suffix.lower() == ".fmu" and path.is_file() and _bundled_provenance(path) is not None


def _bundled_provenance(path: Path) -> Any:
    """The provenance.json that 'fmu-opinf export' bundles in a ROM FMU (parsed), or None where there is none."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            names = [n for n in archive.namelist() if n.endswith("provenance.json")]
            return json.loads(archive.read(names[0])) if names else None
    except (OSError, zipfile.BadZipFile, ValueError, RecursionError):   # (a file nested past Python's limit)
        return None


def _declared_model(source: Any) -> Any:
    """The source FMU's :class:`~fmu_opinf.sources._variables.ModelInfo`, None for another source or an unreadable
    description (units are decoration: without them the figures are drawn in plain numbers)."""
    path = Path(str(source))
    if str(source).startswith("builtin:") or path.suffix.lower() != ".fmu" or not path.is_file():
        return None
    try:
        from ..sources._variables import ModelInfo

        return ModelInfo.from_path(path)
    except Exception:  # noqa: BLE001 - units are decoration: an unreadable description just has none
        return None


def _declared_variable(variables: dict[str, Any], name: str) -> Any:
    """The variable a recorded output name designates: itself, or the FMI 3 array ``y`` of an element ``y[2]``."""
    var = variables.get(name)
    if var is None and name.endswith("]") and "[" in name:  # an element of an array variable
        array = variables.get(name[:name.rindex("[")])
        var = array if array is not None and array.dims else None
    return var


def _printable(text: Any) -> str:
    return "".join(c for c in str(text or "") if c.isprintable())


def _declared_units(source: Any, names: list[str]) -> list[str] | None:
    """Units the source FMU declares for the named variables (its own or its type's), "" where none.

    Names are element names as recorded: an element ``y[2]`` of an FMI 3 array ``y`` has the array's unit.
    """
    model = _declared_model(source)
    if model is None:
        return None
    return [_printable(getattr(_declared_variable(model.by_name, name), "unit", None)) for name in names]


def _declared_display_units(source: Any, names: list[str]) -> list[DisplayUnit | None] | None:
    """The ``displayUnit`` the source FMU declares for each named variable (its own or its type's) where its unit's
    ``DisplayUnit`` definition gives the conversion, None where not (FMI: a display unit not defined is ignored).

    A ``relativeQuantity`` variable (a temperature difference) ignores the offset, as FMI says.
    """
    model = _declared_model(source)
    if model is None:
        return None

    def display(name: str) -> DisplayUnit | None:
        var = _declared_variable(model.by_name, name)
        defined = model.display_units.get(getattr(var, "unit", None) or "", {})
        chosen = getattr(var, "display_unit", None) or ""
        if chosen not in defined or not _printable(chosen):
            return None
        factor, offset = defined[chosen]
        return DisplayUnit(_printable(chosen), factor, 0.0 if var.relative_quantity else offset)

    found = [display(name) for name in names]
    return found if any(found) else None


def _training_end(provenance: dict[str, Any]) -> float | None:
    """Last training time recorded in a ROM's provenance, if any."""
    for key in ("t_train_end", "t_end"):
        if provenance.get(key) is not None:
            try:
                return float(provenance[key])
            except (TypeError, ValueError):   # (a damaged file's)
                return None
    snaps = provenance.get("snapshots")
    if isinstance(snaps, dict):
        return _training_end(snaps)
    return None


def _rom_fmu_metadata(path: Path) -> dict[str, Any]:
    """Step and training end of an exported ROM FMU (default experiment, bundled provenance.json); refuses an FMU
    that 'fmu-opinf export' did not write (a full model given where the ROM belongs)."""
    from ..sources._variables import read_description

    md = read_description(path)
    if md.generationTool != "fmu-opinf":
        raise FileFormatError(f"{path} is not a ROM FMU exported by fmu-opinf (generationTool "
                              f"{md.generationTool!r}); give the ROM (.h5 from 'fmu-opinf fit' or .fmu from "
                              "'fmu-opinf export') first and the full model second")
    meta: dict[str, Any] = {"rom_fmu": str(path), "rom_fmu_guid": md.guid}
    if md.defaultExperiment is not None and md.defaultExperiment.stepSize:
        meta["dt"] = float(md.defaultExperiment.stepSize)
    provenance = _bundled_provenance(path)
    if isinstance(provenance, dict):
        meta["t_train_end"] = _training_end(provenance)
        meta["rom_fmu_states"] = provenance.get("rom_fmu_states")
        meta["rom_fmu_driven_inputs"] = provenance.get("rom_fmu_driven_inputs")
        if isinstance(provenance.get("snapshots"), dict):
            meta["snapshots"] = provenance["snapshots"]  # the training's variable selection
        meta["default_test_input"] = provenance.get("default_test_input")
        meta["training_runs"] = provenance.get("training_runs")   # (their output peaks: the check after the run)
        if isinstance(provenance.get("fit_settings"), dict):   # (how the fit read a warned recording: audit 71 F7)
            meta["fit_settings"] = provenance["fit_settings"]
        # what the fit found, for the notes and rows of a compare on the FMU (each judged where it is read)
        for key in ("rom_fmu_order", "rom_fmu_linear_fits", "rom_fmu_moves_on_its_own",
                    "rom_fmu_training_miss"):
            meta[key] = provenance.get(key)
    return meta
