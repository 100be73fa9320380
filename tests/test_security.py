"""Hostile input and faults (issue 13): argument checks, file validation, sizes, permissions, interrupts.

Every bad input must end in one line ``fmu-opinf: error: ...`` with exit code 2, before any work,
without writing files, and without reading anything but the named files.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from fmu_opinf import cli
from fmu_opinf.errors import DataError, FileFormatError
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import Snapshots, record
from fmu_opinf.source import BuiltinSource

SIGNAL = "impulse:amplitude=10,t0=1,width=0.5"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small valid snapshot file and a ROM fitted from it (anchored chain, g = 12)."""
    from fmu_opinf.fit import fit_rom_file

    folder = tmp_path_factory.mktemp("valid")
    snaps = folder / "s.h5"
    record(BuiltinSource("anchored-msd", g=12), SIGNAL, 0.5, 40.0, path=snaps, quiet=True)
    rom = folder / "rom.h5"
    fit_rom_file(snaps, rom, r=3, quiet=True)
    return {"snapshots": snaps, "rom": rom}


def run_main(capsys, *args):
    """Run the CLI in this process; return (exit code, stderr lines)."""
    code = cli.main([str(a) for a in args])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


def assert_one_line_error(code, err, text=""):
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("fmu-opinf: error: "), err
    assert "Traceback" not in err[0]
    assert text in err[0], err


