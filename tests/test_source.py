"""Tests of fmu_opinf.source: variable discovery, bad inputs, stepping FMI 2.0 / 3.0 FMUs.

The tiny test FMU ("toy", a 3-mass chain stepped by Newmark inside C) is compiled here with the
system C compiler; tests that need it skip with a reason when there is none.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from fmu_opinf.errors import DimensionError, FMUError, FmuOpinfError, FmuOpinfWarning, InputSpecError
from fmu_opinf.source import FMUSource, StepError, match_names, natural_key, open_source

TOY_C = r"""
/* Tiny 3-mass chain with Newmark (beta=1/4, gamma=1/2) for fmu-opinf tests; FMI 2.0 and 3.0 co-simulation. */
#include <stdlib.h>
#include <string.h>
#include <stdbool.h>
#include <math.h>

#define N 3
typedef void (*Logger2)(void *env, const char *name, int status, const char *cat, const char *msg, ...);
typedef struct { Logger2 logger; void *alloc; void *free; void *stepFinished; void *env; } Callbacks2;
typedef void (*Logger3)(void *env, int status, const char *cat, const char *msg);

typedef struct {
    double x[N], v[N], a[N], a_pub[N], u, t, k, fault_threshold;
    int fault, started, fmi3;
    Logger2 log2; void *env2; Logger3 log3; void *env3;
} Model;

static void logError(Model *m, const char *msg) {
    if (m->fmi3) { if (m->log3) m->log3(m->env3, 3, "logStatusError", msg); }
    else if (m->log2) m->log2(m->env2, "toy", 3, "logStatusError", msg);
}

static void mat(const Model *m, double K[N][N], double D[N][N]) {
    memset(K, 0, sizeof(double) * N * N);
    for (int i = 0; i < N; i++) {
        K[i][i] = 2 * m->k;
        if (i + 1 < N) { K[i][i + 1] = -m->k; K[i + 1][i] = -m->k; }
    }
    for (int i = 0; i < N; i++) for (int j = 0; j < N; j++) D[i][j] = 0.1 * K[i][j];
}

static void solve(double A[N][N], double b[N]) {  /* Gaussian elimination, SPD so no pivoting */
    for (int c = 0; c < N; c++) for (int r = c + 1; r < N; r++) {
        double f = A[r][c] / A[c][c];
        for (int j = c; j < N; j++) A[r][j] -= f * A[c][j];
        b[r] -= f * b[c];
    }
    for (int r = N - 1; r >= 0; r--) {
        for (int j = r + 1; j < N; j++) b[r] -= A[r][j] * b[j];
        b[r] /= A[r][r];
    }
}

static void publish(Model *m) { memcpy(m->a_pub, m->a, sizeof(m->a)); }

static void consistent(Model *m) {  /* M = I: a = B u - D v - K x */
    double K[N][N], D[N][N]; mat(m, K, D);
    for (int i = 0; i < N; i++) {
        m->a[i] = (i == 0 ? m->u : 0.0);
        for (int j = 0; j < N; j++) m->a[i] -= D[i][j] * m->v[j] + K[i][j] * m->x[j];
    }
    publish(m);
}

static int step(Model *m, double h) {
    if (m->u > m->fault_threshold) {
        if (m->fault == 1) { logError(m, "toy fault: input above threshold"); return 3; }
        if (m->fault == 2) { for (int i = 0; i < N; i++) m->x[i] = NAN; m->t += h; return 0; }
        if (m->fault == 3) { volatile int *p = NULL; *p = 1; }
    }
    double K[N][N], D[N][N], S[N][N], xp[N], vp[N], r[N];
    mat(m, K, D);
    for (int i = 0; i < N; i++) {
        xp[i] = m->x[i] + h * m->v[i] + 0.25 * h * h * m->a[i];
        vp[i] = m->v[i] + 0.5 * h * m->a[i];
    }
    for (int i = 0; i < N; i++) {
        r[i] = (i == 0 ? m->u : 0.0);
        for (int j = 0; j < N; j++) {
            S[i][j] = (i == j) + 0.5 * h * D[i][j] + 0.25 * h * h * K[i][j];
            r[i] -= D[i][j] * vp[j] + K[i][j] * xp[j];
        }
    }
    solve(S, r);
    for (int i = 0; i < N; i++) {
        m->a[i] = r[i];
        m->x[i] = xp[i] + 0.25 * h * h * r[i];
        m->v[i] = vp[i] + 0.5 * h * r[i];
    }
    m->t += h; m->started = 1;
#ifndef TOY_STALE  /* -DTOY_STALE: the accelerations read after doStep stay one step old until an input is set */
    publish(m);
#endif
    return 0;
}

