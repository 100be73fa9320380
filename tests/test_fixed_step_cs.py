"""Co-simulation FMUs that limit the communication step: a fixed step (fixed-step code generators) and an
embedded solver's maximum step that discards longer ones (audit of 2026-11-27, FMUs C, C3 and G).

The FMUs are built by :func:`fmu_opinf.lti_fmus.build_lti_fmu` with ``cs_fixed_step`` (declared as
``DefaultExperiment/@stepSize`` with ``canHandleVariableCommunicationStepSize="false"``; ``doStep`` returns an
error for any other step) or ``cs_max_step`` (``doStep`` returns a discard for a longer step).  Recordings are
checked against the exact zero-order-hold solution (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import build_fmu_set
from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.newmark import time_grid
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Snapshots, record_to_file

pytestmark = pytest.mark.fmu

FIXED, MAX_STEP = 0.02, 0.02
HARMONIC = "harmonic:amplitude=1,omega=0.8"
#: Bounds near what is achieved (2026-11-27): recordings 1.8e-12 off the exact outputs (relative to their peak; the
#: FMU's RK4 at the tolerance 1e-10), max eps_y (squared) of compare 1.1e-26 and of the ROM against the exact
#: solution 3.4e-27.  Until the refinement kept starts that already reproduce the data (training objective 2.7e-24,
#: below fmu_opinf.refinement.REPRODUCED) it fitted the FMU's RK4 error: compare 6.7e-28, but 1.25e-26 against the
#: exact solution.  Bounds about 3x in eps_y.
RECORDING, EPS_Y_COMPARE, EPS_Y_EXACT = 1e-11, 3e-26, 1e-26


def _model():
    return lti_fmus.chain_model(3, name="Limited")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """The FMUs by name: ``fixed2`` / ``fixed3`` (FMI 2 / 3, fixed communication step 0.02, co-simulation only),
    ``fixed_me`` (the same with model exchange), ``max2`` / ``max3`` (maximum step 0.02, longer steps discarded),
    ``declared`` (declares the fixed step 0.02 but runs at any constant step)."""
    items = {"fixed2": dict(cs_fixed_step=FIXED), "fixed3": dict(cs_fixed_step=FIXED, fmi_version="3.0"),
             "fixed_me": dict(cs_fixed_step=FIXED, interfaces=("me", "cs")),
             "max2": dict(cs_max_step=MAX_STEP), "max3": dict(cs_max_step=MAX_STEP, fmi_version="3.0"),
             "declared": dict(cs_fixed_step=FIXED, cs_fixed_step_enforced=False)}

    def build(folder: Path, item):
        name, options = item
        options = {"interfaces": ("cs",), **options}
        built = lti_fmus.build_lti_fmu(_model(), folder / f"{name}.fmu", identifier=f"Limited_{name}", **options)
        return name, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-fixed-step", build, items.items())


def _exact(run) -> np.ndarray:
    """The exact outputs on the run's grid under its held inputs."""
    u = np.asarray(run.u)
    return lti_fmus.zoh_response(_model(), np.asarray(run.t), u[:, 1:] if u.shape[0] else None).y


def _relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def _last_line_error(capsys) -> str:
    """The error line that ends stderr (warnings may come before it), without a traceback."""
    err = capsys.readouterr().err.strip()
    assert err and "Traceback" not in err, err
    return err.splitlines()[-1]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err and "\n" not in err and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------------------------------- fixed step
def test_the_fmus_refuse_another_step(fmus, tmp_path, capsys):
    """The test FMUs do what fixed-step exporters do: a step of half the fixed one, given with --t-end so that no
    check of fmu-opinf stands in the way, fails in the FMU itself (here through compare's path, which drives any
    FMU); and a step longer than the maximum is discarded."""
    from fmu_opinf.compare import simulate_outputs
    from fmu_opinf.errors import FmuOpinfError
    from fmu_opinf.sources import FMUSource

    source = FMUSource(fmus["fixed2"])
    try:
        source.start(time_grid(FIXED / 2, 0.5), np.zeros((51, 1)))
        with pytest.raises(FmuOpinfError, match="differs from the fixed step"):
            source.advance(np.zeros((51, source.width)), 0, 51)
    finally:
        source.close()
    with pytest.raises(FmuOpinfError, match="discarded the communication step 0.05"):
        simulate_outputs(fmus["max2"], parse_signal(HARMONIC, 1), time_grid(0.05, 1.0))


