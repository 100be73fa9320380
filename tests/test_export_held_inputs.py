"""The ROM FMU keeps the inputs its training held (audit 69 F4).

A source with two force inputs ``F[1], F[2]`` and a parameter exposed as an input, ``stiffness_scale`` (start 1),
trained three ways, as the audit's A, A2 and A3: by default (``stiffness_scale`` held at its start), with
``--inputs F[2]`` (``F[1]`` held at its start too), and with ``--set stiffness_scale=2``.  The ROM FMU declares every
source input in the source's order, each held one with its held value as start and as its only allowed value.
References are the source FMU itself (its declared inputs and start values, its outputs), not the code under test.
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import read_model_description, simulate_fmu  # noqa: E402

from fmu_opinf import compare, export, lti_fmus, snapshots  # noqa: E402
from fmu_opinf.errors import FmuOpinfWarning  # noqa: E402
from fmu_opinf.fit import fit_rom  # noqa: E402
from fmu_opinf.source import open_source  # noqa: E402

pytestmark = pytest.mark.slow   # one source FMU and six ROM FMUs compiled: 20 s on the 2-core machine

DT = 0.05
#: Training and test inputs: a pulse on the first force input and a harmonic on the second, or the pulse alone.
TWO = "impulse:amplitude=40,t0=1,width=0.5;harmonic:amplitude=8,omega=1.3"
ONE = "impulse:amplitude=40,t0=1,width=0.5"
#: The audit's situations: how the source is opened for training, and the training input.
SITUATIONS = {"A": ({}, TWO), "A2": ({"inputs": "F[2]"}, ONE), "A3": ({"parameters": {"stiffness_scale": 2}}, TWO)}


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    model = lti_fmus.chain_model(4, inputs=(0, -1), force_offset=0.5, acceleration_outputs=(-1,), name="Held")
    path = tmp_path_factory.mktemp("held") / "Held.fmu"
    return lti_fmus.build_lti_fmu(model, path, parameter_inputs=("stiffness_scale",)).path


@pytest.fixture(scope="module")
def declared(source) -> dict[str, float]:
    """The source's inputs in its declared order, with their declared start values (0 where none)."""
    md = read_model_description(str(source))
    return {v.name: float(v.start or 0.0) for v in md.modelVariables if v.causality == "input"}


@pytest.fixture(scope="module")
def roms(source) -> dict:
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)   # (stiffness_scale held: said once at recording)
        for name, (options, spec) in SITUATIONS.items():
            recorded = snapshots.record(open_source(source, **options), spec, dt=DT, t_end=25.0, quiet=True)
            out[name] = fit_rom(recorded, r=4)
    return out


@pytest.fixture(scope="module")
def fmus_of(roms, tmp_path_factory) -> dict[tuple[str, str], Path]:
    folder = tmp_path_factory.mktemp("held-roms")
    return {(name, version): export.export_fmu(rom, folder / f"{name}ROM{version[0]}.fmu", fmi_version=version)
            for name, rom in roms.items() for version in ("2.0", "3.0")}


def _inputs(path: Path) -> dict[str, tuple[float, str | None, str | None, str]]:
    md = read_model_description(str(path))
    return {v.name: (float(v.start), v.min, v.max, v.description or "") for v in md.modelVariables
            if v.causality == "input"}


@pytest.mark.parametrize("version", ["2.0", "3.0"])
@pytest.mark.parametrize("situation, held", [("A", {"stiffness_scale": None}),
                                             ("A2", {"F[1]": None, "stiffness_scale": None}),
                                             ("A3", {"stiffness_scale": 2.0})])
def test_every_source_input_is_declared_in_order_with_its_held_value(fmus_of, declared, situation, held, version):
    """Before audit 69 the held inputs were missing (``stiffness_scale`` could not be set on the ROM FMU)."""
    inputs = _inputs(fmus_of[situation, version])
    assert list(inputs) == list(declared)
    for name, (start, low, high, description) in inputs.items():
        if name in held:
            value = declared[name] if held[name] is None else held[name]   # the source's start, or the --set value
            assert (start, float(low), float(high)) == (value, value, value)
            assert f"held at {value!r} in training" in description
        else:
            assert low is None and high is None and start == declared[name]
    description = read_model_description(str(fmus_of[situation, version])).description
    assert "inputs held in training" in description and "stiffness_scale = " in description


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_setting_the_held_value_changes_nothing(fmus_of, version):
    path = fmus_of["A3", version]
    plain = simulate_fmu(str(path), stop_time=5.0, output_interval=DT)
    held = simulate_fmu(str(path), stop_time=5.0, output_interval=DT, start_values={"stiffness_scale": 2.0})
    assert all(np.array_equal(plain[name], held[name]) for name in plain.dtype.names)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_setting_another_value_is_refused_with_one_line_naming_the_held_value(fmus_of, version):
    """The A3 ROM at the source's default (1) would be 0.88 of the range off the source there: it refuses it."""
    lines = []
    with pytest.raises(Exception, match="failed with status 3"):
        simulate_fmu(str(fmus_of["A3", version]), stop_time=5.0, output_interval=DT,
                     start_values={"stiffness_scale": 1.0}, logger=lambda *args: lines.append(args[-1].decode()))
    refused = [line for line in lines if "refused" in line]
    assert len(refused) == 1 and "\n" not in refused[0]
    assert "input stiffness_scale" in refused[0] and "held at 2 in training" in refused[0]


