"""The default training window on an anchored slow model under a constant load (audit 71, finding F5).

An anchored chain whose ground spring is weak (a mode of minutes) sags under a constant load (``f0`` inside the
model, a non-zero input start, a ``--set`` value) by far more than the default impulse moves it.  The window judged
the raw response: the sag set a step of seconds on which the 0.5 s pulse was never sampled, and the recording was
refused with "is zero at every sample of the grid", blaming the impulse on a grid the tool chose; the same model
without the load recorded by default.  Now a run without the pulse on the first pilot's grid tells whether the model
moves on its own, and where it does every pilot is judged net of the run without the pulse: the loaded model gets
the window of its unloaded twin.  A window whose step steps over the pulse widens the impulse (loaded or not), and
where no window is found even net of the load, one line says that the response to the load dominates, with its size.
Recordings are checked against the exact zero-order-hold solution (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import build_fmu_set

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.errors import DataError
from fmu_opinf.snapshots import Snapshots
from fmu_opinf.sources import open_source

pytestmark = pytest.mark.fmu

#: A recording against the exact solution, relative to each output's range: the default recording integrates the
#: model exchange at the tolerance 1e-10, relative to positions of 3.7e4 m here, which leaves 2.6e-5 absolute on the
#: 5 m spring elongation, 5.0e-6 of its range (the tip: 3.2e-10; measured 2026-12-07).
EXACT = 2e-5


def _sagging(load: float, name: str, ground: float = 0.005) -> lti_fmus.LinearMechanicalModel:
    """A 3-mass chain (forces on masses 1 and 3) whose spring to ground is ``ground`` N/m instead of 30 (slowest
    mode 0.039 rad/s, a period of 160 s, at 0.005; the others 2.7-7.4 rad/s), stiffness-proportional damping,
    ``load`` N on every mass (a static sag of 3 * load / ground at the base); outputs the tip position and the
    first spring's elongation."""
    chain = lti_fmus.chain_model(3, inputs=(0, -1))
    K = chain.K.copy()
    K[0, 0] -= 30.0 - ground
    Cp = np.zeros((2, 3))
    Cp[0, 2], Cp[1, 0], Cp[1, 1] = 1.0, -1.0, 1.0
    return lti_fmus.LinearMechanicalModel(M=chain.M, D=0.01 * K, K=K, B=chain.B, f0=load * np.ones(3), Cp=Cp,
                                          Cv=np.zeros((2, 3)), name=name)


def _models() -> dict[str, lti_fmus.LinearMechanicalModel]:
    return {"Sag": _sagging(0.5, "Sag"), "SagBase": _sagging(0.0, "SagBase"),
            "Sag05": _sagging(0.5, "Sag05", 0.05), "Sag05Base": _sagging(0.0, "Sag05Base", 0.05)}


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """The models' FMUs, built once."""
    models = _models()

    def build(folder, item):
        return item, lti_fmus.build_lti_fmu(models[item], folder / f"{item}.fmu").path

    return build_fmu_set(request, tmp_path_factory, "lti-loaded-window", build, list(models))


def _worst_miss(run, model: lti_fmus.LinearMechanicalModel) -> float:
    """The recording's largest difference from the exact solution under its inputs, relative to each output's
    range."""
    exact = lti_fmus.zoh_response(model, np.asarray(run.t), np.asarray(run.u)[:, 1:]).y
    return float((np.abs(np.asarray(run.y) - exact).max(axis=1) / np.ptp(exact, axis=1)).max())


def _window_line(out: str) -> str:
    lines = [line for line in out.splitlines() if "auto window: dt=" in line]
    assert lines, out
    return lines[0].split("(")[0].strip()