@pytest.mark.parametrize("name", ["fixed2", "fixed3"])
@pytest.mark.slow  # 9 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_fixed_communication_step_is_recorded_with_defaults(fmus, name, tmp_path):
    """Before: 'returned an error in fmi2DoStep ... communication step 0.025 differs from the fixed step' (the step
    check's dt/2 run, or the window's own pilot step).  Now the pilots, the window and the recording use exactly
    the declared step, and the recording is the exact solution to the FMU's RK4 accuracy."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus[name]), "-o", str(out), "-q"]) == 0
    snaps = Snapshots.load(out)
    run = snaps.runs[0]
    window = json.loads(run.attrs["auto_window"]) if isinstance(run.attrs["auto_window"], str) \
        else run.attrs["auto_window"]
    assert run.attrs["dt"] == FIXED and window["dt"] == FIXED and window["pilot_dt"] == FIXED
    summary = record_to_file(str(fmus[name]), tmp_path / "again.h5", None, quiet=True)
    assert "auto window for t_end only: dt=0.02 (the FMU's fixed communication step); the window's own: dt=0.02" \
        in summary.describe()
    assert np.all(np.diff(run.t) == pytest.approx(FIXED, rel=1e-9)) and run.t[-1] > 50.0
    assert _relative(run.y, _exact(run)) < RECORDING


@pytest.mark.slow
def test_the_default_chain_runs_on_a_fixed_step_fmu(fmus, tmp_path, capsys):
    """snapshots, fit, compare (at the training step: the fixed one), export with defaults; compare's eps_y is
    checked against the exact solution; a compare --dt other than the fixed step fails at the
    FMU's first doStep, in one line naming the step to give."""
    fmu, train, rom, report = fmus["fixed2"], tmp_path / "train.h5", tmp_path / "rom.h5", tmp_path / "report"
    assert main(["snapshots", str(fmu), "-o", str(train), "-q"]) == 0
    assert main(["fit", str(train), "-o", str(rom), "-q"]) == 0
    assert main(["compare", str(rom), str(fmu), "--input", HARMONIC, "-o", str(report), "-q"]) == 0
    metrics = json.loads((report / "metrics.json").read_text())
    model = SecondOrderROM.load(rom)
    t = time_grid(FIXED, metrics["t_end"])
    exact = lti_fmus.zoh_response(_model(), t, parse_signal(HARMONIC, 1).sample(t)).y
    y = model.simulate(HARMONIC, FIXED, t[-1]).y[:, :t.size]
    eps_exact = float((((y - exact) ** 2).sum(axis=0) / (exact ** 2).sum(axis=0).max()).max())
    assert metrics["dt"] == FIXED and metrics["max_error"] < EPS_Y_COMPARE and eps_exact < EPS_Y_EXACT
    assert main(["export", str(rom), "-o", str(tmp_path / "rom.fmu"), "-q"]) == 0

    capsys.readouterr()
    assert main(["compare", str(rom), str(fmu), "--input", HARMONIC, "--dt", "0.01", "-o", str(tmp_path / "r2"),
                 "-q"]) == 2
    err = _last_line_error(capsys)
    assert re.search(r"differs from the fixed step 0\.02; it declares the fixed communication step 0\.02: leave --dt "
                     r"or dt= out or give --dt 0\.02 or dt=0\.02", err), err
    assert not (tmp_path / "r2").exists()


