"""The training data of a fit: the runs checked and read (reduced states of eq. 14, inputs, outputs), centred on
the reference position (package docstring, *Reference state*), the data the SDP fits where they are not the samples
(explicit Euler triples, interval averages and their corrections), the training step, and the snapshot attributes
the fit reads."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..basis import PODBasis, centred, column_blocks, project, read_columns
from ..errors import DataError, DimensionError
from ..inference import lowpass_filter


def _check_complete(runs: list) -> None:
    """Refuse an incomplete run (a recording that stopped early keeps what it had: the partial file) before
    anything is computed from it (ninth audit: a 1-sample partial run was reported as "all snapshots are zero")."""
    for i, run in enumerate(runs):
        if not bool(getattr(run, "attrs", {}).get("complete", True)):
            k = _run_length(run)
            raise DataError(f"run {i} is incomplete: the recording stopped early, after {k} sample"
                            f"{'s' if k != 1 else ''}; re-record it or drop it")


def _run_data(run: Any, i: int, basis: np.ndarray, chunk: int) -> dict[str, np.ndarray]:
    """Reduced states (eq. 14) and inputs of one run, with shape and value checks (its outputs:
    :func:`_stacked_outputs`; completeness: :func:`_check_complete`)."""
    k = _run_length(run)
    out = {name: project(basis, getattr(run, name), chunk, label=f"{name} of run {i}")
           for name in ("xddot", "xdot", "x")}
    for name, array in out.items():
        if array.shape[1] != k:
            raise DimensionError(f"{name} of run {i} has {array.shape[1]} columns; t has {k}")
    _check_port_shape(run, i, "u", k)
    out["u"] = read_columns(run.u, 0, k, f"u of run {i}")
    return out


def _run_length(run: Any) -> int:
    return int(np.shape(run.t)[0])


def _check_port_shape(run: Any, i: int, name: str, k: int) -> None:
    shape = getattr(run, name).shape
    if len(shape) != 2 or shape[1] != k:
        raise DimensionError(f"{name} of run {i} has shape {tuple(shape)}; expected ({name[0]}, {k})")


def _stacked_outputs(runs: list) -> np.ndarray:
    """The outputs of all runs side by side, ``(p, sum k)``, each run read straight into its columns: with many
    outputs they are the largest array of a fit (seventh audit: 200 outputs, 172180 samples, 275 MB), so it is
    held once, not once per run and once stacked."""
    lengths = [_run_length(run) for run in runs]
    for i, (run, k) in enumerate(zip(runs, lengths)):
        _check_port_shape(run, i, "y", k)
    rows = sorted({int(run.y.shape[0]) for run in runs})
    if len(rows) != 1:
        raise DimensionError(f"runs disagree in the number of rows of y: {rows}")
    out = np.empty((rows[0], sum(lengths)))
    start = 0
    for i, (run, k) in enumerate(zip(runs, lengths)):
        for part in column_blocks(rows[0], k):
            out[:, start + part.start:start + part.stop] = read_columns(run.y, part.start, part.stop, f"y of run {i}")
        start += k
    return out


class _CentredRun:
    """A run whose positions read as ``x - x_ref`` (lazily, block by block); every other attribute as is."""

    def __init__(self, run: Any, x_ref: np.ndarray) -> None:
        self._run = run
        self.x = centred(run.x, x_ref)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._run, name)


def _reference_position(runs: list) -> np.ndarray:
    """``x_ref``: the initial position of the first run (module docstring, *Reference state*)."""
    first = runs[0]
    x0 = getattr(first, "x0", None)
    if x0 is None:
        x0 = read_columns(first.x, 0, 1, "x of run 0")[:, 0]
    x0 = np.asarray(x0, dtype=float).reshape(-1)
    if not np.all(np.isfinite(x0)):
        raise DataError("the initial position of run 0 has NaN/Inf; re-record the data")
    return x0


def _initial_velocity(run: Any) -> np.ndarray:
    v0 = getattr(run, "v0", None)
    return np.asarray(read_columns(run.xdot, 0, 1, "xdot of run 0")[:, 0] if v0 is None else v0,
                      dtype=float).reshape(-1)


def _reduced_data(runs: list, pod: PODBasis, lowpass: float | None = None, wide: bool = False,
                  outputs: np.ndarray | None = None, euler_rates: bool = False) -> dict[str, np.ndarray]:
    """Reduced data of all runs side by side: ``xddot, xdot, x (r, k)``, ``u (m, k)``, ``y (p, k)``; with ``wide``
    on the POD's :attr:`~fmu_opinf.basis.PODBasis.wide_basis_` (the extra terms' decision).  ``outputs``: ``y``
    when it was read already (it does not depend on the basis).

    With ``lowpass`` the entries ``"f_xddot", "f_xdot", "f_x", "f_u"`` hold low-pass filtered copies (each
    run filtered separately) for the SDP; the plain entries are always present (outputs fit, eq. 17).  Runs
    recorded with ``fit_rates="interval-averages"`` (accelerations derived from a continuous-time recording)
    give the SDP their interval averages instead (:func:`fmu_opinf.snapshots._rates.interval_averages`).
    """
    basis = pod.wide_basis_ if wide else pod.basis_
    chunk = pod.columns_per_chunk(basis.shape[0])
    per_run = [_run_data(run, i, basis, chunk) for i, run in enumerate(runs)]
    if euler_rates:
        for run, d in zip(runs, per_run):
            d.update(_euler_triples(run, d))
    elif any(_averaged(run) for run in runs):
        for run, d in zip(runs, per_run):
            d.update(zip(("f_xddot", "f_xdot", "f_x", "f_u", "f_start", "f_h"), _sdp_triples(run, d)))
    rows = sorted({d["u"].shape[0] for d in per_run})
    if len(rows) != 1:
        raise DimensionError(f"runs disagree in the number of rows of u: {rows}")
    if lowpass is not None:
        names = ("xddot", "xdot", "x", "u")
        for run, d in zip(runs, per_run):
            step = float(np.diff(np.asarray(run.t[:2], dtype=float))[0])
            d.update(zip(("f_" + n for n in names), lowpass_filter([d.get("f_" + n, d[n]) for n in names],
                                                                   step, lowpass)))
    stacked = {name: np.hstack([d[name] for d in per_run]) for name in per_run[0]}
    stacked["y"] = _stacked_outputs(runs) if outputs is None else outputs
    return stacked


def _euler_triples(run: Any, d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The SDP data of a run that follows explicit Euler steps and whose FMU gave no accelerations: at sample ``i``
    the velocities' backward difference ``(v_i - v_(i-1)) / dt`` with the state of sample ``i - 1``, exactly the
    model's derivative there under the input ``u_i`` held over that step (audit 71 F3: the rates derived for
    accurate data were 1.55 of their norm off, with wrong signs, and the ROM 6-19 % of range off the model).
    Sample 0 repeats sample 1's triple with its own input, so that each run keeps its length and its start."""
    if d["x"].shape[1] < 2:
        return {}
    step = float(np.diff(np.asarray(run.t[:2], dtype=float))[0])
    rates = np.diff(d["xdot"], axis=1) / step
    return {"f_xddot": np.hstack([rates[:, :1], rates]), "f_xdot": np.hstack([d["xdot"][:, :1], d["xdot"][:, :-1]]),
            "f_x": np.hstack([d["x"][:, :1], d["x"][:, :-1]]), "f_u": d["u"]}


