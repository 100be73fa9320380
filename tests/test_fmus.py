"""Tests of the benchmark FMUs (fmus/ C sources, fmu_opinf.fmus builder) driven by FMPy."""

from __future__ import annotations

import re
import subprocess
from ctypes import byref
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import calloc, extract, free, read_model_description  # noqa: E402
from fmpy.fmi1 import FMICallException  # noqa: E402
from fmpy.fmi2 import (  # noqa: E402
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2CoSimulation,
    fmi2Error,
)
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_opinf import fmus, newmark, signals, systems  # noqa: E402
from fmu_opinf.errors import FmuOpinfError  # noqa: E402

pytestmark = pytest.mark.fmu

if fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"
HARMONIC = "harmonic:amplitude=2,omega=0.3"
CASES = {
    # name: (reference system, spec, step, end time)
    "AnchoredMSD": (systems.anchored_msd(600), fmus.anchored_msd_spec(600), 0.5, 60.0),
    "TripleChainMSD": (systems.triple_chain(100), fmus.triple_chain_spec(100), 0.1, 12.0),
}


# --------------------------------------------------------------------------- fixtures

@pytest.fixture(scope="module")
def built(tmp_path_factory) -> dict[str, tuple[Path, Path]]:
    """Build both FMUs once: name -> (fmu path, extracted folder)."""
    out = tmp_path_factory.mktemp("fmus")
    paths = fmus.build_fmus(out)
    return {path.stem: (path, Path(extract(str(path), str(out / path.stem)))) for path in paths}


class Driver:
    """An FMPy co-simulation instance whose log messages are captured."""

    def __init__(self, folder: Path, spec: fmus.SecondOrderFmuSpec, name: str = "test") -> None:
        md = read_model_description(str(folder))
        self.spec = spec
        self.vr = fmus.value_references(spec)
        self.messages: list[tuple[int, str]] = []
        self._logger = fmi2CallbackLoggerTYPE(self._log)
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = self._logger
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self.callbacks)

    def _log(self, env, instance, status, category, message) -> None:
        self.messages.append((status, message.decode()))

    def start(self, t0: float = 0.0) -> None:
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def get(self, key: str) -> np.ndarray:
        return np.array(self.fmu.getReal(self.vr[key]))

    def set_input(self, u: np.ndarray) -> None:
        self.fmu.setReal(self.vr["u"], [float(value) for value in np.ravel(u)])

    def record(self) -> tuple[np.ndarray, ...]:
        return tuple(self.get(key) for key in ("x", "v", "a", "y"))

    def free(self) -> None:
        self.fmu.freeInstance()


def run(driver: Driver, signal, t: np.ndarray) -> dict[str, np.ndarray]:
    """Drive the FMU on grid t, setting u(t_k) at each step start (fmpy's convention)."""
    columns = {key: [] for key in ("x", "v", "a", "y")}
    u = signal.sample(t)
    driver.set_input(u[:, 0])
    for i in range(t.size):
        if i > 0:
            driver.set_input(u[:, i - 1])
            driver.fmu.doStep(t[i - 1], t[i] - t[i - 1])
        for key, value in zip(columns, driver.record()):
            columns[key].append(value)
    return {key: np.array(value).T for key, value in columns.items()}


def relative_error(actual: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(actual - reference).max() / np.abs(reference).max())


@pytest.fixture
def driver_factory(built):
    drivers = []

    def make(name: str, instance: str = "test") -> Driver:
        driver = Driver(built[name][1], CASES[name][1], instance)
        drivers.append(driver)
        return driver

    yield make
    for driver in drivers:
        driver.free()


# ------------------------------------------------------------------------ the files

@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.slow  # 4 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_validate_fmu_reports_no_problem(built, name):
    assert validate_fmu(str(built[name][0])) == []


