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

Packed in bulk: python-can's writer packs each frame with three ``struct`` calls and three
buffer appends (about 9 us of a lockstep tick's 100). Every classic data or
remote frame (all the rig sends) is the same 48-byte BLF object, so ``drain()`` packs the
queued frames into one buffer with a single precompiled struct and hands that to the
writer's buffer in one piece, byte for byte what ``BLFWriter.on_message_received`` writes
(tested); error and CAN FD frames still go through the writer's own method, in order.
"""

from __future__ import annotations

import struct
from pathlib import Path

import can
from can.io import blf
from can.util import channel2int

from harness.record.output import OutputError, as_output_error, is_output_failure

CONTAINER_BYTES = 32 * 1024

# one BLF CAN_MESSAGE object: base header, v1 header (ns timestamps), the frame; 48 bytes,
# a multiple of 4 (no padding). The layouts are python-can's own (can.io.blf).
_OBJ = struct.Struct("<" + blf.OBJ_HEADER_BASE_STRUCT.format.lstrip("<") +
                     blf.OBJ_HEADER_V1_STRUCT.format.lstrip("<") +
                     blf.CAN_MSG_STRUCT.format.lstrip("<"))
_HEADER_SIZE = blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size
_OBJ_SIZE = _HEADER_SIZE + blf.CAN_MSG_STRUCT.size
assert _OBJ.size == _OBJ_SIZE and _OBJ_SIZE % 4 == 0
# every field up to the v1 header's timestamp is the same for every such object: an object
# is this template with its timestamp and frame packed over its tail (one struct call of
# six values, not sixteen)
_CONSTANT = _OBJ.pack(b"LOBJ", _HEADER_SIZE, 1, _OBJ_SIZE, blf.CAN_MESSAGE,
                      blf.TIME_ONE_NANS, 0, 0, 0, 0, 0, 0, 0, b"")
_TAIL_AT = _HEADER_SIZE - 8  # the v1 header's 8-byte timestamp, then the CAN_MSG fields
_TAIL = struct.Struct("<Q" + blf.CAN_MSG_STRUCT.format.lstrip("<"))
assert _TAIL_AT + _TAIL.size == _OBJ_SIZE


class CanLog:
    def __init__(self, path: Path, flush_every_s: float = 1.0) -> None:
        self.path = path
        self._writer = can.BLFWriter(str(path), compression_level=1,
                                     max_container_size=CONTAINER_BYTES)
        self.flush_every_s = flush_every_s
        self._last_flush_ts: float | None = None
        self._taken = 0  # frames queued and since taken off the queue (written or dropped)
        self._closed = False
        self._numbered: dict[object, int | None] = {}
        self._blf_channel: dict[object, int] = {}
        self._pending: list[can.Message] = []
        # log(msg) queues a frame (the message must not be changed afterwards; ours never
        # are): the queue's own append, no Python call per frame in the tick; the
        # queue is emptied in place, never replaced
        self.log = self._pending.append
        self.failed: OutputError | None = None

    @property
    def frames(self) -> int:
        """Frames logged so far."""
        return self._taken + len(self._pending)

    @property
    def pending(self) -> int:
        """Frames queued and not yet handed to the writer."""
        return len(self._pending)

    def drain(self) -> int:
        """Write the queued frames to the writer's buffer (packed in bulk); returns how
        many. Raises ``OutputError`` when the file cannot be written (a full or read-only
        disk); later calls drop the queue (memory stays bounded) and raise it again."""
        if self.failed is not None:
            self._taken += len(self._pending)
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
        if not self._pending:
            return 0
        pending = self._pending.copy()
        self._pending.clear()
        self._taken += len(pending)
        writer = self._writer
        packed = bytearray(_CONSTANT * len(pending))
        pack_into = _TAIL.pack_into
        channels = self._blf_channel  # channel -> BLF channel number, filled as seen
        ext_bit, remote_flag, dir_flag = blf.CAN_MSG_EXT, blf.REMOTE_FLAG, blf.DIR
        start = writer.start_timestamp
        offset = 0
        last_ts = 0.0
        last_ch: object = channels  # no message's channel: looked up at the first frame
        channel = 0
        for msg in pending:
            if msg.is_error_frame or msg.is_fd:
                ch = msg.channel
                if offset:  # what is packed so far goes first: the file keeps the order
                    self._append(packed[:offset], offset // _OBJ_SIZE, last_ts)
                    packed = bytearray(_CONSTANT * len(pending))
                    offset = 0
                if ch is not None and self._numbered_as(ch) is None:
                    msg.channel = None  # written as the default channel either way
                writer.on_message_received(msg)
                start = writer.start_timestamp
                continue
            ts = msg.timestamp
            if start is None:
                # python-can's rule: the start truncated to milliseconds
                start = writer.start_timestamp = int(ts * 1000) / 1000
            ns = int((ts - start) * 1e9)
            ch = msg.channel
            if ch is not last_ch:  # the frames of a run are on one channel
                channel = channels.get(ch)  # type: ignore[assignment]
                if channel is None:
                    channel = channels[ch] = self._channel_number(ch)
                last_ch = ch
            arb_id = msg.arbitration_id
            pack_into(packed, offset + _TAIL_AT, ns if ns > 0 else 0, channel,
                      (remote_flag if msg.is_remote_frame else 0)
                      | (0 if msg.is_rx else dir_flag), msg.dlc,
                      arb_id | ext_bit if msg.is_extended_id else arb_id, msg.data)
            offset += _OBJ_SIZE
            last_ts = ts
        if offset:
            self._append(packed[:offset] if offset < len(packed) else packed,
                         offset // _OBJ_SIZE, last_ts)
        ts = pending[-1].timestamp
        if self._last_flush_ts is None:
            self._last_flush_ts = ts
        elif ts - self._last_flush_ts >= self.flush_every_s:
            self.flush()
            self._last_flush_ts = ts
        return len(pending)

    def _channel_number(self, channel: object) -> int:
        """A message's BLF channel: python-can's rule (a channel number n is written as
        n + 1, anything else, e.g. "sgsrt", as the writer's default), its regex run once per
        channel."""
        number = self._numbered_as(channel) if channel is not None else None
        return number if number is not None else self._writer.channel

    def _numbered_as(self, channel: object) -> int | None:
        number = self._numbered.get(channel, -1)
        if number == -1:
            n = channel2int(channel)  # type: ignore[arg-type]
            # BLF keeps a channel number in 16 bits
            number = n + 1 if n is not None and 0 <= n < 65535 else None
            self._numbered[channel] = number
        return number

    def _append(self, data: bytearray, n_objects: int, last_ts: float) -> None:
        """Hand packed objects to the writer's buffer, as its ``_add_object`` would."""
        writer = self._writer
        writer._buffer.append(bytes(data))
        writer._buffer_size += len(data)
        writer.object_count += n_objects
        writer.stop_timestamp = last_ts
        while writer._buffer_size >= writer.max_container_size:
            before = writer._buffer_size
            writer._flush()  # one container a call; the rest stays buffered
            if writer._buffer_size >= before:
                break

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
