"""A velocity constraint reduced by dummy derivatives (audit 77b, F1).

Index reduction of ``G x' = 0`` by dummy derivatives keeps every position a state and makes one velocity per
constraint row a computed variable: ``der(mass[j].s)`` of a dependent position is an alias (the same value reference)
of the local ``mass[j].v``, which is no state.  fmu-opinf refused such an FMU: "its continuous state(s) mass[1].s,
... are neither positions nor velocities ... (an actuator lag, a filter or a controller state?)".  Discovery now
records those positions with their computed velocities (accelerations derived from the data), says that the exporter
reduced a velocity constraint, and names ``--constraint velocity``.  Reference: the exact zero-order-hold response
(:func:`fmu_opinf.lti_fmus.zoh_response`) of the constrained model, and intrusive POD-Galerkin on the ROM's basis.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import miss_against_model

from fmu_opinf import lti_fmus, systems
from fmu_opinf.cli import main
from fmu_opinf.errors import FMUError
from fmu_opinf.rom import SecondOrderROM
from fmu_opinf.sources import resolve_variables

# ---------------------------------------------------------------- model descriptions only (no binary)


def _sv(name: str, vr: int, causality: str = "local", body: str = "<Real/>") -> str:
    return (f'<ScalarVariable name="{name}" valueReference="{vr}" causality="{causality}" '
            f'variability="continuous">{body}</ScalarVariable>')


def _description(variables: list[str], derivatives: list[int]) -> str:
    """FMI 2.0 ME description; ``derivatives``: 1-based indices of the state derivatives."""
    unknowns = "".join(f'<Unknown index="{i}"/>' for i in derivatives)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="2.0" modelName="Dd" '
            'guid="{0}"><ModelExchange modelIdentifier="Dd"/><ModelVariables>' + "".join(variables)
            + f"</ModelVariables><ModelStructure><Derivatives>{unknowns}</Derivatives></ModelStructure>"
            "</fmiModelDescription>")


def three_masses(lag: bool = False) -> str:
    """Three masses, ``v2 = v1`` reduced by dummy derivatives: states ``mass[1..3].s``, ``mass[1].v``,
    ``mass[3].v``; ``der(mass[2].s)`` shares the value reference of the local ``mass[2].v``.  ``lag``: an actuator
    lag state ``act.F`` besides (its derivative no alias of anything)."""
    v = [_sv("F", 0, "input", '<Real start="0"/>'),                       # 1
         _sv("mass[1].s", 1, body='<Real start="0"/>'),                  # 2
         _sv("mass[2].s", 2, body='<Real start="0"/>'),                  # 3
         _sv("mass[3].s", 3, body='<Real start="0"/>'),                  # 4
         _sv("mass[1].v", 4, body='<Real start="0"/>'),                  # 5
         _sv("mass[2].v", 5),                                            # 6: computed (dummy derivative)
         _sv("mass[3].v", 6, body='<Real start="0"/>'),                  # 7
         _sv("der(mass[1].s)", 4, body='<Real derivative="2"/>'),        # 8: alias of mass[1].v (a state)
         _sv("der(mass[2].s)", 5, body='<Real derivative="3"/>'),        # 9: alias of mass[2].v (no state)
         _sv("der(mass[3].s)", 6, body='<Real derivative="4"/>'),        # 10: alias of mass[3].v (a state)
         _sv("der(mass[1].v)", 7, body='<Real derivative="5"/>'),        # 11
         _sv("der(mass[3].v)", 8, body='<Real derivative="7"/>'),        # 12
         _sv("y", 9, "output")]                                          # 13
    derivatives = [8, 9, 10, 11, 12]
    if lag:
        v += [_sv("act.F", 10, body='<Real start="0"/>'),                # 14
              _sv("der(act.F)", 11, body='<Real derivative="14"/>')]     # 15
        derivatives.append(15)
    return _description(v, derivatives)


def _write(tmp_path: Path, xml: str) -> Path:
    path = tmp_path / "modelDescription.xml"
    path.write_text(xml, encoding="utf-8")
    return path


def test_positions_with_computed_velocities_are_recorded_with_them(tmp_path):
    """Before: refused as "neither positions nor velocities ... (an actuator lag, a filter or a controller
    state?)"."""
    selection = resolve_variables(_write(tmp_path, three_masses())).selection
    assert [c.name for c in selection.positions] == ["mass[1].s", "mass[2].s", "mass[3].s"]
    assert [c.name for c in selection.velocities] == ["mass[1].v", "mass[2].v", "mass[3].v"]
    assert selection.accelerations == [] and selection.unrecorded_states == []
    assert selection.position_derivatives == ["der(mass[1].s)", "der(mass[2].s)", "der(mass[3].s)"]
    rule = selection.how["positions"]
    assert "velocity constraint by dummy derivatives" in rule and "--constraint velocity" in rule
    assert selection.how["velocities"] == rule and "derived from the data" in selection.how["accelerations"]
    assert not selection.guessed


