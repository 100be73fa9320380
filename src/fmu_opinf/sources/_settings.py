"""Values given by the user (``--set NAME=VALUE``): parameters, start values, held inputs, structural parameters.

A setting names a variable (``k``, ``mass.s``), a whole FMI 3 array (``x0=[1,2,3]``) or one element
of it (``x0[2]=1.5``).  Values are typed by the variable's declared type (real, integer, boolean,
string) and checked against its ``min``/``max``; structural parameters (FMI 3) are applied in
configuration mode, everything else before initialization.  Every problem is a one-line error.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import re
from collections.abc import Iterable, Mapping
from typing import Any

from .._validate import setting_said
from ..errors import InputSpecError
from ._variables import ModelInfo, Variable

__all__ = ["Setting", "parse_assignments", "resolve_settings", "typed_assignments"]

_INTEGER_TYPES = ("Integer", "Enumeration", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64",
                  "UInt64")
_FLOAT_TYPES = ("Real", "Float32", "Float64")
_ELEMENT = re.compile(r"^(.+)\[(\d+(?:\s*,\s*\d+)*)\]$")


@dataclasses.dataclass
class Setting:
    """The values to set for one variable (all its elements for an array)."""

    var: Variable
    values: list[Any]
    structural: bool


#: One part of a variable name: an identifier (any script: ``Masse_ü``) or a Modelica quoted identifier
#: (``'mass 1'``), with any ``(...)`` and ``[...]`` after it (``der(x)``, ``sensor[1,1]``).
_NAME_PART = r"(?:[^\W\d]\w*|'(?:[^'\\]|\\.)+')(?:\([^)]*\))?(?:\[[^\]]*\])*"
#: A whole variable name followed by ``=``, at the start of an assignment: dots join the parts.
_NAME_THEN_EQUALS = re.compile(rf"\s*({_NAME_PART}(?:\.{_NAME_PART})*)\s*=")


def parse_assignments(items: Iterable[str] | Mapping[str, Any] | None) -> dict[str, Any]:
    """``["k=4", "x0=[1,2]"]`` or ``["k=4,c=0.1"]`` (command line) or a mapping, as an ordered ``{name: value}``.

    A comma starts another assignment where a variable name and ``=`` follow it (``--set a=1,'mass 1'.s=2``);
    commas inside array values (``x0=[1,2,3]``, ``x0=1,2,3``), indices (``sensor[1,1]=3``) and Modelica quoted
    names (``'a,b=c'.s=2``) do not.
    """
    if items is None:
        return {}
    if isinstance(items, Mapping):
        return dict(items)
    out: dict[str, Any] = {}
    for item in (piece for given in items for piece in _split_assignments(str(given))):
        named = _NAME_THEN_EQUALS.match(item)
        if named:
            name, value = named.group(1), item[named.end():]
        else:
            name, sep, value = item.partition("=")
            if not sep or not name.strip():
                raise InputSpecError(f"--set {item!r} is not NAME=VALUE; write e.g. --set k=1000 or --set x0=[1,2,3]")
        out[name.strip()] = value.strip()
    return out


def _split_assignments(text: str) -> list[str]:
    """``text`` cut at the commas that start another ``NAME=`` (none inside a quoted name or brackets)."""
    pieces, start, depth, quoted, escaped = [], 0, 0, False, False
    for index, char in enumerate(text):
        if quoted:
            escaped, quoted = (not escaped and char == "\\"), quoted and (escaped or char != "'")
        elif char == "'":
            quoted = True
        elif char in "[(":
            depth += 1
        elif char in "])":
            depth = max(depth - 1, 0)
        elif char == "," and depth == 0 and _NAME_THEN_EQUALS.match(text, index + 1):
            pieces.append(text[start:index])
            start = index + 1
    return pieces + [text[start:]]


def resolve_settings(model: ModelInfo, settings: Mapping[str, Any]) -> tuple[list[Setting], dict[str, int]]:
    """Check and type the settings against the model description.

    Returns
    -------
    settings : list of Setting
        One per variable, structural parameters first.
    structural : dict of str to int
        Values of the structural parameters that were set (array sizes depend on them).
    """
    targets = [(name, value, *_target(model, name)) for name, value in settings.items()]
    structural: dict[str, int] = {}
    merged: dict[str, Setting] = {}
    order = sorted(targets, key=lambda item: item[2].causality != "structuralParameter")
    for name, value, var, index in order:
        _check_settable(model, name, var)
        shape = model.shape(var, structural)
        setting = merged.get(var.name) or Setting(var, _start_values(model, var, shape),
                                                  var.causality == "structuralParameter")
        if index is None:
            setting.values = _whole(model, name, var, value, shape)
        else:
            setting.values[_flat_index(model, name, index, shape)] = _typed(model, name, var, value)
        merged[var.name] = setting
        if setting.structural and not shape:
            structural[var.name] = int(setting.values[0])
    return list(merged.values()), structural


def typed_assignments(model: ModelInfo, settings: Mapping[str, Any], structural: Mapping[str, int]) -> dict[str, Any]:
    """``settings`` as given (``k``, ``x0``, ``x0[2]``), each value typed by its variable (a number for ``--set
    k=2``'s ``"2"``, a list for a whole array): what the provenance records, alike from the command line and Python.

    ``settings`` must have passed :func:`resolve_settings` (which raises the one-line errors); ``structural`` is
    its second result (array sizes).
    """
    typed: dict[str, Any] = {}
    for name, value in settings.items():
        var, index = _target(model, name)
        if index is not None:
            typed[name] = _typed(model, name, var, value)
            continue
        shape = model.shape(var, structural)
        values = _whole(model, name, var, value, shape)
        typed[name] = values if shape else values[0]
    return typed


def _target(model: ModelInfo, name: str) -> tuple[Variable, tuple[int, ...] | None]:
    if name in model.by_name:
        return model.by_name[name], None
    match = _ELEMENT.match(name)
    if match and match[1] in model.by_name and model.by_name[match[1]].dims:
        return model.by_name[match[1]], tuple(int(i) for i in match[2].split(","))
    close = difflib.get_close_matches(name, list(model.by_name), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise InputSpecError(f"{setting_said(name)}: {model.label} has no variable {name!r}{hint}; check the name")


def _check_settable(model: ModelInfo, name: str, var: Variable) -> None:
    if var.variability == "constant":
        raise InputSpecError(f"{setting_said(name)}: {var.name} is a constant of {model.label} and cannot be set")
    if var.causality in ("calculatedParameter", "independent"):
        raise InputSpecError(f"{setting_said(name)}: {var.name} is {_article(var.causality)} {var.causality} of "
                             f"{model.label} and cannot be set")
    if var.causality in ("parameter", "structuralParameter", "input"):
        return
    if var.initial == "calculated" or (var.initial is None and var.start is None):
        raise InputSpecError(f"{setting_said(name)}: {var.name} has no start value in {model.label} (it is calculated) "
                             "and cannot be set")


def _start_values(model: ModelInfo, var: Variable, shape: tuple[int, ...]) -> list[Any]:
    size = 1
    for s in shape:
        size *= s
    parts = (var.start or "").split()
    if len(parts) == size:
        try:
            return [_convert(var, p) for p in parts]
        except ValueError:
            pass
    if len(parts) == 1 and size > 1:  # one start value for the whole array
        try:
            return [_convert(var, parts[0])] * size
        except ValueError:
            pass
    default: Any = "" if var.type == "String" else False if var.type == "Boolean" else 0
    return [default] * size


def _whole(model: ModelInfo, name: str, var: Variable, value: Any, shape: tuple[int, ...]) -> list[Any]:
    if not shape:
        return [_typed(model, name, var, value)]
    items = _row_major(_as_list(value), shape)
    size = 1
    for s in shape:
        size *= s
    if items is None or len(items) != size:
        got = "a scalar" if items is None else f"{len(items)} values"
        raise InputSpecError(f"{setting_said(name)}: {var.name} is an array of {size} values{_shape_said(shape)} in "
                             f"{model.label} but got {got}; write {_array_forms(name, shape, size)}")
    return [_typed(model, name, var, item) for item in items]


def _row_major(items: list[Any] | None, shape: tuple[int, ...]) -> list[Any] | None:
    """``items`` flattened in row-major order (FMI 3's order of array values) where it is a nested list of exactly
    ``shape`` (``A=[[1,2],[3,4]]`` for a 2 x 2 ``A``), else as given."""
    if items is None or len(shape) < 2 or not _nested_as(items, shape):
        return items
    flat: list[Any] = items
    for _ in shape[1:]:
        flat = [item for row in flat for item in row]
    return flat


def _nested_as(items: Any, shape: tuple[int, ...]) -> bool:
    """Whether ``items`` is a nested list whose lengths are ``shape`` at every level."""
    if not shape:
        return not isinstance(items, (list, tuple))
    return (isinstance(items, (list, tuple)) and len(items) == shape[0]
            and all(_nested_as(item, shape[1:]) for item in items))


def _shape_said(shape: tuple[int, ...]) -> str:
    """``" (shape 8x8)"`` for an array of more than one dimension, else ``""``."""
    return f" (shape {'x'.join(map(str, shape))})" if len(shape) > 1 else ""


def _array_forms(name: str, shape: tuple[int, ...], size: int) -> str:
    """The ways to write a value of an array of ``shape`` in ``--set``, for a refusal's fix."""
    if len(shape) < 2:
        return f"{name}=[v1,...,v{size}] or {name}[i]=v"
    index = ",".join("ijklmn"[:len(shape)])
    return (f"{name}=[v1,...,v{size}] (row-major, as FMI 3 stores it), {name} as nested lists of shape "
            f"{'x'.join(map(str, shape))}, or {name}[{index}]=v")


def _as_list(value: Any) -> list[Any] | None:
    if isinstance(value, (list, tuple)):
        return list(value)
    if hasattr(value, "tolist") and getattr(value, "ndim", 0) > 0:
        return list(value.tolist())
    if isinstance(value, str) and value.strip().startswith("["):
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = [p.strip() for p in value.strip()[1:-1].split(",")] if value.strip().endswith("]") else None
        return list(parsed) if isinstance(parsed, list) else None
    return None


def _flat_index(model: ModelInfo, name: str, index: tuple[int, ...], shape: tuple[int, ...]) -> int:
    if len(index) != len(shape):
        forms = ",".join("ijklmn"[:len(shape)])
        raise InputSpecError(f"{setting_said(name)}: {name.split('[')[0]} has {len(shape)} dimension(s) "
                             f"({'x'.join(map(str, shape))}) in {model.label} but the index has {len(index)}; write "
                             f"{name.split('[')[0]}[{forms}]=v (indices start at 1)")
    if any(not 1 <= i <= s for i, s in zip(index, shape)):
        raise InputSpecError(f"{setting_said(name)}: index out of range; {name.split('[')[0]} has shape "
                             f"{'x'.join(map(str, shape))} in {model.label} (indices start at 1)")
    flat = 0
    for i, s in zip(index, shape):
        flat = flat * s + (i - 1)
    return flat


def _article(word: str) -> str:
    """``"an"`` before a word that starts with a vowel (``an Integer``, ``an input``), else ``"a"``."""
    return "an" if word[:1].lower() in "aeiou" else "a"


def _typed(model: ModelInfo, name: str, var: Variable, value: Any) -> Any:
    try:
        typed = _convert(var, value)
    except (ValueError, TypeError):
        kind = ("a number" if var.type in _FLOAT_TYPES else "an integer" if var.type in _INTEGER_TYPES
                else "true or false" if var.type == "Boolean" else "a string")
        several = " (one --set per variable if the value holds another NAME=VALUE)" if "=" in str(value) else ""
        raise InputSpecError(f"{setting_said(name, value)}: {var.name} is {_article(var.type)} {var.type} variable of "
                             f"{model.label}; "
                             f"give {kind}{several}") from None
    _check_bounds(model, name, var, typed)
    return typed


def _convert(var: Variable, value: Any) -> Any:
    text = value.strip() if isinstance(value, str) else value
    if var.type in _FLOAT_TYPES:
        if isinstance(text, bool):
            raise ValueError(text)
        return float(text)
    if var.type in _INTEGER_TYPES:
        if isinstance(text, bool):
            raise ValueError(text)
        if isinstance(text, float):
            if not text.is_integer():
                raise ValueError(text)
            return int(text)
        number = int(str(text), 10)
        if var.type.startswith("UInt") and number < 0:
            raise ValueError(text)
        return number
    if var.type == "Boolean":
        if isinstance(text, bool):
            return text
        lowered = str(text).lower()
        if lowered in ("true", "1"):
            return True
        if lowered in ("false", "0"):
            return False
        raise ValueError(text)
    return str(text)


def _check_bounds(model: ModelInfo, name: str, var: Variable, value: Any) -> None:
    if isinstance(value, (bool, str)):
        return
    low = float(var.min) if var.min not in (None, "") else None
    high = float(var.max) if var.max not in (None, "") else None
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = f"[{var.min if low is not None else '-inf'}, {var.max if high is not None else 'inf'}]"
        what = "structural parameter" if var.causality == "structuralParameter" else "variable"
        raise InputSpecError(f"{setting_said(name, value)}: outside the bounds {bounds} of the {what} {var.name} in "
                             f"{model.label}; give a value within them")
