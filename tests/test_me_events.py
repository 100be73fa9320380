"""Model exchange through time events and state events, against the exact piecewise solution.

The FMUs (:func:`fmu_opinf.lti_fmus.build_lti_fmu` with a :class:`~fmu_opinf.lti_fmus.TimeEvent` or a
:class:`~fmu_opinf.lti_fmus.StateEvent`) switch a constant force on only in an event iteration, so an
importer that misses the event records the model without it.  The reference integrates the first-order
system exactly (``scipy.linalg.expm`` of the system augmented by its constant forcing), split at the
event; the crossing time of the state event is found on that exact solution with ``scipy.optimize.brentq``.
Neither uses the FMU builder's coordinates nor :func:`~fmu_opinf.lti_fmus.zoh_response`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus, sources  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import ModelExchangeSource  # noqa: E402

from conftest import build_fmu_set  # noqa: E402

pytestmark = pytest.mark.fmu

DT, T_END = 0.1, 4.0
INPUT = "impulse:amplitude=2,t0=0.5,width=0.3"
#: the time event: off the sample grid, on a sample (t[3] = 0.30000000000000004) up to one ulp either side
T_EVENT = 1.2345
T_ON_GRID = 3 * DT
T_EVENTS = {"off-grid": T_EVENT, "ulp-below": math.nextafter(T_ON_GRID, 0.0), "ulp-above":
            math.nextafter(T_ON_GRID, 1.0)}
TIME_FORCE = np.array([0.0, 3.0])
#: the state event: mass 2 (dof 1) passing 0.05 m latches a force on mass 1
STATE = lti_fmus.StateEvent(dof=1, threshold=0.05, force=[2.0, 0.0])


def two_masses() -> lti_fmus.LinearMechanicalModel:
    """Two masses in a chain, the force input on the second, started off rest."""
    M = np.diag([1.0, 2.0])
    K = np.array([[30.0, -10.0], [-10.0, 10.0]])
    return lti_fmus.LinearMechanicalModel(M=M, D=0.05 * K + 0.1 * M, K=K, B=[[0.0], [1.0]], Cp=[[0.0, 1.0]],
                                          x0=[0.1, 0.0], name="TwoMasses")


#: the state event moved by the input: x[1] + u - 1 crosses zero where the impulse's input (2 N) is set
INPUT_STATE = lti_fmus.StateEvent(dof=1, threshold=1.0, force=[2.0, 0.0], input_gain=1.0)
#: the time event also re-initializes the velocities (a Modelica reinit): the states change in the event
JUMP = np.array([0.05, -0.1])
CASES = {("2.0", "time"), ("3.0", "time"), ("2.0", "state"), ("3.0", "state"), ("2.0", "plain"),
         ("2.0", "ulp-below"), ("3.0", "ulp-above"), ("3.0", "input-state"), ("2.0", "jump"), ("3.0", "jump")}


@pytest.fixture(scope="module")
def fmus(request, tmp_path_factory) -> dict:
    def build(folder, case):
        version, kind = case
        events = {}
        if kind == "state":
            events["state_event"] = STATE
        elif kind == "input-state":
            events["state_event"] = INPUT_STATE
        elif kind == "jump":
            events["time_event"] = lti_fmus.TimeEvent(T_EVENT, TIME_FORCE, velocity_jump=JUMP)
        elif kind != "plain":
            at = T_EVENTS["off-grid" if kind == "time" else kind]
            events["time_event"] = lti_fmus.TimeEvent(at, TIME_FORCE)
        path = folder / f"events-{kind}-fmi{version[0]}.fmu"
        return case, lti_fmus.build_lti_fmu(two_masses(), path, fmi_version=version, interfaces=("me", "cs"),
                                            **events).path

    return build_fmu_set(request, tmp_path_factory, "lti-events", build, sorted(CASES))


# ------------------------------------------------------------------------------ exact reference

def _system(model):
    """``z' = A z + b(f)`` of ``z = (x, v)`` for a total force ``f``."""
    n = model.n
    Minv = np.linalg.inv(model.M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ model.K, -Minv @ model.D]])
    return A, lambda force: np.r_[np.zeros(n), Minv @ force]