def _averaged(run: Any) -> bool:
    return getattr(run, "attrs", {}).get("fit_rates") == "interval-averages"


def _sdp_triples(run: Any, d: dict[str, np.ndarray]) -> tuple[np.ndarray, ...]:
    """The SDP data of one run: its interval averages if it asks for them, else its samples; then the state at
    the start of each interval and the interval length (0 for samples), for :func:`_corrected_averages`."""
    if not _averaged(run) or d["x"].shape[1] < 2:
        k = d["x"].shape[1]
        return d["xddot"], d["xdot"], d["x"], d["u"], np.zeros((2 * d["x"].shape[0], k)), np.zeros((1, k))
    from ..snapshots._rates import interval_averages

    step = float(np.diff(np.asarray(run.t[:2], dtype=float))[0])
    start = np.vstack([d["x"][:, :-1], d["xdot"][:, :-1]])
    return (*interval_averages(d["x"], d["xdot"], d["u"], step), start, np.full((1, start.shape[1]), step))


def _corrected_averages(ops: Any, u_fit: np.ndarray, data: dict[str, np.ndarray]) -> np.ndarray:
    """The interval means of the positions: the two-point Hermite rule of the data plus what the rule misses
    of the fitted model's own trajectory from the same start (:func:`hermite_rule_corrections`)."""
    from ..snapshots._rates import hermite_rule, hermite_rule_corrections

    x_mean = data["f_x"].copy()
    r = x_mean.shape[0]
    force = ops.Br @ u_fit
    for step in np.unique(data["f_h"][0][data["f_h"][0] > 0]):
        cols = data["f_h"][0] == step
        x0, v0 = data["f_start"][:r, cols], data["f_start"][r:, cols]
        x1, v1 = x0 + step * data["f_xdot"][:, cols], v0 + step * data["f_xddot"][:, cols]
        x_mean[:, cols] = hermite_rule(x0, x1, v0, v1, step) + hermite_rule_corrections(
            ops.Mr, ops.Dr, ops.Kr, force[:, cols], x0, v0, step)
    return x_mean


def _at_fixed_step(attrs: dict, dt: float | None) -> bool:
    """Whether the training step ``dt`` is the FMU's fixed communication step, the only one it accepts (the
    snapshot attribute ``fixed_communication_step``; files written before 2026-12-06 do not say: False)."""
    fixed = attrs.get("fixed_communication_step")
    try:
        return dt is not None and fixed is not None and abs(float(fixed) - dt) <= 1e-9 * float(fixed)
    except (TypeError, ValueError):
        return False


def _training_dt(runs: list, attrs: dict) -> float | None:
    if attrs.get("dt") is not None:
        return float(attrs["dt"])
    t = np.asarray(runs[0].t[:2], dtype=float)
    return float(t[1] - t[0]) if t.size == 2 else None


def _net_outputs(y: np.ndarray, u: np.ndarray, Dur: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """``y - Dur u - y0``, formed in blocks into one new array (no full-size temporaries)."""
    out = np.empty_like(y)
    for part in column_blocks(*y.shape):
        np.subtract(y[:, part], Dur @ u[:, part] + y0[:, None], out=out[:, part])
    return out


def _held_outputs(attrs: dict) -> list[str]:
    """The recorded outputs held between samples (``held_outputs`` of the snapshot file, written since 2026-12-07
    when ``--outputs`` named such an output; :mod:`fmu_opinf.sources`)."""
    names = attrs.get("held_outputs")
    return [str(v) for v in np.atleast_1d(names)] if names is not None and np.size(names) else []


def _names(names: Any, count: int) -> list[str] | None:
    if isinstance(names, (list, tuple)) and len(names) == count:
        return [str(v) for v in names]
    return None
