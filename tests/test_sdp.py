"""Dense interior-point SDP solver (fmu_opinf._sdp) against Clarabel and independent KKT checks (issue 16)."""

import cvxpy as cp
import numpy as np
import pytest

from conftest import exact_operator_data, spd
from fmu_opinf import _sdp
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf._sdp_paths import fit_compressed
from fmu_opinf.inference import compressed_factor, fit_operators

NORMALIZATIONS = ("trace", "mass-eigenvalue")


@pytest.fixture()
def rng():
    return np.random.default_rng(20261123)




def _active_data(rng, r=6, k=300, noise=0.5):
    """Noisy data of a system with rank-one damping and stiffness: several PSD bounds bind (rank-deficient
    optimum), so the SDP, not a least-squares solve, decides the result."""
    M = spd(rng, r, 1.0)
    wd, wk = rng.standard_normal((r, 1)), rng.standard_normal((r, 1))
    D, K = wd @ wd.T, wk @ wk.T + 0.05 * np.eye(r)
    B = rng.standard_normal((r, 1))
    x, v, u = rng.standard_normal((r, k)), rng.standard_normal((r, k)), rng.standard_normal((1, k))
    a = np.linalg.solve(M, B @ u - D @ v - K @ x) + noise * rng.standard_normal((r, k))
    return a, v, x, u


def _damping_data(rng, r=5, k=300, noise=0.3):
    """Rank-one damping, well conditioned mass and stiffness: cone screening keeps the damping cone only, so
    the default solver path (interior point on screened SDPs) applies."""
    M, K = spd(rng, r, 1.0), spd(rng, r, 1.0)
    w = rng.standard_normal((r, 1))
    B = rng.standard_normal((r, 1))
    x, v, u = rng.standard_normal((r, k)), rng.standard_normal((r, k)), rng.standard_normal((1, k))
    a = np.linalg.solve(M, B @ u - w @ (w.T @ v) - K @ x) + noise * rng.standard_normal((r, k))
    return a, v, x, u


def _scaled_problem(data):
    """R, r, m and the scaled Gram matrix G of the objective trace(T G T^T) (as in fmu_opinf._sdp_paths.fit_compressed)."""
    a, v, x, u = data
    r, m = x.shape[0], u.shape[0]
    R, _ = compressed_factor(a, v, x, u)
    R22 = R[m:, m:]
    R22 = R22 / (np.linalg.norm(R22) / np.sqrt(3 * r))
    return R, r, m, R22.T @ R22


def _objective(mats, G):
    T = np.hstack(mats)
    return float(np.sum((T @ G) * T))


def _clarabel_reference(G, r, normalization):
    """Independent reference: the SDP stated directly in cvxpy with matrix variables, Clarabel at 1e-10."""
    W = np.linalg.cholesky(G + 1e-14 * np.eye(3 * r))  # G = W W^T up to round-off
    mats = [cp.Variable((r, r), symmetric=True) for _ in range(3)]
    T = cp.hstack(mats)
    constraints = [mats[1] >> 0, mats[2] >> 0]
    if normalization == "trace":
        constraints += [mats[0] >> 0, cp.trace(mats[0]) == r]
    else:
        constraints += [mats[0] >> np.eye(r)]
    problem = cp.Problem(cp.Minimize(cp.sum_squares(T @ W)), constraints)
    problem.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
    return problem.value


def _kkt(mats, G, normalization):
    """Independent KKT check: dual matrices from the gradient; returns (min dual eigenvalue, |complementarity|)
    relative to the gradient scale, and the primal minimum eigenvalue (of M - I for M >= I)."""
    r = mats[0].shape[0]
    T = np.hstack(mats)
    grad = 2 * T @ G
    duals = [0.5 * (grad[:, b * r:(b + 1) * r] + grad[:, b * r:(b + 1) * r].T) for b in range(3)]
    primal = [mats[0] - (np.eye(r) if normalization != "trace" else 0), mats[1], mats[2]]
    if normalization == "trace":  # the multiplier that makes the mass block complementary
        duals[0] = duals[0] - np.sum(duals[0] * mats[0]) / np.trace(mats[0]) * np.eye(r)
    scale = np.linalg.norm(grad) + 1e-300
    dual_min = min(np.linalg.eigvalsh(z)[0] for z in duals) / scale
    comp = sum(abs(np.sum(z * p)) for z, p in zip(duals, primal)) / (scale * np.linalg.norm(T))
    primal_min = min(np.linalg.eigvalsh(p)[0] for p in primal)
    return dual_min, comp, primal_min


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
@pytest.mark.parametrize("method", ["auto", "sdp"])
def test_ipm_reaches_the_clarabel_optimum_with_active_cones(rng, normalization, method):
    R, r, m, G = _scaled_problem(_active_data(rng))
    *mats, info = fit_compressed(R, r, m, method, 1e-9, False, normalization, "ipm")
    reference = _clarabel_reference(G, r, normalization)
    assert info["solver"] == "IPM" and info["status"] == "optimal" and info["gap"] <= 1e-6
    assert _objective(mats, G) == pytest.approx(reference, rel=1e-6)
    ranks = [np.sum(np.linalg.eigvalsh(b) > 1e-6 * np.abs(b).max()) for b in mats[1:]]
    assert min(ranks) < r  # the optimum is rank deficient: the cones bind
    dual_min, comp, primal_min = _kkt(mats, G, normalization)
    assert dual_min > -1e-6 and comp < 1e-6 and primal_min > -1e-9


