"""The reduced second-order model: identifiability, paper benchmarks (eq. 19), files, bad input."""

import h5py
import numpy as np
import pytest
import scipy.sparse as sp

from fmu_opinf import newmark, systems
from fmu_opinf.basis import cumulative_energy, energy_order
from fmu_opinf.compare import output_error
from fmu_opinf.errors import DataError, DimensionError, FileFormatError
from fmu_opinf.fit import fit_rom, fit_rom_file
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import Run, Snapshots

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


@pytest.fixture()
def rng():
    """A fresh generator per test, so results do not depend on which tests ran before."""
    return np.random.default_rng(20251121)


def _random_system(rng, n=6):
    def spd(shift):
        a = rng.standard_normal((n, n))
        return sp.csr_matrix(a @ a.T / n + shift * np.eye(n))

    return systems.SecondOrderSystem(
        M=spd(1.0), D=spd(0.05), K=spd(1.0), G=sp.csr_matrix((0, n)), constraint=None,
        B=sp.csr_matrix(rng.standard_normal((n, 2))), Cp=sp.csr_matrix(rng.standard_normal((3, n))),
        Cv=sp.csr_matrix(rng.standard_normal((3, n))), name="random-spd",
    )


def _intrusive(system, V, dt, t_end, signal):
    """POD-Galerkin ROM from the true matrices (eq. 12) with the same basis (test reference only)."""
    rom = SecondOrderROM(*(V.T @ (A @ V) for A in (system.M, system.D, system.K)), V.T @ system.B.toarray(),
                         np.asarray(system.Cp @ V), np.asarray(system.Cv @ V))
    return rom.simulate(signal, dt, t_end).y


def _paper_case(system, dt, t_train, r, t_test, lowpass=None):
    """Fit on the impulse run; max eps_y (eq. 19) of OpInf and intrusive ROMs on the harmonic test input."""
    train = newmark.simulate(system, TRAIN, dt, t_train)
    attrs = {"constraint": system.constraint}
    rom = fit_rom(Snapshots([Run(train.t, train.u, train.x, train.xdot, train.xddot, train.y)], attrs), r=r,
                  lowpass=lowpass)
    ref = newmark.simulate(system, TEST, dt, t_test).y
    eps = output_error(ref, rom.simulate(TEST, dt, t_test).y).max()
    eps_intrusive = output_error(ref, _intrusive(system, rom.basis, dt, t_test, TEST)).max()
    eps_train = output_error(train.y, rom.simulate(TRAIN, dt, t_train).y).max()
    print(f"\n{system.name}: r={r}, lowpass={lowpass}: max eps_y test OpInf {eps:.3e}, intrusive "
          f"{eps_intrusive:.3e}, ratio {eps / eps_intrusive:.3g}; training input {eps_train:.3e}; "
          f"fit {rom.fit_info['method']} {rom.fit_info['total_seconds']:.2f}s")
    return rom, eps, eps_intrusive, eps_train


# --------------------------------------------------------------------------------------------------------
# Identifiability and the paper's benchmarks
# --------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["auto", "sdp"])
def test_known_system_is_identified(rng, method):
    system = _random_system(rng)
    # one spec per input, so that the two columns of B are excited independently
    train = newmark.simulate(system, "chirp:amplitude=1,omega0=0.05,omega1=3,duration=60;"
                             "impulse:amplitude=5,t0=1,width=0.5", 0.05, 60.0)
    rom = fit_rom([train], r=6, method=method)
    ref = newmark.simulate(system, "harmonic:amplitude=2,omega=0.7;step:amplitude=1,t0=3", 0.05, 40.0).y
    y = rom.simulate("harmonic:amplitude=2,omega=0.7;step:amplitude=1,t0=3", 0.05, 40.0).y
    assert np.abs(y - ref).max() < 1e-6 * np.abs(ref).max()
    assert rom.is_stable()


@pytest.fixture(scope="module")
def anchored_case():
    # periods 20-44 s: dt = 0.1 resolves the 0.5 s pulse and the slowest decay (40 s) fades by t = 400 s
    return _paper_case(systems.anchored_msd(600), 0.1, 400.0, 5, 400.0)


@pytest.fixture(scope="module")
def triple_case():
    # frequencies up to 6.3 rad/s: dt = 0.05 gives 20 samples per shortest period; 6001 snapshots
    return _paper_case(systems.triple_chain(), 0.05, 300.0, 35, 400.0)


@pytest.fixture(scope="module")
def triple_case_lowpass():
    # same data; the SDP residual weighted below 1 rad/s (5x the test frequency), see fit_rom(lowpass=...)
    return _paper_case(systems.triple_chain(), 0.05, 300.0, 35, 400.0, lowpass=1.0)


def test_anchored_chain_reproduces_the_paper(anchored_case):
    rom, eps, eps_intrusive, eps_train = anchored_case
    assert eps < 1e-4
    assert eps_train < 1e-4
    assert eps_intrusive < 1e-4
    assert rom.basis_kind == "positions"
    assert np.abs(systems.anchored_msd(600).G @ rom.basis).max() < 1e-12


@pytest.mark.slow
def test_energy_criterion_on_the_benchmarks(anchored_case, triple_case):
    """Eq. 18 on the reference data: what the documented thresholds give next to the paper's r = 5 and 35."""
    anchored, triple = anchored_case[0].singular_values, triple_case[0].singular_values
    assert cumulative_energy(anchored)[4] == pytest.approx(0.980, abs=5e-4)
    assert cumulative_energy(triple)[34] == pytest.approx(0.950, abs=5e-4)
    assert [energy_order(anchored, e) for e in (0.95, 0.98, 0.99)] == [4, 6, 6]
    assert [energy_order(triple, e) for e in (0.95, 0.98, 0.99)] == [36, 55, 67]


@pytest.mark.slow
def test_triple_chain_reaches_the_paper_bound(triple_case):
    rom, eps, eps_intrusive, eps_train = triple_case
    assert eps < 1e-4
    assert eps_train < 1e-4
    # the trace normalization collapses on these data (module docstring of inference), so auto switched
    assert rom.fit_info["normalization"] == "mass-eigenvalue"
    assert rom.fit_info["trace_mass_ratio"] < 1e-3


@pytest.mark.slow
def test_trace_normalization_alone_collapses_on_the_triple_chain(triple_case):
    """Why the default switches: with only trace(Mr) fixed the fit concentrates the mass in a few directions
    (a near-singular Mr) and the ROM misses the bound; this pins that diagnosis."""
    rom = triple_case[0]
    train = newmark.simulate(systems.triple_chain(), TRAIN, 0.05, 300.0)
    attrs = {"constraint": "velocity"}
    trace_rom = fit_rom(Snapshots([Run(train.t, train.u, train.x, train.xdot, train.xddot, train.y)], attrs), r=35,
                        normalization="trace", refine=False)  # the SDP alone: the refinement would rescue it
    eigs = np.linalg.eigvalsh(trace_rom.Mr)
    assert eigs[0] / eigs[-1] < 1e-3
    ref = newmark.simulate(systems.triple_chain(), TEST, 0.05, 400.0).y
    assert output_error(ref, trace_rom.simulate(TEST, 0.05, 400.0).y).max() > 1e-4
    good = np.linalg.eigvalsh(rom.Mr)
    assert good[0] / good[-1] > 1e-2


@pytest.mark.slow
def test_triple_chain_with_frequency_weighted_fit_reaches_the_bound(triple_case_lowpass):
    _, eps, _, eps_train = triple_case_lowpass
    assert eps < 1e-4
    assert eps_train < 1e-4


@pytest.mark.parametrize("case", ["triple_case", "triple_case_lowpass"])
@pytest.mark.slow
def test_triple_chain_rom_is_stable_spd_and_constraint_consistent(case, request):
    rom = request.getfixturevalue(case)[0]
    assert rom.basis_kind == "velocities"
    assert np.abs(systems.triple_chain().G @ rom.basis).max() < 1e-12
    for mat in (rom.Mr, rom.Dr, rom.Kr):
        eigs = np.linalg.eigvalsh(mat)
        assert np.array_equal(mat, mat.T) and eigs[0] >= -1e-10 * eigs[-1]
    assert rom.is_stable()


# --------------------------------------------------------------------------------------------------------
# The model object
# --------------------------------------------------------------------------------------------------------
@pytest.fixture()
def small_rom(rng):
    system = _random_system(rng, n=4)
    train = newmark.simulate(system, "chirp:amplitude=1,omega0=0.1,omega1=2,duration=30;step:amplitude=1,t0=5",
                             0.1, 30.0)
    return fit_rom([train], r=3)


