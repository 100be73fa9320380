"""The demo's figures: log-axis tick labels typeset without mathtext, same values as matplotlib's."""

import numpy as np
import pytest

from fmu_opinf import plots


@pytest.mark.parametrize("value, label", [
    (1.0, "10\u2070"), (10.0, "10\u00b9"), (1e2, "10\u00b2"), (1e-5, "10\u207b\u2075"), (1e-15, "10\u207b\u00b9\u2075"),
    (1e16, "10\u00b9\u2076"), (1e300, "10\u00b3\u2070\u2070"), (2e-3, "0.002"), (5.0, "5"), (0.0, ""), (-1.0, ""),
    (np.inf, ""), (np.nan, ""),
])
def test_decade_label(value, label):
    assert plots.decade_label(value) == label


def test_singular_value_figure_labels_every_decade_tick_like_matplotlib(tmp_path, monkeypatch):
    from matplotlib.ticker import LogFormatterSciNotation

    figures = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: figures.append(fig) or path)
    sigmas = {"positions": np.logspace(0, -12, 40), "velocities": np.logspace(1, -10, 40)}
    plots.plot_singular_values(sigmas, tmp_path / "sv.png", r=5)
    ax = figures[0].axes[0]
    figures[0].canvas.draw()
    ticks = [t for t in ax.yaxis.get_major_ticks() if t.label1.get_visible() and t.label1.get_text()]
    assert len(ticks) >= 3
    reference = LogFormatterSciNotation()
    reference.set_axis(ax.yaxis)
    for tick in ticks:
        text = tick.label1.get_text()
        assert "$" not in text  # no mathtext to typeset
        # the same number as matplotlib's own label, e.g. $\mathdefault{10^{-4}}$
        exponent = reference(tick.get_loc()).split("^{")[1].split("}")[0].replace("\u2212", "-")
        assert text == "10" + exponent.translate(plots._SUPERSCRIPTS)
    plots._pyplot().close(figures[0])
