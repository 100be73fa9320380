"""Folders that hold an unpacked FMU: made for one process, removed with its source object, and swept up by the
next fmu-opinf process where their owner was killed before it could remove them.

A process ended by SIGKILL (or the OOM killer, or a power-off of a container) runs no finalizer, so its unpack
folder stays behind in the temporary folder: one FMU's binaries and resources per killed run.  Each folder holds
a small owner file naming the process (its PID and, on Linux, its start time, so that a recycled PID is not taken
for the owner); making a new folder removes the folders in the same place whose owner is gone.  A folder without
an owner file (one being made, or left by an older version) is never touched.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

PREFIX = "fmu_opinf_"
OWNER_FILE = ".fmu-opinf-owner"


def make_unpack_folder(parent: str | None = None) -> str:
    """A new empty folder in ``parent`` (None: the temporary folder) owned by this process, after removing the
    folders there that a killed process left behind.

    Parameters
    ----------
    parent : str or None
        Where to make the folder.

    Returns
    -------
    str
        The folder's path.
    """
    remove_orphans(parent)
    folder = tempfile.mkdtemp(prefix=PREFIX, dir=parent)
    try:
        Path(folder, OWNER_FILE).write_text(_identity(os.getpid()) or str(os.getpid()), encoding="ascii")
    except OSError:
        pass   # (the folder then stays unswept if its owner is killed, as before)
    return folder


def remove_orphans(parent: str | None = None) -> list[str]:
    """Remove the unpack folders in ``parent`` (None: the temporary folder) whose owning process has ended.

    Returns
    -------
    list of str
        The folders removed.
    """
    try:
        candidates = list(Path(parent or tempfile.gettempdir()).glob(PREFIX + "*"))
    except OSError:
        return []
    removed = []
    for folder in candidates:
        owner = _owner(folder)
        if owner is not None and not _alive(owner):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(str(folder))
    return removed


def _owner(folder: Path) -> str | None:
    """The owner file's text, or None where the folder has none (or is no folder, or not ours to read)."""
    try:
        if folder.is_symlink() or not folder.is_dir():
            return None
        return folder.joinpath(OWNER_FILE).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None


def _alive(owner: str) -> bool:
    """Whether the process an owner file names still runs (unreadable text counts as alive: never remove a folder
    on a guess)."""
    pid_text = owner.split()[0] if owner.split() else ""
    if not pid_text.isdigit():
        return True
    pid = int(pid_text)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True   # (it exists, as another user's process)
    now = _identity(pid)
    return now is None or " " not in owner or now == owner


def _identity(pid: int) -> str | None:
    """``"<pid> <start time in clock ticks since boot>"`` on Linux, None where /proc does not say."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()
    return f"{pid} {fields[19]}" if len(fields) > 19 else None
