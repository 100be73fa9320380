"""Reference simulator scaling: time per Newmark step and peak memory vs n (anchored chain).

Usage: python benchmarks/bench_simulator.py [--sizes 600 10000 100000 1000000] [--steps 200] [--repeats 3]

Each size runs in a fresh child process so that its peak resident memory (ru_maxrss) is its own.
The step loop holds only the current state (no recording), as the streaming snapshot recorder does.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
import numpy as np
from fmu_opinf import newmark, systems
g, steps, repeats = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
s = systems.anchored_msd(g=g)
t0 = time.perf_counter()
stepper = newmark.NewmarkStepper(s.M, s.D, s.K, s.B, 0.5, G=s.G, constraint=s.constraint)
setup = time.perf_counter() - t0
per_step = []
for _ in range(repeats):
    stepper.start(np.array([100.0]))
    t0 = time.perf_counter()
    for k in range(steps):
        stepper.step(np.array([100.0 if k < 2 else 0.0]))
    per_step.append((time.perf_counter() - t0) / steps)
print(json.dumps({"g": g, "setup_s": setup, "per_step_s": sorted(per_step)[len(per_step) // 2],
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def measure(g: int, steps: int, repeats: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(g), str(steps), str(repeats)],
                         check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[600, 10_000, 100_000, 1_000_000])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    rows = [measure(g, args.steps, args.repeats) for g in args.sizes]
    print(f"{'g':>9} {'setup [s]':>10} {'step [us]':>10} {'step/g [ns]':>12} {'peak RSS [MiB]':>15}")
    for row in rows:
        print(f"{row['g']:>9} {row['setup_s']:>10.3f} {row['per_step_s'] * 1e6:>10.1f} "
              f"{row['per_step_s'] / row['g'] * 1e9:>12.2f} {row['peak_rss_mib']:>15.1f}")
    return rows


if __name__ == "__main__":
    main()
