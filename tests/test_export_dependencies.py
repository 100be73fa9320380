"""The ROM FMU's ``ModelStructure`` declares which inputs each output depends on (audit 69 F5).

FMI 2.0 and 3.0 read an output without ``dependencies`` as depending on every input, so a master that looks for
algebraic loops sees loops that are not there.  The reference is the true model's feedthrough (an acceleration
sensor on a mass with a force input), not the ROM's fitted ``Dur``, whose round-off entries are never exactly zero;
the training data are the exact zero-order-hold solution of the full model (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402
from fmpy.fmi3 import FMU3Slave  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_opinf import export, fmus  # noqa: E402
from fmu_opinf.errors import FMUError  # noqa: E402
from fmu_opinf.lti_fmus import chain_model, zoh_response  # noqa: E402
from fmu_opinf.newmark import applied_inputs, time_grid  # noqa: E402
from fmu_opinf.fit import fit_rom  # noqa: E402
from fmu_opinf.signals import parse_signal  # noqa: E402

DT = 0.02
PULSE = "impulse:amplitude=20,t0=1,width=0.3"


def _run(model, spec: str, t_end: float) -> SimpleNamespace:
    """One training run of the exact solution, in the snapshot column convention (u[:, i] = u(t_{i-1}))."""
    t = time_grid(DT, t_end)
    signal = parse_signal(spec, model.m)
    exact = zoh_response(model, t, signal.sample(t))
    return SimpleNamespace(t=t, u=applied_inputs(signal, t), x=exact.x, xdot=exact.v, xddot=exact.a, y=exact.y,
                           x0=exact.x[:, 0], v0=exact.v[:, 0])


@pytest.fixture(scope="module")
def model():
    """Four masses, forces on the first and the last, outputs: last position, first velocity, last acceleration
    (the only output with a feedthrough, from the second input)."""
    return chain_model(4, inputs=(0, -1), force_offset=0.7, x0=[0.05, -0.02, 0.03, 0.0],
                       v0=[0.0, 0.1, 0.0, -0.05], acceleration_outputs=(-1,), output_offset=0.1)


@pytest.fixture(scope="module")
def rom(model):
    runs = [_run(model, f"{PULSE};none", 30.0), _run(model, f"none;{PULSE}", 30.0)]
    fitted = fit_rom(runs, r=4, integrator="exact")
    fitted.input_names, fitted.output_names = ["F[1]", "F[2]"], ["pos", "vel", "acc"]
    return fitted


def _true_dependencies(model, inputs: list[str], outputs: list[str]) -> dict[str, set[str]]:
    """Output name -> the inputs it depends on directly, from the full model's feedthrough ``Ca M^-1 B``."""
    D = model.feedthrough
    return {name: {inputs[j] for j in range(D.shape[1]) if D[i, j] != 0} for i, name in enumerate(outputs)}


def _declared(xml: str) -> dict[str, dict[str, tuple[set[str], list[str]] | None]]:
    """``{"Outputs": {output: (inputs, kinds)}, "InitialUnknowns": ...}`` as the XML declares them (None: no
    ``dependencies`` attribute), read with the standard library, not the code under test."""
    root = ET.fromstring(xml)
    variables = list(root.find("ModelVariables"))
    structure = root.find("ModelStructure")
    if root.get("fmiVersion") == "2.0":
        name_of = {str(i): v.get("name") for i, v in enumerate(variables, start=1)}
        groups = {group: list(structure.find(group)) for group in ("Outputs", "InitialUnknowns")}
        key = "index"
    else:
        name_of = {v.get("valueReference"): v.get("name") for v in variables}
        groups = {"Outputs": structure.findall("Output"), "InitialUnknowns": structure.findall("InitialUnknown")}
        key = "valueReference"
    declared = {}
    for group, unknowns in groups.items():
        declared[group] = {}
        for unknown in unknowns:
            listed = unknown.get("dependencies")
            kinds = (unknown.get("dependenciesKind") or "").split()
            declared[group][name_of[unknown.get(key)]] = (None if listed is None else
                                                          ({name_of[k] for k in listed.split()}, kinds))
    return declared


