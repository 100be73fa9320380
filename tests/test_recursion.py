"""Blocked evaluation of s+ = Phi s + Gamma u (fmu_opinf._recursion) against the step-by-step loop."""

import numpy as np
import pytest
import scipy.linalg

from fmu_opinf._recursion import block_length, linear_recursion, modal_form
from fmu_opinf.fmus import find_build_tools
from fmu_opinf.newmark import step_matrices
from fmu_opinf.rom import SecondOrderROM


@pytest.fixture()
def rng():
    return np.random.default_rng(20261123)


def _loop(phi, s0, gamma, inputs):
    """Reference: one matrix-vector product per step (what SecondOrderROM.simulate did before)."""
    states = np.empty((phi.shape[0], inputs.shape[1] + 1), dtype=np.result_type(phi, s0, gamma, inputs))
    states[:, 0] = s0
    for i in range(inputs.shape[1]):
        states[:, i + 1] = phi @ states[:, i] + gamma @ inputs[:, i]
    return states


def _relative(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def _stable(rng, n, radius=0.98):
    a = rng.standard_normal((n, n))
    return radius * a / np.abs(np.linalg.eigvals(a)).max()


def _spd(rng, r, shift):
    a = rng.standard_normal((r, r))
    return a @ a.T / r + shift * np.eye(r)


def _rom(rng, r=35, integrator="newmark"):
    return SecondOrderROM(_spd(rng, r, 1.0), _spd(rng, r, 0.02), _spd(rng, r, 1.0), rng.standard_normal((r, 1)),
                          rng.standard_normal((3, r)), rng.standard_normal((3, r)), fr=rng.standard_normal(r),
                          q0=rng.standard_normal(r), qdot0=rng.standard_normal(r), integrator=integrator)


@pytest.mark.parametrize("k", [1, 5, 7, 64, 1001])
@pytest.mark.parametrize("block", [None, 1, 4, 9])
def test_matches_loop_any_length_and_block(rng, k, block):
    phi, gamma = _stable(rng, 12), rng.standard_normal((12, 3))
    s0, inputs = rng.standard_normal(12), rng.standard_normal((3, k))
    states = linear_recursion(phi, s0, gamma, inputs, block=block)
    assert states.shape == (12, k + 1)
    assert _relative(states, _loop(phi, s0, gamma, inputs)) < 1e-12


def test_outputs_only_equal_outputs_of_states(rng):
    phi, gamma, C = _stable(rng, 20), rng.standard_normal((20, 2)), rng.standard_normal((3, 20))
    s0, inputs = rng.standard_normal(20), rng.standard_normal((2, 3000))
    y = linear_recursion(phi, s0, gamma, inputs, C=C)
    assert y.shape == (3, 3001)
    assert _relative(y, C @ _loop(phi, s0, gamma, inputs)) < 1e-12


def test_defective_zero_and_unit_eigenvalues(rng):
    """A Jordan block, a nilpotent part and an undamped rotation: no eigendecomposition is needed."""
    n = 9
    blocks = [np.array([[0.9, 1.0], [0.0, 0.9]]), np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]),
              np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]]), np.array([[1.0]]),
              np.array([[-0.5]])]
    T = rng.standard_normal((n, n)) + 3 * np.eye(n)
    phi = T @ scipy.linalg.block_diag(*blocks) @ np.linalg.inv(T)
    gamma, s0, inputs = rng.standard_normal((n, 1)), rng.standard_normal(n), rng.standard_normal((1, 2000))
    exact = _loop(*(np.asarray(a, dtype=np.longdouble) for a in (phi, s0, gamma, inputs)))  # 80-bit reference
    # measured 6.6e-12 (OpenBLAS 0.3.31; below 1e-12 with the BLAS of earlier machines), the plain loop 9.6e-14:
    # the block starts use Phi^L, whose rounding a non-normal Phi (cond(T) = 64) amplifies by about cond(T)^2
    assert _relative(linear_recursion(phi, s0, gamma, inputs), exact) < 1.5e-11


def test_no_inputs_and_no_steps(rng):
    phi, s0 = _stable(rng, 5), rng.standard_normal(5)
    free = linear_recursion(phi, s0, np.zeros((5, 0)), np.zeros((0, 50)))
    assert _relative(free, _loop(phi, s0, np.zeros((5, 0)), np.zeros((0, 50)))) < 1e-12
    assert np.array_equal(linear_recursion(phi, s0, np.zeros((5, 1)), np.zeros((1, 0))), s0[:, None])


def test_block_length_bounds():
    assert block_length(105, 4, 105, 100_000) >= 4
    assert block_length(105, 4, 3, 100_000) > block_length(105, 4, 105, 100_000)  # outputs: longer blocks
    assert block_length(105, 4, 3, 2) == 2


