"""FMUs that ship only C sources for this platform are compiled once into the cache and run like the others.

Exporters that cross-compile (a Windows tool: ``binaries/win64`` only) or export source-code FMUs leave a Linux
user with ``sources/``; the seventh audit's source-only FMU was refused, and the ``fmpy compile`` it was told to run
failed on its description (units without definitions).  The FMUs here are corpus FMUs with their binaries removed;
the reference is the same FMU with the exporter's binary.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.errors import FMUError, FmuOpinfWarning  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.source import open_source  # noqa: E402
from fmu_opinf.sources import _compile  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)


@pytest.fixture(scope="module")
def corpus(request, tmp_path_factory) -> dict[str, Path]:
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    built = lti_fmus.build_corpus(folder, ("me-only", "fmi3-array-structural"))
    return {name: fmu.path for name, fmu in built.items()}


def without_binaries(fmu: Path, out: Path, extra: dict[str, str] | None = None) -> Path:
    """A copy of ``fmu`` without ``binaries/``, with ``extra`` files added or replaced."""
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            if not item.filename.startswith("binaries/") and item.filename not in (extra or {}):
                target.writestr(item, source.read(item))
        for name, text in (extra or {}).items():
            target.writestr(name, text)
    return out


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    from fmu_opinf import sources

    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(sources, "_REPORTED", set())
    return tmp_path / "cache"


@pytest.mark.parametrize("name, interface", [("me-only", "me"), ("fmi3-array-structural", "cs"),
                                             ("fmi3-array-structural", "me")])
@pytest.mark.slow  # 4 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_a_source_only_fmu_is_compiled_once_and_records_as_with_its_binary(corpus, cache, tmp_path, name, interface,
                                                                           monkeypatch):
    fmu = without_binaries(corpus[name], tmp_path / f"{name}-sources.fmu")
    with pytest.warns(FmuOpinfWarning, match=r"has no binary for this platform .*compiled from its C sources"):
        compiled = record(open_source(fmu, interface=interface), "impulse:amplitude=2,t0=0.5,width=0.4", 0.05, 4.0,
                          quiet=True, isolate=True).runs[0]
    binary = record(open_source(corpus[name], interface=interface), "impulse:amplitude=2,t0=0.5,width=0.4", 0.05,
                    4.0, quiet=True).runs[0]
    for key in ("x", "xdot", "y"):
        a, b = np.asarray(getattr(compiled, key)), np.asarray(getattr(binary, key))
        # measured 0 (bit for bit, -O2 against the exporter's CMake build); a few ulps for another compiler's rounding
        assert np.abs(a - b).max() <= 1e-15 * np.abs(b).max(), key
    libraries = list((cache / "compiled-fmus").rglob("*.so"))
    assert len(libraries) == 1
    assert fmu.read_bytes() == without_binaries(corpus[name], tmp_path / "again.fmu").read_bytes()   # unchanged

    def no_second_build(*args):
        raise AssertionError("compiled again")

    monkeypatch.setattr(_compile, "_compile_one", no_second_build)
    open_source(fmu, interface=interface).close()   # from the cache


def test_sources_that_do_not_compile_are_a_one_line_error(corpus, cache, tmp_path):
    fmu = without_binaries(corpus["me-only"], tmp_path / "broken.fmu", {"sources/lti_model.c": "this is not C;\n"})
    with pytest.raises(FMUError, match=r"^broken\.fmu has no binary for this platform and its C sources do not "
                                       r"compile here \(.*error.*\); export it with a binary for this platform$"):
        open_source(fmu)
    assert not list((cache / "compiled-fmus").rglob("*.so")) and not list(cache.rglob("*.part"))


def test_a_cached_library_others_could_have_written_is_compiled_again(corpus, cache, tmp_path, monkeypatch):
    """A shared cache folder must not let another user plant code: a cached library writable by others is not
    used but compiled again (as the model-exchange step loop's is not loaded)."""
    import os

    if os.name != "posix":
        pytest.skip("file modes are POSIX")
    fmu = without_binaries(corpus["me-only"], tmp_path / "shared.fmu")
    with pytest.warns(FmuOpinfWarning):
        open_source(fmu).close()
    library, = (cache / "compiled-fmus").rglob("*.so")
    library.chmod(0o666)
    builds, build = [], _compile._compile_one
    monkeypatch.setattr(_compile, "_compile_one", lambda *args: (builds.append(args[3]), build(*args))[1])
    open_source(fmu).close()
    assert builds == ["MeOnly"] and not library.stat().st_mode & 0o022


def test_auto_drives_model_exchange_where_neither_interface_has_a_binary(corpus, tmp_path):
    """Both interfaces are compiled from the sources, so ``auto`` keeps its preference for model exchange (the
    audit's source-only FMU was driven through its co-simulation, eps_y 5.7e-24 against 1.6e-28)."""
    from fmu_opinf.sources import choose_interface

    assert choose_interface(without_binaries(corpus["fmi3-array-structural"], tmp_path / "both.fmu")) == "me"
    assert choose_interface(corpus["fmi3-array-structural"]) == "me"
