"""The output-error refinement on trial steps that overflow, and ``fit --no-refine`` on a gross miss (audit 76 F1).

A recording whose "positions" are really a first-order state vector (x[7..12] = v + x[1..6] of a 6-mass chain,
no pair found) made ``fmu-opinf fit`` die in the order search's r = 12 refinement: a trial step's exact step map
overflowed, and scipy's ``expm_frechet`` raised ``ValueError: array must not contain infs or NaNs`` (a traceback,
exit 1).  The L-BFGS line search already treats an infinite objective as no decrease; the evaluation now returns
one instead of raising, so the refinement keeps its best finite point and ``fit`` says so in its stage line.  With
``--no-refine`` the same recording gave a ROM 2100-3200 % of range off its own training outputs without a word: the
training-miss warning was skipped for unrefined fits altogether; it now fires above ``GROSS_MISS``.

References: the exact zero-order-hold response (:func:`fmu_opinf.lti_fmus.zoh_response`, and the matrix
exponential of the first-order system for the state-vector recording) and the objective recomputed by
:func:`fmu_opinf.refinement.output_error_objective`, an independent simulation of the returned operators.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.linalg

from fmu_opinf import lti_fmus, refinement
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Run, Snapshots
from fmu_opinf.snapshots._rates import (
    inputs_in_effect,
    newmark_velocities_and_accelerations,
    time_grid,
)

DT = 0.05
OVERFLOW = "array must not contain infs or NaNs"   # scipy's message for a non-finite matrix


def _chain_data(t_end: float = 40.0) -> tuple[lti_fmus.LinearMechanicalModel, tuple[np.ndarray, ...]]:
    """Exact ZOH data of a 3-mass chain pushed by a pulse: ``(v, x, u, y, a)`` in the model's own coordinates."""
    model = lti_fmus.chain_model(3, inputs=(-1,), name="OverflowChain")
    t = time_grid(DT, t_end)
    u = inputs_in_effect(parse_signal("impulse:amplitude=10,t0=2,width=0.5", 1), t, 1)
    exact = lti_fmus.zoh_response(model, t, u[:, 1:])
    return model, (exact.v, exact.x, u, exact.y, exact.a)


def _overflow_on_calls(monkeypatch: pytest.MonkeyPatch, calls: set[int] | None) -> list[int]:
    """Make the exact step's gradient raise scipy's non-finite error on the given evaluation numbers (1-based;
    None: on every evaluation after the first two, the start's), as an overflowing trial step does; returns the
    call counter."""
    original = refinement._ExactStep.operator_gradients
    counter = [0]

    def overflowing(self, grad_A, grad_B):
        counter[0] += 1
        if (calls is None and counter[0] > 2) or (calls is not None and counter[0] in calls):
            raise ValueError(OVERFLOW)
        return original(self, grad_A, grad_B)

    monkeypatch.setattr(refinement._ExactStep, "operator_gradients", overflowing)
    return counter


def _refine(model: lti_fmus.LinearMechanicalModel, data: tuple[np.ndarray, ...], iterations: int = 60):
    v, x, u, y, _ = data
    start = (1.05 * model.M, 0.8 * model.D, 1.05 * model.K, model.B)   # away from the truth
    output_map = (model.Cp, model.Cv)
    *operators, report = refinement.refine_output_error(*start, v, x, u, y, DT, output_map=output_map,
                                                       integrator="exact", max_iterations=iterations)
    recomputed = refinement.output_error_objective(*operators, v, x, u, y, DT, output_map=output_map,
                                                   integrator="exact")
    return start, operators, report, recomputed


def test_overflowing_trial_steps_are_rejected_and_the_refinement_goes_on(monkeypatch):
    """Two trial steps that overflow (evaluations 3 and 4: the first line search; 1 and 2 are the start) are
    rejected, counted, and the refinement goes on from the finite start to the exact model's outputs; old code:
    the ValueError escaped."""
    model, data = _chain_data()
    _overflow_on_calls(monkeypatch, {3, 4})
    _, operators, report, recomputed = _refine(model, data)
    assert report["non_finite_trials"] == 2
    assert report["objective"] < 1e-3 * report["objective_start"], report   # without the overflows: 5e-5 of it
    assert recomputed == pytest.approx(report["objective"], rel=1e-6)
    assert all(np.all(np.isfinite(op)) for op in operators)


def test_a_refinement_whose_every_trial_overflows_keeps_its_start(monkeypatch):
    """Every trial after the start overflows: the line search finds no finite point, and the start's operators
    come back with the start's objective (status "kept start"), not an exception."""
    model, data = _chain_data()
    _overflow_on_calls(monkeypatch, None)
    start, operators, report, recomputed = _refine(model, data)
    assert report["status"] == "kept start" and report["non_finite_trials"] >= 1, report
    for got, given in zip(operators, start):
        np.testing.assert_allclose(got, given, rtol=1e-12, atol=1e-12 * np.abs(given).max())
    assert recomputed == pytest.approx(report["objective_start"], rel=1e-9)


