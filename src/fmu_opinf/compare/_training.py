"""What the ROM's training provenance tells a comparison: the source driven as trained, what the fit found (order,
linear fits, training miss), and the warnings where the comparison leaves what the ROM was trained on."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import either, values_said
from ..errors import FmuOpinfError
from ..snapshots._merge import same_setting
from ._declared import _declared_starts, _is_rom_fmu
from ._sides import _exact_names


#: How many times the training's amplitude on an input a given test input must depart from the training's operating
#: point before compare says so: a ROM fitted on a 100 N pulse was 35-90 % of range off at 1e4 N, and the order
#: advice alone (fit --r 8) still 2-4 % off, where training at 1e4 N gave 0.1 % (audit 74, F1).
INPUT_SIZE_NOTE = 10.0


def input_beyond_training(signal: Any, t: np.ndarray, rom_info: dict[str, Any]) -> dict[str, Any]:
    """The input on which the test input ``signal`` (sampled on ``t``) departs furthest, relative to the training's
    amplitude on it, from the training's operating point there (``training_runs`` of the ROM's provenance: the
    largest amplitude an input was driven with and that run's offset), where that is over :data:`INPUT_SIZE_NOTE`
    times: ``{"input", "ratio", "given", "trained"}``; empty where it is within, or the training is not readable.

    A linear ROM's error grows with the input where its basis misses modes the small training input hardly
    excited against the model's own motion; the cure is training at the loads meant, not a larger order."""
    from .._test_input import _training_drives

    m, names = int(rom_info["m"]), list(rom_info.get("input_names") or [])
    try:
        drives = _training_drives(rom_info["provenance"].get("training_runs"), m, names or None)
        u = np.atleast_2d(signal.sample(t))
    except (FmuOpinfError, AttributeError, TypeError, ValueError):
        return {}
    worst: dict[str, Any] = {}
    for i, drive in enumerate(drives):
        if drive is None or not drive[0] > 0 or i >= u.shape[0]:
            continue
        given = float(np.abs(u[i] - drive[1]).max())
        ratio = given / drive[0]
        if ratio > INPUT_SIZE_NOTE and ratio > worst.get("ratio", 0.0):
            name = names[i] if i < len(names) else f"input {i + 1}"
            worst = {"input": name, "ratio": ratio, "given": given, "trained": float(drive[0])}
    return worst


def _warn_beyond_training(beyond: dict[str, Any], source: Any) -> None:
    """The one line of :func:`input_beyond_training`'s finding."""
    import warnings

    from ..errors import FmuOpinfWarning

    warnings.warn(f"the test input departs by {beyond['given']:.3g} on {beyond['input']}, {beyond['ratio']:.3g} "
                  f"times the training's amplitude there ({beyond['trained']:.3g}): the ROM of "
                  f"{Path(str(source)).name} learned only the responses to inputs that size; train with an input "
                  f"nearer this one (snapshots {either('--input')} at these loads) before trusting or enlarging it",
                  FmuOpinfWarning, stacklevel=3)


def _linear_fits(rom_side: Any) -> list[str]:
    """The outputs a ROM object's fit left out of its judgement as not linear in the states (their names, from
    ``fit_info["nonlinear_outputs"]``); empty for a fit that left none out, an older one or an exported FMU."""
    found = (getattr(rom_side, "fit_info", None) or {}).get("nonlinear_outputs")
    if not isinstance(found, dict) or not found.get("left_out"):
        return []
    return [str(name) for name in found.get("names") or []]


def _carried_linear_fits(rom_info: dict[str, Any]) -> list[str]:
    """:func:`_linear_fits` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_linear_fits``).  A data file: only names of the FMU's own outputs are taken."""
    carried = rom_info["provenance"].get("rom_fmu_linear_fits")
    outputs = set(rom_info.get("output_names") or [])
    if not isinstance(carried, list):
        return []
    return [name for name in carried if isinstance(name, str) and name in outputs][:1000]


def _training_miss_of(rom_side: Any) -> dict[str, Any] | None:
    """What fit warned about a ROM object's miss of its own training outputs (from its ``fit_info``: :func:`fmu_opinf.
    fit._training_checks.training_miss_record`), None where it did not warn or the ROM does not say."""
    from ..fit._training_checks import training_miss_record

    info = getattr(rom_side, "fit_info", None)
    settings = (getattr(rom_side, "provenance", None) or {}).get("fit_settings")
    unrefined = isinstance(settings, dict) and settings.get("refine") is False
    return training_miss_record(info, list(getattr(rom_side, "output_names", None) or ()), unrefined)


