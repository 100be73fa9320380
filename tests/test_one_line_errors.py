"""Inputs that ended in a traceback (audit 55) end in one line naming the problem and the fix."""

import resource
import zipfile

import numpy as np
import pytest

from fmu_opinf import compare, rom, snapshots
from fmu_opinf.fit import fit_rom
from fmu_opinf.errors import DataError

from test_cli import run_cli

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fitted")
    snapshots.record_to_file("builtin:anchored-msd", folder / "s.h5", TRAIN, dt=0.5, t_end=40.0, quiet=True)
    model = fit_rom(snapshots.Snapshots.load(folder / "s.h5"), r=4)
    model.save(folder / "rom.h5")
    return folder


def _one_line(done, *parts):
    """Exit code 2, no traceback, the error in one line, after the lines of the work done before (if any)."""
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert lines[-1].startswith("fmu-opinf: error: ") and "warning" not in done.stderr, done.stderr
    for part in parts:
        assert part in lines[-1], lines[-1]


@pytest.mark.parametrize("args, parts", [
    (["fit", "{s}", "-o", "r.h5", "--lowpass", "1e300"], ["lowpass cutoff 1e+300 rad/s must lie in", "--lowpass"]),
    (["fit", "{s}", "-o", "r.h5", "--terms", "foo"], ["terms ['foo'] are not known; use 'auto'"]),
    (["fit", "{s}", "-o", "a" * 300 + ".h5"], ["-o names a path too long for the file system (303 bytes in one name)"]),
    (["snapshots", "builtin:anchored-msd", "--g", "100000000000", "--dt", "0.1", "--t-end", "1", "-o", "s.h5"],
     ["the anchored chain with g=100000000000 needs", "give a smaller --g"]),
])
@pytest.mark.slow
def test_options_the_work_cannot_take(fitted, tmp_path, args, parts):
    done = run_cli(*[a.replace("{s}", str(fitted / "s.h5")) for a in args], cwd=tmp_path)
    _one_line(done, *parts)
    assert list(tmp_path.iterdir()) == []


def test_an_fmu_with_a_member_name_fmpy_refuses(tmp_path):
    """fmpy refuses to unpack a member named with a colon (legal on Linux) with a bare Exception: a traceback,
    and the run's shared memory was reported as leaked."""
    from fmu_opinf import lti_fmus

    fmu = lti_fmus.build_lti_fmu(lti_fmus.chain_model(2), tmp_path / "colon.fmu", interfaces=("cs",)).path
    with zipfile.ZipFile(fmu, "a") as archive:
        archive.writestr("documentation/a:b.txt", "x")
    done = run_cli("snapshots", str(fmu), "-o", str(tmp_path / "s.h5"), "--dt", "0.1", "--t-end", "5",
                   "--input", TRAIN)
    _one_line(done, "colon.fmu cannot be unpacked: Illegal path documentation/a:b.txt",
              "repack the FMU with plain relative member names")


def test_names_are_drawn_as_text_and_absurd_outputs_are_said(fitted, tmp_path):
    """An output named ``$x^{$`` was parsed as math (a traceback); outputs of 1.7e308 (a damaged ROM's y0) broke
    the axis ticks."""
    result = compare.compare(fitted / "rom.h5", "builtin:anchored-msd", "harmonic:amplitude=1,omega=0.2",
                             dt=0.5, t_end=40.0, quiet=True)
    result.output_names = ["$x^{$", "cost in $", "y3"]
    assert compare.write_report(result, tmp_path / "named").exists()
    result.y_rom = np.full_like(result.y_rom, 1.7e308)
    with pytest.raises(DataError, match=r"figures cannot be drawn \(.*\); the outputs reach 1.7e\+308"):
        compare.write_report(result, tmp_path / "absurd")


def test_a_rom_whose_step_overflows_is_not_exported(fitted, tmp_path):
    from fmu_opinf.export import export_fmu

    model = rom.SecondOrderROM.load(fitted / "rom.h5")
    model.dt = 1e300   # (as a damaged file's)
    with pytest.raises(DataError, match=r"the ROM's step map at dt=1e\+300 is not finite; choose a smaller --step "
                                        r"or step="):
        export_fmu(model, tmp_path / "x.fmu")
    assert list(tmp_path.iterdir()) == []


def _small_file_limit():
    resource.setrlimit(resource.RLIMIT_FSIZE, (20 * 512, resource.RLIM_INFINITY))


def test_a_file_size_limit_while_building_is_said(fitted, tmp_path):
    """Under ``ulimit -f`` the sources' write ended in a traceback (EFBIG), or the compiler, killed by SIGXFSZ,
    reported an "internal compiler error"."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "export", str(fitted / "rom.h5"), "-o",
                           str(tmp_path / "x.fmu")], capture_output=True, text=True, preexec_fn=_small_file_limit)
    _one_line(done, "the disk is full or a file size limit is set (ulimit -f)")
