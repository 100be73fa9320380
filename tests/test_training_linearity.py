"""The default training's amplitude on models that are linear only near rest (audit 79b, F1-F3).

The default pulse is 100 in the input's unit whatever the model: on a 100 N/m chain with a hardening spring it moved
the masses by 1.4-2.2 m, and the ROM, fitted to that, was 3-100 % of range off the exact linearization on small
inputs, silently at 15 % extra stiffness.  ``snapshots`` now compares the response to the default pulse with -10 times
the response to a tenth of it the other way (:mod:`fmu_opinf.snapshots._linearity`), lowers the amplitude by decades
where they differ, and warns, kept in the file, where no decade cures it (friction).  References: the exact
linearization (``lti_fmus.zoh_response`` of the linear model the nonlinear FMU is built around)."""

from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Snapshots, record_to_file
from fmu_opinf.snapshots import _linearity
from fmu_opinf.snapshots._linearity import mismatch
from fmu_opinf.snapshots._notes import recorded_verdicts, recorded_warning

DEFAULT = "impulse:amplitude=100,t0=2,width=0.5"

#: One nonlinear force per unit mass on dof 0, added to the lti_fmus kernel's accelerations after its damping term
#: (``z``: positions then velocities, ``qdd``: accelerations); the linear part stays the linearization at rest.
FORCES = {
    "hardening": "qdd[0] -= 1e4 * z[0] * z[0] * z[0];",    # k x + k3 x^3, k3 = 1e4 N/m^3
    "friction": "qdd[0] -= 5.0 * tanh(z[nq] / 0.01);",    # 5 N Coulomb friction, smoothed over 0.01 m/s
    "softening": "qdd[0] += 30.0 * z[0] * z[0] * z[0];",   # k x - k3 x^3, k3 = 30 N/m^3: escapes beyond 2.6 m
}
_ANCHOR = "    addProduct(qdd, inst->Dq, z + nq, nq, nq, -1.0);\n"


def _two_masses() -> lti_fmus.LinearMechanicalModel:
    """Two 1 kg masses, springs of 100 N/m to ground and between them, a force on the second; outputs x1, x2."""
    K = np.array([[200.0, -100.0], [-100.0, 100.0]])
    return lti_fmus.LinearMechanicalModel(M=np.eye(2), D=0.02 * K + 0.05 * np.eye(2), K=K,
                                          B=np.array([[0.0], [1.0]]), Cp=np.eye(2), name="TwoMasses")


def _nonlinear_fmu(tmp_path, monkeypatch, force: str):
    """The FMU of :func:`_two_masses` with the test-only C term ``FORCES[force]`` added (a copy of the sources)."""
    sources = tmp_path / f"src_{force}"
    shutil.copytree(lti_fmus._lti_sources_dir(), sources)
    text = (sources / "lti.c").read_text()
    assert _ANCHOR in text
    (sources / "lti.c").write_text(text.replace(_ANCHOR, _ANCHOR + "    " + FORCES[force] + "\n", 1))
    monkeypatch.setattr(lti_fmus, "_lti_sources_dir", lambda: sources)
    fmu = lti_fmus.build_lti_fmu(_two_masses(), tmp_path / f"{force}.fmu", reuse=False)
    monkeypatch.undo()
    return str(fmu.path)


def _counting_checks(monkeypatch) -> list[float]:
    """The amplitude factors of the check's runs, as they are made."""
    made: list[float] = []
    run = _linearity._run_scaled

    def counted(source, reference, factor, quiet, isolate):
        made.append(factor)
        return run(source, reference, factor, quiet, isolate)

    monkeypatch.setattr(_linearity, "_run_scaled", counted)
    return made


def _off_linearization(rom, spec: str, dt: float, t_end: float = 60.0) -> np.ndarray:
    """The ROM's largest output error on ``spec`` relative to each output's range, against the exact linearization."""
    t = np.arange(round(t_end / dt) + 1) * dt
    exact = lti_fmus.zoh_response(_two_masses(), t, parse_signal(spec).sample(t)).y
    return np.abs(rom.simulate(spec, dt, t_end).y[:, :t.size] - exact).max(axis=1) / np.ptp(exact, axis=1)


