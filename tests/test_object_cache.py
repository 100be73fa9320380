"""Tests of the object-file cache of FMU builds (:mod:`fmu_opinf._object_cache`, ``fmus._compile_objects``).

A cached object is only worth the time it saves if it is never the wrong one: each test below that reuses nothing
would pass a cache that never hits, and each test that changes an input would fail a cache that keyed on less than
the preprocessed source, the flags and the compiler, or that trusted a file without checking its header.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
import zipfile
from pathlib import Path

import pytest

from fmu_opinf import _object_cache, fmus

pytestmark = pytest.mark.fmu

COMPILER = fmus.find_c_compiler()
if COMPILER is None:
    pytest.skip("no C compiler", allow_module_level=True)

#: The object of the unit holding the model identifier and the GUID (``fmus.IDENTITY_SOURCE``), fifth source.
IDENTITY = "4_fmu_identity.o"

SOURCE = '#include "value.h"\nint value(void) { return VALUE; }\n'


@pytest.fixture(autouse=True)
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A cache folder of this test's own; returns its ``objects/`` folder."""
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "objects"


class Builds:
    """Builds of ``value.c`` (which returns the header's ``VALUE``) through the cache, each in a folder of its own."""

    def __init__(self, root: Path) -> None:
        self.root, self.count = root, 0

    def __call__(self, header: str = "#define VALUE 1\n", source: str = SOURCE,
                 flags: tuple[str, ...] = ()) -> ctypes.CDLL:
        """Compile and link the files, and load the library (a new path each time: no library is reused)."""
        self.count += 1
        folder = self.root / f"build{self.count}"
        folder.mkdir(parents=True)
        (folder / "value.c").write_text(source)
        (folder / "value.h").write_text(header)
        fmus._compile_objects(COMPILER, ["-fPIC", "-O2", *flags], ["-I" + folder.as_posix()],
                              [(folder / "value.c", folder / "value.o")])
        library = folder / "libvalue.so"
        subprocess.run([*COMPILER, "-shared", str(folder / "value.o"), "-o", str(library)], check=True)
        return ctypes.CDLL(str(library))


@pytest.fixture
def build(tmp_path: Path) -> Builds:
    return Builds(tmp_path / "builds")


def entries(cache: Path) -> list[Path]:
    return sorted(cache.iterdir())


def test_the_same_source_is_compiled_once(build, compiled, cache):
    assert build().value() == 1
    assert build().value() == 1
    assert compiled == ["value.o"]
    assert [path.suffix for path in entries(cache)] == [".o"]   # one entry, no temporary file left
    assert entries(cache)[0].stat().st_mode & 0o777 == 0o644


def test_a_changed_header_is_compiled_again(build, compiled):
    assert build("#define VALUE 1\n").value() == 1
    assert build("#define VALUE 2\n").value() == 2
    assert compiled == ["value.o", "value.o"]


def test_a_changed_source_is_compiled_again(build):
    assert build().value() == 1
    assert build(source=SOURCE.replace("return VALUE;", "return VALUE + 40;")).value() == 41


def test_a_changed_flag_is_compiled_again(build, compiled):
    """``-fvisibility=hidden`` leaves the preprocessed text as it is but hides the function: a stale object of the
    first build would export it."""
    assert build().value() == 1
    hidden = build(flags=("-fvisibility=hidden",))
    with pytest.raises(AttributeError):
        hidden.value  # noqa: B018 - the lookup is the test
    assert compiled == ["value.o", "value.o"]


def test_another_compiler_is_not_given_the_old_objects(build, compiled, monkeypatch):
    build()
    monkeypatch.setattr(_object_cache, "_compiler_report", lambda compiler: b"gcc version 99 (upgraded)")
    build()
    assert compiled == ["value.o", "value.o"]


