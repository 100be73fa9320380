"""Atomic HDF5 writing and provenance attributes shared by snapshot and ROM files."""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import os
import platform
import tempfile
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from .errors import FileFormatError

__all__ = ["atomic_h5", "tool_versions", "sha256_of", "write_attrs", "read_attrs"]


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, overwrite: bool = False) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file next to ``path``; move it into place only on success.

    An existing file at ``path`` is never half-overwritten: until the ``with`` block ends
    without an exception the old file is untouched, and the replacement is one rename.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--force) to replace it")
    if path.is_dir():
        raise FileFormatError(f"{path} is a directory; give a file name ending in .h5")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise FileFormatError(f"directory {parent} does not exist; create it first")
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=parent)
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def tool_versions() -> dict[str, str]:
    """Versions of the tool and the libraries whose results it stores."""
    import importlib.metadata as md

    versions = {"python": platform.python_version(), "platform": platform.platform()}
    for dist in ("fmu-opinf", "numpy", "scipy", "fmpy", "cvxpy", "clarabel", "h5py"):
        try:
            versions[dist] = md.version(dist)
        except md.PackageNotFoundError:
            versions[dist] = "not installed"
    versions["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return versions


def sha256_of(path: str | os.PathLike) -> str:
    """SHA-256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    """Store a flat dict as HDF5 attributes; ``None`` is skipped, lists of str kept as str arrays."""
    for key, value in attrs.items():
        if value is None:
            continue
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            obj.attrs[key] = np.array(value, dtype=h5py.string_dtype())
        elif isinstance(value, dict):
            import json

            obj.attrs[key] = json.dumps(value)
        else:
            obj.attrs[key] = value


def read_attrs(obj: h5py.HLObject) -> dict[str, Any]:
    """Read HDF5 attributes back into plain Python values (str arrays become lists)."""
    out: dict[str, Any] = {}
    for key, value in obj.attrs.items():
        if isinstance(value, bytes):
            value = value.decode()
        elif isinstance(value, np.ndarray) and value.dtype.kind in "OS":
            value = [v.decode() if isinstance(v, bytes) else str(v) for v in value]
        elif isinstance(value, np.generic):
            value = value.item()
        out[key] = value
    return out