@pytest.mark.parametrize("name", list(CASES))
def test_binary_links_only_libc_and_libm(built, name):
    binary = built[name][1] / "binaries" / "linux64" / f"{name}.so"
    libraries = subprocess.run(["ldd", str(binary)], capture_output=True, text=True, check=True).stdout
    assert "python" not in libraries
    needed = set(re.findall(r"^\s*(lib\S+)", libraries, flags=re.M))
    assert needed <= {"libc.so.6", "libm.so.6"}, needed


@pytest.mark.parametrize("name", list(CASES))
def test_fmu_keeps_sources_and_description(built, name):
    folder = built[name][1]
    md = read_model_description(str(folder))
    for file in ("fmi2Functions.c", "newmark.c", "model.c", "config.h", "model.h", "newmark.h",
                 "fmi2Functions.h", "readme.md"):
        assert (folder / "sources" / file).is_file()
    identity = (folder / "sources" / fmus.IDENTITY_SOURCE).read_text()
    assert f'"{md.guid}"' in identity and f'"{md.coSimulation.modelIdentifier}"' in identity
    assert md.guid not in (folder / "sources" / "config.h").read_text()   # (else every unit changes with it)
    assert [s for s in md.buildConfigurations[0].sourceFileSets[0].sourceFiles if s == fmus.IDENTITY_SOURCE]
    assert md.coSimulation.canHandleVariableCommunicationStepSize
    assert md.coSimulation.canGetAndSetFMUstate
    names = [v.name for v in md.modelVariables]
    n = CASES[name][1].n
    assert names[0] == "u" and f"x[{n}]" in names and f"a[{n}]" in names


@pytest.mark.slow  # 21 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_cmake_build_gives_the_same_working_fmu(tmp_path, monkeypatch):
    """The CMake path (Windows, or FMU_OPINF_BUILD=cmake) and the direct compiler call build FMUs that both
    reproduce the reference simulator; the direct one is the default on Linux."""
    system, spec, dt, _ = CASES["AnchoredMSD"]
    reference = newmark.simulate(system, IMPULSE, dt, 10.0)
    for mode in ("direct", "cmake"):
        monkeypatch.setenv("FMU_OPINF_BUILD", mode)
        path = fmus.build_second_order_fmu(spec, tmp_path / mode / "AnchoredMSD.fmu")
        driver = Driver(Path(extract(str(path), str(tmp_path / mode / "x"))), spec, mode)
        try:
            driver.start()
            got = run(driver, signals.parse_signal(IMPULSE), reference.t)
        finally:
            driver.free()
        assert relative_error(got["x"], reference.x) < 1e-13, mode   # measured 1.6e-16 for both
        assert validate_fmu(str(path)) == [], mode


def test_guid_derives_from_content():
    first = fmus._source_tree(fmus.anchored_msd_spec(600))[1]
    again = fmus._source_tree(fmus.anchored_msd_spec(600))[1]
    other = fmus._source_tree(fmus.anchored_msd_spec(601))[1]
    assert first == again != other


# ------------------------------------------------------------------------- numerics

@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("spec", [IMPULSE, HARMONIC])
def test_fmu_matches_reference_simulator(driver_factory, name, spec):
    system, _, dt, t_end = CASES[name]
    reference = newmark.simulate(system, spec, dt, t_end)
    driver = driver_factory(name)
    driver.start()
    got = run(driver, signals.parse_signal(spec), reference.t)
    for key, expected in (("x", reference.x), ("v", reference.xdot), ("a", reference.xddot),
                          ("y", reference.y)):
        assert relative_error(got[key], expected) < 1e-10, key


@pytest.mark.parametrize("name", list(CASES))
def test_constraint_holds_inside_fmu(driver_factory, name):
    system, _, dt, t_end = CASES[name]
    driver = driver_factory(name)
    driver.start()
    got = run(driver, signals.parse_signal(IMPULSE), np.arange(0.0, t_end + dt / 2, dt))
    level = got["x"] if system.constraint == "position" else got["v"]
    assert np.abs(level).max() > 1e-3
    assert np.abs(system.G @ level).max() < 1e-12 * np.abs(level).max()