def _carried_training_miss(provenance: dict[str, Any]) -> dict[str, Any]:
    """:func:`_training_miss_of` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_training_miss``).  A data file: the figures only as finite shares, the names only as short
    printable strings; else nothing."""
    carried = provenance.get("rom_fmu_training_miss")
    if not isinstance(carried, dict):
        return {}
    found: dict[str, Any] = {}
    for key in ("rms", "peak"):
        value = carried.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value < 1e12:
            found[key] = float(value)
    for key in ("output", "run", "peak_output", "peak_run"):
        value = carried.get(key)
        if isinstance(value, str) and len(value) <= 200 and value.isprintable():
            found[key] = value
    return found if "rms" in found or "peak" in found else {}


def _training_miss(rom_side: Any, rom_info: dict[str, Any]) -> dict[str, Any]:
    """The fit's warned training miss of either kind of ROM side (empty where none)."""
    if isinstance(rom_side, Path):
        return _carried_training_miss(rom_info["provenance"])
    return _training_miss_of(rom_side) or {}


def _warn_if_training_missed(rom_side: Any, rom_info: dict[str, Any]) -> None:
    """fit's warning that the ROM misses its own training outputs, again (as export repeats the start miss): a
    comparison on another input must not make such a ROM look validated (audit 79a F1)."""
    import warnings

    from ..errors import FmuOpinfWarning
    from ..fit._training_checks import training_miss_text

    record = _training_miss(rom_side, rom_info)
    if record:
        warnings.warn(f"fit warned that this ROM misses its own training outputs by {training_miss_text(record)}: "
                      "an input like the training one is that far off, whatever the test below shows; see fit's "
                      f"warning for the causes (a larger {either('--r')} first where its order search kept lowering "
                      "the miss)"
                      + _replay_hint(record, rom_info), FmuOpinfWarning, stacklevel=3)


def _replay_hint(record: dict[str, Any], rom_info: dict[str, Any]) -> str:
    """How to compare on the training run the miss was found in (its input spec, as fit names the run: "run 0
    (SPEC)", and the training's end), "" where the run's spec or the end is not known.  Not run by default: fit's
    figure is that comparison's already (audit 79a F1: 0.25 of y74's range in both), and the run costs one more
    FMU run over the training window (17.8 s there, against 57.5 s for compare's default test)."""
    import re

    name, end = record.get("peak_run") or record.get("run") or "", rom_info.get("t_train_end")
    found = re.fullmatch(r"run \d+ \(([^()'\\]+)\)", str(name))
    if not found or not isinstance(end, (int, float)) or not math.isfinite(end) or end <= 0:
        return ""
    replay = values_said(("--input", found.group(1)), ("--t-end", float(f"{end:g}")))
    return f"; compare {replay} replays that training run"


def _order_chosen(rom_side: Any) -> dict[str, Any]:
    """How a ROM object's order was chosen (for :func:`~fmu_opinf.compare._metrics.order_note`): ``r``; ``"given"``,
    ``"energy"`` where the fit took it from the POD energy (eq. 18) and judged it good enough, or ``"search"`` where
    its order search ran (and grew it, or kept the energy's after trying larger ones); the snapshot rank that bounds
    it; the orders the search tried (``fit_info["order_search"]``), and ``noise_floor`` where it stopped at one of the
    singular values (:func:`fmu_opinf.fit._order_search._noise_floor`).  Empty for a ROM that does not say (an
    exported FMU carries it: :func:`_carried_order`)."""
    info = getattr(rom_side, "fit_info", None) or {}
    settings = (getattr(rom_side, "provenance", None) or {}).get("fit_settings")
    rank = info.get("snapshot_rank")
    if not isinstance(settings, dict) or "r" not in settings or not isinstance(rank, (int, np.integer)):
        return {}
    search = info.get("order_search") or []
    how = "given" if settings["r"] is not None else "search" if search else "energy"
    chosen = {"r": int(rom_side.r), "chosen": how, "snapshot_rank": int(rank),
              "tried": [int(entry["r"]) for entry in search if "r" in entry]}
    floor = next((entry["noise_floor"] for entry in search if isinstance(entry.get("noise_floor"), int)), None)
    if floor is not None:
        chosen["noise_floor"] = floor
    return chosen


