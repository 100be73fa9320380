"""Pairs the data find or confirm where the FMU declares none must match as a true rate does at the step (audit 76).

F1: a first-order state vector whose second half is the rates plus a damping-like offset (``x[7..12] = v + c x[1..6]``)
matched the old bar (:data:`MISMATCH` = 0.25) within 0.016 .. 0.18 where the step explains 0.001, and was recorded
as velocities (ROM 4-69 % off); at c = 1 nothing paired and all 12 rows were recorded as positions (fit crashed).
F2: on a long chain the positions at a wave front "were the rates" of their neighbours (0.013 .. 0.07) and overruled
a right name pairing; masses the wave had not reached were called "an actuator lag, a filter or a controller state".
The data come from exact discretizations (matrix exponential), never from the code under test.
"""

from __future__ import annotations

import types

import numpy as np
import pytest
from test_guessed_pairings import DT, _chain, _zoh

from fmu_opinf.snapshots._consistency import check_rates
from fmu_opinf.snapshots._pairing import rates_among_positions
from fmu_opinf.snapshots._rate_tests import Repair
from fmu_opinf.sources._cosimulation import FMUSource
from fmu_opinf.sources._variables import _LOCAL_STEMS


def _soft_chain() -> tuple[np.ndarray, np.ndarray]:
    """First-order form of an anchored 3-mass chain (unit masses, springs 1, light damping; natural frequencies
    0.45 .. 1.8 rad/s, so ``omega h`` = 0.02 .. 0.09 at :data:`DT`, as the audit's 6-mass chain at its step) forced
    at its first mass."""
    K = 2 * np.eye(3) - np.eye(3, k=1) - np.eye(3, k=-1)
    A = np.block([[np.zeros((3, 3)), np.eye(3)], [-K, -(0.02 * K + 0.01 * np.eye(3))]])
    return A, np.r_[np.zeros(3), 1.0, 0.0, 0.0]