/* value references: 0 u, 1 y[1]=x[1], 2 y[2]=x[3], 10.. x, 20.. v, 30.. a, 40 fault (int), 41 threshold, 42 k */
static int getReal(Model *m, unsigned vr, double *out) {
    if (vr == 0) *out = m->u;
    else if (vr == 1) *out = m->x[0];
    else if (vr == 2) *out = m->x[N - 1];
    else if (vr >= 10 && vr < 10 + N) *out = m->x[vr - 10];
    else if (vr >= 20 && vr < 20 + N) *out = m->v[vr - 20];
    else if (vr >= 30 && vr < 30 + N) *out = m->a_pub[vr - 30];
    else if (vr == 41) *out = m->fault_threshold;
    else if (vr == 42) *out = m->k;
    else return 3;
    return 0;
}
static int setReal(Model *m, unsigned vr, double value) {
    if (vr == 0) { m->u = value; if (!m->started) consistent(m); publish(m); }
    else if (vr == 41) m->fault_threshold = value;
    else if (vr == 42) m->k = value;
    else if (vr >= 10 && vr < 10 + N && !m->started) m->x[vr - 10] = value;  /* start values of the positions */
    else return 3;
    return 0;
}
static Model *create(void) {
    Model *m = calloc(1, sizeof(Model));
    m->k = 1.0; m->fault_threshold = 1e300;
    return m;
}

/* ---------------- FMI 2.0 ---------------- */
const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
void *fmi2Instantiate(const char *name, int type, const char *guid, const char *res, const Callbacks2 *cb, int vis, int log) {
    Model *m = create(); m->log2 = cb ? cb->logger : NULL; m->env2 = cb ? cb->env : NULL; return m;
}
void fmi2FreeInstance(void *c) { free(c); }
int fmi2SetupExperiment(void *c, int td, double tol, double t0, int sd, double ts) { ((Model *)c)->t = t0; return 0; }
int fmi2EnterInitializationMode(void *c) { return 0; }
int fmi2ExitInitializationMode(void *c) { consistent((Model *)c); return 0; }
int fmi2Terminate(void *c) { return 0; }
int fmi2GetReal(void *c, const unsigned *vr, size_t n, double *v) {
    for (size_t i = 0; i < n; i++) if (getReal((Model *)c, vr[i], &v[i])) return 3;
    return 0;
}
int fmi2SetReal(void *c, const unsigned *vr, size_t n, const double *v) {
    for (size_t i = 0; i < n; i++) if (setReal((Model *)c, vr[i], v[i])) return 3;
    return 0;
}
int fmi2GetInteger(void *c, const unsigned *vr, size_t n, int *v) {
    for (size_t i = 0; i < n; i++) { if (vr[i] != 40) return 3; v[i] = ((Model *)c)->fault; }
    return 0;
}
int fmi2SetInteger(void *c, const unsigned *vr, size_t n, const int *v) {
    for (size_t i = 0; i < n; i++) { if (vr[i] != 40) return 3; ((Model *)c)->fault = v[i]; }
    return 0;
}
int fmi2DoStep(void *c, double t, double h, int noSet) { return step((Model *)c, h); }

