"""A Boolean input that gates the force (a drive's ``enable``, a Simulink enabled subsystem), at its start value
false: where nothing moves, fmu-opinf names the inputs it held, with their values and the ``--set`` that changes one.
Audit 77a, F2.

Before: the automatic window stopped with "give an input that reaches the outputs (its amplitude, its channel)",
never naming ``enable``; with ``--dt``/``--t-end`` a file of constants was written without a word, and ``fit`` said
"all snapshots are zero; excite the system with a non-zero input" after a 100 N impulse.  Now each of the three
names ``enable (Boolean, held at its start value false)`` and ``--set enable=true``, as a candidate (no Boolean is
guessed to be the gate).  The references: the exact zero-order-hold response of the model (``lti_fmus.zoh_response``)
for the FMU with ``enable=true``, and exact zeros for the positions without it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import Snapshots

from conftest import build_fmu_set, miss_against_model

pytestmark = pytest.mark.fmu

#: What every message names: the held Boolean with its value, and the setting that changes it.
NAMED = "enable (Boolean, held at its start value false)"
FIX = "--set enable=true"


def _chain(inputs=(-1,)) -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(2, inputs=inputs, name="Gated")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    items = [("fmi2", dict()), ("fmi3", dict(fmi_version="3.0")), ("two", dict(model_inputs=(0, 1))),
             ("sensor", dict(input_sensors=True))]

    def build(folder, item):
        name, options = item
        model = _chain(options.pop("model_inputs", (-1,)))
        built = lti_fmus.build_lti_fmu(model, folder / f"{name}.fmu", identifier=f"Gated_{name}", enable_input=True,
                                       **options)
        return name, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-enable-input", build, items)


def _snapshots(fmu, out, *options) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        code = main(["snapshots", str(fmu), "-o", str(out), "-q", *options])
    return code


def test_the_builders_enable_input_gates_the_force(fmus, tmp_path, capsys):
    """The check of the test FMU: with enable=true the recording is the exact model's, without it nothing moves."""
    assert _snapshots(fmus["fmi2"], tmp_path / "on.h5", "--dt", "0.02", "--t-end", "20", *FIX.split()) == 0
    run = Snapshots.load(tmp_path / "on.h5").runs[0]
    exact = lti_fmus.zoh_response(_chain(), run.t, run.u[:, 1:]).y
    assert np.abs(run.y - exact).max() < 2e-14 * np.ptp(exact)   # measured 2.6e-15 (model exchange)
    assert _snapshots(fmus["fmi2"], tmp_path / "off.h5", "--dt", "0.02", "--t-end", "20") == 0
    off = Snapshots.load(tmp_path / "off.h5").runs[0]
    assert np.ptp(off.u) == 100 and not np.any(off.x) and not np.any(off.y)
    capsys.readouterr()


@pytest.mark.parametrize("kind", ["fmi2", "fmi3"])
def test_the_automatic_window_names_the_held_boolean_and_its_setting(kind, fmus, tmp_path, capsys):
    code = _snapshots(fmus[kind], tmp_path / "s.h5")
    err = capsys.readouterr().err
    line = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err, err
    assert line.startswith("fmu-opinf: error: auto window: the outputs stay constant"), line
    assert NAMED in line and FIX in line, line   # was: "give an input that reaches the outputs" alone


def test_a_force_sensor_that_moves_while_the_positions_rest_does_not_choose_the_window(fmus, tmp_path, capsys):
    """The sensor (y = u, direct feedthrough) shows the pulse although the Boolean keeps it from acting: the window
    judges the positions (it was: the pulse's own spectrum, dt = 5e-08 to t_end = 2.3e-06, exit 0)."""
    code = _snapshots(fmus["sensor"], tmp_path / "s.h5")
    err = capsys.readouterr().err
    assert code == 2, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("fmu-opinf: error: auto window: the positions stay constant over t <= "), line
    assert NAMED in line and FIX in line, line


def test_a_real_input_held_by_choice_is_named_beside_the_boolean(fmus, tmp_path, capsys):
    code = _snapshots(fmus["two"], tmp_path / "s.h5", "--inputs", "F[1]")
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2, line
    assert f"{NAMED}, F[2] (Real, held at its start value 0); if one does, set it, e.g. {FIX}" in line, line


def test_a_constant_recording_is_warned_about_naming_the_held_boolean(fmus, tmp_path, capsys):
    assert _snapshots(fmus["fmi2"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "20") == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "stay constant in every run" in line]
    assert len(said) == 1 and said[0].startswith("fmu-opinf: warning: fmi2.fmu: the positions and outputs"), said
    assert NAMED in said[0] and FIX in said[0], said   # was: no warning


def test_fit_of_a_constant_recording_names_the_held_boolean(fmus, tmp_path, capsys):
    assert _snapshots(fmus["fmi2"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "20") == 0
    capsys.readouterr()
    code = main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"])
    err = capsys.readouterr().err
    line = err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in err, err
    assert line.startswith("fmu-opinf: error: all snapshots are zero: nothing moved the model"), line
    assert NAMED in line and FIX in line, line   # was: "excite the system with a non-zero input"


def test_a_recording_that_moves_is_not_warned_about(fmus, tmp_path, capsys):
    assert _snapshots(fmus["fmi2"], tmp_path / "s.h5", "--dt", "0.02", "--t-end", "20", *FIX.split()) == 0
    assert "stay constant" not in capsys.readouterr().err


@pytest.mark.slow
def test_with_the_boolean_set_the_default_chain_fits_the_exact_model(fmus, tmp_path, capsys):
    assert _snapshots(fmus["fmi2"], tmp_path / "s.h5", *FIX.split()) == 0, capsys.readouterr().err
    assert main(["fit", str(tmp_path / "s.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0, capsys.readouterr().err
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    for spec in ("harmonic:amplitude=20,omega=2.71", "step:amplitude=100,t0=1"):
        assert miss_against_model(rom, _chain(), spec, 100.0) < 5e-12, spec   # measured 1.8e-12, 2.1e-14


def test_the_advice_offers_the_other_boolean_value_and_names_every_candidate():
    from fmu_opinf.basis import zero_snapshots_error
    from fmu_opinf.sources._base import held_inputs_advice

    line = held_inputs_advice({"gain": ["Real", "2", True], "brake": ["Boolean", "true", False],
                               "mode": ["Enumeration", "1", False]})
    assert line == ("inputs held while it ran, one of which may keep the force from acting: brake (Boolean, held at "
                    "its start value true), mode (Enumeration, held at its start value 1), gain (Real, set to 2); if "
                    "one does, set it, e.g. --set brake=false or parameters['brake']=false")
    assert held_inputs_advice({}) == ""
    assert zero_snapshots_error({}) == "all snapshots are zero; excite the system with a non-zero input"


def test_only_runs_of_two_samples_or_more_can_be_found_still():
    from types import SimpleNamespace

    from fmu_opinf.snapshots._write import _runs_still

    def run(x, y):
        return SimpleNamespace(x=np.asarray(x, dtype=float), y=np.asarray(y, dtype=float))

    assert _runs_still([run([[0.0, 0.0]], [[5.0, 5.0]])])
    assert not _runs_still([run([[0.0]], [[5.0]])])   # one sample: nothing to judge
    assert not _runs_still([run([[0.0, 0.0]], [[5.0, 5.0]]), run([[0.0, 1e-9]], [[5.0, 5.0]])])
    assert not _runs_still([run([[0.0, 0.0]], [[5.0, 5.0 + 1e-10]])])