@pytest.mark.parametrize("name", list(CASES))
def test_step_size_change_mid_run(driver_factory, name):
    system, _, dt, _ = CASES[name]
    steps = [dt] * 20 + [dt / 3] * 15 + [2 * dt] * 10
    t = np.concatenate([[0.0], np.cumsum(steps)])
    signal = signals.parse_signal(HARMONIC)
    u = signal.sample(t)
    stepper = newmark.NewmarkStepper(system.M, system.D, system.K, system.B, dt, G=system.G,
                                     constraint=system.constraint)
    stepper.start(u[:, 0])
    driver = driver_factory(name)
    driver.start()
    got = run(driver, signal, t)
    expected = [stepper.x.copy()]
    for i, h in enumerate(steps, start=1):
        stepper.set_step(h)
        stepper.step(u[:, i - 1])
        expected.append(stepper.x.copy())
    assert relative_error(got["x"], np.array(expected).T) < 1e-10


def test_parameters_are_used(driver_factory):
    heavy = systems.anchored_msd(600, mass=50.0, k1=3.0)
    reference = newmark.simulate(heavy, IMPULSE, 0.5, 20.0)
    driver = driver_factory("AnchoredMSD")
    mass, k1 = driver.vr["parameters"][:2]
    driver.fmu.setReal([mass, k1], [50.0, 3.0])
    driver.start()
    got = run(driver, signals.parse_signal(IMPULSE), reference.t)
    assert relative_error(got["x"], reference.x) < 1e-10


# ------------------------------------------------------------- state, reset, restart

def advance(driver: Driver, t0: float, h: float, steps: int, amplitude: float) -> np.ndarray:
    outputs = []
    for i in range(steps):
        driver.set_input([amplitude * np.sin(0.3 * (t0 + i * h))])
        driver.fmu.doStep(t0 + i * h, h)
        outputs.append(np.concatenate(driver.record()))
    return np.array(outputs)


@pytest.mark.parametrize("name", list(CASES))
def test_get_set_and_serialize_fmu_state(driver_factory, name):
    h = CASES[name][2]
    driver = driver_factory(name)
    driver.start()
    advance(driver, 0.0, h, 10, 5.0)
    state = driver.fmu.getFMUstate()
    first = advance(driver, 10 * h, h, 10, 5.0)
    driver.fmu.setFMUstate(state)
    assert np.array_equal(advance(driver, 10 * h, h, 10, 5.0), first)

    blob = driver.fmu.serializeFMUstate(state)
    driver.fmu.freeFMUstate(state)
    other = driver_factory(name, "other")
    other.start()
    restored = other.fmu.deSerializeFMUstate(blob)
    other.fmu.setFMUstate(restored)
    assert np.array_equal(advance(other, 10 * h, h, 10, 5.0), first)
    other.fmu.freeFMUstate(restored)


@pytest.mark.parametrize("name", list(CASES))
def test_reset_restarts_from_scratch(driver_factory, name):
    h = CASES[name][2]
    driver = driver_factory(name)
    driver.start()
    first = advance(driver, 0.0, h, 15, 3.0)
    driver.fmu.reset()
    driver.start()
    assert np.array_equal(advance(driver, 0.0, h, 15, 3.0), first)


def test_input_set_before_first_step_gives_consistent_acceleration(driver_factory):
    system = CASES["TripleChainMSD"][0]
    driver = driver_factory("TripleChainMSD")
    driver.start()
    driver.set_input([4.0])
    stepper = newmark.NewmarkStepper(system.M, system.D, system.K, system.B, 0.1, G=system.G,
                                     constraint=system.constraint)
    stepper.start(np.array([4.0]))
    assert relative_error(driver.get("a"), stepper.a) < 1e-12


# ------------------------------------------------------------------------- bad calls

def expect_error(driver: Driver, call, *args, pattern: str) -> None:
    driver.messages.clear()
    with pytest.raises(FMICallException) as info:
        call(*args)
    assert info.value.status == fmi2Error
    assert any(status == fmi2Error and re.search(pattern, text) for status, text in driver.messages), \
        driver.messages


