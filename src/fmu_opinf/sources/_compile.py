"""Compile the C sources of an FMU that ships no binary for this platform.

Exporters that cross-compile (a Windows tool: ``binaries/win64`` only) or export "source code FMUs" (OpenModelica,
Dymola's source export) leave a Linux user with ``sources/``.  fmpy's ``compile`` reads the description strictly,
so it fails on the descriptions this tool reads leniently (seventh audit: units without ``UnitDefinitions``).  Here
the files named by the description (FMI 2: ``<SourceFiles>`` of each interface; FMI 3:
``sources/buildDescription.xml``, with its preprocessor definitions and include directories), or every ``.c`` file
in ``sources/`` where none are named, are compiled with the C compiler of :func:`fmu_opinf.fmus.find_c_compiler`
and fmpy's FMI headers into one shared library per model identifier.  The libraries are kept in the per-user cache
folder, named after a digest of the FMU file, the compiler command and the machine's kind, so each FMU is compiled
once per machine; the unpacked copy of the FMU gets them in ``binaries/<platform>/``.  The FMU file itself is never
changed.  As for the model-exchange step loop, a cached library that another user could have written is not used.
"""

from __future__ import annotations

import hashlib
import os
import platform
import shutil
import struct
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

from ..errors import FMUError
from ._compiled_rk import _private, _trusted

__all__ = ["has_c_sources", "compile_sources", "install_binaries"]

#: Seconds a compilation may take before it is given up (a large generated model compiles in about a minute).
COMPILE_TIMEOUT = 600


def has_c_sources(files: list[str]) -> bool:
    """Whether an FMU's file list has C sources in ``sources/``."""
    return any(f.startswith("sources/") and f.lower().endswith(".c") for f in files)


def _library_suffix() -> str:
    return ".dll" if os.name == "nt" else ".dylib" if sys.platform == "darwin" else ".so"


def _fmi_headers() -> Path:
    import fmpy

    return Path(fmpy.__file__).parent / "c-code"


def _build_plan(root: ET.Element, unzipped: Path, identifier: str) -> tuple[list[Path], list[str], list[Path]]:
    """The source files, preprocessor definitions and include folders for ``identifier``."""
    sources = unzipped / "sources"
    files: list[str] = []
    defines: list[str] = []
    includes: list[Path] = []
    build = sources / "buildDescription.xml"
    if build.is_file():   # FMI 3
        for config in ET.parse(build).getroot().iter("BuildConfiguration"):
            if config.get("modelIdentifier") not in (None, identifier):
                continue
            for file_set in config.iter("SourceFileSet"):
                files += [f.get("name", "") for f in file_set.iter("SourceFile")]
                for definition in file_set.iter("PreprocessorDefinition"):
                    value = definition.get("value")
                    defines.append(definition.get("name", "") + ("" if value is None else f"={value}"))
                includes += [sources / d.get("name", "") for d in file_set.iter("IncludeDirectory")]
    for interface in ("ModelExchange", "CoSimulation"):   # FMI 2
        element = root.find(interface)
        if element is not None and element.get("modelIdentifier") == identifier:
            files += [f.get("name", "") for f in element.iterfind("SourceFiles/File")]
    named = [sources / name for name in dict.fromkeys(files) if name]
    if not named:
        named = sorted(sources.rglob("*.c"))
    headers = sorted({path.parent for path in sources.rglob("*.h")})
    for path in named:
        if not path.resolve().is_relative_to(sources.resolve()) or not path.is_file():
            raise FMUError(f"its description names the source file {path.name!r}, which is not in its sources/ "
                           "folder; export it with a binary for this platform")
    return named, defines, [sources, *includes, *headers]


def _digest(fmu_sha256: str, compiler: list[str]) -> str:
    """The cache folder's name: the FMU file's digest, the compiler command and the machine's kind."""
    h = hashlib.sha256(fmu_sha256.encode())
    h.update("\0".join(compiler).encode())
    h.update(f"{sys.platform} {platform.machine()} {struct.calcsize('P')}".encode())   # a cache shared by machines
    return h.hexdigest()[:24]


