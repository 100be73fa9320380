"""Large-model run: the anchored chain at g = 250000 through snapshots, streamed POD, fit and test.

Usage: python benchmarks/bench_large.py [--g 250000] [--steps 1000] [--dt 0.5] [--r 5] [--workdir DIR]

Training: impulse-like input, ``steps`` Newmark steps recorded (x, x', x'' streamed to an HDF5 file:
about 6 GB at the defaults). The ROM is fitted from the file read chunk by chunk (method of snapshots
for the POD, chunked projection), then compared with the full model on the harmonic test input.
Each stage runs in its own child process so that its peak resident memory (ru_maxrss) is its own.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

STAGES = {
    "snapshots": r"""
from fmu_opinf import snapshots
snapshots.record_to_file("builtin:anchored-msd", OUT / "train.h5", ["impulse:amplitude=100,t0=2,width=0.5"],
                         dt=ARGS["dt"], t_end=ARGS["dt"] * ARGS["steps"], g=ARGS["g"], overwrite=True,
                         quiet=True, isolate=False)
""",
    "fit": r"""
from fmu_opinf import fit
model = fit.fit_rom_file(OUT / "train.h5", OUT / "rom.h5", r=ARGS["r"], overwrite=True, quiet=True,
                         keep_basis=False, max_memory=ARGS["max_memory"])
RESULT.update(r=model.r, pod_method=model.fit_info.get("pod_method"), status=model.fit_info.get("status"),
              solve_seconds=model.fit_info.get("solve_seconds"))
""",
    "compare": r"""
from fmu_opinf import compare
result = compare.compare(OUT / "rom.h5", "builtin:anchored-msd", "harmonic:amplitude=1,omega=0.2",
                         dt=ARGS["dt"], t_end=ARGS["test_t_end"], quiet=True, source_options={"g": ARGS["g"]})
RESULT.update(result.metrics())
RESULT.pop("fom"); RESULT.pop("rom"); RESULT.pop("per_output")
""",
}

CHILD = r"""
import json, resource, sys, time
from pathlib import Path
ARGS = json.loads(sys.argv[1]); OUT = Path(ARGS["workdir"]); RESULT = {}
start = time.perf_counter()
exec(sys.argv[2])
RESULT["seconds"] = time.perf_counter() - start
RESULT["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps(RESULT))
"""


def run_stage(name: str, args: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(args), STAGES[name]],
                          capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"stage {name} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--g", type=int, default=250_000)
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--dt", type=float, default=0.5)
    parser.add_argument("--r", type=int, default=5)
    parser.add_argument("--test-t-end", type=float, default=400.0)
    parser.add_argument("--max-memory", type=float, default=1e9, help="bytes the POD may hold at once")
    parser.add_argument("--workdir", help="where the snapshot and ROM files go (default: a temporary folder)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        settings = {"g": args.g, "steps": args.steps, "dt": args.dt, "r": args.r, "test_t_end": args.test_t_end,
                    "max_memory": args.max_memory, "workdir": tmp}
        results = {}
        for stage in STAGES:
            results[stage] = run_stage(stage, settings)
            if stage == "snapshots":
                results[stage]["file_gib"] = (Path(tmp) / "train.h5").stat().st_size / 2**30
            print(f"{stage:>10}: {json.dumps(results[stage])}", flush=True)
    peak = max(r["peak_rss_gib"] for r in results.values())
    print(f"g={args.g}: peak memory {peak:.2f} GiB, max eps_y on the test input "
          f"{results['compare']['max_error']:.2e}")
    return results


if __name__ == "__main__":
    main()
