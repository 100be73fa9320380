"""Exceptions and warnings of fmu-opinf.

Every error a user can cause derives from :class:`FmuOpinfError`; the command line
catches that class, prints its one-line message and exits non-zero.  Each class also
derives from the matching built-in so that callers can catch, e.g., ``ValueError``.
Messages are one line: what is wrong, what was expected, and how to fix it.
"""

__all__ = [
    "FmuOpinfError",
    "InputSpecError",
    "InputTypeError",
    "DimensionError",
    "NotFittedError",
    "FMUError",
    "SolverError",
    "FileFormatError",
    "DataError",
    "FmuOpinfWarning",
    "Interrupted",
]


class FmuOpinfError(Exception):
    """Base class of all errors the tool reports to the user as one line."""


class InputSpecError(FmuOpinfError, ValueError):
    """An input-signal specification or input table is malformed."""


class InputTypeError(InputSpecError, TypeError):
    """An argument of the wrong type (a string for a number); also a ``TypeError``, as Python's own was."""


class DimensionError(FmuOpinfError, ValueError):
    """Arrays, models or signals disagree in size (e.g. number of inputs)."""


class NotFittedError(FmuOpinfError, ValueError, AttributeError):
    """An object was used before it was fitted."""


class FMUError(FmuOpinfError, RuntimeError):
    """An FMU is missing, unsupported, or failed during simulation."""


class SolverError(FmuOpinfError, RuntimeError):
    """The semidefinite program could not be solved."""


class FileFormatError(FmuOpinfError, ValueError):
    """A snapshot or ROM file is missing, truncated, or of the wrong layout."""


class DataError(FmuOpinfError, ValueError):
    """Data are unusable: NaN/Inf values, too few snapshots, r above the rank."""


class FmuOpinfWarning(UserWarning):
    """Something worked but deserves the user's attention."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM, raised where the tool can stop cleanly; ``signum`` is the signal's number.

    A ``KeyboardInterrupt`` (not an :class:`FmuOpinfError`): the command line exits with 128 + ``signum``.
    """

    def __init__(self, signum: int) -> None:
        import signal

        super().__init__(f"interrupted by {signal.Signals(signum).name}")
        self.signum = signum
