"""SocketCAN with the kernel's echo of the harness's own frames, told apart from the rest.

With ``CAN_RAW_RECV_OWN_MSGS`` the kernel hands a socket back every frame it sent, time
stamped when the kernel passed it to the driver (on a controller with its own echo, when
it was on the wire). python-can marks a frame ``is_rx = False`` when it was made *on this
host* (``MSG_DONTROUTE``), which on vcan is every frame, the virtual rig's too; the echo
of this very socket is marked ``MSG_CONFIRM``. ``EchoSocketcanBus`` sets ``is_rx = False``
for that echo only, so the harness's bus watch can take it as its own frame and not as
another master's. The echo is off until ``enable_echo`` (the CANopen set-up before the run
does not see it).

The socket also asks the kernel how many frames it dropped because the socket's receive
queue was full (``SO_RXQ_OVFL``: a loop that fell behind on a busy host), counted in
``kernel_drops``, and asks for a receive queue of ``RECEIVE_BUFFER_BYTES`` (the kernel
grants at most its ``net.core.rmem_max`` to a process without CAP_NET_ADMIN).

Also: ``broadcast_manager_missing`` says whether a bus can have the kernel send SYNC.
"""

from __future__ import annotations

import select
import socket
import struct
from typing import Any

import can
from can.interfaces.socketcan import constants
from can.interfaces.socketcan.socketcan import (
    RECEIVED_ANCILLARY_BUFFER_SIZE,
    RECEIVED_TIMESTAMP_STRUCT,
    SocketcanBus,
    dissect_can_frame,
)

MSG_CONFIRM = getattr(socket, "MSG_CONFIRM", 0x800)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
DROPS = struct.Struct("@I")
ANCILLARY_BYTES = RECEIVED_ANCILLARY_BUFFER_SIZE + socket.CMSG_SPACE(DROPS.size)
RECEIVE_BUFFER_BYTES = 4 << 20
"""The receive queue asked for: at 500 Hz a tick's answers take a few kB of the kernel's
memory (a frame's buffer is several hundred bytes), so 4 MiB holds seconds of a stalled
loop's traffic where the default (about 200 kB) holds a few hundred frames."""


class EchoSocketcanBus(SocketcanBus):  # type: ignore[misc]
    """python-can's SocketCAN bus whose received frames say ``is_rx = False`` only for the
    echo of its own socket's frames (``MSG_CONFIRM``), with the kernel's time stamp."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        super().__init__(channel=channel, receive_own_messages=False, **kwargs)
        self.echo = False
        self.kernel_drops = 0  # frames the kernel dropped: this socket's queue was full
        self.receive_buffer_bytes = self._grow_receive_buffer()
        try:
            self.socket.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            self.drops_counted = True
        except OSError:  # a kernel without it: drops are not counted (said in the summary)
            self.drops_counted = False

    def _grow_receive_buffer(self) -> int:
        """Ask for ``RECEIVE_BUFFER_BYTES`` of receive queue (forced when privileged);
        the size the kernel granted (it reports twice what it accounts for)."""
        sock = self.socket
        for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
            try:
                sock.setsockopt(socket.SOL_SOCKET, option, RECEIVE_BUFFER_BYTES)
                break
            except OSError:  # not privileged: the plain option, capped at rmem_max
                continue
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))

    def enable_echo(self, on: bool = True) -> None:
        """The kernel's echo of this socket's frames on (or off) from now on."""
        self.socket.setsockopt(constants.SOL_CAN_RAW, constants.CAN_RAW_RECV_OWN_MSGS,
                               1 if on else 0)
        self.echo = on

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            ready, _, _ = select.select([self.socket], [], [], timeout)
        except OSError as error:
            raise can.CanOperationError(f"Failed to receive: {error.strerror}",
                                        error.errno) from error
        if not ready:
            return None, self._is_filtered
        try:
            cf, ancillary, flags, _addr = self.socket.recvmsg(constants.CANFD_MTU,
                                                              ANCILLARY_BYTES)
        except OSError as error:
            raise can.CanOperationError(f"Error receiving: {error.strerror}",
                                        error.errno) from error
        can_id, dlc, fd_flags, data = dissect_can_frame(cf)
        timestamp = 0.0
        for level, kind, cdata in ancillary:
            if level == socket.SOL_SOCKET and kind == constants.SO_TIMESTAMPNS:
                sec, nsec = RECEIVED_TIMESTAMP_STRUCT.unpack_from(cdata)
                timestamp = sec + nsec * 1e-9
            elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(cdata) >= 4:
                # the socket's running count of frames dropped before this one was queued
                self.kernel_drops = DROPS.unpack_from(cdata)[0]
        ext = bool(can_id & constants.CAN_EFF_FLAG)
        msg = can.Message(
            timestamp=timestamp, channel=self.channel,
            arbitration_id=can_id & (0x1FFFFFFF if ext else 0x7FF), is_extended_id=ext,
            is_remote_frame=bool(can_id & constants.CAN_RTR_FLAG),
            is_error_frame=bool(can_id & constants.CAN_ERR_FLAG),
            is_fd=len(cf) == constants.CANFD_MTU,
            bitrate_switch=bool(fd_flags & constants.CANFD_BRS),
            error_state_indicator=bool(fd_flags & constants.CANFD_ESI),
            is_rx=not flags & MSG_CONFIRM, dlc=dlc, data=data, check=False)
        return msg, self._is_filtered


def broadcast_manager_missing(bus: can.BusABC) -> str | None:
    """Why the kernel cannot send this bus's periodic frames (SocketCAN's broadcast
    manager), or None if it can: a BCM socket is opened on the bus's channel and closed."""
    if not isinstance(bus, SocketcanBus):
        return f"{type(bus).__name__} is not a SocketCAN bus"
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_DGRAM, socket.CAN_BCM) as bcm:
            bcm.connect((bus.channel,))
    except (OSError, AttributeError) as exc:
        return f"no broadcast manager on {bus.channel} ({exc}; Linux: modprobe can-bcm)"
    return None
