"""A dependency-free progress bar for long loops (simulation steps, solver runs).

It draws on stderr only when stderr is a terminal, the caller did not ask for quiet,
and the work has already taken longer than ``delay`` seconds, so short runs and logs stay clean.
"""

from __future__ import annotations

import sys
import time


class Progress:
    """Report ``done / total`` on one terminal line, at most ten times a second."""

    def __init__(self, total: int, label: str, quiet: bool = False, delay: float = 1.0) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = not quiet and sys.stderr.isatty()
        self.delay = delay
        self.start = time.perf_counter()
        self._last_draw = 0.0
        self._drawn = False
        self.done = 0

    def update(self, done: int) -> None:
        """Set the number of finished units and redraw if due."""
        self.done = done
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
        """Finish the line if anything was drawn."""
        if self._drawn:
            self._last_draw = 0.0  # the final state is drawn even right after another draw
            self.update(self.done)
            sys.stderr.write("\n")
            sys.stderr.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
