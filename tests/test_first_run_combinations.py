"""A new user's first run on exporter conventions combined in ways the other suites do not cover.

Each FMU is built by :mod:`fmu_opinf.lti_fmus` and driven through the command line as a new user would (defaults
first); results are checked against the exact zero-order-hold solution of the model
(:func:`fmu_opinf.lti_fmus.zoh_response`) and against what the generator declared, not against the tool's output.

* ``stiffness-input``: FMI 2 ME + CS, ``stiffness_scale`` exposed as an input (start 1).  Unlike ``mass_scale``
  it does not fail at 0, so driving it with the training impulse used to give a silently wrong model (m = 2,
  a stiffness that follows the impulse) and a comparison that blew up.
* ``array-outputs``: FMI 3, the outputs one array ``y`` (positions, ``declaredType`` Position: unit on the type
  definition) with an ``<Alias>``, a force sensor output ``forceSensor.f = F`` (direct feedthrough, unit N), a
  constant force.  The figures lost the unit of array elements (``y[1]`` is no variable name), and the exported
  ROM FMU declared no units at all.
* ``body-by-body`` (FMI 3, with and without model-structure dependencies) and ``body-by-body-fmi2``: states,
  ``der()`` variables and the state vector sorted by component (``mass[1].s, mass[1].v, mass[2].s, ...``).  In
  FMI 3 ``der(mass[1].s)`` cannot share ``mass[1].v``'s value reference, and the states used to be split in
  halves: a wrong model, max eps_y 0.34.
* ``array-structural``: FMI 3 arrays sized by the structural parameter ``n`` (set to 8), outputs with aliases
  and units (m, m/s, m/s2: an acceleration sensor with feedthrough), a constant force, start off rest.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import build_fmu_set
from fmu_opinf.cli import main
from fmu_opinf.newmark import time_grid
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Snapshots

pytestmark = pytest.mark.fmu

HARMONIC = "harmonic:amplitude=1,omega=0.8"
OFF_REST = dict(x0=[0.05, -0.02, 0.03, 0.0, 0.04], v0=[0.0, 0.1, 0.0, -0.05, 0.0])


def _two_position_sensors(model):
    """Outputs: positions of masses 5 and 3 with offsets (both in m, so an output array has one unit)."""
    Cp = np.zeros((2, 5))
    Cp[0, 4] = Cp[1, 2] = 1.0
    return replace(model, Cp=Cp, Cv=np.zeros((2, 5)), Ca=np.zeros((2, 5)), y0=np.array([0.1, -0.05]))


def _definitions():
    from fmu_opinf import lti_fmus

    return {
        "stiffness-input": (lti_fmus.chain_model(name="StiffnessInput", **OFF_REST),
                            dict(parameter_inputs=("stiffness_scale",))),
        "array-outputs": (_two_position_sensors(lti_fmus.chain_model(name="ArrayOutputs", force_offset=0.3)),
                          dict(fmi_version="3.0", output_array=True, input_sensors=True, output_units=True,
                               declared_types=True, output_aliases=True)),
        "body-by-body": (lti_fmus.chain_model(name="BodyByBody", force_offset=0.3, **OFF_REST),
                         dict(fmi_version="3.0", interleaved=True, output_units=True)),
        "body-by-body-no-dependencies": (lti_fmus.chain_model(name="BodyByBodyNoDeps", force_offset=0.3, **OFF_REST),
                                         dict(fmi_version="3.0", interleaved=True, dependencies=False)),
        "body-by-body-fmi2": (lti_fmus.chain_model(name="BodyByBody2", force_offset=0.3, **OFF_REST),
                              dict(interleaved=True, interfaces=("me",))),
        "array-structural": (lti_fmus.MassChain(n=5, force_offset=0.2, start_position=0.01, acceleration_sensor=True,
                                                name="ArrayStructural"),
                             dict(fmi_version="3.0", naming="array", output_units=True, output_aliases=True)),
    }


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory):
    """``name -> LtiFmu``; built once (cached across sessions like the corpus)."""
    from fmu_opinf import lti_fmus

    def build(folder, item):
        name, (model, options) = item
        return name, lti_fmus.build_lti_fmu(model, folder / f"{name}.fmu", **options)

    return build_fmu_set(request, tmp_path_factory, "lti-first-run", build, _definitions().items())


def max_eps(y: np.ndarray, y_exact: np.ndarray) -> float:
    """eps_y of the compare metric: ``max_t ||y - y_exact||^2 / max_t ||y_exact||^2``."""
    return float((((y - y_exact) ** 2).sum(axis=0) / (y_exact ** 2).sum(axis=0).max()).max())


def relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def exact(model, t: np.ndarray, spec: str, **scales):
    """Exact response on ``t`` under the held input ``spec``, and the input in effect at each sample (the
    project's column convention: ``u(t_0)``, then the input held over the step that ends there)."""
    from fmu_opinf.lti_fmus import zoh_response

    held = parse_signal(spec, model.m).sample(t) if model.m else None
    response = zoh_response(model, t, held, **scales)
    in_effect = np.hstack([held[:, :1], held[:, :-1]]) if model.m else np.zeros((0, t.size))
    return response, in_effect


# ------------------------------------------------------------------------------ parameters exposed as inputs
@pytest.mark.slow
def test_parameter_input_that_survives_zero_is_held_not_driven(fmus, tmp_path, capsys, monkeypatch):
    """stiffness_scale (an input starting at 1) is held at its start value by default, with one warning line;
    before, the impulse drove it too (m = 2) and the data were those of another model.  A --set value is held
    as given.  Both recordings are the exact solution with that stiffness scale."""
    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())   # the warning is once per process
    fmu = fmus["stiffness-input"]
    grid = ["--dt", "0.05", "--t-end", "30", "-q"]
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmu.path), "-o", str(train), *grid]) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(r"input\(s\) stiffness_scale start at non-zero values \(parameters "
                                              r"exposed as inputs\?\) and are held at them", err), err
    snaps = Snapshots.load(train)
    assert snaps.m == 1 and snaps.attrs["input_names"] == ["F"]
    assert snaps.attrs["held_input_names"] == ["stiffness_scale"]
    run = snaps.runs[0]
    reference, _ = exact(fmu.model, np.asarray(run.t), snaps.runs[0].attrs["input_spec"])
    assert relative(run.x, reference.x) < 2e-12 and relative(run.y, reference.y) < 1e-11  # measured 2.1e-13, 1.3e-12

    stiffer = tmp_path / "stiffer.h5"
    assert main(["snapshots", str(fmu.path), "-o", str(stiffer), "--set", "stiffness_scale=1.5", *grid]) == 0
    assert "non-zero values" not in capsys.readouterr().err        # the user gave its value: nothing to tell
    run = Snapshots.load(stiffer).runs[0]
    reference, _ = exact(fmu.model, np.asarray(run.t), run.attrs["input_spec"], stiffness_scale=1.5)
    assert relative(run.x, reference.x) < 1e-11                                           # measured 1.2e-12

    # the ROM of the default recording against the exact solution on a new input
    assert main(["fit", str(train), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    t = time_grid(0.05, 60.0)
    reference, _ = exact(fmu.model, t, HARMONIC)
    assert max_eps(rom.simulate(HARMONIC, 0.05, 60.0).y, reference.y) < 3e-22                 # measured 3.1e-23


# ------------------------------------------------------------------------------------------------ units
def test_units_of_fmi3_array_outputs_and_type_definitions(fmus):
    """The unit of an element ``y[2]`` is its array's (here from its declaredType), so the figures label it."""
    from fmu_opinf.compare._declared import _declared_units

    fmu = fmus["array-outputs"]
    assert fmu.outputs == ["y[1]", "y[2]", "forceSensor.f"]
    assert _declared_units(fmu.path, ["forceSensor.f", "y[1]", "y[2]", "F", "nothing[3]"]) == ["N", "m", "m", "N",
                                                                                                  ""]


@pytest.mark.slow
def test_array_outputs_with_feedthrough_default_chain_and_units(fmus, tmp_path):
    """Defaults through the whole chain: the force sensor (y = u) and the position array with offsets are exact;
    the report figure, and the exported ROM FMU (which passes fmpy's strict validation), carry the units."""
    from fmpy import read_model_description

    from fmu_opinf.compare import compare, simulate_outputs

    fmu = fmus["array-outputs"]
    train, rom_file, out = tmp_path / "train.h5", tmp_path / "rom.h5", tmp_path / "rom.fmu"
    assert main(["snapshots", str(fmu.path), "-o", str(train), "-q"]) == 0
    assert main(["fit", str(train), "-o", str(rom_file), "-q"]) == 0
    snaps, rom = Snapshots.load(train), SecondOrderROM.load(rom_file)
    assert snaps.attrs["output_names"] == ["y[1]", "y[2]", "forceSensor.f"]  # the declared (port) order
    assert snaps.attrs["output_units"] == ["m", "m", "N"] and snaps.attrs["input_units"] == ["N"]
    dt = float(snaps.attrs["dt"])
    t = time_grid(dt, dt * round(4 * float(snaps.runs[0].t[-1]) / dt))
    reference, u = exact(fmu.model, t, HARMONIC)
    y_exact = np.vstack([reference.y, u])
    assert max_eps(rom.simulate(HARMONIC, dt, t[-1]).y, y_exact) < 1e-24  # measured 3.5e-25 at dt = 0.02 (12592 steps)

    result = compare(rom_file, fmu.path, HARMONIC, quiet=True)
    assert result.output_units == ["m", "m", "N"]                      # before: ["", "", "N"]
    assert max_eps(result.y_fom, y_exact) < 2e-26                  # measured 1.3e-27

    assert main(["export", str(rom_file), "-o", str(out), "-q", "--reconstruct", "mass[3].s"]) == 0
    described = {v.name: v for v in read_model_description(str(out), validate=True).modelVariables}
    assert [described[name].unit for name in ("F", "forceSensor.f", "y[1]", "y[2]", "mass[3].s")] == \
        ["N", "N", "m", "m", "m"]                                     # before: no units
    y_exported, _, _, names = simulate_outputs(out, parse_signal(HARMONIC, 1), t)  # the model's run: above
    rows = [names.index(name) for name in ("y[1]", "y[2]", "forceSensor.f")]
    assert max_eps(y_exported[rows], y_exact) < 1e-24                                      # measured 3.5e-25


@pytest.mark.slow
def test_fmi3_structural_size_with_output_aliases_and_units(fmus, tmp_path):
    """--set n=8 in configuration mode; outputs with <Alias> children and units; the default chain is exact and
    the comparison knows the units (m, m/s, m/s2)."""
    from fmu_opinf.compare import compare

    fmu = fmus["array-structural"]
    model = _definitions()["array-structural"][0].model(8)
    train, rom_file = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu.path), "-o", str(train), "-q", "--set", "n=8"]) == 0
    assert main(["fit", str(train), "-o", str(rom_file), "-q"]) == 0
    snaps, rom = Snapshots.load(train), SecondOrderROM.load(rom_file)
    assert snaps.n == 8 and snaps.attrs["output_units"] == ["m", "m/s", "m/s2"]
    dt = float(snaps.attrs["dt"])
    t = time_grid(dt, dt * round(4 * float(snaps.runs[0].t[-1]) / dt))
    reference, _ = exact(model, t, HARMONIC)
    assert max_eps(rom.simulate(HARMONIC, dt, t[-1]).y, reference.y) < 1e-19                  # measured 9.8e-21
    result = compare(rom_file, fmu.path, HARMONIC, quiet=True)
    assert result.output_units == ["m", "m/s", "m/s2"]
    assert max_eps(result.y_fom, reference.y) < 2e-17   # measured 2.4e-18: the model exchange integration (tol 1e-10)


