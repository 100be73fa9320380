"""The ROM FMU declares its source's Enumeration and Float32 parameters with their types (api84, item 2).

Before, a snapshot file did not record the source's Enumeration parameters, so the ROM FMU did not declare them and an
importer that set them on it, as on the source, failed ("could not be set"); an FMI 3 source's Float32 parameters were
declared Float64, so an importer's ``fmi3SetFloat32`` failed.  Now an Enumeration is recorded with its type's items and
declared fixed at its trained value with the source's type definition (FMI 2 ``SimpleType``/``Enumeration``, FMI 3
``EnumerationType``), served by FMI 2's Integer and FMI 3's Int64 functions; a Float32 is declared Float32 and accepts
the float of its trained value.  Another value is refused in one log line.  References: the source's model description
(types, items) and ``lti_fmus.zoh_response`` of the true model (outputs), never the code under test.
"""

from __future__ import annotations

import copy
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from fmu_opinf import export, lti_fmus, snapshots  # noqa: E402
from fmu_opinf.errors import FmuOpinfWarning  # noqa: E402
from fmu_opinf.fit import fit_rom  # noqa: E402
from fmu_opinf.source import open_source  # noqa: E402
from test_export_discrete_parameters import _miss  # noqa: E402  (the staircase run against the exact model)

DT = 0.02
TRAINING = "impulse:amplitude=100,t0=2,width=0.5;harmonic:amplitude=8,omega=1.3"
#: Bound on max |y - y_exact| / range(y_exact) of the ROM FMU of the source's order (measured 1.1e-13 .. 1.4e-13, as
#: for test_export_discrete_parameters' model)
EXACT = 1e-12
#: What the training set and an importer gives the ROM FMU: another item than the source's start (rk4 = 2), and on
#: FMI 3 another tolerance than its 1e-4
TRAINED = {"2.0": {"solverMethod": 3}, "3.0": {"solverMethod": 3, "relTol": 1e-3}}


def _model() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(inputs=(1, -1), force_offset=0.6, acceleration_outputs=(-1,), output_offset=0.1,
                                name="Typed", x0=[0.05, -0.02, 0.03, 0.0, 0.04], v0=[0.0, 0.1, 0.0, -0.05, 0.0])


def _parameters(path: Path) -> dict:
    return {v.name: v for v in read_model_description(str(path)).modelVariables if v.causality == "parameter"}


def _items(path: Path, name: str) -> list[tuple[str, int, str]]:
    """The items of the Enumeration type ``name`` as fmpy reads the model description."""
    kind = next(t for t in read_model_description(str(path)).typeDefinitions if t.name == name)
    return [(item.name, int(item.value), item.description or "") for item in kind.items]


@pytest.fixture(scope="module", params=["2.0", "3.0"])
def trained(request, tmp_path_factory) -> dict:
    """A source with an Enumeration (and, FMI 3, a Float32) parameter, trained at other values than its starts, and its
    ROM FMU of the same FMI version (a source FMU and a ROM FMU compiled: the tests using it are slow)."""
    version = request.param
    folder = tmp_path_factory.mktemp(f"typed{version[0]}")
    source = lti_fmus.build_lti_fmu(_model(), folder / "Typed.fmu", fmi_version=version, output_units=True,
                                    typed_parameters=True).path
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        recorded = snapshots.record(open_source(source, parameters=TRAINED[version]), TRAINING, dt=DT, t_end=40.0,
                                    quiet=True)
        rom = fit_rom(recorded)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FmuOpinfWarning)
        path = export.export_fmu(rom, folder / f"TypedRom{version[0]}.fmu", fmi_version=version)
    return {"version": version, "source": source, "rom": rom, "fmu": path, "folder": folder,
            "warnings": [str(w.message) for w in caught]}


