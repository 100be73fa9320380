"""What each side's time measured, for the speed-up of a comparison."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def _timed_description(side: Any, isolate: bool = True, provenance: dict | None = None) -> str:
    """What :func:`~fmu_opinf.compare._simulate.simulate_outputs` times for a model (the loop only: no loading,
    compilation or set-up); ``provenance`` of the run, if known, says how an FMU was driven."""
    from ..rom import SecondOrderROM

    if isinstance(side, SecondOrderROM) or Path(str(side)).suffix.lower() in (".h5", ".hdf5"):
        return ("ROM simulated in Python, in this process (SecondOrderROM.simulate, outputs only: the step map "
                "applied in blocks of steps as matrix products, the reduced states not formed; input sampling "
                "and step-map set-up included)")
    if str(side).startswith("builtin:"):
        return f"{side} simulated in Python (the reference Newmark stepper, one sparse solve per step)"
    where = "in a separate process, its stepping loop alone" if isolate else "in this process"
    provenance = provenance or {}
    if provenance.get("fmi_interface") == "me":
        return (f"FMU {Path(str(side)).name} integrated by model exchange from Python {where} (per step: input "
                f"set, {provenance.get('integrator', 'the ODE integrated')}, outputs read)")
    from .._stepping import stepping_of

    tool = provenance.get("fmu_generation_tool", "fmu-opinf")
    again = ", input set again" if stepping_of(tool, provenance.get("fmu_stepping")) == "continuous" else ""
    return (f"FMU {Path(str(side)).name} stepped through FMI from Python {where} (per step: input set when "
            f"changed, one step{again}, outputs read)")


def _timed(source: Any, rom_side: Any, isolate: bool = True, fom_provenance: dict | None = None) -> dict[str, Any]:
    """What each side's time measured; like with like when both are FMUs stepped by co-simulation (a full model
    integrated by model exchange against the ROM FMU's co-simulation steps is not: eleventh audit, F9)."""
    fmu = [not str(side).startswith("builtin:") and Path(str(side)).suffix.lower() == ".fmu"
           for side in (source, rom_side)]
    model_exchange = (fom_provenance or {}).get("fmi_interface") == "me"
    return {"fom": _timed_description(source, isolate, fom_provenance), "rom": _timed_description(rom_side, isolate),
            "like_with_like": all(fmu) and not model_exchange, "clock": "wall time (time.perf_counter)"}
