"""Tests of fmu_opinf.snapshots: recording, the HDF5 layout, failures that keep data, auto window."""

from __future__ import annotations

import os
import pickle
import re
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from fmu_opinf import newmark, snapshots
from fmu_opinf.signals import parse_signal
from fmu_opinf.errors import DimensionError, FileFormatError, FMUError, FmuOpinfError, FmuOpinfWarning, InputSpecError
from fmu_opinf.snapshots import Snapshots, auto_window, newmark_rates, record, record_to_file, time_grid
from fmu_opinf.source import BuiltinSource, FMUSource, StepError
from test_source import SignalStub

ARRAYS = ("t", "u", "x", "xdot", "xddot", "y")


def relative(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), np.finfo(float).tiny))


@pytest.fixture(scope="module")
def bundled():
    """The benchmark FMUs (built with CMake on first use; skipped without build tools)."""
    from fmu_opinf import fmus

    if fmus.find_build_tools() is None and not all(
            (fmus._c_sources_dir() / f"{name}.fmu").is_file() for name in fmus.BENCHMARK_MODELS):
        pytest.skip("no CMake / C compiler to build the benchmark FMUs")
    return {name: fmus.bundled_fmu(name) for name in fmus.BENCHMARK_MODELS}


# ------------------------------------------------------------------------------- equality with the reference


@pytest.mark.parametrize("model, builtin, dt, t_end", [
    ("AnchoredMSD", "anchored-msd", 0.5, 100.0),
    ("TripleChainMSD", "triple-chain", 0.1, 30.0),
])
def test_bundled_fmu_snapshots_equal_the_reference_simulator(bundled, model, builtin, dt, t_end):
    spec = "impulse:amplitude=100,t0=2,width=0.5"
    fmu_run = record(FMUSource(bundled[model]), spec, dt, t_end, quiet=True).runs[0]
    builtin_source = BuiltinSource(builtin)
    reference = newmark.simulate(builtin_source.system, spec, dt, t_end)
    for name in ARRAYS:
        assert getattr(fmu_run, name).shape == getattr(reference, name).shape
        assert relative(getattr(fmu_run, name), getattr(reference, name)) <= 1e-10, name
    builtin_run = record(builtin_source, spec, dt, t_end, quiet=True).runs[0]
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(builtin_run, name), getattr(reference, name))


# ------------------------------------------------------------------------------- files


def small_snapshots() -> Snapshots:
    source = BuiltinSource("anchored-msd", g=12)
    snaps = record(source, "impulse:amplitude=10,t0=1,width=0.5", 0.5, 30.0, quiet=True)
    return snaps.append(record(source, "harmonic:amplitude=2,omega=0.3", 0.5, 20.0, quiet=True))


def assert_same(a: Snapshots, b: Snapshots) -> None:
    assert a.attrs == b.attrs
    assert len(a.runs) == len(b.runs)
    for ra, rb in zip(a.runs, b.runs):
        assert ra.attrs == rb.attrs
        for name in ARRAYS:
            np.testing.assert_array_equal(np.asarray(getattr(ra, name)[()]), np.asarray(getattr(rb, name)[()]))


def test_round_trip_keeps_arrays_and_attributes(tmp_path):
    snaps = small_snapshots()
    assert (snaps.n, snaps.m, snaps.p, len(snaps.runs)) == (12, 1, 3, 2)
    assert [r.k for r in snaps.runs] == [61, 41]
    path = snaps.save(tmp_path / "s.h5")
    loaded = Snapshots.load(path)
    assert_same(snaps, loaded)
    assert loaded.attrs["constraint"] == "position" and loaded.attrs["layout_version"] == snapshots.LAYOUT_VERSION
    assert loaded.runs[1].attrs["input_spec"] == parse_signal("harmonic:amplitude=2,omega=0.3").spec
    assert loaded.runs[0].attrs["complete"] is True
    assert loaded.runs[0].attrs["versions"]["fmu-opinf"] == snaps.runs[0].attrs["versions"]["fmu-opinf"]
    with Snapshots.open(path) as lazy:
        x = lazy.runs[0].x
        assert isinstance(x, h5py.Dataset) and x.compression == "gzip" and x.chunks is not None
        np.testing.assert_array_equal(x[:, 10:20], snaps.runs[0].x[:, 10:20])
        np.testing.assert_array_equal(lazy.concatenate("x"), np.hstack([r.x for r in snaps.runs]))
    assert not x.id.valid  # closed by the context manager


@pytest.mark.parametrize(("kind", "layout", "message"), [
    (snapshots.FILE_KIND, 0, "snapshot layout 0, which no fmu-opinf wrote (layouts start at 1)"),
    ("something else", snapshots.LAYOUT_VERSION, "not an fmu-opinf snapshot file (kind='something else', not"),
])
def test_a_snapshot_file_of_no_layout_or_another_kind_is_named_as_such(tmp_path, kind, layout, message):
    """Audit 68: layout 0 (written by no version) was read as a snapshot file, and a file of another kind was said
    to have no kind attribute.  The attributes are edited on purpose, so the seal goes too."""
    from fmu_opinf._seal import SEAL_ATTR

    path = small_snapshots().save(tmp_path / "s.h5")
    with h5py.File(path, "r+") as f:
        f.attrs["kind"], f.attrs["layout_version"] = kind, layout
        del f.attrs[SEAL_ATTR]
    with pytest.raises(FileFormatError, match=re.escape(message)):
        Snapshots.load(path)


def test_save_never_clobbers_and_overwrite_is_atomic(tmp_path):
    snaps = small_snapshots()
    path = snaps.save(tmp_path / "s.h5")
    with pytest.raises(FileFormatError, match="exists; pass --force or overwrite=True to replace it"):
        snaps.save(path)
    before = path.read_bytes()
    source = BuiltinSource("anchored-msd", g=12)
    with pytest.raises(InputSpecError, match="non-finite"):  # fails inside the write: the old file survives
        record_to_file(source, path, ["step:amplitude=1", SignalStub(amplitude=float("nan"))], dt=0.5, t_end=5.0,
                       overwrite=True, quiet=True)
    with pytest.raises(DimensionError, match="2"):
        record_to_file(source, path, "impulse:amplitude=1,t0=1,width=0.5;step:amplitude=1", dt=0.5, t_end=5.0,
                       overwrite=True, quiet=True)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


