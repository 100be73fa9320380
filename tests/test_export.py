"""Tests of the ROM -> FMU exporter (fmu_opinf.export)."""

from __future__ import annotations

import re
import subprocess
import warnings
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_opinf import export, fmus, newmark, signals, systems  # noqa: E402
from fmu_opinf.errors import (  # noqa: E402
    DataError,
    DimensionError,
    FileFormatError,
    FMUError,
    FmuOpinfWarning,
)

pytestmark = pytest.mark.fmu

TRAIN = "impulse:amplitude=10,t0=1,width=0.5"
TEST = "harmonic:amplitude=3,omega=0.8,phase=0.2"
RECONSTRUCT = ["x[1]", "x[17]"]


class StandInROM:
    """Small intrusive POD-Galerkin ROM of a triple chain, with the SecondOrderROM surface."""

    def __init__(self, r: int = 6, dt: float = 0.1) -> None:
        full = systems.triple_chain(n1=10)
        snapshots = newmark.simulate(full, TRAIN, dt, 30.0)
        V = np.linalg.svd(snapshots.xdot, full_matrices=False)[0][:, :r]
        project = lambda A: V.T @ (A @ V)  # noqa: E731
        self.Mr, self.Dr, self.Kr = (project(A) for A in (full.M, full.D, full.K))
        self.Mr, self.Dr, self.Kr = ((A + A.T) / 2 for A in (self.Mr, self.Dr, self.Kr))
        self.Br = np.asarray(V.T @ full.B.toarray())
        self.Cpr = np.asarray(full.Cp @ V)
        self.Cvr = np.zeros_like(self.Cpr)
        self.basis, self.basis_kind = V, "velocities"
        self.input_names, self.output_names = ["u"], ["y"]
        self.dt = dt
        self.provenance = {"source": "TripleChainMSD.fmu", "guid": "{1234-abcd}",
                           "training_input": TRAIN, "fit_date": "2026-11-21T05:00:00Z"}

    r = property(lambda self: self.Mr.shape[0])
    m = property(lambda self: self.Br.shape[1])
    p = property(lambda self: self.Cpr.shape[0])

    def simulate(self, signal, dt: float, t_end: float) -> SimpleNamespace:
        r = self.r
        reduced = SimpleNamespace(M=self.Mr, D=self.Dr, K=self.Kr, B=self.Br, Cp=self.Cpr,
                                  Cv=self.Cvr, G=np.zeros((0, r)), constraint=None)
        run = newmark.simulate(reduced, signal, dt, t_end)
        return SimpleNamespace(t=run.t, u=run.u, y=run.y, q=run.x, qdot=run.xdot, qddot=run.xddot)


@pytest.fixture(scope="module")
def rom() -> StandInROM:
    return StandInROM()


@pytest.fixture(scope="module")
def exported(rom, tmp_path_factory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("rom")
    path = export.export_fmu(rom, out / "TripleChainROM.fmu", reconstruct=RECONSTRUCT)
    return path, Path(extract(str(path), str(out / "unzipped")))


def drive(folder: Path, signal, t: np.ndarray, r: int) -> dict[str, np.ndarray]:
    """Run the FMU with FMPy, setting u(t_k) before each step; record y, q, qdot, qddot."""
    md = read_model_description(str(folder))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    states = {key: [refs[f"{key}[{i}]"] for i in range(1, r + 1)] for key in ("q", "qdot", "qddot")}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="rom")
    fmu.instantiate()
    fmu.setupExperiment(startTime=float(t[0]))
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    u = signal.sample(t)
    record = {key: [] for key in ("y", "q", "qdot", "qddot")}
    for i in range(t.size):
        fmu.setReal([refs["u"]], [float(u[0, max(i - 1, 0)])])
        if i > 0:
            fmu.doStep(t[i - 1], t[i] - t[i - 1])
        record["y"].append(fmu.getReal(outputs))
        for key, vrs in states.items():
            record[key].append(fmu.getReal(vrs))
    fmu.terminate()
    fmu.freeInstance()
    return {key: np.array(value).T for key, value in record.items()}


def relative_error(actual: np.ndarray, reference: np.ndarray) -> float:
    return float(np.abs(actual - reference).max() / np.abs(reference).max())


# ------------------------------------------------------------------------ the file

def test_exported_fmu_validates(exported):
    assert validate_fmu(str(exported[0])) == []


