"""Model-exchange recording, interface choice and tolerances, against exact zero-order-hold solutions.

The reference is :func:`fmu_opinf.lti_fmus.zoh_response` (matrix exponential of the minimal
coordinates, independent of the FMU and of the integrator).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.cli import main  # noqa: E402
from fmu_opinf.errors import FmuOpinfError, InputSpecError  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import (DEFAULT_TOLERANCE, FMUSource, ModelExchangeSource, StepError,  # noqa: E402
                               choose_interface, open_source)

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None and not Path("/tmp/corpus/me-only.fmu").is_file():
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

NAMES = ("me-only", "start-off-rest", "offset-equilibrium", "fmi3-array-structural", "no-inputs",
         "cs-euler", "parameters-as-inputs", "modelica-der-aliases")


@pytest.fixture(scope="module")
def corpus(request, tmp_path_factory) -> dict[str, Path]:
    """Corpus FMUs: built once into pytest's cache (GUID-checked, so a changed builder rebuilds them)."""
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    built = lti_fmus.build_corpus(folder, NAMES)
    return {name: fmu.path for name, fmu in built.items()}


def model_of(name: str) -> lti_fmus.LinearMechanicalModel:
    model = lti_fmus.corpus_models()[name][0]
    return model.model() if isinstance(model, lti_fmus.MassChain) else model


class Levels:
    """A piecewise-constant input: random levels, each held for ``hold`` steps of ``dt``."""

    spec = "levels"

    def __init__(self, m: int, dt: float, hold: int = 5, seed: int = 1) -> None:
        self.m, self.dt, self.hold = m, dt, hold
        self.levels = np.random.default_rng(seed).normal(size=(m, 10_000))

    def sample(self, t) -> np.ndarray:
        index = np.floor(np.asarray(t) / (self.dt * self.hold) + 1e-9).astype(int)
        return self.levels[:, index]


def exact(name: str, run) -> lti_fmus.ZohResponse:
    """The exact response to the run's inputs: ``run.u[:, i+1]`` is held over ``[t_i, t_{i+1}]``."""
    model = model_of(name)
    held = np.hstack([run.u[:, 1:], run.u[:, -1:]]) if model.m else None
    return lti_fmus.zoh_response(model, run.t, held)


def relative_errors(run, ref) -> dict[str, float]:
    pairs = {"x": (run.x, ref.x), "xdot": (run.xdot, ref.v), "xddot": (run.xddot, ref.a), "y": (run.y, ref.y)}
    out = {}
    for key, (a, b) in pairs.items():
        out[key] = float(np.abs(np.asarray(a) - b).max() / max(np.abs(b).max(), 1e-300))
    return out


# ----------------------------------------------------------------------------- accuracy

@pytest.mark.parametrize("name", ["me-only", "start-off-rest", "offset-equilibrium", "fmi3-array-structural"])
def test_model_exchange_recording_matches_the_exact_zoh_solution(corpus, name):
    source = open_source(corpus[name])
    assert isinstance(source, ModelExchangeSource)  # auto prefers model exchange
    dt = 0.05
    run = record(source, Levels(source.m, dt), dt, 8.0, quiet=True).runs[0]
    errors = relative_errors(run, exact(name, run))
    assert max(errors.values()) < 1e-8, errors
    assert run.attrs["fmi_interface"] == "me"
    assert run.attrs["tolerance"] == DEFAULT_TOLERANCE
    assert "DOP853" in run.attrs["integrator"]


def test_free_response_through_model_exchange(corpus):
    run = record(open_source(corpus["no-inputs"]), "none", 0.1, 10.0, quiet=True).runs[0]
    errors = relative_errors(run, exact("no-inputs", run))
    assert max(errors.values()) < 1e-8, errors


@pytest.mark.parametrize("method", ["lsoda", "radau"])
@pytest.mark.slow
def test_other_integrators_follow_the_tolerance(corpus, method):
    source = open_source(corpus["start-off-rest"], method=method, tolerance=1e-11)
    run = record(source, Levels(1, 0.1), 0.1, 4.0, quiet=True).runs[0]
    assert max(relative_errors(run, exact("start-off-rest", run)).values()) < 1e-7
    assert method.upper()[:4] in run.attrs["integrator"].upper()


