"""The reference DAE integrators against independent references (spec section 3)."""

import numpy as np
import pytest
import scipy.sparse as sp

from conftest import relative
from fmu_opinf import newmark, signals
from fmu_opinf.errors import DataError, DimensionError

IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"


@pytest.fixture(scope="module")
def triple_impulse_run(triple):
    return newmark.simulate(triple, IMPULSE, 0.05, 60.0)


def test_position_constraint_holds(anchored, anchored_impulse_run):
    run = anchored_impulse_run
    assert np.abs(anchored.G @ run.x).max() < 1e-12 * np.abs(run.x).max()
    assert np.abs(run.x).max() > 1e-3  # the run really moved


def test_velocity_constraint_holds(triple, triple_impulse_run):
    run = triple_impulse_run
    assert np.abs(triple.G @ run.xdot).max() < 1e-12 * np.abs(run.xdot).max()
    # with a zero initial state G x' = 0 implies G x = 0 (spec section 2)
    assert np.abs(triple.G @ run.x).max() < 1e-12 * np.abs(run.x).max()


@pytest.mark.parametrize("name", ["anchored", "triple"])
def test_dae_newmark_equals_classical_newmark_on_hidden_manifold(name, request):
    system = request.getfixturevalue(name)
    run = request.getfixturevalue(f"{name}_impulse_run")
    dt, t_end = run.t[1], run.t[-1]
    ode, N = system.hidden_manifold_ode()
    reduced = newmark.simulate(ode, IMPULSE, dt, t_end)
    for full, hidden in ((run.x, reduced.x), (run.xdot, reduced.xdot), (run.xddot, reduced.xddot)):
        assert relative(N @ hidden, full) < 1e-10
    assert relative(reduced.y, run.y) < 1e-10


def _error_vs_reference(system, spec, steps, t_end, x0=None, v0=None):
    fine = newmark.simulate(system, spec, t_end / steps[-1], t_end, x0=x0, v0=v0)
    errors = []
    for count in steps[:-1]:
        coarse = newmark.simulate(system, spec, t_end / count, t_end, x0=x0, v0=v0)
        stride = steps[-1] // count
        errors.append(np.abs(coarse.x - fine.x[:, ::stride]).max())
    return np.array(errors)


@pytest.mark.parametrize("name", ["anchored", "triple"])
def test_second_order_convergence_with_step_input(name, request):
    """A step switched on at a grid point is exactly representable by every grid, so only
    the integrator's error remains; halving h must divide it by about 4."""
    system = request.getfixturevalue(name)
    t_end = 40.0 if name == "anchored" else 8.0
    t_switch = t_end / 10  # a grid point of every grid used
    errors = _error_vs_reference(system, f"step:amplitude=1,t0={t_switch}", [100, 200, 400, 3200], t_end)
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all((orders > 1.8) & (orders < 2.2)), orders


@pytest.mark.slow  # 4 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_second_order_convergence_free_vibration(triple, rng):
    N = triple.kernel_basis()
    x0 = N @ rng.standard_normal(N.shape[1]) * 1e-2
    errors = _error_vs_reference(triple, "step:amplitude=0", [200, 400, 800, 6400], 8.0, x0=x0)
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all((orders > 1.8) & (orders < 2.2)), orders


@pytest.mark.parametrize("name", ["anchored", "triple"])
def test_energy_never_increases_without_input(name, request, rng):
    system = request.getfixturevalue(name)
    N = system.kernel_basis()
    x0 = N @ rng.standard_normal(N.shape[1])
    v0 = N @ rng.standard_normal(N.shape[1])
    run = newmark.simulate(system, "step:amplitude=0", 0.1, 50.0, x0=x0, v0=v0)
    energy = 0.5 * (np.sum(run.xdot * (system.M @ run.xdot), axis=0) + np.sum(run.x * (system.K @ run.x), axis=0))
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    assert energy[-1] < 0.9 * energy[0]  # and damping really dissipates


