"""Runs that are fitted together share one step (audit 72, F2 and F6).

Before: a run table without --dt gave each row its own automatic window (an impulse row at dt 0.02, a harmonic
row at 0.1), and ``fit`` on the folder then silently dropped the output-error refinement, the least-squares
candidate, the order search and the training-miss check (the ROM was 15-51 % of range off its own training
inputs); two ``--input`` tables of different lengths were both cut to the shorter one without a word.
The references are independent of the table code: each row recorded alone (its own automatic window), the input
tables' own values (np.interp), and the steps the files were recorded with.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from fmu_opinf import lti_fmus, runs
from fmu_opinf.errors import FmuOpinfWarning, InputSpecError
from fmu_opinf.fit import fit_rom_file
from fmu_opinf.snapshots import Snapshots, record_to_file

from conftest import build_fmu_set

pytestmark = pytest.mark.fmu

ROWS = {"imp": "impulse:amplitude=100,t0=2,width=0.5", "harm": "harmonic:amplitude=5,omega=1.3"}


@pytest.fixture(scope="module")
def fmu(request, tmp_path_factory) -> Path:
    def build(folder, item):
        built = lti_fmus.build_lti_fmu(lti_fmus.chain_model(2, name="Steps"), folder / "steps.fmu",
                                       identifier="TableSteps_chain")
        return item, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-table-steps", build, ["chain"])["chain"]


@pytest.fixture(scope="module")
def alone(fmu, tmp_path_factory) -> dict[str, Snapshots]:
    """Each row recorded on its own (its own automatic window): the reference steps and ends."""
    folder = tmp_path_factory.mktemp("alone")
    for name, spec in ROWS.items():
        record_to_file(fmu, folder / f"{name}.h5", spec, quiet=True, isolate=False)
    return {name: Snapshots.load(folder / f"{name}.h5") for name in ROWS}


def _step(run) -> float:
    return float(run.t[1] - run.t[0])


def _table(folder: Path) -> Path:
    lines = ["name,input"] + [f'{name},"{spec}"' for name, spec in ROWS.items()]
    (folder / "table.csv").write_text("\n".join(lines) + "\n")
    return folder / "table.csv"


@pytest.mark.slow
def test_a_run_table_without_dt_records_every_row_at_the_finest_of_the_rows_own_steps(fmu, alone, tmp_path,
                                                                                        monkeypatch):
    own = {name: _step(data.runs[0]) for name, data in alone.items()}
    assert len(set(own.values())) == 2   # the premise: alone, the rows take different steps
    report = runs.record_runs(fmu, _table(tmp_path), tmp_path / "runs", isolate=False, quiet=True)
    report.raise_for_failures()
    for name, data in alone.items():
        run = Snapshots.load(tmp_path / "runs" / f"{name}.h5").runs[0]
        assert _step(run) == pytest.approx(min(own.values()), rel=1e-12)
        assert abs(run.t[-1] - data.runs[0].t[-1]) < own[name]   # each row to its own end
    monkeypatch.setattr(runs, "row_window", _no_pilots)   # a rerun of a done table needs no pilots
    again = runs.record_runs(fmu, _table(tmp_path), tmp_path / "runs", isolate=False, quiet=True)
    assert [outcome.status for outcome in again.outcomes] == ["skipped", "skipped"]


def _no_pilots(*args, **kwargs):
    raise AssertionError("the rows' pilots ran again")


@pytest.mark.slow
def test_a_row_added_with_a_finer_step_records_the_done_rows_again_at_it(fmu, alone, tmp_path):
    own = {name: _step(data.runs[0]) for name, data in alone.items()}
    coarse = max(own, key=own.get)
    (tmp_path / "one.csv").write_text(f'name,input\n{coarse},"{ROWS[coarse]}"\n')
    runs.record_runs(fmu, tmp_path / "one.csv", tmp_path / "runs", isolate=False, quiet=True).raise_for_failures()
    both = runs.record_runs(fmu, _table(tmp_path), tmp_path / "runs", isolate=False, quiet=True)
    assert [outcome.status for outcome in both.outcomes] == ["recorded", "recorded"]
    for name in ROWS:
        assert _step(Snapshots.load(tmp_path / "runs" / f"{name}.h5").runs[0]) == pytest.approx(
            min(own.values()), rel=1e-12)


@pytest.mark.slow
def test_the_table_says_the_step_it_shares(fmu, alone, tmp_path, capsys):
    runs.record_runs(fmu, _table(tmp_path), tmp_path / "runs", isolate=False, quiet=False).raise_for_failures()
    own = {name: _step(data.runs[0]) for name, data in alone.items()}
    err = capsys.readouterr().err
    assert f"every row recorded at dt={min(own.values()):g}" in err
    assert all(f"{name} {step:g}" in err for name, step in own.items())


def test_fit_on_runs_of_different_steps_says_what_is_off_and_the_fix(fmu, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for name, dt in (("a", 0.02), ("b", 0.05)):
        record_to_file(fmu, folder / f"{name}.h5", ROWS["imp"], dt=dt, t_end=20.0, quiet=True, isolate=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit_rom_file(folder, tmp_path / "rom.h5", r=2, quiet=True)
    said = [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)
            and "different steps" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in caught]
    assert "(0.02, 0.05)" in said[0] and "refinement" in said[0] and "order search" in said[0]
    assert "--dt" in said[0]


def test_fit_on_runs_of_one_step_refines_without_that_warning(fmu, tmp_path):
    folder = tmp_path / "same"
    folder.mkdir()
    for name, spec in ROWS.items():
        record_to_file(fmu, folder / f"{name}.h5", spec, dt=0.05, t_end=20.0, quiet=True, isolate=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rom = fit_rom_file(folder, tmp_path / "rom.h5", r=2, quiet=True)
    assert not [w for w in caught if "different steps" in str(w.message)]
    assert rom.fit_info.get("refinement")


def _input_table(path: Path, end: float, omega: float) -> Path:
    t = np.arange(0.0, end + 1e-9, 0.01)
    np.savetxt(path, np.column_stack([t, 5.0 * np.sin(omega * t)]), delimiter=",", header="time,F", comments="")
    return path


def test_input_tables_of_different_lengths_are_each_recorded_to_their_own_end(fmu, tmp_path):
    long, short = _input_table(tmp_path / "long.csv", 40.0, 0.9), _input_table(tmp_path / "short.csv", 20.0, 2.0)
    summary = record_to_file(fmu, tmp_path / "t.h5", [str(long), str(short)], quiet=True, isolate=False)
    data = Snapshots.load(tmp_path / "t.h5")
    assert [float(run.t[-1]) for run in data.runs] == pytest.approx([40.0, 20.0], abs=1e-9)
    for run, path in zip(data.runs, (long, short)):
        reference = np.loadtxt(path, delimiter=",", skiprows=1)
        # the file's u[i] is the input held over the step that ends at t[i]: the table's value at t[i - 1]
        assert np.allclose(run.u[0, 1:], np.interp(run.t[:-1], reference[:, 0], reference[:, 1]), atol=1e-12)
    assert "each run to its input table's last time: 40, 20" in summary.describe()


def test_a_window_that_is_no_window_is_a_one_line_error(fmu, tmp_path):
    with pytest.raises(InputSpecError, match="not an automatic window.*Window.as_dict"):
        record_to_file(fmu, tmp_path / "w.h5", ROWS["imp"], window={"dt": 0.1}, quiet=True, isolate=False)


@pytest.mark.slow
def test_a_table_on_a_cluster_shares_the_step_as_in_this_process(fmu, alone, tmp_path):
    own = {name: _step(data.runs[0]) for name, data in alone.items()}
    report = runs.record_runs(fmu, _table(tmp_path), tmp_path / "runs", scheduler="local:1", isolate=False,
                              quiet=True)
    report.raise_for_failures()
    for name, data in alone.items():
        run = Snapshots.load(tmp_path / "runs" / f"{name}.h5").runs[0]
        assert _step(run) == pytest.approx(min(own.values()), rel=1e-12)
        assert abs(run.t[-1] - data.runs[0].t[-1]) < own[name]
