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


@pytest.mark.parametrize("late", ["clean-up", "remembered"])
def test_a_ctrl_c_after_the_work_is_done_is_not_an_interrupted_run(tmp_path, monkeypatch, capsys, late):
    """A Ctrl-C to the process group as a demo ends (audit 67) landed after the demo had written everything: the
    command exited 130 with no message, or said the folder was left as it was before the run, though it held the
    new run.  Once the verb's work is done, a late Ctrl-C says so and the exit code stays 0."""
    import contextlib

    from fmu_opinf.snapshots import _isolation

    done = []
    monkeypatch.setitem(cli._VERBS, "build-fmus", lambda args: done.append((tmp_path / "out.txt").write_text("x")))
    if late == "clean-up":  # in the clean-up after the verb: the fork server's setting being restored
        real = _isolation.use_fork_server

        def restore_interrupted(enabled):
            real(enabled)
            if done:
                raise KeyboardInterrupt

        monkeypatch.setattr(_isolation, "use_fork_server", restore_interrupted)
    else:  # remembered while the verb ran (swallowed in a finalizer) and raised at the end of the command

        @contextlib.contextmanager
        def raised_at_the_end():
            yield
            raise KeyboardInterrupt

        monkeypatch.setattr(cli, "remembered_interrupts", raised_at_the_end)
    assert cli.main(["build-fmus", "-o", str(tmp_path / "fmus")]) == 0
    assert done and (tmp_path / "out.txt").read_text() == "x"
    assert capsys.readouterr().err.strip().splitlines() == [
        "fmu-opinf: Ctrl-C arrived after build-fmus had finished; its outputs are complete"]


def test_a_ctrl_c_before_the_work_is_done_is_still_an_interrupt(tmp_path, monkeypatch, capsys):
    """The counterpart: the verb itself interrupted exits 130 with the interrupt's message."""

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setitem(cli._VERBS, "build-fmus", interrupted)
    assert cli.main(["build-fmus", "-o", str(tmp_path / "fmus")]) == 130
    assert capsys.readouterr().err.strip().startswith("fmu-opinf: interrupted (Ctrl-C)")


def test_build_fmus_replaces_fmus_in_a_given_folder_only_with_force(tmp_path, monkeypatch, capsys):
    """Audit 68: ``build-fmus -o DIR`` replaced a file of the user's without ``--force``, and ``--g 0`` / ``--g 1``
    gave two different lower bounds.  The tool's own folder (no ``-o``) is still rebuilt in place."""
    from fmu_opinf import fmus

    mine = tmp_path / "AnchoredMSD.fmu"
    mine.write_text("not built by fmu-opinf")
    built = []
    monkeypatch.setattr(fmus, "build_fmus", lambda out_dir, g, n1: built.append(out_dir) or [])
    assert cli.main(["build-fmus", "-o", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"fmu-opinf: error: {mine} exists; pass --force to replace it"
    assert mine.read_text() == "not built by fmu-opinf" and not built
    assert cli.main(["build-fmus", "-o", str(tmp_path), "--force"]) == 0 and built == [str(tmp_path)]
    assert cli.main(["build-fmus"]) == 0 and built[-1] == fmus.bundled_fmu_dir()
    monkeypatch.undo()
    for g in ("0", "1"):
        assert cli.main(["build-fmus", "-o", str(tmp_path / "new"), "--g", g]) == 2
        assert capsys.readouterr().err.strip().endswith("is invalid for AnchoredMSD; use an integer g >= 3")
    assert not (tmp_path / "new").exists()


def test_an_undamped_rigid_body_mode_s_split_double_pole_is_a_zero_pole():
    """Audit 78 F3: an undamped free-free ROM (M = diag(1, 2, 3), D = 0, K a Laplacian) has a defective double pole
    at 0, which round-off splits into a pair of about sqrt(eps) of the scale; the fit printed 'damping ratios -1 .. 1'
    and stable=False for a ROM exact to 4e-12.  Reference: the exact poles, 0 (double) and +-i omega from the
    generalized eigenvalues of (K, M)."""
    import numpy as np
    import scipy.linalg

    from fmu_opinf.cli import _ROUNDING, _ZERO_POLE, _pole_summary
    from fmu_opinf.inference import _pole_info
    from fmu_opinf.rom import SecondOrderROM

    M, D = np.diag([1.0, 2.0, 3.0]), np.zeros((3, 3))
    K = 30 * np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    rigid = np.ones(3) / np.sqrt(3.0)
    K = K - 1e-14 * np.outer(rigid, rigid)   # round-off of a learned Kr (entries of 60: eps 60 = 1.3e-14)
    rom = SecondOrderROM(M, D, K, np.ones((3, 1)), np.ones((1, 3)), np.zeros((1, 3)))
    split = np.abs(rom.eigenvalues())
    assert np.sort(split)[1] > 1e3 * _ROUNDING * split.max()      # the premise: round-off alone would not say zero
    assert rom.is_stable(_ROUNDING, _ZERO_POLE) and not rom.is_stable(_ROUNDING)
    omega = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True)[1:])
    line = _pole_summary(_pole_info(M, D, K)["poles"])
    assert (f"natural frequencies {omega.min():.3g} .. {omega.max():.3g} rad/s, damping ratios 0 .. 0; 2 zero pole(s)"
            in line), line
