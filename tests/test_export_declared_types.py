"""The ROM FMU keeps its source's declared types and reads display units as compare does (fix82a, items 2 and 3).

Item 2: the type definitions the source's inputs and outputs name (``declaredType="Modelica.Units.SI.Force"``) are
declared on the ROM FMU with their quantity and unit, and the ports name them (before: a plain ``unit``).  Item 3:
units are read by one XML reader (:func:`fmu_opinf.sources._variables.defined_units`, the one compare's report uses);
an FMI 3 ``inverse="true"`` display unit is not declared as a linear one (before: ``factor="1.0"``, and the output's
``displayUnit`` with it).  References: the source's own model description (read by fmpy), the source FMU run under the
same fmpy settings and ``lti_fmus.zoh_response`` of the true model.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import read_model_description, simulate_fmu  # noqa: E402
from fmpy.validation import validate_fmu  # noqa: E402

from conftest import rewrite_description  # noqa: E402
from fmu_opinf import export, lti_fmus, snapshots  # noqa: E402
from fmu_opinf.errors import FmuOpinfWarning  # noqa: E402
from fmu_opinf.fit import fit_rom  # noqa: E402
from fmu_opinf.source import open_source  # noqa: E402
from fmu_opinf.sources._variables import ModelInfo  # noqa: E402

pytestmark = pytest.mark.slow   # three source FMUs and six ROM FMUs compiled

DT = 0.05
START = {"x0": [0.05, -0.02, 0.03, 0.0, 0.04], "v0": [0.0, 0.1, 0.0, -0.05, 0.0]}
TRAINING = "impulse:amplitude=100,t0=2,width=0.5;harmonic:amplitude=8,omega=1.3"
#: Bounds on max |y - y_exact| / range(y_exact): a ROM FMU of the source's order (measured below 1e-13) and the
#: source (its RK4 substeps; measured below 3e-7)
EXACT = 1e-12
SOURCE = 1e-6
PORTS = ("F[1]", "F[2]", "y[1]", "y[2]", "y[3]")


def _model() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(inputs=(1, -1), force_offset=0.6, acceleration_outputs=(-1,), output_offset=0.1,
                                name="Typed", **START)


def _roms(source: Path, folder: Path, stem: str) -> dict[str, Path]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        rom = fit_rom(snapshots.record(open_source(source), TRAINING, dt=DT, t_end=30.0, quiet=True))
        return {v: export.export_fmu(rom, folder / f"{stem}{v[0]}.fmu", fmi_version=v) for v in ("2.0", "3.0")}


def _staircase(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    rows = []
    for i in range(len(t) - 1):
        rows += [(t[i], *u[:, i]), (t[i + 1], *u[:, i])]
    return np.array(rows, dtype=[("time", float), ("F[1]", float), ("F[2]", float)])


def _miss(path: Path) -> float:
    """The largest max |y - y_exact| / range(y_exact) of the outputs over 20 s of a staircase input."""
    t = np.arange(0.0, 20.0 + DT / 2, DT)
    u = np.vstack([np.sin(0.8 * t), 2 * np.cos(0.5 * t)])
    result = simulate_fmu(str(path), stop_time=20.0, output_interval=DT, input=_staircase(t, u))
    exact = lti_fmus.zoh_response(_model(), t, u).y
    y = np.vstack([result[name] for name in ("y[1]", "y[2]", "y[3]")])
    return float((np.abs(y - exact).max(axis=1) / np.ptp(exact, axis=1)).max())


# ------------------------------------------------------------------------------------- declared types (item 2)

@pytest.fixture(scope="module", params=["2.0", "3.0"])
def declared(request, tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp(f"declared{request.param[0]}")
    source = lti_fmus.build_lti_fmu(_model(), folder / "Typed.fmu", fmi_version=request.param, declared_types=True,
                                    output_units=True).path
    return {"source": source, "roms": _roms(source, folder, "TypedRom")}


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_ports_name_the_sources_type_definitions(declared, version):
    source = read_model_description(str(declared["source"]))
    types = {t.name: t for t in source.typeDefinitions}
    wanted = {v.name: v.declaredType.name for v in source.modelVariables if v.name in PORTS}
    assert set(wanted.values()) == {"Modelica.Units.SI.Force", "Modelica.Units.SI.Position",
                                    "Modelica.Units.SI.Velocity", "Modelica.Units.SI.Acceleration"}
    path = declared["roms"][version]
    md = read_model_description(str(path))
    got = {v.name: v for v in md.modelVariables if v.name in PORTS}
    assert {name: v.declaredType.name for name, v in got.items() if v.declaredType} == wanted
    for name, variable in got.items():
        kept, original = variable.declaredType, types[wanted[name]]
        assert (kept.quantity, kept.unit) == (original.quantity, original.unit)
        assert kept.type == ("Real" if version == "2.0" else "Float64")
    assert validate_fmu(str(path)) == []
    assert _miss(path) < EXACT
    assert _miss(declared["source"]) < SOURCE


def test_type_definitions_are_data_checked_before_they_reach_the_xml():
    from fmu_opinf.fmus import is_type_name, type_definition

    assert is_type_name("Modelica.Units.SI.Force") and not is_type_name("a\nb") and not is_type_name(" x")
    assert type_definition({"type": "Float64", "quantity": "Force", "unit": "N", "displayUnit": ""})
    assert type_definition({"type": "Int32", "quantity": "", "unit": "", "displayUnit": ""}) is None
    assert type_definition({"type": "Float64", "quantity": "Force", "unit": "N\"/><x", "displayUnit": ""}) is None


# ---------------------------------------------------------------------------------------- display units (item 3)

def _display_units(text: str) -> str:
    """The FMI 3 source with a linear display unit ``mm`` of ``m`` (y[1] shown in it) and an inverse one ``s/m`` of
    ``m/s`` (y[2] shown in it) beside a linear ``km/h``."""
    text = text.replace('<Unit name="m"><BaseUnit m="1"/></Unit>',
                        '<Unit name="m"><BaseUnit m="1"/><DisplayUnit name="mm" factor="1000"/></Unit>')
    text = text.replace('<Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>',
                        '<Unit name="m/s"><BaseUnit m="1" s="-1"/><DisplayUnit name="s/m" inverse="true"/>'
                        '<DisplayUnit name="km/h" factor="3.6"/></Unit>')
    text = re.sub(r'(name="y\[1\]"[^>]*unit="m")', r'\1 displayUnit="mm"', text, count=1)
    return re.sub(r'(name="y\[2\]"[^>]*unit="m/s")', r'\1 displayUnit="s/m"', text, count=1)


@pytest.fixture(scope="module")
def inverse(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("inverse")
    built = lti_fmus.build_lti_fmu(_model(), folder / "Shown0.fmu", fmi_version="3.0", output_units=True).path
    source = rewrite_description(built, folder / "Shown.fmu", _display_units)
    return {"source": source, "roms": _roms(source, folder, "ShownRom")}


def test_the_reader_leaves_inverse_display_units_out(inverse):
    info = ModelInfo.from_path(inverse["source"])
    assert info.unit_definitions["m/s"]["display"] == [["km/h", 3.6, 0.0]]
    assert info.unit_definitions["m"] == {"base": {"m": 1}, "factor": 1.0, "offset": 0.0,
                                          "display": [["mm", 1000.0, 0.0]]}
    assert info.display_units == {"m": {"mm": (1000.0, 0.0)}, "m/s": {"km/h": (3.6, 0.0)}}   # (compare's view)
    names = [d.name for u in read_model_description(str(inverse["source"])).unitDefinitions for d in u.displayUnits]
    assert "s/m" in names     # (the source does declare it)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_an_inverse_display_unit_is_not_declared_as_a_linear_one(inverse, version):
    path = inverse["roms"][version]
    md = read_model_description(str(path))
    display = {u.name: {d.name: (d.factor, d.offset) for d in u.displayUnits} for u in md.unitDefinitions}
    assert display["m"] == {"mm": (1000.0, 0.0)} and display["m/s"] == {"km/h": (3.6, 0.0)}
    shown = {v.name: v.displayUnit for v in md.modelVariables if v.name.startswith("y[")}
    assert shown == {"y[1]": "mm", "y[2]": None, "y[3]": None}
    assert validate_fmu(str(path)) == []
    assert _miss(path) < EXACT
