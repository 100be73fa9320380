"""Audit86 F4b: compare judged an output that rests in a run against its round-off.

Two decoupled 3-mass chains, the force on the first, the second started off rest, exported in relative coordinates
(one ``s_rel`` across the chains' boundary).  In the free response (input ``none``) the first chain's output moves
by round-off (4.5e-17); compare said "largest miss 2.7e+06 of y[1]'s range there" and "y[1] is 5.3e+06 of its peak
off" for a ROM 1.2e-10 off in absolute terms.  Now an output that moves by no more than ``OWN_MOTION_SHARE`` of its
training motion (``training_runs[*].output_peak``) is judged against that motion, as fit judges it, and the line
and the notes say which; eq. (19) is unchanged.

The ROM is the exact model (the true matrices, absolute coordinates, no basis), so its miss is the FMU's own
integration error; the training peaks and the reference are :func:`fmu_opinf.lti_fmus.zoh_response`.
"""

from __future__ import annotations


import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.compare import comparison_notes, compare, error_metrics
from fmu_opinf.compare._run import free_response_line
from fmu_opinf.fit import OWN_MOTION_SHARE
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

DT, T_END = 0.02, 20.0
IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"


def _two_chains() -> lti_fmus.LinearMechanicalModel:
    """Two decoupled copies of a 3-mass chain; the force on mass 3 of the first; outputs x3, x6, v4; chain 2 off
    rest (audit86's ``twosub``)."""
    c = lti_fmus.chain_model(3, inputs=())
    M, D, K = (np.kron(np.eye(2), a) for a in (c.M, c.D, c.K))
    B = np.zeros((6, 1))
    B[2, 0] = 1.0
    Cp, Cv = np.zeros((3, 6)), np.zeros((3, 6))
    Cp[0, 2] = Cp[1, 5] = Cv[2, 3] = 1.0
    return lti_fmus.LinearMechanicalModel(M=M, D=D, K=K, B=B, Cp=Cp, Cv=Cv, x0=np.r_[0, 0, 0, 0.02, -0.01, 0.03],
                                          name="TwoSubRel")


def _training_peaks(model: lti_fmus.LinearMechanicalModel) -> list[float]:
    """Each output's largest departure from its start over the exact impulse and free runs (what fit records)."""
    t = time_grid(DT, 100.0)
    peaks = np.zeros(3)
    for spec in (IMPULSE, "none"):
        y = lti_fmus.zoh_response(model, t, inputs_in_effect(parse_signal(spec, 1), t, 1)[:, 1:]).y
        peaks = np.maximum(peaks, np.abs(y - y[:, :1]).max(axis=1))
    return [float(v) for v in peaks]


@pytest.fixture(scope="module")
def free_run(tmp_path_factory):
    """compare's free response of the exact ROM against the relative-coordinates FMU, and the training peaks."""
    model = _two_chains()
    path = tmp_path_factory.mktemp("f4b") / "twosub_rel.fmu"
    lti_fmus.build_lti_fmu(model, path, relative=True, interleaved=True)
    peaks = _training_peaks(model)
    rom = SecondOrderROM(model.M, model.D, model.K, model.B, model.Cp, model.Cv, dt=DT, q0=model.x0,
                         qdot0=model.v0, integrator="exact", output_names=["y[1]", "y[2]", "y[3]"],
                         provenance={"training_runs": [{"output_peak": peaks}]})
    return compare(rom, str(path), "none", dt=DT, t_end=T_END, quiet=True), peaks, model


def test_an_output_at_rest_is_judged_against_its_training_motion(free_run):
    """Measured: y[1] moves by 4.5e-17 here (its training peak 6.07); the exact ROM misses it by 2.2e-17, 3.7e-18 of
    that peak (before: 0.50 of its "range", 1.0 of its peak; audit86's fitted ROM: 2.7e6 and 5.3e6).  The other
    outputs keep their scale of this run."""
    result, peaks, model = free_run
    metrics = result.metrics()
    y1 = metrics["per_output"]["y[1]"]
    assert np.ptp(result.y_fom[0]) < OWN_MOTION_SHARE * peaks[0]     # the case: y[1] rests in this run
    assert metrics["at_rest"] == ["y[1]"]
    assert [v["scale"] for v in metrics["per_output"].values()] == ["training", "this run", "this run"]
    # the independent figure: the FMU against the exact model, over the training peak
    t = result.t
    exact = lti_fmus.zoh_response(model, t, np.zeros((1, t.size - 1))).y
    assert np.abs(result.y_fom[0] - exact[0]).max() / peaks[0] < 1e-16   # measured 3.7e-18
    assert y1["relative_max_variation"] == pytest.approx(y1["absolute_max"] / peaks[0], rel=1e-12)
    assert y1["relative_max"] == pytest.approx(y1["absolute_max"] / peaks[0], rel=1e-12)
    assert y1["relative_max_variation"] < 1e-16 and y1["relative_l2"] < 1e-16   # measured 3.7e-18, 2.0e-18


