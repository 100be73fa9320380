"""A per-user cache of the object files that an FMU build compiles, keyed by what the compiler sees.

Exporting a ROM compiles four C files, of which the shared kernel (``newmark.c``) and the FMI layer take most of the
compiler's time and do not change from one export to the next of a ROM of the same sizes.  Each object file is
stored under a key: the SHA-256 of the compiler's identity (its ``-v`` report and the size and time of its
executable), the code-generation flags, the source's file name and the preprocessed translation unit (the source with
every header and definition expanded, so that a changed source, header, ``config.h`` or flag gives another key).  A
cached file holds its key and the SHA-256 of the object in a header that is checked before the object is used: a
damaged or truncated file, or one stored under another key, is compiled anew.  Files are written through a temporary
file renamed into place, only into a folder of this user that nobody else can write (linked into a binary that is
loaded, an object is code; :func:`fmu_opinf.sources._compiled_rk._trusted`).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import Sequence

__all__ = ["object_key", "restore", "store"]

#: First line of a cache file (its format's version).
_MAGIC = b"fmu-opinf object file 1\n"

#: Most object files kept; storing one more removes the least recently used (an object is 20-60 kB).
MAX_ENTRIES = 256


def _folder() -> Path:
    """``objects/`` in the per-user cache folder (``$FMU_OPINF_CACHE_DIR``, else e.g. ``~/.cache/fmu-opinf``)."""
    from .fmus import _user_cache_dir

    return _user_cache_dir() / "objects"


@functools.lru_cache(maxsize=None)
def _compiler_report(compiler: tuple[str, ...]) -> bytes:
    """What ``compiler -v`` says about itself (version, target, configuration), once per process and compiler."""
    try:
        result = subprocess.run([*compiler, "-v"], capture_output=True, timeout=60, check=False)
    except (OSError, subprocess.SubprocessError):
        return b""
    return result.stdout + result.stderr


def compiler_identity(compiler: Sequence[str]) -> bytes:
    """The compiler's command, its ``-v`` report, and the size and modification time of its executable: an
    upgraded or replaced compiler gives other keys, so that no object of the old one is linked with the new one's."""
    executable = shutil.which(compiler[0]) or compiler[0]
    try:
        status = os.stat(executable)
        stamp = f"{status.st_size}:{status.st_mtime_ns}"
    except OSError:
        stamp = "missing"
    return b"\0".join([*(part.encode() for part in compiler), stamp.encode(), _compiler_report(tuple(compiler))])


def object_key(compiler: Sequence[str], flags: Sequence[str], name: str, preprocessed: bytes) -> str:
    """The cache key of one object file.

    Parameters
    ----------
    compiler : sequence of str
        The compiler command (:func:`fmu_opinf.fmus.find_c_compiler`).
    flags : sequence of str
        Every flag of the compilation other than include folders, input and output (include folders only decide
        which headers are read, and those are in ``preprocessed``).
    name : str
        The source's file name (the object file records it).
    preprocessed : bytes
        The compiler's preprocessed output of the source with the same flags and include folders.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    digest = hashlib.sha256()
    for part in (compiler_identity(compiler), "\0".join(flags).encode(), name.encode(), preprocessed):
        digest.update(len(part).to_bytes(8, "little") + part)
    return digest.hexdigest()


def _entry(key: str) -> Path:
    return _folder() / f"{key}.o"


def _unpacked(data: bytes, key: str) -> bytes | None:
    """The object in a cache file's ``data`` if its header names ``key`` and its object's SHA-256, else None."""
    header_size = len(_MAGIC) + 2 * 65
    if len(data) < header_size or not data.startswith(_MAGIC):
        return None
    stored_key, checksum = data[len(_MAGIC):header_size].decode("ascii", "replace").split("\n")[:2]
    payload = data[header_size:]
    if stored_key != key or checksum != hashlib.sha256(payload).hexdigest():
        return None
    return payload


def restore(key: str, target: Path) -> bool:
    """Write the cached object of ``key`` to ``target``; False (nothing written) where there is none, or it is
    damaged, stored under another key, or could have been written by another user."""
    from .sources._compiled_rk import _trusted

    path = _entry(key)
    if not _trusted(path):
        return False
    try:
        payload = _unpacked(path.read_bytes(), key)
    except OSError:
        return False
    if payload is None:
        return False
    target.write_bytes(payload)
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used: kept by the pruning
    return True


def store(key: str, compiled: Path) -> None:
    """Keep the object file ``compiled`` under ``key``, written atomically; a cache folder that cannot be written
    (read-only, full disk, another user's) only means that the next build compiles again."""
    from ._hdf5 import atomic_path
    from .errors import FmuOpinfError
    from .sources._compiled_rk import _private

    folder = _folder()
    _private(folder)
    try:
        payload = compiled.read_bytes()
        with atomic_path(_entry(key), output=False) as temporary:
            Path(temporary).write_bytes(_MAGIC + f"{key}\n{hashlib.sha256(payload).hexdigest()}\n".encode() + payload)
        os.chmod(_entry(key), 0o644)  # not writable by others, else never trusted
    except (OSError, FmuOpinfError):
        return
    _prune(folder)


def _prune(folder: Path) -> None:
    """Remove the least recently used object files beyond :data:`MAX_ENTRIES`."""
    try:
        entries = sorted(folder.glob("*.o"), key=lambda path: path.stat().st_mtime_ns)
    except OSError:
        return
    for path in entries[:max(0, len(entries) - MAX_ENTRIES)]:
        with contextlib.suppress(OSError):
            path.unlink()
