"""The whole chain on the bundled benchmark FMUs, with the paper's defaults.

For each model: build the FMU if missing; impulse-like training input with the automatic
snapshot window (paper section 4.2); POD order from the cumulative energy (eq. 18); SDP fit
(eq. 16) and output least squares (eq. 17); comparison with the FMU on a harmonic test input
(eq. 19); export of the ROM as an FMU, compared with the full-order FMU as well; one report per
model and a summary page.
"""

from __future__ import annotations

import contextlib
import html
import json
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, TypeVar

from ._interrupts import deferred_interrupts
from .report import _atomic_write_bytes, prepare_report_directory, summary_table
from .errors import FileFormatError

__all__ = ["DemoCase", "CASES", "run_demo"]

T = TypeVar("T")


@dataclass(frozen=True)
class DemoCase:
    """Settings of one benchmark in the demo.

    Attributes
    ----------
    fmu : str
        Name of the bundled FMU.
    constraint : str
        Constraint kind the user knows about the black box (chooses the POD data).
    training_input, test_input : str
        Impulse-like training input and harmonic test input (paper Fig. 3).
    window : dict
        Keywords of :func:`fmu_opinf.snapshots.auto_window`.
    test_t_end : float
        Length of the test simulation.
    quick_window : tuple of float
        ``(dt, t_end)`` used by ``--quick`` instead of the pilot runs of the automatic window (the window
        that the automatic choice takes, rounded).
    quick_order : int or None
        Reduced order used by ``--quick`` (None: the default order of eq. 18, as without ``--quick``).
    """

    fmu: str
    constraint: str
    training_input: str
    test_input: str
    window: dict[str, Any]
    test_t_end: float
    quick_window: tuple[float, float]
    quick_order: int | None = None


CASES: dict[str, DemoCase] = {
    "anchored-msd": DemoCase(
        fmu="AnchoredMSD", constraint="position",
        training_input="impulse:amplitude=100,t0=2,width=0.5",
        test_input="harmonic:amplitude=1,omega=0.2",
        window={}, test_t_end=400.0, quick_window=(0.5, 95.5)),
    "triple-chain": DemoCase(
        fmu="TripleChainMSD", constraint="velocity",
        training_input="impulse:amplitude=100,t0=2,width=0.5",
        test_input="harmonic:amplitude=1,omega=0.2",
        window={}, test_t_end=400.0, quick_window=(0.5, 884.5), quick_order=12),
}


#: The demo's FMUs (benchmarks built from the bundled C sources, ROM FMUs it exports) run in the demo's process, as
#: its recordings do: a separate process per simulation (compare's default, against crashing third-party
#: binaries) cost about 0.5 s of interpreter start-up and imports each, six times.
_IN_PROCESS = {"isolate": False}


def _log(message: str, quiet: bool) -> None:
    if not quiet:
        print(message, flush=True)


