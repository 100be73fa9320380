"""Issue 17, beyond one machine: run tables recorded and compared on a local Dask cluster of two worker processes,
and the distributed POD (TSQR on dask arrays) against the in-core SVD.

One cluster serves the module (starting it takes a few seconds).  The run table has five rows of
``builtin:anchored-msd`` (g = 40); row 3 drives the model with an input so large that its states overflow at
step 45, i.e. it fails mid-run after samples were written.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
import scipy.linalg

pytest.importorskip("distributed")

from fmu_opinf import runs  # noqa: E402
from fmu_opinf.basis import PODBasis, open_snapshot_set, snapshot_files  # noqa: E402
from fmu_opinf.errors import FmuOpinfError  # noqa: E402
from fmu_opinf.snapshots import Snapshots, record_to_file  # noqa: E402

SOURCE = "builtin:anchored-msd"
SETTINGS = {"dt": 0.1, "t_end": 20.0, "g": 40}
GOOD = {
    "imp": "impulse:amplitude=100,t0=2,width=0.5",
    "harm": "harmonic:amplitude=1,omega=0.7",
    "load": "loads/case1.csv",
    "chirp": "chirp:amplitude=1,omega0=0.1,omega1=2",
}
FAILING = ("blowup", "harmonic:amplitude=1.7e308,omega=1")  # overflows to Inf at step 45 (t = 4.5)
TABLE_ORDER = ["imp", "harm", "blowup", "load", "chirp"]
LOAD_TIMES = np.arange(0.0, 25.0, 1.5)
LOAD_VALUES = np.cos(0.4 * LOAD_TIMES) + 0.1 * LOAD_TIMES


def _write_load(folder: Path, scale: float = 1.0) -> None:
    (folder / "loads").mkdir(exist_ok=True)
    lines = ["time,u"] + [f"{float(t)!r},{scale * float(v)!r}" for t, v in zip(LOAD_TIMES, LOAD_VALUES)]
    (folder / "loads" / "case1.csv").write_text("\n".join(lines) + "\n")


def _write_table(folder: Path, specs: dict[str, str], order: list[str], name: str = "runs.csv") -> Path:
    if not (folder / "loads" / "case1.csv").exists():
        _write_load(folder)
    rows = ["name,input"] + [f'{name},"{specs[name]}"' for name in order]
    path = folder / name
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def client():
    with runs.dask_client("local:2") as c:
        yield c


@pytest.fixture(scope="module")
def table(tmp_path_factory) -> Path:
    return _write_table(tmp_path_factory.mktemp("table"), {**GOOD, FAILING[0]: FAILING[1]}, TABLE_ORDER)


@pytest.fixture(scope="module")
def recorded(client, table, tmp_path_factory):
    """The same table recorded sequentially and on the cluster."""
    out = tmp_path_factory.mktemp("recorded")
    seq = runs.record_runs(SOURCE, table, out / "seq", quiet=True, **SETTINGS)
    par = runs.record_runs(SOURCE, table, out / "par", scheduler=client, quiet=True, **SETTINGS)
    return {"seq": (seq, out / "seq"), "par": (par, out / "par")}


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with Snapshots.open(path) as snaps:
        (run,) = snaps.runs
        return {name: np.asarray(getattr(run, name)[()]) for name in ("t", "u", "x", "xdot", "xddot", "y")}


# --------------------------------------------------------------------------------------------------------
# Recording a run table
# --------------------------------------------------------------------------------------------------------
def test_parallel_recording_equals_sequential(recorded):
    (seq, seq_dir), (par, par_dir) = recorded["seq"], recorded["par"]
    assert [o.status for o in par.outcomes] == ["recorded", "recorded", "failed", "recorded", "recorded"]
    assert [o.status for o in seq.outcomes] == [o.status for o in par.outcomes]
    assert len({o.worker for o in par.outcomes if o.status == "recorded"}) == 2  # both workers took rows
    for name in GOOD:
        a, b = _arrays(seq_dir / f"{name}.h5"), _arrays(par_dir / f"{name}.h5")
        assert a["x"].shape == (40, 201)
        for key in a:
            scale = max(np.abs(a[key]).max(), 1e-300)
            np.testing.assert_allclose(b[key], a[key], rtol=0, atol=1e-13 * scale, err_msg=f"{name}: {key}")


def test_each_file_holds_its_rows_input(recorded):
    """Independent of the recorder: the stored inputs are the rows' formulas and table, held over each step."""
    _, par_dir = recorded["par"]
    held = {
        "harm": lambda t: np.sin(0.7 * t),
        "load": lambda t: LOAD_VALUES[np.searchsorted(LOAD_TIMES, t + 1e-9, side="right") - 1],
    }
    for name, formula in held.items():
        data = _arrays(par_dir / f"{name}.h5")
        t, u = data["t"], data["u"][0]
        np.testing.assert_allclose(u[1:], formula(t[:-1]), atol=1e-12)  # u_i is the input over [t_{i-1}, t_i]
    with h5py.File(par_dir / "load.h5", "r") as f:
        stamp = f.attrs[runs.ROW_ATTR]
    assert '"name": "load"' in stamp and "case1.csv" in stamp