def test_consistent_initial_acceleration(anchored):
    run = newmark.simulate(anchored, "step:amplitude=3", 0.5, 1.0)
    a0 = run.xddot[:, 0]
    residual = anchored.M @ a0 - anchored.B.toarray()[:, 0] * 3.0
    # a0 satisfies the dynamics up to a constraint force along G^T, and G a0 = 0
    lam = residual @ anchored.G.toarray()[0] / 2.0
    assert np.abs(residual - lam * anchored.G.toarray()[0]).max() < 1e-13
    assert abs(anchored.G @ a0).max() < 1e-15


def test_applied_input_convention(anchored):
    run = newmark.simulate(anchored, "harmonic:amplitude=1,omega=0.3", 0.5, 5.0)
    expected = signals.harmonic(1.0, 0.3).sample(run.t)
    assert np.array_equal(run.u[:, 0], expected[:, 0])
    assert np.array_equal(run.u[:, 1:], expected[:, :-1])


def test_inconsistent_initial_state_is_rejected(anchored):
    x0 = np.zeros(anchored.n)
    x0[0] = 1.0
    with pytest.raises(DataError, match="violates the constraint"):
        newmark.simulate(anchored, "step:amplitude=0", 0.5, 1.0, x0=x0)


def test_bad_step_and_grid_are_rejected(anchored):
    with pytest.raises(DimensionError, match="positive"):
        newmark.NewmarkStepper(anchored.M, anchored.D, anchored.K, anchored.B, 0.0, anchored.G, "position")
    with pytest.raises(DimensionError, match="whole number of steps"):
        newmark.time_grid(0.3, 1.0)
    with pytest.raises(DimensionError, match="end time"):
        newmark.time_grid(0.1, 0.0)


def test_nan_input_is_rejected():
    M = sp.identity(2, format="csr")
    stepper = newmark.NewmarkStepper(M, 0 * M, M, np.ones((2, 1)), 0.1)
    stepper.start(np.zeros(1))
    with pytest.raises(DataError, match="NaN"):
        stepper.step(np.array([np.nan]))


def test_step_size_change_refactors():
    M = np.diag([1.0, 2.0])
    K = np.array([[3.0, -1.0], [-1.0, 2.0]])
    B = np.array([[1.0], [0.0]])
    a = newmark.NewmarkStepper(M, 0.1 * K, K, B, 0.1)
    a.start(np.ones(1))
    for _ in range(10):
        a.step(np.ones(1))
    a.set_step(0.05)
    for _ in range(20):
        a.step(np.ones(1))
    b = newmark.NewmarkStepper(M, 0.1 * K, K, B, 0.1)
    b.start(np.ones(1))
    for _ in range(10):
        b.step(np.ones(1))
    c = newmark.NewmarkStepper(M, 0.1 * K, K, B, 0.05)
    c.x, c.v, c.a, c.u = b.x, b.v, b.a, b.u
    for _ in range(20):
        c.step(np.ones(1))
    assert np.allclose(a.x, c.x, rtol=0, atol=1e-15) and abs(a.t - 2.0) < 1e-12


def test_step_matrices_reproduce_the_stepper(rng):
    r, m = 4, 2
    A = rng.standard_normal((r, r))
    M, K = A @ A.T + r * np.eye(r), np.diag(rng.uniform(1, 3, r))
    D, B = 0.1 * K, rng.standard_normal((r, m))
    u = rng.standard_normal((m, 30))
    stepper = newmark.NewmarkStepper(M, D, K, B, 0.2)
    stepper.start(u[:, 0])
    state = np.concatenate([stepper.x, stepper.v, stepper.a])
    phi, gamma_new, gamma_old = newmark.step_matrices(M, D, K, B, 0.2)
    for i in range(1, u.shape[1]):
        stepper.step(u[:, i])
        state = phi @ state + gamma_new @ u[:, i] + gamma_old @ u[:, i - 1]
        assert np.allclose(state, np.concatenate([stepper.x, stepper.v, stepper.a]), rtol=0, atol=1e-12)
