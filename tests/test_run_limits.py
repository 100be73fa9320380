"""The latest time a run may reach: an input table's last time, a given --t-end, an FMU's termination (audit 70,
F3 and F5), and a fixed communication step that the fit must not advise against (F10).

Before: a CSV table needed both --dt and --t-end (the automatic window's pilots ran to t = 550 past a table ending
at 120, and a given --t-end alone was ignored); a table in FMU time was refused with a window that said nothing of
where table times count from; an FMU that terminates at t = 30 was refused whatever --t-end said, and compare's
default end ran into the termination with the advice "record a shorter run"; fit advised "--dt 0.02" to an FMU
that accepts only its fixed step 0.05.  The references are independent of the tool: the table's own values
(np.interp), the exact zero-order-hold response of the model (lti_fmus.zoh_response), the declared times.
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.snapshots import Snapshots

from conftest import build_fmu_set

pytestmark = pytest.mark.fmu

TABLE_END, TERMINATE, FIXED = 40.0, 20.0, 0.05


def _chain() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(2, name="Limits")


def _fast() -> lti_fmus.LinearMechanicalModel:
    """Three masses stiffened a hundredfold: modes at 22, 60 and 83 rad/s, the last above the 62.8 rad/s (pi/dt)
    of the fixed step 0.05."""
    chain = lti_fmus.chain_model(3, name="Fast")
    return dataclasses.replace(chain, K=100.0 * chain.K, D=10.0 * chain.D)


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    items = {"plain": (_chain(), {}),
             "term": (_chain(), dict(fmi_version="3.0", interfaces=("cs",), cs_terminate_at=TERMINATE)),
             "fixed": (_fast(), dict(interfaces=("cs",), cs_fixed_step=FIXED))}

    def build(folder, item):
        name, (model, options) = item
        built = lti_fmus.build_lti_fmu(model, folder / f"{name}.fmu", identifier=f"Limits_{name}", **options)
        return name, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-run-limits", build, items.items())


def _table(path: Path, start: float = 0.0) -> Path:
    """A pulse then a slow sine, at 0.01 s from ``start`` to ``start + TABLE_END``."""
    t = np.arange(0.0, TABLE_END + 1e-9, 0.01)
    u = 20.0 * np.exp(-((t - 2.0) / 0.3) ** 2) + np.sin(0.7 * t)
    np.savetxt(path, np.column_stack([t + start, u]), delimiter=",", header="time,F", comments="")
    return path


def _snapshots(fmu, out, *options) -> int:
    return main(["snapshots", str(fmu), "-o", str(out), "-q", *options])


def test_a_table_alone_records_to_its_last_time_at_the_window_step(fmus, tmp_path, capsys):
    table = _table(tmp_path / "u.csv")
    assert _snapshots(fmus["plain"], tmp_path / "s.h5", "--input", str(table)) == 0, capsys.readouterr().err
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    dt = float(run.t[1] - run.t[0])
    assert run.t[-1] == pytest.approx(TABLE_END, abs=1e-9) and dt < 0.1   # the model's periods: 1.9 s and up
    reference = np.loadtxt(table, delimiter=",", skiprows=1)
    # the file's u[i] is the input held over the step that ends at t[i]: the table's value at t[i - 1]
    assert np.allclose(run.u[0, 1:], np.interp(run.t[:-1], reference[:, 0], reference[:, 1]), atol=1e-12)


def test_a_given_t_end_with_a_table_is_honoured(fmus, tmp_path, capsys):
    table = _table(tmp_path / "u.csv")
    assert _snapshots(fmus["plain"], tmp_path / "s.h5", "--input", str(table), "--t-end", "25") == 0, \
        capsys.readouterr().err
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert 25.0 - (run.t[1] - run.t[0]) < run.t[-1] <= 25.0 + 1e-9


def test_a_table_in_fmu_time_is_refused_saying_what_to_subtract(fmus, tmp_path, capsys):
    table = _table(tmp_path / "u.csv", start=10.0)
    code = _snapshots(fmus["plain"], tmp_path / "s.h5", "--input", str(table), "--start-time", "10")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "table times count from the run's start" in err and "subtract 10" in err, err
    assert not (tmp_path / "s.h5").exists()


def test_compare_on_a_table_runs_to_its_last_time(fmus, tmp_path, capsys):
    table = _table(tmp_path / "u.csv")
    assert _snapshots(fmus["plain"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "30") == 0
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    code = main(["compare", str(tmp_path / "rom.h5"), str(fmus["plain"]), "--input", str(table),
                 "-o", str(tmp_path / "report"), "-q"])
    assert code == 0, capsys.readouterr().err
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert metrics["t_end"] == pytest.approx(TABLE_END)   # was: refused at four times the training, 120 s


def test_a_termination_in_a_pilot_ends_the_window_before_it(fmus, tmp_path, capsys):
    with warnings.catch_warnings(record=True):
        code = _snapshots(fmus["term"], tmp_path / "s.h5")
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"terminates the simulation at t={TERMINATE:g}" in err, err
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    dt = float(run.t[1] - run.t[0])
    assert TERMINATE - 2 * dt < run.t[-1] < TERMINATE
    exact = lti_fmus.zoh_response(_chain(), run.t, run.u[:, 1:]).y
    assert np.abs(run.y - exact).max() < 1e-6 * np.abs(exact).max()


def test_a_given_t_end_bounds_the_pilots_of_a_terminating_fmu(fmus, tmp_path, capsys):
    assert _snapshots(fmus["term"], tmp_path / "s.h5", "--t-end", "15") == 0, capsys.readouterr().err
    run = Snapshots.load(tmp_path / "s.h5").runs[0]
    assert 15.0 - (run.t[1] - run.t[0]) < run.t[-1] <= 15.0 + 1e-9


def test_compare_past_a_termination_names_compare_t_end(fmus, tmp_path, capsys):
    assert _snapshots(fmus["term"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "15") == 0
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    capsys.readouterr()
    code = main(["compare", str(tmp_path / "rom.h5"), str(fmus["term"]), "-o", str(tmp_path / "report"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code != 0 and f"compare --t-end or t_end= below {TERMINATE:g}" in err and "record" not in err, err


def test_fit_offers_only_a_smaller_r_at_an_fmus_fixed_step(fmus, tmp_path, capsys):
    assert _snapshots(fmus["fixed"], tmp_path / "s.h5") == 0, capsys.readouterr().err
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    err = capsys.readouterr().err
    line = next(text for text in err.splitlines() if "above the" in text and "pi/dt" in text)
    assert "fit a smaller r" in line and "--dt" not in line, line   # was: "record with --dt 0.02 or below"
    snaps = Snapshots.load(tmp_path / "s.h5")
    assert snaps.attrs["fixed_communication_step"] == FIXED and snaps.runs[0].t[1] == pytest.approx(FIXED)

    from fmu_opinf.fit._training_data import _at_fixed_step

    assert not _at_fixed_step({}, FIXED)   # a file written before says nothing: the advice stays as it was


@pytest.mark.slow
def test_compare_s_default_end_stops_before_the_termination_the_training_found(fmus, tmp_path, capsys):
    """Audit 71 F8: the default training of an FMU that terminates at t = 20 ends before it and records where
    (``auto_window["terminates_at"]``); compare's default end (four times the training's) then ran into the
    termination and failed with an error naming --t-end.  Now it stops at the last point of its grid before the
    termination, says so in one line, and the FMU's outputs up to there are the model's exact response; a --t-end
    past the termination keeps the error that names the --t-end that works."""
    from fmu_opinf.compare import compare

    with warnings.catch_warnings(record=True):
        assert _snapshots(fmus["term"], tmp_path / "s.h5") == 0, capsys.readouterr().err
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0, capsys.readouterr().err
    dt = float(Snapshots.load(tmp_path / "s.h5").runs[0].t[1])
    t0 = 1.0 + 0.5 * dt   # mid-step: the held input's switch is unambiguous
    capsys.readouterr()
    with warnings.catch_warnings(record=True):
        result = compare(tmp_path / "rom.h5", fmus["term"], f"step:amplitude=1,t0={t0!r}")
    said = [line for line in capsys.readouterr().err.splitlines() if "terminated the simulation" in line]
    assert len(said) == 1 and f"at t={TERMINATE:g}" in said[0] and "--t-end" in said[0], said
    assert result.t[-1] == pytest.approx(TERMINATE - dt, abs=1e-9)   # the last grid point before 20
    u = np.where(result.t[:-1] >= t0, 1.0, 0.0)[None, :]   # u[i]: held from t[i] to t[i + 1]
    exact = lti_fmus.zoh_response(_chain(), result.t, u).y
    assert np.abs(result.y_fom - exact).max() < 1e-6 * np.abs(exact).max()
    code = main(["compare", str(tmp_path / "rom.h5"), str(fmus["term"]), "--t-end", "30", "-o",
                 str(tmp_path / "past"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code != 0 and f"--t-end or t_end= below {TERMINATE:g}" in err, err   # (compare's line and the recording's)


@pytest.mark.slow
def test_compare_of_the_exported_rom_fmu_stops_before_the_termination_too(fmus, tmp_path, capsys):
    """The same for ``compare rom.fmu term.fmu``: the ROM FMU's provenance.json carries the training's snapshot
    notes, its automatic window with the termination among them (audit 71 F8)."""
    with warnings.catch_warnings(record=True):
        assert _snapshots(fmus["term"], tmp_path / "s.h5") == 0, capsys.readouterr().err
    dt = float(Snapshots.load(tmp_path / "s.h5").runs[0].t[1])
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0, capsys.readouterr().err
    assert main(["export", str(tmp_path / "rom.h5"), "-o", str(tmp_path / "rom.fmu"), "-q"]) == 0, \
        capsys.readouterr().err
    capsys.readouterr()
    code = main(["compare", str(tmp_path / "rom.fmu"), str(fmus["term"]), "-o", str(tmp_path / "report")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert sum("terminated the simulation at t=20" in line for line in err.splitlines()) == 1, err
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert metrics["t_end"] == pytest.approx(TERMINATE - dt, abs=1e-9)


def test_compare_on_a_table_past_a_termination_names_the_table_as_its_end(fmus, tmp_path, capsys):
    """A table that runs past the FMU's termination: compare's end was the table's last time, and the error said
    "its default t_end=40, four times the training's end" (the training ended at 15)."""
    table = _table(tmp_path / "u.csv")
    assert _snapshots(fmus["term"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "15") == 0
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    capsys.readouterr()
    code = main(["compare", str(tmp_path / "rom.h5"), str(fmus["term"]), "--input", str(table),
                 "-o", str(tmp_path / "report"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code != 0 and f"t_end={TABLE_END:g}, the input table's last time" in err, err
    assert f"compare --t-end or t_end= below {TERMINATE:g}" in err and "four times" not in err, err