def test_failing_row_is_reported_and_the_others_are_kept(recorded):
    par, par_dir = recorded["par"]
    (failed,) = par.failed
    assert (failed.number, failed.name) == (3, "blowup")
    assert "non-finite" in failed.error and "step 45" in failed.error
    kept = par_dir / "blowup.incomplete.h5"
    assert failed.path == str(kept) and str(kept) in failed.error
    with h5py.File(kept, "r") as f:
        (group,) = f["runs"].values()
        assert not group.attrs["complete"] and int(group.attrs["k"]) == 45
    assert not (par_dir / "blowup.h5").exists()
    assert [p.name for p in snapshot_files(par_dir)] == ["chirp.h5", "harm.h5", "imp.h5", "load.h5"]
    with pytest.raises(FmuOpinfError, match=r"1 of 5 runs failed, the others are kept: row 3 \(blowup\)"):
        par.raise_for_failures()
    assert "row 3 (blowup): failed" in par.describe()


def test_rerun_skips_complete_runs_and_redoes_changed_rows(client, recorded, table, tmp_path):
    _, par_dir = recorded["par"]
    before = {p.name: p.stat().st_mtime_ns for p in par_dir.glob("*.h5")}
    again = runs.record_runs(SOURCE, table, par_dir, scheduler=client, quiet=True, **SETTINGS)
    assert [o.status for o in again.outcomes] == ["skipped", "skipped", "failed", "skipped", "skipped"]
    assert all(o.k == 201 for o in again.outcomes if o.status == "skipped")
    after = {p.name: p.stat().st_mtime_ns for p in par_dir.glob("*.h5")}
    assert {k: v for k, v in after.items() if "incomplete" not in k} == \
        {k: v for k, v in before.items() if "incomplete" not in k}
    # a changed row (same name, other input) is recorded again; rows moved within the table still count as done
    changed = _write_table(table.parent, {**GOOD, "imp": "impulse:amplitude=50,t0=2,width=0.5"},
                           ["chirp", "imp", "harm", "load"], name="changed.csv")
    third = runs.record_runs(SOURCE, changed, par_dir, scheduler=client, quiet=True, **SETTINGS)
    assert [o.status for o in third.outcomes] == ["skipped", "recorded", "skipped", "skipped"]
    first, imp = _arrays(recorded["seq"][1] / "imp.h5"), _arrays(par_dir / "imp.h5")
    np.testing.assert_allclose(imp["x"], 0.5 * first["x"], rtol=0, atol=1e-13 * np.abs(first["x"]).max())
    # an edited input table is a new input for the row that reads it (the stamp holds a hash of its content)
    moved = tmp_path / "moved"
    moved.mkdir()
    _write_load(moved, scale=2.0)
    edited = _write_table(moved, GOOD, ["chirp", "imp", "harm", "load"])
    fourth = runs.record_runs(SOURCE, edited, par_dir, scheduler=client, quiet=True, **SETTINGS)
    assert [o.status for o in fourth.outcomes] == ["skipped", "recorded", "skipped", "recorded"]
    load = _arrays(par_dir / "load.h5")
    np.testing.assert_allclose(load["x"], 2 * _arrays(recorded["seq"][1] / "load.h5")["x"], rtol=0,
                               atol=1e-13 * np.abs(load["x"]).max())
    _write_load(moved)  # the original content in another folder: complete already
    fifth = runs.record_runs(SOURCE, edited, par_dir, quiet=True, **SETTINGS)
    assert [o.status for o in fifth.outcomes] == ["skipped", "skipped", "skipped", "recorded"]
    sixth = runs.record_runs(SOURCE, table, par_dir, quiet=True, **SETTINGS)  # same content, other folder
    assert [o.status for o in sixth.outcomes] == ["skipped", "skipped", "failed", "skipped", "skipped"]


