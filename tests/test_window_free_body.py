"""The default training window on a free body under a constant load, and on a co-simulation that discards long
steps (audit 70, findings 2 and 9).

A free body (a rigid-body mode, no spring to ground) under a constant load, inside the model (``f0``) or from a
``--set`` value on an input, accelerates on its own: its outputs grow like ``t**2`` whatever the pulse does.  Before,
the window widened the default impulse three times, to t0 = 2e6 s, and refused after 70-118 s with advice that did
not fit ("scale the input"); with ``--dt 0.02 --t-end 60`` the recording was exact.  The window now sees, from the
first pilot's samples before its pulse acts, that the body moves on its own and judges every pilot net of a run
without the pulse (since audit 71, F5; at first, from audit 70, only after a pulse too narrow and a t^2 drift): the
loaded body gets the window of the same body without the load.  A co-simulation whose embedded solver discards
steps above 0.01 s stopped the default chain ("discarded the communication step 0.05 ... give a smaller --dt, e.g.
0.01"); the window's step search now takes a discarded pilot step like one where the co-simulation overflows.
Recordings are checked against the exact zero-order-hold solution (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import build_fmu_set

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.signals import NoInput
from fmu_opinf.snapshots import Snapshots
from fmu_opinf.sources import open_source

pytestmark = pytest.mark.fmu

#: A recording against the exact solution, relative to each output's range: the FMUs step the exact ZOH map, so
#: only round-off remains (about 1e-12 measured on the drifting tip, 2026-12-06).
EXACT = 1e-9


def _free(load: float, name: str) -> lti_fmus.LinearMechanicalModel:
    """A 3-mass chain (forces on masses 1 and 3) with its ground spring removed, stiffness-proportional damping
    only (the rigid-body mode is undamped), ``load`` N on every mass; outputs the tip position and the first
    spring's elongation."""
    chain = lti_fmus.chain_model(3, inputs=(0, -1))
    K = chain.K.copy()
    K[0, 0] -= 30.0                     # the first mass's spring to ground
    Cp = np.zeros((2, 3))
    Cp[0, 2], Cp[1, 0], Cp[1, 1] = 1.0, -1.0, 1.0
    return lti_fmus.LinearMechanicalModel(M=chain.M, D=0.01 * K, K=K, B=chain.B, f0=load * np.ones(3), Cp=Cp,
                                          Cv=np.zeros((2, 3)), name=name)


def _models() -> dict[str, tuple[lti_fmus.LinearMechanicalModel, dict]]:
    return {"FreeLoad": (_free(0.5, "FreeLoad"), {}),
            "FreeBase": (_free(0.0, "FreeBase"), {}),
            "Anchored": (replace(lti_fmus.chain_model(3, inputs=(0, -1), force_offset=0.5), name="Anchored"), {}),
            "MaxStep": (lti_fmus.chain_model(3, name="MaxStep"), {"interfaces": ("cs",), "cs_max_step": 0.01})}


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """The models' FMUs, built once."""
    models = _models()

    def build(folder, item):
        model, options = models[item]
        return item, lti_fmus.build_lti_fmu(model, folder / f"{item}.fmu", **options).path

    return build_fmu_set(request, tmp_path_factory, "lti-free-body-window", build, list(models))


def _held_second(model: lti_fmus.LinearMechanicalModel, value: float) -> lti_fmus.LinearMechanicalModel:
    """``model`` with its second input held at ``value`` (``--set``): a constant force, no longer an input."""
    return replace(model, B=model.B[:, :1], f0=model.f0 + value * model.B[:, 1])


def _worst_miss(run, model: lti_fmus.LinearMechanicalModel) -> float:
    """The recording's largest difference from the exact solution under its inputs, relative to each output's
    range."""
    u = np.asarray(run.u)
    exact = lti_fmus.zoh_response(model, np.asarray(run.t), u[:, 1:]).y
    y = np.asarray(run.y)
    return float((np.abs(y - exact).max(axis=1) / np.ptp(exact, axis=1)).max())


def _window_line(out: str) -> str:
    lines = [line for line in out.splitlines() if "auto window: dt=" in line]
    assert lines, out
    return lines[0].split("(")[0].strip()


@pytest.mark.slow
@pytest.mark.parametrize("case", ["f0", "set"])
def test_a_free_body_under_a_constant_load_gets_the_window_of_the_body_without_it(fmus, tmp_path, capsys, case):
    """The load inside the model (``f0``), or a ``--set`` value on the input the default training then holds: the
    window says that the outputs move without the pulse, judges the pilots net of that, and chooses the window that
    the same body gets without the load (dt=0.02, the end where its pulse response has faded); the recording is the
    exact solution, and the load's drift is in it (the fit learns the force).  Before: three widenings to
    t0 = 2e6 s, a false 'stale accelerations' warning and a refusal, over a minute."""
    fmu, args = (fmus["FreeLoad"], []) if case == "f0" else (fmus["FreeBase"], ["--set", "F[2]=0.5"])
    base_args = [] if case == "f0" else ["--set", "F[2]=0"]
    assert main(["snapshots", str(fmus["FreeBase"]), "-o", str(tmp_path / "base.h5"), *base_args]) == 0
    base = capsys.readouterr()
    assert main(["snapshots", str(fmu), "-o", str(tmp_path / "load.h5"), *args]) == 0
    said = capsys.readouterr()
    assert "the outputs move without the pulse (y[1] by " in said.err and "warning" not in said.err, said.err
    assert "move without the pulse" not in base.err, base.err
    assert _window_line(said.out) == _window_line(base.out)
    model = _free(0.5, "FreeLoad") if case == "f0" else _held_second(_free(0.0, "FreeBase"), 0.5)
    unloaded = _free(0.0, "FreeBase") if case == "f0" else _held_second(_free(0.0, "FreeBase"), 0.0)
    runs = Snapshots.load(tmp_path / "load.h5").runs
    for run in runs:
        assert run.attrs["dt"] == 0.02
        assert _worst_miss(run, model) < EXACT
        assert _worst_miss(run, unloaded) > 0.1   # the load's drift is in the data