def test_accelerations_pair_with_the_input_held_over_the_step_that_ends_there(corpus):
    """At an input jump, the recorded acceleration is der(v) under the previous input (design.md)."""
    dt = 0.05
    run = record(open_source(corpus["me-only"]), Levels(1, dt, hold=1), dt, 1.0, quiet=True).runs[0]
    model = model_of("me-only")
    held = np.hstack([run.u[:, 1:], run.u[:, -1:]])
    current = lti_fmus.zoh_response(model, run.t, held, accelerations_from="current")
    previous = lti_fmus.zoh_response(model, run.t, held, accelerations_from="previous")
    assert np.abs(run.xddot - previous.a).max() < 1e-8 * np.abs(previous.a).max()
    assert np.abs(run.xddot - current.a).max() > 1e-3 * np.abs(current.a).max()


# ----------------------------------------------------------------------- interface choice

def test_auto_prefers_model_exchange_and_falls_back_to_cosimulation(corpus):
    assert choose_interface(corpus["start-off-rest"]) == "me"
    assert choose_interface(corpus["me-only"], "auto") == "me"
    assert choose_interface(corpus["cs-euler"]) == "cs"
    assert choose_interface(corpus["start-off-rest"], "cs") == "cs"
    assert type(open_source(corpus["cs-euler"])) is FMUSource
    assert type(open_source(corpus["start-off-rest"], interface="cs")) is FMUSource
    with pytest.raises(InputSpecError, match="--interface"):
        choose_interface(corpus["me-only"], "both")


def test_an_interface_the_fmu_lacks_is_a_one_line_error(corpus):
    with pytest.raises(FmuOpinfError, match="offers no co-simulation.*--interface me") as info:
        open_source(corpus["me-only"], interface="cs")
    assert "\n" not in str(info.value)
    with pytest.raises(FmuOpinfError, match="offers no model exchange.*--interface cs"):
        open_source(corpus["cs-euler"], interface="me")


def test_tolerance_is_checked():
    with pytest.raises(InputSpecError, match="tolerance"):
        open_source("/tmp/does-not-matter.fmu", tolerance=2.0, interface="cs")


# ------------------------------------------------------------------------ co-simulation

def test_cosimulation_error_follows_the_tolerance_passed_to_the_fmu(corpus):
    """The accurate CS FMU's internal solver follows the tolerance that fmu-opinf now passes."""
    errors = {}
    for tolerance in (1e-3, 1e-9):
        source = open_source(corpus["start-off-rest"], interface="cs", tolerance=tolerance)
        run = record(source, Levels(1, 0.1), 0.1, 6.0, quiet=True).runs[0]
        errors[tolerance] = relative_errors(run, exact("start-off-rest", run))["x"]
        assert run.attrs["fmi_interface"] == "cs" and run.attrs["tolerance"] == tolerance
    assert errors[1e-9] < 1e-7
    assert errors[1e-3] > 100 * errors[1e-9], errors


# --------------------------------------------------------------------------------- errors

def zero_mass_table(source, folder: Path) -> Path:
    """Inputs holding every scale at 1, then ``mass_scale = 0`` from t = 0.15 (a division by zero)."""
    names = source.input_names
    rows = [[0.0] + [0.0 if n == "F" else 1.0 for n in names], [0.15] + [0.0 if n != "stiffness_scale" else 1.0
                                                                        for n in names]]
    rows.append([1.0] + rows[-1][1:])
    path = folder / "zero-mass.csv"
    path.write_text("\n".join([",".join(["time"] + names)] + [",".join(map(str, r)) for r in rows]) + "\n")
    return path


def test_integration_failure_is_a_one_line_step_error(corpus, tmp_path):
    """mass_scale driven to 0 divides by zero inside the derivatives: the integration must stop cleanly."""
    source = open_source(corpus["parameters-as-inputs"], inputs="F,mass_scale,stiffness_scale")
    assert source.interface == "me" and source.m == 3
    with pytest.raises(StepError, match="model-exchange integration.*failed at step 3 ") as info:
        record(source, str(zero_mass_table(source, tmp_path)), 0.1, 1.0, quiet=True)
    assert "\n" not in str(info.value)