def test_a_changed_row_that_fails_leaves_no_stale_result(tmp_path):
    """In this process (no scheduler): the old file of a row whose new version fails is not kept as its result."""
    (tmp_path / "short.csv").write_text("time,u\n0,1\n5,0\n")  # ends before t_end = 20
    first = tmp_path / "first.csv"
    first.write_text('name,input\na,"step:amplitude=1"\nb,"step:amplitude=2"\n')
    runs.record_runs(SOURCE, first, tmp_path / "set", quiet=True, **SETTINGS).raise_for_failures()
    second = tmp_path / "second.csv"
    second.write_text('name,input\na,short.csv\nb,"step:amplitude=2"\n')
    report = runs.record_runs(SOURCE, second, tmp_path / "set", quiet=True, **SETTINGS)
    assert [o.status for o in report.outcomes] == ["failed", "skipped"]
    assert "extend the table or shorten --t-end" in report.outcomes[0].error
    assert [p.name for p in snapshot_files(tmp_path / "set")] == ["b.h5"]


@pytest.mark.slow  # 4 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_cli_records_a_table_on_a_running_cluster(client, table, tmp_path):
    out = tmp_path / "set"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    proc = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "snapshots", SOURCE, "--runs", str(table),
                           "-o", str(out), "--scheduler", client.scheduler.address, "--g", "40", "--dt", "0.1",
                           "--t-end", "20", "-q"], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "1 of 5 runs failed, the others are kept: row 3 (blowup)" in last
    assert "4 recorded, 0 already complete, 1 failed" in proc.stdout
    assert sorted(p.name for p in out.glob("*.h5")) == ["blowup.incomplete.h5", "chirp.h5", "harm.h5", "imp.h5",
                                                        "load.h5"]


def test_bad_scheduler_and_table_are_one_line_errors(table, tmp_path):
    with pytest.raises(runs.InputSpecError, match="local:4"):
        runs.parse_scheduler("local:zero")
    with pytest.raises(runs.InputSpecError, match="tcp://HOST:PORT"):
        runs.parse_scheduler("cluster-please")
    bad = tmp_path / "bad.csv"
    bad.write_text('name,input\nok,"step:amplitude=1"\nok,"step:amplitude=2"\n')
    with pytest.raises(runs.RunTableError, match=r"row 2, column 'name': 'ok' is already the name of row 1"):
        runs.read_run_table(bad)
    with pytest.raises(runs.InputSpecError, match="directory"):
        runs.record_runs(SOURCE, table, tmp_path / "one.h5", quiet=True, **SETTINGS)


# --------------------------------------------------------------------------------------------------------
# Distributed POD
# --------------------------------------------------------------------------------------------------------
def _well_separated_order(sigma: np.ndarray) -> int:
    """An order whose modes are determined to 1e-10 by any backward-stable SVD (sigma_r >= 1e-4 sigma_1 and a
    relative gap to sigma_{r+1}); the subspace angle of a backward-stable method is ~ eps sigma_1 / gap."""
    good = [r for r in range(1, len(sigma) - 1)
            if sigma[r - 1] >= 1e-4 * sigma[0] and sigma[r - 1] - sigma[r] >= 1e-4 * sigma[0]]
    return max(good)


def _check_distributed(files: Path, max_memory: float, method: str) -> None:
    with open_snapshot_set(files, dask=False) as snaps:
        incore = PODBasis(r=1).fit(snaps)
        r = _well_separated_order(incore.svdvals_)
        incore = PODBasis(r=r).fit(snaps)
    assert incore.method_ == "dense"
    with open_snapshot_set(files, dask=True, max_memory=max_memory) as snaps:
        assert len(snaps.runs[0].x.chunks[0]) * len(snaps.runs[0].x.chunks[1]) > 1  # blocks, not one array
        dist = PODBasis(r=r, max_memory=max_memory).fit(snaps)
    assert dist.method_ == method
    assert np.max(scipy.linalg.subspace_angles(dist.basis_, incore.basis_)) < 1e-10
    np.testing.assert_allclose(dist.basis_.T @ dist.basis_, np.eye(r), atol=1e-13)
    m = min(len(dist.svdvals_), len(incore.svdvals_))
    np.testing.assert_allclose(dist.svdvals_[:m], incore.svdvals_[:m], rtol=0, atol=1e-13 * incore.svdvals_[0])
    assert r >= 3


def test_distributed_pod_wide_data_equals_incore(client, recorded):
    """n = 40 rows, k = 804 columns: TSQR of X^T in column blocks of >= 40 columns (20 blocks)."""
    _check_distributed(recorded["par"][1], max_memory=40 * 8 * 4 * 40, method="distributed-tsqr-transposed")