@pytest.fixture(scope="module", params=["2.0", "3.0"])
def exported(request, rom, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp(f"deps{request.param[0]}") / "ChainROM.fmu"
    return export.export_fmu(rom, path, fmi_version=request.param, reconstruct=["x[1]"])


def test_outputs_declare_the_true_models_feedthrough(exported, model, rom):
    """Only ``acc`` depends on ``F[2]``; the other outputs and the reconstructed position on no input (before
    audit 69: no ``dependencies`` attribute at all, every output on every input); ``Dur`` itself has round-off
    of 1e-16 .. 1e-15 where the true feedthrough is zero."""
    assert np.count_nonzero(rom.Dur) > 1      # the round-off is there: an exact != 0 would declare it
    declared = _declared(zipfile.ZipFile(exported).read("modelDescription.xml").decode())
    expected = _true_dependencies(model, rom.input_names, rom.output_names) | {"x[1]": set()}
    assert expected["acc"] == {"F[2]"}
    for group in ("Outputs", "InitialUnknowns"):
        assert {name: entry[0] for name, entry in declared[group].items()} == expected
        assert all(kinds == ["constant"] * len(inputs) for inputs, kinds in declared[group].values())
    assert validate_fmu(str(exported)) == []


def _started(folder: str):
    """The extracted FMU instantiated, initialized and stepped once; its ``set`` and ``get`` of Float64 values."""
    md = read_model_description(folder)
    kind = FMU2Slave if md.fmiVersion == "2.0" else FMU3Slave
    fmu = kind(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
               instanceName="deps")
    fmu.instantiate()
    if md.fmiVersion == "2.0":
        fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(0.0, DT)
    if md.fmiVersion == "2.0":
        return md, fmu, fmu.setReal, fmu.getReal
    return md, fmu, fmu.setFloat64, fmu.getFloat64


def test_an_output_declared_independent_does_not_move_with_the_inputs(exported, model):
    """What the FMU computes matches what it declares: setting the inputs before a step changes only ``acc``, by
    the true feedthrough times the change (the others exactly not at all)."""
    md, fmu, set_values, get_values = _started(extract(str(exported)))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [refs[name] for name in ("pos", "vel", "acc", "x[1]")]
    before = np.array(get_values(outputs))
    change = np.array([3.0, -2.0])
    set_values([refs["F[1]"], refs["F[2]"]], list(change))
    after = np.array(get_values(outputs))
    fmu.terminate()
    fmu.freeInstance()
    assert after[[0, 1, 3]].tolist() == before[[0, 1, 3]].tolist()
    expected = model.feedthrough[2] @ change      # 0.833 * (-2)
    assert abs(after[2] - before[2] - expected) <= 1e-12 * abs(expected)


def test_fmi3_array_variables_depend_on_input_arrays(rom):
    """FMI 3 with the source's arrays: ``F`` (2 values) and outputs ``y`` (pos, vel) and the scalar ``acc``:
    ``acc`` depends on the array ``F`` (one of its elements), ``y`` on nothing (providesPerElementDependencies is
    false, so a dependence names whole variables)."""
    ported = copy.copy(rom)
    ported.input_names, ported.output_names = ["F[1]", "F[2]"], ["y[1]", "y[2]", "acc"]
    provenance = copy.deepcopy(rom.provenance)
    provenance.setdefault("snapshots", {})["fmi3_ports"] = {
        "inputs": [{"name": "F", "shape": [2], "type": "Float64"}],
        "outputs": [{"name": "y", "shape": [2], "type": "Float64"}, {"name": "acc", "shape": [], "type": "Float32"}]}
    ported.provenance = provenance
    spec = export.rom_fmu_spec(ported, "Ported", fmi_version="3.0")
    declared = _declared(fmus._model_description3(spec, "{0}"))
    assert declared["Outputs"] == {"y": (set(), []), "acc": ({"F"}, ["constant"])}


def test_without_recorded_scales_every_nonzero_entry_is_a_dependence(rom):
    """A ROM without its training scales (built by hand, an older file) declares each non-zero ``Dur`` entry:
    a dependence too many is safe, one too few is not."""
    Dur = np.array([[0.0, 1e-17], [0.0, 0.0], [0.0, 0.83]])
    assert export._feedthrough_pattern(Dur, {}, {}).tolist() == [[False, True], [False, False], [False, True]]
    scaled = export._feedthrough_pattern(Dur, rom.provenance, rom.fit_info)
    assert scaled.tolist() == [[False, False], [False, False], [False, True]]


def test_initial_dependencies_are_not_declared_with_parameters():
    """FMI counts parameters among the knowns at initialization: an FMU with parameters declares no initial
    dependencies (each initial unknown then depends on all knowns), its outputs' still."""
    spec = fmus.anchored_msd_spec(g=3)
    spec = fmus.SecondOrderFmuSpec(**{**spec.__dict__, "output_dependencies": [[]] * spec.p,
                                      "initial_dependencies": [[]] * spec.p})
    assert spec.parameters
    declared = _declared(fmus._model_description(spec, "{0}", []))
    assert all(entry == (set(), []) for entry in declared["Outputs"].values())
    assert all(entry is None for entry in declared["InitialUnknowns"].values())


@pytest.mark.parametrize("dependencies", [[[0]], [[-1], []], [[1], [1]], [[0, 0], []], [["u"], []], [[True], []]])
def test_bad_dependencies_are_refused(dependencies):
    with pytest.raises(FMUError, match="output_dependencies") as error:
        fmus.SecondOrderFmuSpec("Bad", "", n=1, m=1, p=2, output_dependencies=dependencies)
    assert "\n" not in str(error.value)
