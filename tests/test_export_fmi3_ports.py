"""The FMI 3 ROM FMU declares the source's input and output variables: arrays and Float32 (eighth audit, finding 7).

Each chain records an FMI 3 LTI FMU, fits the ROM and exports it.  The exported FMU is checked against the exact
response of the source's own matrices (``lti_fmus.zoh_response``) and against the Python ROM's simulation (an
independent implementation of the same step: the C kernel against numpy), both through the variables it declares.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from conftest import build_fmu_set, rewrite_description  # noqa: E402
from fmu_opinf.cli import main  # noqa: E402
from fmu_opinf.compare import simulate_outputs  # noqa: E402
from fmu_opinf.newmark import time_grid  # noqa: E402
from fmu_opinf.rom import SecondOrderROM  # noqa: E402
from fmu_opinf.signals import parse_signal  # noqa: E402

pytestmark = pytest.mark.fmu

DT, T_END = 0.05, 60.0
TEST = {1: "harmonic:amplitude=1,omega=2", 2: "harmonic:amplitude=1,omega=2;step:amplitude=0.5,t0=1"}


def single_precision(text: str) -> str:
    """The force input F and the output y[1] as Float32 variables (an FMI 3 exporter's single-precision signals)."""
    return re.sub(r'<Float64( name="(F|y\[1\])")', r"<Float32\1", text)


@pytest.fixture(scope="module")
def sources(request, tmp_path_factory):
    """``name -> (path, model)``: a two-force chain with input and output arrays, a chain with Float32 ports."""
    from fmu_opinf import lti_fmus

    edited = tmp_path_factory.mktemp("ports")
    items = {"array": (lti_fmus.chain_model(inputs=(1, -1), name="PortsArray"),
                       dict(fmi_version="3.0", input_array=True, output_array=True), None),
             "single": (lti_fmus.chain_model(name="PortsSingle"), dict(fmi_version="3.0"), single_precision)}

    def build(folder, item):
        name, (model, options, edit) = item
        built = lti_fmus.build_lti_fmu(model, folder / f"{name}.fmu", **options)
        path = rewrite_description(built.path, edited / f"{name}.fmu", edit) if edit else built.path
        return name, (path, model)

    return build_fmu_set(request, tmp_path_factory, "export-ports", build, items.items())


@pytest.fixture(scope="module")
def array_rom(sources, tmp_path_factory):
    return exported(sources, "array", tmp_path_factory.mktemp("array-rom"))


def exported(sources, name: str, tmp_path, *snapshot_args: str) -> tuple[SecondOrderROM, dict]:
    """ROM of source ``name`` and its FMI 3 and FMI 2 exports."""
    fmu = sources[name][0]
    train, rom_file = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu), "-o", str(train), "-q", "--dt", str(DT), "--t-end", str(T_END),
                 *snapshot_args]) == 0
    assert main(["fit", str(train), "-o", str(rom_file), "-q"]) == 0
    paths = {}
    for version in ("3.0", "2.0"):
        paths[version] = tmp_path / f"Rom{version[0]}.fmu"
        assert main(["export", str(rom_file), "-o", str(paths[version]), "--fmi-version", version, "-q"]) == 0
    return SecondOrderROM.load(rom_file), paths


def ports(path) -> list[tuple]:
    """``(name, type, shape)`` of the inputs and outputs an FMU declares, after fmpy's strict validation."""
    md = read_model_description(str(path), validate=True)
    return [(v.name, v.type, [int(d.start) for d in v.dimensions]) for v in md.modelVariables
            if v.causality in ("input", "output")]


def outputs_through_fmu(path, rom: SecondOrderROM) -> tuple[np.ndarray, np.ndarray]:
    """Outputs of the FMU at ``path`` under the test input, driven through the variables it declares, and
    the time grid."""
    t = time_grid(float(rom.dt), 400 * float(rom.dt))
    y, *_ = simulate_outputs(path, parse_signal(TEST[rom.m], rom.m), t)
    return y, t


def exact(model, rom: SecondOrderROM, t: np.ndarray) -> np.ndarray:
    from fmu_opinf.lti_fmus import zoh_response

    return zoh_response(model, t, parse_signal(TEST[rom.m], rom.m).sample(t)).y


def relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def initialized(folder, md, log: list) -> FMU3Slave:
    """An instance of the unpacked FMU after initialization, logging into ``log``."""
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="ports")
    fmu.instantiate(loggingOn=True, logMessage=lambda *args: log.append(args[-1].decode()))
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    return fmu


def test_array_ports_of_the_source_are_array_ports_of_the_rom_fmu(sources, array_rom):
    rom, paths = array_rom
    assert ports(paths["3.0"]) == [("F", "Float64", [2]), ("y", "Float64", [2])]
    assert ports(paths["2.0"]) == [("F[1]", "Real", []), ("F[2]", "Real", []), ("y[1]", "Real", []),
                                   ("y[2]", "Real", [])]   # FMI 2 has no arrays: the element names
    assert validate_fmu(str(paths["3.0"])) == []
    y3, t = outputs_through_fmu(paths["3.0"], rom)
    y_rom = rom.simulate(TEST[rom.m], float(rom.dt), t[-1]).y[:, :len(t)]
    assert relative(y3, y_rom) < 2e-14                        # measured 4.1e-15
    assert relative(y3, exact(sources["array"][1], rom, t)) < 4e-14   # a full-order ROM (r = n = 5): 8.7e-15
    y2, _ = outputs_through_fmu(paths["2.0"], rom)
    assert relative(y3, y2) < 1e-15   # the same kernel behind both interfaces: measured 0


@pytest.mark.slow  # 6 s on the 2-core machine of 2026-11-28
def test_float32_ports_of_the_source_are_float32_ports_of_the_rom_fmu(sources, tmp_path):
    rom, paths = exported(sources, "single", tmp_path)
    assert ports(paths["3.0"]) == [("F", "Float32", []), ("y[1]", "Float32", []), ("y[2]", "Float64", [])]
    y3, t = outputs_through_fmu(paths["3.0"], rom)
    y_rom = rom.simulate(TEST[rom.m], float(rom.dt), t[-1]).y[:, :len(t)]
    assert relative(y3[1], y_rom[1]) < 3e-8     # the Float64 output; its input came as a Float32 (1.3e-8)
    assert relative(y3[0], y3[0].astype(np.float32)) == 0.0   # the Float32 output holds single-precision values
    assert 1e-9 < relative(y3[0], y_rom[0]) < 1e-7   # measured 4.3e-8
    null_values_are_an_error(paths["3.0"], tmp_path)


def null_values_are_an_error(path, tmp_path) -> None:
    """fmi3GetFloat32 / fmi3SetFloat32 with a NULL values array log an error (they crashed: review of
    2026-11-28, under AddressSanitizer)."""
    import ctypes

    folder = extract(str(path), str(tmp_path / "single3"))
    md = read_model_description(folder)
    vr = (ctypes.c_uint32 * 1)(next(v.valueReference for v in md.modelVariables if v.name == "F"))
    log = []
    for function in ("fmi3GetFloat32", "fmi3SetFloat32"):
        fmu = initialized(folder, md, log)
        with pytest.raises(Exception, match="status 3"):
            getattr(fmu, function)(fmu.component, vr, 1, None, 1)
        assert log[-1] == f"{function}: values is NULL"
        fmu.freeInstance()


def test_array_value_references_take_their_whole_size_and_the_declared_type(array_rom, tmp_path):
    """fmi3GetFloat64 of an array takes all its values; a count that does not fit is an error the FMU logs."""
    rom, paths = array_rom
    folder = extract(str(paths["3.0"]), str(tmp_path / "rom3"))
    md = read_model_description(folder)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    log = []
    fmu = initialized(folder, md, log)
    fmu.setFloat64([refs["F"]], [1.0, -2.0])
    assert fmu.getFloat64([refs["F"]], nValues=2) == [1.0, -2.0]
    fmu.doStep(0.0, float(rom.dt))
    both = fmu.getFloat64([refs["y"], refs["F"]], nValues=4)
    assert both[2:] == [1.0, -2.0] and both[:2] == fmu.getFloat64([refs["y"]], nValues=2)
    with pytest.raises(Exception, match="status 3"):
        fmu.getFloat64([refs["y"]], nValues=1)
    assert "1 values for value references that hold 2" in log[-1]
    fmu.freeInstance()
    for set_, vr in ((False, refs["y"] + 1), (True, refs["F"] + 1)):   # an element's own value reference
        fmu = initialized(folder, md, log)
        with pytest.raises(Exception, match="status 3"):
            fmu.setFloat64([vr], [5.0]) if set_ else fmu.getFloat64([vr])
        assert f"value reference {vr} is not declared" in log[-1]
        fmu.freeInstance()