def read_only_dir(tmp_path: Path) -> Path:
    """A directory this process cannot create files in (root ignores modes: use /sys then)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        fd, probe = tempfile.mkstemp(dir=folder)
    except OSError:
        return folder
    os.close(fd)
    os.unlink(probe)
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
    except OSError:
        return Path("/sys")
    os.close(fd)
    os.unlink(probe)
    pytest.skip("no unwritable directory available (running as root without /sys)")


# ------------------------------------------------------------------------------------------------------
# item 5: arguments are validated before any work
# ------------------------------------------------------------------------------------------------------

SNAP = ["snapshots", "builtin:anchored-msd", "--g", "5", "-o", "out.h5", "--input", "step"]


@pytest.mark.parametrize("args, text", [
    (SNAP + ["--positions", "", "--dt", "1", "--t-end", "2"], "--positions is empty"),
    (SNAP + ["--dt", "1e-300", "--t-end", "2"], "increase --dt"),
    (SNAP + ["--dt", "1", "--t-end", "1e15"], "decrease --t-end"),
    (SNAP + ["--dt", "nan", "--t-end", "2"], "--dt nan"),
    (SNAP + ["--dt", "1", "--t-end", "-3"], "--t-end -3"),
    (SNAP + ["--g", "0", "--dt", "1", "--t-end", "2"], "--g 0"),
])
def test_snapshots_arguments_are_checked_first(tmp_path, monkeypatch, capsys, args, text):
    monkeypatch.chdir(tmp_path)
    code, err = run_main(capsys, *args)
    assert_one_line_error(code, err, text)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra, text", [
    (["--energy", "1.5"], "--energy 1.5"),
    (["--energy", "0"], "--energy 0"),
    (["--energy", "nan"], "--energy nan"),
    (["--lowpass", "-1"], "--lowpass -1"),
    (["--lowpass", "nan"], "--lowpass nan"),
    (["--r", "0"], "--r 0"),
])
def test_fit_arguments_are_checked_before_the_pod(files, tmp_path, capsys, monkeypatch, extra, text):
    import fmu_opinf.rom

    def no_work(*args, **kwargs):
        raise AssertionError("the fit started before its arguments were checked")

    monkeypatch.setattr(fmu_opinf.rom, "fit_rom", no_work)
    code, err = run_main(capsys, "fit", files["snapshots"], "-o", tmp_path / "rom.h5", *extra)
    assert_one_line_error(code, err, text)
    assert list(tmp_path.iterdir()) == []


def test_compare_dt_zero_is_one_line_and_leaves_no_report_folder(files, tmp_path, capsys):
    report = tmp_path / "report"
    code, err = run_main(capsys, "compare", files["rom"], "builtin:anchored-msd", "--g", "12", "--input", "step",
                         "--dt", "0", "-o", report)
    assert_one_line_error(code, err, "--dt 0")
    assert not report.exists()


def test_compare_error_after_start_leaves_no_empty_report_folder(files, tmp_path, capsys):
    report = tmp_path / "report"
    code, err = run_main(capsys, "compare", files["rom"], "builtin:anchored-msd", "--g", "12", "--input", "step",
                         "--t-end", "0.3", "-o", report)  # 0.3 is no whole number of steps 0.5
    assert_one_line_error(code, err, "whole number of steps")
    assert not report.exists()


@pytest.mark.parametrize("verb", ["snapshots", "fit", "fit-figures"])
def test_unwritable_output_folder_fails_before_work(files, tmp_path, capsys, monkeypatch, verb):
    import fmu_opinf.rom
    import fmu_opinf.snapshots

    def no_work(*args, **kwargs):
        raise AssertionError("work started although the output cannot be written")

    monkeypatch.setattr(fmu_opinf.rom, "fit_rom", no_work)
    monkeypatch.setattr(fmu_opinf.snapshots, "record_to_file", no_work)
    folder = read_only_dir(tmp_path)
    if verb == "snapshots":
        args = SNAP[:4] + ["-o", folder / "s.h5", "--input", "step", "--dt", "1", "--t-end", "2"]
    elif verb == "fit":
        args = ["fit", files["snapshots"], "-o", folder / "rom.h5"]
    else:
        args = ["fit", files["snapshots"], "-o", tmp_path / "rom.h5", "--figures", folder / "figs"]
    code, err = run_main(capsys, *args)
    assert_one_line_error(code, err, "cannot write")


def test_force_does_not_overwrite_the_input(files, tmp_path, capsys):
    snaps = tmp_path / "s.h5"
    shutil.copy(files["snapshots"], snaps)
    before = snaps.read_bytes()
    code, err = run_main(capsys, "fit", snaps, "-o", snaps, "--force", "--r", "2")
    assert_one_line_error(code, err, "is also an input")
    assert snaps.read_bytes() == before


# ------------------------------------------------------------------------------------------------------
# items 5 and 7: files are validated on load
# ------------------------------------------------------------------------------------------------------


def _set_attr(name, value, where="/"):
    def mutate(f):
        group = f[where]
        if "_attrs" in group and name in group["_attrs"]:  # large values live in a dataset
            del group["_attrs"][name]
        group.attrs[name] = value
    return mutate


def _replace(name, data=None, **kwargs):
    def mutate(f):
        del f[name]
        if data is not None:
            f.create_dataset(name, data=data)
        else:
            f.create_dataset(name, **kwargs)
    return mutate


def _external_link(name):
    def mutate(f):
        other = Path(f.filename).with_name("other.h5")
        with h5py.File(other, "w") as g:
            g.create_dataset("x", data=np.zeros(f[name].shape))
        del f[name]
        f[name] = h5py.ExternalLink(str(other), "/x")
    return mutate


def _transform(name, func):
    def mutate(f):
        data = func(np.array(f[name][()]))
        del f[name]
        f.create_dataset(name, data=data)
    return mutate


RUN = "runs/0000"
SNAPSHOT_DEFECTS = {
    "layout_version text": _set_attr("layout_version", "one"),
    "dt as text": _set_attr("dt", "0.5"),
    "dt NaN": _set_attr("dt", np.nan),
    "dt negative": _set_attr("dt", -0.5),
    "dt zero in a run": _set_attr("dt", 0.0, RUN),
    "bool array as n": _set_attr("n", np.array([True, False])),
    "compound attribute": _set_attr("complete", np.array([(1, 2.0)], dtype=[("a", "i4"), ("b", "f8")]), RUN),
    "complex attribute": _set_attr("dt", 0.5 + 1j),
    "names as integers": _set_attr("position_names", np.arange(12)),
    "JSON list": _set_attr("system_options", json.dumps([1, 2])),
    "external link": _external_link(RUN + "/x"),
    "t NaN": _transform(RUN + "/t", lambda t: np.where(np.arange(t.size) == 5, np.nan, t)),
    "t decreasing": _transform(RUN + "/t", lambda t: t[::-1].copy()),
    "u rows != m": _transform(RUN + "/u", lambda u: np.vstack([u, u])),
    "complex x": _transform(RUN + "/x", lambda x: x + 1j * x),
    "bool x": _transform(RUN + "/x", lambda x: x > 0),
    "x of strings": _transform(RUN + "/x", lambda x: np.array([["a"] * x.shape[1]] * x.shape[0], dtype="S1")),
    "600e9 samples declared": lambda f: [f[RUN + "/" + a].resize(6 * 10**11, axis=1) for a in ("x", "xdot")],
}


def _mutated(src: Path, folder: Path, mutate) -> Path:
    path = folder / src.name
    shutil.copy(src, path)
    with h5py.File(path, "r+") as f:
        mutate(f)
    return path


@pytest.mark.parametrize("defect", list(SNAPSHOT_DEFECTS))
def test_damaged_snapshot_file_is_one_line_error(files, tmp_path, capsys, defect):
    path = _mutated(files["snapshots"], tmp_path, SNAPSHOT_DEFECTS[defect])
    with pytest.raises((FileFormatError, DataError)):
        Snapshots.load(path)
    before = sorted(tmp_path.iterdir())
    code, err = run_main(capsys, "fit", path, "-o", tmp_path / "rom.h5", "--r", "2", "-q")
    assert_one_line_error(code, err)
    assert sorted(tmp_path.iterdir()) == before


def _negative(name):
    return _transform(name, lambda a: -np.eye(a.shape[0]))


ROM_DEFECTS = {
    "layout_version text": _set_attr("layout_version", "one"),
    "dt as text": _set_attr("dt", "0.5"),
    "dt NaN": _set_attr("dt", np.nan),
    "provenance JSON list": _set_attr("provenance", json.dumps(["a", "b"])),
    "names as integers": _set_attr("output_names", np.arange(3)),
    "compound attribute": _set_attr("basis_kind", np.array([(1, 2.0)], dtype=[("a", "i4"), ("b", "f8")])),
    "Mr wrong shape": _replace("Mr", data=np.ones((3, 4))),
    "Mr zero": _transform("Mr", np.zeros_like),
    "Kr negative definite": _negative("Kr"),
    "Kr asymmetric (a flipped byte)": _transform("Kr", lambda k: k + np.diag(np.full(k.shape[0] - 1, 1e-6 *
                                                                                  np.abs(k).max()), 1)),
    "Dr asymmetric": _transform("Dr", lambda d: d + np.diag(np.full(d.shape[0] - 1, 1e-3 * np.abs(d).max()), -1)),
    "NaN basis": _transform("basis", lambda v: np.where(v == v.max(), np.nan, v)),
    "complex Br": _transform("Br", lambda b: b + 1j),
    "bool Dr": _transform("Dr", lambda d: d > 0),
    "external link": _external_link("basis"),
    "200000^2 Mr declared": _replace("Mr", shape=(200000, 200000), dtype="f8"),
}


@pytest.mark.parametrize("defect", list(ROM_DEFECTS))
def test_damaged_rom_file_is_one_line_error(files, tmp_path, capsys, defect):
    path = _mutated(files["rom"], tmp_path, ROM_DEFECTS[defect])
    with pytest.raises((FileFormatError, DataError)):
        SecondOrderROM.load(path)
    report = tmp_path / "report"
    code, err = run_main(capsys, "compare", path, "builtin:anchored-msd", "--g", "12", "--input", "step",
                         "--t-end", "2", "-o", report, "-q")
    assert_one_line_error(code, err)
    assert not report.exists()


@pytest.mark.parametrize("kind, command", [("snapshots", "fmu-opinf snapshots"), ("rom", "fmu-opinf fit")])
def test_truncated_files_are_said_to_be_truncated(files, tmp_path, capsys, kind, command):
    """Audit 62, finding 7: the first half of a snapshot file was "not an HDF5 file" (a ROM's: "not HDF5 or is
    truncated")."""
    data = files[kind].read_bytes()
    path = tmp_path / f"half_{kind}.h5"
    path.write_bytes(data[:len(data) // 2])
    expected = f"it is not HDF5 or is truncated: restore it or write it again with '{command}'"
    with pytest.raises(FileFormatError, match=f"cannot read {'snapshot' if kind == 'snapshots' else 'ROM'} file "
                                              f"{re.escape(str(path))} .*; {expected}"):
        (Snapshots if kind == "snapshots" else SecondOrderROM).load(path)
    args = ("fit", path, "-o", tmp_path / "rom.h5", "-q") if kind == "snapshots" else ("export", path, "-o",
                                                                                       tmp_path / "rom.fmu")
    code, err = run_main(capsys, *args)
    assert_one_line_error(code, err, expected)


def _flip_a_stored_byte(src: Path, folder: Path, name: str) -> Path:
    """A copy of ``src`` with one byte of the first stored chunk of dataset ``name`` changed (a bit rot)."""
    path = folder / src.name
    shutil.copy(src, path)
    with h5py.File(path, "r") as f:
        assert f[name].fletcher32, f"{name} is written without a checksum"
        info = f[name].id.get_chunk_info(0)
    with open(path, "r+b") as handle:
        handle.seek(info.byte_offset + info.size // 3)
        byte = handle.read(1)[0]
        handle.seek(info.byte_offset + info.size // 3)
        handle.write(bytes([byte ^ 0x10]))
    return path


@pytest.mark.parametrize("kind, name", [("rom", "Kr"), ("rom", "basis"), ("snapshots", "runs/0000/x"),
                                        ("snapshots", "runs/0000/x0")])
def test_changed_bytes_fail_the_checksum_in_one_line(files, tmp_path, capsys, kind, name):
    """Audit 62, finding 5: flipped bytes in a ROM's Kr were read as data; HDF5's checksum now refuses them."""
    path = _flip_a_stored_byte(files[kind], tmp_path, name)
    reader = SecondOrderROM if kind == "rom" else Snapshots
    with pytest.raises(FileFormatError, match="fail HDF5's checksum .*damaged, restore it from a copy"):
        reader.load(path)
    args = ("compare", path, "builtin:anchored-msd", "--g", "12", "--input", "step", "--t-end", "2", "-o",
            tmp_path / "report", "-q") if kind == "rom" else ("fit", path, "-o", tmp_path / "rom.h5", "-q")
    code, err = run_main(capsys, *args)
    assert_one_line_error(code, err, "fail HDF5's checksum")
    assert path.name in err[0] and "damaged" in err[0]


def _without_checksums(src: Path, folder: Path) -> Path:
    """``src`` rewritten as older versions wrote it: the same datasets and attributes, no checksums."""
    path = folder / ("old_" + src.name)

    def copy(source, target):
        for key, value in source.attrs.items():
            target.attrs[key] = value
        for key, obj in source.items():
            if isinstance(obj, h5py.Group):
                copy(obj, target.create_group(key))
            else:
                target.create_dataset(key, data=obj[()])

    with h5py.File(src, "r") as old, h5py.File(path, "w") as new:
        copy(old, new)
    return path


def test_files_without_checksums_still_load(files, tmp_path):
    """New files carry checksums; the files older versions wrote, without, load as before (docs/file-format.md)."""
    with h5py.File(files["rom"], "r") as rom, h5py.File(files["snapshots"], "r") as snaps:
        assert all(rom[name].fletcher32 for name in ("Mr", "Dr", "Kr", "Br", "Cpr", "Cvr", "basis"))
        assert all(snaps["runs/0000"][name].fletcher32 for name in ("t", "u", "x", "xdot", "xddot", "y", "x0", "v0"))
    old_rom = _without_checksums(files["rom"], tmp_path)
    with h5py.File(old_rom, "r") as f:
        assert not f["Kr"].fletcher32 and f["Kr"].chunks is None
    np.testing.assert_array_equal(SecondOrderROM.load(old_rom).Kr, SecondOrderROM.load(files["rom"]).Kr)
    old_snapshots = _without_checksums(files["snapshots"], tmp_path)
    np.testing.assert_array_equal(Snapshots.load(old_snapshots).runs[0].x, Snapshots.load(files["snapshots"]).runs[0].x)


def test_valid_files_still_load(files):
    assert Snapshots.load(files["snapshots"]).n == 12
    assert SecondOrderROM.load(files["rom"]).r == 3


# ------------------------------------------------------------------------------------------------------
# item 8: permissions follow the umask
# ------------------------------------------------------------------------------------------------------


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_output_files_honour_the_umask_and_keep_the_mode_they_replace(files, tmp_path):
    old = os.umask(0o022)
    try:
        snaps = Snapshots.load(files["snapshots"])
        new = snaps.save(tmp_path / "s.h5")
        assert _mode(new) == 0o644
        new.chmod(0o640)
        snaps.save(new, overwrite=True)
        assert _mode(new) == 0o640
        os.umask(0o077)
        other = snaps.save(tmp_path / "t.h5")
        assert _mode(other) == 0o600
    finally:
        os.umask(old)


# ------------------------------------------------------------------------------------------------------
# item 6: declared sizes are checked against the data present and the memory available
# ------------------------------------------------------------------------------------------------------


def test_snapshot_file_claiming_600e9_samples_fails_fast(files, tmp_path, capsys):
    import time

    def claim(f):
        for name in ("t", "u", "x", "xdot", "xddot", "y"):
            f[RUN + "/" + name].resize(6 * 10**11, axis=f[RUN + "/" + name].ndim - 1)

    path = _mutated(files["snapshots"], tmp_path, claim)
    assert path.stat().st_size < 200_000
    start = time.perf_counter()
    code, err = run_main(capsys, "fit", path, "-o", tmp_path / "rom.h5", "--r", "2", "-q")
    assert_one_line_error(code, err, "holds data for only part of it")
    assert time.perf_counter() - start < 5


def test_sizes_beyond_available_memory_are_refused_before_allocating(files, monkeypatch):
    import fmu_opinf._validate as validate

    monkeypatch.setattr(validate, "available_memory", lambda: 256)
    with pytest.raises(DataError, match="of memory but only"):
        SecondOrderROM.load(files["rom"])
    with pytest.raises(DataError, match="of memory but only"):
        Snapshots.load(files["snapshots"])


# ------------------------------------------------------------------------------------------------------
# item 4: a full disk while recording is one line, the previous file stays, no temporary file
# ------------------------------------------------------------------------------------------------------


def _as_from_a_terminal() -> None:
    """Child set-up for the interrupt tests: Ctrl-C acts as it does for a command typed in a terminal, also when
    the test run itself was started in the background (a non-interactive shell starts background jobs with
    SIGINT ignored, and children inherit that)."""
    import signal as _signal

    _signal.signal(_signal.SIGINT, _signal.SIG_DFL)
    _signal.signal(_signal.SIGTERM, _signal.SIG_DFL)


def ctrl_c_after(arguments: list[str], delay: float, after_line: str | None = None,
                 terminate: bool = False) -> tuple[int, str]:
    """Run ``fmu-opinf *arguments`` as from a terminal, press Ctrl-C (SIGINT to its process group) ``delay``
    seconds after its start, or after it printed a line containing ``after_line``; its exit code and standard
    error, once every process of its group has ended (a forked helper included).  ``terminate``: SIGTERM to the
    command's process alone instead (as a service manager or ``timeout`` stops it)."""
    import signal as _signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "fmu_opinf.cli", *arguments], stderr=subprocess.PIPE, text=True,
                            env=_cli_env(), start_new_session=True, preexec_fn=_as_from_a_terminal)
    head = ""
    while after_line is not None and after_line not in head:
        line = proc.stderr.readline()
        if not line:
            break
        head += line
    time.sleep(delay)
    os.kill(proc.pid, _signal.SIGTERM) if terminate else os.killpg(proc.pid, _signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)
        deadline = time.monotonic() + 5
        while _group_alive(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _group_alive(proc.pid), "a process of the command outlived it"
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, _signal.SIGKILL)
    return proc.returncode, head + err


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def _cli_env() -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    src = str(Path(cli.__file__).resolve().parents[1])
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.parametrize("limit, g, dt, said", [(20_000, 50, 0.1, "the disk is full"),
                                                (40 * 2**20, 2000, 0.01, "the recording needs about 961 MB")],
                         ids=["at-open", "before-streaming"])
@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_disk_full_is_one_line_and_keeps_the_previous_file(tmp_path, limit, g, dt, said):
    import resource
    import signal as _signal
    import subprocess
    import sys

    def small_disk():  # a file size limit: writes beyond it fail with EFBIG, as on a full disk
        _signal.signal(_signal.SIGXFSZ, _signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    out = tmp_path / "s.h5"
    out.write_bytes(b"previous")
    result = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "snapshots", "builtin:anchored-msd", "--g",
                             str(g), "-o", str(out), "--input", "step", "--dt", str(dt), "--t-end", "200", "-q",
                             "--force"], capture_output=True, text=True, preexec_fn=small_disk, env=_cli_env(),
                            timeout=120)
    err = result.stderr.strip().splitlines()
    assert_one_line_error(result.returncode, err, said)   # (a recording that cannot fit: refused before it starts)
    assert out.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


# ------------------------------------------------------------------------------------------------------
# item 2: Ctrl-C / SIGTERM during a streamed recording stop it, keep the previous file, leave no temp file
# ------------------------------------------------------------------------------------------------------


def _without_size_line(err: str) -> list[str]:
    """The lines of ``err`` but the recording's up-front size warning (these runs record 2.9 GB before compression:
    the warning is right, and the interruption must still be the one other line)."""
    return [line for line in err.strip().splitlines() if not line.startswith("fmu-opinf: warning: s.h5: 1 run(s) of")]


@pytest.fixture(scope="module")
def anchored_fmu():
    from fmu_opinf import fmus

    if fmus.find_build_tools() is None and not (fmus._c_sources_dir() / "AnchoredMSD.fmu").is_file():
        pytest.skip("no CMake / C compiler to build the benchmark FMUs")
    return fmus.bundled_fmu("AnchoredMSD")


def _wait_for_stream(folder: Path, proc, minimum: int = 4 * 2**20, timeout: float = 60.0) -> None:
    import time

    start = time.monotonic()
    while time.monotonic() - start < timeout and proc.poll() is None:
        temps = list(folder.glob("*.tmp"))
        if temps and temps[0].stat().st_size >= minimum:
            return
        time.sleep(0.05)
    pytest.fail(f"the recording did not start streaming (exit code {proc.poll()})")


@pytest.mark.parametrize("isolation", ["--in-process", "isolated"])
@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGINT-to-group"])
@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_interrupted_streamed_recording_keeps_the_previous_file(anchored_fmu, tmp_path, isolation, how):
    """A streamed run (data over the in-memory limit) is interrupted while writing its temporary file."""
    import signal as _signal
    import subprocess
    import sys
    import time

    out = tmp_path / "s.h5"
    out.write_bytes(b"the previous, complete snapshot file")
    before = out.read_bytes()
    args = [sys.executable, "-m", "fmu_opinf.cli", "snapshots", str(anchored_fmu), "-o", str(out), "--input",
            "impulse:amplitude=100,t0=2,width=0.5", "--dt", "0.01", "--t-end", "2000", "--force", "-q"]
    args += [isolation] if isolation.startswith("--") else []
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_cli_env(),
                            start_new_session=True, preexec_fn=_as_from_a_terminal)
    try:
        _wait_for_stream(tmp_path, proc)
        signum = _signal.SIGTERM if how == "SIGTERM" else _signal.SIGINT
        sent = time.monotonic()
        if how.endswith("group"):  # a terminal's Ctrl-C reaches the tool and its simulation process
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        _, err = proc.communicate(timeout=20)
        elapsed = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, _signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 128 + signum, err
    assert elapsed < 5, elapsed
    lines = _without_size_line(err)
    assert len(lines) == 1 and lines[0].startswith("fmu-opinf: interrupted"), err
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5"]


# ------------------------------------------------------------------------------------------------------
# item 3: compare runs the FMU in a separate process: a crash or a hang is one line
# ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def toy_rom(tmp_path_factory):
    """A one-input, two-output ROM matching the toy FMU of test_source (r = 1)."""
    path = tmp_path_factory.mktemp("toyrom") / "rom.h5"
    SecondOrderROM([[1.0]], [[1.0]], [[1.0]], [[1.0]], [[1.0], [0.5]], [[0.0], [0.0]], dt=0.1).save(path)
    return path


@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_compare_with_a_crashing_fmu_is_one_line(toys, toy_rom, tmp_path):
    """The toy dereferences NULL in doStep once its input exceeds 0.5; on main this killed the tool."""
    import subprocess
    import sys

    report = tmp_path / "report"
    result = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "compare", str(toy_rom), str(toys["full"]),
                             "--input", "step:amplitude=1,t0=3.95", "--dt", "0.1", "--t-end", "6", "--set", "fault=3",
                             "--set", "fault_threshold=0.5", "-o", str(report), "-q"],
                            capture_output=True, text=True, env=_cli_env(), timeout=120)
    assert_one_line_error(result.returncode, result.stderr.strip().splitlines(),
                          "crashed the simulation process (signal SIGSEGV) at step 41")
    assert not report.exists()


