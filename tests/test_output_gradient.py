"""The refinement's objective and gradient through the eigenvalues of the step map (``_output_gradient``).

References: the objective by a plain step-by-step loop and its derivative by central differences of that loop,
independent of both the adjoint recursion and the polynomial sums.
"""

import numpy as np
import pytest

from fmu_opinf._output_gradient import dense_output_gradient, modal_is_faster, modal_output_gradient
from fmu_opinf.refinement import newmark_step_map


def _plain_objective(A, B, C, runs):
    """``sum ||C z_i - t_i||^2`` by the step-by-step loop."""
    total = 0.0
    for z0, u, target in runs:
        z = np.asarray(z0, dtype=float)
        total += float(np.sum((C @ z - target[:, 0]) ** 2))
        for i in range(1, u.shape[1]):
            z = A @ z + B @ u[:, i]
            total += float(np.sum((C @ z - target[:, i]) ** 2))
    return total


def _damped_system(rng, r=6, m=2, p=2, dt=0.1):
    """A stable Newmark step map with distinct eigenvalues, its output map and two runs from non-zero states."""
    Q = rng.standard_normal((r, r))
    K = Q @ Q.T + r * np.eye(r)
    M = np.eye(r) + 0.1 * np.diag(rng.random(r))
    A, B = newmark_step_map(M, 0.02 * M + 0.01 * K, K, rng.standard_normal((r, m)), dt)
    C = rng.standard_normal((p, 2 * r))
    runs = [(rng.standard_normal(2 * r), rng.standard_normal((m, k)), rng.standard_normal((p, k))) for k in (150, 97)]
    return A, B, C, runs


def test_modal_gradient_equals_finite_differences_of_the_plain_loop(rng):
    A, B, C, runs = _damped_system(rng)
    value, grad_A, grad_B = modal_output_gradient(A, B, C, runs)
    assert value == pytest.approx(_plain_objective(A, B, C, runs), rel=1e-14)  # measured 6e-16
    for _ in range(3):
        dA, dB = rng.standard_normal(A.shape), rng.standard_normal(B.shape)
        fd = _richardson_difference(lambda h: _plain_objective(A + h * dA, B + h * dB, C, runs))
        # Richardson-extrapolated central differences: measured 3.7e-10 at worst over 60 seeded draws; plain
        # central differences at h = 1e-6 reached 1.2e-6 there (the step map's eigenvalues near 0.996 over 150
        # steps give large third derivatives), which made this test fail on some draws of the shared generator
        assert np.sum(grad_A * dA) + np.sum(grad_B * dB) == pytest.approx(fd, rel=2e-9)


def _richardson_difference(f, h: float = 1e-6) -> float:
    """``f'(0)`` from central differences at ``h`` and ``h / 2`` combined to cancel their ``h^2`` error."""
    def central(step: float) -> float:
        return (f(step) - f(-step)) / (2 * step)

    return (4 * central(h / 2) - central(h)) / 3


def test_modal_and_dense_gradients_agree_to_rounding(rng):
    A, B, C, runs = _damped_system(rng, r=12, m=1, p=3)
    modal = modal_output_gradient(A, B, C, runs)
    dense = dense_output_gradient(A, B, C, runs)
    assert modal[0] == pytest.approx(dense[0], rel=1e-14)  # measured 3e-16
    for got, want in zip(modal[1:], dense[1:]):
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()  # measured 1e-13


def test_modal_gradient_declines_repeated_and_defective_eigenvalues(rng):
    _, B, C, runs = _damped_system(rng, r=2, m=1, p=1)
    repeated = 0.9 * np.eye(4)                                  # one eigenvalue four times
    jordan = np.diag([0.9, 0.5, 0.3, 0.2]) + np.diag([1.0, 0, 0], 1) * 1.0
    jordan[1, 1] = 0.9                                          # a 2 x 2 Jordan block at 0.9
    for A in (repeated, jordan):
        assert modal_output_gradient(A, B, C, runs) is None
        assert dense_output_gradient(A, B, C, runs)[0] == pytest.approx(_plain_objective(A, B, C, runs), rel=1e-12)


def test_refinement_falls_back_to_the_dense_gradient_and_refuses_a_forced_modal_one(rng):
    from fmu_opinf.inference import refine_output_error

    r, k = 8, 300
    M, D, K = np.eye(r), 0.05 * np.eye(r), np.eye(r)            # eight identical oscillators: repeated poles
    B = rng.standard_normal((r, 1))
    x, v = rng.standard_normal((r, k)), rng.standard_normal((r, k))
    u, y = rng.standard_normal((1, k)), rng.standard_normal((1, k))
    Cp = rng.standard_normal((1, r))
    options = dict(output_map=(Cp, 0 * Cp), max_iterations=2)
    auto = refine_output_error(M, D, K, B, v, x, u, y, 0.1, gradient="auto", **options)[-1]
    dense = refine_output_error(M, D, K, B, v, x, u, y, 0.1, gradient="dense", **options)[-1]
    assert auto["objective"] == dense["objective"]
    with pytest.raises(ValueError, match="gradient='modal'"):
        refine_output_error(M, D, K, B, v, x, u, y, 0.1, gradient="modal", **options)
    with pytest.raises(ValueError, match="gradient='fast' is not known"):
        refine_output_error(M, D, K, B, v, x, u, y, 0.1, gradient="fast", **options)


def test_the_modal_way_is_chosen_where_it_was_measured_faster():
    assert not modal_is_faster(8, 1, 1)       # r = 4: 1.1-1.5x the dense time
    assert modal_is_faster(20, 1, 1)          # r = 10: 2-3x faster
    assert modal_is_faster(70, 3, 1)          # r = 35: 3.5x faster
    assert not modal_is_faster(20, 4, 3)      # many outputs and inputs: dense up to about r = 15


