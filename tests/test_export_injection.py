"""Issue 13 item 1: nothing read from a ROM file becomes code in the exported FMU."""

from __future__ import annotations

import warnings
import zipfile

import numpy as np
import pytest

from fmu_opinf.cli import main
from fmu_opinf.export import export_fmu, rom_fmu_spec
from fmu_opinf.rom import SecondOrderROM

PAYLOAD = '*/ __attribute__((constructor)) static void pwn(void) { system("touch /tmp/pwned"); } /*'


def _rom(**changes) -> SecondOrderROM:
    options = dict(provenance={"snapshots": {"source": f"/data/{PAYLOAD}/m.fmu", "fmu_guid": PAYLOAD,
                                             "input_spec": PAYLOAD}, "fit_date": "\n#include <stdlib.h>\n"},
                   dt=0.1)
    options.update(changes)
    return SecondOrderROM(np.eye(2), 0.1 * np.eye(2), np.diag([1.0, 4.0]), np.ones((2, 1)), np.ones((1, 2)),
                          np.zeros((1, 2)), **options)


def test_provenance_text_never_reaches_the_generated_c():
    spec = rom_fmu_spec(_rom(), "Injected")
    assert "pwn" not in spec.model_source and "#include <stdlib.h>" not in spec.model_source
    assert "*/" not in spec.model_source.split("*/", 1)[1]       # the one comment is the fixed header
    assert "\n" not in spec.description and "pwn" in spec.description   # kept as data, in the XML only


@pytest.mark.fmu
def test_hostile_rom_exports_and_its_xml_is_well_formed(tmp_path):
    from fmu_opinf.fmus import find_build_tools
    from xml.etree import ElementTree

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    path = export_fmu(_rom(), tmp_path / "Injected.fmu")
    with zipfile.ZipFile(path) as archive:
        root = ElementTree.fromstring(archive.read("modelDescription.xml"))
        model_c = archive.read("sources/model.c").decode()
    assert PAYLOAD in root.get("description")
    assert "pwn" not in model_c


