"""A co-simulation FMU stable only below a communication step (audit 58, finding 5).

The FMU makes one RK4 step per ``doStep`` (:func:`fmu_opinf.lti_fmus.build_lti_fmu` with ``cs_method="rk4"``) on a
fixed-free chain of three masses whose first link is stiff (2.5e4 N/m, 204 rad/s): stable below dt = 2.83 / 204 =
0.0139, so it overflows at the automatic window's pilot steps 0.05 and 0.025, and at 0.02, like the audit's
free-free chain with four RK4 substeps per ``doStep`` (stable below 0.011).  Before, ``snapshots`` without ``--dt``
refused it ("depends on the communication step ... non-finite values at dt=0.05 or dt=0.025") without naming a
step, although ``--dt 0.01`` records it accurately; a run at a step where it diverges but stays finite (1e200)
printed NumPy's "overflow encountered in matmul" and "... in reduce" before fmu-opinf's own lines.  Recordings are
checked against the exact zero-order-hold solution (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from conftest import build_fmu_set
from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.errors import DataError
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Snapshots
from fmu_opinf.snapshots._rate_tests import rate_mismatch, stale_rates
from fmu_opinf.snapshots._window import pilot_step
from fmu_opinf.sources import open_source

pytestmark = pytest.mark.fmu

#: Stiffness of the chain's first link (N/m): one RK4 step per doStep is stable below dt = 0.0139.
STIFF = 2.5e4
#: The recording at dt = 0.01 against the exact solution, relative to the outputs' peak: 6.9e-7 measured
#: (2026-12-06; the FMU's RK4 at that step), bound about 3x.
RECORDING = 2e-6


def _model() -> lti_fmus.LinearMechanicalModel:
    """:func:`~fmu_opinf.lti_fmus.chain_model` (3 masses, input on the last) with its first link made stiff."""
    model = lti_fmus.chain_model(3, name="StiffLinkRk4")
    K = model.K.copy()
    K[:2, :2] += (STIFF + K[0, 1]) * np.array([[1.0, -1.0], [-1.0, 1.0]])  # K[0, 1]: minus the link's own spring
    return replace(model, K=K)


@pytest.fixture(scope="module")
def fmu(request, tmp_path_factory):
    """The chain's co-simulation-only FMU, one RK4 step per doStep."""

    def build(folder, item):
        built = lti_fmus.build_lti_fmu(_model(), folder / f"{item}.fmu", interfaces=("cs",), cs_method="rk4")
        return item, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-unstable-step", build, ["StiffLinkRk4"])["StiffLinkRk4"]


def _exact(run) -> np.ndarray:
    """The exact outputs on the run's grid under its held inputs."""
    u = np.asarray(run.u)
    return lti_fmus.zoh_response(_model(), np.asarray(run.t), u[:, 1:] if u.shape[0] else None).y


def test_the_model_is_stable_only_below_the_step_the_window_finds():
    """The premise, from the model alone: the RK4 amplification ``|R(lambda h)|`` of its fastest mode exceeds 1 at
    the pilot steps and at 0.02, and not at 0.01."""
    M, D, K = _model().M, _model().D, _model().K
    n = M.shape[0]
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, D)]])
    z = np.linalg.eigvals(A)

    def growth(h: float) -> float:
        w = z * h
        return float(np.abs(1 + w + w**2 / 2 + w**3 / 6 + w**4 / 24).max())

    assert min(growth(h) for h in (0.05, 0.025, 0.02)) > 8.0 and growth(0.01) < 1.0