def test_another_dt_is_tried_with_a_warning_and_the_fmu_s_refusal_names_its_step(fmus, tmp_path, capsys,
                                                                                 monkeypatch):
    """FMI asks an FMU that cannot vary its communication step for one constant step, not for its declared one, so a
    --dt that differs (also a multiple of it) is used, with a warning naming the declared step.  An FMU that refuses
    it fails at its first doStep in one line that names the step to give (and model exchange, where it is on
    offer); one that runs at any constant step records at the --dt asked for, to the exact solution."""
    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())   # the warning is once per FMU, step and process
    out = tmp_path / "train.h5"
    for dt in ("0.01", "0.04"):
        assert main(["snapshots", str(fmus["fixed2"]), "-o", str(out), "-q", "--dt", dt, "--t-end", "5"]) == 2
        err = capsys.readouterr().err
        assert f"it declares one fixed communication step 0.02 (canHandleVariableCommunicationStepSize=false, " \
               f"DefaultExperiment stepSize=0.02); running at the step {dt} as asked" in err, err
        assert "differs from the fixed step 0.02; it declares the fixed communication step 0.02: leave --dt or dt= " \
               "out or give --dt 0.02 or dt=0.02" in err.strip().splitlines()[-1], err
        assert "Traceback" not in err and "(complete=False)" in err   # as for any step the FMU fails
        out.unlink()
    assert main(["snapshots", str(fmus["fixed_me"]), "-o", str(out), "-q", "--interface", "cs", "--dt", "0.01",
                 "--t-end", "5"]) == 2
    assert "drive its model exchange, --interface me" in _last_line_error(capsys)
    out.unlink()
    # model exchange has no fixed step: the same FMU records at 0.01 there, without a word
    assert main(["snapshots", str(fmus["fixed_me"]), "-o", str(out), "-q", "--dt", "0.01", "--t-end", "5"]) == 0
    assert Snapshots.load(out).runs[0].attrs["dt"] == 0.01 and "fixed" not in capsys.readouterr().err
    out.unlink()
    assert main(["snapshots", str(fmus["declared"]), "-o", str(out), "-q", "--dt", "0.01", "--t-end", "5"]) == 0
    assert "running at the step 0.01 as asked" in capsys.readouterr().err
    run = Snapshots.load(out).runs[0]
    assert run.attrs["dt"] == 0.01 and _relative(run.y, _exact(run)) < RECORDING
    out.unlink()
    assert main(["snapshots", str(fmus["fixed2"]), "-o", str(out), "-q", "--dt", "0.02", "--t-end", "5"]) == 0
    assert "fixed" not in capsys.readouterr().err
    run = Snapshots.load(out).runs[0]
    assert run.attrs["dt"] == FIXED and _relative(run.y, _exact(run)) < RECORDING


def test_a_fixed_step_is_kept_by_auto_window_and_not_step_checked(fmus, tmp_path, recwarn):
    """--auto-window picks the window's own step for other FMUs; a fixed step stays.  No step-dependence warning:
    the results cannot depend on a step that cannot be changed."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["fixed2"]), "-o", str(out), "-q", "--auto-window"]) == 0
    assert Snapshots.load(out).runs[0].attrs["dt"] == FIXED
    assert not [w for w in recwarn if "depends on the communication step" in str(w.message)]


# ---------------------------------------------------------------------------------------- maximum step
@pytest.mark.parametrize("name", ["max2", "max3"])
def test_a_discarded_step_is_said_with_its_fix(fmus, name, tmp_path, capsys):
    """Before: 'returned an error in fmi2DoStep ... : step size 0.05 exceeds ...' with no hint.  Now the discard is
    told from an error, with the FMU's log and a smaller --dt.  The default window's own pilot step (0.05), refused
    the same way before, now takes the window's step search (audit 70, finding 9): recorded at 0.02, exact."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus[name]), "-o", str(out), "-q", "--dt", "0.05", "--t-end", "5"]) == 2
    err = _one_line_error(capsys)
    assert re.search(r"discarded the communication step 0\.05 in fmi[23]DoStep at step 1 \(t=0 -> 0\.05; its log: "
                     r".*exceeds the maximum step size 0\.02.*\): give a smaller step, e\.g\. --dt 0\.02 or dt=0\.02",
                     err), err
    assert "returned an error" not in err and not out.exists()
    assert main(["snapshots", str(fmus[name]), "-o", str(out), "-q"]) == 0
    run = Snapshots.load(out).runs[0]
    assert run.attrs["dt"] == 0.02 and _relative(run.y, _exact(run)) < RECORDING
    out.unlink()
    # the example is the largest step below the discarded one that the FMU's log names, not half of it (tenth
    # audit: at 0.05 the advice was 0.02 beside a log naming 0.01; here 0.1 was advised 0.05, refused again)
    assert main(["snapshots", str(fmus[name]), "-o", str(out), "-q", "--dt", "0.1", "--t-end", "5"]) == 2
    assert _one_line_error(capsys).endswith("give a smaller step, e.g. --dt 0.02 or dt=0.02; no file was written")


