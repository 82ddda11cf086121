"""Ctrl-C and SIGTERM as a request to stop at the next tick boundary.

The first SIGINT/SIGTERM sets a flag that the loop reads once per tick, so a run never stops
half-way through writing a frame or a block of the recording; it then leaves the rig safe and
closes the logs. A second signal raises KeyboardInterrupt at once.
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
            raise KeyboardInterrupt
        self.reason = name
        print(f"\nharness: {name}: stopping at the next tick (again to abort at once)",
              file=sys.stderr)


@contextmanager
def stop_on_signals() -> Iterator[StopRequest]:
    req = StopRequest()
    previous = {s: signal.signal(s, req._handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield req
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