def test_the_window_records_at_the_largest_stable_step_and_says_why(fmu, tmp_path, capsys):
    """Without --dt the pilots' step check overflows at 0.05 and 0.025; the steps 0.02 (overflows) and 0.01
    (finite, its outputs within 6.5e-7 of a run at 0.005) are tried, and the recording is at 0.01, the exact
    solution to the FMU's RK4 accuracy; the window's line says which step and why."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmu), "-o", str(out)]) == 0
    said = capsys.readouterr()
    assert "Traceback" not in said.err and "encountered" not in said.err and "warning" not in said.err, said.err
    line = [line for line in said.out.splitlines() if "auto window: dt=0.01" in line]
    assert line and ("the co-simulation overflows or diverges at dt=0.02: steps at most dt=0.01, the largest tried "
                     "where it is finite and agrees with dt=0.005 to ") in line[0], said.out
    run = Snapshots.load(out).runs[0]
    window = run.attrs["auto_window"]
    window = json.loads(window) if isinstance(window, str) else window
    assert run.attrs["dt"] == 0.01 and window["stable_dt"] == 0.01 and window["unstable_dt"] == 0.02
    assert window["stable_difference"] < 1e-3 and run.t[-1] > 30.0
    y = np.asarray(run.y)
    assert np.isfinite(y).all()
    assert float(np.abs(y - _exact(run)).max() / np.abs(_exact(run)).max()) < RECORDING


def test_every_step_tried_overflowing_names_a_smaller_one(fmu):
    """Where the search ends before a stable step (here after one try, 0.02), the refusal is one line whose fix
    names a step below the smallest tried."""
    source = open_source(str(fmu))
    signal = parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1)
    with pytest.raises(DataError) as refused:
        pilot_step(source, signal, 0.05, 10.0, tries=1)
    message = str(refused.value)
    assert "\n" not in message
    assert ("the co-simulation overflows or diverges at every communication step the automatic window tried, down "
            "to dt=0.02 (it produced non-finite values at dt=0.02") in message, message
    assert "give --dt or dt= below 0.02 (e.g. 0.01) and --t-end" in message, message


def test_a_diverging_run_prints_no_numpy_warning(fmu, tmp_path, capsys):
    """At --dt 0.0145, just above the stability limit, the run grows to about 1e200 but stays finite: the rate checks'
    sums of squares overflow.  Only fmu-opinf's lines are printed (before: NumPy's 'overflow encountered in matmul'
    and '... in reduce'); with RuntimeWarnings as errors the command still ends normally."""
    out = tmp_path / "train.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        main(["snapshots", str(fmu), "-o", str(out), "--dt", "0.0145", "--t-end", "30", "-q"])
    err = capsys.readouterr().err
    assert "encountered" not in err and "Traceback" not in err, err
    assert all(line.startswith(("fmu-opinf: ", "wrote ", "  ")) for line in err.strip().splitlines()), err
    assert "the co-simulation depends on the communication step" in err, err


def test_rate_checks_of_huge_finite_values_do_not_warn():
    """The rate checks (:func:`rate_mismatch`, :func:`stale_rates`) on a run diverging near 1e200: no NumPy warning,
    and no stale accelerations claimed."""
    t = np.arange(50) * 0.01
    v = np.vstack([1e200 * np.exp(t) * np.cos(40 * t), 1e200 * np.exp(t)])
    a = np.gradient(v, 0.01, axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rate_mismatch(v, v, 0.01)
        assert not stale_rates(v, a, 0.01)


# ------------------------------------------------------------------ a first pilot that diverges but stays finite
#: The mild chain (audit 60, finding 6: ``chain_model(3)`` with K x 50, fastest mode 58.5 rad/s, one RK4 step per
#: doStep) recorded by the window at dt = 0.005 against the exact solution, relative to the outputs' peak: 1.04e-4
#: measured (2026-12-07), bound about 3x.
MILD_RECORDING = 3e-4


def _mild() -> lti_fmus.LinearMechanicalModel:
    """:func:`~fmu_opinf.lti_fmus.chain_model` (3 masses) with every spring 50 times stiffer."""
    model = lti_fmus.chain_model(3, name="MildRk4")
    return replace(model, K=50.0 * model.K)


@pytest.fixture(scope="module")
def mild(request, tmp_path_factory):
    """The mild chain's co-simulation-only FMU, one RK4 step per doStep."""

    def build(folder, item):
        return item, lti_fmus.build_lti_fmu(_mild(), folder / f"{item}.fmu", interfaces=("cs",), cs_method="rk4").path

    return build_fmu_set(request, tmp_path_factory, "lti-diverging-step", build, ["MildRk4"])["MildRk4"]


def _rk4_growth(model: lti_fmus.LinearMechanicalModel, h: float) -> float:
    """The largest RK4 amplification ``|R(lambda h)|`` over the model's eigenvalues."""
    n = model.M.shape[0]
    M, D, K = model.M, model.D, model.K
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(M, K), -np.linalg.solve(M, D)]])
    w = np.linalg.eigvals(A) * h
    return float(np.abs(1 + w + w**2 / 2 + w**3 / 6 + w**4 / 24).max())


