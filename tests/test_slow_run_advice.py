"""The advice of the slow-run warning of model exchange, by what the stiffness probe measured (audit 77b, F3).

A dense 1198-state chain (spectral radius 0.316 1/s, ``rho h`` = 0.016 at the communication step 0.05 s) spent
280 s in the automatic window's pilot runs, and the warning blamed stiffness, friction or single precision and
advised ``--interface cs``, which took twice as long (26.0 s against 12.8 s for 20 s of model time).  Where the
probe says the model is not stiff and the steps are near the communication step, the warning now names the
derivative's cost (states, milliseconds per call) and ``--dt``/``--t-end`` or ``--me-method linear``.  The timings
are set by hand (the audit's figures), so the message choice is checked without a 30-second run.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.sources import _integrators
from fmu_opinf.sources._model_exchange import ModelExchangeSource

#: The audit's anchored chain: 1198 states, rho 0.316 1/s, about 0.37 ms per derivative call.
AUDIT = (0.316, 3.7e-4)


def _warning(tmp_path, monkeypatch, measured, h: float = 0.039, name: str = "DOP853", cosimulation=True) -> str:
    """The one slow-run warning of a stand-in source of 1198 states at t = 91.35 of a run to 157.95 at the
    communication step 0.05 s (the audit's), its integrator ``name`` at step ``h``."""
    monkeypatch.setattr(_integrators, "_SLOW_RUN_INTEGRATOR_SECONDS", 30.0)
    source = SimpleNamespace(path=tmp_path / f"Chain{id(measured)}{h}{name}.fmu", nx=1198, start_time=0.0,
                             _t=np.arange(0.0, 157.95 + 0.025, 0.05), _integrator_seconds=31.0,
                             md=SimpleNamespace(coSimulation=object() if cosimulation else None))
    if measured is not None:
        source._stiffness_measured = measured
    with pytest.warns(FmuOpinfWarning) as seen:
        ModelExchangeSource._warn_slow_run(source, name, 91.3, 91.35, 91.35, h)
    (text,) = [str(w.message) for w in seen if "has spent" in str(w.message)]
    return " ".join(text.split())


def test_a_model_that_is_not_stiff_is_told_the_cost_of_its_derivative_and_not_co_simulation(tmp_path, monkeypatch):
    """rho h = 0.016 and steps of 0.039 s in a step of 0.05 s: the cost is the derivative, 1198 states at 0.37 ms a
    call; the remedies skip the pilots or take the exact step.  Before: "a stiff model holds it to its stability
    limit ... record by co-simulation (--interface cs)"."""
    text = _warning(tmp_path, monkeypatch, AUDIT)
    assert "the model is not stiff (spectral radius about 0.32 1/s, 0.016 times the step)" in text, text
    assert "1198 states at 0.37 ms per call, 12 calls per DOP853 step" in text
    assert "give --dt and --t-end or dt= and t_end=" in text and "--me-method linear" in text
    assert "co-simulation does not help" in text
    assert "--interface cs" not in text and "stability limit" not in text and "Coulomb" not in text


def test_a_stiff_model_keeps_the_stiffness_advice(tmp_path, monkeypatch):
    """rho h = 10 (the audit's FE1000 case, where the warning was apt): the text is as before."""
    text = _warning(tmp_path, monkeypatch, (200.0, 3.7e-4), h=0.004)
    assert "a stiff model holds it to its stability limit" in text
    assert "record by co-simulation (--interface cs or interface='cs')" in text and "Coulomb friction" in text
    assert "not stiff" not in text and "ms per call" not in text


def test_an_unmeasured_model_keeps_the_stiffness_advice(tmp_path, monkeypatch):
    """No stiffness estimate (--me-method dop853 skips the probe): nothing to tell the regimes apart by."""
    text = _warning(tmp_path, monkeypatch, None)
    assert "a stiff model holds it to its stability limit" in text and "--interface cs" in text


def test_collapsing_steps_of_a_model_that_is_not_stiff_point_to_jumps_not_stiffness(tmp_path, monkeypatch):
    """rho h small but steps of 1e-6 s in a step of 0.05 s: jumps or rounding, not stiffness and not the cost."""
    text = _warning(tmp_path, monkeypatch, AUDIT, h=1e-6)
    assert "the model is not stiff" in text and "Coulomb friction" in text and "loosen --tolerance" in text
    assert "stability limit" not in text and "ms per call" not in text


@pytest.mark.parametrize("h", [0.039, math.nan])
def test_implicit_methods_are_pointed_to_the_default_integrator(tmp_path, monkeypatch, h):
    text = _warning(tmp_path, monkeypatch, AUDIT, h=h, name="BDF")
    assert "record with --me-method auto" in text and "stability limit" not in text
