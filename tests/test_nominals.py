"""Recording an FMU whose declared state nominals or velocity states do not fit its motion, against exact solutions.

Audit 2026-11-27 (finding 5): an FE-like export with state nominals spread over 1e-6 .. 1e3.  The reference is
:func:`fmu_opinf.lti_fmus.zoh_response` (matrix exponential of the minimal coordinates, independent of the FMU and of
the integrator).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import ModelExchangeSource, open_source  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

MODEL = lti_fmus.chain_model(3)


@pytest.fixture(scope="module")
def generic_fmu(request, tmp_path_factory) -> Path:
    """A 3-mass chain, model exchange only, states x1 .. x6 with ``der(x1) .. der(x6)`` of their own whose model
    structure pairs them (``der(x1)`` depends on ``x4`` alone), as generic LTI exporters write it."""
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("nominals") if cache is not None else tmp_path_factory.mktemp("nominals")
    return lti_fmus.build_lti_fmu(MODEL, folder / "chain3.fmu", naming="generic", interfaces=("me",)).path


def _exact(run) -> lti_fmus.ZohResponse:
    """The exact response to the run's inputs: ``run.u[:, i+1]`` is held over ``[t_i, t_{i+1}]``."""
    return lti_fmus.zoh_response(MODEL, run.t, np.hstack([run.u[:, 1:], run.u[:, -1:]]))


def _relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def test_a_careless_nominal_does_not_loosen_the_integration(generic_fmu, monkeypatch):
    """Nominals of 1e9 on states moving by about 0.05 (what fmiGetNominalsOfContinuousStates returns): the floor of
    the absolute tolerance was 1e-6 of the nominal, and the recording was 3.8e-9 off the exact solution instead of
    1.0e-10 with unit nominals; a nominal may tighten the floor, never loosen it."""
    signal, dt, t_end = "impulse:amplitude=1,t0=2,width=0.5", 0.1, 30.0
    plain = record(str(generic_fmu), signal, dt, t_end, quiet=True).runs[0]
    monkeypatch.setattr(ModelExchangeSource, "_nominals", lambda self: np.full(self.nx, 1e9))
    careless = record(str(generic_fmu), signal, dt, t_end, quiet=True).runs[0]
    reference = _exact(careless)
    assert _relative(careless.x, reference.x) < 3e-10   # measured 1.05e-10 (3.8e-9 before)
    assert _relative(careless.xdot, reference.v) < 3e-10
    assert np.array_equal(careless.x, plain.x)   # a nominal above 1 changes nothing