def _flow(A, b, z, h):
    """Exact ``z(h)`` of ``z' = A z + b`` (b constant): exponential of the augmented matrix."""
    size = A.shape[0]
    augmented = np.zeros((size + 1, size + 1))
    augmented[:size, :size], augmented[:size, size] = A * h, b * h
    E = scipy.linalg.expm(augmented)
    return E[:size, :size] @ z + E[:size, size]


def reference(model, t, u_held, switches=(), jumps=()):
    """Exact samples ``(x, v, a)`` under inputs held over each step (``u_held[:, i]`` on ``[t_i, t_{i+1}]``)
    and constant forces switched on at given times (``switches``: ``(time, force)``, on from that time);
    ``jumps``: ``(time, dv)`` added to the velocities at a time strictly between two samples.
    The acceleration at ``t_i`` pairs with the input of the step that ends there and with every force
    switched on at or before ``t_i``."""
    A, b = _system(model)
    n = model.n
    z = np.r_[model.x0, model.v0]
    states, accelerations = [z], []

    def force(u, time):
        return model.B @ u + model.f0 + sum((f for at, f in switches if at <= time), np.zeros(n))

    accelerations.append((A @ z + b(force(u_held[:, 0], t[0])))[n:])
    for i in range(len(t) - 1):
        u = u_held[:, i]
        cuts = sorted({t[i], t[i + 1], *(at for at, _ in (*switches, *jumps) if t[i] < at < t[i + 1])})
        for start, end in zip(cuts[:-1], cuts[1:]):
            z = _flow(A, b(force(u, start)), z, end - start)
            for at, dv in jumps:
                if at == end and end < t[i + 1]:
                    z = np.r_[z[:n], z[n:] + dv]
        states.append(z)
        accelerations.append((A @ z + b(force(u, t[i + 1])))[n:])
    Z = np.array(states).T
    return Z[:n], Z[n:], np.array(accelerations).T


def first_crossing(model, t, u_held, event: lti_fmus.StateEvent) -> float:
    """First time ``x[dof]`` crosses ``threshold`` on the exact solution without the event: a scan on a grid
    50 times finer than the samples, then brentq on the exact flow."""
    A, b = _system(model)
    z = np.r_[model.x0, model.v0]
    for i in range(len(t) - 1):
        forcing = b(model.B @ u_held[:, i] + model.f0)

        def gap(s, z=z, forcing=forcing):
            return _flow(A, forcing, z, s)[event.dof] - event.threshold

        h = t[i + 1] - t[i]
        fine = np.linspace(0.0, h, 51)
        values = [gap(s) for s in fine]
        for k in range(50):
            if (values[k] > 0) != (values[k + 1] > 0):
                return t[i] + scipy.optimize.brentq(gap, fine[k], fine[k + 1], xtol=1e-15, rtol=1e-15)
        z = _flow(A, forcing, z, h)
    raise AssertionError("the reference never crosses the threshold: choose another StateEvent")


def held_inputs(run) -> np.ndarray:
    """``run.u[:, i+1]`` is the input held over ``[t_i, t_{i+1}]``."""
    return np.hstack([run.u[:, 1:], run.u[:, -1:]])


def errors(run, x, v, a) -> dict[str, float]:
    return {key: float(np.abs(got - want).max() / np.abs(want).max())
            for key, got, want in (("x", run.x, x), ("v", run.xdot, v), ("a", run.xddot, a))}


def spy(monkeypatch, name: str, seen) -> None:
    """Call ``seen(args, result)`` after every call of ``ModelExchangeSource.<name>``.  A method the class
    lacks (the importer before event handling) is never called, so ``seen`` never is either."""
    original = getattr(ModelExchangeSource, name, None)
    if original is None:
        return

    def wrapper(self, *args):
        result = original(self, *args)
        seen(args, result)
        return result

    monkeypatch.setattr(ModelExchangeSource, name, wrapper)


def record_me(path):
    source = ModelExchangeSource(path)
    return record(source, INPUT, DT, T_END, quiet=True).runs[0], source


# ------------------------------------------------------------------------------ time events