@pytest.mark.parametrize("integrator", ["newmark", "exact"])
def test_rom_simulate_equals_step_map_loop(rng, integrator):
    """SecondOrderROM.simulate at r = 35 equals the step map applied step by step, to 1e-12 per block."""
    rom, dt, k = _rom(rng, integrator=integrator), 0.1, 3000
    trajectory = rom.simulate("harmonic:amplitude=1,omega=0.3", dt, k * dt)
    B = np.hstack([rom.Br, rom.fr[:, None]])
    forced = np.vstack([trajectory.u, np.ones((1, k + 1))])
    if integrator == "exact":
        phi, gamma = rom.step_map(dt)
        drive = forced[:, 1:]
    else:
        phi, gamma_new, gamma_old = step_matrices(rom.Mr, rom.Dr, rom.Kr, B, dt)
        gamma, drive = np.hstack([gamma_new, gamma_old]), np.vstack([forced[:, 1:], forced[:, :-1]])
    s0 = np.concatenate([trajectory.q[:, 0], trajectory.qdot[:, 0], trajectory.qddot[:, 0]])
    reference = _loop(phi, s0, gamma, drive)
    r = rom.r
    for got, part in ((trajectory.q, 0), (trajectory.qdot, 1), (trajectory.qddot, 2)):
        assert _relative(got, reference[part * r:(part + 1) * r]) < 1e-12
    assert np.allclose(trajectory.q[:, 0], rom.q0) and np.allclose(trajectory.qdot[:, 0], rom.qdot0)


# ------------------------------------------------------------------ modal form and the exported FMU

def test_modal_form_refuses_a_defective_map(rng):
    phi = np.array([[0.9, 1.0], [0.0, 0.9]])
    assert modal_form(phi, np.ones((2, 1))) is None


def test_modal_form_reproduces_the_step_maps(rng):
    rom = _rom(rng)
    B = np.hstack([rom.Br, rom.fr[:, None]])
    phi, gamma_new, gamma_old = step_matrices(rom.Mr, rom.Dr, rom.Kr, B, 0.1)
    for phi, gamma in ((phi, gamma_new + gamma_old), rom.step_map(0.1)):
        form = modal_form(phi, gamma)
        assert form is not None and form.size == 2 * rom.r                # the r zero eigenvalues drop out
        assert np.abs(form.shape @ form.step_matrix() @ form.projection - phi).max() < 1e-12 * np.abs(phi).max()


def test_modal_form_pads_an_odd_number_of_real_eigenvalues(rng):
    """A rotation pair, three real eigenvalues (one block padded with a dead coordinate) and a zero eigenvalue."""
    blocks = [np.array([[0.9 * np.cos(0.4), -0.9 * np.sin(0.4)], [0.9 * np.sin(0.4), 0.9 * np.cos(0.4)]]),
              np.diag([0.5, -0.3, 0.7, 0.0])]
    T = rng.standard_normal((6, 6)) + 4 * np.eye(6)
    phi = T @ scipy.linalg.block_diag(*blocks) @ np.linalg.inv(T)
    form = modal_form(phi, rng.standard_normal((6, 2)))
    assert form is not None and form.size == 6
    assert np.abs(form.shape @ form.step_matrix() @ form.projection - phi).max() < 1e-13
    assert np.abs(form.complement @ phi).max() < 1e-13            # the rest lies in the kernel: gone in one step
    expected = np.sort_complex(np.linalg.eigvals(scipy.linalg.block_diag(*blocks)))   # the pad is a zero
    assert np.allclose(np.sort_complex(np.linalg.eigvals(form.step_matrix())), expected, atol=1e-12)


def _initialized_fmu(path):
    """An exported ROM FMU instantiated and initialized through fmpy, with its value references:
    ``(fmu, refs by name, output refs, state refs)``."""
    from fmpy import extract

    from conftest import started_fmu2

    folder = extract(str(path))
    fmu, md = started_fmu2(folder, "modal")
    refs = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    states = [v.valueReference for v in md.modelVariables if v.name.startswith(("q[", "qdot[", "qddot["))]
    return fmu, refs, outputs, states


def _drive(path, u, read_states_at=(), snapshot_at=None):
    """Outputs after each step (input u[:, i] held over step i); states where asked; optionally replay from a
    snapshot taken after step ``snapshot_at``."""
    fmu, refs, outputs, states = _initialized_fmu(path)
    dt, ys, read, snapshot, replay = 0.1, [], {}, None, []
    for i in range(u.shape[1]):
        fmu.setReal([refs["u[1]"]], [float(u[0, i])])
        fmu.doStep(i * dt, dt)
        ys.append(fmu.getReal(outputs))
        if i in read_states_at:
            read[i] = np.array(fmu.getReal(states))
        if i == snapshot_at:
            snapshot = fmu.getFMUstate()
    if snapshot is not None:
        fmu.setFMUstate(snapshot)
        for i in range(snapshot_at + 1, u.shape[1]):
            fmu.setReal([refs["u[1]"]], [float(u[0, i])])
            fmu.doStep(i * dt, dt)
            replay.append(fmu.getReal(outputs))
        fmu.freeFMUstate(snapshot)
    fmu.terminate()
    fmu.freeInstance()
    return np.array(ys).T, read, np.array(replay).T