def test_streamed_recording_equals_in_memory_recording(tmp_path):
    source = BuiltinSource("anchored-msd", g=12)
    spec = "impulse:amplitude=10,t0=1,width=0.5"
    memory = record(source, spec, 0.5, 30.0, quiet=True)
    with record(source, spec, 0.5, 30.0, path=tmp_path / "s.h5", quiet=True, stream=True) as streamed:
        assert isinstance(streamed.runs[0].x, h5py.Dataset)
        for name in ARRAYS:
            np.testing.assert_array_equal(getattr(streamed.runs[0], name)[()], getattr(memory.runs[0], name))
        assert streamed.attrs["position_names"] == memory.attrs["position_names"]


def test_large_runs_are_streamed_to_disk_automatically(tmp_path, monkeypatch):
    source = BuiltinSource("anchored-msd", g=12)
    small = record(source, "step:amplitude=1", 0.5, 10.0, path=tmp_path / "small.h5", quiet=True)
    assert isinstance(small.runs[0].x, np.ndarray)
    monkeypatch.setattr(snapshots._record, "STREAM_THRESHOLD", 8 * 21 * (3 * 12 + 3 + 1 + 1) - 1)
    with record(source, "step:amplitude=1", 0.5, 10.0, path=tmp_path / "large.h5", quiet=True) as large:
        assert isinstance(large.runs[0].x, h5py.Dataset)
        np.testing.assert_array_equal(large.runs[0].xddot[()], small.runs[0].xddot)


def test_merging_requires_the_same_system():
    snaps = small_snapshots()
    other = record(BuiltinSource("anchored-msd", g=10), "step:amplitude=1", 0.5, 5.0, quiet=True)
    with pytest.raises(DimensionError, match="n differs"):
        snaps.append(other)
    assert len(snaps.runs) == 2


@pytest.mark.parametrize("content", ["text", "foreign-h5", "newer"])
def test_open_rejects_files_of_another_kind(tmp_path, content):
    path = tmp_path / "f.h5"
    if content == "text":
        path.write_text("hello")
    else:
        with h5py.File(path, "w") as f:
            if content == "newer":
                f.attrs["kind"] = snapshots.FILE_KIND
                f.attrs["layout_version"] = snapshots.LAYOUT_VERSION + 1
    with pytest.raises(FileFormatError) as info:
        Snapshots.load(path)
    assert "\n" not in str(info.value)
    with pytest.raises(FileFormatError, match="does not exist"):
        Snapshots.open(tmp_path / "missing.h5")


# ------------------------------------------------------------------------------- derived rates


def test_newmark_rates_recover_velocities_of_newmark_data():
    run = record(BuiltinSource("anchored-msd", g=12), "impulse:amplitude=10,t0=1,width=0.5", 0.5, 150.0,
                 quiet=True).runs[0]
    h = 0.5
    v = newmark_rates(run.x, h)
    trapezoid = run.x[:, 1:] - run.x[:, :-1] - h / 2 * (v[:, 1:] + v[:, :-1])
    assert np.abs(trapezoid).max() <= 1e-13 * np.abs(run.x).max()
    # the free alternating mode is fixed by least roughness: close to the true velocities
    assert relative(v, run.xdot) < 1e-2


def test_fmu_without_rates_gets_derived_rates_marked_in_the_file(toys, tmp_path):
    signal = SignalStub(amplitude=1.0, t0=0.35)
    full = record(FMUSource(toys["full"]), signal, 0.05, 20.0, quiet=True).runs[0]
    derived = record(FMUSource(toys["positions-only"]), signal, 0.05, 20.0, path=tmp_path / "d.h5", quiet=True)
    run = derived.runs[0]
    np.testing.assert_array_equal(run.x, full.x)
    v, a = run.xdot, run.xddot
    # against the rates the toy FMU integrates (it exposes them in its "full" variant)
    assert relative(v, full.xdot) < 1e-10
    assert relative(a, full.xddot) < 1e-6
    loaded = Snapshots.load(tmp_path / "d.h5")
    assert loaded.runs[0].attrs["derived_xdot"] is True and loaded.runs[0].attrs["derived_xddot"] is True
    assert loaded.attrs["velocity_names"] == [] and loaded.attrs["derived_xddot"] is True
    with record(FMUSource(toys["positions-only"]), signal, 0.05, 20.0, path=tmp_path / "s.h5", quiet=True,
                stream=True) as streamed:
        np.testing.assert_allclose(streamed.runs[0].xddot[()], run.xddot, rtol=0, atol=1e-12 * np.abs(a).max())


# ------------------------------------------------------------------------------- failures keep data


@pytest.mark.parametrize("fault, text", [(1, "returned an error in fmi2DoStep at step 5 \\(t=0.4 -> 0.5\\)"),
                                         (2, "produced non-finite values at step 5 \\(t=0.5\\) in x\\[1\\], "
                                             "x\\[2\\], x\\[3\\], y\\[1\\] and 1 more; the FMU's co-simulation")])
def test_error_mid_run_keeps_the_samples_so_far(toys, tmp_path, fault, text):
    signal = SignalStub(amplitude=1.0, t0=0.35)
    clean = record(FMUSource(toys["full"]), signal, 0.1, 3.0, quiet=True).runs[0]
    failing = FMUSource(toys["full"], parameters={"fault": fault, "fault_threshold": 0.5})
    path = tmp_path / "partial.h5"
    with pytest.raises(StepError, match=text) as info:
        record(failing, signal, 0.1, 3.0, path=path, quiet=True)
    assert "\n" not in str(info.value) and "the 5 samples before it are kept" in str(info.value)
    kept = Snapshots.load(path)
    run = kept.runs[0]
    assert run.attrs["complete"] is False and run.k == 5 and run.attrs["k_planned"] == 31
    assert "step 5" in run.attrs["error"]
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(run, name), getattr(clean, name)[..., :5])


