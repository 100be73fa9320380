"""Issue 14 goal on the paper's benchmarks: the default fit (SDP + output-error refinement) is stable and at most 2x
the error of the better of intrusive POD-Galerkin and (stable) unconstrained least squares on the same basis.

The references are independent of the fit: POD-Galerkin uses the true system matrices, least squares the plain
normal equations, and all errors are eq. (19) against the reference simulator (benchmarks/bench_accuracy.py).
"""

import numpy as np
import pytest


def _check(figures):
    print(f"\n{figures}")
    assert figures["fit_stable"]
    assert figures["ratio"] <= 2.0


@pytest.mark.slow  # about 10 s idle, 20 s under load: four full-model test runs and the refinement
def test_anchored_chain_r5_is_within_2x_of_the_best_reference(bench):
    figures = bench.row("anchored", 5)
    _check(figures)
    assert figures["fit"] < figures["lstsq"]  # measured 6e-9 against 2e-7: the refinement, not luck of the SDP


@pytest.mark.slow  # about 12 s: the same references at r = 11, where the fixed output map stays 50x above
def test_anchored_chain_r11_with_the_refitted_output_map_beats_the_best_reference(bench):
    figures = bench.row("anchored", 11, "refit-map")
    _check(figures)
    assert figures["ratio"] <= 0.1  # measured 0.04 (the default fit with eq. 17's map: 51)


@pytest.mark.slow
def test_triple_chain_r10_is_within_2x_of_the_best_reference(bench):
    figures = bench.row("triple", 10)
    _check(figures)
    # the plain SDP (eq. 16 with the Mr >= I normalization) is 20x above least squares here
    plain = bench.max_error("triple", bench.fit_rom_default("triple", 10, refine=False))
    assert plain > 5 * figures["lstsq"]


def _per_output_errors(bench, system, rom, references):
    """Max over the benchmark's test inputs of each output's max error relative to that output's peak."""
    worst = np.zeros(len(references[0]))
    for spec, ref in zip(bench.TESTS, references):
        y = rom.simulate(spec, 0.1, 400.0).y
        worst = np.maximum(worst, np.abs(ref - y).max(axis=1) / np.abs(ref).max(axis=1))
    return worst


@pytest.mark.slow  # about 8 s: a training and four test runs of the anchored chain, two fits
def test_an_output_in_other_units_is_fitted_as_well_as_the_others(bench):
    """The anchored chain with its first output in km instead of m (a factor 1e-3): each output relative to its
    own size in the refinement (``output_weighting="per-output"``, the default) keeps every output within a tenth
    of POD-Galerkin's error on the same basis (measured 0.04); the lumped objective of eq. (19) left the small
    output 23x above POD-Galerkin (1.5e-2 against 6.3e-4, 2026-11-27), and the fit in m and in km differed."""
    import dataclasses

    import scipy.sparse as sp

    from fmu_opinf import newmark
    from fmu_opinf.basis import PODBasis
    from fmu_opinf.inference import fit_operators, fit_output_map
    from fmu_opinf.rom import SecondOrderROM

    metres = bench.system("anchored")
    errors = {}
    for name, factor in (("m", 1.0), ("km", 1e-3)):
        system = dataclasses.replace(metres, Cp=sp.diags([factor, 1.0, 1.0]) @ metres.Cp)
        train = newmark.simulate(system, bench.TRAIN, 0.1, 400.0)
        references = [newmark.simulate(system, spec, 0.1, 400.0).y for spec in bench.TESTS]
        V = PODBasis(r=5, kind="positions").fit([train]).basis_
        data = [V.T @ a for a in (train.xddot, train.xdot, train.x)]
        galerkin = SecondOrderROM(*(np.asarray(V.T @ (A @ V)) for A in (system.M, system.D, system.K)),
                                  np.asarray(V.T @ system.B.toarray()), np.asarray(system.Cp @ V),
                                  np.asarray(system.Cv @ V))
        ops = fit_operators(*data, train.u, y=train.y, dt=0.1)
        outputs = ops.output_map or fit_output_map(data[1], data[2], train.y)[:2]
        fitted = _per_output_errors(bench, system, SecondOrderROM(ops.Mr, ops.Dr, ops.Kr, ops.Br, *outputs),
                                    references)
        assert np.all(fitted <= 0.1 * _per_output_errors(bench, system, galerkin, references)), (name, fitted)
        errors[name] = fitted
    # the units of an output do not change the objective; 300 L-BFGS iterations amplify its rounding, so the two
    # fits differ within the iterates' swing (measured 16 %), where the lumped objective's differ 400x
    assert np.all(np.abs(np.log(errors["km"] / errors["m"])) < np.log(1.5)), errors


