"""One run of a source into a sink: the run loop, its checks and its attributes.

:func:`record_run` steps a :class:`~fmu_opinf.sources.Source` on a uniform grid with the input held over each step
(design.md input timing), in this process or a child process (:mod:`._isolation`), into a sink: :class:`MemorySink`
(one array filled in place) or ``_H5Sink`` (blocks streamed into a run group of the file, above
:data:`STREAM_THRESHOLD` bytes).  It derives the velocities or accelerations the source does not expose
(:func:`derive_rates`, :mod:`._rates`), checks a complete run's rates (:mod:`._consistency`; a repaired source is
recorded again), and ends at a failing step or non-finite values with a one-line error *after* the samples so far
are kept (``complete=False``, :func:`incomplete_error`).  ``_run_attrs`` says what the run was.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import math
import os
import time as _time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .._hdf5 import ensure_space, tool_versions, write_attrs
from .._progress import Progress
from ..errors import FMUError, FmuOpinfError, FmuOpinfWarning
from ..sources import EventCount, Source, StepError, warn_once
from ._consistency import judge_run, live_rate_sums
from ._data import Run
from ._file import ARRAYS, create_dataset, write_initial_state
from ._isolation import check_interrupt, deferred_interrupts, produce_inprocess, produce_isolated, source_label
from ._rate_tests import RateSums
from ._rates import (continuous_accelerations, continuous_recording, inputs_in_effect, newmark_accelerations,
                     newmark_rates, newmark_velocities_and_accelerations)
from ._size import note_pace, recorded_rows, tolerance_pace

__all__ = ["record_run", "MemorySink", "incomplete_error", "derive_rates", "STREAM_THRESHOLD"]


#: Bytes of one run above which ``record(..., path=...)`` streams blocks to disk instead of memory.
STREAM_THRESHOLD = 256 * 2**20
_BLOCK_BYTES = 4 * 2**20


class _Sink:
    """Provides row buffers for the source to fill (one sample per row) and assembles a :class:`Run`.

    ``rows(i0, count)`` is where samples ``i0 ..`` are written; ``commit(i0, count)`` marks them
    valid.  ``block`` is the largest ``count`` the sink accepts at once.
    """

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray) -> None:
        self.layout = source.layout
        self.width = source.width
        self.n, self.p, self.k = source.n, source.p, len(t)
        self.derived = source.derived
        self._source = source
        self.t, self.u = t, u
        self.count = 0
        self.block = _block_rows(self.width, self.k)
        self.events: EventCount | None = None  # the producer's: Source.events_seen at the end
        self.report: dict[str, Any] = {}        # ... and its Source.run_report

    @functools.cached_property
    def continuous(self) -> bool:
        """Samples of a continuous-time model (:func:`continuous_recording`), asked once the run is over."""
        return continuous_recording(self._source.provenance())

    def rows(self, i0: int, count: int) -> np.ndarray:
        raise NotImplementedError

    def commit(self, i0: int, count: int) -> None:
        self.count = i0 + count

    def finish(self, attrs: dict[str, Any]) -> Run:
        raise NotImplementedError

    def _h(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else 1.0


class MemorySink(_Sink):
    """All samples in one (k, width) array, filled in place by the source (no copies).

    The run's ``x, xdot, xddot, y`` are ``(n, k)`` views of it (column ``i`` = sample ``i``).
    """

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray) -> None:
        super().__init__(source, t, u)
        self.samples = np.empty((self.k, self.width))
        self.block = max(self.block, 1)

    def rows(self, i0: int, count: int) -> np.ndarray:
        return self.samples[i0:i0 + count]

    def finish(self, attrs: dict[str, Any]) -> Run:
        c = self.count
        view = self.samples[:c].T
        arrays = {name: view[self.layout[name]] for name in ("x", "xdot", "xddot", "y")}
        arrays["xdot"], arrays["xddot"] = derive_rates(self.derived, self._h(), arrays["x"], arrays["xdot"],
                                                       arrays["xddot"], self.u[:, :c], self.continuous)
        return Run(t=self.t[:c].copy(), u=np.ascontiguousarray(self.u[:, :c]), **arrays, attrs=attrs)


class _H5Sink(_Sink):
    """Streams blocks into the (chunked, compressed) datasets of one run group."""

    def __init__(self, source: Source, t: np.ndarray, u: np.ndarray, group: h5py.Group,
                 target: Path | None = None) -> None:
        super().__init__(source, t, u)
        self.group = group
        self.target = target  # the file name shown when the disk is full
        self.scratch = np.empty((self.block, self.width))
        self.ds = {name: create_dataset(group, name, (rows, self.k)) for name, rows in
                   (("x", self.n), ("xdot", self.n), ("xddot", self.n), ("y", self.p))}

    def rows(self, i0: int, count: int) -> np.ndarray:
        return self.scratch[:count]

    def commit(self, i0: int, count: int) -> None:
        ensure_space(self.group.file.filename, 8.0 * count * self.width, self.target)
        for name, ds in self.ds.items():
            part = self.layout[name]
            if part.stop > part.start and count:
                ds[:, i0:i0 + count] = np.ascontiguousarray(self.scratch[:count, part].T)
        super().commit(i0, count)

    def finish(self, attrs: dict[str, Any]) -> Run:
        c = self.count
        for ds in self.ds.values():
            ds.resize(c, axis=1)
        if any(self.derived.values()):
            self._derive_rates()
        for name, array in (("t", self.t[:c]), ("u", self.u[:, :c])):
            create_dataset(self.group, name, array.shape)[...] = array
        arrays = {a: self.group[a] for a in ARRAYS}
        run = Run(**arrays, attrs=attrs)  # initial state: the first samples
        write_initial_state(self.group, run.x0, run.v0)
        write_attrs(self.group, attrs)
        return run

    def _derive_rates(self) -> None:
        """Derived rates need the whole run (:func:`derive_rates`); above 1 GiB of states, the smoothest
        solutions of :func:`newmark_rates` are taken row block by row block instead."""
        c = self.count
        if 16 * self.n * c > 2**30 and continuous_rule(self.derived, self.continuous):
            self._derive_continuous()
            return
        if 16 * self.n * c > 2**30:
            for src, dst in (("x", "xdot"), ("xdot", "xddot")):
                if self.derived[dst]:
                    self._derive(src, dst)
            return
        x, xdot, xddot = (self.ds[name][:, :c] for name in ("x", "xdot", "xddot"))
        xdot, xddot = derive_rates(self.derived, self._h(), x, xdot, xddot, self.u[:, :c], self.continuous)
        for name, values in (("xdot", xdot), ("xddot", xddot)):
            if self.derived[name]:
                self.ds[name][:, :c] = values

    def _derive(self, src: str, dst: str) -> None:
        """Rows (DOFs) are independent: derive in row blocks without loading the whole run."""
        block = max(1, (64 * 2**20) // (8 * max(self.count, 1)))
        for r0 in range(0, self.n, block):
            self.ds[dst][r0:r0 + block, :] = newmark_rates(self.ds[src][r0:r0 + block, :], self._h())

    def _derive_continuous(self) -> None:
        """:func:`continuous_accelerations` row block by row block (rows are independent)."""
        c, u = self.count, self.u[:, :self.count]
        block = max(1, (64 * 2**20) // (8 * max(c, 1)))
        for r0 in range(0, self.n, block):
            rows = slice(r0, r0 + block)
            self.ds["xddot"][rows, :c] = continuous_accelerations(self.ds["xdot"][rows, :c], self._h(),
                                                                  self.ds["x"][rows, :c], u)


def continuous_rule(derived: dict[str, bool], continuous: bool) -> bool:
    """True when the accelerations (only) are derived from a continuous-time recording: then they come from
    :func:`continuous_accelerations` and the fit uses interval averages (``fit_rates``)."""
    return bool(continuous and derived["xddot"] and not derived["xdot"])


def derive_rates(derived: dict[str, bool], h: float, x: np.ndarray, xdot: np.ndarray, xddot: np.ndarray,
                 u: np.ndarray, continuous: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The velocities and accelerations a source does not expose, from the recorded samples (:mod:`._rates`).

    ``continuous``: the samples are of a continuous-time model (any FMU not generated by fmu-opinf's Newmark
    kernel); derived accelerations then come from :func:`continuous_accelerations`.  Positions alone are
    always treated as Newmark data (no continuous-time rule for them yet).
    """
    if continuous_rule(derived, continuous):
        return xdot, continuous_accelerations(xdot, h, x, u)
    if derived["xdot"] and derived["xddot"]:
        return newmark_velocities_and_accelerations(x, h, u)
    if derived["xdot"]:
        return newmark_rates(x, h), xddot
    if derived["xddot"]:
        return xdot, newmark_accelerations(xdot, h, x, u)
    return xdot, xddot


