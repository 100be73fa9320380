"""A SHA-256 seal over every attribute of an HDF5 file fmu-opinf writes (docs/file-format.md, "Attribute seal").

HDF5's Fletcher-32 checksums (:func:`fmu_opinf._hdf5.checksummed`) cover the bytes of datasets, not attributes:
a flipped byte in ``input_names``, a unit or the provenance was read without a word.  :func:`seal_attributes`
stores the digest of all attributes (and of the large values kept as datasets in ``_attrs`` groups) as the root
attribute :data:`SEAL_ATTR` just before a file is closed; :func:`check_seal` recomputes it when a file is read.

The digest is canonical: it depends on the names, types and values of the attributes, never on the order in
which the HDF5 library lists them, on how a string is stored (variable or fixed length) or on byte order.
"""

from __future__ import annotations

import hashlib
import os
from typing import Any

import h5py
import numpy as np

from .errors import FileFormatError

__all__ = ["SEAL_ATTR", "attribute_digest", "check_seal", "seal_attributes"]

#: Root attribute holding the seal: 64 lowercase hexadecimal digits of a SHA-256 digest.
SEAL_ATTR = "attributes_sha256"
#: Group holding the attribute values too large for an object header (:func:`fmu_opinf._hdf5.write_attrs`).
_LARGE_GROUP = "_attrs"
#: Prefix of the hashed text, naming the encoding (a future encoding gets another prefix).
_ENCODING = b"fmu-opinf attribute seal 1\n"


def _frame(data: bytes) -> bytes:
    """``data`` preceded by its length (8 bytes, little-endian), so that concatenated fields cannot be confused."""
    return len(data).to_bytes(8, "little") + data


def _text_bytes(item: Any) -> bytes:
    """The stored bytes of one text element: h5py returns undecodable UTF-8 as surrogate escapes, undone here."""
    if isinstance(item, (bytes, np.bytes_)):
        return bytes(item)
    return str(item).encode("utf-8", "surrogateescape")


def _text_items(array: np.ndarray) -> list[bytes]:
    """The stored bytes of the elements of a text array, in C order.

    Text datasets (the large values of ``_attrs``) read as bytes and are taken as they are: a million names are
    hashed in a fraction of a second (converting each one took longer than reading them).
    """
    items = array.reshape(-1).tolist()
    if all(type(item) is bytes for item in items):
        return items
    return [_text_bytes(item) for item in items]


def _value_fields(value: Any) -> list[bytes]:
    """Canonical fields of one attribute value: a type tag, the shape, then the contents.

    Text (variable or fixed length) is tagged ``text``: the lengths of all elements (8 bytes each, little-endian)
    then their bytes, in C order.  Numbers and booleans are tagged with their little-endian numpy type (``<f8``,
    ``<i8``, ``|b1``) and hashed as little-endian bytes in C order.  An HDF5 empty value is tagged ``empty``.
    """
    if isinstance(value, h5py.Empty):
        return [b"empty", b"", b""]
    array = np.asarray(value)
    shape = ",".join(map(str, array.shape)).encode()
    if array.dtype.kind in "OSU":
        items = _text_items(array)
        lengths = np.fromiter(map(len, items), dtype="<u8", count=len(items))
        return [b"text", shape, lengths.tobytes() + b"".join(items)]
    little = array.astype(array.dtype.newbyteorder("<"), copy=False)
    return [little.dtype.str.encode(), shape, np.ascontiguousarray(little).tobytes()]


def _objects(f: h5py.File) -> list[tuple[str, h5py.HLObject]]:
    """Every group and dataset of ``f`` with its path, the root first, sorted by the UTF-8 bytes of the path."""
    found: list[tuple[str, h5py.HLObject]] = [("/", f)]

    def collect(name: str, obj: h5py.HLObject) -> None:
        found.append(("/" + name, obj))

    f.visititems(collect)
    return sorted(found, key=lambda item: item[0].encode("utf-8", "surrogateescape"))