def test_fit_says_in_its_stage_line_that_trial_steps_overflowed(monkeypatch, capsys):
    """``fit`` ends normally and its refinement line names the rejected trial steps (one line); the refinement
    still reaches the exact model's outputs (noisy accelerations make the SDP start 5.6e-2 off)."""
    _, (v, x, u, y, a) = _chain_data()
    t = time_grid(DT, 40.0)
    noisy = a + 0.05 * np.abs(a).max() * np.random.default_rng(0).standard_normal(a.shape)
    _overflow_on_calls(monkeypatch, {3})
    rom = fit_rom(Snapshots([Run(t, u, x, v, noisy, y)], {"dt": DT}), r=3, integrator="exact", quiet=False,
                  least_squares_candidate=False)
    lines = [line for line in capsys.readouterr().err.splitlines() if "overflow" in line]
    assert len(lines) == 1 and "1 trial step(s) made the model overflow and were rejected" in lines[0], lines
    assert rom.fit_info["refinement"]["non_finite_trials"] == 1
    assert rom.fit_info["refinement"]["objective"] < 1e-20, rom.fit_info["refinement"]


def _state_vector_recording(t_end: float = 60.0) -> tuple[Snapshots, np.ndarray]:
    """Audit 76 F1's recording without the FMU: a 6-mass chain's first-order state ``z = [s; v + s]`` (the exact
    ZOH step, a matrix exponential of the first-order system) recorded as 12 positions with derived rates, two
    runs (a 1000 N pulse on each input); returns the snapshots and the first run's exact outputs."""
    base = lti_fmus.chain_model(6, inputs=(2, 5), x0=[0, 0, 0, 0, 0, 0.05])
    Mi = np.linalg.inv(1000 * base.M)
    A = np.block([[np.zeros((6, 6)), np.eye(6)], [-Mi @ (1000 * base.K), -Mi @ (1000 * base.D)]])
    B = np.vstack([np.zeros((6, 2)), Mi @ base.B])
    T = np.eye(12) + np.eye(12, k=-6)   # z = T [s; v]: x[7..12] = v + x[1..6]
    A, B = T @ A @ np.linalg.inv(T), T @ B
    C = np.zeros((2, 12))
    C[0, 5] = C[1, 2] = 1.0
    C = C @ np.linalg.inv(T)
    block = scipy.linalg.expm(np.block([[A, B], [np.zeros((2, 14))]]) * 0.02)
    t = time_grid(0.02, t_end)
    runs = []
    for spec in ("impulse:amplitude=1000,t0=2,width=0.5;none", "none;impulse:amplitude=1000,t0=2,width=0.5"):
        u = inputs_in_effect(parse_signal(spec, 2), t, 2)
        z = np.zeros((12, t.size))
        z[:, 0] = T @ np.r_[base.x0, np.zeros(6)]
        for i in range(1, t.size):
            z[:, i] = block[:12, :12] @ z[:, i - 1] + block[:12, 12:] @ u[:, i]
        runs.append(Run(t, u, z, *newmark_velocities_and_accelerations(z, 0.02, u), C @ z))
    return Snapshots(runs, {"dt": 0.02, "derived_xdot": True, "derived_xddot": True}), runs[0].y


def test_no_refine_warns_where_the_sdp_solution_misses_its_training_outputs_grossly():
    """``--no-refine`` on the first-order state vector: the ROM misses its own training outputs by far more than
    their range (checked here by simulating it against the exact outputs), and says so; old code: silent."""
    snaps, y_exact = _state_vector_recording()
    with pytest.warns(FmuOpinfWarning, match=r"training outputs only to .*--no-refine"):
        rom = fit_rom(snaps, refine=False, quiet=True)
    sim = rom.simulate(parse_signal("impulse:amplitude=1000,t0=2,width=0.5;none", 2), 0.02, 60.0)
    miss = np.abs(sim.y - y_exact).max(axis=1) / np.ptp(y_exact, axis=1)
    assert miss.max() > 1.0, miss   # the warning tells the truth: over 100 % of the range off


def test_no_refine_stays_quiet_on_a_mechanical_recording():
    """The same bar does not fire on exact data of a mechanical model fitted at its full order without refinement."""
    _, (v, x, u, y, a) = _chain_data()
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        fit_rom(Snapshots([Run(time_grid(DT, 40.0), u, x, v, a, y)], {"dt": DT}), r=3, refine=False, quiet=True)
