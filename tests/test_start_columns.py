"""Run table ``start:`` columns are initial conditions of one model (audit 73 F2).

A table whose every row had its own ``start:`` value gave a ROM, and a ROM FMU, that started from the first row's
state instead of the model's own (the FMU's free response 174-180 % of range off the model), and ``fit`` called the
start values "settings" ("fit one ROM per setting"), as did ``compare --runs``.  A ``start:`` column naming a
parameter recorded another model without a word.  References: the exact zero-order-hold response of the model from
its declared start (:func:`fmu_opinf.lti_fmus.zoh_response`), not the tool's output.
"""

from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest
from conftest import build_fmu_set, miss_against_model

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots._merge import merge_differences

#: The model's own start: the last mass 0.05 m out (declared start of ``mass[4].s``).
MODEL = lti_fmus.chain_model(4, inputs=(-1,), x0=[0.0, 0.0, 0.0, 0.05], name="OwnStart")
#: Every row its own start; neither is the model's.
EVERY_ROW = ('name,input,start:mass[4].s\na,"impulse:amplitude=100,t0=2,width=0.5",0.2\n'
             'b,"harmonic:amplitude=1,omega=0.9",-0.1\n')
GRID = ["--dt", "0.05", "--t-end", "20", "-q"]


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """The chain (Modelica naming, states with start values) and an FMI 3 array chain (``x`` calculated from the
    parameter ``x_start``)."""
    def build(folder, item):
        if item == "chain":
            return item, lti_fmus.build_lti_fmu(MODEL, folder / "OwnStart.fmu", identifier="OwnStart").path
        chain = lti_fmus.MassChain(n=4, start_position=0.01)
        return item, lti_fmus.build_lti_fmu(chain, folder / "OwnStartArray.fmu", identifier="OwnStartArray",
                                            fmi_version="3.0", naming="array").path

    return build_fmu_set(request, tmp_path_factory, "lti-start-columns", build, ["chain", "array"])


def _record(fmu, folder, table: str) -> int:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "runs.csv").write_text(table)
    return main(["snapshots", str(fmu), "--runs", str(folder / "runs.csv"), "-o", str(folder / "snaps"), *GRID])


def _fmu_free_response_miss(rom_fmu, t_end: float, dt: float) -> float:
    """Largest output error over its range of the ROM FMU's free response against the exact model's."""
    import fmpy

    t = np.arange(0.0, t_end + dt / 2, dt)
    reference = lti_fmus.zoh_response(MODEL, t, np.zeros((1, t.size))).y
    result = fmpy.simulate_fmu(str(rom_fmu), stop_time=t[-1], output_interval=dt, output=["y[1]", "y[2]"])
    y = np.array([result["y[1]"], result["y[2]"]])[:, :t.size]
    return float(np.max(np.abs(y - reference).max(axis=1) / np.ptp(reference, axis=1)))


@pytest.mark.fmu
def test_every_row_with_its_own_start_gives_a_rom_and_fmu_starting_at_the_models_start(fmus, tmp_path, capsys):
    """Before: the ROM and its FMU started at row a's 0.2 (free response 1.8 x range off the model from 0.05), and
    fit and export warned of "different settings"."""
    assert _record(fmus["chain"], tmp_path, EVERY_ROW) == 0
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "snaps"), "-o", str(tmp_path / "rom.h5")]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "settings" not in err and "the ROM starts from the model's own start" in err, err
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    assert rom.fit_info["start"]["from"] == "the model's own start"
    # measured 1.7e-14 (free response), 1.3e-14 (harmonic); before: 1.8 and 1.36
    assert miss_against_model(rom, MODEL, "none", 20.0) < 1e-10
    assert miss_against_model(rom, MODEL, "harmonic:amplitude=1,omega=0.9", 20.0) < 1e-10
    assert main(["export", str(tmp_path / "rom.h5"), "-o", str(tmp_path / "rom.fmu"), "-q"]) == 0
    assert "settings" not in capsys.readouterr().err
    assert _fmu_free_response_miss(tmp_path / "rom.fmu", 20.0, rom.dt) < 1e-10   # measured 2.7e-14; before 1.8


