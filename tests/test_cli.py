"""The command line: verbs exist, user errors are one line with a non-zero exit code."""

import subprocess
import sys

import pytest

from fmu_opinf import cli


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fmu_opinf.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_every_verb_has_help():
    for verb in ("snapshots", "fit", "compare", "export", "demo", "build-fmus"):
        with pytest.raises(SystemExit) as info:
            cli.main([verb, "--help"])
        assert info.value.code == 0


@pytest.mark.parametrize("args, message", [
    (["snapshots", "missing.fmu", "-o", "s.h5", "--input", "step"], "does not exist"),
    (["snapshots", "builtin:anchored-msd", "-o", "s.h5", "--input", "pulse:x=1", "--dt", "1", "--t-end", "2"],
     "unknown input kind 'pulse'"),
    (["fit", "missing.h5", "-o", "rom.h5"], "missing.h5"),
    (["export", "missing.h5", "-o", "rom.fmu"], "missing.h5"),
    (["compare", "missing.h5", "builtin:anchored-msd", "--input", "step", "-o", "report"], "missing.h5"),
    (["export", "folder.h5", "-o", "rom.fmu"], "ROM file folder.h5 is a directory"),
    (["compare", "folder.h5", "builtin:anchored-msd", "--input", "step", "-o", "report"], "is a directory"),
])
def test_user_errors_are_one_line_with_nonzero_exit(tmp_path, args, message):
    (tmp_path / "folder.h5").mkdir()
    result = run_cli(*args, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fmu-opinf: error:"), result.stderr
    assert message in lines[0]


def test_report_path_that_is_a_file_fails_before_simulating(tmp_path):
    (tmp_path / "report").write_text("keep me")
    result = run_cli("compare", "rom.h5", "builtin:anchored-msd", "--input", "step", "-o", "report", cwd=tmp_path)
    assert result.returncode == 2
    assert "report directory report is an existing file" in result.stderr
    assert (tmp_path / "report").read_text() == "keep me"


def test_round_off_poles_of_a_free_free_rom_are_neither_unstable_nor_negatively_damped():
    """Audit 2026-11-27: a free-free chain's ROM (PSD operators, a rigid-body mode) printed stable=False and
    'damping ratios -1' for poles at +8.9e-16; the exact poles are 0 (double) and +-i sqrt(2) (undamped)."""
    import numpy as np

    from fmu_opinf.cli import _ROUNDING, _pole_summary
    from fmu_opinf.inference import _pole_info
    from fmu_opinf.rom import SecondOrderROM

    M, D, K = np.eye(2), np.zeros((2, 2)), np.array([[1.0, -1.0], [-1.0, 1.0]])
    info = _pole_info(M, D, K)
    rom = SecondOrderROM(M, D, K, np.ones((2, 1)), np.ones((1, 2)), np.zeros((1, 2)))
    assert rom.is_stable(tol=_ROUNDING)
    line = _pole_summary(info["poles"])
    assert "natural frequencies 1.41 .. 1.41 rad/s, damping ratios 0 .. 0; 2 zero pole(s) (rigid-body motion)" in line
    assert "-1" not in line