# ----------------------------------------------------------------------------------------------------------
# Refinement machinery (fast): Jacobian of the Levenberg-Marquardt polish, stagnation stop
# ----------------------------------------------------------------------------------------------------------
def _spd(rng, r, floor):
    A = rng.standard_normal((r, r))
    return A @ A.T / r + floor * np.eye(r)


def _two_runs(rng, r=3, dt=0.1, steps=150):
    """A known system through the reference Newmark stepper (fmu_opinf.newmark): an impulse run from rest and a
    free run from a non-zero state."""
    import scipy.sparse as sp

    from fmu_opinf import newmark, systems

    M, D, K = _spd(rng, r, 1.0), _spd(rng, r, 0.05), _spd(rng, r, 1.0)
    B, Cp = rng.standard_normal((r, 1)), rng.standard_normal((2, r))
    system = systems.SecondOrderSystem(M=sp.csr_matrix(M), D=sp.csr_matrix(D), K=sp.csr_matrix(K),
                                       G=sp.csr_matrix((0, r)), constraint=None, B=sp.csr_matrix(B),
                                       Cp=sp.csr_matrix(Cp), Cv=sp.csr_matrix((2, r)), name="oscillators")
    runs = (newmark.simulate(system, "impulse:amplitude=5,t0=0.5,width=0.5", dt, steps * dt),
            newmark.simulate(system, "none", dt, steps * dt, x0=rng.standard_normal(r), v0=rng.standard_normal(r)))
    return (M, D, K, B, Cp), runs


def _problem(rng, runs, Cp, columns=None):
    from fmu_opinf.refinement import _Trajectories

    C = np.hstack([Cp, np.zeros_like(Cp)])
    return _Trajectories(z=[np.vstack([run.x, run.xdot]) for run in runs], u=[run.u for run in runs],
                         target=[run.y for run in runs], C=C, dt=0.1, scales=np.array([2.0, 0.5, 3.0, 1.5]),
                         columns=columns)


def test_output_jacobian_matches_finite_differences_and_the_adjoint_gradient():
    """Forward sensitivities (Jacobian) against central differences of the simulated residuals, and ``2 J^T e``
    against the adjoint gradient of the L-BFGS objective: three independent derivations."""
    from fmu_opinf.refinement import _residuals_and_jacobian

    rng = np.random.default_rng(7)
    (M, D, K, B, Cp), runs = _two_runs(rng, steps=60)
    problem = _problem(rng, runs, Cp, columns=rng.uniform(0.5, 2.0, size=(3, 3)))
    point = rng.standard_normal(3 * 9 + 3)
    e, J = _residuals_and_jacobian(problem, point, 3, 1, chunk=7)  # chunks that do not divide the run length
    value, grad = problem.loss(point, 3, 1)
    assert e @ e == pytest.approx(value, rel=1e-12)
    np.testing.assert_allclose(2.0 * J.T @ e, grad, rtol=0, atol=1e-10 * np.abs(grad).max())
    step = 1e-6
    for index in rng.choice(point.size, 6, replace=False):
        shift = np.zeros_like(point)
        shift[index] = step
        fd = (_residuals_and_jacobian(problem, point + shift, 3, 1)[0]
              - _residuals_and_jacobian(problem, point - shift, 3, 1)[0]) / (2 * step)
        np.testing.assert_allclose(J[:, index], fd, rtol=0, atol=1e-6 * np.abs(J).max())