def _strip_stored_start(folder) -> None:
    """Make the row files of ``folder`` like files recorded before the model's start was stored with them."""
    import h5py

    from fmu_opinf._seal import seal_attributes

    for path in sorted(folder.glob("*.h5")):
        with h5py.File(path, "r+") as f:
            for group in f["runs"].values():
                for name in ("model_start_x0", "model_start_v0"):
                    group.pop(name, None)
                if "model_start" in group.attrs:
                    del group.attrs["model_start"]
            seal_attributes(f)


@pytest.mark.fmu
def test_each_row_file_stores_the_models_declared_start_read_once(fmus, tmp_path, monkeypatch):
    """The snapshot stage stores the model's own start with every row that has start: values: the FMU's declared
    start (``mass[4].s`` 0.05, at rest), not the row's; one initialization for a table whose rows share their
    settings (before: nothing stored; the fit opened the FMU again)."""
    from fmu_opinf import _model_start
    from fmu_opinf.snapshots import Snapshots

    calls = []
    initialize = _model_start._initialized
    monkeypatch.setattr(_model_start, "_READ", {})
    monkeypatch.setattr(_model_start, "_initialized", lambda *a: calls.append(a) or initialize(*a))
    assert _record(fmus["chain"], tmp_path, EVERY_ROW) == 0
    assert len(calls) == 1
    for name, start in (("a", 0.2), ("b", -0.1)):
        with Snapshots.open(tmp_path / "snaps" / f"{name}.h5") as snaps:
            run = snaps.runs[0]
            assert run.x0[3] == start   # (the row's own start)
            np.testing.assert_array_equal(run.model_start["x0"], MODEL.x0)
            np.testing.assert_array_equal(run.model_start["v0"], np.zeros(4))
            assert run.attrs["model_start"] == {"row": {"number": 1, "name": "a"}, "settings": {}}


@pytest.mark.fmu
def test_an_array_fmus_stored_start_is_its_declared_x_start_whatever_the_rows_set(fmus, tmp_path, monkeypatch):
    """FMI 3 array chain, ``x`` calculated from ``x_start`` (declared 0.01 each): rows that start other states
    (``v_start[1]``, ``x_start[2]``) store the model's start, read once: what the fit used to read from the FMU."""
    from fmu_opinf import _model_start
    from fmu_opinf.snapshots import Snapshots

    calls = []
    initialize = _model_start._initialized
    monkeypatch.setattr(_model_start, "_READ", {})
    monkeypatch.setattr(_model_start, "_initialized", lambda *a: calls.append(a) or initialize(*a))
    table = ('name,input,start:v_start[1],start:x_start[2]\na,"impulse:amplitude=100,t0=2,width=0.5",0.5,\n'
             'b,"harmonic:amplitude=1,omega=0.9",,0.3\n')
    assert _record(fmus["array"], tmp_path, table) == 0
    assert len(calls) == 1
    for name, x0, v0 in (("a", [0.01] * 4, [0.5, 0, 0, 0]), ("b", [0.01, 0.3, 0.01, 0.01], [0] * 4)):
        with Snapshots.open(tmp_path / "snaps" / f"{name}.h5") as snaps:
            run = snaps.runs[0]
            np.testing.assert_array_equal(np.r_[run.x0, run.v0], np.r_[x0, v0])   # (the row's own start)
            np.testing.assert_array_equal(run.model_start["x0"], np.full(4, 0.01))
            np.testing.assert_array_equal(run.model_start["v0"], np.zeros(4))


