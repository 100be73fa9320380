"""The worker plugin of fmu-opinf's local Dask cluster: a closing worker stops its running row cleanly.

Imported only where ``distributed`` is installed (:func:`fmu_opinf.runs.dask_client`).  When the tool is
interrupted it closes its cluster; each worker then asks its plugins to tear down before it waits for its running
task, and the nanny kills a worker whose task has not ended 4 s later.  A row killed that way leaves its
temporary file in the output folder, its unpacked FMU in ``$TMPDIR`` and its shared memory (audit 68).  The
teardown here marks an interrupt as pending in the worker process, so that the row's recording stops at its next
block (:func:`fmu_opinf._interrupts.check_interrupt`, polled every 50 ms while an isolated FMU steps) and removes
what it made, as it does on Ctrl-C in a serial run.
"""

from __future__ import annotations

import logging
import signal
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from . import _interrupts

__all__ = ["StopRowsOnClose"]


class StopRowsOnClose(WorkerPlugin):
    """Ignore Ctrl-C in the worker process (the client acts on it), and mark it as pending when the worker closes
    (its running row then stops)."""

    name = "fmu-opinf-stop-rows-on-close"

    def setup(self, worker: Any) -> None:
        """Called in the worker's event loop, its process's main thread: a worker that the nanny started again
        after a crash, while the client's Ctrl-C is handled, also leaves Ctrl-C to the client."""
        import threading

        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.SIG_IGN)

    def teardown(self, worker: Any) -> None:
        """Called by ``Worker.close`` before it waits for the running task; what distributed says while the
        worker closes (a heartbeat to a scheduler that closed first) is no news: only critical messages."""
        logging.getLogger("distributed").setLevel(logging.CRITICAL)
        if signal.SIGINT not in _interrupts._pending:
            _interrupts._pending.append(signal.SIGINT)
