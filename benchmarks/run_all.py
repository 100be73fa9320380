"""Run every benchmark and write their tables into README.md (between the benchmark markers).

Usage: python benchmarks/run_all.py [--skip-large] [--no-readme]

Each script reports medians of several runs itself; this runner only states the machine, runs the
scripts one after another (nothing else should run meanwhile) and pastes their output verbatim.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
README = HERE.parent / "README.md"
START, END = "<!-- benchmarks:start -->", "<!-- benchmarks:end -->"

#: (title, script, arguments)
BENCHMARKS = [
    ("Reference simulator: time per step and peak memory vs n (issue: linear in n)",
     "bench_simulator.py", []),
    ("Benchmark FMU: time per doStep vs n, against the Python reference simulator",
     "bench_fmus.py", []),
    ("Snapshot recording overhead (600-mass FMU, all x, v, a) and fmpy.simulate_fmu",
     "bench_snapshots.py", []),
    ("POD time and peak memory vs n", "bench_pod.py", []),
    ("SDP fit time vs r (6000 snapshots), compressed vs direct formulation", "bench_fit.py", ["--direct-max-r", "20"]),
    ("ROM FMU vs full-order FMU, time per step", "bench_export.py", []),
    ("Python ROM evaluation, 1e5 steps at r = 10, 35, 100: loop / outputs / states", "bench_rom.py", []),
    ("Small dense kernels under oversubscription: machine's BLAS threads vs one", "bench_threads.py", []),
    ("Accuracy: fit vs intrusive POD-Galerkin and least squares (issue 14 table)", "bench_accuracy.py", []),
    ("Model exchange vs co-simulation recording cost per step", "bench_me.py", []),
    ("Dask: run table on a local cluster and distributed POD (quick variant)", "bench_dask.py", ["--quick"]),
    ("Demo wall time (both models, paper sizes)", None, ["demo"]),
    ("Large model: anchored chain g = 250000 through the whole pipeline", "bench_large.py", []),
]


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        memory = int(re.search(r"MemTotal:\s+(\d+)", Path("/proc/meminfo").read_text()).group(1)) / 2**20
    except (OSError, AttributeError):
        memory = float("nan")
    return (f"{cpu}, {os.cpu_count()} cores, {memory:.0f} GiB, {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}; {datetime.date.today().isoformat()}")


def run(script: str | None, arguments: list[str]) -> tuple[str, float]:
    start = time.perf_counter()
    if script is None:
        with_tmp = ["fmu-opinf", "demo", "-o", str(HERE / ".demo-bench"), "--quiet"]
        done = subprocess.run(with_tmp, capture_output=True, text=True)
        text = f"fmu-opinf demo: {time.perf_counter() - start:.1f} s wall time (exit code {done.returncode})"
        return text, time.perf_counter() - start
    done = subprocess.run([sys.executable, str(HERE / script), *arguments], capture_output=True, text=True)
    text = done.stdout.strip() or done.stderr.strip()[-2000:]
    return text, time.perf_counter() - start


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-large", action="store_true", help="skip the g = 250000 run (about 10 minutes)")
    parser.add_argument("--no-readme", action="store_true", help="print only, do not edit README.md")
    args = parser.parse_args(argv)
    parts = [START, "", f"Measured with `python benchmarks/run_all.py` on: {machine()}.", ""]
    for title, script, arguments in BENCHMARKS:
        if args.skip_large and script == "bench_large.py":
            continue
        print(f"running {script or 'demo'} ...", flush=True)
        text, seconds = run(script, arguments)
        parts += [f"**{title}** (`{script or 'fmu-opinf demo'}`, {seconds:.0f} s)", "", "```", text, "```", ""]
        print(text, flush=True)
    parts.append(END)
    block = "\n".join(parts)
    if not args.no_readme:
        readme = README.read_text()
        if START in readme and END in readme:
            readme = readme[:readme.index(START)] + block + readme[readme.index(END) + len(END):]
        else:
            readme = readme.rstrip() + "\n\n## Benchmarks\n\n" + block + "\n"
        README.write_text(readme)
    return block


if __name__ == "__main__":
    main()
