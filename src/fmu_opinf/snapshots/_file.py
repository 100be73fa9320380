"""The HDF5 layout of snapshot files (docs/file-format.md): attributes, chunked datasets, atomic writes."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

from .._hdf5 import atomic_h5, checksummed, ensure_space, write_attrs
from .._validate import either
from ..errors import FileFormatError

if TYPE_CHECKING:
    from ._data import Run

__all__ = ["LAYOUT_VERSION", "FILE_KIND", "ARRAYS", "INITIAL", "MODEL_START", "write_initial_state", "atomic", "decode",
           "write_file_attrs", "create_dataset", "write_run", "write_model_start", "read_model_start"]

#: Version of the HDF5 layout written by this package (docs/file-format.md).
LAYOUT_VERSION = 2
FILE_KIND = "fmu-opinf snapshots"
ARRAYS = ("t", "u", "x", "xdot", "xddot", "y")
#: Per-run initial state datasets (layout 2; layout 1 files take the first samples instead).
INITIAL = ("x0", "v0")
#: Run attribute (JSON) and dataset prefix of the model's own start recorded beside a run table row with ``start:``
#: values (layout 2, since 2026-12-07: :mod:`fmu_opinf._model_start`); datasets ``model_start_x0``, ``model_start_v0``.
MODEL_START = "model_start"
_JSON_ATTRS = ("system_options", "fmu_parameters", "fmu_settings", "variable_selection", "versions", "auto_window",
               "source_parameters", "port_aliases", "type_definitions",
               "unit_definitions", "initialization", "fmi3_ports", "held_inputs", "merged_parts",
               MODEL_START)


@contextlib.contextmanager
def atomic(path: Path, overwrite: bool) -> Iterator[h5py.File]:
    """:func:`atomic_h5` with an existing file reported as a one-line :class:`FileFormatError`."""
    if path.exists() and not overwrite:
        raise FileFormatError(f"{path} exists; pass {either('--force')} to replace it")
    with atomic_h5(path, overwrite=overwrite) as f:
        yield f


def decode(attrs: dict[str, Any]) -> dict[str, Any]:
    """Parse the JSON-valued attributes back into dicts."""
    for key in _JSON_ATTRS:
        if isinstance(attrs.get(key), str):
            try:
                attrs[key] = json.loads(attrs[key])
            except ValueError:
                raise FileFormatError(f"attribute {key!r} is not valid JSON; the file is damaged") from None
            if not isinstance(attrs[key], dict):
                raise FileFormatError(f"attribute {key!r} holds JSON {type(attrs[key]).__name__}, expected an "
                                      "object; the file is damaged")
    return attrs


def write_file_attrs(f: h5py.File, attrs: dict[str, Any]) -> None:
    attrs = dict(attrs)
    attrs["kind"] = FILE_KIND
    attrs["layout_version"] = LAYOUT_VERSION
    write_attrs(f, attrs)


def _chunks(shape: tuple[int, ...]) -> tuple[int, ...]:
    """About 1 MiB chunks holding whole columns (time samples) when possible."""
    shape = tuple(max(int(d), 1) for d in shape)
    if len(shape) == 1:
        return (min(shape[0], 131072),)
    rows, k = shape
    cols = max(1, min(k, 2**20 // (8 * rows)))
    return (min(rows, max(1, 2**20 // (8 * cols))), cols)


def create_dataset(group: h5py.Group, name: str, shape: tuple[int, ...]) -> h5py.Dataset:
    """A chunked, gzip-compressed float64 dataset resizable along time, with a checksum per chunk
    (:func:`~fmu_opinf._hdf5.checksummed`: HDF5 refuses changed bytes instead of reading them)."""
    # a fixed size of 0 (no inputs: m = 0) cannot hold a chunk of 1; leave such dimensions unlimited
    maxshape = tuple(None if d == 0 else d for d in shape[:-1]) + (None,)
    return group.create_dataset(name, shape=shape, dtype="f8", maxshape=maxshape, chunks=_chunks(shape),
                                compression="gzip", compression_opts=1, shuffle=True, fletcher32=True)


def write_initial_state(group: h5py.Group, x0: Any, v0: Any) -> None:
    """The run's initial positions and velocities as small datasets ``x0``, ``v0`` (layout 2)."""
    for name, values in (("x0", x0), ("v0", v0)):
        data = np.asarray(values, dtype=float).reshape(-1)
        group.create_dataset(name, data=data, **checksummed(data.shape))


def write_run(runs: h5py.Group, index: int, run: Run) -> None:
    g = runs.create_group(f"{index:04d}")
    for name, array in run.arrays().items():
        ds = create_dataset(g, name, tuple(array.shape))
        k = array.shape[-1]
        step = max(1, ds.chunks[-1] * 64) if ds.chunks else k
        for j0 in range(0, k, step):
            ensure_space(runs.file.filename, 8.0 * ds.size / max(k, 1) * min(step, k - j0))
            ds[..., j0:j0 + step] = np.ascontiguousarray(array[..., j0:j0 + step])
    write_initial_state(g, run.x0, run.v0)
    write_model_start(g, run.model_start)
    write_attrs(g, run.attrs)


def write_model_start(group: h5py.Group, start: dict[str, Any] | None) -> None:
    """The model's own start of a run (``{"x0": positions, "v0": velocities}``, ``v0`` absent where the source's
    velocities are derived) as datasets ``model_start_x0``, ``model_start_v0``; nothing for None.  Its provenance is
    the run attribute ``model_start`` (written with the other attributes)."""
    for name, values in (start or {}).items():
        data = np.asarray(values, dtype=float).reshape(-1)
        key = f"{MODEL_START}_{name}"
        if key in group:
            del group[key]
        group.create_dataset(key, data=data, **checksummed(data.shape))


def read_model_start(group: h5py.Group, attrs: dict[str, Any], n: int, label: str) -> dict[str, np.ndarray] | None:
    """The model's own start stored with a run (:func:`write_model_start`), or None where the run has none (a file
    written before 2026-12-07, a run that is no run table row with ``start:`` values, or one whose start could
    not be read when it was recorded: its attribute ``model_start`` then says why).

    Raises
    ------
    FileFormatError
        A stored start that is not ``n`` finite numbers, or provenance that promises a start the run lacks.
    """
    found = {}
    for name in ("x0", "v0"):
        key = f"{MODEL_START}_{name}"
        if key in group:
            data = np.asarray(group[key][()], dtype=float)
            if data.shape != (n,) or not np.all(np.isfinite(data)):
                raise FileFormatError(f"{label}: {key} is not {n} finite numbers (one per position); the file is "
                                      "damaged: record the snapshots again")
            found[name] = data
    provenance = attrs.get(MODEL_START)
    if isinstance(provenance, dict) and "reason" not in provenance and "x0" not in found:
        raise FileFormatError(f"{label}: its attribute {MODEL_START} names a stored start but {MODEL_START}_x0 is "
                              "missing; the file is damaged: record the snapshots again")
    return found or None