def test_compare_timeout_stops_a_slow_fmu(anchored_fmu, files, tmp_path, capsys):
    import time

    start = time.monotonic()
    code, err = run_main(capsys, "compare", files["rom"], anchored_fmu, "--input", "step", "--dt", "0.01",
                         "--t-end", "2000", "--timeout", "1", "-o", tmp_path / "report", "-q")
    assert_one_line_error(code, err, "did not finish within the timeout of 1 s")
    assert time.monotonic() - start < 10
    assert not (tmp_path / "report").exists()


# ------------------------------------------------------------------------------------------------------
# item 8: messages say what happened to the data
# ------------------------------------------------------------------------------------------------------


def test_crash_in_the_auto_window_pilot_does_not_claim_kept_samples(toys, tmp_path):
    from fmu_opinf.snapshots import record_to_file
    from fmu_opinf.sources import StepError

    out = tmp_path / "s.h5"
    with pytest.raises(StepError) as info:
        record_to_file(str(toys["full"]), out, ["step:amplitude=1,t0=0.35"], auto_window=True, quiet=True,
                       isolate=True, parameters={"fault": 3, "fault_threshold": 0.5})
    assert "crashed the simulation process" in str(info.value)
    assert "kept" not in str(info.value) and "no file was written" in str(info.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("grid", [[], ["--dt", "0.5", "--t-end", "20"]])
def test_parameter_refused_at_initialization_is_one_line_and_keeps_the_previous_file(anchored_fmu, tmp_path,
                                                                                     capsys, grid):
    """The FMU refuses a --set value when it initializes: no sample is recorded, so no file is kept (it was left
    empty, or a traceback from reading the first sample)."""
    out = tmp_path / "s.h5"
    out.write_bytes(b"previous")
    code = cli.main(["snapshots", str(anchored_fmu), "-o", str(out), "--force", "--set", "mass=-1", *grid])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "Traceback" not in err and "IndexError" not in err
    last = err.splitlines()[-1]
    assert last.startswith("fmu-opinf: error: ") and "failed to initialize" in last and "mass must be positive" in last
    assert out.read_bytes() == b"previous" and list(tmp_path.iterdir()) == [out]


def test_report_files_honour_the_umask(files, tmp_path, capsys):
    old = os.umask(0o022)
    try:
        code, err = run_main(capsys, "compare", files["rom"], "builtin:anchored-msd", "--g", "12", "--input", "step",
                             "--t-end", "5", "-o", tmp_path / "report", "-q")
    finally:
        os.umask(old)
    assert code == 0, err
    for name in ("index.html", "metrics.json", "outputs.png", "error.png"):
        assert _mode(tmp_path / "report" / name) == 0o644, name


def test_compare_refuses_a_folder_with_other_files_but_replaces_an_earlier_report(files, tmp_path, capsys):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"keep")
    code, err = run_main(capsys, "compare", files["rom"], "builtin:anchored-msd", "--g", "12", "--input", "step",
                         "--t-end", "5", "-o", folder, "-q")
    assert_one_line_error(code, err, "holds other files")
    assert sorted(p.name for p in folder.iterdir()) == ["holiday.jpg"]
    report = tmp_path / "report"
    for _ in range(2):
        code, err = run_main(capsys, "compare", files["rom"], "builtin:anchored-msd", "--g", "12", "--input", "step",
                             "--t-end", "5", "-o", report, "-q")
        assert code == 0, err


