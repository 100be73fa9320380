"""How an FMU steps, as far as fmu-opinf can tell: the one answer that fit, the snapshot stage and compare ask.

fmu-opinf writes two kinds of co-simulation FMU, both with ``generationTool="fmu-opinf"``: the benchmark FMUs
(:mod:`fmu_opinf.fmus`), which step by classical Newmark, and the ROM FMUs of ``fmu-opinf export``, which step by
their ROM's integrator: Newmark, or the exact hold step of a ROM of a continuous-time source.  A recording of a
Newmark FMU is fitted with the Newmark integrator; one of an exact-step FMU is the sampled response of a
continuous-time linear model, like an FMU of any other tool, and is fitted with the exact one (audit 75, F1: a ROM
re-fitted on an exact ROM FMU with Newmark was 1.2e-5..2.7e-5 of the output range off the original source, with
the exact integrator 1.4e-9..5.3e-9).

Since 2026-12-07 the FMUs fmu-opinf writes declare how they step in a vendor annotation::

    FMI 2.0: <VendorAnnotations><Tool name="fmu-opinf"><Model stepping="newmark|exact" .../></Tool>...
    FMI 3.0: <Annotations><Annotation type="fmu-opinf"><Model stepping="newmark|exact"/></Annotation>...

(one element: FMI 2.0's schema allows one element in a ``Tool``; a benchmark FMU's constraint kind is another
attribute of it, ``constraint="position|velocity"``, which :func:`fmu_opinf.sources.annotated_constraint` reads
from any element there)
and a recording keeps the declaration in its provenance (``fmu_stepping``).  A ROM FMU exported before says its
integrator in its description (``... (r=6, positions basis, exact integrator) learned by operator inference from
...``), which is read instead.  Any other fmu-opinf FMU written before declares nothing: it is taken for a Newmark
FMU, the rule before the declaration (right for the benchmark FMUs), and the fit says it cannot tell.
"""

from __future__ import annotations

import re
from typing import Any
from xml.etree import ElementTree as ET

__all__ = ["STEPPINGS", "TOOL", "stepping_of", "recorded_stepping", "declared_stepping", "stepping_annotation"]

#: The steppings an fmu-opinf FMU can declare (the ROM integrators, :data:`fmu_opinf.rom.INTEGRATORS`).
STEPPINGS = ("newmark", "exact")

#: ``generationTool`` of fmu-opinf's FMUs and the name of its vendor annotation.
TOOL = "fmu-opinf"


def stepping_of(generation_tool: Any, declared: Any) -> str:
    """How an FMU steps, from its ``generationTool`` and its declared stepping.

    Parameters
    ----------
    generation_tool : str
        The FMU's ``generationTool`` attribute (anything else counts as another tool's).
    declared : str
        The stepping its fmu-opinf annotation declares (:func:`declared_stepping`; ``""`` or None if none).

    Returns
    -------
    str
        ``"continuous"`` for another tool's FMU (a continuous-time model, integrated or stepped by its own
        solver); for an fmu-opinf FMU ``"newmark"`` or ``"exact"`` as it declares, ``"unknown"`` where it
        declares neither (written before the declaration).
    """
    if generation_tool != TOOL:
        return "continuous"
    return declared if declared in STEPPINGS else "unknown"


def recorded_stepping(provenance: dict[str, Any]) -> str:
    """How the source of a recording (its provenance, snapshot attributes) steps: ``"newmark"`` for the builtin
    simulator, else :func:`stepping_of` its FMU's recorded ``fmu_generation_tool`` and ``fmu_stepping``."""
    if provenance.get("source_kind") != "fmu":
        return "newmark"
    return stepping_of(provenance.get("fmu_generation_tool"), provenance.get("fmu_stepping"))


def declared_stepping(root: ET.Element) -> str:
    """The stepping an fmu-opinf vendor annotation of a model description declares, ``""`` if none (module
    docstring); an unknown value counts as none.  A ROM FMU exported before the annotation says its integrator in
    its description, which is read instead (:func:`_described_stepping`)."""
    for element in list(root.iter("Tool")) + list(root.iter("Annotation")):
        if TOOL not in (element.get("name"), element.get("type")):
            continue
        for child in element.iter():
            if child.get("stepping") in STEPPINGS:
                return str(child.get("stepping"))
    return _described_stepping(root)


#: The start of the description ``fmu-opinf export`` gives a ROM FMU since 2026-11-26 (:func:`fmu_opinf.export`'s
#: ``_description``): ``Reduced second-order model (r=6, positions basis, exact integrator) learned by ...``.
_ROM_DESCRIPTION = re.compile(r"Reduced second-order model \(r=\d+, \w+ basis, (newmark|exact) integrator\) learned "
                              r"by operator inference from ")


def _described_stepping(root: ET.Element) -> str:
    """The integrator an fmu-opinf ROM FMU written before the stepping annotation names in its description
    (audit 76 F4: an exact ROM FMU of then was fitted with Newmark, 1e-5 of range off, while its description said
    "exact integrator"); ``""`` for any other FMU.  Only one of :data:`STEPPINGS` is ever taken from the text."""
    if root.get("generationTool") != TOOL:
        return ""
    found = _ROM_DESCRIPTION.match(root.get("description") or "")
    return found.group(1) if found else ""


def stepping_annotation(stepping: str, fmi_version: str, constraint: str | None = None) -> str:
    """The vendor annotation declaring ``stepping`` (module docstring) and, where given, the constraint kind, as
    lines of a model description: FMI 2.0's ``VendorAnnotations``, FMI 3.0's ``Annotations`` element.  Both must be
    known words (:data:`STEPPINGS`; ``"position"``, ``"velocity"``): no other text reaches the XML."""
    if stepping not in STEPPINGS:
        raise ValueError(f"stepping {stepping!r} is not one of {', '.join(STEPPINGS)}")
    if constraint not in (None, "position", "velocity"):
        raise ValueError(f"constraint {constraint!r} is not 'position' or 'velocity'")
    kind = "" if constraint is None else f' constraint="{constraint}"'
    element = f'      <Model stepping="{stepping}"{kind}/>\n'
    if fmi_version.startswith("3"):
        return f'  <Annotations>\n    <Annotation type="{TOOL}">\n{element}    </Annotation>\n  </Annotations>\n'
    return f'  <VendorAnnotations>\n    <Tool name="{TOOL}">\n{element}    </Tool>\n  </VendorAnnotations>\n'
