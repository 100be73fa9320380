"""The demo's quick mode runs the whole chain end to end on the bundled FMUs."""

import json

import pytest

from fmu_opinf import cli
from fmu_opinf.fmus import find_build_tools

pytestmark = pytest.mark.skipif(find_build_tools() is None, reason="no C compiler or CMake to build the FMUs")


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert cli.main(["demo", "-o", str(out), "--quick", "--quiet"]) == 0
    return out


@pytest.mark.parametrize("model", ["anchored-msd", "triple-chain"])
@pytest.mark.slow
def test_quick_demo_meets_the_error_bound(demo_dir, model):
    for report in ("report", "report-fmu"):
        metrics = json.loads((demo_dir / model / report / "metrics.json").read_text())
        assert metrics["max_error"] < 1e-4, (model, report, metrics["max_error"])
        assert (demo_dir / model / report / "index.html").is_file()


@pytest.mark.slow
def test_quick_demo_writes_everything(demo_dir):
    summary = json.loads((demo_dir / "summary.json").read_text())
    assert [case["model"] for case in summary["cases"]] == ["anchored-msd", "triple-chain"]
    for case in summary["cases"]:
        folder = demo_dir / case["model"]
        for name in ("snapshots.h5", "rom.h5", "report/outputs.png", "report/error.png"):
            assert (folder / name).is_file(), name
        assert list(folder.glob("*ROM.fmu"))
        # the exported FMU reproduces the Python ROM: their errors against the FMU agree
        assert case["rom_fmu"]["max_error"] == pytest.approx(case["rom"]["max_error"], rel=1e-6, abs=1e-14)
    assert "demo" in (demo_dir / "index.html").read_text()


@pytest.mark.slow
def test_quick_demo_without_the_least_squares_candidate_is_as_accurate_as_the_default_fit(demo_dir):
    """--quick leaves the least-squares candidate out to save time.  Where the default fit keeps the refined SDP
    solution, the quick ROM is the same bits (anchored chain); where it keeps the candidate (triple chain r = 12
    since 2026-11-28: training objective 5.39e-7 against 5.50e-7), the quick ROM's max eps_y against the FMU on
    the demo's test input is within 2x of the default's (measured 4.1e-8 against 6.5e-8)."""
    import numpy as np

    from fmu_opinf.compare import compare
    from fmu_opinf.fit import fit_rom
    from fmu_opinf.rom import SecondOrderROM
    from fmu_opinf.snapshots import Snapshots

    summary = {case["model"]: case for case in json.loads((demo_dir / "summary.json").read_text())["cases"]}
    for model, order in (("anchored-msd", None), ("triple-chain", 12)):
        quick = SecondOrderROM.load(demo_dir / model / "rom.h5")
        default = fit_rom(Snapshots.load(demo_dir / model / "snapshots.h5"), r=order, quiet=True)
        if not default.fit_info["least_squares_candidate"].get("chosen"):
            for name in ("Mr", "Dr", "Kr", "Br"):
                assert np.array_equal(getattr(quick, name), getattr(default, name)), (model, name)
            continue
        case = summary[model]["rom"]
        errors = [compare(rom, summary[model]["rom"]["fom"]["source"], case["input"], dt=case["dt"],
                          t_end=case["t_end"], quiet=True).metrics()["max_error"] for rom in (quick, default)]
        assert errors[0] <= 2.0 * errors[1], (model, errors)
