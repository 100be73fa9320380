"""Input signals: values, textual form, tables, and clear errors for bad specifications."""

import re

import numpy as np
import pytest

from fmu_opinf import signals
from fmu_opinf.errors import DimensionError, FmuOpinfWarning, InputSpecError


def test_impulse_is_a_smooth_pulse_centred_at_t0():
    s = signals.parse_signal("impulse:amplitude=100,t0=2,width=0.5")
    values = s.sample(np.array([0.0, 1.75, 1.875, 2.0, 2.125, 2.25, 3.0]))[0]
    assert np.allclose(values, [0, 0, 50, 100, 50, 0, 0], atol=1e-12)


def test_harmonic_step_chirp_values():
    t = np.linspace(0, 10, 11)
    assert np.allclose(signals.parse_signal("harmonic:amplitude=2,omega=0.2").sample(t)[0], 2 * np.sin(0.2 * t))
    assert np.array_equal(signals.parse_signal("step:amplitude=3,t0=4").sample(t)[0], np.where(t >= 4, 3.0, 0.0))
    chirp = signals.parse_signal("chirp:amplitude=1,omega0=0.5,omega1=2,duration=10")
    # instantaneous frequency sweeps linearly: phase 0.5 t + 1.5 t^2 / 20
    assert np.allclose(chirp.sample(t)[0], np.sin(0.5 * t + 0.075 * t**2))


def test_spec_round_trips_through_its_text():
    s = signals.parse_signal("harmonic:omega=0.2,amplitude=1")
    again = signals.parse_signal(s.spec)
    t = np.linspace(0, 50, 101)
    assert np.array_equal(s.sample(t), again.sample(t))


def test_one_spec_per_input_and_broadcast():
    two = signals.parse_signal("step:amplitude=1;harmonic:omega=1", n_inputs=2)
    assert two.sample(np.array([1.0])).shape == (2, 1)
    broadcast = signals.parse_signal("step:amplitude=2", n_inputs=3)
    assert np.array_equal(broadcast.sample(np.array([1.0]))[:, 0], [2.0, 2.0, 2.0])
    with pytest.raises(DimensionError, match="2 channels but the model has 3 inputs"):
        signals.parse_signal("step;step", n_inputs=3)


@pytest.mark.parametrize("spec, message", [
    ("pulse:amplitude=1", "unknown input kind 'pulse'"),
    ("Data/PULSE:amplitude=1", "unknown input kind 'Data/PULSE'"),   # (as given: a path keeps its capitals)
    ("impulse:height=3", "unknown key 'height' for impulse input"),
    ("impulse:amplitude", "malformed impulse parameter 'amplitude'"),
    ("harmonic:omega=fast", "omega='fast' is not a number"),
    ("step:t0=1,t0=2", "given twice"),
    ("impulse:width=-1", "width must be positive"),
    ("harmonic:omega=nan", "not a finite number"),
    ("", "empty input specification"),
    ("missing.csv", "not found"),
])
def test_bad_specs_give_one_line_errors(spec, message):
    with pytest.raises(InputSpecError, match=message) as info:
        signals.parse_signal(spec)
    assert "\n" not in str(info.value)


