"""Stale accelerations confirmed by the FMU itself (audit 71 F6).

The recorder calls accelerations stale where, shifted by one sample, they fit the velocities' increments better
(:func:`fmu_opinf.snapshots._rate_tests.stale_rates`).  On an FE beam started by an impact, whose modes lie far
above pi/dt, that rule fired on exact current derivatives, and the recording was made a second time with
accelerations taken from the data instead of the FMU's.  The verdict is now checked by one direct evaluation: the
run again up to a sample and a step of 1e-6 of the run's past it, the FMU's accelerations read there, and compared
with the ones recorded at that sample (current) and at the next (stale).  The references are independent of the
tool: the exact zero-order-hold response of the model and its derivative ``M^-1 (B u - D v - K x)``.
"""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots._consistency import STALE_REASON, judge_run
from fmu_opinf.snapshots._rate_tests import Repair, evaluation_sample, evaluation_verdict, stale_rates
from fmu_opinf.sources._variables import Selection

#: The step and length of audit 71's recording of the impacted beam (the automatic window's choice).
H, K_SAMPLES = 0.002, 786
IMPULSE = "impulse:amplitude=100,t0=0.2,width=0.05"


def _impacted_beam() -> lti_fmus.LinearMechanicalModel:
    """A cantilever of 30 Euler-Bernoulli elements (1 m, EI 2800 N m^2, 3.14 kg/m), clamped at one end, in mm and
    rad (translations scaled by 1000), 2 % Rayleigh damping on its first two modes, struck at its middle node
    (v0 = 1 m/s) and with a force input at its tip: 60 degrees of freedom, modes from 105 rad/s to 1.6e6 rad/s."""
    elements, length = 30, 1.0 / 30
    bending, mass = 2800.0 / length**3, 3.14 * length / 420
    le = length
    k_e = bending * np.array([[12, 6 * le, -12, 6 * le], [6 * le, 4 * le**2, -6 * le, 2 * le**2],
                              [-12, -6 * le, 12, -6 * le], [6 * le, 2 * le**2, -6 * le, 4 * le**2]])
    m_e = mass * np.array([[156, 22 * le, 54, -13 * le], [22 * le, 4 * le**2, 13 * le, -3 * le**2],
                           [54, 13 * le, 156, -22 * le], [-13 * le, -3 * le**2, -22 * le, 4 * le**2]])
    size = 2 * (elements + 1)
    K, M = np.zeros((size, size)), np.zeros((size, size))
    for e in range(elements):
        block = slice(2 * e, 2 * e + 4)
        K[block, block] += k_e
        M[block, block] += m_e
    K, M = K[2:, 2:], M[2:, 2:]   # clamped: the first node's translation and rotation are zero
    n = size - 2
    omega = np.sort(np.sqrt(np.linalg.eigvals(np.linalg.solve(M, K)).real))
    D = (2 * 0.02 * omega[0] * omega[1] / (omega[0] + omega[1])) * M + (2 * 0.02 / (omega[0] + omega[1])) * K
    scale = np.diag(1.0 / np.where(np.arange(n) % 2 == 0, 1000.0, 1.0))   # translations in mm

    def symmetric(matrix: np.ndarray) -> np.ndarray:
        scaled = scale @ matrix @ scale
        return 0.5 * (scaled + scaled.T)

    B = np.zeros((n, 1))
    B[n - 2, 0] = 1e-3
    Cp = np.zeros((3, n))
    Cp[0, n - 2], Cp[1, n - 1], Cp[2, 29] = 1.0, 1.0, 1.0
    v0 = np.zeros(n)
    v0[28] = 1000.0   # 1 m/s at the middle node
    return lti_fmus.LinearMechanicalModel(M=symmetric(M), D=symmetric(D), K=symmetric(K), B=B, Cp=Cp, v0=v0,
                                          name="BeamImpact")


@pytest.fixture(scope="module")
def beam():
    """The beam, its grid, the inputs in effect (u[:, i] held over the step that ends at t[i]) and its exact
    response with the model's own derivative at each sample."""
    model = _impacted_beam()
    t = np.arange(K_SAMPLES) * H
    held = parse_signal(IMPULSE, 1, ["u"]).sample(t[:-1])
    u = np.hstack([held[:, :1], held])
    response = lti_fmus.zoh_response(model, t, held)
    derivative = np.linalg.solve(model.M, model.B @ u - model.D @ response.v - model.K @ response.x)
    return SimpleNamespace(model=model, t=t, u=u, x=response.x, v=response.v, a=derivative)


def _judge(data, accelerations: np.ndarray, evaluate) -> Repair | None:
    """:func:`judge_run` of a recording with the exact positions and velocities of ``data`` and ``accelerations``,
    paired by the FMU's model structure (as the beam's FMU declares them)."""
    n = data.x.shape[0]
    selection = Selection([], [1], [1], {"positions": "pattern", "velocities": "pattern"}, [None] * n)
    source = SimpleNamespace(selection=selection, n=n, derived={"xdot": False, "xddot": False},
                             position_names=[f"x{i}" for i in range(n)], velocity_names=[f"v{i}" for i in range(n)],
                             label="model.fmu")
    run = SimpleNamespace(x=data.x, xdot=data.v, xddot=accelerations, u=data.u)
    return judge_run(source, run, data.t, evaluate=evaluate)


