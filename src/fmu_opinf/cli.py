"""The ``fmu-opinf`` command line: a thin layer over the Python API, one verb per stage.

    fmu-opinf snapshots SOURCE -o snapshots.h5 [--input SPEC] [--dt H] [--t-end T | --auto-window]
    fmu-opinf fit snapshots.h5 -o rom.h5 [--r N | --energy E] [--basis positions|velocities]
    fmu-opinf compare rom.h5 SOURCE [--input SPEC] [--dt H] [--t-end T] -o report/
    fmu-opinf export rom.h5 -o rom.fmu [--reconstruct 'x[1],x[300]']
    fmu-opinf demo -o out/ [--model anchored-msd|triple-chain|all] [--quick]
    fmu-opinf build-fmus [-o fmus/] [--g 600] [--n1 100]

Every error the tool can diagnose is printed as one line ``fmu-opinf: error: ...`` with exit
code 2; anything else keeps its traceback (a bug to report).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path
from typing import Sequence

from . import __version__
from ._interrupts import remembered_interrupts
from .errors import FmuOpinfError, InputSpecError

__all__ = ["main", "run", "build_parser"]


def _add_source_options(parser: argparse.ArgumentParser, recording: bool = True) -> None:
    group = parser.add_argument_group("source variables and sizes")
    if recording:
        group.add_argument("--positions", help="name patterns of the positions, e.g. 'x[*]'")
        group.add_argument("--velocities", help="name patterns of the velocities, e.g. 'v[*]'")
        group.add_argument("--accelerations", help="name patterns of the accelerations, e.g. 'a[*]'")
    trained = "" if recording else " (default: those the ROM was trained with)"
    group.add_argument("--inputs", help="name patterns of the force inputs (default: every real continuous input "
                                        "but those with a --set value and those that look like parameters: a "
                                        "start value other than 0 in a unit that is not a force's or a moment's, or "
                                        "a unit such as N/m, N.s/m or kg; "
                                        "'none': no force input); other inputs are held at their start "
                                        "(or --set) values"
                                        + trained)
    group.add_argument("--outputs", help="name patterns of the outputs" + trained)
    if recording:
        group.add_argument("--constraint", choices=["position", "velocity", "none", "unknown"],
                           help="constraint kind of a black-box FMU (chooses the POD data in fit)")
    group.add_argument("--set", dest="settings", action="append", metavar="NAME=VALUE",
                       help="set a parameter, start value, held input or (FMI 3) structural parameter before the "
                            "run, e.g. --set k=1000,c=0.1, --set x0=[1,2,3], --set x0[2]=1.5; repeatable" + trained)
    group.add_argument("--interface", choices=["auto", "me", "cs"],
                       help="FMI interface to drive: me (model exchange, fmu-opinf integrates with --tolerance), "
                            "cs (co-simulation, the FMU steps itself) or auto (default: model exchange when the FMU "
                            "offers it, else co-simulation; docs/design.md)")
    group.add_argument("--tolerance", type=float,
                       help="relative tolerance of the model-exchange integration, also passed to the FMU "
                            "(fmi2SetupExperiment / fmi3EnterInitializationMode); default 1e-10")
    group.add_argument("--me-method", dest="method", metavar="METHOD",
                       help="integrator of model exchange: auto (default: linear for a stiff model, "
                            "else dop853), dop853 (explicit Runge-Kutta of order 8), linear (the exact step of the "
                            "FMU's identified Jacobian under held inputs, each step checked, DOP853 where the model is "
                            "not linear), lsoda, bdf, radau or rk45; recorded in the provenance (docs/real-fmus.md)")
    group.add_argument("--start-time", dest="start_time", type=float, metavar="S",
                       help="FMU time at which every run starts (the FMU runs at S + t; inputs, windows and the "
                            "recorded times still start at 0); default: the FMU's DefaultExperiment startTime, else 0"
                            + ("" if recording else "; compare: the start the ROM was trained with"))
    group.add_argument("--g", type=int, help="builtin:anchored-msd size (masses), default 600")
    group.add_argument("--n1", type=int, help="builtin:triple-chain masses per chain, default 100")


def _add_scaleout_options(parser: argparse.ArgumentParser, what: str) -> None:
    group = parser.add_argument_group("run tables and Dask (docs/scale-out.md)")
    group.add_argument("--runs", help=f"run table (.csv): one row per run to {what} (input, name, set:NAME, "
                                      "start:NAME); -o is then a directory with one result per row")
    group.add_argument("--scheduler", help="with --runs: run the rows on Dask, local[:N] (N worker processes, "
                                           "default one per core) or tcp://HOST:PORT (a running cluster)")


def _scaleout_dispatch(args: argparse.Namespace) -> bool:
    """Run the --runs/--scheduler forms; False if the verb's plain form applies."""
    from . import runs

    if args.verb == "fit" and args.scheduler:
        with runs.dask_client(args.scheduler):
            _run_fit(args)
        return True
    if args.verb not in ("snapshots", "compare"):
        return False
    if args.runs is None and args.scheduler is None:
        return False
    if args.runs is None:
        raise runs.RunTableError("--scheduler needs --runs TABLE.csv (one row per run)")
    if args.input_spec:
        raise runs.RunTableError("give either --input or --runs; the run table holds each run's input")
    if args.verb == "snapshots":
        report = runs.record_runs(args.source, args.runs, args.output, scheduler=args.scheduler, dt=args.dt,
                                  t_end=args.t_end, auto_window=args.auto_window, isolate=not args.in_process,
                                  quiet=args.quiet, check_linearity=args.check_linearity, **_source_options(args))
        print(report.describe())
    else:
        report, table = runs.compare_runs(args.rom, args.source, args.runs, args.output, scheduler=args.scheduler,
                                          dt=args.dt, t_end=args.t_end, quiet=args.quiet, **_source_options(args))
        print(table)
        print(f"report: {Path(args.output) / 'index.html'}")
    report.raise_for_failures()
    return True