def test_levenberg_marquardt_polish_recovers_the_outputs_of_the_true_system():
    """From a perturbed structured start the polish drives the training output error to round-off level; the
    reference outputs come from fmu_opinf.newmark, not from the refinement's step map."""
    from fmu_opinf.inference import refine_output_error

    rng = np.random.default_rng(3)
    (M, D, K, B, Cp), runs = _two_runs(rng)
    x, v, u, y = (np.hstack([getattr(run, name) for run in runs]) for name in ("x", "xdot", "u", "y"))
    start = [A + 0.05 * _spd(rng, 3, 0.0) for A in (M, D, K)] + [B * 1.05]
    lengths = [run.t.size for run in runs]
    *_, plain = refine_output_error(*start, v, x, u, y, 0.1, output_map=(Cp, np.zeros_like(Cp)),
                                    run_lengths=lengths, max_iterations=30, rtol=0.0)
    *_, polished = refine_output_error(*start, v, x, u, y, 0.1, output_map=(Cp, np.zeros_like(Cp)),
                                       run_lengths=lengths, max_iterations=30, rtol=0.0, polish_iterations=40)
    assert polished["objective"] < 1e-3 * plain["objective"]
    assert polished["objective"] < 1e-12 * polished["objective_start"]


def test_variable_projection_gradient_matches_finite_differences_of_the_projected_objective():
    """With the output map re-fitted at every evaluation, the adjoint gradient (C held at its optimum) must equal
    central differences of the objective with C re-optimized at each shifted point (the envelope theorem)."""
    rng = np.random.default_rng(11)
    (M, D, K, B, Cp), runs = _two_runs(rng, steps=60)
    problem = _problem(rng, runs, Cp, columns=rng.uniform(0.5, 2.0, size=(3, 3)))
    problem.free_output_map = True
    point = rng.standard_normal(3 * 9 + 3)
    value, grad = problem.loss(point, 3, 1)
    fixed = _problem(rng, runs, Cp, columns=problem.columns)
    fixed.C = problem.C.copy()  # frozen at the map re-fitted for point
    assert fixed.loss(point, 3, 1)[0] == pytest.approx(value, rel=1e-12)
    assert fixed.loss(point, 3, 1)[0] < _problem(rng, runs, Cp).loss(point, 3, 1)[0]  # it is a better map
    step = 1e-6
    for index in rng.choice(point.size, 8, replace=False):
        shift = np.zeros_like(point)
        shift[index] = step
        fd = (problem.loss(point + shift, 3, 1)[0] - problem.loss(point - shift, 3, 1)[0]) / (2 * step)
        assert abs(fd - grad[index]) < 1e-8 * np.abs(grad).max()  # measured 2.3e-9 over all 30