def test_binary_needs_no_python(exported):
    binary = exported[1] / "binaries" / "linux64" / "TripleChainROM.so"
    libraries = subprocess.run(["ldd", str(binary)], capture_output=True, text=True, check=True).stdout
    assert "python" not in libraries
    assert set(re.findall(r"^\s*(lib\S+)", libraries, flags=re.M)) <= {"libc.so.6", "libm.so.6"}


def test_model_description_keeps_names_and_provenance(exported, rom):
    md = read_model_description(str(exported[1]))
    inputs = [v.name for v in md.modelVariables if v.causality == "input"]
    outputs = [v.name for v in md.modelVariables if v.causality == "output"]
    assert inputs == ["u"] and outputs == ["y", "x[1]", "x[17]"]
    assert float(md.defaultExperiment.stepSize) == rom.dt
    for fact in ("r=6", "TripleChainMSD.fmu", "{1234-abcd}", TRAIN, "2026-11-21T05:00:00Z"):
        assert fact in md.description
    names = zipfile.ZipFile(exported[0]).namelist()
    for file in ("model.c", "fmi2Functions.c", "newmark.c", "provenance.json"):
        assert f"sources/{file}" in names


def test_exported_fmu_matches_rom_simulation(exported, rom):
    dt, t_end = rom.dt, 25.0
    expected = rom.simulate(TEST, dt, t_end)
    got = drive(exported[1], signals.parse_signal(TEST), expected.t, rom.r)
    assert relative_error(got["y"][:1], expected.y) < 1e-12
    for key in ("q", "qdot", "qddot"):
        assert relative_error(got[key], getattr(expected, key)) < 1e-12, key
    rows = rom.basis[[0, 16]]
    assert relative_error(got["y"][1:], rows @ expected.q) < 1e-12


def test_variable_step_matches_classical_newmark(exported, rom):
    steps = [0.1] * 10 + [0.05] * 10 + [0.3] * 5
    t = np.concatenate([[0.0], np.cumsum(steps)])
    signal = signals.parse_signal(TEST)
    u = signal.sample(t)
    stepper = newmark.NewmarkStepper(rom.Mr, rom.Dr, rom.Kr, rom.Br, steps[0])
    stepper.start(u[:, 0])
    expected = [stepper.x.copy()]
    for i, h in enumerate(steps, start=1):
        stepper.set_step(h)
        stepper.step(u[:, i - 1])
        expected.append(stepper.x.copy())
    got = drive(exported[1], signal, t, rom.r)
    assert relative_error(got["q"], np.array(expected).T) < 1e-12