def test_simulation_shapes_and_timing(small_rom):
    out = small_rom.simulate("step:amplitude=1,t0=0.5", 0.1, 2.0)
    assert out.t.shape == (21,) and out.u.shape == (2, 21) and out.y.shape == (3, 21)
    assert out.q.shape == out.qdot.shape == out.qddot.shape == (3, 21)
    np.testing.assert_allclose(out.y, small_rom.Cpr @ out.q + small_rom.Cvr @ out.qdot)
    lhs = small_rom.Mr @ out.qddot + small_rom.Dr @ out.qdot + small_rom.Kr @ out.q
    np.testing.assert_allclose(lhs, small_rom.Br @ out.u, atol=1e-10)  # column i of u pairs with state i
    assert small_rom.reconstruct(out.q).shape == (4, 21)


def test_eigenvalues_of_a_single_oscillator():
    rom = SecondOrderROM([[2.0]], [[0.4]], [[8.0]], [[1.0]], [[1.0]], [[0.0]])
    lam = np.sort_complex(rom.eigenvalues())
    np.testing.assert_allclose(lam, np.sort_complex(np.roots([2.0, 0.4, 8.0])))
    assert rom.is_stable()
    assert not SecondOrderROM([[1.0]], [[-0.1]], [[1.0]], [[1.0]], [[1.0]], [[0.0]]).is_stable()


def test_save_load_round_trip(tmp_path, small_rom):
    path = small_rom.save(tmp_path / "rom.h5")
    back = SecondOrderROM.load(path)
    for name in ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr", "basis", "singular_values"):
        np.testing.assert_array_equal(getattr(back, name), getattr(small_rom, name))
    assert back.input_names == ["u[1]", "u[2]"] and back.output_names == small_rom.output_names
    assert back.dt == pytest.approx(0.1) and back.basis_kind == "positions"
    assert back.fit_info["status"] == "optimal" and "fit_date" in back.provenance
    with pytest.raises(FileExistsError, match="exists"):
        small_rom.save(path)
    small_rom.save(path, overwrite=True)


def test_missing_truncated_and_foreign_rom_files(tmp_path, small_rom):
    with pytest.raises(FileFormatError, match="does not exist"):
        SecondOrderROM.load(tmp_path / "nope.h5")
    path = small_rom.save(tmp_path / "rom.h5")
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match="not HDF5 or is truncated"):
        SecondOrderROM.load(tmp_path / "cut.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["x"] = 1.0
    with pytest.raises(FileFormatError, match="is not an fmu-opinf ROM file"):
        SecondOrderROM.load(tmp_path / "other.h5")


def test_wrong_version_missing_matrix_and_nan(tmp_path, small_rom):
    path = small_rom.save(tmp_path / "rom.h5")
    with h5py.File(path, "a") as f:
        f.attrs["layout_version"] = 99
    with pytest.raises(FileFormatError, match="layout version 99; this tool reads versions 1, 2"):
        SecondOrderROM.load(path)
    path = small_rom.save(tmp_path / "rom.h5", overwrite=True)
    with h5py.File(path, "a") as f:
        del f["Kr"]
    with pytest.raises(FileFormatError, match="lacks Kr"):
        SecondOrderROM.load(path)
    path = small_rom.save(tmp_path / "rom.h5", overwrite=True)
    with h5py.File(path, "a") as f:
        f["Dr"][0, 0] = np.nan
    with pytest.raises(DataError, match="Dr contains NaN/Inf"):
        SecondOrderROM.load(path)


def test_asymmetric_operator_in_a_file_is_refused_like_export_refuses_it(tmp_path, small_rom):
    """Audit 62, finding 5: a ROM file whose Kr bytes were flipped was compared (exit 0) but not exported."""
    from fmu_opinf.export import export_fmu

    path = small_rom.save(tmp_path / "rom.h5")
    with h5py.File(path, "a") as f:
        f["Kr"][0, 1] = f["Kr"][0, 1] * (1 + 1e-7) + 1e-7 * np.abs(f["Kr"][()]).max()
    expected = f"{path}: ROM matrix Kr is not symmetric .*re-fit the ROM"
    with pytest.raises(DataError, match=expected):
        SecondOrderROM.load(path)
    with pytest.raises(DataError, match=expected):
        export_fmu(path, tmp_path / "rom.fmu")
    assert not (tmp_path / "rom.fmu").exists()


@pytest.mark.parametrize("name, change, problem", [
    ("Mr", lambda a: a - 2 * np.abs(a).max() * np.eye(len(a)), "Mr is not positive definite"),
    ("Dr", lambda a: a - 2 * max(np.abs(a).max(), 1.0) * np.eye(len(a)), "Dr has a negative eigenvalue"),
])
def test_indefinite_operator_in_a_file_is_refused(tmp_path, small_rom, name, change, problem):
    path = small_rom.save(tmp_path / "rom.h5")
    with h5py.File(path, "a") as f:
        f[name][...] = change(f[name][()])
    with pytest.raises(DataError, match=f"{path}: ROM matrix {problem}.*re-fit the ROM"):
        SecondOrderROM.load(path)


def _round_off(rng, eigenvalues) -> np.ndarray:
    """A symmetric 2 x 2 matrix with ``eigenvalues`` in a random orthonormal basis."""
    q = np.linalg.qr(rng.standard_normal((2, 2)))[0]
    return q @ np.diag(eigenvalues) @ q.T


@pytest.mark.parametrize("name", ["Dr", "Kr"])
def test_an_operator_that_is_round_off_may_dip_below_zero_by_round_off(tmp_path, rng, name):
    """Audit 63, finding 9: an undamped ROM whose Dr is round-off (largest eigenvalue 1e-16, smallest -7.7e-17
    beside a Kr of 900) was refused as damaged: the semidefinite test was relative to Dr alone.  Its floor is now
    1e-12 of the scale the other operators give it, sqrt(|Mr| |Kr|) for Dr (here 30), |Dr|^2 / |Mr| for Kr (a
    free body with a damping of 3: 9), so such a ROM saves, loads and exports; an eigenvalue of -1e-9 (over 1e-11
    of that scale) is still refused."""
    from fmu_opinf.export import export_fmu

    noise = _round_off(rng, [1e-16, -7.7e-17])
    operators = {"Mr": np.eye(2), "Dr": noise, "Kr": np.diag([100.0, 900.0])} if name == "Dr" else \
        {"Mr": np.eye(2), "Dr": np.diag([1.0, 3.0]), "Kr": noise}
    rom = SecondOrderROM(operators["Mr"], operators["Dr"], operators["Kr"], np.eye(2), np.eye(2), np.zeros((2, 2)),
                         dt=0.01)
    path = rom.save(tmp_path / "rom.h5")
    loaded = SecondOrderROM.load(path)
    np.testing.assert_array_equal(getattr(loaded, name), noise)
    assert export_fmu(path, tmp_path / "rom.fmu").stat().st_size > 0
    with h5py.File(path, "a") as f:
        f[name][...] = _round_off(rng, [1e-16, -1e-9])
    with pytest.raises(DataError, match=f"{path}: ROM matrix {name} has a negative eigenvalue -1e-09.*re-fit"):
        SecondOrderROM.load(path)


def test_inconsistent_matrices_are_rejected():
    with pytest.raises(DimensionError, match="Cvr has shape"):
        SecondOrderROM(np.eye(2), np.eye(2), np.eye(2), np.ones((2, 1)), np.ones((1, 2)), np.ones((1, 3)))


# --------------------------------------------------------------------------------------------------------
# The pipeline on snapshot files
# --------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def snapshot_file(tmp_path_factory):
    system = systems.anchored_msd(40)
    run = newmark.simulate(system, TRAIN, 0.5, 200.0)
    path = tmp_path_factory.mktemp("snaps") / "train.h5"
    Snapshots([Run(run.t, run.u, run.x, run.xdot, run.xddot, run.y, {"dt": 0.5})],
              {"constraint": "position", "input_names": ["F"], "output_names": ["a", "b", "c"]}).save(path)
    return path, run


def test_fit_rom_file_streams_lazy_data(tmp_path, snapshot_file):
    path, run = snapshot_file
    # the SDP alone: the path under test is the streamed POD (the refinement's L-BFGS would amplify round-off)
    rom = fit_rom_file(path, tmp_path / "rom.h5", r=4, figures=tmp_path / "figs", streamed=True, chunk_size=37,
                       refine=False)
    dense = fit_rom([run], r=4, refine=False)
    assert rom.fit_info["pod_method"] == "streamed-correlation"
    assert np.max(np.abs(np.abs(rom.basis.T @ dense.basis) - np.eye(4))) < 1e-10
    np.testing.assert_allclose(rom.simulate(TEST, 0.5, 50.0).y, dense.simulate(TEST, 0.5, 50.0).y,
                               atol=1e-8 * np.abs(dense.simulate(TEST, 0.5, 50.0).y).max())
    assert rom.input_names == ["F"] and rom.output_names == ["a", "b", "c"]
    assert SecondOrderROM.load(tmp_path / "rom.h5").r == 4
    assert (tmp_path / "figs" / "singular_values.png").stat().st_size > 0
    assert (tmp_path / "figs" / "cumulative_energy.png").stat().st_size > 0


def test_bad_snapshot_files(tmp_path, snapshot_file):
    path, run = snapshot_file
    with pytest.raises(FileFormatError):
        fit_rom_file(tmp_path / "missing.h5", tmp_path / "rom.h5", r=2)
    data = path.read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) // 3])
    with pytest.raises(FileFormatError):
        fit_rom_file(tmp_path / "cut.h5", tmp_path / "rom.h5", r=2)
    with h5py.File(tmp_path / "foreign.h5", "w") as f:
        f["x"] = np.zeros((3, 3))
    with pytest.raises(FileFormatError):
        fit_rom_file(tmp_path / "foreign.h5", tmp_path / "rom.h5", r=2)
    (tmp_path / "future.h5").write_bytes(data)
    with h5py.File(tmp_path / "future.h5", "a") as f:
        f.attrs["layout_version"] = 99
    with pytest.raises(FileFormatError, match="layout 99"):
        fit_rom_file(tmp_path / "future.h5", tmp_path / "rom.h5", r=2)
    (tmp_path / "partial.h5").write_bytes(data)
    with h5py.File(tmp_path / "partial.h5", "a") as f:
        del f["runs/0000/xddot"]
    with pytest.raises(FileFormatError, match="lacks xddot"):
        fit_rom_file(tmp_path / "partial.h5", tmp_path / "rom.h5", r=2)
    assert not (tmp_path / "rom.h5").exists()