def _reference_states(rom, u):
    """States after each step: consistent start at rest input, then the step map (for Newmark with the
    acceleration update for each new input first) applied step by step."""
    k = u.shape[1]
    B = np.hstack([rom.Br, rom.fr[:, None]])
    forced = np.vstack([np.concatenate([[0.0], u[0]]), np.ones(k + 1)])
    qddot0 = np.linalg.solve(rom.Mr, B @ forced[:, 0] - rom.Dr @ rom.qdot0 - rom.Kr @ rom.q0)
    s0 = np.concatenate([rom.q0, rom.qdot0, qddot0])
    if rom.integrator == "exact":
        phi, gamma = rom.step_map(0.1)
        drive = forced[:, 1:]
    else:
        phi, gamma_new, gamma_old = step_matrices(rom.Mr, rom.Dr, rom.Kr, B, 0.1)
        gamma, drive = np.hstack([gamma_new, gamma_old]), np.vstack([forced[:, 1:], forced[:, :-1]])
    return _loop(phi, s0, gamma, drive)[:, 1:]


def needs_compiler(test):
    """FMU tests: a C compiler and CMake, and about 12 s to build the two FMUs (slow)."""
    skip = pytest.mark.skipif(find_build_tools() is None, reason="no C compiler or CMake to build FMUs")
    return pytest.mark.fmu(pytest.mark.slow(skip(test)))


@pytest.fixture(scope="module")
def modal_fmus(tmp_path_factory):
    from fmu_opinf.export import export_fmu

    rng = np.random.default_rng(7)
    out = tmp_path_factory.mktemp("modal")
    fmus = {}
    for integrator in ("newmark", "exact"):
        rom = _rom(rng, integrator=integrator)
        rom.Dur, rom.y0, rom.dt = rng.standard_normal((3, 1)), rng.standard_normal(3), 0.1
        fmus[integrator] = rom, export_fmu(rom, out / f"{integrator}.fmu")
    return fmus


@needs_compiler
@pytest.mark.parametrize("integrator", ["newmark", "exact"])
def test_modal_fmu_equals_step_map_loop(modal_fmus, integrator):
    """The exported FMU (modal kernel) against the step map applied step by step, to 1e-12: outputs every step,
    all states where read (rebuilt from the modal state), and a replay from an FMU state snapshot."""
    import zipfile

    rom, path = modal_fmus[integrator]
    assert "MatrixModalSize" in zipfile.ZipFile(path).read("sources/model.c").decode()
    k = 1500
    u = np.sin(0.05 * np.arange(k))[None, :] + 0.3 * np.sign(np.sin(0.011 * np.arange(k)))[None, :]
    y, read, replay = _drive(path, u, read_states_at=(0, 333, 334, 1000), snapshot_at=700)
    states = _reference_states(rom, u)
    r = rom.r
    expected = rom.Cpr @ states[:r] + rom.Cvr @ states[r:2 * r] + rom.Dur @ u + rom.y0[:, None]
    assert _relative(y, expected) < 1e-12
    for i, values in read.items():
        for part in range(3):
            block = slice(part * r, (part + 1) * r)
            assert _relative(values[block], states[block, i]) < 1e-12 * np.abs(states[block]).max() / np.abs(
                states[block, i]).max()
    assert _relative(replay, y[:, 701:]) < 1e-12


@needs_compiler
@pytest.mark.parametrize("integrator", ["newmark", "exact"])
def test_modal_fmu_states_follow_an_input_set_between_steps(modal_fmus, integrator):
    """After steps on the modal path (outputs read, states not), a new input set before the next step shows at
    once in the acceleration (``q'' += Mr^-1 Br du``, as the Newmark reference and the old kernel do)."""
    rom, path = modal_fmus[integrator]
    fmu, refs, outputs, states = _initialized_fmu(path)
    u = np.full((1, 20), 0.5)
    for i in range(20):
        fmu.setReal([refs["u[1]"]], [0.5])
        fmu.doStep(i * 0.1, 0.1)
        fmu.getReal(outputs)
    fmu.setReal([refs["u[1]"]], [2.0])
    got = np.array(fmu.getReal(states))
    fmu.terminate()
    fmu.freeInstance()
    expected = _reference_states(rom, u)[:, -1]
    expected[2 * rom.r:] += np.linalg.solve(rom.Mr, rom.Br[:, 0] * 1.5)
    assert _relative(got, expected) < 1e-12


@needs_compiler
def test_exact_fmu_takes_steps_computed_as_time_differences_late_in_a_long_run(modal_fmus):
    """``h = t[i+1] - t[i]`` on ``t = dt * arange`` differs from dt by ~1e-12 relative near t = 1000: still the step."""
    fmu = _initialized_fmu(modal_fmus["exact"][1])[0]
    t = 0.1 * np.arange(10_300)
    assert np.abs(np.diff(t) - 0.1).max() > 1e-12 * 0.1          # the case the check must tolerate
    for i in range(t.size - 1):
        fmu.doStep(float(t[i]), float(t[i + 1] - t[i]))             # raises on an fmi2Error
    fmu.terminate()
    fmu.freeInstance()