@pytest.mark.parametrize("whiten", [False, True])
def test_refit_output_map_recovers_the_outputs_through_a_wrong_start_map(whiten):
    """The start's output map is wrong by a factor 1.3 and its operators perturbed: with the map fixed the
    refinement cannot reach the outputs of the true system (from fmu_opinf.newmark), with the map re-fitted it
    reaches them, and the returned map, taken back from the modal coordinates when ``whiten``, reproduces them
    in a ROM simulation."""
    from fmu_opinf.inference import refine_output_error
    from fmu_opinf.refinement import output_error_objective

    rng = np.random.default_rng(3)
    (M, D, K, B, Cp), runs = _two_runs(rng)
    x, v, u, y = (np.hstack([getattr(run, name) for run in runs]) for name in ("x", "xdot", "u", "y"))
    start = [A + 0.05 * _spd(rng, 3, 0.0) for A in (M, D, K)] + [B * 1.05]
    lengths = [run.t.size for run in runs]
    wrong = (1.3 * Cp, np.zeros_like(Cp))
    # the bounds below were measured on the lumped objective of eq. (19) (per output, the round-off level reached
    # is 1.4e-29 in modal coordinates; the simulated outputs below are checked either way)
    *_, fixed = refine_output_error(*start, v, x, u, y, 0.1, output_map=wrong, run_lengths=lengths,
                                    max_iterations=200, whiten=whiten, output_weighting="lumped")
    *mats, refit = refine_output_error(*start, v, x, u, y, 0.1, output_map=wrong, run_lengths=lengths,
                                       max_iterations=200, refit_output_map=True, whiten=whiten,
                                       output_weighting="lumped")
    assert fixed["output_map"] == "fixed" and refit["output_map"] == "refitted"
    assert fixed["objective"] > 1e-3  # measured 4.8e-3
    # the round-off floor: the same objective at the true operators and map, 4.9e-30 (outputs to ~2e-15)
    floor = output_error_objective(M, D, K, B, v, x, u, y, 0.1, output_map=(Cp, np.zeros_like(Cp)),
                                   run_lengths=lengths, output_weighting="lumped")
    # measured 2.6e-29 (modal) and 7.5e-30 since 2026-11-28, when the runs' states are stepped side by side (a
    # matrix product of all runs' block starts instead of one matrix-vector product per run: other rounding;
    # 1.3e-30 and 5.9e-30 before)
    assert refit["objective"] < 10 * floor
    Cpr, Cvr = refit["refitted_map"]
    from fmu_opinf.rom import SecondOrderROM

    rom = SecondOrderROM(*mats, Cpr, Cvr)
    for run, spec in zip(runs, ("impulse:amplitude=5,t0=0.5,width=0.5", "none")):
        simulated = rom.simulate(spec, 0.1, (run.t.size - 1) * 0.1, q0=run.x[:, 0], qdot0=run.xdot[:, 0]).y
        # measured 1.6e-13, 3.2e-15 (given), 9.2e-15, 3.0e-15 (modal); a map not taken back would be off by O(1)
        assert np.abs(simulated - run.y).max() < 1e-12 * np.abs(run.y).max()


@pytest.mark.slow  # about 8 s: two fits of the anchored chain and their test errors
def test_the_default_fit_ends_a_stalled_refinement_early_at_the_error_of_the_whole_budget(bench, monkeypatch):
    """Anchored r = 3, where the training objective stalls (the basis bounds it): the default fit stops at the
    stall (measured 186 of 300 iterations) and its max eps_y on the test inputs is that of the whole budget
    (measured 3.58e-6 against 3.59e-6)."""
    from fmu_opinf import inference

    stopped = bench.fit_rom_default("anchored", 3, dt=bench.CASES["anchored"].dt)
    monkeypatch.setattr(inference, "STALL_RTOL", 0.0)
    whole = bench.fit_rom_default("anchored", 3, dt=bench.CASES["anchored"].dt)
    stages = [rom.fit_info["refinement"] for rom in (stopped, whole)]
    assert stages[0]["status"] == "stagnated" and stages[0]["iterations"] < 250
    assert stages[1]["iterations"] == 300
    assert bench.max_error("anchored", stopped) <= 1.01 * bench.max_error("anchored", whole)


def test_stagnation_stop_fires_exactly_when_the_window_decrease_is_below_rtol():
    from types import SimpleNamespace

    from fmu_opinf.refinement import _Stagnation

    history = [1.0]
    stop = _Stagnation(history, window=5, rtol=0.1)
    values = [0.5 ** i for i in range(1, 11)] + [0.5 ** 10 * (1 - 0.01 * i) for i in range(1, 30)]
    calls = 0
    with pytest.raises(StopIteration):
        for value in values:
            calls += 1
            stop(SimpleNamespace(fun=value))
    # fast decrease for 10 iterations, then 1 % per iteration: over 5 iterations a factor < 1.1 from call 15 on
    ratio = [history[i - 5] / history[i] for i in range(5, len(history))]
    assert stop.stopped and calls == len(history) - 1
    assert ratio[-1] <= 1.1 and all(value > 1.1 for value in ratio[:-1])
    never = _Stagnation([1.0], window=5, rtol=0.0)
    for value in values:
        never(SimpleNamespace(fun=value))
    assert not never.stopped