def test_non_finite_values_name_their_variables_and_the_usual_causes(toys):
    """Audit of 2026-12-06: ``--set mass1.m=0`` on a model-exchange FMU ended in "produced non-finite values at
    step 0 (t=0)", naming neither the variables nor a fix.  The line names the first variables that are not finite,
    and an FMU source with no other explanation (here: no step was taken, so no unstable explicit step) the usual
    causes."""
    from types import SimpleNamespace

    from fmu_opinf.snapshots._run import _non_finite_names, _with_hint

    names = SimpleNamespace(layout={"x": slice(0, 2), "xdot": slice(2, 4), "xddot": slice(4, 4), "y": slice(4, 5)},
                            position_names=["s1", "s2"], velocity_names=["v1", "v2"], output_names=["acc"])
    row = np.array([0.0, 1.0, 0.0, np.nan, np.inf])
    failure = StepError(f"m.fmu produced non-finite values at step 0 (t=0){_non_finite_names(names, row)}", 0, 0.0)
    assert str(_with_hint(FMUSource(toys["full"]), failure, np.zeros((1, 1)))) == (
        "m.fmu produced non-finite values at step 0 (t=0) in v2, acc; check the --set or parameters= values and the "
        "inputs (a mass "
        "or a stiffness at 0, a parameter exposed as an input driven to 0)")
    assert _non_finite_names(names, np.full(5, np.nan)) == " in s1, s2, v1, v2 and 1 more"


@pytest.mark.slow
def test_crashing_fmu_binary_is_reported_and_the_data_kept(toys, tmp_path):
    """The toy dereferences NULL in doStep once its input exceeds the threshold: u(4.0) = 1 is in
    effect for the step from t=4.0 to sample 41, so samples 0..40 exist when the process dies."""
    signal = SignalStub(amplitude=1.0, t0=3.95)
    clean = record(FMUSource(toys["full"]), signal, 0.1, 6.0, quiet=True).runs[0]
    path = tmp_path / "crash.h5"
    with pytest.raises(StepError, match="crashed the simulation process \\(signal SIGSEGV\\) at step 41 "
                                         "\\(t=4 -> 4.1\\); the 41 samples before it are kept") as info:
        record_to_file(str(toys["full"]), path, [signal.spec], dt=0.1, t_end=6.0, quiet=True, isolate=True,
                       parameters={"fault": 3, "fault_threshold": 0.5})
    assert isinstance(info.value, FmuOpinfError) and "\n" not in str(info.value)
    run = Snapshots.load(path).runs[0]
    assert run.attrs["complete"] is False and run.attrs["isolated"] is True
    assert run.k == 41 and run.attrs["k_planned"] == 61
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(run, name), getattr(clean, name)[..., :run.k])


def test_binary_failing_to_load_in_the_child_is_reported_without_a_file(toys, tmp_path):
    import fmpy

    from test_source import pack_fmu, toy_xml2

    garbage = tmp_path / "garbage.so"
    garbage.write_bytes(b"not a shared library")
    fmu = pack_fmu(tmp_path / "garbage.fmu", toy_xml2(), garbage, fmpy.platform)
    with pytest.raises(FMUError, match="cannot load the binary of garbage.fmu") as info:
        record_to_file(str(fmu), tmp_path / "none.h5", "step:amplitude=1", dt=0.1, t_end=1.0, quiet=True)
    assert not isinstance(info.value, StepError) and "\n" not in str(info.value)
    assert not (tmp_path / "none.h5").exists()


@pytest.mark.parametrize("isolate", [False, True])
@pytest.mark.parametrize("stream", [False, True])
def test_runs_spanning_many_blocks(toys, tmp_path, monkeypatch, isolate, stream):
    """16-sample blocks: block boundaries, a failure in a later block, streaming and isolation."""
    signal = SignalStub(amplitude=1.0, t0=2.25)  # u(2.3) = 1 is in effect from the step ending at sample 24
    clean = record(FMUSource(toys["full"]), signal, 0.1, 6.0, quiet=True).runs[0]
    monkeypatch.setattr(snapshots._run, "_BLOCK_BYTES", 1)
    whole = record(FMUSource(toys["full"]), SignalStub(amplitude=0.2, t0=2.25), 0.1, 6.0, quiet=True,
                   isolate=isolate, path=tmp_path / "whole.h5", stream=stream)
    reference = record(FMUSource(toys["full"]), SignalStub(amplitude=0.2, t0=2.25), 0.1, 6.0, quiet=True).runs[0]
    for name in ARRAYS:
        np.testing.assert_array_equal(np.asarray(getattr(whole.runs[0], name)[()]), getattr(reference, name))
    whole.close()
    failing = FMUSource(toys["full"], parameters={"fault": 1, "fault_threshold": 0.5})
    with pytest.raises(StepError, match="at step 24 \\(t=2.3 -> 2.4\\)"):
        record(failing, signal, 0.1, 6.0, path=tmp_path / "part.h5", quiet=True, isolate=isolate, stream=stream)
    run = Snapshots.load(tmp_path / "part.h5").runs[0]
    assert run.k == 24 and not run.complete
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(run, name), getattr(clean, name)[..., :24])


def test_isolated_recording_equals_in_process_recording(toys):
    signal = SignalStub(amplitude=1.0, t0=0.35)
    inproc = record(FMUSource(toys["fmi3"]), signal, 0.01, 3.0, quiet=True).runs[0]
    child = record(FMUSource(toys["fmi3"]), signal, 0.01, 3.0, quiet=True, isolate=True).runs[0]
    assert child.attrs["isolated"] is True and child.k == 301
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(child, name), getattr(inproc, name))