def test_the_mismatch_is_zero_for_a_scaled_response_and_the_stiffening_share_otherwise():
    t = np.linspace(0.0, 10.0, 501)
    free = np.vstack([np.full_like(t, 3.0), 0.1 * t])   # an offset and the model's own drift
    shape = np.vstack([np.sin(t), np.cos(2 * t) - 1.0])
    assert mismatch(free + 100 * shape, free - 10 * shape, free, -10.0) < 1e-13
    assert mismatch(free + 100 * shape * 1.01, free - 10 * shape, free, -10.0) == pytest.approx(0.01 / 1.01)
    # an output the pulse does not reach is not judged (its round-off is no mismatch)
    still = np.vstack([free[0] + 1e-14 * np.sin(3 * t), free[1] + 100 * shape[1]])
    assert mismatch(still, free - 0.0, free, -10.0) == pytest.approx(1.0)   # only output 2 judged: it misses by 1


@pytest.mark.fmu
@pytest.mark.slow
def test_a_hardening_spring_is_trained_at_a_lowered_amplitude_and_its_rom_is_the_linearization(
        tmp_path, monkeypatch, capsys):
    """k3 = 1e4 N/m^3: 100 N moved the masses by 0.3 and 1.7 m; the ROM was 43 % / 89 % of range off the exact
    linearization on 0.01 N inputs (audit 79b, F1).  The check lowers to 0.1 N (mismatch 3.1, then 0.9, 0.02,
    2e-4 per decade), said in one line; the ROM is then 5.9e-5 / 1.3e-4 off.  The old code: 100 N, no line."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    made = _counting_checks(monkeypatch)
    record_to_file(fmu, tmp_path / "train.h5", None)
    said = capsys.readouterr().err
    # (the first at the pilots' tolerance, then again at the recording's: model exchange, DOP853)
    assert made == [-0.1, -0.1, 0.01, -0.001, 0.0001]
    assert "training amplitude 0.1 on F: the response to the default 100 on F and -10 times the response to -10 on F" \
        in said and "give --input or signal= impulse:amplitude=... to choose another" in said
    snaps = Snapshots.load(tmp_path / "train.h5")
    assert snaps.runs[0].attrs["input_spec"].startswith("impulse:amplitude=0.1,")
    assert "recording_warnings" not in snaps.attrs
    rom = fit_rom(snaps, quiet=True)
    dt = float(snaps.runs[0].t[1] - snaps.runs[0].t[0])
    assert np.all(_off_linearization(rom, "harmonic:amplitude=0.01,omega=1.3", dt) < 1.2e-4)  # 5.9e-5, 4.2e-5
    assert np.all(_off_linearization(rom, "step:amplitude=0.01,t0=0.5", dt) < 2.6e-4)        # 1.3e-4, 1.1e-4


@pytest.mark.fmu
@pytest.mark.slow
def test_friction_keeps_the_default_amplitude_with_a_warning_kept_in_the_file(tmp_path, monkeypatch):
    """5 N smoothed Coulomb friction: the mismatch does not fall with the amplitude (0.66, then 0.92): no decade is
    linear, the default stays, and the warning reaches fit (recorded_warning) with the figures and the cause."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "friction")
    made = _counting_checks(monkeypatch)
    with pytest.warns(FmuOpinfWarning, match=r"friction.fmu: the response does not scale with the input: .* differ "
                      r"by 0\.\d+, and by 0\.\d+ a decade lower each \(friction, a contact at the rest position, or a "
                      r"saturation below the smallest pulse tried\): "
                      "the model is not linear, and a ROM fits it only near one amplitude"):
        record_to_file(fmu, tmp_path / "train.h5", None, quiet=True)
    assert made == [-0.1, -0.1, 0.01]   # (the first at the pilots' tolerance, then at the check's)
    snaps = Snapshots.load(tmp_path / "train.h5")
    assert snaps.runs[0].attrs["input_spec"] == DEFAULT
    assert recorded_verdicts(snaps.attrs) == {"nonlinear"}
    assert "the model is not linear" in recorded_warning(snaps.attrs)


