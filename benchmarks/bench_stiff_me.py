"""Model exchange of a stiff FE-style beam: the exact hold step (``--me-method auto``/``linear``) against DOP853.

Usage: python benchmarks/bench_stiff_me.py [--elements 50 100 200] [--dt 0.01] [--t-end 2]
       [--dop853-samples 20] [--out DIR]

The model is a cantilever of ``N`` lumped-mass Euler-Bernoulli elements (``fmu_opinf.lti_fmus.build_lti_fmu``,
generic LTI-generator naming, model exchange only, dense matrices): first mode near 5 rad/s, the fastest at
2e4 / 8e4 / 3.2e5 rad/s for N = 50 / 100 / 200, Rayleigh damping ``D = 2e-4 K + 0.2 M`` (so the fastest modes are
overdamped, real eigenvalues down to -2e7), a force at the tip, tip and mid-span positions as outputs.  It is
recorded under an impulse at the CLI's default tolerance 1e-10:

* ``auto``: the default, which takes the exact zero-order-hold step of the identified Jacobian for such a model;
* ``dop853``: the explicit integrator, which the fastest mode holds to its stability limit; timed over its first
  ``--dop853-samples`` samples only (the impulse is in them) where the whole run would take too long.

Printed per row: wall seconds of the recording (Jacobian identification and matrix exponential included), seconds
per sample, the largest position error against the exact modal solution (each mode's own 2 x 2 exponential;
the modes of a stiff beam are themselves computed only to about ``eps * cond(K)``, so below about 1e-8 the
reference, not the recording, sets the figure: at N = 50 over 2 s DOP853 and ``auto`` are both 6.3e-9 off it),
and how far the positions are from ``auto``'s over the samples both recorded, relative to their peak.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

SIGNAL = "impulse:amplitude=1,t0=0.02,width=0.05"


def beam(elements: int):
    """A clamped-free beam of unit length, ``EI = 4``, unit mass per length, lumped masses."""
    from fmu_opinf import lti_fmus

    h = 1.0 / elements
    second = -2.0 * np.eye(elements) + np.eye(elements, k=1) + np.eye(elements, k=-1)
    second[-1, -1] = -1.0
    K = 4.0 / h**3 * (second.T @ second)
    M = h * np.eye(elements)
    B = np.zeros((elements, 1))
    B[-1, 0] = 1.0
    Cp = np.zeros((2, elements))
    Cp[0, -1] = Cp[1, elements // 2] = 1.0
    return lti_fmus.LinearMechanicalModel(M=M, D=2e-4 * K + 0.2 * M, K=K, B=B, Cp=Cp, name=f"Beam{elements}")


def modal_positions(model, t: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Exact positions under held inputs, mode by mode (Rayleigh damping decouples the modes)."""
    from scipy.linalg import eigh, expm

    w2, modes = eigh(model.K, model.M)
    damping = np.einsum("ji,jk,ki->i", modes, model.D, modes)
    forces = modes.T @ (model.B @ held)
    h = float(t[1] - t[0])
    maps = []
    for square, d in zip(w2, damping):
        block = np.zeros((3, 3))
        block[:2, :2] = h * np.array([[0.0, 1.0], [-square, -d]])
        block[1, 2] = h
        maps.append(expm(block))
    maps = np.array(maps)
    q = np.zeros((len(w2), len(t)))
    qd = np.zeros_like(q)
    for k in range(len(t) - 1):
        q[:, k + 1] = maps[:, 0, 0] * q[:, k] + maps[:, 0, 1] * qd[:, k] + maps[:, 0, 2] * forces[:, k]
        qd[:, k + 1] = maps[:, 1, 0] * q[:, k] + maps[:, 1, 1] * qd[:, k] + maps[:, 1, 2] * forces[:, k]
    return modes @ q


def bench(elements: int, dt: float, t_end: float, dop853_samples: int, folder: Path) -> list[tuple]:
    from fmu_opinf import lti_fmus
    from fmu_opinf.snapshots import record
    from fmu_opinf.sources import open_source

    model = beam(elements)
    path = folder / f"Beam{elements}.fmu"
    lti_fmus.build_lti_fmu(model, path, naming="generic", interfaces=("me",))
    rows, first = [], None
    plan = [("auto", t_end)] + ([("dop853", min(t_end, dop853_samples * dt))] if dop853_samples > 0 else [])
    for method, end in plan:
        started = time.perf_counter()
        run = record(open_source(path, method=method), SIGNAL, dt, end, quiet=True).runs[0]
        seconds = time.perf_counter() - started
        held = np.hstack([run.u[:, 1:], run.u[:, -1:]])
        exact = modal_positions(model, run.t, held)
        error = float(np.abs(run.x - exact).max() / np.abs(exact).max())
        chosen = run.attrs["integrator"].split(" (")[0].split(";")[0]
        first = run.x if first is None else first
        k = len(run.t)
        apart = float(np.abs(run.x - first[:, :k]).max() / np.abs(exact).max())
        rows.append((elements, method, chosen, k, seconds, seconds / k, error, apart))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--elements", type=int, nargs="+", default=[50, 100, 200])
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--t-end", type=float, default=2.0)
    parser.add_argument("--dop853-samples", type=int, default=20,
                        help="samples DOP853 records (default 20; the whole run can take hours; 0: none)")
    parser.add_argument("--out", help="folder for the FMUs (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.out or tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"{'N':>4} {'method':>7} {'integrator':>40} {'samples':>8} {'wall [s]':>9} {'s/sample':>9} "
              f"{'max x err':>10} {'vs auto':>9}")
        for elements in args.elements:
            for row in bench(elements, args.dt, args.t_end, args.dop853_samples, folder):
                print(f"{row[0]:>4} {row[1]:>7} {row[2]:>40} {row[3]:>8} {row[4]:>9.2f} {row[5]:>9.2e} "
                      f"{row[6]:>10.2e} {row[7]:>9.1e}", flush=True)


if __name__ == "__main__":
    main()