def test_isolated_runs_follow_the_callers_directory_and_environment(toys, tmp_path, monkeypatch):
    """Runs from the fork server (the command line's, here switched on for the API; Linux), which was started in
    another directory with an older environment: a relative path of an unpacked FMU after a chdir still opens
    (it was refused in process too: "can't be expressed as a file URI"), and the child takes over the caller's
    environment of the moment before it rebuilds the source."""
    import multiprocessing as mp
    import sys

    from fmpy import extract

    from fmu_opinf.snapshots import _isolation

    monkeypatch.setitem(_isolation._FORK_SERVER, "enabled", True)
    signal = SignalStub(amplitude=1.0, t0=0.35)
    record(FMUSource(toys["fmi3"]), signal, 0.01, 0.5, quiet=True, isolate=True)  # the server starts here
    if sys.platform.startswith("linux") and "forkserver" in mp.get_all_start_methods():
        assert _isolation._process_context().get_start_method() == "forkserver"
    extract(str(toys["fmi3"]), unzipdir=str(tmp_path / "unpacked"))  # an unpacked FMU is read where it lies
    monkeypatch.chdir(tmp_path)
    for isolate in (False, True):
        run = record(FMUSource("unpacked"), signal, 0.01, 0.5, quiet=True, isolate=isolate).runs[0]
        assert run.k == 51 and run.complete
    monkeypatch.setenv("FMU_OPINF_TEST_VARIABLE", "set after the server started")
    inherited = pickle.loads(pickle.dumps(_isolation._Inherited(dict(os.environ))))
    monkeypatch.delenv("FMU_OPINF_TEST_VARIABLE")
    inherited.take_over()   # what the child does first
    try:
        assert os.environ["FMU_OPINF_TEST_VARIABLE"] == "set after the server started"
    finally:
        os.environ.pop("FMU_OPINF_TEST_VARIABLE", None)


