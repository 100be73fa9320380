"""Each training run counts: the weights by which the SDP (eq. 16) and the output-error refinement see each run.

Both fits weigh all runs together, per output: a run whose outputs are 2700 times smaller than another's (the
default pulse of 100 in each input's unit: 100 N beside 100 kN, or beside 100 m of support travel) is fitted only to
its share of the other's round-off, and a full-order ROM of a structure driven by a force and a support motion missed
the exact model by 0.1-6 % of range on the small run's input (audit84 F3).  So each run's columns of the data that
:func:`fmu_opinf.inference.fit_operators` receives -- accelerations, velocities, positions, inputs with the row of
ones of ``fr``, and the refinement's output target -- are multiplied by ``1 / (the run's output size)``
(:func:`run_weights`), the largest run's by one.

That is a weighting, not a change of the data's meaning, for every run, whatever its start or the model: each
column of eq. (16) is one equation ``Mr q'' + Dr q' + Kr q = Br u + fr`` and a column times ``w`` is the same
equation ``w`` times (weighted least squares); and the ROM's step is linear in its start state and its inputs (the
row of ones included), so the run simulated from ``w z0`` under ``w u`` gives ``w`` times its outputs, and its error
against ``w`` times its target counts ``w^2`` times in the refinement's objective.  The operators come out in the
data's units.  Scaling a run's deviations from the reference state instead (``x - x_ref``, ``u - u_start``, ...)
gives the same equations only for a linear model started at rest at the reference with the inputs at their start
values; the weighting needs none of that, so runs from other starts, free responses and nonlinear models are
weighted alike.  The fit's judgements (training misses, order search, warnings) read the data unweighted.
"""

from __future__ import annotations

import numpy as np

from ..basis import column_blocks
from ..refinement import OUTPUT_FLOOR

#: Output size of a run, relative to the largest run's, below which it is weighted as if it had that size: its
#: outputs are then mostly its recording's round-off (1e-10 of the largest run's at the default tolerance), which a
#: weight above 1e4 would raise above the other runs' fits.
RUN_SIZE_FLOOR = 1e-4


#: Ratio of the largest to the smallest run weight below which the runs are left unweighted: runs within this factor
#: of each other's size each count far above the others' round-off already (audit84's runs differed 30-3000x), and
#: weighting them only moves an exact fit within its round-off (a preloaded chain's pulse and own-motion runs, 1 :
#: 2.2: 5e-13 -> 1.5e-12 RMS on exact data) and costs a weighted copy of the outputs (400 outputs: the fit's traced
#: peak 1.3 -> 2.3 times the outputs' size).
BALANCE_FROM = 10.0


def run_weights(y: np.ndarray, u: np.ndarray, maps: tuple[np.ndarray, ...], lengths: list[int],
                judged: np.ndarray) -> np.ndarray | None:
    """The weight of each run: the largest run's output size over its own, at most ``1 / RUN_SIZE_FLOOR``.

    A run's output size is the RMS over its samples of its outputs net of the fitted feedthrough and offset
    (``y - Dur u - y0``, what the refinement compares), each output relative to its RMS over all runs (floored at
    :data:`fmu_opinf.refinement.OUTPUT_FLOOR` of the largest output's, as the refinement weighs outputs), over the
    ``judged`` outputs (those that steer the dynamics).

    Parameters
    ----------
    y : (p, k) ndarray
        Recorded outputs of all runs side by side.
    u : (m, k) ndarray
        Inputs in effect at each sample.
    maps : (Cpr, Cvr, Dur, y0)
        The output map of eq. (17); its feedthrough ``Dur`` and offset ``y0`` are taken off.
    lengths : list of int
        Samples of each run, summing to ``k``.
    judged : (p',) int ndarray
        The rows of the outputs that steer the dynamics.

    Returns
    -------
    (runs,) ndarray or None
        None where there is one run, no judged output moves, or the runs' sizes lie within
        :data:`BALANCE_FROM` of each other: nothing to balance.
    """
    if len(lengths) < 2 or not judged.size:
        return None
    squares = _run_output_squares(y, u, maps[2], maps[3], lengths, judged)
    counts = np.asarray(lengths, dtype=float)[:, None]
    overall = squares.sum(axis=0) / counts.sum()
    if not overall.max() > 0:
        return None
    relative = (squares / counts) / np.maximum(overall, OUTPUT_FLOOR ** 2 * overall.max())
    size = np.sqrt(relative.mean(axis=1))
    weights = size.max() / np.maximum(size, RUN_SIZE_FLOOR * size.max())
    return weights if weights.max() >= BALANCE_FROM else None


def _run_output_squares(y: np.ndarray, u: np.ndarray, Dur: np.ndarray, y0: np.ndarray, lengths: list[int],
                        judged: np.ndarray) -> np.ndarray:
    """``(runs, p')``: each run's sum of squares of each judged output net of ``Dur u + y0``, in column blocks."""
    out = np.zeros((len(lengths), judged.size))
    start = 0
    for i, k in enumerate(lengths):
        for part in column_blocks(judged.size, k):
            cols = slice(start + part.start, start + part.stop)
            net = y[judged, cols] - Dur[judged] @ u[:, cols] - y0[judged, None]
            out[i] += np.sum(net * net, axis=1)
        start += k
    return out


def weighted_columns(array: np.ndarray, weights: np.ndarray | None, lengths: list[int]) -> np.ndarray:
    """A copy of ``array`` (rows, sum of ``lengths``) with each run's columns times its weight; ``array`` itself
    where ``weights`` is None."""
    if weights is None:
        return array
    if sum(lengths) != array.shape[1]:
        raise ValueError(f"run lengths {lengths} do not sum to the {array.shape[1]} columns to weight")
    out = np.empty_like(array, dtype=float)
    start = 0
    for weight, k in zip(weights, lengths):
        np.multiply(array[:, start:start + k], weight, out=out[:, start:start + k])
        start += k
    return out