@pytest.fixture(scope="module")
def tall_set(client, table, tmp_path_factory) -> Path:
    """n = 1500 rows, k = 4 x 61 columns."""
    folder = tmp_path_factory.mktemp("tall")
    good = folder / "good.csv"
    good.write_text("\n".join(line for line in table.read_text().splitlines() if "blowup" not in line) + "\n")
    (folder / "loads").symlink_to(table.parent / "loads")
    report = runs.record_runs(SOURCE, good, folder / "set", scheduler=client, quiet=True, dt=0.1, t_end=6.0, g=1500)
    report.raise_for_failures()
    return folder / "set"


@pytest.mark.parametrize("ratio", [0.0, np.inf], ids=["modes-X-W-over-sigma", "modes-Q-U"])
def test_distributed_pod_tall_data_equals_incore(tall_set, ratio, monkeypatch):
    """TSQR of X in row blocks (6 blocks); the modes from X W_r / sigma_r and from Q U_R both to 1e-10."""
    import fmu_opinf.basis as basis_module

    monkeypatch.setattr(basis_module, "TSQR_CHEAP_MODES_RATIO", ratio)
    _check_distributed(tall_set, max_memory=250 * 8 * 4 * 244, method="distributed-tsqr")


# --------------------------------------------------------------------------------------------------------
# Fitting from a per-run set, comparing on a run table
# --------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def roms(client, recorded, tmp_path_factory):
    """The ROM of the per-run set (fitted while the client is active: distributed POD) and of one file."""
    from fmu_opinf.fit import fit_rom, fit_rom_file

    out = tmp_path_factory.mktemp("roms")
    one = out / "one.h5"
    record_to_file(SOURCE, one, [_row_input(recorded, name) for name in ("chirp", "harm", "imp", "load")],
                   quiet=True, **SETTINGS)  # the set's files in the set's (sorted) order
    # the SDP alone (refine=False): these tests are about the data paths; the output-error refinement's L-BFGS
    # amplifies round-off differences of the basis into 1e-4 differences of the operators
    rom_set = fit_rom_file(recorded["par"][1], out / "set-rom.h5", r=4, quiet=True, refine=False)
    with Snapshots.open(one) as snaps:  # the file itself: h5py datasets, in-core POD even with a client active
        rom_one = fit_rom(snaps, r=4, quiet=True, refine=False)
    return rom_set, rom_one, out


def _row_input(recorded, name: str) -> str:
    with h5py.File(recorded["par"][1] / f"{name}.h5", "r") as f:
        (group,) = f["runs"].values()
        return str(group.attrs["input_spec"])


def test_fit_from_run_set_equals_fit_from_one_file(roms, recorded):
    """In core the per-run set is the one file's data set exactly; through the distributed POD the basis agrees
    to round-off and the operators to the fit's own conditioning (a relative 1e-15 perturbation of the snapshots
    moves this fit's Mr by ~1e-5, measured)."""
    from fmu_opinf.fit import fit_rom

    rom_set, rom_one, _ = roms
    assert (rom_set.fit_info["pod_method"], rom_one.fit_info["pod_method"]) == ("distributed-tsqr-transposed", "dense")
    with open_snapshot_set(recorded["par"][1], dask=False) as snaps:
        rom_incore = fit_rom(snaps, r=4, quiet=True, refine=False)
    assert np.max(scipy.linalg.subspace_angles(rom_set.basis, rom_one.basis)) < 1e-10
    for name in ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr"):
        a, b, c = getattr(rom_incore, name), getattr(rom_one, name), getattr(rom_set, name)
        np.testing.assert_array_equal(a, b, err_msg=name)
        np.testing.assert_allclose(c, b, rtol=0, atol=1e-4 * max(np.abs(b).max(), 1e-300), err_msg=name)
    poles = np.array(rom_set.fit_info["poles"]), np.array(rom_one.fit_info["poles"])
    np.testing.assert_allclose(poles[0], poles[1], rtol=1e-4)


@pytest.mark.slow  # 9 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_cli_fits_a_per_run_set_on_a_running_cluster(client, recorded, roms, tmp_path):
    from fmu_opinf.rom import SecondOrderROM

    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    proc = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "fit", str(recorded["par"][1]), "-o",
                           str(tmp_path / "rom.h5"), "--r", "4", "--scheduler", client.scheduler.address, "-q"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    assert rom.fit_info["pod_method"] == "distributed-tsqr-transposed"
    assert np.max(scipy.linalg.subspace_angles(rom.basis, roms[1].basis)) < 1e-10


