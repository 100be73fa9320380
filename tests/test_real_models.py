"""Real-model terms (issue 11): equilibrium offsets, initial states, free responses, direct feedthrough.

References are independent of the code under test: training and test outputs are the exact zero-order-hold
solution of the full-order model (matrix exponential in its minimal coordinates,
:func:`fmu_opinf.lti_fmus.zoh_response`), equilibria and feedthrough come from the true matrices.  The data are
continuous-time, so the ROMs integrate exactly (``integrator="exact"``, what ``fit`` chooses for such FMUs).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from fmu_opinf.errors import DataError
from fmu_opinf.lti_fmus import chain_model, zoh_response
from fmu_opinf.newmark import applied_inputs, time_grid
from fmu_opinf.fit import fit_rom
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.signals import parse_signal

DT = 0.02
X0 = [0.05, -0.02, 0.03, 0.0]
V0 = [0.0, 0.1, 0.0, -0.05]


def _run(model, spec: str, t_end: float):
    """One training run of the exact solution, in the snapshot column convention (u[:, i] = u(t_{i-1}))."""
    t = time_grid(DT, t_end)
    signal = parse_signal(spec, model.m)
    held = signal.sample(t)
    exact = zoh_response(model, t, held)
    return SimpleNamespace(t=t, u=applied_inputs(signal, t), x=exact.x, xdot=exact.v, xddot=exact.a, y=exact.y,
                           x0=exact.x[:, 0], v0=exact.v[:, 0])


def _reference_outputs(model, spec: str, t_end: float) -> np.ndarray:
    """Exact full-order outputs ``Cp x + Cv v + Ca a + y0`` under the held input."""
    t = time_grid(DT, t_end)
    return zoh_response(model, t, parse_signal(spec, model.m).sample(t)).y


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.fixture(scope="module")
def offset_model():
    return chain_model(4, force_offset=0.7, x0=X0, v0=V0, acceleration_outputs=(-1,), output_offset=0.1)


def test_offset_initial_state_and_feedthrough_are_identified(offset_model):
    model = offset_model
    runs = [_run(model, "impulse:amplitude=20,t0=1,width=0.3", 30.0),
            _run(replace(model, x0=np.zeros(4), v0=np.zeros(4)), "none", 20.0)]  # a second start, free response
    rom = fit_rom(runs, r=4, integrator="exact")
    assert {name: term["fitted"] for name, term in rom.fit_info["terms"].items()} == {"fr": True, "Dur": True,
                                                                                     "y0": True}
    spec = "harmonic:amplitude=3,omega=1.7"
    # achieved: 1.7e-10, 4e-13, 1e-15 (the issue asks for 1e-8)
    assert _relative(rom.simulate(spec, DT, 40.0).y, _reference_outputs(model, spec, 40.0)) < 1e-9
    assert _relative(rom.equilibrium(), model.equilibrium()) < 1e-11
    assert _relative(rom.Dur, model.feedthrough) < 1e-12
    assert np.allclose(rom.reconstruct(rom.q0), model.x0, atol=1e-12)


@pytest.mark.slow
def test_terms_are_found_for_a_truncated_rom():
    """30 masses under gravity, started off equilibrium, an acceleration sensor and an output offset, ROM order
    9 of 30: the terms are decided on a wider POD basis, so all three are found (third audit, 2026-11-26: at the
    ROM's order the truncation hid them, only ``fr`` kept, 10x the error of ``terms="all"``), and the ROM is as
    good as with every term forced."""
    model = chain_model(30, force_offset=0.5, x0=np.linspace(0.02, -0.02, 30), acceleration_outputs=(-1,),
                        output_offset=0.1)
    runs = [_run(model, "impulse:amplitude=20,t0=1,width=0.3", 60.0)]
    auto = fit_rom(runs, r=9, integrator="exact", refine=False)
    forced = fit_rom(runs, r=9, integrator="exact", refine=False, terms="all")
    assert {name: term["fitted"] for name, term in auto.fit_info["terms"].items()} == {"fr": True, "Dur": True,
                                                                                      "y0": True}
    spec = "step:amplitude=2,t0=1"
    reference = _reference_outputs(model, spec, 60.0)
    error = _relative(auto.simulate(spec, DT, 60.0).y, reference)
    assert error <= 1.01 * _relative(forced.simulate(spec, DT, 60.0).y, reference)


def test_a_rom_trained_without_the_terms_is_wrong(offset_model):
    """The same data with the paper's model (terms='none'): the check above can fail."""
    runs = [_run(offset_model, "impulse:amplitude=20,t0=1,width=0.3", 30.0)]
    rom = fit_rom(runs, r=4, terms="none", integrator="exact")
    spec = "harmonic:amplitude=3,omega=1.7"
    assert _relative(rom.simulate(spec, DT, 40.0).y, _reference_outputs(offset_model, spec, 40.0)) > 1e-2


def test_free_response_rom_without_inputs():
    model = chain_model(4, inputs=(), force_offset=-0.4, x0=X0, v0=V0)
    rom = fit_rom([_run(model, "none", 30.0)], r=4, integrator="exact")
    assert rom.m == 0 and rom.fit_info["terms"]["fr"]["fitted"]
    assert _relative(rom.simulate("none", DT, 60.0).y, _reference_outputs(model, "none", 60.0)) < 1e-9  # 8e-11


def test_terms_are_exactly_zero_on_the_paper_benchmark(anchored_impulse_run):
    rom = fit_rom(anchored_impulse_run, r=5)
    assert not np.any(rom.fr) and not np.any(rom.Dur) and not np.any(rom.y0) and not np.any(rom.x_ref)
    info = rom.fit_info["terms"]
    assert all(not term["fitted"] for term in info.values())
    assert info["fr"]["residual_with"] > 0.9 * info["fr"]["residual_without"]


def test_initial_state_off_the_constraint_is_refused():
    bar = np.zeros((1, 4))
    bar[0, 1], bar[0, 3] = 1.0, -1.0        # x_2 = x_4
    model = replace(chain_model(4, force_offset=0.3), G=bar, constraint="position", x0=[0.05, 0.02, 0.0, 0.02])
    rom = fit_rom([_run(model, "impulse:amplitude=20,t0=1,width=0.3", 30.0)], r=3, integrator="exact")
    q0, _ = rom.initial_state(x0=[0.0, 0.01, 0.02, 0.01])
    assert np.allclose(rom.reconstruct(q0), [0.0, 0.01, 0.02, 0.01], atol=1e-12)
    with pytest.raises(DataError, match="violate the constraint"):
        rom.initial_state(x0=[0.0, 0.01, 0.02, 0.03])


def test_rom_file_round_trip_and_layout_1(tmp_path, offset_model):
    rom = fit_rom([_run(offset_model, "impulse:amplitude=20,t0=1,width=0.3", 30.0)], r=4, integrator="exact")
    loaded = SecondOrderROM.load(rom.save(tmp_path / "rom.h5"))
    for name in ("fr", "Dur", "y0", "q0", "qdot0", "x_ref", "Mr", "basis"):
        assert np.array_equal(getattr(loaded, name), getattr(rom, name)), name
    with h5py.File(tmp_path / "rom.h5", "a") as f:   # what layout 1 wrote: no extra terms, no attribute seal
        for name in ("fr", "Dur", "y0", "q0", "qdot0", "x_ref"):
            del f[name]
        f.attrs["layout_version"] = 1
        del f.attrs["attributes_sha256"]
    old = SecondOrderROM.load(tmp_path / "rom.h5")
    assert not np.any(old.fr) and not np.any(old.y0) and old.x_ref.shape == (4,) and not np.any(old.q0)


# ----------------------------------------------------------------------------------- FMUs like real exports
CORPUS_CASES = {   # name -> training input, test input (None: free response over a longer horizon)
    "offset-equilibrium": ("impulse:amplitude=5,t0=1,width=0.5", "harmonic:amplitude=2,omega=1.3"),
    "start-off-rest": ("impulse:amplitude=5,t0=1,width=0.5", "harmonic:amplitude=2,omega=1.3"),
    "acceleration-output": ("impulse:amplitude=5,t0=1,width=0.5", "harmonic:amplitude=2,omega=1.3"),
    "no-inputs": (None, None),
}


@pytest.fixture(scope="module")
def real_corpus(request, tmp_path_factory):
    from fmu_opinf import lti_fmus

    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    return lti_fmus.build_corpus(folder, names=list(CORPUS_CASES) + ["no-accelerations"])


@pytest.mark.fmu
@pytest.mark.parametrize("name", list(CORPUS_CASES))
@pytest.mark.slow  # 18 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_exporter_style_fmu_through_the_whole_chain(real_corpus, tmp_path, name):
    """snapshots -> fit -> compare -> export on FMUs with offsets, start values off rest, feedthrough, no input."""
    from fmu_opinf.cli import main
    from fmu_opinf.compare import compare, simulate_outputs
    from fmu_opinf.export import export_fmu

    fmu = str(real_corpus[name].path)
    train, test = CORPUS_CASES[name]
    args = ["snapshots", fmu, "-o", str(tmp_path / "train.h5"), "--dt", "0.02", "--t-end", "20", "-q"]
    assert main(args + (["--input", train] if train else [])) == 0
    assert main(["fit", str(tmp_path / "train.h5"), "-o", str(tmp_path / "rom.h5"), "--r", "5", "-q"]) == 0
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    assert rom.integrator == "exact"
    result = compare(rom, fmu, test, t_end=60.0, quiet=True)
    # the issue asks for max eps_y <= 1e-6; achieved 1e-24 .. 9e-19 (relative max error 1e-12 .. 1e-9)
    assert result.metrics()["max_error"] <= 1e-17
    assert float(np.abs(result.y_rom - result.y_fom).max() / np.abs(result.y_fom).max()) < 1e-8
    exported = export_fmu(rom, tmp_path / "rom.fmu", fmi_version="3.0" if name == "offset-equilibrium" else "2.0")
    t = result.t[:1001]
    y_fmu, *_ = simulate_outputs(exported, parse_signal(test or "none", rom.m), t)
    assert _relative(y_fmu, result.y_rom[:, :1001]) < 1e-12  # measured 1e-14 .. 8e-14 (the issue asks 1e-10)


@pytest.mark.fmu
def test_report_labels_carry_the_units_the_fmu_declares(real_corpus):
    from fmu_opinf.compare._declared import _declared_units

    fmu = str(real_corpus["start-off-rest"].path)
    assert _declared_units(fmu, ["mass[1].s", "mass[2].v", "der(mass[1].v)", "y[1]"]) == ["m", "m/s", "m/s2", ""]
    assert _declared_units("builtin:anchored-msd", ["y[1]"]) is None


@pytest.mark.fmu
def test_positions_and_velocities_by_unit_when_no_states_are_declared(real_corpus):
    """The no-accelerations FMU declares no states and no der() variables; its mass[i].s / mass[i].v carry units."""
    from fmu_opinf.sources import open_source

    source = open_source(str(real_corpus["no-accelerations"].path))
    try:
        assert source.position_names == [f"mass[{i}].s" for i in range(1, 6)]
        assert source.velocity_names == [f"mass[{i}].v" for i in range(1, 6)]
        assert "by unit" in source.selection_text()
    finally:
        source.close()


@pytest.mark.slow
@pytest.mark.fmu
@pytest.mark.parametrize("name", ["offset-equilibrium", "no-inputs"])
def test_exporter_style_fmu_with_cli_defaults_only(real_corpus, tmp_path, name):
    """Issues 11/12: `snapshots FMU -o`, `fit`, `compare` with nothing else named (model exchange, the paper's
    impulse or the free response, the automatic window, the default order) reach max eps_y <= 1e-6."""
    from fmu_opinf.cli import main

    fmu = str(real_corpus[name].path)
    assert main(["snapshots", fmu, "-o", str(tmp_path / "train.h5"), "-q"]) == 0
    assert main(["fit", str(tmp_path / "train.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    test = [] if name == "no-inputs" else ["--input", "harmonic:amplitude=1,omega=0.8"]
    assert main(["compare", str(tmp_path / "rom.h5"), fmu, "-o", str(tmp_path / "report"), "-q"] + test) == 0
    import json

    metrics = json.loads((tmp_path / "report" / "metrics.json").read_text())
    # the issue asks for <= 1e-6; measured 8.9e-24 (offset-equilibrium) and 4.8e-21 (no-inputs)
    assert metrics["r"] == 5 and metrics["max_error"] <= 1e-18, metrics["max_error"]


@pytest.mark.slow
def test_exported_rom_outputs_see_an_input_set_between_steps(offset_model, tmp_path):
    """An acceleration sensor feeds the input through (``Dur``): after a step, setting a new input must change the
    outputs read before the next step by ``Dur`` times the change, as FMI requires of a direct dependency (third
    audit, 2026-11-26: the exported FMU kept the old value, off by exactly the change)."""
    from fmpy import extract

    from conftest import started_fmu2
    from fmu_opinf.export import export_fmu

    runs = [_run(offset_model, "impulse:amplitude=20,t0=1,width=0.3", 30.0)]
    rom = fit_rom(runs, r=4, integrator="exact", refine=False)
    assert np.abs(rom.Dur).max() > 0.1  # the sensor's feedthrough was fitted
    folder = extract(str(export_fmu(rom, tmp_path / "Sensor.fmu")), str(tmp_path / "unzipped"))
    fmu, md = started_fmu2(folder, "rom")
    inputs = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fmu.setReal(inputs, [1.0])
    fmu.doStep(0.0, DT)
    before = np.array(fmu.getReal(outputs))
    fmu.setReal(inputs, [3.0])
    after = np.array(fmu.getReal(outputs))
    fmu.terminate()
    fmu.freeInstance()
    # measured 2.8e-18 with outputs of 2.1: the change is exact up to the round-off of the outputs
    assert np.abs(after - before - 2.0 * rom.Dur[:, 0]).max() < 1e-15 * max(1.0, np.abs(before).max())