def test_bad_snapshot_data(snapshot_file):
    _, run = snapshot_file
    x = run.x.copy()
    x[5, 10] = np.nan
    bad = Run(run.t, run.u, x, run.xdot, run.xddot, run.y)
    with pytest.raises(DataError, match="snapshot array x of run 0 has NaN/Inf at column 10"):
        fit_rom([bad], r=2)
    y = run.y.copy()
    y[0, 3] = np.inf
    with pytest.raises(DataError, match="y of run 0 has NaN/Inf"):
        fit_rom([Run(run.t, run.u, run.x, run.xdot, run.xddot, y)], r=2)
    with pytest.raises(DataError, match="run 0 is incomplete"):
        fit_rom([Run(run.t, run.u, run.x, run.xdot, run.xddot, run.y, {"complete": False})], r=2)
    # the one sample that a recording failing at its first step keeps: incomplete, not "all snapshots are zero"
    first = Run(run.t[:1], run.u[:, :1], 0 * run.x[:, :1], 0 * run.xdot[:, :1], 0 * run.xddot[:, :1],
                run.y[:, :1], {"complete": False})
    with pytest.raises(DataError, match="run 0 is incomplete: the recording stopped early, after 1 sample;"):
        fit_rom([first])
    with pytest.raises(DimensionError, match="u of run 0 has shape"):
        fit_rom([Run(run.t, run.u[:, :-1], run.x, run.xdot, run.xddot, run.y)], r=2)


def test_r_above_rank_is_a_one_line_error(snapshot_file):
    _, run = snapshot_file
    rank = int(np.linalg.matrix_rank(run.x))
    with pytest.raises(DataError, match=rf"^r=60 exceeds the snapshot rank {rank}; choose r <= {rank}$"):
        fit_rom([run], r=60)


def test_a_start_outside_the_truncated_basis_names_the_order_as_a_cause():
    """Audit 2026-11-27: the source's start was the training start, only partly in the span of an r = 5 basis of a
    20-mass chain, and the message blamed the constraint or data never trained on; it now names the order too."""
    V = np.array([[1.0], [0.0]])  # r = 1 of n = 2
    rom = SecondOrderROM(np.eye(1), np.eye(1), np.eye(1), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)),
                         basis=V)
    assert rom.initial_state(np.array([2.0, 0.0]))[0][0] == 2.0
    with pytest.raises(DataError, match=r"relative part outside 4.5e-01.*need more than the ROM's r=1 basis vectors.*"
                                        r"fit with a larger r \(--r or r=, --energy or energy=\)"):
        rom.initial_state(np.array([2.0, 1.0]))


