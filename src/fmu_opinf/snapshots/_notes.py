"""Warnings that a recording follows the FMU's integrator rather than the model, kept in the snapshot file.

``snapshots`` says once that a co-simulation depends on its communication step, lags by one step or takes one
explicit Euler step per communication step; ``fit``, ``compare`` and ``export`` run later, in other processes, on
the file alone.  Before, they then reported success on ROMs 28-72 % of range off the model (audit 70 F4), because
nothing of the warning was left.  :func:`warn_recording` warns as before and adds the line to the notes of the
recording in progress (:func:`collecting_recording_notes` around :func:`~fmu_opinf.snapshots.record_to_file`);
the file keeps them in its attribute ``recording_warnings`` (and what each says, a word of :data:`VERDICTS`, in
``recording_verdicts``), and :func:`recorded_warning` gives the later stages one line to repeat.  A model's own
events (a force on a timer, a switch) are kept the same way (:func:`note_recording`; audit 72 F5: they were warned
in ``snapshots`` only, and compare then reported a 22 % error with no word on why).
"""

from __future__ import annotations

import contextvars
import functools
import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from ..errors import FmuOpinfWarning

__all__ = ["VERDICTS", "WRONG_MODEL_VERDICTS", "collecting_recording_notes", "current_recording_notes",
           "note_recording", "recorded_verdicts", "recorded_warning", "warn_recording"]

#: What a recording warning says: the co-simulation takes one explicit Euler step per communication step (each
#: position moves by the step times its velocity at the step's start), one semi-implicit or implicit one (at its
#: end), depends on the step in another way, or returns its outputs one step late; or the model had events of its
#: own during the recording (which a linear ROM cannot follow; no change to the fit); or the co-simulation takes
#: several explicit Euler steps of its fixed internal step per communication step (``"euler-substeps"``), or follows
#: a fixed internal step whose integrator the data cannot tell (``"internal-step"``; no change to the fit); or the
#: response grows without bound once the inputs are held (``"unbounded-growth"``, :mod:`._growth`: a model unstable
#: at its operating point, which a stable ROM cannot represent; no change to the fit); or the model's response does
#: not scale with the default training's amplitude at any amplitude tried (``"nonlinear"``, :mod:`._linearity`; no
#: change to the fit); or the velocities miss their positions' rates though the FMU pairs them, the step too coarse for
#: the motion (``"coarse-step"``, :func:`~._consistency.judge_run`; no change to the fit: compare repeats it, since a
#: co-simulation at that step is itself off the model, audit86 F5: RK4 per doStep 10 % off, the ROM 0.8 %).
VERDICTS = ("forward-euler", "backward-euler", "step-dependent", "late-outputs", "internal-events", "euler-substeps",
            "internal-step", "unbounded-growth", "nonlinear", "coarse-step")

#: Verdicts that make any linear ROM of the recording wrong, whatever the fit makes of the FMU's steps: a response
#: that grows without bound, or one that does not scale with the amplitude.  Their warning comes first in a file's
#: ``recording_warnings``, which ``fit``, ``compare`` and ``export`` repeat.
WRONG_MODEL_VERDICTS = ("unbounded-growth", "nonlinear")

_NOTES: contextvars.ContextVar[dict[str, list[str]] | None] = contextvars.ContextVar("recording_notes",
                                                                                    default=None)
_F = TypeVar("_F", bound=Callable[..., Any])


def collecting_recording_notes(function: _F) -> _F:
    """``function`` with the recording notes of its call collected (a fresh list; an enclosing call's are kept
    apart)."""
    @functools.wraps(function)
    def collecting(*args: Any, **kwargs: Any) -> Any:
        token = _NOTES.set({"recording_warnings": [], "recording_verdicts": []})
        try:
            return function(*args, **kwargs)
        finally:
            _NOTES.reset(token)
    return collecting  # type: ignore[return-value]


def current_recording_notes() -> dict[str, list[str]]:
    """The file attributes ``recording_warnings`` and ``recording_verdicts`` of the recording in progress (empty
    outside one, or where nothing was warned)."""
    notes = _NOTES.get()
    return {key: list(value) for key, value in notes.items()} if notes and notes["recording_warnings"] else {}


def warn_recording(message: str, verdict: str, stacklevel: int = 2) -> None:
    """Warn ``message`` (a :class:`~fmu_opinf.errors.FmuOpinfWarning`) and keep it, with its ``verdict`` (one of
    :data:`VERDICTS`), for the file being recorded."""
    if verdict not in VERDICTS:
        raise ValueError(f"verdict={verdict!r} is not one of {VERDICTS}")
    warnings.warn(message, FmuOpinfWarning, stacklevel=stacklevel + 1)
    note_recording(message, verdict)


def note_recording(message: str, verdict: str) -> None:
    """Keep ``message`` with its ``verdict`` (one of :data:`VERDICTS`) for the file being recorded, without warning
    (for a warning said once per process while every recording must keep it, e.g. a model's own events)."""
    if verdict not in VERDICTS:
        raise ValueError(f"verdict={verdict!r} is not one of {VERDICTS}")
    notes = _NOTES.get()
    if notes is not None and message not in notes["recording_warnings"]:
        # a later stage repeats the first warning: one about the model itself goes before those about the FMU's steps
        first_of_its_kind = sum(1 for kept in notes["recording_verdicts"] if kept in WRONG_MODEL_VERDICTS)
        notes["recording_warnings"].insert(first_of_its_kind if verdict in WRONG_MODEL_VERDICTS
                                           else len(notes["recording_warnings"]), message)
        if verdict not in notes["recording_verdicts"]:
            notes["recording_verdicts"].append(verdict)


def texts(value: Any) -> list[str]:
    """A list attribute of text read as data: one string alone counts as a list of it, other items and values are
    none (a file's ``recording_warnings`` / ``recording_verdicts``)."""
    items = [value] if isinstance(value, str) else list(value) if isinstance(value, (list, tuple)) else []
    return [item for item in items if isinstance(item, str) and item]


def recorded_verdicts(attrs: Any) -> set[str]:
    """The verdicts of :data:`VERDICTS` that snapshot attributes ``attrs`` carry (other text is ignored)."""
    found = texts(attrs.get("recording_verdicts")) if isinstance(attrs, dict) else []
    return {verdict for verdict in found if verdict in VERDICTS}


def recorded_warning(attrs: Any) -> str | None:
    """The line a later stage repeats for snapshot attributes ``attrs`` (a file's, or a ROM's
    ``provenance["snapshots"]``) that carry recording warnings, or None.  Read as data: only text counts."""
    notes = texts(attrs.get("recording_warnings")) if isinstance(attrs, dict) else []
    if not notes:
        return None
    more = f" (and {len(notes) - 1} more warning{'s' if len(notes) > 2 else ''})" if len(notes) > 1 else ""
    return f"the training snapshots were recorded with this warning: {notes[0]}{more}"
