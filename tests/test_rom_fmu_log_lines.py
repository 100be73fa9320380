"""The ROM FMU's log lines name their fixes in both vocabularies (api84, item 1).

A user of a ROM FMU may have made it from Python: the refusal of another communication step (an exact step map) and of
another value of a fixed source parameter named the command line's ``--step h`` and ``--set NAME=VALUE`` only.  Now
they name ``step=h`` and ``parameters['NAME']`` too, as the rest of the project does (``_validate.either``).  The
parameter's name reaches the line as printf data (``%s`` argument of a C string literal), never as code or format.
"""

from __future__ import annotations

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

from fmpy import simulate_fmu  # noqa: E402

from fmu_opinf.export import export_fmu  # noqa: E402
from fmu_opinf.rom import SecondOrderROM  # noqa: E402

pytestmark = pytest.mark.slow   # two ROM FMUs compiled (about 3 s each on the 2-core machine)

#: A name a printf format would read as a conversion and a C literal as its end, were it not escaped as data
NAME = 'gain%s"x'
#: A long Modelica path (162 characters): its line, the name three times, is 690 characters (512 were kept before)
LONG = ".".join(f"plant{i}.block[{i}].spring" for i in range(1, 8)) + ".c"


def _rom() -> SecondOrderROM:
    """An exact-step ROM (step map of h = 0.05) whose training recorded two real source parameters (2.5 and 1)."""
    record = {"names": [NAME, LONG], "types": ["Real", "Real"], "values": [2.5, 1.0], "units": ["", ""],
              "quantities": ["", ""], "set": [NAME]}
    return SecondOrderROM(np.diag([1.0, 2.0]), np.array([[0.3, -0.1], [-0.1, 0.2]]),
                          np.array([[5.0, -2.0], [-2.0, 3.0]]), np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]]),
                          np.zeros((1, 2)), dt=0.05, integrator="exact",
                          provenance={"snapshots": {"source_parameters": record}})


@pytest.fixture(scope="module", params=["2.0", "3.0"])
def rom_fmu(request, tmp_path_factory):
    from fmu_opinf.fmus import find_build_tools

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    folder = tmp_path_factory.mktemp(f"lines{request.param[0]}")
    return export_fmu(_rom(), folder / "Lines.fmu", fmi_version=request.param)


def _log_lines(path, **options) -> list[str]:
    """The FMU's log lines of one fmpy run that the FMU refuses (status 3)."""
    lines = []

    def logger(*args):   # FMI 2: (component, instance, status, category, message); FMI 3: (env, status, ...)
        message = args[-1]
        lines.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception, match="status 3"):
        simulate_fmu(str(path), logger=logger, **options)
    return lines


def test_another_step_is_refused_naming_both_vocabularies(rom_fmu):
    lines = [line for line in _log_lines(rom_fmu, stop_time=1.0, output_interval=0.02) if "step map" in line]
    assert len(lines) == 1
    assert lines[0].endswith("got h = 0.02; use such a communication step, or export the ROM again with --step h "
                             "or step=h")


def test_another_parameter_value_is_refused_naming_both_vocabularies(rom_fmu):
    lines = [line for line in _log_lines(rom_fmu, stop_time=0.5, output_interval=0.05, start_values={NAME: 3.0})
             if "refused" in line]
    assert len(lines) == 1
    assert f"parameter {NAME} (value reference 3) was 2.5 in training" in lines[0]
    assert lines[0].endswith(f"3 refused: set it to 2.5 or leave it, or record the snapshots and fit again with "
                             f"--set {NAME}=VALUE or parameters['{NAME}']")


def test_the_line_of_a_long_name_is_whole(rom_fmu):
    lines = [line for line in _log_lines(rom_fmu, stop_time=0.5, output_interval=0.05, start_values={LONG: 2.0})
             if "refused" in line]
    assert len(lines) == 1 and len(lines[0]) > 600
    assert lines[0].endswith(f"--set {LONG}=VALUE or parameters['{LONG}']")
