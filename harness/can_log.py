"""The raw CAN log of a run: every frame the harness sent or received, in BLF.

BLF (Vector binary logging format) is read by python-can (``can.BLFReader``/``can.LogReader``)
and by common CAN tools. ``log()`` only queues the frame (a list append, in the tick's
critical path); ``drain()`` hands queued frames to python-can's writer and runs where the
loop drains the Rerun recording, outside the critical path. The writer buffers and
compresses; ``close()`` drains and finalises the file, and the session calls it on every
exit path (faults, errors, Ctrl-C). Frames are held in memory either way until the writer
fills a block, so queueing loses nothing that the writer alone would have kept.
"""

from __future__ import annotations

from pathlib import Path

import can
from can.util import channel2int


class CanLog:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._writer = can.BLFWriter(str(path))
        self.frames = 0
        self._closed = False
        self._numbered: dict[object, bool] = {}
        self._pending: list[can.Message] = []

    def log(self, msg: can.Message) -> None:
        """Queue a frame (the message must not be changed afterwards; ours never are)."""
        self._pending.append(msg)
        self.frames += 1

    @property
    def pending(self) -> int:
        """Frames queued and not yet handed to the writer."""
        return len(self._pending)

    def drain(self) -> int:
        """Write the queued frames through python-can's BLF writer; returns how many."""
        pending, self._pending = self._pending, []
        write = self._writer.on_message_received
        numbered_of = self._numbered
        for msg in pending:
            channel = msg.channel
            if channel is not None:
                numbered = numbered_of.get(channel)
                if numbered is None:
                    numbered = numbered_of[channel] = channel2int(channel) is not None
                if not numbered:
                    # a channel name without a number ("sgsrt") is written as the writer's
                    # default channel either way; dropping it skips python-can's regex
                    msg.channel = None
            write(msg)
        return len(pending)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self.drain()
            finally:
                self._writer.stop()


def read_can_log(path: Path) -> list[can.Message]:
    return list(can.LogReader(str(path)))