def test_a_given_dt_is_the_pilots_step(fmus, tmp_path):
    """--dt without --t-end: the window's pilots ran at their own 0.05 and were discarded; now every pilot runs at
    the given step, which is recorded, and the window chooses the end."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["max2"]), "-o", str(out), "-q", "--dt", "0.02"]) == 0
    run = Snapshots.load(out).runs[0]
    window = json.loads(run.attrs["auto_window"]) if isinstance(run.attrs["auto_window"], str) \
        else run.attrs["auto_window"]
    assert run.attrs["dt"] == 0.02 and window["pilot_dt"] == 0.02 and run.t[-1] > 50.0
    assert _relative(run.y, _exact(run)) < RECORDING


def test_one_run_keeps_one_step(fmus, tmp_path):
    """At --dt equal to the maximum step the grid's differences exceed it by rounding (1.02 - 1.00 =
    0.020000000000000018) and the FMU discarded them; every doStep of a run now gets the one step."""
    out = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["max2"]), "-o", str(out), "-q", "--dt", "0.02", "--t-end", "300"]) == 0
    run = Snapshots.load(out).runs[0]
    assert run.t[-1] == pytest.approx(300.0) and _relative(run.y, _exact(run)) < RECORDING


@pytest.mark.slow  # 18 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_given_coarse_dt_is_recorded_and_said_to_be_coarse(fmus, tmp_path):
    """--dt 0.1 without --t-end (model exchange: no limit on the step): the pilots run at 0.1, the recording too,
    and one warning says that it gives fewer than 20 samples per period of the fastest mode (1.5 Hz; 1.28 Hz as
    seen at that step: 7.8 samples per period)."""
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.snapshots import record_to_file

    with pytest.warns(FmuOpinfWarning, match=r"the step dt=0\.1 gives [\d.]+ samples per period of the fastest "
                                             r"significant frequency [\d.]+ Hz .*a smaller step resolves it, e\.g\. "
                                             r"--dt 0\.02 or dt=0\.02"):
        summary = record_to_file(fmus["fixed_me"], tmp_path / "train.h5", None, dt=0.1, quiet=True)
    run = Snapshots.load(tmp_path / "train.h5").runs[0]
    assert summary.dt == 0.1 and summary.window.pilot_dt == 0.1 and run.attrs["fmi_interface"] == "me"
    assert _relative(run.y, _exact(run)) < 1e-9  # DOP853 at the tolerance 1e-10: 1.7e-10


@pytest.mark.slow  # 7 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_given_dt_sets_the_pilots_step_also_on_a_declared_fixed_step_fmu(fmus, tmp_path, monkeypatch):
    """Review of the fifth audit's fix: a --dt given without --t-end to an FMU that declares a fixed step ran the
    window's pilots at the declared step, and the under-resolution warning called the user's step the FMU's.  The
    pilots run at the step asked for, the one recorded, and the recording is the exact solution."""
    import warnings

    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        summary = record_to_file(str(fmus["declared"]), tmp_path / "a.h5", None, dt=0.1, quiet=True)
    said = " ".join(str(w.message) for w in caught)
    assert summary.window.pilot_dt == 0.1 and summary.dt == 0.1, summary.describe()
    assert "running at the step 0.1 as asked" in said and "fixed communication step 0.1" not in said, said
    run = Snapshots.load(tmp_path / "a.h5").runs[0]
    assert _relative(run.y, _exact(run)) < RECORDING


def test_a_fixed_step_fmu_that_declares_no_step_is_told_to_give_dt(fmus, tmp_path, capsys):
    """Eighth audit (a Simulink-style FMU): canHandleVariableCommunicationStepSize=false without a declared stepSize
    gives no step to keep, so the window's first pilot step is refused by doStep; the one line says what the FMU
    lacks and to give --dt as a multiple of its internal step, with a round value."""
    from conftest import rewrite_description

    silent = rewrite_description(fmus["fixed2"], tmp_path / "silent.fmu",
                                 lambda text: re.sub(r'\s*stepSize="[^"]*"', "", text))
    assert main(["snapshots", str(silent), "-o", str(tmp_path / "train.h5")]) == 2
    line = _last_line_error(capsys)
    assert re.search(r"returned an error in fmi2DoStep.*cannot vary its communication step .* declares no "
                     r"DefaultExperiment stepSize.*give --dt or dt= as such a multiple, e\.g\. [0-9.e-]+, and --t-end "
                     r"or t_end=", line)
    assert not (tmp_path / "train.h5").exists()
