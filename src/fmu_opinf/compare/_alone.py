"""Each input alone on a given test input: a spec that drives two inputs or more alike (one harmonic, pulse, step or
chirp for all) is also run with one input driven at a time, and a line says where the joint run hides an input.

Of several inputs driven together, the one that moves the outputs most hides the others' errors: audit84 F4, an
r = 14 ROM of a 20-mass chain (forces in N and kN, a support motion in m) read max eps_y 5.3e-7 (0.07 % of range) on
``harmonic:amplitude=1,omega=0.5`` for all three, and was 18 % of range off the exact model with the N force alone,
59 % with the support motion alone.  compare split only its own default test per input.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from .._validate import either

if TYPE_CHECKING:
    from ._comparison import Comparison

#: The most inputs a given test input is run alone on without being asked (one source run each); above it compare
#: says in a line how to run one alone instead: a model of 10 inputs would cost 10 more runs of the source unsaid.
ALONE_AT_MOST = 6

#: Factor by which an input's miss alone must exceed the joint run's for compare to say the joint run hides it.
HIDDEN_FACTOR = 3.0


def given_each_input_alone(signal: Any, m: int, names: list[str]) -> tuple[list[tuple[str, str]], str]:
    """The given test input ``signal`` with each of the ``m`` inputs (named ``names``) driven alone, and a line
    saying why none is run ("" where that needs no word).

    Only a single parametric spec driving every input alike is split (the others held at its offset: amplitude
    0, so that the joint run is the sum of the runs alone about that operating point).  A ``;``-separated spec or a
    table chose each input's signal: that is the scenario asked for, and it is compared as given.  Above
    :data:`ALONE_AT_MOST` inputs none is run: the line names the one run that judges the first input alone."""
    from ..signals import ParametricSignal, parse_signal

    if m < 2 or isinstance(signal, os.PathLike):
        return [], ""
    try:
        one = parse_signal(signal) if isinstance(signal, str) else signal
    except Exception:   # (compare's own parse of the input says what is wrong with it)
        return [], ""
    if not isinstance(one, ParametricSignal) or one.params.get("amplitude", 0.0) == 0:
        return [], ""
    held = type(one)(one.kind, {**one.params, "amplitude": 0.0}, one.formula).spec
    alone = [(str(names[i]) if i < len(names) else f"u[{i + 1}]",
              ";".join(one.spec if j == i else held for j in range(m))) for i in range(m)]
    if len(alone) <= ALONE_AT_MOST:
        return alone, ""
    first, spec = alone[0]
    return [], (f"{one.spec} drives all {m} inputs at once: the input that moves the outputs most may hide the "
                f"others' errors; not run each alone ({m} more runs of the source, over compare's {ALONE_AT_MOST}): "
                f"to judge one input alone give it, e.g. {first}: {either('--input', value=spec)}")


def hidden_input_line(joint: "Comparison", alone: list["Comparison"]) -> str:
    """The line saying that the run of all inputs together hides an input's error, naming the input, the miss over
    an output's range alone and together, and the ``--input`` that shows it; "" where no input alone misses
    :data:`HIDDEN_FACTOR` times more than the joint run."""
    if not alone:
        return ""
    worst = worst_of(alone)
    name, miss = largest_miss(worst)
    joint_name, joint_miss = largest_miss(joint)
    if name is None or not miss > HIDDEN_FACTOR * joint_miss:
        return ""
    together = f"{joint_miss:.2g} of {joint_name}'s" if joint_name is not None else "no miss"
    return (f"{worst.driven_alone} alone is {miss:.2g} of {name}'s range off, {miss / max(joint_miss, 1e-300):.2g} "
            f"times what all inputs together on {joint.input_spec} show ({together}): the others' larger response "
            f"hides it; compare it alone with {either('--input', value=worst.input_spec)}")


def worst_of(comparisons: list["Comparison"]) -> "Comparison":
    """The comparison with the largest miss over an output's range (:func:`largest_miss`): of several inputs
    driven together, the one that moves the outputs most hides the others' errors, at the band's top as at the
    default test (audit84 F2: a 20-mass chain's r = 14 ROM read 0.036 of range there on two forces in N and kN and a
    support motion together, 0.28 and 0.29 with the N force or the support motion alone)."""
    return max(comparisons, key=lambda comparison: largest_miss(comparison)[1])


def largest_miss(comparison: "Comparison") -> tuple[str | None, float]:
    """The output with the largest miss over its range in ``comparison``, and that share (None, 0 where no output
    moves)."""
    per_output = comparison.metrics()["per_output"]
    misses = {name: figures["relative_max_variation"] for name, figures in per_output.items()
              if figures["relative_max_variation"] == figures["relative_max_variation"]}
    worst = max(misses, key=misses.get) if misses else None
    return worst, float(misses[worst]) if worst is not None else 0.0
