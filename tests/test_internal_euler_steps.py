"""A co-simulation FMU that declares a fixed internal step (FMI 3 ``fixedInternalStepSize``) and takes several
explicit Euler steps of it per communication step (audit 73 F4: a Simulink ode1-style FMI 3 export, 0.003 s inside,
recorded at dt = 0.018).  The step check skips such FMUs (their results cannot depend on the communication step)
and the Euler rule of :func:`fmu_opinf.snapshots._integrator_checks.warn_if_euler_steps` fits one step per ``doStep``
only: ``snapshots`` said nothing, and the default fit refined the ROM toward the integrator (1-18 % of range off the
model, top mode 28 % underdamped), where the FMU's own derivatives give the model.

The recordings here are made in the test: explicit Euler substeps written out from the model's matrices (the FMU's
integrator), RK4 substeps and the exact zero-order-hold solution (:func:`fmu_opinf.lti_fmus.zoh_response`, also the
reference for the ROMs), judged by :func:`~fmu_opinf.snapshots._consistency.judge_run` as the recorder does.
"""

from __future__ import annotations

import re
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import miss_against_model

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Run, Snapshots
from fmu_opinf.snapshots._consistency import judge_run
from fmu_opinf.snapshots._notes import collecting_recording_notes, current_recording_notes
from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid
from fmu_opinf.sources._variables import Selection

#: The audit's FMU: internal step 0.003, recorded at the automatic window's dt = 0.018 (6 internal steps per doStep).
INTERNAL, DT, T_END = 0.003, 0.018, 54.0
IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"


def _model() -> lti_fmus.LinearMechanicalModel:
    """The audit's 4-mass chain (damping ratios 0.023-0.047, 1.7-8.9 rad/s), force on the last mass."""
    return lti_fmus.chain_model(4, inputs=(-1,), x0=[0.0, 0.0, 0.0, 0.05], name="FixedInternalStep")


def _substeps(method: str, spec: str = IMPULSE, dt: float = DT) -> SimpleNamespace:
    """What a co-simulation FMU records that integrates the model by ``method`` (``"euler"``: explicit, ``"semi"``:
    semi-implicit, ``"rk4"``) with steps of :data:`INTERNAL` inside each ``doStep`` of ``dt``, or exactly
    (``"exact"``); inputs held over each step, accelerations the model's derivatives at the recorded states (with
    the input of the step that ends there: the project's column convention)."""
    model = _model()
    t = time_grid(dt, T_END)
    u = inputs_in_effect(parse_signal(spec, 1), t, 1)
    if method == "exact":
        exact = lti_fmus.zoh_response(model, t, u[:, 1:])
        return SimpleNamespace(t=t, u=u, x=exact.x, v=exact.v, a=exact.a, y=exact.y)
    n = model.M.shape[0]
    stiffness, damping, force = (np.linalg.solve(model.M, matrix) for matrix in (model.K, model.D, model.B))
    x, v = np.empty((n, t.size)), np.empty((n, t.size))
    x[:, 0], v[:, 0] = model.x0, model.v0
    h = dt / round(dt / INTERNAL)

    def rate(xi, vi, ui):
        return vi, force @ ui - stiffness @ xi - damping @ vi

    for i in range(t.size - 1):
        xi, vi, ui = x[:, i].copy(), v[:, i].copy(), u[:, i + 1]
        for _ in range(round(dt / INTERNAL)):
            if method == "euler":
                dx, dv = rate(xi, vi, ui)
                xi, vi = xi + h * dx, vi + h * dv
            elif method == "semi":
                vi = vi + h * rate(xi, vi, ui)[1]
                xi = xi + h * vi
            else:
                k1 = rate(xi, vi, ui)
                k2 = rate(xi + h / 2 * k1[0], vi + h / 2 * k1[1], ui)
                k3 = rate(xi + h / 2 * k2[0], vi + h / 2 * k2[1], ui)
                k4 = rate(xi + h * k3[0], vi + h * k3[1], ui)
                xi = xi + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                vi = vi + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        x[:, i + 1], v[:, i + 1] = xi, vi
    a = force @ u - stiffness @ x - damping @ v
    y = model.Cp @ x + model.Cv @ v + model.Ca @ a + model.y0[:, None]
    return SimpleNamespace(t=t, u=u, x=x, v=v, a=a, y=y)