@pytest.mark.parametrize("ports", [
    [{"name": "F", "shape": [10 ** 9] * 60_000, "type": "Float64"}],   # a product of 9e5 digits, not formed
    [{"name": "F", "shape": [2.0], "type": "Float64"}], [{"name": "F", "shape": [True, True], "type": "Float64"}],
    [{"name": "F", "shape": [2], "type": "Int32"}], [{"name": "F", "shape": [3], "type": "Float64"}],
    [{"name": "G", "shape": [2], "type": "Float64"}], "F", [["F", [2]]]])
def test_recorded_ports_that_do_not_fit_the_rom_give_scalars(ports):
    """Ports come from a data file: anything but ports that expand to exactly the ROM's names is ignored (the FMU
    then declares Float64 scalars), in bounded time."""
    import time

    from fmu_opinf.export import _recorded_ports

    provenance = {"snapshots": {"fmi3_ports": {"inputs": ports}}}
    start = time.perf_counter()
    assert _recorded_ports(provenance, "inputs", ["F[1]", "F[2]"]) is None
    assert time.perf_counter() - start < 0.1
    good = {"snapshots": {"fmi3_ports": {"inputs": [{"name": "F", "shape": [2], "type": "Float32"}]}}}
    assert _recorded_ports(good, "inputs", ["F[1]", "F[2]"]) == [{"name": "F", "shape": [2], "type": "Float32"}]


@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28
def test_part_of_an_array_is_exported_as_scalar_ports(sources, tmp_path):
    """Only F[2] driven (F[1] held): the ROM FMU's inputs are the scalars F[1] (held at its start, audit 69 F4) and
    F[2], in the source's order; the outputs stay an array."""
    rom, paths = exported(sources, "array", tmp_path, "--inputs", "F[2]")
    assert rom.input_names == ["F[2]"]
    assert ports(paths["3.0"]) == [("F[1]", "Float64", []), ("F[2]", "Float64", []), ("y", "Float64", [2])]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_master_keeps_the_step_of_an_exact_step_map(array_rom, version):
    """A ROM of a continuous-time source steps by multiples of its exact step map only, and says so
    (``canHandleVariableCommunicationStepSize="false"``, FMI 3 ``fixedInternalStepSize``): fmpy then keeps its
    step at an input event between grid points and at a stop time off the grid (eleventh audit, F7: it shortened
    those steps and the FMU's refusal ended the simulation with an error)."""
    rom, paths = array_rom
    assert rom.integrator == "exact"
    md = read_model_description(str(paths[version]))
    assert md.coSimulation.canHandleVariableCommunicationStepSize is False
    if version == "3.0":
        assert float(md.coSimulation.fixedInternalStepSize) == float(rom.dt)
    dt = float(rom.dt)
    event = 10.5 * dt   # a force step between two grid points
    rows = [(0.0, 0.0, 0.0), (event, 0.0, 0.0), (event, 1.0, -0.5), (1.0, 1.0, -0.5)]
    if version == "3.0":   # the array input F as one field of two values
        signals = np.array([(t, (a, b)) for t, a, b in rows], dtype=[("time", float), ("F", float, (2,))])
    else:
        signals = np.array(rows, dtype=[("time", float), ("F[1]", float), ("F[2]", float)])
    result = fmpy.simulate_fmu(str(paths[version]), stop_time=40.5 * dt, output_interval=dt, input=signals)
    assert np.isclose(result["time"][-1], 40 * dt)   # the last whole step: not shortened to the stop time
    y = np.asarray(result["y"]).T if version == "3.0" else np.vstack([result["y[1]"], result["y[2]"]])
    # the reference: the ROM under the step held from the first grid point after the event (as fmpy applies it)
    expected = rom.simulate(f"step:amplitude=1,t0={11 * dt - dt / 2};step:amplitude=-0.5,t0={11 * dt - dt / 2}",
                            dt, 40 * dt).y
    assert relative(y, expected) < 2e-14   # measured 4.9e-15
