"""The default training pulse follows an input's declared size (audit 73, F1).

A force declared ``nominal="1e5" min="-2e5" max="2e5"`` on a heavy chain released under gravity was trained with the
default 100 N pulse, whose response was a few 1e-4 of the gravity swing: the POD order followed the swing, and the
ROM was 3-8 times the output range off at loads of the declared size while fit and compare (at 100 N) looked clean.
Now the pulse takes the declared nominal (FMI 2 ``Real``, FMI 3 ``Float64`` / ``Float32``), bounded by the declared
range; a finite range without a nominal sizes it by a tenth of its width where that exceeds 100; an input that
declares neither keeps 100.  References: the exact zero-order-hold response of the model (lti_fmus.zoh_response)
and amplitudes written out by hand.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import numpy as np
import pytest

from fmu_opinf import lti_fmus

#: The declared load of the loaded chain below, also its constant load per mass (gravity-like).
LOAD = 1e5


def _source(nominals, low, high, starts=None, units=None):
    """A duck-typed source with one input per entry, as :func:`default_amplitudes` reads it."""
    m = len(nominals)
    return SimpleNamespace(input_names=[f"F{i + 1}" for i in range(m)], input_units=units or ["N"] * m,
                           input_starts=lambda: np.zeros(m) if starts is None else np.asarray(starts, float),
                           input_ranges=lambda: (np.asarray(low, float), np.asarray(high, float)),
                           input_nominals=lambda: np.asarray(nominals, float), model=None)


def test_the_default_pulse_takes_the_declared_nominal_within_the_declared_range():
    """Nominal 1e5 in [-2e5, 2e5] -> 1e5; nominal 3e5 in the same range -> 2e5 (its max, from a start of 0);
    nominal 0.02 (a small force) -> 0.02; nominal 1, FMI's default written out -> 100 as without one."""
    from fmu_opinf.snapshots._inputs import _lowered_amplitudes, default_amplitudes

    source = _source([1e5, 3e5, 0.02, 1.0], [-2e5, -2e5, -math.inf, -math.inf], [2e5, 2e5, math.inf, math.inf])
    amplitudes = default_amplitudes(source)
    assert amplitudes == [1e5, 2e5, 0.02, 100.0]
    assert _lowered_amplitudes(source, amplitudes) == (" (amplitude 200000 on F2 (its declared nominal 300000): "
                                                       "what its declared range allows; 100000 on F1, 0.02 on F3: "
                                                       "its declared nominal)")


def test_an_input_without_a_nominal_or_a_wide_range_keeps_the_old_amplitude():
    """Guard (passes on the old code too): no declaration -> 100; a range narrower than the pulse -> lowered as
    before ([-20, 20] -> 20, a pull in [-1000, 0] -> -100); a range written out as unbounded (1e300) -> 100; a
    source of the API that knows no nominals -> 100."""
    from fmu_opinf.snapshots._inputs import _lowered_amplitudes, default_amplitudes

    source = _source([math.nan] * 4, [-math.inf, -20, -1000, -1e300], [math.inf, 20, 0, 1e300])
    amplitudes = default_amplitudes(source)
    assert amplitudes == [100.0, 20.0, -100.0, 100.0]
    said = _lowered_amplitudes(source, amplitudes)
    assert said == " (amplitude 20 on F2, -100 on F3: what its declared range allows)"
    plain = SimpleNamespace(**{k: v for k, v in vars(source).items() if k != "input_nominals"})
    assert default_amplitudes(plain) == [100.0, 20.0, -100.0, 100.0]


def test_a_range_far_wider_than_the_default_pulse_sizes_it_where_no_nominal_is_declared():
    """[-1000, 1000] -> 200 (a tenth of 2000); [-2e5, 2e5] -> 40000; [0, 5000] from a start of 0 -> 500."""
    from fmu_opinf.snapshots._inputs import _lowered_amplitudes, default_amplitudes

    source = _source([math.nan] * 3, [-1000, -2e5, 0], [1000, 2e5, 5000])
    amplitudes = default_amplitudes(source)
    assert amplitudes == [200.0, 40000.0, 500.0]
    assert _lowered_amplitudes(source, amplitudes) == (" (amplitude 200 on F1, 40000 on F2, 500 on F3: a tenth of "
                                                       "its declared range's width)")


