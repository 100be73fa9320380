"""The refinement's L-BFGS (issue 16) against independent references: the BFGS inverse-Hessian recursion, exact
minimizers, the strong Wolfe conditions, and SciPy's L-BFGS-B on the same problem.  That its work releases the GIL
is measured in ``benchmarks/bench_fit.py --total`` (the two starts side by side), not asserted here: on a loaded
2-core machine no timing can tell."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

from fmu_opinf._lbfgs import _CURVATURE, _DECREASE, LBFGSResult, _line_search, _Pairs, minimize_lbfgs


def _bfgs_inverse(pairs: list[tuple[np.ndarray, np.ndarray]], n: int) -> np.ndarray:
    """The textbook recursion ``H <- (I - rho s y^T) H (I - rho y s^T) + rho s s^T`` from ``gamma I``."""
    s, y = pairs[-1]
    H = (s @ y) / (y @ y) * np.eye(n)
    for s, y in pairs:
        rho = 1.0 / (s @ y)
        V = np.eye(n) - rho * np.outer(y, s)
        H = V.T @ H @ V + rho * np.outer(s, s)
    return H


@pytest.mark.parametrize("added", [3, 5, 9])  # fewer, as many as and more pairs than the memory
def test_compact_direction_equals_the_bfgs_recursion_over_the_last_pairs(added):
    rng = np.random.default_rng(added)
    n, memory = 15, 5
    A = rng.standard_normal((n, n))
    A = A @ A.T + np.eye(n)
    pairs, store = [], _Pairs(n, memory)
    for _ in range(added):
        s = rng.standard_normal(n)
        pairs.append((s, A @ s))
        store.add(*pairs[-1])
    g = rng.standard_normal(n)
    expected = -_bfgs_inverse(pairs[-memory:], n) @ g
    assert np.linalg.norm(store.direction(g) - expected) <= 1e-13 * np.linalg.norm(expected)


@pytest.mark.parametrize("added", [3, 5, 9])
def test_direction_from_projected_gradients_equals_the_bfgs_recursion(added):
    """The pass-saving path (pairs added with the gradients, each direction asked for before its pair comes)
    gives the recursion's direction too."""
    rng = np.random.default_rng(10 + added)
    n, memory = 15, 5
    A = rng.standard_normal((n, n))
    A = A @ A.T + np.eye(n)
    b = rng.standard_normal(n)
    x = rng.standard_normal(n)
    g = A @ x - b
    pairs, store = [], _Pairs(n, memory)
    for _ in range(added):
        store.direction(g)
        x_new = x + rng.standard_normal(n)
        g_new = A @ x_new - b
        pairs.append((x_new - x, g_new - g))
        store.add(*pairs[-1], gradient=g_new, previous=g)
        x, g = x_new, g_new
    assert store._projected is not None and store._projected[0] is g  # the cheap path was taken
    expected = -_bfgs_inverse(pairs[-memory:], n) @ g
    assert np.linalg.norm(store.direction(g) - expected) <= 1e-13 * np.linalg.norm(expected)


def test_quadratic_minimizer_is_found_to_the_gradient_tolerance():
    rng = np.random.default_rng(0)
    n = 60
    Q = rng.standard_normal((n, n))
    Q = Q @ Q.T / n + np.diag(np.linspace(0.1, 10.0, n))
    b = rng.standard_normal(n)
    exact = np.linalg.solve(Q, b)
    result = minimize_lbfgs(lambda x: (0.5 * x @ Q @ x - b @ x, Q @ x - b), np.zeros(n), max_iterations=500,
                            memory=20, ftol=0.0, gtol=1e-7)  # below ~1e-8 the objective's round-off stops it
    assert result.success and result.message == "gradient below gtol"
    assert np.max(np.abs(Q @ result.x - b)) <= 1e-7
    assert np.linalg.norm(result.x - exact) <= 1e-6 * np.linalg.norm(exact)  # |Q^-1| <= 10: measured 1.4e-8
    assert result.nit <= 40 and result.nfev <= 40  # SciPy's L-BFGS-B: 31 iterations, 34 evaluations, as here