@pytest.mark.parametrize("verb", ["fit", "compare"])
@pytest.mark.slow
def test_disk_full_in_fit_and_compare_is_one_line(files, tmp_path, verb):
    import resource
    import signal as _signal
    import subprocess
    import sys

    def small_disk():
        _signal.signal(_signal.SIGXFSZ, _signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (30_000, 30_000))

    if verb == "fit":
        args = ["fit", str(files["snapshots"]), "-o", str(tmp_path / "rom.h5"), "--r", "2", "-q"]
    else:
        args = ["compare", str(files["rom"]), "builtin:anchored-msd", "--g", "12", "--input", "step", "--t-end", "5",
                "-o", str(tmp_path / "report"), "-q"]
    result = subprocess.run([sys.executable, "-m", "fmu_opinf.cli", *args], capture_output=True, text=True,
                            preexec_fn=small_disk, env=_cli_env(), timeout=120)
    assert_one_line_error(result.returncode, result.stderr.strip().splitlines(), "the disk is full")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def interpreter_start_seconds() -> float:
    """How long a bare ``python -c pass`` takes here (its site imports included): the best of three."""
    import subprocess
    import sys
    import time

    seconds = []
    for _ in range(3):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], env=_cli_env(), check=True)
        seconds.append(time.perf_counter() - start)
    return min(seconds)