def test_the_mild_chain_is_unstable_at_the_first_pilot_step_only():
    """The premise, from the model alone: RK4 grows at 0.05 (h omega = 2.9, slowly: 200 steps stay finite), not at
    half of it."""
    assert 1.0 < _rk4_growth(_mild(), 0.05) < 1.5 and _rk4_growth(_mild(), 0.025) < 1.0


def test_a_first_pilot_that_diverges_but_stays_finite_searches_a_smaller_step(mild, tmp_path, capsys):
    """Audit 60, finding 6: at the pilot step 0.05 the outputs grow to 2.4e13 times those at 0.025, which stay
    bounded.  Before, that was refused as 'depends on the communication step (... differ by 2.6e+13 of their peak)'
    with no step named.  Now it is a divergence like an overflow: the search passes 0.02 and 0.01 (bounded, the
    difference falling 11-fold, RK4 just below its stability limit) and records at 0.005, the exact solution to
    the FMU's RK4 accuracy."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(mild), "-o", str(out)]) == 0
    said = capsys.readouterr()
    assert "Traceback" not in said.err and "warning" not in said.err, said.err
    line = [line for line in said.out.splitlines() if "auto window: dt=0.005" in line]
    assert line and "the co-simulation overflows or diverges at dt=0.05: steps at most dt=0.005" in line[0], said.out
    run = Snapshots.load(out).runs[0]
    window = run.attrs["auto_window"]
    window = json.loads(window) if isinstance(window, str) else window
    assert run.attrs["dt"] == 0.005 and window["stable_dt"] == 0.005 and window["unstable_dt"] == 0.05
    u = np.asarray(run.u)
    exact = lti_fmus.zoh_response(_mild(), np.asarray(run.t), u[:, 1:]).y
    assert float(np.abs(np.asarray(run.y) - exact).max() / np.abs(exact).max()) < MILD_RECORDING


def _fake_checks(monkeypatch, found: list[tuple[float, float]]) -> list[float]:
    """Make the step checks of :func:`pilot_step` report ``(dt, difference)`` in turn (``inf``: non-finite);
    returns the list of steps checked."""
    import fmu_opinf.snapshots._window as window_module

    checked, results = [], iter(found)

    def check(source, signal, dt, T, *args, **kwargs):
        step, difference = next(results)
        assert step == dt, (step, dt)
        checked.append(dt)
        said = (f"it produced non-finite values at dt={dt:g}" if np.isinf(difference) else
                f"its outputs at dt={dt:g} and dt={dt / 2:g} differ by {difference:.2g} of their peak")
        return window_module._StepCheck(said, object(), False, difference, dt)

    monkeypatch.setattr(window_module, "_step_dependence", check)
    return checked


def test_a_bounded_step_whose_difference_falls_slowly_ends_the_search(mild, monkeypatch):
    """After the divergence, a step where the runs stay bounded but differ is passed once (0.02); where the next
    step's difference falls only in proportion to the step (explicit Euler: 0.2 -> 0.1), no step within reach is
    accurate: refused there, in one line that shows the fall, without trying smaller steps."""
    checked = _fake_checks(monkeypatch, [(0.05, np.inf), (0.02, 0.2), (0.01, 0.1), (0.005, 0.0)])
    source = open_source(str(mild))
    with pytest.raises(DataError) as refused:
        pilot_step(source, parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1), 0.05, 10.0)
    message = str(refused.value)
    assert checked == [0.05, 0.02, 0.01] and "\n" not in message, (checked, message)
    assert ("the co-simulation depends on the communication step (it produced non-finite values at dt=0.05; its "
            "outputs at dt=0.02 and dt=0.01 differ by 0.2 of their peak; its outputs at dt=0.01 and dt=0.005 differ "
            "by 0.1 of their peak over t <= 10") in message, message


def test_a_search_ending_while_the_difference_still_falls_names_a_smaller_step(mild, monkeypatch):
    """Where the tries end at steps whose difference falls fast (RK4) but is not yet within the threshold, the
    refusal says so and names a --dt below the smallest tried (before: refused as step-dependent at the first
    bounded step, with no step named)."""
    checked = _fake_checks(monkeypatch, [(0.05, np.inf), (0.02, 0.5), (0.01, 0.05)])
    source = open_source(str(mild))
    with pytest.raises(DataError) as refused:
        pilot_step(source, parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1), 0.05, 10.0, tries=2)
    message = str(refused.value)
    assert checked == [0.05, 0.02, 0.01] and "\n" not in message, (checked, message)
    assert ("the co-simulation diverges at dt=0.05 (it produced non-finite values at dt=0.05) and converges at "
            "smaller steps, but not yet at the smallest the automatic window tried (its outputs at dt=0.01 and "
            "dt=0.005 differ by 0.05 of their peak over t <= 10); give --dt or dt= below 0.01 (e.g. 0.005)") \
        in message, message


#: One mass, omega = 10 rad/s, damping ratio 0.1: explicit Euler is stable below dt = 2 zeta / omega = 0.02.
EULER_ONE = {"K": np.array([[100.0]]), "D": np.array([[2.0]])}


@pytest.fixture(scope="module")
def euler_one(request, tmp_path_factory):
    """The one-mass model's co-simulation-only FMU, one explicit Euler step per doStep."""

    def build(folder, item):
        model = replace(lti_fmus.chain_model(1, name=item), **EULER_ONE)
        return item, lti_fmus.build_lti_fmu(model, folder / f"{item}.fmu", interfaces=("cs",), cs_method="euler").path

    return build_fmu_set(request, tmp_path_factory, "lti-euler-both", build, ["EulerOne"])["EulerOne"]


