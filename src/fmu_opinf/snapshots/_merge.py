"""What the parts of a merged data set (a folder of snapshot files, several files, appended snapshots) were recorded
from, and where they differ.

Merging checks that the parts describe the same system (sizes, variable names, constraint kind); it cannot check
that they record the same model.  Audit 72 (F3, F4): a folder holding one FMU by model exchange and its explicit
Euler co-simulation (or two FMUs), or files recorded at two stiffness values (a run table's ``set:`` column), was
fitted as one model without a word, one part's Euler verdict applied to every run (the ROM 15-31 % of range off a
model either file fits exactly), and the provenance named the first file's FMU only.

The merged attributes keep a summary of every part (``merged_parts``: its file, FMU name and hash, interface,
settings and recording verdicts), :func:`merge_differences` names what differs for ``fit`` to warn, and the
recording verdicts of the merged set are those every part carries (:func:`part_verdicts` gives the mixed ones).
"""

from __future__ import annotations

import json
from typing import Any

from ._notes import VERDICTS, texts

__all__ = ["MERGED_PARTS", "SOURCE_KEYS", "merge_differences", "merge_warnings", "merged_parts", "merged_source",
           "mixed_interfaces", "mixed_steps", "part_summary", "part_verdicts", "repeated_merge_warning", "same_setting",
           "setting_key"]

#: The attribute that holds the parts' summaries: ``{"parts": [summary, ...]}`` (JSON object, as the other dict
#: attributes).
MERGED_PARTS = "merged_parts"

#: Summary keys copied from a part's attributes.
_KEYS = ("fmu_name", "fmu_sha256", "fmu_guid", "fmi_interface", "fmu_settings", "recording_verdicts")

_INTERFACES = {"me": "model exchange", "cs": "co-simulation"}

#: The verdicts that change how ``fit`` treats a recording
#: (:func:`fmu_opinf.fit._time_integrator._recorded_euler_step`) and what each says.
_STEP_VERDICTS = {"forward-euler": "the FMU's explicit Euler co-simulation steps",
                  "backward-euler": "the FMU's semi-implicit Euler co-simulation steps",
                  "euler-substeps": "the FMU's explicit Euler steps of its fixed internal step",
                  "step-dependent": "a co-simulation that depends on its communication step"}


def setting_key(value: Any) -> Any:
    """A setting's value in a form that compares equal where the values mean the same: numbers as floats, arrays as
    tuples of them, booleans and other text as lower-case text.

    The command line gives every ``--set`` value as text (``"2"``, ``"[1,2]"``), Python as numbers (``2.0``), and files
    recorded before 2026-12-08 kept the text: a merge of two such files, or ``compare`` against one, must see
    ``k1=2`` and ``k1=2.0`` as one setting (before, the merge warned "different settings" and dropped it, and the
    merged ROM was compared against the FMU at its start value).
    """
    if isinstance(value, str):
        text = value.strip()
        try:
            value = json.loads(text) if text[:1] in "[-.0123456789" else text
        except ValueError:
            return text.lower()
    if isinstance(value, (list, tuple)):
        return tuple(setting_key(item) for item in value)
    if isinstance(value, bool) or value is None:
        return str(value).lower()
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value).strip().lower()


def same_setting(value: Any, other: Any) -> bool:
    """Whether two values of one setting mean the same (:func:`setting_key`)."""
    return setting_key(value) == setting_key(other)


def part_summary(attrs: dict[str, Any], name: str) -> dict[str, Any]:
    """What a part with file attributes ``attrs``, called ``name`` (its file name), was recorded from."""
    summary: dict[str, Any] = {"file": name}
    for key in _KEYS:
        value = attrs.get(key)
        if key == "recording_verdicts":
            value = [verdict for verdict in texts(value) if verdict in VERDICTS]
        elif key == "fmu_settings":
            value = dict(value) if isinstance(value, dict) else {}
        elif not isinstance(value, str):
            continue
        summary[key] = value
    return summary


def merged_parts(attrs: dict[str, Any], name: str) -> list[dict[str, Any]]:
    """The part summaries of attributes ``attrs``: those stored by an earlier merge, else ``attrs`` as one part
    called ``name``."""
    stored = attrs.get(MERGED_PARTS)
    parts = stored.get("parts") if isinstance(stored, dict) else None
    if isinstance(parts, list) and parts and all(isinstance(part, dict) for part in parts):
        return [dict(part) for part in parts]
    return [part_summary(attrs, name)]


