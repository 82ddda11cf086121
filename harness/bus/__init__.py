"""The bus side: frames, not physics.

This package opens the bus (here), carries frames over a Unix-domain socket (``unix``), tells the
SocketCAN kernel's echo of the harness's own frames from the rest (``socketcan_echo``),
measures bus load (``load``), puts every device driver on one bus (``rig_interface``) and
runs the virtual rig as its own process (``rig_process``). It may import ``drivers``,
``rig_models``, ``harness.state`` and ``harness.record.can_log`` (the interface logs every
frame); never ``harness.core``. The pre-flight check, which ticks a loop, is
``harness.core.probe``.

Opening the CAN bus named by ``--bus INTERFACE:CHANNEL`` or a run file.

Accepted: ``virtual:NAME`` (python-can's in-process bus; the default, what CI uses),
``socketcan:vcan0`` / ``socketcan:can0`` (Linux lab machines), and
``socketcand:127.0.0.1:PORT`` (a virtual rig in its own process serving socketcand on
loopback; any other host is refused: the harness reaches the lab rig through SocketCAN)
and ``unix:NAME`` (a virtual rig in its own process on a Unix-domain socket of this machine,
``harness.bus.unix``).
python-can's ``udp_multicast`` interface is refused: it sends on the real network.
"""

from __future__ import annotations

import logging
import queue
import socket
import time
from dataclasses import dataclass
from typing import Any

import can
from can.interfaces.virtual import VirtualBus, channels_lock

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


class BusSpecError(ValueError):
    pass


@dataclass(frozen=True)
class BusSpec:
    interface: str
    channel: str
    host: str = ""
    port: int = 0

    def __str__(self) -> str:
        if self.interface == "socketcand":
            return f"socketcand:{self.host}:{self.port}"
        return f"{self.interface}:{self.channel}"

    @property
    def in_process(self) -> bool:
        return self.interface == "virtual"


def parse_bus(text: str) -> BusSpec:
    interface, sep, rest = text.partition(":")
    interface = interface.strip().lower()
    if not sep or not rest:
        raise BusSpecError(
            f"--bus {text!r}: expected INTERFACE:CHANNEL, e.g. virtual:sgsrt, socketcan:vcan0 "
            "or socketcand:127.0.0.1:29536"
        )
    if interface == "udp_multicast":
        raise BusSpecError(
            "--bus udp_multicast: refused; it sends on the machine's real network interface. "
            "Use virtual:NAME in one process, socketcand:127.0.0.1:PORT between processes, "
            "or socketcan:vcan0 on Linux."
        )
    if interface == "virtual":
        return BusSpec("virtual", rest)
    if interface == "socketcan":
        return BusSpec("socketcan", rest)
    if interface == "unix":
        return BusSpec("unix", rest)
    if interface == "socketcand":
        host, _, port = rest.rpartition(":")
        if host not in LOOPBACK_HOSTS or not port.isdigit() or not 0 < int(port) < 65536:
            raise BusSpecError(
                f"--bus {text!r}: expected socketcand:127.0.0.1:PORT; socketcand is for a "
                "virtual rig on this machine (loopback only), the lab rig is reached with "
                "socketcan:can0"
            )
        return BusSpec("socketcand", "can0", host=host, port=int(port))
    raise BusSpecError(
        f"--bus {text!r}: unknown interface {interface!r} (use virtual, socketcan, socketcand "
        "or unix)"
    )


class _UnboundedQueue(queue.SimpleQueue):  # type: ignore[type-arg]
    """C-implemented FIFO with the part of ``queue.Queue``'s interface python-can's virtual
    bus uses (put/get with block and timeout, Empty); no Python-level locks per frame."""

    def full(self) -> bool:
        return False