def test_explicit_euler_diverging_at_both_pilot_steps_is_called_a_divergence(euler_one):
    """Audit 63, finding 8: explicit Euler diverges at both pilot steps (growth per step 1.07 at 0.05 and 1.006 at
    0.025 in amplitude: |1 + h lambda|), the run at 0.05 reaching thousands of times the peak at 0.025.  It stays
    refused at once, but as a divergence at both steps with a step below them named, not as 'depends on the
    communication step'.  Reference: the stability limit 0.02 by hand; the step named, 0.01, is below it."""
    h = np.array([0.05, 0.025, 0.01])
    lam = -1.0 + 1j * np.sqrt(99.0)   # roots of s^2 + 2 s + 100
    assert np.all(np.abs(1 + h[:2] * lam) > 1.0) and abs(1 + h[2] * lam) < 1.0
    source = open_source(str(euler_one))
    with pytest.raises(DataError) as refused:
        pilot_step(source, parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1), 0.05, 10.0)
    message = str(refused.value)
    assert "\n" not in message and "depends on the communication step" not in message, message
    assert "the co-simulation diverges at both communication steps the automatic window tried" in message, message
    assert "which grow too once the input is constant" in message, message
    assert "it offers no model exchange: give --dt or dt= below 0.025 (e.g. 0.01) and --t-end" in message, message


def test_judging_a_pilot_that_diverges_to_huge_finite_values_does_not_warn(monkeypatch):
    """Audit 63, finding 8: the step check hands its first run to the window's analysis before judging whether it
    diverges; outputs near 1e200 (RK4 above its stability limit, still finite) overflowed in the envelope's norms,
    and 'fmu-opinf: warning: overflow encountered in dot' was printed three times.  The analysis runs without
    NumPy's overflow warnings (here made errors) and still says what it sees: since audit 79b (F4) the growth, at
    its rate (a DataError, which the step check's hook drops: the step search then has its say), and without the
    growth test the envelope's peak."""
    from types import SimpleNamespace

    from fmu_opinf.snapshots import _window
    from fmu_opinf.snapshots._growth import GrowsWithoutBound

    t = np.round(np.arange(201) * 0.05, 12)
    y = np.vstack([np.exp(2.3 * t) * np.sin(30.0 * t), np.exp(2.3 * t) * np.cos(30.0 * t)]) * 1e200 / np.exp(23.0)
    run = SimpleNamespace(t=t, x=y, y=y, k=t.size)   # (positions diverge with the outputs)
    source = SimpleNamespace(m=1, held_input_names=[])
    signal = parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(GrowsWithoutBound) as grows:
            _window._analyse_pilot(source, signal, t, 2.5, 0.99, 0.01, 10.0, True, False, run=run)
        monkeypatch.setattr(_window, "refuse_growth", lambda *args: None)
        seen = _window._analyse_pilot(source, signal, t, 2.5, 0.99, 0.01, 10.0, True, False, run=run)
    assert abs(grows.value.growth.rate - 2.3) < 0.01 * 2.3, grows.value.growth
    assert seen.peak > 1e199