def part_verdicts(attrs: dict[str, Any]) -> tuple[set[str], dict[str, list[str]]]:
    """The recording verdicts every part of ``attrs`` carries, and those only some carry (each with its parts' file
    names); for a single recording, its verdicts and none mixed."""
    parts = merged_parts(attrs, "")
    sets = [set(texts(part.get("recording_verdicts"))) for part in parts]
    every = set.intersection(*sets) if sets else set()
    mixed = {verdict: [str(part.get("file")) for part, found in zip(parts, sets) if verdict in found]
             for verdict in sorted(set.union(*sets) - every)} if sets else {}
    return every, mixed


def merge_differences(attrs: dict[str, Any]) -> str | None:
    """One sentence naming where the parts of merged snapshot attributes ``attrs`` differ (the FMU, its interface,
    its settings with their values), or None when they agree or ``attrs`` are one recording's."""
    parts = merged_parts(attrs, "")
    if len(parts) < 2:
        return None
    settings = _differing_settings(parts, attrs)
    said = [text for text in (_differing(parts, "fmu_sha256", _fmu), _differing(parts, "fmi_interface", _interface),
                              settings) if text]
    if not said:
        return None
    files = _listing([str(part.get("file")) for part in parts])
    advice = (f"one linear ROM cannot follow {'both' if len(parts) == 2 else 'all of them'}; fit one ROM per setting"
              if settings else
              "the ROM is one model fitted to all of them; fit one ROM per FMU and interface")
    return f"the merged snapshot files ({files}) were recorded {'; '.join(said)}: {advice}"


def _differing(parts: list[dict[str, Any]], key: str, label: Any) -> str | None:
    """``key``'s values of ``parts`` said by ``label`` where they are not all the same (absent values count as
    unknown, not as different)."""
    values = [part.get(key) for part in parts]
    if len({value for value in values if value is not None}) < 2:
        return None
    return label(_listing([f"{part.get('file')} {_said(key, part)}" for part in parts]))


def _said(key: str, part: dict[str, Any]) -> str:
    """A part's value of ``key`` in words."""
    if key == "fmu_sha256":
        digest = part.get("fmu_sha256")
        return f"{part.get('fmu_name', '?')} (sha256 {str(digest)[:12] if digest else 'unknown'})"
    return _INTERFACES.get(str(part.get(key)), str(part.get(key, "unknown")))


def _fmu(text: str) -> str:
    return f"from different FMUs ({text})"


def _interface(text: str) -> str:
    return f"by different FMI interfaces ({text})"


def _differing_settings(parts: list[dict[str, Any]], attrs: dict[str, Any]) -> str | None:
    """The settings (``--set``, a run table's ``set:`` cells) whose values differ between ``parts``, each with every
    part's value ("default" where a part did not set it).

    A start value of an initial state (:func:`fmu_opinf._model_start.sets_initial_state`: a recorded position or
    velocity, or its ``<state>_start`` parameter, which a run table's ``start:`` cells name) is an
    initial condition, not a setting: runs that differ only in them are one training set of one model
    (``docs/scale-out.md``), and the warning called them settings and said "fit one ROM per setting" (audit 73 F2).
    """
    from .._model_start import sets_initial_state

    settings = [part.get("fmu_settings") if isinstance(part.get("fmu_settings"), dict) else {} for part in parts]
    names = sorted({name for setting in settings for name in setting if not sets_initial_state(name, attrs)})
    differing = [name for name in names if len({repr(setting_key(setting.get(name))) for setting in settings}) > 1]
    if not differing:
        return None
    said = "; ".join(f"{name}: " + _listing([f"{part.get('file')} {setting.get(name, 'default')}"
                                              for part, setting in zip(parts, settings)]) for name in differing[:3])
    said += f"; and {len(differing) - 3} more" if len(differing) > 3 else ""
    return f"with different settings ({said})"


