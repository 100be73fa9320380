"""compare and the report: error measures against independent computations, files, bad input."""

import json
import re
import shutil
import subprocess
import warnings

import numpy as np
import pytest

from fmu_opinf import compare, newmark, rom, snapshots, systems
from fmu_opinf.fit import fit_rom
from fmu_opinf.errors import DimensionError, FileFormatError, FmuOpinfError, FmuOpinfWarning, InputSpecError

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


@pytest.fixture(scope="module")
def anchored_rom(tmp_path_factory):
    """A ROM of the builtin anchored chain (r = 5), saved to a file."""
    snaps = snapshots.record("builtin:anchored-msd", TRAIN, 0.5, 100.0, quiet=True)
    model = fit_rom(snaps, r=5)
    path = tmp_path_factory.mktemp("rom") / "rom.h5"
    model.save(path)
    return model, path


def test_error_measure_is_eq19():
    y_ref = np.array([[0.0, 2.0, -1.0], [0.0, 0.0, 1.0]])
    y = np.array([[0.0, 1.0, -1.0], [1.0, 0.0, 1.0]])
    assert np.allclose(compare.output_error(y_ref, y), np.array([1.0, 1.0, 0.0]) / 4.0)
    with pytest.raises(DimensionError, match="identically zero"):
        compare.output_error(np.zeros((1, 3)), np.zeros((1, 3)))


def test_rom_against_itself_has_zero_error(anchored_rom):
    model, path = anchored_rom
    result = compare.compare(path, str(path), TEST, dt=0.5, t_end=50.0, quiet=True)
    metrics = result.metrics()
    assert metrics["max_error"] == 0.0 and metrics["l2_error"] == 0.0


def test_rom_against_fom_matches_an_independent_computation(anchored_rom):
    model, path = anchored_rom
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=400.0, quiet=True)
    fom = newmark.simulate(systems.anchored_msd(), TEST, 0.5, 400.0)
    reduced = model.simulate(TEST, 0.5, 400.0)
    expected = compare.output_error(fom.y, reduced.y).max()
    assert result.metrics()["max_error"] == pytest.approx(expected, rel=1e-12)
    assert 0 < expected < 1e-4
    assert result.metrics()["l2_error"] == pytest.approx(
        np.linalg.norm(fom.y - reduced.y) / np.linalg.norm(fom.y), rel=1e-12)


def test_report_files(anchored_rom, tmp_path):
    model, path = anchored_rom
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=200.0, quiet=True)
    page = compare.write_report(result, tmp_path / "report")
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    for key in ("max_error", "l2_error", "r", "fom_seconds", "rom_seconds", "speedup", "input", "fom", "rom"):
        assert key in metrics
    assert metrics["r"] == 5 and metrics["input"].startswith("harmonic")
    assert metrics["fom"]["source"] == "builtin:anchored-msd"
    text = page.read_text()
    assert text.count("data:image/png;base64,") == 2
    assert "eq. (19)" in text
    for png in ("outputs.png", "error.png"):
        assert (tmp_path / "report" / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_control_characters_in_names_are_drawn_as_spaces_without_a_font_warning(anchored_rom, tmp_path):
    """Audit 62, finding 7: a carriage return in an output's name printed matplotlib's "Glyph 13 missing from
    font(s) DejaVu Sans" warning; the names stay as they are in the report's data."""
    model, path = anchored_rom
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=20.0, quiet=True)
    names = ["pos%d\r\nline2 ]]> <!-- -->", "a\tb\x01", "y3"]
    result.output_names = list(names)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compare.write_report(result, tmp_path / "report")
    assert not [str(w.message) for w in caught if "Glyph" in str(w.message)]
    assert result.output_names == names
    from fmu_opinf.plots import plot_text

    assert plot_text("pos%d\r\nline2 ]]> $x$\x85\x7f") == "pos%d line2 ]]> \\$x\\$ "


def test_report_directory_that_is_a_file_is_refused(anchored_rom, tmp_path):
    model, path = anchored_rom
    result = compare.compare(model, "builtin:anchored-msd", TEST, dt=0.5, t_end=10.0, quiet=True)
    target = tmp_path / "report"
    target.write_text("keep me")
    with pytest.raises(FileFormatError, match="is an existing file"):
        compare.write_report(result, target)
    assert target.read_text() == "keep me"


def test_rom_and_source_that_disagree_are_refused(anchored_rom):
    model, path = anchored_rom
    with pytest.raises(DimensionError, match="the source has 1 outputs but the ROM has 3"):
        compare.compare(path, "builtin:triple-chain", TEST, dt=0.5, t_end=10.0, quiet=True)


def test_input_beyond_its_table_is_refused(anchored_rom, tmp_path):
    model, path = anchored_rom
    table = tmp_path / "u.csv"
    table.write_text("t,u\n0,1\n20,0\n")
    with pytest.raises(InputSpecError, match=r"defined on \[0, 20\]"):
        compare.compare(path, "builtin:anchored-msd", str(table), dt=0.5, t_end=40.0, quiet=True)


def _chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


CHECK_IMAGES = """
<script>
window.addEventListener("load", () => {
  const images = Array.from(document.images);
  const ok = images.filter(i => i.complete && i.naturalWidth > 0).length;
  document.body.setAttribute("data-images", ok + "/" + images.length);
});
</script>
"""


@pytest.mark.skipif(_chromium() is None, reason="no chromium installed (.ci/run installs Debian's chromium)")
@pytest.mark.slow
def test_report_page_renders_in_headless_chromium(anchored_rom, tmp_path):
    model, path = anchored_rom
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=200.0, quiet=True)
    page = compare.write_report(result, tmp_path / "report")
    probe = page.with_name("probe.html")
    probe.write_text(page.read_text().replace("</body>", CHECK_IMAGES + "</body>"))
    command = [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0",
               "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert 'data-images="2/2"' in done.stdout, done.stdout[-500:]
    console_errors = [line for line in done.stderr.splitlines() if "CONSOLE" in line and "ERROR" in line]
    assert not console_errors, console_errors


def test_report_figures_keep_every_label_inside_the_image(anchored_rom, tmp_path, monkeypatch):
    """The fixed margins (instead of tight layout) leave no tick label, axis label, title or legend cut off, with
    long output names and units on two outputs, and large tick labels."""
    import matplotlib.figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from fmu_opinf import plots

    model, path = anchored_rom
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=200.0, quiet=True)
    result.y_fom = np.vstack([result.y_fom[:1] * 1e5, result.y_fom[1:2]])
    result.y_rom = np.vstack([result.y_rom[:1] * 1e5, result.y_rom[1:2]])
    result.output_names = ["chain.mass[600].flange_b.s", "sensor.v"]
    result.output_units = ["mm", "m/s"]
    # two inputs' signals in the title (audit 77a F4: drawn on one line, cut off at both edges)
    result.input_spec = ("harmonic:amplitude=12.4,omega=3.49,phase=1.7671,offset=0;"
                         "harmonic:amplitude=12.4,omega=3.8,phase=0.2,offset=0")
    figures, save = [], matplotlib.figure.Figure.savefig
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig",
                        lambda fig, *args, **kwargs: figures.append(fig) or save(fig, *args, **kwargs))
    compare.write_report(result, tmp_path / "report")
    plots.pod_figures([newmark.simulate(systems.anchored_msd(), TRAIN, 0.5, 100.0)], model, tmp_path / "fit")
    assert len(figures) == 4
    for fig in figures:
        canvas = FigureCanvasAgg(fig)  # the figures are closed: draw them again on a canvas of their own
        canvas.draw()
        drawn = fig.get_tightbbox(canvas.get_renderer())  # inches: every drawn artist, as bbox_inches="tight"
        width, height = fig.get_size_inches()
        assert drawn.x0 >= -0.01 and drawn.y0 >= -0.01, (drawn, fig.texts, fig.axes[0].get_title())
        assert drawn.x1 <= width + 0.01 and drawn.y1 <= height + 0.01, (drawn, fig.axes[0].get_title())
        renderer = canvas.get_renderer()
        axes_top = max(ax.get_window_extent(renderer).y1 for ax in fig.axes)
        for text in fig.texts:   # a figure title (several lines) stays above the axes
            assert text.get_window_extent(renderer).y0 >= axes_top, (text.get_text(), axes_top)


