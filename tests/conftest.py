"""Shared fixtures: small reference systems and simulations reused across test modules."""

import importlib.util
import os
import sys
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from fmu_opinf import newmark, systems

# A runner started in the background of a non-interactive shell (`cmd &`) inherits SIGINT ignored, which the tool
# respects (nohup semantics); the Ctrl-C tests need it delivered as a terminal delivers it.
import signal as _signal  # noqa: E402

if _signal.getsignal(_signal.SIGINT) is _signal.SIG_IGN:
    _signal.signal(_signal.SIGINT, _signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def one_blas_thread_per_test_process():
    """`pytest -n auto` runs one test process per core; BLAS threads on top of that oversubscribe the cores
    (the suite took 3 min 4 s instead of 2 min 26 s).  Tests of thread counts set their own limits inside."""
    with threadpool_limits(limits=1):
        yield


@pytest.fixture(scope="session")
def anchored():
    """The anchored chain at its default size g = 600 (position constraint)."""
    return systems.anchored_msd()


@pytest.fixture(scope="session")
def triple():
    """The triple chain at its default size n = 301 (velocity constraint)."""
    return systems.triple_chain()


@pytest.fixture
def rng():
    """A generator seeded alike for every test, so that a test's draws do not depend on which tests ran before it
    in the same process (a session-wide generator made the draws differ between runs under pytest-xdist, and a
    finite-difference check failed on one of them)."""
    return np.random.default_rng(20251121)


def spd(rng, r, shift):
    """A random symmetric positive definite ``(r, r)`` matrix with eigenvalues above ``shift``."""
    a = rng.standard_normal((r, r))
    return a @ a.T / r + shift * np.eye(r)


def exact_operator_data(rng, r=6, m=2, k=400):
    """Random ``M, D, K, B`` and snapshots satisfying ``M a + D v + K x = B u`` exactly (random states,
    consistent accelerations): ``(M, D, K, B), (a, v, x, u)``."""
    M, D, K = spd(rng, r, 1.0), spd(rng, r, 0.1), spd(rng, r, 2.0)
    B = rng.standard_normal((r, m))
    x, v, u = rng.standard_normal((r, k)), rng.standard_normal((r, k)), rng.standard_normal((m, k))
    return (M, D, K, B), (np.linalg.solve(M, B @ u - D @ v - K @ x), v, x, u)


def fake_terminal(monkeypatch, *modules):
    """Make stderr a terminal (a ``StringIO`` that says so, returned) and let the ``Progress`` bars of ``modules``
    draw from their first update (no one-second delay), so that a test sees what a user's terminal would."""
    import io

    from fmu_opinf import _progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(_progress.sys, "stderr", terminal)
    for module in modules:
        monkeypatch.setattr(module, "Progress", lambda *args, **kwargs: _progress.Progress(*args, **kwargs,
                                                                                           delay=0.0))
    return terminal


def rewrite_description(src, dst, edit) -> Path:
    """Copy the FMU ``src`` to ``dst`` with its modelDescription.xml passed through ``edit(text) -> text``.

    Written beside ``dst`` and moved into place: FMU sets in pytest's cache are rewritten by every worker of a
    parallel run, and a worker reading one while another wrote it failed ("not a zip archive")."""
    dst = Path(dst)
    partial = dst.with_name(f".{dst.name}.{os.getpid()}.{threading.get_ident()}.partial")
    try:
        with zipfile.ZipFile(src) as zin, zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zout:
            for item in zin.infolist():
                data = zin.read(item.filename)
                if item.filename == "modelDescription.xml":
                    data = edit(data.decode()).encode()
                zout.writestr(item, data)
        os.replace(partial, dst)
    finally:
        partial.unlink(missing_ok=True)
    return dst


def started_fmu2(folder, instance: str = "test", start: float = 0.0):
    """An FMI 2 co-simulation instance of the unzipped FMU in ``folder``, initialized at ``start`` (FMPy), and its
    model description."""
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(folder))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName=instance)
    fmu.instantiate()
    fmu.setupExperiment(startTime=start)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu, md


