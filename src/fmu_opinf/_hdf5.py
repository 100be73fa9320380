"""Atomic HDF5 writing and provenance attributes shared by snapshot and ROM files."""

from __future__ import annotations

import contextlib
import datetime
import errno
import hashlib
import os
import platform
import shutil
import stat
import tempfile
from pathlib import Path
from typing import Any, Iterable, Iterator

try:
    import resource
except ImportError:  # not on Windows
    resource = None  # type: ignore[assignment]

import h5py
import numpy as np

from ._interrupts import check_interrupt
from ._validate import either
from .errors import FileFormatError

__all__ = ["atomic_h5", "atomic_path", "output_target", "check_folder_entries", "replace_together", "REPLACED",
           "write_error", "output_mode", "ensure_space", "free_space", "tool_versions", "sha256_of", "write_attrs",
           "read_attrs", "jsonable", "unreadable_file", "checksummed"]


@contextlib.contextmanager
def atomic_h5(path: str | os.PathLike, overwrite: bool = False) -> Iterator[h5py.File]:
    """Open a temporary HDF5 file next to ``path``; move it into place only on success.

    An existing file at ``path`` is never half-overwritten: until the ``with`` block ends
    without an exception the old file is untouched, and the replacement is one rename.
    The new file gets the permissions of the file it replaces, else ``0666`` minus the umask.
    Failing writes (disk full, no permission) are reported as one-line :class:`FileFormatError`.
    Just before the file is closed its attributes are sealed (:func:`fmu_opinf._seal.seal_attributes`: HDF5
    checksums only the datasets' bytes), so every snapshot and ROM file carries the seal.
    """
    from ._seal import seal_attributes

    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass {either('--force')} to replace it")
    if path.is_dir():
        raise FileFormatError(f"{path} is a directory; give a file name ending in .h5")
    with atomic_path(path) as tmp:
        ensure_space(tmp, 0, path)
        try:
            with h5py.File(tmp, "w") as f:
                yield f
                seal_attributes(f)
        except OSError as exc:
            raise write_error(path, exc) from None