@pytest.mark.parametrize("delay", [0.2, 0.3, 0.4, 0.7, 1.5])
@pytest.mark.slow  # 5 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_ctrl_c_during_start_up_is_one_line_and_writes_nothing(anchored_fmu, tmp_path, delay,
                                                                interpreter_start_seconds):
    """Ctrl-C to the whole process group while the tool or its simulation process is still starting: while numpy
    and fmpy are imported, the fork server starts and the first run is handed to it (0.2-0.4 s gave exit -2, or
    a traceback, about one trial in ten before).  A Ctrl-C while the interpreter itself starts is Python's, with
    its own traceback: delays shorter than twice that start are skipped (0.2 s on a slow machine)."""
    if delay < 2 * interpreter_start_seconds:
        pytest.skip(f"the interpreter alone takes {interpreter_start_seconds:.2f} s to start here")
    returncode, err = ctrl_c_after(["snapshots", str(anchored_fmu), "-o", str(tmp_path / "s.h5"), "--input", "step",
                                    "--dt", "0.01", "--t-end", "2000", "-q"], delay)
    lines = _without_size_line(err)
    assert returncode == 130 and len(lines) == 1 and lines[0].startswith("fmu-opinf: interrupted"), err
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_that_ended_a_string_evaluation_still_exits_130_under_python_m(tmp_path):
    """CPython remembers a KeyboardInterrupt that ended code evaluated from a string (a dataclass being created
    when Ctrl-C arrived), also once caught, and ``python -m`` then died by SIGINT (exit -2) after the one-line
    message instead of exiting 130."""
    import subprocess
    import sys

    (tmp_path / "probe.py").write_text(
        "import fmu_opinf.cli as cli\n"
        "def main():\n"
        "    try:\n"
        "        exec('raise KeyboardInterrupt', {})\n"
        "    except KeyboardInterrupt:\n"
        "        return 130\n"
        "cli.main = main\n"
        "cli.run()\n")
    result = subprocess.run([sys.executable, "-m", "probe"], cwd=tmp_path, env=_cli_env(), capture_output=True,
                            text=True, timeout=60, preexec_fn=_as_from_a_terminal)
    assert result.returncode == 130, result.stderr