def test_rosenbrock_takes_about_as_many_evaluations_as_scipys_l_bfgs_b():
    def rosen(x):
        return scipy.optimize.rosen(x), scipy.optimize.rosen_der(x)

    start = np.full(20, -1.0)
    ours = minimize_lbfgs(rosen, start, max_iterations=2000, memory=10, ftol=0.0, gtol=1e-10)
    scipys = scipy.optimize.minimize(rosen, start, jac=True, method="L-BFGS-B",
                                     options={"maxiter": 2000, "maxcor": 10, "ftol": 0.0, "gtol": 1e-10})
    assert ours.success and np.max(np.abs(ours.x - 1.0)) <= 1e-9  # the exact minimizer is all ones
    assert ours.nfev <= 1.25 * scipys.nfev  # measured 163 against 170


@pytest.mark.parametrize("first", [1e-6, 1.0, 1e3])  # extrapolates, accepts, interpolates
def test_line_search_meets_the_strong_wolfe_conditions(first):
    def fun(x):  # along d = 1: phi(t) = (t - 2)^4 + t, minimum near t = 1.37
        t = float(x[0])
        return (t - 2.0) ** 4 + t, np.array([4.0 * (t - 2.0) ** 3 + 1.0])

    f0, g0 = fun(np.zeros(1))
    state = LBFGSResult(np.zeros(1), f0, g0, 0, 1, False, "")
    d = np.ones(1)
    slope = float(g0 @ d)
    (step, f, g), evaluations = _line_search(fun, state, d, slope, first)
    assert f <= f0 + _DECREASE * step * slope
    assert abs(float(g @ d)) <= _CURVATURE * abs(slope)
    assert evaluations <= 10


def test_callback_stop_iteration_ends_with_the_last_iterate():
    seen = []

    def stop(result):
        seen.append(result.fun)
        if len(seen) == 3:
            raise StopIteration

    result = minimize_lbfgs(lambda x: (float(x @ x), 2.0 * x), np.arange(1.0, 6.0), max_iterations=50,
                            callback=stop, ftol=0.0, gtol=0.0)
    assert result.nit == 3 and result.message == "stopped by callback" and result.fun == seen[-1]


def test_line_search_recovers_from_trial_steps_that_overflow():
    """A first trial far beyond where the model exists (a ROM that blows up): tenfold shrinking, not halving."""
    def fun(x):
        t = float(x[0])
        if t > 1e-4:
            return np.inf, np.array([np.nan])
        return t * t - 2e-6 * t, np.array([2.0 * t - 2e-6])  # minimum at t = 1e-6

    f0, g0 = fun(np.zeros(1))
    state = LBFGSResult(np.zeros(1), f0, g0, 0, 1, False, "")
    slope = float(g0[0])
    (step, f, g), evaluations = _line_search(fun, state, np.ones(1), slope, 1.0)
    assert f <= f0 + _DECREASE * step * slope and abs(float(g[0])) <= _CURVATURE * abs(slope)
    assert evaluations <= 8  # halving would need 17 trials to get below 1e-4


def test_huge_curvature_keeps_its_pairs_like_l_bfgs_b():
    """Curvature far above 1 / eps (the refinement's factors in badly scaled units): a pair is kept when
    ``s^T y > eps (-g^T s)``, not ``eps y^T y``, or every iteration falls back to a steepest-descent search."""
    curvature = np.logspace(18, 20, 50)

    def fun(x):
        return 0.5 * float(curvature @ (x * x)), curvature * x

    ours = minimize_lbfgs(fun, np.ones(50), max_iterations=100, memory=20, ftol=0.0, gtol=1e-3)
    scipys = scipy.optimize.minimize(fun, np.ones(50), jac=True, method="L-BFGS-B",
                                     options={"maxiter": 100, "maxcor": 20, "ftol": 0.0, "gtol": 1e-3})
    assert ours.nfev <= 1.1 * scipys.nfev  # measured 103 and 103 (with the y^T y test: 306)
    assert ours.fun <= 1.1 * scipys.fun  # measured 28.6 and 28.6 (with the y^T y test: 7.8e11)
