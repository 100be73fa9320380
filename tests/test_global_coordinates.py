"""Positions in global coordinates: start values of 6.4e6 m (a chain placed in an Earth-centred frame, as
multibody and FE exports give them) moving by millimetres.

The model-exchange recording integrates each state's deviation from its start value, and no state is asked to be
more accurate than the FMU can resolve (sources/_model_exchange.py).  Before, the tolerance followed the states'
absolute size (1e-10 x 6.4e6 m = 0.6 mm on a motion of 17 mm), each integrator step added a few ulps to a 6.4e6 m
position, and the steps shrank to the accelerations' rounding noise: here 7000 ulps off, 2.7 million derivative
evaluations.  The reference is :func:`fmu_opinf.lti_fmus.zoh_response` of the same chain in displacement
coordinates, the step count that of the same chain placed at 0.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.source import open_source  # noqa: E402

from conftest import build_fmu_set  # noqa: E402

pytestmark = pytest.mark.fmu

OFFSET = 6.4e6
EQUILIBRIUM = OFFSET + np.array([1.0, 2.0, 3.0])
DT, T_END = 0.01, 2.0
INPUT = "harmonic:amplitude=1,omega=2"


def chain(global_frame: bool) -> lti_fmus.LinearMechanicalModel:
    """Three unit masses, springs of 100 N/m, the force on the last one, its first and last positions the outputs;
    ``global_frame``: at rest at :data:`EQUILIBRIUM` under the constant force that holds it there, else at 0."""
    K = 100.0 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    placed = dict(f0=K @ EQUILIBRIUM, x0=EQUILIBRIUM) if global_frame else {}
    return lti_fmus.LinearMechanicalModel(M=np.eye(3), D=0.02 * K + 0.1 * np.eye(3), K=K, B=[[0.0], [0.0], [1.0]],
                                          Cp=[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], name="GlobalFrame", **placed)


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    def build(folder, frame):
        return frame, lti_fmus.build_lti_fmu(chain(frame == "global"), folder / f"{frame}-frame.fmu").path

    return build_fmu_set(request, tmp_path_factory, "global-coordinates", build, ["global", "zero"])


def _evaluations(source) -> int:
    return source._kernel.evaluations


@pytest.mark.parametrize("loop", ["compiled", "python"])
def test_motion_about_global_coordinates_is_recorded_to_the_rounding_of_the_positions(fmus, loop, monkeypatch):
    from fmu_opinf.sources import _compiled_rk

    if loop == "compiled" and not _compiled_rk.available():
        pytest.skip("no C compiler for the compiled step loop")
    if loop == "python":
        monkeypatch.setattr(_compiled_rk, "kernel", lambda *args: None)
    source = open_source(fmus["global"], interface="me")
    run = record(source, INPUT, DT, T_END, quiet=True).runs[0]
    held = np.hstack([run.u[:, 1:], run.u[:, -1:]])
    motion = lti_fmus.zoh_response(chain(False), run.t, held).y
    error = np.abs(run.y - EQUILIBRIUM[[0, 2], None] - motion).max(axis=1) / np.ptp(motion, axis=1)
    ulp = np.spacing(OFFSET) / np.ptp(motion, axis=1)   # the positions' resolution, relative to their motion
    assert (error < 6 * ulp).all(), error / ulp   # measured 2.4 and 2.2 ulps (7058 and 5726 before)
    if loop == "compiled":
        at_zero = open_source(fmus["zero"], interface="me")
        record(at_zero, INPUT, DT, T_END, quiet=True)
        # measured 5433 against 5037 (2.7 million before)
        assert _evaluations(source) < 1.3 * _evaluations(at_zero), (_evaluations(source), _evaluations(at_zero))