class CopyingVirtualBus(VirtualBus):
    """python-can's ``virtual`` bus (same channels, interoperable with ``can.Bus(
    interface="virtual")``), made cheaper per frame for the lockstep loop:

    - send copies a frame with the Message constructor instead of ``copy.deepcopy`` (about
      25 us a frame, which dominated the loop);
    - its receive queue is a ``queue.SimpleQueue`` (unbounded, like python-can's default
      ``rx_queue_size=0``) instead of a lock-and-condition ``queue.Queue``;
    - ``recv(0)`` with no filters set is a plain non-blocking get, skipping BusABC's generic
      timeout/filter loop. Any other call goes through python-can's own path.
    """

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        fast: queue.SimpleQueue[can.Message] = _UnboundedQueue()
        with channels_lock:
            # a frame may have been put on the old queue since it was registered: keep it
            while True:
                try:
                    fast.put(self.queue.get_nowait())
                except queue.Empty:
                    break
            self.channel[self.channel.index(self.queue)] = fast
            self.queue = fast  # type: ignore[assignment]

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout == 0 and self._filters is None:
            self._check_if_open()
            try:
                return self.queue.get_nowait()
            except queue.Empty:
                return None
        return super().recv(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame, channel=self.channel_id, dlc=msg.dlc,
                data=data, is_rx=bus_queue is not self.queue, check=False)
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except Exception as exc:  # queue.Full
                raise can.CanOperationError(f"virtual bus {self.channel_id}: {exc}") from exc

    def send_owned(self, msg: can.Message) -> None:
        """``send`` for a frame its sender made for this call and never uses again (the
        virtual rig's telemetry): with one other end on the channel, that end receives
        ``msg`` itself, given the fields ``send``'s copy would have (this bus's channel,
        received, the send time), instead of a copy (a Message construction a frame, about
        0.6 us). Any other channel layout goes through ``send``."""
        self._check_if_open()
        queues = self.channel
        if len(queues) != 2 or self.receive_own_messages:
            self.send(msg)
            return
        other = queues[1] if queues[0] is self.queue else queues[0]
        if not self.preserve_timestamps:
            msg.timestamp = time.time()
        msg.channel = self.channel_id
        msg.is_rx = True
        other.put(msg)


class _BenignSplitFilter(logging.Filter):
    """python-can's socketcand client reads the TCP stream 1024 bytes at a time and warns
    every time a frame straddles two reads, which is ordinary TCP framing: it keeps the
    partial text and completes the frame on the next read. Only that warning is dropped;
    bad data, over-long and invalid frames are still reported."""

    MESSAGE = "Got incomplete message => waiting for more data"

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() != self.MESSAGE


_SOCKETCAND_LOG = logging.getLogger("can.interfaces.socketcand.socketcand")


class _ConnectRetryFilter(logging.Filter):
    """python-can's socketcand client retries ``connect`` in a busy loop for 10 s, logging a
    warning each time (about 700 000 lines with nothing listening); ``open_bus`` checks the
    server first and says it in one line, so these are dropped."""

    PREFIX = "Failed to connect to server"

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.PREFIX)


class _FailedReceiveFilter(logging.Filter):
    """python-can's socketcand client logs a failed read (the server gone: connection reset)
    with a traceback before it raises it as ``can.CanError``; the harness reports the error
    it raises, in one line, so the log record is dropped."""

    PREFIX = "Failed to receive"

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.PREFIX)


def _quiet_socketcand_client() -> None:
    for kind in (_BenignSplitFilter, _ConnectRetryFilter, _FailedReceiveFilter):
        if not any(isinstance(f, kind) for f in _SOCKETCAND_LOG.filters):
            _SOCKETCAND_LOG.addFilter(kind())


CONNECT_TIMEOUT_S = 3.0
"""How long ``open_bus`` tries to reach a socketcand server (a rig process just started
may take a moment to listen) before it says nothing listens."""


def _check_listening(spec: BusSpec, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """A socketcand server listens at ``spec``'s address, or ``BusSpecError`` in one line
    naming the bus and what to try, within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    last: OSError | None = None
    while True:
        try:
            with socket.create_connection((spec.host, spec.port),
                                          timeout=max(0.1, deadline - time.monotonic())):
                return
        except OSError as exc:
            last = exc
        if time.monotonic() >= deadline:
            break
        time.sleep(0.05)
    raise BusSpecError(
        f"cannot open bus {spec}: nothing answers at {spec.host}:{spec.port} within "
        f"{timeout_s:g} s ({last.strerror if last and last.strerror else last}); start the "
        f"virtual rig with 'harness virtual-rig --serve-socketcand {spec.port}', or check the "
        "port")


def open_bus(spec: BusSpec, receive_own_messages: bool = False) -> can.BusABC:
    try:
        if spec.interface == "virtual":
            return CopyingVirtualBus(channel=spec.channel,
                                     receive_own_messages=receive_own_messages)
        if spec.interface == "socketcan":
            # the kernel's echo of the harness's own frames, told from the rest (off until
            # the loop turns it on: timing on the wire)
            from harness.bus.socketcan_echo import EchoSocketcanBus

            bus = EchoSocketcanBus(spec.channel)
            if receive_own_messages:
                bus.enable_echo()
            return bus
        if spec.interface == "unix":
            from harness.bus.unix import UnixCanBus

            return UnixCanBus(spec.channel)
        _quiet_socketcand_client()
        _check_listening(spec)
        return can.Bus(interface="socketcand", channel=spec.channel, host=spec.host,
                       port=spec.port, tcp_tune=True)
    except (OSError, can.CanError, AttributeError) as exc:
        hint = ""
        if spec.interface == "socketcan":
            hint = (" (SocketCAN needs Linux with AF_CAN; create a virtual channel with "
                    "'sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0')")
        raise BusSpecError(f"cannot open bus {spec}: {exc}{hint}") from exc
