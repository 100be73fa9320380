"""compare without --input on a ROM of two inputs: each input is also judged alone (audit 72 F1's compare side).

The default test input swings every driven input at once, each at its own frequency.  Where one input moves the
outputs far more than another, a ROM wrong on the weaker input passed: on audit 72's twostiff10.fmu (a stiff base
force, a free tip force) an r = 18 ROM read 0.16 % of range with both forces on and was 11 % of range off with the
base force alone.  The reference here is exact by construction: a ROM of the model at full order (exact for these
linear data) with its first input's column of ``Br`` scaled by 1.3, so its response to that input alone is 1.3 times
the model's (eq. 19: 0.3**2 = 0.09) and to the other input exact.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from fmu_opinf import fit, lti_fmus, snapshots
from fmu_opinf.cli import main

GAIN_ERROR = 0.3


def _model() -> lti_fmus.LinearMechanicalModel:
    """A 4-mass chain with forces at the base and the tip, its wall spring 10 times stiffer (the base force moves
    the tip little), the tip position the only output."""
    chain = lti_fmus.chain_model(4, inputs=(0, 3), x0=[0.0] * 4, name="StiffBaseTwoForces")
    K = np.array(chain.K, dtype=float)
    K[0, 0] *= 10.0
    return dataclasses.replace(chain, K=K, D=0.05 * np.asarray(chain.M) + 0.01 * K, Cp=np.eye(4)[3:], Cv=None,
                               Ca=None, y0=None)


@pytest.mark.fmu
@pytest.mark.slow
def test_default_compare_judges_each_input_alone_and_names_it(tmp_path, capsys):
    fmu = lti_fmus.build_lti_fmu(_model(), tmp_path / "two.fmu", interfaces=("cs",)).path
    training = ["impulse:amplitude=3,t0=1,width=0.5;none", "none;impulse:amplitude=3,t0=1,width=0.5"]
    snapshots.record_to_file(str(fmu), tmp_path / "train.h5", training, dt=0.05, t_end=60.0, quiet=True)
    fitted = fit.fit_rom(snapshots.Snapshots.load(tmp_path / "train.h5"), r=4, quiet=True, refine=False)
    fitted.Br = np.array(fitted.Br, dtype=float)
    fitted.Br[:, 0] *= 1.0 + GAIN_ERROR   # wrong on the base force alone
    fitted.save(tmp_path / "rom.h5")
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "rom.h5"), str(fmu), "--t-end", "60", "-o", str(tmp_path / "report")]) == 0
    out, err = capsys.readouterr()
    assert "then each of F[1], F[2] alone (2 more runs of the source" in err
    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    # both forces on: measured 2.0e-4 (0.7 % of range): the tip force's response hides the base force's error
    assert metrics["max_error"] < 1e-3
    alone = {run["driven_alone"]: run for run in metrics["each_input_alone"]}
    assert list(alone) == ["F[1]", "F[2]"]
    assert alone["F[1]"]["max_error"] == pytest.approx(GAIN_ERROR ** 2, rel=1e-6)   # measured 0.0900000000
    assert alone["F[2]"]["max_error"] < 1e-20   # measured 5e-28: exact
    for name, run in alone.items():   # the other input held at its operating point (amplitude 0)
        parts = run["input"].split(";")
        assert [("amplitude=0," in part) for part in parts] == [name != "F[1]", name != "F[2]"]
    rows = {line.split("  ")[0].strip(): line for line in out.splitlines() if line.startswith("rom.h5")}
    assert set(rows) == {"rom.h5", "rom.h5, F[1] alone", "rom.h5, F[2] alone"}
    assert "9.00e-02" in rows["rom.h5, F[1] alone"]
    page = (tmp_path / "report" / "index.html").read_text()
    assert "<h2>Each input alone</h2>" in page and "F[1] alone" in page


def test_a_single_driven_input_needs_no_runs_alone():
    """One input swinging (the other 'none'), or a ROM of one input: the comparison itself is that input alone."""
    from fmu_opinf._test_input import each_input_alone

    assert each_input_alone("harmonic:amplitude=1,omega=0.5;none", 2, ["a", "b"]) == []
    assert each_input_alone("harmonic:amplitude=1,omega=0.5", 1, ["a"]) == []
    assert each_input_alone("harmonic:amplitude=1,omega=0.5,phase=0,offset=2;harmonic:amplitude=3,omega=0.7", 2,
                            ["a", "b"]) == [
        ("a", "harmonic:amplitude=1,omega=0.5,phase=0,offset=2;harmonic:amplitude=0,omega=0.7,phase=0,offset=0"),
        ("b", "harmonic:amplitude=0,omega=0.5,phase=0,offset=2;harmonic:amplitude=3,omega=0.7,phase=0,offset=0")]