@pytest.mark.slow  # 6 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_compare_runs_in_parallel_gives_one_summary(client, roms, table, tmp_path):
    rom_set, _, out = roms
    tests = tmp_path / "tests.csv"
    tests.write_text('name,input\nslow,"harmonic:amplitude=1,omega=0.3"\nimpulse,"impulse:amplitude=80,t0=3,'
                     'width=0.6"\nblowup,"harmonic:amplitude=1.7e308,omega=1"\nshort,short.csv\n')
    (tmp_path / "short.csv").write_text("time,u\n0,1\n10,0\n")  # ends before t_end = 20
    rom_path = out / "set-rom.h5"
    par, table_text = runs.compare_runs(rom_path, SOURCE, tests, tmp_path / "par", scheduler=client, quiet=True,
                                        **SETTINGS)
    seq, seq_text = runs.compare_runs(rom_path, SOURCE, tests, tmp_path / "seq", quiet=True, **SETTINGS)
    assert [o.status for o in par.outcomes] == ["compared", "compared", "failed", "failed"]
    assert [o.status for o in seq.outcomes] == ["compared", "compared", "failed", "failed"]
    assert par.outcomes[2].number == 3 and "source produced non-finite outputs" in par.outcomes[2].error
    assert par.outcomes[3].number == 4 and "extend the table or shorten --t-end" in par.outcomes[3].error
    lines = table_text.split("\nspeed-up =")[0].splitlines()  # the table rows, without the timing notes below
    assert len(lines) == 4 and lines[2].startswith("slow") and lines[3].startswith("impulse")
    for a, b in zip(lines[2:], seq_text.splitlines()[2:4]):
        assert a.split()[:4] == b.split()[:4]  # case, r, max error, L2 error (times differ)
    assert float(lines[2].split()[2]) < 0.05
    assert (tmp_path / "par" / "summary.txt").read_text().strip() == table_text.strip()
    page = (tmp_path / "par" / "index.html").read_text()
    assert 'href="slow/index.html"' in page and "failed" in page
    assert (tmp_path / "par" / "slow" / "index.html").exists()


def test_a_free_response_row_beside_forced_rows_keeps_the_inputs(tmp_path):
    """A ``none`` row of a table was recorded without input channels (m = 0) and the folder did not fit ("m
    differs (0 vs 1)"; second audit, 2026-11-26); beside forced rows it keeps them, held at their start values."""
    table = _write_table(tmp_path, {"imp": GOOD["imp"], "free": "none"}, ["imp", "free"])
    report = runs.record_runs(SOURCE, table, tmp_path / "out", quiet=True, **SETTINGS)
    assert [o.status for o in report.outcomes] == ["recorded", "recorded"]
    with open_snapshot_set(tmp_path / "out") as snaps:
        assert [run.u.shape[0] for run in snaps.runs] == [1, 1]
        assert not np.any(snaps.runs[[r.attrs["input_spec"] for r in snaps.runs].index("none")].u)
    alone = _write_table(tmp_path, {"imp": GOOD["imp"]}, ["imp"], name="alone.csv")
    again = runs.record_runs(SOURCE, alone, tmp_path / "out", quiet=True, **SETTINGS)
    assert [o.status for o in again.outcomes] == ["skipped"]  # the forced row's stamp does not see the free row


def _warning_row(row):
    import warnings

    from fmu_opinf.errors import FmuOpinfWarning

    warnings.warn(f"row {row} looks odd", FmuOpinfWarning)
    warnings.warn("the same for every row", FmuOpinfWarning)
    return runs.RunOutcome(row, f"r{row}", "recorded")


def test_a_worker_s_warnings_are_said_by_the_caller_once_each(client, monkeypatch):
    """Warnings of a task on a worker went to the worker's log, multi-line, one per row; now the caller says them
    (one line on the command line), each text once."""
    from fmu_opinf.errors import FmuOpinfWarning

    monkeypatch.setattr(runs, "_RELAYED", set())
    rows = [runs.RunRow(i, f"r{i}", "step") for i in range(3)]
    with pytest.warns(FmuOpinfWarning) as seen:
        outcomes = runs._map_rows(client, _warning_row, rows, lambda *a: None, lambda row: (row.number,))
    assert [o.name for o in outcomes] == ["r0", "r1", "r2"]
    said = sorted(str(w.message) for w in seen)
    assert said == ["row 0 looks odd", "row 1 looks odd", "row 2 looks odd", "the same for every row"]