def test_output_errors_simulated_on_a_helper_thread_give_the_same_numbers(rng):
    """With a helper thread (a spare core) the outputs are simulated there, beside the eigendecomposition: the
    same bits as in one thread, and the plain loop's objective."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    import fmu_opinf._output_gradient as og

    A, B, C, runs = _damped_system(rng, r=12, m=1, p=3)
    threads = []
    simulate = og._output_errors

    def recording(*args):
        threads.append(threading.current_thread().name)
        return simulate(*args)

    alone = modal_output_gradient(A, B, C, runs)
    og._output_errors = recording
    try:
        with ThreadPoolExecutor(1, thread_name_prefix="helper") as pool:
            helped = modal_output_gradient(A, B, C, runs, pool)
    finally:
        og._output_errors = simulate
    assert len(threads) == 1 and threads[0].startswith("helper")
    assert helped[0] == alone[0] and all(np.array_equal(a, b) for a, b in zip(helped[1:], alone[1:]))
    assert helped[0] == pytest.approx(_plain_objective(A, B, C, runs), rel=1e-14)


def test_refinement_with_a_spare_core_ends_where_the_single_thread_one_does(rng):
    from fmu_opinf.inference import refine_output_error

    C = _damped_system(rng, r=10, m=1, p=2)[2]
    r, k = 10, 400
    Q = rng.standard_normal((r, r))
    M, K = np.eye(r), Q @ Q.T + r * np.eye(r)
    D = 0.02 * M + 0.01 * K
    B = rng.standard_normal((r, 1))
    x, v = rng.standard_normal((r, k)), rng.standard_normal((r, k))
    u, y = rng.standard_normal((1, k)), rng.standard_normal((1, k))
    options = dict(output_map=(C[:1, :r], C[:1, r:]), max_iterations=20, gradient="modal")
    one = refine_output_error(M, D, K, B, v, x, u, y, 0.1, **options)
    two = refine_output_error(M, D, K, B, v, x, u, y, 0.1, spare_core=True, **options)
    assert one[-1]["iterations"] == two[-1]["iterations"] > 0
    assert all(np.array_equal(a, b) for a, b in zip(one[:4], two[:4]))


def test_an_error_of_the_main_thread_is_raised_after_the_helper_ended(rng, monkeypatch):
    """Ctrl-C during the eigendecomposition: the helper's simulation is waited for (nothing left running) and the
    interrupt, not the helper's own failure, reaches the caller."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import fmu_opinf._output_gradient as og

    A, B, C, runs = _damped_system(rng, r=4, m=1, p=1)
    ended = threading.Event()

    def interrupted(_):
        raise KeyboardInterrupt

    def failing(*_):
        time.sleep(0.2)
        ended.set()
        raise ValueError("helper")

    monkeypatch.setattr(og, "_eigenbasis", interrupted)
    monkeypatch.setattr(og, "_output_errors", failing)
    with ThreadPoolExecutor(1) as pool:
        with pytest.raises(KeyboardInterrupt):
            modal_output_gradient(A, B, C, runs, pool)
        assert ended.is_set()


def test_polynomial_values_agree_with_horner_at_conjugate_pairs_in_any_order():
    """Issue 16: the modal gradient's polynomials are evaluated at one eigenvalue of each exact conjugate pair and
    conjugated for the other; the reference is Horner's rule (``numpy.polyval``) at every eigenvalue, also where the
    eigenvalues do not come in LAPACK's order (lower first, or a pair split apart) and where one is real."""
    from fmu_opinf._output_gradient import _polynomial_values

    rng = np.random.default_rng(3)
    A = rng.standard_normal((9, 9))
    mu = np.linalg.eigvals(A / (1.02 * np.abs(np.linalg.eigvals(A)).max()))
    assert np.count_nonzero(mu.imag > 0) >= 2 and np.count_nonzero(mu.imag == 0) >= 1, mu
    coefficients = rng.standard_normal((3, 700))
    for order in (np.arange(mu.size), np.arange(mu.size)[::-1], rng.permutation(mu.size)):
        at = mu[order]
        expected = np.array([[np.polyval(row[::-1], z) for z in at] for row in coefficients])
        np.testing.assert_allclose(_polynomial_values(coefficients, at), expected, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected).max())


def test_blocked_propagation_of_runs_of_any_length_equals_the_plain_loop(rng):
    """:func:`propagate_runs` (blocks of 64 steps, runs of similar length side by side, each run's forcing and
    states copied into and out of the blocked layout once) against the step-by-step loop, for lengths below,
    at and past a block, not multiples of it, and a one-sample run."""
    from fmu_opinf._output_gradient import _STRIDE, propagate_runs

    A, _, _, _ = _damped_system(rng, r=5)
    lengths = [1, 2, _STRIDE, _STRIDE + 1, 3 * _STRIDE - 7, 400, 397]
    forcings = [rng.standard_normal((10, k)) for k in lengths]
    starts = [rng.standard_normal(10) for _ in lengths]
    for z, f, z0 in zip(propagate_runs(A, forcings, starts), forcings, starts):
        plain = np.empty_like(f)
        plain[:, 0] = z0
        for i in range(1, f.shape[1]):
            plain[:, i] = A @ plain[:, i - 1] + f[:, i]
        assert z.shape == f.shape
        assert np.max(np.abs(z - plain)) <= 1e-12 * np.max(np.abs(plain)), f.shape   # measured 1e-15 relative