def test_a_lag_beside_them_is_refused_naming_both_causes(tmp_path):
    """A state that is no position (its derivative no alias of a velocity) is still refused, and the refusal says
    what the others are and which option tells fit."""
    with pytest.raises(FMUError) as caught:
        resolve_variables(_write(tmp_path, three_masses(lag=True)))
    text = str(caught.value)
    assert "its continuous state(s) act.F are neither positions nor velocities" in text
    assert "(an actuator lag, a filter or a controller state?)" in text
    assert "der(mass[2].s) is the computed velocity mass[2].v" in text
    assert "dummy derivatives of a velocity constraint" in text and "--constraint velocity" in text
    assert "\n" not in text


def test_a_lag_whose_rate_is_aliased_and_depends_on_itself_is_no_position(tmp_path):
    """Where the model structure makes ``der(mass[2].s)`` depend on ``mass[2].s`` itself (a first-order lag), the
    alias does not make it a position: refused as before."""
    xml = three_masses().replace('<Unknown index="9"/>', '<Unknown index="9" dependencies="3 5"/>')
    with pytest.raises(FMUError, match=r"mass\[2\]\.s are neither positions nor velocities"):
        resolve_variables(_write(tmp_path, xml))


# ---------------------------------------------------------------- a compiled FMU of this layout

_C = r"""
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"
#include "model.h"
/* z' = A z + BZ u with z = (positions (NX), independent velocities (NK)); the NX velocities are TV z[NX:]. */
typedef struct { double z[NS], u[NU], dz[NS]; } Inst;
static void eval(Inst *I) {
    for (int i = 0; i < NS; i++) { double s = 0; for (int j = 0; j < NS; j++) s += A[i*NS+j]*I->z[j];
        for (int j = 0; j < NU; j++) s += BZ[i*NU+j]*I->u[j]; I->dz[i] = s; } }
static double value(Inst *I, unsigned vr) {
    if (vr < NX) return I->z[vr];
    if (vr < 2*NX) { double s = 0; for (int j = 0; j < NK; j++) s += TV[(vr-NX)*NK+j]*I->z[NX+j]; return s; }
    if (vr < 2*NX + NK) { eval(I); return I->dz[NX + vr - 2*NX]; }
    if (vr < 2*NX + NK + NU) return I->u[vr - 2*NX - NK];
    { double s = 0; for (int j = 0; j < NX; j++) s += CP[(vr-2*NX-NK-NU)*NX+j]*I->z[j]; return s; } }
const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char* fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean l, size_t n, const fmi2String x[]) { return fmi2OK; }
fmi2Component fmi2Instantiate(fmi2String n, fmi2Type t, fmi2String g, fmi2String r,
                              const fmi2CallbackFunctions* f, fmi2Boolean v, fmi2Boolean l) {
    if (t != fmi2ModelExchange || strcmp(g, GUID)) return NULL;
    Inst *I = calloc(1, sizeof(Inst)); memcpy(I->z, Z0, sizeof(I->z)); return I; }
void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real s, fmi2Boolean d,
                               fmi2Real e) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) {
    Inst *I = c; memcpy(I->z, Z0, sizeof(I->z)); memset(I->u, 0, sizeof(I->u)); return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    for (size_t i = 0; i < n; i++) { if (vr[i] >= NVR) return fmi2Error; v[i] = value(c, vr[i]); }
    return fmi2OK; }
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Inst *I = c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] < NX) I->z[vr[i]] = v[i];
        else if (vr[i] < 2*NX) { int j; for (j = 0; j < NK && KEEP[j] != (int)(vr[i] - NX); j++) ;
                                  if (j == NK) return fmi2Error; I->z[NX+j] = v[i]; }
        else if (vr[i] >= 2*NX + NK && vr[i] < 2*NX + NK + NU) I->u[vr[i] - 2*NX - NK] = v[i];
        else return fmi2Error; }
    return fmi2OK; }
#define NONE(f, T) fmi2Status f(fmi2Component c, const fmi2ValueReference vr[], size_t n, T v[]) { \
    return n ? fmi2Error : fmi2OK; }
NONE(fmi2GetInteger, fmi2Integer) NONE(fmi2GetBoolean, fmi2Boolean) NONE(fmi2GetString, fmi2String)
NONE(fmi2SetInteger, const fmi2Integer) NONE(fmi2SetBoolean, const fmi2Boolean) NONE(fmi2SetString, const fmi2String)
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t* n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate* s) {
    return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
    const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real r[]) { return fmi2Error; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo* e) {
    memset(e, 0, sizeof(*e)); return fmi2OK; }
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean n, fmi2Boolean* e, fmi2Boolean* t) {
    *e = fmi2False; *t = fmi2False; return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    if (n != NS) return fmi2Error; memcpy(((Inst*)c)->z, x, sizeof(double)*NS); return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real d[], size_t n) {
    if (n != NS) return fmi2Error; eval(c); memcpy(d, ((Inst*)c)->dz, sizeof(double)*NS); return fmi2OK; }
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real e[], size_t n) { return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    if (n != NS) return fmi2Error; memcpy(x, ((Inst*)c)->z, sizeof(double)*NS); return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    for (size_t i = 0; i < n; i++) x[i] = 1; return fmi2OK; }
"""


