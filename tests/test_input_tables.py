"""Input tables whose header names the inputs drive each input with its own column, in the recording and in the
ROM (audit 58: read by position, a table headed ``time,F_kN,F_mN`` for inputs ``F_mN, F_kN`` swapped them, and
compare agreed to 1e-25 because both sides got the same swapped input)."""

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import InputSpecError
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.snapshots import record
from fmu_opinf.source import open_source

DT, T_END = 0.05, 4.0


def _table(path, header, columns):
    """A CSV table on the grid, the time column first."""
    t = DT * np.arange(round(T_END / DT) + 1)
    rows = [",".join(["time", *header])] + [",".join(repr(float(v)) for v in (ti, *col)) for ti, *col in
                                            zip(t, *columns)]
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def _forces():
    t = DT * np.arange(round(T_END / DT) + 1)
    return np.sin(1.3 * t), 5.0 * np.cos(0.7 * t) - 5.0   # two inputs that differ in shape and size


@pytest.mark.fmu
def test_a_recording_drives_each_input_with_the_column_its_header_names(tmp_path):
    n = 3
    K = np.diag([20.0, 20.0, 10.0]) - np.diag([10.0, 10.0], 1) - np.diag([10.0, 10.0], -1)
    B = np.zeros((n, 2))
    B[0, 0] = B[2, 1] = 1.0
    model = lti_fmus.LinearMechanicalModel(M=np.eye(n), D=0.1 * np.eye(n), K=K, B=B, Cp=np.eye(n)[[0, 2]],
                                           name="TwoForces")
    path = tmp_path / "TwoForces.fmu"
    lti_fmus.build_lti_fmu(model, path, interfaces=("me",))
    first, second = _forces()
    in_order = _table(tmp_path / "ordered.csv", ["F[1]", "F[2]"], [first, second])
    reversed_ = _table(tmp_path / "reversed.csv", ["F[2]", "F[1]"], [second, first])
    runs = [record(open_source(path), table, DT, T_END, quiet=True).runs[0] for table in (in_order, reversed_)]
    for run in runs:   # the sample at t_i carries the input held over the step ending there
        np.testing.assert_array_equal(run.u[:, 1:], np.vstack([first, second])[:, :-1])
    np.testing.assert_array_equal(runs[0].x, runs[1].x)
    with pytest.raises(InputSpecError, match=r"has no column for F\[1\]"):
        record(open_source(path), _table(tmp_path / "one.csv", ["F[2]"], [second]), DT, T_END, quiet=True)


def test_a_rom_simulated_from_a_table_takes_each_input_from_its_named_column(tmp_path):
    rom = SecondOrderROM(np.eye(2), 0.2 * np.eye(2), np.diag([1.0, 4.0]), [[1.0, 0.0], [0.0, 1.0]], np.eye(2),
                         np.zeros((2, 2)), input_names=["pull", "push"])
    first, second = _forces()
    ordered = rom.simulate(_table(tmp_path / "a.csv", ["pull", "push"], [first, second]), DT, T_END)
    swapped = rom.simulate(_table(tmp_path / "b.csv", ["push", "pull"], [second, first]), DT, T_END)
    np.testing.assert_array_equal(swapped.u, ordered.u)
    np.testing.assert_array_equal(swapped.y, ordered.y)
    assert np.abs(ordered.y[0]).max() > 0.1 and np.abs(ordered.y[1]).max() > 0.1   # both inputs move the model


def test_a_rom_refuses_a_table_column_named_after_an_input_its_source_held(tmp_path):
    """Audit 60: compare and the ROM drove the force with a column headed by the stiffness input the training held
    (only snapshots refused it)."""
    rom = SecondOrderROM(np.eye(1), 0.2 * np.eye(1), np.eye(1), np.eye(1), np.eye(1), np.zeros((1, 1)),
                         input_names=["F"], provenance={"snapshots": {"held_input_names": ["springScale"]}})
    first, _ = _forces()
    with pytest.raises(InputSpecError, match="has a column for springScale, held at its start value"):
        rom.simulate(_table(tmp_path / "scale.csv", ["springScale"], [first]), DT, T_END)
