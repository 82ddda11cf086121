"""A socketcand (rawmode) server on 127.0.0.1 that is itself a python-can bus.

The virtual rig runs in its own process and uses :class:`SocketcandServerBus` as its CAN
bus; the harness connects with python-can's own client::

    can.Bus(interface="socketcand", host="127.0.0.1", port=P, channel="can0", tcp_tune=True)

``send()`` on the server bus writes the frame to every client in rawmode; ``recv()`` returns
the frames the clients sent. A frame sent by one client is also relayed to the other clients,
as on a shared CAN bus (a sender never gets its own frame back).

Protocol subset (socketcand rawmode, as spoken by python-can's ``socketcand`` interface):

- server greets ``< hi >``; client ``< open CHANNEL >`` -> ``< ok >`` (a wrong channel gets
  ``< error could not open bus >`` and the connection is closed); client ``< rawmode >`` ->
  ``< ok >``. ``< bcmmode >`` -> ``< ok >`` (stops frame delivery), ``< echo >`` -> ``< echo >``.
- client -> server: ``< send ID LEN B0 B1 ... >``: ID is 1-3 hex digits (standard, <= 7FF) or
  exactly 8 hex digits (extended, <= 1FFFFFFF); LEN 0-8; each byte 1-2 hex digits.
- server -> client: ``< frame ID SECONDS.USECONDS HEXDATA >`` with ID as ``%03X`` (standard)
  or ``%08X`` (extended) and the data bytes run together (``< frame 123 12.000100  >`` for no
  data: python-can's parser needs that second space). Error frames go out as
  ``< error CLASS SECONDS.USECONDS >`` as socketcand does. Remote and CAN FD frames cannot be
  expressed in this protocol subset; ``send()`` refuses them with ValueError.

Malformed client input (anything that is not a well-formed command, text outside ``< >``,
over-long fragments) is counted in :attr:`SocketcandServerStats.malformed_commands` and
skipped. Before rawmode an unknown command is also answered ``< error unknown command >``
(as socketcand does); in rawmode nothing is answered, because python-can's client would
treat such a reply as a bad error frame and raise.

Handshake settle: python-can's client reads the ``< ok >`` that answers ``< rawmode >`` with
a single ``recv(256)`` and requires it to be exactly ``< ok >``; a frame that arrives in the
same read makes its constructor fail. The server cannot see when that read happened, so for
``handshake_settle_s`` after entering rawmode it queues (never drops, up to a bound) the frames
for that client, then flushes them in order.

Its own log is bounded: at most ``LOG_LINES_PER_S`` lines of malformed input per client a
second, the rest counted and said in one line (200 000 malformed commands wrote 15.8 MB
to stderr). A full server never lets idle clients lock a new one out: a client that sent
nothing for ``EVICT_IDLE_S`` (one not in rawmode first, then the longest idle) is dropped
to make room; only when every client is active is a new one refused.

Only 127.0.0.1 is served: any other host is refused with ValueError. TCP_NODELAY is set on
every accepted socket; pass ``tcp_tune=True`` to the python-can client for the other
direction.
"""

from __future__ import annotations

import enum
import logging
import os
import queue
import re
import selectors
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import can

log = logging.getLogger(__name__)

LOG_LINES_PER_S = 5
"""Lines of malformed input a client gets in the log a second; the rest are counted."""

EVICT_IDLE_S = 1.0
"""A client that sent nothing this long may be dropped to make room for a new one."""

QUOTE_CHARS = 80
"""The most characters of a client's command a log line quotes."""

LOOPBACK_HOST = "127.0.0.1"
MAX_COMMAND_CHARS = 256
"""A fragment this long without a closing ``>`` is discarded as malformed."""

_STD_ID_MAX = 0x7FF
_EXT_ID_MAX = 0x1FFFFFFF
_MAX_CLASSIC_DATA = 8
_ID_RE = re.compile(r"[0-9A-Fa-f]{1,3}|[0-9A-Fa-f]{8}")
_LEN_RE = re.compile(r"[0-8]")
_BYTE_RE = re.compile(r"[0-9A-Fa-f]{1,2}")
_CHANNEL_RE = re.compile(r"[A-Za-z0-9_.\-]{1,32}")
_MAX_PENDING_FRAMES = 10_000
_SHUTDOWN_SENTINEL = object()