def _source(internal: float | None = INTERNAL, model_exchange: bool = False, derived: bool = False):
    """An FMI 3 co-simulation FMU source as :func:`judge_run` reads it: positions and velocities paired by the
    model structure, its own accelerations (``derived``: taken from the data), ``fixedInternalStepSize`` as
    given (None: not declared)."""
    n = _model().M.shape[0]
    selection = Selection([], [1], [1], {"positions": "pattern", "velocities": "pattern"}, [None] * n)
    md = SimpleNamespace(coSimulation=SimpleNamespace(fixedInternalStepSize=internal,
                                                      canHandleVariableCommunicationStepSize=True),
                         modelExchange=object() if model_exchange else None)
    return SimpleNamespace(selection=selection, n=n, derived={"xdot": False, "xddot": derived}, interface="cs",
                           position_names=[f"x{i}" for i in range(n)], velocity_names=[f"v{i}" for i in range(n)],
                           md=md, path="fis.fmu")


@collecting_recording_notes
def _judged(data: SimpleNamespace | list[SimpleNamespace],
            source: SimpleNamespace | None = None) -> tuple[dict, list[str]]:
    """The recording notes and the warnings of :func:`judge_run` on the run ``data`` (or each of a list of runs of
    one recording, in order), as the recorder judges them."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for each in data if isinstance(data, list) else [data]:
            run = SimpleNamespace(x=each.x, xdot=each.v, xddot=each.a, u=each.u)
            assert judge_run(source or _source(), run, each.t) is None
    return current_recording_notes(), [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)]


@pytest.mark.parametrize("spec", [IMPULSE, "harmonic:amplitude=1,omega=0.9"])
def test_explicit_euler_steps_inside_each_do_step_are_said(spec):
    """Before: no warning, no verdict (the impulse run, as in the audit; the harmonic changes the input at every
    step, whose share of the residual the rule removes).  Measured: the rule of 6 Euler steps fits to 5.2e-6
    (impulse) / 3.7e-6 (harmonic), an accurate integration's misses by 4.1e-3 / 2.3e-3."""
    notes, said = _judged(_substeps("euler", spec))
    assert notes.get("recording_verdicts") == ["euler-substeps"], said
    assert len(said) == 1 and "\n" not in said[0]
    assert "takes 6 steps of its fixedInternalStepSize=0.003 per communication step dt=0.018 by explicit Euler" \
        in said[0]
    found = re.search(r"increments to ([-+.e\d]+), an accurate integration's misses by ([-+.e\d]+)\)", said[0])
    fits, misses = float(found[1]), float(found[2])
    assert fits < 1e-5 and misses > 2e-3, said[0]
    assert "export it with a smaller fixedInternalStepSize or a higher-order solver" in said[0]


def test_the_fix_named_for_an_fmu_with_model_exchange_is_model_exchange():
    _, said = _judged(_substeps("euler"), _source(model_exchange=True))
    assert said[0].endswith("record by model exchange (--interface me or interface='me')")


@pytest.mark.parametrize("method", ["exact", "rk4"])
def test_an_accurate_fixed_internal_step_is_not_flagged(method):
    """The guard: the exact solution and RK4 with the same declared internal step (6 steps per doStep) get no
    warning (the accurate rule fits to 7e-6, Euler's misses by 3.9e-3)."""
    notes, said = _judged(_substeps(method))
    assert notes == {} and said == []


def test_euler_at_one_internal_step_per_do_step_is_told_as_before_with_a_fix_it_can_take():
    """dt = the internal step: the forward rule of one Euler step tells, as before (forward-euler); its advice was
    "record at a smaller --dt", which a fixed internal step does not allow (audit 73 F4, cosmetic)."""
    notes, said = _judged(_substeps("euler", dt=INTERNAL))
    assert notes.get("recording_verdicts") == ["forward-euler"] and len(said) == 1
    assert "smaller --dt (" not in said[0]
    assert "export it with a smaller fixedInternalStepSize or a higher-order solver" in said[0]