@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_a_time_event_is_met_exactly(fmus, version):
    run, source = record_me(fmus[(version, "time")])
    model = two_masses()
    x, v, a = reference(model, run.t, held_inputs(run), [(T_EVENT, TIME_FORCE)])
    found = errors(run, x, v, a)
    # measured (FMI 2 and 3 alike): x 4.3e-12, v 2.7e-11, a 3.5e-11; against the model without the event 0.48 to 8
    assert max(found.values()) < 1e-10, found
    assert source._t_next == math.inf   # the event is past: no time event announced any more
    without = reference(model, run.t, held_inputs(run))
    assert max(errors(run, *without).values()) > 0.1   # the event matters


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_states_changed_in_an_event_are_read_again(fmus, version):
    """A reinit of the velocities at the time event: the integration must go on from the FMU's new states."""
    run, _ = record_me(fmus[(version, "jump")])
    model = two_masses()
    x, v, a = reference(model, run.t, held_inputs(run), [(T_EVENT, TIME_FORCE)], [(T_EVENT, JUMP)])
    found = errors(run, x, v, a)
    assert max(found.values()) < 1e-10, found   # measured (FMI 2 and 3): x 4.3e-12, v 2.6e-11, a 3.5e-11
    without = reference(model, run.t, held_inputs(run), [(T_EVENT, TIME_FORCE)])
    assert max(errors(run, *without).values()) > 0.1   # the jump matters (0.16)


@pytest.mark.parametrize("case", [("2.0", "ulp-below"), ("3.0", "ulp-above")])
def test_a_time_event_on_a_sample_up_to_rounding_is_taken_at_the_sample(fmus, case, monkeypatch):
    """No sliver of integration between the sample and the event, and the sample holds the values after it."""
    pieces = []
    spy(monkeypatch, "_piece", lambda args, result: pieces.append(args[2] - args[1]))
    run, _ = record_me(fmus[case])
    assert run.t[3] == 3 * DT and abs(T_EVENTS[case[1]] - run.t[3]) <= math.ulp(run.t[3])
    x, v, a = reference(two_masses(), run.t, held_inputs(run), [(run.t[3], TIME_FORCE)])
    found = errors(run, x, v, a)
    assert max(found.values()) < 1.5e-10, found   # measured 5.5e-11 (a), both cases
    # the acceleration recorded at the event's sample includes the new force (0.5 of the 2 kg mass is 1.5)
    before = reference(two_masses(), run.t[:4], held_inputs(run)[:, :4])[2][:, 3]
    assert abs(run.xddot[1, 3] - before[1] - 1.5) < 1e-9
    assert min(pieces) > 0.5 * DT   # every integration is a whole step: the event did not split one


# ------------------------------------------------------------------------------ state events

@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_a_state_event_is_located_and_handled(fmus, version, monkeypatch):
    located = []
    spy(monkeypatch, "_locate_crossing", lambda args, result: located.append(result))
    run, source = record_me(fmus[(version, "state")])
    model = two_masses()
    t_cross = first_crossing(model, run.t, held_inputs(run), STATE)
    x, v, a = reference(model, run.t, held_inputs(run), [(t_cross, np.asarray(STATE.force))])
    found = errors(run, x, v, a)
    # measured (FMI 2 and 3 alike): x 2.4e-11, v 5.6e-11, a 3.3e-11; against the model without the event 0.5 to 1.9
    assert max(found.values()) < 1.5e-10, found
    without = reference(model, run.t, held_inputs(run))
    assert max(errors(run, *without).values()) > 0.1
    assert source.nz == 1
    # measured 1.6e-11 s: the integrator's position error (about 5e-13 m) over the speed there (0.03 m/s); the
    # search itself brackets the crossing of the integrated solution to 1e-13 s
    assert located and abs(located[0] - t_cross) < 5e-11, (located, t_cross)


def test_an_indicator_moved_across_zero_by_the_input_set_at_a_communication_point_is_an_event_there(fmus,
                                                                                                 monkeypatch):
    located = []
    spy(monkeypatch, "_locate_crossing", lambda args, result: located.append(result))
    run, _ = record_me(fmus[("3.0", "input-state")])
    u = held_inputs(run)
    on = int(np.flatnonzero(u[0] >= 1.0)[0])   # 2 N set at t[on] (0.5 N the step before: x[1] + 0.5 - 1 < 0)
    # the force is on from t[on] for the integration; the sample at t[on] was read before the input was set
    switch = math.nextafter(run.t[on], math.inf)
    x, v, a = reference(two_masses(), run.t, u, [(switch, np.asarray(INPUT_STATE.force))])
    found = errors(run, x, v, a)
    assert max(found.values()) < 1e-10, found   # measured (FMI 3) x 2.0e-11, v 4.0e-11, a 4.2e-11
    without = reference(two_masses(), run.t, u)
    assert max(errors(run, *without).values()) > 0.1
    assert located == []   # handled where the input was set, not found by a search inside the next step


