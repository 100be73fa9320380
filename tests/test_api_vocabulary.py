"""The Python API offers what the command line offers, in one vocabulary (audit 81c F12 and its open points).

* ``snapshots.record`` takes ``record_to_file``'s source keywords (variable patterns, ``parameters``, ...): the same
  meaning and checks through one opener, checked here against the exact response of the model it names;
* ``report.write_report`` refuses a folder holding other files as ``fmu-opinf compare -o`` does (``overwrite=True``
  writes there anyway);
* ``fit.fit_rom`` prints its labelled stage lines by default, as ``fit_rom_file``, ``record`` and ``compare`` do;
* a fix raised below the command line and the functions names the option and the keyword (``_validate.either``).

Each test fails on the code before (checked with ``PYTHONPATH`` on the commit before the change).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import build_fmu_set
from fmu_opinf import compare, lti_fmus, report, snapshots
from fmu_opinf.errors import FileFormatError, FmuOpinfError, FmuOpinfWarning, InputSpecError
from fmu_opinf.fit import fit_rom
from fmu_opinf.source import open_source
from fmu_opinf.sources import BuiltinSource

STEP = "step:amplitude=1,t0=0"
TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


@pytest.fixture(scope="module")
def fmu(request, tmp_path_factory):
    """A two-mass chain as a co-simulation FMU (lti_fmus): positions mass[1].s, mass[2].s, input F, outputs
    y[1], y[2], parameter stiffness_scale (default 1)."""
    def build(folder, item):
        return item, lti_fmus.build_lti_fmu(lti_fmus.chain_model(2), folder / f"{item}.fmu", interfaces=("cs",),
                                            identifier=item).path

    return build_fmu_set(request, tmp_path_factory, "api-vocabulary", build, ["VocabChain"])["VocabChain"]


@pytest.fixture(scope="module")
def comparison(tmp_path_factory):
    """A comparison of a ROM of the anchored chain (g = 12, r = 3) with its source."""
    folder = tmp_path_factory.mktemp("vocab")
    snaps = snapshots.record(BuiltinSource("anchored-msd", g=12), TRAIN, 0.5, 40.0, quiet=True)
    rom = fit_rom(snaps, r=3, quiet=True)
    rom.save(folder / "rom.h5")
    return compare.compare(folder / "rom.h5", "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
                           source_options={"g": 12, "isolate": False})


def _one_line(error: BaseException, *parts: str) -> None:
    assert isinstance(error, FmuOpinfError), repr(error)
    assert "\n" not in str(error)
    for part in parts:
        assert part in str(error), str(error)


# -- record() takes record_to_file's source keywords ----------------------------------------------------------


def test_record_on_a_grid_takes_output_patterns_and_parameters(fmu):
    """``record(fmu, signal, dt, t_end, outputs=..., parameters=...)`` raised ``TypeError: unexpected keyword``; it
    now records the output named, at the parameter given: the exact response of the model with that stiffness."""
    model = lti_fmus.chain_model(2)
    snaps = snapshots.record(str(fmu), STEP, 0.1, 3.0, quiet=True, outputs="y[2]",
                             parameters={"stiffness_scale": 2.0})
    run = snaps.runs[0]
    assert list(snaps.attrs["output_names"]) == ["y[2]"]
    assert snaps.attrs["fmu_settings"] == {"stiffness_scale": 2.0}
    exact = lti_fmus.zoh_response(model, run.t, run.u, stiffness_scale=2.0).y[1:2]
    unscaled = lti_fmus.zoh_response(model, run.t, run.u).y[1:2]
    assert np.abs(run.y - exact).max() < 1e-10 * np.abs(exact).max()          # measured 1.3e-12 of it
    assert np.abs(run.y - unscaled).max() > 0.5 * np.abs(exact).max()        # (the parameter changed the model)


def test_record_on_a_grid_takes_position_and_velocity_patterns(fmu):
    with pytest.warns(FmuOpinfWarning, match=r"its continuous state\(s\) mass\[1\].s, mass\[1\].v are recorded "
                                             r"neither as positions nor as velocities"):   # (as record_to_file's)
        snaps = snapshots.record(str(fmu), STEP, 0.1, 3.0, quiet=True, positions="mass[2].s",
                                 velocities="mass[2].v", inputs="F", interface="cs", tolerance=1e-9)
    run = snaps.runs[0]
    assert run.x.shape == (1, 31)
    exact = lti_fmus.zoh_response(lti_fmus.chain_model(2), run.t, run.u)
    assert np.abs(run.x[0] - exact.x[1]).max() < 1e-10 * np.abs(exact.x[1]).max()


def test_record_with_its_defaults_passes_them_to_record_to_file(fmu, tmp_path):
    """Without a grid, record() runs record_to_file: the keywords reach it (same attributes in the file)."""
    snaps = snapshots.record(str(fmu), outputs="y[2]", parameters={"stiffness_scale": 2.0}, quiet=True,
                             path=tmp_path / "a.h5")
    snapshots.record_to_file(str(fmu), tmp_path / "b.h5", outputs="y[2]", parameters={"stiffness_scale": 2.0},
                             quiet=True)
    other = snapshots.Snapshots.load(tmp_path / "b.h5")
    for key in ("output_names", "position_names", "fmu_settings", "dt"):
        assert snaps.attrs[key] == other.attrs[key], key
    assert np.array_equal(snaps.runs[0].y, other.runs[0].y)


def test_record_checks_its_source_keywords_as_record_to_file_does(fmu):
    with pytest.raises(InputSpecError) as caught:
        snapshots.record(str(fmu), STEP, 0.1, 1.0, quiet=True, parameters={"stifness_scale": 2.0})
    _one_line(caught.value, "has no variable 'stifness_scale' (did you mean stiffness_scale")


@pytest.mark.parametrize("grid", [(STEP, 0.1, 1.0), ()])
def test_an_opened_source_with_source_keywords_is_refused_not_recorded_as_opened(fmu, grid):
    """An opened source is recorded as opened: record_to_file(source, outputs=...) dropped ``outputs`` without a
    word and recorded every output."""
    source = open_source(str(fmu))
    with pytest.raises(InputSpecError) as caught:
        snapshots.record(source, *grid, quiet=True, outputs="y[2]")
    _one_line(caught.value, "outputs= applies where the source is given as a path or spec, but VocabChain.fmu is "
                            "an opened source", "open_source(spec, outputs=...)")


def test_record_to_file_refuses_source_keywords_with_an_opened_source(fmu, tmp_path):
    """record_to_file(source, parameters=...) recorded the source at its own values without a word."""
    source = open_source(str(fmu))
    with pytest.raises(InputSpecError) as caught:
        snapshots.record_to_file(source, tmp_path / "s.h5", STEP, dt=0.1, t_end=1.0, quiet=True,
                                 parameters={"stiffness_scale": 2.0})
    _one_line(caught.value, "parameters= applies where the source is given")
    assert not (tmp_path / "s.h5").exists()


# -- write_report refuses a folder of other files -------------------------------------------------------------


def test_write_report_refuses_a_folder_holding_other_files_as_the_command_line_does(comparison, tmp_path):
    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    with pytest.raises(FileFormatError) as caught:
        report.write_report(comparison, folder)
    _one_line(caught.value, f"report directory {folder} exists and holds other files; give out_dir= a new path, or "
                            "overwrite=True to write the report among them (an earlier report in it would be replaced)")
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt"]
    page = report.write_report(comparison, folder, overwrite=True)
    assert page.is_file() and (folder / "notes.txt").read_text() == "mine"
    assert report.write_report(comparison, folder).is_file()   # an earlier report (metrics.json) is replaced
    empty = tmp_path / "empty"
    empty.mkdir()
    assert report.write_report(comparison, empty).is_file()


def test_write_report_names_its_keyword_for_an_existing_file(comparison, tmp_path):
    target = tmp_path / "report"
    target.write_text("a file")
    with pytest.raises(FileFormatError) as caught:
        report.write_report(comparison, target)
    _one_line(caught.value, f"report directory {target} is an existing file; give out_dir= another path")


def test_the_command_line_keeps_its_report_folder_words(tmp_path, capsys):
    from fmu_opinf import cli

    folder = tmp_path / "results"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    assert cli.main(["compare", "unused.h5", "builtin:anchored-msd", "-o", str(folder)]) == 2
    assert "exists and holds other files; choose a new -o path (an earlier report" in capsys.readouterr().err


# -- progress: fit_rom prints its stage lines as the other functions do ---------------------------------------


def test_fit_rom_prints_labelled_stage_lines_by_default(capsys):
    """A 45 s notebook fit printed nothing (fit_rom's quiet=True) where record, compare and fit_rom_file print."""
    snaps = snapshots.record(BuiltinSource("anchored-msd", g=12), TRAIN, 0.5, 40.0, quiet=True)
    capsys.readouterr()
    fit_rom(snaps, r=3, refine=False)
    said = capsys.readouterr().err
    lines = said.splitlines()
    assert lines[0].startswith("POD of the positions (dense, "), said
    assert any(line.startswith("SDP: optimal via ") for line in lines), said
    fit_rom(snaps, r=3, refine=False, quiet=True)
    assert capsys.readouterr().err == ""


# -- a fix raised below both callers names the option and the keyword -----------------------------------------


def test_either_names_the_option_and_its_keyword():
    """One style for every such fix (fixapi2's ``--input none or signal='none'``), the keyword from one table."""
    from fmu_opinf._validate import DT_T_END, ME, either, patterns_said, setting_said

    assert either("--input", "signal", "none") == "--input none or signal='none'"
    assert either("--dt", value=0.02) == "--dt 0.02 or dt=0.02"
    assert either("--dt") == "--dt or dt="
    assert either("--no-refine") == "--no-refine or refine=False"
    assert either("--in-process") == "--in-process or isolate=False"
    assert either("--positions", value="mass[1].s") == "--positions \"mass[1].s\" or positions='mass[1].s'"
    assert ME == "--interface me or interface='me'"
    assert DT_T_END == "--dt and --t-end or dt= and t_end="
    assert setting_said("k") == "--set k or parameters['k']"
    assert setting_said("k", 2.0) == "--set k=2.0 or parameters['k']=2.0"
    assert patterns_said(positions="a,b", velocities="c") == \
        "--positions \"a,b\" --velocities \"c\" or positions='a,b', velocities='c'"


def test_a_misnamed_parameter_is_named_in_both_vocabularies(fmu, tmp_path):
    """Was ``--set stifness_scale: ... has no variable`` for ``parameters={"stifness_scale": 2}`` in Python."""
    with pytest.raises(InputSpecError) as caught:
        snapshots.record_to_file(str(fmu), tmp_path / "s.h5", STEP, dt=0.1, t_end=1.0, quiet=True,
                                 parameters={"stifness_scale": 2.0})
    _one_line(caught.value, "--set stifness_scale or parameters['stifness_scale']: VocabChain.fmu has no variable "
                            "'stifness_scale' (did you mean stiffness_scale")


def test_an_fmu_option_on_a_builtin_source_is_named_in_both_vocabularies():
    """Was ``--outputs applies to fmu sources`` for ``record("builtin:...", outputs=...)``."""
    with pytest.raises(InputSpecError) as caught:
        snapshots.record("builtin:anchored-msd", STEP, 0.1, 1.0, quiet=True, outputs="y[1]")
    _one_line(caught.value, "--outputs or outputs= applies to fmu sources, not to builtin:anchored-msd")
    with pytest.raises(InputSpecError) as caught:
        open_source("builtin:anchored-msd", parameters={"k": 1.0})
    _one_line(caught.value, "--set or parameters= applies to fmu sources")


def test_the_aliasing_warning_names_the_step_in_both_vocabularies():
    """Was ``record with --dt 0.2 or below and --t-end 300`` (audit 81c F8) for a fit called from Python."""
    from fmu_opinf.fit._training_checks import _warn_if_modes_above_nyquist

    with pytest.warns(FmuOpinfWarning, match=r"above the 6.28 rad/s \(pi/dt\) .*; record with --dt 0.2 or dt=0.2 "
                                             r"\(or a smaller step\) and --t-end 300 or t_end=300.0 \(this "
                                             r"recording's end"):
        _warn_if_modes_above_nyquist([(-0.1, 10.0)], 0.5, 300.0)


def test_the_training_miss_advice_names_the_patterns_in_both_vocabularies():
    """Was ``check that --positions names positions only`` (audit 81c F5) in a warning of fit_rom."""
    from fmu_opinf.fit._training_checks import _miss_causes

    causes = _miss_causes(3, [], [], True, None, None, [], {})
    text = causes[-1]
    assert "that --positions or positions= names positions only" in text, text
    assert "the refinement may reach them; --r or r=)" in text and "(--interface me or interface='me')" in text
    assert "the SDP solution unrefined (--no-refine or refine=False)" in text