def test_the_python_api_spawns_and_the_command_line_uses_the_fork_server(monkeypatch, tmp_path):
    """The fork server is shared by everything in a process that uses multiprocessing's "forkserver" method, and
    fmu-opinf's keeps SIGINT/SIGTERM blocked: only the command line, where no other code runs, switches it on."""
    from fmu_opinf.cli import main
    from fmu_opinf.snapshots import _isolation

    monkeypatch.setitem(_isolation._FORK_SERVER, "enabled", False)
    assert _isolation._process_context().get_start_method() == "spawn"
    settings = []
    use = _isolation.use_fork_server
    monkeypatch.setattr(_isolation, "use_fork_server", lambda enabled=True: (settings.append(enabled), use(enabled)))
    assert main(["fit", str(tmp_path / "missing.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 2
    assert settings == [True, False] and not _isolation._FORK_SERVER["enabled"]  # on for the command, then restored


def test_a_builtin_source_is_recorded_in_this_process_even_when_isolation_is_asked(monkeypatch, tmp_path):
    """Isolation is for an FMU's binary; ``record_to_file`` of a builtin source ran it in a child process once its
    grid choice moved into ``_plan_recording`` (fix72b, reverted): a run table's builtin rows then went through the
    fork server, which under pytest-xdist stopped as the first row started, and the row failed without its file."""
    from fmu_opinf.snapshots import _run

    def no_child(*args, **kwargs):
        raise AssertionError("a builtin source was run in a child process")

    monkeypatch.setattr(_run, "produce_isolated", no_child)
    for dt in (0.1, None):   # a given step, and the automatic window's pilots
        path = tmp_path / f"b{dt}.h5"
        record_to_file("builtin:anchored-msd", path, "impulse:amplitude=100,t0=1,width=0.5", dt=dt, t_end=5.0,
                       g=5, quiet=True, isolate=True)
        assert Snapshots.load(path).runs[0].attrs["isolated"] is False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server is used on Linux only")
def test_isolated_runs_of_the_command_line_work_under_a_deep_tmpdir(tmp_path):
    """The fork server's socket lives in $TMPDIR; under a folder of 75 characters or so its path no longer fits a
    Unix socket's 108 bytes, the server did not start, and every isolated run failed with "the fork server ...
    stopped as the run ... started; run the command again" (pytest -n 2: popen-gwN/test_NAME0/tmp).  Such runs
    now spawn.  In a fresh process: multiprocessing keeps its temporary folder and its fork server per process."""
    import subprocess

    deep = tmp_path / ("d" * (100 - len(str(tmp_path)))) / "tmp"
    deep.mkdir(parents=True)
    script = ("from fmu_opinf.snapshots import _isolation, record\n"
              "from fmu_opinf.source import BuiltinSource\n"
              "_isolation.use_fork_server(True)\n"
              "run = record(BuiltinSource('anchored-msd', g=5), 'impulse:amplitude=1,t0=1,width=0.5', 0.1, 3.0,\n"
              "             quiet=True, isolate=True).runs[0]\n"
              "print(run.attrs['isolated'], run.k)\n")
    env = {**os.environ, "TMPDIR": str(deep), "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0 and done.stdout.split() == ["True", "31"], done.stdout + done.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server is used on Linux only")
def test_a_fork_server_killed_during_a_run_is_named_and_the_next_run_restarts_it(toys, monkeypatch):
    """Killing the server mid-run used to be reported as a crash of the FMU (exit code 255) and left its child
    running; now the error names the server, and the next run starts a new one."""
    import threading
    from multiprocessing import forkserver

    from fmu_opinf.errors import FMUError
    from fmu_opinf.snapshots import _isolation

    monkeypatch.setitem(_isolation._FORK_SERVER, "enabled", True)
    signal = SignalStub(amplitude=1.0, t0=0.35)
    record(FMUSource(toys["fmi3"]), signal, 0.01, 0.5, quiet=True, isolate=True)  # starts the server
    if _isolation._process_context().get_start_method() != "forkserver":
        pytest.skip("another fork server runs in this process")
    server = forkserver._forkserver._forkserver_pid
    stop = threading.Event()
    killer = threading.Thread(target=_kill_once_it_forked, args=(server, stop))
    killer.start()  # not after a fixed delay: on a loaded machine the run had not started yet, or had ended
    try:
        with pytest.raises(FMUError, match="fork server .* stopped during the run"):
            record(FMUSource(toys["fmi3"]), signal, 1e-5, 30.0, quiet=True, isolate=True)
    finally:
        stop.set()
        killer.join()
    run = record(FMUSource(toys["fmi3"]), signal, 0.01, 0.5, quiet=True, isolate=True).runs[0]
    assert run.k == 51 and forkserver._forkserver._forkserver_pid not in (None, server)


def _kill_once_it_forked(server: int, stop) -> None:
    """SIGKILL the fork server once it has a child (the run's) that has run for 0.2 s."""
    import time

    children = Path(f"/proc/{server}/task/{server}/children")
    while not stop.is_set():
        if children.read_text().split():
            time.sleep(0.2)
            os.kill(server, 9)
            return
        time.sleep(0.01)


@pytest.mark.slow  # 7 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_fork_server_that_dies_as_a_run_is_handed_to_it_is_named(toys, monkeypatch):
    """The server killed between taking a run's request and reading the run: a BrokenPipeError traceback before
    (seen on a loaded machine); now the one-line error that names the server, and the next run starts a new one."""
    from multiprocessing import forkserver

    from fmu_opinf.errors import FMUError
    from fmu_opinf.snapshots import _isolation

    monkeypatch.setitem(_isolation._FORK_SERVER, "enabled", True)
    signal = SignalStub(amplitude=1.0, t0=0.35)
    record(FMUSource(toys["fmi3"]), signal, 0.01, 0.5, quiet=True, isolate=True)  # starts the server
    if _isolation._process_context().get_start_method() != "forkserver":
        pytest.skip("another fork server runs in this process")
    handed_over = forkserver.connect_to_new_process

    def then_lose_the_server(fds):
        pipes = handed_over(fds)
        os.kill(forkserver._forkserver._forkserver_pid, 9)  # no wait: its pipes break before it has exited
        return pipes

    for _ in range(3):  # a review saw 1 BrokenPipeError in 40 while the dead server was not reaped yet
        server = forkserver._forkserver._forkserver_pid
        monkeypatch.setattr(forkserver, "connect_to_new_process", then_lose_the_server)
        with pytest.raises(FMUError, match="fork server .* stopped"):
            record(FMUSource(toys["fmi3"]), signal, 1e-5, 30.0, quiet=True, isolate=True)
        monkeypatch.setattr(forkserver, "connect_to_new_process", handed_over)
        run = record(FMUSource(toys["fmi3"]), signal, 0.01, 0.5, quiet=True, isolate=True).runs[0]
        assert run.k == 51 and forkserver._forkserver._forkserver_pid not in (None, server)

@pytest.mark.slow  # 3 s: builds an FMU and starts a Python process with a fork server
def test_an_isolated_run_ends_when_its_caller_is_killed_inside_a_long_sample(tmp_path):
    """The run's process ignores SIGINT and SIGTERM (its caller decides) and reported only after each block: inside
    a sample that took minutes it outlived its killed command for 7 minutes (audit of 2026-12-05).  It now leaves
    as soon as its caller dies, and the fork server and resource tracker follow."""
    import signal as _signal
    import subprocess
    import textwrap
    import time

    from fmu_opinf import lti_fmus
    from test_linear_hold import stiff_chain

    path = tmp_path / "Chain.fmu"
    lti_fmus.build_lti_fmu(stiff_chain(), path, interfaces=("me",))
    script = textwrap.dedent(f"""
        from fmu_opinf.snapshots import record, use_fork_server
        from fmu_opinf.sources import open_source
        use_fork_server()
        # samples of 1e5 s, each about 5 minutes of DOP853 held to its stability limit
        record(open_source({str(path)!r}, method="dop853"), "step", 1e5, 1e6, quiet=True, isolate=True)
    """)
    # (its own temporary folder: the killed caller cannot remove the FMU it unpacked)
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path), TMPDIR=str(tmp_path))
    caller = subprocess.Popen([sys.executable, "-c", script], env=environment)
    try:
        # tracker, server, run: the same three for half a second (a short-lived child, such as a compiler building
        # the step loop in a fresh checkout, came and went: CI of 2026-12-06 counted three, then two)
        deadline, left_behind = time.monotonic() + 60, []
        while time.monotonic() < deadline:
            seen = _descendants(caller.pid)
            if len(seen) >= 3 and sorted(seen) == sorted(left_behind):
                break
            left_behind = seen
            time.sleep(0.5)
        assert len(left_behind) >= 3, left_behind
    finally:
        caller.kill()
        caller.wait()
    deadline = time.monotonic() + 10
    try:
        while any(_alive(pid) for pid in left_behind) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not [pid for pid in left_behind if _alive(pid)]
    finally:
        for pid in left_behind:
            if _alive(pid):
                os.kill(pid, _signal.SIGKILL)


def _descendants(pid: int) -> list[int]:
    try:
        children = [int(child) for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    return children + [grandchild for child in children for grandchild in _descendants(child)]


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


# ------------------------------------------------------------------------------- command-line entry, auto window


def test_record_to_file_writes_one_run_per_input_with_provenance(toys, tmp_path):
    summary = record_to_file(str(toys["full"]), tmp_path / "two.h5",
                             ["step:amplitude=1,t0=0.35", "harmonic:amplitude=1,omega=2"], dt=0.1, t_end=2.0,
                             constraint="none", quiet=True, isolate=False)
    assert [k for k, _, _ in summary.runs] == [21, 21] and "2 run(s)" in summary.describe()
    assert str(summary) == str(tmp_path / "two.h5")
    snaps = Snapshots.load(tmp_path / "two.h5")
    assert snaps.attrs["constraint"] == "none" and snaps.attrs["fmi_version"] == "2.0" and snaps.attrs["dt"] == 0.1
    assert snaps.attrs["fmu_guid"] == "{toy-0001}" and len(snaps.attrs["fmu_sha256"]) == 64
    assert snaps.attrs["input_names"] == ["u"] and snaps.attrs["output_names"] == ["y[1]", "y[2]"]
    assert [r.attrs["input_spec"] for r in snaps.runs] == [parse_signal("step:amplitude=1,t0=0.35").spec,
                                                           parse_signal("harmonic:amplitude=1,omega=2").spec]
    assert all(r.complete and r.attrs["dt"] == 0.1 and r.attrs["t_end"] == 2.0 for r in snaps.runs)
    np.testing.assert_allclose(snaps.runs[1].u[0, 1:], np.sin(2.0 * snaps.runs[1].t[:-1]), rtol=0, atol=1e-15)


@pytest.mark.slow
def test_record_to_file_without_a_window_chooses_it_automatically(tmp_path):
    summary = record_to_file("builtin:anchored-msd", tmp_path / "x.h5", "impulse:amplitude=100,t0=2,width=0.5",
                             quiet=True, g=12)
    assert summary.window is not None and summary.window.stopped_by == "fade"
    assert Snapshots.load(tmp_path / "x.h5").runs[0].attrs["dt"] == summary.window.dt


@pytest.mark.slow  # 8 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_auto_window_resolves_the_response_and_waits_for_the_fade_out(bundled, tmp_path):
    spec = "impulse:amplitude=100,t0=2,width=0.5"
    source = FMUSource(bundled["AnchoredMSD"])
    window = auto_window(source, spec)
    assert window.dt * window.f_max * window.points_per_period <= 1.0
    assert window.t_end >= window.t_fade and window.t_end - window.t_fade < window.dt
    # check against a long run: after t_end the output stays below fade x its peak
    long_run = record(source, spec, window.dt, 4 * window.t_end, quiet=True).runs[0]
    e = np.linalg.norm(long_run.y, axis=0)
    assert e[long_run.t > window.t_end].max() <= window.fade * e.max() * 1.05
    assert e[long_run.t > 0.5 * window.t_end].max() > window.fade * e.max()  # ... and not much earlier
    summary = record_to_file(source, tmp_path / "auto.h5", spec, auto_window=True, quiet=True)
    stored = Snapshots.load(tmp_path / "auto.h5")
    assert stored.attrs["auto_window"] == window.as_dict() == stored.runs[0].attrs["auto_window"]
    assert stored.runs[0].attrs["dt"] == window.dt and summary.window == window


def test_auto_window_rejects_bad_thresholds():
    source = BuiltinSource("anchored-msd", g=12)
    for kwargs, text in (({"energy": 1.0}, "energy=1.0 must lie strictly between"),
                         ({"fade": 0.0}, "fade=0.0 must lie strictly between"),
                         ({"points_per_period": 1}, "at least 2")):
        with pytest.raises(InputSpecError, match=text):
            auto_window(source, "impulse:amplitude=1", **kwargs)


def test_time_grid_and_inputs_in_effect():
    t = time_grid(0.25, 1.0)
    np.testing.assert_array_equal(t, [0.0, 0.25, 0.5, 0.75, 1.0])
    u = snapshots.inputs_in_effect(SignalStub(amplitude=2.0, t0=0.5), t, 1)
    np.testing.assert_array_equal(u, [[0.0, 0.0, 0.0, 2.0, 2.0]])  # u[:, i] = u(t_{i-1})
    for dt, t_end, text in ((0.0, 1.0, "must be positive"), (2.0, 1.0, "longer than the time window"),
                            (0.1, -1.0, "after the start time")):
        with pytest.raises(InputSpecError, match=text):
            time_grid(dt, t_end)


def test_recording_is_silent_when_quiet_or_not_a_terminal(capsys):
    record(BuiltinSource("anchored-msd", g=12), "step:amplitude=1", 0.5, 10.0, quiet=False)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""


# ------------------------------------------------------------------------------- free response, inputs, layout


def _free_reference(x0: np.ndarray, t: np.ndarray, k: float = 1.0) -> np.ndarray:
    """Exact positions of x'' + 0.1 K x' + K x = 0 (the toy chain) from x(0) = x0, x'(0) = 0."""
    from scipy.linalg import expm

    from test_source import TOY_K

    K = k * TOY_K
    n = len(x0)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-K, -0.1 * K]])
    z0 = np.concatenate([x0, np.zeros(n)])
    return np.stack([(expm(A * ti) @ z0)[:n] for ti in t], axis=1)


