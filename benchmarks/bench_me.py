"""Recording cost per step: model exchange (fmu-opinf integrates) against co-simulation ``doStep``.

Usage: python benchmarks/bench_me.py [--g 600] [--n1 100] [--steps 200] [--methods dop853 lsoda]
       [--tolerance 1e-10] [--out DIR]
       python benchmarks/bench_me.py --rates [--g 600] [--n1 100]   (derived accelerations, bench_rates)

For each benchmark system (anchored chain with a rigid bar, triple chain) this builds an exporter-style
FMU offering both interfaces (``fmu_opinf.lti_fmus.build_lti_fmu``, dense matrices, the index reduced
by the exporter) and records the paper's impulse response through :func:`fmu_opinf.snapshots.record`:

* ``me/<method>``: model exchange at the given tolerance (default 1e-10, the CLI default); ``dop853`` is the
  compiled step loop (``fmus/integrator/erk.c``) where a C compiler is found, ``dop853-scipy`` the same method
  through :class:`scipy.integrate.DOP853`'s Python loop;
* ``cs/accurate``: the same FMU's co-simulation (RK4 substeps following the same tolerance);
* ``cs/newmark``: the project's benchmark co-simulation FMU (``fmu_opinf.fmus``, one sparse Newmark
  step per doStep), the reference cost of one ``doStep``.

Printed per row: microseconds per communication step (recording loop only, after loading), the number
of right-hand-side evaluations per step for model exchange, and the largest error of the outputs
against the exact zero-order-hold solution (``lti_fmus.zoh_response``) relative to their peak
(outputs: the positions the benchmark's ``Cp`` selects).
"""

from __future__ import annotations

import argparse
import contextlib
import tempfile
import time
from pathlib import Path

import numpy as np

IMPULSE = "impulse:amplitude=100,t0=2,width=0.5"


def lti_model(name: str, size: int):
    """The benchmark system as a dense :class:`~fmu_opinf.lti_fmus.LinearMechanicalModel`."""
    from fmu_opinf import lti_fmus, systems

    system = systems.anchored_msd(size) if name == "anchored" else systems.triple_chain(size)

    def dense(a):
        return np.asarray(a.toarray() if hasattr(a, "toarray") else a, dtype=float)

    return lti_fmus.LinearMechanicalModel(M=dense(system.M), D=dense(system.D), K=dense(system.K), B=dense(system.B),
                                          Cp=dense(system.Cp), G=dense(system.G), constraint=system.constraint,
                                          name=f"Bench{name.capitalize()}")


class _Counting:
    """Counts right-hand-side evaluations of a model-exchange source."""

    def __init__(self, source) -> None:
        self.calls = 0
        self.source = source
        original = source.rhs

        def rhs(t, x):
            self.calls += 1
            return original(t, x)

        source.rhs = rhs

    @property
    def evaluations(self) -> int:
        """Evaluations through Python plus those of the compiled loop."""
        kernel = getattr(self.source, "_kernel", None)
        return self.calls + (kernel.evaluations if kernel is not None else 0)


@contextlib.contextmanager
def _without_compiled_loop(active: bool):
    """While active, model-exchange sources use scipy's DOP853 loop instead of the compiled one."""
    from fmu_opinf.sources import _compiled_rk

    saved = _compiled_rk.kernel
    if active:
        _compiled_rk.kernel = lambda *args: None
    try:
        yield
    finally:
        _compiled_rk.kernel = saved


def time_recording(source, dt: float, steps: int) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Seconds per step of the recording loop; the run's t, u, y."""
    from fmu_opinf.snapshots import inputs_in_effect, time_grid
    from fmu_opinf.snapshots._inputs import as_signal

    t = time_grid(dt, dt * steps)
    signal = as_signal(IMPULSE, source.m, source)
    u = inputs_in_effect(signal, t, source.m)
    rows = np.empty((len(t), source.width))
    source.start(t, np.ascontiguousarray(u.T))
    try:
        start = time.perf_counter()
        source.advance(rows, 0, len(t))
        seconds = time.perf_counter() - start
    finally:
        source.close()
    return seconds / steps, t, u, rows[:, source.layout["y"]].T


