"""The ROM FMU declares its source's integer and Boolean parameters, fixed at their training values (fix82a, item 1).

Before, the snapshots recorded them but the ROM FMU left them out with a warning, so an importer that set them on the
ROM FMU (at the value it gives the source) failed: "The start values for the following variables could not be set".
Now each is declared with its type (FMI 2 ``Integer`` / ``Boolean``, FMI 3 ``Int8`` .. ``UInt64`` / ``Boolean``) at its
trained value, the FMU accepts that value, refuses another in one log line and returns it.  References: the source FMU
run under the same fmpy settings and ``lti_fmus.zoh_response`` of the true model, not the code under test.
"""

from __future__ import annotations

import copy
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

pytestmark = pytest.mark.slow   # two source FMUs and four ROM FMUs compiled

DT = 0.02
START = {"x0": [0.05, -0.02, 0.03, 0.0, 0.04], "v0": [0.0, 0.1, 0.0, -0.05, 0.0]}
TRAINING = "impulse:amplitude=100,t0=2,width=0.5;harmonic:amplitude=8,omega=1.3"
#: Bounds on max |y - y_exact| / range(y_exact): the ROM FMU of the source's order (measured 1.1e-13 .. 1.4e-13) and
#: the source itself (its RK4 substeps; measured 3.4e-9 .. 1.9e-7)
EXACT = 1e-12
SOURCE = 1e-6
#: What an importer gives both FMUs: the trained values (solverOrder set to 3 in training, useCache left at true)
TRAINED = {"solverOrder": 3, "useCache": True}


def _model() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(inputs=(1, -1), force_offset=0.6, acceleration_outputs=(-1,), output_offset=0.1,
                                name="Disc", **START)


@pytest.fixture(scope="module", params=["2.0", "3.0"])
def trained(request, tmp_path_factory) -> dict:
    """A source with an Integer (FMI 3: Int32) and a Boolean parameter, trained with ``--set solverOrder=3``, and its
    ROM FMU of the same FMI version."""
    version = request.param
    folder = tmp_path_factory.mktemp(f"discrete{version[0]}")
    source = lti_fmus.build_lti_fmu(_model(), folder / "Disc.fmu", fmi_version=version, output_units=True,
                                    discrete_parameters=True).path
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        recorded = snapshots.record(open_source(source, parameters={"solverOrder": 3}), TRAINING, dt=DT,
                                    t_end=40.0, quiet=True)
        rom = fit_rom(recorded)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FmuOpinfWarning)
        path = export.export_fmu(rom, folder / f"DiscRom{version[0]}.fmu", fmi_version=version)
    return {"version": version, "source": source, "rom": rom, "fmu": path, "folder": folder,
            "warnings": [str(w.message) for w in caught]}


