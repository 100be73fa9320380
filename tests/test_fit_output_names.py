"""fit names outputs by their recorded names, as compare and the report do (audit 81c, F11: ``y[1]`` for an FMU
whose first output is ``Antriebsstrang...``, and wrong outright where an FMU names its outputs ``y[k]`` in another
order)."""

from __future__ import annotations

import re

import pytest

from fmu_opinf import fit, snapshots
from fmu_opinf.fit._order_search import _search_summary


@pytest.fixture(scope="module")
def recorded():
    """The anchored chain's three outputs, named y[1], y[2], y[3] by the builtin source."""
    return snapshots.record("builtin:anchored-msd", "impulse:amplitude=100,t0=2,width=0.5", dt=0.5, t_end=60.0,
                            quiet=True)


@pytest.mark.parametrize("names", [["Tip.x", "Middle.x", "Base.x"], ["y[3]", "y[1]", "y[2]"]])
def test_the_training_line_names_the_recorded_outputs(recorded, names):
    plain = [[], []]
    fit.fit_rom(recorded, r=4, log=plain[0].append)
    positions = [int(j) - 1 for j in re.findall(r"\(y\[(\d)\]", next(l for l in plain[0] if "training outputs" in l))]
    assert len(positions) == 2   # the worst RMS output and the worst peak output, by position (names y[1..3])
    recorded.attrs["output_names"] = names
    try:
        fit.fit_rom(recorded, r=4, log=plain[1].append)
    finally:
        recorded.attrs["output_names"] = ["y[1]", "y[2]", "y[3]"]
    line = next(l for l in plain[1] if "training outputs" in l)
    assert [f"({names[j]}" in line for j in positions] == [True, True], line


def test_the_order_search_line_names_the_worst_output():
    search = [{"r": 4, "judged": 0.04, "worst_output": 1, "worst_output_error": 0.04, "worst_run": 0,
               "worst_run_name": "run 0", "n_runs": 1},
              {"r": 8, "judged": 1e-8, "worst_output": 0, "worst_output_error": 1e-8, "worst_run": 0, "n_runs": 1}]
    line = _search_summary(search, 8, ["Tip.x", "Middle.x"])
    assert "on Middle.x" in line and "on Tip.x" in line and "y[" not in line
    assert "on y[2]" in _search_summary(search, 8)   # no recorded names: by position
