"""Model-exchange recordings of the paper's benchmark systems against the exact zero-order-hold solution (issue 12).

The benchmark systems (anchored chain with a rigid bar, triple chain with its velocity coupling) are built as
exporter-style FMUs offering model exchange (``lti_fmus.build_lti_fmu``: dense matrices, the constraint reduced
to an ODE by the exporter), recorded through :func:`fmu_opinf.snapshots.record` with the defaults (DOP853,
tolerance 1e-10) and compared with :func:`fmu_opinf.lti_fmus.zoh_response` (matrix exponential of the minimal
coordinates, independent of the FMU and of the integrator).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus, systems  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import ModelExchangeSource, open_source  # noqa: E402

pytestmark = pytest.mark.fmu

IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"

#: name -> (system, training step of the paper's benchmark, end time)
CASES = {"anchored": (lambda: systems.anchored_msd(12), 0.5, 200.0),
         "triple": (lambda: systems.triple_chain(6), 0.1, 40.0)}


def _dense(a) -> np.ndarray:
    return np.asarray(a.toarray() if hasattr(a, "toarray") else a, dtype=float)


def _model(name: str) -> lti_fmus.LinearMechanicalModel:
    system = CASES[name][0]()
    return lti_fmus.LinearMechanicalModel(
        M=_dense(system.M), D=_dense(system.D), K=_dense(system.K), B=_dense(system.B), Cp=_dense(system.Cp),
        Cv=_dense(system.Cv), G=_dense(system.G), constraint=system.constraint, name=f"Me{name.capitalize()}")


@pytest.fixture(scope="module")
def benchmark_fmus(request, tmp_path_factory) -> dict[str, lti_fmus.LtiFmu]:
    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-benchmarks") if cache is not None else tmp_path_factory.mktemp("lti-bench")
    return {name: lti_fmus.build_lti_fmu(_model(name), folder / f"{name}.fmu", interfaces=("me",))
            for name in CASES}


def _errors(run, ref) -> dict[str, float]:
    pairs = {"x": (run.x, ref.x), "xdot": (run.xdot, ref.v), "xddot": (run.xddot, ref.a), "y": (run.y, ref.y)}
    return {key: float(np.abs(np.asarray(a) - b).max() / np.abs(b).max()) for key, (a, b) in pairs.items()}


@pytest.mark.parametrize("name", list(CASES))
def test_model_exchange_recording_of_the_benchmark_matches_the_exact_solution(benchmark_fmus, name):
    # every mass, not only the exporter's states (the independent coordinates of the constrained system)
    source = open_source(benchmark_fmus[name].path, positions="mass[*].s", velocities="mass[*].v",
                         accelerations="mass[*].a")
    model = _model(name)
    assert isinstance(source, ModelExchangeSource)
    assert source.position_names == [f"mass[{i}].s" for i in range(1, model.n + 1)]
    _, dt, t_end = CASES[name]
    run = record(source, IMPULSE, dt, t_end, quiet=True).runs[0]
    u = np.asarray(run.u)
    ref = lti_fmus.zoh_response(model, run.t, np.hstack([u[:, 1:], u[:, -1:]]))
    errors = _errors(run, ref)
    # the issue asks for 1e-8; measured: anchored (g = 12) <= 7.2e-16, triple (n1 = 6) <= 2.9e-12 (accelerations)
    assert max(errors.values()) < 3e-11, errors
    assert run.attrs["fmi_interface"] == "me" and "DOP853" in run.attrs["integrator"]
