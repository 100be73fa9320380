"""Fuzz test of the file readers (issue 13): random and mutated snapshot and ROM files.

Every case runs the command line on one damaged file (``fit`` for snapshot files, ``compare`` for ROM
files).  Whatever the damage, the tool must either work (a harmless mutation, e.g. of a data value) or
stop with exit code 2 and one line ``fmu-opinf: error: ...``: no traceback, no crash, and no file other
than the named output.  The cases run in one child process (a crash of the HDF5 library must not take
pytest with it); the case count and the time are bounded.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

SEED = 20261123
#: Cases per kind of damage, each for a snapshot and a ROM file (44 in all, about 15 s).
CASES_PER_KIND = {"random-bytes": 2, "truncated": 3, "bytes-flipped": 4, "attribute": 6, "dataset": 5,
                  "deleted": 1, "link": 1}
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


# ------------------------------------------------------------------------------------------------------
# mutations
# ------------------------------------------------------------------------------------------------------


def _objects(f: h5py.File) -> tuple[list[str], list[str]]:
    groups, datasets = ["/"], []
    f.visititems(lambda name, obj: (datasets if isinstance(obj, h5py.Dataset) else groups).append(name))
    return groups, datasets


def _bad_value(rng: np.random.Generator):
    pool = [
        "one", "", float("nan"), -1.0, 0.0, 1e308, -(2**62), np.array([True, False]),
        np.array([(1, 2.0)], dtype=[("a", "i4"), ("b", "f8")]), 1 + 2j, np.arange(5), json.dumps([1, 2]),
        json.dumps({"a": [1]}), np.array([b"\xff\xfe"], dtype="S2"), np.zeros((2, 2)), "{not json",
    ]
    return pool[int(rng.integers(len(pool)))]


def _bad_dataset(rng: np.random.Generator, shape: tuple[int, ...]) -> dict:
    choice = int(rng.integers(8))
    if choice == 0:
        return {"data": np.ones(shape) + 1j}
    if choice == 1:
        return {"data": np.ones(shape, dtype=bool)}
    if choice == 2:
        return {"data": np.array(["x"] * max(int(np.prod(shape)), 1), dtype="S1")}
    if choice == 3:
        return {"data": np.full(shape, np.nan)}
    if choice == 4:
        return {"data": 3.0}
    if choice == 5:
        return {"data": np.ones(tuple(s + 1 for s in shape) or (2,))}
    if choice == 6:
        return {"shape": tuple(10**6 for _ in shape) or (10**9,), "dtype": "f8"}
    return {"data": -np.abs(np.random.default_rng(0).standard_normal(shape))}


def mutate(kind: str, valid: Path, path: Path, rng: np.random.Generator) -> None:
    """Write a damaged variant of ``valid`` to ``path``."""
    data = valid.read_bytes()
    if kind == "random-bytes":
        body = rng.integers(0, 256, int(rng.integers(0, 4096)), dtype=np.uint8).tobytes()
        path.write_bytes((HDF5_SIGNATURE if rng.random() < 0.5 else b"") + body)
        return
    if kind == "truncated":
        path.write_bytes(data[:int(rng.integers(1, len(data)))])
        return
    if kind == "bytes-flipped":
        raw = bytearray(data)
        for offset in rng.integers(0, min(len(raw), 8192), int(rng.integers(1, 20))):  # metadata lives up front
            raw[offset] = int(rng.integers(256))
        path.write_bytes(bytes(raw))
        return
    shutil.copy(valid, path)
    with h5py.File(path, "r+") as f:
        groups, datasets = _objects(f)
        if kind == "attribute":
            group = f[groups[int(rng.integers(len(groups)))]]
            keys = list(group.attrs.keys()) or ["kind"]
            group.attrs[keys[int(rng.integers(len(keys)))]] = _bad_value(rng)
        elif kind == "dataset":
            name = datasets[int(rng.integers(len(datasets)))]
            shape = f[name].shape
            del f[name]
            f.create_dataset(name, **_bad_dataset(rng, shape))
        elif kind == "deleted":
            names = groups[1:] + datasets
            del f[names[int(rng.integers(len(names)))]]
        elif kind == "link":
            name = datasets[int(rng.integers(len(datasets)))]
            del f[name]
            f[name] = h5py.ExternalLink("/etc/hostname", "/x") if rng.random() < 0.5 else h5py.SoftLink("/nowhere")


# ------------------------------------------------------------------------------------------------------
# the worker: runs every case in one process, reports one JSON line per case
# ------------------------------------------------------------------------------------------------------


def _run_case(case: dict) -> dict:
    from fmu_opinf import cli

    folder = Path(case["folder"])
    err = io.StringIO()
    traceback_text = ""
    start = time.perf_counter()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = cli.main(case["argv"])
        except BaseException as exc:  # noqa: BLE001 - anything escaping main is a finding
            import traceback

            code, traceback_text = -1, "".join(traceback.format_exception(exc))[-2000:]
    return {"name": case["name"], "code": code, "stderr": err.getvalue(), "traceback": traceback_text,
            "files": sorted(p.name for p in folder.iterdir()), "seconds": time.perf_counter() - start}


def worker(cases_file: str) -> None:
    """Run the cases of ``cases_file``; one JSON result per line on stdout (flushed: a crash shows where)."""
    for case in json.loads(Path(cases_file).read_text()):
        print("START " + case["name"], flush=True)
        print(json.dumps(_run_case(case)), flush=True)


# ------------------------------------------------------------------------------------------------------
# the test
# ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory):
    from fmu_opinf.fit import fit_rom_file
    from fmu_opinf.snapshots import record
    from fmu_opinf.source import BuiltinSource

    folder = tmp_path_factory.mktemp("fuzz-valid")
    snaps = folder / "s.h5"
    record(BuiltinSource("anchored-msd", g=8), "impulse:amplitude=10,t0=1,width=0.5", 0.5, 20.0, path=snaps,
           quiet=True)
    rom = folder / "rom.h5"
    fit_rom_file(snaps, rom, r=2, quiet=True)
    return {"snapshots": snaps, "rom": rom}


def _cases(valid_files: dict, root: Path) -> list[dict]:
    rng = np.random.default_rng(SEED)
    cases = []
    for kind, count in CASES_PER_KIND.items():
        for index in range(count):
            for what in ("snapshots", "rom"):
                name = f"{what}-{kind}-{index}"
                folder = root / name
                folder.mkdir()
                path = folder / ("in.h5")
                mutate(kind, valid_files[what], path, rng)
                if what == "snapshots":
                    argv = ["fit", str(path), "-o", str(folder / "out.h5"), "--r", "2", "-q"]
                    allowed = {"in.h5", "out.h5"}
                else:
                    argv = ["compare", str(path), "builtin:anchored-msd", "--g", "8", "--input", "step",
                            "--t-end", "5", "-o", str(folder / "report"), "-q"]
                    allowed = {"in.h5", "report"}
                cases.append({"name": name, "folder": str(folder), "argv": argv, "allowed": sorted(allowed)})
    return cases


@pytest.mark.slow  # 23 s on the 2-core machine of 2026-11-28 (2.7x slower than the README's)
def test_damaged_files_give_one_line_errors(valid_files, tmp_path):
    cases = _cases(valid_files, tmp_path)
    assert len(cases) == 2 * sum(CASES_PER_KIND.values())
    cases_file = tmp_path / "cases.json"
    cases_file.write_text(json.dumps(cases))
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
    src = str(Path(__import__("fmu_opinf").__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join([src, str(Path(__file__).parent), env.get("PYTHONPATH", "")])
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", f"import test_fuzz; test_fuzz.worker({str(cases_file)!r})"],
                          capture_output=True, text=True, env=env, timeout=300)
    seconds = time.monotonic() - start
    lines = proc.stdout.splitlines()
    results = [json.loads(line) for line in lines if line.startswith("{")]
    started = [line[6:] for line in lines if line.startswith("START ")]
    last = started[-1] if started else "?"
    assert proc.returncode == 0, f"the worker died (exit {proc.returncode}) in case {last}: {proc.stderr[-2000:]}"
    assert len(results) == len(cases)
    problems = []
    for case, result in zip(cases, results):
        err = result["stderr"].strip().splitlines()
        if result["code"] == 2:
            ok = len(err) == 1 and err[0].startswith("fmu-opinf: error: ")
        else:
            ok = result["code"] == 0  # a harmless mutation (e.g. a data value): the command worked
        extra = set(result["files"]) - set(case["allowed"])
        if result["code"] == 2:
            extra |= set(result["files"]) - {"in.h5"}
        if not ok or extra or result["traceback"] or "Traceback" in result["stderr"]:
            problems.append(f"{case['name']}: exit {result['code']}, files {result['files']}, "
                            f"stderr {result['stderr'][-300:]!r} {result['traceback'][-600:]}")
    errors = sum(r["code"] == 2 for r in results)
    slowest = sorted(results, key=lambda r: -r["seconds"])[:5]
    print(f"{len(results)} cases, {errors} refused, {seconds:.1f} s; slowest:",
          ", ".join(f"{r['name']} {r['seconds']:.2f}s (exit {r['code']})" for r in slowest))
    assert not problems, "\n".join(problems)
    assert errors >= 0.7 * len(results), f"only {errors} of {len(results)} damaged files were refused"
    assert seconds < 45, seconds


if __name__ == "__main__":
    worker(sys.argv[1])