def test_a_learned_mode_above_the_training_nyquist_frequency_is_warned():
    """Fifth audit: a learned mode at 8.3e3 rad/s from data at dt = 0.01 (pi/dt = 314 rad/s) rang in an acceleration
    output, 3 % off, without a word.  Two masses with modes at 1.0 and 50 rad/s, the faster one oscillating at
    48.4 rad/s (the reference: the system's own eigenvalues, which Newmark data at full order reproduce): at dt = 0.1 (pi/dt = 31 rad/s) the fit warns with
    the mode and a step that resolves it, at dt = 0.05 (63 rad/s) it says nothing."""
    import warnings

    import scipy.sparse as sp

    from fmu_opinf import newmark, systems
    from fmu_opinf.errors import FmuOpinfWarning

    M, K = np.diag([1.0, 0.01]), np.diag([1.0, 25.0])  # modes 1 and 50 rad/s
    system = systems.SecondOrderSystem(
        sp.csr_matrix(M), sp.csr_matrix(0.01 * K), sp.csr_matrix(K), sp.csr_matrix((0, 2)), None,
        sp.csr_matrix([[1.0], [0.001]]), sp.csr_matrix([[1.0, 1.0]]), sp.csr_matrix((1, 2)), name="two")
    omega = np.sqrt(np.linalg.eigvals(np.linalg.solve(M, K)).real).max()
    zeta = 0.01 * omega / 2  # D = 0.01 K: modal damping ratio 0.01 omega / 2
    assert omega == pytest.approx(50.0) and omega * np.sqrt(1 - zeta**2) == pytest.approx(48.41, abs=0.005)
    train = "impulse:amplitude=1,t0=1,width=0.5"
    coarse = newmark.simulate(system, train, 0.1, 60.0)
    with pytest.warns(FmuOpinfWarning, match=r"mode at 48\.4 rad/s, above the 31\.4 rad/s \(pi/dt\).*--dt 0\.05 or "
                                             r"dt=0\.05 \(or a smaller step\) and --t-end 60 or t_end=60\.0 "):
        fit_rom([coarse], r=2, quiet=True, refine=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        fit_rom([newmark.simulate(system, train, 0.05, 60.0)], r=2, quiet=True, refine=False)


def test_an_order_below_the_number_of_inputs_is_warned_about():
    """Seventh audit: 20 inputs on 20 masses, r = 5 chosen from the energy at E_r = 0.959 (snapshot rank 20), one
    output 11 % off, while --r 20 was exact.  The warning names the order to try; none where the snapshots hold no
    more (rank = r) or r covers the inputs."""
    import warnings

    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.fit._training_checks import _warn_if_order_below_inputs

    with pytest.warns(FmuOpinfWarning, match=r"r=5 \(from the cumulative energy\) is below the 20 inputs, and the "
                                             r"snapshots have rank 20: .* fit with --r 20"):
        _warn_if_order_below_inputs(5, 20, 20)
    with pytest.warns(FmuOpinfWarning, match="fit with --r 8"):
        _warn_if_order_below_inputs(5, 8, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_if_order_below_inputs(5, 5, 20)
        _warn_if_order_below_inputs(20, 40, 20)


@pytest.mark.slow  # 13 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_fit_with_many_outputs_holds_them_about_once(monkeypatch):
    """Memory proportional to the outputs (seventh audit: 200 outputs, 266 MB recorded, the fit peaked at 2.34 GB):
    the traced peak of a fit with 400 outputs stays near the size of its stacked outputs, with column blocks of
    1 MB (5.2x before 2026-11-28: copies of ``y^T`` in each least-squares solve, full-size residuals and weighted
    targets).  The output map of eq. 17 fitted to ``W x`` is ``W`` times the one fitted to ``x``."""
    import tracemalloc
    import warnings

    from fmu_opinf import basis

    monkeypatch.setattr(basis, "BLOCK_BYTES", 1_000_000)
    system = systems.anchored_msd(g=10)
    W = np.random.default_rng(0).standard_normal((400, system.M.shape[0]))
    trajectories = [newmark.simulate(system, spec, 0.1, 300.0)
                    for spec in ("impulse:amplitude=100,t0=2,width=0.5", "harmonic:amplitude=1,omega=0.3")]
    attrs = {"constraint": system.constraint}
    wide = Snapshots([Run(tr.t, tr.u, tr.x, tr.xdot, tr.xddot, W @ tr.x) for tr in trajectories], attrs)
    size = sum(run.y.nbytes for run in wide.runs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tracemalloc.start()
        try:
            rom = fit_rom(wide, r=4, quiet=True)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        narrow = fit_rom(Snapshots([Run(tr.t, tr.u, tr.x, tr.xdot, tr.xddot, tr.x) for tr in trajectories], attrs),
                         r=4, refine=False, quiet=True)
    assert peak < 1.6 * size, peak / size  # measured 1.30
    unrefined = fit_rom(wide, r=4, refine=False, quiet=True)
    for mine, theirs in ((unrefined.Cpr, narrow.Cpr), (unrefined.Cvr, narrow.Cvr)):
        np.testing.assert_allclose(mine, W @ theirs, rtol=0, atol=1e-10 * np.abs(W @ theirs).max())
    assert rom.fit_info["refinement"]["iterations"] > 0


@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_the_same_rom_with_one_and_two_blas_threads():
    """The whole fit (projection, POD, SDP, refinement) gives the same bits with one and two BLAS threads (issue 16):
    the projection's products run with one thread each on fixed column blocks (with two OpenBLAS threads the
    reduced data differed in their last bits, and the demo's triple chain ended its refinement 1 % apart)."""
    from threadpoolctl import threadpool_limits

    system = systems.triple_chain()
    train = newmark.simulate(system, "impulse:amplitude=100,t0=2,width=0.5", 0.05, 300.0)
    snapshots = Snapshots([Run(train.t, train.u, train.x, train.xdot, train.xddot, train.y)],
                          {"constraint": system.constraint})
    roms = []
    for threads in (1, 2):
        with threadpool_limits(limits=threads):
            roms.append(fit_rom(snapshots, r=8, refine_iterations=30, quiet=True))
    assert roms[0].fit_info["refinement"]["iterations"] == 30
    for name in ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr"):
        assert np.array_equal(getattr(roms[0], name), getattr(roms[1], name)), name


def test_the_same_rom_from_a_recording_in_memory_and_from_its_file():
    """A recording held in memory (column-major arrays) and the same values read from its file (row-major) fit to the
    same bits: BLAS rounds the two layouts differently, and the refinement, which is not convex, carried the last-bit
    difference to 3e-3 in ``Mr`` at its iteration limit (the quick demo's anchored chain, 2026-12-05)."""
    system = systems.anchored_msd()   # 600 masses: smaller matrices took the same BLAS path in both layouts
    train = newmark.simulate(system, "impulse:amplitude=100,t0=2,width=0.5", 0.5, 95.5)
    roms = []
    for layout in (np.asfortranarray, np.ascontiguousarray):
        run = Run(train.t, train.u, *(layout(a) for a in (train.x, train.xdot, train.xddot, train.y)))
        roms.append(fit_rom(Snapshots([run], {"constraint": system.constraint}), r=4, refine_iterations=60,
                            quiet=True))
    for name in ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr"):
        assert np.array_equal(getattr(roms[0], name), getattr(roms[1], name)), name


@pytest.mark.slow
def test_a_rom_that_misses_its_own_training_outputs_is_warned_about():
    """Eighth audit: a velocity recorded among the positions (a Simulink-style FMU whose outputs were all passed as
    --positions) fitted to a training output error of 9.0e-3 without a word, and the ROM was 12.7 % off.  Here two
    masses whose outputs are both positions, recorded with the second mass' velocity in place of its position: the
    fit warns; with the true positions it does not (the same data otherwise)."""
    import warnings

    import scipy.sparse as sp

    from fmu_opinf.errors import FmuOpinfWarning

    M, K = np.diag([1.0, 2.0]), np.array([[30.0, -10.0], [-10.0, 10.0]])
    system = systems.SecondOrderSystem(
        sp.csr_matrix(M), sp.csr_matrix(0.05 * K + 0.1 * M), sp.csr_matrix(K), sp.csr_matrix((0, 2)), None,
        sp.csr_matrix([[0.0], [1.0]]), sp.csr_matrix(np.eye(2)), sp.csr_matrix((2, 2)), name="two")
    train = newmark.simulate(system, "impulse:amplitude=1,t0=1,width=0.5", 0.05, 60.0)
    mixed = train.x.copy()
    mixed[1] = train.xdot[1]
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        good = fit_rom([Run(train.t, train.u, train.x, train.xdot, train.xddot, train.y)], r=2, quiet=True)
    assert good.fit_info["refinement"]["objective"] < 1e-10
    with pytest.warns(FmuOpinfWarning, match=r"reproduces its own training outputs only to .*--positions or "
                                             r"positions= names"):
        fit_rom([Run(train.t, train.u, mixed, train.xdot, train.xddot, train.y)], r=2, quiet=True)
    # a force that switches on by itself at t = 30 s (a co-simulation FMU's internal time event: audit of
    # 2026-12-05, where the hint named only the positions, the order and the outputs)
    import dataclasses

    timed = dataclasses.replace(system, B=sp.csr_matrix([[0.0, 1.0], [1.0, 0.0]]))   # the timer's force on mass 1
    switched = newmark.simulate(timed, "impulse:amplitude=1,t0=1,width=0.5;step:amplitude=0.5,t0=30", 0.05, 60.0)
    assert np.array_equal(switched.u[:1], train.u)   # the FMU's input as recorded; the timer is not among them
    with pytest.warns(FmuOpinfWarning, match=r"reproduces its own training outputs only to .*changes only with its "
                                             r"inputs \(an internal event, a force on a timer"):
        fit_rom([Run(train.t, train.u, switched.x, switched.xdot, switched.xddot, switched.y)], r=2, quiet=True)


def _fixed_free_bar(n: int):
    """A fixed-free bar of ``n`` lumped nodes (length 1, wave speed 100: first mode 157 rad/s, the others at odd
    multiples of it), light Rayleigh damping, a force at the free end; outputs: the positions of the tip and of
    the middle node."""
    from fmu_opinf import lti_fmus

    k, m = 1e4 * n, 1.0 / n
    K = np.diag(np.full(n, 2 * k)) - np.diag(np.full(n - 1, k), 1) - np.diag(np.full(n - 1, k), -1)
    K[-1, -1] = k
    M = np.diag(np.full(n, m))
    M[-1, -1] = m / 2
    B, Cp = np.zeros((n, 1)), np.zeros((2, n))
    B[-1, 0] = Cp[0, -1] = Cp[1, n // 2] = 1.0
    return lti_fmus.LinearMechanicalModel(M, 0.5 * M + 2e-5 * K, K, B, Cp=Cp, name="bar")


@pytest.mark.slow
def test_an_order_from_the_energy_that_misses_the_training_outputs_is_grown():
    """Audit 62: on an FE-like model the energy (eq. 18) keeps too few modes for the outputs of a training pulse
    that excites the dynamics (a 300-node fixed-free bar: r = 2, 5 % RMS off its own training outputs; fit
    warned and suggested --r).  Here a 40-node bar and a 10 ms pulse: the default fit grows the order until the
    ROM reproduces its training outputs and says so; an explicit r stays as given (and warns).  Reference: the
    exact zero-order-hold response (matrix exponential) to a harmonic test input the fit never saw."""
    import re
    import warnings

    from fmu_opinf import lti_fmus
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.fit import TRAINING_MISS
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    model, dt, t_end = _fixed_free_bar(40), 2e-4, 0.2
    t = time_grid(dt, t_end)

    def exact(spec):
        u = inputs_in_effect(parse_signal(spec, 1), t, 1)   # u[:, i + 1] is held over [t_i, t_i+1]
        return u, lti_fmus.zoh_response(model, t, u[:, 1:])

    u, train = exact("impulse:amplitude=100,t0=0.01,width=0.01")
    run = Run(t, u, train.x, train.v, train.a, train.y)
    test_input = "harmonic:amplitude=50,omega=200"
    reference = exact(test_input)[1].y
    fits, missed, said = {}, {}, []
    for name, order in (("default", None), ("energy order", 2), ("generous", 8)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fits[name] = fit_rom([run], r=order, integrator="exact", log=said.append if order is None else None)
        missed[name] = any("reproduces its own training outputs only" in str(w.message) for w in caught
                           if issubclass(w.category, FmuOpinfWarning))
    errors = {name: float(np.sqrt(np.mean((rom.simulate(test_input, dt, t_end).y - reference) ** 2)
                                  / np.mean(reference ** 2))) for name, rom in fits.items()}
    # measured 1.4e-4 against 4.2e-2 at the energy's order (r = 4, which reproduces its training outputs to 0.44 %
    # RMS, was 1.5e-3 off: the search goes on past an order whose miss still falls steeply, CONVERGED, audit base82)
    assert fits["default"].r == 8 and fits["energy order"].r == 2, fits
    assert errors["default"] < 0.06 * errors["energy order"], errors
    assert errors["default"] <= errors["generous"] < 3e-4, errors
    assert not missed["default"] and missed["energy order"], missed
    search = fits["default"].fit_info["order_search"]
    assert search[0]["r"] == 2 and search[0]["training_output_error"] > TRAINING_MISS, search   # measured 2.7e-3
    assert search[-1]["r"] == fits["default"].r and search[-1]["training_output_error"] <= TRAINING_MISS, search
    assert "order_search" not in fits["energy order"].fit_info
    assert fits["default"].provenance["fit_settings"]["order_search_limit"] >= 8
    line = (r"order search: r=2 from eq\. \(18\) misses its training outputs \(0\.05\d* relative RMS on y\[1\]\); "
            r"r=4: 0\.00\d* on y\[1\], r=8: 0\.000\d* on y\[1\], kept$")
    assert any(re.match(line, said_line) for said_line in said), [s for s in said if "order search" in s]


def test_the_order_search_doubles_up_to_its_limit_and_keeps_the_closest_where_none_reproduces():
    """The orders tried (doubling, capped at the snapshot rank and ORDER_SEARCH_LIMIT, the cap tried last, while
    each lowers the training output error ORDER_HELPS-fold); where no order reproduces the training outputs, the
    closest is kept where the order helped, else the energy's, said in the stage line, and the warning names the
    orders tried.  Fits stand in for :func:`fit_rom`'s (only their order and training output error count)."""
    from types import SimpleNamespace

    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.fit._order_search import ORDER_SEARCH_LIMIT, _grow_order, _search_orders
    from fmu_opinf.fit._training_checks import _warn_if_training_outputs_missed

    assert _search_orders(2, 28) == [4, 8, 16, 28] and _search_orders(36, 151) == [ORDER_SEARCH_LIMIT] == [60]
    assert _search_orders(5, 5) == [] and _search_orders(61, 151) == []
    objectives = {2: 5e-2, 4: 4e-3, 8: 2e-3, 16: 3e-3}

    def fit(order):
        return SimpleNamespace(pod=SimpleNamespace(r_=order, rank_=16, svdvals_=None),   # (no noise floor)
                               info={"refinement": {"objective": objectives[order]}, "total_seconds": 0.1})

    said = []
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 8 and [entry["r"] for entry in search] == [2, 4, 8, 16], search   # 8 -> 16: worse
    assert said == [("order search: r=2 from eq. (18) misses its training outputs (0.22 relative RMS); r=4: 0.063, "
                     "r=8: 0.045, r=16: 0.055; none reproduces them within 0.032: kept r=8, the closest")], said
    with pytest.warns(FmuOpinfWarning, match=r"order suffices \(r=8, the closest of r=2, 4, 8, 16 tried; --r or r=\)"):
        _warn_if_training_outputs_missed(kept.info, 8, tried=[2, 4, 8, 16])
    objectives[4] = 3.5e-2   # doubling lowers the error 1.4-fold only: not the order's miss, no larger fits
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 2 and [entry["r"] for entry in search] == [2, 4], search
    assert said[-1].endswith("kept r=2, larger orders lowered the error less than 2-fold (squared)"), said
    said.pop()
    objectives[4] = 5e-6   # the first order that reproduces them ends the search (below CONVERGED)
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 4 and len(search) == 2 and said[-1].endswith("r=4: 0.0022, kept"), said
    # above CONVERGED, after a fall of STILL_FALLING-fold or more, the next order is tried (audit base82, F3) and
    # kept where it lowers the miss ORDER_HELPS-fold again; the first that reproduced them where it does not
    objectives[4] = 1e-4
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 4 and len(search) == 3 and said[-1].endswith("r=4: 0.01, kept, r=8: 0.045"), said
    objectives[8] = 6e-5   # reproduces them too, but gains less than ORDER_HELPS-fold: the smaller order is kept
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 4 and len(search) == 3 and said[-1].endswith("r=4: 0.01, kept, r=8: 0.0077"), said
    objectives[8] = 2e-8   # below CONVERGED: kept, and the search ends there (16 is not tried)
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 8 and len(search) == 3 and said[-1].endswith("r=4: 0.01, r=8: 0.00014, kept"), said
    objectives[4], objectives[8] = 3e-4, 1e-4   # fell 3-fold to r = 8: kept (ORDER_HELPS), not STILL_FALLING: 16
    kept, search = _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)   # is not tried
    assert kept.pod.r_ == 8 and [entry["r"] for entry in search] == [2, 4, 8], said
    said.clear()
    objectives[2] = 1e-4   # none where the energy's order reproduces them
    assert _grow_order(fit(2), fit, judge_unrefined=True, say=said.append)[1] == [] and said == []


def _bar_with_a_tip_accelerometer(n: int):
    """The tests' chain of ``n`` unequal masses (:func:`fmu_opinf.lti_fmus.chain_model`, forces at node ``n // 3``
    and at the tip), its mass scaled so that the first mode lies at 157 rad/s, with 2 % Rayleigh damping at that
    mode; outputs: the displacements of nodes ``n // 4``, ``n // 2`` and of the tip, and the tip's acceleration (a
    feedthrough of the tip force, and an output 1e4-1e5 times larger than the displacements)."""
    from dataclasses import replace

    from fmu_opinf import lti_fmus

    chain = lti_fmus.chain_model(n, inputs=(n // 3, n - 1))
    lowest = np.sqrt(np.linalg.eigvals(np.linalg.solve(chain.M, chain.K)).real.min())
    mass = chain.M * (lowest / 157.0) ** 2
    Cp, Ca = np.zeros((4, n)), np.zeros((4, n))
    Cp[[0, 1, 2], [n // 4, n // 2, n - 1]] = 1.0
    Ca[3, n - 1] = 1.0
    beta = 0.04 / (6 * 157.0)   # D = beta (alpha M + K), alpha = 5 * 157^2: damping ratio 2 % at 157 rad/s
    damping = beta * (5 * 157.0 ** 2 * mass + chain.K)
    return replace(chain, M=mass, D=damping, Cp=Cp, Cv=np.zeros((4, n)), Ca=Ca, y0=np.zeros(4))


@pytest.mark.slow
def test_the_order_search_judges_each_output_by_its_own_size():
    """Audit 65, F2: beside a tip acceleration (RMS 4e7), the displacements (RMS 1e2-1e3) counted in the training
    output error only as much as an output of 1e-3 of the acceleration's size, so the default fit kept the energy's
    r = 3 at 0.8 % RMS on average while one displacement was 5.3 % off its training runs and 6.6 % of its range
    off an unseen input.  The search now judges the worst output, each relative to its own size, and grows the order.
    Reference: the exact zero-order-hold response of the full model to an input the fit never saw."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.fit import TRAINING_MISS
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    model, dt, t_end = _bar_with_a_tip_accelerometer(16), 1e-3, 1.005
    t = time_grid(dt, t_end)

    def exact(spec):
        u = inputs_in_effect(parse_signal(spec, 2), t, 2)   # u[:, i + 1] is held over [t_i, t_i+1]
        return u, lti_fmus.zoh_response(model, t, u[:, 1:])

    pulse = "impulse:amplitude=100,t0=0.128,width=0.032"   # the default training of each input, as `snapshots` made
    runs = [Run(t, u, y.x, y.v, y.a, y.y) for u, y in map(exact, (f"{pulse};none", f"none;{pulse}"))]
    test_input = "harmonic:amplitude=17.8,omega=210;harmonic:amplitude=17.8,omega=235"
    reference = exact(test_input)[1].y
    fits = {"default": fit_rom(runs, integrator="exact")}
    with pytest.warns(FmuOpinfWarning, match=r"outputs only to 0\.05\d* relative RMS \(output y\[1\] of run 1; "
                                             r"training output error 6\.\de-05\)"):   # the mean: 0.8 % RMS
        fits["energy"] = fit_rom(runs, r=3, integrator="exact")
    errors = {name: np.abs(rom.simulate(test_input, dt, t_end).y - reference).max(axis=1) / np.ptp(reference, axis=1)
              for name, rom in fits.items()}
    assert fits["energy"].fit_info["energy_r"] >= 0.95   # r = 3 is the energy's order (E_3 = 0.9985)
    # measured r = 6: displacements 0.0032 / 0.0015 / 0.0012 of their range against 0.066 / 0.015 / 0.024 at r = 3
    assert fits["default"].r > 3 and np.max(errors["default"][:3]) < 0.005 < 0.05 < errors["energy"][0], errors
    first = fits["default"].fit_info["order_search"][0]   # the mean passed; the worst output (y[1], 5.3 %) did not
    assert first["r"] == 3 and first["training_output_error"] < TRAINING_MISS < first["worst_output_error"], first


def test_a_gross_training_miss_keeps_the_order_search_going_while_any_order_lowers_it():
    """Above GROSS_MISS a doubling that lowers the training output error less than ORDER_HELPS-fold, or raises it,
    does not end the search; where no order helped ORDER_HELPS-fold the energy's is kept.  Fits stand in for
    :func:`fit_rom`'s (only their order and training output error count)."""
    from types import SimpleNamespace

    from fmu_opinf.fit import GROSS_MISS, ORDER_HELPS
    from fmu_opinf.fit._order_search import _grow_order

    objectives = {4: 0.97, 8: 0.91, 16: 0.05, 30: 1e-20}   # audit 69's chain: 4 -> 8 lowers it 1.07-fold only
    assert objectives[8] * ORDER_HELPS > objectives[4] and objectives[8] > GROSS_MISS

    def fit(order):
        return SimpleNamespace(pod=SimpleNamespace(r_=order, rank_=30, svdvals_=None),
                               info={"refinement": {"objective": objectives[order]}, "total_seconds": 0.1})

    said = []
    kept, search = _grow_order(fit(4), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 30 and [entry["r"] for entry in search] == [4, 8, 16, 30], search
    objectives.update({8: 3.1, 16: 3.5})   # audit 69's chain judged with its free response: up, then exact
    kept, search = _grow_order(fit(4), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 30 and [entry["r"] for entry in search] == [4, 8, 16, 30], search
    objectives.update({8: 0.05, 16: 0.06})   # below GROSS_MISS and no lower: the search ends there
    kept, search = _grow_order(fit(4), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 8 and [entry["r"] for entry in search] == [4, 8, 16], search
    objectives.update({8: 0.9, 16: 0.8, 30: 0.7})   # lowered each time, never ORDER_HELPS-fold: the energy's kept
    kept, search = _grow_order(fit(4), fit, judge_unrefined=True, say=said.append)
    assert kept.pod.r_ == 4 and [entry["r"] for entry in search] == [4, 8, 16, 30], search


def test_the_order_search_refines_in_full_only_what_it_keeps_or_relies_on():
    """Issue 16: the orders the search tries are fitted with a screen that ends their refinement where they still
    miss grossly (SCREEN_CHECKPOINTS); such an order is taken not to pass, and the search refits it in full before it
    relies on its figure: where the next order's miss is not gross (ORDER_HELPS decides) and where no order
    reproduces the outputs (the closest is kept).  Where a larger order reproduces them, the screened ones are never
    refitted.  The decisions are those of full fits throughout.  Fits stand in for :func:`fit_rom`'s (their order,
    training output error and refinement status count)."""
    from types import SimpleNamespace

    from fmu_opinf.fit import GROSS_MISS, SCREEN_CHECKPOINTS
    from fmu_opinf.fit._order_search import _grow_order

    full = {4: 0.97, 8: 0.91, 16: 0.5, 30: 1e-20}       # audit 69's chain, judged after a full refinement
    screened = {4: 2.0, 8: 1.5}                         # the same orders ended by the screen
    assert min(screened.values()) > max(limit for _, limit in SCREEN_CHECKPOINTS) > GROSS_MISS
    refitted = []

    def stand_in(order, figure, status):
        return SimpleNamespace(pod=SimpleNamespace(r_=order, rank_=30, svdvals_=None),
                               info={"refinement": {"objective": figure, "status": status, "iterations": 40},
                                     "total_seconds": 0.1})

    def fit_at(order):
        if order in screened:
            return stand_in(order, screened[order], "screened out")
        return stand_in(order, full[order], "iteration limit")

    def refit(order):
        refitted.append(order)
        return stand_in(order, full[order], "iteration limit")

    said = []
    kept, search = _grow_order(fit_at(4), fit_at, judge_unrefined=True, say=said.append, refit=refit)
    assert kept.pod.r_ == 30 and [entry["r"] for entry in search] == [4, 8, 16, 30] and refitted == [], search
    assert [entry.get("screened", False) for entry in search] == [True, True, False, False], search
    assert said[-1] == ("order search: r=4 from eq. (18) misses its training outputs (1.4 relative RMS after 40 "
                        "refinement iterations); r=8: 1.2 after 40 refinement iterations, r=16: 0.71, r=30: 1e-10, "
                        "kept"), said
    full.update({8: 0.11, 16: 0.06})   # 16 misses less than GROSS_MISS, by no ORDER_HELPS-fold gain: the end
    kept, search = _grow_order(fit_at(4), fit_at, judge_unrefined=True, say=said.append, refit=refit)
    assert [entry["r"] for entry in search] == [4, 8, 16] and kept.pod.r_ == 16, search   # (8's screened 1.5: on)
    assert refitted == [8, 4] and [entry["judged"] for entry in search] == [0.97, 0.11, 0.06], (refitted, search)
    refitted.clear()
    screened[8], full[16] = 50.0, 4e-3   # 50 after 40 iterations: at least 0.05 in full, 2x 16's miss: no refit
    kept, search = _grow_order(fit_at(4), fit_at, judge_unrefined=True, say=said.append, refit=refit)
    assert kept.pod.r_ == 30 and [entry["r"] for entry in search] == [4, 8, 16, 30] and refitted == [], search
    lone = stand_in(4, 2.0, "screened out")
    lone.pod.rank_ = 4   # no larger order to try
    kept, search = _grow_order(lone, fit_at, judge_unrefined=True, say=said.append, refit=refit)
    assert refitted == [4] and search == [] and kept.info["refinement"]["status"] == "iteration limit"


def _chain_off_rest(n: int, force_offset: float, dt: float, t_end: float):
    """A chain of ``n`` masses (:func:`fmu_opinf.lti_fmus.chain_model`) started off rest, forces on the first, the
    middle and the last mass, acceleration sensors on the last and on ``n // 3``, an output offset of 0.1, and a
    constant force ``force_offset`` on every mass; returns its exact zero-order-hold response to an input
    specification, ``exact(spec) -> (u, response)``, and the runs of the default training (one 100 N pulse per
    input)."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    s = np.arange(n) / (n - 1)
    model = lti_fmus.chain_model(n, inputs=(0, n // 2, n - 1), force_offset=force_offset,
                                 x0=0.05 * np.sin(np.pi * s) + 0.02 * np.sin(3 * np.pi * s),
                                 v0=0.1 * np.sin(2 * np.pi * s), acceleration_outputs=(n - 1, n // 3),
                                 output_offset=0.1)
    t = time_grid(dt, t_end)

    def exact(spec):
        u = inputs_in_effect(parse_signal(spec, 3), t, 3)   # u[:, i + 1] is held over [t_i, t_i+1]
        return u, lti_fmus.zoh_response(model, t, u[:, 1:])

    pulse = "impulse:amplitude=100,t0=2,width=0.5"
    specs = [";".join(pulse if j == i else "none" for j in range(3)) for i in range(3)]
    return exact, [Run(t, u, y.x, y.v, y.a, y.y) for u, y in map(exact, specs)]


@pytest.mark.slow
def test_a_chain_under_a_constant_load_started_off_equilibrium_gets_the_order_it_needs():
    """Audit 69, F1: a 30-mass chain under a constant force on every mass, started neither at rest nor at its
    equilibrium, with three force inputs and two acceleration sensors.  The sag to the equilibrium takes most of
    the snapshot energy; the energy's r = 4 missed the training outputs by 0.99 relative RMS and r = 8 by 0.96,
    which ended the order search, and the ROM was 11-61 % of each output's range off an unseen input.  Reference:
    the exact zero-order-hold response of the full model."""
    from fmu_opinf.fit import GROSS_MISS

    n, dt, t_end = 30, 0.05, 100.0
    exact, runs = _chain_off_rest(n, 0.5, dt, t_end)
    rom = fit_rom(runs, integrator="exact")
    search = rom.fit_info["order_search"]
    assert search[0]["r"] == 4 and search[1]["judged"] > GROSS_MISS, search   # the plateau that ended it
    # issue 16: the orders it discards were refined only until they still missed grossly, the kept one in full
    assert [entry.get("screened", False) for entry in search] == [True] * (len(search) - 1) + [False], search
    assert rom.fit_info["refinement"]["status"] != "screened out" and search[-1]["r"] == rom.r, rom.fit_info
    test_input = "harmonic:amplitude=3,omega=1.3;none;harmonic:amplitude=2,omega=0.7"
    reference = exact(test_input)[1].y
    error = np.abs(rom.simulate(test_input, dt, t_end).y - reference).max(axis=1) / np.ptp(reference, axis=1)
    # measured 2.1e-10 on the machine of 2026-12-06, 0.92e-9 .. 1.002e-9 on that of 2026-12-07 (same code; r = 4:
    # 0.11 .. 0.61): the refinement ends at its iteration limit on the round-off floor (objective 5.8e-20 -> 6.4e-21),
    # where the last digits follow the machine's rounding
    assert rom.r == n and error.max() < 2.5e-9, (rom.r, error)


def test_free_response_errors_measure_each_run_until_its_inputs_change():
    """The free-response errors of :func:`fmu_opinf.refinement.output_errors` against a by-hand figure: a model with a
    10 % stiffer spring, simulated by the exact zero-order-hold response (:func:`fmu_opinf.lti_fmus.zoh_response`,
    not the refinement's step), over the samples before the first run's pulse, relative to the recorded outputs'
    variation about their mean. A run whose inputs change at once has no free response; a start at rest has none to
    judge."""
    from dataclasses import replace

    from fmu_opinf import lti_fmus
    from fmu_opinf.refinement import FREE_RESPONSE_SAMPLES, output_errors
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    n, dt = 6, 0.05
    model = lti_fmus.chain_model(n, inputs=(n - 1,), x0=0.1 * np.sin(np.arange(n)), v0=0.2 * np.cos(np.arange(n)))
    stiffer = replace(model, K=1.1 * model.K)
    t = time_grid(dt, 6.0)
    pulse_u = inputs_in_effect(parse_signal("impulse:amplitude=5,t0=1,width=0.5", 1), t, 1)
    changing_u = inputs_in_effect(parse_signal("harmonic:amplitude=1,omega=3", 1), t, 1)
    runs = [(u, lti_fmus.zoh_response(model, t, u[:, 1:])) for u in (pulse_u, changing_u)]
    free = int(np.flatnonzero(pulse_u[0] != pulse_u[0, 0])[0])   # samples before the pulse acts on the outputs
    assert free >= FREE_RESPONSE_SAMPLES > np.flatnonzero(changing_u[0] != changing_u[0, 0])[0]
    recorded = runs[0][1].y[:, :free]
    wrong = lti_fmus.zoh_response(stiffer, t[:free], pulse_u[:, 1:free]).y
    motion = recorded - recorded.mean(axis=1, keepdims=True)
    expected = np.sum((wrong - recorded) ** 2, axis=1) / np.sum(motion ** 2, axis=1)

    def errors(runs, K):
        u = np.hstack([u for u, _ in runs])
        x, v, y = (np.hstack([getattr(run, name) for _, run in runs]) for name in ("x", "v", "y"))
        return output_errors(model.M, model.D, K, model.B, v, x, u, y, dt, output_map=(model.Cp, model.Cv),
                             run_lengths=[t.size] * len(runs), integrator="exact").free_response

    assert expected.min() > 1e-3   # the stiffer spring is visible in the free response
    np.testing.assert_allclose(errors(runs, stiffer.K), expected, rtol=1e-8)
    np.testing.assert_allclose(errors(runs, model.K), 0.0, atol=1e-20)
    at_rest = replace(model, x0=np.zeros(n), v0=np.zeros(n))
    resting = [(u, lti_fmus.zoh_response(at_rest, t, u[:, 1:])) for u in (pulse_u, changing_u)]
    assert np.all(np.isnan(errors(resting, stiffer.K)))


def _two_input_chain_with_a_stiff_mount(n: int) -> tuple[object, float, np.ndarray, tuple[str, str], list[Run]]:
    """``lti_fmus.chain_model(n)`` with forces at the base and at the tip and the wall spring 10x stiffer (audit
    72's twostiff10 at 12 masses): the base force hardly moves the tip (tip position RMS 0.021 against 2.5 from the
    tip force), and each run's exact zero-order-hold response to a 100 N pulse on one input."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    chain = lti_fmus.chain_model(n, inputs=(0, n - 1))
    K = chain.K.copy()
    K[0, 0] *= 10.0
    model = lti_fmus.LinearMechanicalModel(chain.M, 0.05 * chain.M + 0.01 * K, K, chain.B, Cp=chain.Cp, Cv=chain.Cv)
    dt, t = 0.05, time_grid(0.05, 60.0)
    pulse = "impulse:amplitude=100,t0=2,width=0.5"
    specs = (f"{pulse};none", f"none;{pulse}")
    inputs = [inputs_in_effect(parse_signal(spec, 2), t, 2) for spec in specs]   # u[:, i + 1] held over [t_i, t_i+1]
    responses = [lti_fmus.zoh_response(model, t, u[:, 1:]) for u in inputs]
    return model, dt, t, specs, [Run(t, u, y.x, y.v, y.a, y.y) for u, y in zip(inputs, responses)]


def test_output_errors_judge_each_run_against_its_own_variation():
    """Audit 72, F1: :func:`fmu_opinf.refinement.output_errors` over whole runs against a by-hand figure: a model
    with a 10 % stiffer spring, simulated by the exact zero-order-hold response (not the refinement's step), each
    run's squared output error relative to that run's variation about its mean, the worst run counting (the old
    figure, pooled over the runs relative to the outputs' size, was half of it for the tip position).  The exact
    model has none."""
    from dataclasses import replace

    from fmu_opinf import lti_fmus
    from fmu_opinf.refinement import output_errors

    model, dt, t, _, runs = _two_input_chain_with_a_stiff_mount(12)
    stiffer = replace(model, K=1.1 * model.K)
    figures = []
    for run in runs:
        wrong = lti_fmus.zoh_response(stiffer, t, run.u[:, 1:]).y
        motion = run.y - run.y.mean(axis=1, keepdims=True)
        figures.append(np.sum((wrong - run.y) ** 2, axis=1) / np.sum(motion ** 2, axis=1))
    figures = np.array(figures)
    u, x, v, y = (np.hstack([getattr(run, name) for run in runs]) for name in ("u", "x", "xdot", "y"))
    found = output_errors(model.M, model.D, stiffer.K, model.B, v, x, u, y, dt, output_map=(model.Cp, model.Cv),
                          run_lengths=[t.size] * 2, integrator="exact")
    np.testing.assert_allclose(found.whole, figures.max(axis=0), rtol=1e-8)
    np.testing.assert_array_equal(found.whole_run, np.argmax(figures, axis=0))
    pooled = np.sum([f * np.sum(r.y ** 2, axis=1) for f, r in zip(figures, runs)], axis=0) / np.sum(y ** 2, axis=1)
    assert found.whole[0] > 1.5 * pooled[0], (found.whole, pooled)   # measured 0.75 against 0.38 pooled
    exact = output_errors(model.M, model.D, model.K, model.B, v, x, u, y, dt, output_map=(model.Cp, model.Cv),
                          run_lengths=[t.size] * 2, integrator="exact")
    np.testing.assert_allclose(exact.whole, 0.0, atol=1e-24)


def test_the_order_search_judges_each_training_run_on_its_own():
    """Audit 72, F1: with one pulse run per input of a chain whose base force hardly moves the tip, the order
    search judged the outputs pooled over the runs and kept r = 8, whose tip position was 84 % RMS (1.7 of its
    range) off the exact model in the base-force run.  Judged run by run, against each run's own variation, the
    search goes on to the order that reproduces both runs, and its line names the output and run that missed.
    Reference: the exact zero-order-hold response of the full model to each training input."""
    import re

    n = 12
    _, dt, t, specs, runs = _two_input_chain_with_a_stiff_mount(n)
    said = []
    rom = fit_rom(runs, integrator="exact", log=said.append)
    for spec, run in zip(specs, runs):
        error = np.abs(rom.simulate(spec, dt, t[-1]).y - run.y).max(axis=1) / np.ptp(run.y, axis=1)
        assert error.max() < 1e-11, (spec, rom.r, error)   # measured 2e-14 .. 1.7e-13 at r = 12 (before: r = 8, 1.7)
    assert rom.r == n, rom.r
    line = r"order search: r=4 from eq\. \(18\) misses its training outputs \([\d.]+ relative RMS on y\[1\] of run 0"
    assert any(re.match(line, said_line) for said_line in said), [s for s in said if "order search" in s]


@pytest.mark.slow
def test_a_chain_started_off_rest_reproduces_its_free_response():
    """Audit 69, F2: a 20-mass chain started off rest (no load), three force inputs and two acceleration sensors.
    Pooled over whole runs the 100 N training pulses dwarf the motion from the start values: the order search kept
    r = 18 at a training error of 7e-4, and the ROM run with no input was 6.7 % of an acceleration's range off the
    source.  Judging each run's free response on its own grows the order to the snapshots' rank.  Reference: the
    exact zero-order-hold response of the full model."""
    from fmu_opinf.fit import TRAINING_MISS

    n, dt, t_end = 20, 0.05, 60.0
    exact, runs = _chain_off_rest(n, 0.0, dt, t_end)
    rom = fit_rom(runs, integrator="exact")
    eighteen = next(entry for entry in rom.fit_info["order_search"] if entry["r"] == 18)   # kept before
    assert eighteen["training_output_error"] < TRAINING_MISS < eighteen["judged"], eighteen
    reference = exact("none;none;none")[1].y
    error = np.abs(rom.simulate("none;none;none", dt, t_end).y - reference).max(axis=1) / np.ptp(reference, axis=1)
    assert rom.r == n and error.max() < 3e-13, (rom.r, error)   # measured 3.2e-14 (before: r = 18, 0.067)


def test_the_order_search_tries_no_order_beyond_a_noise_floor_of_the_singular_values():
    """Audit 65, F3: with 5 % noise on the positions of a 40-node bar, eq. (18) kept r = 33 of the rank 40 (noise
    fills the energy), the ROM missed its noisy training outputs, and the search's one trial, at r = 40, the
    costliest and worst-conditioned fit, made the fit 47 s instead of 15 s to be 272 relative RMS off.  The
    singular values of white noise on 40 x 1001 snapshots lie within (sqrt(1001) + sqrt(40)) / (sqrt(1001) -
    sqrt(40)) = 1.5 of each other (Marchenko-Pastur): the search now stops where the modes beyond lie on that floor,
    and says so.  The singular values are those of the exact response (matrix exponential) with and without the
    noise; the fits stand in for :func:`fit_rom`'s (only their order and training output error count)."""
    from types import SimpleNamespace

    from fmu_opinf import lti_fmus
    from fmu_opinf.basis import cumulative_energy
    from fmu_opinf.fit._order_search import _grow_order
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    model, t = _fixed_free_bar(40), time_grid(2e-4, 0.2)
    u = inputs_in_effect(parse_signal("impulse:amplitude=100,t0=0.01,width=0.01", 1), t, 1)
    x = lti_fmus.zoh_response(model, t, u[:, 1:]).x
    noisy = x + 0.05 * np.abs(x).max() * np.random.default_rng(0).standard_normal(x.shape)
    # (clean: r = 16 reproduces them after a 4-fold fall, STILL_FALLING, so r = 32 is tried too, and misses)
    for positions, energy_r, tried, kept_r in ((noisy, 33, [33], 33), (x, 2, [2, 4, 8, 16, 32], 16)):
        sigma = np.linalg.svd(positions, compute_uv=False)
        r = int(np.argmax(cumulative_energy(sigma) >= 0.95)) + 1
        assert r == energy_r and np.count_nonzero(sigma > 1e-13 * sigma[0]) >= 28, sigma   # the audit's orders

        def fit(order, rank=np.count_nonzero(sigma > 1e-13 * sigma[0]), sigma=sigma):
            error = {2: 4e-2, 4: 1e-2, 8: 4e-3, 16: 1e-3, 33: 1.2e-2}.get(order, 3.0)   # r = 40: 272^2 / 2.5e4
            return SimpleNamespace(pod=SimpleNamespace(r_=order, rank_=rank, svdvals_=sigma),
                                   info={"refinement": {"objective": error}, "total_seconds": 0.1, "n": 40,
                                         "k": positions.shape[1]})

        said: list[str] = []
        kept, search = _grow_order(fit(r), fit, judge_unrefined=True, say=said.append)
        assert [entry["r"] for entry in search] == tried and kept.pod.r_ == kept_r, search
        if positions is noisy:   # s_4 on lie within 1.54 of the smallest: about 3 modes carry the motion
            assert search[0]["noise_floor"] == 4, search
            assert said[-1].endswith("kept r=33; the singular values from s_4 on lie on a noise floor, so no order "
                                     "above r=33 was tried (it would fit the noise); with noisy snapshots a smaller "
                                     "order, about --r 3 or r=3, may follow other inputs better"), said
        else:   # clean: 1e14 from s_3 to the rank; the search goes on as before
            assert all("noise_floor" not in entry for entry in search) and "noise" not in said[-1], said


def test_a_fit_of_states_that_are_no_positions_and_velocities_warns_without_an_output_check():
    """States of a state space in other coordinates (``z = T^-1 [x; v]``) recorded as positions ``z1..z3`` and
    velocities ``z4..z6``.  Where no refinement can run (interval averages) no training output error was
    simulated, and the fit said nothing (ninth audit, finding 2: compare 128 % off); now the SDP solution's
    training output error is simulated and judged like the refinement's (:data:`TRAINING_MISS`).  The true
    positions and velocities of the same motion fit exactly and say nothing.  Reference: the exact response."""
    import warnings

    from fmu_opinf import lti_fmus
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.fit import TRAINING_MISS

    model = lti_fmus.chain_model(3)
    t = np.arange(0.0, 40.0, 0.05)
    held = np.where((t > 1.0) & (t < 2.0), 1.0, 0.0)[None, :]   # over [t_i, t_i+1]
    exact = lti_fmus.zoh_response(model, t, held)
    u = np.hstack([held[:, :1], held[:, :-1]])   # a run's u[:, i + 1] is held over [t_i, t_i+1]
    transform = np.random.default_rng(3).standard_normal((6, 6)) + 3.0 * np.eye(6)
    z, dz = (np.linalg.solve(transform, np.vstack(pair)) for pair in ((exact.x, exact.v), (exact.v, exact.a)))
    errors = {}
    averages = {"fit_rates": "interval-averages"}   # rates from the data, as for a CS FMU without accelerations
    for name, run, refine in (("wrong", Run(t, u, z[:3], z[3:], dz[3:], exact.y), False),
                              ("wrong averages", Run(t, u, z[:3], z[3:], dz[3:], exact.y, averages), "auto"),
                              ("right", Run(t, u, exact.x, exact.v, exact.a, exact.y), False),
                              ("right averages", Run(t, u, exact.x, exact.v, exact.a, exact.y, averages), "auto")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rom = fit_rom([run], r=3, refine=refine, integrator="exact", quiet=True)
        said = [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)
                and "reproduces its own training outputs only" in str(w.message)]
        errors[name] = (rom.fit_info["training_output_error"], len(said))
    assert errors["wrong"][0] > 100 * TRAINING_MISS and errors["wrong"][1] == 1, errors   # measured 1.43, and
    # refine=False asks for the SDP solution as it is, but a gross miss (above GROSS_MISS) is said (audit 76 F1)
    assert errors["wrong averages"][0] > 100 * TRAINING_MISS and errors["wrong averages"][1] == 1, errors   # 1.46
    for name in ("right", "right averages"):   # measured 7.9e-29 and 2.1e-28
        assert errors[name][0] < 1e-20 and errors[name][1] == 0, errors


def test_the_fit_functions_are_still_reached_where_they_lived_before_the_fit_module():
    """``fmu_opinf.rom.fit_rom`` and ``fit_rom_file`` (scripts written before :mod:`fmu_opinf.fit`) are the fit
    module's functions, and a misspelt name is still an AttributeError."""
    from fmu_opinf import fit, rom

    assert rom.fit_rom is fit.fit_rom and rom.fit_rom_file is fit.fit_rom_file
    with pytest.raises(AttributeError, match="fit_romm"):
        rom.fit_romm
