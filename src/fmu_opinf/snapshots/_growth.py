"""Responses that grow without bound once the inputs are held: a model linearized about an unstable equilibrium.

An inverted pendulum or a buckled structure has a stiffness matrix with a negative eigenvalue, and its response to any
disturbance grows like ``e^(sigma t)``.  fmu-opinf's ROMs are stable by construction (``Mr, Dr, Kr`` positive
semidefinite, eq. 16) and cannot represent it.  Before this test, the automatic window judged such a response
'faded' against its own huge end value, narrowed the training pulse twice and stopped after 28 s with advice
about the pulse's width; with ``--dt`` and ``--t-end`` the chain fitted a stable ROM 2e3 times off (audit 79b, F4).

The test (:func:`unbounded_growth`) splits the part of a run after the inputs stop changing into four equal
quarters and takes the peak of ``||z(t) - z(t_s)||`` in each (``z``: positions, outputs; ``t_s``: the first
sample with the inputs held).  The response grows exponentially where every quarter's peak exceeds the one before
by :data:`GROWTH_RATIO` and the growth does not slow down (:data:`STEADY_GROWTH`).  A model whose ``M, D, K`` are
positive semidefinite cannot pass: with the inputs held its energy does not increase, so a free body drifts
linearly (``t``), or like ``t^2`` under a constant load, and a power ``t^n`` from rest gives quarter ratios
``2^n, 1.5^n, 1.33^n``, whose logarithms fall to 0.42 of the first: the last ratio stays below 3 for ``n <= 3``
and the growth slows for any ``n``.  Oscillations, beats and decays stay bounded.  A growth too slow to reach
:data:`GROWTH_RATIO` per quarter within a run is not seen in it (a longer pilot sees it).

The positions decide where the run has any, the outputs only where it has none: an unstable direction that the
outputs barely show grows in the positions first, and the outputs follow it only once it has outgrown every other
motion (audit 80, F3: ``y = x1 + 1e-3 x2`` with ``x2`` growing like ``e^(0.1 t)``; the positions grew 4.7 times per
quarter over a held part of 62 s, the outputs fell, and they first passed the bar over 248 s).  An output far from the
input (a chain's far end) can rise steeply for a while as the disturbance travels to it; the positions of the masses
the input pushed cannot, so the outputs add no safeguard the positions lack.  A run whose positions still rise
steadily at its end, below the bar (:func:`still_rising`), may hold such a growth that is too slow for it: the
automatic window runs longer probes then (:func:`~._window.probe_growth`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..errors import DataError
from ._isolation import source_label

__all__ = ["GROWTH_RATIO", "RISING", "STEADY_GROWTH", "STILL_STEADY", "Growth", "GrowsWithoutBound",
           "exponential_growth", "growth_error", "growth_rate", "growth_warning", "held_ratios", "quarter_ratios",
           "still_rising", "unbounded_growth", "warn_if_grows"]

#: Each quarter of the held part of a run must peak at least this many times higher than the one before.  A free
#: body under a constant load (``t^2`` from rest) reaches 1.78 in the last quarter; ``e^(sigma t)`` reaches it where
#: the held part lasts at least ``4 ln 3 = 4.4`` time constants ``1 / sigma``.
GROWTH_RATIO = 3.0

#: The growth over the last quarter (its logarithm) must be at least this share of the growth over each quarter
#: before: an exponential keeps its rate (1), a power of time slows (``ln(4/3) / ln 2 = 0.42`` from rest).
STEADY_GROWTH = 0.75

#: The last quarter's peak of the positions over the third's, from which a run that does not pass the test may still
#: be rising at its end (:func:`still_rising`).  An undamped 5-mass chain's last ratio is 0.99 .. 1.03 over held
#: parts of 15.6 to 496 s after the default pulse (1.06 in its outputs), a sagging chain's 0.88 .. 1.0.
RISING = 1.1

#: The growth over the last quarter (its logarithm), as a share of that over the third, from which a run whose last
#: ratio reaches :data:`RISING` may still be rising (:func:`still_rising`).  Above any drift of a free body: a power
#: of time from rest gives ``ln(4/3) / ln(3/2) = 0.71``, a body moving at ``v`` under a constant load ``a``
#: (``v t + a t^2 / 2``) at most 0.753 (at ``a L = 0.49 v``, ``L`` a quarter); 0.75 (:data:`STEADY_GROWTH`) let such
#: a body pushed by the default pulse under a ``--set`` load run probes to t = 2371 s (2.2 s,
#: tests/test_window_free_body.py).
STILL_STEADY = 0.8

#: A run 4 times longer than one before it still rises where its last ratio is at least this many times that run's
#: (:func:`still_rising`): a slow exponential's ratio grew from 1.17 to 1.37, 1.89 and 3.46 over held parts of 7.75,
#: 31, 124 and 248 s (``sigma = 0.02``); a drift's stays at 1.33 (within 1 %).
LONGER_RISE = 1.02

#: Fewest samples per quarter of the held part that the test judges.
QUARTER_SAMPLES = 8

#: Columns read at once from a recording's datasets (:func:`warn_if_grows` on a file).
BLOCK_COLUMNS = 65536


@dataclasses.dataclass(frozen=True)
class Growth:
    """An exponential growth seen in a run.

    Attributes
    ----------
    rate : float
        ``sigma``, the growth rate of ``||z(t) - z(t_s)||`` over the second half of the held part, per time unit
        (:func:`growth_rate`).
    factor : float
        The last quarter's peak over the first quarter's.
    t_start, t_end : float
        The held part judged.
    what : str
        ``"positions"`` or ``"outputs"``: the rows whose growth is reported.
    """

    rate: float
    factor: float
    t_start: float
    t_end: float
    what: str = "outputs"

    def describe(self) -> str:
        """``grows like e^(sigma t) with sigma = 2.66 per time unit (time constant 0.376; ...)``."""
        return (f"grows like e^(sigma t) with sigma = {self.rate:.3g} per time unit (time constant 1/sigma = "
                f"{1.0 / self.rate:.3g}; its {self.what} grew {self.factor:.2g} times from the first to the last "
                f"quarter of t in [{self.t_start:.4g}, {self.t_end:.4g}], the inputs held)")


class GrowsWithoutBound(DataError):
    """The source's response grows without bound once its inputs are held (:func:`growth_error`); ``growth``: what
    was measured."""

    def __init__(self, message: str, growth: Growth) -> None:
        super().__init__(message)
        self.growth = growth


def held_from(t: np.ndarray, t_input: float) -> int:
    """The first sample of ``t`` whose step lies wholly after ``t_input`` (the inputs held from there on)."""
    if len(t) < 2:
        return len(t)
    h = float(t[1] - t[0])
    return int(np.searchsorted(t, t_input + h - 1e-9 * h, side="left"))


def _deviation_norms(z: Any, start: int, stop: int, reference: np.ndarray) -> np.ndarray:
    """``||z[:, j] - reference||_2`` for ``start <= j < stop``, read in column blocks (``z`` may be a dataset); each
    column scaled by its largest entry first, so that a run that grew to 1e300 before it overflowed does not
    overflow here."""
    out = np.empty(max(stop - start, 0))
    for j0 in range(start, stop, BLOCK_COLUMNS):
        j1 = min(j0 + BLOCK_COLUMNS, stop)
        block = np.asarray(z[:, j0:j1], dtype=float) - reference[:, None]
        largest = np.abs(block).max(axis=0)
        scaled = block / np.where(largest > 0, largest, 1.0)
        out[j0 - start:j1 - start] = largest * np.sqrt(np.einsum("ij,ij->j", scaled, scaled))
    return out


def quarter_ratios(t: np.ndarray, z: Any, start: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Each quarter's peak of ``||z(t) - z(t_s)||`` over the peak of the quarter before (3 ratios), and the norms
    themselves over the four quarters, for the rows ``z`` (rows, k) from sample ``start`` on; None where the held
    part has fewer than :data:`QUARTER_SAMPLES` samples per quarter, is not finite, or a quarter stays at
    ``z(t_s)``."""
    k = min(len(t), z.shape[1]) if z.shape[0] else 0
    quarter = (k - start) // 4
    if quarter < QUARTER_SAMPLES:
        return None
    reference = np.asarray(z[:, start], dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        norms = _deviation_norms(z, start, start + 4 * quarter, reference)
        if not np.all(np.isfinite(norms)):
            return None
        peaks = norms.reshape(4, quarter).max(axis=1)
    if not np.all(peaks > 0):
        return None
    return peaks[1:] / peaks[:-1], norms


def exponential_growth(t: np.ndarray, z: Any, start: int, what: str = "outputs") -> Growth | None:
    """The exponential growth of the rows ``z`` (rows, k) from sample ``start`` on, or None (module docstring).

    Parameters
    ----------
    t : (k,) ndarray
        Sample times.
    z : (rows, k) array
        Positions or outputs (an ndarray or an h5py dataset, read in blocks).
    start : int
        First sample with the inputs held.
    what : str
        What the rows are, for :attr:`Growth.what`.

    Returns
    -------
    Growth or None
    """
    seen = quarter_ratios(t, z, start)
    if seen is None:
        return None
    ratios, norms = seen
    rates = np.log(ratios)
    if not (np.all(rates >= math.log(GROWTH_RATIO)) and rates[-1] >= STEADY_GROWTH * rates[:-1].max()):
        return None
    tt = np.asarray(t[start:start + norms.size], dtype=float)
    return Growth(rate=growth_rate(tt, norms), factor=float(np.prod(ratios)), t_start=float(tt[0]),
                  t_end=float(tt[-1]), what=what)


def growth_rate(t: np.ndarray, norms: np.ndarray) -> float:
    """``sigma`` of ``norms ~ e^(sigma t)`` over the second half of ``t``: the least-squares slope of the logarithm
    at the crests (the samples above both neighbours) where there are three or more, at every sample where the
    growth is monotone.  A growing oscillation peaks at one phase of each period, so its crests lie on the exponential
    (a fit to every sample, or to the running maximum, is off by up to 2 % on ``e^(1.3 t) sin 7t``)."""
    half = slice(norms.size // 2, norms.size)
    tt, nn = t[half], norms[half]
    crest = np.nonzero((nn[1:-1] > nn[:-2]) & (nn[1:-1] >= nn[2:]))[0] + 1
    if crest.size >= 3:
        tt, nn = tt[crest], nn[crest]
    return float(np.polyfit(tt, np.log(nn), 1)[0])


def _judged_rows(x: Any, y: Any) -> tuple[Any, str] | None:
    """The rows the test judges: the positions ``x`` where there are any, else the outputs ``y`` (module
    docstring); None where there are neither."""
    for z, what in ((x, "positions"), (y, "outputs")):
        if z is not None and z.shape[0]:
            return z, what
    return None


def unbounded_growth(t: np.ndarray, x: Any, y: Any, t_input: float) -> Growth | None:
    """The exponential growth of a run after its inputs stop changing at ``t_input``, or None.

    The positions ``x`` must grow (:func:`exponential_growth`), or the outputs ``y`` where the run records no
    positions (module docstring: the positions of a model with positive semidefinite ``M, D, K`` cannot grow so,
    and an unstable direction shows in them before it shows in the outputs)."""
    t = np.asarray(t, dtype=float)
    rows = _judged_rows(x, y)
    return None if rows is None else exponential_growth(t, rows[0], held_from(t, t_input), rows[1])


def held_ratios(t: np.ndarray, x: Any, y: Any, t_input: float) -> np.ndarray | None:
    """The quarter ratios (:func:`quarter_ratios`) of a run's positions (its outputs where it records none) once its
    inputs are held from ``t_input``; None where the test cannot judge them."""
    t = np.asarray(t, dtype=float)
    rows = _judged_rows(x, y)
    seen = None if rows is None else quarter_ratios(t, rows[0], held_from(t, t_input))
    return None if seen is None else seen[0]


def still_rising(ratios: np.ndarray | None, before: np.ndarray | None = None) -> bool:
    """Whether a run whose :func:`held_ratios` are ``ratios`` still rises at its end: the last ratio at least
    :data:`RISING`, and the growth over the last quarter at least :data:`STILL_STEADY` of that over the third (or
    the third quarter no higher than the second); or, given the ratios ``before`` of a shorter run of the same input,
    the last ratio at least :data:`RISING` and :data:`LONGER_RISE` times the shorter run's.

    An exponential growth too slow to pass :func:`unbounded_growth` within the run looks so: its ratios stay equal
    once any transient has died out, and rise while a decaying mode beside it dies out (the audit's hidden unstable
    model, ``sigma = 0.1``: 0.81, 1.06, 1.22 over its first pilot's 7.75 s); they rise with the run's length too (to
    the power 4 when the run is 4 times longer, once the growth dominates), a drift's stay 2, 1.5, 1.33 whatever the
    length (after a pulse: the last growth 0.71 of the third's, under a load at most 0.753).  A decaying or
    oscillating response (last ratio near or below 1) is not rising.  Measured on the default pulse, held parts of
    7.75 to 496 s (REPORT of fix80f3): a free body under a constant load reaches 0.72-0.75 of the third's growth,
    and an undamped 5-mass chain rose 1.37 after 0.70 over 7.75 s (at most 1.06 over longer parts), which may count
    as rising and cost the automatic window a probe (:func:`~._window.probe_growth`), never a verdict.
    """
    if ratios is None or not ratios[2] >= RISING:
        return False
    if before is not None and ratios[2] >= LONGER_RISE * before[2]:
        return True
    return bool(ratios[1] <= 1.0 or math.log(ratios[2]) >= STILL_STEADY * math.log(ratios[1]))


def _why_and_fix(growth: Growth) -> str:
    """The cause and the fix, shared by the error and the warning."""
    return (f"the response {growth.describe()}, so the model is unstable at its operating point; fmu-opinf's ROMs "
            "are stable by construction (Mr, Dr, Kr positive semidefinite) and cannot represent it; linearize the "
            "model about a stable operating point, or export it with its stabilizing controller")


def growth_error(source: Any, growth: Growth) -> GrowsWithoutBound:
    """The one-line refusal of the automatic window where a pilot grows without bound."""
    return GrowsWithoutBound(f"auto window: {source_label(source)}: {_why_and_fix(growth)}; no file was written",
                             growth)


def growth_warning(source: Any, growth: Growth) -> str:
    """The one-line warning on a recording (a given ``--dt`` and ``--t-end``) that grows without bound."""
    return f"{source_label(source)}: the recording is kept, but {_why_and_fix(growth)}"


def warn_if_grows(source: Any, signal: Any, run: Any) -> Growth | None:
    """Warn (and keep the warning with the file being recorded, :func:`~._notes.warn_recording`) where a recorded
    ``run`` of ``signal`` grows without bound once its inputs are held; the growth, or None (also where an earlier
    run of the same file was warned).  Inputs that never
    settle (harmonic, chirp) are not judged."""
    from ._notes import current_recording_notes, warn_recording
    from ._window import input_activity

    if "unbounded-growth" in current_recording_notes().get("recording_verdicts", []):
        return None   # said once per file: one run's growth speaks for the model
    t = np.asarray(run.t, dtype=float)
    t_input, _ = input_activity(signal, getattr(source, "m", 0))
    if len(t) < 2 or (t_input == 0.0 and not _held_throughout(signal, t)):
        return None
    growth = unbounded_growth(t, run.x, run.y, t_input)
    if growth is not None:
        warn_recording(growth_warning(source, growth), "unbounded-growth", stacklevel=3)
    return growth


def _held_throughout(signal: Any, t: np.ndarray) -> bool:
    """Whether ``signal`` is constant over ``t`` (a free response, held inputs); :func:`input_activity` gives
    ``t_input = 0`` for it and for an input that never settles alike."""
    try:
        u = np.atleast_2d(np.asarray(signal.sample(t), dtype=float))
    except Exception:  # a signal that cannot be sampled: not judged
        return False
    return bool(u.size == 0 or np.all(u == u[:, :1]))