@pytest.fixture(scope="module")
def chain():
    """The free response of a 5-mass chain off rest at dt = 0.05 (its modes resolved), exact."""
    model = lti_fmus.chain_model(inputs=(), x0=[0.05, -0.02, 0.03, 0.0, 0.04], v0=[0.0, 0.1, 0.0, -0.05, 0.0])
    t = np.arange(600) * 0.05
    response = lti_fmus.zoh_response(model, t)
    return SimpleNamespace(t=t, u=np.zeros((0, t.size)), x=response.x, v=response.v, a=response.a)


def test_the_data_alone_call_the_impacted_beam_s_current_derivatives_stale(beam):
    """The premise (audit 71 F6, reproduced on exact data): no rule on sampled increments tells here."""
    assert np.abs(beam.a).max() > 0
    assert stale_rates(beam.v, beam.a, H, beam.u)


def test_the_fmu_s_own_value_overrules_the_data_on_current_derivatives(beam):
    """With the model's derivative just after a sample (what a current FMU gives there), the beam's exact current
    accelerations pass; where the FMU cannot be evaluated so, the data's verdict stands."""
    asked = []

    def current(rows, i):
        asked.append(i)
        return beam.a[rows, i]

    assert _judge(beam, beam.a, current) is None
    assert asked and 1 <= asked[0] < K_SAMPLES - 1
    unknown = _judge(beam, beam.a, lambda rows, i: None)
    assert isinstance(unknown, Repair) and unknown.reason == STALE_REASON


def test_a_stale_exporter_is_confirmed_by_its_own_value(chain):
    """Accelerations one sample late (a stale exporter's): just after sample i such an FMU gives the derivative at
    sample i, which it records only at i + 1.  The repair stands, its reason saying that the FMU confirmed it."""
    stale = np.hstack([chain.a[:, :1], chain.a[:, :-1]])
    asked = []

    def late(rows, i):
        asked.append(i)
        return chain.a[rows, i]

    repair = _judge(chain, stale, late)
    assert asked and isinstance(repair, Repair) and repair.accelerations == "" and repair.positions is None
    assert repair.reason.startswith(STALE_REASON) and "own value just after" in repair.reason
    assert _judge(chain, chain.a, late) is None and len(asked) == 1   # current data: the rule alone says so


def test_the_evaluated_sample_has_a_large_next_increment_and_a_steady_input():
    a = np.array([[0.0, 1.0, 1.0, 5.0, 5.1, 9.0, 9.0]])
    u = np.array([[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]])
    assert evaluation_sample(a, None) == 2      # 1 -> 5, the first of the increments >= half of the largest (4)
    assert evaluation_sample(a, u) == 4         # the input changes from sample 2 to 3: 5.1 -> 9.0 instead
    assert evaluation_sample(np.ones((2, 5)), None) is None
    assert evaluation_sample(a[:, :2], None) is None


def test_the_evaluation_decides_only_when_it_is_clearly_one_of_the_two_samples():
    now, after = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    assert evaluation_verdict(np.array([0.02, 0.98]), now, after) is True
    assert evaluation_verdict(np.array([0.98, 0.02]), now, after) is False
    assert evaluation_verdict(np.array([0.6, 0.4]), now, after) is None
    assert evaluation_verdict(np.array([np.nan, 0.0]), now, after) is None


@pytest.mark.fmu
def test_an_impacted_beam_fmu_keeps_its_own_accelerations(tmp_path):
    """The beam as an FMU (current derivatives), recorded by model exchange at audit 71's step (as the default
    recording does; its co-simulation crawls through the stiff modes): no stale verdict, and the accelerations
    recorded are the model's exact ones (before: derived from the data, far off where the step leaves the modes
    unresolved).  The direct evaluation runs one sample and a step of 2e-9 s: 0.1-0.7 s."""
    from fmu_opinf import snapshots
    from fmu_opinf.sources import open_source

    model = _impacted_beam()
    built = lti_fmus.build_lti_fmu(model, tmp_path / "beam.fmu", naming="generic", interfaces=("me",))
    source = open_source(str(built.path), tolerance=1e-10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = snapshots.record(source, IMPULSE, H, (K_SAMPLES - 1) * H, quiet=True).runs[0]
    said = [str(w.message) for w in caught]
    assert not any("lag the velocities" in text for text in said), said
    exact = lti_fmus.zoh_response(model, run.t, run.u[:, 1:])
    derivative = np.linalg.solve(model.M, model.B @ run.u - model.D @ exact.v - model.K @ exact.x)
    assert np.abs(run.x - exact.x).max() < 1e-6 * np.abs(exact.x).max()
    assert np.abs(run.xddot - derivative).max() < 1e-6 * np.abs(derivative).max()
