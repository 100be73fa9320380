"""The sdist and the wheel carry the FMUs' C sources and py.typed, and an unpacked wheel finds them.

The distributions are built with setuptools' PEP 517 hooks from a copy of the checkout (so the test
neither writes into the checkout nor needs the network); ``.ci/run`` additionally installs a wheel in a
fresh virtual environment and runs the quick demo from it.
"""

import os
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
BUILD_PRODUCTS = shutil.ignore_patterns("*.fmu", "build", "*.o", "*.so", "__pycache__", "*.egg-info",
                                        "_csources", ".*")


def _c_source_files() -> set[str]:
    """Every file of the checkout's fmus/ tree that is a source (build products left out)."""
    excluded = {".fmu", ".o", ".so"}
    return {p.relative_to(ROOT / "fmus").as_posix() for p in (ROOT / "fmus").rglob("*")
            if p.is_file() and p.suffix not in excluded and "build" not in p.relative_to(ROOT / "fmus").parts
            and "__pycache__" not in p.parts}


def _run(command: list[str], cwd: Path) -> str:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done.stdout


def _build_sdist(project: Path, out: Path) -> Path:
    code = f"from setuptools import build_meta; print(build_meta.build_sdist({str(out)!r}))"
    return out / _run([sys.executable, "-c", code], project).strip().splitlines()[-1]


def _build_wheel(project: Path, out: Path) -> Path:
    """pip's isolated build, as a user's ``pip install`` does it (setuptools and wheel from pip's cache)."""
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), "."], project)
    return next(out.glob("fmu_opinf-*.whl"))


@pytest.fixture(scope="module")
def distributions(tmp_path_factory):
    """(sdist, wheel built from that sdist) of a copy of the checkout that also holds build products."""
    tmp = tmp_path_factory.mktemp("dist")
    project = tmp / "checkout"
    project.mkdir()
    for name in ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md"):
        shutil.copy2(ROOT / name, project / name)
    for folder in ("src", "fmus"):
        shutil.copytree(ROOT / folder, project / folder, ignore=BUILD_PRODUCTS)
    # products of a local build must stay out of the distributions
    (project / "fmus" / "AnchoredMSD.fmu").write_bytes(b"built")
    (project / "fmus" / "build").mkdir()
    (project / "fmus" / "build" / "model.o").write_bytes(b"object")
    sdist = _build_sdist(project, tmp)
    with tarfile.open(sdist) as archive:
        archive.extractall(tmp / "unpacked")
    unpacked = next((tmp / "unpacked").iterdir())
    wheel = _build_wheel(unpacked, tmp)
    return sdist, wheel


def test_sdist_carries_the_c_sources_and_the_build_hook(distributions):
    sdist, _ = distributions
    with tarfile.open(sdist) as archive:
        names = {name.split("/", 1)[1] for name in archive.getnames() if "/" in name}
    expected = {"fmus/" + name for name in _c_source_files()}
    assert expected <= names, sorted(expected - names)
    assert {"setup.py", "MANIFEST.in", "src/fmu_opinf/py.typed"} <= names
    assert not [name for name in names if name.endswith((".fmu", ".o"))]


def test_wheel_built_from_the_sdist_carries_the_c_sources_and_py_typed(distributions):
    _, wheel = distributions
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    expected = {"fmu_opinf/_csources/" + name for name in _c_source_files()}
    assert expected <= names, sorted(expected - names)
    assert "fmu_opinf/py.typed" in names
    assert not [name for name in names if name.endswith((".fmu", ".o"))]


def test_unpacked_wheel_reads_its_packaged_sources_and_caches_fmus_outside(distributions, tmp_path):
    _, wheel = distributions
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(site)
    code = ("from fmu_opinf import fmus; "
            "print(fmus._c_sources_dir()); print(fmus.bundled_fmu_dir()); "
            "files, guid = fmus._source_tree(fmus.anchored_msd_spec(10)); print(len(files))")
    env = {"PYTHONPATH": str(site), "FMU_OPINF_CACHE_DIR": str(tmp_path / "cache"), "PATH": ""}
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    sources, fmu_dir, count = done.stdout.split()
    assert Path(sources) == site / "fmu_opinf" / "_csources"
    assert Path(fmu_dir) == tmp_path / "cache" / "fmus"
    assert int(count) > 10
    # the model-exchange step loop is compiled from the wheel's copy into the cache (with a compiler on PATH)
    code = ("from fmu_opinf.sources import _compiled_rk; print(_compiled_rk._source()); "
            "print(_compiled_rk.available())")
    env["PATH"] = os.environ.get("PATH", "")
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    source, available = done.stdout.split()
    assert Path(source) == site / "fmu_opinf" / "_csources" / "integrator" / "erk.c"
    if shutil.which("cc") or shutil.which("gcc"):
        assert available == "True" and list((tmp_path / "cache" / "integrator").glob("erk-*"))