def test_fmu_without_inputs_records_its_free_response_from_the_initial_state(toys, tmp_path):
    path = tmp_path / "free.h5"
    summary = record_to_file(toys["no-input"], path, [], dt=0.01, t_end=3.0, parameters={"x[1]": "0.5", "x[3]": "-0.2"},
                             quiet=True)
    assert (summary.m, summary.runs[0][2]) == (0, "none")
    snaps = Snapshots.load(path)
    run = snaps.runs[0]
    assert snaps.m == 0 and run.u.shape == (0, run.k) and snaps.attrs["layout_version"] == 2
    np.testing.assert_array_equal(run.x0, [0.5, 0.0, -0.2])
    np.testing.assert_array_equal(run.v0, [0.0, 0.0, 0.0])
    # the toy integrates by Newmark; at dt = 0.01 its error against the exact response is 4.1e-5 of the peak
    assert relative(run.x, _free_reference(np.array([0.5, 0.0, -0.2]), run.t)) < 1e-4


@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_input_none_on_a_model_with_inputs_holds_them_at_their_start_values(toys, tmp_path):
    only_free = record_to_file(toys["param-input"], tmp_path / "a.h5", "none", dt=0.1, t_end=1.0,
                               parameters={"x[2]": "0.1"}, quiet=True)
    assert only_free.m == 0  # every run free: no force inputs at all
    snaps = Snapshots.load(tmp_path / "a.h5")
    assert snaps.attrs["held_input_names"] == ["fault_threshold", "u"]
    assert np.abs(snaps.runs[0].x).max() > 0.05  # it moves: the initial state is off rest
    mixed = record_to_file(toys["param-input"], tmp_path / "b.h5", ["step:amplitude=1,t0=0.35", "none"], dt=0.1,
                           t_end=1.0, inputs="u", quiet=True)
    assert mixed.m == 1
    runs = Snapshots.load(tmp_path / "b.h5").runs
    assert runs[0].u.max() == 1.0 and np.all(runs[1].u == 0.0)  # u's start value is 0
    assert np.abs(runs[1].x).max() == 0.0  # from rest without input nothing moves


def test_builtin_free_response_with_input_none():
    run = record(BuiltinSource("anchored-msd", g=12), "none", 0.5, 5.0, quiet=True).runs[0]
    assert run.u.shape == (1, 11) and np.all(run.u == 0.0) and run.attrs["input_spec"] == "none"
    assert np.abs(run.x).max() == 0.0  # the builtin systems start at rest


