"""An FMU that keeps the stop time it is given with no slack (``t + h > stopTime`` is an error, as some generated FMUs
do; FMI: the run's final time), FMI 2 and 3, co-simulation and model exchange.  Audit 77a, F3.

Before: fmu-opinf gave ``stopTime = t[-1]`` and took the last uniform step from ``t[-2]``, landing an ulp past it
(``56.98 + 0.02 = 57.000000000000007``): co-simulation failed at the last step of ``--t-end 57 --dt 0.02`` and at the
first pilot of the automatic window (``9.95 + 0.05``).  Now the stop time given lies 1e-6 of the last step after the
last sample, and the uniform step is kept.  The reference is the exact zero-order-hold response of the model
(``lti_fmus.zoh_response``); each test fails with the stop time at ``t[-1]`` (checked here by putting it back).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.snapshots import Snapshots
from fmu_opinf.snapshots._rates import time_grid
from fmu_opinf.sources import _cosimulation

from conftest import build_fmu_set

pytestmark = pytest.mark.fmu

#: The FMUs: FMI version and interface.
KINDS = {"cs2": dict(interfaces=("cs",)), "cs3": dict(fmi_version="3.0", interfaces=("cs",)),
         "me2": dict(interfaces=("me",)), "me3": dict(fmi_version="3.0", interfaces=("me",))}

#: Bounds of a recording's miss of the exact model, relative to the outputs' range (measured 1.05e-12 for the RK4
#: substeps of the co-simulation; 2.6e-15 for model exchange at dt 0.02 to 57, 1.1e-14 on the automatic window).
RECORDED = {"cs2": 2e-12, "cs3": 2e-12, "me2": 2e-14, "me3": 2e-14}


def _chain() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(2, name="Strict")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    def build(folder, item):
        name, options = item
        built = lti_fmus.build_lti_fmu(_chain(), folder / f"{name}.fmu", identifier=f"Strict_{name}",
                                       strict_stop_time=True, **options)
        return name, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-strict-stop", build, list(KINDS.items()))


@pytest.fixture
def old_stop_time(monkeypatch):
    """The stop time as it was given before the fix: the run's last sample."""
    monkeypatch.setattr(_cosimulation, "stop_time_given", lambda t: float(t[-1]))


def _miss(run) -> float:
    exact = lti_fmus.zoh_response(_chain(), run.t, run.u[:, 1:]).y
    return float(np.abs(run.y - exact).max() / np.ptp(exact))


def test_the_stop_time_given_is_past_the_end_of_the_last_uniform_step_and_far_below_a_step():
    for dt, t_end in ((0.02, 57.0), (0.05, 10.0), (0.001, 1e4), (0.1, 0.3), (1e-3, 0.007)):
        t = time_grid(dt, t_end)
        h = float(f"{(t[1] - t[0]):.12g}")   # the uniform step of FMUSource._steps
        stop = _cosimulation.stop_time_given(t)
        assert t[-2] + h <= stop, (dt, t_end)
        assert stop - t[-1] <= 2e-6 * dt, (dt, t_end)
    assert (time_grid(0.02, 57.0)[-2] + 0.02) > 57.0   # the case of the audit: the old stop time is passed


@pytest.mark.parametrize("kind", ["cs2", "cs3"])
def test_the_builders_fmu_refuses_a_step_past_the_stop_time_it_was_given(kind, fmus, tmp_path, capsys,
                                                                          old_stop_time):
    """The check of the test FMU itself: with the old stop time the run of the audit fails at its last step (in
    this process, where the old stop time is put back)."""
    code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.02",
                 "--t-end", "57", "--in-process"])
    err = capsys.readouterr().err
    assert code == 2 and "at step 2850" in err and "passes the stop time 57" in err, err


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_run_whose_last_step_rounds_past_its_end_records_every_sample(kind, fmus, tmp_path, capsys):
    code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.02",
                 "--t-end", "57"])
    assert code == 0, capsys.readouterr().err   # was (co-simulation): an error at step 2850, 56.98 -> 57
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert run.complete and run.t.size == 2851 and run.t[-1] == pytest.approx(57.0, abs=1e-9)
    assert _miss(run) < RECORDED[kind]


@pytest.mark.parametrize("kind", ["cs2", "cs3", "me2"])
def test_the_automatic_window_runs_on_an_fmu_that_enforces_its_stop_time(kind, fmus, tmp_path, capsys):
    with warnings.catch_warnings(record=True):
        code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q"])
    assert code == 0, capsys.readouterr().err   # was (co-simulation): an error at the first pilot, 9.95 -> 10
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert run.complete and run.t[-1] > 20
    assert _miss(run) < RECORDED[kind]


@pytest.mark.parametrize("kind", ["me2", "me3"])
def test_model_exchange_never_set_a_time_past_the_run_end(kind, fmus, tmp_path, capsys, old_stop_time):
    """Model exchange integrates to the samples themselves: it kept to the old stop time too (the strict FMU
    refuses fmiSetTime past it), and the new one changes nothing there."""
    code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.02",
                 "--t-end", "57", "--in-process"])
    assert code == 0, capsys.readouterr().err
    assert _miss(Snapshots.load(tmp_path / "s.h5").runs[0]) < RECORDED[kind]