@pytest.mark.slow
def test_a_crossing_is_located_with_scipys_integrators_too(fmus):
    source = ModelExchangeSource(fmus[("2.0", "state")], method="radau", tolerance=1e-11)
    run = record(source, INPUT, DT, T_END, quiet=True).runs[0]
    model = two_masses()
    t_cross = first_crossing(model, run.t, held_inputs(run), STATE)
    x, v, a = reference(model, run.t, held_inputs(run), [(t_cross, np.asarray(STATE.force))])
    found = errors(run, x, v, a)
    # measured 3.2e-13 (v); 4.3e-14 with another sequence of trial points (Radau restarts at each)
    assert max(found.values()) < 1e-12, found


# ------------------------------------------------------------------------------ no events, no cost

@pytest.fixture
def events_unsaid(monkeypatch):
    """The events of every FMU not yet reported in this process (they are said once per FMU and process)."""
    from fmu_opinf import sources

    monkeypatch.setattr(sources, "_REPORTED", set())


@pytest.mark.parametrize("isolate", [False, True], ids=["in-process", "isolated"])
@pytest.mark.slow  # 10 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_the_events_of_a_run_are_counted_stored_and_said_once(fmus, isolate, events_unsaid):
    """A linear ROM cannot follow a model that switches: the recording says when it had events (the count came
    from the isolated child too) and stores them per run; the time is the exact solution's crossing."""
    from fmu_opinf.errors import FmuOpinfWarning

    source = ModelExchangeSource(fmus[("3.0", "state")])
    with pytest.warns(FmuOpinfWarning, match=r"had 1 event\(s\) during the run .* first at t=(\S+)\)") as seen:
        snaps = record(source, INPUT, DT, T_END, quiet=True, isolate=isolate)
        record(ModelExchangeSource(fmus[("3.0", "state")]), INPUT, DT, T_END, quiet=True,
               isolate=isolate)   # said once per FMU, not per run (a row of --runs opens a source of its own)
    run = snaps.runs[0]
    t_cross = first_crossing(two_masses(), run.t, held_inputs(run), STATE)
    assert run.attrs["events"] == 1 and abs(run.attrs["first_event_t"] - t_cross) < 5e-11
    assert len([w for w in seen if "event(s)" in str(w.message)]) == 1
    timed = record(ModelExchangeSource(fmus[("2.0", "time")]), INPUT, DT, T_END, quiet=True, isolate=isolate)
    assert timed.runs[0].attrs["events"] == 1 and timed.runs[0].attrs["first_event_t"] == T_EVENT


@pytest.mark.slow  # 11 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_the_recording_summary_counts_each_run_s_events(fmus, tmp_path, events_unsaid):
    from fmu_opinf.snapshots import Snapshots, record_to_file

    with pytest.warns(UserWarning, match="event"):
        summary = record_to_file(ModelExchangeSource(fmus[("2.0", "time")]), tmp_path / "s.h5", [INPUT, "none"],
                                 dt=DT, t_end=T_END, quiet=True)
    assert summary.events == [1, 1] and summary.describe().count(", 1 event(s)") == 2
    assert [r.attrs["events"] for r in Snapshots.load(tmp_path / "s.h5").runs] == [1, 1]


def test_a_run_without_events_says_nothing_and_co_simulation_stores_no_count(fmus, recwarn, events_unsaid):
    plain = record(ModelExchangeSource(fmus[("2.0", "plain")]), INPUT, DT, T_END, quiet=True).runs[0]
    assert plain.attrs["events"] == 0 and "first_event_t" not in plain.attrs
    from fmu_opinf.sources import FMUSource

    cosim = record(FMUSource(fmus[("2.0", "state")]), INPUT, DT, T_END, quiet=True).runs[0]
    assert "events" not in cosim.attrs   # a co-simulation FMU handles its events unseen: no count is not zero
    assert not [w for w in recwarn if "event(s)" in str(w.message)]


