"""First use (issue 15): provenance into the exported FMU, compare on a --reconstruct export, CLI help."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from fmu_opinf import compare, export
from fmu_opinf.cli import build_parser, main

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Anchored chain (g = 40) recorded through the snapshot stage, fitted at r = 5, exported with x[1]."""
    folder = tmp_path_factory.mktemp("first-use")
    assert main(["snapshots", "builtin:anchored-msd", "--g", "40", "-o", str(folder / "train.h5"), "--input", TRAIN,
                 "--dt", "0.5", "--t-end", "100", "-q"]) == 0
    assert main(["fit", str(folder / "train.h5"), "-o", str(folder / "rom.h5"), "--r", "5", "-q"]) == 0
    from fmu_opinf.rom import SecondOrderROM

    rom = SecondOrderROM.load(folder / "rom.h5")
    path = export.export_fmu(rom, folder / "RomX.fmu", reconstruct=["x[1]"])
    return folder, rom, path


@pytest.mark.fmu
def test_exported_fmu_carries_the_training_provenance(trained):
    from fmpy import read_model_description

    folder, rom, path = trained
    md = read_model_description(str(path), validate=False)
    assert f"training input {TRAIN}" in md.description
    assert str(folder) not in md.description
    assert float(md.defaultExperiment.stopTime) == pytest.approx(100.0)
    with zipfile.ZipFile(path) as archive:
        provenance = json.loads(archive.read(next(n for n in archive.namelist() if n.endswith("provenance.json"))))
    assert provenance["training_runs"][0]["input_spec"] == TRAIN
    assert "/" not in provenance["snapshot_file"] and str(folder) not in json.dumps(provenance)
    outputs = {v.name: v.description for v in md.modelVariables if v.causality == "output"}
    assert outputs["x[1]"].startswith("reconstructed full-order position")


@pytest.mark.fmu
def test_compare_on_an_export_with_reconstructed_outputs(trained):
    folder, rom, path = trained
    result = compare.compare(path, "builtin:anchored-msd", TEST, dt=0.5, t_end=50.0, quiet=True,
                             source_options={"g": 40})
    reference = rom.simulate(TEST, 0.5, 50.0).y
    assert result.y_rom.shape == reference.shape
    assert np.abs(result.y_rom - reference).max() <= 1e-12 * np.abs(reference).max()  # measured 2e-14
    assert "max_eps_y" in repr(result) and "array" not in repr(result)


def test_cli_help_lists_only_options_that_act():
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices
    compare_options = {o for a in verbs["compare"]._actions for o in a.option_strings}
    assert not compare_options & {"--constraint", "--positions", "--velocities", "--accelerations"}
    assert "-q" in {o for a in verbs["export"]._actions for o in a.option_strings}
    for name, verb in verbs.items():
        for action in verb._actions:
            assert action.help, f"{name} {action.option_strings or action.dest} has no help text"


def test_warnings_on_the_command_line_are_one_line(monkeypatch, capsys):
    import warnings

    from fmu_opinf import cli
    from fmu_opinf.errors import FmuOpinfWarning

    def noisy(args):
        warnings.warn("first part\n  second part", FmuOpinfWarning)

    monkeypatch.setitem(cli._VERBS, "demo", noisy)
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = before
        assert main(["demo", "-o", "unused"]) == 0
    err = capsys.readouterr().err
    assert err == "fmu-opinf: warning: first part second part\n"


def test_fit_solver_option_reaches_the_sdp(trained, tmp_path):
    """`fit --solver clarabel` and `--solver ipm` solve the same SDP with the named solver (recorded in the
    ROM) and, without refinement, give the same operators (the IPM optimum equals Clarabel's to 1e-6)."""
    from fmu_opinf.rom import SecondOrderROM

    folder = trained[0]
    roms = {}
    for solver in ("clarabel", "ipm"):
        out = tmp_path / f"{solver}.h5"
        assert main(["fit", str(folder / "train.h5"), "-o", str(out), "--r", "5", "--solver", solver,
                     "--normalization", "mass-eigenvalue", "--no-refine", "-q"]) == 0
        roms[solver] = SecondOrderROM.load(out)
        assert roms[solver].fit_info["solver"] == solver.upper()
        assert roms[solver].provenance["fit_settings"]["solver"] == solver
    a, b = roms["clarabel"], roms["ipm"]
    for name in ("Mr", "Dr", "Kr", "Br"):  # measured 1.1e-5 .. 1.7e-5 (the optimum is flat along these)
        assert np.abs(getattr(a, name) - getattr(b, name)).max() < 5e-5 * np.abs(getattr(a, name)).max(), name


