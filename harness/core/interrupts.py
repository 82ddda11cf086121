"""Ctrl-C and SIGTERM as a request to stop at the next tick boundary.

Before a run has begun (its files read and checked: nothing opened, nothing sent) a signal
raises KeyboardInterrupt at once: there is nothing to leave safe or close, and a read that
blocks (a FIFO given as a file) must not keep the process alive; waiting for a tick that
never comes kept it for minutes. Once a run has begun (``StopRequest.begin``), the first
SIGINT/SIGTERM sets a flag that the loop reads once per tick, so a run never stops
half-way through writing a frame or a block of the recording; it then leaves the rig safe and
closes the logs. A second signal raises KeyboardInterrupt at once while a loop ticks (the
loop catches it and leaves the rig safe); after the loop, while the run's files are closed
and judged, it is noted: raising there cuts the closing short (no verdict, the buses not
shut down in order), so only a third signal does so. The command turns that
KeyboardInterrupt into one line and exit 130.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType


class StopRequest:
    def __init__(self) -> None:
        self.reason: str | None = None
        self.begun = False
        self.noted = 0

    def __call__(self) -> str | None:
        return self.reason

    def begin(self) -> None:
        """A run begins (buses, rig, files): from now on a first signal stops at a tick."""
        self.begun = True

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if not self.begun:  # nothing opened or sent yet: end at once
            self.reason = name
            raise KeyboardInterrupt
        if self.reason is not None:
            if _in_loop(frame):
                raise KeyboardInterrupt
            self.noted += 1
            if self.noted > 1:
                print(f"\nharness: {name}: closing cut short", file=sys.stderr)
                raise KeyboardInterrupt
            print(f"\nharness: {name}: the rig is already left safe; closing the run's "
                  "files (again to cut the closing short)", file=sys.stderr)
            return
        self.reason = name
        print(f"\nharness: {name}: stopping at the next tick (again to abort at once)",
              file=sys.stderr)


LOOP_FUNCTIONS = frozenset({"run_loop", "run_probe", "probe"})
"""Functions whose frames mean a loop is ticking (``harness.core.loop``, the probe)."""


def _in_loop(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code.co_name in LOOP_FUNCTIONS and \
                frame.f_globals.get("__name__", "").startswith("harness.core"):
            return True
        frame = frame.f_back
    return False


@contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    req = StopRequest()
    previous = {s: signal.signal(s, req._handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield req
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
