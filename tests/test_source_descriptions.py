"""Audit 79a, F4: the source's descriptions of its inputs and outputs reach the exported ROM FMU.

``snapshots`` records them from the modelDescription, ``fit`` carries them in the ROM's provenance, ``export``
declares them (an output's followed by the ROM's formula), escaped for XML and never in the generated C; files
without them keep the ROM's own texts."""

from __future__ import annotations

import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest

from fmu_opinf.export import rom_fmu_spec
from fmu_opinf.rom import SecondOrderROM

#: Quotes, markup, a C comment's end, a backslash, non-ASCII and a C0 control character XML cannot hold.
NASTY = 'Kraft "F" <am> Lager & µN °, Ölpumpe */ \\ Ende \x01'
CLEANED = 'Kraft "F" <am> Lager & µN °, Ölpumpe */ \\ Ende ?'
FORMULA = "Cpr q + Cvr q' + Dur u + y0"


def _rom(snapshots: dict) -> SecondOrderROM:
    return SecondOrderROM(np.eye(2), 0.1 * np.eye(2), np.diag([1.0, 4.0]), np.ones((2, 1)), np.ones((1, 2)),
                          np.zeros((1, 2)), provenance={"snapshots": snapshots}, dt=0.1,
                          input_names=["F"], output_names=["tip.s"])


def _xml_descriptions(spec) -> dict[str, str]:
    from fmu_opinf.fmus import _model_description, _model_description3

    xml = (_model_description3(spec, "{guid}") if spec.fmi_version == "3.0"
           else _model_description(spec, "{guid}", ["model.c"]))
    root = ElementTree.fromstring(xml)
    return {v.get("name"): v.get("description") for v in root.iter() if v.get("causality") in ("input", "output")}


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_recorded_descriptions_reach_the_xml_unchanged_and_not_the_c(version):
    """A description holding " < & */ \\ and unicode arrives byte-identical in the parsed modelDescription (the
    control character as '?'); the generated C holds none of it.  Before: "input (held over each communication
    step)" and "ROM output tip.s: ..." whatever the source said."""
    rom = _rom({"input_descriptions": [NASTY], "output_descriptions": ["Auslenkung <Spitze> & \"µm\""]})
    spec = rom_fmu_spec(rom, "Described", fmi_version=version)
    found = _xml_descriptions(spec)
    assert found["F"] == CLEANED
    assert found["tip.s"] == f'Auslenkung <Spitze> & "µm" (ROM: {FORMULA})'
    assert "Lager" not in spec.model_source and "Spitze" not in spec.model_source


def test_files_without_descriptions_keep_the_roms_own_texts():
    """Older recordings (no descriptions), a wrong count, or non-text entries: the ROM's own texts, no error."""
    for snapshots in ({}, {"input_descriptions": ["a", "b"], "output_descriptions": [7]},
                      {"input_descriptions": [""], "output_descriptions": [""]}):
        found = _xml_descriptions(rom_fmu_spec(_rom(snapshots), "Plain"))
        assert found == {"F": "input (held over each communication step)", "tip.s": f"ROM output tip.s: {FORMULA}"}


def _described_fmu(tmp_path):
    """A 3-mass chain FMU (ME and CS) whose input and outputs carry NASTY-like descriptions."""
    from fmu_opinf.lti_fmus import build_lti_fmu, chain_model

    base = tmp_path / "base.fmu"
    lti = build_lti_fmu(chain_model(3, inputs=(2,), name="Described"), base, naming="modelica")
    with zipfile.ZipFile(base) as z:
        files = {i.filename: z.read(i.filename) for i in z.infolist()}
    root = ElementTree.fromstring(files["modelDescription.xml"])
    texts = {}
    for sv in root.iter("ScalarVariable"):
        if sv.get("causality") in ("input", "output"):
            texts[sv.get("name")] = f"{NASTY[:-2]} of {sv.get('name')}"
            sv.set("description", texts[sv.get("name")])
    files["modelDescription.xml"] = ElementTree.tostring(root, encoding="utf-8", xml_declaration=True)
    path = tmp_path / "X.fmu"
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return path, lti, texts


@pytest.mark.fmu
@pytest.mark.slow
def test_descriptions_round_trip_from_the_source_fmu_to_the_exported_rom_fmu(tmp_path):
    """snapshots -> fit -> export of an FMU with described ports: rom.fmu's modelDescription.xml gives each input
    the source's text and each output the source's text followed by the ROM's formula."""
    from fmu_opinf.cli import main
    from fmu_opinf.fmus import find_build_tools
    from fmu_opinf.snapshots import Snapshots

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    path, lti, texts = _described_fmu(tmp_path)
    h5, rom, out = (str(tmp_path / n) for n in ("t.h5", "rom.h5", "rom.fmu"))
    assert main(["snapshots", str(path), "-o", h5, "--dt", "0.05", "--t-end", "40", "-q"]) == 0
    attrs = Snapshots.load(h5).attrs
    assert list(attrs["input_descriptions"]) == [texts[n] for n in lti.inputs]
    assert list(attrs["output_descriptions"]) == [texts[n] for n in lti.outputs]
    assert main(["fit", h5, "-o", rom, "-q"]) == 0
    assert main(["export", rom, "-o", out]) == 0
    with zipfile.ZipFile(out) as z:
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    found = {v.get("name"): v.get("description") for v in root.iter("ScalarVariable")}
    for name in lti.inputs:
        assert found[name] == texts[name]
    for name in lti.outputs:
        assert found[name] == f"{texts[name]} (ROM: {FORMULA})"