@pytest.mark.parametrize("value, pattern", [(float("nan"), "not finite"), (float("inf"), "not finite")])
def test_non_finite_input_is_an_error(driver_factory, value, pattern):
    driver = driver_factory("AnchoredMSD")
    driver.start()
    expect_error(driver, driver.set_input, [value], pattern=pattern)
    driver.fmu.reset()
    driver.start()
    driver.fmu.doStep(0.0, 0.5)


@pytest.mark.parametrize("h", [0.0, -0.5, float("nan")])
def test_non_positive_step_is_an_error(driver_factory, h):
    driver = driver_factory("TripleChainMSD")
    driver.start()
    expect_error(driver, driver.fmu.doStep, 0.0, h, pattern="must be positive")


def test_wrong_communication_point_is_an_error(driver_factory):
    driver = driver_factory("TripleChainMSD")
    driver.start()
    driver.fmu.doStep(0.0, 0.1)
    expect_error(driver, driver.fmu.doStep, 0.5, 0.1, pattern="communication point")


def test_step_past_stop_time_is_an_error(driver_factory):
    driver = driver_factory("TripleChainMSD")
    driver.fmu.setupExperiment(startTime=0.0, stopTime=0.15)
    driver.fmu.enterInitializationMode()
    driver.fmu.exitInitializationMode()
    driver.fmu.doStep(0.0, 0.1)
    expect_error(driver, driver.fmu.doStep, 0.1, 0.1, pattern="stop time")


def test_calls_out_of_order_are_errors(driver_factory):
    driver = driver_factory("AnchoredMSD")
    expect_error(driver, driver.fmu.doStep, 0.0, 0.5, pattern="fmi2DoStep must not be called")
    driver.fmu.reset()
    expect_error(driver, driver.fmu.exitInitializationMode, pattern="must not be called")
    driver.fmu.reset()
    driver.start()
    expect_error(driver, driver.fmu.enterInitializationMode, pattern="must not be called")


def test_setting_outputs_states_or_fixed_parameters_is_an_error(driver_factory):
    driver = driver_factory("AnchoredMSD")
    driver.start()
    expect_error(driver, driver.fmu.setReal, driver.vr["y"][:1], [1.0], pattern="cannot be set")
    driver.fmu.reset()
    driver.start()
    expect_error(driver, driver.fmu.setReal, driver.vr["parameters"][:1], [1.0], pattern="fixed")
    driver.fmu.reset()
    driver.start()
    expect_error(driver, driver.fmu.getReal, [10**7], pattern="unknown value reference")


def test_invalid_parameter_is_an_error(driver_factory):
    driver = driver_factory("AnchoredMSD")
    driver.fmu.setReal(driver.vr["parameters"][:1], [-1.0])
    driver.fmu.setupExperiment(startTime=0.0)
    driver.fmu.enterInitializationMode()
    expect_error(driver, driver.fmu.exitInitializationMode, pattern="mass must be positive")


def test_wrong_guid_is_refused_with_a_message(built):
    folder = built["AnchoredMSD"][1]
    md = read_model_description(str(folder))
    driver = Driver(folder, CASES["AnchoredMSD"][1])
    try:
        component = driver.fmu.fmi2Instantiate(b"bad", fmi2CoSimulation, b"{not-the-guid}",
                                               b"file:///", byref(driver.callbacks), 0, 0)
        assert component is None
        assert any("wrong GUID" in text for _, text in driver.messages)
        assert md.guid
    finally:
        driver.free()


def test_unsupported_functions_are_errors(driver_factory):
    driver = driver_factory("AnchoredMSD")
    driver.start()
    expect_error(driver, driver.fmu.getDirectionalDerivative, driver.vr["y"], driver.vr["u"], [1.0],
                 pattern="not supported")


# --------------------------------------------------------------------------- builder