def run_case(name: str, out_dir: Path, quick: bool = False, quiet: bool = False,
             compile_fmus: bool = True) -> dict[str, Any]:
    """Run the chain for one benchmark into ``out_dir``; returns its summary (metrics and timings).

    With ``compile_fmus=False`` (no C compiler) the builtin reference simulator of the same model
    stands in for the benchmark FMU and the ROM is not exported (``"rom_fmu"`` is None).
    """
    from . import export, fit, fmus, plots, report, snapshots
    from .source import FMUSource

    case = CASES[name]
    prepare_report_directory(out_dir)
    timings: dict[str, float] = {}

    start = time.perf_counter()
    if compile_fmus:
        fmu_path: Any = fmus.bundled_fmu(case.fmu)
        source: Any = FMUSource(fmu_path, constraint=case.constraint)
    else:
        fmu_path = source = f"builtin:{name}"
    timings["build_fmu"] = time.perf_counter() - start

    start = time.perf_counter()
    if quick:
        dt, t_end = case.quick_window
        window_note = f"fixed quick window dt={dt:g}, t_end={t_end:g}"
    else:
        window = snapshots.auto_window(source, case.training_input, **case.window)
        dt, t_end = window.dt, window.t_end
        window_note = str(window)
    timings["window"] = time.perf_counter() - start
    _log(f"[{name}] snapshot window: {window_note}", quiet)

    start = time.perf_counter()
    snaps = snapshots.record(source, case.training_input, dt, t_end, path=out_dir / "snapshots.h5",
                             overwrite=True, quiet=quiet)
    timings["snapshots"] = time.perf_counter() - start

    start = time.perf_counter()
    order = case.quick_order if quick else None
    # --quick leaves out the least-squares candidate: on both models the refined SDP solution is kept over it, so
    # the ROM is the same (tested), 0.7-1.2 s sooner per model
    model = fit.fit_rom(snaps, r=order, quiet=quiet, least_squares_candidate=not quick)  # labelled stage lines
    timings["fit"] = time.perf_counter() - start
    model.save(out_dir / "rom.h5", overwrite=True)
    test = {"fmu_path": fmu_path, "dt": dt, "t_end": dt * round(case.test_t_end / dt), "quiet": quiet}
    notes = {"training input": case.training_input, "snapshot window": window_note,
             "basis": model.basis_kind, "fit status": model.fit_info.get("status")}
    summary = {"model": name, "r": model.r, "dt": dt, "t_end": t_end, "timings": timings, "rom": None,
               "rom_fmu": None}
    with ThreadPoolExecutor(max_workers=1) as background:
        # the C compiler runs in its own process: the ROM FMU is built while this thread draws and compares
        exported = (background.submit(_timed, export.export_fmu, model, out_dir / f"{case.fmu}ROM.fmu",
                                      overwrite=True) if compile_fmus else None)
        figures = plots.pod_figures(snaps, model, out_dir / "fit")
        _log(f"[{name}] ROM r={model.r} fitted in {timings['fit']:.2f}s ({model.fit_info.get('status')})", quiet)
        start = time.perf_counter()
        reference_name = "FMU" if compile_fmus else "reference simulator"
        result = _compare(model, case, test, f"{case.fmu}: ROM (r={model.r}) vs {reference_name}")
        timings["compare"] = time.perf_counter() - start
        report.write_report(result, out_dir / "report",
                             extra_figures={k.replace("_", " "): v for k, v in figures.items()}, notes=notes)
        summary["rom"] = result.metrics()
        if exported is None:
            return summary
        rom_fmu, timings["export"] = exported.result()
    fmu_result = _compare(rom_fmu, case, test, f"{case.fmu}: exported ROM FMU vs FMU")
    fmu_result.t_train_end = t_end
    report.write_report(fmu_result, out_dir / "report-fmu", notes=notes)
    summary["rom_fmu"] = fmu_result.metrics()
    return summary


def _compare(rom: Any, case: DemoCase, test: dict[str, Any], title: str) -> Any:
    """:func:`fmu_opinf.compare.compare` of ``rom`` with the case's FMU on its test input, titled."""
    from . import compare

    result = compare.compare(rom, test["fmu_path"], case.test_input, dt=test["dt"], t_end=test["t_end"],
                             quiet=test["quiet"], source_options=_IN_PROCESS)
    result.title = f"{title} on {case.test_input}"
    return result


def _timed(function: Callable[..., T], *args: Any, **kwargs: Any) -> tuple[T, float]:
    """``function(*args, **kwargs)`` and its wall time in seconds."""
    start = time.perf_counter()
    value = function(*args, **kwargs)
    return value, time.perf_counter() - start


def _summary_page(rows: list[dict[str, Any]], seconds: float) -> str:
    def fmu_cells(r: dict[str, Any]) -> tuple[str, str]:
        if r["rom_fmu"] is None:
            return "not exported (no C compiler)", ""
        return (f"{r['rom_fmu']['max_error']:.2e}",
                f", <a href=\"{r['model']}/report-fmu/index.html\">ROM FMU report</a>")

    body = "".join(
        f"<tr><td>{html.escape(r['model'])}</td><td>{r['r']}</td><td>{r['dt']:g}</td><td>{r['t_end']:g}</td>"
        f"<td>{r['rom']['max_error']:.2e}</td><td>{fmu_cells(r)[0]}</td>"
        f"<td>{r['rom']['speedup']:.1f}</td><td><a href=\"{r['model']}/report/index.html\">ROM report</a>"
        f"{fmu_cells(r)[1]}</td></tr>" for r in rows)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>fmu-opinf demo</title>
