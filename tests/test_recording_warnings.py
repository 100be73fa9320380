"""Recordings that follow the FMU's integrator, not the model (audit 70, F1 and F4).

F1: a Simulink ode1-style co-simulation FMU (one explicit Euler step per ``doStep``, fixed step 0.01 s enforced,
:func:`fmu_opinf.lti_fmus.build_lti_fmu` with ``cs_method="euler"``): ``snapshots`` said nothing and the default
ROM was 22-49 % of range off the model.  The recorded positions move by exactly ``dt`` times the velocity at the
step's start; ``snapshots`` now says so, and ``fit`` refines with that Euler step (the ROM then stands for the
model).  References: the exact zero-order-hold response of the model (:func:`fmu_opinf.lti_fmus.zoh_response`),
not the FMU, and intrusive POD-Galerkin from the model's matrices on the ROM's basis.

F4: such a warning lived only on ``snapshots``' stderr; ``fit``, ``compare`` and ``export`` now repeat it from the
file (attribute ``recording_warnings``).
"""

from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest

from conftest import build_fmu_set, miss_against_model
from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Run, Snapshots, record
from fmu_opinf.snapshots._notes import recorded_warning
from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

pytestmark = pytest.mark.fmu

FIXED_STEP = 0.01


def _model() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(4, inputs=(-1,), x0=[0.0, 0.0, 0.0, 0.05], name="Ode1Chain")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """Euler co-simulation at a fixed step (Simulink ode1-style) and the same model with an accurate one."""
    options = {"Ode1Chain": dict(cs_method="euler", cs_fixed_step=FIXED_STEP),
               "Ode1NoAccelerations": dict(cs_method="euler", cs_fixed_step=FIXED_STEP, expose_accelerations=False),
               "Ode1TwoInputs": dict(cs_method="euler", cs_fixed_step=FIXED_STEP),
               "AccurateChain": dict(cs_fixed_step=FIXED_STEP)}

    def build(folder, item):
        model = _model() if item != "Ode1TwoInputs" else lti_fmus.chain_model(4, inputs=(0, -1), name=item)
        return item, lti_fmus.build_lti_fmu(model, folder / f"{item}.fmu", interfaces=("cs",),
                                            identifier=item, **options[item]).path

    return build_fmu_set(request, tmp_path_factory, "lti-recording-warnings", build, list(options))


def _miss_against_model(rom: SecondOrderROM, spec: str, t_end: float = 60.0) -> float:
    """Largest output error over its range, the ROM against the exact model on ``spec``."""
    return miss_against_model(rom, _model(), spec, t_end)


@pytest.mark.slow
def test_euler_co_simulation_is_said_kept_and_fitted_as_the_model(fmus, tmp_path, capsys):
    train, rom_file = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmus["Ode1Chain"]), "-o", str(train), "-q"]) == 0
    err = capsys.readouterr().err
    assert err.count("one Euler step per communication step") == 1, err
    assert "its communication step is fixed and it offers no model exchange" in err
    with h5py.File(train) as f:
        assert list(f.attrs["recording_verdicts"]) == ["forward-euler"]
        assert "one Euler step" in f.attrs["recording_warnings"][0]
    assert main(["fit", str(train), "-o", str(rom_file), "-q"]) == 0
    assert "the output-error refinement simulates the ROM with that step" in capsys.readouterr().err
    rom = SecondOrderROM.load(rom_file)
    # measured 2.0e-13 / 1.7e-13 (before: 0.49 / 0.41, the refinement fitted the Euler trajectory with the exact step)
    assert _miss_against_model(rom, "none") < 1e-12
    assert _miss_against_model(rom, "harmonic:amplitude=1,omega=0.9") < 1e-12
    assert rom.fit_info["refinement_integrator"] == "forward-euler"
    assert main(["compare", str(rom_file), str(fmus["Ode1Chain"]), "-o", str(tmp_path / "report"), "-q"]) == 0
    assert "includes the FMU's own integration error" in capsys.readouterr().err
    assert main(["export", str(rom_file), "-o", str(tmp_path / "rom.fmu"), "-q"]) == 0
    assert "recorded with this warning" in capsys.readouterr().err
    with warnings.catch_warnings():   # (the same line again from the same place: shown once per process otherwise)
        warnings.simplefilter("always", FmuOpinfWarning)
        assert main(["compare", str(tmp_path / "rom.fmu"), str(fmus["Ode1Chain"]), "-o", str(tmp_path / "report2"),
                     "-q"]) == 0   # (audit 71 F7: the ROM FMU's provenance.json carries the fit's settings)
    assert "includes the FMU's own integration error" in capsys.readouterr().err


