"""An FMU that changes the working directory does not move the command's files (audit 81a, F2).

FMI's guide forbids an FMU function to ``chdir``; some exports do it at instantiate.  With ``--in-process`` the
snapshot file named ``-o d.h5`` landed in the FMU's folder, and ``--force`` replaced a file of that name there.  The
FMU here is a corpus FMU whose instantiate is wrapped to change the directory, as such an FMU's does; the recording
is checked against the model's exact zero-order-hold response.
"""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import cli, lti_fmus  # noqa: E402
from fmu_opinf.sources import _cosimulation  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)


@pytest.fixture(scope="module")
def chain(request, tmp_path_factory) -> lti_fmus.LtiFmu:
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    return lti_fmus.build_corpus(folder, ("me-only",))["me-only"]


@pytest.fixture
def moving_fmu(monkeypatch, tmp_path):
    """FMU instances change into ``tmp_path/elsewhere`` at instantiate, as a chdir-ing export does; the test runs
    in ``tmp_path/wd``."""
    elsewhere, wd = tmp_path / "elsewhere", tmp_path / "wd"
    elsewhere.mkdir()
    wd.mkdir()
    instantiate = _cosimulation.FMUSource._instantiate

    def moving(self, *args, **kwargs):
        instantiate(self, *args, **kwargs)
        os.chdir(elsewhere)

    monkeypatch.setattr(_cosimulation.FMUSource, "_instantiate", moving)
    monkeypatch.setattr(_cosimulation, "_MOVED_DIRECTORY", set(), raising=False)
    monkeypatch.chdir(wd)
    return wd, elsewhere


def exact_miss(path, model) -> float:
    with h5py.File(path, "r") as f:
        run = f["runs/0000"]
        t, u, y = run["t"][()], run["u"][()], run["y"][()]
    exact = lti_fmus.zoh_response(model, t, u[:, 1:]).y
    return float(np.abs(y - exact).max() / np.ptp(exact))


@pytest.mark.parametrize("table", [False, True])
def test_in_process_outputs_stay_in_the_directory_of_the_command(chain, moving_fmu, capsys, table):
    wd, elsewhere = moving_fmu
    args = ["snapshots", str(chain.path), "-o", "d.h5", "--in-process", "-q", "--dt", "0.05", "--t-end", "20"]
    if table:
        (wd / "tab.csv").write_text("time,u\n0,0\n2,0\n2.5,100\n3,0\n20,0\n")
        args += ["--input", "tab.csv"]
    (elsewhere / "d.h5").write_text("a file of the FMU's folder")
    assert cli.main(args + ["--force"]) == 0
    err = capsys.readouterr().err
    assert (wd / "d.h5").is_file() and (elsewhere / "d.h5").read_text() == "a file of the FMU's folder"
    assert os.getcwd() == str(wd)
    assert err.count("changed the working directory") == 1, err   # once, naming the FMU
    assert f"{chain.path.name} changed the working directory" in err
    assert exact_miss(wd / "d.h5", chain.model) < 1e-8


def test_relative_paths_are_absolute_from_the_start():
    args = cli.build_parser().parse_args(["compare", "rom.h5", "model.fmu", "-o", "report", "--input",
                                          "a.csv; sine:amplitude=1,frequency=1"])
    cli._absolute_paths(args)
    assert args.output == os.path.join(os.getcwd(), "report") and args.rom == os.path.join(os.getcwd(), "rom.h5")
    assert args.input_spec == os.path.join(os.getcwd(), "a.csv") + "; sine:amplitude=1,frequency=1"
    assert args.source == "model.fmu"   # (the source makes its own path absolute)
    args = cli.build_parser().parse_args(["build-fmus", "-o", ""])
    cli._absolute_paths(args)
    assert args.output == ""   # refused as empty, not turned into the current folder
