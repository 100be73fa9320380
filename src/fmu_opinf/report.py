"""The comparison report: the paper's figures (Figs. 7-10: outputs of FOM and ROM, eps_y over time on a log
axis), ``metrics.json`` and one self-contained ``index.html`` per comparison, and the summary table that the command
line prints.

:func:`fmu_opinf.compare.compare` measures; this module only presents what it measured, so that a comparison made
through the Python API can be written, or not, without running anything again.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ._hdf5 import atomic_path, jsonable, replace_together, write_error
from ._validate import check_not_input, check_report_directory
from .compare import Comparison, comparison_notes
from .errors import DataError, FileFormatError

__all__ = ["MAX_OUTPUT_PANELS", "plotted_outputs", "prepare_report_directory", "write_report", "summary_table"]


#: Output panels the outputs figure draws at most: with more outputs, those with the largest error relative to
#: their own peak (seventh audit, 2026-11-27: 200 outputs gave an 880 x 48510 pixel figure, a 35 MB report page
#: and 60 s of drawing; every output's errors stay in metrics.json and in the page's table).
MAX_OUTPUT_PANELS = 12


def plotted_outputs(comparison: Comparison) -> list[int]:
    """Indices of the outputs the outputs figure shows: all of them up to :data:`MAX_OUTPUT_PANELS`, else that
    many with the largest max error relative to their own peak, in their order."""
    p = comparison.y_fom.shape[0]
    if p <= MAX_OUTPUT_PANELS:
        return list(range(p))
    peak = np.maximum(np.abs(comparison.y_fom).max(axis=1), 1e-300)
    relative = np.nan_to_num(np.abs(comparison.y_fom - comparison.y_rom).max(axis=1) / peak, nan=np.inf)
    return sorted(np.argsort(-relative, kind="stable")[:MAX_OUTPUT_PANELS].tolist())


def _figure_outputs(comparison: Comparison, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .plots import fixed_margins, plot_text

    p = comparison.y_fom.shape[0]
    shown = plotted_outputs(comparison)
    units = _displayed_units(comparison)
    fig, axes = plt.subplots(len(shown), 1, figsize=(8, 2.2 * len(shown) + 1.0), sharex=True, squeeze=False)
    ylabels = {j: label_lines(comparison.output_names[j], units[j]) for j in shown}
    for j, ax in zip(shown, axes[:, 0]):
        ax.plot(comparison.t, _displayed(comparison, j, comparison.y_fom[j]), "k-", lw=1.6, label="FOM")
        ax.plot(comparison.t, _displayed(comparison, j, comparison.y_rom[j]), "C1--", lw=1.2,
                label=f"ROM (r={comparison.r})")
        ax.set_ylabel("\n".join(plot_text(line) for line in ylabels[j]))
        _mark_training_end(ax, comparison.t_train_end, float(comparison.t[-1]))
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    # the legend sits above the axes, where it cannot cover a curve
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), bbox_to_anchor=(0.5, 1.0), frameon=False)
    which = "" if len(shown) == p else f" ({len(shown)} of {p} outputs: the largest errors relative to their peak)"
    lines = title_lines(f"Outputs, input {comparison.input_spec}{which}")
    fig.suptitle("\n".join(plot_text(line) for line in lines), y=1.0 - 0.3 / fig.get_figheight())
    label_columns = max(len(label) for label in ylabels.values())
    fixed_margins(fig, left=0.95 + LABEL_LINE_INCHES * (label_columns - 1), bottom=0.5,
                  top=0.75 + TITLE_LINE_INCHES * (len(lines) - 1))
    fig.subplots_adjust(hspace=0.12)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _display_unit(comparison: Comparison, j: int) -> Any:
    """Output ``j``'s declared display unit (:class:`~fmu_opinf.compare.DisplayUnit`), None where it has none."""
    display = comparison.output_display_units or []
    return display[j] if j < len(display) else None