def _carried_order(provenance: dict[str, Any]) -> dict[str, Any]:
    """:func:`_order_chosen` of the ROM an exported FMU was made from, as its provenance.json carries it
    (``rom_fmu_order``, since 2026-12-06; audit 69 F6: compare on a ROM FMU gave no order note).  A data file:
    taken only if every field has the form :func:`_order_chosen` gives it, else nothing."""
    carried = provenance.get("rom_fmu_order")
    if not isinstance(carried, dict) or carried.get("chosen") not in ("given", "energy", "search"):
        return {}

    def count(value: Any) -> bool:
        return isinstance(value, int) and not isinstance(value, bool) and 0 < value < 1_000_000

    tried = carried.get("tried")
    if not (count(carried.get("r")) and count(carried.get("snapshot_rank")) and isinstance(tried, list)
            and all(count(value) for value in tried) and len(tried) <= 64):
        return {}
    chosen = {"r": carried["r"], "chosen": carried["chosen"], "snapshot_rank": carried["snapshot_rank"],
              "tried": list(tried)}
    if count(carried.get("noise_floor")):
        chosen["noise_floor"] = carried["noise_floor"]
    return chosen


#: How far past its largest departure in the training an output must go under compare's own test input before that
#: is said: a test at the training size adds a hair to a large free swing (a 100 N harmonic on a 96 m gravity swing:
#: ratio 1.0004, printed "1 times", with the ROM at 1.0 warned "may miss a mode" while 0.5 % of range off; audit 74,
#: F1).  5 % past is a departure the training did not show.
PAST_TRAINING_MARGIN = 1.05


def _past_training(y: np.ndarray, y_rom: np.ndarray, names: list[str], rom_info: dict[str, Any],
                   source: Any) -> str:
    """Where the test input ``compare`` chose drove the source's outputs past their training peak: a warning, and
    the same words for the report ("" where they stayed within).  The input was sized by the ROM: where the ROM
    went past as well, the input's offsets did it; where it did not, the ROM misses a mode of the model there
    (audit 52: an r = 1 ROM beside a lightly damped mode it did not learn, 4.3 times).  Only past
    :data:`PAST_TRAINING_MARGIN` times the training's departure."""
    from .._test_input import recorded_peaks

    peaks = recorded_peaks(rom_info["provenance"], y.shape[0])
    if peaks is None:
        return ""
    scale = np.where(peaks > 0, peaks, np.inf)
    ratios = np.abs(y - y[:, :1]).max(axis=1) / scale
    worst = int(np.argmax(ratios))
    if not ratios[worst] > PAST_TRAINING_MARGIN:
        return ""
    rom_ratio = float(np.abs(y_rom[worst] - y_rom[worst, 0]).max() / scale[worst])
    cause = (f"the input's offsets take it there in the ROM too: a shorter {either('--t-end')} keeps them nearer"
             if rom_ratio > 1.0 else _growth_cause() if _grew(rom_info)
             else f"the ROM stays within it: it may miss a mode of the model there; pass {either('--input')} with a "
                  "smaller amplitude or another frequency")
    text = (f"{Path(str(source)).name}'s {names[worst]} went to {ratios[worst]:.3g} times its largest departure in the "
            f"training; {cause}")
    import warnings

    from ..errors import FmuOpinfWarning

    warnings.warn(f"under the test input compare chose, {text}", FmuOpinfWarning, stacklevel=3)
    return f"; {text}"


def _grew(rom_info: dict[str, Any]) -> bool:
    """Whether ``snapshots`` found the ROM's training source growing without bound (verdict ``unbounded-growth``)."""
    from ..snapshots._notes import recorded_verdicts

    return "unbounded-growth" in recorded_verdicts(rom_info["provenance"].get("snapshots"))


def _growth_cause() -> str:
    """Why the source left its training range where its recording grew without bound (audit 79b F4: compare advised
    a smaller test amplitude for a source 4.9e36 times past it, which no amplitude would have kept in range)."""
    return ("the source grows without bound once its inputs are held (snapshots warned: it is unstable at its "
            "operating point), and no stable ROM follows it, whatever the test input")


#: Recording verdicts about the model itself, not about how the FMU integrated it: a comparison with the same FMU
#: does not share them (its own events; a response that grows without bound, audit 79b F4; a response that does not
#: scale with the training's amplitude, audit 79b F1).
MODEL_VERDICTS = frozenset({"internal-events", "unbounded-growth", "nonlinear"})