@pytest.mark.parametrize("name", ["u\x01", "y\x7fx", "bad\x1bname"])
def test_control_characters_in_names_are_one_line_errors(tmp_path, capsys, name):
    rom = _rom(input_names=[name]) if name.startswith("u") else _rom(output_names=[name])
    rom.save(tmp_path / "rom.h5")
    assert main(["export", str(tmp_path / "rom.h5"), "-o", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "control character" in err and "Traceback" not in err
    assert not (tmp_path / "x.fmu").exists()


def test_recorded_units_reach_the_xml_only_as_plain_unit_names():
    """Units come from the snapshot provenance (data): a plain unit name is declared, anything else (quotes,
    markup, a wrong count) is dropped, never an error or new XML."""
    from fmu_opinf.fmus import _model_description3

    from fmu_opinf.export import _position_unit

    snapshots = {"input_units": ['N"/><Evil x="'], "output_units": ["m/s2"], "position_unit": "m\n"}
    spec = rom_fmu_spec(_rom(provenance={"snapshots": snapshots}), "Units")
    assert spec.input_units == [""] and spec.output_units == ["m/s2"]
    assert _position_unit({"snapshots": snapshots}) == "" and _position_unit({"snapshots": {"position_unit": "m"}}) == "m"
    xml = _model_description3(spec, "{guid}")
    assert xml.count('unit="m/s2"') == 1 and '<Unit name="m/s2"/>' in xml and "Evil" not in xml
    wrong_count = rom_fmu_spec(_rom(provenance={"snapshots": {"output_units": ["m", "m"]}}), "Units")
    assert wrong_count.output_units == [""]


@pytest.mark.parametrize("step, problem", [(1e300, r"more than 1e\+06 times away"), (1e-300, r"between 1e-07 and"),
                                           (float("nan"), "not a positive number")])
def test_export_step_out_of_range_is_one_line(step, problem):
    """``export --step`` far from the training step: one line (an overflowing step map was a traceback)."""
    from fmu_opinf.errors import DataError

    with pytest.raises(DataError, match=problem):
        rom_fmu_spec(_rom(integrator="exact"), "Steps", step=step)


def test_default_experiment_stops_on_a_whole_number_of_steps():
    """The stop time is the training horizon rounded down to the export step (an importer's last step would
    otherwise be refused): 30 s at step 0.07 -> 428 steps."""
    spec = rom_fmu_spec(_rom(provenance={"t_train_end": 30.0}, integrator="exact"), "Stops", step=0.07)
    start, stop, step = spec.default_experiment
    assert step == 0.07 and stop == pytest.approx(428 * 0.07, rel=1e-15)


def test_recorded_unit_definitions_reach_the_xml_only_as_checked_numbers():
    """The source's base and display units (fourth audit: the ROM FMU declared 'mm' without its BaseUnit, so an
    importer could not convert it) are declared again; a definition with anything but SI exponents, finite
    numbers and plain names is dropped to the bare unit name."""
    from xml.etree import ElementTree

    from fmu_opinf.fmus import _model_description, _model_description3

    definitions = {"mm": {"base": {"m": 1}, "factor": 0.001, "offset": 0.0, "display": [["cm", 0.1, 0.0]]},
                   "m/s2": {"base": {"m": 1, "s": "-2\"/><Evil"}, "factor": 1.0, "offset": 0.0, "display": []},
                   "N": {"base": {"kg": 1, "m": 1, "s": -2}, "factor": float("nan")},
                   "mm/s": {"base": None, "factor": 1.0, "offset": 0.0, "display": [["cm/s", 0.1, 0.0]]}}
    snapshots = {"input_units": ["N"], "output_units": ["mm"], "unit_definitions": definitions}
    spec = rom_fmu_spec(_rom(provenance={"snapshots": snapshots}), "Units")
    for xml in (_model_description(spec, "{guid}", ["model.c"]), _model_description3(spec, "{guid}")):
        root = ElementTree.fromstring(xml)
        units = {u.get("name"): u for u in root.iter("Unit")}
        assert set(units) == {"N", "mm"}
        base = units["mm"].find("BaseUnit")
        assert base.attrib == {"m": "1", "factor": "0.001"}
        assert units["mm"].find("DisplayUnit").attrib == {"name": "cm", "factor": "0.1", "offset": "0.0"}
        assert list(units["N"]) == []  # a non-finite factor: the name alone
    by_name = rom_fmu_spec(_rom(provenance={"snapshots": {**snapshots, "output_units": ["mm/s"]}}), "Units")
    unit = {u.get("name"): u for u in ElementTree.fromstring(_model_description3(by_name, "{guid}")).iter("Unit")}
    assert unit["mm/s"].find("BaseUnit") is None  # defined by name only: no claim that it is dimensionless
    assert unit["mm/s"].find("DisplayUnit").get("name") == "cm/s"
    evil = rom_fmu_spec(_rom(provenance={"snapshots": {**snapshots, "output_units": ["m/s2"]}}), "Units")
    xml = _model_description3(evil, "{guid}")
    assert "Evil" not in xml and '<Unit name="m/s2"/>' in xml


def test_non_ascii_unit_names_are_kept_and_format_characters_are_not():
    """Sixth audit: a Latin-1 source's outputs in 'µm' and '°' lost their units in the ROM FMU (the unit filter was
    ASCII only).  Printable symbols are kept; a name with a bidirectional override or white space is still
    dropped, and the XML parses to the same names."""
    from xml.etree import ElementTree

    from fmu_opinf.fmus import _model_description, _model_description3

    definitions = {"µm": {"base": {"m": 1}, "factor": 1e-6, "offset": 0.0, "display": [["Å", 1e4, 0.0]]},
                   "°": {"base": {"rad": 1}, "factor": 0.017453292519943295, "offset": 0.0, "display": []}}
    snapshots = {"input_units": ["\u202eN"], "output_units": ["µm"], "unit_definitions": definitions}
    spec = rom_fmu_spec(_rom(provenance={"snapshots": snapshots}), "Units")
    assert spec.input_units == [""] and spec.output_units == ["µm"]
    for xml in (_model_description(spec, "{guid}", ["model.c"]), _model_description3(spec, "{guid}")):
        root = ElementTree.fromstring(xml.encode())
        units = {u.get("name"): u for u in root.iter("Unit")}
        assert set(units) == {"µm"} and units["µm"].find("DisplayUnit").get("name") == "Å"
    degrees = rom_fmu_spec(_rom(provenance={"snapshots": {**snapshots, "output_units": ["°"]}}), "Units")
    assert degrees.output_units == ["°"]
    spaced = rom_fmu_spec(_rom(provenance={"snapshots": {**snapshots, "output_units": ["µ m"]}}), "Units")
    assert spaced.output_units == [""]


NAMES_WITH_BREAKS = {"input_names": ["F2'); system(\"id\"); //\n#include <x>"],
                     "output_names": ["pos%d\r\nline2 ]]> <!-- -->\tend"]}


@pytest.mark.parametrize("kind, name, words", [("input", "F2\n#include <x>", "a line feed"),
                                               ("output", "pos%d\rline2", "a carriage return"),
                                               ("output", "a\tb", "a TAB")])
def test_tab_newline_and_carriage_return_in_names_are_refused(kind, name, words):
    """Audit 68, finding 3: FMI's naming conventions exclude TAB, LF and CR from variable names, and fmpy's
    validator rejected the FMU that export wrote with them as character references (audit 62 had let them
    through).  The refusal names the variable, the character and the fix."""
    from fmu_opinf.fmus import FmuBuildError

    with pytest.raises(FmuBuildError, match=rf"^{kind} name .* contains {words}, which FMI variable names cannot "
                                            r"hold \(importers reject the FMU\); rename it"):
        rom_fmu_spec(_rom(**{f"{kind}_names": [name]}), "Breaks")


def test_names_with_line_breaks_are_one_line_export_errors(tmp_path, capsys):
    _rom(**NAMES_WITH_BREAKS).save(tmp_path / "rom.h5")
    assert main(["export", str(tmp_path / "rom.h5"), "-o", str(tmp_path / "x.fmu")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "contains a line feed" in err and "Traceback" not in err
    assert not (tmp_path / "x.fmu").exists()


@pytest.mark.fmu
@pytest.mark.parametrize("fmi_version", ["2.0", "3.0"])
def test_a_hostile_rom_exports_an_fmu_that_fmpy_validates(tmp_path, fmi_version):
    """Quotes, markup, format and comment characters in names reach the XML as data: fmpy's validator (which
    checks FMI's naming rules too) finds no problem, and the names read back as they were."""
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    from fmu_opinf.fmus import find_build_tools

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    names = {"input_names": ["F2'); system(\"id\"); // <x>"], "output_names": ["pos%d ]]> <!-- --> &amp; end"]}
    path = export_fmu(_rom(**names), tmp_path / "Hostile.fmu", fmi_version=fmi_version)
    assert validate_fmu(str(path)) == []
    described = read_model_description(str(path), validate=True)
    ports = {v.causality: v.name for v in described.modelVariables if v.causality in ("input", "output")}
    assert [ports["input"]] == names["input_names"] and [ports["output"]] == names["output_names"]


@pytest.mark.parametrize("name, character", [("u\x01", r"control character '\\x01'"),
                                             ("u\x0b", r"control character '\\x0b'"),
                                             ("u\ud800", r"character '\\ud800'"), ("u\uffff", r"character '\\uffff'")])
def test_characters_xml_cannot_hold_are_refused_as_such(name, character):
    from fmu_opinf.fmus import FmuBuildError

    with pytest.raises(FmuBuildError, match=rf"{character}, which XML 1\.0 cannot hold, not even as a character "
                                            r"reference; rename it$"):
        rom_fmu_spec(_rom(input_names=[name]), "Bad")


#: A held input's name that would end a C string and a comment, start a trigraph and a format (audit 69 F4: the
#: names of held inputs reach the generated C, as string literals for the FMU's log line; a line break, which
#: could start a preprocessor line, is refused in any name since audit 68 F3).
HOSTILE_HELD = 'k"); system("touch /tmp/pwned"); //??/ */ #include <x> %s\\'


def _rom_with_held_input() -> SecondOrderROM:
    held = {"order": ["u", HOSTILE_HELD], "values": {HOSTILE_HELD: 2.5}, "units": {HOSTILE_HELD: 'N"/><Evil x="'}}
    return _rom(input_names=["u"], provenance={"snapshots": {"held_inputs": held}})


def test_held_input_names_reach_the_c_only_as_escaped_string_literals():
    from fmu_opinf.fmus import _config_header

    spec = rom_fmu_spec(_rom_with_held_input(), "Held")
    header = _config_header(spec)
    assert "system(" in header and 'system("' not in header   # the quote is \042 only
    assert "??/" not in header and "%s" not in header
    names_line = next(line for line in header.splitlines() if line.startswith("#define INPUT_NAMES"))
    assert names_line.count('"') == 4                          # two literals, no quote of the name's own
    assert spec.input_units == ["", ""]                        # the hostile unit is not a unit name: dropped


@pytest.mark.fmu
@pytest.mark.parametrize("fmi_version", ["2.0", "3.0"])
def test_a_hostile_held_input_name_compiles_and_is_logged_as_it_is(tmp_path, fmi_version):
    """The FMU compiles, declares the name, and its log line refusing another value quotes the name exactly."""
    from fmpy import read_model_description, simulate_fmu

    from fmu_opinf.fmus import find_build_tools

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    path = export_fmu(_rom_with_held_input(), tmp_path / "Held.fmu", fmi_version=fmi_version)
    names = [v.name for v in read_model_description(str(path), validate=True).modelVariables
             if v.causality == "input"]
    assert names == ["u", HOSTILE_HELD]
    lines = []
    with pytest.raises(Exception, match="failed with status 3"):
        simulate_fmu(str(path), stop_time=0.5, start_values={HOSTILE_HELD: 1.0},
                     logger=lambda *args: lines.append(args[-1].decode()))
    assert any(f"input {HOSTILE_HELD} (value reference 2) was held at 2.5 in training" in line for line in lines)


def test_a_unit_or_unit_definition_dropped_from_the_rom_fmu_is_said():
    """Audit 68: units that are not plain names (a hostile ']]>', a name with white space) and malformed unit
    definitions were left out of the exported FMU without a word.  One warning each; a definition of a unit no
    variable uses is not written, so not warned about."""
    from fmu_opinf.errors import FmuOpinfWarning

    definitions = {"N": {"base": {"kg": 1, "m": 1, "s": -2.5}}, "Pa": {"base": {"parsec": 1}}}
    snapshots = {"input_units": ["N"], "output_units": ["]]>"], "unit_definitions": definitions}
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        spec = rom_fmu_spec(_rom(provenance={"snapshots": snapshots}), "Units")
    said = [str(w.message) for w in seen if issubclass(w.category, FmuOpinfWarning)]
    assert spec.output_units == [""] and spec.input_units == ["N"]
    assert len(said) == 2, said
    assert said[0].startswith("the recorded unit ']]>' is not a plain unit name"), said
    assert said[1].startswith("the recorded definition of unit 'N' is not of the form"), said