<style>body {{ font-family: sans-serif; max-width: 960px; margin: 2em auto; }}
table {{ border-collapse: collapse; }} th, td {{ border: 1px solid #ccc; padding: 0.3em 0.6em; }}</style>
</head><body><h1>fmu-opinf demo</h1>
<p>Operator-inference ROMs of the two benchmark FMUs, trained on an impulse-like input and tested on a harmonic
input. Errors are the maximum over time of eq. (19). Total wall time {seconds:.1f} s.</p>
<table><tr><th>model</th><th>r</th><th>dt</th><th>training t_end</th><th>max eps_y ROM</th>
<th>max eps_y ROM FMU</th><th>speed-up</th><th>reports</th></tr>{body}</table></body></html>
"""


def run_demo(out_dir: str | Path = "demo-out", model: str = "all", quick: bool = False,
             quiet: bool = False) -> list[dict[str, Any]]:
    """Run the demo for ``model`` (``"anchored-msd"``, ``"triple-chain"`` or ``"all"``) into ``out_dir``.

    Writes ``<model>/`` folders (snapshots, ROM, figures, reports, exported FMU), ``summary.json``
    and ``index.html``, and prints a summary table. Without a C compiler or CMake it says so first,
    skips the FMU builds and the export, and runs the rest on the builtin reference simulator.
    With a core per model (on Linux) the models run side by side, each after the first in a forked
    worker process, and every line printed for a model starts with its name; the results, files, table
    and errors are those of running them one after the other.  Each model's ROM FMU compiles while its
    figures are drawn and its ROM is compared.  An interrupted or failed run leaves the folder as it was: the
    previous run's entries wait in a hidden folder until this run has written all of its own.

    Returns
    -------
    list of dict
        Per model: r, window, timings, and the metrics of the ROM and of the exported ROM FMU.
    """
    from . import fmus

    from ._hdf5 import check_folder_entries

    out_dir = Path(out_dir)
    prepare_report_directory(out_dir)
    check_folder_entries(out_dir, recursive=True)   # (audit 57: written through links, or refused after the work)
    names = list(CASES) if model == "all" else [model]
    compile_fmus = fmus.find_build_tools() is not None
    if not compile_fmus:
        _log("no C compiler or CMake found: skipping the benchmark FMU builds and the ROM FMU export; "
             "the builtin reference simulator (the same models and Newmark scheme) stands in for the FMUs", quiet)
    start = time.perf_counter()
    with _previous_run_kept(out_dir, names + list(_SUMMARY_FILES)):
        rows = _run_cases(names, out_dir, quick=quick, quiet=quiet, compile_fmus=compile_fmus)
        seconds = time.perf_counter() - start
        _atomic_write_bytes(out_dir / "summary.json",
                            json.dumps({"seconds": seconds, "quick": quick, "cases": rows}, indent=2).encode())
        _atomic_write_bytes(out_dir / "index.html", _summary_page(rows, seconds).encode())
    table = summary_table([(f"{r['model']} ROM", r["rom"]) for r in rows]
                          + [(f"{r['model']} ROM FMU", r["rom_fmu"]) for r in rows if r["rom_fmu"]])
    _log(table + f"\n\ntotal {seconds:.1f} s; open {out_dir / 'index.html'}", quiet)
    return rows


#: The demo folder's own files beside the model folders.
_SUMMARY_FILES = ("summary.json", "index.html")
#: Hidden folder in the demo folder holding the previous run's entries while a run writes new ones.
PREVIOUS_RUN = ".fmu-opinf-previous-run"
_DELETING = PREVIOUS_RUN + "-deleting"
#: File in :data:`PREVIOUS_RUN` naming the entries the run creates that did not exist before it (a JSON list of
#: names): a put-back removes them; the entries set aside are those in the folder itself.
_MANIFEST = "created.json"


@contextlib.contextmanager
def _previous_run_kept(out_dir: Path, entries: list[str]) -> Iterator[None]:
    """Keep the previous run's ``entries`` of ``out_dir`` (model folders, summary files) aside while the block
    writes new ones: if the block fails or is interrupted, the entries it wrote are removed and the previous ones
    put back; once it ends well, the previous ones are deleted.

    Files are written atomically, but a run writes dozens of them: an interrupted run left the folder with this
    run's files beside the previous run's.  The entries move by renames in the same folder (no copy, nothing
    left behind), with interrupts deferred while they move (the folder is never half moved).  A run killed
    outright (SIGKILL) leaves the previous entries in :data:`PREVIOUS_RUN`; the next run puts them back first, so
    they are never lost.  Only
    what was set aside, and what did not exist before, is ever removed: an entry that cannot be moved (a mount
    point, a file held open elsewhere) stops the run in one line and stays as it is (audit 67, finding 1).
    """
    keep = out_dir / PREVIOUS_RUN
    _put_back(out_dir, keep)
    try:
        with deferred_interrupts():
            _set_aside(out_dir, keep, entries)
        yield
    except BaseException:
        _put_back(out_dir, keep)
        raise
    with deferred_interrupts():  # renamed first: a run killed while deleting must not put back half of the previous run
        keep.rename(out_dir / _DELETING)
    shutil.rmtree(out_dir / _DELETING)


def _set_aside(out_dir: Path, keep: Path, entries: list[str]) -> None:
    """Move the existing ``entries`` of ``out_dir`` into ``keep``, after noting in its manifest those that do not
    exist (the run creates them); one line naming the folder and ``-o`` where the folder is not writable."""
    existing = [name for name in entries if _exists(out_dir / name)]
    try:
        keep.mkdir()
        (keep / _MANIFEST).write_text(json.dumps([name for name in entries if name not in existing]))
    except OSError as exc:
        raise FileFormatError(f"cannot write in the demo folder {out_dir} ({exc.strerror or exc}); choose a "
                              "writable location with -o") from None
    for name in existing:
        try:
            (out_dir / name).rename(keep / name)
        except OSError as exc:
            raise FileFormatError(f"cannot set the previous run's {out_dir / name} aside while the demo writes a "
                                  f"new one ({exc.strerror or exc}); the demo folder was left as it was: choose "
                                  "another folder with -o") from None


def _put_back(out_dir: Path, keep: Path) -> None:
    """Remove the entries of ``out_dir`` that the run behind ``keep`` (if it exists) set aside or created, move
    the ones set aside back, then remove ``keep`` (and what a killed run was deleting)."""
    if (out_dir / _DELETING).is_dir():
        shutil.rmtree(out_dir / _DELETING)
    if not keep.is_dir():
        return
    with deferred_interrupts():
        kept = [entry.name for entry in keep.iterdir() if entry.name != _MANIFEST]
        try:
            for name in sorted(set(kept) | set(_created_entries(keep))):
                _remove(out_dir / name)
                if name in kept:
                    (keep / name).rename(out_dir / name)
            shutil.rmtree(keep)
        except OSError as exc:
            raise FileFormatError(f"cannot put the previous demo run back from {keep} into {out_dir} "
                                  f"({exc.strerror or exc}); its files are in {keep}") from None


def _created_entries(keep: Path) -> list[str]:
    """The entry names in ``keep``'s manifest (plain names only: the folder is data, nothing in it names a path
    outside the demo folder); none without a readable manifest (nothing unknown is removed)."""
    try:
        names = json.loads((keep / _MANIFEST).read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(names, list):
        return []
    return [name for name in names if isinstance(name, str) and name not in ("", ".", "..", _MANIFEST)
            and Path(name).name == name]


def _exists(path: Path) -> bool:
    """Whether anything (a broken link too) is at ``path``."""
    return path.exists() or path.is_symlink()


def _remove(path: Path) -> None:
    """Remove the file, link or folder at ``path``, if any."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif _exists(path):
        path.unlink()


#: What a case imports (with matplotlib about 1.2 s), loaded before the workers are forked: only modules a case does
#: import (this is serial time before the cases run side by side; scipy.optimize, which no module imports any more,
#: took 0.1-0.17 s of it).
_PRELOAD = ("fmu_opinf.compare", "fmu_opinf.export", "fmu_opinf.fmus", "fmu_opinf.plots", "fmu_opinf.rom",
            "fmu_opinf.snapshots", "fmu_opinf.source", "fmu_opinf.newmark", "fmu_opinf._sdp", "fmu_opinf._recursion",
            "fmpy.simulation")


def _side_by_side(names: list[str]) -> bool:
    """Run the cases concurrently: more than one, a core for each, and workers can be forked."""
    from ._forked import can_fork
    from ._threads import usable_cores

    return len(names) > 1 and usable_cores() >= len(names) and can_fork()


def _run_cases(names: list[str], out_dir: Path, **options: Any) -> list[dict[str, Any]]:
    """:func:`run_case` for each name, in order, or side by side (the first one here, the others in workers).

    Side by side, every printed line says its case; the rows, and the first error in case order (raised when
    the cases before it have finished), are those of running the cases one after the other.
    """
    if not _side_by_side(names):
        return [run_case(name, out_dir / name, **options) for name in names]
    import threading

    from ._forked import Worker, labelled_output

    lock = threading.Lock()
    with _preloaded_and_frozen():
        workers = [Worker(f"[{name}] ", run_case, name, out_dir / name, lock=lock, **options) for name in names[1:]]
        try:
            with labelled_output(f"[{names[0]}] ", lock):
                first = run_case(names[0], out_dir / names[0], **options)
            return [first] + [worker.result() for worker in workers]
        finally:
            for worker in workers:
                worker.stop()


@contextlib.contextmanager
def _preloaded_and_frozen() -> Iterator[None]:
    """Import what a case imports, once, before the workers are forked inside the block; leave the objects alive
    then out of the garbage collector's passes while the block runs, here and in the workers.

    After the imports the collector tracks about 100,000 objects (modules, functions, matplotlib's and SciPy's
    tables), and each full collection walked all of them: 0.05-0.1 s each, one or two during these imports and
    three to five in the demo's process after them (issue 16).  The imports make next to no garbage (44 objects),
    so the collector is off while they run; the objects stay alive for the whole run anyway, and the collector
    takes them in again once the block ends.
    """
    import gc
    import importlib

    from . import plots

    enabled = gc.isenabled()
    gc.disable()
    try:
        for module in _PRELOAD:  # imported once, before forking, instead of once per case
            importlib.import_module(module)
        plots._pyplot()  # matplotlib with the Agg backend
    finally:
        if enabled:
            gc.enable()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
