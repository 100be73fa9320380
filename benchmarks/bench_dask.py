"""Scale-out on Dask (issue 17): a run table recorded on a local cluster of 2 workers vs sequentially, and the
distributed POD + projections of a 1e6-DOF, 8-run snapshot set with the peak memory of every process.

Usage: python benchmarks/bench_dask.py [--quick] [--workers 2] [--workdir DIR] [--json FILE]

Part 1 (recording): 8 rows of ``builtin:anchored-msd`` at g = 1e5 (``--quick``: 2e4), 200 Newmark steps each
(impulses and harmonics of different sizes), recorded with ``record_runs`` once without a scheduler (one
process, rows one after another) and once with ``scheduler="local:2"``; the wall time of the parallel form
includes starting the cluster.  The files of both must agree (max relative difference).

Part 2 (distributed POD): 8 rows at g = 1e6 (``--quick``: 1e5), 50 steps each, recorded on the cluster; then
``fit_rom_file`` on the per-run set with an active client (the POD is TSQR on dask arrays in row blocks of at most
``--max-memory / 4`` bytes, the projections ``V^T X, V^T X', V^T X''`` run on the workers, only the r = 5 fit on
the client).  Every stage runs in a fresh child process; its peak resident memory (ru_maxrss) and each worker's
are reported.  ``--quick`` also checks the distributed basis against the dense in-core SVD (subspace angle).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

INPUTS = [
    "impulse:amplitude=100,t0=2,width=0.5", "impulse:amplitude=60,t0=5,width=1.5",
    "impulse:amplitude=150,t0=1,width=0.8", "impulse:amplitude=80,t0=8,width=3",
    "harmonic:amplitude=1,omega=0.05", "harmonic:amplitude=2,omega=0.11",
    "harmonic:amplitude=0.5,omega=0.2", "chirp:amplitude=1,omega0=0.01,omega1=0.3",
]

# Each stage is a child process: its ru_maxrss is its own, and the workers it starts are its children.
CHILD = r"""
import json, resource, sys, time
from pathlib import Path
ARGS = json.loads(sys.argv[1]); OUT = Path(ARGS["workdir"]); RESULT = {}

def rss_gib():
    import os
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**30

def worker_peaks(client):
    def peak():
        import resource
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    return sorted(client.run(peak).values())

