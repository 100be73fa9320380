"""The extra terms beyond the paper's model (``fr``, ``Dur``, ``y0``): which are requested, and which the data keep
(``terms="auto"``, decided on a POD basis of order :data:`TERM_DECISION_ORDER`; the package docstring says why)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InputSpecError
from ..inference import TERM_SIGNIFICANCE, term_residuals
from ..rom import TERMS


def _requested_terms(terms: str | Sequence[str]) -> dict[str, bool | None]:
    """``{"fr": ..., "Dur": ..., "y0": ...}`` with True (fit), False (leave out) or None (the data decide)."""
    if isinstance(terms, str) and terms in ("auto", "none", "all"):
        value = {"auto": None, "none": False, "all": True}[terms]
        return dict.fromkeys(TERMS, value)
    names = [t.strip() for t in (terms.split(",") if isinstance(terms, str) else terms) if t.strip()]
    unknown = [t for t in names if t not in TERMS]
    if unknown:
        raise InputSpecError(f"terms {unknown} are not known; use 'auto', 'none', 'all' or a list of "
                             f"{', '.join(TERMS)}")
    return {name: name in names for name in TERMS}


#: Order of the POD basis on which ``terms="auto"`` decides (the snapshot rank if smaller, the ROM's order if
#: larger): at the ROM's order the residuals are the truncation's, which hides the terms a source has (third
#: audit, 2026-11-26: 30 masses under gravity with an acceleration sensor and an output offset, r = 9: only
#: ``fr`` kept, max eps_y 2.9e-3 against 2.8e-4 with every term; r = 20 dropped ``y0``).
TERM_DECISION_ORDER = 60


def _decision_order(runs: list) -> int:
    """Order of the POD basis on which the extra terms are decided: :data:`TERM_DECISION_ORDER`, at most an
    eighth of the samples (about a quarter as many unknowns per row, ``2 order + m``, as samples: the least
    squares stay overdetermined); the POD bounds it by the snapshot rank and keeps at least the ROM's order."""
    samples = sum(int(np.asarray(run.t).size) for run in runs)
    return min(TERM_DECISION_ORDER, samples // 8)


def _choose_terms(data: dict[str, np.ndarray], requested: dict[str, bool | None],
                  sdp: str = "", judged: np.ndarray | None = None) -> tuple[dict, dict]:
    """Decide which extra terms to fit (module docstring): forced ones as requested, the rest by the residual
    reduction each brings to its least-squares problem; the force offset is tested on the data the SDP fits
    (prefix ``sdp``: ``"f_"`` for interval averages); ``Dur`` and ``y0`` on the ``judged`` outputs (default all):
    an output not linear in the states leaves a residual that hides theirs (audit 77a F1: an energy output hid the
    feedthrough of a force sensor, which was then 0.34 of its range off)."""
    k = data["u"].shape[1]
    y = data["y"] if judged is None or judged.size == data["y"].shape[0] else data["y"][judged]
    ones = np.ones((1, k))
    sdp_ones = ones if data[sdp + "u"].shape[1] == k else np.ones((1, data[sdp + "u"].shape[1]))
    tests = {
        "fr": ([data[sdp + "xdot"], data[sdp + "x"], data[sdp + "u"]], sdp_ones, data[sdp + "xddot"]),
        "Dur": ([data["x"], data["xdot"], ones], data["u"], y),
        "y0": ([data["x"], data["xdot"], data["u"]], ones, y),
    }
    chosen, info, spaces = {}, {}, {}
    for name, (base, extra, target) in tests.items():
        if extra.shape[0] == 0 or target.shape[0] == 0:
            chosen[name], info[name] = False, {"fitted": False, "reason": "no such term (m = 0 or p = 0)"}
            continue
        without, with_term = term_residuals(base, extra, target, spaces)
        significant = with_term <= TERM_SIGNIFICANCE * without and without > 1e3 * np.finfo(float).eps
        decision = requested[name]
        chosen[name] = significant if decision is None else decision
        info[name] = {"fitted": bool(chosen[name]), "decided_by": "data" if decision is None else "request",
                      "residual_without": without, "residual_with": with_term}
    return chosen, info