@pytest.mark.slow
def test_enumeration_and_float32_parameters_are_declared_with_the_sources_types(trained):
    source, declared = _parameters(trained["source"]), _parameters(trained["fmu"])
    method = declared["solverMethod"]
    assert (method.type, method.variability, method.start) == ("Enumeration", "fixed", "3")   # (the source's: 2)
    assert method.declaredType.name == source["solverMethod"].declaredType.name == "Solvers.Method"
    assert _items(trained["fmu"], "Solvers.Method") == _items(trained["source"], "Solvers.Method")
    if trained["version"] == "3.0":
        assert (declared["relTol"].type, declared["relTol"].start) == ("Float32", "0.001")    # (was: Float64)
    assert validate_fmu(str(trained["fmu"])) == []
    assert not [text for text in trained["warnings"] if "solverMethod" in text or "relTol" in text]


@pytest.mark.slow
def test_an_importer_sets_the_trained_values_and_the_outputs_match_the_exact_model(trained):
    """fmpy sets the Enumeration by fmi2SetInteger / fmi3SetInt64 and the Float32 by fmi3SetFloat32 (its float of
    1e-3, 4.7e-11 off the double the ROM FMU was made for), as it set them on the source."""
    assert _miss(trained["fmu"], TRAINED[trained["version"]], _model()).max() < EXACT
    assert _miss(trained["fmu"], {}, _model()).max() < EXACT


def _refusals(path: Path, start_values: dict) -> list[str]:
    lines = []

    def logger(*args):   # FMI 2: (component, instance, status, category, message); FMI 3: (env, status, ...)
        message = args[-1]
        lines.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception, match="status 3"):
        simulate_fmu(str(path), stop_time=1.0, start_values=start_values, logger=logger)
    return [line for line in lines if "refused" in line]


@pytest.mark.slow
@pytest.mark.parametrize("name, value, text", [
    ("solverMethod", 2, "was 3 in training, the only value the model knows; 2 refused"),   # (the source's start)
    ("relTol", 2e-3, "was 0.001 in training, the only value the model knows; 0.00200000009 refused"),
])
def test_another_value_is_refused_in_one_line(trained, name, value, text):
    if name == "relTol" and trained["version"] == "2.0":
        pytest.skip("FMI 3 Float32")
    refusals = _refusals(trained["fmu"], {name: value})
    assert len(refusals) == 1 and text in refusals[0]
    assert refusals[0].endswith(f"--set {name}=VALUE or parameters['{name}']")


@pytest.mark.slow
def test_each_type_is_served_by_its_own_functions(trained):
    """get returns the trained values; the Enumeration by Integer (FMI 2) / Int64 (FMI 3) only, the Float32 by
    fmi3GetFloat32 only."""
    from fmpy import extract

    folder = extract(str(trained["fmu"]), unzipdir=str(trained["folder"] / "unzipped"))
    md = read_model_description(folder)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    if trained["version"] == "2.0":
        from fmpy.fmi2 import FMU2Slave as Slave
    else:
        from fmpy.fmi3 import FMU3Slave as Slave
    fmu = Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="typed")
    fmu.instantiate()
    try:
        if trained["version"] == "2.0":
            fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        if trained["version"] == "2.0":
            assert list(fmu.getInteger([refs["solverMethod"]])) == [3]
            with pytest.raises(Exception, match="status 3"):
                fmu.getReal([refs["solverMethod"]])
            return
        assert list(fmu.getInt64([refs["solverMethod"]])) == [3]
        assert list(fmu.getFloat32([refs["relTol"]])) == [np.float32(1e-3)]
        for get, name in ((fmu.getInt32, "solverMethod"), (fmu.getFloat64, "relTol"), (fmu.getFloat64,
                                                                                         "solverMethod")):
            with pytest.raises(Exception, match="status 3"):
                get([refs[name]])
    finally:
        fmu.freeInstance()


# ------------------------------------------------------------------------------ records the ROM FMU cannot declare