def test_every_parameter_like_input_is_excluded_by_the_suggested_fix(tmp_path, monkeypatch):
    """Audit 2026-11-27: of two parameters exposed as inputs, the error named only the one zero at the failing step
    and suggested driving the other; that recorded another model without a word (ROM 120 % off).  The error now
    excludes both, and driving an input that starts at a non-zero value is a warning."""
    from fmu_opinf import lti_fmus, sources

    monkeypatch.setattr(sources, "_REPORTED", set())
    path = tmp_path / "parin.fmu"
    lti_fmus.build_lti_fmu(lti_fmus.chain_model(name="ParIn"), path, parameter_inputs=("mass_scale", "stiffness_scale"))
    with pytest.warns(FmuOpinfWarning, match=r"driven input\(s\) mass_scale, stiffness_scale start at non-zero"):
        with pytest.raises(StepError) as info:
            source = sources.open_source(path, inputs="F,mass_scale,stiffness_scale")
            record(source, "step:amplitude=1;step:amplitude=0;step:amplitude=1", 0.05, 1.0, quiet=True)
    text = str(info.value)
    assert "inputs mass_scale were set to 0" in text and "(and stiffness_scale, which start at non-zero" in text
    assert "exclude them" in text and "with --inputs F or inputs='F' and give their values with --set or " \
                                      "parameters=" in text
    with pytest.warns(FmuOpinfWarning, match=r"driven input\(s\) stiffness_scale .* record with --inputs F or "
                                             r"inputs='F' and"):
        sources.open_source(path, inputs="F,stiffness_scale")


@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_parameter_like_inputs_driven_to_zero_are_named_in_the_error(toys, tmp_path, monkeypatch):
    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())   # the warning is once per process
    with pytest.raises(StepError) as info:
        # one channel per input (fault_threshold, u), both named as forces: the parameter-like input is driven to 0
        record_to_file(toys["param-input"], tmp_path / "p.h5", "step:amplitude=0;step:amplitude=1,t0=0.35", dt=0.1,
                       t_end=1.0, parameters={"fault": "1"}, inputs="fault_threshold,u", quiet=True)
    text = str(info.value)
    assert "\n" not in text and "toy fault" in text
    assert "inputs fault_threshold were set to 0 but have non-zero start values" in text and "--inputs u" in text
    with pytest.warns(FmuOpinfWarning, match="input.s. fault_threshold start at non-zero values .* held at them"):
        fixed = record_to_file(toys["param-input"], tmp_path / "q.h5", "step:amplitude=1,t0=0.35", dt=0.1,
                               t_end=1.0, parameters={"fault": "1"}, quiet=True)
    assert fixed.m == 1  # by default the threshold is held at its start value 1e300, not driven
    assert fixed.runs[0][1]  # complete


def test_layout_1_files_still_load():
    """tests/data/snapshots-v1.h5 was written by the layout-1 recorder (toy FMU, k=2, a step at 0.35)."""
    from pathlib import Path

    snaps = Snapshots.load(Path(__file__).parent / "data" / "snapshots-v1.h5")
    run = snaps.runs[0]
    assert snaps.attrs["layout_version"] == 1 and (snaps.n, snaps.m, snaps.p) == (3, 1, 2)
    assert snaps.attrs["fmu_parameters"] == {"k": 2.0}
    np.testing.assert_array_equal(run.x0, run.x[:, 0])  # layout 1: the initial state is the first sample
    np.testing.assert_array_equal(run.v0, run.xdot[:, 0])
    assert run.k == 11 and run.u[0, 5] == 1.0 and run.u[0, 4] == 0.0  # the step at 0.35 acts from t=0.5


def test_initial_state_survives_save_and_load(tmp_path):
    from fmu_opinf.snapshots import Run

    k, t = 5, np.arange(5.0)
    run = Run(t=t, u=np.zeros((0, k)), x=np.ones((2, k)), xdot=np.zeros((2, k)), xddot=np.zeros((2, k)),
              y=np.zeros((1, k)), x0=[3.0, 4.0], v0=[5.0, 6.0])
    Snapshots([run], {"n": 2, "m": 0, "p": 1}).save(tmp_path / "s.h5")
    back = Snapshots.load(tmp_path / "s.h5").runs[0]
    np.testing.assert_array_equal(back.x0, [3.0, 4.0])
    np.testing.assert_array_equal(back.v0, [5.0, 6.0])
    assert back.u.shape == (0, k)