def compile_sources(fmu: Path, root: ET.Element, identifiers: list[str], fmu_sha256: str) -> dict[str, Path]:
    """The shared library of each model identifier, compiled from the FMU's sources (or found in the cache).

    Parameters
    ----------
    fmu : Path
        The ``.fmu`` file.
    root : Element
        Its ``modelDescription.xml`` root.
    identifiers : list of str
        The model identifiers to build (ME and CS may differ).
    fmu_sha256 : str
        The FMU file's SHA-256 (:func:`fmu_opinf._hdf5.sha256_of`; the source's provenance keeps it).

    Returns
    -------
    dict
        Identifier -> library in the per-user cache.

    Raises
    ------
    FMUError
        No C compiler, or the compilation failed: one line with the compiler's first error.
    """
    from ..fmus import _user_cache_dir, find_c_compiler

    compiler = find_c_compiler()
    if compiler is None:
        raise FMUError(f"{fmu.name} ships only C sources for this platform and no C compiler was found (set CC or "
                       "install gcc); or export it with a binary for this platform")
    folder = _user_cache_dir() / "compiled-fmus" / _digest(fmu_sha256, compiler)
    wanted = {name: folder / f"{name}{_library_suffix()}" for name in identifiers}
    if all(_trusted(path) for path in wanted.values()):
        return wanted
    _private(folder.parent)
    _private(folder)
    with tempfile.TemporaryDirectory(prefix="fmu_opinf_build_") as scratch:
        unzipped = Path(scratch)
        with zipfile.ZipFile(fmu) as zf:
            members = [m for m in zf.namelist() if m.startswith("sources/") and ".." not in Path(m).parts]
            zf.extractall(unzipped, members=members)
        for name, library in wanted.items():
            if not _trusted(library):
                _compile_one(fmu, root, unzipped, name, compiler, library)
            if not _trusted(library):
                raise FMUError(f"{fmu.name}: the library compiled from its sources in {folder} could be changed by "
                               "another user (a shared FMU_OPINF_CACHE_DIR?), so it is not loaded; use a cache folder "
                               "of your own")
    return wanted


def _compile_one(fmu: Path, root: ET.Element, unzipped: Path, identifier: str, compiler: list[str],
                 library: Path) -> None:
    files, defines, includes = _build_plan(root, unzipped, identifier)
    partial = library.with_name(f".{library.name}.{os.getpid()}.part")
    command = [*compiler, "-shared", "-fPIC", "-O2", "-I", str(_fmi_headers()),
               *(arg for folder in includes for arg in ("-I", str(folder))),
               *(f"-D{definition}" for definition in defines), *map(str, files), "-o", str(partial), "-lm"]
    try:
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=COMPILE_TIMEOUT)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise FMUError(f"{fmu.name}: compiling its C sources failed ({type(exc).__name__}); export it with a "
                           "binary for this platform") from None
        if done.returncode != 0 or not partial.is_file():
            errors = [line for line in done.stderr.splitlines() if "error" in line.lower()] or done.stderr.splitlines()
            first = errors[0].strip() if errors else f"exit code {done.returncode}"
            raise FMUError(f"{fmu.name} has no binary for this platform and its C sources do not compile here "
                           f"({first}); export it with a binary for this platform")
        os.replace(partial, library)   # atomic: a concurrent process sees the whole library or none
    finally:   # (also on an interrupt: audit 56 found the partial library left in the cache)
        partial.unlink(missing_ok=True)


def install_binaries(unzipped: Path, platform: str, libraries: dict[str, Path]) -> None:
    """Copy the compiled libraries into ``binaries/<platform>/`` of an unpacked FMU."""
    target = unzipped / "binaries" / platform
    target.mkdir(parents=True, exist_ok=True)
    for identifier, library in libraries.items():
        shutil.copy2(library, target / f"{identifier}{library.suffix}")