@pytest.mark.parametrize("r, expected", [(3, "given"), (39, "given"), (40, "modal")])
def test_refinement_works_in_modal_coordinates_from_order_40(r, expected):
    from fmu_opinf.inference import refine_output_error

    rng = np.random.default_rng(5)
    M, D, K = _spd(rng, r, 1.0), _spd(rng, r, 0.05), _spd(rng, r, 1.0)
    B, Cp = rng.standard_normal((r, 1)), rng.standard_normal((1, r))
    x, v, u = rng.standard_normal((r, 20)), rng.standard_normal((r, 20)), rng.standard_normal((1, 20))
    y = rng.standard_normal((1, 20))
    *_, report = refine_output_error(M, D, K, B, v, x, u, y, 0.1, output_map=(Cp, np.zeros_like(Cp)),
                                     max_iterations=2)
    assert report["coordinates"] == expected


@pytest.mark.parametrize("integrator, state_weight", [("exact", 0.0), ("exact", 0.3), ("newmark", 0.3)])
def test_refinement_gradient_matches_finite_differences(integrator, state_weight):
    """The adjoint gradient of the refinement's objective against central differences, in scaled factor
    coordinates with column scales (all chain-rule paths): with the exact hold step (continuous-time ROMs; through
    the Frechet derivative of the matrix exponential) and with the state-error term."""
    rng = np.random.default_rng(11)
    (M, D, K, B, Cp), runs = _two_runs(rng, steps=60)
    problem = _problem(rng, runs, Cp, columns=rng.uniform(0.5, 2.0, size=(3, 3)))
    problem.integrator, problem.state_weight = integrator, state_weight
    point = rng.standard_normal(3 * 9 + 3)
    value, grad = problem.loss(point, 3, 1)
    step = 1e-6
    fd = np.array([(problem.loss(point + step * e, 3, 1)[0] - problem.loss(point - step * e, 3, 1)[0]) / (2 * step)
                   for e in np.eye(point.size)])
    np.testing.assert_allclose(grad, fd, rtol=0, atol=1e-7 * np.abs(grad).max())  # measured 1.4e-9 relative


@pytest.mark.parametrize("weighted", [False, True])
def test_equation_residual_matches_the_explicit_form_and_its_gradient_finite_differences(weighted):
    """The acceleration residual of the refinement's equation term against ``||X'' + M^-1 (D X' + K X - B U)||^2 /
    ||X''||^2`` computed directly (in the given coordinates ``q = T p`` when ``weighted``), and the log objective's
    gradient (output and equation terms, scaled factors with column scales) against central differences."""
    from fmu_opinf.refinement import _EquationResidual, _split_factors

    rng = np.random.default_rng(13)
    (M, D, K, B, Cp), runs = _two_runs(rng, steps=60)
    xdd, xd, x, u = (np.hstack([getattr(run, key) for run in runs]) for key in ("xddot", "xdot", "x", "u"))
    T = rng.standard_normal((3, 3)) + 3 * np.eye(3) if weighted else np.eye(3)
    T_inv = np.linalg.inv(T)
    # operators and data of p = T^-1 q: M_p = T^T M T, X_p = T^-1 X
    Mp, Dp, Kp, Bp = *(T.T @ A @ T for A in (M, D, K)), T.T @ B
    Mp, Dp, Kp = (A + 0.1 * _spd(rng, 3, 0.0) for A in (Mp, Dp, Kp))  # not the data's model: E > 0
    equation = _EquationResidual(T_inv @ xdd, T_inv @ xd, T_inv @ x, u, T if weighted else None)
    value = equation.value_and_gradients(Mp, Dp, Kp, Bp)[0]
    Mq, Dq, Kq, Bq = *(T_inv.T @ A @ T_inv for A in (Mp, Dp, Kp)), T_inv.T @ Bp
    direct = xdd + np.linalg.solve(Mq, Dq @ xd + Kq @ x - Bq @ u)
    assert value == pytest.approx(np.sum(direct**2) / np.sum(xdd**2), rel=1e-10)
    assert value > 1e-5  # a non-trivial residual (measured 1.5e-4 .. 2e-3)

    problem = _problem(rng, runs, Cp, columns=rng.uniform(0.5, 2.0, size=(3, 3)))
    problem.equation, problem.equation_weight = equation, 0.3
    point = rng.standard_normal(3 * 9 + 3)
    factors, _ = _split_factors(point, 3, 1)
    factors[0] += 3 * np.eye(3)  # a well-conditioned mass
    value, grad, J, E = problem.log_loss(point, 3, 1)
    assert value == pytest.approx(np.log(problem.loss(point, 3, 1)[0]) + 0.3 * np.log(E))
    step = 1e-6
    fd = np.array([(problem.log_loss(point + step * e, 3, 1)[0] - problem.log_loss(point - step * e, 3, 1)[0])
                   / (2 * step) for e in np.eye(point.size)])
    np.testing.assert_allclose(grad, fd, rtol=0, atol=1e-6 * np.abs(grad).max())


