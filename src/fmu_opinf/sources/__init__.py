"""Where snapshot data come from: the reference simulator or a co-simulation FMU, stepped one step at a time.

Modules: :mod:`._base` (the interface), :mod:`._builtin` (reference simulator), :mod:`._variables`
(model description and variable discovery), :mod:`._settings` (``--set`` values), :mod:`._resolve`
(what an FMU records, from its description alone), :mod:`._cosimulation` (co-simulation FMUs).  A
``_model_exchange`` driver with the same stepping interface belongs here too.

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
from typing import Any

from ..errors import InputSpecError
from ._base import Source, StepError, match_names, natural_key
from ._builtin import BUILTIN_SYSTEMS, BuiltinSource
from ._cosimulation import FMUSource
from ._resolve import Resolved, resolve_variables
from ._settings import parse_assignments

__all__ = [
    "Source",
    "BuiltinSource",
    "FMUSource",
    "StepError",
    "open_source",
    "match_names",
    "natural_key",
    "BUILTIN_SYSTEMS",
    "parse_assignments",
    "resolve_variables",
    "Resolved",
]


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
                raise InputSpecError(f"--{_FLAG.get(key, key)} applies to fmu sources, not to {text}")
        return BuiltinSource(name, **options)
    unknown = sorted(set(options) - set(_FMU_OPTIONS))
    if unknown:
        raise InputSpecError(f"--{unknown[0]} applies to builtin sources, not to the fmu {text}")
    return FMUSource(text, **options)


_FMU_OPTIONS = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "parameters",
                "settings")
_FLAG = {"parameters": "set", "settings": "set"}
