"""Without a C compiler the demo says up front what it skips and runs the rest on the reference simulator."""

import json

import pytest

from fmu_opinf import cli, fmus


def test_demo_without_compiler_skips_fmus_and_export_and_runs_the_rest(tmp_path, monkeypatch, capsys):
    def no_compiling(*args, **kwargs):
        raise AssertionError("the demo tried to compile an FMU although no compiler was found")

    monkeypatch.setattr(fmus, "find_build_tools", lambda: None)
    monkeypatch.setattr(fmus, "build_second_order_fmu", no_compiling)
    out = tmp_path / "demo"
    assert cli.main(["demo", "-o", str(out), "--quick", "--model", "anchored-msd"]) == 0
    printed = capsys.readouterr().out
    assert printed.index("no C compiler") < printed.index("[anchored-msd]")
    assert "skipping" in printed and "export" in printed
    case = json.loads((out / "summary.json").read_text())["cases"][0]
    assert case["rom_fmu"] is None and not list(out.rglob("*.fmu"))
    # the ROM is still checked against the full-order reference simulator on the test input
    metrics = json.loads((out / "anchored-msd" / "report" / "metrics.json").read_text())
    assert metrics["max_error"] < 1e-4
    assert case["rom"]["max_error"] == pytest.approx(metrics["max_error"])
    assert "not exported" in (out / "index.html").read_text()