def _block_rows(width: int, k: int) -> int:
    return int(max(1, min(k, max(16, _BLOCK_BYTES // (8 * max(width, 1))))))


def _signal_spec(signal: Any) -> str:
    value = getattr(signal, "spec", None)
    return value if isinstance(value, str) and value else repr(signal)


def _first_bad_row(rows: np.ndarray) -> int | None:
    """Index of the first row with a NaN/inf, or None (fast path: one sum over the block)."""
    with np.errstate(invalid="ignore", over="ignore"):  # inf - inf in the sum is what we look for
        if math.isfinite(float(rows.sum())):
            return None
    bad = ~np.isfinite(rows).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else None


def _non_finite_names(source: Source, row: np.ndarray) -> str:
    """`` in NAME, NAME, ...``: the first few recorded variables that are not finite in the sample ``row``."""
    names: list[str] = []
    for kind, attribute in (("x", "position_names"), ("xdot", "velocity_names"),
                            ("xddot", "acceleration_names"), ("y", "output_names")):
        part, labels = row[source.layout[kind]], list(getattr(source, attribute, []) or [])
        names += [labels[j] if j < len(labels) else f"{kind}[{j + 1}]" for j in np.flatnonzero(~np.isfinite(part))]
    if not names:
        return ""
    return " in " + ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")


def _as_received(source: Source, u: np.ndarray) -> np.ndarray:
    """The inputs ``u`` (m, k) as the FMU receives them: its single-precision (FMI 3 Float32) inputs rounded, so
    that the recorded input is the one the model responded to (else 1e-8 relative off)."""
    single = np.asarray(getattr(source, "single_precision_inputs", ()), dtype=bool)
    if single.size != u.shape[0] or not single.any():
        return u
    source.refuse_single_precision_overflow(u)
    u = u.copy()
    u[single] = u[single].astype(np.float32)
    return u


def record_run(source: Source, signal: Any, t: np.ndarray, sink_factory: Any, quiet: bool,
                isolate: bool, label: str = "recording", repairs: int = 0,
                pilot: bool = False, say_events: bool = True, timed: bool = True) -> tuple[Run, StepError | None]:
    """Drive one run into a sink; return the run and the error that ended it early (if any).

    ``label`` names the run on the progress bar (e.g. which pilot run of the automatic window it is).  A complete
    run of an FMU is checked for consistent rates (:mod:`._consistency`): a guessed pairing of positions and
    velocities that the data contradict, or stale accelerations (confirmed by the FMU's own value just after a
    sample, :func:`_accelerations_after`), are repaired on the source and the run is recorded once more
    (``repairs``: how many times already; both may be needed, one after the other, and a problem left after
    :data:`~._consistency.MAX_REPAIRS` is an error; ``pilot``: a run of the automatic window,
    whose unrepairable problems are left to the recording, ``judge_run(strict=False)``).  The model's events are
    warned about (once per FMU and process) unless ``pilot`` or not ``say_events`` (a probe, like compare's of the
    source's initial state).  ``timed``: the run counts for the source's pace (:func:`~._size.note_pace`) and, where
    slow, is timed at the FMU's own tolerance (:func:`~._size.tolerance_pace`); not for that probe itself.
    """
    u = _as_received(source, inputs_in_effect(signal, t, source.m))
    U = np.ascontiguousarray(u.T)
    sink = sink_factory(source, t, u)
    failure: StepError | None = None
    sums = live_rate_sums(source, t) if isinstance(sink, MemorySink) else None
    started = _time.perf_counter()
    with (source.pilot_accuracy() if pilot else contextlib.nullcontext()), deferred_interrupts(), \
            Progress(len(t), label, quiet=quiet) as bar, _rate_feed(sink, sums) as feed:
        producer = (produce_isolated if isolate else produce_inprocess)(source, t, U, sink)
        try:
            for i0, count in producer:
                check_interrupt()
                rows = sink.rows(i0, count)[:count]
                first = _first_bad_row(rows)
                if first is not None:
                    named = _non_finite_names(source, rows[first])
                    sink.commit(i0, first)
                    i = i0 + first
                    raise StepError(f"{source_label(source)} produced non-finite values at step {i} "
                                    f"(t={t[i]:g}){named}", i, float(t[i]))
                sink.commit(i0, count)
                feed(sink.count)
                bar.update(sink.count)
        except StepError as exc:
            failure = _with_hint(source, exc, U)
        finally:
            producer.close()
    attrs = _run_attrs(source, signal, t, sink, failure, _time.perf_counter() - started, isolate)
    run = sink.finish(attrs)
    if timed:
        note_pace(source, run.k, attrs["wall_seconds"], pilot)   # (what announce predicts the time from)
        what = "its " + label.removeprefix("auto window: ") + ("" if failure is None else " (until it stopped)")
        tolerance_pace(source, run.k, attrs["wall_seconds"], what,
                       functools.partial(_at_own_tolerance, source, signal, t, isolate))
    if attrs.get("events") and say_events and not pilot:
        _warn_events(source, attrs)
    if failure is None:
        evaluate = functools.partial(_accelerations_after, source, t, u, isolate, pilot)
        repair = judge_run(source, run, t, repairs, strict=not pilot, sums=sums, evaluate=evaluate)
        if repair is not None:
            if sink_factory is not MemorySink:  # a streamed run is not recorded twice into its file
                raise FMUError(f"{source_label(source)}: {repair.reason}; record again with {repair.as_options()}, "
                               "or with the auto window (its pilot runs repair this)")
            warnings.warn(f"{source_label(source)}: {repair.reason}; recording again", FmuOpinfWarning,
                          stacklevel=2)
            source.reselect(repair.positions, repair.velocities, repair.accelerations, repair.reason)
            return record_run(source, signal, t, sink_factory, quiet, isolate, label, repairs + 1, pilot, say_events)
    return run, failure


def _at_own_tolerance(source: Source, signal: Any, t: np.ndarray, isolate: bool, n: int) -> float | None:
    """Wall seconds of a run of ``signal`` over the first ``n`` samples of ``t`` at the FMU's own tolerance
    (``--tolerance 0``), None where it fails: the probe of :func:`~._size.tolerance_pace`."""
    asked = source.tolerance
    source.tolerance = 0.0
    started = _time.perf_counter()
    try:
        _, failure = record_run(source, signal, t[:n], MemorySink, True, isolate, "tolerance probe", pilot=True,
                                say_events=False, timed=False)
    except FmuOpinfError:   # (a probe: never a reason for the recording to fail)
        return None
    finally:
        source.tolerance = asked
    return None if failure is not None else _time.perf_counter() - started


#: The step, relative to the run's, that :func:`_accelerations_after` takes past a sample: the accelerations move by
#: ``omega`` times it (3e-3 relative for a mode at 1.6e6 rad/s at dt = 0.002), a sample's shift by ``omega dt``.
EVALUATION_STEP = 1e-6


def _accelerations_after(source: Source, t: np.ndarray, u: np.ndarray, isolate: bool, pilot: bool,
                         rows: slice | np.ndarray, i: int) -> np.ndarray | None:
    """The accelerations (``rows`` of them) that ``source`` gives at the state of sample ``i`` of the run on grid
    ``t`` with inputs ``u``: the run again up to ``t[i]``, then one step of :data:`EVALUATION_STEP` times the run's
    with the input held, read after it.  A current value is the one recorded at ``t[i]``, a stale one (read before
    the FMU updated it) the one recorded at ``t[i + 1]``, where the input stays the same
    (:func:`~._consistency.confirmed_stale`).  None where the FMU refuses that step (a fixed communication step) or
    fails."""
    h = float(t[1] - t[0])
    grid = np.append(t[:i + 1], t[i] + EVALUATION_STEP * h)
    held = np.ascontiguousarray(np.hstack([u[:, :i + 1], u[:, i:i + 1]]))
    sink = MemorySink(source, grid, held)
    with source.pilot_accuracy() if pilot else contextlib.nullcontext():
        producer = (produce_isolated if isolate else produce_inprocess)(source, grid, np.ascontiguousarray(held.T),
                                                                        sink)
        try:
            for i0, count in producer:
                check_interrupt()
                sink.commit(i0, count)
        except (StepError, FMUError):
            return None
        finally:
            producer.close()
    if sink.count != len(grid):
        return None
    return np.asarray(sink.samples[-1, source.layout["xddot"]])[rows]


def _warn_events(source: Source, attrs: dict[str, Any]) -> None:
    """Say, once per FMU and process, that the model had events during a run: what a linear ROM does with them,
    and how to check (each run's count is in its attributes: ``events``, ``first_event_t``).  Every recording keeps
    the line with its file (:func:`~._notes.note_recording`, once per file), so fit, compare and export repeat it
    (audit 72 F5)."""
    from ._notes import current_recording_notes, note_recording

    start = float(getattr(source, "start_time", None) or 0.0)
    first = float(attrs["first_event_t"])
    fmu_time = f", FMU time {start + first:g}" if start else ""
    text = (f"had {attrs['events']} event(s) during the run of {attrs['input_spec']} (the first at t={first:g}"
            f"{fmu_time}): the model changes discretely there (switching, contact, friction, stops, a sampled "
            "controller, a force on a timer or a table), which a linear ROM cannot follow; it fits one linear model "
            "to both sides, so compare the ROM on inputs that cross the events and on inputs that do not")
    warn_once(source, ("events",), text)
    if "internal-events" not in current_recording_notes().get("recording_verdicts", []):
        note_recording(f"{os.path.basename(str(getattr(source, 'path', '')) or type(source).__name__)}: {text}",
                       "internal-events")


@contextlib.contextmanager
def _rate_feed(sink: _Sink, sums: RateSums | None) -> Iterator[Callable[[int], None]]:
    """``feed(count)``: sum the rate checks' blocks of the first ``count`` samples of ``sink`` on a helper thread
    while the next ones are recorded (:class:`~._rate_tests.RateSums`; a no-op without ``sums``).  Leaving the
    context waits for the sums (recording the 600-mass chain's 4001 samples: 22 ms of checks after the run
    before); an error of the recording is raised, not one of the sums."""
    if sums is None:
        yield lambda count: None
        return
    arrays = [sink.samples[:, sink.layout[name]].T for name in ("x", "xdot", "xddot")]
    pending: list[Future] = []
    with ThreadPoolExecutor(1, thread_name_prefix="fmu-opinf rate checks") as pool:
        try:
            yield lambda count: pending.append(pool.submit(sums.feed, *arrays, count))
        except BaseException:
            wait(pending)
            raise
        for done in pending:
            done.result()


def _with_hint(source: Source, failure: StepError, U: np.ndarray) -> StepError:
    """The failure with the source's explanation appended (e.g. inputs that look like parameters)."""
    hint = getattr(source, "failure_hint", None)
    text = hint(U, failure.step, str(failure)) if hint is not None else ""
    return StepError(str(failure) + text, failure.step, failure.time) if text else failure


def _run_attrs(source: Source, signal: Any, t: np.ndarray, sink: _Sink, failure: StepError | None,
               seconds: float, isolate: bool) -> dict[str, Any]:
    attrs = dict(source.provenance())
    attrs.update({
        "input_spec": _signal_spec(signal),
        "dt": float(t[1] - t[0]),
        "t0": float(t[0]),
        "t_end": float(t[-1]),
        "k_planned": len(t),
        "k": sink.count,
        "complete": failure is None and sink.count == len(t),
        "derived_xdot": bool(sink.derived["xdot"]),
        "derived_xddot": bool(sink.derived["xddot"]),
        "derived_method": _derived_method(sink.derived, sink.continuous) if any(sink.derived.values()) else "",
        "fit_rates": "interval-averages" if continuous_rule(sink.derived, sink.continuous) else "pointwise",
        "isolated": bool(isolate),
        "wall_seconds": round(seconds, 6),
        "versions": _versions(),
    })
    attrs["created"] = attrs["versions"]["created"]
    if failure is not None:
        attrs["error"] = str(failure)
    attrs.update(sink.report)   # e.g. the integrator a model-exchange run took
    if sink.events is not None:  # a model-exchange FMU's: co-simulation ones handle theirs unseen
        count, first, inert = sink.events
        attrs["events"] = int(count)
        if first is not None:
            attrs["first_event_t"] = float(first)
        if inert:
            attrs["inert_events"] = int(inert)
    return attrs


def _derived_method(derived: dict[str, bool], continuous: bool = False) -> str:
    if continuous_rule(derived, continuous):
        return ("xddot: continuous_accelerations (continuous-time recording: Hermite stencils of positions and "
                "velocities within each piece of constant held input); the fit uses interval averages instead "
                "(fit_rates=interval-averages, snapshots._rates.interval_averages)")
    parts = []
    if derived["xdot"] and derived["xddot"]:
        return ("newmark_velocities_and_accelerations (Newmark with the acceleration update at input changes; "
                "alternating modes and input jumps by least squares on the span of the recorded states)")
    if derived["xdot"]:
        parts.append("xdot: newmark_rates (trapezoid relation, alternating mode by least roughness)")
    if derived["xddot"]:
        parts.append("xddot: newmark_accelerations (Newmark with the acceleration update at input changes; "
                     "alternating mode and input jumps by least squares on the span of the recorded states)")
    return "; ".join(parts)


@functools.lru_cache(maxsize=1)
def _library_versions() -> tuple[tuple[str, str], ...]:
    return tuple((k, v) for k, v in tool_versions().items() if k != "created")


def _versions() -> dict[str, str]:
    """Tool and library versions (looked up once per process) and the creation time (now)."""
    versions = dict(_library_versions())
    versions["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return versions


def incomplete_error(failure: StepError, run: Run, path: Path | None) -> StepError:
    """The failure with what became of the samples before it: kept in ``path``, or (no path) not written."""
    if path is None:
        return StepError(f"{failure}; no file was written", failure.step, failure.time)
    text = f"{failure}; the {run.k} samples before it are kept in {path} (complete=False)"
    return StepError(text, failure.step, failure.time)


def _run_bytes(source: Source, k: int) -> int:
    return 8 * k * recorded_rows(source)
