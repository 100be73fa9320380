"""A model that ends its simulation on its own (Modelica ``terminate()``, a Simulink stop time) outside FMI 3
co-simulation: FMI 2 co-simulation (``fmi2DoStep`` returns ``fmi2Discard`` and ``fmi2GetBooleanStatus(fmi2Terminated)``
answers true) and model exchange, FMI 2 and 3 (the event iteration at a time event sets ``terminateSimulation``).
Audit 75, F2 and F3.

Before: FMI 2 co-simulation read every discard as a step too long ("give a smaller --dt, e.g. 0.02" at t = 20, then
"e.g. 0.01", ...), and model exchange stopped with "asked to terminate the simulation during an event iteration
(at t=20)", no fix named, even at ``--t-end 20`` where every sample up to the termination is complete; so the default
chain failed.  Now each is handled like the FMI 3 co-simulation termination (tests/test_run_limits.py): the
automatic window ends before it, a run ending at it keeps its samples, a run past it fails with a line naming the
time, the FMU's log line and the --t-end that works, and compare's default end stops before it.  The references are
the exact zero-order-hold response of the model (``lti_fmus.zoh_response``) and the time built into the FMUs.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import Snapshots

from conftest import build_fmu_set, miss_against_model

pytestmark = pytest.mark.fmu

#: The time at which the models end their simulation.
TERMINATE = 20.0

#: The FMUs: how each ends its simulation, and the call the message names.
KINDS = {"cs2": (dict(interfaces=("cs",), cs_terminate_at=TERMINATE), "in fmi2DoStep at t=19.95 -> 20",
                 "fmi2DoStep: the model called terminate() at t=20"),
         "me2": (dict(interfaces=("me",), me_terminate_at=TERMINATE), "in its event iteration at t=20",
                 "terminate() called at t=20: end of the test track"),
         "me3": (dict(fmi_version="3.0", interfaces=("me",), me_terminate_at=TERMINATE),
                 "in its event iteration at t=20", "terminate() called at t=20: end of the test track"),
         "completed": (dict(interfaces=("me",), completed_step_terminate_at=TERMINATE),
                       "in fmiCompletedIntegratorStep at t=20", "terminate() called at t=20: the end stop is reached")}

#: A stop checked in completed integrator steps that falls inside a communication interval (not at its end).
INSIDE = 20.013

#: Bounds of a recording's miss of the exact model, relative to the outputs' range (measured 1.0e-12 for the RK4
#: substeps of the co-simulation; 2.6e-15 for model exchange at the window's dt 0.02, 4.8e-12 at --dt 0.05).
RECORDED = {"cs2": 1e-11, "me2": 2e-11, "me3": 2e-11, "completed": 2e-11}


def _chain() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(2, name="Ends")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    def build(folder, item):
        name, options = item
        built = lti_fmus.build_lti_fmu(_chain(), folder / f"{name}.fmu", identifier=f"Ends_{name}",
                                       stop_time=TERMINATE, **options)
        return name, built.path

    items = [(name, options) for name, (options, _, _) in KINDS.items()]
    items.append(("inside", dict(interfaces=("me",), completed_step_terminate_at=INSIDE)))
    return build_fmu_set(request, tmp_path_factory, "lti-termination", build, items)


def _miss(run) -> float:
    """The recorded outputs' largest miss of the exact model, relative to their range."""
    exact = lti_fmus.zoh_response(_chain(), run.t, run.u[:, 1:]).y
    return float(np.abs(run.y - exact).max() / np.ptp(exact))


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(KINDS))
def test_the_default_chain_ends_before_the_termination(kind, fmus, tmp_path, capsys):
    with warnings.catch_warnings(record=True):
        code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"terminates the simulation at t={TERMINATE:g} (seen in a pilot run" in err, err
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    dt = float(run.t[1] - run.t[0])
    assert TERMINATE - 2 * dt < run.t[-1] < TERMINATE
    assert _miss(run) < RECORDED[kind]
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    capsys.readouterr()
    code = main(["compare", str(tmp_path / "rom.h5"), str(fmus[kind]), "-o", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert code == 0, err   # was: the termination again at compare's default end, 4 x 19.98 s
    assert f"terminated the simulation at t={TERMINATE:g} in the training's recording: comparing to t_end=" in err
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert TERMINATE - 2 * dt < metrics["t_end"] < TERMINATE
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    for spec in ("harmonic:amplitude=20,omega=2.71", "step:amplitude=100,t0=1"):   # past the termination too
        assert miss_against_model(rom, _chain(), spec, 100.0) < 1e-11, spec   # measured 1.8e-12, 2.1e-14


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_run_that_ends_at_the_termination_keeps_every_sample(kind, fmus, tmp_path, capsys):
    code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.05",
                 "--t-end", f"{TERMINATE:g}"])
    assert code == 0, capsys.readouterr().err   # was: refused at the step that ends at t = 20
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert run.complete and run.t[-1] == pytest.approx(TERMINATE, abs=1e-9) and run.t.size == 401
    assert _miss(run) < RECORDED[kind]


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_run_past_the_termination_names_the_time_the_log_and_the_fix(kind, fmus, tmp_path, capsys):
    """--dt and --t-end given: no pilots, the run itself meets the termination and stops there."""
    code = main(["snapshots", str(fmus[kind]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.05",
                 "--t-end", "50"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    _, where, log = KINDS[kind]
    assert code != 0
    run = Snapshots.load(tmp_path / "s.h5").runs[0]   # the samples before the termination are kept, marked
    assert not run.complete and run.t[-1] == pytest.approx(TERMINATE - 0.05, abs=1e-9)
    assert _miss(run) < RECORDED[kind]
    assert f"asked to terminate the simulation {where}" in err, err
    assert f"its log: {log}; end the run before it: --t-end or t_end= below {TERMINATE:g}" in err, err
    assert "smaller --dt" not in err and "discarded the communication step" not in err, err


def test_a_declared_stop_time_crossed_by_a_failed_step_is_named_with_its_t_end(fmus):
    """An error in the step that passes DefaultExperiment stopTime (a compiled-in stop time, audit 75's
    fixstop.fmu) names --t-end at or below it, and compare's own --t-end where compare ran to its default end; an
    error elsewhere does not.  (The builder's FMUs have no such error: the line is asked of a real source.)"""
    from fmu_opinf.compare import _run
    from fmu_opinf.sources import StepError, open_source

    source = open_source(fmus["cs2"], interface="cs")
    try:
        t = np.round(np.arange(0.0, 20.0 + 0.5 + 1e-9, 0.05), 12)
        source.start(t, np.zeros((1, t.size)))
        crossing = int(np.searchsorted(t, TERMINATE, side="right"))   # the step 20 -> 20.05
        line = source._step_failure(3, "fmi2DoStep", crossing)
        assert line.endswith(f"; the step passes its DefaultExperiment stopTime={TERMINATE:g}, where the model may "
                             f"end its simulation: give --t-end or t_end= at or below {TERMINATE:g}"), line
        # compare's default end (four times the training's) past it: the fix is compare's own --t-end
        told = str(_run._past_termination(StepError(line, crossing, float(t[crossing])), 80.0, False))
        assert told.endswith(f"(compare ran to its default t_end=80, four times the training's end; give compare "
                             f"--t-end or t_end= at or below {TERMINATE:g})"), told
        assert "stopTime" not in source._step_failure(3, "fmi2DoStep", crossing + 2)
        assert "stopTime" not in source._step_failure(3, "fmi2DoStep", crossing - 2)
    finally:
        source.close()


def test_a_stop_in_a_completed_step_inside_an_interval_is_the_models_end_not_an_integration_failure(fmus, tmp_path,
                                                                                                    capsys):
    """The integrator's own completed step (scipy's or the compiled DOP853 loop) asks to terminate: before, "model-
    exchange integration failed ... try a looser --tolerance"."""
    code = main(["snapshots", str(fmus["inside"]), "-o", str(tmp_path / "s.h5"), "-q", "--dt", "0.5",
                 "--t-end", "50"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code != 0
    assert "asked to terminate the simulation in fmiCompletedIntegratorStep at t=20.0" in err, err
    assert "its log: terminate() called at t=20.0" in err and "tolerance" not in err, err
    below = float(err.split("--t-end or t_end= below ")[1].split(";")[0])
    assert INSIDE < below < 20.5, err   # the completed step where it stopped, inside the interval 20 -> 20.5
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert not run.complete and run.t[-1] == pytest.approx(20.0, abs=1e-9)
    assert _miss(run) < 2e-9   # measured 5.7e-10 at --dt 0.5
