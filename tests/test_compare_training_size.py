"""compare on inputs sized against the training's: no warning at the training's own size (audit 74, F1's minor
finding), one line where a given input is far above the training's amplitude, and that advice first."""

import warnings

import numpy as np
import pytest

from fmu_opinf import compare, snapshots
from fmu_opinf.compare import _training
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom

TRAIN = "impulse:amplitude=2,t0=2,width=0.5"


def _rom_info(peak: float) -> dict:
    return {"provenance": {"training_runs": [{"input_spec": TRAIN, "output_peak": [peak]}]}}


def test_a_test_at_the_training_size_is_not_said_to_go_past_it():
    """The training's peak departure is 1.0 (given here, the independent reference): an output at 1.0004 times it
    (a 100 N harmonic on a 96 m gravity swing) went past by a hair and was warned "may miss a mode" before."""
    y = np.array([[0.0, 0.5, 1.0004, 0.2]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _training._past_training(y, 0.999 * y, ["y[1]"], _rom_info(1.0), "m.fmu") == ""


def test_a_test_well_past_the_training_size_is_still_said():
    y = np.array([[0.0, 0.5, 1.2, 0.2]])
    with pytest.warns(FmuOpinfWarning, match=r"m.fmu's y\[1\] went to 1.2 times its largest departure in the "
                                             r"training; the ROM stays within it"):
        said = _training._past_training(y, np.minimum(y, 1.0), ["y[1]"], _rom_info(1.0), "m.fmu")
    assert said.startswith("; m.fmu's y[1] went to 1.2 times")


@pytest.fixture(scope="module")
def small_rom(tmp_path_factory):
    """A ROM of the builtin anchored chain trained with a pulse of amplitude 2, saved to a file."""
    model = fit_rom(snapshots.record("builtin:anchored-msd", TRAIN, 0.5, 60.0, quiet=True), r=4)
    path = tmp_path_factory.mktemp("rom") / "rom.h5"
    model.save(path)
    return path


def test_a_given_input_far_above_the_training_is_named_with_its_ratio(small_rom):
    """Trained at amplitude 2 about 0; the harmonic of amplitude 100 departs by 100 (its samples' peak on the
    grid, within 1 %): 50 times, said in one line and carried into the metrics."""
    with pytest.warns(FmuOpinfWarning, match=r"the test input departs by (99\.\d|100) on u, (49\.\d|50) times the "
                                             r"training's amplitude there \(2\): the ROM of builtin:anchored-msd "
                                             r"learned "
                                             r"only the responses to inputs that size; train with an input nearer"):
        result = compare.compare(small_rom, "builtin:anchored-msd", "harmonic:amplitude=100,omega=0.3", dt=0.5,
                                 t_end=60.0, quiet=True)
    beyond = result.metrics()["input_beyond_training"]
    assert beyond["trained"] == 2.0 and 49.5 < beyond["ratio"] <= 50.0


def test_a_given_input_near_the_training_size_says_nothing(small_rom):
    with warnings.catch_warnings():
        warnings.simplefilter("error", FmuOpinfWarning)
        result = compare.compare(small_rom, "builtin:anchored-msd", "harmonic:amplitude=15,omega=0.3", dt=0.5,
                                 t_end=60.0, quiet=True)
    assert result.metrics()["input_beyond_training"] is None


def test_the_order_advice_puts_training_nearer_first_for_an_input_far_above_the_training():
    metrics = {"order": {"r": 4, "chosen": "energy", "snapshot_rank": 30, "tried": []},
               "per_output": {"y[1]": {"relative_max_variation": 0.35}}}
    plain = compare.order_note(metrics)
    assert "a larger order may follow this input (fit --r 8 or r=8" in plain
    metrics["input_beyond_training"] = {"input": "F", "ratio": 100.0, "given": 1e4, "trained": 100.0}
    note = compare.order_note(metrics)
    assert note.startswith("y[1] is 0.35 of its range off, and the ROM's order r=4 came from the POD energy")
    assert note.split(": ", 1)[1].startswith("this input is 100 times the training's amplitude on F, so train with "
                                             "an input nearer this one first")