@pytest.mark.parametrize("normalization", NORMALIZATIONS)
def test_exact_data_gives_the_true_operators_and_zero_objective(rng, normalization):
    truth, data = exact_operator_data(rng)
    fit = fit_operators(*data, method="sdp", normalization=normalization, solver="ipm", refine=False)
    assert fit.info["solver"] == "IPM" and fit.info["status"] == "optimal"
    scale = np.trace(fit.Mr) / np.trace(truth[0])
    for got, want in zip((fit.Mr, fit.Dr, fit.Kr, fit.Br), truth):
        assert np.abs(got - scale * want).max() < 1e-6 * np.abs(want).max()
    assert fit.info["relative_residual"] < 1e-6


def test_certificate_rejects_a_suboptimal_point(rng):
    R, r, m, G = _scaled_problem(_active_data(rng))
    *mats, _ = fit_compressed(R, r, m, "sdp", 1e-9, False, "trace", "ipm")
    T = np.hstack(mats)
    assert _sdp.certificate(T, G, "trace", float(r))[0] < 1e-6
    worse = T.copy()
    worse[:, r:2 * r] += 0.01 * np.eye(r)  # still feasible, not optimal
    assert _sdp.certificate(worse, G, "trace", float(r))[0] > 1e-3


@pytest.mark.parametrize("k", [1, 4, 7])
def test_symmetric_kronecker_block_matches_its_definition(rng, k):
    """The upper triangle that _add_kron_upper adds (the part the Cholesky factorization of the Newton matrix
    reads) is the symmetric Kronecker product entry for entry."""
    Y, Z = spd(rng, k, 0.5), spd(rng, k, 0.5)
    n = k * (k + 1) // 2
    iu, ju = np.triu_indices(k)

    def mat(v):
        out = np.zeros((k, k))
        out[iu, ju] = v
        out[ju, iu] = v
        return out

    def inner(Ep, W):  # <E_pq, W> with both placements of an off-diagonal entry
        return np.sum(Ep * W)

    basis = [mat(e) for e in np.eye(n)]
    want = np.array([[inner(Ep, 0.5 * (Y @ Es @ Z + Z @ Es @ Y)) for Es in basis] for Ep in basis])
    start = rng.standard_normal((n, n))
    got = start.copy()
    _sdp._add_kron_upper(got, Y, Z)
    upper = np.triu_indices(n)
    assert np.abs((got - start)[upper] - want[upper]).max() < 1e-12


