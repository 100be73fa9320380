"""Whether the response scales with a given input (``--input``, a run table, a given grid, a raised pulse).

The default training's amplitude check (:mod:`fmu_opinf.snapshots._linearity`) ran only for the automatic window
with the default pulse: a model linear only near rest (audit 79b: a hardening spring) driven by a user's 100 N
impulse was recorded, fitted and exported without a word.  ``snapshots`` now makes one run of the same input at
-1/10 after recording and warns, kept in the file, where the response does not scale; the input stays as given.
References: the exact linearization of the hardening FMU and the exact response of the linear FMUs
(``lti_fmus.zoh_response``)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.runs import record_runs
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Snapshots, record_to_file
from fmu_opinf.snapshots import _linearity
from fmu_opinf.snapshots._notes import recorded_verdicts, recorded_warning

from test_training_linearity import _nonlinear_fmu, _two_masses

BIG, SMALL = "impulse:amplitude=100,t0=2,width=0.5", "impulse:amplitude=0.1,t0=2,width=0.5"
GRID = {"dt": 0.02, "t_end": 20.0}


def _counting(monkeypatch) -> list[float]:
    """The input factors of the check's runs, as they are made (0: the run without the input)."""
    made: list[float] = []
    recorded, scaled = getattr(_linearity, "_recorded_outputs", None), _linearity._run_scaled

    def at_recording(source, signal, t, quiet, isolate, label):
        made.append(signal.factor)
        return recorded(source, signal, t, quiet, isolate, label)

    def lowered(source, reference, factor, quiet, isolate):
        made.append(factor)
        return scaled(source, reference, factor, quiet, isolate)

    if recorded is not None:   # (None before the check of given inputs: then nothing counts, as nothing runs)
        monkeypatch.setattr(_linearity, "_recorded_outputs", at_recording)
    monkeypatch.setattr(_linearity, "_run_scaled", lowered)
    return made


def _off_linearization(snaps: Snapshots, spec: str) -> np.ndarray:
    """Each output's largest distance from the exact linearization's response, relative to its range."""
    run = snaps.runs[0]
    exact = lti_fmus.zoh_response(_two_masses(), run.t, parse_signal(spec).sample(run.t)).y
    return np.abs(np.asarray(run.y) - exact).max(axis=1) / np.ptp(exact, axis=1)


def _scaling_warnings(seen) -> list[str]:
    return [str(w.message) for w in seen if "does not scale" in str(w.message)]


@pytest.mark.fmu
@pytest.mark.slow   # 7 s on 2 cores
def test_a_hardening_spring_under_a_given_100_n_impulse_warns_with_the_amplitude_that_scales(tmp_path, monkeypatch):
    """The recording is 92 % / 20 % of range off the exact linearization (the model is far from linear there); the
    check measures 3.1 at -1/10, then 0.9, 0.02, 2.1e-4 a decade lower each, and names 0.1 N.  The old code: no
    check run, no warning."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(fmu, tmp_path / "big.h5", BIG, quiet=True, **GRID)
    said = _scaling_warnings(seen)
    assert len(said) == 1 and f"the response to the input {BIG} does not scale with it" in said[0]
    assert "differ by 3.1" in said[0] and "the response scales at 0.001 times this input" in said[0]
    assert said[0].endswith(f"give a smaller input, e.g. '{SMALL}'"), said[0]
    # at the recording's tolerance: -1/10, then the run without the input (the model rests: it does not cure it);
    # at the check's (model exchange, the input recorded again, uncounted): -1/10, then a decade lower each
    assert made == [-0.1, 0.0, -0.1, 0.01, -0.001, 0.0001], made
    snaps = Snapshots.load(tmp_path / "big.h5")
    assert snaps.runs[0].attrs["input_spec"] == BIG   # recorded as given
    assert recorded_verdicts(snaps.attrs) == {"nonlinear"} and "does not scale" in recorded_warning(snaps.attrs)
    assert np.all(_off_linearization(snaps, BIG) > 0.1)


@pytest.mark.fmu
@pytest.mark.slow   # 3 s on 2 cores
def test_the_same_spring_under_a_given_0_1_n_impulse_is_checked_and_recorded_without_a_warning(tmp_path, monkeypatch):
    """At 0.1 N the recording is within 2e-4 of range of the exact linearization: one check run, no warning."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(fmu, tmp_path / "small.h5", SMALL, quiet=True, **GRID)
    assert not _scaling_warnings(seen) and made == [-0.1]
    snaps = Snapshots.load(tmp_path / "small.h5")
    assert "recording_warnings" not in snaps.attrs
    assert np.all(_off_linearization(snaps, SMALL) < 2e-4)