def test_cli_reports_an_integration_failure_in_one_line(corpus, tmp_path, capsys):
    table = zero_mass_table(open_source(corpus["parameters-as-inputs"], inputs="F,mass_scale,stiffness_scale"),
                            tmp_path)
    code = main(["snapshots", str(corpus["parameters-as-inputs"]), "-o", str(tmp_path / "s.h5"), "--input",
                 str(table), "--dt", "0.1", "--t-end", "1", "--inputs", "F,mass_scale,stiffness_scale", "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.count("\n") == 0 and "model-exchange integration" in err, err


def test_cli_interface_and_tolerance_reach_the_file(corpus, tmp_path, capsys):
    out = tmp_path / "s.h5"
    code = main(["snapshots", str(corpus["start-off-rest"]), "-o", str(out), "--input", "none", "--dt", "0.1",
                 "--t-end", "2", "--interface", "cs", "--tolerance", "1e-8", "-q"])
    assert code == 0, capsys.readouterr().err
    from fmu_opinf.snapshots import Snapshots

    snaps = Snapshots.load(out) if hasattr(Snapshots, "load") else Snapshots.open(out)
    attrs = snaps.runs[0].attrs
    assert attrs["fmi_interface"] == "cs" and attrs["tolerance"] == 1e-8


def test_unstable_explicit_cosimulation_gets_a_hint(corpus):
    """One explicit Euler step per doStep blows up at a coarse step: the error says why and what to do."""
    source = open_source(corpus["cs-euler"])
    assert source.interface == "cs"  # the FMU offers no model exchange
    with pytest.raises(StepError, match=r"non-finite values.*explicit step.*: pass a smaller step "
                                        r"\(--dt or dt=\)") as info:
        record(source, "impulse:amplitude=100,t0=2,width=0.5", 0.2, 2000.0, quiet=True)
    assert "\n" not in str(info.value)


def test_structural_parameter_through_model_exchange(corpus):
    """FMI 3 array states whose size is set in configuration mode, integrated by fmu-opinf."""
    source = open_source(corpus["fmi3-array-structural"], parameters={"n": 8})
    assert source.interface == "me" and source.n == 8
    dt = 0.05
    run = record(source, Levels(source.m, dt), dt, 4.0, quiet=True).runs[0]
    chain = lti_fmus.corpus_models()["fmi3-array-structural"][0]
    model = chain.model(8)
    held = np.hstack([run.u[:, 1:], run.u[:, -1:]])
    errors = relative_errors(run, lti_fmus.zoh_response(model, run.t, held))
    assert max(errors.values()) < 1e-8, errors


# ----------------------------------------------------------------------------- --me-method

@pytest.mark.slow
def test_cli_me_method_reaches_the_file_and_the_recording_follows_it(corpus, tmp_path, capsys):
    out = tmp_path / "s.h5"
    code = main(["snapshots", str(corpus["start-off-rest"]), "-o", str(out), "--input", "step:amplitude=2,t0=1",
                 "--dt", "0.1", "--t-end", "4", "--me-method", "Radau", "--tolerance", "1e-11", "-q"])
    assert code == 0, capsys.readouterr().err
    from fmu_opinf.snapshots import Snapshots

    run = Snapshots.load(out).runs[0]
    assert run.attrs["fmi_interface"] == "me" and run.attrs["integrator"].startswith("Radau IIA")
    assert max(relative_errors(run, exact("start-off-rest", run)).values()) < 1e-7


@pytest.mark.parametrize("args, expected", [
    (["--me-method", "euler"], "--me-method 'euler' is not an integrator; choose one of auto, dop853, linear"),
    (["--me-method", "bdf", "--interface", "cs"], "--me-method bdf or method='bdf' applies to model exchange"),
])
def test_cli_me_method_errors_are_one_line(corpus, tmp_path, capsys, args, expected):
    code = main(["snapshots", str(corpus["start-off-rest"]), "-o", str(tmp_path / "s.h5"), "--input", "none",
                 "--dt", "0.1", "--t-end", "1", "-q"] + args)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and expected in err, err
    assert not (tmp_path / "s.h5").exists()


def test_cli_me_method_on_a_builtin_source_is_refused(tmp_path, capsys):
    code = main(["snapshots", "builtin:anchored-msd", "--g", "10", "-o", str(tmp_path / "s.h5"), "--dt", "0.5",
                 "--t-end", "5", "--me-method", "lsoda", "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--me-method or method= applies to fmu sources" in err and err.count("\n") == 0, err


@pytest.mark.slow  # 4 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_compare_drives_the_fmu_with_the_given_method(corpus):
    from fmu_opinf.compare import simulate_outputs
    from fmu_opinf.signals import parse_signal

    t = np.arange(0, 41) * 0.1
    y, _, provenance, _ = simulate_outputs(str(corpus["start-off-rest"]), parse_signal("none", 1), t,
                                           quiet=True, method="bdf")
    assert provenance["integrator"].startswith("BDF")


# ----------------------------------------------------------------------------- compiled step loop

def _record_counting(source, dt: float, t_end: float):
    """Record ``Levels`` inputs and count the derivative evaluations of either step loop."""
    from fmu_opinf.sources import _compiled_rk

    counts = {"python": 0}
    rhs = ModelExchangeSource.rhs

    def counted(self, t, x):
        counts["python"] += 1
        return rhs(self, t, x)

    integrate = _compiled_rk.Kernel.integrate

    def integrate_counted(self, *args, **kwargs):
        try:
            return integrate(self, *args, **kwargs)
        finally:
            counts["compiled"] = self.evaluations

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ModelExchangeSource, "rhs", counted)
        mp.setattr(_compiled_rk.Kernel, "integrate", integrate_counted)
        run = record(source, Levels(source.m, dt), dt, t_end, quiet=True).runs[0]
    return run, counts


@pytest.mark.filterwarnings("ignore:.*too coarse for the motion")
# bound against the exact solution: measured 1.1e-11 / 1.3e-12 at dt = 0.05, 7.0e-10 at dt = 2 (40 time units per
# interval, tolerance 1e-10).  fmi3-array-structural starts at 0.01 and swings to -0.01: its tolerance follows the
# deviation from the start, up to 0.02 (3.2e-13 while it followed |x|, up to 0.01)
@pytest.mark.parametrize("name, dt, bound", [("me-only", 0.05, 3e-11), ("fmi3-array-structural", 0.05, 4e-12),
                                             ("me-only", 2.0, 2e-9)])
def test_compiled_dop853_takes_the_steps_of_scipys_dop853(corpus, name, dt, bound, monkeypatch):
    """The C step loop is scipy's DOP853 (same tableau, error norm and step control): the number of derivative
    evaluations of :class:`scipy.integrate.DOP853` driving the FMU from Python, the same states to rounding, and
    both within the tolerance of the exact solution.  With dt = 2 an interval takes more steps
    than one call of the C loop runs, so the loop pauses (for Ctrl-C) and resumes without changing a step."""
    from fmu_opinf.sources import _compiled_rk

    if not _compiled_rk.available():
        pytest.skip("no C compiler for the compiled step loop")
    pauses = []
    adapt = _compiled_rk.Kernel._adapt
    monkeypatch.setattr(_compiled_rk.Kernel, "_adapt", lambda self, seconds: (pauses.append(seconds),
                                                                               adapt(self, seconds)))
    compiled, counts_c = _record_counting(open_source(corpus[name]), dt, 8.0)
    assert counts_c["python"] == 0 and counts_c["compiled"] > 1000
    assert "compiled" in compiled.attrs["integrator"]
    assert bool(pauses) == (dt > 1)
    monkeypatch.setattr(_compiled_rk, "kernel", lambda *args: None)
    python, counts_py = _record_counting(open_source(corpus[name]), dt, 8.0)
    # equal here; the error estimate's sums are added in another order than numpy's, which can move a step when a
    # state's absolute tolerance is near the rounding of the estimate (3 % fewer on a model starting at 0)
    assert abs(counts_py["python"] - counts_c["compiled"]) <= 0.01 * counts_c["compiled"]
    for key in ("x", "xdot", "xddot", "y"):
        a, b = np.asarray(getattr(compiled, key)), np.asarray(getattr(python, key))
        # measured up to 1.0e-13 (fmi3-array-structural, started at 0.01: the tolerance follows the motion from there,
        # tight at the start, where the sums' order moves steps more; 6.4e-14 while it followed |x|)
        assert np.abs(a - b).max() <= 3e-13 * np.abs(b).max(), key
    assert max(relative_errors(compiled, exact(name, compiled)).values()) < bound


def test_model_exchange_without_a_c_compiler_keeps_scipys_loop(corpus, tmp_path, monkeypatch):
    """No compiler (``CC`` names none, empty cache): the recording is the same through scipy's loop, and the
    provenance says which loop ran."""
    from fmu_opinf.sources import _compiled_rk

    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    _compiled_rk._library.cache_clear()
    try:
        source = open_source(corpus["me-only"])
        run = record(source, Levels(source.m, 0.05), 0.05, 8.0, quiet=True).runs[0]
        assert not _compiled_rk.available()
    finally:
        _compiled_rk._library.cache_clear()
    # auto: a mild model is DOP853's, here scipy's loop
    assert run.attrs["integrator"].startswith("auto: DOP853 (scipy.integrate.DOP853)")
    assert max(relative_errors(run, exact("me-only", run)).values()) < 3e-11


def test_a_failed_build_of_the_step_loop_is_tried_once_and_a_foreign_library_is_not_loaded(tmp_path, monkeypatch):
    """A compiler that fails leaves a marker, so that the runs' processes do not call it again; a library in the
    cache that another user could have written is not loaded (scipy's loop runs instead); a group-writable cache
    folder of this user's (umask 0002) is made private rather than leaving the loop unused."""
    from fmu_opinf.sources import _compiled_rk

    calls = tmp_path / "calls"
    failing = tmp_path / "failing-cc"
    failing.write_text(f"#!/bin/sh\necho called >> {calls}\necho 'no such header' >&2\nexit 1\n")
    failing.chmod(0o755)
    monkeypatch.setenv("CC", str(failing))
    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    from fmu_opinf.errors import FmuOpinfWarning

    try:
        interrupted = tmp_path / "interrupted-cc"
        interrupted.write_text(f"#!/bin/sh\necho called >> {calls}\nkill -INT $$\n")
        interrupted.chmod(0o755)
        monkeypatch.setenv("CC", str(interrupted))
        for _ in range(2):  # a compiler stopped by a signal is no verdict: no marker, tried again
            _compiled_rk._library.cache_clear()
            assert not _compiled_rk.available()
        assert calls.read_text().count("called") == 2 and not list((tmp_path / "cache").rglob("*.failed"))
        calls.unlink()
        monkeypatch.setenv("CC", str(failing))
        for _ in range(3):
            _compiled_rk._library.cache_clear()  # as in a new process
            with pytest.warns(FmuOpinfWarning, match="could not be built .* scipy's slower loop"):
                assert not _compiled_rk.available()
        assert calls.read_text().count("called") == 1
        (marker,) = (tmp_path / "cache" / "integrator").glob("*.failed")
        assert "no such header" in marker.read_text()
        if not (shutil.which("cc") or shutil.which("gcc")):
            return
        monkeypatch.delenv("CC")
        (tmp_path / "cache" / "integrator").chmod(0o775)  # as a umask of 0002 leaves it: made private again
        _compiled_rk._library.cache_clear()
        assert _compiled_rk.available()
        assert (tmp_path / "cache" / "integrator").stat().st_mode & 0o777 == 0o755
        (library,) = (tmp_path / "cache" / "integrator").glob("erk-*.so")
        library.chmod(0o775)  # group-writable: anyone in the group could have replaced it
        _compiled_rk._library.cache_clear()
        assert not _compiled_rk.available()
    finally:
        _compiled_rk._library.cache_clear()


def test_a_motion_that_grows_without_bound_is_said_to_and_not_blamed_on_the_tolerance_alone(tmp_path):
    """An unstable model (a negative stiffness, as a stiffness or damping exposed as an input and driven below 0
    makes one) overflows after about 14 s here (growth rate 50/s); audit 58: the line said only "try a looser
    --tolerance", which cannot help."""
    model = lti_fmus.LinearMechanicalModel(M=np.eye(1), D=np.zeros((1, 1)), K=-2500.0 * np.eye(1),
                                           B=np.ones((1, 1)), Cp=np.eye(1), name="Unstable")
    path = tmp_path / "Unstable.fmu"
    lti_fmus.build_lti_fmu(model, path, interfaces=("me",))
    with pytest.raises(StepError) as info:
        record(open_source(path), "step:amplitude=1,t0=0.5", 0.1, 20.0, quiet=True)
    message = str(info.value)
    assert "the derivatives are not finite at t=14." in message and "\n" not in message
    assert "the motion grew without bound, as an unstable model's does" in message
