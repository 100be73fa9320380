"""How an FMU is packaged: one binary for two model identifiers, unpack folders with spaces, zip methods (audit 81a).

F3: FMI 2 lets model exchange and co-simulation have different model identifiers; with only one library shipped,
forcing the other interface said "no binary for this platform (linux64; it has: linux64)".  F4: FMUs that do not
percent-decode their resource URI (older OpenModelica, Reference-FMUs before #75) fail where the unpack folder has a
space or a non-ASCII letter.  F5: a Deflate64 archive was refused without naming the method or a way out.
Recordings are checked against the model's exact zero-order-hold response (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import shutil
import struct
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.errors import FMUError  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import _cosimulation, open_source  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

SIGNAL = "impulse:amplitude=100,t0=2,width=0.5;none"


@pytest.fixture(scope="module")
def both(request, tmp_path_factory) -> lti_fmus.LtiFmu:
    """An FMI 2 FMU with model exchange and co-simulation under one identifier (one library)."""
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    return lti_fmus.build_corpus(folder, ("modelica-der-aliases",))["modelica-der-aliases"]


def exact_miss(run, model) -> float:
    u = np.asarray(run.u)
    exact = lti_fmus.zoh_response(model, np.asarray(run.t), u[:, 1:]).y
    return float(np.abs(np.asarray(run.y) - exact).max() / np.ptp(exact))


@pytest.mark.parametrize("renamed, forced, other", [("CoSimulation", "cs", "me"), ("ModelExchange", "me", "cs")])
def test_the_interface_without_its_binary_is_named_with_the_fix(both, tmp_path, renamed, forced, other):
    identifier = "DerAliases"
    fmu = tmp_path / "two_ids.fmu"
    with zipfile.ZipFile(both.path) as zin, zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(f'<{renamed} modelIdentifier="{identifier}"'.encode(),
                                    f'<{renamed} modelIdentifier="{identifier}_{forced}"'.encode(), 1)
            if not item.filename.startswith("sources/"):   # (with sources, both would be compiled here)
                zout.writestr(item, data)
    with pytest.raises(FMUError) as caught:
        open_source(str(fmu), interface=forced)
    text = str(caught.value)
    mine = "co-simulation" if forced == "cs" else "model exchange"
    assert f"has no {mine} binary for this platform" in text and f"{identifier}_{forced}.* is missing" in text
    assert f"use --interface {other}" in text and "it has: " not in text
    run = record(str(fmu), SIGNAL, 0.05, 20.0, quiet=True).runs[0]   # auto takes the interface with the binary
    assert exact_miss(run, both.model) < (1e-8 if other == "me" else 1e-5)


def test_the_unpack_folder_avoids_a_temporary_folder_with_spaces(both, tmp_path, monkeypatch):
    odd = tmp_path / "tmp dir ü"
    odd.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(odd))
    source = open_source(str(both.path))
    folder = source._extracted()
    assert "%" not in Path(folder).as_uri() and not folder.startswith(str(odd))
    assert exact_miss(record(source, SIGNAL, 0.05, 20.0, quiet=True).runs[0], both.model) < 1e-8


def test_a_failed_instantiation_in_a_folder_with_spaces_says_what_to_do(both, tmp_path, monkeypatch):
    folder = tmp_path / "dir with spaces ü" / "unpacked"
    folder.mkdir(parents=True)
    with zipfile.ZipFile(both.path) as archive:
        archive.extractall(folder)

    def refusing(self, *args, **kwargs):   # as an FMU that reads its resources through the undecoded URI
        raise RuntimeError("cannot open resource file")

    monkeypatch.setattr(_cosimulation.FMUSource, "_instantiate", refusing)
    with pytest.raises(FMUError) as caught:
        record(str(folder), SIGNAL, 0.05, 5.0, quiet=True)
    text = str(caught.value)
    assert "failed to instantiate (cannot open resource file)" in text
    assert "%20" in text and "unpack the FMU into a folder whose path has neither" in text


def deflate64(src: Path, dst: Path) -> Path:
    """``src`` re-zipped with stored members marked as Deflate64 (method 9): a stored deflate block is the same in
    both, and Python refuses the method as 7-Zip's archives make it."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_STORED) as zout:
        for item in zin.infolist():
            zout.writestr(item.filename, zin.read(item))
    data = bytearray(dst.read_bytes())
    for signature, offset in ((b"PK\x03\x04", 8), (b"PK\x01\x02", 10)):
        at = data.find(signature)
        while at >= 0:
            struct.pack_into("<H", data, at + offset, 9)
            at = data.find(signature, at + 4)
    dst.write_bytes(bytes(data))
    return dst


def test_a_deflate64_fmu_is_refused_naming_the_method_and_the_fix(both, tmp_path):
    fmu = deflate64(both.path, tmp_path / "d64.fmu")
    with zipfile.ZipFile(fmu) as archive:
        assert {item.compress_type for item in archive.infolist()} == {9}
    with pytest.raises(FMUError) as caught:
        open_source(str(fmu))
    text = str(caught.value)
    assert "Deflate64 (zip method 9" in text and "only store and deflate" in text and "re-zip it with deflate" in text
    unpacked = tmp_path / "unpacked"   # the way out it names: the unpacked folder
    with zipfile.ZipFile(both.path) as archive:
        archive.extractall(unpacked)
    shutil.rmtree(unpacked / "sources", ignore_errors=True)
    assert exact_miss(record(str(unpacked), SIGNAL, 0.05, 20.0, quiet=True).runs[0], both.model) < 1e-8