@pytest.mark.parametrize("isolate", [False, True], ids=["in-process", "isolated"])
def test_crossings_that_change_nothing_are_counted_apart(fmus, isolate, events_unsaid):
    """The state event latches its force at the first crossing; the later crossings change nothing (same states,
    derivatives and outputs), which a linear ROM follows exactly: they are counted apart (``inert_events``), and
    the warning counts only the first.  The crossings are those of the exact solution on the samples."""
    from fmu_opinf.errors import FmuOpinfWarning

    with pytest.warns(FmuOpinfWarning, match=r"had 1 event\(s\) during the run"):
        run = record(ModelExchangeSource(fmus[("2.0", "state")]), "harmonic:amplitude=3,omega=3", DT, T_END,
                     quiet=True, isolate=isolate).runs[0]
    model, held = two_masses(), held_inputs(run)
    t_cross = first_crossing(model, run.t, held, STATE)
    x, _, _ = reference(model, run.t, held, switches=[(t_cross, np.asarray(STATE.force))])
    crossings = int(np.sum(np.diff(np.sign(x[STATE.dof] - STATE.threshold)) != 0))
    assert crossings == 3 and run.attrs["events"] == 1 and run.attrs["inert_events"] == crossings - 1


def test_events_that_change_nothing_are_not_warned_about(fmus, recwarn, events_unsaid):
    """The recorder, given a run whose events all changed nothing: it stores their count and says nothing."""
    from fmu_opinf.sources import EventCount

    source = ModelExchangeSource(fmus[("2.0", "state")])
    source.events_seen = lambda: EventCount(0, None, 4)   # what the recorder stores and says, given inert events
    run = record(source, INPUT, DT, T_END, quiet=True).runs[0]
    assert run.attrs["events"] == 0 and run.attrs["inert_events"] == 4
    assert not [w for w in recwarn if "event(s)" in str(w.message)]


@pytest.mark.slow
def test_the_events_are_kept_with_each_recording_and_repeated_by_fit_compare_and_export(fmus, tmp_path,
                                                                                         events_unsaid):
    """Audit 72 F5: the event warning lived on ``snapshots``' stderr only, and compare reported a 22 % error with no
    word on why.  Every file keeps it (also the second recording of the process, where it is not said again), and
    fit, compare and export repeat it."""
    from fmu_opinf import compare
    from fmu_opinf.errors import FmuOpinfWarning
    from fmu_opinf.export import _warn_if_recording_warned
    from fmu_opinf.fit import fit_rom
    from fmu_opinf.snapshots import Snapshots, record_to_file

    path = fmus[("2.0", "time")]
    with pytest.warns(FmuOpinfWarning, match=r"had 1 event\(s\)"):
        record_to_file(ModelExchangeSource(path), tmp_path / "a.h5", INPUT, dt=DT, t_end=T_END, quiet=True)
    record_to_file(ModelExchangeSource(path), tmp_path / "b.h5", "none", dt=DT, t_end=T_END, quiet=True)
    for name in ("a.h5", "b.h5"):
        attrs = Snapshots.load(tmp_path / name).attrs
        assert list(attrs["recording_verdicts"]) == ["internal-events"]
        assert f"(the first at t={T_EVENT:g})" in attrs["recording_warnings"][0]
    said = r"recorded with this warning: events-time-fmi2\.fmu: had 1 event\(s\)"
    with pytest.warns(FmuOpinfWarning, match=said):
        rom = fit_rom(Snapshots.load(tmp_path / "a.h5"), r=2, quiet=True, refine=False)
    with pytest.warns(FmuOpinfWarning, match=said) as seen:
        compare.compare(rom, path, INPUT, t_end=T_END, quiet=True)
    assert not [w for w in seen if "shares what the recording followed" in str(w.message)]
    with pytest.warns(FmuOpinfWarning, match=said):
        assert _warn_if_recording_warned(dict(rom.provenance))


def test_an_fmu_without_events_never_asks_for_event_indicators(fmus, monkeypatch):
    calls = {"_integrate_with_events": 0, "_read_indicators": 0}
    for name in calls:
        spy(monkeypatch, name, lambda args, result, name=name: calls.__setitem__(name, calls[name] + 1))
    run, source = record_me(fmus[("2.0", "plain")])
    assert source.nz == 0 and source._t_next == math.inf
    assert calls == {"_integrate_with_events": 0, "_read_indicators": 0}
    x, v, a = reference(two_masses(), run.t, held_inputs(run))
    assert max(errors(run, x, v, a).values()) < 1e-10   # measured 4.8e-11 (v)
    # the spies do count: the FMU with an event indicator goes through them at every step
    record_me(fmus[("2.0", "state")])
    assert calls["_integrate_with_events"] == len(run.t) - 1 and calls["_read_indicators"] >= len(run.t) - 1


