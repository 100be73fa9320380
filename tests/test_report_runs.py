"""The report page shows every run compare made, and its outputs figure stays readable (audit 81c, F9, F10)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from fmu_opinf import compare

T = np.linspace(0.0, 10.0, 201)


def _comparison(off: float, spec: str = "harmonic:amplitude=1,omega=1", **fields) -> compare.Comparison:
    """One output sin(t), the ROM off by the factor ``1 - off``: eq. (19)'s max is ``off**2`` exactly."""
    y = np.sin(T)[None]
    return compare.Comparison(t=T, y_fom=y, y_rom=(1.0 - off) * y, output_names=["y1"], input_spec=spec,
                              fom_seconds=1.0, rom_seconds=0.1, r=2, **fields)


def test_the_page_shows_the_free_response_and_heads_with_the_worst_run(tmp_path):
    """compare ran the free response, printed it and stored it in metrics.json; the page left it out and headed
    with the test input's 0.100 where the free response read 0.73 (audit 81c, F9)."""
    result = _comparison(0.1)
    result.free_response = _comparison(0.5, "none", driven_alone=compare.FREE_RESPONSE)
    page = compare.write_report(result, tmp_path / "report").read_text()
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert metrics["free_response"]["max_error"] == pytest.approx(0.25)
    assert "<h2>Free response</h2>" in page and "max eps_y 0.25; y1 off by 0.25 of its range" in page
    headline = page.split("<h2>Result</h2>")[1].split("</table>")[0]
    assert "max eps_y of all the runs compared" in headline and "0.25, on the free response" in headline


def test_the_headline_names_no_further_run_where_the_test_input_is_worst(tmp_path):
    result = _comparison(0.5)
    result.free_response = _comparison(0.1, "none", driven_alone=compare.FREE_RESPONSE)
    page = compare.write_report(result, tmp_path / "report").read_text()
    assert "<h2>Free response</h2>" in page and "all the runs compared" not in page


LONG = ("Antriebsstrang.Getriebe_Stufe2.Welle[3].Lagerwinkel_φ_Überlast_größer_als_zulässig_bei_Nennlast_und_"
        "Temperatur_über_80_Grad")


def test_long_output_names_keep_their_labels_inside_the_figure_with_units(tmp_path, monkeypatch):
    """A 97-character name ran off the outputs figure's top with its unit, and the next labels overlapped the
    panel above's (audit 81c, F10): every label lies inside the figure, apart from the others, unit included."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    t = np.linspace(0.0, 300.0, 601)
    y = np.vstack([np.sin(0.1 * t), 10 * np.sin(0.2 * t), 100 * np.sin(0.3 * t)])
    names = [LONG, "v<script>alert(1)</script>&amp", "Beschleunigung_Masse_8 a₈"]
    result = compare.Comparison(t=t, y_fom=y, y_rom=0.99 * y, output_names=names, output_units=["rad", "m/s", "m/s2"],
                                input_spec="harmonic:amplitude=1,omega=1", fom_seconds=1.0, rom_seconds=0.1, r=8)
    compare.write_report(result, tmp_path / "report")
    figure = next(fig for fig in kept if len(fig.axes) == 3)
    renderer = figure.canvas.get_renderer()
    inside = figure.bbox
    boxes = [ax.yaxis.label.get_window_extent(renderer) for ax in figure.axes]
    for box in boxes:
        assert inside.x0 <= box.x0 and box.x1 <= inside.x1 and inside.y0 <= box.y0 and box.y1 <= inside.y1
    for upper, lower in itertools.pairwise(boxes):
        assert lower.y1 < upper.y0   # no label reaches into the next one
    texts = [ax.get_ylabel() for ax in figure.axes]
    units = ["[rad]", "[m/s]", "[m/s2]"]
    assert [text.splitlines()[-1].endswith(unit) for text, unit in zip(texts, units)] == [True] * 3
    assert texts[0].startswith("Antriebsstrang") and texts[0].replace("\n", "").count("80_Grad") == 1


def test_short_labels_stay_one_line():
    from fmu_opinf.report import label_lines

    assert label_lines("y[1]", "m") == ["y[1] [m]"] and label_lines("y1") == ["y1"]


@pytest.mark.fmu
@pytest.mark.slow   # 2.2 s: a recording, a fit and a comparison
def test_the_report_is_not_written_into_compares_inputs(tmp_path):
    """``write_report(result, folder)`` where the folder is compare's source (an unpacked FMU) or its ROM file:
    refused in one line naming the keyword, nothing written.  The command line refused both (``check_not_input``);
    before, the function wrote index.html, metrics.json and the two figures into the unpacked FMU, and called the
    ROM file only "an existing file; choose another -o path"."""
    import hashlib
    import zipfile

    from fmu_opinf import lti_fmus, report
    from fmu_opinf.errors import FileFormatError
    from fmu_opinf.fit import fit_rom
    from fmu_opinf.snapshots import record

    fmu = lti_fmus.build_lti_fmu(lti_fmus.chain_model(3, name="Chain3"), tmp_path / "Chain3.fmu").path
    folder, rom_file = tmp_path / "Chain3", tmp_path / "rom.h5"
    zipfile.ZipFile(fmu).extractall(folder)
    fit_rom(record(str(folder), "impulse:amplitude=1,t0=2,width=0.5", 0.05, 30.0, quiet=True), r=3).save(rom_file)
    result = compare.compare(rom_file, folder, "harmonic:amplitude=1,omega=0.9", dt=0.05, t_end=30.0, quiet=True)
    files = {path: hashlib.sha256(path.read_bytes()).digest() for path in (*folder.rglob("*"), rom_file)
             if path.is_file()}
    for target in (folder, rom_file, str(rom_file.relative_to(tmp_path.parent).as_posix())):
        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(tmp_path.parent)
            with pytest.raises(FileFormatError) as refused:
                report.write_report(result, target)
        assert str(refused.value) == (f"report directory {target} is also an input of this call; give out_dir= "
                                      "another path"), refused.value
    assert {path: hashlib.sha256(path.read_bytes()).digest() for path in (*folder.rglob("*"), rom_file)
            if path.is_file()} == files
    assert report.write_report(result, tmp_path / "report").is_file()   # (another folder is written as before)