def test_ctrl_c_while_numpy_is_imported_is_one_line(monkeypatch, capsys):
    """A Ctrl-C while the command line imports its file layer (numpy, h5py) leaves numpy half imported, and the
    message saying what was left imported it again: "cannot load module more than once", exit 1 with a traceback
    (CI, 2026-12-06, one trial in many of the start-up test).  Both imports are played here: the first is
    interrupted, any later one fails as numpy's did."""
    import importlib.abc
    import sys

    class HalfImported(importlib.abc.MetaPathFinder):
        tries = 0

        def find_spec(self, name, path=None, target=None):
            if name != "fmu_opinf._hdf5":
                return None
            HalfImported.tries += 1
            if HalfImported.tries == 1:
                raise KeyboardInterrupt
            raise ImportError("cannot load module more than once per process")

    monkeypatch.delitem(sys.modules, "fmu_opinf._hdf5")
    monkeypatch.setattr(sys, "meta_path", [HalfImported(), *sys.meta_path])
    assert cli.main(["fit", "missing.h5", "-o", "rom.h5"]) == 130
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["fmu-opinf: interrupted (Ctrl-C); no output file was written or replaced"]
    assert HalfImported.tries == 1


def test_an_error_raised_by_the_interrupt_itself_is_the_interrupt():
    """A Ctrl-C landing in ``__set_name__`` while a module defines a class (seen importing fmu_opinf.signals) comes
    out as a RuntimeError; under the command line's handler it is the interrupt, not a traceback."""
    import signal as _signal

    from fmu_opinf._interrupts import remembered_interrupts
    from fmu_opinf.errors import Interrupted

    class Named:
        def __set_name__(self, owner, name):
            os.kill(os.getpid(), _signal.SIGINT)
            for _ in range(1000):  # the handler raises here; type() wraps it in a RuntimeError
                pass

    with pytest.raises(Interrupted):
        with remembered_interrupts():
            type("Defined", (), {"field": Named()})


