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

__all__ = ["atomic_h5", "tool_versions", "sha256_of", "write_attrs", "read_attrs", "jsonable"]


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
    # the cvxpy module comes from the "cvxpy-base" distribution (the dependency) or from "cvxpy"
    for key, dists in (("fmu-opinf", ("fmu-opinf",)), ("numpy", ("numpy",)), ("scipy", ("scipy",)),
                       ("fmpy", ("fmpy",)), ("cvxpy", ("cvxpy", "cvxpy-base")), ("clarabel", ("clarabel",)),
                       ("h5py", ("h5py",))):
        versions[key] = "not installed"
        for dist in dists:
            try:
                versions[key] = md.version(dist)
                break
            except md.PackageNotFoundError:
                continue
    versions["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return versions


def sha256_of(path: str | os.PathLike) -> str:
    """SHA-256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


#: Values larger than this go into datasets: HDF5 object headers hold at most 64 KiB of attributes.
LARGE_ATTRIBUTE_BYTES = 16 * 1024
_LARGE_GROUP = "_attrs"


def _encode(value: Any) -> Any:
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        return np.array(value, dtype=h5py.string_dtype())
    if isinstance(value, dict):
        import json

        return json.dumps(value)
    return value


def _nbytes(value: Any) -> int:
    if isinstance(value, str):
        return len(value.encode())
    if isinstance(value, np.ndarray) and value.dtype.kind == "O":
        return sum(len(str(v)) + 16 for v in value.flat)
    return int(np.asarray(value).nbytes)


def write_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    """Store a flat dict as HDF5 attributes; ``None`` is skipped, lists of str become str arrays,
    dicts become JSON text.

    A value too large for an object header (e.g. the names of a million variables) is stored
    as a dataset in the group's ``_attrs`` subgroup instead; :func:`read_attrs` merges it back.
    """
    for key, value in attrs.items():
        if value is None:
            continue
        encoded = _encode(value)
        if isinstance(obj, h5py.Group) and _nbytes(encoded) > LARGE_ATTRIBUTE_BYTES:
            large = obj.require_group(_LARGE_GROUP)
            if key in large:
                del large[key]
            if isinstance(encoded, str):
                large.create_dataset(key, data=encoded, dtype=h5py.string_dtype())
            else:
                large.create_dataset(key, data=encoded, compression="gzip", compression_opts=1)
        else:
            obj.attrs[key] = encoded


def _decode(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray) and value.dtype.kind in "OS":
        if value.ndim == 0:
            return _decode(value[()])
        return [v.decode() if isinstance(v, bytes) else str(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_attrs(obj: h5py.HLObject) -> dict[str, Any]:
    """Read HDF5 attributes (and large values kept as datasets) back into plain Python values."""
    out = {key: _decode(value) for key, value in obj.attrs.items()}
    if isinstance(obj, h5py.Group) and isinstance(obj.get(_LARGE_GROUP), h5py.Group):
        for key, dataset in obj[_LARGE_GROUP].items():
            out[key] = _decode(dataset[()])
    return out


def jsonable(value: Any) -> Any:
    """Plain JSON types for nested dicts/lists of numpy scalars and arrays (non-finite floats as text)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
