"""The report shows outputs in the displayUnit their FMU declares (audit 81c, F10: rad and m/s2 were drawn where the
FMU declared deg and mm/s2)."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from fmu_opinf import compare
from fmu_opinf.compare import _declared

T = np.linspace(0.0, 10.0, 201)

#: FMI 2.0 outputs: an angle in rad shown in deg (as in p3.fmu of audit 81c), a speed without display unit, a
#: temperature in K shown in degC (offset), its difference (relativeQuantity: no offset) and a unit whose only
#: display unit is FMI 3's inverse kind (not a linear map: left out).
DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="D" guid="{0}">
  <CoSimulation modelIdentifier="D"/>
  <UnitDefinitions>
    <Unit name="rad"><BaseUnit rad="1"/><DisplayUnit name="deg" factor="57.29577951308232"/></Unit>
    <Unit name="m/s"><BaseUnit m="1" s="-1"/></Unit>
    <Unit name="K"><BaseUnit K="1"/><DisplayUnit name="degC" offset="-273.15"/></Unit>
    <Unit name="s/m"><BaseUnit s="1" m="-1"/><DisplayUnit name="m/s" inverse="true"/></Unit>
  </UnitDefinitions>
  <ModelVariables>
    <ScalarVariable name="phi" valueReference="1" causality="output">
      <Real unit="rad" displayUnit="deg"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="2" causality="output"><Real unit="m/s"/></ScalarVariable>
    <ScalarVariable name="T" valueReference="3" causality="output"><Real unit="K" displayUnit="degC"/></ScalarVariable>
    <ScalarVariable name="dT" valueReference="4" causality="output">
      <Real unit="K" displayUnit="degC" relativeQuantity="true"/></ScalarVariable>
    <ScalarVariable name="pace" valueReference="5" causality="output">
      <Real unit="s/m" displayUnit="m/s"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure/>
</fmiModelDescription>
"""


def _fmu(tmp_path) -> str:
    """An .fmu holding only :data:`DESCRIPTION` (the display units are read from the description alone)."""
    path = tmp_path / "display.fmu"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", DESCRIPTION)
    return str(path)


def test_declared_display_units_follow_fmi_conversion(tmp_path):
    """FMI: DisplayUnit_value = factor * Unit_value + offset; relativeQuantity voids the offset; an inverse display
    unit and an output without one get none."""
    fmu = _fmu(tmp_path)
    display = _declared._declared_display_units(fmu, ["phi", "v", "T", "dT", "pace"])
    assert [d.name if d else None for d in display] == ["deg", None, "degC", "degC", None]
    assert display[0].values(np.pi) == pytest.approx(180.0, rel=1e-15)
    assert display[2].values(300.0) == pytest.approx(26.85, rel=1e-13)     # 300 K is 26.85 degC
    assert display[3].values(10.0) == 10.0                                  # a difference of 10 K is 10 degC
    assert _declared._declared_display_units(fmu, ["v"]) is None              # none declared: the report is unchanged


