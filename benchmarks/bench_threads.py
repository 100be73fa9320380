"""Small dense kernels under oversubscription: the machine's BLAS threads against the one thread the tool uses.

Usage: python benchmarks/bench_threads.py [--busy 2] [--repeats 5]

``--busy`` background processes spin on the CPU (a second model of the demo, a C compiler, other users' jobs)
while each kernel runs, first with the BLAS pools at the machine's core count, then with one thread
(:func:`fmu_opinf._threads.single_threaded`, which the tool applies to these kernels).  Kernels, all of the
sizes the demo and issue 16 met:

* ``pod-svd``: :func:`fmu_opinf.basis.svdvals`-sized SVD of a 600 x 201 snapshot matrix (the anchored chain);
* ``qr``: the QR of a 600 x 193 matrix (issue 16: 2.8-5 s with two threads under load);
* ``rom-400``: :meth:`SecondOrderROM.simulate` of a random stable ROM with r = 36 over 400 steps (the demo's
  test run), with the tool's own thread limit switched off for the first column;
* ``rom-1e5``: the same over 1e5 steps.

Figures are the median wall time of ``--repeats`` runs, then their ratio; for the ROM also how far its outputs
differ between the two thread counts without the limit (with it they are the same bits whatever the caller's
pools: ``tests/test_rom_speed.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import statistics
import time

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits


def _spin(stop: multiprocessing.Event) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def _rom(r: int):
    from fmu_opinf.rom import SecondOrderROM

    rng = np.random.default_rng(0)

    def spd(scale: float) -> np.ndarray:
        a = rng.standard_normal((r, r))
        return a @ a.T / r + scale * np.eye(r)

    return SecondOrderROM(spd(1.0), spd(0.02), spd(1.0), rng.standard_normal((r, 1)), rng.standard_normal((1, r)),
                          np.zeros((1, r)))


def _median_seconds(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--busy", type=int, default=2, help="spinning background processes")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    import fmu_opinf._threads as threads

    rng = np.random.default_rng(1)
    snapshots, tall = rng.standard_normal((600, 201)), rng.standard_normal((600, 193))
    rom = _rom(36)
    kernels = {
        "pod-svd": lambda: scipy.linalg.svd(snapshots, full_matrices=False),
        "qr": lambda: scipy.linalg.qr(tall, mode="economic"),
        "rom-400": lambda: rom.simulate("harmonic:amplitude=1,omega=0.2", 1.0, 400.0),
        "rom-1e5": lambda: rom.simulate("harmonic:amplitude=1,omega=0.2", 0.05, 5000.0),
    }
    cores = os.cpu_count() or 1
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.busy)]
    for worker in workers:
        worker.start()
    print(f"{cores} cores, {args.busy} spinning background processes; median wall seconds of {args.repeats} runs")
    print(f"{'kernel':>8} | {f'{cores} threads':>11} | {'1 thread':>9} | ratio")
    try:
        outputs = {}
        for name, kernel in kernels.items():
            seconds = {}
            for count in (cores, 1):
                unlimited = contextlib.ExitStack()
                if count > 1:  # switch off the tool's own limit to see what it avoids
                    unlimited.enter_context(_patched(threads, "single_threaded", contextlib.nullcontext))
                with unlimited, threadpool_limits(limits=count):
                    seconds[count] = _median_seconds(kernel, args.repeats)
                    if name.startswith("rom"):
                        outputs[count] = kernel().y
            differ = ""
            if name.startswith("rom"):
                gap = float(np.max(np.abs(outputs[cores] - outputs[1])) / np.max(np.abs(outputs[1])))
                differ = f" | outputs differ by {gap:.1e} (relative)"
            print(f"{name:>8} | {seconds[cores]:11.4f} | {seconds[1]:9.4f} | {seconds[cores] / seconds[1]:5.1f}"
                  + differ, flush=True)
    finally:
        stop.set()
        for worker in workers:
            worker.join()


@contextlib.contextmanager
def _patched(module, name: str, value):
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


if __name__ == "__main__":
    main()