def test_absurd_grid_from_the_api_is_one_line():
    from fmu_opinf.snapshots import time_grid

    with pytest.raises(DataError, match="increase --dt"):
        time_grid(1e-300, 10.0)


def test_ctrl_c_swallowed_by_a_finalizer_still_stops_the_run(tmp_path, monkeypatch):
    """A Ctrl-C whose KeyboardInterrupt lands in a finalizer (seen in ZipFile.__del__ while an FMU is opened) is
    swallowed by Python; under the command line's handler it is raised again before any file is replaced, and the
    swallowed raise prints no "Exception ignored" traceback (CI saw one beside the one-line message)."""
    import signal as _signal
    import sys

    from fmu_opinf._hdf5 import atomic_h5
    from fmu_opinf._interrupts import remembered_interrupts
    from fmu_opinf.errors import Interrupted

    class Finalized:
        def __del__(self):
            os.kill(os.getpid(), _signal.SIGINT)
            for _ in range(1000):  # the handler runs here, inside the finalizer: Python swallows what it raises
                pass

    target = tmp_path / "out.h5"
    target.write_bytes(b"previous")
    reached = []
    printed = []
    monkeypatch.setattr(sys, "unraisablehook", printed.append)  # what Python would print as "Exception ignored"
    with pytest.raises(Interrupted):
        with remembered_interrupts():
            Finalized()
            reached.append("after the finalizer")  # the run went on: the first raise was swallowed
            with atomic_h5(target, overwrite=True) as f:
                f["x"] = 1.0
    assert reached and target.read_bytes() == b"previous"
    assert list(tmp_path.iterdir()) == [target]
    assert printed == []


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the swallowed first raise
def test_ctrl_c_swallowed_before_an_fmu_is_written_keeps_the_previous_fmu(tmp_path):
    """The same for the FMU archives that export and build-fmus write, and for a block that ends without
    another safe point: the command still ends interrupted."""
    import signal as _signal

    from fmu_opinf import fmus
    from fmu_opinf._interrupts import remembered_interrupts
    from fmu_opinf.errors import Interrupted

    class Finalized:
        def __del__(self):
            os.kill(os.getpid(), _signal.SIGINT)
            for _ in range(1000):
                pass

    unzipped = tmp_path / "unzipped"
    unzipped.mkdir()
    (unzipped / "modelDescription.xml").write_text("<fmiModelDescription/>")
    target = tmp_path / "out" / "model.fmu"
    target.parent.mkdir()
    target.write_bytes(b"previous")
    with pytest.raises(Interrupted):
        with remembered_interrupts():
            Finalized()
            fmus._write_zip(unzipped, target)
    assert target.read_bytes() == b"previous" and list(target.parent.iterdir()) == [target]
    with pytest.raises(Interrupted):
        with remembered_interrupts():
            Finalized()  # no safe point after it in the block: its end raises


