"""Derived accelerations against the true accelerations of Newmark data (recording convention).

The data come from :func:`fmu_opinf.newmark.simulate`, whose ``xddot`` is the integrator's own
acceleration paired with the input in effect; :func:`newmark_accelerations` only sees ``x``,
``xdot`` and ``u``.
"""

from __future__ import annotations

import numpy as np
import pytest

from fmu_opinf import newmark, systems
from fmu_opinf.compare import output_error
from fmu_opinf.fit import fit_rom
from fmu_opinf.snapshots import (Run, Snapshots, newmark_accelerations, newmark_rates,
                                 newmark_velocities_and_accelerations)

IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"


def relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.fixture(scope="module")
def anchored_run():
    return newmark.simulate(systems.anchored_msd(60), IMPULSE, 0.5, 300.0)


@pytest.fixture(scope="module")
def triple_run():
    return newmark.simulate(systems.triple_chain(20), IMPULSE, 0.05, 100.0)


@pytest.mark.parametrize("case", ["anchored_run", "triple_run"])
def test_derived_accelerations_match_the_true_ones(case, request):
    run = request.getfixturevalue(case)
    derived = newmark_accelerations(run.xdot, 0.05 if case == "triple_run" else 0.5, run.x, run.u)
    assert relative(derived, run.xddot) < 1e-6
    # the trapezoid relation alone is wrong at every input change
    assert relative(newmark_rates(run.xdot, run.t[1] - run.t[0]), run.xddot) > 1e-2


@pytest.mark.parametrize("case", ["anchored_run", "triple_run"])
def test_velocities_and_accelerations_from_positions_alone(case, request):
    run = request.getfixturevalue(case)
    v, a = newmark_velocities_and_accelerations(run.x, float(run.t[1] - run.t[0]), run.u)
    assert relative(v, run.xdot) < 1e-9
    assert relative(a, run.xddot) < 1e-6


def test_several_inputs():
    import dataclasses

    import scipy.sparse as sp

    system = systems.triple_chain(10)
    second = sp.csr_matrix(np.eye(system.M.shape[0])[:, [3]])
    two = dataclasses.replace(system, B=sp.hstack([sp.csr_matrix(system.B), second]).tocsr())
    signal = "impulse:amplitude=100,t0=2,width=0.5;step:amplitude=3,t0=4.05"
    run = newmark.simulate(two, signal, 0.05, 40.0)
    assert run.u.shape[0] == 2
    derived = newmark_accelerations(run.xdot, 0.05, run.x, run.u)
    assert relative(derived, run.xddot) < 1e-6


def test_the_jump_matters_only_where_the_input_changes(triple_run):
    """On a constant input the method and the trapezoid relation agree (no jump to account for)."""
    run = newmark.simulate(systems.triple_chain(20), "step:amplitude=1,t0=0", 0.05, 50.0)
    derived = newmark_accelerations(run.xdot, 0.05, run.x, run.u)
    assert relative(derived, run.xddot) < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("name,r,constraint,dt,t_end", [("anchored", 5, "position", 0.5, 300.0),
                                                         ("triple", 35, "velocity", 0.1, 300.0)])
def test_a_fit_from_derived_accelerations_is_as_good(name, r, constraint, dt, t_end):
    """The paper's orders: the fit from derived accelerations is within 2x of the one from the true ones."""
    system = systems.anchored_msd(600) if name == "anchored" else systems.triple_chain(100)
    train = newmark.simulate(system, IMPULSE, dt, t_end)
    test = newmark.simulate(system, "harmonic:amplitude=1,omega=0.2", dt, t_end)
    derived = newmark_accelerations(train.xdot, dt, train.x, train.u)
    errors = []
    for xddot in (train.xddot, derived):
        data = Run(t=train.t, u=train.u, x=train.x, xdot=train.xdot, xddot=xddot, y=train.y)
        rom = fit_rom(Snapshots([data], {"constraint": constraint, "dt": dt}), r=r)
        y = rom.simulate("harmonic:amplitude=1,omega=0.2", dt, t_end).y
        errors.append(float(np.max(output_error(test.y, y))))
    assert errors[1] <= 2 * errors[0] + 1e-12, errors