def main():
    import os
    RESULT["load_before"] = os.getloadavg()[0]
    start = time.perf_counter()
    exec(STAGE, globals())
    RESULT["seconds"] = time.perf_counter() - start
    RESULT["client_peak_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    RESULT["load_after"] = os.getloadavg()[0]
    print(json.dumps(RESULT))

STAGE = sys.argv[2]
if __name__ == "__main__":
    main()
"""

STAGES = {
    "record-sequential": r"""
from fmu_opinf import runs
report = runs.record_runs("builtin:anchored-msd", OUT / "table.csv", OUT / "seq", dt=ARGS["dt"],
                          t_end=ARGS["dt"] * ARGS["steps"], g=ARGS["g"], quiet=True)
report.raise_for_failures()
RESULT["per_run_seconds"] = [o.seconds for o in report.outcomes]
RESULT["per_run_cpu_seconds"] = [o.cpu_seconds for o in report.outcomes]
""",
    "record-parallel": r"""
from fmu_opinf import runs
t0 = time.perf_counter()
with runs.dask_client(f"local:{ARGS['workers']}") as client:
    RESULT["cluster_start_seconds"] = time.perf_counter() - t0
    report = runs.record_runs("builtin:anchored-msd", OUT / "table.csv", OUT / ARGS["target"], dt=ARGS["dt"],
                              t_end=ARGS["dt"] * ARGS["steps"], g=ARGS["g"], quiet=True, scheduler=client)
    RESULT["worker_peak_gib"] = worker_peaks(client)
report.raise_for_failures()
RESULT["table_seconds"] = report.seconds
RESULT["per_run_seconds"] = [o.seconds for o in report.outcomes]
RESULT["per_run_cpu_seconds"] = [o.cpu_seconds for o in report.outcomes]
RESULT["workers_used"] = len({o.worker for o in report.outcomes})
""",
    "compare-files": r"""
import numpy as np
from fmu_opinf.basis import open_snapshot_set
worst = 0.0
with open_snapshot_set(OUT / "seq", dask=False) as a, open_snapshot_set(OUT / "par", dask=False) as b:
    for ra, rb in zip(a.runs, b.runs):
        for name in ("x", "xdot", "xddot", "y"):
            xa, xb = np.asarray(getattr(ra, name)[()]), np.asarray(getattr(rb, name)[()])
            worst = max(worst, float(np.abs(xa - xb).max() / max(np.abs(xa).max(), 1e-300)))
RESULT["max_relative_difference"] = worst
""",
    "distributed-fit": r"""
import numpy as np, resource
from fmu_opinf import runs
from fmu_opinf.basis import open_snapshot_set, _block_shape
from fmu_opinf.fit import fit_rom_file
from distributed import get_task_stream
with runs.dask_client(f"local:{ARGS['workers']}") as client:
    RESULT["client_rss_at_start_gib"] = rss_gib()
    t0 = time.perf_counter()
    with get_task_stream(client) as stream:
        rom = fit_rom_file(OUT / "pod", OUT / "rom.h5", r=5, quiet=True, overwrite=True,
                           max_memory=ARGS["max_memory"])
    RESULT["fit_seconds"] = time.perf_counter() - t0
    RESULT["client_rss_after_fit_gib"] = rss_gib()
    RESULT["client_peak_during_fit_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    RESULT["worker_peak_gib"] = worker_peaks(client)
tasks = {}
for task in stream.data:  # compute time per task kind (read a block, block QR, products, ...)
    prefix = task["key"][0] if isinstance(task["key"], tuple) else task["key"]
    prefix = str(prefix).rsplit("-", 1)[0]
    spent = sum(s["stop"] - s["start"] for s in task["startstops"] if s["action"] == "compute")
    count, seconds = tasks.get(prefix, (0, 0.0))
    tasks[prefix] = (count + 1, seconds + spent)
RESULT["tasks"] = {k: {"count": c, "seconds": round(t, 3)} for k, (c, t) in sorted(tasks.items(), key=lambda kv: -kv[1][1])[:12]}
info = rom.fit_info
RESULT.update(pod_method=info["pod_method"], n=info["n"], k=info["k"], r=rom.r, status=info["status"])
with open_snapshot_set(OUT / "pod", dask=True, max_memory=ARGS["max_memory"]) as snaps:
    RESULT["block_rows_aligned"] = int(max(snaps.runs[0].x.chunks[0]))
import h5py
with h5py.File(sorted((OUT / "pod").glob("*.h5"))[0], "r") as f:
    RESULT["file_chunks"] = list(next(iter(f["runs"].values()))["x"].chunks)
rows, cols = _block_shape(info["n"], info["k"], ARGS["max_memory"])
RESULT["block_rows"], RESULT["blocks"] = rows, -(-info["n"] // rows)
RESULT["data_gib_per_array"] = info["n"] * info["k"] * 8 / 2**30
RESULT["basis_file"] = str(OUT / "rom.h5")
""",
    "incore-check": r"""
import numpy as np, scipy.linalg
from fmu_opinf.basis import PODBasis, open_snapshot_set
from fmu_opinf.rom import SecondOrderROM
rom = SecondOrderROM.load(OUT / "rom.h5")
with open_snapshot_set(OUT / "pod", dask=False) as snaps:
    ref = PODBasis(r=rom.r, kind=rom.basis_kind, max_memory=1e12).fit(snaps)
RESULT["incore_method"] = ref.method_
RESULT["subspace_angle"] = float(np.max(scipy.linalg.subspace_angles(rom.basis, ref.basis_)))
""",
}


def run_stage(name: str, args: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(args), STAGES[name]], capture_output=True,
                          text=True)
    if done.returncode:
        raise SystemExit(f"stage {name} failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"  {name}: {json.dumps(result)}", file=sys.stderr, flush=True)
    return result


def write_table(folder: Path) -> None:
    rows = ["name,input"] + [f'run{i + 1},"{spec}"' for i, spec in enumerate(INPUTS)]
    (folder / "table.csv").write_text("\n".join(rows) + "\n")


def recording(base: dict, g: int, steps: int) -> dict:
    args = {**base, "g": g, "steps": steps, "target": "par"}
    out = {"seq": run_stage("record-sequential", args), "par": run_stage("record-parallel", args),
           "check": run_stage("compare-files", args)}
    out["speedup"] = out["seq"]["seconds"] / out["par"]["seconds"]
    out["speedup_without_start"] = out["seq"]["seconds"] / out["par"]["table_seconds"]
    return out


def distributed_pod(base: dict, g: int, steps: int, check: bool) -> dict:
    args = {**base, "g": g, "steps": steps, "target": "pod", "check": check}
    out = {"record": run_stage("record-parallel", args), "fit": run_stage("distributed-fit", args)}
    if check:
        out["check"] = run_stage("incore-check", args)
    return out


def _mean(values: list) -> float:
    return sum(values) / max(len(values), 1)


def report(results: dict) -> str:
    rec, pod = results["recording"], results["pod"]
    fit = pod["fit"]
    lines = [
        f"{'stage':<44} {'wall [s]':>9} {'peak/process [GiB]':>20}",
        f"{'record 8 runs, g=%d, sequential' % results['g1']:<44} {rec['seq']['seconds']:>9.1f} "
        f"{rec['seq']['client_peak_gib']:>20.2f}",
        f"{'record 8 runs, g=%d, local:%d' % (results['g1'], results['workers']):<44} {rec['par']['seconds']:>9.1f} "
        f"{max(rec['par']['worker_peak_gib']):>20.2f}",
        f"{'  of which cluster start':<44} {rec['par']['cluster_start_seconds']:>9.1f}",
        f"{'record 8 runs, g=%d, local:%d' % (results['g2'], results['workers']):<44} "
        f"{pod['record']['seconds']:>9.1f} {max(pod['record']['worker_peak_gib']):>20.2f}",
        f"{'distributed POD + projections + fit (workers)':<44} {fit['fit_seconds']:>9.1f} "
        f"{max(fit['worker_peak_gib']):>20.2f}",
        f"{'  client (scheduler, fit)':<44} {'':>9} {fit['client_peak_gib']:>20.2f}",
        "",
        f"recording speed-up {rec['speedup']:.2f}x (without cluster start {rec['speedup_without_start']:.2f}x), "
        f"files equal to {rec['check']['max_relative_difference']:.1e} (relative)",
        f"per run (wall / CPU): {_mean(rec['seq']['per_run_seconds']):.2f}s / "
        f"{_mean(rec['seq']['per_run_cpu_seconds']):.2f}s at g={results['g1']} (sequential), "
        f"{_mean(rec['par']['per_run_seconds']):.2f}s / {_mean(rec['par']['per_run_cpu_seconds']):.2f}s on a worker; "
        f"{_mean(pod['record']['per_run_seconds']):.2f}s / {_mean(pod['record']['per_run_cpu_seconds']):.2f}s at "
        f"g={results['g2']} on a worker",
        "1-min load average of the machine at the stage starts: "
        + ", ".join(f"{r['load_before']:.1f}" for r in (rec["seq"], rec["par"], pod["record"], fit)),
        f"POD: {fit['pod_method']}, n={fit['n']}, k={fit['k']}, {fit['data_gib_per_array']:.2f} GiB per array, "
        f"row blocks of {fit['block_rows_aligned']} rows (budget {fit['block_rows']}, file chunks "
        f"{fit['file_chunks']}), max_memory={results['max_memory']:.0e}",
    ]
    lines.append("worker compute time by task kind (count, seconds): " + ", ".join(
        f"{k} ({v['count']}, {v['seconds']:.1f})" for k, v in list(fit.get("tasks", {}).items())[:6]))
    if "check" in pod:
        lines.append(f"distributed vs in-core ({pod['check']['incore_method']}) basis: subspace angle "
                     f"{pod['check']['subspace_angle']:.1e}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="g = 2e4 / 1e5 instead of 1e5 / 1e6")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--max-memory", type=float, help="POD memory budget in bytes (default 1e9; quick: 2e8)")
    parser.add_argument("--workdir", help="where the files go (default: a temporary folder)")
    parser.add_argument("--json", help="also write the results to this file")
    args = parser.parse_args(argv)
    g1, g2 = (20_000, 100_000) if args.quick else (100_000, 1_000_000)
    args.max_memory = args.max_memory or (2e8 if args.quick else 1e9)
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        write_table(Path(tmp))
        base = {"workdir": tmp, "dt": 0.5, "workers": args.workers, "max_memory": args.max_memory}
        results = {"g1": g1, "g2": g2, "workers": args.workers, "max_memory": args.max_memory, "quick": args.quick}
        results["recording"] = recording(base, g1, 200)
        results["pod"] = distributed_pod(base, g2, 50, check=args.quick)
    text = report(results)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    main()
