"""A CAN bus between two processes of one machine over a Unix-domain socket (``unix:NAME``).

The cheaper transport for a virtual rig in its own process (``harness virtual-rig
--serve-unix NAME``): one ``SOCK_SEQPACKET`` datagram per CAN frame, a fixed 22-byte
binary record (timestamp, identifier, flags, DLC, 8 data bytes), no text to format or
parse, no TCP stack. The socket lives in Linux's abstract namespace (no file, nothing
written anywhere; only processes of this machine can connect). Classic CAN frames keep
their meaning: identifier, extended/remote/error flags, DLC and data; CAN FD is refused.

``UnixCanServerBus(name)`` listens and serves one client (the harness); frames it sends
while no client is connected are dropped, as on a CAN bus with no other node.
``UnixCanBus(name)`` connects. Both are python-can buses (``can.BusABC``).
"""

from __future__ import annotations

import select
import socket
import struct
import time
from typing import Any

import can

FRAME = struct.Struct("<dIBB8s")
F_EXT, F_REMOTE, F_ERROR = 1, 2, 4


def _address(name: str) -> str:
    if not name or "\x00" in name or len(name) > 100:
        raise ValueError(f"unix bus name {name!r}: expected 1-100 characters without NUL")
    return "\x00sgsrt-can-" + name


def pack(msg: can.Message) -> bytes:
    if msg.is_fd:
        raise ValueError("unix bus: CAN FD frames are not supported")
    flags = (F_EXT if msg.is_extended_id else 0) | (F_REMOTE if msg.is_remote_frame else 0) \
        | (F_ERROR if msg.is_error_frame else 0)
    return FRAME.pack(msg.timestamp or time.time(), msg.arbitration_id, flags, msg.dlc,
                      bytes(msg.data))


def unpack(raw: bytes, channel: Any) -> can.Message:
    ts, arb, flags, dlc, data = FRAME.unpack(raw)
    return can.Message(timestamp=ts, arbitration_id=arb, is_extended_id=bool(flags & F_EXT),
                       is_remote_frame=bool(flags & F_REMOTE),
                       is_error_frame=bool(flags & F_ERROR), dlc=dlc,
                       data=data[:dlc] if not flags & F_REMOTE else b"", channel=channel,
                       is_rx=True, check=False)


class _SeqpacketBus(can.BusABC):
    _sock: socket.socket | None
    _stuck = False  # the last send timed out (the harness's end: SEND_TIMEOUT_S)

    def _recv_sock(self, timeout: float | None) -> can.Message | None:
        sock = self._sock
        if sock is None:
            return None
        try:
            raw = sock.recv(64, socket.MSG_DONTWAIT)
        except BlockingIOError:
            if timeout == 0:
                return None
            ready, _, _ = select.select([sock], [], [], timeout)
            if not ready:
                return None
            try:
                raw = sock.recv(64, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return None
            except ConnectionResetError:  # the peer closed with frames unread
                raw = b""
        except ConnectionResetError:
            raw = b""
        if not raw:  # the peer closed
            self._peer_closed()
            return None
        return unpack(raw, "unix")  # no digits: logs write it as their default channel

    def _peer_closed(self) -> None:
        raise can.CanOperationError(f"{self.channel_info}: the other end closed the bus")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._recv_sock(timeout), False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is None:
            return self._recv_sock(timeout)
        return super().recv(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        sock = self._sock
        if sock is None:
            return
        try:
            # once a send has timed out the other end is not reading: the next frames are
            # refused at once, until one goes through again (SEND_TIMEOUT_S)
            sock.send(pack(msg), socket.MSG_DONTWAIT if self._stuck else 0)
            self._stuck = False
        except BlockingIOError:  # the peer's queue is full: it is not reading
            self._stuck = True
            raise can.CanOperationError(f"{self.channel_info}: the other end is not reading "
                                        "(its queue is full): frame not sent") from None
        except (BrokenPipeError, ConnectionResetError):
            self._peer_closed()


SEND_TIMEOUT_S = 0.5
"""The longest the harness's end waits to send one frame while the other end's queue is
full (a rig process the host stalled, or stopped): a short stall is waited out, as the host
would hold a frame on a real bus's full transmit queue, and the rig's late answers are then
the host's; past it the frame is refused (``can.CanOperationError``), the frames after it
at once while the queue stays full, and the ticks go on at their rate, so a rig that has
stopped holds the loop once for this long (the monitor's bench-stall rule ends the run)."""


class UnixCanBus(_SeqpacketBus):
    """The harness's end: connects to a ``UnixCanServerBus`` of the same name. A send waits
    at most ``SEND_TIMEOUT_S`` for room in the other end's queue, then refuses the frame,
    and the frames after it at once until the other end reads again."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self.channel_info = f"unix:{channel}"
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.connect(_address(channel))
            whole = int(SEND_TIMEOUT_S)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack(
                "ll", whole, int(round((SEND_TIMEOUT_S - whole) * 1e6))))
        except OSError:
            sock.close()
            raise
        self._sock = sock
        super().__init__(channel=channel, **kwargs)

    def shutdown(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        super().shutdown()


class UnixCanServerBus(_SeqpacketBus):
    """The rig's end: listens on ``name`` (abstract namespace) and serves one client at a
    time; a client that leaves is replaced by the next one to connect."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self.channel_info = f"unix:{channel}"
        self._listen = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._listen.bind(_address(channel))
        self._listen.listen(1)
        self._listen.setblocking(False)
        self._sock = None
        super().__init__(channel=channel, **kwargs)

    def _accept(self, timeout: float | None) -> bool:
        ready, _, _ = select.select([self._listen], [], [], timeout)
        if not ready:
            return False
        try:
            sock, _ = self._listen.accept()
        except BlockingIOError:
            return False
        sock.setblocking(True)
        self._sock = sock
        return True

    def _peer_closed(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _recv_sock(self, timeout: float | None) -> can.Message | None:
        if self._sock is None:
            t0 = time.monotonic()
            if not self._accept(timeout):
                return None
            if timeout is not None:
                timeout = max(0.0, timeout - (time.monotonic() - t0))
        return super()._recv_sock(timeout)

    def shutdown(self) -> None:
        self._peer_closed()
        self._listen.close()
        super().shutdown()