@contextlib.contextmanager
def atomic_path(path: Path, output: bool = True) -> Iterator[str]:
    """A temporary file name next to ``path``, renamed to ``path`` if the block succeeds, else removed.

    Interrupts (Ctrl-C, SIGTERM turned into an exception) remove it too, so no ``.tmp`` file is left.  An
    ``output`` is listed in :data:`REPLACED` (not a file of the tool's cache).
    """
    path = output_target(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileFormatError(f"directory {parent} does not exist; create it first")
    try:
        fd, tmp = tempfile.mkstemp(prefix=path.name[:_TEMPORARY_PREFIX] + ".", suffix=".tmp", dir=parent)
    except OSError as exc:
        raise write_error(path, exc) from None
    os.close(fd)
    try:
        with _terminate_as_exception():
            yield tmp
            check_interrupt()  # a Ctrl-C that Python swallowed in a finalizer: do not replace the previous file
            os.chmod(tmp, output_mode(path))
            os.replace(tmp, path)
            if output:
                REPLACED.append(path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


#: Characters of an output's name that its temporary file's name starts with (the rest of 255 for the random part).
_TEMPORARY_PREFIX = 200

#: The outputs this process wrote or replaced since the list was last cleared (the command line clears it at the
#: start of a command and names them if it is interrupted: audit 55, ``build-fmus`` replaced one FMU of two and
#: said that none was).
REPLACED: list[Path] = []


def output_target(path: str | os.PathLike) -> Path:
    """The file an output named ``path`` replaces: ``path``, or the file a symbolic link there points to (the
    link stays); refused where that is not a regular file.  Renamed over a device, a pipe or a link, an output
    replaced them with a plain file (audit 55: ``-o /dev/null --force`` replaced the system's /dev/null)."""
    target = Path(os.path.realpath(path)) if os.path.islink(path) else Path(path)
    try:
        mode = os.stat(target).st_mode
    except OSError as exc:   # (nothing there yet, or a name the system refuses: the write says why)
        if exc.errno == errno.ELOOP:   # (audit 56: replaced by a plain file, without --force)
            raise FileFormatError(f"{path} is a loop of symbolic links; give the name of a file to write") from None
        return target
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "a device, a pipe or a socket"
        raise FileFormatError(f"{path} is {kind}, not a file; give the name of a file to write")
    return target


def check_folder_entries(folder: str | os.PathLike, names: Iterable[str] | None = None,
                         recursive: bool = False) -> None:
    """Refuse a folder of outputs (a report, figures, the demo's) holding a symbolic link or anything but plain
    files and folders among ``names`` (default: every entry; ``recursive``: in its subfolders too): its files are
    written in the folder, not through a link (audit 56: a report's ``outputs.png`` linked to the ROM being
    compared overwrote it; a pipe among the figures ended a fit in a traceback)."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    entries = folder.rglob("*") if recursive else folder.iterdir() if names is None else \
        (folder / name for name in names)
    for entry in entries:
        if entry.is_symlink() or entry.exists() and not (entry.is_file() or entry.is_dir()):
            raise FileFormatError(f"{entry} is {'a symbolic link' if entry.is_symlink() else 'not a plain file'}; "
                                  f"the files of {folder} are written there: remove it or choose another folder")


def replace_together(folder: Path, files: dict[str, bytes]) -> None:
    """Write every file under a temporary name in ``folder``, then rename them all, with interrupts deferred
    (a report's page, metrics and figures; a run table's summary and page).

    A failure while writing (a full disk) leaves the earlier files as they were and no temporary file: the
    renames, which need no space, start only once every byte is written (eleventh audit: new figures and
    metrics beside the old page after a full disk).  A link or a pipe where a file goes is refused
    (:func:`check_folder_entries`).
    """
    from ._interrupts import deferred_interrupts

    check_folder_entries(folder, files)
    temporary: dict[str, str] = {}
    try:
        for name, data in files.items():
            fd, temporary[name] = tempfile.mkstemp(prefix=name + ".", suffix=".tmp", dir=folder)
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
        with deferred_interrupts():
            for name, tmp in list(temporary.items()):
                os.chmod(tmp, output_mode(folder / name))
                os.replace(tmp, folder / name)
                del temporary[name]
            REPLACED.append(folder)
    except OSError as exc:
        raise write_error(folder / name, exc) from None
    finally:
        for tmp in temporary.values():
            with contextlib.suppress(OSError):
                os.unlink(tmp)


@contextlib.contextmanager
def _terminate_as_exception() -> Iterator[None]:
    """SIGTERM (default action: die on the spot) raises :class:`Interrupted` instead, so ``finally`` blocks
    run and temporary files are removed.  Only in the main thread and when SIGTERM has its default action."""
    import signal
    import threading

    from .errors import Interrupted

    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise Interrupted(signum)

    signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def write_error(path: Path, exc: OSError) -> FileFormatError:
    """One line for a failed write: disk full, file size limit, permission, ..."""
    text = " ".join(str(exc).split())
    if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT) or "errno = 28" in text or "errno = 27" in text \
            or "No space" in text or "too large" in text:
        return FileFormatError(f"cannot write {path}: the disk is full (or a file size limit was reached); "
                               "free space or choose another -o location, the previous file is unchanged")
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return FileFormatError(f"cannot write {path}: {exc.strerror}; choose a writable location with -o")
    return FileFormatError(f"cannot write {path} ({text[:200]}); the previous file is unchanged")


def checksummed(shape: tuple[int, ...]) -> dict[str, Any]:
    """``create_dataset`` options storing HDF5's Fletcher-32 checksum with each chunk of a dataset of ``shape``.

    HDF5 then refuses to read a chunk whose bytes changed (audit 62, finding 5: a ROM file with flipped bytes
    in ``Kr`` was read without a word).  The checksum needs a chunked dataset, which a fixed dimension of
    size 0 cannot hold (empty datasets have no bytes to check: they get none).  Readers need nothing: the filter
    is built into every HDF5 library, and files without checksums read as before.
    """
    return {"fletcher32": True} if len(shape) > 0 and all(int(d) > 0 for d in shape) else {}


def unreadable_file(path: str | os.PathLike, what: str, command: str, exc: OSError) -> FileFormatError:
    """One line for a file HDF5 cannot open: not HDF5 at all, or cut short (a copy or a download that stopped).

    Snapshot and ROM files say it alike (audit 62, finding 7: a truncated snapshot file was called "not an HDF5
    file", which a file ``fmu-opinf snapshots`` wrote and a copy cut short is not).

    Parameters
    ----------
    path : str or PathLike
        The file.
    what : str
        What it should be (``"snapshot"``, ``"ROM"``).
    command : str
        The command that writes such files (``"fmu-opinf snapshots"``), named in the fix.
    exc : OSError
        HDF5's refusal, shown shortened in parentheses.
    """
    text = " ".join(str(exc).split())[:200]
    return FileFormatError(f"cannot read {what} file {path} ({text}); it is not HDF5 or is truncated: "
                           f"restore it or write it again with '{command}'")


#: Free bytes kept beyond the next write: HDF5 chunk caches and metadata written when the file is closed.
SPACE_MARGIN = 16 * 2**20


def free_space(path: str | os.PathLike) -> float:
    """Bytes that can still be written to ``path`` (a file being written): free disk space, and the
    process's file size limit (``ulimit -f``) minus the file's current size."""
    path = Path(path)
    free = float(shutil.disk_usage(path.parent if str(path.parent) else ".").free)
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0] if resource is not None else -1
    if limit not in (-1, getattr(resource, "RLIM_INFINITY", -1)):
        size = path.stat().st_size if path.exists() else 0
        free = min(free, float(limit - size))
    return free


def ensure_space(path: str | os.PathLike, nbytes: float, target: str | os.PathLike | None = None) -> None:
    """Raise the disk-full :class:`FileFormatError` *before* writing ``nbytes`` more to ``path``.

    HDF5 cannot recover from a failed write (closing such a file may even crash the process), so writers
    stop while there is still room for the file's metadata.  ``target`` is the name shown to the user.
    """
    if free_space(path) < nbytes + SPACE_MARGIN:
        raise write_error(Path(target or path), OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))


def _umask() -> int:
    """The process umask (read from /proc without changing it; else set and restore)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def output_mode(path: Path) -> int:
    """Permission bits for a new output at ``path``: those of the file it replaces, else 0666 & ~umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~_umask()


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
#: Largest attribute value read back (names of ~10 million variables).
_LARGE_LIMIT = 256 * 2**20


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


def _decode(value: Any, where: str = "") -> Any:
    if isinstance(value, bytes):
        try:
            return value.decode()
        except UnicodeDecodeError:
            raise FileFormatError(f"{where} is not UTF-8 text; the file is damaged") from None
    if isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in "cV":
        raise FileFormatError(f"{where} has type {value.dtype}; fmu-opinf writes only text, numbers and "
                              "booleans, the file is damaged or was not written by fmu-opinf")
    if isinstance(value, np.ndarray) and value.dtype.kind in "OS":
        if value.ndim == 0:
            return _decode(value[()], where)
        items = [_decode(v, where) for v in value.flat]
        if not all(isinstance(v, str) for v in items):
            raise FileFormatError(f"{where} holds non-text objects; the file is damaged")
        return items
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_attrs(obj: h5py.HLObject) -> dict[str, Any]:
    """Read HDF5 attributes (and large values kept as datasets) back into plain Python values.

    Raises
    ------
    FileFormatError
        An attribute of a type fmu-opinf never writes (compound, complex, references, unreadable).
    """
    where = f"{obj.file.filename}:{obj.name}"
    try:
        out = {key: _decode(obj.attrs[key], f"{where} attribute {key!r}") for key in obj.attrs.keys()}
        large = obj.get(_LARGE_GROUP, getlink=True) if isinstance(obj, h5py.Group) else None
        if isinstance(large, h5py.HardLink) and isinstance(obj[_LARGE_GROUP], h5py.Group):
            for key, dataset in obj[_LARGE_GROUP].items():
                if not isinstance(dataset, h5py.Dataset):
                    raise FileFormatError(f"{where}/{_LARGE_GROUP}/{key} is not a dataset; the file is damaged")
                if dataset.size * dataset.dtype.itemsize > _LARGE_LIMIT:
                    raise FileFormatError(f"{where} attribute {key!r} declares {dataset.shape} values; "
                                          "the file is damaged or not an fmu-opinf file")
                out[key] = _decode(dataset[()], f"{where} attribute {key!r}")
    except (OSError, TypeError, ValueError, KeyError, RuntimeError) as exc:
        if isinstance(exc, FileFormatError):
            raise
        raise FileFormatError(f"cannot read the attributes of {where} ({' '.join(str(exc).split())[:160]}); "
                              "the file is damaged") from None
    return out


def jsonable(value: Any, non_finite_as_null: bool = False) -> Any:
    """Plain JSON types for nested dicts/lists of numpy scalars and arrays: non-finite floats as text (``"nan"``),
    or as None (JSON's null) with ``non_finite_as_null``, for files other programs parse (a bare NaN is not
    JSON)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v, non_finite_as_null) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v, non_finite_as_null) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist(), non_finite_as_null)
    if isinstance(value, np.generic):
        return jsonable(value.item(), non_finite_as_null)
    if isinstance(value, float) and not np.isfinite(value):
        return None if non_finite_as_null else str(value)
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)