def _displayed_units(comparison: Comparison) -> list[str]:
    """The unit each output is shown in: its declared ``displayUnit`` where its definition is known (FMI:
    ``DisplayUnit_value = factor * Unit_value + offset``), else its unit, else ""."""
    units = list(comparison.output_units or [])
    units += [""] * (comparison.y_fom.shape[0] - len(units))
    return [getattr(_display_unit(comparison, j), "name", None) or unit for j, unit in enumerate(units)]


def _displayed(comparison: Comparison, j: int, y: np.ndarray) -> np.ndarray:
    """Output ``j``'s values ``y`` in the unit :func:`_displayed_units` names (unchanged where it has no display
    unit: the figure of such a model stays the same to the byte)."""
    display = _display_unit(comparison, j)
    return y if display is None else display.values(y)


#: Characters of a figure title's line (8 inch wide figure, 12 pt) and lines at most; the height of one more line.
TITLE_WIDTH, TITLE_LINES, TITLE_LINE_INCHES = 80, 4, 0.22


def title_lines(text: str, width: int = TITLE_WIDTH, most: int = TITLE_LINES, breaks: str = ", ") -> list[str]:
    """``text`` broken into lines of at most ``width`` characters: after each ``;`` (one input's signal per line),
    within that after one of the characters ``breaks`` (a ``,`` or a space), and inside a longer word where nothing
    else helps; at most ``most`` lines, the last ending in ``...`` where text is left out.  A compare of several
    inputs drew its whole input spec on one line, cut off at both edges (audit 77a F4)."""
    lines: list[str] = []
    for part in re.split(r"(?<=;)", text):
        line = ""
        for piece in re.split(f"(?<=[{re.escape(breaks)}])", part):
            while len(line) + len(piece) > width:
                if line:
                    lines.append(line)
                    line = ""
                else:
                    lines.append(piece[:width])
                    piece = piece[width:]
            line += piece
        if line:
            lines.append(line)
    if len(lines) > most:
        lines = lines[:most]
        lines[-1] = lines[-1][: width - 3] + "..."
    return [line.rstrip() for line in lines] or [""]


#: Characters of one line of an output panel's y-label (rotated along a panel of about 2 inches, at
#: matplotlib's 10 points), the lines a name takes at most (its unit may take one more), and the width of one line.
LABEL_WIDTH, LABEL_LINES, LABEL_LINE_INCHES = 22, 3, 0.18


