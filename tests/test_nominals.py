"""Recording an FMU whose declared state nominals or velocity states do not fit its motion, against exact solutions.

Audit 2026-11-27 (finding 5): an FE-like export with state nominals spread over 1e-6 .. 1e3.  The reference is
:func:`fmu_opinf.lti_fmus.zoh_response` (matrix exponential of the minimal coordinates, independent of the FMU and of
the integrator).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.errors import FmuOpinfWarning  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.snapshots._consistency import check_rates  # noqa: E402
from fmu_opinf.snapshots._rate_tests import Repair  # noqa: E402
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


def test_a_step_too_coarse_for_a_pairing_the_model_structure_declares_is_no_wrong_guess(generic_fmu):
    """At dt = 0.7 (periods of a few seconds) the declared velocity x4 misses the increments of x1 by 0.4 per step.
    That was called a wrong guess: the positions' derivative variables were recorded again as velocities with
    accelerations from the data, and then the same mismatch stopped the recording.  Now a warning says to record at
    a smaller --dt, and the recording keeps the FMU's own velocities and accelerations, exact at the samples."""
    source = open_source(str(generic_fmu))
    assert "model structure" in source.selection.how["positions"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = record(source, "impulse:amplitude=1,t0=2,width=2", 0.7, 60.0, quiet=True).runs[0]
    said = [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)]
    assert len(said) == 1 and "record at a smaller --dt" in said[0] and "model structure" in said[0], said
    assert "guess" not in said[0]
    assert source.velocity_names == [f"x{i}" for i in range(4, 7)]
    assert source.selection.how["accelerations"] == "derivatives of the velocity states"
    reference = _exact(run)
    assert _relative(run.x, reference.x) < 1e-9   # measured 3.7e-10
    assert _relative(run.xdot, reference.v) < 4e-9   # 1.4e-9
    assert _relative(run.xddot, reference.a) < 5e-9   # 1.8e-9: the FMU's own accelerations


def test_scaled_velocity_states_are_repaired_without_blaming_a_guess():
    """Velocity states that the model structure pairs with the positions but that are their rates times 1e4 (states
    scaled by the exporter, like the FE-like export's x251 .. x500 by their nominals): the positions' derivative
    variables become the velocities, and the reason names the factor, not a wrong guess."""
    t = np.arange(0.0, 30.0, 0.05)
    u = np.where((t > 1.0) & (t < 2.0), 1.0, 0.0)[None, :]
    reference = lti_fmus.zoh_response(MODEL, t, u)
    names = {"positions": ["x1", "x2", "x3"], "velocities": ["x4", "x5", "x6"]}
    derivatives = ["der(x1)", "der(x2)", "der(x3)"]
    verdict = check_rates(reference.x, 1e4 * reference.v, None, 0.05, names, False, derivatives, declared=True)
    assert isinstance(verdict, Repair), verdict
    assert verdict.velocities == derivatives and verdict.accelerations == ""
    assert "times 1e+04" in verdict.reason and "scaled states" in verdict.reason and "guess" not in verdict.reason
    # the same data unscaled: consistent
    assert check_rates(reference.x, reference.v, None, 0.05, names, False, derivatives, declared=True) is None
    # unscaled at a step too coarse for the motion (0.4 off per step): the step's problem, no repair
    coarse_t = np.arange(0.0, 60.0, 0.7)
    coarse = lti_fmus.zoh_response(MODEL, coarse_t, np.where((coarse_t > 1.0) & (coarse_t < 3.0), 1.0, 0.0)[None, :])
    verdict = check_rates(coarse.x, coarse.v, None, 0.7, names, False, derivatives, declared=True)
    assert isinstance(verdict, str) and verdict.startswith("velocities do not match the positions"), verdict


def test_states_in_other_coordinates_are_refused_not_replaced_by_derivative_variables():
    """A generic LTI export whose states are ``z = T^-1 [x; v]`` (a state space in other coordinates, as from a
    transformed Simulink block): the halves of the guess are no positions and velocities, and the data pair none.
    Recording the first half with its derivative variables as velocities left the other half out, and the fit
    learned a model 120 % off without a word (ninth audit, finding 2); now the recording stops and names the
    states that are no combination of the positions' rates.  Velocity states that are the positions' rates times a
    constant (scaled by the exporter) are still repaired that way, under a guessed pairing too (and absolute
    velocities beside relative positions: ``test_other_exporters.py``)."""
    t = np.arange(0.0, 30.0, 0.05)
    u = np.where((t > 1.0) & (t < 2.0), 1.0, 0.0)[None, :]
    reference = lti_fmus.zoh_response(MODEL, t, u)
    names = {"positions": ["x1", "x2", "x3"], "velocities": ["x4", "x5", "x6"]}
    derivatives = ["der(x1)", "der(x2)", "der(x3)"]
    transform = np.random.default_rng(3).standard_normal((6, 6)) + 3.0 * np.eye(6)
    z = np.linalg.solve(transform, np.vstack([reference.x, reference.v]))
    verdict = check_rates(z[:3], z[3:], None, 0.05, names, True, derivatives)
    assert isinstance(verdict, str) and "the states x4, x5, x6 are no combination of the positions' rates" in verdict, \
        verdict
    # the fix a user can follow where no state is a position or a velocity (audit 74 F2: only --positions was named)
    assert "export the model with its mechanical states" in verdict and "\n" not in verdict, verdict
    scaled = check_rates(reference.x, 1e4 * reference.v, None, 0.05, names, True, derivatives)
    assert isinstance(scaled, Repair) and scaled.velocities == derivatives, scaled


def test_states_left_out_for_the_positions_derivative_variables_are_not_called_a_lag(tmp_path):
    """Velocity states scaled by the exporter, replaced by the positions' derivative variables (the rate check's
    repair above): compare's source warned that they "are recorded neither as positions nor as velocities ... an
    actuator lag" on an exact ROM (audit 74 F4).  Where the recorded velocities are the positions' derivative
    variables, the line says so; states left out beside the states' own velocities keep the lag wording."""
    import types
    import warnings

    from fmu_opinf.sources import _warn_unrecorded_states

    def said(velocities: list[str], name: str) -> str:
        column = types.SimpleNamespace
        selection = types.SimpleNamespace(velocities=[column(name=v) for v in velocities], followers={},
                                          position_derivatives=["der(x1)", "der(x2)"], unrecorded_states=["x3", "x4"])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            _warn_unrecorded_states(types.SimpleNamespace(selection=selection, path=str(tmp_path / name)))
        assert len(caught) == 1, caught
        return str(caught[0].message)

    scaled = said(["der(x1)", "der(x2)"], "scaled.fmu")
    assert "x3, x4 are not recorded (the velocities recorded are the positions' derivative variables)" in scaled
    assert "nothing is lost" in scaled
    lag = said(["x3", "x5"], "lag.fmu")
    assert "recorded neither as positions nor as velocities" in lag and "actuator lag" in lag
