"""Which integrator a co-simulation's recording follows: one explicit (or implicit) Euler step per communication
step, or a declared fixed internal step taken by explicit Euler.  Either way the recording follows the FMU's
first-order integrator, not the model, and the recording says so (a warning kept in the snapshot file, with the fix).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._validate import ME, either
from ._isolation import source_label
from ._rate_tests import _BLOCK, RateSums, _quiet_overflow

__all__ = ["EULER_EXACT", "EULER_TRAPEZOIDAL_MISS", "INTERNAL_RULE_MARGIN", "internal_step_rules",
           "warn_if_euler_steps", "warn_if_internal_steps"]


#: A co-simulation takes one Euler step per communication step when the forward (or backward) rule fits the position
#: increments to this relative residual, round-off, ...
EULER_EXACT = 1e-9
#: ... while the trapezoidal rule, which an accurate integration follows to ``(omega h)^2 / 12``, misses by at least
#: this (audit 70 F1, a Simulink ode1-style FMU at 0.01 s: forward 2.2e-15, trapezoidal 2.1e-2; an accurate FMU at
#: 0.003 s: forward 3.9e-3, trapezoidal 9.5e-6).
EULER_TRAPEZOIDAL_MISS = 1e-5


def warn_if_euler_steps(source: Any, x: np.ndarray, v: np.ndarray, h: float, sums: RateSums | None) -> None:
    """Warn (kept in the snapshot file, :mod:`._notes`) where a co-simulation's positions move by exactly ``h`` times
    the velocity at the start (explicit Euler) or at the end (semi-implicit or implicit Euler) of each step: the
    recording then follows the FMU's first-order integrator, not the model (audit 70 F1: a Simulink ode1-style FMU
    recorded silently, its ROM 41-49 % of range off the model, with most of the damping lost)."""
    from ..sources import fixed_communication_step, offers_model_exchange
    from ._notes import current_recording_notes, warn_recording

    if {"forward-euler", "backward-euler"} & set(current_recording_notes().get("recording_verdicts", [])):
        return   # said for an earlier run of this recording
    if sums is None or sums.squares is None or sums.k != x.shape[1]:
        sums = RateSums(x.shape[0], x.shape[1], h, mismatch=True, stale=False)
        sums.feed(x, v, None, x.shape[1])
    trapezoidal, forward, backward = sums.rules()
    euler = min(forward, backward)
    if not (euler <= EULER_EXACT and trapezoidal >= EULER_TRAPEZOIDAL_MISS):
        return
    if offers_model_exchange(source):
        remedy = f"record by model exchange ({ME})"
    elif fixed_communication_step(source) is not None:
        remedy = ("its communication step is fixed and it offers no model exchange: export it with a smaller step or "
                  "a higher-order solver")
    elif _fixed_internal_step(source) is not None:   # a smaller --dt takes the same internal steps (audit 73 F4)
        remedy = _FIXED_INTERNAL_REMEDY
    else:
        remedy = f"record at a smaller {either('--dt')} (the error shrinks like dt; it offers no model exchange)"
    rule = "start" if forward <= backward else "end"
    warn_recording(f"{source_label(source)}: the co-simulation takes one Euler step per communication step (each "
                   f"position moves by dt={h:g} times its velocity at the {rule} of the step, to {euler:.1e}; an "
                   f"accurate integration follows the trapezoidal rule, which misses by {trapezoidal:.1e}): the "
                   f"recording follows the FMU's integrator, not the model (damping and frequencies off by terms of "
                   f"order omega dt); {remedy}", "forward-euler" if rule == "start" else "backward-euler",
                   stacklevel=4)


#: A co-simulation with a fixed internal step (FMI 3 ``fixedInternalStepSize``) takes explicit Euler steps when the
#: rule of those steps fits the position increments at most this fraction of the residual of the rule of an accurate
#: integration, and integrates accurately when the accurate rule fits at most this fraction of the Euler rule's
#: (audit 73 F4, 6 Euler steps of 0.003 s per communication step: 5.2e-6 against 4.0e-3; :func:`internal_step_rules`).
INTERNAL_RULE_MARGIN = 0.1
#: The fix for a co-simulation whose fixed internal step follows a low-order integrator and that offers no model
#: exchange: no communication step changes its internal one.
_FIXED_INTERNAL_REMEDY = (f"its internal step is fixed (a smaller {either('--dt')} takes the same steps) and it offers "
                          "no model exchange: export it with a smaller fixedInternalStepSize or a higher-order solver")


def _fixed_internal_step(source: Any) -> float | None:
    """:func:`fmu_opinf.snapshots._window.fixed_internal_step` (imported late: that module imports this one's
    users)."""
    from ._window import fixed_internal_step

    return fixed_internal_step(source)


@_quiet_overflow
def internal_step_rules(x: np.ndarray, v: np.ndarray, a: np.ndarray, u: np.ndarray | None, dt: float,
                        steps: int) -> tuple[float, float]:
    """The relative residuals of two rules for the position increments of a co-simulation recorded at ``dt``: the
    rule of ``steps`` explicit Euler steps of ``h = dt / steps`` per communication step, and the rule of an accurate
    integration (its limit of infinitely many steps).  NaN where the positions do not move.

    Explicit Euler maps the state over one communication step by ``(I + h A)^N`` (``N = steps``): the positions
    move by ``dt v_0 + h^2 sum_(i < N-1) (N - 1 - i) a_i`` and the velocities by ``h sum_(i < N) a_i``, with
    ``a_i`` the model's accelerations at the internal steps.  With ``a_i = a_0 + i s`` (the part of them the samples
    hold), the velocities' increment gives ``s`` and the rule is

        dx - dt v_0 - h^2 N (N - 1) / 2 a_0 - h (N - 2) / 3 (dv - dt a_0) = 0,

    exact for ``N <= 2`` (one step: the forward rule of :func:`warn_if_euler_steps`) and else left with terms of
    order ``(omega dt)^3`` relative.  As ``N`` grows it becomes Taylor's rule through the third derivative,
    ``dx - dt v_0 - dt^2 / 2 a_0 - dt / 3 (dv - dt a_0)``, which an accurate integration follows to those terms.
    The two differ by about ``dt h a_0 / 2``, i.e. ``omega h / 2`` relative: the damping Euler's steps lose.

    ``a`` must be the FMU's derivatives at the recorded states (data-derived ones follow the steps).  Sample ``i``'s
    acceleration pairs with the input ``u[:, i]`` held over the step that ends there (the project's column
    convention), while the step from ``i`` takes ``u[:, i + 1]``: the part of each row's residual that is linear
    in ``u[:, i + 1] - u[:, i]`` is removed by least squares."""
    k = x.shape[1]
    changes = np.diff(u, axis=1) if u is not None and u.size else np.zeros((0, k - 1))
    changes = changes[np.any(changes != 0, axis=1)]
    basis = np.linalg.qr(changes.T)[0] if changes.size and changes.shape[0] < (k - 1) // 4 else None
    squares, projected = np.zeros(3), np.zeros((2, x.shape[0], 0 if basis is None else basis.shape[1]))
    for c0 in range(0, k - 1, _BLOCK):   # blocks of samples: a few (n, _BLOCK) temporaries, not (n, k)
        c1 = min(c0 + _BLOCK, k - 1)
        dx, residuals = _internal_step_residuals(x[:, c0:c1 + 1], v[:, c0:c1 + 1], a[:, c0:c1], dt, steps)
        squares[0] += float(np.einsum("ij,ij->", dx, dx))
        for j, residual in enumerate(residuals):
            squares[1 + j] += float(np.einsum("ij,ij->", residual, residual))
            if basis is not None:
                projected[j] += residual @ basis[c0:c1]
    if not (squares[0] > 0 and math.isfinite(squares[0])):
        return math.nan, math.nan
    # the residual left after removing the least-squares part in the input changes: ||R||^2 - ||R Q||^2
    left = [max(squares[1 + j] - float(np.einsum("ij,ij->", projected[j], projected[j])), 0.0) for j in range(2)]
    return math.sqrt(left[0] / squares[0]), math.sqrt(left[1] / squares[0])


def _internal_step_residuals(x: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float,
                             steps: int) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The position increments over the samples of ``x, v`` (one more than ``a``), and the residuals of the rule of
    ``steps`` explicit Euler steps and of the accurate rule (:func:`internal_step_rules`)."""
    h = dt / steps
    dx = np.diff(x, axis=1)
    base, slope = dx - dt * v[:, :-1], np.diff(v, axis=1) - dt * a
    euler = base - (h * h * steps * (steps - 1) / 2.0) * a - (h * (steps - 2) / 3.0) * slope
    accurate = base - (dt * dt / 2.0) * a - (dt / 3.0) * slope
    return dx, (euler, accurate)