def _source_options(args: argparse.Namespace) -> dict:
    from .sources import parse_assignments

    keys = ("positions", "velocities", "accelerations", "inputs", "outputs", "constraint", "interface", "tolerance",
            "method", "start_time", "g", "n1")
    options = {k: getattr(args, k) for k in keys if getattr(args, k, None) is not None}
    if getattr(args, "settings", None):
        options["parameters"] = parse_assignments(args.settings)  # the FMU keyword of the --set values
    return options


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of all verbs (exposed for documentation and tests)."""
    parser = argparse.ArgumentParser(
        prog="fmu-opinf",
        description="Learn stable reduced second-order models of constrained mechanical systems from FMUs "
                    "by operator inference.")
    parser.add_argument("--version", action="version", version=f"fmu-opinf {__version__}")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    p = verbs.add_parser("snapshots", help="simulate a source and record snapshots into an HDF5 file")
    p.add_argument("source", help="path to an FMU (model exchange or co-simulation, FMI 2.0 or 3.0), or "
                                  "builtin:anchored-msd / builtin:triple-chain")
    p.add_argument("-o", "--output", required=True, help="snapshot file to write (.h5)")
    p.add_argument("--input", dest="input_spec", action="append",
                   help="input signal, e.g. 'impulse:amplitude=100,t0=2,width=0.5' or a .csv table, or 'none' for "
                        "the free response from the initial state (every input held at its start value); ';' "
                        "separates one spec per input ('none' there: that input held); repeat for several training "
                        "runs; default: the paper's impulse training input "
                        "'impulse:amplitude=100,t0=2,width=0.5' (the amplitude an input's declared nominal where it "
                        "has one, within its declared range), in one run per input with several inputs, or the "
                        "free response of a model without inputs")
    p.add_argument("--dt", type=float, help="communication step (default: the FMU's default experiment step, "
                                            "else the automatic window)")
    p.add_argument("--t-end", type=float, help="end time (default: as --dt; an FMU's stopTime alone is not used)")
    p.add_argument("--auto-window", action="store_true",
                   help="choose dt and t-end from an impulse response (the paper's procedure; automatic when "
                        "neither is given and the FMU declares no default step): the step resolves the fastest "
                        "significant oscillation, the end is when the vibrations have faded out, or 20 periods of "
                        "the slowest significant oscillation after the input died out if they do not fade by then")
    p.add_argument("--in-process", action="store_true",
                   help="run the FMU inside this process (faster start; a crashing FMU then ends the tool)")
    p.add_argument("--no-linearity-check", dest="check_linearity", action="store_false",
                   help="do not check that the response scales with the inputs recorded (by default one extra run "
                        "of the largest input at -1/10 per input, or per --set/start group of a run table, and a "
                        "warning naming a smaller input where the model is linear only near its start)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    _add_scaleout_options(p, "record")
    _add_source_options(p)

    p = verbs.add_parser("fit", help="learn a reduced model from a snapshot file")
    p.add_argument("snapshots", help="snapshot file from 'fmu-opinf snapshots', or a directory of them (a run "
                                     "table's output), read as one data set")
    p.add_argument("-o", "--output", required=True, help="ROM file to write (.h5)")
    order = p.add_mutually_exclusive_group()
    order.add_argument("--r", type=int, help="reduced order")
    order.add_argument("--energy", type=float,
                       help="choose r where the cumulative energy (eq. 18) saturates at this threshold (default "
                            "0.95; snapshots of rank <= 10 keep all their modes unless --energy is given)")
    p.add_argument("--basis", choices=["auto", "positions", "velocities"], default="auto",
                   help="POD data: positions (position constraints) or velocities (velocity constraints); "
                        "auto follows the constraint kind recorded in the file")
    p.add_argument("--normalization", choices=["auto", "trace", "mass-eigenvalue"], default="auto",
                   help="how the homogeneous SDP is normalized: trace(Mr) fixed, Mr >= I, or auto (solves both, "
                        "keeps the smaller acceleration residual)")
    p.add_argument("--solver", choices=["auto", "ipm", "clarabel", "factored"], default="auto",
                   help="SDP solver: auto (dense interior-point method, its result certified, Clarabel when the "
                        "certificate fails; above r = 60 the refinement starts from the "
                        "factored solve instead), ipm, clarabel, or factored (L-BFGS over PSD factors, not "
                        "certified, O(r^3) per iteration)")
    p.add_argument("--integrator", choices=["auto", "newmark", "exact"], default="auto",
                   help="time discretization of the ROM: Newmark (matches Newmark sources: the builtin "
                        "simulator and benchmark FMUs) or exact under held inputs (continuous-time FMUs); auto "
                        "chooses from the snapshot provenance")
    p.add_argument("--lowpass", type=float,
                   help="optional frequency weighting: cutoff in rad/s of a zero-phase low-pass filter applied to "
                        "the reduced data before the fit (beyond the paper; default off)")
    p.add_argument("--terms", default="auto",
                   help="terms beyond the paper's model: constant force fr, feedthrough Dur, output offset y0; "
                        "'auto' (default) fits those the data need, 'none' the paper's model, 'all', or a list "
                        "such as 'fr,y0'")
    p.add_argument("--max-memory", type=float, default=1e9,
                   help="bytes the POD may hold in memory (default 1e9); larger data are streamed, or distributed "
                        "with --scheduler (docs/scale-out.md)")
    p.add_argument("--no-refine", dest="refine", action="store_false",
                   help="keep the SDP solution (eq. 16) instead of refining it by output error with the ROM's own "
                        "step (the default; see fmu_opinf.inference)")
    p.add_argument("--refine-iterations", type=int, metavar="N",
                   help="L-BFGS iterations of each refinement start at most (default 300 up to r = 40, 20 r up to "
                        "r = 60, 600 above; a start whose objective falls by less than 0.01 %% over 50 iterations ends "
                        "early); fewer are faster and less accurate (100 halve the fit at r = 35)")
    p.add_argument("--refit-output-map", action="store_true",
                   help="let the refinement re-fit the output map to the ROM's own trajectory (variable projection; "
                        "much more accurate on some models, less on others: see fmu_opinf.inference, default off)")
    p.add_argument("--output-weighting", choices=["per-output", "lumped"], default="per-output",
                   help="how the refinement weighs several outputs: each relative to its own size (default), or all "
                        "relative to their common size as eq. (19) does (see fmu_opinf.inference)")
    p.add_argument("--no-lstsq-candidate", dest="least_squares_candidate", action="store_false",
                   help="keep the refined SDP solution even where the mechanical realization of the unconstrained "
                        "least-squares fit has the smaller training output error (see fmu_opinf.inference)")
    p.add_argument("--figures", help="directory for singular-value and cumulative-energy figures")
    p.add_argument("--scheduler", help="run the POD and projections on Dask: local[:N] or tcp://HOST:PORT")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("-q", "--quiet", action="store_true", help="no stage lines")

    p = verbs.add_parser("compare", help="validate a ROM against its source on a new input; write a report")
    p.add_argument("rom", help="ROM file (.h5) or exported ROM FMU (.fmu)")
    p.add_argument("source", help="FMU path or builtin:NAME of the full-order model")
    p.add_argument("--input", dest="input_spec",
                   help="test input signal (or --runs), ';'-separated specs in the ROM's input order (the "
                        "FMU gets each at the input of its name); default: a harmonic on each input the training "
                        "drove, "
                        "off the ROM's natural frequencies, sized to stay within the training's output range, and "
                        "with two driven inputs or more each input's harmonic alone as well (a row each); 'none' "
                        "(the default for a ROM without inputs): the free response from the source's initial state")
    p.add_argument("--dt", type=float, help="step (default: the ROM's training step)")
    p.add_argument("--t-end", type=float, help="end time (default: four times the training end time, cut before "
                   "the time at which the training found the FMU terminating the simulation)")
    p.add_argument("-o", "--output", required=True, help="report directory")
    p.add_argument("--timeout", type=float, help="seconds the full-order FMU may run before it is stopped "
                                                 "(it runs in a separate process; default: no limit)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    _add_scaleout_options(p, "compare")
    _add_source_options(p, recording=False)

    p = verbs.add_parser("export", help="export a ROM as a self-contained co-simulation FMU")
    p.add_argument("rom", help="ROM file (.h5)")
    p.add_argument("-o", "--output", required=True, help="FMU to write (.fmu)")
    p.add_argument("--reconstruct", help="full-order positions to add as outputs: the source's names of recorded "
                                         "positions, or x[i] for the i-th recorded one, e.g. 'x[1],x[300]'")
    p.add_argument("--fmi-version", choices=["2.0", "3.0"], default="2.0",
                   help="FMI version of the exported co-simulation FMU (default 2.0); 3.0 declares an FMI 3 "
                        "source's array and Float32 inputs and outputs as the source does")
    p.add_argument("--step", type=float, default=None,
                   help="communication step the FMU is made for (default: the training step); a ROM of a "
                        "continuous-time FMU steps by its exact step map of this step and accepts its multiples")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")

    p = verbs.add_parser("demo", help="the whole chain on the bundled benchmark FMUs, with reports")
    p.add_argument("-o", "--output", default="demo-out", help="output directory (default demo-out)")
    p.add_argument("--model", choices=["anchored-msd", "triple-chain", "all"], default="all",
                   help="which benchmark to run (default: both)")
    p.add_argument("--quick", action="store_true", help="smaller, faster variant: fixed windows, r=12 for the triple chain, no least-squares "
                   "candidate (used by the tests)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars or stage lines")

    p = verbs.add_parser("build-fmus", help="build the benchmark FMUs from their C sources")
    p.add_argument("-o", "--output", default=None,
                   help="directory for the FMUs (default: the tool's own folder, rebuilt in place: fmus/ of a "
                        "checkout, or fmus/ in the user cache folder of an installed package, $FMU_OPINF_CACHE_DIR)")
    p.add_argument("--g", type=int, default=600, help="anchored chain size (masses, at least 3)")
    p.add_argument("--n1", type=int, default=100, help="triple chain masses per chain (even, at least 4)")
    p.add_argument("--force", action="store_true", help="replace existing FMUs in the -o directory")
    return parser


def _run_snapshots(args: argparse.Namespace) -> None:
    from .snapshots import record_to_file

    summary = record_to_file(args.source, args.output, args.input_spec, dt=args.dt, t_end=args.t_end,
                             auto_window=args.auto_window, overwrite=args.force, quiet=args.quiet,
                             isolate=not args.in_process, check_linearity=args.check_linearity,
                             **_source_options(args))
    print(f"wrote {summary.describe()}")


def _run_fit(args: argparse.Namespace) -> None:
    from .fit import fit_rom_file

    rom = fit_rom_file(args.snapshots, args.output, r=args.r, energy=args.energy, basis=args.basis,
                       figures=args.figures, overwrite=args.force, quiet=args.quiet,
                       normalization=args.normalization, solver=args.solver, lowpass=args.lowpass,
                       terms=args.terms,
                       integrator=args.integrator, refine="auto" if args.refine else False,
                       refine_iterations=args.refine_iterations, refit_output_map=args.refit_output_map,
                       least_squares_candidate=args.least_squares_candidate,
                       output_weighting=args.output_weighting, max_memory=args.max_memory)
    info = rom.fit_info
    extra = [name for name, term in (info.get("terms") or {}).items() if term.get("fitted")]
    print(f"wrote {args.output}: r={rom.r} ({info.get('basis_kind')} basis), fit {info.get('method')} "
          f"[{info.get('solver')}, {info.get('normalization')} normalization, cones {', '.join(info.get('cones') or []) or 'none'}] "
          f"{info.get('status')} in {info.get('total_seconds', 0):.2f}s; eigenvalues min Mr "
          f"{info.get('Mr_eig_min', float('nan')):.3g}, Dr {info.get('Dr_eig_min', float('nan')):.3g}, "
          f"Kr {info.get('Kr_eig_min', float('nan')):.3g}; stable={rom.is_stable(_ROUNDING, _ZERO_POLE)}; extra terms "
          f"{', '.join(extra) or 'none'}")
    if info.get("integrator_choice"):
        print(info["integrator_choice"])
    if (info.get("least_squares_candidate") or {}).get("chosen"):
        print("kept the model started from the mechanical realization of least squares (modal coordinates): its "
              "training output error was below the SDP model's (fit_info['least_squares_candidate'])")
    print(_pole_summary(info.get("poles") or []))


#: Real parts of poles up to this fraction of the largest pole magnitude are round-off of zero: a free-free
#: structure's rigid-body poles came out at +8.9e-16 and the fit said ``stable=False`` and "damping ratios -1"
#: of a model whose operators are PSD (audit 2026-11-27).
_ROUNDING = 1e-12
#: Poles within this fraction of the largest pole magnitude of zero are zero poles (rigid-body motion): an undamped
#: rigid-body mode's double pole at 0 is defective, and round-off splits it into a pair of about sqrt(eps) of the
#: scale (audit 78 F3: +-5e-10 relative, printed as "damping ratios -1 .. 1" and stable=False for an exact ROM).
_ZERO_POLE = 1e-7


def _pole_summary(poles: list) -> str:
    """One line on the learned poles: natural frequencies and damping ratios of the oscillating ones (what a user
    checks against the physics they know; the poles reproduce the input-output behaviour and need not be the full
    model's modes); poles within :data:`_ZERO_POLE` of zero are counted as zero poles (rigid-body motion), real
    ones (an overdamped pair) by their decay rates (audit86 F6: a stiff ROM's two real poles were counted "in the
    upper half plane" as a mode at 2.04e3 rad/s with damping ratio 1, 4 of them for r = 3)."""
    import numpy as np

    values = np.array([complex(re, im) for re, im in poles])
    zero = np.abs(values) <= _ZERO_POLE * max(float(np.abs(values).max(initial=0.0)), np.finfo(float).tiny)
    rigid = f"; {int(zero.sum())} zero pole(s) (rigid-body motion)" if zero.any() else ""
    real = values[~zero & (values.imag == 0)]
    overdamped = (f"; {real.size} real pole(s) (overdamped), decay rates {-real.real.max():.3g} .. "
                  f"{-real.real.min():.3g} 1/s" if real.size else "")
    values = values[~zero & (values.imag != 0)]
    if values.size == 0:
        return f"learned poles: none{rigid}" if not real.size else \
            f"learned poles: none in the upper half plane{overdamped}{rigid} (fit_info['poles'])"
    omega = np.abs(values)
    zeta = -values.real / omega
    zeta[np.abs(values.real) <= _ROUNDING * omega.max()] = 0.0  # undamped, up to round-off
    return (f"learned poles: {values.size} in the upper half plane, natural frequencies {omega.min():.3g} .. "
            f"{omega.max():.3g} rad/s, damping ratios {zeta.min():.3g} .. {zeta.max():.3g}{overdamped}{rigid} "
            "(fit_info['poles'])")


def _run_compare(args: argparse.Namespace) -> None:
    from .compare import compare
    from .report import summary_table, write_report

    # the report folder was checked up front (_check_arguments) and is created only once there is a report
    options = _source_options(args)
    if args.timeout is not None:
        options["timeout"] = args.timeout
    result = compare(args.rom, args.source, args.input_spec, dt=args.dt, t_end=args.t_end, quiet=args.quiet,
                     source_options=options)
    page = write_report(result, args.output)
    name = Path(str(args.rom)).name
    free = [(f"{name}, {extra.driven_alone}", extra.run_metrics())
            for extra in (result.free_response, result.training_band) if extra is not None]
    print(summary_table([(name, result.metrics())] + [(f"{name}, {alone.driven_alone} alone", alone.run_metrics())
                                                      for alone in result.each_input_alone] + [f for f in free if f]))
    print(f"report: {page}")


def _run_export(args: argparse.Namespace) -> None:
    from .export import export_fmu
    from .rom import SecondOrderROM

    from .sources._base import split_patterns

    reconstruct = split_patterns(args.reconstruct) if args.reconstruct is not None else None
    if reconstruct is not None and not reconstruct:
        raise InputSpecError(f"--reconstruct {args.reconstruct!r} names no position; give names such as "
                             "'x[1],x[300]', or leave the option out")
    rom = SecondOrderROM.load(args.rom)
    if not args.quiet:
        print(f"exporting the r={rom.r} ROM: modal form of its step map, FMI {args.fmi_version} description, C "
              "compilation ...", flush=True)
    path = export_fmu(rom, args.output, fmi_version=args.fmi_version, reconstruct=reconstruct,
                      overwrite=args.force, step=args.step)
    if not args.quiet:
        print(f"wrote {path}")


def _run_demo(args: argparse.Namespace) -> None:
    from .demo import run_demo

    run_demo(args.output, model=args.model, quick=args.quick, quiet=args.quiet)


def _run_build_fmus(args: argparse.Namespace) -> None:
    from .fmus import BENCHMARK_MODELS, build_fmus, bundled_fmu_dir

    out_dir = args.output if args.output is not None else bundled_fmu_dir()
    if args.output is not None and not args.force:   # the tool's own folder is rebuilt in place
        for name in BENCHMARK_MODELS:
            if (Path(out_dir) / f"{name}.fmu").exists():
                raise FileExistsError(f"{Path(out_dir) / f'{name}.fmu'} exists; pass --force to replace it")
    for path in build_fmus(out_dir=out_dir, g=args.g, n1=args.n1):
        print(f"built {path}")


#: The options that name files or folders the command reads or writes (``source`` is made absolute by the source).
_PATH_OPTIONS = ("output", "runs", "figures", "snapshots", "rom")


def _absolute_paths(args: argparse.Namespace) -> dict[str, str]:
    """Turn the command's relative paths into absolute ones, now: an FMU that changes the working directory
    (``chdir`` in its instantiate) would otherwise move a relative ``-o`` into its own folder (audit 81a, F2: with
    ``--in-process`` the snapshot file landed there, and ``--force`` replaced a file of that name there).  Empty
    names keep their meaning (``build-fmus -o ""`` is refused as such).  Returns absolute path -> the text given,
    for the one-line messages (:func:`_as_given`)."""
    given: dict[str, str] = {}
    for name in _PATH_OPTIONS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value and value != "-":
            setattr(args, name, _absolute(value, given))
    specs = getattr(args, "input_spec", None)
    if isinstance(specs, str):
        args.input_spec = _absolute_tables(specs, given)
    elif isinstance(specs, list):
        args.input_spec = [_absolute_tables(spec, given) if isinstance(spec, str) else spec for spec in specs]
    return given


def _absolute(text: str, given: dict[str, str]) -> str:
    import os

    path = os.path.abspath(text)
    if path != text:
        given[path] = text
    return path


def _absolute_tables(spec: str, given: dict[str, str]) -> str:
    """An input spec with its ``.csv`` tables (one per ';'-separated input, as the signal parser reads them) named
    by absolute paths."""
    return ";".join(_absolute(part.strip(), given) if part.strip().lower().endswith(".csv") else part
                    for part in spec.split(";"))


def _as_given(text: str, given: dict[str, str]) -> str:
    """A message with the paths :func:`_absolute_paths` made absolute written as the user gave them (longest
    first)."""
    for path in sorted(given, key=len, reverse=True):
        text = text.replace(path, given[path])
    return text


def _check_arguments(args: argparse.Namespace) -> None:
    """Validate option values and output locations before any work (one-line errors, exit code 2)."""
    from . import _validate as v
    from ._hdf5 import check_folder_entries

    for option in ("positions", "velocities", "accelerations", "inputs", "outputs"):
        v.check_patterns(getattr(args, option, None), "--" + option)
    for option, flag in (("output", "-o"), ("figures", "--figures")):   # ("" is the current folder, audit 55)
        if getattr(args, option, None) == "":
            raise InputSpecError(f"{flag} is empty; give a path")
        if getattr(args, option, None) is not None:
            v.check_name_length(getattr(args, option), flag)
            v.check_not_dangling(getattr(args, option), flag)
    for option in ("dt", "t_end", "lowpass", "timeout", "max_memory"):
        v.check_positive(getattr(args, option, None), "--" + option.replace("_", "-"))
    sizes = () if args.verb == "build-fmus" else (("g", 1), ("n1", 1))   # build-fmus names the FMUs' own bounds
    for option, least in (("r", 1), *sizes, ("refine_iterations", 0)):   # (the same checks as fit_rom's keywords)
        v.check_at_least(getattr(args, option, None), "--" + option.replace("_", "-"), least)
    v.check_fraction(getattr(args, "energy", None), "--energy")
    if getattr(args, "method", None) is not None:
        args.method = _me_method(args.method)
    if getattr(args, "dt", None) is not None and getattr(args, "t_end", None) is not None:
        v.check_grid(args.dt, args.t_end)
    if args.verb == "snapshots" and not args.runs:
        _check_output_file(args, [args.source] + list(args.input_spec or []))
    elif args.verb == "fit":
        _check_output_file(args, [args.snapshots])
        if args.figures:
            from .plots import POD_FIGURES

            v.check_writable(args.figures, "figure directory", directory=True, option="--figures")
            check_folder_entries(args.figures, POD_FIGURES)
    elif args.verb == "export":
        _check_output_file(args, [args.rom])
    elif args.verb == "compare":
        v.check_not_input(args.output, [args.rom, args.source, args.input_spec], "report directory")
        v.check_writable(args.output, "report directory", directory=True)
        if not args.runs:  # a run table's folder holds one report per row
            v.check_report_directory(args.output)
        else:
            check_folder_entries(args.output, ("summary.txt", "index.html"))


def _me_method(text: str) -> str:
    """``--me-method``: one of the model-exchange integrators, in lower case."""
    from .sources import METHODS

    value = text.strip().lower()
    if value not in METHODS:
        raise InputSpecError(f"--me-method {text!r} is not an integrator; choose one of {', '.join(METHODS)}")
    return value


def _check_output_file(args: argparse.Namespace, inputs: list) -> None:
    from . import _validate as v
    from ._hdf5 import output_target

    v.check_not_input(args.output, inputs, "output")
    if Path(args.output).is_dir():   # before "exists": --force cannot replace a folder
        raise FileExistsError(f"{args.output} is a directory; give a file name")
    if args.verb == "export":   # the exporter's own checks of the name: a suffix, not a folder
        from .export import check_output_name

        check_output_name(Path(args.output), overwrite=True)   # an existing file: the line below
    if Path(args.output).exists() and not args.force:
        raise FileExistsError(f"{args.output} exists; pass --force to replace it")
    output_target(args.output)   # (a device, a pipe: refused before the work, not at its end)
    v.check_writable(args.output, "output")


_VERBS = {"snapshots": _run_snapshots, "fit": _run_fit, "compare": _run_compare, "export": _run_export,
          "demo": _run_demo, "build-fmus": _run_build_fmus}


def _one_line_warning(message, category, filename, lineno, file=None, line=None,  # noqa: ANN001
                      given: dict[str, str] | None = None) -> None:
    """Warnings on the command line are one line each, like errors (no source file or code line); paths made
    absolute are written as given."""
    text = _as_given(" ".join(str(message).split()), given or {})
    print(f"fmu-opinf: warning: {text}", file=file or sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fmu-opinf`` console script; returns the exit code.

    The command's FMU runs start from a fork server (:func:`fmu_opinf.snapshots._isolation.use_fork_server`):
    about 25 ms per run instead of 0.4 s.
    """
    finished: list[bool] = []
    try:
        return _main(argv, finished)
    except KeyboardInterrupt:  # a second Ctrl-C while the first was being reported, or one after the end
        return 0 if finished else 130


def _main(argv: Sequence[str] | None, finished: list[bool]) -> int:
    """:func:`main`; appends to ``finished`` once the verb has done its work, so that a Ctrl-C which arrives
    during the clean-up after it (audit 67: a demo complete on disk, exit 130 with no message) is not reported as
    an interrupted run."""
    import warnings

    previous = warnings.showwarning
    verb = None
    given: dict[str, str] = {}   # absolute paths -> as given, for the messages
    try:
        with remembered_interrupts():  # a Ctrl-C swallowed in a finalizer is raised again at the next safe point
            # imported here, not at the top: numpy and fmpy take a while, and a Ctrl-C meanwhile is an interrupt
            from ._hdf5 import REPLACED
            from .snapshots._isolation import _FORK_SERVER, use_fork_server

            args = build_parser().parse_args(argv)
            given.update(_absolute_paths(args))
            verb = args.verb
            REPLACED.clear()
            warnings.showwarning = functools.partial(_one_line_warning, given=given)
            before = _FORK_SERVER["enabled"]
            use_fork_server(True)
            try:
                _check_arguments(args)
                _scaleout_dispatch(args) or _VERBS[args.verb](args)
                finished.append(True)
            finally:
                use_fork_server(before)  # a script calling main() keeps its own setting
    except (FmuOpinfError, FileExistsError) as exc:
        print("fmu-opinf: error: " + _as_given(" ".join(str(exc).split()), given), file=sys.stderr)  # one line
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (snapshots.Interrupted)
        signum = getattr(exc, "signum", 2)
        if finished:
            print(f"fmu-opinf: {'SIGTERM' if signum == 15 else 'Ctrl-C'} arrived after {verb} had finished; "
                  "its outputs are complete", file=sys.stderr)
            return 0
        print(f"fmu-opinf: interrupted ({'SIGTERM' if signum == 15 else 'Ctrl-C'}); {_left_behind(verb)}",
              file=sys.stderr)
        return 128 + signum
    finally:
        warnings.showwarning = previous
    return 0


def _left_behind(verb: str | None) -> str:
    """What an interrupted command leaves: the outputs it replaced before the interrupt (:data:`_hdf5.REPLACED`),
    or none; the demo's cases, written by worker processes, are not counted here: the demo puts its folder back
    as it was (:func:`fmu_opinf.demo.run_demo`).

    A Ctrl-C while ``_hdf5`` (numpy, h5py) was still being imported leaves it half imported, and importing it again
    fails: before that import ends, no output can have been written.
    """
    hdf5 = sys.modules.get(f"{__package__}._hdf5")
    replaced = getattr(hdf5, "REPLACED", [])
    if verb == "demo":
        return "the demo folder was left as it was before the run"
    if not replaced:
        return "no output file was written or replaced"
    return (f"written before it: {', '.join(str(path) for path in replaced)}; every other output was left as it "
            "was")


def run() -> None:
    """The ``fmu-opinf`` console script: :func:`main`, then exit with its code.

    Once the run is over, a signal that arrives late (Ctrl-C to the whole process group while the simulation
    process is still starting) must not turn the reported exit code into a death by signal.
    """
    import signal

    code = main()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)
    _forget_caught_keyboard_interrupts()
    sys.exit(code)


def _forget_caught_keyboard_interrupts() -> None:
    """Make ``python -m fmu_opinf.cli`` exit with the code given after a Ctrl-C that was reported.

    CPython remembers a KeyboardInterrupt that ended code evaluated from a string (a dataclass or namedtuple being
    created while Ctrl-C arrived), also when it was caught, and at the end of ``python -m`` kills the process by
    SIGINT instead of exiting with the code given (exit -2 instead of 130, one trial in ten at 0.3 s).  The next
    string evaluation clears what it remembered.
    """
    eval("None")  # a constant: nothing from outside is evaluated


if __name__ == "__main__":
    run()