@pytest.mark.parametrize("to_file, stream", [(False, None), (True, None), (True, True)],
                         ids=["in-memory", "path", "streamed"])
def test_record_keeps_the_euler_warning_and_the_fit_uses_it(fmus, tmp_path, to_file, stream):
    """Audit 81c F1: ``snapshots.record`` (the README's API) warned of the Euler steps but kept nothing of it, in
    memory or in its ``path=`` file, so ``fit_rom`` fitted the Euler trajectory as the model: 0.51 / 0.42 of range off
    the exact model.  It now keeps the notes as ``record_to_file`` does, and the ROM stands for the model."""
    path = tmp_path / "train.h5" if to_file else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FmuOpinfWarning)
        snaps = record(fmus["Ode1Chain"], "impulse:amplitude=100,t0=2,width=0.5", dt=FIXED_STEP, t_end=60.0,
                       path=path, quiet=True, stream=stream)
    assert sum("one Euler step per communication step" in str(w.message) for w in caught) == 1
    assert list(snaps.attrs["recording_verdicts"]) == ["forward-euler"]
    assert "one Euler step" in snaps.attrs["recording_warnings"][0]
    if to_file:
        with h5py.File(path) as f:
            assert list(f.attrs["recording_verdicts"]) == ["forward-euler"]
        snaps = Snapshots.load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        rom = fit_rom(snaps, quiet=True)
    assert rom.fit_info["refinement_integrator"] == "forward-euler"
    # measured 2.0e-13 / 1.7e-13 (before: 0.51 / 0.42, fitted as if the FMU's steps were the model's)
    assert _miss_against_model(rom, "none") < 1e-12
    assert _miss_against_model(rom, "harmonic:amplitude=1,omega=0.9") < 1e-12


def test_euler_co_simulation_without_accelerations_is_fitted_from_its_velocities_steps(fmus, tmp_path):
    """Audit 71 F3: the same FMU without ``der(v)`` variables: the accelerations derived for accurate data were
    1.55 of their norm off (wrong signs) and the ROM 6-19 % of range off; the velocities' steps are the model's
    derivatives exactly (measured 2.0e-13 / 1.7e-13 of range against the exact model)."""
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["Ode1NoAccelerations"]), "-o", str(train), "-q"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        rom = fit_rom(Snapshots.load(train), quiet=True)
    assert _miss_against_model(rom, "none") < 1e-12
    assert _miss_against_model(rom, "harmonic:amplitude=1,omega=0.9") < 1e-12


def _galerkin(rom: SecondOrderROM, model: lti_fmus.LinearMechanicalModel) -> SecondOrderROM:
    """Intrusive POD-Galerkin from the model's matrices on the ROM's own basis (the model starts at rest at 0)."""
    V = rom.basis
    return SecondOrderROM(V.T @ model.M @ V, V.T @ model.D @ V, V.T @ model.K @ V, V.T @ model.B,
                          np.asarray(model.Cp) @ V, np.asarray(model.Cv) @ V, dt=rom.dt, integrator="exact")


@pytest.mark.slow
def test_euler_co_simulation_at_a_reduced_order_is_refined_with_its_step(tmp_path):
    """A 30-mass chain in Simulink ode1 style at r = 16 of 30: refined with the FMU's Euler step the ROM is as
    close to the model as POD-Galerkin on the same basis (measured impulse / harmonic, max |dy| over the range:
    0.031 / 0.0076 against Galerkin's 0.034 / 0.0021; refined with the ROM's exact step, as before: 0.41 / 0.065;
    the SDP solution alone: 0.038 / 0.041)."""
    model = lti_fmus.chain_model(30, inputs=(-1,), name="Ode1Chain30")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "Ode1Chain30.fmu", interfaces=("cs",), cs_method="euler",
                                 cs_fixed_step=FIXED_STEP).path
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmu), "-o", str(train), "-q"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        rom = fit_rom(Snapshots.load(train), r=16, quiet=True)
    galerkin = _galerkin(rom, model)

    def miss(which: SecondOrderROM, spec: str) -> float:
        t = time_grid(which.dt, 60.0)
        u = inputs_in_effect(parse_signal(spec, 1), t, 1)
        reference = lti_fmus.zoh_response(model, t, u[:, 1:]).y
        return float(np.max(np.abs(which.simulate(spec, which.dt, 60.0).y - reference).max(axis=1)
                            / np.ptp(reference, axis=1)))

    impulse, harmonic = "impulse:amplitude=100,t0=2,width=0.5", "harmonic:amplitude=1,omega=0.9"
    assert miss(rom, impulse) < 1.2 * miss(galerkin, impulse)        # measured ratio 0.93
    assert miss(rom, harmonic) < 5.0 * miss(galerkin, harmonic)      # measured ratio 3.7
    assert miss(rom, harmonic) < 0.012                                # measured 0.0076


