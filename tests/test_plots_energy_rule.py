"""The POD figures mark eq. 18's order and its threshold where the order search kept another (audit 81c, F13)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fmu_opinf import plots
from fmu_opinf.basis import DEFAULT_ENERGY, energy_order


def _drawn(monkeypatch, tmp_path, rom):
    """The two figures pod_figures draws for ``rom``, kept open: {file name: figure}."""
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    monkeypatch.setattr(plots, "svdvals", lambda *args, **kwargs: rom.singular_values)
    plots.pod_figures(None, rom, tmp_path / "fig")
    return kept


def _lines(ax):
    vertical = {round(line.get_xdata()[0], 9): line.get_label() for line in ax.get_lines()
                if len(set(np.atleast_1d(line.get_xdata()))) == 1}
    horizontal = {round(line.get_ydata()[0], 9): line.get_label() for line in ax.get_lines()
                  if len(set(np.atleast_1d(line.get_ydata()))) == 1}
    return vertical, horizontal


SIGMA = np.exp(-0.15 * np.arange(80))


def test_order_search_above_eq18_marks_both_orders_and_the_threshold(monkeypatch, tmp_path):
    first = energy_order(SIGMA, DEFAULT_ENERGY)
    rom = SimpleNamespace(r=60, basis_kind="positions", singular_values=SIGMA,
                          fit_info={"order_search": [{"r": first}, {"r": 30}, {"r": 60}]})
    singular, energy = _drawn(monkeypatch, tmp_path, rom)
    vertical, horizontal = _lines(energy.axes[0])
    assert vertical[60] == "chosen order r = 60" and vertical[first] == f"eq. 18: r = {first} (first E_r >= 0.95)"
    assert horizontal[DEFAULT_ENERGY] == "energy threshold 0.95"
    assert first in _lines(singular.axes[0])[0]
    legend = [text.get_text() for text in energy.axes[0].get_legend().get_texts()]
    assert "energy threshold 0.95" in legend and f"eq. 18: r = {first} (first E_r >= 0.95)" in legend


def test_an_order_from_eq18_is_marked_once(monkeypatch, tmp_path):
    first = energy_order(SIGMA, DEFAULT_ENERGY)
    rom = SimpleNamespace(r=first, basis_kind="positions", singular_values=SIGMA,
                          fit_info={"order_search": [{"r": first}]})
    _, energy = _drawn(monkeypatch, tmp_path, rom)
    assert _lines(energy.axes[0]) == ({first: f"chosen order r = {first}"}, {})
