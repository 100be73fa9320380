"""The demo's cases side by side: same rows and table as one after the other, labelled lines, same errors.

run_case is replaced by a fast stand-in (the real chain is exercised by test_demo.py); the worker is forked,
so the stand-in runs there as well.
"""

import json
import os
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from fmu_opinf import cli, demo
from fmu_opinf._forked import LabelledLines, RemoteTraceback, Worker, can_fork
from fmu_opinf.errors import DataError, Interrupted
from fmu_opinf.fmus import find_build_tools
from fmu_opinf.sources import StepError

pytestmark = pytest.mark.skipif(not can_fork(), reason="workers are forked only on Linux")


def _metrics(max_error: float) -> dict:
    return {"max_error": max_error, "l2_error": 2 * max_error, "r": 3, "fom_seconds": 0.5, "rom_seconds": 0.25,
            "speedup": 2.0}


def fake_case(name, out_dir, quick=False, quiet=False, compile_fmus=True):
    """Prints to both streams (unless quiet), sleeps, and says in which process and when it ran."""
    started = time.time()
    if not quiet:
        print(f"stdout line of {name}")
        print(f"stderr line of {name}", file=sys.stderr)
        print(f"[{name}] already labelled")
    time.sleep(0.5)
    out_dir.mkdir(parents=True, exist_ok=True)
    return {"model": name, "r": 3, "dt": 0.5, "t_end": 10.0, "timings": {"fit": 0.1},
            "rom": _metrics(1e-7 if name == "anchored-msd" else 2e-8), "rom_fmu": None,
            "pid": os.getpid(), "span": [started, time.time()]}


def _run_demo(tmp_path, monkeypatch, capsys, side_by_side: bool, folder: str):
    monkeypatch.setattr(demo, "_side_by_side", lambda names: side_by_side)
    rows = demo.run_demo(tmp_path / folder)
    return rows, capsys.readouterr()


def test_side_by_side_gives_the_rows_and_table_of_one_after_the_other(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo, "run_case", fake_case)
    serial, serial_out = _run_demo(tmp_path, monkeypatch, capsys, False, "serial")
    parallel, parallel_out = _run_demo(tmp_path, monkeypatch, capsys, True, "parallel")
    # the second case ran in another process, at the same time as the first
    assert parallel[0]["pid"] == os.getpid() != parallel[1]["pid"]
    assert parallel[1]["span"][0] < parallel[0]["span"][1] and parallel[0]["span"][0] < parallel[1]["span"][1]
    assert serial[1]["span"][0] >= serial[0]["span"][1]

    def content(rows):
        return [{k: v for k, v in row.items() if k not in ("pid", "span")} for row in rows]

    assert content(parallel) == content(serial)
    files = [json.loads((tmp_path / folder / "summary.json").read_text()) for folder in ("serial", "parallel")]
    assert content(files[1]["cases"]) == content(files[0]["cases"]) == content(serial)
    # the same table; every line a case prints says which case it comes from, and is whole
    table = serial_out.out[serial_out.out.index("case "):serial_out.out.index("total ")]
    assert table in parallel_out.out
    for name in demo.CASES:
        assert f"[{name}] stdout line of {name}\n" in parallel_out.out
        assert f"[{name}] stderr line of {name}\n" in parallel_out.err
        assert f"[{name}] already labelled\n" in parallel_out.out
        assert f"[{name}] [{name}]" not in parallel_out.out


def _freeze_count_case(name, out_dir, **options):
    """Says how many objects the garbage collector leaves out in the process the case runs in."""
    import gc

    return {**fake_case(name, out_dir, quiet=True), "frozen": gc.get_freeze_count()}


