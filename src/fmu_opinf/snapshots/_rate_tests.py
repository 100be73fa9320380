"""The data's tests of recorded rates: whether velocities are the rates of the positions, and whether
accelerations lag the velocities by one sample.

Over a step ``h`` a position moves by ``h`` times its velocity (trapezoidal rule for an accurate integration; the
forward or backward rule for an FMU's explicit Euler steps), so a mismatch of order one per step, where a right
pairing leaves ``(omega h)^2``, shows a wrong pairing (:func:`rate_mismatch`); accelerations that fit the velocities'
increments far better when shifted by one sample are stale (:func:`stale_rates`).  :class:`RateSums` sums both tests
block by block while a run is recorded.  What the verdicts mean for a recording is decided in
:mod:`fmu_opinf.snapshots._consistency`; :class:`Repair` is the shape of a verdict that records a run again.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["MISMATCH", "RateSums", "Repair", "evaluation_sample", "evaluation_verdict", "rate_mismatch",
           "stale_rates", "stale_verdict"]

#: A position whose increments differ from ``h`` times its velocity by more than this fraction (relative, over a
#: run) is not paired with that velocity: a right pairing at a step that resolves the motion leaves at most
#: ``omega h / 2`` (explicit Euler, ``omega h < 0.5``), a wrong one about one.
MISMATCH = 0.25
#: Accelerations are stale when shifted by one sample they fit the velocities' increments this much better ...
_STALE_GAIN = 0.2
#: ... and then fit them to this fraction of the increments themselves, as a step that resolves the motion allows
#: (the trapezoidal rule leaves ``(omega h)^2 / 12``).  Audit 70 F8: an FE beam whose fastest modes the step did not
#: resolve fitted its increments to 2.9 times their size, shifted to 0.55: "stale", though its derivatives were
#: current.
_STALE_FIT = 0.3
#: A direct evaluation of the accelerations (:func:`evaluation_verdict`) decides where it lies this much closer to one
#: recorded sample than to the other (a current value is off by ``omega`` times the probe's step, 1e-6 ``h``, relative;
#: the other sample by ``omega h`` or more).
_EVALUATION_MARGIN = 0.1
#: Rows (states) moving less than this fraction of the most moving one are not judged.
_QUIET = 1e-8


@dataclass(frozen=True)
class Repair:
    """What to record instead: variable names (None: the default rule), ``""`` to derive from the data, and why."""

    positions: list[str] | None
    velocities: list[str] | str | None
    accelerations: str | None
    reason: str

    def as_options(self) -> str:
        """The command-line options that make the repair."""
        options = []
        for flag, value in (("positions", self.positions), ("velocities", self.velocities),
                            ("accelerations", self.accelerations)):
            if value is not None:
                options.append(f'--{flag} "{value if isinstance(value, str) else ",".join(value)}"')
        return " ".join(options)


#: Samples per block of the rate checks: ``600 x 256`` doubles (1.2 MB) stay in cache through the several passes
#: over a block (600 states x 4000 samples, 2026-11-27: 14.5 / 10.0 ms for the two checks over whole arrays, 9.1 /
#: 8.2 ms in blocks).
_BLOCK = 256


def rate_mismatch(x: np.ndarray, v: np.ndarray, h: float) -> np.ndarray:
    """Per row: ``min`` over the trapezoidal, forward and backward rule of ``||dx - h v_rule|| / scale`` (0 for a
    row that hardly moves), ``dx`` the increments of ``x``, ``v_rule`` the velocity the rule uses and ``scale``
    the larger of ``||dx||`` and ``||h v_trapezoid||``; the squared norms are summed block by block
    (:data:`_BLOCK`, :class:`RateSums`)."""
    sums = RateSums(x.shape[0], x.shape[1], h, mismatch=True, stale=False)
    sums.feed(x, v, None, x.shape[1])
    return sums.mismatch()


def rate_mismatch_over(x: np.ndarray, v: np.ndarray, h: float, steps: np.ndarray,
                       floor: np.ndarray | None = None) -> np.ndarray:
    """:func:`rate_mismatch` over the steps ``steps`` alone (step ``j`` from sample ``j`` to ``j + 1``, ascending),
    each row's scale raised to at least ``floor`` (a row that rests on those steps is judged against the motion
    the caller names, not against its own round-off)."""
    sums = RateSums(x.shape[0], x.shape[1], h, mismatch=True, stale=False)
    breaks = np.flatnonzero(np.diff(steps) != 1) + 1
    for run in np.split(np.asarray(steps), breaks):   # (consecutive steps: one block of samples each)
        if run.size:
            sums._add_mismatch(x[:, run[0]:run[-1] + 2], v[:, run[0]:run[-1] + 2])
    return sums.mismatch(floor)


def _row_squares(a: np.ndarray) -> np.ndarray:
    """Sum of squares of each row."""
    return np.einsum("ij,ij->i", a, a)


def stale_rates(v: np.ndarray, a: np.ndarray, h: float, u: np.ndarray | None = None) -> bool:
    """Whether ``a`` lags ``v``'s rate by one sample: shifted by one, the trapezoidal rule fits the increments of
    ``v`` at least five times better and to 0.3 of their size, and unshifted it misses by more than round-off.
    Steps next to a change of the inputs ``u`` (where the rule misses anyway, by the jump of the acceleration) are
    not counted.  Computed block by block (:data:`_BLOCK`, :class:`RateSums`)."""
    sums = RateSums(v.shape[0], v.shape[1], h, mismatch=False, stale=True)
    sums.feed(None, v, a, v.shape[1])
    return sums.stale(v, u)


def evaluation_sample(a: np.ndarray, u: np.ndarray | None) -> int | None:
    """The sample ``i`` at which a direct evaluation of the accelerations tells stale from current ones best
    (:func:`evaluation_verdict`): the first whose next increment ``||a[:, i + 1] - a[:, i]||`` is at least half the
    largest, among those with ``1 <= i <= k - 2`` and the same input over the steps that end at ``t[i]`` and
    ``t[i + 1]`` (an FMU's stale value may belong to either input); None where no such increment moves."""
    k = a.shape[1]
    if k < 3:
        return None
    jumps = np.linalg.norm(np.diff(a, axis=1), axis=0)[1:k - 1]   # a[:, i + 1] - a[:, i] for i = 1 .. k - 2
    if u is not None and u.size:
        jumps = np.where(np.all(u[:, 1:k - 1] == u[:, 2:k], axis=0), jumps, 0.0)
    largest = float(np.max(jumps, initial=0.0))
    if not (largest > 0 and math.isfinite(largest)):
        return None
    return 1 + int(np.flatnonzero(jumps >= 0.5 * largest)[0])


def evaluation_verdict(evaluated: np.ndarray, now: np.ndarray, after: np.ndarray) -> bool | None:
    """Whether accelerations are stale, from the FMU's own value ``evaluated`` at the state of sample ``i`` (read
    just after it, :func:`evaluation_sample`): True where it is the value recorded at sample ``i + 1`` (``after``:
    each sample then holds the derivative of the one before), False where it is the value recorded at ``i``
    (``now``), None where it is neither clearly (:data:`_EVALUATION_MARGIN`).

    The rule of :func:`stale_rates` on sampled increments cannot tell where the step leaves modes unresolved: an FE
    beam started by an impact (modes far above pi/dt) fitted the shifted rule better with current derivatives, and
    was recorded a second time with derivatives taken from the data (audit 71 F6)."""
    to_now, to_after = float(np.linalg.norm(evaluated - now)), float(np.linalg.norm(evaluated - after))
    if not (math.isfinite(to_now) and math.isfinite(to_after)):
        return None
    if to_after <= _EVALUATION_MARGIN * to_now:
        return True
    if to_now <= _EVALUATION_MARGIN * to_after:
        return False
    return None


def stale_verdict(now: float, shifted: float, increments: float) -> bool:
    """The rule of :func:`stale_rates` on the norms of the trapezoidal rule's residuals with the accelerations as
    recorded (``now``) and shifted by one sample (``shifted``), and of the velocities' increments."""
    return bool(now > 1e-6 * increments and shifted < _STALE_GAIN * now and shifted < _STALE_FIT * increments)


def _column_squares(a: np.ndarray) -> np.ndarray:
    """Sum of squares of each column."""
    return np.einsum("ij,ij->j", a, a)


def _quiet_overflow(method: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` with NumPy's overflow and invalid-value warnings off: a run diverging at an unstable step (finite
    values near 1e300) overflows the sums of squares to inf, and the checks then judge nothing (comparisons with
    inf and nan are false) where NumPy's raw warning reached the user before the run's own error (audit 58)."""
    @functools.wraps(method)
    def quiet(*args: Any, **kwargs: Any) -> Any:
        with np.errstate(over="ignore", invalid="ignore"):
            return method(*args, **kwargs)
    return quiet


class RateSums:
    """The sums behind :func:`rate_mismatch` and :func:`stale_rates` over the first ``k`` samples, fed as they are
    recorded: :meth:`feed` takes every block of :data:`_BLOCK` samples that is complete, so a recorder can check
    the samples so far on another core while it records the next ones (the same numbers as the whole arrays).

    ``rows``: the rows of the arrays fed that are judged (default all).
    """

    def __init__(self, n: int, k: int, h: float, *, mismatch: bool, stale: bool,
                 rows: slice | np.ndarray = slice(None)) -> None:
        self.k, self.h, self.rows = k, h, rows
        self.squares = np.zeros((5, n)) if mismatch else None  # dx, h v_trapezoid, trapezoidal / forward / backward
        self.count = k - 2  # increments v_(i+1) - v_i judged by the stale test, i < k - 2
        self.now = np.empty(max(self.count, 0)) if stale else None
        self.shifted = np.empty(max(self.count, 0)) if stale else None
        self.increments_squared = 0.0
        self._mismatch_from = self._stale_from = 0

    def _block(self, array: np.ndarray, c0: int, c1: int) -> np.ndarray:
        part = array[:, c0:c1]
        return part if isinstance(self.rows, slice) and self.rows == slice(None) else part[self.rows]

    @_quiet_overflow
    def feed(self, x: np.ndarray | None, v: np.ndarray, a: np.ndarray | None, available: int) -> None:
        """Sum every block whose samples are among the first ``available`` of the ``(n, >= available)`` arrays."""
        available = min(available, self.k)
        while self.squares is not None and self._mismatch_from < self.k - 1:
            c0 = self._mismatch_from
            c1 = min(c0 + _BLOCK, self.k - 1)
            if c1 + 1 > available:
                break
            self._add_mismatch(self._block(x, c0, c1 + 1), self._block(v, c0, c1 + 1))
            self._mismatch_from = c1
        while self.now is not None and self._stale_from < self.count:
            c0 = self._stale_from
            c1 = min(c0 + _BLOCK, self.count)
            if c1 + 2 > available:
                break
            self._add_stale(c0, c1, self._block(v, c0, c1 + 1), self._block(a, c0, c1 + 2))
            self._stale_from = c1

    def _add_mismatch(self, x: np.ndarray, v: np.ndarray) -> None:
        dx = np.subtract(x[:, 1:], x[:, :-1])
        before, after = v[:, :-1], v[:, 1:]
        buffer = np.add(before, after)
        buffer *= 0.5 * self.h
        squares = self.squares
        squares[0] += _row_squares(dx)
        squares[1] += _row_squares(buffer)
        squares[2] += _row_squares(np.subtract(dx, buffer, out=buffer))
        for row, rule in ((3, before), (4, after)):
            np.multiply(rule, self.h, out=buffer)
            squares[row] += _row_squares(np.subtract(dx, buffer, out=buffer))

    def _add_stale(self, c0: int, c1: int, v: np.ndarray, a: np.ndarray) -> None:
        dv = np.subtract(v[:, 1:], v[:, :-1])
        sums = np.add(a[:, :-1], a[:, 1:])  # a_i + a_(i+1), one more for the shifted rule
        sums *= 0.5 * self.h
        self.increments_squared += float(np.einsum("ij,ij->", dv, dv))
        residual = np.subtract(dv, sums[:, :-1])
        self.now[c0:c1] = _column_squares(residual)
        self.shifted[c0:c1] = _column_squares(np.subtract(dv, sums[:, 1:], out=residual))

    @_quiet_overflow
    def mismatch(self, floor: np.ndarray | None = None) -> np.ndarray:
        """:func:`rate_mismatch` of the samples fed (all ``k`` of them); ``floor``: a least scale per row
        (:func:`rate_mismatch_over`)."""
        squares = self.squares
        scale = np.sqrt(np.maximum(squares[0], squares[1]))
        if floor is not None:
            scale = np.maximum(scale, floor)
        residual = np.sqrt(squares[2:].min(axis=0))
        moving = scale > _QUIET * max(float(scale.max(initial=0.0)), np.finfo(float).tiny)
        return np.where(moving, residual / np.where(moving, scale, 1.0), 0.0)

    @_quiet_overflow
    def rules(self) -> tuple[float, float, float]:
        """The relative residuals of the trapezoidal, forward and backward rule over all rows fed (each the root of
        its summed squares over that of the larger of ``||dx||`` and ``||h v_trapezoid||``; NaN for data that do
        not move)."""
        scale = math.sqrt(float(np.maximum(self.squares[0], self.squares[1]).sum()))
        if not scale > 0 or not math.isfinite(scale):
            return math.nan, math.nan, math.nan
        trapezoidal, forward, backward = (math.sqrt(float(row.sum())) / scale for row in self.squares[2:])
        return trapezoidal, forward, backward

    @_quiet_overflow
    def stale(self, v: np.ndarray, u: np.ndarray | None = None) -> bool:
        """:func:`stale_rates` of the samples fed (all ``k`` of them; ``v``, the judged rows only, for its last
        increment)."""
        if self.k < 4:
            return False
        last = v[:, self.k - 1] - v[:, self.k - 2]  # the one increment that no block judges, in the scale of round-off
        increments_squared = self.increments_squared + float(last @ last)
        smooth = np.ones(self.count, dtype=bool)
        if u is not None and u.size:  # a change between samples c and c + 1 spoils the steps c - 2 .. c + 2
            changes = np.any(np.diff(u[:, :self.k], axis=1) != 0, axis=0).astype(float)
            smooth = np.convolve(changes, np.ones(5))[2:2 + self.count] == 0
        now_norm, shifted_norm = math.sqrt(self.now[smooth].sum()), math.sqrt(self.shifted[smooth].sum())
        return stale_verdict(now_norm, shifted_norm, math.sqrt(increments_squared))

