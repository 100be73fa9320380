"""Reading an FMU's model description and resolving which variables are recorded."""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import FMUError
from ._base import CONSTRAINTS, match_names, natural_key

__all__ = ["REAL_TYPES", "read_description", "annotated_constraint", "binary_platform", "VariableSelection",
           "show_patterns"]

REAL_TYPES = ("Real", "Float64")


def read_description(path: Path) -> Any:
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


def annotated_constraint(path: Path) -> str | None:
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
                if kind in CONSTRAINTS:
                    return kind
    return None


def binary_platform(fmi_version: str) -> str:
    import fmpy

    return fmpy.platform if fmi_version.startswith("2") else fmpy.platform_tuple


class VariableSelection:
    """Resolve positions/velocities/accelerations/inputs/outputs of a model description."""

    def __init__(self, md: Any, path: Path) -> None:
        self.path = path
        self.reals = {v.name: v for v in md.modelVariables if v.type in REAL_TYPES}
        self.names = list(self.reals)
        # derivative links: state name -> its derivative variable
        self.der = {v.derivative.name: v for v in md.modelVariables if getattr(v, "derivative", None) is not None}

    def pattern(self, what: str, patterns: str | Sequence[str], required: bool) -> list[str]:
        names = match_names(patterns, self.names)
        if not names and required:
            examples = ", ".join(sorted(self.names, key=natural_key)[:6]) or "none"
            raise FMUError(f"{what} pattern {show_patterns(patterns)} matches no real variable of {self.path.name} "
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


def show_patterns(patterns: str | Sequence[str]) -> str:
    return repr(patterns if isinstance(patterns, str) else ",".join(patterns))