def test_generated_descriptions_pass_strict_validation(fmus):
    """The builder's new conventions (type definitions, output arrays, aliases, force sensors) are valid FMI."""
    from fmpy import read_model_description

    for fmu in fmus.values():
        read_model_description(str(fmu.path), validate=True)
    declared = {v.name: v for v in read_model_description(str(fmus["array-outputs"].path)).modelVariables}
    assert declared["y"].declaredType.unit == "m" and [a.name for a in declared["y"].aliases] == ["sensors"]
    assert declared["forceSensor.f"].causality == "output" and declared["forceSensor.f"].declaredType.unit == "N"


# ----------------------------------------------------------------------------------------- body by body
@pytest.mark.slow
def test_fmi3_states_sorted_by_component_default_chain(fmus, tmp_path):
    """The default chain on the FMI 3 FMU whose states go body by body: positions and velocities paired through
    the model structure, data and ROM exact (before: positions mass[1].s, mass[1].v, ...; max eps_y 0.34)."""
    fmu = fmus["body-by-body"]
    train, rom_file = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu.path), "-o", str(train), "-q"]) == 0
    assert main(["fit", str(train), "-o", str(rom_file), "-q"]) == 0
    snaps, rom = Snapshots.load(train), SecondOrderROM.load(rom_file)
    assert snaps.attrs["position_names"] == [f"mass[{i}].s" for i in range(1, 6)]
    assert snaps.attrs["velocity_names"] == [f"mass[{i}].v" for i in range(1, 6)]
    run = snaps.runs[0]
    reference, _ = exact(fmu.model, np.asarray(run.t), run.attrs["input_spec"])
    # measured 1.3e-13 / 4.7e-13 / 9.6e-13
    assert relative(run.x, reference.x) < 1e-12 and relative(run.xdot, reference.v) < 5e-12
    assert relative(run.xddot, reference.a) < 1e-11
    dt = float(snaps.attrs["dt"])
    t = time_grid(dt, dt * round(4 * float(run.t[-1]) / dt))
    reference, _ = exact(fmu.model, t, HARMONIC)
    assert max_eps(rom.simulate(HARMONIC, dt, t[-1]).y, reference.y) < 5e-21                  # measured 5.0e-22


