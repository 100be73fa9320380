"""A model description is parsed once per process, and a source's copy in a child process does not parse it again.

Audit 81a, F1: Modelica exports of big models carry 10-50 MB model descriptions; a 17 MB one was parsed about five
times per source (fmpy's lenient and strict readings, the XML for the variables and for the constraint annotation)
and again in every isolated run's child process: 75 s for a recording that takes 2.5 s with a small description.
The counts here are of the parsers themselves (fmpy's reader and ElementTree), patched with counters; the recordings
are checked against the FMU's exact zero-order-hold response (:func:`fmu_opinf.lti_fmus.zoh_response`).
"""

from __future__ import annotations

import os
import pickle
import shutil
import xml.etree.ElementTree as ET
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

import fmpy  # noqa: E402

from fmu_opinf import lti_fmus  # noqa: E402
from fmu_opinf.snapshots import record  # noqa: E402
from fmu_opinf.sources import _variables, open_source  # noqa: E402

pytestmark = pytest.mark.fmu

if lti_fmus.find_build_tools() is None:
    pytest.skip("CMake and a C compiler are needed to build FMUs", allow_module_level=True)

SIGNAL = "impulse:amplitude=100,t0=2,width=0.5"


@pytest.fixture(scope="module")
def corpus(request, tmp_path_factory) -> dict[str, lti_fmus.LtiFmu]:
    cache = getattr(request.config, "cache", None)
    folder = cache.mkdir("lti-corpus") if cache is not None else tmp_path_factory.mktemp("lti")
    return lti_fmus.build_corpus(folder, ("me-only", "cs-euler"))


@pytest.fixture
def parses(monkeypatch) -> dict[str, int]:
    """Counts of fmpy's reads and of ElementTree's parses from here on, with this process's descriptions
    forgotten (as in a fresh process)."""
    counts = {"fmpy": 0, "etree": 0}
    read, fromstring, parse = fmpy.read_model_description, ET.fromstring, ET.parse

    def counted(function, what):
        def wrapper(*args, **kwargs):
            counts[what] += 1
            return function(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(fmpy, "read_model_description", counted(read, "fmpy"))
    monkeypatch.setattr(ET, "fromstring", counted(fromstring, "etree"))
    monkeypatch.setattr(ET, "parse", counted(parse, "etree"))
    for name in ("_PARSED", "_DESCRIPTIONS"):   # (the older cache's name too: the test fails, not errs, on it)
        if hasattr(_variables, name):
            monkeypatch.setattr(_variables, name, OrderedDict())
    return counts


def forget() -> None:
    """Forget this process's parsed descriptions: what a child process of the fork server or a spawned one starts
    with."""
    for name in ("_PARSED", "_DESCRIPTIONS"):
        getattr(_variables, name, {}).clear()


def exact_miss(run, model) -> float:
    """Largest output error of a recorded run against the exact response, relative to the output range."""
    u = np.asarray(run.u)
    exact = lti_fmus.zoh_response(model, np.asarray(run.t), u[:, 1:]).y
    y = np.asarray(run.y)
    return float(np.abs(y - exact).max() / np.ptp(exact))


@pytest.mark.parametrize("name", ["me-only", "cs-euler"])
def test_a_recording_with_an_isolated_run_parses_the_description_once(corpus, parses, name):
    fmu = corpus[name]
    snaps = record(str(fmu.path), SIGNAL, 0.05, 20.0, quiet=True, isolate=True)
    # one strict fmpy reading (which is also the lenient one) and one XML parse for the variables; before: two of
    # each per source (plus the child's own)
    assert parses == {"fmpy": 1, "etree": 1}
    if name == "me-only":   # (cs-euler is one explicit Euler step per communication step: not the exact response)
        assert exact_miss(snaps.runs[0], fmu.model) < 1e-8


@pytest.mark.parametrize("name", ["me-only", "cs-euler"])
def test_a_copy_in_another_process_takes_the_parse_and_records_the_same_bits(corpus, parses, name):
    source = open_source(str(corpus[name].path))
    payload = pickle.dumps(source)
    before = dict(parses)
    forget()
    copy = pickle.loads(payload)
    assert parses == before      # nothing parsed again
    assert type(copy) is type(source) and copy.position_names == source.position_names
    assert len(copy.md.modelVariables) <= len(source.md.modelVariables)
    original = record(source, SIGNAL, 0.05, 20.0, quiet=True)
    again = record(copy, SIGNAL, 0.05, 20.0, quiet=True)
    for field in ("x", "xdot", "y"):
        assert np.asarray(getattr(again.runs[0], field)).tobytes() == np.asarray(
            getattr(original.runs[0], field)).tobytes()
    if name == "me-only":
        assert exact_miss(again.runs[0], corpus[name].model) < 1e-8


def test_a_changed_fmu_is_read_again_by_the_copy(corpus, parses, tmp_path):
    from conftest import rewrite_description

    path = tmp_path / "chain.fmu"
    shutil.copy(corpus["me-only"].path, path)
    payload = pickle.dumps(open_source(str(path)))
    rewrite_description(corpus["me-only"].path, path,   # a new export under the same name
                        lambda text: text.replace('description="linear', 'description="re-exported linear', 1))
    forget()
    counted = dict(parses)
    copy = pickle.loads(payload)
    assert parses["fmpy"] == counted["fmpy"] + 1   # read again, not taken from the handover
    assert copy.md.description.startswith("re-exported")


def test_the_parse_is_kept_per_file_state(corpus, parses, tmp_path):
    path = tmp_path / "chain.fmu"
    shutil.copy(corpus["me-only"].path, path)
    for _ in range(3):
        open_source(str(path))
    assert parses == {"fmpy": 1, "etree": 1}
    Path(path).write_bytes(Path(path).read_bytes())   # rewritten in place: another change time
    os.utime(path, ns=(2, 2))
    open_source(str(path))
    assert parses == {"fmpy": 2, "etree": 2}