def test_cli_set_and_input_none(toys, tmp_path, capsys):
    from fmu_opinf.cli import main

    out = tmp_path / "cli.h5"
    code = main(["snapshots", str(toys["no-input"]), "-o", str(out), "--dt", "0.1", "--t-end", "1", "--set",
                 "x[2]=0.3", "--set", "k=2", "--in-process"])
    assert code == 0
    err = capsys.readouterr().err
    assert "positions x[1], x[2], x[3]" in err
    snaps = Snapshots.load(out)
    assert snaps.attrs["fmu_settings"] == {"x[2]": 0.3, "k": 2.0} and snaps.m == 0  # typed, as from Python
    np.testing.assert_array_equal(snaps.runs[0].x0, [0.0, 0.3, 0.0])
    code = main(["snapshots", str(toys["no-input"]), "-o", str(tmp_path / "bad.h5"), "--dt", "0.1", "--t-end", "1",
                 "--set", "k=stiff"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "k is a Real variable" in err[0]
    code = main(["snapshots", str(toys["full"]), "-o", str(tmp_path / "early.h5"), "--dt", "0.1", "--t-end", "1"])
    err = capsys.readouterr().err.strip().splitlines()  # the default impulse at t = 2 would never act
    assert code == 2 and "is zero at every sample of the grid dt=0.1, t_end=1" in err[-1]
    assert not (tmp_path / "early.h5").exists()
    code = main(["snapshots", str(toys["full"]), "-o", str(tmp_path / "none.h5"), "--dt", "0.1", "--t-end", "3"])
    assert code == 0 and "no --input or signal= given: recording the impulse training input" in capsys.readouterr().err
    assert Snapshots.load(tmp_path / "none.h5").runs[0].attrs["input_spec"].startswith("impulse:amplitude=100")


def test_a_run_table_rows_own_settings_do_not_become_the_data_sets():
    """Run table rows recorded with their own start values (a file each): the merged set keeps only the settings
    all rows share, and a row without settings of its own comes first (its start is the ROM's reference state).
    Before, the alphabetically first row's ``start:`` values were the set's: compare and the exported FMU started
    from them (second audit, 2026-11-26: max eps_y 20.4 against the model's own start)."""
    from fmu_opinf.basis import _common_settings_first

    common = {"k": "2"}
    settings = [{**common, "mass[1].s": "0.3"}, dict(common), dict(common)]
    assert _common_settings_first(["free", "imp1", "imp2"], settings) == ["imp1", "imp2", "free"]
    from fmu_opinf.snapshots import Run

    k = 5
    run = Run(t=np.arange(5.0), u=np.zeros((0, k)), x=np.ones((2, k)), xdot=np.zeros((2, k)),
              xddot=np.zeros((2, k)), y=np.zeros((1, k)))
    merged = Snapshots([run], {"fmu_settings": {**common, "mass[1].s": "0.3"}})
    merged.append(Snapshots([run], {"fmu_settings": dict(common)}))
    assert merged.attrs["fmu_settings"] == common


def test_settings_given_as_text_and_as_numbers_are_one_setting_when_merged():
    """A file recorded from the command line before 2026-12-08 keeps ``--set k1=2`` as the text ``"2"``, one recorded
    from Python (or since) the number ``2.0``: merged, they were "recorded with different settings" (a false warning)
    and the merged set lost ``k1``, so ``compare`` ran the FMU at its start value, not the trained one."""
    from fmu_opinf.snapshots import Run
    from fmu_opinf.snapshots._merge import merge_differences

    k = 5
    run = Run(t=np.arange(5.0), u=np.zeros((0, k)), x=np.ones((2, k)), xdot=np.zeros((2, k)),
              xddot=np.zeros((2, k)), y=np.zeros((1, k)))
    old = {"fmu_settings": {"k1": "2", "x0": "[1, 2.5]", "on": "True", "mode": " Fast"}}
    new = {"fmu_settings": {"k1": 2.0, "x0": [1, 2.5], "on": True, "mode": "fast"}}
    merged = Snapshots([run], old)
    merged.append(Snapshots([run], new))
    assert merged.attrs["fmu_settings"] == old["fmu_settings"]
    assert len(merged.attrs["merged_parts"]["parts"]) == 2 and merge_differences(merged.attrs) is None
    for changed in ({"k1": 2.5}, {"x0": [1, 2.4]}, {"on": False}, {"mode": "slow"}):
        other = Snapshots([run], {"fmu_settings": {**new["fmu_settings"], **changed}})
        other.append(Snapshots([run], old))
        assert other.attrs["fmu_settings"].keys() == old["fmu_settings"].keys() - changed.keys()
        assert f"different settings ({next(iter(changed))}: " in merge_differences(other.attrs)


def test_a_non_inheritable_descriptor_in_place_of_stdout_is_not_handed_to_the_run(monkeypatch, tmp_path):
    """With stdout closed, the run's shared memory (opened close-on-exec) can take descriptor 1; handing that to a
    fork-server child as its stdout let an FMU's printing overwrite recorded samples (review of 2026-11-27).  Only
    inheritable descriptors are passed; the child points the others at the null device."""
    from multiprocessing import reduction

    from fmu_opinf.snapshots import _isolation

    passed = []
    monkeypatch.setattr(reduction, "DupFd", lambda fd: passed.append(fd) or fd)
    saved = os.dup(1)
    private = os.open(tmp_path / "private", os.O_WRONLY | os.O_CREAT)
    try:
        os.dup2(private, 1, inheritable=False)  # what SharedMemory(create=True) does when fd 1 is free
        _isolation._Inherited({}).__reduce__()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(private)
    assert passed == [2]
    passed.clear()
    _isolation._Inherited({}).__reduce__()
    assert passed == [1, 2]


def test_a_slow_model_reports_its_progress_in_a_log(monkeypatch, capsys):
    """A model that takes seconds per sample (a stiff FE model under an explicit integrator: 0.4 s per sample,
    twelfth audit) gets small blocks, so a log (stderr not a terminal) has a line while it runs, not minutes of
    silence; a fast run writes none."""
    import time as _time

    from fmu_opinf import _progress
    from fmu_opinf.snapshots import _isolation

    monkeypatch.setattr(_progress, "LOG_AFTER", 0.3)
    monkeypatch.setattr(_progress, "LOG_EVERY", 0.3)
    monkeypatch.setattr(_isolation._BlockSizes, "SECONDS", 0.05)
    source = BuiltinSource("anchored-msd", g=4)
    advance = source.advance
    sizes = []

    def slow_advance(rows, i0, count, **kwargs):
        sizes.append(count)
        _time.sleep(0.01 * count)   # 10 ms per sample
        return advance(rows, i0, count, **kwargs)

    monkeypatch.setattr(source, "advance", slow_advance)
    record(source, "step", 0.5, 60.0, quiet=False)
    err = capsys.readouterr().err
    assert sizes[:2] == [16, 16] and max(sizes) <= 64   # blocks stay small: each took longer than 0.05 s
    lines = [line for line in err.splitlines() if "after" in line]
    assert len(lines) >= 2 and lines[-1].endswith("(ended)") and "121/121" in lines[-1]
    record(BuiltinSource("anchored-msd", g=4), "step", 0.5, 60.0, quiet=False)
    assert "after" not in capsys.readouterr().err


def test_record_to_file_names_the_input_signal_like_record_and_compare(tmp_path):
    """Audit 68: the input was ``signal=`` in ``record`` and ``compare`` but ``input_spec=`` here, and ``energy=``
    meant the auto window's spectral share here but the POD energy in ``fit_rom``.  The old keywords still work,
    with a DeprecationWarning, and give the same file."""
    spec = "harmonic:amplitude=1,omega=0.5"
    new = snapshots.record_to_file("builtin:anchored-msd", tmp_path / "new.h5", signal=spec, dt=0.5, t_end=10.0,
                                   quiet=True, g=12)
    with pytest.warns(DeprecationWarning, match=r"input_spec=\.\.\.\) is now signal="):
        old = snapshots.record_to_file("builtin:anchored-msd", tmp_path / "old.h5", input_spec=spec, dt=0.5,
                                       t_end=10.0, quiet=True, g=12)
    a, b = Snapshots.load(str(new)), Snapshots.load(str(old))
    np.testing.assert_array_equal(a.runs[0].x, b.runs[0].x)
    assert a.runs[0].attrs["input_spec"] == parse_signal(spec).spec
    with pytest.warns(DeprecationWarning, match=r"energy=\.\.\.\) is now window_energy="):
        snapshots.record_to_file("builtin:anchored-msd", tmp_path / "e.h5", signal=spec, auto_window=True,
                                 energy=0.99, quiet=True, g=12)
