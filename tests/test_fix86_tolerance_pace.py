"""Audit86 F7: a co-simulation FMU whose embedded solver follows the tolerance fmu-opinf passes.

``stiff_cs``: three masses, a 1e-4 kg mass on a 1e4 N/m spring, exported as co-simulation only with RK4 substeps
that follow the tolerance of ``setupExperiment`` (``w h = tol**(1/4)``).  At the default 1e-10 the step check took
183 s and the pilots were projected at about 50 min, with progress lines only; ``--tolerance 0`` (the FMU's own,
1e-4) recorded in 183 s in all.  Now, after the first run over ``SLOW_RUN_SECONDS``, the run's first samples are
timed at the FMU's own tolerance, and where that is ``TOLERANCE_BOUND`` times faster one line names the FMU, the
tolerance, both paces and the fixes in both vocabularies.  The default tolerance is unchanged.

The tests lower ``SLOW_RUN_SECONDS`` so that a run of about a second counts as slow; the reference pace is an
independent timing of the same FMU at both tolerances (CPU time, in this process).
"""

from __future__ import annotations

import re
import time
import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import _size
from fmu_opinf.snapshots._rates import time_grid
from fmu_opinf.snapshots._run import MemorySink, record_run
from fmu_opinf.source import open_source

DT, SAMPLES = 0.01, 121
PULSE = "impulse:amplitude=1,t0=0.1,width=0.5"


def _stiff(m3: float = 1e-4, k3: float = 1e4) -> lti_fmus.LinearMechanicalModel:
    """audit86's ``stiff``: masses 1, 1, ``m3`` on springs 1, 1, ``k3``; the force on mass 2."""
    m, k = np.array([1.0, 1.0, m3]), np.array([1.0, 1.0, k3])
    K = np.diag(k + np.r_[k[1:], 0]) - np.diag(k[1:], 1) - np.diag(k[1:], -1)
    M = np.diag(m)
    B = np.zeros((3, 1))
    B[1, 0] = 1.0
    Cp = np.zeros((2, 3))
    Cp[0, 2] = Cp[1, 0] = 1.0
    return lti_fmus.LinearMechanicalModel(M=M, D=0.02 * M + 1e-5 * K, K=K, B=B, Cp=Cp, Cv=np.zeros((2, 3)),
                                          name="StiffCs")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """The stiff model as co-simulation with RK4 substeps following the tolerance, and with one RK4 step per
    communication step (which no tolerance changes)."""
    folder = tmp_path_factory.mktemp("f7")
    paths = {}
    for method in ("accurate", "rk4"):
        model = _stiff() if method == "accurate" else _stiff(m3=1.0, k3=1.0)   # (rk4: stable at DT)
        paths[method] = str(folder / f"stiff_{method}.fmu")
        lti_fmus.build_lti_fmu(model, paths[method], interfaces=("cs",), cs_method=method)
    return paths


def _run(path: str, **options) -> tuple[list[str], float]:
    """One pilot-like run of the pulse over SAMPLES samples in this process; fit's warnings and its CPU time."""
    source = open_source(path, **options)
    t = time_grid(DT, DT * (SAMPLES - 1))
    started = time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, failure = record_run(source, parse_signal(PULSE, 1), t, MemorySink, True, False, "step check", pilot=True)
    assert failure is None
    return [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)], time.process_time() - started


def _said(lines: list[str]) -> list[str]:
    return [line for line in lines if "integrates at the tolerance" in line]


def test_an_fmu_held_back_by_the_tolerance_passed_is_named_with_the_fix(fmus, monkeypatch):
    """Measured (in process, loaded machine): 13 ms per step at 1e-10, 0.5 ms at the FMU's own tolerance, over
    100 steps of 0.01 s; the line says so after the run, once per source."""
    monkeypatch.setattr(_size, "SLOW_RUN_SECONDS", 0.3)
    said, cpu = _run(fmus["accurate"])
    _, own_cpu = _run(fmus["accurate"], tolerance=0.0)   # the independent reference: the same run at its own
    assert cpu > 4 * _size.TOLERANCE_BOUND * own_cpu, (cpu, own_cpu)   # measured 0.67 s against 0.025 s
    lines = _said(said)
    assert len(lines) == 1, said
    line = lines[0]
    assert line.startswith("stiff_accurate.fmu: its co-simulation integrates at the tolerance fmu-opinf passes it "
                           "(1e-10, --tolerance or tolerance=)"), line
    for fix in ("--tolerance 1e-06 or tolerance=1e-06", "--tolerance 0 or tolerance=0", "--dt and --t-end or dt= and "
                "t_end="):
        assert fix in line, (fix, line)
    asked, own = (float(v) for v in re.findall(r"([0-9.e+-]+) ms per step", line))
    assert asked > _size.TOLERANCE_BOUND * own
    # the run's own pace (wall, in this process: not below its CPU time; under load far above), not the probe's
    assert asked >= 0.5 * 1e3 * cpu / SAMPLES, (asked, cpu)
    assert "\n" not in line


def test_no_line_where_the_tolerance_does_not_hold_the_fmu_back(fmus, monkeypatch):
    """An FMU that takes one RK4 step per communication step is as fast at its own tolerance: timed (every run
    counts as slow here) but not named; the FMU's own tolerance and fast runs are not timed at all."""
    monkeypatch.setattr(_size, "SLOW_RUN_SECONDS", 0.0)
    probed = []
    original = _size.tolerance_pace

    def counting(source, samples, seconds, what, probe):
        return original(source, samples, seconds, what, lambda n: probed.append(n) or probe(n))

    monkeypatch.setattr("fmu_opinf.snapshots._run.tolerance_pace", counting)
    assert not _said(_run(fmus["rk4"])[0]) and probed == [_size.PACE_SAMPLES]
    assert not _said(_run(fmus["accurate"], tolerance=0.0)[0]) and len(probed) == 1
    monkeypatch.setattr(_size, "SLOW_RUN_SECONDS", 1e9)
    assert not _said(_run(fmus["accurate"])[0]) and len(probed) == 1


def test_a_failed_probe_says_nothing():
    """A probe that fails (None) or a source that is not a co-simulation FMU: no line, no error."""
    class Cs:
        interface, tolerance, path = "cs", 1e-10, "x.fmu"

    assert _size.tolerance_pace(Cs(), 1000, 1e3, "its run", lambda n: None) is None
    me = Cs()
    me.interface = "me"
    assert _size.tolerance_pace(me, 1000, 1e3, "its run", lambda n: 1e-6) is None
    with pytest.warns(FmuOpinfWarning, match="x.fmu: its co-simulation integrates at the tolerance"):
        assert _size.tolerance_pace(Cs(), 1000, 1e3, "its run", lambda n: 1e-6) is not None