C_IMPORTER = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env; (void)name; (void)category;
    fprintf(stderr, "[%d] %s\n", (int)status, message);
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(library, #name); if (!name) return 2;

int main(int argc, char *argv[]) {
    void *library;
    fmi2CallbackFunctions callbacks = { logger, calloc, free, NULL, NULL };
    fmi2ValueReference input = 1, outputs[3] = { 2, 3, 4 };
    fmi2Real u, y[3], t = 0.0, h = atof(argv[3]);
    fmi2Component c;
    int k;

    if (argc != 4 || !(library = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL))) return 1;
    LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
    LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep)
    LOAD(fmi2Terminate) LOAD(fmi2FreeInstance)

    c = fmi2Instantiate("c", fmi2CoSimulation, argv[2], "", &callbacks, fmi2False, fmi2False);
    if (!c || fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
        fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) return 3;
    for (k = 0; k < 100; k++) {
        if (scanf("%lf", &u) != 1 || fmi2SetReal(c, &input, 1, &u) != fmi2OK) return 4;
        if (fmi2DoStep(c, t, h, fmi2True) != fmi2OK) return 5;
        t += h;
        if (fmi2GetReal(c, outputs, 3, y) != fmi2OK) return 6;
        printf("%.17g %.17g %.17g\n", y[0], y[1], y[2]);
    }
    fmi2Terminate(c);
    fmi2FreeInstance(c);
    dlclose(library);
    return 0;
}
"""


def test_c_program_runs_exported_fmu(exported, rom, tmp_path):
    compiler = fmus.find_build_tools()[1]
    source = tmp_path / "importer.c"
    source.write_text(C_IMPORTER)
    program = tmp_path / "importer"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([compiler, "-std=c99", "-O1", "-I", str(headers), str(source), "-o", str(program),
                    "-ldl"], check=True, capture_output=True, text=True)
    expected = rom.simulate(TEST, rom.dt, 100 * rom.dt)
    inputs = "\n".join(repr(float(v)) for v in signals.parse_signal(TEST).sample(expected.t[:-1])[0])
    guid = read_model_description(str(exported[1])).guid
    binary = exported[1] / "binaries" / "linux64" / "TripleChainROM.so"
    result = subprocess.run([str(program), str(binary), guid, repr(rom.dt)], input=inputs,
                            capture_output=True, text=True, check=True)
    got = np.array([[float(v) for v in line.split()] for line in result.stdout.splitlines()]).T
    assert got.shape == (3, 100)
    reference = np.vstack([expected.y, rom.basis[[0, 16]] @ expected.q])[:, 1:]
    assert relative_error(got, reference) < 1e-12


# ---------------------------------------------------------------------- bad input

def test_missing_rom_file_is_a_clear_error(tmp_path):
    with pytest.raises(FileFormatError, match="does not exist"):
        export.export_fmu(tmp_path / "nothing.h5", tmp_path / "rom.fmu")


def test_corrupt_rom_file_is_a_clear_error(tmp_path):
    pytest.importorskip("fmu_opinf.rom")
    bad = tmp_path / "rom.h5"
    bad.write_bytes(b"this is not an HDF5 ROM file")
    with pytest.raises(FileFormatError):
        export.export_fmu(bad, tmp_path / "rom.fmu")
    assert not (tmp_path / "rom.fmu").exists()


def test_unwritable_output_path_is_a_clear_error(rom, tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("a file, not a folder")
    with pytest.raises(FMUError, match="cannot create the output folder"):
        export.export_fmu(rom, blocker / "sub" / "rom.fmu")
    with pytest.raises(FMUError, match="must end in .fmu"):
        export.export_fmu(rom, tmp_path / "rom.zip")


def test_existing_file_needs_overwrite(rom, tmp_path):
    target = tmp_path / "rom.fmu"
    target.write_bytes(b"old")
    with pytest.raises(FMUError, match="overwrite=True"):
        export.export_fmu(rom, target)
    export.export_fmu(rom, target, overwrite=True)
    assert validate_fmu(str(target)) == []


def test_unsupported_fmi_version(rom, tmp_path):
    with pytest.raises(FMUError, match="not supported"):
        export.export_fmu(rom, tmp_path / "rom.fmu", fmi_version="1.0")


@pytest.mark.parametrize("reconstruct, pattern", [(["x[0]"], "1 <= i <= 31"), (["x[99]"], "1 <= i <= 31"),
                                                  (["v[1]"], "x\\[i\\]"), (["x[2]", 2], "twice")])
def test_bad_reconstruct_is_a_clear_error(rom, tmp_path, reconstruct, pattern):
    with pytest.raises(DimensionError, match=pattern):
        export.export_fmu(rom, tmp_path / "rom.fmu", reconstruct=reconstruct)


def test_reconstruct_without_basis_is_an_error(rom, tmp_path):
    no_basis = StandInROM.__new__(StandInROM)
    no_basis.__dict__.update(rom.__dict__, basis=None)
    with pytest.raises(DimensionError, match="basis"):
        export.export_fmu(no_basis, tmp_path / "rom.fmu", reconstruct=["x[1]"])


@pytest.mark.parametrize("field, value, error, pattern", [
    ("Mr", -np.eye(6), DataError, "not positive definite"),
    ("Kr", np.full((6, 6), np.nan), DataError, "NaN"),
    ("Dr", np.triu(np.ones((6, 6))), DataError, "not symmetric"),
    ("Br", np.ones((5, 1)), DimensionError, "expected \\(6, 1\\)"),
])
def test_bad_matrices_are_clear_errors(rom, tmp_path, field, value, error, pattern):
    broken = StandInROM.__new__(StandInROM)
    broken.__dict__.update(rom.__dict__, **{field: value})
    with pytest.raises(error, match=pattern):
        export.export_fmu(broken, tmp_path / "rom.fmu")
    assert not (tmp_path / "rom.fmu").exists()


def test_without_compiler_writes_sources_and_warns(rom, tmp_path, monkeypatch):
    monkeypatch.setattr(export, "find_build_tools", lambda: None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        path = export.export_fmu(rom, tmp_path / "rom.fmu")
    assert any(issubclass(w.category, FmuOpinfWarning) and "still needs compiling" in str(w.message)
               for w in caught)
    names = zipfile.ZipFile(path).namelist()
    assert "sources/model.c" in names and not any(n.startswith("binaries/") for n in names)


def test_saved_second_order_rom_exports_and_matches(rom, tmp_path):
    """The project's SecondOrderROM, saved and exported from its file, matches its own simulate."""
    rom_module = pytest.importorskip("fmu_opinf.rom")
    real = rom_module.SecondOrderROM(
        rom.Mr, rom.Dr, rom.Kr, rom.Br, rom.Cpr, rom.Cvr, basis=rom.basis, basis_kind="velocities",
        input_names=["force"], output_names=["sum_x"], dt=rom.dt,
        provenance={"snapshots": {"source": "/data/TripleChainMSD.fmu", "fmu_guid": "{feed-beef}",
                                  "input_spec": TRAIN},
                    "fit_date": "2026-11-21T06:00:00+00:00"})
    saved = real.save(tmp_path / "rom.h5")
    path = export.export_fmu(saved, tmp_path / "Saved.fmu", reconstruct=["x[5]"])
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert [v.name for v in md.modelVariables if v.causality in ("input", "output")] == \
        ["force", "sum_x", "x[5]"]
    for fact in ("TripleChainMSD.fmu", "{feed-beef}", TRAIN, "2026-11-21T06:00:00+00:00", "r=6"):
        assert fact in md.description
    signal = "chirp:amplitude=2,omega0=0.1,omega1=2,duration=20"
    expected = real.simulate(signal, 0.05, 20.0)
    folder = Path(extract(str(path), str(tmp_path / "saved")))
    md_refs = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [md_refs["sum_x"], md_refs["x[5]"]]
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="saved")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    got = []
    for i, t in enumerate(expected.t):
        if i > 0:
            fmu.setReal([md_refs["force"]], [float(expected.u[0, i])])
            fmu.doStep(expected.t[i - 1], t - expected.t[i - 1])
        got.append(fmu.getReal(outputs))
    fmu.terminate()
    fmu.freeInstance()
    got = np.array(got).T
    assert relative_error(got[0], expected.y[0]) < 1e-12
    assert relative_error(got[1], rom.basis[4] @ expected.q) < 1e-12


