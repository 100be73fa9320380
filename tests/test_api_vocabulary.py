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
def anchored_rom(tmp_path_factory):
    """The file of a ROM of the anchored chain (g = 12, r = 3)."""
    folder = tmp_path_factory.mktemp("vocab")
    snaps = snapshots.record(BuiltinSource("anchored-msd", g=12), TRAIN, 0.5, 40.0, quiet=True)
    rom = fit_rom(snaps, r=3, quiet=True)
    return rom.save(folder / "rom.h5")


@pytest.fixture(scope="module")
def comparison(anchored_rom):
    """A comparison of a ROM of the anchored chain (g = 12, r = 3) with its source."""
    return compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
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


# -- compare's fixes and progress line, export's and the overwrite escape, in both vocabularies (api83) ----------
# (fix82b left them: compare.py and export.py were being edited then; each test fails on the code before)


def test_the_new_sayings_name_the_option_and_its_keyword():
    from fmu_opinf._validate import either, values_said

    assert either("--step") == "--step or step="
    assert either("--force") == "--force or overwrite=True"
    assert values_said(("--input", "impulse:t0=2"), ("--t-end", 60.0)) == \
        "--input \"impulse:t0=2\" --t-end 60 or signal='impulse:t0=2', t_end=60.0"


def test_compares_order_advice_names_r_in_both_vocabularies():
    """Was ``(fit --r 8, then compare again)``, ``snapshots --input at these loads``, ``fit --r up to the snapshot
    rank``: fit_rom(r=) and record(signal=) for a Python caller."""
    metrics = {"order": {"r": 4, "chosen": "energy", "snapshot_rank": 10, "tried": []},
               "per_output": {"y": {"relative_max_variation": 0.05}}}
    assert "(fit --r 8 or r=8, then compare again)" in compare.order_note(metrics)
    floor = {**metrics, "order": {**metrics["order"], "noise_floor": 3}}
    assert "(fit --r 2 or r=2, then compare again)" in compare.order_note(floor)
    beyond = {**metrics, "input_beyond_training": {"ratio": 100.0, "input": "F"}}
    note = compare.order_note(beyond)
    assert "(snapshots --input or signal= at these loads)" in note and "(fit --r 8 or r=8) fits only" in note, note
    missed = {**metrics, "training_miss": {"rms": 0.3, "output": "y", "run": "run 0"}}
    assert "(fit --r or r= up to the snapshot rank 10, see fit's warning)" in compare.training_miss_note(missed)


def test_compares_end_and_replay_fixes_name_t_end_in_both_vocabularies():
    """Was ``give compare --t-end below 5`` and ``compare --input '...' --t-end 60 replays that training run``."""
    from fmu_opinf.compare._run import _past_termination
    from fmu_opinf.compare._training import _replay_hint
    from fmu_opinf.sources import StepError
    from fmu_opinf.sources._cosimulation import TERMINATED

    stopped = StepError(f"m.fmu {TERMINATED} at t=5; record a shorter run (--t-end or t_end= below 5)", 10, 5.0)
    said = str(_past_termination(stopped, 20.0, end_given=False))
    assert said.endswith("(compare ran to its default t_end=20, four times the training's end; give compare "
                         "--t-end or t_end= below 5)"), said
    hint = _replay_hint({"run": f"run 0 ({TRAIN})"}, {"t_train_end": 60.0})
    assert hint == f"; compare --input \"{TRAIN}\" --t-end 60 or signal='{TRAIN}', t_end=60.0 replays that training run"


def test_compares_source_option_fixes_name_the_keyword(anchored_rom):
    """compare takes a source's options as keywords (since api84; ``source_options`` still): ``--start-time applies
    to fmu sources`` told a Python caller nothing; then ``source_options['start_time']``, now ``start_time=`` as
    everywhere else."""
    from types import SimpleNamespace

    from fmu_opinf.compare._simulate import _in_source_order

    with pytest.raises(InputSpecError) as caught:
        compare.compare(anchored_rom, "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
                        source_options={"g": 12, "start_time": 1.0})
    _one_line(caught.value, "--start-time or start_time= applies to fmu sources, not to builtin:")
    source = SimpleNamespace(input_names=["F1", "F3"])
    with pytest.raises(InputSpecError) as caught:
        _in_source_order(np.zeros((2, 3)), ["F2", "F1"], source, "m.fmu")
    _one_line(caught.value, "compare drives the ROM's inputs: leave out --inputs or inputs=, or give --inputs F2,F1 or "
                            "inputs='F2,F1'")


def test_compares_test_input_fixes_and_progress_line_name_signal(anchored_rom, capsys):
    """Was ``no --input given: comparing on ...`` (and ``snapshots``' twin ``no --input given: recording ...``),
    ``pass --input SPEC``, ``pass --input with a smaller amplitude``, ``a shorter --t-end keeps them nearer``."""
    from pathlib import Path

    from fmu_opinf.compare._run import _default_test_input
    from fmu_opinf.compare._training import _past_training

    compare.compare(anchored_rom, "builtin:anchored-msd", t_end=10.0, source_options={"g": 12, "isolate": False})
    assert capsys.readouterr().err.startswith("no --input or signal= given: comparing on harmonic:")
    snapshots.record(BuiltinSource("anchored-msd", g=4), dt=0.5, t_end=5.0)
    assert "no --input or signal= given: recording the impulse training input" in capsys.readouterr().err
    with pytest.raises(InputSpecError) as caught:
        _default_test_input(Path("old.fmu"), {"provenance": {}}, 0.5, 10.0)
    _one_line(caught.value, "carries none (exported before 2026-12-06); pass a test input, e.g. --input "
                            "\"harmonic:amplitude=1,omega=0.2\" or signal='harmonic:amplitude=1,omega=0.2'")
    info = {"provenance": {"training_runs": [{"output_peak": [1.0]}], "snapshots": {}}}
    y = np.array([[0.0, 2.0]])
    with pytest.warns(FmuOpinfWarning, match=r"may miss a mode of the model there; pass --input or signal= with a "
                                             r"smaller amplitude"):
        _past_training(y, np.array([[0.0, 0.5]]), ["y"], info, "m.fmu")
    with pytest.warns(FmuOpinfWarning, match=r"take it there in the ROM too: a shorter --t-end or t_end= keeps them"):
        _past_training(y, np.array([[0.0, 3.0]]), ["y"], info, "m.fmu")


