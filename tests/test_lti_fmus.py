"""Tests of the exporter-style FMUs (fmu_opinf.lti_fmus) against exact solutions.

The reference is :func:`zoh_response` (matrix exponential in the orthonormal minimal coordinates
of the model), itself checked against a closed-form damped oscillator and an independent
``solve_ivp`` integration; the FMUs are driven by FMPy (CVODE for model exchange).
"""

from __future__ import annotations

import zipfile
from dataclasses import replace

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.errors import DimensionError, FmuOpinfError  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

STEP = 0.05
T_END = 6.0


# ----------------------------------------------------------------------- helpers

@pytest.fixture(scope="module")
def corpus(request, tmp_path_factory) -> dict[str, lti_fmus.LtiFmu]:
    """Every corpus FMU, compiled once; kept in pytest's cache folder between sessions.

    A cached FMU is reused only if its GUID, a hash of every generated file and C source,
    is the one the current code generates, so any change of the builder rebuilds it.
    """
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    return lti_fmus.build_corpus(folder)


def grid(end: float = T_END, step: float = STEP) -> np.ndarray:
    return np.arange(0.0, end + step / 2, step)


def held_input(m: int, t: np.ndarray, seed: int = 0) -> np.ndarray:
    """A piecewise-constant input (m, N-1): random levels held over a few steps each."""
    rng = np.random.default_rng(seed)
    levels = rng.normal(size=(m, (t.size - 1) // 7 + 1))
    return np.repeat(levels, 7, axis=1)[:, : t.size - 1]


def fmpy_table(names: list[str], t: np.ndarray, u: np.ndarray, extra=None):
    """FMPy input table holding ``u[:, i]`` on ``[t_i, t_{i+1}]`` (a jump at every t_i)."""
    if not names and not extra:
        return None
    extra = extra or {}
    rows = []
    for i in range(t.size - 1):
        values = tuple(u[:, i]) + tuple(extra.values())
        rows.append((t[i],) + values)
        rows.append((t[i + 1],) + values)
    dtype = [("time", float)] + [(name, float) for name in list(names) + list(extra)]
    return np.array(rows, dtype=dtype)


def simulate(fmu: lti_fmus.LtiFmu, interface: str, t: np.ndarray, u: np.ndarray,
             outputs: list[str], **options) -> dict[str, np.ndarray]:
    """Simulate with FMPy; each output sampled at the grid (value before an input jump)."""
    kind = {"me": "ModelExchange", "cs": "CoSimulation"}[interface]
    if interface == "me":
        options.setdefault("solver", "CVode")
    result = simulate_fmu(str(fmu.path), fmi_type=kind, start_time=t[0], stop_time=t[-1],
                          output_interval=t[1] - t[0], output=outputs,
                          input=fmpy_table(fmu.inputs, t, u, options.pop("extra", None)),
                          **options)
    times = result["time"]
    first = np.array([np.flatnonzero(np.isclose(times, ti, rtol=0, atol=1e-9))[0] for ti in t])
    return {name: np.asarray(result[name])[first] for name in outputs}


def relative_error(value: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(value - reference).max() / np.abs(reference).max())


def recorded_blocks(fmu: lti_fmus.LtiFmu, data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Positions, velocities, accelerations (n, N) and outputs (p, N) from a recording."""
    blocks = {}
    for key in ("positions", "velocities", "accelerations", "outputs"):
        names = getattr(fmu, key)
        if not names:
            continue
        if fmu.naming == "array" and key != "outputs":
            blocks[key] = np.asarray(data[names[0]]).T
        else:
            blocks[key] = np.array([data[name] for name in names])
    return blocks


def reference_blocks(response: lti_fmus.ZohResponse) -> dict[str, np.ndarray]:
    return {"positions": response.x, "velocities": response.v, "accelerations": response.a,
            "outputs": response.y}


def all_names(fmu: lti_fmus.LtiFmu) -> list[str]:
    names = fmu.positions + fmu.velocities + fmu.accelerations + fmu.outputs
    return list(dict.fromkeys(names))


# ------------------------------------------------------------- the exact reference

def test_zoh_response_matches_closed_form_damped_oscillator():
    """1 dof, offset force, start off rest, two input levels: piecewise closed form."""
    mass, damping, stiffness, offset = 2.0, 0.6, 18.0, 1.5
    model = lti_fmus.LinearMechanicalModel(
        M=[[mass]], D=[[damping]], K=[[stiffness]], B=[[1.0]], f0=[offset], Cp=[[1.0]],
        Ca=[[0.5]], y0=[0.25], x0=[0.3], v0=[-0.4])
    t = np.linspace(0.0, 4.0, 81)
    u = np.where(t[:-1] < 2.0, 3.0, -1.0)[None, :]
    omega0 = np.sqrt(stiffness / mass)
    zeta = damping / (2 * np.sqrt(stiffness * mass))
    omega = omega0 * np.sqrt(1 - zeta**2)

    def free(x0, v0, force, s):
        equilibrium = force / stiffness
        a, b = x0 - equilibrium, (v0 + zeta * omega0 * (x0 - equilibrium)) / omega
        decay = np.exp(-zeta * omega0 * s)
        x = equilibrium + decay * (a * np.cos(omega * s) + b * np.sin(omega * s))
        v = decay * ((-zeta * omega0 * a + omega * b) * np.cos(omega * s)
                     + (-zeta * omega0 * b - omega * a) * np.sin(omega * s))
        return x, v

    x_switch, v_switch = free(0.3, -0.4, offset + 3.0, 2.0)
    first = t <= 2.0
    x = np.empty_like(t)
    v = np.empty_like(t)
    x[first], v[first] = free(0.3, -0.4, offset + 3.0, t[first])
    x[~first], v[~first] = free(x_switch, v_switch, offset - 1.0, t[~first] - 2.0)
    response = lti_fmus.zoh_response(model, t, u)
    paired = np.r_[u[0, 0], u[0]]          # input in effect over the step ending at t_i
    a = (paired + offset - damping * v - stiffness * x) / mass
    assert np.abs(response.x[0] - x).max() < 1e-12
    assert np.abs(response.v[0] - v).max() < 1e-11
    assert np.abs(response.a[0] - a).max() < 1e-10
    assert np.abs(response.y[0] - (x + 0.5 * a + 0.25)).max() < 1e-10
    current = lti_fmus.zoh_response(model, t, u, accelerations_from="current")
    assert abs(current.a[0, 40] - (-1.0 + offset - damping * v[40] - stiffness * x[40]) / mass) \
        < 1e-10


def test_zoh_response_of_a_constrained_chain_matches_solve_ivp():
    """Bar-tied chain: reference integrated in other coordinates (independent positions)."""
    from scipy.integrate import solve_ivp

    model = lti_fmus.corpus_models()["constrained-bar"][0]
    model = replace(model, f0=0.3 * np.ones(model.n))
    t = np.linspace(0.0, 3.0, 31)
    u = np.sin(1.3 * t[:-1])[None, :]
    T, offset = model.state_map()
    keep = model.independent_dofs()
    Mq = T.T @ model.M @ T

    def rhs(time, z, level):
        r = T.shape[1]
        force = T.T @ (model.B[:, 0] * level + model.f0 - model.K @ (T @ z[:r] + offset)
                       - model.D @ (T @ z[r:]))
        return np.r_[z[r:], np.linalg.solve(Mq, force)]

    z = np.r_[model.x0[keep], model.v0[keep]]
    states = [z]
    for i in range(t.size - 1):
        sol = solve_ivp(rhs, (t[i], t[i + 1]), z, args=(u[0, i],), method="DOP853",
                        rtol=1e-12, atol=1e-14)
        z = sol.y[:, -1]
        states.append(z)
    states = np.array(states).T
    r = T.shape[1]
    response = lti_fmus.zoh_response(model, t, u)
    assert relative_error(response.x, T @ states[:r] + offset[:, None]) < 1e-9
    assert relative_error(response.v, T @ states[r:]) < 1e-9
    assert np.abs(model.G @ response.x).max() < 1e-13


# ------------------------------------------------------------------- the corpus

def test_corpus_has_every_convention(corpus):
    assert tuple(corpus) == lti_fmus.CORPUS_NAMES


@pytest.mark.parametrize("name", lti_fmus.CORPUS_NAMES)
def test_corpus_fmu_passes_fmpy_validation(corpus, name):
    fmu = corpus[name]
    assert validate_fmu(str(fmu.path)) == []
    md = read_model_description(str(fmu.path))
    assert md.defaultExperiment.stopTime == "1.0"
    assert md.defaultExperiment.stepSize is None
    assert (md.modelExchange is not None) == ("me" in fmu.interfaces)
    assert (md.coSimulation is not None) == ("cs" in fmu.interfaces)
    if fmu.naming != "generic":
        units = {v.name: v.unit for v in md.modelVariables}
        for name_ in fmu.inputs:
            assert units[name_] == "N"
        if fmu.positions:
            assert units[fmu.positions[0]] == "m"


def _me_names():
    return [name for name, (_, options) in lti_fmus.corpus_models().items()
            if "me" in options.get("interfaces", ("me", "cs"))]


def _accurate_cs_names():
    names = []
    for name, (_, options) in lti_fmus.corpus_models().items():
        if "cs" in options.get("interfaces", ("me", "cs")) and options.get("cs_method") != "euler":
            names.append(name)
    return names


@pytest.mark.parametrize("name", _me_names())
def test_model_exchange_matches_the_exact_zero_order_hold_solution(corpus, name):
    fmu = corpus[name]
    t = grid()
    u = held_input(fmu.model.m, t)
    data = simulate(fmu, "me", t, u, all_names(fmu), relative_tolerance=1e-10)
    reference = reference_blocks(lti_fmus.zoh_response(fmu.model, t, u))
    recorded = recorded_blocks(fmu, data)
    assert recorded
    for key, value in recorded.items():
        assert relative_error(value, reference[key]) < 1e-6, key


@pytest.mark.parametrize("name", _accurate_cs_names())
def test_accurate_co_simulation_matches_the_exact_solution(corpus, name):
    fmu = corpus[name]
    t = grid()
    u = held_input(fmu.model.m, t, seed=1)
    data = simulate(fmu, "cs", t, u, all_names(fmu), relative_tolerance=1e-10)
    reference = reference_blocks(lti_fmus.zoh_response(fmu.model, t, u))
    for key, value in recorded_blocks(fmu, data).items():
        assert relative_error(value, reference[key]) < 1e-9, key


def test_co_simulation_error_follows_the_tolerance(corpus):
    fmu = corpus["start-off-rest"]
    t = grid(step=0.2)
    u = held_input(1, t, seed=2)
    reference = lti_fmus.zoh_response(fmu.model, t, u).x
    errors = {}
    for tolerance in (None, 1e-6, 1e-10):
        data = simulate(fmu, "cs", t, u, fmu.positions, relative_tolerance=tolerance)
        errors[tolerance] = relative_error(np.array([data[n] for n in fmu.positions]), reference)
    assert 1e-9 < errors[None] < 1e-3
    assert errors[1e-6] < errors[None] / 10
    assert errors[1e-10] < 1e-9


def test_euler_co_simulation_is_one_explicit_euler_step_per_communication_step(corpus):
    fmu = corpus["cs-euler"]
    model = fmu.model
    t = grid(end=2.0, step=0.05)
    u = held_input(1, t, seed=3)
    data = simulate(fmu, "cs", t, u, fmu.positions + fmu.velocities)
    x = np.array([data[n] for n in fmu.positions])
    v = np.array([data[n] for n in fmu.velocities])
    h = t[1] - t[0]
    a0 = np.linalg.solve(model.M, model.B @ u[:, 0] + model.f0 - model.D @ model.v0
                         - model.K @ model.x0)
    assert np.abs(x[:, 1] - (model.x0 + h * model.v0)).max() < 1e-15
    assert np.abs(v[:, 1] - (model.v0 + h * a0)).max() < 1e-14
    xe, ve = model.x0.copy(), model.v0.copy()
    for i in range(t.size - 1):
        ae = np.linalg.solve(model.M, model.B @ u[:, i] + model.f0 - model.D @ ve - model.K @ xe)
        xe, ve = xe + h * ve, ve + h * ae
    assert relative_error(x[:, -1], xe) < 1e-12 and relative_error(v[:, -1], ve) < 1e-12
    exact = lti_fmus.zoh_response(model, t, u)
    assert relative_error(x, exact.x) > 1e-2      # explicit Euler at h = 0.05 is far off


# ----------------------------------------------------------- parameters and starts

def test_parameter_input_zero_is_a_division_by_zero(corpus):
    fmu = corpus["parameters-as-inputs"]
    assert fmu.parameter_inputs == ["mass_scale", "stiffness_scale"]
    t = grid(end=1.0)
    u = np.zeros((1, t.size - 1))
    messages = []
    for interface in ("me", "cs"):
        with pytest.raises(Exception, match="status 3"):
            simulate(fmu, interface, t, u, fmu.outputs,
                     extra={"mass_scale": 0.0, "stiffness_scale": 1.0},
                     logger=lambda *args: messages.append(args[-1]))
    assert any(b"division by zero" in message for message in messages)


def test_parameter_inputs_scale_the_model(corpus):
    fmu = corpus["parameters-as-inputs"]
    t = grid(end=3.0)
    u = held_input(1, t, seed=4)
    data = simulate(fmu, "me", t, u, fmu.positions, relative_tolerance=1e-10,
                    extra={"mass_scale": 2.0, "stiffness_scale": 0.5})
    reference = lti_fmus.zoh_response(fmu.model, t, u, mass_scale=2.0, stiffness_scale=0.5)
    assert relative_error(np.array([data[n] for n in fmu.positions]), reference.x) < 1e-6


@pytest.mark.parametrize("name, start, dof", [
    ("start-off-rest", "mass[2].s", 1),
    ("generic-lti", "x2_start", 1),
    ("offset-equilibrium", "mass[3].s", 2),
])
def test_start_values_can_be_set_before_initialization(corpus, name, start, dof):
    fmu = corpus[name]
    t = grid(end=3.0)
    u = held_input(fmu.model.m, t, seed=5)
    x0 = fmu.model.x0.copy()
    x0[dof] = 0.25
    reference = lti_fmus.zoh_response(replace(fmu.model, x0=x0), t, u)
    data = simulate(fmu, "me", t, u, fmu.outputs, relative_tolerance=1e-10,
                    start_values={start: 0.25})
    assert relative_error(np.array([data[n] for n in fmu.outputs]), reference.y) < 1e-6


def test_structural_size_resizes_the_arrays(corpus):
    from fmpy.fmi3 import FMU3Slave

    fmu = corpus["fmi3-array-structural"]
    chain = lti_fmus.corpus_models()["fmi3-array-structural"][0]
    md = read_model_description(str(fmu.path))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    size = next(v for v in md.modelVariables if v.name == "n")
    assert (size.causality, size.type, size.start) == ("structuralParameter", "UInt64", "5")
    with zipfile.ZipFile(fmu.path) as archive:
        assert 'min="1" max="64"' in archive.read("modelDescription.xml").decode()
    assert all(d.valueReference == refs["n"] for d in
               next(v for v in md.modelVariables if v.name == "x").dimensions)
    messages = []
    slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(fmu.path)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="resize")
    slave.instantiate(logMessage=lambda *args: messages.append(args[-1]))
    with pytest.raises(Exception):
        slave.setUInt64([refs["n"]], [7])          # outside configuration mode
    slave.enterConfigurationMode()
    for bad in (0, 65):
        with pytest.raises(Exception):
            slave.setUInt64([refs["n"]], [bad])
    slave.setUInt64([refs["n"]], [7])
    slave.exitConfigurationMode()
    slave.enterInitializationMode(tolerance=1e-10)
    slave.exitInitializationMode()
    t = grid(end=3.0, step=0.1)
    u = held_input(1, t, seed=6)
    x = [slave.getFloat64([refs["x"]], nValues=7)]
    for i in range(t.size - 1):
        slave.setFloat64([refs["u1"]], [u[0, i]])
        slave.doStep(t[i], t[i + 1] - t[i])
        x.append(slave.getFloat64([refs["x"]], nValues=7))
    slave.terminate()
    slave.freeInstance()
    assert any(b"outside [1, 64]" in message for message in messages)
    assert relative_error(np.array(x).T, lti_fmus.zoh_response(chain.model(7), t, u).x) < 1e-9


# ------------------------------------------------------- names, links, structure

def _variables(fmu):
    return {v.name: v for v in read_model_description(str(fmu.path)).modelVariables}


def test_modelica_fmi2_der_variables_are_aliases_with_derivative_links(corpus):
    fmu = corpus["modelica-der-aliases"]
    variables = _variables(fmu)
    md = read_model_description(str(fmu.path))
    assert [d.variable.name for d in md.derivatives] == fmu.derivatives
    for i in range(1, fmu.model.n + 1):
        position, velocity = variables[f"mass[{i}].s"], variables[f"mass[{i}].v"]
        der_s, der_v = variables[f"der(mass[{i}].s)"], variables[f"der(mass[{i}].v)"]
        assert der_s.valueReference == velocity.valueReference
        assert der_s.derivative is position and der_v.derivative is velocity
        assert variables[f"mass[{i}].a"].valueReference == der_v.valueReference
        assert variables[f"mass[{i}].a"].derivative is None
        assert position.initial == "exact" and position.causality == "local"


def test_fmi3_modelica_uses_own_value_references_and_alias_elements(corpus):
    fmu = corpus["offset-equilibrium"]
    variables = _variables(fmu)
    der_s, velocity = variables["der(mass[1].s)"], variables["mass[1].v"]
    assert der_s.valueReference != velocity.valueReference
    assert der_s.derivative is variables["mass[1].s"]
    assert "mass[1].a" in [a.name for a in variables["der(mass[1].v)"].aliases]


def test_generic_naming_has_start_parameters_that_are_not_states(corpus):
    fmu = corpus["generic-lti"]
    variables = _variables(fmu)
    n = fmu.model.n
    assert fmu.states == [f"x{k}" for k in range(1, 2 * n + 1)]
    for k in range(1, 2 * n + 1):
        assert variables[f"der_x{k}"].derivative is variables[f"x{k}"]
        assert variables[f"x{k}_start"].causality == "parameter"
        assert variables[f"x{k}"].initial == "calculated"
    assert not any(v.derivative is variables["x1_start"] for v in variables.values())


def test_relative_coordinates_are_the_states_and_absolute_positions_are_locals(corpus):
    fmu = corpus["relative-coordinates"]
    variables = _variables(fmu)
    assert fmu.states[0] == "spring[1].s_rel"
    linked = {v.derivative.name for v in variables.values() if v.derivative is not None}
    assert "spring[3].s_rel" in linked and "mass[3].s" not in linked
    assert variables["mass[3].s"].causality == "local"


def test_constrained_fmu_states_are_the_independent_positions(corpus):
    fmu = corpus["constrained-bar"]
    tied = {"mass[2].s", "mass[4].s"}
    assert len(tied & set(fmu.states)) == 1           # one of the tied masses is computed
    assert len(fmu.states) == 2 * (fmu.model.n - 1)
    computed = (tied - set(fmu.states)).pop()
    assert _variables(fmu)[computed].derivative is None
    t = grid(end=3.0)
    u = held_input(1, t, seed=7)
    data = simulate(fmu, "me", t, u, fmu.positions, relative_tolerance=1e-10)
    x = np.array([data[n] for n in fmu.positions])
    assert np.abs(fmu.model.G @ x).max() < 1e-14


def test_output_dependencies_show_the_feedthrough(corpus):
    fmu = corpus["acceleration-output"]
    md = read_model_description(str(fmu.path))
    assert np.abs(fmu.model.feedthrough[2]).max() > 0 and np.abs(fmu.model.feedthrough[3]).max() == 0
    dependencies = {u.variable.name: [d.name for d in u.dependencies] for u in md.outputs}
    assert "F" in dependencies["y[3]"]                # a_5, the force acts on mass 5
    assert "F" not in dependencies["y[1]"] and "F" not in dependencies["y[4]"]
    assert "mass[5].s" in dependencies["y[1]"]


def test_no_accelerations_fmu_has_no_derivatives(corpus):
    fmu = corpus["no-accelerations"]
    md = read_model_description(str(fmu.path))
    assert md.derivatives == [] and md.modelExchange is None
    assert not any(v.name.startswith("der(") or v.name.endswith(".a") for v in md.modelVariables)


def test_velocity_constraint_fmu_built_afresh_keeps_g_x_constant(tmp_path):
    """A fresh FMI 3.0 build (no cache): G v = 0 reduced to an ODE with a position offset."""
    base = lti_fmus.chain_model(n=4, force_offset=0.3)
    G = np.zeros((1, 4))
    G[0, 0], G[0, 2] = 1.0, -1.0
    model = replace(base, G=G, constraint="velocity", x0=[0.1, 0.0, 0.05, 0.02],
                    v0=[0.1, 0.2, 0.1, 0.0], name="VelocityBar")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "velocity.fmu", fmi_version="3.0",
                                 reuse=False)
    assert validate_fmu(str(fmu.path)) == []
    assert len(fmu.states) == 2 * 3
    t = grid(end=3.0)
    u = held_input(1, t, seed=8)
    data = simulate(fmu, "me", t, u, fmu.positions, relative_tolerance=1e-10)
    x = np.array([data[n] for n in fmu.positions])
    assert relative_error(x, lti_fmus.zoh_response(model, t, u).x) < 1e-6
    assert np.abs(G @ x - 0.05).max() < 1e-14


# ------------------------------------------------------------------- bad input

def test_bad_builder_input_gives_one_line_errors(tmp_path):
    model = lti_fmus.chain_model()
    with pytest.raises(FmuOpinfError, match="needs FMI 3.0"):
        lti_fmus.build_lti_fmu(model, tmp_path / "a.fmu", naming="array")
    with pytest.raises(FmuOpinfError, match="unknown"):
        lti_fmus.build_lti_fmu(model, tmp_path / "a.fmu", parameter_inputs=("spring",))
    with pytest.raises(FmuOpinfError, match="interfaces"):
        lti_fmus.build_lti_fmu(model, tmp_path / "a.fmu", expose_accelerations=False)
    with pytest.raises(DimensionError, match="violates the constraint"):
        replace(model, G=np.eye(1, model.n), constraint="position", x0=np.ones(model.n))
    with pytest.raises(DimensionError, match="shape"):
        lti_fmus.zoh_response(model, np.linspace(0, 1, 5), np.zeros((2, 5)))
