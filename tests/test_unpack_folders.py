"""Unpack folders left by a killed process are removed by the next one (sources/_unpack.py).

Found in the temporary folder of the development machine on 2026-12-07: 34 unpacked copies of one test FMU, one
per full test run, from the test that SIGKILLs a recording command (no finalizer runs on SIGKILL)."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fmu_opinf.sources import _unpack

pytestmark = pytest.mark.skipif(not Path(f"/proc/{os.getpid()}/stat").exists(), reason="needs /proc (Linux)")


def _folder_of_a_process(tmp_path: Path, fmu: Path) -> tuple[subprocess.Popen, Path]:
    """A Python process that opened ``fmu`` (unpacking it under ``tmp_path``) and waits; its unpack folder."""
    script = textwrap.dedent(f"""
        import sys, time
        from fmu_opinf.sources import FMUSource
        source = FMUSource({str(fmu)!r})
        print(source._extracted(), flush=True)
        time.sleep(600)
    """)
    environment = dict(os.environ, TMPDIR=str(tmp_path), PYTHONPATH=os.pathsep.join(sys.path))
    process = subprocess.Popen([sys.executable, "-c", script], env=environment, stdout=subprocess.PIPE, text=True)
    folder = Path(process.stdout.readline().strip())
    return process, folder


def test_the_folder_of_a_killed_process_is_removed_and_a_live_ones_kept(tmp_path, toys):
    killed, killed_folder = _folder_of_a_process(tmp_path, toys["fmi3"])
    living, living_folder = _folder_of_a_process(tmp_path, toys["fmi3"])
    try:
        assert killed_folder.parent == tmp_path and (killed_folder / "modelDescription.xml").is_file()
        killed.send_signal(signal.SIGKILL)
        killed.wait()
        assert killed_folder.is_dir()   # (SIGKILL: nothing of the process ran)
        unowned = tmp_path / "fmu_opinf_unowned"   # (being made, or left by an older version)
        unowned.mkdir()
        mine = _unpack.make_unpack_folder(str(tmp_path))
        assert not killed_folder.exists()
        assert living_folder.is_dir() and unowned.is_dir() and Path(mine).is_dir()
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted([living_folder.name, "fmu_opinf_unowned",
                                                                     Path(mine).name])
    finally:
        living.kill()
        living.wait()
    assert _unpack.remove_orphans(str(tmp_path)) == [str(living_folder)]


def test_a_recycled_pid_is_not_taken_for_the_owner(tmp_path):
    """The owner file names the process's start time too: a new process that got the dead owner's PID (here: this
    one, with another start time) does not keep the folder alive."""
    recycled, current, garbled = (tmp_path / f"fmu_opinf_{name}" for name in ("recycled", "current", "garbled"))
    for folder in (recycled, current, garbled):
        folder.mkdir()
    pid, started = _unpack._identity(os.getpid()).split()
    (recycled / _unpack.OWNER_FILE).write_text(f"{pid} {int(started) - 1}")
    (current / _unpack.OWNER_FILE).write_text(f"{pid} {started}")
    (garbled / _unpack.OWNER_FILE).write_text("not a pid")
    assert _unpack.remove_orphans(str(tmp_path)) == [str(recycled)]
    assert current.is_dir() and garbled.is_dir()


def test_a_link_named_like_an_unpack_folder_is_not_followed(tmp_path):
    """A symbolic link in the temporary folder (anyone may make one there) never leads the sweep elsewhere."""
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / _unpack.OWNER_FILE).write_text("999999999 1")   # (no such process)
    (target / "keep").write_text("x")
    (tmp_path / "fmu_opinf_link").symlink_to(target)
    assert _unpack.remove_orphans(str(tmp_path)) == []
    assert (target / "keep").is_file()