@pytest.mark.slow  # 15-30 s each: the loaded model's pilots each run twice
@pytest.mark.parametrize("ground", [0.005])
def test_an_anchored_slow_chain_under_a_constant_load_gets_the_window_of_the_chain_without_it(fmus, tmp_path,
                                                                                           capsys, ground):
    """The loaded chain says that it moves without the pulse and records with the window of the chain without the
    load; the recording is the exact solution with the sag in it.  Ground spring 0.005 (a 160 s mode, a static sag
    of 300 m): the impulse widened to 50 s, dt=5.  Before: both refused, 'impulse ... is zero at every sample of the
    grid dt=5' (t_end=3455 loaded, 3775 not).  Ground spring 0.05 (a 51 s mode, a sag of 30 m): dt=2 as without the
    load.  Before: dt=0.05, t_end=1058.25, the raw response's load transient setting the window (judged without the
    net judgement but with the widening, the same); kept so (the pilots as they are found that window, and the
    net judgement is armed only where they find none), so that 0.05 is not a case here."""
    loaded, base = ("Sag", "SagBase") if ground == 0.005 else ("Sag05", "Sag05Base")
    assert main(["snapshots", str(fmus[base]), "-o", str(tmp_path / "base.h5")]) == 0
    said_base = capsys.readouterr()
    assert main(["snapshots", str(fmus[loaded]), "-o", str(tmp_path / "load.h5")]) == 0
    said = capsys.readouterr()
    assert _window_line(said.out) == _window_line(said_base.out)
    assert "the outputs move without the pulse (y[1] by " in said.err and "warning" not in said.err, said.err
    assert "move without the pulse" not in said_base.err, said_base.err
    runs = Snapshots.load(tmp_path / "load.h5").runs
    # the model's own motion as a run of its own beside the pulses' (audit 77b, F2); none for the chain at rest
    assert [run.attrs["input_spec"] for run in runs].count("none") == 1
    assert "recording a run without it as well" in said.err
    assert all(run.attrs["input_spec"] != "none" for run in Snapshots.load(tmp_path / "base.h5").runs)
    for run in runs:
        assert ("width=50" in run.attrs["input_spec"]) == (ground == 0.005 and run.attrs["input_spec"] != "none")
        assert _worst_miss(run, _sagging(0.5, loaded, ground)) < EXACT
        assert _worst_miss(run, _sagging(0.0, base, ground)) > 0.01   # the sag is in the data (1.6 % of the range
        #                                                                 at 0.005)


@pytest.mark.slow
def test_the_unloaded_slow_chain_widens_the_impulse_its_window_would_step_over(fmus):
    """The chain without the load: the pilots of the 0.5 s impulse settle on dt=5 (20 points per period of its
    160 s mode), which never samples the pulse; the default training widens the impulse to 50 s instead of handing
    over a window that the recording refuses.  Before: dt=5 with the 0.5 s pulse, then 'zero at every sample'."""
    from fmu_opinf.snapshots._default_training import _default_training_window

    source = open_source(fmus["SagBase"])
    try:
        window, signals = _default_training_window(source, {"quiet": True})
    finally:
        source.close()
    assert [signal.spec for signal in signals] == ["impulse:amplitude=100,t0=200,width=50;none",
                                                   "none;impulse:amplitude=100,t0=200,width=50"]
    assert window.dt == 5.0   # ten samples across the widened pulse


def _real_window_functions() -> tuple:
    from fmu_opinf.snapshots import _window

    return _window.auto_window, _window.record_run


_REAL_WINDOW, _REAL_RUN = _real_window_functions()


def _calls_of_auto_window(monkeypatch, fmu, answer) -> tuple[list, list, object]:
    """Run the default training's window on ``fmu`` with :func:`auto_window` stubbed: its first call runs the real
    first pilot (which tells whether the model moves), and every call ends in ``answer(call number)`` (a window, or
    an error it raises); returns the calls' keywords, the runs made (the input's kind, the grid's length) and what
    the window ended in (the window, or the error)."""
    from fmu_opinf.snapshots import _window
    from fmu_opinf.snapshots._default_training import _default_training_window

    calls, runs = [], []
    real_window, real_run = _REAL_WINDOW, _REAL_RUN   # (not this test's stubs of an earlier call)

    def first_pilot_then_answer(source, pilot, **options):
        calls.append(options)
        if len(calls) == 1:   # the first pilot of the first try tells whether the model moves
            try:
                real_window(source, pilot, **{**options, "max_pilots": 1})
            except DataError:   # (the pilots do not settle within one)
                pass
        return answer(len(calls))

    def spy(source, signal, t, *args, **kwargs):
        runs.append((type(signal).__name__, len(t)))
        return real_run(source, signal, t, *args, **kwargs)

    monkeypatch.setattr(_window, "auto_window", first_pilot_then_answer)
    monkeypatch.setattr(_window, "record_run", spy)
    source = open_source(fmu)
    try:
        ended = _default_training_window(source, {"quiet": True})
    except DataError as error:
        ended = error
    finally:
        source.close()
    return calls, runs, ended


