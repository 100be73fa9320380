"""The Python API checks its arguments as the command line does (audit 81c, F2, F3, F7, F8).

Each bad call ends in one line of an :mod:`fmu_opinf.errors` class that also derives from the built-in Python
raised before (``ValueError``, ``TypeError``), naming the keyword, the closest valid one and the fix; nothing is
dropped silently and no input file is overwritten.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from conftest import build_fmu_set
from fmu_opinf import compare, export, lti_fmus, snapshots
from fmu_opinf.errors import FileFormatError, FmuOpinfError, InputSpecError, InputTypeError
from fmu_opinf.fit import fit_rom, fit_rom_file
from fmu_opinf.source import open_source
from fmu_opinf.sources import BuiltinSource

TRAIN = "impulse:amplitude=100,t0=2,width=0.5"
TEST = "harmonic:amplitude=1,omega=0.2"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A snapshot file of the anchored chain (g = 12) and a ROM fitted from it."""
    folder = tmp_path_factory.mktemp("api")
    snaps = folder / "s.h5"
    snapshots.record(BuiltinSource("anchored-msd", g=12), TRAIN, 0.5, 40.0, path=snaps, quiet=True)
    rom = folder / "rom.h5"
    fit_rom_file(snaps, rom, r=3, quiet=True)
    return {"snapshots": snaps, "rom": rom}


@pytest.fixture(scope="module")
def fmu(request, tmp_path_factory):
    """A two-mass chain as a co-simulation FMU (lti_fmus)."""
    def build(folder, item):
        return item, lti_fmus.build_lti_fmu(lti_fmus.chain_model(2), folder / f"{item}.fmu", interfaces=("cs",),
                                            identifier=item).path

    return build_fmu_set(request, tmp_path_factory, "api-arguments", build, ["ApiChain"])["ApiChain"]


def _one_line(error: BaseException, *parts: str) -> None:
    assert isinstance(error, FmuOpinfError), repr(error)
    assert "\n" not in str(error)
    for part in parts:
        assert part in str(error), str(error)


# -- F7: fit_rom on a path, and its keywords ------------------------------------------------------------------


def test_fit_rom_takes_a_snapshot_file_as_fmu_opinf_fit_does(files):
    """``fit_rom("train.h5")`` raised ``AttributeError: 'str' object has no attribute 'x'``; it now reads the file
    lazily (as fit_rom_file does) and fits the same ROM as from the loaded snapshots."""
    from_path = fit_rom(str(files["snapshots"]), r=3)
    from_list = fit_rom([files["snapshots"]], r=3)
    loaded = fit_rom(snapshots.Snapshots.load(files["snapshots"]), r=3)
    reference = loaded.simulate(TEST, 0.5, 40.0).y
    for rom in (from_path, from_list):
        assert rom.provenance["snapshot_file"] == "s.h5"
        assert np.max(np.abs(rom.simulate(TEST, 0.5, 40.0).y - reference)) <= 1e-12 * np.ptp(reference)


@pytest.mark.parametrize("keywords, builtin, parts", [
    ({"energy": 1.5}, ValueError, ["energy=1.5 must lie strictly between 0 and 1", "e.g. energy=0.9999"]),
    ({"basis": "position"}, ValueError, ["basis='position' is not known", "did you mean basis='positions'?"]),
    ({"solver": "x"}, ValueError, ["solver='x' is not known; use one of 'auto', 'ipm', 'clarabel', 'factored'"]),
    ({"refine_iterations": -1}, ValueError, ["refine_iterations=-1 must be at least 0"]),
    ({"max_memory": 0}, ValueError, ["max_memory=0 must be a positive finite number"]),
    ({"energy": "0.9"}, TypeError, ["energy='0.9' is a str, not a number", "e.g. energy=0.9"]),
])
def test_fit_rom_refuses_bad_keywords_before_any_work(files, monkeypatch, keywords, builtin, parts):
    """Before: built-in ValueErrors (some after the POD), and max_memory=0 was taken; the CLI said one line."""
    import fmu_opinf.fit as fit

    monkeypatch.setattr(fit, "as_runs", lambda *a: pytest.fail("work started on a bad keyword"))
    with pytest.raises(builtin) as caught:
        fit_rom(snapshots.Snapshots.load(files["snapshots"]), **keywords)
    _one_line(caught.value, *parts)