def _warn_if_recording_warned(rom_info: dict[str, Any], interface: str | None) -> None:
    """The warning ``snapshots`` gave on the ROM's training recording, again (audit 70 F4: a recording that
    followed the FMU's integrator, compared against the same FMU at the same step: 7.6e-7 and no word, the ROM
    28-72 % of range off the model).  Where the fit made the ROM stand for the model, the FMU's own integration
    error is part of the difference only when this comparison drives the FMU by co-simulation (``interface``
    ``"cs"``; audit 72 F3: said of an FMU driven by model exchange, where the error was the ROM's)."""
    import warnings

    from ..errors import FmuOpinfWarning
    from ..snapshots._notes import recorded_verdicts, recorded_warning

    message = recorded_warning(rom_info["provenance"].get("snapshots"))
    if not message:
        return
    settings = rom_info["provenance"].get("fit_settings")
    modelled = isinstance(settings, dict) and (settings.get("recording_integrator") in (
        "forward-euler", "backward-euler", "euler-substeps", "step-dependent")
        or settings.get("mixed_recordings") is True)
    if modelled and interface == "cs":
        message += ("; the ROM stands for the model (fitted through the FMU's Euler steps or from its derivatives), "
                    "so the difference to this FMU's co-simulation includes the FMU's own integration error")
    elif modelled:
        message += ("; the ROM stands for the model (fitted through the FMU's Euler steps or from its derivatives), "
                    "and this comparison ran no co-simulation: the difference is the ROM's")
    elif "coarse-step" in (verdicts := recorded_verdicts(rom_info["provenance"].get("snapshots"))):
        message += _coarse_step_note(interface)
    elif not verdicts or verdicts - MODEL_VERDICTS:
        message += "; a comparison with the same FMU shares what the recording followed"
    warnings.warn(message, FmuOpinfWarning, stacklevel=4)


def _coarse_step_note(interface: str | None) -> str:
    """What the recording's "step too coarse" verdict means for this comparison: driven by co-simulation at such a
    step, the FMU itself is off the model, and the figure can be its error more than the ROM's (audit86 F5: RK4 per
    doStep at dt=0.005, the FMU 9.9 % of range off the exact model, the ROM 0.8 %; compare read 9.4 % and said
    nothing); by model exchange, fmu-opinf integrates and the FMU side is accurate."""
    if interface == "cs":
        return ("; this comparison drives the FMU's co-simulation, which at such a step is itself off the model: its "
                f"figure can be the FMU's integration error more than the ROM's; compare at a smaller "
                f"{either('--dt')} (and record the training there) to tell them apart")
    return "; the ROM was fitted from samples at that step, and this comparison ran no co-simulation"


def _warn_if_merged(rom_info: dict[str, Any]) -> None:
    """The warning ``fit`` gave where the ROM's merged snapshot files differ (FMU, interface, settings), again, from
    the ROM's provenance: a ROM of several models compared against one of them measures that blend (audit 72 F3,
    F4: ``fit`` warned, ``compare`` said nothing)."""
    import warnings

    from ..errors import FmuOpinfWarning
    from ..snapshots._merge import repeated_merge_warning

    message = repeated_merge_warning(rom_info["provenance"].get("snapshots"))
    if message:
        warnings.warn(message, FmuOpinfWarning, stacklevel=4)


def _compared_interface(source: Any, options: dict[str, Any]) -> str | None:
    """The FMI interface this comparison drives ``source`` by (``"me"``, ``"cs"``), None for a builtin source or a
    ROM file (no FMU integrator) or where the FMU's description cannot be read (the run then says why)."""
    text = str(source)
    if text.startswith("builtin:") or Path(text).suffix.lower() in (".h5", ".hdf5"):
        return None
    from ..errors import FmuOpinfError
    from ..sources import choose_interface

    try:
        return choose_interface(text, options.get("interface") or "auto")
    except (FmuOpinfError, OSError, ValueError):
        return None


def _warn_if_another_fmu(rom_info: dict[str, Any], source: Any) -> None:
    """One warning when the source FMU is not the one the ROM was learned from (its GUID differs from the one the
    training recorded): with the same variable names the comparison runs and measures another model (third
    audit, 2026-11-26: max eps_y 0.99 and no word)."""
    snapshots = rom_info["provenance"].get("snapshots")
    trained = _trained_guids(snapshots)
    path = Path(str(source))
    if not trained or str(source).startswith("builtin:") or path.suffix.lower() in (".h5", ".hdf5"):
        return
    try:
        from ..sources._variables import read_description

        md = read_description(path)
    except Exception:  # noqa: BLE001 - the run itself reports an unreadable FMU
        return
    # a ROM exported from that FMU's training names its GUID in the description
    exported = any(f"(GUID {guid})" in (md.description or "") for guid in trained)
    if md.guid and md.guid not in trained and not exported:
        import warnings

        from ..errors import FmuOpinfWarning

        learned = ", ".join(f"{name}, GUID {guid}" for guid, name in trained.items())
        warnings.warn(f"{path.name} is not the FMU the ROM was learned from ({learned}; this one has {md.guid}): the "
                      "comparison measures another model", FmuOpinfWarning, stacklevel=3)


