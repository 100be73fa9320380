"""What an FMU source records, decided from the model description alone (no binary needed).

Shared by every FMU driver (co-simulation here; a model-exchange driver uses the same): the user's
settings are typed first (array sizes may depend on structural parameters), then arrays are expanded
and the positions, velocities, accelerations, force inputs, held inputs and outputs are chosen.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from ._settings import Setting, parse_assignments, resolve_settings
from ._variables import (Element, ModelInfo, Selection, discover, held_outputs, outputs_left_out,
                         parameter_like_inputs, select_inputs, select_outputs)

__all__ = ["Resolved", "resolve_variables"]


@dataclasses.dataclass
class Resolved:
    """The recorded variables of a model and the settings to apply."""

    model: ModelInfo
    settings: list[Setting]
    structural: dict[str, int]
    selection: Selection
    forces: list[Element]
    held: list[Element]
    outputs: list[Element]
    #: held inputs that the default selection left out as parameters exposed as inputs (a non-zero start value in
    #: no force unit, or a coefficient's unit); empty when the force inputs were named
    parameter_like: list[Element] = dataclasses.field(default_factory=list)
    #: declared outputs the default selection left out, name -> why (``"discrete"``: held between samples; else
    #: the type of one that is not real); empty when the outputs were named
    outputs_left_out: dict[str, str] = dataclasses.field(default_factory=dict)
    #: outputs held between samples that ``--outputs`` named: recorded, though no continuous output map follows them
    held_outputs: list[Element] = dataclasses.field(default_factory=list)


def resolve_variables(model: ModelInfo | str | Path, positions: str | None = None, velocities: str | None = None,
                      accelerations: str | None = None, inputs: str | None = None, outputs: str | None = None,
                      settings: Any = None) -> Resolved:
    """Choose the recorded variables of a model description.

    Parameters
    ----------
    model : ModelInfo or path
        A parsed model description, or an ``.fmu``, extracted FMU directory or ``modelDescription.xml``.
    positions, velocities, accelerations, inputs, outputs : str, optional
        Patterns as for :class:`~fmu_opinf.sources.FMUSource`.
    settings : dict or list of "NAME=VALUE", optional
        The ``--set`` values.

    Returns
    -------
    Resolved
    """
    if not isinstance(model, ModelInfo):
        model = ModelInfo.from_path(model)
    typed, structural = resolve_settings(model, parse_assignments(settings))
    elements = model.elements(structural)
    selection = discover(model, elements, positions, velocities, accelerations)
    given = {setting.var.name for setting in typed}
    forces, held = select_inputs(model, elements, inputs, given)
    parameter_like = parameter_like_inputs(model, held, given) if inputs is None else []
    chosen = select_outputs(model, elements, outputs)
    left_out = outputs_left_out(elements) if outputs is None else {}
    return Resolved(model, typed, structural, selection, forces, held, chosen, parameter_like, left_out,
                    held_outputs(chosen))