@pytest.mark.parametrize("name", ["body-by-body-no-dependencies", "body-by-body-fmi2"])
def test_states_sorted_by_component_are_recorded_exactly(fmus, tmp_path, name):
    """Without dependencies the units and names pair the FMI 3 states; in FMI 2 der(mass[i].s) is an alias of
    mass[i].v.  Model exchange integrates the state vector in the FMU's (body-by-body) order: exact data."""
    fmu = fmus[name]
    train = tmp_path / "train.h5"
    assert main(["snapshots", str(fmu.path), "-o", str(train), "-q", "--dt", "0.05", "--t-end", "20"]) == 0
    snaps = Snapshots.load(train)
    assert snaps.attrs["position_names"] == [f"mass[{i}].s" for i in range(1, 6)]
    run = snaps.runs[0]
    reference, _ = exact(fmu.model, np.asarray(run.t), run.attrs["input_spec"])
    # measured 1.3e-12 / 9.3e-12 with the compiled DOP853 loop, 4.8e-13 / 3.6e-12 with scipy's (the same method at
    # tolerance 1e-10: rounding differences in the sums move 12 of 10,100 derivative evaluations)
    assert relative(run.x, reference.x) < 3e-12 and relative(run.xddot, reference.a) < 3e-11


# ------------------------------------------------------------------------ the exported FMU in an importer
@pytest.mark.slow  # 12 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_exported_exact_rom_steps_with_multiples_of_its_step(tmp_path):
    """A ROM of a continuous-time FMU steps by its exact step map: an importer's communication step that is a
    multiple of the training step is that many map steps (exact; before: refused), another step is refused in
    one line that names the fix.  Reference: the exact solution of the ROM's own ODE under the held input."""
    from fmu_opinf.compare import simulate_outputs
    from fmu_opinf.export import export_fmu
    from fmu_opinf.fmus import find_build_tools
    from fmu_opinf.lti_fmus import LinearMechanicalModel, zoh_response
    from fmu_opinf.sources import StepError

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    M, D, K = np.diag([1.0, 2.0]), np.array([[0.3, -0.1], [-0.1, 0.2]]), np.array([[5.0, -2.0], [-2.0, 3.0]])
    B, Cp = np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]])
    rom = SecondOrderROM(M, D, K, B, Cp, np.zeros((1, 2)), dt=0.05, integrator="exact", fr=np.array([0.1, 0.0]),
                         y0=np.array([0.2]), q0=np.array([0.01, 0.0]))
    path = export_fmu(rom, tmp_path / "Exact.fmu")
    model = LinearMechanicalModel(M=M, D=D, K=K, B=B, f0=np.array([0.1, 0.0]), Cp=Cp, y0=np.array([0.2]),
                                  x0=np.array([0.01, 0.0]))
    signal = parse_signal(HARMONIC, 1)
    t = time_grid(0.15, 30.0)                                       # three map steps per communication step
    y, *_ = simulate_outputs(path, signal, t)
    reference = zoh_response(model, t, signal.sample(t)).y
    assert max_eps(y, reference) < 1e-27                                                     # measured 1.5e-28
    with pytest.raises(StepError, match=r"steps with multiples of h = 0\.05.* got h = 0\.02; use such a "
                                        r"communication step, or export the ROM again with --step h"):
        simulate_outputs(path, signal, time_grid(0.02, 1.0))
    # exported for the importer's step 0.02 (finer than the training step): exact there
    fine = tmp_path / "fine.fmu"
    assert main(["export", str(_saved(rom, tmp_path)), "-o", str(fine), "--step", "0.02", "-q"]) == 0
    t = time_grid(0.02, 30.0)
    y, *_ = simulate_outputs(fine, signal, t)
    assert max_eps(y, zoh_response(model, t, signal.sample(t)).y) < 5e-26                      # measured 5.7e-27


def _saved(rom: SecondOrderROM, folder: Path) -> Path:
    rom.save(folder / "rom.h5")
    return folder / "rom.h5"


def test_parameter_like_warning_once_for_a_run_table(fmus, tmp_path, capsys, monkeypatch):
    """A run table opens the source once per row: the warning about held parameter-like inputs is printed once."""
    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())
    table = tmp_path / "runs.csv"
    table.write_text('input,name\n"impulse:amplitude=100,t0=2,width=0.5",a\n"step:amplitude=1",b\n')
    assert main(["snapshots", str(fmus["stiffness-input"].path), "-o", str(tmp_path / "out"), "--runs", str(table),
                 "--dt", "0.05", "--t-end", "5", "-q"]) == 0
    assert capsys.readouterr().err.count("start at non-zero values") == 1