def test_an_existing_output_names_force_and_overwrite_in_one_style(anchored_rom, tmp_path):
    """Was ``pass overwrite=True (--force)`` (snapshot files, _hdf5) beside ``replace it with overwrite=True (command
    line: --force)`` (fit_rom_file, export_fmu): one text, option first, as every other fix."""
    from fmu_opinf import export
    from fmu_opinf._hdf5 import atomic_h5
    from fmu_opinf.errors import FMUError
    from fmu_opinf.fit import fit_rom_file

    fix = "exists; pass --force or overwrite=True to replace it"
    taken = tmp_path / "taken.h5"
    taken.write_bytes(b"")
    with pytest.raises(FileExistsError, match=fix):
        with atomic_h5(taken):
            pass
    snaps = snapshots.record(BuiltinSource("anchored-msd", g=4), TRAIN, 0.5, 10.0, quiet=True)
    saved = snaps.save(tmp_path / "s.h5")
    with pytest.raises(FileFormatError, match=fix):
        snaps.save(saved)
    with pytest.raises(FileExistsError, match=fix):
        fit_rom_file(saved, taken, quiet=True)
    (tmp_path / "rom.fmu").write_bytes(b"")
    with pytest.raises(FMUError, match=fix):
        export.export_fmu(anchored_rom, tmp_path / "rom.fmu")


def test_exports_set_warnings_name_both_vocabularies():
    """The training's ``--set`` values the ROM FMU cannot declare: was ``(--set)`` / ``another --set``."""
    from fmu_opinf.export import _warn_if_settings_not_declared

    snaps = {"fmu_settings": {"mass[1].s": 0.1}}
    with pytest.warns(FmuOpinfWarning, match=r"the training set mass\[1\]\.s \(--set or parameters=\); record the "
                                             r"snapshots again"):
        _warn_if_settings_not_declared({"snapshots": snaps}, [], [])
    recorded = {"names": ["k"], "types": ["Real"], "values": [1.0], "units": [""], "set": []}
    with pytest.warns(FmuOpinfWarning, match=r"the training set mass\[1\]\.s \(--set or parameters=\), which the ROM "
                                             r"FMU does not declare: .* with another --set or parameters= value"):
        _warn_if_settings_not_declared({"snapshots": {**snaps, "source_parameters": recorded}}, [], [])


def test_compares_warnings_and_grid_fix_name_both_vocabularies(anchored_rom, monkeypatch):
    """Was ``(snapshots --input at these loads)``, ``(a larger --r first ...)``, ``record without it (snapshots
    --outputs)`` and ``no --t-end given ...; pass --t-end``."""
    from fmu_opinf.compare import _run, _training

    with pytest.warns(FmuOpinfWarning, match=r"train with an input nearer this one \(snapshots --input or signal= at "
                                             r"these loads\)"):
        _training._warn_beyond_training({"given": 100.0, "input": "F", "ratio": 100.0, "trained": 1.0}, "m.fmu")
    monkeypatch.setattr(_training, "_training_miss", lambda side, info: {"rms": 0.3, "output": "y", "run": "run 0"})
    with pytest.warns(FmuOpinfWarning, match=r"\(a larger --r or r= first where its order search kept lowering"):
        _training._warn_if_training_missed(None, {"t_train_end": None})
    metrics = {"linear_fits": ["E"], "per_output": {"E": {"relative_max": 0.1}}}
    assert "record without it (snapshots --outputs or outputs=) where not needed" in compare.linear_fit_note(metrics)
    side_info = _run._rom_side_info
    monkeypatch.setattr(_run, "_rom_side_info", lambda side: {**side_info(side), "t_train_end": None})
    with pytest.raises(FmuOpinfError) as caught:
        compare.compare(anchored_rom, "builtin:anchored-msd", TEST, quiet=True, source_options={"g": 12})
    _one_line(caught.value, "no --t-end or t_end= given and the ROM does not record a usable training end time (None); "
                            "pass --t-end or t_end=")


def test_an_exact_step_map_that_is_not_finite_names_step_in_both_vocabularies(anchored_rom, tmp_path):
    """Was ``choose a smaller --step`` (export_fmu(step=) in Python); the Newmark path: test_one_line_errors."""
    from fmu_opinf import export
    from fmu_opinf.errors import DataError
    from fmu_opinf.rom import SecondOrderROM

    def overflowing(dt: float) -> None:   # (where the matrix exponential fails; at dt=1e300 it returns inf)
        raise np.linalg.LinAlgError("overflow")

    model = SecondOrderROM.load(anchored_rom)
    model.integrator, model.step_map = "exact", overflowing
    with pytest.raises(DataError, match=r"the ROM's exact step map at dt=0.5 is not finite; choose a smaller "
                                        r"--step or step=$"):
        export.export_fmu(model, tmp_path / "x.fmu")
    assert list(tmp_path.iterdir()) == []