def label_lines(name: str, unit: str = "", width: int = LABEL_WIDTH, most: int = LABEL_LINES) -> list[str]:
    """An output panel's y-label as lines: ``name`` broken after ``.``, ``_``, ``,``, ``]`` or a space, shortened
    in its middle (``…``) where it needs more than ``most`` lines, so that its start and its last part (the
    variable itself) both stay; ``[unit]`` on the last line, or on a line of its own, never cut.

    A 97-character name on one rotated line ran off the figure's top with its unit, and shorter ones overlapped
    the label of the panel above (audit 81c, F10).
    """
    unit_text = f"[{unit}]" if unit else ""
    room = width * most - 2 * most   # a broken line is seldom full
    if len(name) > room:
        head = (room - 1) // 2
        name = name[:head] + "…" + name[len(name) - (room - 1 - head):]
    lines = title_lines(name, width, most + 1, breaks="._,] ")
    if len(lines) > most:   # the breaks left a longer tail: cut the middle further
        return label_lines(name[: len(name) // 2 - width // 2] + "…" + name[len(name) // 2 + width // 2:], unit,
                           width, most)
    if unit_text and len(lines[-1]) + 1 + len(unit_text) <= width:
        lines[-1] += " " + unit_text
    elif unit_text:
        lines.append(unit_text)
    return lines


def _figure_error(comparison: Comparison, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from matplotlib.ticker import FuncFormatter

    from .plots import decade_label, fixed_margins

    eps = comparison.eps
    fig, ax = plt.subplots(figsize=(8, 3.2))
    # twelve decades below the peak are enough to read the error's history (round-off would stretch the axis)
    floor = max(eps[eps > 0].min() if np.any(eps > 0) else 1e-300, 1e-12 * float(eps.max()), 1e-300)
    ax.semilogy(comparison.t, np.maximum(eps, floor), "C0-", lw=1.2)
    ax.yaxis.set_major_formatter(FuncFormatter(decade_label))  # 10⁻⁵ without mathtext: a quarter less drawing time
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$\varepsilon_y(t)$, eq. (19)")
    ax.set_title(r"squared relative output error $\|y - y_r\|^2 / \max_t \|y\|^2$ (eq. 19), "
                 f"max {eps.max():.2e}", fontsize=10)
    _mark_training_end(ax, comparison.t_train_end, float(comparison.t[-1]))
    ax.grid(alpha=0.3, which="both")
    fixed_margins(fig, left=0.85, bottom=0.5, top=0.35)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mark_training_end(ax, t_train_end: float | None, t_last: float) -> None:
    """Dotted line at the last training snapshot (paper Figs. 7-8), if it lies inside the plotted window."""
    if t_train_end is not None and math.isfinite(t_train_end) and t_train_end <= t_last:
        ax.axvline(t_train_end, color="0.4", ls=":", lw=1.0, label="last training snapshot")


def prepare_report_directory(out_dir: str | os.PathLike, option: str = "-o") -> None:
    """Create the report directory, or fail with a one-line error if the path is an existing file (naming how it
    was given: ``-o`` or a Python keyword, ``out_dir`` for :func:`write_report`)."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        fix = f"choose another {option} path" if option.startswith("-") else f"give {option}= another path"
        raise FileFormatError(f"report directory {out_dir} is an existing file; {fix}")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"cannot create report directory {out_dir}: {exc.strerror}") from None


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file renamed to ``path`` (mode from the umask; one-line write errors)."""
    with atomic_path(path) as tmp:
        try:
            Path(tmp).write_bytes(data)
        except OSError as exc:
            raise write_error(path, exc) from None


def write_report(comparison: Comparison, out_dir: str | os.PathLike, extra_figures: dict[str, Path] | None = None,
                 notes: dict[str, Any] | None = None, *, overwrite: bool = False) -> Path:
    """Write ``metrics.json``, ``outputs.png``, ``error.png`` and ``index.html`` into ``out_dir``.

    An earlier report in ``out_dir`` is replaced as a whole: every file is written under a temporary name
    first and the renames follow, so a failure (a full disk) or an interrupt leaves it as it was.

    Parameters
    ----------
    comparison : Comparison
    out_dir : path
        Created if missing; must not be an existing file, nor one of the comparison's inputs (``inputs``, the
        source in ``fom_provenance``: an unpacked FMU folder is one).  A folder holding other files than an
        earlier report is refused, as ``fmu-opinf compare -o`` refuses it, unless ``overwrite``.
    extra_figures : dict, optional
        Caption -> PNG path of further figures to embed (e.g. singular values from the fit).
    notes : dict, optional
        Extra settings shown on the page and stored under ``notes`` in metrics.json.
    overwrite : bool, default=False
        Write the report into a folder that holds other files too (they are kept; the report's own files are
        replaced).  An earlier report alone (a folder with ``metrics.json``) is replaced without it.

    Returns
    -------
    Path
        The report's ``index.html``.
    """
    out_dir = Path(out_dir)
    check_not_input(out_dir, [*comparison.inputs, comparison.fom_provenance.get("source")], "report directory",
                    "out_dir")   # (the command line refused it, the function wrote into an unpacked FMU: audit 81c)
    if not overwrite:   # (as the command line: the function mixed its files with a folder's others, audit 81c F12)
        check_report_directory(out_dir, "out_dir")
    created = not out_dir.exists()
    prepare_report_directory(out_dir, "out_dir")
    try:
        return _write_report_files(comparison, out_dir, extra_figures, notes)
    except OSError as exc:  # e.g. disk full while rendering a figure
        raise write_error(out_dir, exc) from None
    finally:
        if created and out_dir.is_dir() and not any(out_dir.iterdir()):
            out_dir.rmdir()  # no empty report folder after a failure


def _write_report_files(comparison: Comparison, out_dir: Path, extra_figures: dict[str, Path] | None,
                        notes: dict[str, Any] | None) -> Path:
    metrics = comparison.metrics()
    if notes:
        metrics["notes"] = jsonable(notes)
    files: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        figures = {"Outputs of full-order model and ROM (paper Figs. 9-10 a-c)": Path(tmp) / "outputs.png",
                   "Relative output error eq. (19) over time (paper Figs. 9-10 d)": Path(tmp) / "error.png"}
        try:
            _figure_outputs(comparison, figures["Outputs of full-order model and ROM (paper Figs. 9-10 a-c)"])
            _figure_error(comparison, figures["Relative output error eq. (19) over time (paper Figs. 9-10 d)"])
        except (ValueError, OverflowError) as exc:   # (audit 55: outputs of 1.7e308 from a damaged ROM's y0)
            peak = max(float(np.max(np.abs(y), initial=0.0)) for y in (comparison.y_fom, comparison.y_rom))
            raise DataError(f"the comparison's figures cannot be drawn ({' '.join(str(exc).split())[:120]}); "
                            f"the outputs reach {peak:.3g}: check the ROM and the source") from None
        files.update({png.name: png.read_bytes() for png in figures.values()})
        all_figures = {**figures, **(extra_figures or {})}
        page = _html_page(comparison, metrics, all_figures)
    # a constant output has no relative error: null, since a bare NaN is not JSON (seventh audit: metrics.json
    # of a model with a constant output failed to parse)
    files["metrics.json"] = json.dumps(jsonable(metrics, non_finite_as_null=True), indent=2, allow_nan=False).encode()
    files["index.html"] = page.encode()
    replace_together(out_dir, files)
    return out_dir / "index.html"


def _html_table(rows: list[tuple[str, Any]]) -> str:
    cells = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in rows)
    return f"<table>{cells}</table>"


def _fmt(value: Any) -> str:
    if isinstance(value, float) and math.isnan(value):
        return "none (the output is constant)"
    if isinstance(value, float):
        return f"{value:.3e}" if (value != 0 and (abs(value) < 1e-2 or abs(value) >= 1e4)) else f"{value:.4g}"
    return str(value)


def _html_page(comparison: Comparison, metrics: dict[str, Any], figures: dict[str, Path]) -> str:
    headline = [
        ("max over time of eps_y, eq. (19) (squared relative error)", _fmt(metrics["max_error"])),
        ("relative L2 error", _fmt(metrics["l2_error"])),
        ("reduced order r", metrics["r"]),
        ("full-order simulation [s]", _fmt(metrics["fom_seconds"])),
        ("ROM simulation [s]", _fmt(metrics["rom_seconds"])),
        ("speed-up (full-order time / ROM time)", _fmt(metrics["speedup"])),
    ]
    timed = metrics.get("speedup_timed") or {}
    if timed:
        headline += [("full-order time measures", timed["fom"]), ("ROM time measures", timed["rom"]),
                     ("like with like", "yes: both FMUs, stepped the same way" if timed["like_with_like"]
                      else "no: the two sides run differently (export the ROM and compare its FMU for that)")]
    chosen = f" ({metrics['input_choice']})" if metrics.get("input_choice") else ""
    settings = [("test input", metrics["input"] + chosen), ("step dt", metrics["dt"]), ("end time", metrics["t_end"]),
                ("steps", metrics["steps"]), ("last training snapshot", metrics["t_train_end"])]
    per_output = [(name, f"relative L2 {_fmt(v['relative_l2'])}; relative max (not squared: max_t |y - y_r| / "
                         f"max_t |y|) {_fmt(v['relative_max'])}; {_range_said(v)} "
                         f"{_fmt(v.get('relative_max_variation', math.nan))}; absolute max "
                         f"{_absolute_max(comparison, j, v.get('absolute_max', math.nan))}")
                  for j, (name, v) in enumerate(metrics["per_output"].items())]
    headline.insert(2, ("max over time of eps_y relative to the outputs' variation (time mean removed from the "
                        "scale)", _fmt(metrics.get("max_error_variation", math.nan))))
    headline[3:3] = [("note", note) for note in comparison_notes(metrics)]
    provenance = [(f"FOM {k}", v) for k, v in comparison.fom_provenance.items() if not isinstance(v, (list, dict))]
    provenance += [(f"ROM {k}", v) for k, v in comparison.rom_provenance.items() if not isinstance(v, (list, dict))]
    images = "".join(
        f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,'
        f'{base64.b64encode(Path(png).read_bytes()).decode()}"><figcaption>{html.escape(caption)}</figcaption></figure>'
        for caption, png in figures.items())
    notes = _html_table([(k, v) for k, v in metrics.get("notes", {}).items()]) if metrics.get("notes") else ""
    alone = _html_each_input_alone(metrics.get("each_input_alone") or [])
    free = metrics.get("free_response")
    alone += _html_free_response(free) if free else ""
    band = metrics.get("training_band")
    alone += _html_training_band(band) if band else ""
    headline[1:1] = _worst_run(metrics)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(comparison.title)}</title>
