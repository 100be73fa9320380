"""Each training run counts (audit84 F3): runs whose outputs differ thousands of times in size -- the default pulse
of 100 in each input's unit, 100 N beside 100 kN or beside 100 m of support travel -- are weighted by 1 / their
output size in the SDP data and the refinement's objective (:mod:`fmu_opinf.fit._run_balance`).

The reference is the exact zero-order-hold response of the true matrices (``lti_fmus.zoh_response``), each input
driven alone; the training data are the default training's runs (each input pulsed alone) as exact data.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from fmu_opinf import lti_fmus
from fmu_opinf.errors import FmuOpinfWarning
from fmu_opinf.fit import fit_rom
from fmu_opinf.fit._run_balance import RUN_SIZE_FLOOR, run_weights
from fmu_opinf.signals import parse_signal
from fmu_opinf.snapshots import Run
from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

PULSE = "impulse:amplitude=100,t0=2,width=0.5"
DT, T_TRAIN = 0.02, 86.6   # the automatic window audit84 recorded its support chain at
TEST = "harmonic:amplitude=1,omega=0.5"


def _alone(signal: str, j: int, m: int) -> str:
    return ";".join(signal if i == j else "none" for i in range(m))


def _exact_runs(model: lti_fmus.LinearMechanicalModel) -> list[Run]:
    """The default training's runs, each input pulsed alone (100 in its unit), as exact data."""
    runs = []
    t = time_grid(DT, T_TRAIN)
    for j in range(model.m):
        spec = _alone(PULSE, j, model.m)
        u = inputs_in_effect(parse_signal(spec, model.m), t, model.m)
        ref = lti_fmus.zoh_response(model, t, u[:, 1:])
        runs.append(Run(t=ref.t, u=u, x=ref.x, xdot=ref.v, xddot=ref.a, y=ref.y,
                        attrs={"fit_rates": "pointwise", "input_spec": spec, "dt": DT, "t0": 0.0,
                               "t_end": T_TRAIN}))
    return runs


def _misses_alone(rom, model: lti_fmus.LinearMechanicalModel, t_end: float = 100.0) -> np.ndarray:
    """Each input driven alone by the test harmonic: the ROM's largest output error over the output's range
    against the exact model, the worst output."""
    t = time_grid(DT, t_end)
    out = []
    for j in range(model.m):
        spec = _alone(TEST, j, model.m)
        u = inputs_in_effect(parse_signal(spec, model.m), t, model.m)
        reference = lti_fmus.zoh_response(model, t, u[:, 1:]).y
        y = rom.simulate(spec, DT, t_end).y
        out.append(float(np.max(np.abs(y - reference).max(axis=1) / np.ptp(reference, axis=1))))
    return np.array(out)


def _fit(model: lti_fmus.LinearMechanicalModel):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)
        return fit_rom(_exact_runs(model), integrator="exact", quiet=True)


def _forces_and_support(source: str, n: int = 6) -> lti_fmus.LinearMechanicalModel:
    """audit84's model A: :func:`lti_fmus.support_chain_model`'s chain with a force in N on mass 3 (input 1), a
    force in kN on the last mass (input 2: a column of 1000 N per unit) and the support's motion (input 3)."""
    support = lti_fmus.support_chain_model(n, source=source)
    B = np.zeros((n + 1, 3))
    B[2, 0], B[n - 1, 1], B[:, 2] = 1.0, 1000.0, support.B[:, 0]
    return lti_fmus.LinearMechanicalModel(M=support.M, D=support.D, K=support.K, B=B, Cp=support.Cp, Ca=support.Ca,
                                          ideal_sources=1, name="ForcesAndSupport")


@pytest.mark.slow   # three fits' worth of exact responses: about 3 s
def test_a_support_motion_beside_forces_of_other_sizes_is_fitted_as_well_as_they_are():
    """Full order (r = 7, the snapshot rank) on a ``Position`` support with forces in N and kN: the kN run moves
    the outputs 3000 times more than the N run, 75 times more than the support's.  Weighted together, the ROM was
    8.2e-4 of range off the exact model on the support motion alone and 3.8e-5 on the N force alone; each run
    weighted by its size: 2.2e-6 and 1.1e-6 (every input alone)."""
    model = _forces_and_support("position")
    rom = _fit(model)
    assert rom.r == 7
    misses = _misses_alone(rom, model)
    assert misses.max() < 1e-5, misses   # measured 1.1e-6 / 1.2e-6 / 2.2e-6 (before: 3.8e-5 / 3.5e-7 / 8.2e-4)


@pytest.mark.slow   # order search to the snapshot rank, 20 masses: about 7 s
def test_two_forces_in_n_and_kn_are_each_reproduced():
    """A 20-mass chain with a force in N on mass 3 and one in kN on the last mass: the kN run's outputs are 1300
    times the N run's.  Weighted together, the N run was fitted to its share of the other's round-off: the ROM of
    the snapshot rank was 2.7e-9 of range off on the N force alone; each run weighted by its size: 1.0e-11."""
    n = 20
    chain = lti_fmus.chain_model(n, inputs=(2, n - 1), acceleration_outputs=(n - 1,))
    B = chain.B.copy()
    B[:, 1] *= 1000.0
    model = lti_fmus.LinearMechanicalModel(M=chain.M, D=chain.D, K=chain.K, B=B, Cp=chain.Cp, Cv=chain.Cv,
                                           Ca=chain.Ca, name="TwoForces")
    rom = _fit(model)
    assert rom.r == n
    misses = _misses_alone(rom, model)
    assert misses.max() < 5e-11, misses   # measured 1.0e-11 / 1.9e-12 (before: 2.7e-9 / 5.2e-12)