def mixed_steps(attrs: dict[str, Any]) -> str | None:
    """Where some parts of merged attributes ``attrs`` follow the FMU's integrator (a verdict of
    :data:`_STEP_VERDICTS`) and others do not: one sentence saying so and what the fit does instead, else None.

    The Euler treatment is for runs that all follow those steps: applied to every run it stepped the accurate runs
    by Euler too (audit 72 F3: the ROM 15-31 % of range off the model), and the output-error refinement with the
    ROM's own step pulls toward the Euler runs (0.61 relative error on the free response).  The SDP of eq. (16)
    alone fits the FMU's derivatives at the recorded states, which both kinds of recording give (that set: the
    model to 2e-13 .. 4e-13 of range, tests/test_merged_recordings.py)."""
    _, mixed = part_verdicts(attrs)
    found = [(verdict, files) for verdict, files in mixed.items() if verdict in _STEP_VERDICTS]
    if not found:
        return None
    said = "; ".join(f"{_listing(files)} follow{'s' if len(files) == 1 else ''} {_STEP_VERDICTS[verdict]}"
                     for verdict, files in found)
    return (f"of the merged snapshot files, {said} (snapshots warned), the others do not: the Euler treatment "
            "would step the accurate runs by Euler too, and the output-error refinement would pull toward the Euler "
            "runs, so the fit keeps the SDP solution of eq. (16), fitted to the FMU's derivatives at the recorded "
            "states (fit_rom(refine=True) refines anyway); where the accelerations were derived from the "
            "samples they follow the Euler steps: then fit the two kinds apart")


#: The top-level attributes that name one recording's FMU; a set merged from different FMUs drops them, as its
#: ``fmu_name`` and ``source`` say how many FMUs it holds (:func:`merged_source`).
SOURCE_KEYS = ("fmu_guid", "fmu_sha256")


def merged_source(parts: list[dict[str, Any]]) -> str | None:
    """What a set merged from ``parts`` names as its FMU where the parts come from different FMUs, e.g.
    ``"2 FMUs merged (c4.fmu, ode1.fmu)"`` (each part keeps its own in ``merged_parts``); None where every part
    names the same FMU (or none).

    The merge took the first part's attributes as the set's: its FMU name, hash and GUID stood for every part, so
    the ROM's provenance, ``compare``'s words and the exported FMU's description named one FMU of several (audit 72
    F3).  FMUs are told apart by their hash where every part records one, else by their file name."""
    key = "fmu_sha256" if all(part.get("fmu_sha256") for part in parts) else "fmu_name"
    distinct = {str(part[key]) for part in parts if part.get(key)}
    if len(distinct) < 2:
        return None
    names = list(dict.fromkeys(str(part.get("fmu_name") or "unnamed FMU") for part in parts))
    return f"{len(distinct)} FMUs merged ({_listing(names)})"


def mixed_interfaces(parts: list[dict[str, Any]]) -> bool:
    """Whether ``parts`` were recorded by different FMI interfaces (model exchange and co-simulation): the set then
    names none (it named the first part's)."""
    return len({part["fmi_interface"] for part in parts if part.get("fmi_interface")}) > 1


def repeated_merge_warning(snapshots: Any) -> str | None:
    """The warning ``fit`` gave where the merged snapshot files of a ROM differ (:func:`merge_differences`), from
    the ROM's snapshot provenance ``snapshots`` (a ROM file's, or an exported ROM FMU's provenance.json), for
    ``compare`` and ``export`` to repeat; None for one recording, parts that agree, or no provenance."""
    text = merge_differences(snapshots) if isinstance(snapshots, dict) else None
    return f"as fit warned, {text}" if text else None


def merge_warnings(attrs: dict[str, Any]) -> list[str]:
    """What ``fit`` says about merged snapshot attributes ``attrs``: the parts' differences
    (:func:`merge_differences`) and mixed integrator verdicts (:func:`mixed_steps`)."""
    return [text for text in (merge_differences(attrs), mixed_steps(attrs)) if text]


#: Items a warning lists at most (a run table of a thousand rows made a warning of 24 kB).
_LISTED = 4


def _listing(items: list[str]) -> str:
    """``items`` joined by commas, the first :data:`_LISTED` of many and their count."""
    if len(items) <= _LISTED + 1:
        return ", ".join(items)
    return ", ".join(items[:_LISTED]) + f", ... ({len(items)} in all)"
