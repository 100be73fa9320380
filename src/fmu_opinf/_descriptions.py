"""The source's descriptions of its inputs and outputs, as recorded with the snapshots, for the exported ROM FMU.

Modelica and FE exporters describe every port ("Kraft am Lager in µN ..."); the ROM FMU replaced them with its own
texts (audit 79a, F4).  ``fmu-opinf snapshots`` records them (``input_descriptions``, ``output_descriptions``
among the snapshot file's attributes, one per recorded input and output, "" where the source has none), ``fit``
carries them in the ROM's provenance, and ``export`` declares them: an input's as the source's text, an output's
followed by the ROM's formula.  Files without them (older recordings) keep the ROM's own texts.  The text is
data from the FMU: characters XML 1.0 cannot hold (and DEL) become ``?`` (the export's quoting escapes the rest,
``quoteattr``), and a text is cut at :data:`MAX_CHARACTERS`.
"""

from __future__ import annotations

import re
from typing import Any

__all__ = ["MAX_CHARACTERS", "recorded_descriptions", "input_descriptions", "output_descriptions"]

#: Longest description kept from a recording (a modelDescription is data: a bound on what is repeated).
MAX_CHARACTERS = 1000
#: What XML 1.0 cannot hold even as a character reference, and DEL (:func:`fmu_opinf.fmus._check_xml_characters`).
_UNFIT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ud800-\udfff\ufffe\uffff]")


def recorded_descriptions(provenance: dict[str, Any], key: str, count: int) -> list[str]:
    """The ``count`` descriptions recorded under ``key`` with the training snapshots, cleaned; ``[""] * count``
    where the recording has none, or not one per variable (a file damaged or of another selection)."""
    snapshots = provenance.get("snapshots")
    values = snapshots.get(key) if isinstance(snapshots, dict) else None
    if not isinstance(values, (list, tuple)) or len(values) != count:
        return [""] * count
    return [_clean(v) if isinstance(v, str) else "" for v in values]


def _clean(text: str) -> str:
    text = _UNFIT.sub("?", text.strip())
    return text if len(text) <= MAX_CHARACTERS else text[:MAX_CHARACTERS - 3] + "..."


def input_descriptions(provenance: dict[str, Any], m: int) -> list[str | None]:
    """The ROM FMU's input descriptions: the source's text, None (the ROM's own) where it has none."""
    return [text or None for text in recorded_descriptions(provenance, "input_descriptions", m)]


def output_descriptions(provenance: dict[str, Any], names: list[str], formula: str) -> list[str]:
    """The ROM FMU's output descriptions: ``"<source's text> (ROM: <formula>)"``, else the ROM's own
    ``"ROM output <name>: <formula>"``."""
    texts = recorded_descriptions(provenance, "output_descriptions", len(names))
    return [f"{text} (ROM: {formula})" if text else f"ROM output {name}: {formula}"
            for name, text in zip(names, texts)]