def test_outputs_figure_and_table_use_the_display_unit(tmp_path, monkeypatch):
    """The angle's plotted lines are the exact values x 180/pi, labelled [deg]; the speed without a display unit is
    drawn as it is; the page gives the angle's max absolute error in deg.  eq. (19) is a ratio: unchanged."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    names = ["phi", "v"]
    y = np.vstack([np.sin(T), 3.0 * np.cos(T)])           # exact outputs, in the FMU's units rad and m/s
    y_rom = np.vstack([0.99 * np.sin(T), 3.0 * np.cos(T)])
    result = compare.Comparison(t=T, y_fom=y, y_rom=y_rom, output_names=names, input_spec="none",
                                fom_seconds=1.0, rom_seconds=0.1, r=2,
                                output_units=_declared._declared_units(_fmu(tmp_path), names),
                                output_display_units=_declared._declared_display_units(_fmu(tmp_path), names))
    page = compare.write_report(result, tmp_path / "report").read_text()
    figure = next(fig for fig in kept if len(fig.axes) == 2)
    angle, speed = figure.axes
    fom, rom = angle.get_lines()[:2]
    np.testing.assert_allclose(fom.get_ydata(), np.sin(T) * 180.0 / np.pi, rtol=1e-15, atol=0)
    np.testing.assert_allclose(rom.get_ydata(), 0.99 * np.sin(T) * 180.0 / np.pi, rtol=1e-15, atol=0)
    assert angle.get_ylabel().endswith("[deg]") and speed.get_ylabel().endswith("[m/s]")
    assert np.array_equal(speed.get_lines()[0].get_ydata(), y[1])
    error_deg = 0.01 * np.abs(np.sin(T)).max() * 180.0 / np.pi
    assert f"absolute max {error_deg:.4g} deg" in page                       # 0.5729 deg, not 0.01 (rad)
    assert result.metrics()["max_error"] == pytest.approx(1e-4 * np.sin(T).max() ** 2 / (np.sin(T) ** 2
                                                                                         + 9 * np.cos(T) ** 2).max())


@pytest.mark.slow
def test_compare_on_an_fmu_with_display_units_plots_them(tmp_path, monkeypatch):
    """The chain of audit 81c's p3.fmu (an angle in rad shown in deg, an acceleration in m/s2 shown in mm/s2):
    snapshots and fit with defaults, compare on a harmonic; the report's plotted FOM lines are the exact response
    (matrix exponential) times 180/pi and 1000, labelled deg and mm/s2; the speed, without display unit, as it is."""
    import matplotlib.pyplot as plt
    from conftest import rewrite_description

    from fmu_opinf import lti_fmus
    from fmu_opinf.cli import main
    from fmu_opinf.signals import parse_signal

    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    model = lti_fmus.chain_model(n=4, acceleration_outputs=(-1,), name="Shown")
    built = lti_fmus.build_lti_fmu(model, tmp_path / "plain.fmu", output_units=True)

    def edit(text: str) -> str:
        text = text.replace("<UnitDefinitions>", '<UnitDefinitions>\n    <Unit name="rad"><BaseUnit rad="1"/>'
                            '<DisplayUnit name="deg" factor="57.29577951308232"/></Unit>')
        text = text.replace('<Unit name="m/s2"><BaseUnit m="1" s="-2"/></Unit>', '<Unit name="m/s2"><BaseUnit m="1" '
                            's="-2"/><DisplayUnit name="mm/s2" factor="1000"/></Unit>')
        text = text.replace('<Real unit="m"/>', '<Real unit="rad" displayUnit="deg"/>', 1)
        return text.replace('<Real unit="m/s2"/>', '<Real unit="m/s2" displayUnit="mm/s2"/>', 1)

    fmu = rewrite_description(built.path, tmp_path / "shown.fmu", edit)
    train, rom = tmp_path / "train.h5", tmp_path / "rom.h5"
    assert main(["snapshots", str(fmu), "-o", str(train), "-q"]) == 0
    assert main(["fit", str(train), "-o", str(rom), "-q"]) == 0
    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    spec = "harmonic:amplitude=1,omega=0.8"
    result = compare.compare(rom, fmu, spec, quiet=True)
    assert [d.name if d else None for d in result.output_display_units] == ["deg", None, "mm/s2"]
    compare.write_report(result, tmp_path / "report")
    figure = next(fig for fig in kept if len(fig.axes) == 3)
    exact = lti_fmus.zoh_response(model, result.t, parse_signal(spec, 1).sample(result.t)).y
    for j, (factor, unit) in enumerate(zip((180.0 / np.pi, 1.0, 1000.0), ("[deg]", "[m/s]", "[mm/s2]"))):
        ax = figure.axes[j]
        plotted, reference = ax.get_lines()[0].get_ydata(), factor * exact[j]
        assert ax.get_ylabel().endswith(unit)
        assert np.abs(plotted - reference).max() < 1e-12 * np.abs(reference).max(), j   # measured 2.6e-13