def _runs_of_sizes(sizes: list[float], k: int = 50, p: int = 3) -> tuple[np.ndarray, list[int]]:
    """Outputs of runs side by side, each run the same response times its size."""
    shape = np.sin(np.outer(np.arange(1, p + 1), np.linspace(0.0, 6.0, k))) * np.array([[1.0], [1e3], [1e-2]])
    return np.hstack([size * shape for size in sizes]), [k] * len(sizes)


def _no_terms(p: int, m: int = 1) -> tuple[np.ndarray, ...]:
    return np.zeros((p, 2)), np.zeros((p, 2)), np.zeros((p, m)), np.zeros(p)


def test_runs_that_are_multiples_of_one_response_are_weighted_by_the_multiple():
    """A linear model's runs from rest under pulses of different sizes are one response times the pulse: the
    weights make them equal (the largest run keeps weight one); one run, or a run of round-off, as documented."""
    y, lengths = _runs_of_sizes([2700.0, 1.0, 37.0])
    u = np.zeros((1, y.shape[1]))
    weights = run_weights(y, u, _no_terms(3), lengths, np.arange(3))
    np.testing.assert_allclose(weights, [1.0, 2700.0, 2700.0 / 37.0], rtol=1e-12)
    one, one_length = _runs_of_sizes([5.0])
    assert run_weights(one, np.zeros((1, one.shape[1])), _no_terms(3), one_length, np.arange(3)) is None
    tiny, tiny_lengths = _runs_of_sizes([1.0, 1e-9])
    floored = run_weights(tiny, np.zeros((1, tiny.shape[1])), _no_terms(3), tiny_lengths, np.arange(3))
    np.testing.assert_allclose(floored, [1.0, 1.0 / RUN_SIZE_FLOOR], rtol=1e-12)


def test_the_fitted_offset_and_feedthrough_are_no_part_of_a_runs_size():
    """The size is that of what the refinement compares, ``y - Dur u - y0``: a common offset (an output's static
    value) or a feedthrough does not make a small run look large."""
    y, lengths = _runs_of_sizes([30.0, 1.0])
    u = np.vstack([np.full(lengths[0], 3.0), np.full(lengths[1], -1.0)]).reshape(1, -1)
    Cpr, Cvr, _, _ = _no_terms(3)
    Dur, y0 = np.array([[0.5], [40.0], [0.0]]), np.array([100.0, -7e4, 1.0])
    shifted = y + Dur @ u + y0[:, None]
    weights = run_weights(shifted, u, (Cpr, Cvr, Dur, y0), lengths, np.arange(3))
    np.testing.assert_allclose(weights, [1.0, 30.0], rtol=1e-12)


def test_runs_of_comparable_sizes_are_left_unweighted():
    """Runs within BALANCE_FROM of each other's size each count well above the others' round-off: no weights (a
    preloaded chain's pulse and own-motion runs, 1 : 2.2, kept their exact fit, 5e-13 RMS, where weighting moved it
    to 1.5e-12; test_training_defaults' preloaded ROM FMU within 3e-14 of the exact model)."""
    for sizes in ([1.0, 2.2], [9.0, 1.0, 3.0]):
        y, lengths = _runs_of_sizes(sizes)
        assert run_weights(y, np.zeros((1, y.shape[1])), _no_terms(3), lengths, np.arange(3)) is None, sizes
    y, lengths = _runs_of_sizes([11.0, 1.0])
    np.testing.assert_allclose(run_weights(y, np.zeros((1, y.shape[1])), _no_terms(3), lengths, np.arange(3)),
                               [1.0, 11.0], rtol=1e-12)


@pytest.mark.slow   # builds an FMI 3 FMU and records its default training (about 7 s)
def test_the_default_recording_of_an_fmi3_input_array_gives_a_rom_that_follows_each_input(tmp_path):
    """audit84's model C: the forces and support of :func:`_forces_and_support` as one FMI 3 input array, recorded
    with the defaults (automatic window, one pulse of 100 per element) and fitted with the defaults.  Weighted
    together, the ROM was 6.6e-4 of range off the exact model on the support motion alone and 1.4e-4 on the N force
    alone, without a warning (audit84 measured 7.5e-3 on its recording); each run weighted by its size: 2.1e-6 at
    most."""
    from fmu_opinf.snapshots import record

    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    model = _forces_and_support("position")
    fmu = lti_fmus.build_lti_fmu(model, tmp_path / "C.fmu", fmi_version="3.0", input_array=True,
                                 identifier="MultiInC")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)   # (the support's fast filter: said, and right)
        snaps = record(fmu.path, quiet=True)
        rom = fit_rom(snaps, quiet=True)
    assert len(snaps.runs) == 3 and rom.r == 7
    t_end = 100.0
    t = time_grid(rom.dt, t_end)
    misses = []
    for j in range(3):
        spec = _alone(TEST, j, 3)
        u = inputs_in_effect(parse_signal(spec, 3), t, 3)
        reference = lti_fmus.zoh_response(model, t, u[:, 1:]).y
        y = rom.simulate(spec, rom.dt, t_end).y
        misses.append(float(np.max(np.abs(y - reference).max(axis=1) / np.ptp(reference, axis=1))))
    assert max(misses) < 1e-5, misses   # measured 5.9e-7 / 2.9e-7 / 2.1e-6 (before: 1.4e-4 / 3.0e-7 / 6.6e-4)