def test_fit_refit_output_map_option_reaches_the_refinement(trained, tmp_path, capsys):
    """`fit --refit-output-map` makes the refinement re-fit the output map (recorded in the ROM, its map is not
    eq. 17's and its training objective is lower); with `--no-refine` it is a one-line error, no file."""
    from fmu_opinf.rom import SecondOrderROM

    folder, default, _ = trained
    out = tmp_path / "refit.h5"
    assert main(["fit", str(folder / "train.h5"), "-o", str(out), "--r", "5", "--refit-output-map", "-q"]) == 0
    rom = SecondOrderROM.load(out)
    assert rom.provenance["fit_settings"]["refit_output_map"] is True
    refined, before = rom.fit_info["refinement"], default.fit_info["refinement"]
    assert refined["output_map"] == "refitted" and before["output_map"] == "fixed"
    assert np.abs(rom.Cpr - default.Cpr).max() > 1e-6 * np.abs(default.Cpr).max()
    assert refined["objective"] < before["objective"]
    capsys.readouterr()
    bad = tmp_path / "bad.h5"
    assert main(["fit", str(folder / "train.h5"), "-o", str(bad), "--r", "5", "--refit-output-map",
                 "--no-refine", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs the output-error refinement" in err and "drop the option" in err
    assert not bad.exists() and not list(tmp_path.glob("bad*"))


def test_fit_refine_iterations_option_bounds_both_starts(trained, tmp_path, capsys):
    """`fit --refine-iterations 7` runs at most 7 L-BFGS iterations from each start (the default fit of the same
    data runs more), records the setting, and leaves a training error between the unrefined and the default
    one; a negative count is a one-line error and writes nothing."""
    from fmu_opinf.rom import SecondOrderROM

    folder, default, _ = trained
    out = tmp_path / "short.h5"
    assert main(["fit", str(folder / "train.h5"), "-o", str(out), "--r", "5", "--refine-iterations", "7",
                 "-q"]) == 0
    rom = SecondOrderROM.load(out)
    assert rom.provenance["fit_settings"]["refine_iterations"] == 7
    short, full = rom.fit_info["refinement"], default.fit_info["refinement"]
    assert short["iterations"] <= 7 < full["iterations"]
    candidate = rom.fit_info["least_squares_candidate"]
    assert candidate["refinement"]["iterations"] <= 7
    assert full["objective"] < short["objective"] < short["objective_start"]
    capsys.readouterr()
    bad = tmp_path / "bad.h5"
    assert main(["fit", str(folder / "train.h5"), "-o", str(bad), "--refine-iterations", "-1", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--refine-iterations -1 must be at least 0" in err
    assert not bad.exists()


def test_fit_prints_the_learned_poles_and_no_lstsq_candidate_is_recorded(trained, tmp_path, capsys):
    """`fit` prints the natural frequencies and damping ratios of the learned poles (checked against the
    eigenvalues of the saved ROM's first-order matrix); `--no-lstsq-candidate` reaches the fit settings."""
    import re

    from fmu_opinf.rom import SecondOrderROM

    folder, _, _ = trained
    out = tmp_path / "plain.h5"
    capsys.readouterr()
    assert main(["fit", str(folder / "train.h5"), "-o", str(out), "--r", "5", "--no-lstsq-candidate", "-q"]) == 0
    printed = capsys.readouterr().out
    rom = SecondOrderROM.load(out)
    assert rom.provenance["fit_settings"]["least_squares_candidate"] is False
    assert "least_squares_candidate" not in rom.fit_info and rom.coordinates is None
    r = rom.r
    Minv = np.linalg.inv(rom.Mr)
    poles = np.linalg.eigvals(np.block([[np.zeros((r, r)), np.eye(r)], [-Minv @ rom.Kr, -Minv @ rom.Dr]]))
    upper = poles[poles.imag > 0]
    match = re.search(r"learned poles: (\d+) in the upper half plane, natural frequencies (\S+) \.\. (\S+) rad/s, "
                      r"damping ratios (\S+) \.\. (\S+)", printed)
    assert match, printed
    count, w_lo, w_hi, z_lo, z_hi = (float(v) for v in match.groups())
    assert count == upper.size
    printed_digits = 5e-3  # three significant digits are printed: at most half a unit of the third, relative
    assert w_lo == pytest.approx(np.abs(upper).min(), rel=printed_digits)
    assert w_hi == pytest.approx(np.abs(upper).max(), rel=printed_digits)
    zeta = -upper.real / np.abs(upper)
    assert z_lo == pytest.approx(zeta.min(), rel=printed_digits) and z_hi == pytest.approx(zeta.max(), rel=printed_digits)