@pytest.mark.fmu
def test_the_fit_starts_at_the_models_start_after_the_fmu_is_deleted(fmus, tmp_path, capsys):
    """A fit where the FMU is gone (another machine, a snapshots file sent on) starts at the model's own start, from
    the snapshots alone, also after a merge and save (before: a warning, and the ROM started from row a's 0.2: free
    response 1.8 x range off the model)."""
    from fmu_opinf.snapshots import Snapshots

    fmu = shutil.copy(fmus["chain"], tmp_path / "gone.fmu")
    assert _record(fmu, tmp_path, EVERY_ROW) == 0
    (tmp_path / "gone.fmu").unlink()
    merged = Snapshots()
    for name in ("a", "b"):
        merged.append(Snapshots.load(tmp_path / "snaps" / f"{name}.h5"))
    merged.save(tmp_path / "merged.h5")
    capsys.readouterr()
    for data, rom_file in ((tmp_path / "snaps", tmp_path / "rom.h5"), (tmp_path / "merged.h5", tmp_path / "m.h5")):
        with warnings.catch_warnings():
            warnings.simplefilter("error", FmuOpinfWarning)
            assert main(["fit", str(data), "-o", str(rom_file)]) == 0
        err = " ".join(capsys.readouterr().err.split())
        assert "the ROM starts from the model's own start" in err and "read when the snapshots were recorded" in err
        rom = SecondOrderROM.load(rom_file)
        assert rom.fit_info["start"]["from"] == "the model's own start"
        # measured 8.2e-15 (free response, directory); before: 1.80 (the first row's start)
        assert miss_against_model(rom, MODEL, "none", 20.0) < 1e-10


