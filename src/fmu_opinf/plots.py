"""POD figures (paper Figs. 4 and 6): singular value decay of X and X', cumulative energy with the chosen r.

Figures are drawn with matplotlib's Agg backend and written to files; nothing is shown on screen.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from .basis import cumulative_energy, svdvals

__all__ = ["plot_singular_values", "plot_cumulative_energy", "pod_figures", "decade_label", "fixed_margins",
           "plot_text"]

_ROUND_OFF = 1e-15
_LABELS = {"positions": r"$\sigma_i(X)$", "velocities": r"$\sigma_i(\dot X)$"}
_ELABELS = {"positions": r"$E^i_{\mathrm{cum}}(X)$", "velocities": r"$E^i_{\mathrm{cum}}(\dot X)$"}


#: Runs of control characters (C0, DEL, C1): no font has glyphs for them.
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]+")


def plot_text(label: str) -> str:
    """A label or title from the data (a variable's name, an input's text) drawn as it is.

    matplotlib reads ``$...$`` as math (audit 55: an output named ``$x^{$`` ended the comparison with a parse
    error), so ``$`` is escaped; a control character has no glyph in any font (audit 62: a carriage return in
    an output's name printed matplotlib's "Glyph 13 missing from font(s)" warning), so each run of them is
    drawn as one space.  The names stay as they are everywhere else (files, reports, the exported FMU).
    """
    return _CONTROL.sub(" ", label).replace("$", r"\$")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def fixed_margins(fig: Any, left: float = 0.85, right: float = 0.15, bottom: float = 0.55, top: float = 0.4) -> None:
    """Margins of the axes area in inches, fixed instead of measured.

    ``tight_layout`` and ``bbox_inches="tight"`` draw every text once more to measure it: about 40 % of a
    figure's time (0.18-0.21 s against 0.11 s for the error figure of a report).  The labels of these figures
    have known sizes, so fixed margins fit them.
    """
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=left / width, right=1.0 - right / width, bottom=bottom / height,
                        top=1.0 - top / height)


def _save(fig: Any, path: str | os.PathLike) -> Path:
    """Draw ``fig`` into ``path`` as a whole file (a temporary one renamed), in a folder of plain files only."""
    from ._hdf5 import atomic_path, check_folder_entries

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    check_folder_entries(path.parent, [path.name])
    fixed_margins(fig)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png")
    finally:
        _pyplot().close(fig)
    return path


_SUPERSCRIPTS = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")


def decade_label(value: float, pos: Any = None) -> str:
    """Tick label of a log axis: ``10⁻⁵`` in Unicode superscripts for powers of ten, else ``%g``.

    Looks like matplotlib's default (``$10^{-5}$``) without typesetting each label with mathtext, which took
    40 % of the singular-value figure's drawing time (25 % of the error figure's in a comparison report).
    """
    if not np.isfinite(value) or value <= 0:
        return ""
    exponent = round(float(np.log10(value)))
    if abs(value / 10.0 ** exponent - 1) > 1e-9:
        return f"{value:g}"
    return "10" + str(exponent).translate(_SUPERSCRIPTS)


def _decade_ticks(axis: Any) -> None:
    """Label the major ticks of a log axis with :func:`decade_label`."""
    from matplotlib.ticker import FuncFormatter

    axis.set_major_formatter(FuncFormatter(decade_label))


def _mark_order(ax: Any, r: int | None) -> None:
    """The chosen order as a dashed vertical line with its own legend entry."""
    if r is not None:
        ax.axvline(r, color="k", lw=0.8, ls="--", label=f"chosen order r = {r}")


def _mark_energy_order(ax: Any, rule: tuple[int, float] | None, threshold: bool = False) -> None:
    """Eq. 18's order (a dotted line) where the kept order differs from it, and with ``threshold`` the energy
    threshold that gave it (audit 81c, F13: the figures showed r = 60 from the order search and neither eq. 18's
    r = 24 nor the 0.95 behind it)."""
    if rule is None:
        return
    order, level = rule
    ax.axvline(order, color="0.45", lw=0.8, ls=":", label=f"eq. 18: r = {order} (first E_r >= {level:g})")
    if threshold:
        ax.axhline(level, color="0.45", lw=0.8, ls="-.", label=f"energy threshold {level:g}")


def energy_rule(rom: Any) -> tuple[int, float] | None:
    """``(order, threshold)`` of eq. 18 where the fit kept another order: the first order its order search tried
    (``fit_info["order_search"]``; the search runs only without ``r`` and ``energy``, so at the default threshold
    :data:`~fmu_opinf.basis.DEFAULT_ENERGY`), else None."""
    from .basis import DEFAULT_ENERGY

    search = (getattr(rom, "fit_info", None) or {}).get("order_search") or []
    first = search[0].get("r") if search and isinstance(search[0], dict) else None
    if first is None or int(first) == int(rom.r):
        return None
    return int(first), DEFAULT_ENERGY


def _index_axis(ax: Any, count: int) -> None:
    """Both POD figures span the same index range 1..count, so they can be read side by side."""
    ax.set_xlabel("index i")
    if count:
        ax.set_xlim(0, count + 1)


def plot_singular_values(sigmas: dict[str, np.ndarray], path: str | os.PathLike, r: int | None = None,
                         rule: tuple[int, float] | None = None) -> Path:
    """Singular value decay on a log axis (Figs. 4a, 6a); values below ``1e-15 sigma_1`` (round-off) are omitted.

    Parameters
    ----------
    sigmas : dict
        ``{"positions": (N,) ndarray, "velocities": (N,) ndarray}`` (either may be missing).
    path : str or PathLike
        Image file to write (format from the suffix, e.g. ``.png``).
    r : int, optional
        Chosen order, marked by a vertical line.
    rule : (int, float), optional
        Eq. 18's order and threshold where the kept order differs (:func:`energy_rule`), marked by a dotted line.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    count = 0
    for kind, sigma in sigmas.items():
        sigma = np.asarray(sigma, dtype=float)
        # values below round-off of the largest one carry no information (and unresolved streamed ones are 0)
        shown = sigma > _ROUND_OFF * sigma.max()
        idx = np.arange(1, sigma.size + 1)
        ax.semilogy(idx[shown], sigma[shown], "o", ms=3, fillstyle="none", label=_LABELS.get(kind, kind))
        count = max(count, sigma.size)
    _mark_order(ax, r)
    _mark_energy_order(ax, rule)
    _index_axis(ax, count)
    _decade_ticks(ax.yaxis)
    ax.set_ylabel(r"$\sigma_i$")
    ax.set_title("singular value decay")
    ax.legend()
    return _save(fig, path)