# ------------------------------------------------------------------------------ co-simulation of the same FMUs

def test_cosimulation_meets_the_time_event_and_sees_the_state_event_at_the_next_communication_point(fmus):
    from fmu_opinf.sources import FMUSource

    model = two_masses()
    run = record(FMUSource(fmus[("3.0", "time")], tolerance=1e-12), INPUT, DT, T_END, quiet=True).runs[0]
    x, v, a = reference(model, run.t, held_inputs(run), [(T_EVENT, TIME_FORCE)])
    found = errors(run, x, v, a)
    assert max(found.values()) < 4e-14, found   # the doStep is split at the event; measured 1.3e-14 (a)
    run = record(FMUSource(fmus[("2.0", "state")], tolerance=1e-12), INPUT, DT, T_END, quiet=True).runs[0]
    t_cross = first_crossing(model, run.t, held_inputs(run), STATE)
    after = run.t[np.searchsorted(run.t, t_cross)]   # the communication point after the crossing
    x, v, a = reference(model, run.t, held_inputs(run), [(after, np.asarray(STATE.force))])
    found = errors(run, x, v, a)
    assert max(found.values()) < 4e-14, found   # measured 7.8e-15 (v)


def test_invalid_events_are_refused_in_one_line(tmp_path):
    from fmu_opinf.errors import DimensionError

    model = two_masses()
    with pytest.raises(DimensionError, match="give 2 finite values"):
        lti_fmus.build_lti_fmu(model, tmp_path / "a.fmu", time_event=lti_fmus.TimeEvent(1.0, [1.0]))
    with pytest.raises(DimensionError, match="velocity_jump of TimeEvent has shape"):
        lti_fmus.build_lti_fmu(model, tmp_path / "d.fmu", time_event=lti_fmus.TimeEvent(1.0, [0.0, 1.0], [1.0]))
    with pytest.raises(lti_fmus.FmuBuildError, match=r"dof in \[0, 1\]"):
        lti_fmus.build_lti_fmu(model, tmp_path / "b.fmu", state_event=lti_fmus.StateEvent(2, 0.0, [0.0, 1.0]))
    with pytest.raises(lti_fmus.FmuBuildError, match="need a fixed size"):
        lti_fmus.build_lti_fmu(lti_fmus.MassChain(n=2), tmp_path / "c.fmu", fmi_version="3.0", naming="array",
                               time_event=lti_fmus.TimeEvent(1.0, [0.0, 1.0]))
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------ the crossing search alone

class _LinearIndicator:
    """Stand-in for a source in :meth:`ModelExchangeSource._locate_crossing`: one indicator ``g(t) = t - c``
    (no state), each trial integration counted and capped."""

    nz, nx, _comp = 1, 0, None

    def __init__(self, a: float, b: float, c: float) -> None:
        self.c, self.trials = c, 0
        self._z, self._z_end = np.array([a - c]), np.array([b - c])
        self._x, self._h_last = np.zeros(0), 0.01

    def _piece(self, i, t0, t1):
        self.trials += 1
        assert self.trials <= 250, "the search does not end"

    def _read_indicators(self, i, t, out):
        out[0] = t - self.c

    def _c_time(self, comp, t):
        pass


def test_the_crossing_search_ends_and_brackets_the_crossing_to_its_tolerance():
    """Random brackets of a linear indicator, including a crossing at the interval's start (g = 0 there) and
    brackets within rounding of the tolerance: before the fix 114 of 20 000 such searches never ended, and a
    crossing at the start took 40 bisections."""
    rng = np.random.default_rng(7)
    worst = 0
    for k in range(5000):
        a = float(rng.uniform(0.0, 10.0))
        b = a + 0.1
        c = a if k % 10 == 0 else a + (b - a) * float(rng.random())
        fake = _LinearIndicator(a, b, c)
        found = ModelExchangeSource._locate_crossing(fake, 0, a, b, np.zeros(0))
        tolerance = 1e-12 * (b - a) + 4 * math.ulp(b)
        assert c <= found <= c + tolerance + 2 * math.ulp(b), (a, b, c, found)
        worst = max(worst, fake.trials)
    assert worst <= 4   # measured 3: the secant of a straight line is exact, then one trial to close the bracket