@pytest.mark.parametrize("damage", ["flipped byte", "truncated", "empty", "no header"])
def test_a_damaged_entry_is_compiled_again_and_replaced(build, compiled, cache, damage):
    build()
    entry, = entries(cache)
    data = entry.read_bytes()
    entry.write_bytes({"flipped byte": data[:-100] + bytes([data[-100] ^ 1]) + data[-99:],
                       "truncated": data[:len(data) // 2], "empty": b"",
                       "no header": data[data.index(b"\x7fELF"):] if b"\x7fELF" in data else data[200:]}[damage])
    assert build().value() == 1
    assert build().value() == 1
    assert compiled == ["value.o", "value.o"]   # the third build takes the second's object
    assert entries(cache) == [entry]


def test_an_entry_stored_under_another_key_is_not_used(build, compiled, cache):
    """A valid file of another key renamed to this key's name (its header names its own key) is not used."""
    build("#define VALUE 1\n")
    one, = entries(cache)
    build("#define VALUE 2\n")
    two, = set(entries(cache)) - {one}
    two.replace(one)
    assert build("#define VALUE 1\n").value() == 1
    assert compiled == ["value.o"] * 3


@pytest.mark.skipif(os.name != "posix", reason="file modes")
def test_an_entry_others_may_write_is_not_used(build, compiled, cache):
    build()
    entries(cache)[0].chmod(0o666)
    assert build().value() == 1
    assert compiled == ["value.o", "value.o"]


def test_an_unusable_cache_folder_only_costs_the_compilation(build, compiled, tmp_path, monkeypatch):
    (tmp_path / "not-a-folder").write_text("")
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "not-a-folder"))
    assert build().value() == 1
    assert build().value() == 1
    assert compiled == ["value.o", "value.o"]


def test_the_least_recently_used_entries_beyond_the_limit_are_removed(build, cache, monkeypatch):
    monkeypatch.setattr(_object_cache, "MAX_ENTRIES", 2)
    for value in (1, 2, 3):
        build(f"#define VALUE {value}\n")
    assert len(entries(cache)) == 2


def binary(path: Path) -> bytes:
    with zipfile.ZipFile(path) as archive:
        return next(archive.read(name) for name in archive.namelist() if name.startswith("binaries/"))


@pytest.mark.slow
def test_an_fmu_rebuilt_from_cached_objects_is_the_same_binary(tmp_path, compiled, cache, monkeypatch):
    first = fmus.build_second_order_fmu(fmus.anchored_msd_spec(10), tmp_path / "First.fmu")
    assert len(compiled) == 5 and len(entries(cache)) == 4   # the name and GUID unit is compiled, never cached
    again = fmus.build_second_order_fmu(fmus.anchored_msd_spec(10), tmp_path / "First.fmu", compile=True)
    assert compiled[5:] == [IDENTITY] and binary(again) == binary(first)
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "fresh"))   # compiled anew: the same bytes
    assert binary(fmus.build_second_order_fmu(fmus.anchored_msd_spec(10), tmp_path / "Third.fmu")) == binary(first)


@pytest.mark.slow
def test_an_fmu_of_another_guid_or_size_compiles_what_depends_on_it(tmp_path, compiled):
    """Another description changes only the GUID, which ``instance.c`` checks at instantiation: only the unit that
    holds it (never cached) is compiled again (a stale GUID would refuse the FMU), the others are reused; another
    number of degrees of freedom compiles the instance, the kernel and the model too (the FMI layer's preprocessed
    text holds the numbers of inputs, outputs and parameters only)."""
    from fmpy import simulate_fmu

    fmus.build_second_order_fmu(fmus.anchored_msd_spec(10), tmp_path / "A.fmu")
    compiled.clear()
    spec = fmus.anchored_msd_spec(10)
    spec.description = "the same model, described otherwise"
    other = fmus.build_second_order_fmu(spec, tmp_path / "B.fmu")
    assert compiled == [IDENTITY]
    assert len(simulate_fmu(str(other), stop_time=1.0, output_interval=0.1)) > 1   # instantiates: its GUID matches
    compiled.clear()
    fmus.build_second_order_fmu(fmus.anchored_msd_spec(12), tmp_path / "C.fmu")
    assert sorted(compiled) == ["1_instance.o", "2_newmark.o", "3_model.o", IDENTITY]