@pytest.mark.fmu
def test_an_older_file_without_the_stored_start_reads_it_from_the_fmu_or_says_it_cannot(fmus, tmp_path, capsys):
    """Files recorded before the start was stored: the fit initializes the FMU as before; with the FMU gone, the ROM
    keeps the first row's start and one warning says so and how to fix it."""
    fmu = shutil.copy(fmus["chain"], tmp_path / "gone.fmu")
    assert _record(fmu, tmp_path, EVERY_ROW) == 0
    _strip_stored_start(tmp_path / "snaps")
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "snaps"), "-o", str(tmp_path / "rom.h5")]) == 0
    assert "read from the FMU now" in " ".join(capsys.readouterr().err.split())
    assert miss_against_model(SecondOrderROM.load(tmp_path / "rom.h5"), MODEL, "none", 20.0) < 1e-10
    (tmp_path / "gone.fmu").unlink()
    assert main(["fit", str(tmp_path / "snaps"), "-o", str(tmp_path / "rom.h5"), "-q", "--force"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "every training run has its own start: values, and the model's own start cannot be read" in err, err
    assert "is not there any more" in err
    assert "starts from the first run's start (mass[4].s=0.2)" in err
    assert "add a run table row without start: values" in err


@pytest.mark.fmu
def test_a_start_that_could_not_be_read_when_recorded_is_said_without_opening_the_fmu(fmus, tmp_path, capsys,
                                                                                         monkeypatch):
    """An initialization that failed at recording time is stored as its reason; the fit says it (with the fix) and
    does not try the FMU again."""
    from fmu_opinf import _model_start

    monkeypatch.setattr(_model_start, "_READ", {})
    monkeypatch.setattr(_model_start, "_initialized", lambda *a: "OwnStart.fmu could not be initialized (boom)")
    assert _record(fmus["chain"], tmp_path, EVERY_ROW) == 0
    monkeypatch.setattr(_model_start, "_source_start", lambda *a: pytest.fail("the fit opened the FMU"))
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "snaps"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "the model's own start cannot be read: OwnStart.fmu could not be initialized (boom) (when the snapshots " \
           "were recorded)" in err, err
    assert "add a run table row without start: values" in err


@pytest.mark.fmu
def test_a_damaged_stored_start_is_refused_in_one_line(fmus, tmp_path):
    """A stored start of the wrong length (a damaged or hand-edited file) is no start to begin a ROM from."""
    import h5py

    from fmu_opinf.errors import FileFormatError
    from fmu_opinf.snapshots import Snapshots

    assert _record(fmus["chain"], tmp_path, EVERY_ROW) == 0
    with h5py.File(tmp_path / "snaps" / "a.h5", "r+") as f:
        f["runs/0000"].pop("model_start_x0", None)
        f["runs/0000"].create_dataset("model_start_x0", data=np.zeros(3))
    with pytest.raises(FileFormatError, match=r"run 0000: model_start_x0 is not 4 finite numbers \(one per position\)"
                       r"; the file is damaged"):
        Snapshots.open(tmp_path / "snaps" / "a.h5")


@pytest.mark.fmu
def test_a_start_column_naming_a_parameter_or_a_calculated_state_is_refused_in_one_line(fmus, tmp_path, capsys):
    """``start:mass_scale`` recorded another model (before: no word); ``start:x[4]`` of an FMI 3 array whose ``x``
    is calculated from ``x_start`` was refused without the column that works."""
    table = 'name,input,start:mass_scale\na,"impulse:amplitude=100,t0=2,width=0.5",2\n'
    assert _record(fmus["chain"], tmp_path / "param", table) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column start:mass_scale: mass_scale is a parameter, not a state" in err[0], err
    assert "give a parameter as column set:mass_scale" in err[0]
    table = 'name,input,start:x[4]\na,"impulse:amplitude=100,t0=2,width=0.5",0.2\n'
    assert _record(fmus["array"], tmp_path / "array", table) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column start:x[4]:" in err[0] and "give column start:x_start[4]" in err[0], err


def _parts(**settings) -> dict:
    """Merged snapshot attributes of parts ``a.h5``, ``b.h5`` with the given settings each."""
    return {"position_names": [f"mass[{i}].s" for i in range(1, 5)],
            "velocity_names": [f"mass[{i}].v" for i in range(1, 5)],
            "merged_parts": {"parts": [{"file": f"{name}.h5", "fmu_settings": value}
                                       for name, value in settings.items()]}}


def test_start_values_of_states_are_no_settings_in_the_merge_warning():
    """Parts that differ only in the start of a recorded position or velocity (or of an array's ``x_start``) are one
    training set: no warning (before: "different settings ... fit one ROM per setting"); a parameter still is."""
    assert merge_differences(_parts(a={"mass[4].s": 0.2}, b={"mass[4].s": -0.1, "mass[1].v": 1.0})) is None
    arrays = _parts(a={"x_start[4]": 0.2}, b={"x_start[4]": -0.1})
    arrays.update(position_names=["x[1]", "x[2]"], velocity_names=["v[1]", "v[2]"])
    assert merge_differences(arrays) is None
    said = merge_differences(_parts(a={"mass[4].s": 0.2}, b={"mass[4].s": 0.2, "stiffness_scale": 2.5}))
    assert said is not None and "different settings (stiffness_scale: a.h5 default, b.h5 2.5)" in said
    assert "mass[4].s" not in said


def test_compare_with_another_start_value_of_a_state_is_no_model_change():
    """``compare --runs`` rows with their own ``start:``: before, each warned "a ROM describes the model it was
    trained on"; a parameter given another value still warns."""
    from fmu_opinf.compare._training import _training_settings

    trained = {"stiffness_scale": "1", "mass[4].s": "0.05"}   # (recorded with --set mass[4].s=0.05)
    info = {"provenance": {"snapshots": {"source_kind": "fmu", "fmu_settings": trained,
                                         "position_names": ["mass[4].s"], "velocity_names": ["mass[4].v"]}}}
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        options = _training_settings(info, "model.fmu", {"parameters": {"mass[4].s": 0.2, "mass[4].v": 1.0}})
    assert options["parameters"] == {**trained, "mass[4].s": 0.2, "mass[4].v": 1.0}
    with pytest.warns(FmuOpinfWarning, match="compared with stiffness_scale=2.5, but the ROM was trained with"):
        _training_settings(info, "model.fmu", {"parameters": {"stiffness_scale": 2.5, "mass[4].s": 0.2}})


@pytest.mark.fmu
def test_an_interrupt_while_the_models_start_is_read_leaves_no_temporary_and_the_previous_result(fmus, tmp_path,
                                                                                                 monkeypatch, capsys):
    """A Ctrl-C while the FMU is initialized once more for the model's start (after the row was recorded into its
    hidden intermediate file) removes that file; the row's earlier result stays as it was."""
    from fmu_opinf import _model_start

    assert _record(fmus["chain"], tmp_path, EVERY_ROW) == 0
    before = {path.name: path.read_bytes() for path in (tmp_path / "snaps").iterdir()}

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(_model_start, "_READ", {})
    monkeypatch.setattr(_model_start, "_initialized", interrupted)
    changed = EVERY_ROW.replace("0.2\n", "0.3\n")   # row a changed: it is recorded again
    assert _record(fmus["chain"], tmp_path, changed) != 0
    after = {path.name: path.read_bytes() for path in (tmp_path / "snaps").iterdir()}
    assert after == before
    assert ".partial" not in capsys.readouterr().err   # (the message names no file it did not leave)
