"""The raw CAN log of a run: every frame the harness sent or received, in BLF.

BLF (Vector binary logging format) is read by python-can (``can.BLFReader``/``can.LogReader``)
and by common CAN tools. Frames are buffered by python-can's writer and the file is
finalised in ``close()``, which the loop calls on every exit path.
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

    def log(self, msg: can.Message) -> None:
        channel = msg.channel
        if channel is not None:
            numbered = self._numbered.get(channel)
            if numbered is None:
                numbered = self._numbered[channel] = channel2int(channel) is not None
            if not numbered:
                # a channel name without a number ("sgsrt") is written as the writer's default
                # channel either way; dropping it skips python-can's regex for every frame
                msg.channel = None
        self._writer.on_message_received(msg)
        self.frames += 1

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._writer.stop()


def read_can_log(path: Path) -> list[can.Message]:
    return list(can.LogReader(str(path)))
