"""Snapshot files merged into one data set that were recorded differently (audit 72, F3 and F4).

F3: a folder holding one FMU's model-exchange recording and its explicit Euler co-simulation (Simulink ode1-style,
:func:`fmu_opinf.lti_fmus.build_lti_fmu` with ``cs_method="euler"``) was fitted without a word, the Euler file's
verdict applied to every run: the ROM was 15-31 % of range off the model either file alone gives exactly, and
``compare`` against the FMU by model exchange blamed "the FMU's own integration error".  F4: files recorded at two
stiffness values (``--set``, a run table's ``set:`` column) were fitted as one model and the merge dropped the
differing setting silently.  References: the exact zero-order-hold response of the model
(:func:`fmu_opinf.lti_fmus.zoh_response`), not the FMU.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import build_fmu_set, miss_against_model

from fmu_opinf import lti_fmus
from fmu_opinf.basis import open_snapshot_set
from fmu_opinf.cli import main
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Run, Snapshots
from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

FIXED_STEP = 0.01


def _model(stiffness: float = 1.0) -> lti_fmus.LinearMechanicalModel:
    model = lti_fmus.chain_model(4, inputs=(-1,), x0=[0.0, 0.0, 0.0, 0.05], name="Ode1AndME")
    return dataclasses.replace(model, K=stiffness * np.asarray(model.K))


@pytest.fixture(scope="module")
def euler_and_me(request, tmp_path_factory):
    """One FMU: model exchange (integrated accurately here) and an explicit Euler co-simulation at a fixed step."""
    def build(folder, item):
        return item, lti_fmus.build_lti_fmu(_model(), folder / f"{item}.fmu", interfaces=("me", "cs"),
                                            identifier=item, cs_method="euler", cs_fixed_step=FIXED_STEP).path

    return build_fmu_set(request, tmp_path_factory, "lti-merged-recordings", build, ["Ode1AndME"])["Ode1AndME"]


def _miss_against_model(rom: SecondOrderROM, spec: str, t_end: float = 60.0) -> float:
    """Largest output error over its range, the ROM against the exact model on ``spec``."""
    return miss_against_model(rom, _model(), spec, t_end)


@pytest.mark.fmu
@pytest.mark.slow
def test_model_exchange_and_euler_co_simulation_merged_are_said_and_fitted_as_the_model(euler_and_me, tmp_path,
                                                                                       capsys):
    folder, rom_file = tmp_path / "train", tmp_path / "rom.h5"
    folder.mkdir()
    common = ["--dt", str(FIXED_STEP), "--t-end", "60", "-q"]
    assert main(["snapshots", str(euler_and_me), "-o", str(folder / "a.h5"), "--interface", "me", *common]) == 0
    assert main(["snapshots", str(euler_and_me), "-o", str(folder / "b.h5"), "--interface", "cs",
                 "--input", "harmonic:amplitude=3,omega=1.1", *common]) == 0
    assert "one Euler step per communication step" in capsys.readouterr().err   # (b.h5's, as before)
    assert main(["fit", str(folder), "-o", str(rom_file), "-q"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "(a.h5, b.h5) were recorded by different FMI interfaces (a.h5 model exchange, b.h5 co-simulation)" in err
    assert "b.h5 follows the FMU's explicit Euler co-simulation steps" in err
    assert "the output-error refinement simulates the ROM with that step" not in err   # (the old Euler treatment)
    rom = SecondOrderROM.load(rom_file)
    # measured 1.9e-13 / 2.5e-13 / 3.5e-13 (before: 0.32 / 0.057 / 0.15, the accurate run stepped by Euler too)
    for spec in ("none", "harmonic:amplitude=3,omega=0.9", "impulse:amplitude=100,t0=2,width=0.5"):
        assert _miss_against_model(rom, spec) < 2e-12, spec
    parts = rom.provenance["snapshots"]["merged_parts"]["parts"]
    assert [(p["file"], p["fmi_interface"], p["recording_verdicts"]) for p in parts] == [
        ("a.h5", "me", []), ("b.h5", "cs", ["forward-euler"])]
    assert rom.provenance["fit_settings"]["mixed_recordings"] is True
    assert main(["compare", str(rom_file), str(euler_and_me), "-o", str(tmp_path / "me"), "-q"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "this comparison ran no co-simulation: the difference is the ROM's" in err
    assert "own integration error" not in err   # (model exchange: the FMU's integrator is accurate)
    assert main(["compare", str(rom_file), str(euler_and_me), "--interface", "cs", "-o", str(tmp_path / "cs"),
                 "-q"]) == 0
    assert "includes the FMU's own integration error" in capsys.readouterr().err


def _exact_part(stiffness: float, attrs: dict) -> Snapshots:
    """One exact run of the model at ``stiffness`` (no FMU), with file attributes as ``snapshots`` writes them."""
    t = time_grid(0.05, 40.0)
    u = inputs_in_effect(parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1), t, 1)
    exact = lti_fmus.zoh_response(_model(stiffness), t, u[:, 1:])
    return Snapshots([Run(t, u, exact.x, exact.v, exact.a, exact.y)], {"n": 4, "m": 1, "p": exact.y.shape[0],
                                                                       **attrs})


def test_files_recorded_at_different_settings_are_named_with_their_values(tmp_path):
    """A run table's rows ``base`` and ``stiff`` (``set:stiffness_scale`` empty and 2.5): the fit names the files,
    the setting and both values, and says to fit one ROM per setting."""
    fmu = {"fmu_name": "c4.fmu", "fmu_sha256": "93db" * 16, "fmi_interface": "me"}
    _exact_part(1.0, {**fmu, "fmu_settings": {}}).save(tmp_path / "base.h5")
    _exact_part(2.5, {**fmu, "fmu_settings": {"stiffness_scale": 2.5}}).save(tmp_path / "stiff.h5")
    with open_snapshot_set(tmp_path) as snaps:
        assert snaps.attrs["fmu_settings"] == {}   # (the set's own settings: those both share, as before)
        with pytest.warns(FmuOpinfWarning, match=r"snapshot files \(base\.h5, stiff\.h5\) were recorded with different "
                                                 r"settings \(stiffness_scale: base\.h5 default, stiff\.h5 2\.5\): one "
                                                 r"linear ROM cannot follow both; fit one ROM per setting"):
            fit_rom(snaps, r=4, quiet=True, refine=False)


def test_merged_parts_are_kept_through_nested_merges_and_files():
    """Every part's FMU and hash is kept (not only the first's), through a merge of merges and a saved file; the
    set's verdicts are those every part carries."""
    first = _exact_part(1.0, {"fmu_name": "a.fmu", "fmu_sha256": "aa" * 32, "recording_verdicts": ["forward-euler"]})
    second = _exact_part(1.0, {"fmu_name": "b.fmu", "fmu_sha256": "bb" * 32,
                               "recording_verdicts": ["forward-euler", "late-outputs"]})
    third = _exact_part(1.0, {"fmu_name": "c.fmu", "fmu_sha256": "cc" * 32})
    pair = Snapshots().append(first).append(second)
    assert pair.attrs["recording_verdicts"] == ["forward-euler"]
    merged = Snapshots().append(pair).append(third)
    assert "recording_verdicts" not in merged.attrs
    assert [(p["file"], p["fmu_name"]) for p in merged.attrs["merged_parts"]["parts"]] == [
        ("part 1", "a.fmu"), ("part 2", "b.fmu"), ("part 3", "c.fmu")]