def test_the_cases_run_with_the_imports_left_out_of_garbage_collection_and_the_demo_takes_them_back(
        tmp_path, monkeypatch, capsys):
    """A full collection walked the ~100,000 objects of the imports, 0.05-0.1 s each, several times per case."""
    import gc

    monkeypatch.setattr(demo, "run_case", _freeze_count_case)
    assert gc.get_freeze_count() == 0
    rows, _ = _run_demo(tmp_path, monkeypatch, capsys, True, "frozen")
    assert rows[0]["pid"] != rows[1]["pid"]
    # the imports of the demo's modules, matplotlib and SciPy (well over 50,000 objects) in both processes
    assert all(row["frozen"] > 50_000 for row in rows), [row["frozen"] for row in rows]
    assert gc.get_freeze_count() == 0 and gc.isenabled()


@pytest.mark.skipif(find_build_tools() is None, reason="no C compiler or CMake to build the FMUs")
@pytest.mark.slow  # one quick case in a fresh interpreter: 4 s on the idle 2-core machine
def test_every_module_the_demo_loads_before_forking_is_one_a_case_imports(tmp_path):
    """The preload is serial time before the cases run side by side: a module no case imports (scipy.optimize,
    0.1-0.17 s, after the fit stopped using it) only delays both."""
    script = textwrap.dedent(f"""
        import sys
        from pathlib import Path
        from fmu_opinf import demo
        demo.run_case("anchored-msd", Path({str(tmp_path / "case")!r}), quick=True, quiet=True)
        print(",".join(name for name in demo._PRELOAD if name not in sys.modules))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                          env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    assert done.stdout.strip().splitlines()[-1:] in ([], [""]), done.stdout


def _failing_second_case(name, out_dir, **options):
    if name == "triple-chain":
        raise StepError("TripleChainMSD.fmu crashed the simulation process (signal SIGSEGV) at step 3 "
                        "(t=2 -> 3)", 3, 2.0)
    return fake_case(name, out_dir, **options)


def test_an_error_in_the_worker_is_the_cli_one_line_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo, "run_case", _failing_second_case)
    monkeypatch.setattr(demo, "_side_by_side", lambda names: True)
    assert cli.main(["demo", "-o", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err == ("fmu-opinf: error: TripleChainMSD.fmu crashed the simulation process (signal SIGSEGV) at "
                   "step 3 (t=2 -> 3)\n")
    assert not (tmp_path / "out" / "summary.json").exists()


def _failing_first_case(name, out_dir, **options):
    if name == "anchored-msd":
        raise DataError("the snapshots hold NaN; check the FMU")
    time.sleep(60)


def test_an_error_in_the_first_case_stops_the_worker_at_once(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(demo, "run_case", _failing_first_case)
    monkeypatch.setattr(demo, "_side_by_side", lambda names: True)
    started = time.perf_counter()
    assert cli.main(["demo", "-o", str(tmp_path / "out"), "--quiet"]) == 2
    assert time.perf_counter() - started < 30  # the worker's 60 s sleep was cut short
    assert capsys.readouterr().err == "fmu-opinf: error: the snapshots hold NaN; check the FMU\n"


def _raise(exc):
    raise exc


class _Unpicklable(ValueError):
    def __init__(self, message):
        super().__init__(message)
        self.handle = threading.Lock()


@pytest.mark.parametrize("exc, attributes", [
    (StepError("step 7 failed", 7, 3.5), {"step": 7, "time": 3.5}),  # __init__ does not take its args
    (Interrupted(15), {"signum": 15}),
    (FileExistsError(17, "File exists", "out.h5"), {"filename": "out.h5", "errno": 17}),
    (ZeroDivisionError("a bug"), {}),
])
def test_worker_exceptions_keep_type_message_and_attributes(exc, attributes):
    worker = Worker("[w] ", _raise, exc, lock=threading.Lock())
    try:
        with pytest.raises(type(exc)) as raised:
            worker.result()
    finally:
        worker.stop()
    assert type(raised.value) is type(exc) and str(raised.value) == str(exc)
    for name, value in attributes.items():
        assert getattr(raised.value, name) == value
    cause = raised.value.__cause__
    assert isinstance(cause, RemoteTraceback) and "_raise" in cause.text  # the worker's own traceback


def test_an_exception_that_cannot_travel_becomes_a_runtime_error_with_its_traceback():
    worker = Worker("[w] ", _raise, _Unpicklable("cannot pickle a lock"), lock=threading.Lock())
    try:
        with pytest.raises(RuntimeError, match="worker process failed") as raised:
            worker.result()
    finally:
        worker.stop()
    assert "_Unpicklable: cannot pickle a lock" in raised.value.__cause__.text


def test_a_worker_that_dies_without_a_result_is_reported():
    worker = Worker("[w] ", os._exit, 3, lock=threading.Lock())
    try:
        with pytest.raises(RuntimeError, match=r"\[w\] ended without a result \(exit code 3\)"):
            worker.result()
    finally:
        worker.stop()


def test_the_worker_exits_when_its_parent_is_killed(tmp_path):
    script = textwrap.dedent("""
        import os, sys, threading, time
        from fmu_opinf._forked import Worker

        def report_and_wait():
            print(os.getpid())
            time.sleep(60)

        Worker("", report_and_wait, lock=threading.Lock())
        time.sleep(60)
    """)
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    try:
        child = int(parent.stdout.readline())
    finally:
        parent.kill()
        parent.wait()
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and _state(child) not in ("gone", "Z"):
            time.sleep(0.05)
        assert _state(child) in ("gone", "Z")
    finally:
        if _state(child) not in ("gone", "Z"):
            os.kill(child, 9)


def _state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


@pytest.mark.skipif(find_build_tools() is None, reason="no C compiler or CMake to build the FMUs")
@pytest.mark.slow  # 10 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_the_rom_fmu_compiles_while_the_figures_are_drawn_and_its_errors_stay_the_same(tmp_path, monkeypatch,
                                                                                        capsys):
    from fmu_opinf import export, plots
    from fmu_opinf.fmus import FmuBuildError

    events = {}
    pod_figures = plots.pod_figures

    def failing_export(*args, **kwargs):
        events["export started"] = time.perf_counter()
        time.sleep(0.5)
        raise FmuBuildError("compilation failed (exit code 1): model.c:1: error")

    def timed_figures(*args, **kwargs):
        value = pod_figures(*args, **kwargs)
        events["figures done"] = time.perf_counter()
        return value

    monkeypatch.setattr(export, "export_fmu", failing_export)
    monkeypatch.setattr(plots, "pod_figures", timed_figures)
    out = tmp_path / "out"
    assert cli.main(["demo", "-o", str(out), "--quick", "--quiet", "--model", "anchored-msd"]) == 2
    assert events["export started"] < events["figures done"]
    assert capsys.readouterr().err == "fmu-opinf: error: compilation failed (exit code 1): model.c:1: error\n"
    # the failed run leaves the folder as it was before it (empty: since 2026-12-06 a demo folder holds whole runs)
    assert sorted(path.name for path in out.iterdir()) == []


def test_labelled_lines_pass_on_whole_lines_once_labelled():
    emitted = []
    stream = LabelledLines("[case] ", emitted.append)
    stream.write("first ")
    assert emitted == []  # nothing until the line is whole
    stream.write("line\nsecond\n[case] third\nunfinished")
    stream.finish()
    assert "".join(emitted) == "[case] first line\n[case] second\n[case] third\n[case] unfinished\n"
    assert not stream.isatty()


def test_labelled_lines_written_from_two_threads_at_once_stay_whole():
    """A demo case's export runs in a thread that may warn while the case's main thread prints: nothing written
    is lost or doubled, each line is passed on whole and labelled once."""
    emitted = []
    stream = LabelledLines("[case] ", emitted.append)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads as often as possible: interleavings the old code did not survive
    try:
        def write(word):
            for _ in range(20000):
                stream.write(word)
                stream.write(word + "\n")

        threads = [threading.Thread(target=write, args=(word,)) for word in ("abc", "xyz")]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(interval)
    text = "".join(emitted)
    # nothing lost or doubled: every character written, every line whole and labelled once
    assert (text.count("b"), text.count("y"), text.count("\n")) == (40000, 40000, 40000)
    assert all(line.startswith("[case] ") and "[case]" not in line[7:] for line in text.splitlines())
