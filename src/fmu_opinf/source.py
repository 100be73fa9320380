"""Compatibility name: the sources now live in the package :mod:`fmu_opinf.sources`."""

from .sources import (BUILTIN_SYSTEMS, BuiltinSource, FMUSource, Source, StepError, match_names, natural_key,
                      open_source)

__all__ = [
    "Source",
    "BuiltinSource",
    "FMUSource",
    "StepError",
    "open_source",
    "match_names",
    "natural_key",
    "BUILTIN_SYSTEMS",
]