def _spec(rom, version: str, match: str):
    """The ROM FMU's spec, and the one warning ``match`` finds (the only one naming solverMethod)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FmuOpinfWarning)
        spec = export.rom_fmu_spec(rom, "Typed", fmi_version=version)
    named = [str(w.message) for w in caught if "solverMethod" in str(w.message)]
    assert len(named) == 1 and re.search(match, named[0]), named
    return spec


@pytest.mark.slow
def test_a_record_without_the_enumeration_type_exports_without_it(trained):
    """A record whose Enumeration has no recorded type (merged snapshot parts keep the shared rows only) or a value
    none of its items has: the ROM FMU exports without it and says so in one line, as for other parameters it cannot
    declare (not also as a start value of a state it does not declare, the line of settings it has no record of)."""
    rom = copy.deepcopy(trained["rom"])
    record = rom.provenance["snapshots"]["source_parameters"]
    record["enumerations"]["solverMethod"]["items"] = [["euler", 1, ""], ["rk4", 2, ""]]      # (3 is none of them)
    spec = _spec(rom, trained["version"], r"does not declare the source parameters solverMethod")
    assert "solverMethod" not in {par.name for par in spec.parameters} and spec.enumeration_types is None
    del record["enumerations"]
    spec = _spec(rom, trained["version"], r"does not declare the source parameters solverMethod")
    assert "solverMethod" not in {par.name for par in spec.parameters}


@pytest.mark.slow
def test_a_record_before_api84_exports_as_before(trained):
    """A ROM file of snapshots recorded before: no Enumeration rows, a Float32 one; on FMI 2 the Float32 is a
    Float64 (FMI 2 has no Float32).  The training's setting of the Enumeration is named as one the ROM FMU does not
    declare, as before."""
    rom = copy.deepcopy(trained["rom"])
    record = rom.provenance["snapshots"]["source_parameters"]
    keep = [i for i, kind in enumerate(record["types"]) if kind != "Enumeration"]
    for key in ("names", "types", "values", "units", "quantities"):
        record[key] = [record[key][i] for i in keep]
    del record["enumerations"]
    if trained["version"] == "2.0":
        record["types"].append("Float32"), record["names"].append("relTol"), record["values"].append(0.001)
        record["units"].append(""), record["quantities"].append("")
    spec = _spec(rom, trained["version"], r"the training set solverMethod \(--set or parameters=\), which the ROM FMU "
                                          "does not declare")
    kinds = {par.name: par.type for par in spec.parameters}
    assert kinds == {"mass_scale": "Float64", "stiffness_scale": "Float64",
                     "relTol": "Float32" if trained["version"] == "3.0" else "Float64"}


@pytest.mark.slow
def test_item_names_from_the_file_reach_the_xml_as_data(trained):
    """Items and type names are read from the source's file: quotes, markup and a format conversion are declared as
    they are (quoted XML; nothing of them reaches the C); a control character leaves the parameter out."""
    rom = copy.deepcopy(trained["rom"])
    hostile = ['e"<u>&amp;', "r]]>%s'", "d */ #include"]
    enumeration = rom.provenance["snapshots"]["source_parameters"]["enumerations"]["solverMethod"]
    enumeration["type"] = 'Solvers."Method"<x>'
    enumeration["items"] = [[name, value, f"{name} described"] for name, value in zip(hostile, (1, 2, 3))]
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        path = export.export_fmu(rom, trained["folder"] / "Hostile.fmu", fmi_version=trained["version"])
    assert _items(path, 'Solvers."Method"<x>') == [(name, value, f"{name} described")
                                                   for name, value in zip(hostile, (1, 2, 3))]
    assert validate_fmu(str(path)) == []
    enumeration["items"][0][0] = "euler\x1b[2J"
    spec = _spec(rom, trained["version"], r"does not declare the source parameters solverMethod")
    assert "solverMethod" not in {par.name for par in spec.parameters}