def test_record_refuses_a_step_given_as_text():
    """``record(..., dt="0.1")``: ``TypeError: '>' not supported between instances of 'str' and 'int'``."""
    with pytest.raises(TypeError) as caught:
        snapshots.record("builtin:anchored-msd", "none", dt="0.1", t_end=1.0, quiet=True)
    assert isinstance(caught.value, InputTypeError)
    _one_line(caught.value, "dt='0.1' is a str, not a number; give a number, e.g. dt=0.1")


def test_the_command_line_keeps_its_words(files, capsys):
    """The checks are shared with cli._check_arguments, which keeps the option's spelling."""
    from fmu_opinf import cli

    for args, text in ((["--energy", "1.5"], "--energy 1.5 must lie strictly between 0 and 1, e.g. --energy 0.9999"),
                       (["--refine-iterations", "-1"], "--refine-iterations -1 must be at least 0")):
        assert cli.main(["fit", str(files["snapshots"]), "-o", "unused.h5", *args]) == 2
        assert text in capsys.readouterr().err


# -- F2: compare's source_options ----------------------------------------------------------------------------


@pytest.mark.parametrize("key, parts", [
    ("parameter", ["compare's source_options takes no key 'parameter'; did you mean 'parameters'?"]),
    ("set", ["takes no key 'set'; the command line's --set is 'parameters' in Python"]),
    ("positions", ["takes no key 'positions'", "valid: inputs, outputs, parameters, interface, tolerance"]),
    ("t_end", ["takes no key 't_end'"]),
])
def test_compare_refuses_a_source_option_it_does_not_know(files, key, parts):
    """A key compare does not know was dropped: ``{"set": {"stiffness_scale": 1.5}}`` compared the FMU at its
    training value and reported max eps_y 4e-27 for a model never compared."""
    with pytest.raises(InputSpecError) as caught:
        compare.compare(files["rom"], "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
                        source_options={key: {"g": 12} if key in ("parameter", "set") else 3})
    _one_line(caught.value, *parts)


def test_compare_takes_its_valid_source_options(files):
    result = compare.compare(files["rom"], "builtin:anchored-msd", TEST, t_end=10.0, quiet=True,
                             source_options={"g": 12, "isolate": False})
    assert result.y_fom.shape == result.y_rom.shape


# -- F8: an FMU source's keywords ------------------------------------------------------------------------------


def test_an_fmu_source_names_a_misspelt_keyword_and_the_closest_one(fmu):
    """Before: ``--postions applies to builtin sources, not to the fmu ...`` (and the same for ``set=``)."""
    with pytest.raises(InputSpecError) as caught:
        open_source(str(fmu), postions="mass[*].s")
    _one_line(caught.value, "an fmu source (ApiChain.fmu) takes no keyword 'postions'; did you mean 'positions'?")
    with pytest.raises(InputSpecError) as caught:
        snapshots.record_to_file(fmu, "unused.h5", "none", dt=0.1, t_end=1.0, quiet=True, set={"k": 1})
    _one_line(caught.value, "takes no keyword 'set'; the command line's --set is 'parameters' in Python")
    with pytest.raises(InputSpecError) as caught:   # a builtin size keeps its own line
        open_source(str(fmu), g=10)
    _one_line(caught.value, "--g or g= applies to builtin sources")


# -- F3: no function writes over its own input ---------------------------------------------------------------


def test_fit_rom_file_does_not_overwrite_its_snapshots(files, tmp_path):
    snaps = tmp_path / "same.h5"
    shutil.copy(files["snapshots"], snaps)
    before = snaps.read_bytes()
    with pytest.raises(FileFormatError) as caught:
        fit_rom_file(snaps, snaps, overwrite=True, r=3, quiet=True)
    _one_line(caught.value, f"output {snaps} is also an input of this call; give output= another path")
    assert snaps.read_bytes() == before


def test_record_to_file_and_export_do_not_overwrite_the_fmu(fmu, tmp_path):
    victim = tmp_path / "victim.fmu"
    shutil.copy(fmu, victim)
    before = victim.read_bytes()
    with pytest.raises(FileFormatError) as caught:
        snapshots.record_to_file(victim, victim, "none", dt=0.1, t_end=1.0, quiet=True, overwrite=True)
    _one_line(caught.value, "is also an input of this call")
    with pytest.raises(FileFormatError) as caught:
        export.export_fmu(victim, victim, overwrite=True)
    _one_line(caught.value, "is also an input of this call; give path= another path")
    assert victim.read_bytes() == before