def test_an_output_offset_does_not_hide_the_error_of_its_motion():
    """y = 100 + sin t against 100 + 0.8 sin t over whole periods: eq. (19) is 0.2^2 / 101^2 = 3.9e-6, the error of
    the motion 0.2^2 / 1 = 0.04 (mean removed) and 0.2 / 2 = 0.1 of its range; the table says so."""
    t = np.linspace(0.0, 20 * np.pi, 20001)
    y_ref, y = 100.0 + np.sin(t), 100.0 + 0.8 * np.sin(t)
    metrics = compare.error_metrics(y_ref[None], y[None], ["y"])
    assert metrics["max_error"] == pytest.approx(0.04 / 101.0**2, rel=1e-6)
    assert metrics["max_error_variation"] == pytest.approx(0.04, rel=1e-6)
    assert metrics["per_output"]["y"]["relative_max_variation"] == pytest.approx(0.1, rel=1e-6)
    table = compare.summary_table([("offset", {**metrics, "r": 2, "fom_seconds": 1.0, "rom_seconds": 0.1,
                                               "speedup": 10.0})])
    assert "offset hides the error in eq. (19)" in table and "y is 0.1 of its range off" in table
    plain = compare.error_metrics(np.sin(t)[None], 0.8 * np.sin(t)[None], ["y"])
    # eq. (19) is squared: the table says so, with the root (ninth audit: 2.1e-4, a 1.5 % error, read as 4 digits)
    table = compare.summary_table([("plain", {**plain, "r": 2, "fom_seconds": 1.0, "rom_seconds": 0.1,
                                              "speedup": 10.0})])
    assert plain["max_error"] == pytest.approx(0.04, rel=1e-6)
    assert "squared output error relative to the outputs' peak (its square root, 0.2 for 0.04" in table
    assert compare.offset_note(plain) is None


def test_larger_outputs_do_not_hide_the_error_of_a_small_one():
    """Fifth audit: positions in mm (about 1e4) beside an acceleration in m/s2 (1e-2) that is 3 % off give eq. (19)
    (0.03 * 1e-2)^2 / 1e4^2 = 9e-16, and the variation form the same; the table and the report say which output
    is off.  Outputs of one scale with that error say nothing more (eq. 19 shows it)."""
    t = np.linspace(0.0, 20 * np.pi, 20001)
    y_ref = np.vstack([1e4 * np.sin(t), 1e-2 * np.sin(3 * t)])
    y = np.vstack([y_ref[0], 0.97 * y_ref[1]])
    metrics = compare.error_metrics(y_ref, y, ["frame.s", "joint2.a"])
    assert metrics["max_error"] == pytest.approx((0.03e-2 / 1e4) ** 2, rel=1e-3)
    table = compare.summary_table([("units", {**metrics, "r": 3, "fom_seconds": 1.0, "rom_seconds": 0.1,
                                              "speedup": 10.0})])
    assert "larger outputs hide an error in eq. (19): joint2.a is 0.03 of its peak off" in table
    same_scale = 2e4 * np.sin(3 * t)
    alike = compare.error_metrics(np.vstack([y_ref[0], same_scale]), np.vstack([y[0], 0.97 * same_scale]), ["a", "b"])
    assert alike["per_output"]["b"]["relative_max"] == pytest.approx(0.03, rel=1e-3)
    assert compare.scale_note(alike) is None and compare.offset_note(alike) is None
    # round-off of a small output (a ROM FMU against its ROM) is no hidden error
    rounding = compare.error_metrics(y_ref, np.vstack([y_ref[0], (1 + 1e-13) * y_ref[1]]), ["frame.s", "joint2.a"])
    assert rounding["per_output"]["joint2.a"]["relative_max"] ** 2 > 100 * rounding["max_error"]
    assert compare.scale_note(rounding) is None


def test_a_rom_whose_energy_order_misses_the_test_gets_a_larger_order_suggested():
    """Audit 62: an FE bar's ROM at the energy order (r = 3 of a snapshot rank of 300) was 1-1.6 % off on a harmonic
    test and nothing said what to try.  Here the anchored chain at the order of a 0.6 energy threshold (r = 2) is
    compared with the builtin model (Newmark, independent of the ROM): the table suggests twice the order; a ROM
    with the
    order given, a smaller error or no room below the snapshot rank, says nothing."""
    snaps = snapshots.record("builtin:anchored-msd", TRAIN, 0.5, 100.0, quiet=True)
    small = fit_rom(snaps, energy=0.6, refine=False)
    assert small.r == 2 and small.fit_info["snapshot_rank"] > 4
    fast = "harmonic:amplitude=1,omega=0.28"   # near the chain's fastest learned modes
    metrics = compare.compare(small, "builtin:anchored-msd", fast, dt=0.5, t_end=50.0, quiet=True).metrics()
    worst = max(output["relative_max_variation"] for output in metrics["per_output"].values())
    assert worst > 4 * compare.ORDER_NOTE   # measured 5.9e-2
    assert metrics["order"] == {"r": 2, "chosen": "energy", "snapshot_rank": small.fit_info["snapshot_rank"],
                                "tried": []}
    table = compare.summary_table([("small", metrics)])
    assert "came from the POD energy (eq. 18) on snapshots of rank" in table
    assert "(fit --r 4 or r=4, then compare" in table
    given = fit_rom(snaps, r=2, refine=False)
    given_metrics = compare.compare(given, "builtin:anchored-msd", fast, dt=0.5, t_end=50.0, quiet=True).metrics()
    assert given_metrics["order"]["chosen"] == "given" and compare.order_note(given_metrics) is None
    assert compare.order_note({**metrics, "per_output": {"y": {"relative_max_variation": 0.5 * compare.ORDER_NOTE}}}) \
        is None
    assert compare.order_note({**metrics, "order": {**metrics["order"], "snapshot_rank": 2}}) is None
    searched = compare.order_note({**metrics, "order": {**metrics["order"], "chosen": "search"}})
    assert "the fit's order search kept r=2 on snapshots of rank" in searched
    tried = {**metrics["order"], "chosen": "search", "tried": [2, 4]}   # audit 65: the search tried r = 4, kept 2
    assert "(fit --r" not in compare.order_note({**metrics, "order": tried})


