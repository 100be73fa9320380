"""Audit 79a, F2: a large or long recording says so before it starts, with its figures and what cuts them, and one
that cannot fit the free space stops before it records (a 300-output FE export wrote 813 MB in 13.5 min, silent)."""

from __future__ import annotations

import re
import warnings

import pytest

from fmu_opinf import snapshots
from fmu_opinf.errors import FileFormatError, FmuOpinfWarning
from fmu_opinf.snapshots import _size

TRAIN = ["impulse:amplitude=100,t0=1,width=0.5", "chirp:amplitude=5,omega0=0.3,omega1=3,duration=10"]


def _size_lines(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)
            and "recorded rows" in str(w.message)]


def test_large_recording_says_its_size_up_front(tmp_path, monkeypatch):
    """Above the bar (lowered here, not 1 GB recorded), one line with runs x samples x rows x 8 bytes, before the
    first run is recorded, naming --outputs/--positions, --inputs and --dt/--t-end; the file is still written."""
    monkeypatch.setattr(_size, "LARGE_BYTES", 1000.0)
    first_run = []
    recorded = snapshots._write.record_run

    def record_run(*args, **kwargs):
        first_run.append(len(_size_lines(caught)))
        return recorded(*args, **kwargs)

    monkeypatch.setattr(snapshots._write, "record_run", record_run)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        summary = snapshots.record_to_file("builtin:anchored-msd", tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0,
                                           quiet=True)
    lines = _size_lines(caught)
    assert len(lines) == 1 and first_run[0] == 1   # said once, before the first run
    n, m, p = summary.n, summary.m, summary.p
    rows, samples = 3 * n + p + m + 1, 81
    assert f"2 run(s) of {samples} samples x {rows} recorded rows" in lines[0]
    size = 8 * 2 * samples * rows
    assert f"= {size / 1e6:.3g} MB before compression" in lines[0]   # 2.34 MB: n = 600
    for option in ("--outputs", "--positions", "--inputs", "--dt", "--t-end"):
        assert option in lines[0]
    assert "\n" not in lines[0] and (tmp_path / "s.h5").exists()


def test_small_recording_says_nothing(tmp_path):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        snapshots.record_to_file("builtin:anchored-msd", tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    assert _size_lines(caught) == []


@pytest.mark.parametrize("pilot, said", [(False, "about 3 min at 1e+03 ms per sample, the runs recorded so far"),
                                         (True, "about 3 min at 1e+03 ms per sample, the pilot runs' (a rough guide")])
def test_long_recording_predicts_its_time_from_the_runs_before(tmp_path, monkeypatch, pilot, said):
    """The time is the samples times the pace of the runs recorded with the same source before (pilots: a rough
    guide, they run at a looser tolerance): here the pace is planted (1 s per sample), so 2 x 81 samples predict
    162 s = 3 min."""
    from fmu_opinf.sources import open_source

    monkeypatch.setattr(_size, "LONG_SECONDS", 100.0)
    source = open_source("builtin:anchored-msd")
    _size.note_pace(source, 50, 50.0, pilot)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        snapshots.record_to_file(source, tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    lines = _size_lines(caught)
    assert len(lines) == 1 and said in lines[0], lines
    assert not [w for w in caught if "the first run took" in str(w.message)]   # (the real runs are fast)


def test_a_long_recording_not_foreseen_is_said_after_its_first_run(tmp_path, monkeypatch):
    """Without a pace before (--dt and --t-end: no pilots), the first run's pace predicts the rest: with the bar at
    0 s, one line names the first run's time and the other run's."""
    monkeypatch.setattr(_size, "LONG_SECONDS", 0.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        snapshots.record_to_file("builtin:anchored-msd", tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    lines = [str(w.message) for w in caught if "the first run took" in str(w.message)]
    assert len(lines) == 1 and re.search(r"ms per sample\): the other 1 run\(s\) take about \d+ s more", lines[0])


def test_recording_that_cannot_fit_stops_before_it_starts(tmp_path, monkeypatch, capsys):
    """Free space below half the predicted size: a one-line error before any run is written, no file left behind."""
    from fmu_opinf.cli import main

    monkeypatch.setattr(_size, "free_space", lambda path: 1000.0)
    runs = []
    monkeypatch.setattr(snapshots._write, "_H5Sink", lambda *a, **k: runs.append(1))   # a run into the file
    with pytest.raises(FileFormatError, match=r"needs about .* before compression .* and only 1 kB are free"):
        snapshots.record_to_file("builtin:anchored-msd", tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    assert runs == [] and not (tmp_path / "s.h5").exists()
    assert main(["snapshots", "builtin:anchored-msd", "-o", str(tmp_path / "c.h5"), "--dt", "0.5", "--t-end", "40",
                 "-q"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--outputs" in err and "Traceback" not in err


def _planted_line(tmp_path, monkeypatch, planted: list[tuple[int, float]], bar: float) -> list[str]:
    """The up-front lines of a recording of 2 x 81 samples after runs of ``planted`` (samples, seconds)."""
    from fmu_opinf.sources import open_source

    monkeypatch.setattr(_size, "LONG_SECONDS", bar)
    source = open_source("builtin:anchored-msd")
    for samples, seconds in planted:
        _size.note_pace(source, samples, seconds)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        snapshots.record_to_file(source, tmp_path / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    return _size_lines(caught)


def test_a_short_check_run_alone_predicts_no_time(tmp_path, monkeypatch):
    """A run of 4 samples is mostly its start: before 2026-12-08 its 1.2 s predicted "about 9 min at 6.8e+02 ms
    per sample" for an 801-sample recording of 1.5 s (AnchoredMSD.fmu, n = 600).  Planted here: 4 samples in 10 s
    would have said 2 x 81 samples x 2.5 s = 7 min; no pace, no line (after the first run the recording's own
    pace speaks, :func:`test_a_long_recording_not_foreseen_is_said_after_its_first_run`)."""
    assert _planted_line(tmp_path, monkeypatch, [(4, 10.0)], bar=100.0) == []


def test_runs_of_two_lengths_give_a_start_and_a_pace(tmp_path, monkeypatch):
    """Runs of 4 samples in 10 s and 400 in 20 s: 9.90 s per run and 25.3 ms per sample (the line through both),
    so 2 runs of 81 samples take 2 x 9.90 + 162 x 0.0253 = 23.9 s, said as about 24 s (the time per sample alone,
    30 s / 404 samples, said 12 s)."""
    lines = _planted_line(tmp_path, monkeypatch, [(4, 10.0), (400, 20.0)], bar=20.0)
    assert len(lines) == 1 and "about 24 s at 25 ms per sample and 10 s per run, the runs recorded so far" in lines[0]