def bench_system(name: str, size: int, dt: float, steps: int, methods: list[str], tolerance: float,
                 folder: Path) -> list[tuple[str, ...]]:
    from fmu_opinf import fmus, lti_fmus
    from fmu_opinf.sources import FMUSource, ModelExchangeSource

    model = lti_model(name, size)
    start = time.perf_counter()
    fmu = lti_fmus.build_lti_fmu(model, folder / f"{name}.fmu")
    build = time.perf_counter() - start
    rows = []

    def error(t, u, y) -> float:
        held = np.hstack([u[:, 1:], u[:, -1:]])
        ref = lti_fmus.zoh_response(model, t, held).y
        return float(np.abs(y - ref).max() / np.abs(ref).max())

    for method in methods:
        scipy_loop = method == "dop853-scipy"
        source = ModelExchangeSource(fmu.path, method="dop853" if scipy_loop else method, tolerance=tolerance)
        counter = _Counting(source)
        with _without_compiled_loop(scipy_loop):
            per_step, t, u, x = time_recording(source, dt, steps)
        rows.append((name, f"me/{method}", f"{per_step * 1e6:.0f}", f"{counter.evaluations / steps:.1f}",
                     f"{error(t, u, x):.1e}"))
    per_step, t, u, x = time_recording(FMUSource(fmu.path, tolerance=tolerance), dt, steps)
    rows.append((name, "cs/accurate", f"{per_step * 1e6:.0f}", "-", f"{error(t, u, x):.1e}"))
    bench = "AnchoredMSD" if name == "anchored" else "TripleChainMSD"
    kwargs = {"g": size} if name == "anchored" else {"n1": size}
    path = fmus.build_fmus(out_dir=folder / "newmark", models=[bench], **kwargs)[0]
    per_step, *_ = time_recording(FMUSource(path, positions=""), dt, steps)
    rows.append((name, "cs/newmark", f"{per_step * 1e6:.0f}", "-", "(Newmark, O(h^2))"))
    print(f"[{name}] n={model.n}: built the ME+CS FMU in {build:.1f} s", flush=True)
    return rows


def bench_rates(name: str, size: int, dt: float, t_end: float, r: int) -> list[tuple[str, ...]]:
    """Accelerations of a continuous-time recording without accelerations (issue 12): the exact zero-order-hold
    solution (``zoh_response``) of the impulse response, its accelerations derived by the Newmark-consistent
    rule and by the continuous-time rule, and the max eps_y (harmonic test input) of fits at order ``r`` (ROM
    integrator ``"exact"``) from the true accelerations, from each derived set, and from interval averages."""
    from fmu_opinf import lti_fmus
    from fmu_opinf.compare import output_error
    from fmu_opinf.fit import fit_rom
    from fmu_opinf.signals import parse_signal
    from fmu_opinf.snapshots import Run, inputs_in_effect, time_grid
    from fmu_opinf.snapshots._rates import continuous_accelerations, newmark_accelerations

    model = lti_model(name, size)

    def exact(spec: str) -> tuple[np.ndarray, lti_fmus.ZohResponse]:
        t = time_grid(dt, t_end)
        u = inputs_in_effect(parse_signal(spec, model.m), t, model.m)
        return u, lti_fmus.zoh_response(model, t, u[:, 1:])

    u, ref = exact(IMPULSE)
    test_spec = "harmonic:amplitude=1,omega=0.2"
    _, test = exact(test_spec)
    derived = {"true": ref.a, "newmark": newmark_accelerations(ref.v, dt, ref.x, u),
               "continuous": continuous_accelerations(ref.v, dt, ref.x, u)}
    rows = []
    for label, a in derived.items():
        error = np.abs(a - ref.a).max() / np.abs(ref.a).max()
        fits = {"pointwise": "pointwise"} if label != "continuous" else {"pointwise": "pointwise",
                                                                        "averages": "interval-averages"}
        for kind, rates in fits.items():
            run = Run(t=ref.t, u=u, x=ref.x, xdot=ref.v, xddot=a, y=ref.y, attrs={"fit_rates": rates})
            rom = fit_rom(run, r=r, integrator="exact")
            eps = output_error(test.y, rom.simulate(test_spec, dt, t_end).y).max()
            rows.append((name, f"{label}/{kind}", f"{error:.1e}", f"{eps:.2e}"))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--g", type=int, default=600, help="anchored chain masses (default 600)")
    parser.add_argument("--n1", type=int, default=100, help="triple chain masses per chain (default 100)")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--methods", nargs="+", default=["dop853", "dop853-scipy", "lsoda"])
    parser.add_argument("--tolerance", type=float, default=1e-10)
    parser.add_argument("--out", help="folder for the FMUs (default: a temporary one)")
    parser.add_argument("--rates", action="store_true",
                        help="instead: derived accelerations of continuous-time recordings (bench_rates)")
    args = parser.parse_args()
    if args.rates:
        rows = bench_rates("anchored", args.g, 0.5, 300.0, 5) + bench_rates("triple", args.n1, 0.1, 300.0, 35)
        print("impulse training, harmonic:amplitude=1,omega=0.2 test, ROM integrator exact; "
              "columns: system, accelerations/fit data, max rel. error of a, max eps_y")
        for row in rows:
            print("  ".join(row))
        return
    folder = Path(args.out or tempfile.mkdtemp(prefix="bench-me-"))
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    rows += bench_system("anchored", args.g, 0.5, args.steps, args.methods, args.tolerance, folder)
    rows += bench_system("triple", args.n1, 0.1, args.steps, args.methods, args.tolerance, folder)
    header = ("system", "interface", "us/step", "rhs/step", "max rel. error y")
    widths = [max(len(r[i]) for r in rows + [header]) for i in range(len(header))]
    print(f"tolerance {args.tolerance:g}, {args.steps} steps (anchored dt=0.5, triple dt=0.1), impulse {IMPULSE}")
    for row in [header] + rows:
        print("  ".join(value.ljust(width) for value, width in zip(row, widths)))


if __name__ == "__main__":
    main()