def test_the_order_note_reads_the_fit_s_order_search():
    """Audit 65, F4: for a ROM whose order search kept the energy's r = 33 after trying r = 40 (272 times off its
    training outputs), compare said the order "came from the POD energy" and suggested ``fit --r 40``.  The note
    now says what the search kept and tried, never suggests an order it tried, suggests the next doubling where
    the search kept the largest order it tried, and a smaller order where it stopped at a noise floor.  ROM objects
    stand in with only what :func:`compare._training._order_chosen` reads."""
    from types import SimpleNamespace

    def order_of(r, search):
        return compare._training._order_chosen(SimpleNamespace(r=r, provenance={"fit_settings": {"r": None}},
                                                     fit_info={"snapshot_rank": 40, "order_search": search}))

    off = {"per_output": {"y[2]": {"relative_max_variation": 0.35}}}
    kept_first = order_of(33, [{"r": 33, "training_output_error": 1.2e-2}, {"r": 40, "training_output_error": 7.4e4}])
    assert kept_first == {"r": 33, "chosen": "search", "snapshot_rank": 40, "tried": [33, 40]}
    note = compare.order_note({**off, "order": kept_first})
    assert note == ("y[2] is 0.35 of its range off, and the fit's order search kept r=33 (tried r=33, 40) on "
                    "snapshots of rank 40: the larger orders it tried did not fit the training outputs enough better "
                    "to be kept; train with an input nearer this one (or add it as a training run)"), note
    grown = order_of(4, [{"r": 2}, {"r": 4}])   # kept the largest it tried: the next doubling is untried
    assert "search kept r=4 (tried r=2, 4)" in compare.order_note({**off, "order": grown})
    assert "(fit --r 8 or r=8, then compare again)" in compare.order_note({**off, "order": grown})
    floor = order_of(33, [{"r": 33, "noise_floor": 4}])
    assert floor["noise_floor"] == 4
    assert "(fit --r 3 or r=3, then compare again)" in compare.order_note({**off, "order": floor})
    assert order_of(3, [])["chosen"] == "energy"   # no search ran: the energy's order passed its training