class MalformedCommandError(ValueError):
    """A client command that does not follow the socketcand syntax."""


# --------------------------------------------------------------------------- protocol text


def format_frame_line(msg: can.Message, now_s: float | None = None) -> str:
    """Return the socketcand text that carries ``msg`` to a client.

    ``msg.timestamp`` (seconds) is used when positive, else ``now_s`` (default: wall clock).
    Raises ValueError for frames the rawmode text cannot carry.
    """
    if msg.is_fd:
        raise ValueError("msg: CAN FD frames are not supported by socketcand rawmode")
    if msg.is_remote_frame:
        raise ValueError("msg: remote frames are not supported by socketcand rawmode")
    data = bytes(msg.data)
    if len(data) > _MAX_CLASSIC_DATA:
        raise ValueError(f"msg: expected at most 8 data bytes, got {len(data)}")
    stamp = _format_timestamp(msg.timestamp if msg.timestamp > 0 else _now(now_s))
    if msg.is_error_frame:
        return f"< error {msg.arbitration_id & _EXT_ID_MAX:03X} {stamp} >"
    can_id = _format_id(msg.arbitration_id, msg.is_extended_id)
    return f"< frame {can_id} {stamp} {data.hex().upper()} >"


def parse_send_command(command: str, timestamp_s: float = 0.0) -> can.Message:
    """Parse one ``< send ID LEN B0 ... >`` command into a received python-can Message.

    Raises MalformedCommandError (a ValueError) naming what was wrong.
    """
    tokens = _command_tokens(command)
    if not tokens or tokens[0] != "send":
        raise MalformedCommandError(f"command: expected '< send ... >', got {command!r}")
    if len(tokens) < 3:
        raise MalformedCommandError(f"command: expected '< send ID LEN DATA... >', got {command!r}")
    id_text, len_text, byte_texts = tokens[1], tokens[2], tokens[3:]
    if not _ID_RE.fullmatch(id_text):
        raise MalformedCommandError(
            f"ID: expected 1-3 (standard) or 8 (extended) hex digits, got {id_text!r}"
        )
    is_extended = len(id_text) == 8
    can_id = int(id_text, 16)
    if can_id > (_EXT_ID_MAX if is_extended else _STD_ID_MAX):
        raise MalformedCommandError(f"ID: {id_text!r} is out of range")
    if not _LEN_RE.fullmatch(len_text):
        raise MalformedCommandError(f"LEN: expected one digit 0-8, got {len_text!r}")
    length = int(len_text)
    if len(byte_texts) != length:
        raise MalformedCommandError(f"DATA: LEN is {length} but {len(byte_texts)} bytes follow")
    for text in byte_texts:
        if not _BYTE_RE.fullmatch(text):
            raise MalformedCommandError(f"DATA: expected a 1-2 digit hex byte, got {text!r}")
    return can.Message(
        timestamp=timestamp_s,
        arbitration_id=can_id,
        is_extended_id=is_extended,
        data=bytes(int(text, 16) for text in byte_texts),
        is_rx=True,
    )


def split_commands(buffer: str) -> tuple[list[str], int, str]:
    """Cut complete ``< ... >`` commands out of ``buffer``.

    Returns ``(commands, junk_count, rest)``: the complete commands in order, how many pieces
    of junk (text outside brackets, a ``<`` never closed before the next ``<``, an over-long
    unterminated fragment) were discarded, and the unfinished tail to keep for the next read.
    """
    commands: list[str] = []
    junk = 0
    pos = 0
    while True:
        start = buffer.find("<", pos)
        if start == -1:
            if buffer[pos:].strip():
                junk += 1
            return commands, junk, ""
        if buffer[pos:start].strip():
            junk += 1
        end = buffer.find(">", start)
        next_start = buffer.find("<", start + 1)
        if next_start != -1 and (end == -1 or next_start < end):
            junk += 1  # '<' never closed before the next '<'
            pos = next_start
            continue
        if end == -1:
            rest = buffer[start:]
            if len(rest) > MAX_COMMAND_CHARS:
                return commands, junk + 1, ""
            return commands, junk, rest
        commands.append(buffer[start : end + 1])
        pos = end + 1


