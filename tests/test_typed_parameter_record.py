"""The record of Enumeration and Float32 source parameters and what the ROM FMU's spec makes of it (api84, item 2).

Fast checks beside tests/test_export_typed_parameters.py (which compiles the FMUs): the record read from model
descriptions written here by hand (the FMI 2 and FMI 3 forms of an Enumeration type), and the spec's parameters of a
ROM carrying such a record.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from fmu_opinf import export
from fmu_opinf.fmus import FmuBuildError, Parameter, SecondOrderFmuSpec
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.sources._variables import ModelInfo, source_parameters_record

FMI2 = """<fmiModelDescription fmiVersion="2.0" modelName="m" guid="{x}">
<TypeDefinitions>
 <SimpleType name="S.M"><Enumeration><Item name="a" value="1"/><Item name="b" value="2" description="bee"/>
 </Enumeration></SimpleType>
 <SimpleType name="Bad"><Enumeration><Item name="x" value="one"/></Enumeration></SimpleType>
</TypeDefinitions>
<ModelVariables>
 <ScalarVariable name="sm" valueReference="1" causality="parameter" variability="fixed">
  <Enumeration declaredType="S.M" start="2"/></ScalarVariable>
 <ScalarVariable name="bad" valueReference="2" causality="parameter" variability="fixed">
  <Enumeration declaredType="Bad" start="1"/></ScalarVariable>
 <ScalarVariable name="k" valueReference="3" causality="parameter" variability="fixed"><Real start="2.5"/>
 </ScalarVariable>
</ModelVariables><ModelStructure/></fmiModelDescription>"""

FMI3 = """<fmiModelDescription fmiVersion="3.0" modelName="m" instantiationToken="{x}">
<TypeDefinitions><EnumerationType name="S.M"><Item name="a" value="1"/><Item name="b" value="2"/></EnumerationType>
</TypeDefinitions>
<ModelVariables><Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>
 <Enumeration name="sm" valueReference="1" causality="parameter" variability="fixed" declaredType="S.M" start="1"/>
 <Float32 name="tol" valueReference="2" causality="parameter" variability="fixed" start="0.001"/>
</ModelVariables><ModelStructure/></fmiModelDescription>"""


def test_an_enumeration_is_recorded_with_its_types_items():
    """FMI 2: the items of the SimpleType; a type whose item has no whole-number value is not recorded (nor its
    parameter: the ROM FMU could not declare it)."""
    record = source_parameters_record(ModelInfo(ET.fromstring(FMI2), "m"), [])
    assert record["names"] == ["sm", "k"] and record["types"] == ["Enumeration", "Real"]
    assert record["values"] == [2.0, 2.5]
    assert record["enumerations"] == {"sm": {"type": "S.M", "items": [["a", 1, ""], ["b", 2, "bee"]]}}


def test_an_fmi3_enumeration_and_float32_are_recorded():
    record = source_parameters_record(ModelInfo(ET.fromstring(FMI3), "m"), [])
    assert list(zip(record["names"], record["types"], record["values"])) == [("sm", "Enumeration", 1.0),
                                                                              ("tol", "Float32", 0.001)]
    assert record["enumerations"] == {"sm": {"type": "S.M", "items": [["a", 1, ""], ["b", 2, ""]]}}


def test_a_record_without_enumerations_has_no_such_key():
    """A model without Enumeration parameters records what it recorded before (its sha256 in provenance.json, which
    tells two trainings apart, stays)."""
    root = ET.fromstring(FMI3.replace('<Enumeration name="sm" valueReference="1" causality="parameter" '
                                      'variability="fixed" declaredType="S.M" start="1"/>', ""))
    assert "enumerations" not in source_parameters_record(ModelInfo(root, "m"), [])


def _rom(record: dict) -> SecondOrderROM:
    return SecondOrderROM(np.eye(2), 0.1 * np.eye(2), np.diag([1.0, 4.0]), np.ones((2, 1)), np.ones((1, 2)),
                          np.zeros((1, 2)), dt=0.1, provenance={"snapshots": {"source_parameters": record}})


@pytest.mark.parametrize("version, float32", [("2.0", "Float64"), ("3.0", "Float32")])
def test_the_spec_declares_them_with_their_types(version, float32):
    record = source_parameters_record(ModelInfo(ET.fromstring(FMI3), "m"), [])
    spec = export.rom_fmu_spec(_rom(record), "Typed", fmi_version=version)
    assert [(p.name, p.type, p.default, p.enumeration) for p in spec.parameters] == [
        ("sm", "Enumeration", 1.0, "S.M"), ("tol", float32, 0.001, "")]
    assert spec.enumeration_types == {"S.M": [("a", 1, ""), ("b", 2, "")]}


def test_items_a_spec_takes():
    spec = SecondOrderFmuSpec(identifier="T", model_source="", n=1, m=0, p=1, fixed_parameters=True,
                              parameters=[Parameter("e", 2.0, type="Enumeration", enumeration="T")],
                              enumeration_types={"T": [["a", 1, ""], ["b", 2.0, "bee"]]})
    assert spec.parameters[0].type == "Enumeration"


@pytest.mark.parametrize("items", [[["a", 1, ""], ["a", 2, ""]],      # two items of one name
                                   [["a", 1.5, ""]], [["a", True, ""]], [["", 1, ""]], [["a\n", 1, ""]],
                                   [["a", 2**31, ""]]])                 # beyond FMI 2's Integer
def test_items_that_cannot_be_declared_are_refused_by_the_spec(items):
    with pytest.raises(FmuBuildError, match=r"enumeration type 'T': .* is not a type name with checked items"):
        SecondOrderFmuSpec(identifier="T", model_source="", n=1, m=0, p=1, fixed_parameters=True,
                           parameters=[Parameter("e", 1.0, type="Enumeration", enumeration="T")],
                           enumeration_types={"T": items})


def test_merged_parts_keep_the_enumeration_types_they_share():
    """Merged snapshot parts kept the shared rows only, and dropped the record's types: the ROM FMU of merged parts
    left the Enumeration out (measured before: 'does not declare the source parameters solverMethod')."""
    import copy

    from fmu_opinf.snapshots._data import shared_parameters

    record = source_parameters_record(ModelInfo(ET.fromstring(FMI3), "m"), [])
    shared = shared_parameters(record, copy.deepcopy(record))
    assert shared["enumerations"] == record["enumerations"]
    assert [p.type for p in export.rom_fmu_spec(_rom(shared), "Merged", fmi_version="3.0").parameters] == [
        "Enumeration", "Float32"]
    other = copy.deepcopy(record)
    other["enumerations"]["sm"]["items"][1][0] = "c"          # (another model's type of the same name)
    assert "enumerations" not in shared_parameters(record, other)
