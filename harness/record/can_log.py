"""The raw CAN log of a run: every frame the harness sent or received, in BLF.

BLF (Vector binary logging format) is read by python-can (``can.BLFReader``/``can.LogReader``)
and by common CAN tools. ``log()`` only queues the frame (a list append, in the tick's
critical path); ``drain()`` hands queued frames to python-can's writer and runs where the
loop drains the Rerun recording, outside the critical path. ``close()`` drains and finalises
the file, and the session calls it on every exit path (faults, errors, Ctrl-C).

Bounded memory and SIGKILL: python-can's ``BLFWriter`` holds frames until a container
(``CONTAINER_BYTES`` uncompressed) is full, then compresses and writes it, and writes the
file header's counts only in ``stop()``. Here every ``flush_every_s`` of frame time (and at
each full container) the writer's buffer is written as a complete container and the file is
flushed to the OS, so memory holds at most one container and, after a SIGKILL, the file is a
sequence of whole containers behind a provisional header: python-can's ``BLFReader`` reads it
to the last flushed container (it reads objects to the end of the file; the header's counts
are not used), so only the frames since the last flush are lost (tested). Compression level 1
keeps a container's compression well under a tick's slack.
"""

from __future__ import annotations

from pathlib import Path

import can
from can.util import channel2int

from harness.record.output import OutputError, as_output_error, is_output_failure

CONTAINER_BYTES = 32 * 1024


class CanLog:
    def __init__(self, path: Path, flush_every_s: float = 1.0) -> None:
        self.path = path
        self._writer = can.BLFWriter(str(path), compression_level=1,
                                     max_container_size=CONTAINER_BYTES)
        self.flush_every_s = flush_every_s
        self._last_flush_ts: float | None = None
        self.frames = 0
        self._closed = False
        self._numbered: dict[object, bool] = {}
        self._pending: list[can.Message] = []
        self.failed: OutputError | None = None

    def log(self, msg: can.Message) -> None:
        """Queue a frame (the message must not be changed afterwards; ours never are)."""
        self._pending.append(msg)
        self.frames += 1

    @property
    def pending(self) -> int:
        """Frames queued and not yet handed to the writer."""
        return len(self._pending)

    def drain(self) -> int:
        """Write the queued frames through python-can's BLF writer; returns how many.
        Raises ``OutputError`` when the file cannot be written (a full or read-only disk);
        later calls drop the queue (memory stays bounded) and raise it again."""
        if self.failed is not None:
            self._pending.clear()
            raise self.failed
        try:
            return self._drain()
        except OSError as exc:
            if not is_output_failure(exc):
                raise
            self.failed = as_output_error(self.path.parent, exc)
            raise self.failed from exc

    def _drain(self) -> int:
        pending, self._pending = self._pending, []
        write = self._writer.on_message_received
        numbered_of = self._numbered
        for msg in pending:
            channel = msg.channel
            if channel is not None:
                numbered = numbered_of.get(channel)
                if numbered is None:
                    number = channel2int(channel)
                    # BLF keeps a channel number in 16 bits
                    numbered = numbered_of[channel] = number is not None and 0 <= number < 65535
                if not numbered:
                    # a channel name without a number ("sgsrt") is written as the writer's
                    # default channel either way; dropping it skips python-can's regex
                    msg.channel = None
            write(msg)
        if pending:
            ts = pending[-1].timestamp
            if self._last_flush_ts is None:
                self._last_flush_ts = ts
            elif ts - self._last_flush_ts >= self.flush_every_s:
                self.flush()
                self._last_flush_ts = ts
        return len(pending)

    def flush(self) -> None:
        """Write the writer's buffered frames as whole containers and flush the file."""
        writer = self._writer
        while writer._buffer_size > 0:  # python-can writes one container per call
            before = writer._buffer_size
            writer._flush()
            if writer._buffer_size >= before:
                break
        writer.file.flush()

    def close(self) -> None:
        """Drain and finalise the file; after a failed write only close it (its whole
        containers stay readable: the reader does not use the header's counts)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.drain()
        finally:
            if self.failed is None:
                try:
                    self._writer.stop()
                except OSError as exc:
                    if not is_output_failure(exc):
                        raise
                    self.failed = as_output_error(self.path.parent, exc)
                    raise self.failed from exc
            else:
                try:
                    self._writer.file.close()
                except OSError:
                    pass  # its buffered bytes could not be written either


def read_can_log(path: Path) -> list[can.Message]:
    return list(can.LogReader(str(path)))