def test_a_pressure_about_its_start_keeps_a_tenth_of_it_whatever_its_nominal():
    from fmu_opinf.snapshots._inputs import default_amplitudes

    source = _source([1e5], [-math.inf], [math.inf], starts=[101325.0], units=["Pa"])
    assert default_amplitudes(source) == [10100.0]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_the_declared_nominal_is_read_from_the_variable_or_its_declared_type(version):
    """FMI 2: ``<Real nominal=...>`` or its SimpleType's; FMI 3: ``<Float64 nominal=...>`` / ``<Float32 ...>`` or
    its type's.  A nominal that is not a number above 0 is none."""
    from fmu_opinf.sources._variables import Element, ModelInfo, declared_nominal

    if version == "2.0":
        types = ('<TypeDefinitions><SimpleType name="Force"><Real unit="N" nominal="5e4"/></SimpleType>'
                 "</TypeDefinitions>")

        def var(name, vr, attrs):
            return (f'<ScalarVariable name="{name}" valueReference="{vr}" causality="input" variability="continuous">'
                    f'<Real start="0" {attrs}/></ScalarVariable>')
    else:
        types = '<TypeDefinitions><Float64Type name="Force" unit="N" nominal="5e4"/></TypeDefinitions>'

        def var(name, vr, attrs):
            tag = "Float32" if name == "F5" else "Float64"
            return f'<{tag} name="{name}" valueReference="{vr}" causality="input" start="0" {attrs}/>'
    variables = "".join(var(f"F{i + 1}", i + 1, attrs) for i, attrs in enumerate(
        ['nominal="1e5"', 'declaredType="Force"', 'declaredType="Force" nominal="2"', "", 'nominal="0.5"',
         'nominal="-3"', 'nominal="abc"']))
    root = ET.fromstring(f'<fmiModelDescription fmiVersion="{version}" modelName="m">{types}'
                         f"<ModelVariables>{variables}</ModelVariables></fmiModelDescription>")
    model = ModelInfo(root, "m.fmu")
    nominals = [declared_nominal(Element(f"F{i}", model.by_name[f"F{i}"], 0)) for i in range(1, 8)]
    np.testing.assert_array_equal(nominals, [1e5, 5e4, 2.0, math.nan, 0.5, math.nan, math.nan])


@pytest.fixture(scope="module")
def loaded_chain(request, tmp_path_factory) -> tuple[lti_fmus.LinearMechanicalModel, lti_fmus.LtiFmu]:
    """12 masses (lti_fmus.chain_model) under a constant load of :data:`LOAD` on each, released from rest, outputs
    the tip and middle positions; its FMU (co-simulation) built once, kept in pytest's cache where there is one."""
    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    n = 12
    base = lti_fmus.chain_model(n)
    outputs = np.zeros((2, n))
    outputs[0, -1] = outputs[1, n // 2] = 1.0
    model = lti_fmus.LinearMechanicalModel(base.M, base.D, base.K, base.B, f0=LOAD * np.ones(n), Cp=outputs,
                                           name="Loaded")
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("declared_nominal") if cache is not None else tmp_path_factory.mktemp("declared_nominal")
    return model, lti_fmus.build_lti_fmu(model, folder / "loaded.fmu", interfaces=("cs",))


@pytest.mark.fmu
@pytest.mark.slow
def test_a_loaded_chain_trained_by_default_is_right_at_loads_of_its_declared_nominal(loaded_chain, tmp_path,
                                                                                     capsys):
    """The audit's case in small: 12 masses under a constant load of 1e5 N each, released from rest, the tip force F
    declared ``nominal="1e5"``; snapshots and fit with their defaults (window given, to stay fast).  Against the
    exact model at loads of the declared size the ROM is within 1.5 % of the output range (measured 2026-12-07,
    r = 4: harmonic 1.21 %, step 0.99 %); trained with the old 100 N pulse it was 98 % and 213 % off.  The same FMU
    without the declaration was still trained at 100 N; now its pulse is raised where the load's swing hides it."""
    from conftest import miss_against_model, rewrite_description

    from fmu_opinf.cli import main
    from fmu_opinf.rom import SecondOrderROM
    from fmu_opinf.snapshots import Snapshots

    model, built = loaded_chain
    fmu = rewrite_description(built.path, tmp_path / "loaded.fmu", lambda text: text.replace(
        '<Real unit="N" start="0.0"/>', f'<Real unit="N" start="0.0" nominal="{LOAD:g}"/>', 1))
    window = ["--dt", "0.05", "--t-end", "20", "--in-process"]
    capsys.readouterr()
    assert main(["snapshots", str(fmu), "-o", str(tmp_path / "train.h5"), *window]) == 0
    said = capsys.readouterr().err
    assert main(["fit", str(tmp_path / "train.h5"), "-o", str(tmp_path / "rom.h5"), "-q"]) == 0
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    for spec in (f"harmonic:amplitude={LOAD:g},omega=0.8", f"step:amplitude={LOAD:g},t0=3"):
        assert miss_against_model(rom, model, spec) < 0.015, spec
    assert "recording the impulse training input impulse:amplitude=100000,t0=2,width=0.5 (amplitude 100000 on F: " \
           "its declared nominal)" in said   # the spec recorded, not the template's 100
    # without the declaration the 100 N pulse is lost in the swing under the load: raised (audit 74 F1), and that
    # ROM is right at these loads (measured 2026-12-07: a pulse of 9.5e5 N, harmonic 0.16 %, step 0.22 %)
    assert main(["snapshots", str(built.path), "-o", str(tmp_path / "plain.h5"), *window]) == 0
    assert "on F: the 100 pulse moved the outputs by " in capsys.readouterr().err
    assert not Snapshots.load(tmp_path / "plain.h5").runs[0].attrs["input_spec"].startswith("impulse:amplitude=100,")
    assert main(["fit", str(tmp_path / "plain.h5"), "-o", str(tmp_path / "plain_rom.h5"), "-q"]) == 0
    plain = SecondOrderROM.load(tmp_path / "plain_rom.h5")
    for spec in (f"harmonic:amplitude={LOAD:g},omega=0.8", f"step:amplitude={LOAD:g},t0=3"):
        assert miss_against_model(plain, model, spec) < 0.004, spec
