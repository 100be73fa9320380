"""Audit86 F6: fit's line on the learned poles counted the real poles of an overdamped pair "in the upper half plane",
each as a mode whose natural frequency is its magnitude and whose damping ratio is 1.

A stiff model's ROM (r = 3, a light mass on a 1e4 rad/s spring) printed "4 in the upper half plane, natural
frequencies 0.618 .. 2.04e+03 rad/s, damping ratios 0.00794 .. 1": two oscillating poles and two real ones, at -1.5
and -2.0e3 1/s.  The reference here: the roots of each decoupled mode's ``s^2 + d s + k`` (numpy.roots).
"""

from __future__ import annotations

import numpy as np

from fmu_opinf.cli import _pole_summary
from fmu_opinf.inference import _pole_info


def test_real_poles_are_said_by_their_decay_rates_not_as_modes():
    M, D, K = np.eye(2), np.diag([0.4, 10.0]), np.diag([4.0, 1.0])   # zeta 0.1 at 2 rad/s; overdamped
    slow, fast = sorted(-np.roots([1.0, 10.0, 1.0]).real)
    line = _pole_summary(_pole_info(M, D, K)["poles"])
    assert line.startswith("learned poles: 1 in the upper half plane, natural frequencies 2 .. 2 rad/s, damping "
                           "ratios 0.1 .. 0.1; "), line
    assert f"; 2 real pole(s) (overdamped), decay rates {slow:.3g} .. {fast:.3g} 1/s (fit_info['poles'])" in line


def test_a_rom_with_real_poles_only_says_none_oscillate():
    line = _pole_summary(_pole_info(np.eye(1), np.array([[10.0]]), np.array([[1.0]]))["poles"])
    assert line.startswith("learned poles: none in the upper half plane; 2 real pole(s) (overdamped)"), line
