"""Runs fitted together at different steps are said (audit 72, F2).

Before: ``fit`` on a folder of runs recorded at different steps silently dropped the output-error refinement, the
least-squares candidate, the order search and the training-miss check (a run table without --dt gave each row its
own automatic window; the ROM was 15-51 % of range off its own training inputs).  Now one warning says what is off
and the fix (record at one --dt).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom_file
from fmu_opinf.snapshots import record_to_file

from conftest import build_fmu_set

pytestmark = pytest.mark.fmu

ROWS = {"imp": "impulse:amplitude=100,t0=2,width=0.5", "harm": "harmonic:amplitude=5,omega=1.3"}


@pytest.fixture(scope="module")
def fmu(request, tmp_path_factory) -> Path:
    def build(folder, item):
        built = lti_fmus.build_lti_fmu(lti_fmus.chain_model(2, name="Steps"), folder / "steps.fmu",
                                       identifier="TableSteps_chain")
        return item, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-table-steps", build, ["chain"])["chain"]


def test_fit_on_runs_of_different_steps_says_what_is_off_and_the_fix(fmu, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for name, dt in (("a", 0.02), ("b", 0.05)):
        record_to_file(fmu, folder / f"{name}.h5", ROWS["imp"], dt=dt, t_end=20.0, quiet=True, isolate=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit_rom_file(folder, tmp_path / "rom.h5", r=2, quiet=True)
    said = [str(w.message) for w in caught if issubclass(w.category, FmuOpinfWarning)
            and "different steps" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in caught]
    assert "(0.02, 0.05)" in said[0] and "refinement" in said[0] and "order search" in said[0]
    assert "--dt" in said[0]


def test_fit_on_runs_of_one_step_refines_without_that_warning(fmu, tmp_path):
    folder = tmp_path / "same"
    folder.mkdir()
    for name, spec in ROWS.items():
        record_to_file(fmu, folder / f"{name}.h5", spec, dt=0.05, t_end=20.0, quiet=True, isolate=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rom = fit_rom_file(folder, tmp_path / "rom.h5", r=2, quiet=True)
    assert not [w for w in caught if "different steps" in str(w.message)]
    assert rom.fit_info.get("refinement")