def relative(a, b):
    """Max-norm difference of a and b relative to the max norm of b."""
    return np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max()


@pytest.fixture(scope="session")
def toys(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The toy FMUs of tests/test_source.py (a fault switch, FMI 2 variants, FMI 3, no binary, another platform)."""
    from test_source import build_toys

    return build_toys(tmp_path_factory.mktemp("toys"))


@pytest.fixture(scope="session")
def anchored_impulse_run(anchored):
    """Anchored chain, impulse-like input, dt = 0.5 to t = 300 (the paper's training shape)."""
    return newmark.simulate(anchored, "impulse:amplitude=100,t0=2,width=0.5", 0.5, 300.0)


@pytest.fixture(scope="session")
def bench():
    """``benchmarks/bench_accuracy.py`` as a module: its independent references (POD-Galerkin from the true
    matrices, plain least squares) and its cached benchmark data."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_accuracy.py"
    spec = importlib.util.spec_from_file_location("bench_accuracy", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass needs the module registered
    spec.loader.exec_module(module)
    return module


def build_fmu_set(request, tmp_path_factory, label: str, build, items) -> dict:
    """``dict(build(item) for item in items)`` for FMUs built once into a folder kept across sessions (pytest's
    cache, like the corpus), two builds at a time; skips without CMake and a C compiler."""
    from concurrent.futures import ThreadPoolExecutor

    from fmu_opinf import lti_fmus

    if lti_fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build FMUs")
    cache = getattr(request.config, "cache", None)
    folder = Path(cache.mkdir(label) if cache is not None else tmp_path_factory.mktemp(label))
    with ThreadPoolExecutor(max_workers=2) as pool:
        return dict(pool.map(lambda item: build(folder, item), items))


@pytest.fixture
def compiled(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The object files that FMU builds had the compiler write (not those taken from the object cache), in order,
    over the whole test."""
    from fmu_opinf import fmus

    written: list[str] = []
    run = fmus._run_side_by_side

    def spy(commands: list[list[str]], what: str) -> None:
        written.extend(Path(command[-1]).name for command in commands if "-c" in command)
        run(commands, what)

    monkeypatch.setattr(fmus, "_run_side_by_side", spy)
    return written


class _NoRecipient:
    def log(self, *message) -> None:  # never reached: the dispatcher finds no living recipient and prints
        pass


@pytest.fixture(autouse=True)
def _fmpy_logger_slot_pointed_at_a_living_logger():
    """After each test, point fmpy's native logger-proxy slot back at the tool's process-long dispatcher
    (:func:`fmu_opinf.sources._cosimulation._fmi2_callbacks`, the mechanism the tool's own sources use).

    ``fmpy.simulate_fmu(logger=...)`` on an FMI 2 FMU leaves that process-wide slot at a ctypes thunk freed when it
    returns, and the next FMU that logs through fmpy's default callbacks (``FMU2Slave`` used directly) jumps into
    freed memory: a held input's refusal tested that way crashed a later test's ``fmi2DeSerializeFMUstate`` in the
    same worker (segmentation fault or illegal instruction)."""
    yield
    if "fmpy.logging" in sys.modules:
        from fmu_opinf.sources._cosimulation import _fmi2_callbacks

        _fmi2_callbacks(_NoRecipient().log)


def miss_against_model(rom, model, spec: str, t_end: float = 60.0) -> float:
    """Largest output error over the output's range of ``rom`` simulated on the input ``spec`` (one input) against
    the exact zero-order-hold response of the linear ``model`` (:func:`fmu_opinf.lti_fmus.zoh_response`), at the
    ROM's step to ``t_end``: the independent reference of the recording tests."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    t = time_grid(rom.dt, t_end)
    u = inputs_in_effect(parse_signal(spec, 1), t, 1)
    reference = lti_fmus.zoh_response(model, t, u[:, 1:]).y
    y = rom.simulate(spec, rom.dt, t_end).y
    return float(np.max(np.abs(y - reference).max(axis=1) / np.ptp(reference, axis=1)))