@pytest.mark.parametrize("whiten", [False, True])
def test_equation_weight_refines_towards_the_true_system_and_reports_the_residual(whiten):
    """``refine_output_error(equation_weight=0.1)`` from a perturbed start: the output error falls, the reported
    start residual is the explicit-form acceleration residual of the start (computed here directly, in the given
    coordinates also when the refinement works in modal ones), and without accelerations the option is refused."""
    from fmu_opinf.inference import refine_output_error

    rng = np.random.default_rng(17)
    (M, D, K, B, Cp), runs = _two_runs(rng, steps=100)
    xdd, xd, x, u, y = (np.hstack([getattr(run, key) for run in runs]) for key in ("xddot", "xdot", "x", "u", "y"))
    start = [A + 0.05 * _spd(rng, 3, 0.0) for A in (M, D, K)] + [B * 1.1]
    common = dict(output_map=(Cp, np.zeros_like(Cp)), run_lengths=[run.u.shape[1] for run in runs],
                  max_iterations=100, whiten=whiten)
    *_, report = refine_output_error(*start, xd, x, u, y, 0.1, equation_weight=0.1, xddot_r=xdd, **common)
    direct = xdd + np.linalg.solve(start[0], start[1] @ xd + start[2] @ x - start[3] @ u)
    assert report["acceleration_residual"][0] == pytest.approx(np.linalg.norm(direct) / np.linalg.norm(xdd),
                                                               rel=1e-9)
    assert report["objective"] < 3e-5 * report["objective_start"]  # measured 5.5e-6 / 1.9e-6 (given / modal)
    assert report["acceleration_residual"][1] < 0.4 * report["acceleration_residual"][0]  # measured 0.18 / 0.26
    assert report["history"][-1] == pytest.approx(report["objective"])
    with pytest.raises(ValueError, match="xddot_r"):
        refine_output_error(*start, xd, x, u, y, 0.1, equation_weight=0.1, **common)