def _dense(a) -> np.ndarray:
    return np.asarray(a.toarray() if hasattr(a, "toarray") else a, dtype=float)


def _c_array(name: str, values) -> str:
    flat = np.asarray(values, dtype=float).ravel()
    return f"static const double {name}[{max(flat.size, 1)}] = {{{','.join(repr(float(v)) for v in flat) or '0'}}};\n"


def dummy_derivative_model(n1: int = 4) -> tuple[lti_fmus.LinearMechanicalModel, np.ndarray, np.ndarray]:
    """The triple chain of ``n1`` (spec/benchmarks.md, six velocity constraints), started off rest with
    ``G x0 != 0`` (allowed by ``G x' = 0``), as the exact model, the independent velocities ``keep`` and the velocity
    map ``T`` (``v = T v[keep]``)."""
    s = systems.triple_chain(n1)
    M, D, K, B, Cp, G = (_dense(a) for a in (s.M, s.D, s.K, s.B, s.Cp, s.G))
    x0 = 0.5 * np.sin(np.arange(1, M.shape[0] + 1))
    model = lti_fmus.LinearMechanicalModel(M=M, D=D, K=K, B=B, Cp=Cp, G=G, constraint="velocity", x0=x0,
                                           name="DummyDerivatives")
    keep = model.independent_dofs()
    drop = np.setdiff1d(np.arange(model.n), keep)
    T = np.zeros((model.n, keep.size))
    T[keep, np.arange(keep.size)] = 1.0
    T[drop] = -np.linalg.solve(G[:, drop], G[:, keep])
    return model, keep, T


