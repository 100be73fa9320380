"""Audit86 F3: ``fit`` of a recording with several hundred outputs (a chatty FMU recorded without ``--outputs``).

A 6-mass chain with 300 outputs, recorded with the defaults (two runs of 6526 samples, outputs stored in chunks of
all 300 rows by 436 columns, gzip): ``fit`` took 44.5 s wall, of which the fit itself 1.2 s; the profile put 86 of
98 s in :func:`fmu_opinf.fit._output_peak` (the training's output peaks kept in the provenance for ``compare``),
which read the outputs one row at a time, so every compressed chunk was read and inflated once per output: time
grows with the square of the outputs.  Now each chunk is read once (measured 7.4 s wall for the whole fit, 0.07 s
CPU for the peaks of one run).
"""

from __future__ import annotations

import math

import h5py
import numpy as np

from fmu_opinf.fit import _output_peak

P, K, CHUNK = 300, 5000, 436


class _CountedReads:
    """An HDF5 dataset that counts the reads made of it."""

    def __init__(self, dataset: h5py.Dataset) -> None:
        self.dataset, self.reads = dataset, 0
        self.shape, self.chunks = dataset.shape, dataset.chunks

    def __getitem__(self, key):
        self.reads += 1
        return self.dataset[key]


def test_each_chunk_of_the_outputs_is_read_once_for_their_peaks(tmp_path):
    """Before: 300 reads, each inflating all 12 chunks; now 13 (the first column, then each chunk of columns).  The
    peaks are those of the whole array read at once."""
    rng = np.random.default_rng(86)
    y = np.cumsum(rng.standard_normal((P, K)), axis=1) + rng.standard_normal((P, 1))
    with h5py.File(tmp_path / "y.h5", "w") as f:
        f.create_dataset("y", data=y, chunks=(P, CHUNK), compression="gzip")
    with h5py.File(tmp_path / "y.h5", "r") as f:
        counted = _CountedReads(f["y"])
        peaks = _output_peak(counted)
    assert counted.reads <= math.ceil(K / CHUNK) + 1
    assert peaks == [float(v) for v in np.abs(y - y[:, :1]).max(axis=1)]


def test_the_peaks_of_an_array_are_its_largest_departures_from_the_start():
    y = np.array([[1.0, 3.0, -2.0], [0.0, 0.0, 0.0], [5.0, 4.0, 7.5]])
    assert _output_peak(y) == [3.0, 0.0, 2.5]
    assert _output_peak(np.zeros((2, 0))) is None and _output_peak(None) is None