def _is_large_value(obj: h5py.HLObject) -> bool:
    """Whether ``obj`` is an attribute value kept as a dataset in an ``_attrs`` group."""
    return isinstance(obj, h5py.Dataset) and obj.parent.name.rsplit("/", 1)[-1] == _LARGE_GROUP


def attribute_digest(f: h5py.File) -> str:
    """SHA-256 (hexadecimal) of every attribute of ``f`` but the seal itself.

    The hashed text is :data:`_ENCODING`, then for each object in :func:`_objects` order: for each of its
    attributes, sorted by the UTF-8 bytes of their names, the framed (:func:`_frame`) fields ``attribute``, the
    object's path, the attribute's name and :func:`_value_fields`; for a dataset of an ``_attrs`` group, the
    framed fields ``value``, its path and :func:`_value_fields` of its contents.  The seal (:data:`SEAL_ATTR`
    of the root) is left out.

    Parameters
    ----------
    f : h5py.File
        An open file (any mode).

    Returns
    -------
    str
        64 lowercase hexadecimal digits.
    """
    digest = hashlib.sha256(_ENCODING)
    for path, obj in _objects(f):
        names = sorted(obj.attrs.keys(), key=lambda name: name.encode("utf-8", "surrogateescape"))
        for name in names:
            if path == "/" and name == SEAL_ATTR:
                continue
            fields = [b"attribute", path.encode("utf-8", "surrogateescape"),
                      name.encode("utf-8", "surrogateescape"), *_value_fields(obj.attrs[name])]
            digest.update(b"".join(map(_frame, fields)))
        if _is_large_value(obj):
            fields = [b"value", path.encode("utf-8", "surrogateescape"), *_value_fields(obj[()])]
            digest.update(b"".join(map(_frame, fields)))
    return digest.hexdigest()


def seal_attributes(f: h5py.File) -> None:
    """Store :func:`attribute_digest` of ``f`` as its root attribute :data:`SEAL_ATTR` (replacing an older seal).

    Called last before a file is closed (:func:`fmu_opinf._hdf5.atomic_h5`) and after any later change of its
    attributes (a run table's stamp), so that the seal describes the attributes as they are left.
    """
    f.attrs[SEAL_ATTR] = attribute_digest(f)


def check_seal(f: h5py.File, path: str | os.PathLike) -> None:
    """Refuse a file whose attributes do not match its seal; a file without a seal (older) passes.

    Parameters
    ----------
    f : h5py.File
        The open file (links already refused: the digest reads every object).
    path : str or PathLike
        The file's name, for the message.

    Raises
    ------
    FileFormatError
        The seal is not a SHA-256 in hexadecimal, or the attributes' digest differs from it: an attribute
        changed after the file was written.  The one-line message names both ways out: restore or write the file
        again, or, for a deliberate change, the statement that deletes the seal (:func:`unseal_statement`).
    """
    from ._validate import RESTORE

    if SEAL_ATTR not in f.attrs:
        return
    stored = f.attrs[SEAL_ATTR]
    stored = _text_bytes(stored).decode("ascii", "replace") if np.ndim(stored) == 0 else ""
    if stored != attribute_digest(f):
        raise FileFormatError(f"cannot read {path} (its attributes do not match their SHA-256 seal {SEAL_ATTR!r}: "
                              f"they changed after the file was written); if the file is damaged, {RESTORE}; "
                              f"if you changed an attribute on purpose, {unseal_statement(path)}")


def unseal_statement(path: str | os.PathLike) -> str:
    """The documented way to accept a deliberate change of attributes (docs/file-format.md, "Attribute seal"):
    the Python statement that deletes the seal of ``path``, after which the file is read as an unsealed one.

    Parameters
    ----------
    path : str or PathLike
        The sealed file.

    Returns
    -------
    str
        Text naming the statement, with the path as a Python string literal (quotes in it stay valid).
    """
    return (f"delete the seal in Python (the file's attributes are then read unchecked): "
            f"with h5py.File({os.fspath(path)!r}, 'r+') as f: del f.attrs[{SEAL_ATTR!r}]")