def warn_if_internal_steps(source: Any, x: np.ndarray, v: np.ndarray | None, a: np.ndarray | None,
                            u: np.ndarray, dt: float) -> None:
    """Judge the integrator of a co-simulation FMU that declares a fixed internal step ``h`` (FMI 3
    ``fixedInternalStepSize``) and was recorded at ``dt = N h``, ``N >= 2`` (one step per ``doStep``:
    :func:`warn_if_euler_steps`).  Its results cannot depend on ``dt``, so the step check skips it
    (:func:`fmu_opinf.snapshots._window.fixed_internal_step`); audit 73 F4: explicit Euler with 6 steps per
    ``doStep`` was recorded silently and the default ROM, refined toward those steps, was 1-18 % of range off the
    model, while the FMU's own derivatives gave it to 4e-14.  Explicit Euler (:func:`internal_step_rules`) is
    warned with the verdict ``"euler-substeps"``, on which ``fit`` keeps the SDP fitted to the FMU's derivatives;
    where the data cannot tell (no velocities or accelerations of the FMU's own, motion the step does not resolve,
    another low-order integrator) one line says what the recording follows and the fix (``"internal-step"``)."""
    from ..sources import offers_model_exchange
    from ._notes import current_recording_notes, warn_recording

    internal = _fixed_internal_step(source)
    said = set(current_recording_notes().get("recording_verdicts", []))
    if internal is None or said & {"forward-euler", "backward-euler", "euler-substeps"}:
        return   # (an earlier run that could not tell leaves the next one to judge)
    steps = round(dt / internal)
    if steps < 2 or abs(dt / internal - steps) > 1e-9 * steps:
        return   # one step per doStep (the forward and backward rules tell), or not on its grid (warned)
    euler, accurate = (math.nan, math.nan) if v is None or a is None else internal_step_rules(x, v, a, u, dt, steps)
    if accurate < EULER_TRAPEZOIDAL_MISS or accurate <= INTERNAL_RULE_MARGIN * euler:
        return
    if "internal-step" in said and not euler <= INTERNAL_RULE_MARGIN * accurate:
        return   # said for an earlier run
    label = f"{source_label(source)}: the co-simulation"
    where = f"{steps} steps of its fixedInternalStepSize={internal:g} per communication step dt={dt:g}"
    remedy = f"record by model exchange ({ME})" if offers_model_exchange(source) else _FIXED_INTERNAL_REMEDY
    if euler <= INTERNAL_RULE_MARGIN * accurate:
        warn_recording(f"{label} takes {where} by explicit Euler (their rule fits the position increments to "
                       f"{euler:.1e}, an accurate integration's misses by {accurate:.1e}): the recording follows "
                       "the FMU's integrator, not the model (damping off by about omega h / 2; fit keeps the SDP "
                       f"fitted to the FMU's derivatives at the recorded states); {remedy}", "euler-substeps",
                       stacklevel=4)
        return
    why = ("it gave no velocities or accelerations of its own to judge its integrator by" if v is None or a is None
           else "its positions did not move in the samples judged" if math.isnan(accurate)
           else f"the data cannot tell its integrator from an accurate one (explicit Euler's rule misses by "
                f"{euler:.1e}, an accurate integration's by {accurate:.1e})")
    fix = (remedy if offers_model_exchange(source) or a is None else
           f"fit with {either('--no-refine')} (the SDP then fits the FMU's derivatives at the recorded states, not its "
           "steps), or "
           f"{remedy.split(': ', 1)[1]}")
    warn_recording(f"{label} integrates with {where} and the recording follows them; {why}: where that "
                   f"integrator is a low-order one (Euler), {fix}", "internal-step", stacklevel=4)