def test_fmi3_export_validates_and_matches_rom_simulation(rom, tmp_path):
    from fmpy.fmi3 import FMU3Slave

    path = export.export_fmu(rom, tmp_path / "Rom3.fmu", fmi_version="3.0", reconstruct=["x[3]"])
    assert validate_fmu(str(path)) == []
    folder = Path(extract(str(path), str(tmp_path / "rom3")))
    libraries = subprocess.run(["ldd", str(folder / "binaries" / "x86_64-linux" / "Rom3.so")],
                               capture_output=True, text=True, check=True).stdout
    assert "python" not in libraries
    md = read_model_description(str(folder))
    assert md.fmiVersion == "3.0" and float(md.defaultExperiment.stepSize) == rom.dt
    refs = {v.name: v.valueReference for v in md.modelVariables}
    expected = rom.simulate(TEST, rom.dt, 15.0)
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=str(folder),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="rom3")
    fmu.instantiate()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    got = []
    for i, t in enumerate(expected.t):
        if i > 0:
            fmu.setFloat64([refs["u"]], [float(expected.u[0, i])])
            fmu.doStep(expected.t[i - 1], t - expected.t[i - 1])
        got.append(fmu.getFloat64([refs["y"], refs["x[3]"]]))
    fmu.terminate()
    fmu.freeInstance()
    got = np.array(got).T
    assert relative_error(got[0], expected.y[0]) < 1e-12
    assert relative_error(got[1], rom.basis[2] @ expected.q) < 1e-12