def test_a_backward_rule_uses_the_sdp_only_with_the_fmu_s_own_accelerations():
    """Semi-implicit or implicit Euler (the data do not tell which), or any co-simulation whose outputs depend on the
    step: the FMU's own accelerations are the model's derivatives, so the SDP solution is kept; with accelerations
    derived from the samples nothing is changed."""
    from fmu_opinf.fit._time_integrator import _recorded_euler_step

    assert _recorded_euler_step({"recording_verdicts": ["forward-euler"], "derived_xddot": True}) == "forward-euler"
    assert _recorded_euler_step({"recording_verdicts": ["backward-euler"], "derived_xddot": False}) == "backward-euler"
    assert _recorded_euler_step({"recording_verdicts": ["backward-euler"], "derived_xddot": True}) is None
    assert _recorded_euler_step({"recording_verdicts": ["step-dependent"], "derived_xddot": np.False_}) == \
        "step-dependent"   # (audit 71 F4: Euler substeps; as read from HDF5, NumPy's bool)
    assert _recorded_euler_step({"recording_verdicts": ["step-dependent"], "derived_xddot": np.True_}) is None
    assert _recorded_euler_step({"recording_verdicts": ["late-outputs"], "derived_xddot": False}) is None
    assert _recorded_euler_step({"recording_verdicts": "forward-euler; rm -rf"}) is None


def test_the_euler_warning_is_said_once_per_recording(fmus, tmp_path, capsys):
    """Two inputs, one run each: one line and one stored warning, not one per run."""
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["Ode1TwoInputs"]), "-o", str(train), "-q"]) == 0
    assert capsys.readouterr().err.count("one Euler step per communication step") == 1
    with h5py.File(train) as f:
        assert len(f.attrs["recording_warnings"]) == 1 and f.attrs["n_runs"] == 2


def test_accurate_co_simulation_at_the_same_step_is_not_called_euler(fmus, tmp_path, capsys):
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmus["AccurateChain"]), "-o", str(train), "-q"]) == 0
    assert "Euler" not in capsys.readouterr().err
    with h5py.File(train) as f:
        assert "recording_warnings" not in f.attrs


def _runs_with_warning(warning: str | None) -> Snapshots:
    """One exact run of the model (no FMU), with a recording warning in its attributes as ``snapshots`` writes it."""
    t = time_grid(0.05, 40.0)
    u = inputs_in_effect(parse_signal("impulse:amplitude=100,t0=2,width=0.5", 1), t, 1)
    exact = lti_fmus.zoh_response(_model(), t, u[:, 1:])
    attrs = {} if warning is None else {"recording_warnings": [warning], "recording_verdicts": ["step-dependent"]}
    return Snapshots([Run(t, u, exact.x, exact.v, exact.a, exact.y)], attrs)


def test_fit_and_export_repeat_the_recording_warning(tmp_path):
    said = "X.fmu: the co-simulation depends on the communication step (...)"
    with pytest.warns(FmuOpinfWarning, match=r"recorded with this warning: X\.fmu: the co-simulation depends"):
        rom = fit_rom(_runs_with_warning(said), quiet=True, refine=False)
    assert recorded_warning(rom.provenance["snapshots"]).endswith(said)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        quiet = fit_rom(_runs_with_warning(None), quiet=True, refine=False)
    from fmu_opinf.export import _warn_if_recording_warned

    with pytest.warns(FmuOpinfWarning, match="recorded with this warning"):
        assert _warn_if_recording_warned(dict(rom.provenance))
    assert not _warn_if_recording_warned(dict(quiet.provenance))


def test_merged_snapshots_keep_every_part_s_warning():
    merged = _runs_with_warning("first").append(_runs_with_warning("second"))
    assert merged.attrs["recording_warnings"] == ["first", "second"]
    assert merged.attrs["recording_verdicts"] == ["step-dependent"]
    assert recorded_warning(merged.attrs).endswith("with this warning: first (and 1 more warning)")


def test_recorded_warnings_are_read_as_data():
    assert recorded_warning({"recording_warnings": [3, None]}) is None
    assert recorded_warning({"recording_warnings": "one"}).endswith("warning: one")
    assert recorded_warning({"recording_warnings": {"a": 1}}) is None