def test_the_drift_test_sees_a_loaded_free_body_and_not_an_anchored_one(fmus):
    """:func:`accelerates_under_load` over 2000 s with the inputs held at 0: the loaded free body accelerates (its
    tip grows like t**2), the unloaded one rests, and the anchored chain under the same load settles (it oscillates
    about its static deflection, periods of a few seconds)."""
    from fmu_opinf.snapshots._window import accelerates_under_load

    said = {item: accelerates_under_load(open_source(fmus[item]), NoInput(2), 2000.0)
            for item in ("FreeLoad", "FreeBase", "Anchored")}
    assert said["FreeLoad"] is not None and "grows like t^2" in said["FreeLoad"]
    assert said["FreeBase"] is None and said["Anchored"] is None


def test_a_discarded_pilot_step_takes_the_step_search_and_a_given_discarded_dt_is_refused(fmus, tmp_path, capsys):
    """The FMU's embedded solver discards steps above 0.01: without --dt the pilots' 0.05 is discarded, the search
    passes 0.02 (discarded) and records at 0.01, the exact solution, saying so in the window's line; a --dt 0.05
    the user gives is refused as before, naming the step the FMU's log gives.  Before, the default chain stopped
    with the refusal."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["MaxStep"]), "-o", str(out)]) == 0
    said = capsys.readouterr()
    assert "warning" not in said.err, said.err
    assert ("the FMU discards the communication step dt=0.02: steps at most dt=0.01, the largest tried that it takes"
            in said.out), said.out
    run = Snapshots.load(out).runs[0]
    assert run.attrs["dt"] == 0.01 and run.t[-1] > 30.0
    assert _worst_miss(run, lti_fmus.chain_model(3)) < EXACT
    assert main(["snapshots", str(fmus["MaxStep"]), "--dt", "0.05", "-o", str(tmp_path / "given.h5")]) != 0
    assert "discarded the communication step 0.05" in capsys.readouterr().err


def test_a_drift_accelerates_away_a_coasting_or_settling_output_does_not():
    """The shape test over a run's second half (:func:`_parabolic`), on closed forms over t in [1000, 2000]: a body
    accelerated from rest (``t**2``) drifts; one coasting at a constant speed (``t``), one creeping to rest
    (``1 - exp(-t / 300)``) and one settled at a constant do not."""
    from fmu_opinf.snapshots._window import _parabolic

    t = np.linspace(1000.0, 2000.0, 1001)
    assert _parabolic(t, 0.25 * t**2, 0.25 * 2000.0**2)
    assert not _parabolic(t, 3.0 * t, 3.0 * 2000.0)
    assert not _parabolic(t, 1.0 - np.exp(-t / 300.0), 1.0)
    assert not _parabolic(t, np.full_like(t, 0.2) + 1e-15 * t**2, 0.2)


def test_a_drifting_body_whose_window_is_not_found_even_net_of_the_drift_is_refused_in_one_line(fmus, monkeypatch):
    """The decision alone, with the window stubbed to find nothing after its first pilot (a pulse always too
    narrow): the body moves before the first pilot's pulse acts, so the impulse and its three widenings are all
    judged net of the run with the inputs held, then a run without the pulse over the last pilot's 2000 s shows
    the t^2 drift, and one line says the model accelerates under its own constant load and what to give.  Before
    audit 70 the widenings ran on the raw response and the pulse refusal was re-raised; before audit 71 the first
    try ran on the raw response too."""
    from fmu_opinf.errors import DataError
    from fmu_opinf.snapshots import _window
    from fmu_opinf.snapshots._default_training import _default_training_window

    calls, real_window = [], _window.auto_window

    def nothing(source, pilot, **options):   # the first pilot (it tells that the body moves), then nothing
        calls.append(options.get("baseline"))
        if len(calls) == 1:
            try:
                real_window(source, pilot, **{**options, "max_pilots": 1})
            except DataError:
                pass
        raise _window.PulseTooNarrow("auto window: the training pulse is far shorter", 2000.0)

    monkeypatch.setattr(_window, "auto_window", nothing)
    source = open_source(fmus["FreeLoad"])
    try:
        with pytest.raises(DataError) as info:
            _default_training_window(source, {"quiet": True})
    finally:
        source.close()
    # the raw first try, the same impulse net of the drift (armed), then its three widenings
    assert len(calls) == 5 and all(isinstance(held.held, NoInput) and held.moving and held.armed for held in calls), \
        calls
    text = str(info.value)
    assert "\n" not in text and "give --dt and --t-end" in text and "over t <= 2000" in text, text
    assert "the model accelerates under its own constant load (a free body under gravity or thrust: y[1] grows like " \
        "t^2, by " in text, text