def _quote(text: str) -> str:
    """``repr(text)`` of at most ``QUOTE_CHARS`` characters of it."""
    if len(text) <= QUOTE_CHARS:
        return repr(text)
    return f"{text[:QUOTE_CHARS]!r}... ({len(text)} characters)"


def _command_tokens(command: str) -> list[str]:
    if not (command.startswith("<") and command.endswith(">")):
        raise MalformedCommandError(f"command: expected '< ... >', got {command!r}")
    return command[1:-1].split()


def _format_id(can_id: int, is_extended: bool) -> str:
    if is_extended:
        if not 0 <= can_id <= _EXT_ID_MAX:
            raise ValueError(f"msg.arbitration_id: expected 0..0x1FFFFFFF, got {can_id:#x}")
        return f"{can_id:08X}"
    if not 0 <= can_id <= _STD_ID_MAX:
        raise ValueError(
            f"msg.arbitration_id: expected 0..0x7FF for a standard id, got {can_id:#x}"
        )
    return f"{can_id:03X}"


def _format_timestamp(timestamp_s: float) -> str:
    seconds = int(timestamp_s)
    micros = round((timestamp_s - seconds) * 1e6)
    if micros >= 1_000_000:
        seconds, micros = seconds + 1, micros - 1_000_000
    return f"{seconds}.{micros:06d}"


def _now(now_s: float | None) -> float:
    return time.time() if now_s is None else now_s


# --------------------------------------------------------------------------- server


class _Mode(enum.Enum):
    NO_BUS = "no_bus"
    BCM = "bcm"
    RAW = "raw"


@dataclass
class _Client:
    sock: socket.socket
    key: int
    peer: tuple[str, int]
    mode: _Mode = _Mode.NO_BUS
    rx_text: str = ""
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    closed: bool = False
    settle_until: float = 0.0
    pending: deque[str] | None = None
    connected_at: float = field(default_factory=time.monotonic)
    last_active: float = field(default_factory=time.monotonic)
    log_window: float = 0.0
    log_lines: int = 0
    log_suppressed: int = 0


@dataclass(frozen=True)
class SocketcandServerStats:
    """Counters of a :class:`SocketcandServerBus` (a snapshot)."""

    clients_connected: int
    clients_in_rawmode: int
    clients_accepted_total: int
    clients_dropped_total: int
    frames_from_clients: int
    frames_to_clients: int
    malformed_commands: int
    frames_dropped: int