def _variables(model, keep: np.ndarray) -> tuple[list[str], list[int]]:
    """Scalar variables (value references: positions, all velocities, their accelerations where states, inputs,
    outputs; ``der(mass[i].s)`` an alias of ``mass[i].v``) and the 1-based indices of the state derivatives."""
    n, nk, kept = model.n, keep.size, set(keep.tolist())

    def body(start: float | None, der: int | None = None) -> str:
        return ("<Real" + (f' start="{start!r}"' if start is not None else "")
                + (f' derivative="{der}"' if der else "") + "/>")

    v = [_sv(f"mass[{i + 1}].s", i, body=body(float(model.x0[i]))) for i in range(n)]
    v += [_sv(f"mass[{i + 1}].v", n + i, body=body(0.0 if i in kept else None)) for i in range(n)]
    v += [_sv(f"der(mass[{i + 1}].s)", n + i, body=body(None, i + 1)) for i in range(n)]
    v += [_sv(f"der(mass[{k + 1}].v)", 2 * n + j, body=body(None, n + k + 1)) for j, k in enumerate(keep)]
    v += [_sv("F", 2 * n + nk, "input", body(0.0))]
    v += [_sv(f"y{k + 1}", 2 * n + nk + 1 + k, "output") for k in range(model.p)]
    derivatives = [2 * n + i + 1 for i in range(n)] + [3 * n + j + 1 for j in range(nk)]
    return v, derivatives


def build_dummy_derivative_fmu(path: Path, n1: int = 4) -> lti_fmus.LinearMechanicalModel:
    """An FMI 2.0 ME FMU of the triple chain after dummy-derivative index reduction (states: the ``n`` positions and
    the ``n - nc`` independent velocities; ``z' = A z + Bz u`` with ``x' = T v_k``,
    ``v_k' = (T'MT)^-1 T'(B u - D T v_k - K x)``), compiled against fmpy's FMI headers; returns the exact model."""
    import fmpy

    model, keep, T = dummy_derivative_model(n1)
    n, nk, m = model.n, keep.size, model.m
    solve = np.linalg.solve(T.T @ model.M @ T, T.T)
    A = np.zeros((n + nk, n + nk))
    A[:n, n:], A[n:, :n], A[n:, n:] = T, -solve @ model.K, -solve @ model.D @ T
    Bz = np.vstack([np.zeros((n, m)), solve @ model.B])
    guid = f"{{{uuid.uuid4()}}}"
    folder = path.parent / "dd_build"
    (folder / "binaries" / "linux64").mkdir(parents=True, exist_ok=True)
    (folder / "model.h").write_text(
        f"#define NX {n}\n#define NK {nk}\n#define NS {n + nk}\n#define NU {m}\n"
        f"#define NVR {2 * n + nk + m + model.p}\n"
        f'#define GUID "{guid}"\nstatic const int KEEP[{nk}] = {{{",".join(map(str, keep))}}};\n'
        + _c_array("A", A) + _c_array("BZ", Bz) + _c_array("TV", T) + _c_array("CP", model.Cp)
        + _c_array("Z0", np.r_[model.x0, np.zeros(nk)]))
    (folder / "dd.c").write_text(_C)
    variables, derivatives = _variables(model, keep)
    xml = _description(variables, derivatives).replace('guid="{0}"', f'guid="{guid}"')
    binary = folder / "binaries" / "linux64" / "Dd.so"
    include = os.path.join(os.path.dirname(fmpy.__file__), "c-code")
    subprocess.run(["cc", "-O2", "-shared", "-fPIC", f"-I{include}", f"-I{folder}", "-o", str(binary),
                    str(folder / "dd.c")], check=True)
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", xml)
        archive.write(binary, "binaries/linux64/Dd.so")
    return model


def _galerkin_miss(rom: SecondOrderROM, model, spec: str, t_end: float) -> float:
    """Largest output error over its range of intrusive POD-Galerkin on the ROM's own basis (the true matrices
    projected, about the ROM's ``x_ref``), against the exact model: the truncation error the basis allows."""
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots._rates import inputs_in_effect, time_grid

    V, x_ref = np.asarray(rom.basis), np.asarray(rom.x_ref).ravel()
    galerkin = lti_fmus.LinearMechanicalModel(M=V.T @ model.M @ V, D=V.T @ model.D @ V, K=V.T @ model.K @ V,
                                              B=V.T @ model.B, f0=-V.T @ model.K @ x_ref, Cp=model.Cp @ V,
                                              y0=model.Cp @ x_ref, x0=V.T @ (model.x0 - x_ref))
    t = time_grid(rom.dt, t_end)
    u = inputs_in_effect(parse_signal(spec, 1), t, 1)[:, 1:]
    reference, y = lti_fmus.zoh_response(model, t, u).y, lti_fmus.zoh_response(galerkin, t, u).y
    return float(np.max(np.abs(y - reference).max(axis=1) / np.ptp(reference, axis=1)))


