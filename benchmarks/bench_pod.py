"""POD time and peak memory vs n: dense SVD when the data fit, streamed method of snapshots otherwise.

Usage: python benchmarks/bench_pod.py [--sizes 600 10000 100000 1000000] [--steps 200] [--repeats 3]

For each n a training run of the anchored chain (impulse input, ``steps`` steps) is recorded to an HDF5
file; then, in a fresh child process per repetition, the r = 5 POD basis is computed from the file opened
lazily (the size decides dense or streamed) and the positions are projected chunk by chunk.
Reported: median wall time, the method used, and the child's peak resident memory.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from fmu_opinf import basis, snapshots
path, max_memory = sys.argv[1], float(sys.argv[2])
start = time.perf_counter()
with snapshots.Snapshots.open(path) as snaps:
    pod = basis.PODBasis(r=5, kind="positions", max_memory=max_memory).fit(snaps)
    reduced = [pod.project(run.x) for run in snaps.runs]
seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "method": pod.method_,
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[600, 10_000, 100_000, 1_000_000])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-memory", type=float, default=1e9, help="bytes the dense SVD may use")
    parser.add_argument("--workdir", help="folder for the temporary snapshot files")
    args = parser.parse_args(argv)
    from fmu_opinf import snapshots

    rows = []
    for g in args.sizes:
        with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
            path = Path(tmp) / "train.h5"
            snapshots.record_to_file("builtin:anchored-msd", path, ["impulse:amplitude=100,t0=2,width=0.5"],
                                     dt=0.5, t_end=0.5 * args.steps, g=g, quiet=True, isolate=False)
            runs = []
            for _ in range(args.repeats):
                done = subprocess.run([sys.executable, "-c", CHILD, str(path), str(args.max_memory)],
                                      check=True, capture_output=True, text=True)
                runs.append(json.loads(done.stdout))
            rows.append({"n": g, "k": args.steps + 1, "seconds": statistics.median(r["seconds"] for r in runs),
                         "method": runs[0]["method"], "peak_rss_mib": max(r["peak_rss_mib"] for r in runs),
                         "file_mib": path.stat().st_size / 2**20})
        row = rows[-1]
        print(f"n={row['n']:>8} k={row['k']:>5} {row['method']:>20} {row['seconds']:8.2f} s "
              f"peak {row['peak_rss_mib']:8.1f} MiB (file {row['file_mib']:.0f} MiB)", flush=True)
    return rows


if __name__ == "__main__":
    main()