def test_rom_in_modal_coordinates_exports_reconstructed_positions_through_both_rows(rom, tmp_path):
    """A ROM kept as the mechanical realization (modal coordinates, ``coordinates = W``) reconstructs
    ``x_i = V[i] (W_qq q + W_qv q')``: the FMU's extra output against the POD-coordinate stand-in's ``V[i] q``
    simulated by the reference Newmark stepper (an independent path)."""
    from fmu_opinf._realization import mechanical_realization
    from fmu_opinf.rom import SecondOrderROM

    unit = np.linalg.solve(rom.Mr, np.hstack([rom.Dr, rom.Kr, rom.Br]))
    r = rom.r
    real = mechanical_realization(unit[:, :r], unit[:, r:2 * r], unit[:, 2 * r:], rom.Cpr, rom.Cvr)
    modal = SecondOrderROM(np.eye(r), np.diag(real.d), np.diag(real.k), real.B, real.Cp, real.Cv, basis=rom.basis,
                           basis_kind="velocities", input_names=["u"], output_names=["y"], dt=rom.dt,
                           coordinates=real.W)
    assert np.any(real.W[:r, r:])  # positions depend on the modal velocities too
    path = export.export_fmu(modal, tmp_path / "Modal.fmu", reconstruct=["x[5]"])
    t = np.arange(0, 201) * rom.dt
    got = drive(Path(extract(str(path), str(tmp_path / "modal"))), signals.parse_signal(TEST), t, r)
    expected = rom.simulate(TEST, rom.dt, t[-1])
    assert relative_error(got["y"][0], expected.y[0]) < 3e-13  # measured 3.2e-14
    assert relative_error(got["y"][1], rom.basis[4] @ expected.q) < 3e-13  # measured 3.1e-14


def test_full_model_fmu_given_as_the_rom_is_named_as_such(exported, tmp_path):
    from conftest import rewrite_description

    from fmu_opinf import compare

    other = rewrite_description(exported[0], tmp_path / "Plant.fmu",
                                lambda text: text.replace('generationTool="fmu-opinf"', 'generationTool="Dymola"'))
    with pytest.raises(FileFormatError, match="Plant.fmu is not a ROM FMU exported by fmu-opinf"):
        compare.compare(other, "builtin:triple-chain", "step", dt=0.5, t_end=2.0, quiet=True)


def test_source_variables_named_like_the_rom_states_get_other_state_names(rom, tmp_path):
    """Robot models call their joints ``q[i]``: a source output ``qdot[1]`` clashed with the ROM FMU's own
    ``qdot[1]`` and export refused it with a fix the user could not apply (fifth audit).  The states move to
    ``rom.q[*]`` etc., the outputs keep their names and values (against the ROM's own simulation), and compare
    finds the states of such an FMU through its provenance.json."""
    from fmpy import simulate_fmu

    from fmu_opinf.compare._sides import _rom_side_info
    from fmu_opinf.rom import SecondOrderROM

    real = SecondOrderROM(rom.Mr, rom.Dr, rom.Kr, rom.Br, np.vstack([rom.Cpr, rom.Cpr]),
                          np.vstack([rom.Cvr, rom.Cpr]), input_names=["q[1]"], output_names=["q[2]", "qdot[1]"],
                          dt=rom.dt)
    path = export.export_fmu(real, tmp_path / "Joints.fmu")
    assert validate_fmu(str(path)) == []
    names = {v.name for v in read_model_description(str(path)).modelVariables}
    assert {"q[1]", "q[2]", "qdot[1]", "rom.q[1]", "rom.qdot[6]", "rom.qddot[6]"} <= names
    assert "q[3]" not in names
    expected = real.simulate(TEST, rom.dt, 20.0)
    held = zip(expected.t[:-1], expected.u[0, 1:])  # u[i] is held over the step that ends at t[i]
    inputs = np.array(list(held), dtype=[("time", float), ("q[1]", float)])
    got = simulate_fmu(str(path), stop_time=20.0, output_interval=rom.dt, input=inputs, output=["q[2]", "qdot[1]"])
    for j, name in enumerate(["q[2]", "qdot[1]"]):
        assert relative_error(got[name], expected.y[j]) < 5e-14   # measured 1.4e-14, 1.7e-14
    info = _rom_side_info(path)
    assert info["r"] == rom.r and info["output_names"] == ["q[2]", "qdot[1]"]
    assert export.rom_state_names(["q[1]", "rom.qddot[2]"]) == ("rom2.q", "rom2.qdot", "rom2.qddot")
    assert export.rom_state_names(["y", "qq[1]"]) == ("q", "qdot", "qddot")


