"""The second start of the refinement in a background thread (issue 16): same fit as one after the other, and
never left running after an error or Ctrl-C."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from fmu_opinf import inference, newmark, systems
from fmu_opinf._background import Background, Cancelled, checkpoint
from fmu_opinf.basis import PODBasis

DT = 0.1


def _fmu_opinf_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("fmu-opinf") and t.is_alive()]


def _count(limit: int, pause: float = 0.01) -> int:
    for i in range(limit):
        checkpoint(i)
        time.sleep(pause)
    return limit


def test_cancel_stops_the_call_at_its_next_checkpoint():
    call = Background(_count, 10_000, label="counting", total=10_000)  # 100 s if not stopped
    time.sleep(0.2)
    start = time.perf_counter()
    call.cancel()
    assert time.perf_counter() - start < 0.5
    assert not _fmu_opinf_threads()
    assert 0 < call.done < 100
    with pytest.raises(Cancelled):
        call.result()


def test_result_returns_the_value_or_raises_the_error_of_the_call():
    assert Background(_count, 3, pause=0.0).result() == 3

    def broken() -> None:
        raise np.linalg.LinAlgError("singular")

    with pytest.raises(np.linalg.LinAlgError, match="singular"):
        Background(broken).result()


def test_checkpoint_outside_a_background_call_does_nothing():
    checkpoint(5)  # no error, nothing recorded


class _Serial:
    """Stand-in for :class:`Background` that runs the call at once in the calling thread."""

    def __init__(self, function, *args, label="", total=1, **kwargs):
        self.value = function(*args, **kwargs)

    def result(self, progress=False):
        return self.value

    def cancel(self):
        pass


@pytest.fixture(scope="module")
def triple_data():
    run = newmark.simulate(systems.triple_chain(), "impulse:amplitude=100,t0=2,width=0.5", DT, 300.0)
    V = PODBasis(r=16, kind="velocities").fit([run]).basis_  # from SIDE_BY_SIDE_FROM = 15 on in a thread
    return [V.T @ a for a in (run.xddot, run.xdot, run.x)], run.u, run.y


def test_the_threaded_fit_equals_the_fit_one_start_after_the_other(triple_data, monkeypatch):
    data, u, y = triple_data
    threaded = inference.fit_operators(*data, u, y=y, dt=DT, refine_iterations=60)
    monkeypatch.setattr(inference, "Background", _Serial)
    serial = inference.fit_operators(*data, u, y=y, dt=DT, refine_iterations=60)
    assert "refinement" in threaded.info["least_squares_candidate"]  # the second start ran and was refined
    for a, b in zip((threaded.Mr, threaded.Dr, threaded.Kr, threaded.Br), (serial.Mr, serial.Dr, serial.Kr,
                                                                           serial.Br)):
        np.testing.assert_array_equal(a, b)
    assert threaded.info["least_squares_candidate"]["objective"] == serial.info["least_squares_candidate"]["objective"]


@pytest.mark.parametrize("error", [KeyboardInterrupt, ValueError])
def test_an_error_in_the_main_thread_stops_the_second_start(triple_data, monkeypatch, error):
    data, u, y = triple_data
    seen = {}

    def failing_sdp(*args, **kwargs):
        deadline = time.monotonic() + 30
        while not seen and time.monotonic() < deadline:  # until the second start iterates
            seen.update({t.name: t for t in _fmu_opinf_threads()})
            time.sleep(0.05)
        time.sleep(0.2)
        raise error("stop")

    monkeypatch.setattr(inference, "_sdp_operators", failing_sdp)
    start = time.perf_counter()
    with pytest.raises(error):
        inference.fit_operators(*data, u, y=y, dt=DT, refine_iterations=100_000)
    assert seen, "the second start did not run in its own thread"
    assert not _fmu_opinf_threads()
    assert time.perf_counter() - start < 10  # not the 100 000 iterations


@pytest.mark.skipif(os.name != "posix", reason="process-group signals")
def test_ctrl_c_during_fit_is_one_line_and_keeps_the_previous_rom(tmp_path):
    from fmu_opinf.snapshots import record

    from test_security import ctrl_c_after

    record("builtin:triple-chain", "impulse:amplitude=100,t0=2,width=0.5", 0.05, 300.0, tmp_path / "s.h5",
           quiet=True)
    out = tmp_path / "rom.h5"
    out.write_bytes(b"previous")
    # after 3 s: in the SDP solve or the first refinement, the second start running beside it
    returncode, err = ctrl_c_after(["fit", str(tmp_path / "s.h5"), "-o", str(out), "--r", "35", "--force"], 3.0)
    lines = err.strip().splitlines()
    assert returncode == 130 and lines[-1].startswith("fmu-opinf: interrupted"), err
    assert "Traceback" not in err
    assert out.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rom.h5", "s.h5"]


def test_below_side_by_side_from_the_second_start_runs_in_the_main_thread(triple_data, monkeypatch):
    def no_thread(*args, **kwargs):
        raise AssertionError("a thread was started")

    data, u, y = triple_data
    monkeypatch.setattr(inference, "Background", no_thread)
    small = inference.SIDE_BY_SIDE_FROM - 1
    fit = inference.fit_operators(*(a[:small] for a in data), u, y=y, dt=DT, refine_iterations=30)
    assert "refinement" in fit.info["least_squares_candidate"]  # refined all the same, one after the other