@pytest.mark.fmu
@pytest.mark.slow   # 3.5-15 s on 2 cores (the re-check at 1e-9 of the loose tolerances)
@pytest.mark.parametrize("options", [{}, {"tolerance": 1e-4, "method": "bdf"}, {"tolerance": 1e-4, "method": "lsoda"}],
                         ids=["default", "loose-bdf", "loose-lsoda"])
def test_a_linear_fmu_with_offsets_and_start_values_under_a_given_input_gives_no_warning(tmp_path, monkeypatch,
                                                                                         options):
    """A chain under a constant load with an output offset, started off rest (it moves on its own): the check takes
    the run without the input out (two runs; measured 11 assuming rest, 5.4e-13 net of that run).  At --tolerance
    1e-4 the two differ by the integrator's error (0.27 with BDF, 0.078 with LSODA: the false alarm of audit 80 F1)
    and are recorded again at the check's tolerance (2.4e-6, 5.7e-7): no warning.  The recording is 3.3e-12 of range
    off the exact response (zoh_response) at the default tolerance, 0.033 / 0.025 at 1e-4."""
    model = lti_fmus.chain_model(4, force_offset=9.81, output_offset=2.0, x0=[0.3, -0.2, 0.1, 0.0],
                                 v0=[0.0, 1.0, 0.0, -0.5], name="Offset4")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "offset.fmu", interfaces=("me",))
    spec = "harmonic:amplitude=5,omega=1.3"
    made = _counting(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(str(fmu.path), tmp_path / "lin.h5", spec, quiet=True, dt=0.05, t_end=30.0, **options)
    assert not _scaling_warnings(seen)
    assert made == ([-0.1, 0.0] if not options else [-0.1, 0.0, -0.1]), made
    run = Snapshots.load(tmp_path / "lin.h5").runs[0]
    exact = lti_fmus.zoh_response(model, run.t, parse_signal(spec).sample(run.t)).y
    off = np.abs(np.asarray(run.y) - exact).max() / np.ptp(exact)
    assert off < (1e-11 if not options else 4e-2), off


@pytest.mark.fmu
@pytest.mark.slow   # 12 s on 2 cores
def test_a_run_table_with_one_large_row_warns_once_and_checks_only_that_row(tmp_path, monkeypatch):
    """Three rows on the hardening spring (0.1 N, a 0.05 N harmonic, 100 N): only the 100 N row drives the input
    furthest, so only it is checked (one run at -1/10 and the decades below), and only its file keeps the warning."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    table = tmp_path / "table.csv"
    table.write_text(f'name,input\nsmall,"{SMALL}"\nmid,"harmonic:amplitude=0.05,omega=1.3"\nlarge,"{BIG}"\n')
    made = _counting(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_runs(fmu, table, tmp_path / "out", quiet=True, **GRID).raise_for_failures()
    said = _scaling_warnings(seen)
    assert len(said) == 1 and BIG in said[0]
    assert made == [-0.1, 0.0, -0.1, 0.01, -0.001, 0.0001], made   # (as for the 100 N file alone)
    verdicts = {name: recorded_verdicts(Snapshots.load(tmp_path / "out" / f"{name}.h5").attrs)
                for name in ("small", "mid", "large")}
    assert verdicts == {"small": set(), "mid": set(), "large": {"nonlinear"}}


@pytest.mark.fmu
@pytest.mark.slow   # 3 s on 2 cores
def test_the_check_can_be_skipped(tmp_path, monkeypatch):
    """``check_linearity=False`` (``--no-linearity-check``): no run of the check, the input as given."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting(monkeypatch)
    record_to_file(fmu, tmp_path / "big.h5", BIG, quiet=True, check_linearity=False, **GRID)
    assert made == [] and "recording_warnings" not in Snapshots.load(tmp_path / "big.h5").attrs


@pytest.mark.fmu
@pytest.mark.slow   # 7 s on 2 cores
def test_the_default_pulse_on_a_given_grid_is_checked_too(tmp_path, monkeypatch):
    """No --input but --dt and --t-end: no pilots, so the default training's own check never ran and the 100 N
    pulse was recorded on the hardening spring without a word.  It is now checked after recording (the same
    figures as a given 100 N impulse) and the warning names the 0.1 N pulse; the default pulse stays."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting(monkeypatch)
    with pytest.warns(FmuOpinfWarning, match=r"the response to the default training input impulse:amplitude=100,"
                                             r"t0=2,width=0\.5 does not scale with it: .* differ by 3\.1: .*\(not "
                                             r"lowered where the grid is given .* e\.g\. "
                                             r"'impulse:amplitude=0\.1,t0=2,width=0\.5'"):
        record_to_file(fmu, tmp_path / "grid.h5", None, quiet=True, **GRID)
    assert made == [-0.1, 0.0, -0.1, 0.01, -0.001, 0.0001], made
    snaps = Snapshots.load(tmp_path / "grid.h5")
    assert snaps.runs[0].attrs["input_spec"] == BIG and recorded_verdicts(snaps.attrs) == {"nonlinear"}


@pytest.mark.fmu
def test_a_run_too_large_for_memory_is_not_checked_and_says_so(tmp_path, monkeypatch, capsys):
    """The check holds its runs in memory: above STREAM_THRESHOLD bytes a run is not checked, in one line."""
    from fmu_opinf.snapshots import _write

    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting(monkeypatch)
    monkeypatch.setattr(_write, "STREAM_THRESHOLD", 1000)
    record_to_file(fmu, tmp_path / "big.h5", BIG, quiet=False, **GRID)
    assert made == [] and "run 0000 is not checked for a response that scales with its input" in capsys.readouterr().err


@pytest.mark.fmu
@pytest.mark.slow   # 14 s: the automatic window's pilots, the sizing, the check at two tolerances and three decades
def test_a_pulse_raised_for_a_loaded_hardening_spring_is_checked_and_warned(tmp_path, monkeypatch):
    """The hardening spring under a constant load of 1e5 N (it swings by metres on its own): the 100 N pulse moved the
    outputs by 8e-4 of that motion and was raised to 12000 N, where the default training's own check never ran.
    The recording's check (net of the recorded run without the pulse) measures 0.62, then 0.079, 0.0083, 8.3e-4 a
    decade lower each, and warns; the raised pulse stays (lowered, it would be lost in the motion again)."""
    import shutil

    from test_training_linearity import _ANCHOR, FORCES

    sources = tmp_path / "src_loaded"
    shutil.copytree(lti_fmus._lti_sources_dir(), sources)
    text = (sources / "lti.c").read_text()
    (sources / "lti.c").write_text(text.replace(_ANCHOR, _ANCHOR + "    " + FORCES["hardening"] + "\n", 1))
    model = _two_masses()
    model.f0 = np.array([1e5, 1e5])
    monkeypatch.setattr(lti_fmus, "_lti_sources_dir", lambda: sources)
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "loaded.fmu", reuse=False)
    monkeypatch.undo()
    made = _counting(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(str(fmu.path), tmp_path / "train.h5", None, quiet=True)
    said = _scaling_warnings(seen)
    raised = "impulse:amplitude=12000,t0=2,width=0.5"
    assert len(said) == 1 and f"the response to the default training input {raised} does not scale" in said[0]
    assert "differ by 0.62" in said[0] and "the response scales at 0.001 times this input" in said[0]
    assert made == [-0.1, -0.1, 0.01, -0.001, 0.0001], made   # (the recorded run without the pulse: no run 0)
    snaps = Snapshots.load(tmp_path / "train.h5")
    assert [run.attrs["input_spec"] for run in snaps.runs] == [raised, "none"]
    # the rate check's "step too coarse" (the model swings by metres on its own) is kept since 2026-12-08 (audit86 F5)
    assert recorded_verdicts(snaps.attrs) == {"nonlinear", "coarse-step"}
    assert any("too coarse" in str(w.message) for w in seen)