class SocketcandServerBus(can.BusABC):
    """A python-can bus whose other nodes are socketcand clients on 127.0.0.1.

    Parameters:
        channel: bus name the clients must ``< open >`` (e.g. ``"can0"``).
        host: must be ``"127.0.0.1"``; anything else raises ValueError.
        port: TCP port; 0 picks a free one (read it back from :attr:`port`).
        handshake_settle_s: how long frames for a client that just entered rawmode are held
            back (see the module docstring).
        client_send_timeout_s: a client that does not take a handshake reply within this
            time is disconnected. Frames are sent without waiting: a client whose socket
            buffer is full (it stopped reading) is disconnected at once, so one slow reader
            never stalls ``send()`` for the others.
        handshake_timeout_s: a client not in rawmode this long after it connected is
            disconnected (idle connections took every slot for good).
        max_clients: connections beyond this get ``< error too many clients >`` and are closed.
        rx_queue_size: frames from clients waiting for ``recv()``; beyond it new ones are
            dropped and counted.
        relay_between_clients: also deliver a client's frame to the other rawmode clients.
    """

    def __init__(
        self,
        channel: str = "can0",
        host: str = LOOPBACK_HOST,
        port: int = 0,
        *,
        handshake_settle_s: float = 0.25,
        client_send_timeout_s: float = 2.0,
        handshake_timeout_s: float = 5.0,
        max_clients: int = 16,
        rx_queue_size: int = 100_000,
        relay_between_clients: bool = True,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: object,
    ) -> None:
        _validate_settings(
            channel,
            host,
            port,
            handshake_settle_s,
            client_send_timeout_s,
            max_clients,
            rx_queue_size,
        )
        self.channel = channel
        self._settle_s = float(handshake_settle_s)
        self._send_timeout_s = float(client_send_timeout_s)
        if not handshake_timeout_s > 0:
            raise ValueError(f"handshake_timeout_s must be > 0, got {handshake_timeout_s!r}")
        self._handshake_timeout_s = float(handshake_timeout_s)
        self._max_clients = max_clients
        self._relay = relay_between_clients
        self._rx: queue.Queue[object] = queue.Queue(maxsize=rx_queue_size)
        self._lock = threading.Lock()
        self._raw_changed = threading.Condition(self._lock)
        self._clients: dict[int, _Client] = {}
        self._counts = {
            "accepted": 0,
            "dropped": 0,
            "from_clients": 0,
            "to_clients": 0,
            "malformed": 0,
            "frames_dropped": 0,
        }
        self._closing = threading.Event()
        self._closed = False

        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._listener.bind((LOOPBACK_HOST, port))
            self._listener.listen(max_clients)
            self._listener.setblocking(False)
        except OSError as exc:
            self._listener.close()
            raise OSError(
                exc.errno, f"cannot listen on {LOOPBACK_HOST}:{port}: {exc.strerror}"
            ) from exc
        self._port: int = self._listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._listener, selectors.EVENT_READ, "listener")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        self.channel_info = f"socketcand server for {channel} on {LOOPBACK_HOST}:{self._port}"
        self._thread = threading.Thread(
            target=self._serve, name=f"socketcand-server-{self._port}", daemon=True
        )
        self._thread.start()
        try:
            super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        except BaseException:
            self._closing.set()
            self._wake()
            self._thread.join(timeout=5.0)
            raise

    # ------------------------------------------------------------------ public API

    @property
    def host(self) -> str:
        return LOOPBACK_HOST

    @property
    def port(self) -> int:
        """The bound TCP port."""
        return self._port

    @property
    def stats(self) -> SocketcandServerStats:
        with self._lock:
            clients = list(self._clients.values())
            c = dict(self._counts)
        return SocketcandServerStats(
            clients_connected=len(clients),
            clients_in_rawmode=sum(1 for cl in clients if cl.mode is _Mode.RAW),
            clients_accepted_total=c["accepted"],
            clients_dropped_total=c["dropped"],
            frames_from_clients=c["from_clients"],
            frames_to_clients=c["to_clients"],
            malformed_commands=c["malformed"],
            frames_dropped=c["frames_dropped"],
        )

    @property
    def malformed_count(self) -> int:
        with self._lock:
            return self._counts["malformed"]

    def wait_for_clients(self, count: int = 1, timeout_s: float = 5.0) -> bool:
        """Wait until at least ``count`` clients are in rawmode; False on timeout."""
        if count < 0:
            raise ValueError(f"count: expected >= 0, got {count}")
        if timeout_s < 0:
            raise ValueError(f"timeout_s: expected >= 0 seconds, got {timeout_s}")
        with self._raw_changed:
            return self._raw_changed.wait_for(
                lambda: self._raw_client_count_locked() >= count, timeout=timeout_s
            )

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send ``msg`` to every client in rawmode (``timeout`` is not used: a client that
        does not take the frame within ``client_send_timeout_s`` is disconnected)."""
        if self._closing.is_set():
            raise can.CanOperationError("socketcand server bus is shut down")
        line = format_frame_line(msg)
        self._broadcast(line, exclude=None)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._closing.is_set():
            raise can.CanOperationError("socketcand server bus is shut down")
        try:
            if timeout is None:
                item = self._rx.get()
            else:
                item = self._rx.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None, False
        if item is _SHUTDOWN_SENTINEL:
            self._rx.put_nowait(item)  # wake any other waiting reader too
            raise can.CanOperationError("socketcand server bus is shut down")
        assert isinstance(item, can.Message)
        return item, False

    def shutdown(self) -> None:
        """Close every client, the listening socket and the server thread (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._closing.set()
        self._wake()
        self._thread.join(timeout=5.0)
        if self._thread.is_alive():  # pragma: no cover - only if a client send is stuck
            log.warning("socketcand server thread did not stop within 5 s")
        try:
            self._rx.put_nowait(_SHUTDOWN_SENTINEL)
        except queue.Full:
            _drain(self._rx)
            self._rx.put_nowait(_SHUTDOWN_SENTINEL)
        with self._raw_changed:
            self._raw_changed.notify_all()
        super().shutdown()

    # ------------------------------------------------------------------ server thread

    def _serve(self) -> None:
        try:
            while not self._closing.is_set():
                for key, _ in self._selector.select(timeout=self._select_timeout()):
                    if key.data == "listener":
                        self._accept()
                    elif key.data == "wake":
                        _drain_socket(self._wake_r)
                    else:
                        self._read_client(key.data)
                self._flush_settled_clients()
                self._drop_idle_clients()
        except Exception:  # pragma: no cover - a bug; keep the process alive, log it
            log.exception("socketcand server thread failed")
        finally:
            self._close_everything()

    def _select_timeout(self) -> float | None:
        with self._lock:
            waits = [cl.settle_until for cl in self._clients.values() if cl.pending is not None]
            waits += [cl.connected_at + self._handshake_timeout_s
                      for cl in self._clients.values() if cl.mode is not _Mode.RAW]
        if not waits:
            return None
        return max(0.0, min(waits) - time.monotonic())

    def _drop_idle_clients(self) -> None:
        now = time.monotonic()
        with self._lock:
            idle = [cl for cl in self._clients.values() if cl.mode is not _Mode.RAW
                    and now - cl.connected_at >= self._handshake_timeout_s]
        for client in idle:
            log.warning("socketcand server: dropping client %s: no rawmode within %g s",
                        client.peer, self._handshake_timeout_s)
            with self._lock:
                self._counts["dropped"] += 1
            self._remove_client(client)

    def _accept(self) -> None:
        try:
            sock, peer = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(self._send_timeout_s)
        client = _Client(sock=sock, key=sock.fileno(), peer=peer)
        with self._lock:
            too_many = len(self._clients) >= self._max_clients
            idle = self._idlest_locked() if too_many else None
        if idle is not None:  # idle clients never lock a new one out
            log.warning("socketcand server: dropping idle client %s (nothing sent for %.1f s) "
                        "for %s", idle.peer, time.monotonic() - idle.last_active, peer)
            with self._lock:
                self._counts["dropped"] += 1
            self._remove_client(idle)
        with self._lock:
            too_many = len(self._clients) >= self._max_clients
            if not too_many:
                self._clients[client.key] = client
                self._counts["accepted"] += 1
        if too_many:
            log.warning(
                "socketcand server: refusing %s, %d clients already", peer, self._max_clients
            )
            self._write(client, "< error too many clients >")
            sock.close()
            return
        self._selector.register(sock, selectors.EVENT_READ, client)
        log.info("socketcand server: client %s connected", peer)
        self._write(client, "< hi >")

    def _idlest_locked(self) -> _Client | None:
        """The client to drop for a new one: idle ``EVICT_IDLE_S`` or more, one not in
        rawmode before one in rawmode, then the longest idle; None when all are active."""
        now = time.monotonic()
        idle = [cl for cl in self._clients.values() if now - cl.last_active >= EVICT_IDLE_S]
        if not idle:
            return None
        return min(idle, key=lambda cl: (cl.mode is _Mode.RAW, cl.last_active))

    def _read_client(self, client: _Client) -> None:
        try:
            chunk = client.sock.recv(4096)
        except (BlockingIOError, InterruptedError, TimeoutError):
            return
        except OSError:
            chunk = b""
        if not chunk or client.closed:
            self._remove_client(client)
            return
        _quickack(client.sock)
        client.last_active = time.monotonic()
        commands, junk, client.rx_text = split_commands(
            client.rx_text + chunk.decode("ascii", errors="replace")
        )
        if junk:
            self._count_malformed(junk, client, "text outside '< >'")
        for command in commands:
            self._handle_command(client, command)
            if client.closed:
                self._remove_client(client)
                return

    def _handle_command(self, client: _Client, command: str) -> None:
        tokens = command[1:-1].split()
        verb = tokens[0] if tokens else ""
        if verb == "send" and client.mode is not _Mode.NO_BUS:
            self._handle_send(client, command)
        elif verb == "echo" and len(tokens) == 1:
            self._write(client, "< echo >")
        elif client.mode is _Mode.NO_BUS and verb == "open" and len(tokens) == 2:
            if tokens[1] == self.channel:
                client.mode = _Mode.BCM
                self._write(client, "< ok >")
            else:
                log.warning(
                    "socketcand server: %s asked for bus %r, serving %r",
                    client.peer,
                    tokens[1],
                    self.channel,
                )
                self._write(client, "< error could not open bus >")
                self._mark_for_close(client)
        elif client.mode is not _Mode.NO_BUS and verb == "rawmode" and len(tokens) == 1:
            self._enter_rawmode(client)
        elif client.mode is not _Mode.NO_BUS and verb == "bcmmode" and len(tokens) == 1:
            self._set_mode(client, _Mode.BCM)
            self._write(client, "< ok >")
        else:
            self._count_malformed(1, client, f"unsupported command {_quote(command)}")
            if client.mode is not _Mode.RAW:
                self._write(client, "< error unknown command >")

    def _handle_send(self, client: _Client, command: str) -> None:
        now = time.time()
        try:
            msg = parse_send_command(command, timestamp_s=now)
        except MalformedCommandError as exc:
            self._count_malformed(1, client, str(exc))
            return
        msg.channel = self.channel
        try:
            self._rx.put_nowait(msg)
        except queue.Full:
            with self._lock:
                self._counts["frames_dropped"] += 1
        with self._lock:
            self._counts["from_clients"] += 1
        if self._relay:
            self._broadcast(format_frame_line(msg, now), exclude=client)

    def _enter_rawmode(self, client: _Client) -> None:
        with client.send_lock:
            if self._settle_s > 0:
                client.pending = deque()
                client.settle_until = time.monotonic() + self._settle_s
        self._write(client, "< ok >")
        self._set_mode(client, _Mode.RAW)

    def _set_mode(self, client: _Client, mode: _Mode) -> None:
        with self._raw_changed:
            client.mode = mode
            self._raw_changed.notify_all()

    def _flush_settled_clients(self) -> None:
        with self._lock:
            settling = [cl for cl in self._clients.values() if cl.pending is not None]
        for client in settling:
            self._deliver(client, None)

    # ------------------------------------------------------------------ writing

    def _broadcast(self, line: str, exclude: _Client | None) -> None:
        with self._lock:
            targets = [
                cl for cl in self._clients.values() if cl.mode is _Mode.RAW and cl is not exclude
            ]
        for client in targets:
            self._deliver(client, line)

    def _deliver(self, client: _Client, line: str | None) -> None:
        """Write a frame line to a rawmode client, holding it back while it settles."""
        with client.send_lock:
            if client.closed:
                return
            text = line or ""
            frames = 0 if line is None else 1
            if client.pending is not None:
                if time.monotonic() < client.settle_until:
                    if line is not None:
                        if len(client.pending) >= _MAX_PENDING_FRAMES:
                            client.pending.popleft()
                            with self._lock:
                                self._counts["frames_dropped"] += 1
                        client.pending.append(line)
                    return
                frames += len(client.pending)
                text = "".join(client.pending) + text
                client.pending = None
            if not text:
                return
            ok = self._sendall_locked(client, text, wait=False)
        if ok:
            with self._lock:
                self._counts["to_clients"] += frames

    def _write(self, client: _Client, text: str) -> None:
        with client.send_lock:
            if not client.closed:
                self._sendall_locked(client, text)

    def _sendall_locked(self, client: _Client, text: str, wait: bool = True) -> bool:
        try:
            if wait:
                client.sock.sendall(text.encode("ascii"))
            else:  # a frame: never wait for one client while the others wait for theirs
                data = text.encode("ascii")
                # the socket has a timeout, so Python keeps its descriptor non-blocking and
                # polls in sock.send: a plain write of the descriptor never waits
                sent = os.write(client.sock.fileno(), data)
                if sent < len(data):
                    raise BlockingIOError(f"its socket buffer is full ({sent} of {len(data)} "
                                          "bytes taken): it stopped reading")
        except OSError as exc:  # includes TimeoutError: the client stopped reading
            log.warning("socketcand server: dropping client %s: %s", client.peer, exc)
            client.closed = True
            with self._lock:
                self._counts["dropped"] += 1
            _shutdown_socket(client.sock)  # the server thread sees EOF and closes it
            return False
        return True

    # ------------------------------------------------------------------ bookkeeping

    def _raw_client_count_locked(self) -> int:
        return sum(1 for cl in self._clients.values() if cl.mode is _Mode.RAW)

    def _count_malformed(self, count: int, client: _Client, why: str) -> None:
        with self._lock:
            self._counts["malformed"] += count
        now = time.monotonic()
        if now - client.log_window >= 1.0:
            if client.log_suppressed:
                log.warning("socketcand server: %d more malformed inputs from %s not logged",
                            client.log_suppressed, client.peer)
            client.log_window, client.log_lines, client.log_suppressed = now, 0, 0
        if client.log_lines >= LOG_LINES_PER_S:
            client.log_suppressed += 1
            return
        client.log_lines += 1
        log.warning("socketcand server: malformed input from %s skipped: %s", client.peer,
                    why[:2 * QUOTE_CHARS])

    def _mark_for_close(self, client: _Client) -> None:
        with client.send_lock:
            client.closed = True

    def _remove_client(self, client: _Client) -> None:
        """Forget and close a client (server thread only)."""
        with self._raw_changed:
            self._clients.pop(client.key, None)
            self._raw_changed.notify_all()
        try:
            self._selector.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        _shutdown_socket(client.sock)
        with client.send_lock:
            client.closed = True
            client.sock.close()
        if client.log_suppressed:
            log.warning("socketcand server: %d more malformed inputs from %s not logged",
                        client.log_suppressed, client.peer)
            client.log_suppressed = 0
        log.info("socketcand server: client %s disconnected", client.peer)

    def _close_everything(self) -> None:
        with self._lock:
            clients = list(self._clients.values())
        for client in clients:
            self._remove_client(client)
        self._selector.close()
        self._listener.close()
        self._wake_r.close()
        self._wake_w.close()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass


SocketcandServer = SocketcandServerBus
"""Alias: the server *is* the bus (``SocketcandServer(host=..., port=..., channel=...)``)."""


def _validate_settings(
    channel: str,
    host: str,
    port: int,
    settle_s: float,
    send_timeout_s: float,
    max_clients: int,
    rx_queue_size: int,
) -> None:
    if host != LOOPBACK_HOST:
        raise ValueError(
            f"host: only {LOOPBACK_HOST!r} is served (traffic must stay on loopback), got {host!r}"
        )
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise ValueError(f"port: expected an int 0..65535 (0 = pick a free port), got {port!r}")
    if not isinstance(channel, str) or not _CHANNEL_RE.fullmatch(channel):
        raise ValueError(
            f"channel: expected 1-32 characters of letters, digits, '_.-', got {channel!r}"
        )
    if not settle_s >= 0:
        raise ValueError(f"handshake_settle_s: expected >= 0 seconds, got {settle_s!r}")
    if not send_timeout_s > 0:
        raise ValueError(f"client_send_timeout_s: expected > 0 seconds, got {send_timeout_s!r}")
    if not isinstance(max_clients, int) or max_clients < 1:
        raise ValueError(f"max_clients: expected an int >= 1, got {max_clients!r}")
    if not isinstance(rx_queue_size, int) or rx_queue_size < 1:
        raise ValueError(f"rx_queue_size: expected an int >= 1, got {rx_queue_size!r}")


def _quickack(sock: socket.socket) -> None:
    quickack = getattr(socket, "TCP_QUICKACK", None)
    if quickack is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, quickack, 1)
        except OSError:
            pass


def _shutdown_socket(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass


def _drain_socket(sock: socket.socket) -> None:
    try:
        while sock.recv(4096):
            pass
    except (BlockingIOError, InterruptedError, OSError):
        pass


def _drain(q: queue.Queue[object]) -> None:
    try:
        while True:
            q.get_nowait()
    except queue.Empty:
        pass