def test_where_the_data_cannot_tell_one_line_says_what_the_recording_follows_and_the_fix():
    """Semi-implicit Euler substeps fit neither rule (7.8e-3 / 3.9e-3); derived accelerations cannot be judged.
    Before: nothing at all."""
    notes, said = _judged(_substeps("semi"))
    assert notes.get("recording_verdicts") == ["internal-step"] and len(said) == 1 and "\n" not in said[0]
    assert "integrates with 6 steps of its fixedInternalStepSize=0.003 per communication step dt=0.018 and the " \
           "recording follows them; the data cannot tell its integrator from an accurate one" in said[0]
    assert "fit with --no-refine" in said[0]
    notes, said = _judged(_substeps("euler"), _source(derived=True))
    assert notes.get("recording_verdicts") == ["internal-step"]
    assert "gave no velocities or accelerations of its own" in said[0] and "--no-refine" not in said[0]


def test_a_run_that_cannot_tell_leaves_the_next_run_of_the_recording_to_judge():
    """A run table's first row at rest (nothing moves: the data cannot tell), then the impulse: the Euler verdict
    of the second run is not lost behind the first run's line; a third run that cannot tell adds no line."""
    rest = _substeps("euler", "harmonic:amplitude=0,omega=1")
    rest.x, rest.v, rest.a = (np.zeros_like(array) for array in (rest.x, rest.v, rest.a))
    notes, said = _judged([rest, _substeps("euler"), rest])
    assert notes.get("recording_verdicts") == ["internal-step", "euler-substeps"], said
    assert len(said) == 2 and "its positions did not move in the samples judged" in said[0]
    notes, said = _judged([rest, _substeps("exact"), rest])
    assert notes.get("recording_verdicts") == ["internal-step"] and len(said) == 1


def test_without_a_declared_internal_step_nothing_changes():
    notes, said = _judged(_substeps("euler"), _source(internal=None))
    assert notes == {} and said == []


def test_the_default_fit_of_euler_substeps_is_the_model(tmp_path):
    """The recording as ``snapshots`` writes it (its verdict from :func:`judge_run`) fitted with the defaults, then
    judged against the exact model.  Before (no verdict, refined toward the Euler steps): 1-18 % of range off in the
    audit; here measured 4e-14 .. 4e-13 (SDP on the FMU's derivatives, no refinement)."""
    data = _substeps("euler")
    notes, _ = _judged(data)
    attrs = {"n": 4, "m": 1, "p": 2, "source_kind": "fmu", "fmu_generation_tool": "Simulink", "fmi_interface": "cs",
             "derived_xddot": False, **notes}
    Snapshots([Run(data.t, data.u, data.x, data.v, data.a, data.y)], attrs).save(tmp_path / "train.h5")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rom = fit_rom(Snapshots.load(tmp_path / "train.h5"), quiet=True)
    # measured 6.2e-14 / 9.6e-14 / 8.7e-14 / 4.3e-13 (before: 0.090 / 0.069 / 0.070 / 0.18)
    for spec in ("none", IMPULSE, "harmonic:amplitude=1,omega=0.9", "harmonic:amplitude=1,omega=8"):
        assert miss_against_model(rom, _model(), spec, T_END) < 2e-12, spec
    assert rom.fit_info["refinement_skipped"] == "euler-substeps"
    assert any("follow the FMU's explicit Euler steps of its fixed internal step" in str(w.message) for w in caught)


def test_the_fit_keeps_the_sdp_for_euler_substeps_only_with_the_fmu_s_own_accelerations():
    """Accelerations derived from the samples follow the Euler steps too: then the verdict changes nothing."""
    from fmu_opinf.fit._time_integrator import _recorded_euler_step

    assert _recorded_euler_step({"recording_verdicts": ["euler-substeps"], "derived_xddot": np.False_}) == \
        "euler-substeps"
    assert _recorded_euler_step({"recording_verdicts": ["euler-substeps"], "derived_xddot": True}) is None
    assert _recorded_euler_step({"recording_verdicts": ["internal-step"], "derived_xddot": False}) is None