def test_the_free_response_line_and_notes_name_the_resting_output(free_run):
    """Before: "largest miss 0.5 of y[1]'s range there" and "y[1] is 1 of its peak off" (scale_note; audit86's
    fitted ROM: 2.7e+06 and 5.3e+06)."""
    result, _, _ = free_run
    line = free_response_line(result)
    assert "e+0" not in line and "judged against their training motion: y[1]" in line, line
    notes = comparison_notes(result.metrics())
    assert not [note for note in notes if "hide" in note], notes
    assert [note for note in notes if note.startswith("y[1] rests in this run")], notes


def test_eq19_and_moving_outputs_keep_their_meaning():
    """eq. (19), the L2 error and an output that moves keep the scale of this run; an output at rest at an offset
    is judged against the larger of its peak here and its training motion (hand-computed figures)."""
    t = np.linspace(0.0, 1.0, 11)
    y_ref = np.vstack([np.sin(2 * np.pi * t), np.full_like(t, 0.5), 1e-18 * np.cos(t)])
    y = y_ref + np.array([[1e-3], [2e-3], [4e-3]]) * np.cos(3 * t)
    plain = error_metrics(y_ref, y)
    floored = error_metrics(y_ref, y, training_peaks=[1.0, 4.0, 2.0])
    assert floored["max_error"] == plain["max_error"] and floored["l2_error"] == plain["l2_error"]
    assert floored["per_output"]["y[1]"] == plain["per_output"]["y[1]"]
    assert floored["at_rest"] == ["y[2]", "y[3]"] and plain["at_rest"] is None
    for name, miss, training, peak in (("y[2]", 2e-3, 4.0, 0.5), ("y[3]", 4e-3, 2.0, 1e-18)):
        figures = floored["per_output"][name]
        assert figures["relative_max_variation"] == pytest.approx(miss / training, rel=1e-12)
        assert figures["relative_max"] == pytest.approx(miss / max(peak, training), rel=1e-12)
        rms = np.sqrt(np.mean((miss * np.cos(3 * t)) ** 2))
        assert figures["relative_l2"] == pytest.approx(rms / max(np.sqrt(np.mean(y_ref[int(name[2]) - 1] ** 2)),
                                                                 training), rel=1e-12)
    assert plain["per_output"]["y[3]"]["relative_max"] > 1e14   # round-off as its own scale


def test_a_moving_output_above_the_share_keeps_its_own_range():
    """An output moving by 10 x OWN_MOTION_SHARE of its training motion moves: its own range judges it."""
    t = np.linspace(0.0, 1.0, 11)
    y_ref = 1e-5 * np.sin(2 * np.pi * t)[None, :]
    y = y_ref + 1e-8
    figures = error_metrics(y_ref, y, training_peaks=[1.0])["per_output"]["y[1]"]
    assert figures["scale"] == "this run"
    assert figures["relative_max_variation"] == pytest.approx(1e-8 / np.ptp(y_ref), rel=1e-9)


def test_training_peaks_missing_or_damaged_keep_the_run_s_scale():
    """A ROM without recorded peaks (built by hand, an older file) or with damaged ones: figures as before."""
    t = np.linspace(0.0, 1.0, 11)
    y_ref = np.vstack([np.sin(t), 1e-18 * t])
    y = y_ref + 1e-6
    plain = error_metrics(y_ref, y)
    for peaks in (None, [1.0], ["a", None], [np.nan, -1.0]):
        assert error_metrics(y_ref, y, training_peaks=peaks)["per_output"] == plain["per_output"], peaks


def test_the_report_says_which_scale_a_resting_output_is_judged_against(free_run):
    """The HTML page's per-output row and a run's row name the training motion for y[1], the range for the others
    (before: "relative to its range" for every output, beside a figure over the training motion)."""
    from fmu_opinf.report import _html_page, _run_row

    result, _, _ = free_run
    metrics = result.metrics()
    page = _html_page(result, metrics, {})
    assert page.count("relative to its training motion (it rests in this run") == 1
    assert page.count("relative to its range (max_t |y - y_r| / (max_t y - min_t y))") == 2
    run = {"input": "none", "max_error": metrics["max_error"],
           "per_output": {"y[1]": metrics["per_output"]["y[1]"]}}
    assert _run_row(run).endswith("of its training motion (it rests there)")