def test_a_table_recorded_from_python_with_integer_times_is_skipped_by_the_same_settings_as_floats(tmp_path):
    """``t_end=20`` (Python) and ``--t-end 20`` (a float on the command line) are the same setting: the rerun
    skips the row (audit 68: the stamps held 20 and 20.0, and every row was recorded again)."""
    table = _write_table(tmp_path, {"imp": GOOD["imp"]}, ["imp"])
    first = runs.record_runs(SOURCE, table, tmp_path / "out", quiet=True, dt=0.1, t_end=20, g=40)
    assert [o.status for o in first.outcomes] == ["recorded"]
    again = runs.record_runs(SOURCE, table, tmp_path / "out", quiet=True, **SETTINGS)
    assert [o.status for o in again.outcomes] == ["skipped"]


def test_a_tls_scheduler_without_tls_settings_is_a_one_line_error():
    """``tls://`` without distributed's TLS configuration raised distributed's TypeError (a traceback, exit 1;
    audit 68); it is a one-line error naming the configuration."""
    with pytest.raises(FmuOpinfError, match="distributed.comm.tls"):
        with runs.dask_client("tls://127.0.0.1:1"):
            pass


# ---------------------------------------------------------------------------------------------
# Interrupts, lost workers and daemonic workers (audit 68, findings 1, 4 and 5)
# ---------------------------------------------------------------------------------------------
LONG_T_END = "1e5"  # a row of 1e6 steps: minutes, so a Ctrl-C finds it running
#: CPU seconds of a process running the pilots before the pilot test interrupts it (its start and some pilots).
PILOT_CPU = 2.5


def _cli(arguments: list[str], tmp_path: Path) -> subprocess.Popen:
    """The command line in its own process group (a Ctrl-C to the group, as a terminal sends it)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src"),
           "TMPDIR": str(tmp_path / "tmp")}
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return subprocess.Popen([sys.executable, "-m", "fmu_opinf.cli", *arguments], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _interrupt_when(proc: subprocess.Popen, ready: Any, timeout: float = 120.0) -> tuple[str, str]:
    """SIGINT to the process group once ``ready()`` holds; the command's stdout and stderr."""
    import signal
    import time

    deadline = time.monotonic() + timeout
    while not ready():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the rows did not start in time"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        return proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def _not_warnings(err: str) -> list[str]:
    """stderr without the tool's one-line warnings (the failing rows' overflow, said by the tool itself)."""
    return [line for line in err.strip().splitlines() if not line.startswith("fmu-opinf: warning: ")]


def _temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp") or ".partial." in p.name)