def _write(tmp_path, text, name="u.csv"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_table_is_held_between_rows(tmp_path):
    s = signals.parse_signal(_write(tmp_path, "time,F1,F2\n0,1,10\n1.5,2,20\n3,3,30\n"))
    assert s.n_inputs == 2
    values = s.sample(np.array([0.0, 1.0, 1.5, 2.9, 3.0]))
    assert np.array_equal(values, [[1, 1, 2, 2, 3], [10, 10, 20, 20, 30]])


def test_table_outside_its_time_range_is_an_error(tmp_path):
    s = signals.parse_signal(_write(tmp_path, "t,u\n0,1\n10,2\n"))
    with pytest.raises(InputSpecError, match=r"defined on \[0, 10\]"):
        s.sample(np.array([0.0, 12.0]))


@pytest.mark.parametrize("text, message", [
    ("t,u\n0,1\n", "at least two data rows"),
    ("t\n0\n1\n", "time column and at least one input column"),
    ("t,u\n0,1\n1,abc\n", ":3: not a number"),
    ("t,u\n0,1\n1,2,3\n", ":3: 3 columns, header has 2"),
    ("t,u\n0,1\n0,2\n", ":3: time does not increase"),
    ("t,u\n0,1\n1,nan\n", ":3: NaN or infinite"),
])
def test_bad_tables_give_one_line_errors(tmp_path, text, message):
    with pytest.raises(InputSpecError, match=message):
        signals.parse_signal(_write(tmp_path, text))


def test_none_among_several_specs_leaves_that_input_undriven():
    from types import SimpleNamespace

    from fmu_opinf.snapshots._inputs import as_signal

    t = np.array([0.0, 1.0, 2.0])
    parsed = signals.parse_signal("step:amplitude=2,t0=1;none", 2)
    np.testing.assert_array_equal(parsed.sample(t), [[0.0, 2.0, 2.0], [0.0, 0.0, 0.0]])
    source = SimpleNamespace(input_starts=lambda: np.array([3.0, 5.0]), input_names=["a", "b"])  # an FMU's starts
    recorded = as_signal("step:amplitude=2,t0=1;none", 2, source)
    np.testing.assert_array_equal(recorded.sample(t), [[0.0, 2.0, 2.0], [5.0, 5.0, 5.0]])
    np.testing.assert_array_equal(as_signal("none;none", 2, source).sample(t), as_signal("none", 2, source).sample(t))


def test_a_signal_for_a_model_without_inputs_is_refused_with_the_fix():
    """Audit 2026-11-27: on a model without inputs, ``compare --input harmonic:...`` was accepted (the signal
    broadcast to no channel) and the report named the free response after the harmonic; ``snapshots`` said 'give a
    signal with 0 channels'.  Both now say to give ``--input none``, and its Python keyword (``signal='none'``: the
    same check serves record and compare, audit 81c F8)."""
    from fmu_opinf.errors import DimensionError
    from fmu_opinf.signals import NoInput, parse_signal

    from fmu_opinf.snapshots import inputs_in_effect

    with pytest.raises(DimensionError, match=r"the model has no inputs; give --input none or signal='none' \(the "
                                             r"free response"):
        parse_signal("harmonic:amplitude=1,omega=0.8", 0)
    assert isinstance(parse_signal("none", 0), NoInput)
    with pytest.raises(DimensionError, match=r"has 1 channel\(s\) but the source has no inputs; give --input none "
                                             r"or signal='none' \(the free response"):
        inputs_in_effect(parse_signal("harmonic:amplitude=1,omega=0.8"), np.arange(5.0), 0)


def test_an_offset_puts_impulse_step_and_chirp_on_an_operating_point():
    """``offset=`` adds a constant to the formula (the default training's pulse on an input's start value); the
    spec names it only where it is not 0 (specs written before read the same), and keeps every digit of it."""
    t = np.linspace(0.0, 4.0, 81)
    for spec in ("impulse:amplitude=2,t0=1,width=0.5", "step:amplitude=2,t0=1",
                 "chirp:amplitude=2,omega0=0.01,omega1=3,duration=100,t0=0"):
        plain, shifted = signals.parse_signal(spec), signals.parse_signal(spec + ",offset=9.80665123")
        assert plain.spec == spec and "offset" not in plain.spec
        np.testing.assert_array_equal(shifted.sample(t), plain.sample(t) + 9.80665123)
        assert signals.parse_signal(shifted.spec).params["offset"] == 9.80665123
        assert shifted.spec.endswith("offset=9.80665123")


def test_a_table_s_header_puts_its_columns_where_it_names_the_inputs(tmp_path):
    """Audit 58: a table headed ``time,F_kN,F_mN`` for inputs ``F_mN, F_kN`` drove each input with the other's
    column.  The header is the reference: each input gets the column named after it."""
    names = ["F_mN", "F_kN"]
    swapped = signals.parse_signal(_write(tmp_path, "time,F_kN,F_mN\n0,1,10\n1,2,20\n"), 2, names)
    assert swapped.names == names
    assert np.array_equal(swapped.sample(np.array([0.0, 1.0])), [[10, 20], [1, 2]])
    placed = signals.parse_signal("none;" + _write(tmp_path, "time,F_kN\n0,1\n1,2\n", "kn.csv"), 2, names)
    assert np.array_equal(placed.sample(np.array([0.0, 1.0])), [[0, 0], [1, 2]])
    with pytest.warns(FmuOpinfWarning, match=r"names none of the inputs \(F_mN, F_kN\), so its columns are taken "
                                             r"in order: u drives each of F_mN, F_kN"):
        generic = signals.parse_signal(_write(tmp_path, "time,u\n0,1\n1,2\n", "u1.csv"), 2, names)
    assert np.array_equal(generic.sample(np.array([1.0])), [[2], [2]])
    with pytest.warns(FmuOpinfWarning, match=r"taken in order: a -> F_mN, b -> F_kN"):
        ordered = signals.parse_signal(_write(tmp_path, "time,a,b\n0,1,10\n1,2,20\n", "ab.csv"), 2, names)
    assert np.array_equal(ordered.sample(np.array([0.0])), [[1], [10]])


@pytest.mark.parametrize("header", ['f_kn,f_mn', 'F_kN [kN], F_mN [mN]', ' "F_kN", "F_mN"', "F_KN,F_MN"])
def test_a_header_that_names_the_inputs_but_for_case_quotes_or_a_unit_is_matched_by_name(tmp_path, header):
    """Audit 59: cells differing from the input names in case, by a unit in brackets or by a blank before a quote
    were read by position, and swapped the two inputs."""
    table = signals.parse_signal(_write(tmp_path, f"time,{header}\n0,1,10\n1,2,20\n"), 2, ["F_mN", "F_kN"])
    assert table.names == ["F_mN", "F_kN"]
    assert np.array_equal(table.sample(np.array([0.0, 1.0])), [[10, 20], [1, 2]])


def test_a_table_with_a_column_for_a_held_input_or_separated_otherwise_is_refused_in_one_line(tmp_path):
    """Audit 59: a one-column table headed by an input the model holds (a parameter exposed as an input) drove
    the force input with its values; a table separated by semicolons was said to lack an input column."""
    with pytest.raises(InputSpecError, match=r"has a column for springScale, held at its start value, not driven "
                                             r"\(the driven inputs: F\); leave its column out, or record "
                                             r"snapshots with --inputs F,springScale or inputs='F,springScale' to "
                                             r"drive it"):
        signals.parse_signal(_write(tmp_path, "time,springScale\n0,1\n1,2\n"), 1, ["F"], ["springScale"])
    with pytest.raises(InputSpecError, match="is separated by semicolons; write it with commas"):
        signals.parse_signal(_write(tmp_path, "time;F\n0;1\n1;2\n", "semi.csv"), 1, ["F"])


@pytest.mark.parametrize("text, spec, message", [
    ("time,F_kN\n0,1\n1,2\n", "{}", "has no column for F_mN; give a column for each input (F_mN, F_kN)"),
    ("time,F_kN\n0,1\n1,2\n", "{};none", "gives F_kN in the place of F_mN among the ';' specs"),
    ("time,F_kN,force\n0,1,2\n1,2,3\n", "{}", "has columns force beside the model's inputs (F_mN, F_kN)"),
    ("time,F_kN,F_kN\n0,1,2\n1,2,3\n", "{}", "names an input twice (F_kN, F_kN)"),
    ("time,F_kN,f_kn [kN]\n0,1,2\n1,2,3\n", "{}", "names an input twice (F_kN, f_kn [kN])"),
])
def test_a_table_naming_inputs_it_cannot_drive_is_refused_in_one_line(tmp_path, text, spec, message):
    path = _write(tmp_path, text)
    with pytest.raises(InputSpecError, match=re.escape(message)) as info:
        signals.parse_signal(spec.format(path), 2, ["F_mN", "F_kN"])
    assert "\n" not in str(info.value)


def test_inputs_that_differ_in_case_take_their_own_columns_and_a_held_one_is_named_as_declared(tmp_path):
    """Audit 60: with inputs F and f, the header 'f [N],F [N]' was taken in order (swapped); with F driven and f
    held, 'F [N]' was refused as f's; a refusal named the header's 'SPRINGSCALE [1]' where --inputs needs the
    input's own name."""
    table = signals.parse_signal(_write(tmp_path, "time,f [N],F [N]\n0,1,10\n1,2,20\n"), 2, ["F", "f"])
    assert np.array_equal(table.sample(np.array([0.0])), [[10], [1]])
    assert signals.parse_signal(_write(tmp_path, "time,F [N]\n0,1\n1,2\n", "F.csv"), 1, ["F"], ["f"]).names == ["F"]
    with pytest.raises(InputSpecError, match=r"a column for springScale, .* --inputs F,springScale or "
                                             r"inputs='F,springScale' to drive it"):
        signals.parse_signal(_write(tmp_path, "time,SPRINGSCALE [1]\n0,1\n1,2\n", "s.csv"), 1, ["F"],
                             ["springScale"])
