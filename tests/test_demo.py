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
def test_quick_demo_without_the_least_squares_candidate_fits_the_same_rom(demo_dir):
    """--quick leaves the least-squares candidate out to save time; that is only right while the default fit keeps
    the refined SDP solution over the candidate on both models: the default fit gives the same bits."""
    import numpy as np

    from fmu_opinf.rom import SecondOrderROM, fit_rom
    from fmu_opinf.snapshots import Snapshots

    for model, order in (("anchored-msd", None), ("triple-chain", 12)):
        quick = SecondOrderROM.load(demo_dir / model / "rom.h5")
        default = fit_rom(Snapshots.load(demo_dir / model / "snapshots.h5"), r=order, quiet=True)
        assert not default.fit_info["least_squares_candidate"].get("chosen")
        for name in ("Mr", "Dr", "Kr", "Br"):
            assert np.array_equal(getattr(quick, name), getattr(default, name)), (model, name)