def _group(pgid: int) -> list[tuple[str, float, str]]:
    """The live processes of a process group, as (state, CPU seconds, command line); zombies, which only wait for
    their reaper, are left out (Linux's /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
            command = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:   # the process ended meanwhile
            continue
        fields = text.rsplit(")", 1)[1].split()   # after "pid (name)": state, ppid, pgrp, ..., utime, stime
        if int(fields[2]) == pgid and fields[0] != "Z":
            cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
            found.append((fields[0], cpu, command.strip()))
    return found


def _left_behind(pgid: int, within: float = 15.0) -> list[str]:
    """The processes of the interrupted command's group still alive ``within`` seconds after it ended (killed then,
    so that none spins on): Dask workers or their rows' children that the interrupt did not stop."""
    import signal
    import time

    deadline = time.monotonic() + within
    while (left := _group(pgid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    if left:
        os.killpg(pgid, signal.SIGKILL)
    return [command for _, _, command in left]


@pytest.mark.slow  # 8 s on the 2-core machine of 2026-12-06 (a local cluster starts, two rows are interrupted)
def test_ctrl_c_during_a_distributed_table_leaves_one_line_naming_the_written_rows_and_no_temporaries(tmp_path):
    """Two rows fail at once (their ``NAME.incomplete.h5`` is written by a worker), two run for minutes; Ctrl-C
    then: the tool's line is all of stderr, it names the files the workers wrote, and the interrupted rows leave
    no temporary file (audit 68: 3-5 tracebacks and log lines, "no output file was written or replaced", and a
    ``.NAME.partial.h5.XXXX.tmp`` per interrupted row)."""
    table = tmp_path / "runs.csv"
    table.write_text(f'name,input\nboom1,"{FAILING[1]}"\nboom2,"{FAILING[1]}"\n'
                     'long1,"harmonic:amplitude=1,omega=0.7"\nlong2,"harmonic:amplitude=1,omega=0.5"\n')
    out = tmp_path / "set"
    proc = _cli(["snapshots", SOURCE, "--runs", str(table), "-o", str(out), "--g", "40", "--dt", "0.1",
                 "--t-end", LONG_T_END, "--scheduler", "local:2", "-q"], tmp_path)
    written = [out / "boom1.incomplete.h5", out / "boom2.incomplete.h5"]

    def ready() -> bool:
        return out.is_dir() and all(p.exists() for p in written) and len(list(out.glob(".long*.tmp"))) == 2

    _, err = _interrupt_when(proc, ready)
    assert proc.returncode == 130, err
    lines = _not_warnings(err)
    assert len(lines) == 1 and err.strip().splitlines()[-1] == lines[0], err
    assert lines[0].startswith("fmu-opinf: interrupted (Ctrl-C); written before it: ")
    assert all(str(path) in lines[0] for path in written) and "long" not in lines[0]
    assert _temporaries(out) == []
    assert sorted(p.name for p in out.iterdir()) == ["boom1.incomplete.h5", "boom2.incomplete.h5"]
    assert _left_behind(proc.pid) == []   # workers and their rows stopped with the command


def test_ctrl_c_in_a_serial_table_names_the_row_file_not_its_intermediate(tmp_path):
    """Serial: the last line named the hidden ``.NAME.partial.h5`` that had been renamed (audit 68)."""
    table = tmp_path / "runs.csv"
    table.write_text(f'name,input\nboom,"{FAILING[1]}"\nlong,"harmonic:amplitude=1,omega=0.7"\n')
    out = tmp_path / "set"
    proc = _cli(["snapshots", SOURCE, "--runs", str(table), "-o", str(out), "--g", "40", "--dt", "0.1",
                 "--t-end", LONG_T_END, "-q"], tmp_path)
    _, err = _interrupt_when(proc, lambda: out.is_dir() and bool(list(out.glob(".long*.tmp"))))
    assert proc.returncode == 130, err
    expected = (f"fmu-opinf: interrupted (Ctrl-C); written before it: {out / 'boom.incomplete.h5'}; "
                "every other output was left as it was")
    assert _not_warnings(err) == [expected], err
    assert _temporaries(out) == []
    assert _left_behind(proc.pid) == []


@pytest.mark.slow  # 6 s and 12-14 s under pytest -n 2 on the 2-core machine of 2026-12-07 (a cluster starts)
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="the process check reads Linux's /proc")
@pytest.mark.parametrize("scheduler", [None, "local:2"], ids=["serial", "local-cluster"])
def test_ctrl_c_during_a_table_s_pilots_leaves_no_file_no_temporary_and_no_process(tmp_path, scheduler):
    """Without --dt every row's pilots run before any row is recorded (the rows share the finest of their steps,
    audit 72 F2), so for a while no row file exists.  A Ctrl-C then writes nothing, says so in one line, exits
    with 130 and leaves no temporary file and no process (a Dask worker still running a pilot) behind."""
    table = tmp_path / "runs.csv"
    table.write_text('name,input\nlong1,"harmonic:amplitude=1,omega=0.7"\nlong2,"harmonic:amplitude=1,omega=0.5"\n')
    out = tmp_path / "set"
    cluster = ["--scheduler", scheduler] if scheduler else []
    # 600 masses: pilots of about 7 s on the machine of 2026-12-07 (40 masses: 2 s, over before the check below held)
    proc = _cli(["snapshots", SOURCE, "--runs", str(table), "-o", str(out), "--g", "600", "--t-end", LONG_T_END,
                 "-q", *cluster], tmp_path)
    workers = 2 if scheduler else 1   # the processes that run the pilots: the Dask workers, or the command

    idle_since: dict[str, tuple[float, float]] = {}   # command -> (CPU seconds, when first seen at that figure)

    def ready() -> bool:
        """The pilots have run for a while (:data:`PILOT_CPU` in a process that runs them) and every process is past
        its start (what a Ctrl-C does to a worker still starting is not what this test checks): it has used that
        much CPU, or 1 s and then stayed idle for a quarter second (Dask may give both rows' pilots to one worker:
        the other, started, waits; on the machine of 2026-12-07 a worker's start took 1.5-2 s of CPU and the pilots
        2 s more, and the rows began before an idle worker reached the 3 s this test waited for)."""
        import time

        now = time.monotonic()
        running = [(command, cpu) for _, cpu, command in _group(proc.pid)
                   if ("spawn_main" in command) == bool(scheduler) and "resource_tracker" not in command]
        started = 0
        for command, cpu in running:
            seen, since = idle_since.get(command, (None, now))
            idle_since[command] = (cpu, since if seen == cpu else now)
            started += cpu > PILOT_CPU or (cpu > 1.0 and seen == cpu and now - since > 0.25)
        return (out.is_dir() and len(running) >= workers and started == len(running)
                and max(cpu for _, cpu in running) > PILOT_CPU)

    at_interrupt: list[list[str]] = []

    def still_in_the_pilots() -> bool:
        if ready():
            at_interrupt.append(sorted(p.name for p in out.iterdir()))
        return bool(at_interrupt)

    _, err = _interrupt_when(proc, still_in_the_pilots)
    assert at_interrupt == [[]], at_interrupt   # the premise: still in the pilots, no row recorded yet
    assert proc.returncode == 130, err
    assert _not_warnings(err) == ["fmu-opinf: interrupted (Ctrl-C); no output file was written or replaced"], err
    assert not out.exists()   # the folder the command made, still empty, went with it (audit 76 F6)
    assert _left_behind(proc.pid) == []


@pytest.mark.parametrize("existed", [False, True], ids=["made-by-the-table", "there-before"])
def test_a_table_stopped_before_its_first_row_leaves_no_folder_it_made(tmp_path, monkeypatch, existed):
    """A Ctrl-C (or a failure) before any row is written removes the output folder, and the parents, that the table
    made, where they are still empty: "no output file was written" leaves nothing behind (audit 76 F6: an empty
    folder stayed).  A folder that was there before is kept."""
    from fmu_opinf import runs

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(runs, "record_row", interrupted)
    base = tmp_path / "results"
    out = base / "nested" / "set"
    if existed:
        out.mkdir(parents=True)
    table = [runs.RunRow(1, "a", "impulse:amplitude=100,t0=2,width=0.5")]
    with pytest.raises(KeyboardInterrupt):
        runs.record_runs(SOURCE, table, out, dt=0.1, t_end=1.0, quiet=True, g=4)
    assert out.is_dir() == existed
    assert base.exists() == existed


def test_a_row_recorded_again_removes_the_temporaries_an_earlier_attempt_left(tmp_path):
    """A worker killed mid-row (by its nanny after a Ctrl-C, or lost and retried by Dask) leaves its temporary
    files; the row's next recording removes them, and only files of the tool's own pattern for that row."""
    table = _write_table(tmp_path, GOOD, ["imp", "harm"])
    out = tmp_path / "set"
    out.mkdir()
    stale = [".imp.partial.h5", ".imp.partial.h5.k2_x9q0a.tmp", ".harm.partial.h5.zzzzzzzz.tmp"]
    kept = [".imp.partial.h5.k2_x9q0.tmp", ".imp.partial.h5.K2_X9Q0A.tmp", ".imp2.partial.h5.k2_x9q0a.tmp",
            "imp.h5.k2_x9q0a.tmp", ".imp.partial.h5.k2_x9q0a.tmp.bak", "notes.txt"]
    for name in stale + kept:
        (out / name).write_bytes(b"x" * 96)
    report = runs.record_runs(SOURCE, table, out, quiet=True, **SETTINGS)
    assert [o.status for o in report.outcomes] == ["recorded", "recorded"]
    assert sorted(p.name for p in out.iterdir()) == sorted(kept + ["imp.h5", "harm.h5"])
    (out / ".harm.partial.h5.abcdefgh.tmp").write_bytes(b"x")  # a complete row, skipped: its debris goes too
    again = runs.record_runs(SOURCE, table, out, quiet=True, **SETTINGS)
    assert [o.status for o in again.outcomes] == ["skipped", "skipped"]
    assert sorted(p.name for p in out.iterdir()) == sorted(kept + ["imp.h5", "harm.h5"])


def test_daemonic_workers_with_isolation_are_one_line_error_naming_the_fix():
    """A user's LocalCluster with Dask's default (daemonic) workers failed every FMU row with a bare
    ``AssertionError: daemonic processes are not allowed to have children`` (audit 68)."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.daemon": True}), \
            LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as user_client:
        with pytest.raises(FmuOpinfError, match="DASK_DISTRIBUTED__WORKER__DAEMON=False") as caught, \
                runs.dask_client(user_client, isolate=True):
            pass
        assert "\n" not in str(caught.value) and "isolate=False" in str(caught.value)
        with runs.dask_client(user_client, isolate=False) as same:  # no child processes: fine
            assert same is user_client


def test_a_row_retried_after_a_lost_worker_says_so():
    outcome = runs.RunOutcome(2, "b", "recorded", "b.h5", 10, 1.0, worker="tcp://w", retries=1)
    assert outcome.line().endswith("on tcp://w (retried after 1 lost worker(s))")