def test_missing_build_tools_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(fmus.shutil, "which", lambda name: None)
    monkeypatch.delenv("CC", raising=False)
    with pytest.raises(fmus.FmuBuildError, match="CMake and a C compiler") as info:
        fmus.build_fmus(tmp_path)
    assert isinstance(info.value, FmuOpinfError)


def test_unknown_model_and_bad_size_are_clear_errors(tmp_path):
    with pytest.raises(fmus.FmuBuildError, match="unknown benchmark"):
        fmus.build_fmus(tmp_path, models=("Pendulum",))
    with pytest.raises(fmus.FmuBuildError, match="even"):
        fmus.build_fmus(tmp_path, models=("TripleChainMSD",), n1=7)


def test_compile_error_is_reported(tmp_path):
    spec = fmus.anchored_msd_spec(10)
    spec.model_source = "this is not C;"
    with pytest.raises(fmus.FmuBuildError, match="compilation failed"):
        fmus.build_second_order_fmu(spec, tmp_path / "Broken.fmu")
    assert not (tmp_path / "Broken.fmu").exists()


def test_source_only_fmu_has_no_binary(tmp_path):
    import zipfile

    path = fmus.build_second_order_fmu(fmus.triple_chain_spec(4), tmp_path / "T.fmu", compile=False)
    names = zipfile.ZipFile(path).namelist()
    assert "sources/model.c" in names and not any(n.startswith("binaries/") for n in names)


def test_fmpy_simulate_fmu_matches_reference(built):
    """FMPy's own co-simulation loop (input table sampled at the grid) gives the reference."""
    system, _, dt, t_end = CASES["AnchoredMSD"]
    reference = newmark.simulate(system, IMPULSE, dt, t_end)
    table = np.zeros(reference.t.size, dtype=[("time", float), ("u", float)])
    table["time"] = reference.t
    table["u"] = signals.parse_signal(IMPULSE).sample(reference.t)[0]
    result = fmpy.simulate_fmu(str(built["AnchoredMSD"][0]), stop_time=t_end, output_interval=dt,
                               input=table, output=["y[1]", "y[2]", "y[3]"])
    got = np.array([result[f"y[{i}]"] for i in (1, 2, 3)])
    assert np.allclose(result["time"], reference.t, rtol=0, atol=1e-9)
    assert relative_error(got, reference.y) < 1e-10


@pytest.mark.slow
def test_states_can_be_left_out_of_the_model_description(tmp_path):
    spec = fmus.anchored_msd_spec(30)
    spec.expose_states = False
    path = fmus.build_second_order_fmu(spec, tmp_path / "AnchoredMSD.fmu")
    assert validate_fmu(str(path)) == []
    names = [v.name for v in read_model_description(str(path)).modelVariables]
    assert "x[1]" not in names and names[:4] == ["u", "y[1]", "y[2]", "y[3]"]


@pytest.mark.slow
def test_fmi3_benchmark_fmu_matches_reference_and_rejects_bad_calls(tmp_path):
    from fmpy.fmi3 import FMU3Slave

    path = fmus.build_fmus(tmp_path, models=("TripleChainMSD",), n1=20, fmi_version="3.0")[0]
    assert validate_fmu(str(path)) == []
    system = systems.triple_chain(20)
    reference = newmark.simulate(system, HARMONIC, 0.1, 10.0)
    folder = extract(str(path), str(tmp_path / "fmi3"))
    md = read_model_description(folder)
    spec = fmus.triple_chain_spec(20)
    vr = fmus.value_references(spec)
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=folder,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="fmi3")
    fmu.instantiate()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    u = signals.parse_signal(HARMONIC).sample(reference.t)
    x = [fmu.getFloat64(vr["x"])]
    for i in range(1, reference.t.size):
        fmu.setFloat64(vr["u"], [float(u[0, i - 1])])
        fmu.doStep(reference.t[i - 1], reference.t[i] - reference.t[i - 1])
        x.append(fmu.getFloat64(vr["x"]))
    assert relative_error(np.array(x).T, reference.x) < 1e-10
    assert fmu.getFloat64([0]) == [pytest.approx(10.0)]
    with pytest.raises(FMICallException):
        fmu.setFloat64(vr["u"], [float("nan")])
    fmu.reset()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):
        fmu.doStep(0.0, -1.0)
    fmu.freeInstance()