def _fixed_window(_: int):
    from fmu_opinf.snapshots._window import Window

    return Window(dt=0.05, t_end=100.0, f_max=1.0, t_fade=90.0, peak=1.0, pilot_dt=0.05, pilot_t_end=100.0,
                  pilots=1, points_per_period=20.0, energy=0.999, fade=0.01)


def test_the_first_pilot_tells_a_loaded_model_from_one_at_rest_at_no_extra_run(fmus, monkeypatch):
    """The decision alone (the window's first pilot, then stubbed to settle): the loaded chain's first
    pilot (10 s, 201 samples) moves before its pulse acts at 1.75 s, which it tells at no extra run; as the
    pilots judged as they are found a window, the net judgement is not armed and the window is chosen without a run
    without the pulse (a model that found its window before keeps it); only the pulse's size is then checked
    against the load (audit 74 F1), then its scaling with the amplitude (audit 79b, one run).  The chain without the
    load rests there: nothing more but that one run."""
    calls, runs, ended = _calls_of_auto_window(monkeypatch, fmus["Sag"], _fixed_window)
    assert len(calls) == 1 and calls[0]["baseline"].moving.startswith("y[1] by "), calls
    assert not calls[0]["baseline"].armed   # a window found by the pilots as they are: kept, no run without pulse
    # then the default pulse's size is checked net of the load on the window's grid (snapshots._default_training.
    # _raised_amplitudes): one run without the pulse and one per input; the pulse stands out here, nothing changes;
    # then the response's scaling with the amplitude (snapshots._linearity: one run, the pulse at a tenth)
    assert runs == [("StackedSignal", 201), ("NoInput", 2001), ("StackedSignal", 2001), ("StackedSignal", 2001),
                    ("Scaled", 2001)], runs
    assert ended[0].dt == 0.05 and "amplitude=100," in ended[1][0].spec, ended
    calls, runs, ended = _calls_of_auto_window(monkeypatch, fmus["SagBase"], _fixed_window)
    # (at rest: no run for the pulse's size; the scaling check's one run reuses the first pilot, on its grid)
    assert len(calls) == 1 and calls[0]["baseline"].moving is None and runs == [("StackedSignal", 201),
                                                                                ("Scaled", 201)], runs


def test_a_loaded_anchored_model_whose_window_is_not_found_even_net_of_the_load_is_refused_in_one_line(
        fmus, monkeypatch):
    """The window stubbed to find nothing after the first pilot (a pulse always too narrow): the first impulse
    judged as it is, then again and with its three widenings net of the run without the pulse, then one line saying
    that the response to the constant load dominates, with its size (the tip, y[1], swings about its static sag of
    300 m through a range of 600 over the last pilot's 2000 s), and to give --dt and --t-end.  The chain is
    anchored: no t^2 drift is claimed.  Before: the raw response judged, and the pulse refusal re-raised ('give an
    input on the model's time scale')."""
    from fmu_opinf.snapshots import _window

    def nothing(_: int):
        raise _window.PulseTooNarrow("auto window: the training pulse is far shorter", 2000.0)

    calls, runs, ended = _calls_of_auto_window(monkeypatch, fmus["Sag"], nothing)
    # the raw first try, the same impulse net of the load (armed), then its three widenings
    assert len(calls) == 5 and calls[-1]["baseline"].armed and calls[-1]["baseline"].moving, calls
    assert runs == [("StackedSignal", 201), ("NoInput", 2001)], runs   # the last: the refusal's
    text = str(ended)
    assert isinstance(ended, DataError) and "\n" not in text, text
    assert "the response to the constant load dominates (without the pulse the outputs move, y[1] by " in text, text
    assert "y[1] by 600 over t <= 2000" in text and "give --dt and --t-end" in text and "accelerates" not in text, text
