"""Ctrl-C and SIGTERM as a request to stop at the next tick boundary.

The first SIGINT/SIGTERM sets a flag that the loop reads once per tick, so a run never stops
half-way through writing a frame or a block of the recording; it then leaves the rig safe and
closes the logs. A second signal raises KeyboardInterrupt at once while a loop ticks (the
loop catches it and leaves the rig safe); after the loop, while the run's files are closed
and judged, it is noted and ignored: raising there cut the closing short (a traceback, the
buses not shut down, no verdict). SIGKILL remains for a harness that does not end.
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

    def __call__(self) -> str | None:
        return self.reason

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if self.reason is not None:
            if _in_loop(frame):
                raise KeyboardInterrupt
            print(f"\nharness: {name}: the rig is already left safe; closing the run's "
                  "files", file=sys.stderr)
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