def _trained_guids(snapshots: Any) -> dict[str, str]:
    """The GUIDs of the FMUs the training recorded, each with its FMU's name: the recording's, or each merged part's
    (a set merged from different FMUs names no GUID of its own; audit 72 F3)."""
    if not isinstance(snapshots, dict):
        return {}
    from ..snapshots._merge import merged_parts

    parts = [snapshots] if snapshots.get("fmu_guid") else merged_parts(snapshots, "")
    return {str(part["fmu_guid"]): str(part.get("fmu_name") or "FMU") for part in parts if part.get("fmu_guid")}


def _training_settings(rom_info: dict[str, Any], source: Any, given: dict[str, Any] | None) -> dict[str, Any]:
    """Source options for an FMU source: the user's, completed from the ROM's training provenance.  A value given
    for an initial state (:func:`fmu_opinf._model_start.sets_initial_state`) is no model change: not warned about
    (audit 73 F2: ``compare --runs`` with a table's ``start:`` rows said a ROM describes the model it was trained on).
    """
    from .._model_start import sets_initial_state

    options = dict(given or {})
    snapshots = rom_info["provenance"].get("snapshots")
    if str(source).startswith("builtin:") or not isinstance(snapshots, dict) or snapshots.get("source_kind") != "fmu":
        return options
    for key, names in (("inputs", snapshots.get("input_names")), ("outputs", snapshots.get("output_names"))):
        pattern = _exact_names(names)
        if key not in options and pattern:
            options[key] = pattern
    if options.get("start_time") is None and not _is_rom_fmu(source):   # the FMU time the training started at
        options["start_time"] = float(snapshots.get("start_time") or 0.0)
    settings = snapshots.get("fmu_settings")
    settings = dict(settings) if isinstance(settings, dict) else {}
    given_settings = options.get("parameters")
    if not isinstance(given_settings, dict):
        if settings:
            options.setdefault("parameters", dict(settings))
        return options
    # what the training ran with: its --set values, else the FMU's start values (tenth audit: --set gear=2 against
    # a ROM recorded at the start value gear=1 was 0.44 off without a word)
    starts = _declared_starts(source) if any(name not in settings for name in given_settings) else {}
    trained = {name: (settings[name], "") if name in settings else (starts[name], " (its start value)")
               for name in given_settings if name in settings or name in starts}
    ports = set(snapshots.get("input_names") or [])   # (a ROM input's value is the test input's, not a setting)
    changed = {name: value for name, value in given_settings.items()
               if name in trained and name not in ports and not same_setting(value, trained[name][0])
               and not sets_initial_state(name, snapshots)}
    if changed:
        import warnings

        from ..errors import FmuOpinfWarning

        warnings.warn("compared with " + ", ".join(f"{name}={value}" for name, value in changed.items())
                      + ", but the ROM was trained with "
                      + ", ".join(f"{name}={trained[name][0]}{trained[name][1]}" for name in changed)
                      + ": a ROM describes the model it was trained on", FmuOpinfWarning, stacklevel=3)
    options["parameters"] = {**settings, **given_settings}  # the training's other settings stay as trained
    return options


def _trained_input_names(rom_info: dict[str, Any]) -> list[str] | None:
    """The names of the FMU inputs the ROM was trained on, in the ROM's input order, as the snapshots recorded
    them (None where none were recorded: a ROM built in Python with placeholder names ``u[1]``, ...)."""
    snapshots = rom_info["provenance"].get("snapshots")
    names = snapshots.get("input_names") if isinstance(snapshots, dict) else None
    if isinstance(names, list) and len(names) == rom_info["m"] > 0 and all(isinstance(n, str) for n in names):
        side = list(rom_info.get("input_names") or [])   # an exported FMU's: in the source's order (audit 69 F4)
        return side if sorted(side) == sorted(names) else list(names)
    return None