def _offset_rows(c: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact impulse response of :func:`_soft_chain`: positions ``q`` and ``v + c q`` (velocities of other
    coordinates), and the true velocities ``v``."""
    states = _zoh(*_soft_chain())
    return np.vstack([states[:3], states[3:] + c * states[:3]]), states[3:]


def test_the_step_explains_the_trapezoidal_rules_own_error():
    """The estimate is the true rate's mismatch (the trapezoidal rule's error, computed from the exact states)
    within 10 % after the pulse (an input's edges raise the estimate, never lower it): the strict bar is built on
    it."""
    from fmu_opinf.snapshots._pairing import step_explains  # new in audit 76's fix

    states = _zoh(*_soft_chain())[:, 40:]
    x, v = states[:3], states[3:]
    increments, averages = np.diff(x, axis=1), DT * 0.5 * (v[:, :-1] + v[:, 1:])
    true = np.linalg.norm(increments - averages, axis=1) / np.linalg.norm(averages, axis=1)
    np.testing.assert_allclose(step_explains(v), true, rtol=0.1)


@pytest.mark.parametrize("c", [0.02, 0.1, 0.3])
def test_near_rates_among_positions_are_recorded_as_the_positions_alone(c):
    """Old code: c <= 0.1 (mismatch 0.02 .. 0.12) recorded ``x[4..6]`` as the velocities (they are no rates),
    c = 0.3 (0.26 .. 0.33, above the old bar) all six rows as positions (None here); the rows ``v + c q`` are
    combinations of the positions and their rates, so the positions alone (velocities derived) are the exact model."""
    rows, _ = _offset_rows(c)
    names = [f"x[{i}]" for i in range(1, 7)]
    repair = rates_among_positions(rows, DT, names)
    assert isinstance(repair, Repair), repair
    assert repair.positions == ["x[1]", "x[2]", "x[3]"] and repair.velocities == "" and repair.accelerations == ""
    assert "x[4] near the rate of x[1]" in repair.reason and "v + c x" in repair.reason, repair.reason


def test_exact_rates_among_positions_still_pair():
    """The strict bar keeps the true rates (c = 0) as velocities (a guard: old code passes it too)."""
    rows, _ = _offset_rows(0.0)
    repair = rates_among_positions(rows, DT, [f"x[{i}]" for i in range(1, 7)])
    assert isinstance(repair, Repair) and repair.velocities == ["x[4]", "x[5]", "x[6]"], repair


def test_halves_of_first_order_states_with_an_offset_take_the_derivative_variables():
    """ssoff.fmu: states split in halves (``derivative=`` links) whose velocity half is ``v + 0.3 q``: old code
    accepted them without a word (mismatch within 0.25; here c = 0.1, 0.09 .. 0.12); the derivative variables are
    the true rates."""
    rows, _ = _offset_rows(0.1)
    names = {"positions": ["x[1]", "x[2]", "x[3]"], "velocities": ["x[4]", "x[5]", "x[6]"]}
    derivatives = ["der(x)[1]", "der(x)[2]", "der(x)[3]"]
    verdict = check_rates(rows[:3], rows[3:], None, DT, names, True, derivatives)
    assert isinstance(verdict, Repair), verdict
    assert verdict.positions == names["positions"] and verdict.velocities == derivatives, verdict
    assert "x[5] matches the increments of x[2]" in verdict.reason, verdict.reason   # the worst pair


def test_halves_with_an_offset_and_no_derivative_variables_record_the_positions_alone():
    """Without derivative variables the positions alone are recorded (velocities derived); old code: None."""
    rows, _ = _offset_rows(0.1)
    names = {"positions": ["x[1]", "x[2]", "x[3]"], "velocities": ["x[4]", "x[5]", "x[6]"]}
    verdict = check_rates(rows[:3], rows[3:], None, DT, names, True, [None] * 3)
    assert isinstance(verdict, Repair) and verdict.velocities == "" and verdict.accelerations == "", verdict


def test_halves_with_true_rates_still_pass():
    """A guard: the halves of exact states pass the strict bar (None, as on old code)."""
    rows, _ = _offset_rows(0.0)
    names = {"positions": ["x[1]", "x[2]", "x[3]"], "velocities": ["x[4]", "x[5]", "x[6]"]}
    assert check_rates(rows[:3], rows[3:], None, DT, names, True, [None] * 3) is None


def _wave(steps: int) -> np.ndarray:
    """Exact response of a 200-mass chain pushed at its first mass, ``steps`` samples: a wave runs along it."""
    A, b = _chain(200)
    return _zoh(A, b, steps)


@pytest.mark.parametrize("steps", [60, 100, 200])
def test_wave_front_positions_are_not_taken_for_rates(steps):
    """F2: old code found "q[43] is the rate of q[47]" etc. (mismatch below 0.25) and stopped a right pairing."""
    positions = _wave(steps)[:200]
    assert rates_among_positions(positions, DT, [f"q[{i}]" for i in range(1, 201)]) is None


def test_masses_the_wave_has_not_reached_are_named_not_excited():
    """F2: interleaved generic names split in halves (wrong as intended): the rows that pair with none are masses
    the wave has not reached; old code called them "an actuator lag, a filter or a controller state"."""
    states = _wave(100)
    rows = np.empty_like(states)
    rows[0::2], rows[1::2] = states[:200], states[200:]
    names = [f"n{i}" for i in range(1, 401)]
    verdict = check_rates(rows[:200], rows[200:], None, DT, {"positions": names[:200], "velocities": names[200:]},
                          True, [None] * 200)
    assert isinstance(verdict, str) and "not excited in this recording" in verdict, verdict
    assert "controller" not in verdict and "n2 is the rate of n1" in verdict, verdict


def test_the_stem_label_names_the_pairs_once():
    """F5: the line repeated a 150-character generic rule (q, qdot, qddot; s, v, der(v)) for each role."""
    source = FMUSource.__new__(FMUSource)
    source.selection = types.SimpleNamespace(how={"positions": _LOCAL_STEMS, "velocities": _LOCAL_STEMS,
                                                  "accelerations": _LOCAL_STEMS})
    source.position_names, source.velocity_names, source.acceleration_names = ["p"], ["pdot"], ["pddot"]
    source.input_names, source.held_input_names = ["F"], []
    source.path = types.SimpleNamespace(name="pres.fmu")
    text = source.selection_text()
    assert "paired by name: p / pdot / pddot" in text and text.count("the same rule") == 2, text
    assert "q, qdot, qddot" not in text, text


def test_a_wrong_halves_guess_is_not_repaired_into_near_rates():
    """States listed body by body (``q1, w1, q2 | w2, q3, w3``, ``w = v + 0.1 q``): the halves are wrong, and the
    old code repaired them into the pairs ``(q_i, w_i)`` the data make within 0.25 (0.09 .. 0.12), recording
    near-rates as velocities; no pairing of these rows is a true rate's, so none is recorded."""
    rows, _ = _offset_rows(0.1)
    order = [0, 3, 1, 4, 2, 5]
    labels = ["q1", "w1", "q2", "w2", "q3", "w3"]
    listed = rows[order]
    verdict = check_rates(listed[:3], listed[3:], None, DT, {"positions": labels[:3], "velocities": labels[3:]},
                          True, [None] * 3)
    assert not isinstance(verdict, Repair), verdict
    assert isinstance(verdict, str) and verdict.startswith("cannot tell positions from velocities"), verdict