@pytest.mark.fmu
@pytest.mark.slow
@pytest.mark.parametrize("case", ["gravity", "euler"])
def test_a_linear_fmu_keeps_the_default_amplitude_at_one_extra_run(tmp_path, monkeypatch, case):
    """A chain under gravity with output offsets (moving on its own: the check reuses the run without the pulse and
    the pulse's run of the sizing) and an explicit-Euler co-simulation at the user's --dt (the last pilot reused):
    mismatch 8e-14 and 5e-15, one run of the check each, the default 100 recorded."""
    if case == "gravity":
        model = lti_fmus.chain_model(5, force_offset=9.81, output_offset=2.0, name="Hung5")
        fmu, options = lti_fmus.build_lti_fmu(model, tmp_path / "hung.fmu", interfaces=("cs",)), {}
    else:
        fmu = lti_fmus.build_lti_fmu(lti_fmus.chain_model(5, name="Euler5"), tmp_path / "euler.fmu",
                                     interfaces=("cs",), cs_method="euler")
        options = {"dt": 0.01}
    made = _counting_checks(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(str(fmu.path), tmp_path / "train.h5", None, quiet=True, **options)
    assert not [w for w in seen if "does not scale" in str(w.message)]
    assert made == [-0.1]
    assert Snapshots.load(tmp_path / "train.h5").runs[0].attrs["input_spec"] == DEFAULT


@pytest.mark.fmu
@pytest.mark.slow   # 9 s: BDF at 1e-4, then the check again at 1e-9
@pytest.mark.parametrize("method", ["bdf", "lsoda"])
def test_a_linear_fmu_integrated_loosely_is_checked_again_at_a_tight_tolerance(tmp_path, monkeypatch, method):
    """Audit 80 F1: a linear model-exchange FMU off rest under gravity, recorded at --tolerance 1e-4, differed from
    its scaled response by 0.031 (BDF) and 0.032 (LSODA) of the pulse's effect, its integration error, and was
    warned 'not linear (friction, or a contact at the rest position)'.  The check now runs again at 1e-9 (measured
    5.3e-7 / 3.9e-7): no warning, the default amplitude."""
    K = np.array([[200.0, -100.0], [-100.0, 100.0]])
    model = lti_fmus.LinearMechanicalModel(M=np.eye(2), D=0.02 * K + 0.05 * np.eye(2), K=K,
                                           B=np.array([[0.0], [1.0]]), Cp=np.eye(2), f0=[-9.81, -9.81],
                                           x0=[0.3, -0.2], v0=[1.0, 0.0], name="GravOff")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "grav.fmu", interfaces=("me",))
    made = _counting_checks(monkeypatch)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        record_to_file(str(fmu.path), tmp_path / "train.h5", None, quiet=True, tolerance=1e-4, method=method)
    assert not [w for w in seen if "does not scale" in str(w.message)]
    assert made == [-0.1, -0.1]   # at the pilots' tolerance, then at the check's
    assert Snapshots.load(tmp_path / "train.h5").runs[0].attrs["input_spec"] == DEFAULT


@pytest.mark.fmu
def test_a_given_input_is_recorded_as_given_and_not_lowered(tmp_path, monkeypatch):
    """The user chose the input: it is not lowered (the hardening spring at 100 N); the check of a given input only
    warns (test_given_input_linearity.py)."""
    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "hardening")
    with pytest.warns(FmuOpinfWarning, match="does not scale with it"):
        record_to_file(fmu, tmp_path / "train.h5", DEFAULT, dt=0.02, t_end=20.0, quiet=True)
    assert Snapshots.load(tmp_path / "train.h5").runs[0].attrs["input_spec"] == DEFAULT


@pytest.mark.fmu
def test_a_pilot_that_fails_under_the_default_pulse_names_a_smaller_pulse(tmp_path, monkeypatch):
    """Audit 80 F2: a softening spring escapes under the default 100 N pulse and the first pilot's integration
    fails; the advice named --dt and --t-end (then a looser tolerance, then the interface), while a smaller pulse
    records it.  The error now names the smaller pulse, and that pulse records."""
    from fmu_opinf.errors import FmuOpinfError

    fmu = _nonlinear_fmu(tmp_path, monkeypatch, "softening")
    with pytest.raises(FmuOpinfError) as caught:
        record_to_file(fmu, tmp_path / "train.h5", None, quiet=True)
    text = str(caught.value)
    assert "default pulse (amplitude 100) may drive it out of its range" in text and "\n" not in text
    assert text.endswith("e.g. --input \"impulse:amplitude=1,t0=2,width=0.5\" or "
                         "signal='impulse:amplitude=1,t0=2,width=0.5'; no file was written"), text
    record_to_file(fmu, tmp_path / "small.h5", "impulse:amplitude=1,t0=2,width=0.5", dt=0.02, t_end=20.0,
                   quiet=True)
    assert not (tmp_path / "train.h5").exists() and (tmp_path / "small.h5").exists()