@pytest.mark.parametrize("output, reconstruct, text", [
    ("folder.fmu", None, "folder.fmu is a directory; give a file name"),   # was "exists; pass --force"
    ("notes.txt", None, "must end in .fmu"),
    ("new.fmu", "", "--reconstruct '' names no position"),                 # exported nothing extra, rc 0
    ("new.fmu", ",", "--reconstruct ',' names no position"),
])
def test_export_output_and_reconstruct_errors_say_what_is_wrong_first(files, tmp_path, capsys, output, reconstruct,
                                                                       text):
    """Eleventh audit, F4 and F6: the first error names the real problem."""
    (tmp_path / "folder.fmu").mkdir()
    (tmp_path / "notes.txt").write_text("keep")
    extra = [] if reconstruct is None else ["--reconstruct", reconstruct]
    code, err = run_main(capsys, "export", files["rom"], "-o", tmp_path / output, *extra)
    assert_one_line_error(code, err, text)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.fmu", "notes.txt"]


def test_export_from_the_api_creates_no_folder_for_refused_arguments(files, tmp_path):
    """Eleventh audit, F5: a refused export left the output's new parent folders behind."""
    from fmu_opinf.errors import DimensionError
    from fmu_opinf.export import export_fmu

    with pytest.raises(DimensionError):
        export_fmu(files["rom"], tmp_path / "new" / "deeper" / "rom.fmu", reconstruct=["x[0]"])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("where", ["file", "run"])
def test_a_dt_attribute_that_is_not_the_stored_step_is_refused(files, tmp_path, capsys, where):
    """Attributes carry no HDF5 checksum: one flipped bit made a file's dt 0.01049 beside times 0.01 apart, and
    the fit took the step from it (audit 63: the ROM 3.0e-2 off, no word).  The stored times decide: a dt that
    is not their step is refused on load, by the API and by fit, in one line."""
    import shutil

    import h5py

    damaged = tmp_path / "s.h5"
    shutil.copy(files["snapshots"], damaged)
    with h5py.File(damaged, "r+") as f:
        holder = f if where == "file" else f["runs"][sorted(f["runs"])[0]]
        holder.attrs["dt"] = float(holder.attrs["dt"]) * (1 + 2.0**-7)   # one bit of the mantissa
    with pytest.raises(FileFormatError, match="attribute dt is 0.50390625, but the stored times are 0.5 apart"):
        Snapshots.load(damaged)
    code, err = run_main(capsys, "fit", damaged, "-o", tmp_path / "rom.h5", "-q")
    assert_one_line_error(code, err, "the file is damaged")
    assert not (tmp_path / "rom.h5").exists()
    assert Snapshots.load(files["snapshots"]).runs   # the undamaged file loads