def test_a_saved_merge_keeps_its_parts(tmp_path):
    first = _exact_part(1.0, {"fmu_name": "a.fmu", "fmu_sha256": "aa" * 32})
    first.save(tmp_path / "a.h5")
    second = _exact_part(1.0, {"fmu_name": "b.fmu", "fmu_sha256": "bb" * 32})
    merged = Snapshots.load(tmp_path / "a.h5").append(second)
    merged.save(tmp_path / "merged.h5")
    again = Snapshots.load(tmp_path / "merged.h5")
    assert [p["fmu_sha256"] for p in again.attrs["merged_parts"]["parts"]] == ["aa" * 32, "bb" * 32]
    assert again.attrs["merged_parts"]["parts"][0]["file"] == "a.h5"
    with pytest.warns(FmuOpinfWarning, match=r"from different FMUs \(a\.h5 a\.fmu \(sha256 aaaaaaaaaaaa\), part 2 "
                                             r"b\.fmu \(sha256 bbbbbbbbbbbb\)\)"):
        fit_rom(again, r=4, quiet=True, refine=False)


def test_a_warning_on_a_thousand_files_stays_one_short_line():
    """A run table of a thousand rows, each at its own setting: the files and values are listed up to four, then
    counted (before the listing was cut, the line was 24 kB)."""
    from fmu_opinf.snapshots._merge import merge_differences

    parts = [{"file": f"r{i}.h5", "fmu_settings": {"k": i}} for i in range(1000)]
    said = merge_differences({"merged_parts": {"parts": parts}})
    assert said is not None and len(said) < 300 and "\n" not in said
    assert "k: r0.h5 0, r1.h5 1, r2.h5 2, r3.h5 3, ... (1000 in all)" in said
    assert said.endswith("fit one ROM per setting")


def _two_fmus(tmp_path) -> Snapshots:
    """A folder of two exact recordings attributed to two FMUs (a.fmu, b.fmu), opened as one set."""
    _exact_part(1.0, {"fmu_name": "a.fmu", "fmu_sha256": "aa" * 32, "fmu_guid": "{a}", "source": "/x/a.fmu",
                      "fmi_interface": "me"}).save(tmp_path / "a.h5")
    _exact_part(1.0, {"fmu_name": "b.fmu", "fmu_sha256": "bb" * 32, "fmu_guid": "{b}", "source": "/x/b.fmu",
                      "fmi_interface": "cs"}).save(tmp_path / "b.h5")
    return open_snapshot_set(tmp_path)