@pytest.mark.parametrize("reuse", [False, True])
@pytest.mark.parametrize("keep", [(0,), (1,), (2,), (0, 1), (0, 2), (1, 2)])
def test_eliminated_blocks_solve_the_constrained_least_squares_problem(rng, keep, reuse):
    """_reduced_quadratic (Schur complement through the triangular factor of H_FF): the recovered entries are the
    constrained minimizer over the eliminated blocks (KKT system solved directly), and the reduced quadratic
    form reproduces the full objective up to a constant.  ``reuse``: with the screening's factor of the whole
    H + a a^T (blocks in the order M, K, D), read from it where its leading blocks are the eliminated ones (kept
    Dr, or Dr and Kr: a wrong block permutation of W or of the Schur complement fails the checks)."""
    from fmu_opinf._sdp_paths import (_SCREENING_ORDER, _hessian, _leading_elimination, _mass_indicator,
                                      _reduced_quadratic, _solve_unconstrained)

    _, r, _, G = _scaled_problem(_active_data(rng))
    H, a = _hessian(G, r), _mass_indicator(r)
    factor = _solve_unconstrained(H, a, float(r), order=_SCREENING_ORDER)[1] if reuse else None
    free = [b for b in range(3) if b not in keep]
    reused = _leading_elimination(H, factor, free, keep, r * (r + 1) // 2) is not None
    assert reused == (reuse and keep in ((1,), (1, 2)))
    idx_a, idx_f, S, lin, recover = _reduced_quadratic(H, a, float(r), keep, r, factor)
    constrained = 0 not in keep
    H_ff, H_fa, a_f = H[np.ix_(idx_f, idx_f)], H[np.ix_(idx_f, idx_a)], a[idx_f]

    def full(w_a):
        w = np.empty(H.shape[0])
        w[idx_a], w[idx_f] = w_a, recover(w_a)
        return w

    values, scale = [], 0.0
    for w_a in rng.standard_normal((3, idx_a.size)):
        if constrained:  # [H_FF, a_F; a_F^T, 0] [w_F; -mu] = [-H_FA w_A; trace]
            kkt = np.block([[H_ff, a_f[:, None]], [a_f[None, :], np.zeros((1, 1))]])
            want = np.linalg.solve(kkt, np.concatenate([-H_fa @ w_a, [r]]))[:-1]
        else:
            want = np.linalg.solve(H_ff, -H_fa @ w_a)
        assert np.abs(recover(w_a) - want).max() <= 1e-8 * np.abs(want).max()
        w = full(w_a)
        values.append(w @ H @ w - (w_a @ S @ w_a + 2 * lin @ w_a))
        scale = max(scale, w @ H @ w)
    assert np.ptp(values) <= 1e-12 * scale  # the same constant for every w_A


def test_a_relaxation_with_a_violated_dropped_cone_is_ended_early_with_the_same_optimum(monkeypatch):
    """Where the Mr >= I screening's first SDP keeps the mass cone only (here forced: the prediction of
    ``_predicted_cones`` would skip that round) and its damping comes out clearly indefinite, the interior-point
    method stops there (status ``stopped``, fewer iterations than a full solve) and the damping cone is added: the
    result is still Clarabel's optimum of the full SDP, certified.  (Seed 1: the relaxation's damping is clearly
    indefinite; with the fixture's seed it is only slightly so and the relaxation is solved.)"""
    from fmu_opinf import _sdp_paths

    data = _damping_data(np.random.default_rng(1))
    monkeypatch.setattr(_sdp_paths, "_predicted_cones", lambda H, r: ((0,), None))
    ends = []
    original = _sdp.solve_ipm

    def spy(*args, **kwargs):
        result = original(*args, **kwargs)
        ends.append((len(args[2]), result.status, result.iterations))
        return result

    monkeypatch.setattr(_sdp, "solve_ipm", spy)
    fit = fit_operators(*data, normalization="mass-eigenvalue", refine=False)
    assert fit.info["cones"] == ["Mr", "Dr"] and fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6
    assert [(cones, status) for cones, status, _ in ends] == [(1, "stopped"), (2, "optimal")]
    assert ends[0][2] < ends[1][2]
    _, r, _, G = _scaled_problem(data)
    reference = _clarabel_reference(G, r, "mass-eigenvalue")
    assert abs(fit.info["sdp_objective"] - reference) <= 1e-6 * reference


def _spy_on_ipm_cones(monkeypatch) -> list[int]:
    """Record the number of cones of every interior-point solve (``fmu_opinf._sdp.solve_ipm``)."""
    cones, original = [], _sdp.solve_ipm

    def spy(*args, **kwargs):
        cones.append(len(args[2]))
        return original(*args, **kwargs)

    monkeypatch.setattr(_sdp, "solve_ipm", spy)
    return cones


def _mass_only_data(rng, noise=0.1):
    """Exact operator data with noisy accelerations whose Mr >= I optimum needs the mass cone only (its
    least-squares damping and stiffness are PSD)."""
    _, (a, v, x, u) = exact_operator_data(rng)
    return a + noise * rng.standard_normal(a.shape), v, x, u


@pytest.mark.parametrize("data, rounds, kept", [(lambda: _damping_data(np.random.default_rng(1)), [2], ["Mr", "Dr"]),
                                                (lambda: _damping_data(np.random.default_rng(20261123)), [2],
                                                 ["Mr", "Dr"]),
                                                (lambda: _mass_only_data(np.random.default_rng(5)), [1], ["Mr"])])
def test_mass_eigenvalue_screening_starts_with_the_cones_its_relaxation_shows(monkeypatch, data, rounds, kept):
    """The Mr >= I screening starts with the cones that the Mr-only relaxation's start (least squares in Dr, Kr
    with Mr = I) shows clearly indefinite: both damping data need the damping cone (one solve with both cones,
    where the relaxation was solved first before 2026-12-07: stopped early with seed 1, to its end with the
    fixture's seed), the noisy exact data need the mass cone only (the relaxation alone).  Either way the result
    is Clarabel's optimum of the full SDP, certified."""
    data = data()
    cones = _spy_on_ipm_cones(monkeypatch)
    fit = fit_operators(*data, normalization="mass-eigenvalue", refine=False)
    assert cones == rounds and fit.info["cones"] == kept
    assert fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6
    _, r, _, G = _scaled_problem(data)
    reference = _clarabel_reference(G, r, "mass-eigenvalue")
    assert abs(fit.info["sdp_objective"] - reference) <= 1e-6 * reference


@pytest.mark.parametrize("guess", [(0, 1), (0, 1, 2)])
def test_a_wrong_cone_prediction_costs_time_not_accuracy(monkeypatch, guess):
    """These data's Mr >= I optimum needs the mass cone only; a prediction that keeps more cones solves a
    tighter relaxation, still optimal for the full SDP (Clarabel's optimum, certified)."""
    from fmu_opinf import _sdp_paths

    data = _mass_only_data(np.random.default_rng(5))
    original = _sdp_paths._predicted_cones
    monkeypatch.setattr(_sdp_paths, "_predicted_cones", lambda H, r: (guess, original(H, r)[1]))
    fit = fit_operators(*data, normalization="mass-eigenvalue", refine=False)
    assert fit.info["cones"] == [_sdp_paths._BLOCKS[b] for b in guess]
    assert fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6
    _, r, _, G = _scaled_problem(data)
    reference = _clarabel_reference(G, r, "mass-eigenvalue")
    assert abs(fit.info["sdp_objective"] - reference) <= 1e-6 * reference


def test_least_squares_start_is_the_clipped_damping_of_least_squares_with_unit_mass(rng):
    """The Mr, Dr round's start: Mr = 1.3 I and the least-squares Dr with Mr = I (here from cvxpy on the matrix form,
    independent of the elimination), eigenvalues clipped at zero and raised by 0.3 of the largest magnitude."""
    from fmu_opinf import _sdp_paths

    _, r, _, G = _scaled_problem(_damping_data(rng))
    W = np.linalg.cholesky(G + 1e-14 * np.eye(3 * r))
    D, K = cp.Variable((r, r), symmetric=True), cp.Variable((r, r), symmetric=True)
    cp.Problem(cp.Minimize(cp.sum_squares(cp.hstack([np.eye(r), D, K]) @ W))).solve(solver=cp.CLARABEL)
    values, vectors = np.linalg.eigh(D.value)
    assert values[0] < -1e-2 * np.abs(values).max()  # a start that needs the clip
    expected = (vectors * (np.maximum(values, 0) + 0.3 * np.abs(values).max())) @ vectors.T
    _, _, S, lin, _ = _sdp_paths._reduced_quadratic(_sdp_paths._hessian(G, r), _sdp_paths._mass_indicator(r),
                                                    float(r), (0, 1), r)
    start = _sdp_paths._least_squares_start(S, lin, r)
    ns = r * (r + 1) // 2
    np.testing.assert_allclose(_sdp._mat(start[:ns], r), 1.3 * np.eye(r), rtol=0, atol=1e-15)
    np.testing.assert_allclose(_sdp._mat(start[ns:], r), expected, rtol=0, atol=1e-7 * np.abs(expected).max())


def _with_and_without_start(monkeypatch, start: str, data: tuple, normalization: str) -> tuple[list, list]:
    """The fits of ``data`` with the interior-point start ``_sdp_paths.<start>`` and with the default start (the
    function made to return None), and every :func:`_sdp.solve_ipm` result of both, in order."""
    from fmu_opinf import _sdp_paths

    fits, rounds, original = [], [], _sdp.solve_ipm

    def spy(*args, **kwargs):
        rounds.append(original(*args, **kwargs))
        return rounds[-1]

    monkeypatch.setattr(_sdp, "solve_ipm", spy)
    for chosen in (getattr(_sdp_paths, start), lambda *args: None):
        monkeypatch.setattr(_sdp_paths, start, chosen)
        fits.append(fit_operators(*data, normalization=normalization, refine=False))
    return fits, rounds


def test_the_least_squares_start_saves_iterations_and_keeps_the_optimum(rng, monkeypatch):
    """On the fixture's damping data the Mr, Dr round takes 9 iterations from the least-squares start against 10
    from the default one (Mr = 2 I, Dr = I, Z = I; 19 before the centrality correctors); the two optima agree to
    1e-9 and are certified."""
    fits, rounds = _with_and_without_start(monkeypatch, "_least_squares_start", _damping_data(rng),
                                           "mass-eigenvalue")
    assert [result.iterations for result in rounds] == [9, 10]
    assert all(fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6 for fit in fits)
    assert fits[0].info["sdp_objective"] == pytest.approx(fits[1].info["sdp_objective"], rel=1e-9)


@pytest.mark.parametrize("data, normalization, iterations", [
    (lambda rng: _damping_data(rng, r=12), "mass-eigenvalue", (10, 17)),
    (lambda rng: _active_data(rng, r=10), "mass-eigenvalue", (13, 16)),
    (lambda rng: _active_data(rng, r=8), "trace", (9, 10))])
def test_centrality_correctors_save_iterations_and_keep_the_clarabel_optimum(rng, monkeypatch, data, normalization,
                                                                            iterations):
    """Gondzio's correctors reuse each iteration's Cholesky factor: fewer iterations (pinned, with and without them),
    the same certified optimum, Clarabel's at tol 1e-10 to 1e-7 (here the interior-point rounds are all ``solve_ipm``
    calls of the fit, the screening's included)."""
    problem = data(rng)
    counts, original = [], _sdp.solve_ipm

    def spy(*args, **kwargs):
        result = original(*args, **kwargs)
        counts[-1] += result.iterations
        return result

    monkeypatch.setattr(_sdp, "solve_ipm", spy)
    fits = []
    for correctors in (3, 0):
        monkeypatch.setattr(_sdp, "_CORRECTORS", correctors)
        counts.append(0)
        fits.append(fit_operators(*problem, normalization=normalization, refine=False))
    reference = fit_operators(*problem, normalization=normalization, refine=False, solver="clarabel", tol=1e-10)
    assert tuple(counts) == iterations
    assert all(fit.info["solver"] == "IPM" and fit.info["gap"] <= 1e-6 for fit in fits)
    assert fits[0].info["sdp_objective"] == pytest.approx(fits[1].info["sdp_objective"], rel=1e-9)
    assert fits[0].info["sdp_objective"] == pytest.approx(reference.info["sdp_objective"], rel=1e-7)


def test_centrality_targets_move_the_scaled_trial_products_into_the_box(rng):
    """``E = L^-T T L^-1`` with ``T`` the change that puts the eigenvalues of the symmetrized scaled product at the
    trial point into ``[0.1, 2] mu`` (computed here from explicit inverses): ``L^T E L = T``, and the corrected
    products lie in the box where no eigenvalue is more than ``4 mu`` above it."""
    k, mu, aim = 6, 0.3, 0.9
    X, Z, dX, dZ = spd(rng, k, 1.0), spd(rng, k, 1.0), rng.standard_normal((k, k)), rng.standard_normal((k, k))
    dX, dZ = 0.3 * (dX + dX.T), 0.3 * (dZ + dZ.T)
    L = np.linalg.cholesky(X)
    Li = np.linalg.inv(L)
    (E,) = _sdp._centrality_targets([L], [Li], [X], [Z], [dX], [dZ], aim, mu)
    A, B = Li @ (X + aim * dX) @ Li.T, L.T @ (Z + aim * dZ) @ L
    product = 0.5 * (A @ B + B @ A)
    values = np.linalg.eigvalsh(product)
    assert values[0] < 0.1 * mu and values[-1] > 2 * mu  # both sides of the box are exercised
    T = L.T @ E @ L
    np.testing.assert_allclose(T, T.T, atol=1e-12)
    corrected = np.linalg.eigvalsh(product + T)
    lowered = np.maximum(2 * mu, values - 2 * mu)  # lowered to the box, by at most its top
    expected = np.sort(np.where(values < 0.1 * mu, 0.1 * mu, np.where(values > 2 * mu, lowered, values)))
    np.testing.assert_allclose(corrected, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("columns", [None, 2])
def test_cholesky_solve_matches_a_dense_solve(rng, columns):
    n = 40
    N = spd(rng, n, 1.0)
    factor = _sdp._regularized_cholesky(lambda: N.copy())
    b = rng.standard_normal(n if columns is None else (n, columns))
    np.testing.assert_allclose(_sdp._cho_solve(factor, b), np.linalg.solve(N, b), rtol=1e-12, atol=1e-12)


def test_an_iterate_that_followed_round_off_below_zero_is_not_certified(rng, monkeypatch):
    """An interior-point result whose reduced objective is clearly negative (exact data: 100 iterations ran along
    the round-off of the elimination, objective -0.2) is not accepted even where the certificate on G passes; the
    default solver then falls back to Clarabel."""
    from fmu_opinf import _sdp_paths

    data = _damping_data(rng)
    original = _sdp.solve_ipm

    def negative(*args, **kwargs):
        result = original(*args, **kwargs)
        result.info["objective"] = -0.2
        return result

    monkeypatch.setattr(_sdp, "solve_ipm", negative)
    fit = fit_operators(*data, normalization="mass-eigenvalue", refine=False)
    assert fit.info["solver"] == "CLARABEL" and fit.info["fallback"]["status"] == "not_certified"
    assert fit.info["fallback"]["gap"] <= 1e-6  # the certificate alone would have accepted it
    assert _sdp_paths._ran_away(-1e-15, np.eye(3), 1, 1.0) is False


def test_failed_certificate_falls_back_to_clarabel(rng, monkeypatch):
    data = _damping_data(rng)
    original = _sdp.solve_ipm
    monkeypatch.setattr(_sdp, "solve_ipm", lambda *a, **k: original(*a, **dict(k, max_iterations=2)))
    fit = fit_operators(*data, normalization="trace", refine=False)
    assert fit.info["solver"] == "CLARABEL" and fit.info["status"] == "optimal"
    assert fit.info["fallback"]["status"] == "not_certified"
    with pytest.warns(FmuOpinfWarning, match="not certified"):
        only = fit_operators(*data, normalization="trace", refine=False, solver="ipm")
    assert only.info["status"] == "not_certified"


def test_default_solver_matches_clarabel_and_reports_the_certificate(rng):
    data = _damping_data(rng)
    fast = fit_operators(*data, refine=False)
    slow = fit_operators(*data, refine=False, solver="clarabel")
    assert fast.info["solver"] == "IPM" and fast.info["gap"] <= 1e-6
    assert fast.info["objective"] == pytest.approx(slow.info["objective"], rel=1e-6)
    assert fast.info["normalization"] == slow.info["normalization"]
    assert len(fast.info["cones"]) < 3


def test_same_ipm_operators_with_one_and_two_blas_threads(rng):
    from threadpoolctl import threadpool_limits

    data = _active_data(rng, r=8, k=1000)
    with threadpool_limits(limits=1):
        one = fit_operators(*data, refine=False, solver="ipm")
    with threadpool_limits(limits=2):
        two = fit_operators(*data, refine=False, solver="ipm")
    for name in ("Mr", "Dr", "Kr", "Br"):
        assert np.array_equal(getattr(one, name), getattr(two, name))


def test_two_indefinite_blocks_are_screened_for_the_ipm_with_the_full_sdp_optimum():
    rng = np.random.default_rng(5)  # the data of test_inference's two-indefinite-blocks test
    r, k = 5, 300
    M = spd(rng, r, 1.0)
    D, K = (w @ w.T for w in rng.standard_normal((2, r, 1)))
    B = rng.standard_normal((r, 1))
    x, v, u = rng.standard_normal((r, k)), rng.standard_normal((r, k)), rng.standard_normal((1, k))
    a = np.linalg.solve(M, B @ u - D @ v - K @ x) + 0.3 * rng.standard_normal((r, k))
    fast = fit_operators(a, v, x, u, normalization="trace", refine=False)
    assert fast.info["solver"] == "IPM" and fast.info["method"] == "sdp-screened"
    assert fast.info["cones"] == ["Dr", "Kr"]
    _, r_, _, G = _scaled_problem((a, v, x, u))
    assert fast.info["sdp_objective"] == pytest.approx(_clarabel_reference(G, r_, "trace"), rel=1e-6)


def test_unknown_solver_is_rejected(rng):
    with pytest.raises(ValueError, match="solver="):
        fit_operators(*_active_data(rng), solver="admm")


def test_certificate_rejects_a_runaway_point_on_round_off_negative_data():
    """A numerically indefinite G (exact data: R22 singular to round-off) lets an iterate run away along the
    negative direction; its size once made the relative gap tiny (measured on exact continuous-time data:
    M ~ 1e14, objective -8e12, 'certified' at 7e-8, output error 4e-5 instead of 2e-20)."""
    r = 3
    G = np.eye(3 * r)
    G[0, 0] = -1e-10  # round-off below zero along the mass block's first entry
    T = np.hstack([np.diag([1e14, 1.0, 1.0]), np.eye(r), np.eye(r)])
    gap, details = _sdp.certificate(T, G, "mass-eigenvalue", float(r))
    assert details["objective"] < 0
    assert gap == float("inf")


# ----------------------------------------------------------------------------------------------------------
# Factored start (L-BFGS over PSD factors) for large orders
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("data", [_active_data, _damping_data])
def test_factored_solve_reaches_the_clarabel_optimum_and_stays_feasible(rng, data):
    """The uncertified factored solve of eq. (16) with Mr >= I ends at the optimum of the SDP stated directly in
    cvxpy (Clarabel at 1e-10), from above, with Mr - I, Dr, Kr PSD."""
    from fmu_opinf._sdp_paths import fit_factored

    R, r, m, G = _scaled_problem(data(rng))
    *mats, info = fit_factored(R, r, m)
    reference = _clarabel_reference(G, r, "mass-eigenvalue")
    value = _objective(mats, G)
    assert info["method"] == "factored" and info["status"] == "approximate"
    assert info["sdp_objective"] == pytest.approx(value, rel=1e-12)
    assert value == pytest.approx(reference, rel=1e-9)  # measured 1.6e-11, 3.7e-11 (in 151, 114 iterations)
    assert value >= reference * (1 - 1e-9)  # every iterate is feasible: never below the optimum (but for round-off)
    _, _, primal_min = _kkt(mats, G, "mass-eigenvalue")
    assert primal_min > -1e-12


def _graded_data(rng, r=8, k=400, noise=0.3):
    """Noisy data whose positions and velocities span six decades of energy across directions: the damping and
    stiffness blocks of the quadratic form have condition numbers near 1e6 (the triple chain's reach 6e10)."""
    M, K = spd(rng, r, 1.0), spd(rng, r, 1.0)
    w, B = rng.standard_normal((r, 1)), rng.standard_normal((r, 1))
    scale = np.logspace(0, -3, r)[:, None]
    x, v, u = scale * rng.standard_normal((r, k)), scale * rng.standard_normal((r, k)), rng.standard_normal((1, k))
    a = np.linalg.solve(M, B @ u - w @ (w.T @ v) - K @ x) + noise * rng.standard_normal((r, k))
    return a, v, x, u


def test_preconditioned_factored_solve_converges_faster_on_graded_data(rng):
    """The preconditioner of the factored solve pays on ill-conditioned blocks: after 300 iterations it is within
    1e-6 of Clarabel's optimum (measured 4.8e-8) where the plain factors are 2.3e-5 above it, and both end at the
    optimum."""
    from fmu_opinf._sdp_paths import fit_factored

    R, r, m, G = _scaled_problem(_graded_data(rng))
    assert np.linalg.cond(G[r:2 * r, r:2 * r]) > 1e5
    reference = _clarabel_reference(G, r, "mass-eigenvalue")
    gaps = {}
    for exponent in (0.0, 0.2):
        *mats, _ = fit_factored(R, r, m, iterations=300, exponent=exponent)
        gaps[exponent] = (_objective(mats, G) - reference) / reference
        *mats, info = fit_factored(R, r, m, exponent=exponent)
        assert _objective(mats, G) == pytest.approx(reference, rel=1e-9)
    assert gaps[0.2] < 2e-7 and gaps[0.0] > 100 * gaps[0.2]


def test_auto_solver_starts_from_the_factored_solve_only_above_order_60_with_refinement():
    from fmu_opinf._sdp_paths import factored_start

    assert factored_start("auto", 61, True, "auto")
    assert not factored_start("auto", 60, True, "auto")
    assert not factored_start("auto", 75, False, "auto")  # the plain SDP fit stays certified
    assert not factored_start("auto", 75, True, "sdp")
    assert not factored_start("ipm", 75, True, "auto") and not factored_start("clarabel", 75, True, "auto")
    assert factored_start("factored", 3, False, "auto")


def test_factored_solver_with_the_trace_normalization_is_rejected(rng):
    with pytest.raises(ValueError, match="normalization='auto' or 'mass-eigenvalue'"):
        fit_operators(*_active_data(rng), solver="factored", normalization="trace")


# ----------------------------------------------------------------------------------------------------------
# Labelled progress of long solves
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("progress", [True, False])
def test_sdp_solves_show_labelled_progress_on_a_terminal_only_when_asked(rng, monkeypatch, progress):
    """``fit_operators(progress=True)`` (what ``fmu-opinf fit`` passes unless ``-q``) draws each interior-point
    solve and the factored start's iterations on a terminal, ending at 100 % for a solve that met its own
    stopping test and at the factored start's iteration count."""
    from conftest import fake_terminal
    from fmu_opinf import _sdp_paths

    terminal = fake_terminal(monkeypatch, _sdp_paths)
    data = _active_data(rng)
    fit = fit_operators(*data, method="sdp", normalization="mass-eigenvalue", solver="ipm", refine=False,
                        progress=progress)
    factored = fit_operators(*data, solver="factored", refine=False, progress=progress)
    if not progress:
        assert terminal.getvalue() == ""
        return
    lines = terminal.getvalue().split("\n")
    sdp = [line for line in lines if "SDP mass-eigenvalue, cones Mr/Dr/Kr (interior point, % to tol)" in line]
    assert fit.info["ipm_status"] in ("optimal", "floor") and sdp and "] 100/100 " in sdp[0].split("\r")[-1]
    steps = [line for line in lines if "factored start (L-BFGS iterations)" in line]
    assert steps and f"] {factored.info['iterations']}/" in steps[0].split("\r")[-1]
    assert terminal.getvalue().endswith("\n")


@pytest.mark.parametrize("normalization", ["mass-eigenvalue", "auto"])
def test_a_singular_eliminated_block_keeps_every_cone(rng, monkeypatch, normalization):
    """When eliminating a block fails (its Hessian block numerically singular: a stiff two-mass FMU sampled at the
    automatic window's 0.2 s, found on 2026-11-26, where `fit` stopped with a LinAlgError traceback from the
    Mr >= I path), the solve keeps every cone, and the result is Clarabel's optimum of the full SDP."""
    from fmu_opinf import _sdp_paths

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("3-th leading minor of the array is not positive definite")

    monkeypatch.setattr(_sdp_paths, "_reduced_quadratic", singular)
    data = _active_data(rng)
    fit = fit_operators(*data, refine=False, normalization=normalization)
    assert fit.info["cones"] == ["Mr", "Dr", "Kr"] and fit.info["status"] == "optimal"
    monkeypatch.undo()
    reference = fit_operators(*data, refine=False, method="sdp", normalization=fit.info["normalization"],
                              solver="clarabel", tol=1e-10)
    assert fit.info["sdp_objective"] == pytest.approx(reference.info["sdp_objective"], rel=1e-6)


def test_a_numerically_singular_mass_has_no_explicit_residual_and_no_library_warning():
    """The undamped audit model's trace fit had rcond(Mr) = 4.8e-19: LAPACK's 'ill-conditioned matrix' warning
    reached the user as a bare line; the residual of an explicit form that does not exist is inf."""
    import warnings

    from fmu_opinf._sdp_paths import _acceleration_residual

    r, m = 2, 1
    R = np.triu(np.arange(1.0, 50.0).reshape(7, 7)) + 10 * np.eye(7)
    singular = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-18]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _acceleration_residual(R, m, (singular, np.eye(r), np.eye(r))) == np.inf
        assert np.isfinite(_acceleration_residual(R, m, (np.eye(r), np.eye(r), np.eye(r))))


def test_auto_normalization_keeps_the_one_that_solved_when_the_other_fails(rng, monkeypatch):
    """An undamped free-free chain's free response (audit 2026-11-27): the ``Mr >= I`` solve failed (not certified,
    then Clarabel failed) and the fit ended although the trace solve had its optimum.  Now ``auto`` keeps the
    normalization that solved, says which failed and why, and raises only when both fail."""
    from fmu_opinf import _sdp_paths
    from fmu_opinf.errors import SolverError

    R, r, m, G = _scaled_problem(_damping_data(rng))
    solve = _sdp_paths.fit_compressed
    reference = solve(R, r, m, "auto", 1e-9, False, "trace", "auto")

    def failing(*args):
        if args[6] in failed:
            raise SolverError(f"clarabel failed on {args[6]}")
        return solve(*args)

    monkeypatch.setattr(_sdp_paths, "fit_compressed", failing)
    failed = ("mass-eigenvalue",)
    *mats, info = solve(R, r, m, "auto", 1e-9, False, "auto", "auto")
    assert info["normalization"] == "trace"
    assert info["normalization_failed"] == {"mass-eigenvalue": "clarabel failed on mass-eigenvalue"}
    for got, want in zip(mats, reference[:3]):
        np.testing.assert_array_equal(got, want)
    failed = ("mass-eigenvalue", "trace")
    with pytest.raises(SolverError, match="failed on trace"):
        solve(R, r, m, "auto", 1e-9, False, "auto", "auto")


def _free_response_gram(damping: float) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Gram matrix ``G`` of exact free-response data ``[q''; q'; q]`` of a 3-mass chain with ``D = damping K`` (no
    input; from the matrix exponential), and its true ``(M, D, K)`` scaled to ``trace(M) = 3``: the objective
    ``trace(T G T^T)`` is zero there, so that point is the SDP's optimum, known without any solver."""
    import scipy.linalg

    M, K = np.diag([1.0, 2.0, 1.5]), np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    D, minv = damping * K, np.linalg.inv(M)
    step = scipy.linalg.expm(0.1 * np.block([[np.zeros((3, 3)), np.eye(3)], [-minv @ K, -minv @ D]]))
    z = [np.array([0.3, -0.2, 0.5, 0.0, 0.1, -0.4])]
    for _ in range(399):
        z.append(step @ z[-1])
    x, v = np.array(z).T[:3], np.array(z).T[3:]
    data = np.vstack([-minv @ (D @ v + K @ x), v, x])
    scale = 3.0 / np.trace(M)
    return data @ data.T / x.shape[1], (scale * M, scale * D, scale * K)


def test_the_clip_at_a_cone_apex_is_kept_only_where_it_is_the_optimum():
    """The screening's clip of a dropped block indefinite within 1e-6 (``_sdp_paths._certified_clip``): an undamped
    model's ``Dr`` at +-1e-15 (round-off of exact data) is clipped to PSD (its true ``Dr = 0`` is the optimum);
    the same point on a damped model's data, where the optimum has ``D = 0.05 K``, is refused although it is as
    close to PSD, and a block 1e-3 below zero is refused on the undamped data too (the cone is added instead)."""
    from fmu_opinf._sdp_paths import _certified_clip

    wobble = 1e-15 * np.array([[1.0, 0.3, 0.0], [0.3, -1.0, 0.2], [0.0, 0.2, 0.5]])
    G, (M, D, K) = _free_response_gram(0.0)
    clipped = _certified_clip((M, D + wobble, K), [1], {"G": G}, "trace", 3.0)
    assert clipped is not None and np.linalg.eigvalsh(clipped[1])[0] > -1e-28   # PSD to round-off
    assert np.abs(clipped[1]).max() < 2e-15 and clipped[0] is M and clipped[2] is K
    assert _certified_clip((M, D - 1e-3 * np.eye(3), K), [1], {"G": G}, "trace", 3.0) is None
    G_damped, (_, D_true, _) = _free_response_gram(0.05)
    assert np.linalg.eigvalsh(D_true)[0] > 1e-3                     # the optimum is far from the apex
    assert _certified_clip((M, wobble, K), [1], {"G": G_damped}, "trace", 3.0) is None


def _soft_stiffness_data(rng, r=6, k=300, noise=0.3, softest=1e-3):
    """Rank-one damping and a stiffness with one soft mode (eigenvalue ``softest``): least squares makes the damping
    clearly and the stiffness barely indefinite."""
    M = spd(rng, r, 1.0)
    Q, _ = np.linalg.qr(rng.standard_normal((r, r)))
    K = (Q * np.r_[softest, np.linspace(0.5, 2.0, r - 1)]) @ Q.T
    w, B = rng.standard_normal((r, 1)), rng.standard_normal((r, 1))
    x, v, u = rng.standard_normal((r, k)), rng.standard_normal((r, k)), rng.standard_normal((1, k))
    a = np.linalg.solve(M, B @ u - w @ (w.T @ v) - K @ x) + noise * rng.standard_normal((r, k))
    return a, v, x, u


@pytest.mark.parametrize("seed, softest, cones", [(7, 1e-3, ["Dr"]), (15, 1e-2, ["Dr", "Kr"])])
def test_the_far_more_indefinite_blocks_cone_is_tried_alone_first_with_the_full_sdp_optimum(monkeypatch, seed,
                                                                                           softest, cones):
    """Trace normalization, least squares with Dr (ratio of eigenvalues -2.7e-2 / -1.6e-2) far more indefinite than
    Kr (-7e-4 / -1.2e-3): the first interior-point round keeps the Dr cone alone.  Its relaxation's Kr is PSD in
    the first case (one cone), indefinite in the second (a round with both cones follows); either way the certified
    optimum of the full SDP (Clarabel at 1e-10 on the matrix form)."""
    data = _soft_stiffness_data(np.random.default_rng(seed), softest=softest)
    rounds, original = [], _sdp.solve_ipm

    def spy(*args, **kwargs):
        rounds.append(len(args[2]))
        return original(*args, **kwargs)

    monkeypatch.setattr(_sdp, "solve_ipm", spy)
    fit = fit_operators(*data, normalization="trace", refine=False)
    assert rounds[0] == 1 and fit.info["cones"] == cones
    assert fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6
    _, r, _, G = _scaled_problem(data)
    assert fit.info["sdp_objective"] == pytest.approx(_clarabel_reference(G, r, "trace"), rel=1e-7)


def test_the_trace_rounds_start_from_least_squares_with_fewer_iterations_and_the_same_optimum(rng, monkeypatch):
    """The trace normalization's screened round (the Dr cone) takes 8 iterations from the screening's least-squares
    solution made interior against 12 from identity blocks with Z = I; the same certified optimum, Clarabel's."""
    data = _damping_data(rng)
    fits, rounds = _with_and_without_start(monkeypatch, "_trace_start", data, "trace")
    assert [result.iterations for result in rounds] == [8, 12]
    assert all(fit.info["cones"] == ["Dr"] for fit in fits)
    assert all(fit.info["status"] == "optimal" and fit.info["gap"] <= 1e-6 for fit in fits)
    assert fits[0].info["sdp_objective"] == pytest.approx(fits[1].info["sdp_objective"], rel=1e-9)
    _, r, _, G = _scaled_problem(data)
    assert fits[0].info["sdp_objective"] == pytest.approx(_clarabel_reference(G, r, "trace"), rel=1e-7)