def test_settings_other_than_the_training_s_are_merged_and_a_change_is_warned():
    """Audit 2026-11-27: ``compare --set n=4`` of a ROM trained with ``n=3`` compared against another model without
    a word (eps_y 0.56), and any ``--set`` dropped every other training setting."""
    from fmu_opinf.compare._training import _training_settings
    from fmu_opinf.errors import FmuOpinfWarning

    info = {"provenance": {"snapshots": {"source_kind": "fmu", "fmu_settings": {"n": "3", "x_start": "[0,1,0]"}}}}
    with pytest.warns(FmuOpinfWarning, match=r"compared with n=4, but the ROM was trained with n=3"):
        options = _training_settings(info, "model.fmu", {"parameters": {"n": "4"}})
    assert options["parameters"] == {"n": "4", "x_start": "[0,1,0]"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        options = _training_settings(info, "model.fmu", {"parameters": {"x_start": "[0,1,0]", "damping": "2"}})
    assert options["parameters"] == {"n": "3", "x_start": "[0,1,0]", "damping": "2"}
    assert _training_settings(info, "model.fmu", None)["parameters"] == {"n": "3", "x_start": "[0,1,0]"}


def test_a_setting_the_training_left_at_its_start_value_is_warned_when_changed(tmp_path):
    """Tenth audit: ``compare --set gear=2`` of a ROM recorded with ``gear`` held at its start value 1 (no --set in
    the training) was 0.44 off without a word; the FMU's start value is what the training ran with."""
    from fmu_opinf.compare._training import _training_settings
    from fmu_opinf.errors import FmuOpinfWarning

    (tmp_path / "modelDescription.xml").write_text(
        '<?xml version="1.0" encoding="UTF-8"?><fmiModelDescription fmiVersion="2.0" modelName="m" guid="{0}">'
        '<CoSimulation modelIdentifier="m"/><ModelVariables>'
        '<ScalarVariable name="gear" valueReference="1" causality="input"><Real start="1"/></ScalarVariable>'
        '<ScalarVariable name="tau" valueReference="2" causality="input"><Real start="0"/></ScalarVariable>'
        '</ModelVariables><ModelStructure/></fmiModelDescription>')
    info = {"provenance": {"snapshots": {"source_kind": "fmu", "fmu_settings": {}}}}
    with pytest.warns(FmuOpinfWarning, match=r"compared with gear=2, but the ROM was trained with gear=1 \(its start "
                                             r"value\): a ROM describes the model it was trained on"):
        _training_settings(info, str(tmp_path), {"parameters": {"gear": "2"}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        options = _training_settings(info, str(tmp_path), {"parameters": {"gear": "1.0"}})   # the same value
    assert options["parameters"] == {"gear": "1.0"}


def test_many_outputs_draw_the_worst_few_and_say_so(tmp_path):
    """200 outputs (seventh audit: an 880 x 48510 pixel figure, a 35 MB page, 60 s of drawing): the outputs figure
    shows the twelve with the largest error relative to their own peak, in their order, and says so; the page
    still lists every output's errors."""
    import matplotlib.image

    p, t = 200, np.linspace(0.0, 10.0, 501)
    scale = np.logspace(-3, 3, p)[:, None]  # sizes of 1e-3 .. 1e3: the ranking is relative, not absolute
    y_fom = scale * np.sin(t)[None]
    off = np.zeros(p)
    worst = [3, 17, 50, 51, 88, 99, 120, 150, 160, 177, 190, 199]
    off[worst] = np.linspace(0.05, 0.2, len(worst))
    off[[0, 60, 130]] = 0.01  # off, but less than the twelve
    y_rom = y_fom * (1.0 - off[:, None])
    comparison = compare.Comparison(t=t, y_fom=y_fom, y_rom=y_rom, output_names=[f"y{j}" for j in range(p)],
                                    input_spec="harmonic:amplitude=1,omega=1", fom_seconds=1.0, rom_seconds=0.1, r=4)
    assert compare.plotted_outputs(comparison) == worst
    compare.write_report(comparison, tmp_path / "report")
    image = matplotlib.image.imread(tmp_path / "report" / "outputs.png")
    assert image.shape[0] <= (2.2 * 12 + 1.0) * 110 + 1   # twelve panels at 110 dpi, not two hundred
    page = (tmp_path / "report" / "index.html").read_text()
    assert all(f"<tr><th>y{j}</th><td>relative L2" in page for j in range(p))
    assert (tmp_path / "report" / "index.html").stat().st_size < 1.5e6   # measured 0.57 MB


def test_constant_outputs_give_valid_json_and_say_so(tmp_path):
    """An output that is zero and one that is constant beside a moving one (seventh audit: metrics.json held bare
    NaN, which JSON parsers refuse, and the page printed 'nan'): null in the file, a word on the page, and the
    absolute error of each output."""
    t = np.linspace(0.0, 10.0, 201)
    y_fom = np.vstack([np.sin(t), np.zeros_like(t), np.full_like(t, 4.5)])
    y_rom = np.vstack([0.9 * np.sin(t), np.full_like(t, 1e-3), np.full_like(t, 4.5)])
    comparison = compare.Comparison(t=t, y_fom=y_fom, y_rom=y_rom, output_names=["y", "unused", "mass"],
                                    input_spec="harmonic:amplitude=1,omega=1", fom_seconds=1.0, rom_seconds=0.1, r=2)
    compare.write_report(comparison, tmp_path / "report")
    text = (tmp_path / "report" / "metrics.json").read_text()
    metrics = json.loads(text, parse_constant=lambda name: pytest.fail(f"{name} in metrics.json"))
    unused, mass = metrics["per_output"]["unused"], metrics["per_output"]["mass"]
    assert unused["relative_max"] is None and unused["absolute_max"] == pytest.approx(1e-3)
    assert mass["relative_max_variation"] is None and mass["relative_max"] == 0.0
    assert metrics["per_output"]["y"]["relative_max"] == pytest.approx(0.1, rel=1e-3)
    page = (tmp_path / "report" / "index.html").read_text()
    assert not re.search(r"\bnan\b", page) and "none (the output is constant)" in page


def test_a_report_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    """A full disk while the last file is written leaves the earlier report as it was, and no temporary file
    (eleventh audit: the new figures and metrics sat beside the old page)."""
    import errno
    import os

    from fmu_opinf._hdf5 import replace_together
    from fmu_opinf.errors import FmuOpinfError

    earlier = {"outputs.png": b"old png", "metrics.json": b"{}", "index.html": b"<p>old</p>"}
    for name, data in earlier.items():
        (tmp_path / name).write_bytes(data)
    real_fdopen = os.fdopen

    def full_disk_at_the_page(fd, *args, **kwargs):
        handle = real_fdopen(fd, *args, **kwargs)
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith("index.html."):
            handle.close()
            raise OSError(errno.ENOSPC, "No space left on device")
        return handle

    monkeypatch.setattr(os, "fdopen", full_disk_at_the_page)
    with pytest.raises(FmuOpinfError, match="disk is full"):
        replace_together(tmp_path, {name: b"new " + data for name, data in earlier.items()})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == earlier
    monkeypatch.setattr(os, "fdopen", real_fdopen)
    replace_together(tmp_path, {name: b"new " + data for name, data in earlier.items()})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == {n: b"new " + d for n, d in earlier.items()}


# ------------------------------------------------------------------------------------------- default test input

def _oscillators(frequencies, damping_ratio, inputs, training, dt=0.01, t_end=40.0):
    """A ROM of decoupled oscillators (``Mr = I``), each input on every mode, outputs the positions; its
    provenance says it was trained on ``training`` (one spec per run) over ``dt``, ``t_end``."""
    omega = np.asarray(frequencies, dtype=float)
    r = omega.size
    B = np.ones((r, inputs)) + np.arange(inputs)[None, :]
    runs = [{"input_spec": spec, "dt": dt, "t0": 0.0, "t_end": t_end} for spec in training]
    return rom.SecondOrderROM(np.eye(r), np.diag(2 * damping_ratio * omega), np.diag(omega ** 2), B, np.eye(r),
                              np.zeros((r, r)), dt=dt, provenance={"training_runs": runs, "t_train_end": t_end})


def _exact_outputs(model, spec, dt, t_end):
    """Outputs (positions) of an oscillator ROM under the held input, by the matrix exponential (Van Loan)."""
    import scipy.linalg

    from fmu_opinf.signals import parse_signal

    r, m = model.r, model.m
    t = np.arange(round(t_end / dt) + 1) * dt
    u = parse_signal(spec, m).sample(t)
    block = np.zeros((2 * r + m, 2 * r + m))
    block[:r, r:2 * r] = np.eye(r)
    block[r:2 * r, :r], block[r:2 * r, r:2 * r], block[r:2 * r, 2 * r:] = -model.Kr, -model.Dr, model.Br
    step = scipy.linalg.expm(block * dt)
    z, out = np.zeros(2 * r), [np.zeros(r)]
    for i in range(t.size - 1):
        z = step[:2 * r, :2 * r] @ z + step[:2 * r, 2 * r:] @ u[:, i]
        out.append(z[:r].copy())
    return np.array(out).T


@pytest.mark.parametrize("frequencies, damping_ratio, inputs", [
    ([10.0], 0.025, 1),                  # audit 50: the one mode driven at resonance, 13x the training peak
    ([10.0], 0.0, 1),                    # undamped: at resonance it grows without bound (181x)
    ([1.0, 31.6, 1000.0], 0.005, 3),     # wide band, three inputs: one at 0.995 rad/s beside the mode at 1 (323x)
    ([2.0, 3.0, 4.5], 0.02, 2),          # close modes
    ([10.0, 10.05], 0.001, 2),           # audit 51: two modes closer than their resonance peaks
    ([0.0, 14.1], 0.02, 1),              # audit 51: a free body beside a mode drifted 2 to 9 times past the training
    ([0.0], 0.0, 1),                     # audit 51: a free mass alone, 18 times
])
def test_the_default_test_input_stays_off_resonance_and_within_the_training_range(frequencies, damping_ratio,
                                                                                  inputs):
    """The training pulse's height as the amplitude of a harmonic at the geometric mean of the ROM's band drove
    models 13 to 323 times past their training peak and crashed an FMU that asserts a range (audit 50).  The
    test harmonics now lie in the widest gap between the natural frequencies (below a single one), apart from
    each other, at amplitudes whose response stays within the training peak.  Reference: the exact response of
    the oscillators (matrix exponential), to the training pulses and to the chosen input."""
    from fmu_opinf._test_input import default_test_input
    from fmu_opinf.signals import parse_signal

    pulse = "impulse:amplitude=100,t0=1,width=0.5"
    training = [";".join(pulse if j == i else "none" for j in range(inputs)) for i in range(inputs)]
    model = _oscillators(frequencies, damping_ratio, inputs, training)
    spec, why = default_test_input(model, 0.01, 160.0)
    signal = parse_signal(spec, inputs)
    omegas = [part.params["omega"] for part in (signal.parts if inputs > 1 else [signal])]
    assert len(set(omegas)) == inputs
    modes = [f for f in frequencies if f > 0]
    assert min([abs(np.log(w / f)) for w in omegas for f in modes] + [1.0]) > np.log(1.15)   # measured >= log 1.2
    trained = np.max([np.abs(_exact_outputs(model, run, 0.01, 40.0)).max(axis=1) for run in training], axis=0)
    ratios = np.abs(_exact_outputs(model, spec, 0.01, 160.0)).max(axis=1) / trained   # per output
    assert ratios.max() <= 0.6, (spec, ratios)    # measured 0.36 .. 0.50: half the training peak, to the 3 digits
    assert ratios.max() >= 0.3, (spec, ratios)    # and still a test of the range it was trained in
    assert "its response in the ROM within half of the outputs' training peak" in why


def test_the_default_test_frequency_of_a_rigid_rom_has_periods_in_the_window():
    """A rigid-body ROM (natural frequencies 0 and 1e-9 rad/s) got a test harmonic of 1e-9 rad/s, a constant over
    the comparison: it now has 4 periods in the window at least."""
    from fmu_opinf._test_input import default_test_input
    from fmu_opinf.signals import parse_signal

    model = _oscillators([1e-9, 1e-7], 0.0, 1, ["impulse:amplitude=5,t0=1,width=0.5"])
    spec, why = default_test_input(model, 0.1, 100.0)
    assert parse_signal(spec).params["omega"] >= 2 * np.pi * 4 / 100.0
    assert why.startswith("a harmonic at the slowest frequency with 4 periods in the comparison, a cosine")


def test_a_training_that_drove_no_input_is_compared_on_the_free_response():
    from fmu_opinf._test_input import default_test_input

    model = _oscillators([1.0, 2.0], 0.01, 2, ["none", "none;none"])
    assert default_test_input(model, 0.1, 100.0) == (
        "none", "the training drove no input: the free response from the source's start, as trained")


@pytest.mark.slow  # 13 s in the fast set of 2026-12-06 (idle 2-core machine)
def test_compare_without_an_input_drives_each_trained_input_with_a_harmonic(tmp_path, capsys, monkeypatch):
    """``compare`` stopped without ``--input`` ("no test input given") on every ROM with inputs.  It now takes a
    harmonic (the paper's test input) on each input the training drove, on the operating point it was trained on,
    within the outputs' training range, and says so.  The FMU's side is checked against the exact response of
    the model to that input, so the input said is the one applied; the exported ROM FMU chooses the same input
    from its provenance.json."""
    from fmu_opinf import _test_input, lti_fmus
    from fmu_opinf.export import export_fmu
    from fmu_opinf.signals import parse_signal

    model = lti_fmus.chain_model(4, inputs=(0, 3), x0=[0.0] * 4, name="TwoForces")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "two.fmu", interfaces=("cs",))
    training = ["impulse:amplitude=3,t0=1,width=0.5;none", "none;impulse:amplitude=-7,t0=1,width=0.5,offset=2"]
    snapshots.record_to_file(str(fmu.path), tmp_path / "train.h5", training, dt=0.05, t_end=60.0, quiet=True)
    recorded = snapshots.Snapshots.load(tmp_path / "train.h5")
    fitted = fit_rom(recorded, r=4)
    fitted.save(tmp_path / "rom.h5")
    capsys.readouterr()
    trained = max(np.abs(run.y - run.y[:, :1]).max() for run in recorded.runs)

    # the offset's step from rest goes on past the 60 s of training: over the 240 s compared it alone takes y[1] to
    # 1.2 times its training peak, which the line says, and the warning names the offsets as the cause; harmonics
    # shifted in phase swing against it (before 2026-12-06 their phase was 0, no room was left and their
    # amplitudes were 0, below)
    with pytest.warns(FmuOpinfWarning, match=r"two.fmu's y\[1\] went to 1.13 times its largest departure in the "
                                             r"training; the input's offsets take it there in the ROM too"):
        result = compare.compare(tmp_path / "rom.h5", fmu.path)
    said = capsys.readouterr().err
    assert ("where the offsets alone take the outputs, 1.2 times it over this comparison (a shorter --t-end or "
            "t_end= keeps them nearer)") in said
    first, alone = said.rstrip().splitlines()[-2:]   # (then each input alone: tests/test_compare_each_input.py)
    assert first.endswith("its phase shifted to let it swing wider)")
    assert alone.startswith("then each of F[1], F[2] alone (2 more runs of the source")
    signal = parse_signal(result.input_spec, 2)
    assert [part.kind for part in signal.parts] == ["harmonic", "harmonic"]
    assert [part.params["offset"] for part in signal.parts] == [0.0, 2.0]
    assert min(part.params["amplitude"] for part in signal.parts) >= 1.0   # measured 1.1 and 2.58 (of 3 and 7)
    assert said.startswith("no --input or signal= given: comparing on harmonic:amplitude=")
    assert "(a harmonic on each input the training drove, in the widest gap between the ROM's natural frequencies" \
           in said
    u = signal.sample(result.t)
    exact = lti_fmus.zoh_response(model, result.t, u[:, :-1]).y
    assert np.abs(result.y_fom - exact).max() < 1e-10 * np.abs(exact).max()
    from fmu_opinf._test_input import recorded_peaks   # (fit records the source's peaks; before, the ROM's guess)
    assert recorded_peaks(fitted.provenance, 2).tolist() == np.max(
        [np.abs(run.y - run.y[:, :1]).max(axis=1) for run in recorded.runs], axis=0).tolist()
    assert np.abs(exact - exact[:, :1]).max() <= 1.2 * trained   # measured 1.13 (the offsets' own reach: 1.18)
    assert result.metrics()["max_error"] < 1e-20   # the ROM is exact for these data (r = n)
    assert result.metrics()["input_choice"].startswith("chosen without --input or signal=: a harmonic on each input")
    page = compare.write_report(result, tmp_path / "report")
    assert "chosen without --input or signal=: a harmonic on each input" in page.read_text()
    assert result.metrics()["input_choice"].endswith("y[1] went to 1.13 times its largest departure in the training; "
                                                     "the input's offsets take it there in the ROM too: a shorter "
                                                     "--t-end or t_end= keeps them nearer")
    exported = export_fmu(fitted, tmp_path / "rom.fmu")
    with pytest.warns(FmuOpinfWarning, match=r"y\[1\] went to 1.13 times"):   # (audit 53: not said for an FMU)
        assert compare.compare(exported, fmu.path, quiet=True).input_spec == result.input_spec

    # without the phase shifts (the choice before 2026-12-06) the harmonics get no amplitude, and the offsets alone
    # take the source to 1.18 times its training peak
    monkeypatch.setattr(_test_input, "_PHASE_SHIFTS", (0.0,))
    with pytest.warns(FmuOpinfWarning, match=r"two.fmu's y\[1\] went to 1.18 times"):
        unshifted = parse_signal(compare.compare(tmp_path / "rom.h5", fmu.path, quiet=True).input_spec, 2)
    assert [part.params["amplitude"] for part in unshifted.parts] == [0.0, 0.0]


@pytest.mark.slow  # 7 s in the fast set of 2026-12-06
def test_compare_without_an_input_after_a_table_training_names_the_fix(tmp_path):
    """A table the training read gives the test its amplitude while it is at hand; once it is gone, nothing sizes
    a test input: one line, the fix, exit code 2, no report."""
    from test_cli import run_cli

    table = tmp_path / "push.csv"
    table.write_text("t,u\n0,0\n1,5\n2,0\n100,0\n")
    snaps = snapshots.record("builtin:anchored-msd", str(table), 0.5, 60.0, quiet=True)
    fit_rom(snaps, r=4).save(tmp_path / "rom.h5")
    done = run_cli("compare", str(tmp_path / "rom.h5"), "builtin:anchored-msd", "-o", str(tmp_path / "report"))
    assert done.returncode == 0 and "no --input or signal= given: comparing on harmonic:amplitude=" in done.stderr
    table.unlink()
    done = run_cli("compare", str(tmp_path / "rom.h5"), "builtin:anchored-msd", "-o", str(tmp_path / "other"))
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == (
        f"fmu-opinf: error: no test input given, and the training input {str(table)!r} cannot be read here (input "
        f"table {table} not found; give an existing .csv file); pass a test input, e.g. --input "
        "\"harmonic:amplitude=1,omega=0.2\" or signal='harmonic:amplitude=1,omega=0.2'")
    assert not (tmp_path / "other").exists()


@pytest.mark.slow  # 4 s: builds an FMU, records, fits and compares twice
def test_a_preload_force_is_trained_and_compared_on_top_of_its_start_value(tmp_path):
    """An input in N that starts at 10 N beside a dimensionless stiffness scale exposed as an input (audit of
    2026-12-06): the defaults held both, so the ROM had no port for the force, the warning offered to drive the
    stiffness, and ``compare`` set a ``none`` input to 0, away from the 10 N the source and the exported ROM FMU
    start at.  Now the force is driven on top of its start, the scale alone is held (and not offered), and
    ``compare`` holds a ``none`` input at its start value.  References: the exact response of the model to the
    inputs as stated."""
    from conftest import rewrite_description

    from fmu_opinf import lti_fmus
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.signals import parse_signal

    model = lti_fmus.chain_model(name="Preloaded")
    built = lti_fmus.build_lti_fmu(model, tmp_path / "built.fmu", interfaces=("cs",),
                                   parameter_inputs=("stiffness_scale",))
    fmu = rewrite_description(built.path, tmp_path / "preloaded.fmu",
                              lambda text: text.replace('<Real unit="N" start="0.0"/>', '<Real unit="N" start="10"/>'))
    with pytest.warns(FmuOpinfWarning, match=r"input\(s\) stiffness_scale start at non-zero values") as seen:
        snapshots.record_to_file(str(fmu), tmp_path / "train.h5", None, dt=0.1, t_end=60.0, quiet=True)
    assert not [w for w in seen if "--inputs" in str(w.message)]   # a scale in unit "1" is no force to drive
    run = snapshots.Snapshots.load(tmp_path / "train.h5").runs[0]
    assert run.attrs["input_spec"] == "impulse:amplitude=100,t0=2,width=0.5,offset=10"
    fitted = fit_rom(snapshots.Snapshots.load(tmp_path / "train.h5"), r=model.M.shape[0])
    assert fitted.input_names == ["F"]
    fitted.save(tmp_path / "rom.h5")

    for given in (None, "none"):
        result = compare.compare(tmp_path / "rom.h5", fmu, given, quiet=True)
        held = parse_signal(result.input_spec, 1).sample(result.t) if given is None else np.full((1, result.t.size),
                                                                                                   10.0)
        if given is None:
            assert result.input_spec.startswith("harmonic:amplitude=") and result.input_spec.endswith("offset=10")
        exact = lti_fmus.zoh_response(model, result.t, held[:, :-1]).y
        assert np.abs(result.y_fom - exact).max() < 1e-10 * np.abs(exact).max(), given
        assert result.metrics()["max_error"] < 1e-20, given
    with warnings.catch_warnings():   # a ROM input's start is not a setting the ROM was trained with (audit 50)
        warnings.simplefilter("error", FmuOpinfWarning)
        result = compare.compare(tmp_path / "rom.h5", fmu, "none", quiet=True, source_options={"parameters": {"F": 20}})
    exact = lti_fmus.zoh_response(model, result.t, np.full((1, result.t.size - 1), 20.0)).y
    assert np.abs(result.y_fom - exact).max() < 1e-10 * np.abs(exact).max()
    assert result.metrics()["max_error"] < 1e-20




def test_a_rom_whose_training_runs_cannot_be_simulated_keeps_the_training_amplitude():
    """Training runs recorded without their grid (older files) give no training peak to size the test by: the
    training amplitude stays (this path raised TypeError in review)."""
    from fmu_opinf._test_input import default_test_input

    model = _oscillators([1.0, 3.0], 0.01, 1, ["impulse:amplitude=7,t0=1,width=0.5"])
    model.provenance["training_runs"] = [{"input_spec": "impulse:amplitude=7,t0=1,width=0.5"}]
    spec, why = default_test_input(model, 0.1, 100.0)
    assert spec.startswith("harmonic:amplitude=7,omega=")
    assert why.endswith("at the training amplitude (no training peak is known to size it by: a fit of today records "
                        "them)")


@pytest.mark.slow  # 3 s: exports a ROM FMU
def test_a_damaged_or_hostile_rom_file_gives_one_line_errors(anchored_rom, tmp_path):
    """Audit 51 edited the provenance of ROM files: a test input carried by a ROM FMU that names a local table (read
    and quoted) or holds 100,000 parts (printed twice), a provenance nested past Python's recursion limit, a training
    end of NaN or 1e15 s: tracebacks, memory errors, a file's line in a message.  Each is now one line naming the
    fix.  The carried input also says it was chosen for the FMU's own grid, and is refused on a grid that does not
    resolve it."""
    import zipfile

    from fmu_opinf.export import export_fmu

    model, path = anchored_rom
    exported = export_fmu(model, tmp_path / "rom.fmu")

    def with_provenance(edit, name):
        target = tmp_path / name
        with zipfile.ZipFile(exported) as zin, zipfile.ZipFile(target, "w") as zout:
            for item in zin.infolist():
                data = zin.read(item.filename)
                if item.filename.endswith("provenance.json"):
                    data = edit(json.loads(data))
                    data = data if isinstance(data, bytes) else json.dumps(data).encode()
                zout.writestr(item, data)
        return target

    carried = json.loads(zipfile.ZipFile(exported).read(
        next(n for n in zipfile.ZipFile(exported).namelist() if n.endswith("provenance.json"))))["default_test_input"]
    result = compare.compare(exported, "builtin:anchored-msd", quiet=True)
    assert result.input_spec == compare.compare(path, "builtin:anchored-msd", quiet=True).input_spec
    (tmp_path / "secret.csv").write_text("t,u\nhunter2,1\n")
    cases = {
        "table": (lambda p: {**p, "default_test_input": [str(tmp_path / "secret.csv"), "x"]}, {}, "is not a harmonic"),
        "many": (lambda p: {**p, "default_test_input": [";".join(["none"] * 100_000), "x"]}, {}, "is not a harmonic"),
        "grid": (lambda p: p, {"dt": 0.5, "t_end": 20.0}, "was chosen for its own step and training end"),
        "nested": (lambda p: b'{"a": ' * 100_000 + b"1" + b"}" * 100_000, {}, "does not record a usable training"),
        "nan end": (lambda p: {**p, "t_train_end": "nan"}, {}, "does not record a usable training end"),
        "huge end": (lambda p: {**p, "t_train_end": 1e15}, {}, "does not record a usable training end"),
    }
    for name, (edit, grid, expected) in cases.items():
        with pytest.raises(FmuOpinfError, match=expected) as info:
            compare.compare(with_provenance(edit, f"{name}.fmu"), "builtin:anchored-msd", quiet=True, **grid)
        assert "\n" not in str(info.value) and "hunter2" not in str(info.value) and len(str(info.value)) < 400, name
    with pytest.raises(DimensionError, match="more than 1e\\+08; pass a shorter --t-end"):
        compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=1e15, quiet=True)
    assert carried[1].startswith("a harmonic")


def test_the_default_test_input_counts_the_offsets_step_response():
    """Audit 52: trained on a step from 50 to -10 (offset 50), the test harmonic on the offset 50 was sized without
    the offset's own step response from rest, and said to stay within half the training peak.  The sizing now
    simulates the whole input and says how far the offsets alone go.  Reference: the exact response of the
    oscillators."""
    from fmu_opinf._test_input import default_test_input

    training = ["step:amplitude=-60,t0=5,offset=50"]
    model = _oscillators([1.0, 3.0], 0.05, 1, training, t_end=30.0)
    spec, why = default_test_input(model, 0.01, 120.0)
    trained = np.abs(_exact_outputs(model, training[0], 0.01, 30.0)).max(axis=1)
    ratios = np.abs(_exact_outputs(model, spec, 0.01, 120.0)).max(axis=1) / trained
    # the training began with the offset's step from rest, which alone reaches the training peak (before, unsized
    # by the offsets, 1.29 on the source; audit 53: with half the peak on top of the offsets, 1.3); a harmonic in
    # phase with the step's overshoot got no amplitude at all, one shifted in phase swings against it
    assert spec.endswith(",offset=50") and ratios.max() <= 1.0 + 1e-6, (spec, ratios)   # measured 1.0 / 1.0
    assert "within the training peak or where the offsets alone take the outputs, 1 times it" in why
    assert why.endswith("its phase shifted to let it swing wider")
    offsets_alone = _exact_outputs(model, re.sub(r"amplitude=[0-9.e-]+", "amplitude=0", spec), 0.01, 120.0)
    swing = np.abs(_exact_outputs(model, spec, 0.01, 120.0) - offsets_alone).max(axis=1) / trained
    assert swing.max() >= 0.1, (spec, swing)   # measured 0.086 / 0.15 (amplitude 6.81 of 60; unshifted: 0)


@pytest.mark.parametrize("low, high", [(0.0, 30.0), (-30.0, 0.0), (-4.0, 6.0)])
def test_the_default_test_input_stays_within_the_declared_input_range(low, high):
    """Audit 60: the exported ROM FMU refuses inputs outside the source's declared range, and compare's default
    harmonic about the training's 0 took a push-only input in [0, 30] to -0.58, so compare failed.  The offsets
    move as little as the swing needs, and the response stays within half the training peak or where the offsets'
    own step response from rest takes it.  Reference: the exact response of the oscillators."""
    from fmu_opinf._test_input import default_test_input
    from fmu_opinf.signals import parse_signal

    training = ["impulse:amplitude=30,t0=2,width=0.5" if high > 0 else "impulse:amplitude=-30,t0=2,width=0.5"]
    model = _oscillators([1.0, 3.0], 0.05, 1, training, t_end=40.0)
    model.provenance["snapshots"] = {"input_min": [low], "input_max": [high]}
    spec, why = default_test_input(model, 0.01, 160.0)
    u = parse_signal(spec, 1).sample(np.arange(16001) * 0.01)
    assert low <= u.min() and u.max() <= high, (spec, u.min(), u.max())
    assert u.max() - u.min() >= 2.0, spec   # it still swings (measured 4.1 / 4.9 / 7.7)
    trained = np.abs(_exact_outputs(model, training[0], 0.01, 40.0)).max(axis=1)
    ratios = np.abs(_exact_outputs(model, spec, 0.01, 160.0)).max(axis=1) / trained
    offsets_alone = _exact_outputs(model, re.sub(r"amplitude=[0-9.e-]+", "amplitude=0", spec), 0.01, 160.0)
    reach = np.abs(offsets_alone).max(axis=1) / trained
    # measured 0.54 / 0.64 / 0.48 (the offsets alone 0.55 / 0.65 / 0)
    assert np.all(ratios <= np.maximum(0.5, reach) + 1e-6), (spec, ratios, reach)
    assert ("within its declared range" in why) == (low == 0.0 or high == 0.0), why


def test_where_moved_offsets_alone_pass_the_limit_the_swing_shrinks_but_never_to_zero(monkeypatch):
    """Audit 61: the offset a push-only input needs drove a rigid-body ROM away, the sizing scaled the swing to 0,
    and then every input was 0 (compare: "the reference output is identically zero").  Here every moved offset
    passes the limit: the swing shrinks by a quarter a round and stays within the range."""
    from fmu_opinf import _test_input
    from fmu_opinf.signals import parse_signal

    def sizing(rom, waves, amplitudes, dt, t_end, rigid):   # a rigid body's drift under any offset: no swing fits
        return (0.0 if any(wave["offset"] for wave in waves.values()) else 1.0), 0.0, 0.0

    monkeypatch.setattr(_test_input, "_scale_to_training_range", sizing)
    model = _oscillators([0.0, 30.0], 0.05, 1, ["impulse:amplitude=5,t0=2,width=0.5"], t_end=10.0)
    model.provenance["snapshots"] = {"input_min": [0.0], "input_max": [5.0]}
    spec, _ = _test_input.default_test_input(model, 0.01, 10.0)
    u = parse_signal(spec, 1).sample(np.arange(1001) * 0.01)
    assert 0.0 <= u.min() and u.max() <= 5.0 and np.ptp(u) > 0.05, spec   # amplitude 2.5 / 4 ** 3 = 0.039


def test_the_default_harmonic_swings_a_pressure_by_at_most_half_its_start():
    """Audit 61, finding 3: trained by a pulse of 100 about 1 bar, the default harmonic swung an absolute pressure
    by 19.4 about 1 bar, down to -18.4 bar.  A pressure's harmonic (by its recorded unit, also one the recording's
    unit definitions define) swings by at most half of its offset; a force beside it keeps its training amplitude.
    Reference: the bounds 0.5 and 1.5 bar and 1 +- 0.5 of the defined unit, written by hand."""
    from fmu_opinf._test_input import default_test_input
    from fmu_opinf.signals import parse_signal

    training = ["impulse:amplitude=100,t0=2,width=0.5;none;none",
                "none;impulse:amplitude=100,t0=2,width=0.5,offset=1;none",
                "none;none;impulse:amplitude=100,t0=2,width=0.5,offset=1"]
    model = _oscillators([10.0, 30.0, 90.0], 0.05, 3, training, t_end=10.0)
    model.provenance["snapshots"] = {"input_units": ["N", "bar", "p_unit"],
                                     "unit_definitions": {"p_unit": {"base": {"kg": 1, "m": -1, "s": -2}}}}
    spec, why = default_test_input(model, 0.001, 40.0)
    u = parse_signal(spec, 3).sample(np.arange(40001) * 0.001)
    assert 0.5 <= u[1].min() and u[1].max() <= 1.5 and 0.5 <= u[2].min() and u[2].max() <= 1.5, spec
    assert np.ptp(u[1]) > 0.1 and np.ptp(u[2]) > 0.1, spec   # (they still swing)
    assert "u[2], u[3] by at most half of its offset (a pressure)" in why, why


def test_an_offset_moved_to_a_bound_is_written_rounded_towards_the_inside(monkeypatch):
    """Audit 61, finding 7: an offset moved just inside a declared range printed as offset=3.9800000000000004,
    because its six digits (3.98) fell an ulp outside.  It is rounded towards the inside of the range instead.
    Reference: the offset the range needs, -2 + 5.98 (written out by hand), and the range itself."""
    from fmu_opinf import _test_input
    from fmu_opinf.signals import parse_signal

    monkeypatch.setattr(_test_input, "_scale_to_training_range", lambda *args: (1.0, 0.0, 0.0))
    model = _oscillators([1.0, 3.0], 0.05, 1, ["impulse:amplitude=5.98,t0=2,width=0.5"], t_end=10.0)
    model.provenance["snapshots"] = {"input_min": [-2.0], "input_max": [50.0]}
    spec, why = _test_input.default_test_input(model, 0.01, 40.0)
    assert parse_signal(spec, 1).params["offset"] == 3.98001, spec   # before: 3.9800000059800003
    assert spec.endswith(",offset=3.98001") and "u[1] about 3.98001 within" in why, (spec, why)
    u = parse_signal(spec, 1).sample(np.arange(4001) * 0.01)
    assert -2.0 <= u.min() and u.max() <= 50.0, (u.min(), u.max())


@pytest.mark.parametrize("value, low, high, expected", [
    (3.9800000000000004, 3.9800000000000004, 30.0, 3.98001),   # the nearest six digits fall below: up
    (29.99999999, 0.0, 29.99999999, 29.9999),                  # above: down
    (-1.999999999, -1.999999999, 5.0, -1.99999),               # a negative bound
    (12.3456789, 0.0, 30.0, 12.3457),                          # inside: the nearest
    (1.23456789, 1.2345678, 1.2345679, 1.2345679),             # narrower than the sixth digit: more digits
])
def test_six_digits_round_towards_the_inside_of_the_range(value, low, high, expected):
    from fmu_opinf._test_input import _six_digits_inside

    assert _six_digits_inside(value, low, high) == expected


def test_a_carried_cosine_is_centred_on_the_comparison_s_steps():
    """Audit 52: a ROM FMU's carried cosine kept the phase of the export's step; at another --dt a free body drifted
    (2.1 times its training peak at t_end 1000).  The phase is made for the comparison's step.  Reference: the
    exact response of a free mass to either input."""
    from fmu_opinf._test_input import carried_for_grid, cosine_phase
    from fmu_opinf.signals import parse_signal

    carried = f"harmonic:amplitude=100,omega=9.13,phase={cosine_phase(9.13, 0.01)!r},offset=2"
    recentred = carried_for_grid(carried, "rom.fmu", 1, 0.02, 1000.0)
    params = parse_signal(recentred).params
    assert params == {"amplitude": 100.0, "omega": 9.13, "phase": pytest.approx(np.pi / 2 + 9.13 * 0.01, abs=1e-9),
                      "offset": 2.0}
    # a free unit mass under each, held at dt = 0.02 for 1000 s (exact response; offsets left out: they push it)
    free = _oscillators([0.0], 0.0, 1, ["none"], dt=0.02)
    drift = [np.abs(_exact_outputs(free, re.sub(r",offset=[0-9.]+", "", spec), 0.02, 1000.0)).max()
             for spec in (carried, recentred)]
    assert drift[1] < 0.01 * drift[0], drift   # measured 2.4 against 503
    # a cosine turned by half a turn (the sizing's shift for a rigid-body ROM) keeps its turn; a harmonic shifted
    # by any other phase is no cosine and keeps its phase
    turned = carried.replace(f"phase={cosine_phase(9.13, 0.01)!r}", f"phase={cosine_phase(9.13, 0.01) + np.pi!r}")
    assert parse_signal(carried_for_grid(turned, "rom.fmu", 1, 0.02, 1000.0)).params["phase"] == pytest.approx(
        3 * np.pi / 2 + 9.13 * 0.01, abs=1e-9)
    shifted = carried.replace(f"phase={cosine_phase(9.13, 0.01)!r}", "phase=1.3744")
    assert parse_signal(carried_for_grid(shifted, "rom.fmu", 1, 0.02, 1000.0)).params["phase"] == 1.3744


def test_error_figures_of_outputs_near_the_top_of_the_floating_point_range_are_finite():
    """Audit 68: outputs of about 1e160 overflowed when squared, and compare printed eps_y = nan with exit code 0.
    A ROM 0.1 % off everywhere has eq. (19) 1e-6 and relative errors 1e-3 at any scale."""
    from fmu_opinf.compare import error_metrics

    t = np.linspace(0.0, 6 * np.pi, 600, endpoint=False)   # whole periods: the outputs' means are 0
    for size in (1.0, 1e160, 1e300):
        y_ref = size * np.vstack([np.sin(t), 2 * np.cos(t)])
        metrics = error_metrics(y_ref, 1.001 * y_ref)
        assert metrics["max_error"] == pytest.approx(1e-6, rel=1e-9), size
        assert metrics["l2_error"] == pytest.approx(1e-3, rel=1e-9), size
        assert metrics["max_error_variation"] == pytest.approx(1e-6, rel=1e-9), size
        first = metrics["per_output"]["y[1]"]
        assert first["relative_max"] == pytest.approx(1e-3, rel=1e-9), size
        assert first["absolute_max"] == pytest.approx(1e-3 * size, rel=1e-6), size


def test_an_exported_rom_fmu_carries_how_its_order_was_chosen():
    """Audit 69, F6: ``compare`` on a ROM FMU gave no order note, since the FMU did not carry the fit's report.  The
    export writes :func:`compare._training._order_chosen` of the ROM into provenance.json, and compare takes it back
    only in that form (a data file)."""
    from fmu_opinf.compare import _training
    from fmu_opinf.export import rom_fmu_spec
    from fmu_opinf.rom import SecondOrderROM

    search = [{"r": 4, "judged": 0.97}, {"r": 8, "judged": 0.9}, {"r": 16, "judged": 0.05}]
    rom = SecondOrderROM(np.eye(2), 0.1 * np.eye(2), np.diag([1.0, 4.0]), np.ones((2, 1)), np.ones((1, 2)),
                         np.zeros((1, 2)), dt=0.1, provenance={"fit_settings": {"r": None}},
                         fit_info={"snapshot_rank": 30, "order_search": search})
    carried = json.loads(rom_fmu_spec(rom, "Order").extra_files["provenance.json"])["rom_fmu_order"]
    expected = {"r": 2, "chosen": "search", "snapshot_rank": 30, "tried": [4, 8, 16]}
    assert carried == expected and _training._carried_order({"rom_fmu_order": carried}) == expected
    off = {"per_output": {"y[1]": {"relative_max_variation": 0.2}}}
    assert "the fit's order search kept r=2 (tried r=4, 8, 16) on snapshots of rank 30" in compare.order_note(
        {**off, "order": _training._carried_order({"rom_fmu_order": carried})})
    for bad in ({**expected, "r": "2; rm -rf"}, {**expected, "chosen": "<script>"}, {**expected, "tried": [True]},
                {**expected, "snapshot_rank": -1}, [expected], None):
        assert _training._carried_order({"rom_fmu_order": bad}) == {}, bad


def test_compare_on_an_exported_rom_fmu_reads_what_the_fit_found(tmp_path):
    """The exported FMU's provenance.json carried the fit's order, linear fits and own motion, but compare's reading of
    the FMU kept only a few named keys and dropped them: the order note (audit 69 F6), the linear-fit note (77a F1)
    and the free-response row (77b F2) never appeared for an FMU.  Read back from a built FMU file."""
    from pathlib import Path

    from fmu_opinf.compare import _training
    from fmu_opinf.export import export_fmu
    from fmu_opinf.rom import SecondOrderROM

    search = [{"r": 4, "judged": 0.97}, {"r": 16, "judged": 0.05}]
    rom = SecondOrderROM(np.eye(2), 0.1 * np.eye(2), np.diag([1.0, 4.0]), np.ones((2, 1)), np.ones((2, 2)),
                         np.zeros((2, 2)), dt=0.1, provenance={"fit_settings": {"r": None}},
                         output_names=["x", "E"],
                         fit_info={"snapshot_rank": 30, "order_search": search, "own_motion": {"spans": [1.0]},
                                   "nonlinear_outputs": {"left_out": True, "names": ["E"]}})
    path = export_fmu(rom, tmp_path / "rom.fmu")
    provenance = compare._sides._rom_side_info(Path(path))["provenance"]
    assert provenance["rom_fmu_order"] == {"r": 2, "chosen": "search", "snapshot_rank": 30, "tried": [4, 16]}
    assert provenance["rom_fmu_linear_fits"] == ["E"] and provenance["rom_fmu_moves_on_its_own"] is True
    info = compare._sides._rom_side_info(Path(path))
    assert _training._carried_linear_fits(info) == ["E"] and compare.moves_on_its_own(Path(path), info)


def test_summary_table_columns_stay_aligned_under_a_long_case_name():
    """The band run's row ("ROM, top of the training band", 29 characters and more) pushed its figures one column
    right of the header's under a fixed 28-character case column."""
    metrics = {"r": 3, "max_error": 1e-3, "l2_error": 1e-2, "fom_seconds": 1.0, "rom_seconds": 0.1, "speedup": 10.0}
    names = ["ROM", "ROM, top of the training band (2.67 rad/s)"]
    lines = compare.summary_table([(name, metrics) for name in names]).splitlines()
    header, rows = lines[0], lines[2:4]
    ends = {line.index(" r ") + 2 if line is header else line.index(" 3 ") + 2 for line in [header, *rows]}
    assert len(ends) == 1 and all(len(row) == len(header) for row in rows), lines[:4]
