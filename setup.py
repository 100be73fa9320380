"""Build hook: ship the repository's ``fmus/`` C sources inside the package.

The C sources of the benchmark FMUs and of the exported ROM FMUs stay in the top-level
``fmus/`` folder of the repository (they are a C project of their own). A wheel has to carry
them, because ``fmu_opinf.fmus`` compiles every FMU from them at run time; this hook copies the
tree into the built package as ``fmu_opinf/_csources/`` (never into ``src/``, so a checkout has
one copy only). An sdist carries ``fmus/`` itself (MANIFEST.in), so a wheel built from the sdist
gets the same copy. Editable installs read the checkout's ``fmus/`` directly.

All metadata is in pyproject.toml.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
C_SOURCES = HERE / "fmus"
PACKAGED_NAME = "_csources"
#: build products and editor/VCS files that live next to the sources but are not sources
NOT_SOURCES = ("*.fmu", "*.fmu.tmp-*", "build", "*.o", "*.so", "*.dll", "*.dylib",
               "__pycache__", ".*")


class BuildPyWithCSources(build_py):
    """``build_py`` that also copies ``fmus/`` into ``<build_lib>/fmu_opinf/_csources``."""

    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False):
            return
        if not (C_SOURCES / "src").is_dir():
            raise RuntimeError(f"the C sources are missing: {C_SOURCES} has no src/ folder; build "
                               "from a complete checkout or sdist of fmu-opinf")
        target = Path(self.build_lib) / "fmu_opinf" / PACKAGED_NAME
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(C_SOURCES, target, ignore=shutil.ignore_patterns(*NOT_SOURCES))


setup(cmdclass={"build_py": BuildPyWithCSources})