def test_driving_a_held_force_input_is_refused_not_ignored(fmus_of):
    """A2: an input table that drives F[1], which the training held at 0, stops the run (it was ignored)."""
    table = np.array([(0.0, 5.0), (10.0, 5.0)], dtype=[("time", float), ("F[1]", float)])
    lines = []
    with pytest.raises(Exception, match="failed with status 3"):
        simulate_fmu(str(fmus_of["A2", "2.0"]), stop_time=2.0, output_interval=DT, input=table,
                     logger=lambda *args: lines.append(args[-1].decode()))
    assert any("input F[1]" in line and "held at 0 in training" in line for line in lines)


def test_a_driven_input_is_unaffected(fmus_of, roms, source, tmp_path):
    """A2's driven F[2]: the ROM FMU's outputs equal those of the FMU exported without the held inputs (the old
    FMU) exactly, and follow the source's (F[1] at 0) as closely as the ROM does."""
    old = copy.copy(roms["A2"])
    old.provenance = copy.deepcopy(old.provenance)
    del old.provenance["snapshots"]["held_inputs"]
    with pytest.warns(FmuOpinfWarning, match=r"records no values for the inputs its training held \(F\[1\], "):
        old_fmu = export.export_fmu(old, tmp_path / "Old.fmu")
    assert list(_inputs(old_fmu)) == ["F[2]"]
    t = np.arange(0.0, 10.0 + DT / 2, DT)
    table = np.array(list(zip(t, 6.0 * np.sin(1.7 * t))), dtype=[("time", float), ("F[2]", float)])
    run = {key: simulate_fmu(str(path), stop_time=10.0, output_interval=DT, input=table, step_size=DT)
           for key, path in (("new", fmus_of["A2", "2.0"]), ("old", old_fmu), ("source", source))}
    names = ["y[1]", "y[2]", "y[3]"]
    assert all(np.array_equal(run["new"][name], run["old"][name]) for name in names)
    for name in names:
        scale = np.ptp(run["source"][name])
        assert np.abs(run["new"][name] - run["source"][name]).max() <= 5e-8 * scale   # achieved: 1.9e-9 .. 1.9e-8


def test_compare_drives_only_the_trained_inputs_of_the_rom_fmu(fmus_of, source):
    """compare on an exported ROM FMU that keeps held inputs drives the inputs the ROM was trained on only."""
    result = compare.compare(fmus_of["A2", "2.0"], source, "harmonic:amplitude=5,omega=1.3", t_end=10.0, quiet=True)
    error = np.abs(result.y_rom - result.y_fom).max() / np.abs(result.y_fom).max()
    assert error < 1e-11   # achieved: 4.6e-13


def test_an_input_held_at_different_values_in_different_runs_is_left_out_with_a_warning(source, tmp_path):
    """Runs recorded at stiffness_scale 2 and 3 and merged (a run table's per-row ``set:``): the ROM was not trained
    at one value of it and cannot follow it, so its FMU does not pretend either (one warning)."""
    parts = [snapshots.record(open_source(source, parameters={"stiffness_scale": value}), spec, dt=DT, t_end=25.0,
                              quiet=True)
             for value, spec in ((2, f"{ONE};none"), (3, f"none;{ONE}"))]
    merged = parts[0].append(parts[1])
    assert merged.attrs["held_inputs"]["varied"] == ["stiffness_scale"]
    rom = fit_rom(merged, r=4)
    with pytest.warns(FmuOpinfWarning, match="held inputs stiffness_scale at different values in different runs"):
        path = export.export_fmu(rom, tmp_path / "Varied.fmu")
    assert list(_inputs(path)) == ["F[1]", "F[2]"]


def test_a_free_response_rom_declares_every_input_held(source, declared, tmp_path):
    """``--inputs none``: the ROM has no input (the source, started at rest away from its equilibrium under its
    constant force, moves freely), its FMU all three of the source's inputs, each held at its start."""
    recorded = snapshots.record(open_source(source, inputs="none"), "none", dt=DT, t_end=25.0, quiet=True)
    path = export.export_fmu(fit_rom(recorded, r=4), tmp_path / "Free.fmu")
    inputs = _inputs(path)
    assert list(inputs) == list(declared)
    for name, (start, low, high, _) in inputs.items():
        assert (start, float(low), float(high)) == (declared[name],) * 3
    result = simulate_fmu(str(path), stop_time=1.0, output_interval=DT, start_values=dict(declared))
    assert np.all(np.isfinite(result["y[1]"]))
