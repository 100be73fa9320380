"""Issue 14 goal on the paper's benchmarks: the default fit (SDP + output-error refinement) is stable and at most 2x
the error of the better of intrusive POD-Galerkin and (stable) unconstrained least squares on the same basis.

The references are independent of the fit: POD-Galerkin uses the true system matrices, least squares the plain
normal equations, and all errors are eq. (19) against the reference simulator (benchmarks/bench_accuracy.py).
"""

import importlib.util
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_accuracy.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_accuracy", _PATH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass needs the module registered
    spec.loader.exec_module(module)
    return module


def _check(figures):
    print(f"\n{figures}")
    assert figures["fit_stable"]
    assert figures["ratio"] <= 2.0


@pytest.mark.slow  # about 10 s idle, 20 s under load: four full-model test runs and the refinement
def test_anchored_chain_r5_is_within_2x_of_the_best_reference(bench):
    figures = bench.row("anchored", 5)
    _check(figures)
    assert figures["fit"] < figures["lstsq"]  # measured 6e-9 against 2e-7: the refinement, not luck of the SDP


@pytest.mark.slow
def test_triple_chain_r10_is_within_2x_of_the_best_reference(bench):
    figures = bench.row("triple", 10)
    _check(figures)
    # the plain SDP (eq. 16 with the Mr >= I normalization) is 20x above least squares here
    plain = bench.max_error("triple", bench.fit_rom_default("triple", 10, refine=False))
    assert plain > 5 * figures["lstsq"]
