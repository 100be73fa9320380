"""Audit 79a, F3: an FMU that logs on every derivative call whatever ``loggingOn`` says.

Its messages (status OK) are counted and dropped before their strings reach Python (:mod:`fmu_opinf.sources._fmu_log`),
and a slow run's warning names the logging -- messages per derivative call, the estimated share of the time, the fix
(an exporter's build without debug logging, the FMU's log categories) -- instead of --me-method linear.  The FMU is
the audit's: a 5-mass chain whose ``fmi2GetDerivatives`` sends 100 lines through the logger (a test-side C patch of
the :mod:`fmu_opinf.lti_fmus` sources, compiled by the tool as a source-only FMU)."""

from __future__ import annotations

import warnings
import zipfile

import numpy as np
import pytest

from fmu_opinf.errors import FmuOpinfWarning

LINES = 100
_CALL = "    return finish(inst, ltiDerivatives(inst, \"{}\", derivatives));\n"
_DERIVATIVES = {"2.0": "fmi2GetDerivatives", "3.0": "fmi3GetContinuousStateDerivatives"}
_CHATTER = """    { int k; char msg[200];
      for (k = 0; k < %d; k++) { snprintf(msg, sizeof msg, "solver trace %%d at t=%%.17g: residual ok", k, inst->time);
        forwardLog(inst, LtiOK, "logAll", msg); } }
"""


def _build(folder, lines: int, version: str = "2.0"):
    """The audit's case-4 FMU (model exchange, sources only) with ``lines`` messages per derivative call."""
    from fmu_opinf.fmus import find_build_tools
    from fmu_opinf.lti_fmus import build_lti_fmu, chain_model

    if find_build_tools() is None:
        pytest.skip("needs a C compiler")
    base = folder / "base.fmu"
    build_lti_fmu(chain_model(5, inputs=(4,), name="Sampled"), base, naming="modelica", interfaces=("me",),
                  fmi_version=version)
    with zipfile.ZipFile(base) as z:
        files = {i.filename: z.read(i.filename) for i in z.infolist() if not i.filename.startswith("binaries/")}
    member, call = f"sources/lti_fmi{version[0]}.c", _CALL.format(_DERIVATIVES[version])
    c = files[member].decode()
    assert call in c
    if lines:
        c = "#include <stdio.h>\n" + c.replace(call, _CHATTER % lines + call)
    files[member] = c.encode()
    path = folder / f"Chatty{lines}_{version[0]}.fmu"
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
    return path


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("chatty")
    return {(lines, version): _build(folder, lines, version) for lines, version in ((LINES, "2.0"), (0, "2.0"),
                                                                                   (LINES, "3.0"))}


def _open(path):
    from fmu_opinf.sources import open_source

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FmuOpinfWarning)   # (compiled from its sources)
        return open_source(path, interface="me")


@pytest.mark.fmu
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_messages_are_counted_per_instance(fmus, version):
    """Each derivative call adds exactly 100 dropped messages to its own instance's count, none to another's."""
    chatty, plain = _open(fmus[LINES, version]), _open(fmus[0, "2.0"])
    try:
        t = np.arange(0.0, 1.0001, 0.1)
        for source in (chatty, plain):
            source.start(t, np.zeros((source.m, t.size)))
        before, quiet = chatty.quiet_messages(), plain.quiet_messages()
        for _ in range(7):
            chatty._derivatives(0.0, np.zeros(chatty.nx))
            plain._derivatives(0.0, np.zeros(plain.nx))
        assert chatty.quiet_messages() - before == 7 * LINES
        assert plain.quiet_messages() == quiet == 0
    finally:
        chatty.close()
        plain.close()


def _slow_run_warning(path, monkeypatch) -> str:
    from fmu_opinf.snapshots import record
    from fmu_opinf.sources import _integrators

    monkeypatch.setattr(_integrators, "_SLOW_RUN_INTEGRATOR_SECONDS", 0.0)   # the first block of steps says it
    source = _open(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        record(source, "impulse:amplitude=100,t0=0.5,width=0.5", 0.05, 3.0, quiet=True, isolate=False)
    (text,) = [str(w.message) for w in caught if "has spent over" in str(w.message)]
    return " ".join(text.split())


@pytest.mark.fmu
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_the_slow_run_warning_names_the_logging_first(fmus, monkeypatch, version):
    """The warning names the count, 100 per derivative call, the estimated share and the exporter's debug build, and
    not --me-method linear.  Before: "the time is the FMU's derivative ... or --me-method linear"."""
    path = fmus[LINES, version]
    text = _slow_run_warning(path, monkeypatch)
    after = text.split(" s: ", 1)[1]
    assert after.startswith(f"{path.name} logged "), text
    assert "(100 per derivative call) although fmu-opinf instantiates it with logging off" in text
    assert "ask its exporter for a build without debug logging" in text
    assert "--me-method linear" not in text and "the time is the FMU's derivative" not in text


@pytest.mark.fmu
def test_the_same_fmu_without_logging_keeps_the_derivative_advice(fmus, monkeypatch):
    text = _slow_run_warning(fmus[0, "2.0"], monkeypatch)
    assert "logged" not in text and "debug logging" not in text