def test_a_set_merged_from_two_fmus_names_neither_alone_and_keeps_both(tmp_path):
    """The set's FMU was the first file's (name, hash, GUID, path: audit 72 F3, ode1.fmu appeared nowhere): it now
    says how many FMUs it holds and names them, and each part keeps its own; through a fit into the ROM."""
    with _two_fmus(tmp_path) as snaps:
        attrs = dict(snaps.attrs)
        with pytest.warns(FmuOpinfWarning, match="from different FMUs"):
            rom = fit_rom(snaps, r=4, quiet=True, refine=False)
    assert attrs["fmu_name"] == "2 FMUs merged (a.fmu, b.fmu)"
    assert attrs["source"] == "2 FMUs merged (a.fmu, b.fmu)"
    assert "fmu_sha256" not in attrs and "fmu_guid" not in attrs and "fmi_interface" not in attrs
    assert [(p["fmu_name"], p["fmu_sha256"]) for p in attrs["merged_parts"]["parts"]] == [
        ("a.fmu", "aa" * 32), ("b.fmu", "bb" * 32)]
    recorded = rom.provenance["snapshots"]
    assert recorded["fmu_name"] == "2 FMUs merged (a.fmu, b.fmu)" and recorded.get("fmu_guid") is None


def test_a_set_of_one_fmu_keeps_its_name_and_hash():
    """Parts of one FMU (a run table's rows at two settings) still name it: only different FMUs are merged names."""
    fmu = {"fmu_name": "c4.fmu", "fmu_sha256": "93db" * 16, "fmu_guid": "{c4}"}
    merged = Snapshots().append(_exact_part(1.0, fmu)).append(_exact_part(2.5, {**fmu, "fmu_settings": {"k": 2.5}}))
    assert (merged.attrs["fmu_name"], merged.attrs["fmu_sha256"], merged.attrs["fmu_guid"]) == (
        "c4.fmu", "93db" * 16, "{c4}")
    fmu = {**fmu, "fmi_interface": "me"}
    same = Snapshots().append(_exact_part(1.0, fmu)).append(_exact_part(1.0, fmu))
    assert same.attrs["fmi_interface"] == "me" and same.attrs["fmu_name"] == "c4.fmu"


def test_compare_and_export_repeat_the_merge_warning_once(tmp_path):
    """fit warned that the merged files come from two FMUs; compare and export said nothing (audit 72 F3/F4).  Each
    now repeats that one line, once, from the ROM's stored provenance; the exported FMU's description names the two
    FMUs, not the first one's GUID."""
    import re
    import warnings

    from fmu_opinf.compare import compare
    from fmu_opinf.export import rom_fmu_spec

    with _two_fmus(tmp_path) as snaps, pytest.warns(FmuOpinfWarning):
        fit_rom(snaps, r=4, quiet=True, refine=False).save(tmp_path / "rom.h5")
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    said = r"as fit warned, the merged snapshot files \(a\.h5, b\.h5\) were recorded from different FMUs"
    for run in (lambda: compare(rom, tmp_path / "rom.h5", "harmonic:amplitude=1,omega=0.9", t_end=5.0, quiet=True),
                lambda: rom_fmu_spec(rom)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = run()
        repeated = [w for w in caught if "as fit warned, the merged" in str(w.message)]
        assert len(repeated) == 1, [str(w.message) for w in caught]
        assert re.search(said, str(repeated[0].message))
    assert "2 FMUs merged (a.fmu, b.fmu)" in result.description and "GUID" not in result.description


def test_compare_against_a_third_fmu_still_says_it_is_not_the_trained_one(tmp_path):
    """A set merged from two FMUs names no GUID of its own (above), so compare's check that the source is the FMU the
    ROM was learned from no longer fired for a third FMU with the same variable names (fix73a's caveat).  Each part
    now keeps its GUID: an FMU of either part is not warned about, a third one is, naming both."""
    import warnings
    import zipfile

    from fmu_opinf.compare._training import _warn_if_another_fmu

    with _two_fmus(tmp_path) as snaps, pytest.warns(FmuOpinfWarning):
        rom = fit_rom(snaps, r=4, quiet=True, refine=False)
    assert [part.get("fmu_guid") for part in rom.provenance["snapshots"]["merged_parts"]["parts"]] == ["{a}", "{b}"]

    def fmu(name: str, guid: str) -> str:
        path = tmp_path / name
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("modelDescription.xml", f'<?xml version="1.0"?><fmiModelDescription fmiVersion="2.0" '
                       f'modelName="m" guid="{guid}"><CoSimulation modelIdentifier="m"/><ModelVariables/>'
                       '<ModelStructure/></fmiModelDescription>')
        return str(path)

    info = {"provenance": rom.provenance}
    for known in (fmu("b.fmu", "{b}"), fmu("a.fmu", "{a}")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            _warn_if_another_fmu(info, known)
    with pytest.warns(FmuOpinfWarning, match=r"c\.fmu is not the FMU the ROM was learned from \(a\.fmu, GUID \{a\}, "
                                              r"b\.fmu, GUID \{b\}; this one has \{c\}\)"):
        _warn_if_another_fmu(info, fmu("c.fmu", "{c}"))