@pytest.mark.slow
def test_bundled_fmu_builds_once_and_rebuilds_when_sources_change(tmp_path, monkeypatch):
    import shutil

    root = Path(fmus.__file__).resolve().parents[2] / "fmus"
    copy = tmp_path / "fmus"
    for folder in ("include", "src", "AnchoredMSD", "TripleChainMSD"):
        shutil.copytree(root / folder, copy / folder, ignore=shutil.ignore_patterns("*.fmu"))
    monkeypatch.setattr(fmus, "_c_sources_dir", lambda: copy)
    path = fmus.bundled_fmu("TripleChainMSD")
    assert path == copy / "TripleChainMSD.fmu" and validate_fmu(str(path)) == []
    built = path.stat().st_mtime_ns
    assert fmus.bundled_fmu("TripleChainMSD").stat().st_mtime_ns == built
    first_guid = fmus._fmu_guid(path)
    model = copy / "TripleChainMSD" / "model.c"
    model.write_text(model.read_text() + "\n/* changed */\n")
    fmus.bundled_fmu("TripleChainMSD")
    assert fmus._fmu_guid(path) != first_guid


def test_round_off_changes_of_the_step_do_not_refactor(driver_factory):
    h = 0.1
    exact = driver_factory("TripleChainMSD", "exact")
    exact.start()
    noisy = driver_factory("TripleChainMSD", "noisy")
    noisy.fmu.setDebugLogging(True, ["logEvents"])
    noisy.start()
    t = 0.0
    for k in range(20):
        step = h * (1.0 + (-1) ** k * 3e-16 * k)
        for driver, size in ((exact, h), (noisy, step)):
            driver.set_input([np.sin(t)])
            driver.fmu.doStep(t if driver is noisy else k * h, size)
        t += step
    factorizations = [text for _, text in noisy.messages if "factored the step matrix" in text]
    assert len(factorizations) == 1
    assert np.array_equal(noisy.get("x"), exact.get("x"))
    noisy.fmu.doStep(t, 0.05)
    assert len([text for _, text in noisy.messages if "factored the step matrix" in text]) == 2


def test_duplicate_variable_names_are_refused():
    with pytest.raises(fmus.FmuBuildError, match="used twice"):
        fmus.SecondOrderFmuSpec("Dup", "", n=2, m=1, p=1, input_names=["y"], output_names=["y"])
    with pytest.raises(fmus.FmuBuildError, match="x\\[1\\]"):
        fmus.SecondOrderFmuSpec("Dup", "", n=2, m=1, p=1, output_names=["x[1]"])