def plot_cumulative_energy(sigmas: dict[str, np.ndarray], path: str | os.PathLike, r: int | None = None,
                           rule: tuple[int, float] | None = None) -> Path:
    """Cumulative energy ``E_i`` (eq. 18) with the chosen order marked (Figs. 4b, 6b), and eq. 18's order and
    threshold where the order search kept another.

    Parameters
    ----------
    sigmas : dict
        ``{"positions": (N,) ndarray, "velocities": (N,) ndarray}``.
    path : str or PathLike
        Image file to write.
    r : int, optional
        Chosen order (vertical line).
    rule : (int, float), optional
        Eq. 18's order and threshold where they differ from ``r`` (:func:`energy_rule`): a dotted vertical line
        and a horizontal one at the threshold.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    count = 0
    for kind, sigma in sigmas.items():
        energy = cumulative_energy(sigma)
        ax.plot(np.arange(1, energy.size + 1), energy, "o", ms=3, fillstyle="none", label=_ELABELS.get(kind, kind))
        count = max(count, energy.size)
    _mark_order(ax, r)
    _mark_energy_order(ax, rule, threshold=True)
    _index_axis(ax, count)
    ax.set_ylabel(r"$E_{\mathrm{cum}}$")
    ax.set_ylim(0, 1.05)
    ax.set_title("cumulative energy (eq. 18)")
    ax.legend()
    return _save(fig, path)


#: The files :func:`pod_figures` writes.
POD_FIGURES = ("singular_values.png", "cumulative_energy.png")


def pod_figures(snapshots: Any, rom: Any, out_dir: str | os.PathLike, max_memory: float = 1e9) -> dict[str, Path]:
    """Write both POD figures for a fitted ROM: ``singular_values.png`` and ``cumulative_energy.png``.

    Parameters
    ----------
    snapshots : Snapshots, list of runs, or run
        Training data (both X and X' are analysed, as in the paper).
    rom : SecondOrderROM
        The fitted model (its ``r`` is marked; its stored singular values are reused).
    out_dir : str or PathLike
        Directory (created if missing).
    max_memory : float, default=1e9
        Dense/streamed switch for the singular values, see :class:`fmu_opinf.basis.PODBasis`.

    Returns
    -------
    dict
        ``{"singular_values": Path, "cumulative_energy": Path}``.
    """
    out_dir = Path(out_dir)
    sigmas = {}
    for kind in ("positions", "velocities"):
        if kind == rom.basis_kind and rom.singular_values is not None:
            sigmas[kind] = rom.singular_values
        else:
            sigmas[kind] = svdvals(snapshots, kind, max_memory=max_memory)
    rule = energy_rule(rom)
    return {
        "singular_values": plot_singular_values(sigmas, out_dir / "singular_values.png", rom.r, rule),
        "cumulative_energy": plot_cumulative_energy(sigmas, out_dir / "cumulative_energy.png", rom.r, rule),
    }