@pytest.fixture(scope="module")
def dd_fmu(tmp_path_factory):
    if shutil.which("cc") is None:
        pytest.skip("a C compiler is needed to build the dummy-derivative FMU")
    path = tmp_path_factory.mktemp("dd") / "Dd.fmu"
    return path, build_dummy_derivative_fmu(path)


TEST = "harmonic:amplitude=5,omega=0.5"


@pytest.mark.fmu
@pytest.mark.parametrize("constraint", [[], ["--constraint", "velocity"]])
def test_the_default_chain_records_it_and_the_rom_is_as_exact_as_galerkin(dd_fmu, tmp_path, capsys, constraint):
    """Triple chain n1 = 4 (13 positions, 7 independent velocities: 20 states), own start values off rest.  Before:
    snapshots exit code 2 ("... an actuator lag, a filter or a controller state?").  Measured: r = 7 (the
    independent dimension), 1.4e-14 of range against the exact model (POD-Galerkin 1.1e-14) from the positions' POD,
    1.5e-14 (1.0e-14) from the velocities' with --constraint velocity."""
    path, model = dd_fmu
    assert main(["snapshots", str(path), "-o", str(tmp_path / "t.h5"), *constraint]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "the exporter reduced a velocity constraint by dummy derivatives" in err, err
    assert main(["fit", str(tmp_path / "t.h5"), "-o", str(tmp_path / "rom.h5")]) == 0
    rom = SecondOrderROM.load(tmp_path / "rom.h5")
    assert rom.r == model.n - model.nc
    assert ("velocities basis" if constraint else "positions basis") in capsys.readouterr().out
    galerkin = _galerkin_miss(rom, model, TEST, 100.0)
    miss = miss_against_model(rom, model, TEST, 100.0)
    assert galerkin < 1e-11 and miss < 1e-11, (miss, galerkin)


def _with_state(extra: list[str], derivative: str) -> str:
    """:func:`three_masses` with one more state (index 14) and its derivative (index 16) appended."""
    xml = three_masses().replace("</ModelVariables>", "".join(extra) + "</ModelVariables>")
    return xml.replace("</Derivatives>", derivative + "</Derivatives>")


@pytest.mark.parametrize("case", ["lag-rate-output", "lag-declared", "pi-integrator", "filter-in-m"])
def test_a_state_whose_derivative_aliases_a_signal_not_named_as_a_velocity_is_refused(tmp_path, case):
    """Audit 78 F2: an actuator lag whose der() aliases an output act.rate (dependencies undeclared, optional in
    FMI 2), a PI integrator whose der() is the control error and a filter state in m whose der() is filt.dy in m/s
    were recorded as positions with those variables as velocities (a spurious 9.9e3 rad/s mode).  A computed
    velocity is named as the linked positions' velocities are (mass[2].s -> mass[2].v); these are refused, naming
    the state."""
    state, rate, causality, unit = {"lag-rate-output": ("act.F", "act.rate", "output", ""),
                                    "lag-declared": ("act.F", "act.rate", "output", ""),
                                    "pi-integrator": ("PI.I.y", "PI.I.u", "local", ""),
                                    "filter-in-m": ("filt.y", "filt.dy", "local", "m")}[case]
    units = (f' unit="{unit}"', f' unit="{unit}/s"') if unit else ("", "")
    extra = [_sv(state, 10, body=f'<Real{units[0]} start="0"/>'), _sv(rate, 11, causality, f"<Real{units[1]}/>"),
             _sv(f"der({state})", 11, body=f'<Real{units[1]} derivative="14"/>')]
    derivative = '<Unknown index="16" dependencies="1 14"/>' if case == "lag-declared" else '<Unknown index="16"/>'
    with pytest.raises(FMUError, match=rf"continuous state\(s\) {state.replace('.', '[.]')} are neither positions"):
        resolve_variables(_write(tmp_path, _with_state(extra, derivative)))