VALGRIND_HARNESS = r"""
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c,
                   fmi2String m, ...) {
    (void)e; (void)n; (void)s; (void)c; (void)m;
}

int main(void) {
    fmi2CallbackFunctions cb = { logger, calloc, free, NULL, NULL };
    const char *categories[] = { "logEvents" };
    fmi2ValueReference input = 1, parameter = 3;
    fmi2FMUstate state = NULL, copy = NULL;
    double u, y, t = 0.0, h;
    size_t size;
    char *buffer;
    int k;
    fmi2Component c = fmi2Instantiate("h", fmi2CoSimulation, INSTANTIATION_TOKEN, "", &cb, 0, 1);

    fmi2SetDebugLogging(c, 1, 1, categories);
    fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0);
    fmi2EnterInitializationMode(c);
    u = 2.0;
    fmi2SetReal(c, &parameter, 1, &u);
    fmi2ExitInitializationMode(c);
    for (k = 0; k < 50; k++) {
        h = k < 25 ? 0.1 : 0.05;
        u = sin(0.3 * t);
        fmi2SetReal(c, &input, 1, &u);
        fmi2DoStep(c, t, h, 1);
        t += h;
    }
    fmi2GetFMUstate(c, &state);
    fmi2SerializedFMUstateSize(c, state, &size);
    buffer = malloc(size);
    fmi2SerializeFMUstate(c, state, buffer, size);
    fmi2DeSerializeFMUstate(c, buffer, size, &copy);
    fmi2SetFMUstate(c, copy);
    fmi2GetReal(c, &input, 1, &y);
    u = NAN;
    fmi2SetReal(c, &input, 1, &u);
    fmi2Reset(c);
    fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0);
    fmi2EnterInitializationMode(c);
    fmi2ExitInitializationMode(c);
    fmi2DoStep(c, 0.0, 0.1, 1);
    fmi2DoStep(c, 5.0, 0.1, 1);
    fmi2FreeFMUstate(c, &state);
    fmi2FreeFMUstate(c, &copy);
    free(buffer);
    fmi2FreeInstance(c);
    printf("done\n");
    return 0;
}
"""


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_sources_compile_without_warnings(tmp_path, version):
    spec = fmus.triple_chain_spec(10)
    spec.fmi_version = version
    path = fmus.build_second_order_fmu(spec, tmp_path / "T.fmu", compile=False)
    import zipfile

    zipfile.ZipFile(path).extractall(tmp_path / "T")
    sources = sorted(str(p) for p in (tmp_path / "T" / "sources").glob("*.c"))
    compiler = fmus.find_build_tools()[1]
    result = subprocess.run([compiler, "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-O2",
                             "-shared", "-fPIC", "-I", str(tmp_path / "T" / "sources"), *sources,
                             "-o", str(tmp_path / "T.so"), "-lm"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


@pytest.mark.slow
def test_no_leaks_or_memory_errors_under_valgrind(tmp_path):
    import shutil
    import zipfile

    if shutil.which("valgrind") is None:
        pytest.skip("valgrind is not installed")
    path = fmus.build_second_order_fmu(fmus.triple_chain_spec(10), tmp_path / "T.fmu", compile=False)
    zipfile.ZipFile(path).extractall(tmp_path / "T")
    src = tmp_path / "T" / "sources"
    (tmp_path / "harness.c").write_text(VALGRIND_HARNESS)
    program = tmp_path / "harness"
    compiler = fmus.find_build_tools()[1]
    subprocess.run([compiler, "-std=c99", "-g", "-O1", "-I", str(src), "-include", "config.h",
                    *(str(src / f) for f in ("fmi2Functions.c", "instance.c", "newmark.c", "model.c",
                                             fmus.IDENTITY_SOURCE)),
                    str(tmp_path / "harness.c"), "-o", str(program), "-lm"], check=True)
    result = subprocess.run(["valgrind", "--leak-check=full", "--error-exitcode=9", str(program)],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "All heap blocks were freed" in result.stderr and result.stdout.strip() == "done"


def test_a_percent_sign_in_a_message_is_text_for_a_formatting_importer(built, capfd):
    """The FMI 2 logger's message is a printf format: fmpy's proxy formats it.  A token with conversions in it (given
    by the importer, repeated in the kernel's refusal) is printed as it was given, instead of reading arguments that
    are not there."""
    import subprocess
    import sys
    import textwrap

    folder = built["AnchoredMSD"][1]
    script = textwrap.dedent(f"""
        from ctypes import byref
        from fmpy.fmi2 import FMU2Slave, defaultCallbacks, fmi2CoSimulation
        fmu = FMU2Slave(guid="x", unzipDirectory={str(folder)!r}, modelIdentifier="AnchoredMSD", instanceName="p")
        component = fmu.fmi2Instantiate(b"p", fmi2CoSimulation, b"{{bad%s%s%s%n}}", b"file:///",
                                        byref(defaultCallbacks), 0, 0)
        assert component is None
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-400:]
    assert 'token "{bad%s%s%s%n}"' in done.stdout