def _staircase(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The inputs as fmpy's input table holding each value over its step (duplicate time points)."""
    rows = []
    for i in range(len(t) - 1):
        rows += [(t[i], *u[:, i]), (t[i + 1], *u[:, i])]
    return np.array(rows, dtype=[("time", float), ("F[1]", float), ("F[2]", float)])


def _miss(path: Path, start_values: dict, model: lti_fmus.LinearMechanicalModel | None = None) -> np.ndarray:
    """max |y - y_exact| / range(y_exact) per output over 20 s of a staircase input, ``model`` the exact one
    (default: this module's chain)."""
    t = np.arange(0.0, 20.0 + DT / 2, DT)
    u = np.vstack([np.sin(0.8 * t), 2 * np.cos(0.5 * t)])
    result = simulate_fmu(str(path), stop_time=20.0, output_interval=DT, input=_staircase(t, u),
                          start_values=start_values)
    exact = lti_fmus.zoh_response(model or _model(), t, u).y
    y = np.vstack([result[name] for name in ("y[1]", "y[2]", "y[3]")])
    return np.abs(y - exact).max(axis=1) / np.ptp(exact, axis=1)


def test_integer_and_boolean_parameters_are_declared_with_their_types(trained):
    source = {v.name: v for v in read_model_description(str(trained["source"])).modelVariables}
    declared = {v.name: v for v in read_model_description(str(trained["fmu"])).modelVariables
                if v.causality == "parameter"}
    assert set(declared) == {"mass_scale", "stiffness_scale", "solverOrder", "useCache"}
    for name in ("solverOrder", "useCache"):
        assert declared[name].type == source[name].type    # Integer / Int32, Boolean
        assert declared[name].variability == "fixed"
    assert declared["solverOrder"].start == "3"            # the --set value, not the source's 4
    assert declared["useCache"].start == "true"
    assert validate_fmu(str(trained["fmu"])) == []
    assert not [text for text in trained["warnings"] if "solverOrder" in text]   # (was: "does not declare")


def test_the_trained_values_set_on_both_fmus_run_and_match_the_exact_model(trained):
    assert _miss(trained["source"], TRAINED).max() < SOURCE
    assert _miss(trained["fmu"], TRAINED).max() < EXACT
    assert _miss(trained["fmu"], {}).max() < EXACT


@pytest.mark.parametrize("name, value, trained_text, given_text", [
    ("solverOrder", 4, "was 3 in training", "4 refused"),     # (the source's default)
    ("useCache", False, "was true in training", "false refused"),
])
def test_another_value_is_refused_in_one_line(trained, name, value, trained_text, given_text):
    lines = []

    def logger(*args):   # FMI 2: (component, instance, status, category, message); FMI 3: (env, status, ...)
        message = args[-1]
        lines.append(message.decode() if isinstance(message, bytes) else str(message))

    assert _miss(trained["source"], {name: value}).max() < SOURCE   # (the source takes it: no effect on its model)
    with pytest.raises(Exception, match="status 3"):
        simulate_fmu(str(trained["fmu"]), stop_time=1.0, start_values={name: value}, logger=logger)
    refusals = [line for line in lines if name in line]
    assert len(refusals) == 1
    assert trained_text in refusals[0] and given_text in refusals[0] and f"--set {name}=VALUE" in refusals[0]


def test_the_fmu_returns_the_values_and_keeps_each_type_to_its_own_functions(trained):
    """get returns the trained value; a real function on an integer parameter (and the reverse) is refused."""
    from fmpy import extract

    folder = extract(str(trained["fmu"]), unzipdir=str(trained["folder"] / "unzipped"))
    md = read_model_description(folder)
    refs = {v.name: v.valueReference for v in md.modelVariables}
    if trained["version"] == "2.0":
        from fmpy.fmi2 import FMU2Slave

        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="typed")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        get_int, get_real = fmu.getInteger, fmu.getReal
    else:
        from fmpy.fmi3 import FMU3Slave

        fmu = FMU3Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="typed")
        fmu.instantiate()
        get_int, get_real = fmu.getInt32, fmu.getFloat64
    try:
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        assert list(get_int([refs["solverOrder"]])) == [3]
        assert list(fmu.getBoolean([refs["useCache"]])) == [True]
        assert list(get_real([refs["stiffness_scale"]])) == [1.0]
        with pytest.raises(Exception, match="status 3"):
            get_real([refs["solverOrder"]])
    finally:
        fmu.freeInstance()


# ------------------------------------------------------------------- every FMI 3 integer type, and their limits

def _with_parameters(rom, rows: list[tuple[str, str, float]]):
    """The ROM with further recorded source parameters ``(name, type, value)``."""
    rom = copy.deepcopy(rom)
    record = rom.provenance["snapshots"]["source_parameters"]
    for name, kind, value in rows:
        for key, item in (("names", name), ("types", kind), ("values", value), ("units", ""), ("quantities", "")):
            record[key].append(item)
    return rom


_ROWS = [("i8", "Int8", -5.0), ("u16", "UInt16", 65535.0), ("i64", "Int64", 2.0**40), ("u64", "UInt64", 7.0),
         ("huge", "Int64", 2.0**60), ("half", "Int32", 2.5)]