# ------------------------------------------------------------------------------ failures and cost in event mode

def test_an_fmu_asking_to_terminate_in_an_event_iteration_is_a_one_line_step_error(fmus, monkeypatch):
    from fmu_opinf.sources._base import StepError

    original = ModelExchangeSource._after_initialization

    def terminating(self):
        original(self)
        if self.fmi_version.startswith("2"):
            self._fmu.newDiscreteStates = lambda: (False, True, False, False, False, 0.0)

    monkeypatch.setattr(ModelExchangeSource, "_after_initialization", terminating)
    with pytest.raises(StepError, match=r"asked to terminate the simulation in its event iteration at t=1\.1\S*; "
                                        r"end the run before it: --t-end or t_end= below 1\.1"):
        record(ModelExchangeSource(fmus[("2.0", "state")]), INPUT, DT, T_END, quiet=True)


def test_indicators_are_checked_at_a_communication_point_only_where_inputs_were_set(fmus, monkeypatch):
    """An indicator can jump at a communication point only through the inputs set there; where none changed, the
    previous interval's end values stand (before, every step set states and time again and read them: +11 us)."""
    checks = []
    spy(monkeypatch, "_indicators_at", lambda args, result: checks.append(args[1]))
    run, _ = record_me(fmus[("2.0", "state")])
    changes = int(np.count_nonzero(np.any(np.diff(run.u, axis=1) != 0, axis=0)))
    assert 0 < len(checks) <= changes < len(run.t) // 4


def test_indicators_that_cannot_be_read_are_a_warning_and_the_run_records_without_them(fmus, monkeypatch):
    """An export that declares more indicators than it returns (the FMU refuses the call): one warning, then the
    recording of the plain path (before 2026-11-27 every recording of such an FMU ignored its indicators)."""
    from fmu_opinf.errors import FmuOpinfWarning

    monkeypatch.setattr(ModelExchangeSource, "_indicator_count", lambda self: 2)  # the FMU has 1
    monkeypatch.setattr(sources, "_REPORTED", set())
    with pytest.warns(FmuOpinfWarning, match="reading its 2 event indicators failed"):
        run, source = record_me(fmus[("2.0", "state")])
    assert source.nz == 0
    x, v, a = reference(two_masses(), run.t, held_inputs(run))  # the latched force never comes on
    assert max(errors(run, x, v, a).values()) < 1e-10   # measured 4.8e-11 (v)


def test_a_warning_of_an_isolated_run_reaches_the_caller(fmus, tmp_path, monkeypatch):
    """The command line records in a child process; its warnings are issued again in the caller (one line there,
    and caught like any other): before, the child printed them itself, with a source line."""
    from conftest import rewrite_description
    from fmu_opinf.errors import FmuOpinfWarning

    declared_two = rewrite_description(fmus[("2.0", "state")], tmp_path / "two.fmu",
                                       lambda text: text.replace('numberOfEventIndicators="1"',
                                                                 'numberOfEventIndicators="2"'))
    monkeypatch.setattr(sources, "_REPORTED", set())
    with pytest.warns(FmuOpinfWarning, match="reading its 2 event indicators failed"):
        run = record(ModelExchangeSource(declared_two), INPUT, DT, T_END, quiet=True, isolate=True).runs[0]
    x, v, a = reference(two_masses(), run.t, held_inputs(run))
    assert max(errors(run, x, v, a).values()) < 1e-10   # measured 4.8e-11 (v)


@pytest.mark.slow
def test_what_every_isolated_run_finds_is_said_once(fmus, tmp_path, monkeypatch):
    """Each run of ``compare`` or a run table opens the FMU in its own child, which finds the same defect again:
    the user hears it once (eighth audit: compare printed the indicator warning twice)."""
    import warnings

    from conftest import rewrite_description

    declared_two = rewrite_description(fmus[("2.0", "state")], tmp_path / "two.fmu",
                                       lambda text: text.replace('numberOfEventIndicators="1"',
                                                                 'numberOfEventIndicators="2"'))
    monkeypatch.setattr(sources, "_REPORTED", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for isolate in (True, True, False, False):   # and in this process, instance after instance
            record(ModelExchangeSource(declared_two), INPUT, DT, T_END, quiet=True, isolate=isolate)
    said = [w for w in caught if "event indicators failed" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in said]