<style>
body {{ font-family: sans-serif; max-width: 960px; margin: 2em auto; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; }}
th, td {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; font-size: 0.92em; }}
th {{ background: #f4f4f4; font-weight: normal; }}
figure {{ margin: 1em 0; }} img {{ max-width: 100%; }} figcaption {{ color: #555; font-size: 0.9em; }}
</style></head><body>
<h1>{html.escape(comparison.title)}</h1>
<p>A reduced second-order model learned by operator inference (Benner, Filanova, Pontes Duff, Saak, 2025) compared
with the full-order model on an input it was not trained on. The error measure is the paper's eq. (19):
eps_y(t) = |y(t) - y_rom(t)|^2 / max_t |y(t)|^2.</p>
<h2>Result</h2>{_html_table(headline)}
<h2>Per output</h2>{_html_table(per_output)}{alone}
<h2>Figures</h2>{images}
<h2>Settings</h2>{_html_table(settings)}{notes}
<h2>Provenance</h2>{_html_table(provenance)}
</body></html>
"""


def _absolute_max(comparison: Comparison, j: int, value: Any) -> str:
    """Output ``j``'s max absolute error (``value``, in its unit as metrics.json keeps it) for the page: in its
    declared display unit, named, where it has one (a deg output's error in deg, audit 81c F10); else as it is."""
    display = _display_unit(comparison, j)
    if display is None or not isinstance(value, float) or not math.isfinite(value):
        return _fmt(value)
    return f"{_fmt(display.difference(value))} {display.name}"


def _html_each_input_alone(runs: list[dict[str, Any]]) -> str:
    """The report's section on the runs of each input alone: per run the input driven, its spec, eq. (19) and the
    output furthest off relative to its range, with the run's notes ("" where there are none)."""
    if not runs:
        return ""
    rows = [(f"{run['driven_alone']} alone", _run_row(run)) for run in runs]
    return ("<h2>Each input alone</h2><p>The same input, one input driven at a time (the others held at its "
            "operating point): together, the input that moves the outputs most hides the others' errors.</p>"
            + _html_table(rows))


def _html_free_response(run: dict[str, Any]) -> str:
    """The report's section on compare's run of the free response (``metrics["free_response"]``), which compare
    ran and printed and the page left out (audit 81c, F9: a headline of 0.100 where the free response read 0.73)."""
    return ("<h2>Free response</h2><p>The ROM's training showed the source moving on its own from its start values, "
            "so the inputs were also held at their start values and the two models compared from there: the default "
            "test input hides that start transient.</p>" + _html_table([("free response", _run_row(run))]))


def _html_training_band(run: dict[str, Any]) -> str:
    """The report's section on compare's second default test, near the top of the band the training excited
    (``metrics["training_band"]``, :func:`fmu_opinf._test_input.band_test_input`)."""
    return ("<h2>Top of the training band</h2><p>The training excited the outputs well above the default test's "
            "frequency, which lies below the modes a reduced order leaves out: a second harmonic near the top of that "
            "band, where a truncation misses most.</p>"
            + _html_table([("top of the training band", _run_row(run))]))


def _range_said(figures: dict[str, Any]) -> str:
    """What an output's ``relative_max_variation`` is relative to: its range in the run, or its training motion where
    the run leaves it at rest (``scale`` "training", :mod:`fmu_opinf.compare._metrics`)."""
    if figures.get("scale") == "training":
        return "relative to its training motion (it rests in this run: max_t |y - y_r| / its training peak)"
    return "relative to its range (max_t |y - y_r| / (max_t y - min_t y))"


def _run_row(run: dict[str, Any]) -> str:
    """One run's line: its input, eq. (19), the output furthest off relative to its range, and its notes."""
    worst = max(run["per_output"].items(), key=lambda item: _or_zero(item[1].get("relative_max_variation")))
    scale = "its training motion (it rests there)" if worst[1].get("scale") == "training" else "its range"
    text = (f"input {run['input']}; max eps_y {_fmt(run['max_error'])}; {worst[0]} off by "
            f"{_fmt(worst[1].get('relative_max_variation', math.nan))} of {scale}")
    return "; ".join([text] + comparison_notes(run))


def _worst_run(metrics: dict[str, Any]) -> list[tuple[str, str]]:
    """The headline's row naming the further run (each input alone, the free response, the top of the training
    band) whose eq. (19) is above the test input's, with its figure: the page's first figure must not under-state
    what the comparison found."""
    runs = [run for run in (metrics.get("each_input_alone") or []) + [metrics.get("free_response"),
                                                                     metrics.get("training_band")] if run]
    worst = max(runs, key=lambda run: _or_zero(run.get("max_error")), default=None)
    if worst is None or not _or_zero(worst.get("max_error")) > _or_zero(metrics.get("max_error")):
        return []
    name = ("free response" if worst is metrics.get("free_response") else "top of the training band"
            if worst is metrics.get("training_band") else f"{worst['driven_alone']} alone")
    return [("worst max eps_y of all the runs compared (the line above: the test input alone)",
             f"{_fmt(worst['max_error'])}, on the {name} (input {worst['input']}; see below)")]


def _or_zero(value: Any) -> float:
    return float(value) if isinstance(value, float) and math.isfinite(value) else 0.0


def summary_table(rows: list[tuple[str, dict[str, Any]]]) -> str:
    """A plain-text table of named metrics dicts (max eq. 19 error, L2 error, r, times, speed-up)."""
    width = max([28] + [len(name) for name, _ in rows])   # (a longer case name widens the column, not the row)
    header = (f"{'case':<{width}} {'r':>3} {'max eps_y':>10} {'L2 error':>10} {'FOM [s]':>9} {'ROM [s]':>9} "
              f"{'speed-up':>9}")
    lines = [header, "-" * len(header)]
    for name, m in rows:
        lines.append(f"{name:<{width}} {m['r']:>3} {m['max_error']:>10.2e} {m['l2_error']:>10.2e} "
                     f"{m['fom_seconds']:>9.3f} {m['rom_seconds']:>9.4f} {m['speedup']:>9.1f}")
    for name, m in rows:
        lines += [f"  {name}: {note}" for note in comparison_notes(m)]
    notes = [(name, m["speedup_timed"]) for name, m in rows if m.get("speedup_timed")]
    if notes:
        lines.append("speed-up = FOM [s] / ROM [s], wall time of the simulation loops alone:")
    for name, timed in notes:
        kind = "like with like" if timed["like_with_like"] else "not like with like"
        lines.append(f"  {name} ({kind}): FOM = {timed['fom']}; ROM = {timed['rom']}")
    worst = max((m["max_error"] for _, m in rows), default=float("nan"))
    if np.isfinite(worst):   # eq. (19) is a squared ratio: 1e-4 is a 1 % error (ninth audit: read as 4 digits)
        lines.append(f"max eps_y: eq. (19), the squared output error relative to the outputs' peak (its square root, "
                     f"{math.sqrt(worst):.2g} for {worst:.2g}, is the relative error)")
    return "\n".join(lines)
