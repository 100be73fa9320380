"""compare on a given test input that drives several inputs alike: each input is also run alone (audit84 F4).

One spec for all inputs (``--input "harmonic:amplitude=1,omega=0.5"``) on a model whose inputs move the outputs by
very different amounts gave one figure, dominated by the largest input: an r = 14 ROM of a 20-mass chain read
0.07 % of range with 1 N, 1 kN and 1 m of support motion together, and was 18 % off with the N force alone, 59 % with
the support alone.  The reference here is the exact zero-order-hold response of the true matrices
(``lti_fmus.zoh_response``).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from test_several_inputs import LATER, TRAINING, _exact_runs, _force_and_support, _miss

from fmu_opinf import lti_fmus
from fmu_opinf.cli import main
from fmu_opinf.compare import Comparison
from fmu_opinf.compare._alone import ALONE_AT_MOST, HIDDEN_FACTOR, given_each_input_alone, hidden_input_line
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.signals import parse_signal

GIVEN = "harmonic:amplitude=1,omega=0.5"


@pytest.mark.fmu
@pytest.mark.slow  # builds two FMUs, fits a 16-state ROM and compares twice (about 25 s)
def test_a_given_input_on_two_inputs_is_also_run_on_each_alone(tmp_path, capsys):
    """A 20-mass chain with a force in kN on its last mass and an ``Accelerate`` support, its r = 16 ROM fitted on
    exact data (:func:`fit_rom_exact`): on ``harmonic:amplitude=1,omega=0.5`` for both the ROM is 0.0016 of range
    off the exact model (the kN force's response dominates), on the support alone 0.082.  compare now runs each
    input alone as well, its rows read what the exact model gives, and a line names the hidden input and the
    --input that shows it; likewise for the exported ROM FMU on the command line."""
    from fmu_opinf.compare import compare
    from fmu_opinf.export import export_fmu

    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    model = _force_and_support()
    dt, t_end = 0.05, 173.85
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)   # (an order given: the fit's own lines are not tested here)
        rom = fit_rom_exact(model, dt, t_end)
        fmu = lti_fmus.build_lti_fmu(model, tmp_path / "two_inputs.fmu", interfaces=("me",))
        capsys.readouterr()
        result = compare(rom, fmu.path, GIVEN, t_end=60.0)
    end = float(result.t[-1])
    joint = _miss(rom, model, GIVEN, end)   # measured 0.00158
    alone = {run.driven_alone: run for run in result.each_input_alone}
    assert list(alone) == ["u[1]", "u[2]"]
    exact = {name: _miss(rom, model, run.input_spec, end) for name, run in alone.items()}   # 0.0020, 0.082
    for name, run in alone.items():
        shown = max(figures["relative_max_variation"] for figures in run.metrics()["per_output"].values())
        assert shown == pytest.approx(exact[name], rel=0.1), (name, shown, exact[name])
    assert exact["u[2]"] > 30 * joint   # the joint figure hides the support's miss (measured 52 times)
    said = capsys.readouterr().err
    assert "then each of u[1], u[2] alone (2 more runs of the source" in said, said
    note = result.metrics()["each_input_alone_note"]
    assert note.startswith("u[2] alone is ") and f'--input "{alone["u[2]"].input_spec}"' in note, note
    assert note in said
    assert [run["driven_alone"] for run in result.metrics()["each_input_alone"]] == ["u[1]", "u[2]"]
    # the exported ROM FMU on the command line: the same runs, rows in the table, metrics.json and the report
    export_fmu(rom, tmp_path / "rom.fmu")
    report = tmp_path / "report"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        assert main(["compare", str(tmp_path / "rom.fmu"), str(fmu.path), "--input", GIVEN, "--t-end", "60",
                     "-o", str(report)]) == 0
    out, err = capsys.readouterr()
    metrics = json.loads((report / "metrics.json").read_text())
    exported = {run["driven_alone"]: run for run in metrics["each_input_alone"]}
    assert list(exported) == ["u[1]", "u[2]"]
    for name, run in exported.items():
        shown = max(figures["relative_max_variation"] for figures in run["per_output"].values())
        assert shown == pytest.approx(exact[name], rel=0.1), (name, shown, exact[name])
    assert metrics["each_input_alone_note"].startswith("u[2] alone is ") and metrics["each_input_alone_note"] in err
    rows = [line.split("  ")[0] for line in out.splitlines() if line.startswith("rom.fmu")]
    assert rows == ["rom.fmu", "rom.fmu, u[1] alone", "rom.fmu, u[2] alone"], out
    page = (report / "index.html").read_text()
    assert "<h2>Each input alone</h2>" in page and "u[2] alone is " in page


def fit_rom_exact(model: lti_fmus.LinearMechanicalModel, dt: float, t_end: float):
    """The r = 16 ROM of ``model`` fitted on one exact run pulsing both inputs (the support later): the kN force's
    response outweighs the support's in the fit, so the ROM misses on the support alone what a joint test hides
    (runs of each input alone are weighted by their sizes since test_run_balance, and their misses come out alike)."""
    from fmu_opinf.fit import fit_rom

    return fit_rom(_exact_runs(model, dt, t_end, (f"{TRAINING};{LATER}",)), r=16, integrator="exact", quiet=True)


def test_one_spec_for_all_inputs_is_split_into_runs_that_add_up_to_it():
    """Each run alone drives one input with the given spec and holds the others at its offset: the runs' inputs
    minus the offsets add up to the joint input's (a linear model's joint response is their sum)."""
    names = ["F[1]", "F[2]", "F[3]"]
    t = np.linspace(0.0, 20.0, 401)
    for spec in ("harmonic:amplitude=2,omega=0.5,offset=3", "impulse:amplitude=100,t0=2,width=0.5",
                 "step:amplitude=1,t0=1,offset=-1", "chirp:amplitude=1,omega1=2,duration=10"):
        runs, line = given_each_input_alone(spec, 3, names)
        assert line == "" and [name for name, _ in runs] == names
        offset = parse_signal(spec).params["offset"]
        joint = parse_signal(spec, 3).sample(t)
        parts = [parse_signal(alone, 3).sample(t) for _, alone in runs]
        assert np.allclose(sum(part - offset for part in parts) + offset, joint, atol=1e-12), spec
        for i, part in enumerate(parts):   # input i driven, the others at the offset
            assert np.allclose(np.delete(part, i, axis=0), offset) and np.allclose(part[i], joint[i])


@pytest.mark.parametrize("spec, m", [
    ("harmonic:amplitude=1,omega=0.5", 1),                               # one input: the run is that input alone
    ("harmonic:amplitude=1,omega=0.5;harmonic:amplitude=1,omega=0.7", 2),   # each input's signal chosen
    ("harmonic:amplitude=0,omega=0.5,offset=2", 3),                      # nothing swings
    ("none", 3),
])
def test_inputs_chosen_one_by_one_or_not_driven_are_compared_as_given(spec, m):
    assert given_each_input_alone(spec, m, [f"u[{i}]" for i in range(1, m + 1)]) == ([], "")


def test_a_table_is_compared_as_given(tmp_path):
    path = tmp_path / "u.csv"
    path.write_text("time,u\n0,0\n10,1\n")
    assert given_each_input_alone(str(path), 2, ["a", "b"]) == ([], "")
    assert given_each_input_alone(path, 2, ["a", "b"]) == ([], "")


def test_more_inputs_than_the_cap_are_not_run_but_the_line_says_how():
    """A model of many inputs would cost as many more runs of the source: none is run, and the line gives the
    --input (and signal=) that judges the first input alone."""
    m = ALONE_AT_MOST + 1
    runs, line = given_each_input_alone(GIVEN, m, [f"F[{i}]" for i in range(1, m + 1)])
    assert runs == []
    first = ";".join(["harmonic:amplitude=1,omega=0.5,phase=0,offset=0"]
                     + ["harmonic:amplitude=0,omega=0.5,phase=0,offset=0"] * (m - 1))
    assert f"drives all {m} inputs at once" in line and f'F[1]: --input "{first}" or signal=' in line, line
    assert len(given_each_input_alone(GIVEN, ALONE_AT_MOST, [f"F[{i}]" for i in range(ALONE_AT_MOST)])[0]) \
        == ALONE_AT_MOST


def _comparison(miss: float, spec: str, alone: str = "") -> Comparison:
    """A comparison of one output of range 2 missed by ``miss`` of its range at one point."""
    t = np.linspace(0.0, 1.0, 5)
    y = np.array([[0.0, 1.0, 0.0, -1.0, 0.0]])
    y_rom = y.copy()
    y_rom[0, 1] += 2.0 * miss
    return Comparison(t=t, y_fom=y, y_rom=y_rom, output_names=["y"], input_spec=spec, fom_seconds=1.0,
                      rom_seconds=0.1, r=2, driven_alone=alone)


def test_the_line_names_an_input_the_joint_run_hides_and_only_then():
    joint = _comparison(1e-3, "harmonic:amplitude=1,omega=0.5")
    hidden = _comparison(0.1, "harmonic:amplitude=0,omega=0.5;harmonic:amplitude=1,omega=0.5", "u[2]")
    seen = _comparison(1e-3 * HIDDEN_FACTOR * 0.9, "harmonic:amplitude=1,omega=0.5;harmonic:amplitude=0,omega=0.5",
                       "u[1]")
    line = hidden_input_line(joint, [seen, hidden])
    assert line.startswith("u[2] alone is 0.1 of y's range off, 1e+02 times"), line
    assert line.endswith(f'--input "{hidden.input_spec}" or signal={hidden.input_spec!r}'), line
    assert hidden_input_line(joint, [seen]) == "" and hidden_input_line(joint, []) == ""