def test_fmi3_integer_types_are_kept_and_values_they_cannot_hold_left_out(trained):
    if trained["version"] != "3.0":
        pytest.skip("FMI 3 types")
    rom = _with_parameters(trained["rom"], _ROWS)
    with pytest.warns(FmuOpinfWarning, match=r"does not declare the source parameters huge, half"):
        path = export.export_fmu(rom, trained["folder"] / "Types3.fmu", fmi_version="3.0")
    declared = {v.name: v for v in read_model_description(str(path)).modelVariables}
    assert [(declared[n].type, declared[n].start) for n in ("i8", "u16", "i64", "u64")] == [
        ("Int8", "-5"), ("UInt16", "65535"), ("Int64", str(2**40)), ("UInt64", "7")]
    assert "huge" not in declared and "half" not in declared   # (beyond 2**53; not a whole number)
    assert validate_fmu(str(path)) == []
    trained_values = {"i8": -5, "u16": 65535, "i64": 2**40, "u64": 7, **TRAINED}
    assert _miss(path, trained_values).max() < EXACT
    for name, other in (("i8", -4), ("u16", 0), ("i64", 2**40 + 1), ("u64", 8)):
        with pytest.raises(Exception, match="status 3"):
            simulate_fmu(str(path), stop_time=0.1, start_values={name: other})


def test_fmi2_declares_integers_that_fit_its_32_bits(trained):
    if trained["version"] != "2.0":
        pytest.skip("FMI 2 Integer")
    rom = _with_parameters(trained["rom"], _ROWS)
    with pytest.warns(FmuOpinfWarning, match=r"does not declare the source parameters i64, huge, half"):
        spec = export.rom_fmu_spec(rom, "Types2", fmi_version="2.0")
    kinds = {par.name: (par.type, par.default) for par in spec.parameters}
    assert kinds["i8"] == ("Int32", -5.0) and kinds["u16"] == ("Int32", 65535.0) and kinds["u64"] == ("Int32", 7.0)
    assert kinds["useCache"] == ("Boolean", 1.0) and kinds["stiffness_scale"] == ("Float64", 1.0)


# ------------------------------------------------------------------------------ provenance.json (fix82a, item 4)

def _bundled(path: Path) -> dict:
    import json
    import zipfile

    with zipfile.ZipFile(path) as archive:
        return json.loads(archive.read("sources/provenance.json"))


def test_provenance_json_summarizes_the_source_parameters_and_keeps_the_rest(trained):
    import hashlib
    import json

    from fmu_opinf.compare._declared import _bundled_provenance, _is_rom_fmu

    bundled = _bundled(trained["fmu"])
    record = trained["rom"].provenance["snapshots"]["source_parameters"]
    digest = hashlib.sha256(json.dumps(record, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    assert bundled["snapshots"]["source_parameters"] == {"count": 4, "set": {"solverOrder": 3.0}, "sha256": digest}
    original = json.loads(json.dumps(trained["rom"].provenance, default=str))
    for key in ("fit_date", "training_runs", "t_train_end"):   # (what compare reads, as before)
        assert bundled.get(key) == original.get(key)
    kept = {k: v for k, v in bundled["snapshots"].items() if k != "source_parameters"}
    assert kept == {k: v for k, v in original["snapshots"].items() if k != "source_parameters"}
    assert _is_rom_fmu(trained["fmu"]) and _bundled_provenance(trained["fmu"])["rom_fmu_states"] == ["q", "qdot",
                                                                                                     "qddot"]


def test_provenance_json_of_60000_parameters_is_small(trained):
    """5,964,819 bytes before (the record indented, one line per value), 5,137 after."""
    rom = _with_parameters(trained["rom"], [(f"plant.block[{i}].spring.c", "Real", 1.0 + i * 1e-3)
                                            for i in range(60000)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        spec = export.rom_fmu_spec(rom, "Many", fmi_version=trained["version"])
    assert len(spec.extra_files["provenance.json"].encode()) < 10_000
    assert len(spec.parameters) == 60004