def test_reconstructed_positions_of_a_recorded_subset_keep_their_own_names():
    """Recorded positions x[2], x[4], ..., x[12] (every second mass): ``x[4]`` is the recorded x[4] (row 2), not
    row 4 (x[8]), and ``x[12]`` is accepted; ``x[3]`` was not recorded (eleventh audit: the output named x[4]
    showed x[8], 73 % off the true x[4], and x[12] was refused)."""
    rng = np.random.default_rng(3)
    basis, x_ref = rng.standard_normal((6, 3)), np.arange(6.0)
    own = [f"x[{2 * i}]" for i in range(1, 7)]
    rom = SimpleNamespace(basis=basis, x_ref=x_ref, coordinates=None,
                          provenance={"snapshots": {"position_names": own}})
    names, rows, _, offsets = export._reconstruction_rows(rom, ["x[4]", "x[12]", 3], 3)
    assert names == ["x[4]", "x[12]", "x[6]"]   # the number 3 is row 3, the source's x[6]
    np.testing.assert_array_equal(rows, basis[[1, 5, 2]])
    np.testing.assert_array_equal(offsets, x_ref[[1, 5, 2]])
    with pytest.raises(DimensionError, match=r"cannot reconstruct 'x\[3\]': it is not a recorded position "
                                             r"\(recorded: x\[2\], x\[4\], x\[6\], x\[8\], \.\.\.\)"):
        export._reconstruction_rows(rom, ["x[3]"], 3)
    with pytest.raises(DimensionError, match="twice"):
        export._reconstruction_rows(rom, ["x[4]", 2], 3)
    assert export._reconstruction_rows(rom, ["3"], 3)[0] == ["x[6]"]   # a number as the command line gives it


def test_a_serialized_state_is_refused_by_another_model_of_the_same_sizes(exported, rom, tmp_path):
    """Eleventh audit, F8: only the sizes were checked, so a state of another ROM FMU (same r, m) was accepted."""
    other = Path(extract(str(export.export_fmu(rom, tmp_path / "OtherROM.fmu")), str(tmp_path / "other")))

    def started(folder: Path) -> FMU2Slave:
        md = read_model_description(str(folder))
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="state")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        return fmu

    source = started(exported[1])
    source.setReal([1], [2.0])
    source.doStep(0.0, rom.dt)
    state = source.getFMUstate()
    blob = source.serializeFMUstate(state)
    source.freeFMUstate(state)
    same, foreign = started(exported[1]), started(other)
    try:
        restored = same.deSerializeFMUstate(blob)   # the same model takes it
        same.setFMUstate(restored)
        same.freeFMUstate(restored)
        with pytest.raises(Exception, match="fmi2DeSerializeFMUstate failed"):
            foreign.deSerializeFMUstate(blob)
    finally:
        for fmu in (source, same, foreign):
            fmu.freeInstance()


# ------------------------------------------------------------------------ the object cache

@pytest.mark.slow
def test_an_export_under_another_name_compiles_only_the_name(rom, tmp_path, monkeypatch, compiled):
    """Audit of 2026-12-06, F5: the name and GUID were in ``config.h``, which every unit includes, so an export under
    a new name compiled ``instance.c`` again and added a cache entry per name.  Now the second export compiles only
    the small unit holding them (never cached); both FMUs validate, keep their own identifier and GUID, and give
    bit-identical outputs that match the ROM's own simulation."""
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    objects = tmp_path / "cache" / "objects"
    first = export.export_fmu(rom, tmp_path / "RomOne.fmu")
    assert len(compiled) == 5 and len(list(objects.glob("*.o"))) == 4
    compiled.clear()
    second = export.export_fmu(rom, tmp_path / "RomTwo.fmu")
    assert compiled == ["4_fmu_identity.o"] and len(list(objects.glob("*.o"))) == 4
    expected = rom.simulate(TEST, rom.dt, 10.0)
    outputs, guids = [], []
    for path, name in ((first, "RomOne"), (second, "RomTwo")):
        assert validate_fmu(str(path)) == []
        folder = Path(extract(str(path), str(tmp_path / name)))
        md = read_model_description(str(folder))
        assert md.coSimulation.modelIdentifier == name and (folder / "binaries" / "linux64" / f"{name}.so").is_file()
        outputs.append(drive(folder, signals.parse_signal(TEST), expected.t, rom.r)["y"])
        guids.append((folder, md.guid))
    assert np.array_equal(outputs[0], outputs[1]) and relative_error(outputs[0], expected.y) < 1e-12
    (folder, _), (_, other_guid) = guids
    assert guids[0][1] != other_guid
    with pytest.raises(Exception, match="Failed to instantiate"):   # its own GUID: RomOne refuses RomTwo's
        FMU2Slave(guid=other_guid, unzipDirectory=str(folder), modelIdentifier="RomOne",
                  instanceName="x").instantiate()