@pytest.mark.parametrize("progress", [True, False])
def test_refinement_shows_labelled_progress_on_a_terminal_only_when_asked(monkeypatch, progress):
    """``progress=True`` (what ``fmu-opinf fit`` passes unless ``-q``) draws the iterations on a terminal; the
    bar's count ends at the iterations the report gives."""
    from conftest import fake_terminal
    from fmu_opinf import refinement
    from fmu_opinf.inference import refine_output_error

    terminal = fake_terminal(monkeypatch, refinement)
    rng = np.random.default_rng(3)
    (M, D, K, B, Cp), runs = _two_runs(rng)
    x, v, u, y = (np.hstack([getattr(run, name) for run in runs]) for name in ("x", "xdot", "u", "y"))
    start = [A + 0.05 * _spd(rng, 3, 0.0) for A in (M, D, K)] + [B * 1.05]
    *_, report = refine_output_error(*start, v, x, u, y, 0.1, output_map=(Cp, np.zeros_like(Cp)),
                                     run_lengths=[run.t.size for run in runs], max_iterations=60, rtol=0.5,
                                     window=5, progress=progress)
    if not progress:
        assert terminal.getvalue() == ""
        return
    assert report["status"] == "stagnated" and report["iterations"] < 60  # stopped early: the bar says when
    assert "output-error refinement (L-BFGS iterations)" in terminal.getvalue()
    last = terminal.getvalue().splitlines()[-1]
    assert terminal.getvalue().endswith("\n") and f"] {report['iterations']}/60 " in last, last


def test_many_outputs_are_compressed_without_changing_the_objective_or_its_gradient():
    """40 outputs of 3 modes (more outputs than the 6 states): the refinement reduces them to 6 through a QR of
    the output map (seventh audit: 200 outputs took 113 s and 2.3 GB).  The objective equals one computed from a
    ROM simulation (fmu_opinf.rom, per output relative to its size), and objective and gradient equal those of
    the uncompressed problem to rounding."""
    import scipy.sparse as sp

    from fmu_opinf import newmark, systems
    from fmu_opinf.refinement import _training_problem, output_error_objective
    from fmu_opinf.rom import SecondOrderROM

    rng = np.random.default_rng(11)
    r, p, dt = 3, 40, 0.1
    M, D, K = _spd(rng, r, 1.0), _spd(rng, r, 0.05), _spd(rng, r, 1.0)
    B, Cp = rng.standard_normal((r, 1)), rng.standard_normal((p, r)) * np.logspace(-1, 1, p)[:, None]
    system = systems.SecondOrderSystem(M=sp.csr_matrix(M), D=sp.csr_matrix(D), K=sp.csr_matrix(K),
                                       G=sp.csr_matrix((0, r)), constraint=None, B=sp.csr_matrix(B),
                                       Cp=sp.csr_matrix(Cp), Cv=sp.csr_matrix((p, r)), name="many")
    run = newmark.simulate(system, "impulse:amplitude=5,t0=0.5,width=0.5", dt, 30.0)
    y = run.y + 1e-3 * rng.standard_normal(run.y.shape) * np.abs(run.y).max(axis=1, keepdims=True)  # unreachable
    model = [A + 0.05 * _spd(rng, r, 0.0) for A in (M, D, K)] + [1.1 * B]
    value = output_error_objective(*model, run.xdot, run.x, run.u, y, dt, output_map=(Cp, np.zeros_like(Cp)))
    simulated = SecondOrderROM(*model, Cp, np.zeros_like(Cp)).simulate("impulse:amplitude=5,t0=0.5,width=0.5", dt,
                                                                     30.0).y
    expected = np.mean(np.sum((simulated - y) ** 2, axis=1) / np.sum(y ** 2, axis=1))
    assert value == pytest.approx(expected, rel=1e-10)
    args = (run.xdot, run.x, run.u, y, dt, (Cp, np.zeros_like(Cp)), [run.t.size], np.ones(4), "per-output")
    compressed, full = _training_problem(*args), _training_problem(*args, compress=False)
    assert compressed.C.shape == (2 * r, 2 * r) and full.C.shape == (p, 2 * r) and compressed.unreached > 0
    params = np.concatenate([np.linalg.cholesky(A).ravel() for A in model[:3]] + [model[3].ravel()])
    (v1, g1), (v2, g2) = compressed.loss(params, r, 1), full.loss(params, r, 1)
    assert v1 == pytest.approx(v2, rel=1e-12) and np.allclose(g1, g2, rtol=1e-9, atol=1e-12 * np.abs(g2).max())