/* ---------------- FMI 3.0 ---------------- */
const char *fmi3GetVersion(void) { return "3.0"; }
void *fmi3InstantiateCoSimulation(const char *name, const char *token, const char *res, bool vis, bool log,
                                  bool ev, bool early, const unsigned *req, size_t nreq, void *env,
                                  Logger3 logger, void *upd) {
    Model *m = create(); m->fmi3 = 1; m->log3 = logger; m->env3 = env; return m;
}
void fmi3FreeInstance(void *c) { free(c); }
int fmi3EnterInitializationMode(void *c, bool td, double tol, double t0, bool sd, double ts) { ((Model *)c)->t = t0; return 0; }
int fmi3ExitInitializationMode(void *c) { consistent((Model *)c); return 0; }
int fmi3Terminate(void *c) { return 0; }
int fmi3GetFloat64(void *c, const unsigned *vr, size_t n, double *v, size_t nv) { return fmi2GetReal(c, vr, n, v); }
int fmi3SetFloat64(void *c, const unsigned *vr, size_t n, const double *v, size_t nv) { return fmi2SetReal(c, vr, n, v); }
int fmi3GetInt32(void *c, const unsigned *vr, size_t n, int *v, size_t nv) { return fmi2GetInteger(c, vr, n, v); }
int fmi3SetInt32(void *c, const unsigned *vr, size_t n, const int *v, size_t nv) { return fmi2SetInteger(c, vr, n, v); }
int fmi3DoStep(void *c, double t, double h, bool noSet, bool *ev, bool *term, bool *early, double *last) {
    *ev = false; *term = false; *early = false;
    int s = step((Model *)c, h); *last = ((Model *)c)->t; return s;
}
"""

TOY_N = 3
TOY_K = np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]])  # stiffness for k = 1
TOY_D = 0.1 * TOY_K


def _scalar2(index_of: dict, name: str, vr: int, causality: str, body: str, variability: str = "continuous",
             initial: str | None = None) -> str:
    index_of[name] = len(index_of) + 1
    init = f' initial="{initial}"' if initial else ""
    return (f'<ScalarVariable name="{name}" valueReference="{vr}" causality="{causality}" '
            f'variability="{variability}"{init}>{body}</ScalarVariable>')


def toy_xml2(variant: str = "full") -> str:
    """FMI 2.0 model description of the toy binary; variants change names/exposure/interface."""
    idx: dict = {}
    rows = [] if variant == "no-input" else [_scalar2(idx, "u", 0, "input", '<Real start="0"/>')]
    rows += [_scalar2(idx, "y[1]", 1, "output", "<Real/>", initial="calculated"),
             _scalar2(idx, "y[2]", 2, "output", "<Real/>", initial="calculated")]
    derivs = []
    for i in range(1, TOY_N + 1):  # reversed creation order would not matter: names are sorted naturally
        if variant == "modelica":
            rows.append(_scalar2(idx, f"q[{i}]", 9 + i, "local", "<Real/>", initial="calculated"))
        elif variant in ("no-input", "param-input"):  # positions with settable start values
            rows.append(_scalar2(idx, f"x[{i}]", 9 + i, "local", '<Real start="0"/>', initial="exact"))
        else:
            rows.append(_scalar2(idx, f"x[{i}]", 9 + i, "local", "<Real/>", initial="calculated"))
    for i in range(1, TOY_N + 1):
        if variant == "modelica":
            rows.append(_scalar2(idx, f"qd[{i}]", 19 + i, "local", f'<Real derivative="{idx[f"q[{i}]"]}"/>',
                                 initial="calculated"))
            derivs.append(idx[f"qd[{i}]"])
        elif variant != "positions-only":
            rows.append(_scalar2(idx, f"v[{i}]", 19 + i, "local", "<Real/>", initial="calculated"))
    for i in range(1, TOY_N + 1):
        if variant == "modelica":
            rows.append(_scalar2(idx, f"der(qd[{i}])", 29 + i, "local", f'<Real derivative="{idx[f"qd[{i}]"]}"/>',
                                 initial="calculated"))
            derivs.append(idx[f"der(qd[{i}])"])
        elif variant not in ("positions-only", "no-accelerations"):
            rows.append(_scalar2(idx, f"a[{i}]", 29 + i, "local", "<Real/>", initial="calculated"))
    rows.append(_scalar2(idx, "fault", 40, "parameter", '<Integer start="0"/>', variability="fixed"))
    if variant == "param-input":  # a parameter exposed as an input, as some exporters do
        rows.append(_scalar2(idx, "fault_threshold", 41, "input", '<Real start="1e300"/>'))
    else:
        rows.append(_scalar2(idx, "fault_threshold", 41, "parameter", '<Real start="1e300"/>', variability="fixed"))
    rows.append(_scalar2(idx, "k", 42, "parameter", '<Real start="1"/>', variability="fixed"))
    interface = ('<ModelExchange modelIdentifier="toy"/>' if variant == "me-only"
                 else '<CoSimulation modelIdentifier="toy" canHandleVariableCommunicationStepSize="true"/>')
    der_xml = "".join(f'<Unknown index="{i}"/>' for i in derivs)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiModelDescription fmiVersion="2.0" modelName="Toy" guid="{toy-0001}" '
            'generationTool="fmu-opinf tests" numberOfEventIndicators="0">'
            f'{interface}<DefaultExperiment startTime="0" stopTime="10" stepSize="0.1"/>'
            f'<ModelVariables>{"".join(rows)}</ModelVariables>'
            f'<ModelStructure><Outputs><Unknown index="{idx["y[1]"]}"/><Unknown index="{idx["y[2]"]}"/></Outputs>'
            f'{"<Derivatives>" + der_xml + "</Derivatives>" if derivs else ""}'
            '</ModelStructure></fmiModelDescription>')


def toy_xml3(variant: str = "full") -> str:
    """FMI 3.0 model description of the toy binary: x, v, a exposed, or Modelica-style states."""
    rows = ['<Float64 name="u" valueReference="0" causality="input" start="0"/>',
            '<Float64 name="y[1]" valueReference="1" causality="output"/>',
            '<Float64 name="y[2]" valueReference="2" causality="output"/>']
    structure = ""
    if variant == "modelica":  # FMI 3 links a derivative to its state by value reference
        rows += [f'<Float64 name="q[{i}]" valueReference="{9 + i}" causality="local"/>' for i in range(1, TOY_N + 1)]
        rows += [f'<Float64 name="qd[{i}]" valueReference="{19 + i}" causality="local" derivative="{9 + i}"/>'
                 for i in range(1, TOY_N + 1)]
        rows += [f'<Float64 name="der(qd[{i}])" valueReference="{29 + i}" causality="local" derivative="{19 + i}"/>'
                 for i in range(1, TOY_N + 1)]
        structure = "".join(f'<ContinuousStateDerivative valueReference="{vr}"/>'
                            for vr in list(range(20, 20 + TOY_N)) + list(range(30, 30 + TOY_N)))
    else:
        for base, letter in ((10, "x"), (20, "v"), (30, "a")):
            rows += [f'<Float64 name="{letter}[{i}]" valueReference="{base + i - 1}" causality="local"/>'
                     for i in range(1, TOY_N + 1)]
    rows += ['<Int32 name="fault" valueReference="40" causality="parameter" variability="fixed" start="0"/>',
             '<Float64 name="fault_threshold" valueReference="41" causality="parameter" variability="fixed" '
             'start="1e300"/>',
             '<Float64 name="k" valueReference="42" causality="parameter" variability="fixed" start="1"/>']
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiModelDescription fmiVersion="3.0" modelName="Toy3" instantiationToken="{toy-0001}">'
            '<CoSimulation modelIdentifier="toy" canHandleVariableCommunicationStepSize="true"/>'
            f'<ModelVariables>{"".join(rows)}</ModelVariables>'
            f'<ModelStructure><Output valueReference="1"/><Output valueReference="2"/>{structure}</ModelStructure>'
            '</fmiModelDescription>')


def compile_toy(directory: Path, defines: tuple[str, ...] = (), name: str = "toy.so") -> Path:
    """Compile the toy binary (all FMI functions fmpy loads exist; unused ones return error); ``defines`` such as
    ``("TOY_STALE",)`` select variants of its behaviour."""
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler to build the test FMU")
    defined = set(re.findall(r"\b(fmi[23]\w+)\(", TOY_C))
    stubs = sorted({n for cls in (FMU2Slave, FMU3Slave) for n in dir(cls)
                    if n.startswith(("fmi2", "fmi3")) and n not in defined})
    (directory / "toy.c").write_text(TOY_C)
    (directory / "stubs.c").write_text("".join(f"int {n}(void) {{ return 3; }}\n" for n in stubs))
    library = directory / name
    subprocess.run([compiler, "-O2", "-shared", "-fPIC", *(f"-D{d}" for d in defines), "-o", str(library),
                    str(directory / "toy.c"), str(directory / "stubs.c"), "-lm"], check=True, capture_output=True)
    return library


def pack_fmu(path: Path, xml: str, library: Path | None, platform_dir: str | None) -> Path:
    """Zip a model description and (optionally) the binary into an FMU."""
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", xml)
        if library is not None:
            zf.write(library, f"binaries/{platform_dir}/toy.so")
    return path


def build_toys(directory: Path) -> dict[str, Path]:
    """All toy FMUs: full, positions-only, no-accelerations, modelica, fmi3, me-only, no-binary."""
    import fmpy

    if not fmpy.platform.startswith("linux"):
        pytest.skip("the toy FMU build is written for Linux")
    library = compile_toy(directory)
    out = {}
    for variant in ("full", "positions-only", "no-accelerations", "modelica", "me-only", "no-input", "param-input"):
        out[variant] = pack_fmu(directory / f"toy-{variant}.fmu", toy_xml2(variant), library, fmpy.platform)
    out["fmi3"] = pack_fmu(directory / "toy3.fmu", toy_xml3(), library, fmpy.platform_tuple)
    out["fmi3-modelica"] = pack_fmu(directory / "toy3-modelica.fmu", toy_xml3("modelica"), library,
                                    fmpy.platform_tuple)
    out["no-binary"] = pack_fmu(directory / "toy-nobinary.fmu", toy_xml2(), None, None)
    stale = compile_toy(directory, ("TOY_STALE",), "toy-stale.so")
    out["stale"] = pack_fmu(directory / "toy-stale.fmu", toy_xml2(), stale, fmpy.platform)
    out["win-only"] = pack_fmu(directory / "toy-win.fmu", toy_xml2(), library, "win64")
    return out


class SignalStub:
    """A one-channel step signal with a spec (the recorder only needs ``sample`` and ``spec``)."""

    def __init__(self, amplitude: float = 1.0, t0: float = 0.35) -> None:
        self.amplitude, self.t0 = amplitude, t0
        self.spec = f"step:amplitude={amplitude},t0={t0}"

    def sample(self, t: np.ndarray) -> np.ndarray:
        return np.where(np.asarray(t) >= self.t0, self.amplitude, 0.0)[None, :]


def planned(source, dt: float = 0.1, t_end: float = 3.0, signal=None):
    """Time grid and inputs in effect (time-major) for driving a source by hand."""
    from fmu_opinf.snapshots import inputs_in_effect, time_grid

    t = time_grid(dt, t_end)
    u = inputs_in_effect(signal or SignalStub(), t, source.m)
    return t, np.ascontiguousarray(u.T)


def drive(source, t, U) -> np.ndarray:
    """All samples through the batched interface, one row per sample."""
    rows = np.empty((len(t), source.width))
    source.start(t, U)
    try:
        source.advance(rows, 0, len(t))
    finally:
        source.close()
    return rows


# ------------------------------------------------------------------------------- names


def test_match_names_orders_numerically_and_treats_brackets_literally():
    names = ["x[10]", "x[2]", "x[1]", "xx[3]", "y[1]", "x*"]
    assert match_names("x[*]", names) == ["x[1]", "x[2]", "x[10]"]
    assert match_names("y[1], x[?]", names) == ["y[1]", "x[1]", "x[2]"]
    assert match_names("x[1],x[*]", names) == ["x[1]", "x[2]", "x[10]"]  # no repeats
    assert match_names("z*", names) == []
    assert sorted(["a[10]", "a[9]", "a[1]"], key=natural_key) == ["a[1]", "a[9]", "a[10]"]


def test_default_names_of_the_toy_fmu(toys):
    source = FMUSource(toys["full"])
    assert source.position_names == ["x[1]", "x[2]", "x[3]"]
    assert source.velocity_names == ["v[1]", "v[2]", "v[3]"]
    assert source.acceleration_names == ["a[1]", "a[2]", "a[3]"]
    assert (source.input_names, source.output_names) == (["u"], ["y[1]", "y[2]"])
    assert (source.n, source.m, source.p, source.width) == (3, 1, 2, 11)
    assert source.derived == {"xdot": False, "xddot": False}
    assert source.constraint == "unknown"
    assert FMUSource(toys["full"], constraint="position").constraint == "position"


@pytest.mark.parametrize("variant", ["modelica", "fmi3-modelica"])
def test_modelica_style_states_are_found_through_derivative_links(toys, variant):
    source = FMUSource(toys[variant])
    assert source.position_names == ["q[1]", "q[2]", "q[3]"]
    assert source.velocity_names == ["qd[1]", "qd[2]", "qd[3]"]
    assert source.acceleration_names == ["der(qd[1])", "der(qd[2])", "der(qd[3])"]
    # the same binary behind other names records the same numbers
    t, U = planned(source)
    np.testing.assert_array_equal(drive(source, t, U), drive(FMUSource(toys["full"]), t, U))


def test_missing_rates_are_marked_derived(toys):
    only_x = FMUSource(toys["positions-only"])
    assert only_x.velocity_names == [] and only_x.derived == {"xdot": True, "xddot": True}
    assert only_x.width == 3 + 2
    no_a = FMUSource(toys["no-accelerations"])
    assert no_a.derived == {"xdot": False, "xddot": True} and no_a.width == 6 + 2


def test_explicit_patterns_select_variables(toys):
    source = FMUSource(toys["full"], positions="x[1],x[2]", velocities="v[1],v[2]", accelerations="a[1],a[2]",
                       outputs="y[2]")
    assert source.n == 2 and source.output_names == ["y[2]"]


# ------------------------------------------------------------------------------- stepping


@pytest.mark.parametrize("variant", ["full", "fmi3", "stale"])
def test_recorded_samples_obey_the_equation_of_motion_with_the_input_in_effect(toys, variant):
    """M a_i + D v_i + K x_i = B u_i exactly, where u_i = u(t_{i-1}): the design.md input timing."""
    source = FMUSource(toys[variant])
    t, U = planned(source, dt=0.1, t_end=3.0)
    rows = drive(source, t, U)
    x, v, a, y = rows[:, 0:3].T, rows[:, 3:6].T, rows[:, 6:9].T, rows[:, 9:11].T
    force = np.zeros_like(x)
    force[0] = U[:, 0]
    residual = a + TOY_D @ v + TOY_K @ x - force
    assert np.abs(residual).max() < 1e-12
    assert U[3, 0] == 0.0 and U[4, 0] == 0.0 and U[5, 0] == 1.0  # step at t=0.35 acts from the step at t=0.4
    assert np.abs(x[:, 4]).max() == 0.0 and np.abs(x[:, 5]).max() > 0.0
    np.testing.assert_array_equal(y, x[[0, 2]])


def test_fmi2_and_fmi3_builds_record_the_same_numbers(toys):
    source2, source3 = FMUSource(toys["full"]), FMUSource(toys["fmi3"])
    assert (source2.fmi_version, source3.fmi_version) == ("2.0", "3.0")
    t, U = planned(source2)
    np.testing.assert_array_equal(drive(source2, t, U), drive(source3, t, U))


@pytest.mark.parametrize("variant", ["full", "fmi3"])
def test_single_steps_match_the_batched_loop(toys, variant):
    source = FMUSource(toys[variant])
    t, U = planned(source)
    batched = drive(source, t, U)
    single = np.empty_like(batched)
    source.start(t, U)
    source.read(single[0])
    for i in range(1, len(t)):  # the batched loop passes one step h on a uniform grid (not t[i] - t[i-1])
        source.step(t[i - 1], t[1] - t[0], U[i])
        source.read(single[i])
    source.close()
    np.testing.assert_array_equal(single, batched)


def test_parameters_are_applied_before_initialization(toys):
    soft, stiff = FMUSource(toys["full"]), FMUSource(toys["full"], parameters={"k": 4.0})
    t, U = planned(soft)
    x_soft, x_stiff = drive(soft, t, U)[:, :3], drive(stiff, t, U)[:, :3]
    assert np.abs(x_soft - x_stiff).max() > 1e-3


def test_builtin_source_steps_like_the_reference_simulator():
    from fmu_opinf.newmark import simulate
    from fmu_opinf.source import BuiltinSource

    source = BuiltinSource("anchored-msd", g=12)
    assert (source.n, source.m, source.p, source.constraint) == (12, 1, 3, "position")
    signal = SignalStub(amplitude=3.0, t0=0.35)
    t, U = planned(source, dt=0.5, t_end=20.0, signal=signal)
    rows = drive(source, t, U)
    reference = simulate(source.system, _as_lead_signal(signal), 0.5, 20.0)
    n = source.n
    for part, array in ((slice(0, n), reference.x), (slice(n, 2 * n), reference.xdot),
                        (slice(2 * n, 3 * n), reference.xddot), (slice(3 * n, 3 * n + 3), reference.y)):
        np.testing.assert_array_equal(rows[:, part].T, array)


def _as_lead_signal(stub: SignalStub):
    from fmu_opinf.signals import parse_signal

    return parse_signal(stub.spec)


def test_step_error_names_step_time_and_fmu_message(toys):
    source = FMUSource(toys["full"], parameters={"fault": 1, "fault_threshold": 0.5})
    t, U = planned(source, dt=0.1, t_end=3.0)
    rows = np.empty((len(t), source.width))
    source.start(t, U)
    with pytest.raises(StepError) as info:
        source.advance(rows, 0, len(t))
    source.close()
    assert info.value.step == 5 and info.value.time == pytest.approx(0.5)
    message = str(info.value)
    assert "\n" not in message and "step 5" in message and "t=0.4 -> 0.5" in message
    assert "toy fault: input above threshold" in message


# ------------------------------------------------------------------------------- bad inputs


def _one_line_error(error_type, func, *args, match: str, **kwargs):
    with pytest.raises(error_type, match=match) as info:
        func(*args, **kwargs)
    assert isinstance(info.value, FmuOpinfError)
    assert "\n" not in str(info.value)
    return info.value


def test_missing_path(tmp_path):
    _one_line_error(FMUError, FMUSource, tmp_path / "nothing.fmu", match="does not exist")


def test_file_that_is_not_an_fmu(tmp_path):
    text = tmp_path / "model.fmu"
    text.write_text("not a zip")
    _one_line_error(FMUError, FMUSource, text, match=r"is not an fmu \(not a zip archive\); give an \.fmu file$")
    empty_zip = tmp_path / "empty.fmu"
    with zipfile.ZipFile(empty_zip, "w") as zf:
        zf.writestr("readme.txt", "hello")
    _one_line_error(FMUError, open_source, str(empty_zip), match="no modelDescription.xml")
    broken = tmp_path / "broken.fmu"
    with zipfile.ZipFile(broken, "w") as zf:
        zf.writestr("modelDescription.xml", "<fmiModelDescription")
    _one_line_error(FMUError, FMUSource, broken, match="cannot read modelDescription.xml")


def test_model_exchange_only_fmu(toys):
    _one_line_error(FMUError, FMUSource, toys["me-only"], match="offers no co-simulation, only model exchange; use --interface me")


@pytest.mark.parametrize("variant", ["no-binary", "win-only"])
def test_no_binary_for_this_platform(toys, variant):
    error = _one_line_error(FMUError, FMUSource, toys[variant], match="no binary for this platform")
    assert ("win64" in str(error)) == (variant == "win-only")
    assert "fmpy compile" not in str(error)


def test_an_fmu_without_our_binary_that_ships_its_sources_is_compiled_here(toys, tmp_path, monkeypatch):
    """Source code FMUs (OpenModelica's --fmiSources, a Windows export with sources): compiled here into the cache
    (tests/test_sources_only.py runs such FMUs); sources that are no FMU's give a one-line error at the first run."""
    from fmu_opinf import sources
    from fmu_opinf.snapshots import record

    monkeypatch.setenv("FMU_OPINF_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(sources, "_REPORTED", set())
    with_sources = tmp_path / "toy-win-sources.fmu"
    with zipfile.ZipFile(toys["win-only"]) as zin, zipfile.ZipFile(with_sources, "w") as zout:
        for item in zin.infolist():
            zout.writestr(item, zin.read(item.filename))
        zout.writestr("sources/model.c", "/* the model */\n")
    with pytest.warns(FmuOpinfWarning, match=r"toy-win-sources\.fmu: has no binary for this platform \([^;]+; it "
                                             r"has: win64\); compiled from its C sources"):
        source = open_source(str(with_sources), interface="cs")
    _one_line_error(FMUError, record, source, "none", 0.1, 1.0, quiet=True, match="cannot load the binary")


def test_patterns_matching_nothing(toys):
    _one_line_error(FMUError, FMUSource, toys["full"], positions="z[*]", match="positions pattern 'z\\[\\*\\]' "
                    "matches no real variable")
    _one_line_error(FMUError, FMUSource, toys["full"], velocities="w[*]", match="velocities pattern")
    _one_line_error(FMUError, FMUSource, toys["full"], outputs="out*", match="outputs pattern")


def test_different_counts_of_positions_velocities_accelerations(toys):
    _one_line_error(FMUError, FMUSource, toys["full"], velocities="v[1],v[2]",
                    match="3 positions but 2 velocities")
    _one_line_error(FMUError, FMUSource, toys["full"], accelerations="a[3]", match="3 positions but 1 accelerations")


def test_input_names_not_in_the_fmu(toys):
    _one_line_error(FMUError, FMUSource, toys["full"], inputs="force", match="input 'force' is not a real variable")
    _one_line_error(FMUError, FMUSource, toys["full"], inputs="y[1]", match="y\\[1\\] has causality 'output'")


def test_binary_that_does_not_load(tmp_path, toys):
    import fmpy

    garbage = tmp_path / "garbage.so"
    garbage.write_bytes(b"\x7fELF not really")
    fmu = pack_fmu(tmp_path / "garbage.fmu", toy_xml2(), garbage, fmpy.platform)
    source = FMUSource(fmu)  # the description is fine; the binary fails when the run starts
    t, U = planned(source)
    _one_line_error(FMUError, source.start, t, U, match="cannot load the binary of garbage.fmu")


def test_bad_builtin_specs():
    _one_line_error(InputSpecError, open_source, "builtin:pendulum", match="unknown builtin system")
    _one_line_error(InputSpecError, open_source, "builtin:anchored-msd", positions="x[*]",
                    match="--positions or positions= applies to fmu sources")
    _one_line_error(InputSpecError, open_source, "builtin:anchored-msd", n1=10, match="bad option for builtin")


def test_size_options_do_not_apply_to_fmus(toys):
    _one_line_error(InputSpecError, open_source, str(toys["full"]), g=10, match="--g or g= applies to builtin sources")


def test_input_with_wrong_number_of_channels(toys):
    source = FMUSource(toys["full"])
    t = np.linspace(0.0, 1.0, 11)
    _one_line_error(DimensionError, source.start, t, np.zeros((11, 2)), match="2 channels but the source has m=1")


def test_sources_pickle_as_recipes(toys):
    import pickle

    source = FMUSource(toys["full"], parameters={"k": 2.0}, constraint="velocity")
    clone = pickle.loads(pickle.dumps(source))
    assert clone.description() == source.description()
    assert clone.recipe() == source.recipe()


def test_failed_binary_load_keeps_the_working_directory(toys):
    import os

    before = os.getcwd()
    source = FMUSource(toys["full"])
    for library in Path(source._extracted()).rglob("*.so"):  # break the binary in the unpacked copy
        library.write_bytes(b"not a shared library")
    with pytest.raises(FMUError, match="cannot load the binary"):
        source.start(np.array([0.0, 0.1]), np.zeros((2, 1)))
    assert os.getcwd() == before


# ------------------------------------------------------------------------------- settings, inputs, m = 0


def test_settings_set_start_values_and_parameters(toys):
    source = FMUSource(toys["no-input"], parameters={"x[1]": "0.5", "x[3]": -0.25, "k": "4"})
    assert source.m == 0 and source.input_names == [] and source.held_input_names == []
    t = np.linspace(0.0, 1.0, 11)
    rows = drive(source, t, np.zeros((len(t), 0)))
    np.testing.assert_array_equal(rows[0, :3], [0.5, 0.0, -0.25])  # the initial state is the one set
    np.testing.assert_array_equal(rows[0, 3:6], [0.0, 0.0, 0.0])
    # consistent initial acceleration of x'' + 0.1 K x' + K x = 0 with K = 4 * tridiag(-1, 2, -1)
    np.testing.assert_allclose(rows[0, 6:9], -4.0 * TOY_K @ np.array([0.5, 0.0, -0.25]), rtol=0, atol=1e-15)
    # recorded typed by the variables (Real): a "4" from the command line and a 4.0 from Python are one setting
    assert source.provenance()["fmu_settings"] == {"x[1]": 0.5, "x[3]": -0.25, "k": 4.0}
    assert all(type(value) is float for value in source.provenance()["fmu_settings"].values())


def test_setting_errors_name_the_variable(toys):
    _one_line_error(InputSpecError, FMUSource, toys["full"], parameters={"kk": 1}, match="has no variable 'kk'")
    _one_line_error(InputSpecError, FMUSource, toys["full"], parameters={"fault": "1.5"},
                    match="fault is an Integer variable.*give an integer")
    _one_line_error(InputSpecError, open_source, "builtin:anchored-msd", parameters={"k": 1},
                    match="--set or parameters= applies to fmu sources")


def test_inputs_none_holds_every_input(toys):
    source = FMUSource(toys["param-input"], inputs="none")
    assert source.m == 0 and source.held_input_names == ["fault_threshold", "u"]
    default = FMUSource(toys["param-input"])   # default: every real input but those with non-zero starts
    assert default.input_names == ["u"] and default.parameter_like_input_names == ["fault_threshold"]
    chosen = FMUSource(toys["param-input"], inputs="u")
    assert chosen.input_names == ["u"] and chosen.held_input_names == ["fault_threshold"]
    assert chosen.description()["held_input_names"] == ["fault_threshold"]


def test_selection_is_described(toys):
    source = FMUSource(toys["modelica"])
    assert source.description()["variable_selection"] == {
        "positions": "from derivative links", "velocities": "from derivative links",
        "accelerations": "derivatives of the velocity states"}
    text = source.selection_text()
    assert "\n" not in text and "positions q[1], q[2], q[3] (from derivative links)" in text


def test_fmpy_default_logging_survives_a_closed_source(tmp_path):
    """fmpy's native logger proxy keeps the last logger it was given in one process-wide slot, also for fmpy's own
    default callbacks.  A source's logger used to go into that slot and die with the source: the next FMU that
    logged through fmpy's defaults crashed the process (segmentation fault).  Run in a child process, which such a
    crash kills, after a source has recorded, been closed and collected."""
    import subprocess
    import sys
    import textwrap

    from fmu_opinf import fmus

    if fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build the benchmark FMU")
    fmu = fmus.bundled_fmu("AnchoredMSD")   # its kernel logs the error below
    script = textwrap.dedent(f"""
        import gc
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmu_opinf.snapshots import record
        from fmu_opinf.source import FMUSource
        source = FMUSource({str(fmu)!r})
        record(source, "step", 0.5, 2.0, quiet=True)
        del source
        gc.collect()
        folder = extract({str(fmu)!r})
        md = read_model_description(folder)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName="other")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        try:
            fmu.setReal([999999], [1.0])   # an error the FMU logs
        except Exception:
            pass
        print("survived")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "survived" in done.stdout, done.stderr[-500:]


def test_a_source_survives_fmpy_simulate_fmu_with_its_own_logger(tmp_path):
    """``fmpy.simulate_fmu(logger=...)`` leaves fmpy's proxy slot at its logger, which is freed when it returns; a
    source opened after it logged through that dead pointer (the CI crash of 2026-11-28: an ME recording whose FMU
    logged an error).  Run in a child process, which such a crash kills."""
    import subprocess
    import sys
    import textwrap

    from fmu_opinf import fmus

    if fmus.find_build_tools() is None:
        pytest.skip("CMake and a C compiler are needed to build the benchmark FMU")
    fmu = fmus.bundled_fmu("AnchoredMSD")
    script = textwrap.dedent(f"""
        import gc
        import fmpy
        from fmu_opinf.source import FMUSource
        from fmu_opinf.sources import StepError
        from fmu_opinf.snapshots import record
        try:   # the FMU logs its refusal through simulate_fmu's logger, and simulate_fmu raises
            fmpy.simulate_fmu({str(fmu)!r}, stop_time=1.0, start_values={{"mass": -1.0}},
                              logger=lambda *args: None)
        except Exception:
            pass
        gc.collect()
        try:
            record(FMUSource({str(fmu)!r}, parameters={{"mass": -1}}), "step", 0.5, 2.0, quiet=True)
        except StepError as exc:
            print("refused:", exc)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "mass must be positive" in done.stdout, done.stderr[-500:]
