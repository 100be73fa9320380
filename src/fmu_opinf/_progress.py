"""A dependency-free progress bar for long loops (simulation steps, solver runs).

It draws on stderr only when stderr is a terminal, the caller did not ask for quiet,
and the work has already taken longer than ``delay`` seconds, so short runs and logs stay clean.
Where stderr is not a terminal (a log file, a pipe), work that runs longer than ``LOG_AFTER`` seconds
gets a plain line then and every ``LOG_EVERY`` seconds after, and one when it ends.
"""

from __future__ import annotations

import math
import sys
import time


#: Seconds after which work reports itself in a log (stderr not a terminal), and between its lines.
LOG_AFTER = 10.0
LOG_EVERY = 60.0


class Progress:
    """Report ``done / total`` on one terminal line, at most ten times a second (in a log: a line a minute)."""

    def __init__(self, total: int, label: str, quiet: bool = False, delay: float = 1.0) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = not quiet and sys.stderr.isatty()
        self.logged = not quiet and not self.enabled
        self.delay = delay
        self.start = time.perf_counter()
        self._last_draw = 0.0
        self._drawn = False
        self._next_log = self.start + LOG_AFTER
        self._log_lines = 0
        self.done = 0

    def _log(self, final: bool = False) -> None:
        """A plain line for a log: where the work stands and how long it has taken."""
        elapsed = time.perf_counter() - self.start
        state = "ended" if final else "running"
        sys.stderr.write(f"{self.label}: {self.done}/{self.total} after {elapsed:.0f} s ({state})\n")
        sys.stderr.flush()
        self._log_lines += 1

    def update(self, done: int) -> None:
        """Set the number of finished units and redraw if due."""
        self.done = done
        if self.logged and time.perf_counter() >= self._next_log:
            self._log()
            self._next_log = time.perf_counter() + LOG_EVERY
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.start < self.delay or now - self._last_draw < 0.1:
            return
        self._last_draw = now
        frac = min(done / self.total, 1.0)
        elapsed = now - self.start
        eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {done}/{self.total} {elapsed:5.1f}s eta {eta:5.1f}s")
        sys.stderr.flush()
        self._drawn = True

    def close(self) -> None:
        """Finish the line if anything was drawn (in a log: a last line if the work had reported itself)."""
        if self._log_lines:
            self._log(final=True)
        if self._drawn:
            self._last_draw = 0.0  # the final state is drawn even right after another draw
            self.update(self.done)
            sys.stderr.write("\n")
            sys.stderr.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def duration_text(seconds: float) -> str:
    """``seconds`` in the unit a reader takes in at once: ``"40 s"``, ``"12 min"``, ``"3.5 h"`` (``"an unknown
    time"`` where not finite)."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.2g} h" if math.isfinite(seconds) else "an unknown time"
