"""The two sides of a comparison: the ROM side (a ROM object, a ROM file or an exported ROM FMU: sizes, step,
provenance), the source's start state and held inputs given to both, and their outputs matched."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DimensionError, FmuOpinfError
from ._declared import _rom_fmu_metadata, _training_end

if TYPE_CHECKING:
    from ..signals import Signal


def _load_rom_side(rom: Any):
    """A ROM object, a ROM file, or an exported ROM FMU (path ending in .fmu)."""
    from ..rom import SecondOrderROM

    if isinstance(rom, SecondOrderROM):
        return rom
    path = Path(rom)
    if path.suffix.lower() == ".fmu":
        return path
    return SecondOrderROM.load(path)


def _held_at_start_values(signal: "Signal", source: Any, options: dict[str, Any]) -> "Signal":
    """``signal`` with its ``none`` channels held at the FMU source's start (or ``--set``) values, on both sides,
    as ``snapshots`` holds them and as the exported ROM FMU starts them.  Before, they were 0 here: a preload
    F = 10 N was compared at 0 N, away from the operating point of the training, and a parameter exposed as an
    input and driven in the training was set to 0 (audit of 2026-12-06: the stiffness, eps_y 1.45)."""
    from ..signals import NoInput, StackedSignal

    parts = signal.parts if isinstance(signal, StackedSignal) else [signal]
    if (not any(isinstance(part, NoInput) and part.n_inputs for part in parts) or str(source).startswith("builtin:")
            or Path(str(source)).suffix.lower() in (".h5", ".hdf5")):
        return signal
    from ..snapshots._inputs import as_signal
    from ..source import open_source

    keep = {k: v for k, v in options.items() if k in ("inputs", "parameters", "interface", "start_time")}
    fom = open_source(source, positions="", **keep)
    try:
        return as_signal(signal.spec, signal.n_inputs, fom) if fom.m == signal.n_inputs else signal
    finally:
        fom.close()


def _source_start(rom: Any, source: Any, signal: Any, t: np.ndarray,
                  options: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """The ROM's reduced initial state for the source's own start (its positions and velocities at ``t[0]`` after
    initialization, with the comparison's settings), or None to keep the ROM's stored one: a builtin or ROM
    source, a ROM without basis, a source whose training variables cannot be read, or a start the ROM cannot
    represent (then one warning).

    Without it the ROM started from the first training run's state while the source might start elsewhere
    (another ``--set`` start value, a ``start:`` column of a run table): third audit, 2026-11-26, a right ROM
    reported at max eps_y 9.8e-2 and 3.5e-3 where it reproduces the source to 1e-22.
    """
    if (str(source).startswith("builtin:") or Path(str(source)).suffix.lower() in (".h5", ".hdf5")
            or rom.basis is None):
        return None
    from ..snapshots._run import MemorySink, record_run
    from ..source import open_source

    keep = {k: v for k, v in options.items()
            if k in ("inputs", "outputs", "parameters", "interface", "tolerance", "start_time")}
    recorded = rom.provenance.get("snapshots") or {}
    for key, field_name in (("positions", "position_names"), ("velocities", "velocity_names")):
        pattern = _exact_names(recorded.get(field_name))  # the variables the training recorded: the basis rows
        if pattern:
            keep[key] = pattern
    try:  # a source whose state cannot be read this way (an exported ROM FMU) starts where the ROM does
        fom = open_source(source, **keep)
        run, failure = record_run(fom, signal, t[:2], MemorySink, True, bool(options.get("isolate", True)),
                                  "initial state of the source", say_events=False)  # isolated like compare's run
        fom.close()
    except FmuOpinfError:
        return None
    if failure is not None:
        return None
    x0, v0 = np.asarray(run.x0), None if fom.derived["xdot"] else np.asarray(run.v0)
    if x0.size != rom.basis.shape[0]:
        return None
    try:
        return rom.initial_state(x0, v0)
    except FmuOpinfError as exc:
        import warnings

        from ..errors import FmuOpinfWarning

        warnings.warn(f"the ROM starts from its training start, not the source's: {exc}", FmuOpinfWarning,
                      stacklevel=3)
        return None


def _exact_names(names: Any) -> str | None:
    """Recorded variable names as one pattern (exact names are patterns without wildcards), None if there are none
    or one could be read as a wildcard or does not come back whole from the patterns' own splitting (commas inside
    brackets, ``sensor[1,1]``, do)."""
    from ..sources._base import split_patterns

    if not (isinstance(names, list) and names and all(isinstance(n, str) and not set(n) & set("*?") for n in names)):
        return None
    joined = ",".join(names)
    return joined if split_patterns(joined) == names else None


def _fmu_path(source: Any) -> bool:
    """Whether ``source`` names an FMU, packed or unpacked (not a builtin model, not a ROM file)."""
    return not str(source).startswith("builtin:") and Path(str(source)).suffix.lower() not in (".h5", ".hdf5")


def _matching_outputs(fom_names: list[str], rom_names: list[str], by_name: bool) -> list[int]:
    """Rows of the ROM side's outputs that correspond to the source's: by position, or (an exported FMU with
    extra reconstructed outputs) by name."""
    if len(fom_names) == len(rom_names):
        return list(range(len(rom_names)))
    if by_name and set(fom_names) <= set(rom_names):
        return [rom_names.index(name) for name in fom_names]
    raise DimensionError(f"the source has {len(fom_names)} outputs but the ROM has {len(rom_names)}, and their "
                         "names do not match; compare a ROM with the model it was learned from")


def _rom_side_info(rom_side: Any) -> dict[str, Any]:
    """Sizes, step, training end and provenance of a ROM object or exported ROM FMU."""
    if isinstance(rom_side, Path):
        from ..source import FMUSource

        meta = _rom_fmu_metadata(rom_side)
        driven = meta.get("rom_fmu_driven_inputs")   # an FMU that keeps its training's held inputs: not driven
        pattern = "none" if driven == [] else _exact_names(driven)
        chosen = {"inputs": pattern} if pattern else {}
        fmu = FMUSource(rom_side, **_rom_fmu_variables(meta.get("rom_fmu_states")), **chosen)
        return {"m": fmu.m, "p": fmu.p, "r": fmu.n, "dt": meta.get("dt"), "output_names": list(fmu.output_names),
                "fmu_options": chosen,
                "input_names": list(fmu.input_names),
                "t_train_end": meta.get("t_train_end"), "provenance": {**fmu.provenance(), **meta}}
    prov = dict(getattr(rom_side, "provenance", {}) or {})
    return {"m": rom_side.m, "p": rom_side.p, "r": rom_side.r, "dt": rom_side.dt,
            "output_names": list(rom_side.output_names), "input_names": list(rom_side.input_names),
            "t_train_end": _training_end(prov), "provenance": prov}


#: Variable patterns of an exported ROM FMU (its reduced coordinates stand where positions would), for FMUs
#: exported before the names were recorded in their provenance.json (``rom_fmu_states``).
ROM_FMU_VARIABLES = {"positions": "q[*]", "velocities": "qdot[*]", "accelerations": "qddot[*]"}


def _rom_fmu_variables(states: Any) -> dict[str, str]:
    """The patterns of an exported ROM FMU's states from the base names its provenance.json records, if any."""
    if isinstance(states, list) and len(states) == 3 and all(isinstance(s, str) and s for s in states):
        return {kind: f"{base}[*]" for kind, base in zip(ROM_FMU_VARIABLES, states)}
    return dict(ROM_FMU_VARIABLES)
