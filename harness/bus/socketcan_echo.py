"""SocketCAN with the kernel's echo of the harness's own frames, told apart from the rest.

With ``CAN_RAW_RECV_OWN_MSGS`` the kernel hands a socket back every frame it sent, time
stamped when the kernel passed it to the driver (on a controller with its own echo, when
it was on the wire). python-can marks a frame ``is_rx = False`` when it was made *on this
host* (``MSG_DONTROUTE``), which on vcan is every frame, the virtual rig's too; the echo
of this very socket is marked ``MSG_CONFIRM``. ``EchoSocketcanBus`` sets ``is_rx = False``
for that echo only, so the harness's bus watch can take it as its own frame and not as
another master's. The echo is off until ``enable_echo`` (the CANopen set-up before the run
does not see it).

Also: ``broadcast_manager_missing`` says whether a bus can have the kernel send SYNC.
"""

from __future__ import annotations

import select
import socket
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


class EchoSocketcanBus(SocketcanBus):  # type: ignore[misc]
    """python-can's SocketCAN bus whose received frames say ``is_rx = False`` only for the
    echo of its own socket's frames (``MSG_CONFIRM``), with the kernel's time stamp."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        super().__init__(channel=channel, receive_own_messages=False, **kwargs)
        self.echo = False

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
                                                              RECEIVED_ANCILLARY_BUFFER_SIZE)
        except OSError as error:
            raise can.CanOperationError(f"Error receiving: {error.strerror}",
                                        error.errno) from error
        can_id, dlc, fd_flags, data = dissect_can_frame(cf)
        timestamp = 0.0
        for level, kind, cdata in ancillary:
            if level == socket.SOL_SOCKET and kind == constants.SO_TIMESTAMPNS:
                sec, nsec = RECEIVED_TIMESTAMP_STRUCT.unpack_from(cdata)
                timestamp = sec + nsec * 1e-9
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
