"""Benchmark: ``fmu-opinf snapshots`` of an FMU with a large model description against the same FMU with a small one.

Modelica exports of big models carry 10-50 MB model descriptions (tens of thousands of parameters and locals).  The
tool parses a description once per process and hands its isolated runs what it found (audit 81a, F1: a 17 MB
description parsed in every run took 75 s instead of 2.5 s).  This script pads the corpus FMU ``me-only`` (a chain of
five masses, model exchange) with ``--extra`` unused parameters, runs the command line's default recording (automatic
window: pilot runs and the recording, each in its own process) on both FMUs, best of ``--repeats`` wall times, and
checks that both recordings hold the same samples bit for bit.

Run: ``python benchmarks/bench_descriptions.py [--extra 20000] [--repeats 3] [--limit 2.0]``.
Exit status 1 if the padded FMU takes more than ``--limit`` times as long as the small one, or the samples differ.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import h5py
import numpy as np


def padded(src: Path, dst: Path, extra: int) -> Path:
    """``src`` with ``extra`` unused fixed parameters appended to its FMI 2 ModelVariables (appended: the model
    structure's 1-based indices stay valid)."""
    block = "".join(f'    <ScalarVariable name="sub.block[{i}].p" valueReference="{100000 + i}" description="unused '
                    f'parameter {i} of a big model, padded for size ......................................" '
                    f'causality="parameter" variability="fixed">\n      <Real start="{i}.5"/>\n    </ScalarVariable>\n'
                    for i in range(extra))
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data = data.decode().replace("  </ModelVariables>", block + "  </ModelVariables>", 1).encode()
            zout.writestr(item, data)
    return dst


def timed_snapshots(fmu: Path, out: Path, repeats: int) -> float:
    """Best wall time of ``fmu-opinf snapshots FMU -o OUT --force -q`` in a fresh interpreter."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fmu_opinf.cli", "snapshots", str(fmu), "-o", str(out), "--force",
                        "-q"], check=True, stdout=subprocess.DEVNULL)
        best = min(best, time.perf_counter() - start)
    return best


def same_samples(a: Path, b: Path) -> bool:
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        runs = list(fa["runs"])
        return runs == list(fb["runs"]) and all(
            np.asarray(fa[f"runs/{run}/{name}"]).tobytes() == np.asarray(fb[f"runs/{run}/{name}"]).tobytes()
            for run in runs for name in fa[f"runs/{run}"] if isinstance(fa[f"runs/{run}/{name}"], h5py.Dataset))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--extra", type=int, default=20000, help="unused parameters to add (20000: about 6 MB)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--limit", type=float, default=2.0, help="largest ratio of the two times that passes")
    args = parser.parse_args(argv)
    from fmu_opinf import lti_fmus

    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        small = lti_fmus.build_corpus(work, ("me-only",))["me-only"].path
        large = padded(small, work / "me-only-padded.fmu", args.extra)
        with zipfile.ZipFile(small) as zs, zipfile.ZipFile(large) as zl:
            sizes = [z.getinfo("modelDescription.xml").file_size / 1e6 for z in (zs, zl)]
        times = [timed_snapshots(fmu, work / f"{fmu.stem}.h5", args.repeats) for fmu in (small, large)]
        same = same_samples(work / f"{small.stem}.h5", work / f"{large.stem}.h5")
    ratio = times[1] / times[0]
    print(f"modelDescription.xml {sizes[0]:.3f} MB: snapshots {times[0]:.2f} s (best of {args.repeats})")
    print(f"modelDescription.xml {sizes[1]:.1f} MB ({args.extra} extra parameters): snapshots {times[1]:.2f} s, "
          f"{ratio:.2f} times as long (limit {args.limit:g})")
    print(f"samples bit for bit the same: {same}; cores {os.cpu_count()}, load {os.getloadavg()[0]:.1f}")
    return 0 if ratio <= args.limit and same else 1


if __name__ == "__main__":
    sys.exit(main())
