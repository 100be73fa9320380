"""What an FMI 3 ``fmi3DoStep`` reports besides its status: an early return that was not allowed and a request to
terminate end the run in one line (audit of 2026-11-27, finding 4: an FMU that returned early anyway gave
time-shifted data and a ROM 46-200 % off, blamed on "one explicit step per doStep").

The FMUs are :func:`fmu_opinf.lti_fmus.build_lti_fmu` FMUs with ``cs_early_return_at`` (``fmi3DoStep`` stops inside
the step containing that time and says ``earlyReturn``, although fmu-opinf never allows it) or ``cs_terminate_at``;
recordings that are accepted are checked against :func:`fmu_opinf.lti_fmus.zoh_response`.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.cli import main  # noqa: E402
from fmu_opinf.errors import FMUError  # noqa: E402
from fmu_opinf.snapshots import Snapshots  # noqa: E402
from fmu_opinf.sources import FMUSource  # noqa: E402

from conftest import build_fmu_set  # noqa: E402

pytestmark = pytest.mark.fmu

DT = 0.1
EARLY, TERMINATE = 0.25, 0.5
INPUT = "harmonic:amplitude=1,omega=2"


def _model() -> lti_fmus.LinearMechanicalModel:
    return lti_fmus.chain_model(2, name="Flags")


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    items = {"early": dict(cs_early_return_at=EARLY, interfaces=("cs",)),
             "early_me": dict(cs_early_return_at=EARLY, interfaces=("me", "cs")),
             "terminate": dict(cs_terminate_at=TERMINATE, interfaces=("cs",))}

    def build(folder, item):
        name, options = item
        built = lti_fmus.build_lti_fmu(_model(), folder / f"{name}.fmu", fmi_version="3.0",
                                       identifier=f"Flags_{name}", **options)
        return name, built.path

    return build_fmu_set(request, tmp_path_factory, "lti-fmi3-flags", build, items.items())


def _snapshots(path, out, *extra) -> int:
    return main(["snapshots", str(path), "-o", str(out), "--input", INPUT, "--dt", str(DT), "-q", *extra])


def _error_vs_exact(out) -> float:
    run = Snapshots.load(out).runs[0]
    y = lti_fmus.zoh_response(_model(), run.t, run.u[:, 1:]).y
    return float(np.abs(run.y - y).max() / np.abs(y).max())


def test_an_early_return_that_was_not_allowed_is_an_error(fmus, tmp_path, capsys):
    code = _snapshots(fmus["early"], tmp_path / "s.h5", "--t-end", "1")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and not (tmp_path / "s.h5").exists()
    assert ("early.fmu returned early from fmi3DoStep at t=0.2 -> 0.3 (lastSuccessfulTime 0.25), although early "
            "return was not allowed") in err, err
    assert "it offers no model exchange" in err and "one explicit step" not in err, err


def test_an_early_return_names_model_exchange_as_the_fix_and_that_records_right(fmus, tmp_path, capsys):
    code = _snapshots(fmus["early_me"], tmp_path / "cs.h5", "--t-end", "1", "--interface", "cs")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "returned early from fmi3DoStep" in err and "(--interface me or interface='me')" in err, err
    assert _snapshots(fmus["early_me"], tmp_path / "me.h5", "--t-end", "1", "--interface", "me") == 0
    assert _error_vs_exact(tmp_path / "me.h5") < 1e-10   # measured 5.3e-11


def test_a_request_to_terminate_is_an_error_before_the_end_and_accepted_at_it(fmus, tmp_path, capsys):
    code = _snapshots(fmus["terminate"], tmp_path / "s.h5", "--t-end", "1")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and ("terminate.fmu asked to terminate the simulation in fmi3DoStep at t=0.4 -> 0.5; "
                          "end the run before it: --t-end or t_end= below 0.5") in err, err
    assert _snapshots(fmus["terminate"], tmp_path / "end.h5", "--t-end", str(TERMINATE)) == 0   # its last step
    assert _error_vs_exact(tmp_path / "end.h5") < 1e-12   # measured 3.7e-13


def test_single_steps_check_the_flags_too(fmus):
    source = FMUSource(fmus["early"])
    t = DT * np.arange(4)
    source.start(t, np.zeros((4, 1)))
    try:
        source.step(0.0, DT, np.zeros(1))
        source.step(DT, DT, np.zeros(1))
        with pytest.raises(FMUError, match=r"returned early from fmi3DoStep at t=0\.2 -> 0\.3"):
            source.step(2 * DT, DT, np.zeros(1))
    finally:
        source.close()
