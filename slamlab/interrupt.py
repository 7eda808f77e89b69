"""Ctrl-C during a run: stop cleanly, keep what is computed, say so in one line.

During the SLAM loop the first Ctrl-C (SIGINT) only asks the engine to stop after the step it
is on, so the partial map and trajectory are consistent and can be written; a second Ctrl-C
stops at once. Outside the loop Ctrl-C raises KeyboardInterrupt as usual.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a Ctrl-C'd program


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C; `str(exc)` is the line for the user, e.g.
    `interrupted at scan 5205/13631; partial results in DIR`."""


class StopOnSigint:
    """A progress callback for the engine that returns True once Ctrl-C was pressed.

    Use as a context manager around the SLAM loop; it also remembers the last progress
    (`done`, `total` scans) so the interruption can say where it happened."""

    def __init__(self, progress: Callable[[int, int], None]):
        self.progress = progress
        self.requested = False
        self.done = 0
        self.total = 0
        self._previous = None

    def __call__(self, done: int, total: int) -> bool:
        self.done, self.total = done, total
        self.progress(done, total)
        return self.requested

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:  # the second Ctrl-C: the user does not want to wait for the step
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> StopOnSigint:
        if threading.current_thread() is threading.main_thread():  # signals reach the main thread only
            self._previous = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None
