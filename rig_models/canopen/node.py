"""One CANopen device (CiA 301) of the virtual rig, built from its EDS.

`VirtualNode(node_id, eds_path, send)` keeps the object dictionary's values in a dict keyed
(index, subindex) of raw CANopen values and talks only through `send(can_id, data)`. It has
no thread and reads no clock: the owner calls `handle(can_id, data, now_s)` for every frame
it receives and `poll(now_s)` for the time-driven work (boot-up, heartbeat producer and
consumer), so it runs the same in lockstep (rig time) and in real time (wall clock).

Emulated: NMT (boot-up, start/stop/pre-operational/reset node/reset communication),
expedited and segmented SDO upload and download (block transfer refused with 0x05040001),
SYNC consumer with synchronous TPDOs (transmission type 0 = on SYNC when the mapped data
changed, 1..240 = every n-th SYNC, counted from the SYNC whose counter byte equals the
TPDO's SYNC start value, sub 6) and RPDOs (0..240 take effect at the next SYNC, 254/255
at once), PDO mapping by SDO in CiA 301's sequence, heartbeat producer and consumer, EMCY
producer with 0x1001 and the 0x1003 history, error behaviour 0x1029. Not emulated: node
guarding and RTR, LSS, event-driven TPDOs (types 252..255 refused), inhibit and event
timers (stored, unused), TIME, SRDO, store/restore parameters.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from operator import itemgetter
from pathlib import Path
from typing import Any

from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.objectdictionary import datatypes as dt

from drivers.binding.canopen import parse_od
from drivers.canopen_pdo import MAX_PDO_BITS, PdoCodec, PdoMappingError, compile_mapping
from drivers.dbc import FrameError

Send = Callable[[int, bytes], None]
Key = tuple[int, int]

# SDO abort codes (CiA 301 table 22)
ABORT_TOGGLE = 0x05030000
ABORT_COMMAND = 0x05040001
ABORT_READ_WRITE_ONLY = 0x06010001
ABORT_WRITE_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_CANNOT_MAP = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_DEVICE_STATE = 0x08000022

# EMCY error codes the node itself raises (CiA 301 table 21)
EMCY_HEARTBEAT = 0x8130
EMCY_PDO_LENGTH = 0x8210
EMCY_PDO_LENGTH_EXCEEDED = 0x8220
EMCY_SYNC_LENGTH = 0x8240
EMCY_RESET = 0x0000

# error register 0x1001 bits
ERR_GENERIC = 0x01
ERR_CURRENT = 0x02
ERR_VOLTAGE = 0x04
ERR_TEMPERATURE = 0x08
ERR_COMMUNICATION = 0x10
ERR_PROFILE = 0x20
ERR_MANUFACTURER = 0x80

MAX_STRING_BYTES = 255
_EMCY = struct.Struct("<HB5s")


_NUMBER_TYPES = frozenset(dt.INTEGER_TYPES) | {dt.BOOLEAN}


def _interpreted(index: int) -> bool:
    """The communication objects the node computes with (error register and history, SYNC,
    EMCY, heartbeats, error behaviour, PDO parameters): an EDS giving one of them a type
    that is not an integer cannot be emulated."""
    return index in (0x1001, 0x1003, 0x1005, 0x1014, 0x1016, 0x1017, 0x1029) or \
        0x1400 <= index <= 0x1BFF


class NmtState(IntEnum):
    INITIALISING = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class SdoAbort(Exception):
    """Raised inside the SDO server (and by validators) to abort a transfer with a code."""

    def __init__(self, code: int, what: str = "") -> None:
        super().__init__(f"SDO abort 0x{code:08X} {what}".strip())
        self.code = code


def error_register_bits(error_code: int) -> int:
    """The 0x1001 bits an EMCY error code sets (CiA 301 table 21 / 47): generic always."""
    bits = ERR_GENERIC
    group = error_code >> 12
    if group == 0x2:
        bits |= ERR_CURRENT
    elif group == 0x3:
        bits |= ERR_VOLTAGE
    elif group == 0x4:
        bits |= ERR_TEMPERATURE
    elif error_code >> 8 == 0x81 or error_code >> 8 == 0x82:
        bits |= ERR_COMMUNICATION
    elif error_code >> 8 == 0xFF:
        bits |= ERR_MANUFACTURER
    return bits


@dataclass
class _Pdo:
    number: int
    is_tpdo: bool
    com_index: int
    map_index: int
    cob_id: int = 0
    valid: bool = False
    trans_type: int = 0
    keys: tuple[Key, ...] = ()
    codec: PdoCodec | None = None
    sync_count: int = 0
    started: bool = True  # False: waiting for the SYNC whose counter is the start value
    pending: tuple[Any, ...] | None = None
    last_payload: bytes | None = None
    # values -> payload: the mapped objects' raw values packed (compiled with the codec)
    payload: Callable[[dict[Key, Any]], bytes] | None = None
    problem: str | None = None  # why its current mapping cannot be carried (no codec)


def _payload_function(codec: PdoCodec, keys: tuple[Key, ...]) -> Callable[[dict[Key, Any]], bytes]:
    """``f(values)`` = ``codec.encode([values[k] for k in keys])``, byte for byte and with the
    same errors, through one itemgetter and the codec's positional packer (every TPDO every
    SYNC, in the tick)."""
    pack = codec.packer()
    if len(keys) == 1:
        key = keys[0]
        return lambda values: pack(values[key])
    get = itemgetter(*keys)
    return lambda values: pack(*get(values))


@dataclass
class _Consumer:
    producer_id: int
    timeout_s: float
    last_seen_s: float | None = None
    timed_out: bool = False


@dataclass
class _SdoTransfer:
    upload: bool
    key: Key
    var: ODVariable
    toggle: int = 0
    buffer: bytearray = field(default_factory=bytearray)
    size: int | None = None
    pos: int = 0


class VirtualNode:
    """A CANopen slave from an EDS: no thread, the owner pumps `handle` and `poll`."""

    def __init__(self, node_id: int, eds_path: str | Path, send: Send) -> None:
        if not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise ValueError(f"node_id: {node_id!r} is not a CANopen node id (1..127)")
        path = Path(eds_path)
        if not path.is_file():
            raise FileNotFoundError(f"eds_path: no EDS file at {path}")
        self.id = node_id
        self.eds_path = path
        self.send = send
        self.od = parse_od(path, node_id, ValueError)
        self.name = str(self._od_default(0x1008, 0) or path.stem)
        self._vars: dict[Key, ODVariable] = {}
        for index in self.od:
            obj = self.od[index]
            if isinstance(obj, ODVariable):
                self._vars[(index, 0)] = obj
            elif isinstance(obj, (ODRecord, ODArray)):
                for sub, v in obj.subindices.items():
                    self._vars[(index, sub)] = v
        for key, var in self._vars.items():
            if _interpreted(key[0]) and var.data_type not in _NUMBER_TYPES:
                raise ValueError(f"{path.name}: 0x{key[0]:04X}:{key[1]:02X} ({var.name}) has "
                                 f"data type 0x{var.data_type or 0:X}, CiA 301 makes it an "
                                 "integer")
        self.values: dict[Key, Any] = {}
        self.state = NmtState.INITIALISING
        # hooks: the owner (physics) and the profiles
        self.before_tpdo: Callable[[VirtualNode, float], None] | None = None
        self.on_comm_error: list[Callable[[int], None]] = []
        self._write_listeners: dict[Key, list[Callable[[Key, Any], None]]] = {}
        self._validators: dict[Key, list[Callable[[Any], int | None]]] = {}
        self._nmt_listeners: list[Callable[[NmtState, NmtState], None]] = []
        self._reset_listeners: list[Callable[[], None]] = []
        self._sync_listeners: list[Callable[[float], None]] = []
        # fault injection
        self._heartbeat_silent = False
        self._abort_next: dict[int, int] = {}
        # communication state
        self._now = 0.0
        self._sdo: _SdoTransfer | None = None
        self._pdos: list[_Pdo] = []
        self._rpdo_by_cob: dict[int, _Pdo] = {}
        # the SYNC's work lists (rebuilt by _reconfigure): the RPDOs that may hold values
        # for the next SYNC, the TPDOs that send; and whether any RPDO holds values now
        self._sync_rpdos: tuple[_Pdo, ...] = ()
        self._tpdos: tuple[_Pdo, ...] = ()
        self._any_pending = False
        # poll() has nothing to do before this time (-inf: look again at the next poll)
        self._poll_due = -math.inf
        self._sync_cob = 0x80
        self._hb_next: float | None = None
        self._consumers: dict[int, _Consumer] = {}
        self.sync_count = 0
        self.emcy_sent = 0
        self._load_defaults(0x0000, 0xFFFF)
        self._reconfigure()

    # ---------------------------------------------------------------- object dictionary
    def _od_default(self, index: int, sub: int) -> Any:
        obj = self.od.indices.get(index)
        if obj is None:
            return None
        v = obj if isinstance(obj, ODVariable) else obj.subindices.get(sub)
        return None if v is None else (v.value if v.value is not None else v.default)

    def _identity_default(self, sub: int, value: Any) -> Any:
        """0x1018's value as such a device reports it: vendor files often leave 0x1018's
        defaults empty (or 0) and name the device in ``[DeviceInfo]`` (VendorNumber,
        ProductNumber, RevisionNumber); the device itself reports its real identity."""
        if value:
            return value
        info = getattr(self.od, "device_information", None)
        attr = {1: "vendor_number", 2: "product_number", 3: "revision_number"}.get(sub)
        from_info = getattr(info, attr, None) if attr and info is not None else None
        return from_info if isinstance(from_info, int) and from_info else value

    def _load_defaults(self, first: int, last: int) -> None:
        for key, var in self._vars.items():
            if first <= key[0] <= last:
                value = var.value if var.value is not None else var.default
                if key[0] == 0x1018 and key[1] in (1, 2, 3):
                    value = self._identity_default(key[1], value)
                if value is None:
                    if var.data_type in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
                        value = ""
                    elif var.data_type in dt.FLOAT_TYPES:
                        value = 0.0
                    elif var.data_type in dt.INTEGER_TYPES or var.data_type == dt.BOOLEAN:
                        value = 0
                    else:
                        value = b""
                self.values[key] = value

    def get(self, index: int, sub: int = 0) -> Any:
        """A raw value of the object dictionary (KeyError naming the object if absent)."""
        try:
            return self.values[(index, sub)]
        except KeyError:
            raise KeyError(f"{self.name}: no object 0x{index:04X}:{sub:02X}") from None

    def set(self, index: int, sub: int, value: Any) -> None:
        """Device-side write (the profile, the physics): no SDO checks, no write listeners."""
        key = (index, sub)
        if key not in self.values:
            raise KeyError(f"{self.name}: no object 0x{index:04X}:{sub:02X}")
        self.values[key] = value

    def has(self, index: int, sub: int = 0) -> bool:
        return (index, sub) in self.values

    def variable(self, index: int, sub: int = 0) -> ODVariable:
        return self._vars[(index, sub)]

    def add_write_listener(self, index: int, sub: int, fn: Callable[[Key, Any], None]) -> None:
        """fn(key, value) after a master's write (SDO or RPDO) of that object."""
        self._write_listeners.setdefault((index, sub), []).append(fn)

    def add_validator(self, index: int, sub: int, fn: Callable[[Any], int | None]) -> None:
        """fn(value) -> an SDO abort code to refuse a master's SDO write, or None."""
        self._validators.setdefault((index, sub), []).append(fn)

    def add_nmt_listener(self, fn: Callable[[NmtState, NmtState], None]) -> None:
        self._nmt_listeners.append(fn)

    def add_reset_listener(self, fn: Callable[[], None]) -> None:
        """fn() after a reset of the application (reset node, reboot): values are defaults."""
        self._reset_listeners.append(fn)

    def add_sync_listener(self, fn: Callable[[float], None]) -> None:
        """fn(now_s) on every SYNC in operational, after RPDOs, before `before_tpdo`."""
        self._sync_listeners.append(fn)

    def _master_write(self, key: Key, value: Any) -> None:
        self.values[key] = value
        for fn in self._write_listeners.get(key, ()):
            fn(key, value)

    # ---------------------------------------------------------------- NMT
    def _set_state(self, new: NmtState) -> None:
        old = self.state
        self.state = new
        self._poll_due = -math.inf
        if new != NmtState.OPERATIONAL:
            for p in self._pdos:
                p.pending = None
            self._any_pending = False
        elif old != NmtState.OPERATIONAL:
            for p in self._pdos:
                p.sync_count = 0
                p.started = False
                p.last_payload = None
        if old != new:
            for fn in self._nmt_listeners:
                fn(old, new)

    def _reset_communication(self) -> None:
        self._load_defaults(0x1000, 0x1FFF)
        self._sdo = None
        self._reconfigure()

    def _reset_application(self) -> None:
        self._load_defaults(0x0000, 0xFFFF)
        self._sdo = None
        self._reconfigure()
        for fn in self._reset_listeners:
            fn()

    def _boot(self) -> None:
        """Initialising -> boot-up frame -> pre-operational (CiA 301 7.3.2)."""
        self.state = NmtState.INITIALISING
        self.send(0x700 + self.id, b"\x00")
        period = self.values.get((0x1017, 0), 0)
        self._hb_next = self._now + period / 1000.0 if period else None
        self._set_state(NmtState.PRE_OPERATIONAL)

    def _nmt_command(self, cmd: int) -> None:
        if self.state == NmtState.INITIALISING:
            return
        if cmd == 0x01:
            self._set_state(NmtState.OPERATIONAL)
        elif cmd == 0x02:
            self._set_state(NmtState.STOPPED)
        elif cmd == 0x80:
            self._set_state(NmtState.PRE_OPERATIONAL)
        elif cmd == 0x81:
            old = self.state
            self._reset_application()
            self._reset_communication()
            self._notify_reset(old)
            self._boot()
        elif cmd == 0x82:
            old = self.state
            self._reset_communication()
            self._notify_reset(old)
            self._boot()

    def _notify_reset(self, old: NmtState) -> None:
        # the listeners see the pass through initialising, as the device's outputs do
        self.state = NmtState.INITIALISING
        if old != NmtState.INITIALISING:
            for fn in self._nmt_listeners:
                fn(old, NmtState.INITIALISING)

    # ---------------------------------------------------------------- pumping
    def poll(self, now_s: float) -> None:
        """Time-driven work: boot-up when initialising, heartbeat producer and consumers."""
        self._now = now_s
        if now_s < self._poll_due:
            return
        if self.state == NmtState.INITIALISING:
            self._boot()
        # 1 ns of slack: a schedule summed in floats (0.025 * 3 = 0.07500000000000001)
        # must not slip a whole tick of a lockstep pump
        if self._hb_next is not None and now_s >= self._hb_next - 1e-9:
            if not self._heartbeat_silent:
                self.send(0x700 + self.id, bytes((int(self.state),)))
            period = self.values[(0x1017, 0)] / 1000.0
            self._hb_next += period
            if self._hb_next <= now_s:  # fell behind (a stalled pump): no burst of frames
                self._hb_next = now_s + period
        for c in self._consumers.values():
            if (c.last_seen_s is not None and not c.timed_out
                    and now_s - c.last_seen_s > c.timeout_s):
                c.timed_out = True
                self._heartbeat_lost(c.producer_id)
        self._poll_due = self._next_poll()

    def _next_poll(self) -> float:
        """The earliest time poll() may act: the next heartbeat (with poll's 1 ns of slack)
        or a consumer's timeout; -inf while initialising (boot at the next poll)."""
        if self.state == NmtState.INITIALISING:
            return -math.inf
        due = math.inf if self._hb_next is None else self._hb_next - 1e-9
        for c in self._consumers.values():
            # (1 ns early: poll's own test, now - last_seen > timeout, decides)
            if c.last_seen_s is not None and not c.timed_out:
                due = min(due, c.last_seen_s + c.timeout_s - 1e-9)
        return due

    def addressed(self, can_id: int) -> bool:
        """Whether a frame with this COB-ID is for this node alone (its SDO server or one
        of its RPDOs): the owner may then skip the other nodes."""
        return can_id == 0x600 + self.id or can_id in self._rpdo_by_cob

    def handle(self, can_id: int, data: bytes | bytearray, now_s: float) -> None:
        """One frame from the bus."""
        self._now = now_s
        if can_id == 0:
            if len(data) >= 2 and data[1] in (0, self.id):
                self._nmt_command(data[0])
            return
        if can_id == self._sync_cob and not 0x701 <= can_id <= 0x77F:  # every tick: first
            if self.state == NmtState.OPERATIONAL:
                if len(data) > 1:
                    self.emcy(EMCY_SYNC_LENGTH)
                    return
                self._on_sync(now_s, data[0] if len(data) == 1 else None)
            return
        if self.state == NmtState.INITIALISING:
            return
        if 0x701 <= can_id <= 0x77F:
            if can_id - 0x700 == self.id:  # our own heartbeat echoed, or a guarding RTR
                return
            self._heartbeat_seen(can_id - 0x700, now_s)
            return
        if can_id == 0x600 + self.id:
            if self.state != NmtState.STOPPED:
                self._on_sdo(bytes(data))
            return
        pdo = self._rpdo_by_cob.get(can_id)
        if pdo is not None and self.state == NmtState.OPERATIONAL:
            self._on_rpdo(pdo, data)

    # ---------------------------------------------------------------- fault injection
    def reboot(self) -> None:
        """The device resets mid-run (power glitch, watchdog): defaults, boot-up frame,
        pre-operational; a silenced heartbeat comes back."""
        old = self.state
        self._heartbeat_silent = False
        self._reset_application()
        self._reset_communication()
        self._notify_reset(old)
        self._boot()

    def stop_heartbeat(self) -> None:
        """The node goes silent on its heartbeat (everything else still answers)."""
        self._heartbeat_silent = True

    def resume_heartbeat(self) -> None:
        self._heartbeat_silent = False

    def force_nmt(self, state: NmtState | int | str) -> None:
        """Puts the node in an NMT state without a command from the master."""
        if isinstance(state, str):
            try:
                state = NmtState[state.upper().replace("-", "_")]
            except KeyError:
                raise ValueError(f"force_nmt: unknown NMT state {state!r}") from None
        self._set_state(NmtState(state))

    def sdo_abort_next(self, index: int, code: int) -> None:
        """The next SDO transfer to `index` (any sub-index) is aborted with `code`."""
        self._abort_next[index] = code

    # ---------------------------------------------------------------- EMCY
    def set_error_bits(self, bits: int) -> None:
        self.values[(0x1001, 0)] = self.values.get((0x1001, 0), 0) | bits

    def clear_error_bits(self, bits: int) -> None:
        reg = self.values.get((0x1001, 0), 0) & ~bits
        if reg == ERR_GENERIC:  # no specific error left
            reg = 0
        self.values[(0x1001, 0)] = reg

    def emcy(self, error_code: int, error_register: int | None = None,
             vendor: bytes = b"") -> None:
        """Sends an EMCY (8 bytes at 0x1014's COB-ID) and keeps 0x1001 and 0x1003. With no
        register given, 0x1001 gains the code's bits (none for an error reset 0x0000)."""
        if error_register is None:
            if error_code != EMCY_RESET:
                self.set_error_bits(error_register_bits(error_code))
            error_register = self.values.get((0x1001, 0), 0)
        else:
            self.values[(0x1001, 0)] = error_register
        if error_code != EMCY_RESET and (0x1003, 1) in self.values:
            n = max(k[1] for k in self.values if k[0] == 0x1003)
            for i in range(n, 1, -1):
                self.values[(0x1003, i)] = self.values[(0x1003, i - 1)]
            self.values[(0x1003, 1)] = error_code
            self.values[(0x1003, 0)] = min(self.values[(0x1003, 0)] + 1, n)
        cob = self.values.get((0x1014, 0), 0x80 + self.id)
        if cob & 0x80000000 or self.state not in (NmtState.PRE_OPERATIONAL,
                                                   NmtState.OPERATIONAL):
            return
        self.send(cob & 0x7FF, _EMCY.pack(error_code, error_register, bytes(vendor[:5])))
        self.emcy_sent += 1

    # ---------------------------------------------------------------- heartbeat consumer
    def _heartbeat_seen(self, producer_id: int, now_s: float) -> None:
        for c in self._consumers.values():
            if c.producer_id == producer_id:
                c.last_seen_s = now_s
                self._poll_due = -math.inf
                if c.timed_out:
                    c.timed_out = False
                    if not any(x.timed_out for x in self._consumers.values()):
                        self.clear_error_bits(ERR_COMMUNICATION)
                        self.emcy(EMCY_RESET)

    def _heartbeat_lost(self, producer_id: int) -> None:
        """Consumer timeout: EMCY 0x8130, the profile's safe reaction, then 0x1029.1."""
        self.emcy(EMCY_HEARTBEAT, vendor=bytes((producer_id,)))
        for fn in self.on_comm_error:
            fn(producer_id)
        behaviour = self.values.get((0x1029, 1), 0)
        if behaviour == 0 and self.state == NmtState.OPERATIONAL:
            self._set_state(NmtState.PRE_OPERATIONAL)
        elif behaviour == 2:
            self._set_state(NmtState.STOPPED)

    # ---------------------------------------------------------------- configuration
    def _reconfigure(self) -> None:
        """Rebuilds SYNC, heartbeat consumers and PDO codecs from the communication objects."""
        self._sync_cob = self.values.get((0x1005, 0), 0x80) & 0x7FF
        consumers: dict[int, _Consumer] = {}
        for (index, sub), value in self.values.items():
            if index == 0x1016 and sub > 0:
                producer, ms = (value >> 16) & 0xFF, value & 0xFFFF
                if producer and ms:
                    old = self._consumers.get(sub)
                    keep = old is not None and old.producer_id == producer and \
                        old.timeout_s == ms / 1000.0
                    consumers[sub] = old if keep else _Consumer(producer, ms / 1000.0)
        self._consumers = consumers
        old_pdos = {(p.is_tpdo, p.number): p for p in self._pdos}
        pdos: list[_Pdo] = []
        for is_tpdo, com_base, map_base in ((False, 0x1400, 0x1600), (True, 0x1800, 0x1A00)):
            for n in range(512):
                if (com_base + n, 1) not in self.values:
                    continue
                p = old_pdos.get((is_tpdo, n + 1)) or _Pdo(n + 1, is_tpdo, com_base + n,
                                                            map_base + n)
                cob = self.values[(com_base + n, 1)]
                p.cob_id = cob & 0x7FF
                p.valid = not cob & 0x80000000
                p.trans_type = self.values.get((com_base + n, 2), 255)
                count = self.values.get((map_base + n, 0), 0)
                name = f"{'T' if is_tpdo else 'R'}PDO{n + 1} of node {self.id}"
                entries = [self.values.get((map_base + n, i)) for i in range(1, count + 1)]
                p.problem = None
                try:
                    if any(not isinstance(w, int) for w in entries):
                        raise PdoMappingError(f"{name}: {count} entries, the EDS declares "
                                              "fewer")
                    p.codec = compile_mapping(name, self.od, entries) if entries else None
                    p.keys = tuple((w >> 16, (w >> 8) & 0xFF) for w in entries)
                except PdoMappingError as exc:
                    # a default mapping this node cannot carry (over 64 bits, an object
                    # the file lacks, a dummy entry): such a PDO sends and takes nothing
                    # until the master maps it anew, as it does during set-up
                    p.codec, p.keys, p.problem = None, (), str(exc)
                pdos.append(p)
        self._pdos = pdos
        self._rpdo_by_cob = {p.cob_id: p for p in pdos
                             if not p.is_tpdo and p.valid and p.codec is not None}
        for p in pdos:
            p.payload = (_payload_function(p.codec, p.keys)
                         if p.is_tpdo and p.codec is not None else None)
        self._sync_rpdos = tuple(p for p in pdos if not p.is_tpdo)
        self._tpdos = tuple(p for p in pdos if p.is_tpdo and p.valid and p.codec is not None)
        self._any_pending = any(p.pending is not None for p in self._sync_rpdos)
        self._poll_due = -math.inf

    def _pdo_for(self, index: int) -> _Pdo | None:
        for p in self._pdos:
            if index in (p.com_index, p.map_index):
                return p
        return None

    def _check_mapping_entry(self, p: _Pdo, word: int) -> int:
        """Bits of one mapping entry; SdoAbort 0x06040041 if the object cannot be mapped."""
        key = (word >> 16, (word >> 8) & 0xFF)
        var = self._vars.get(key)
        bits = word & 0xFF
        what = f"0x{key[0]:04X}:{key[1]:02X} in {'T' if p.is_tpdo else 'R'}PDO{p.number}"
        if var is None or not var.pdo_mappable or var.data_type not in var.STRUCT_TYPES:
            raise SdoAbort(ABORT_CANNOT_MAP, f"{what}: not mappable")
        if bits != len(var):
            raise SdoAbort(ABORT_CANNOT_MAP, f"{what}: {bits} bits, the object has {len(var)}")
        if (p.is_tpdo and not var.readable) or (not p.is_tpdo and not var.writable):
            raise SdoAbort(ABORT_CANNOT_MAP, f"{what}: wrong access for this direction")
        return bits

    def _check_comm_write(self, key: Key, value: Any) -> None:
        """CiA 301's rules for writes to the communication objects (SdoAbort if refused)."""
        index, sub = key
        if index == 0x1005 and value & 0x40000000:
            raise SdoAbort(ABORT_VALUE_RANGE, "0x1005: this node cannot produce SYNC")
        if index == 0x1003 and sub == 0 and value != 0:
            raise SdoAbort(ABORT_VALUE_RANGE, "0x1003:00: only 0 (clear) may be written")
        p = self._pdo_for(index)
        if p is None:
            return
        if index == p.com_index:
            if sub == 1:
                if value & 0x20000000:
                    raise SdoAbort(ABORT_VALUE_RANGE, "PDO COB-ID: 29-bit ids not supported")
                old = self.values[key]
                if p.valid and not value & 0x80000000 and (old ^ value) & 0x1FFFFFFF:
                    raise SdoAbort(ABORT_VALUE_RANGE, "PDO COB-ID changed while valid")
            elif sub == 2:
                ok = 0 <= value <= 240 or (not p.is_tpdo and value in (254, 255))
                if not ok:
                    raise SdoAbort(ABORT_VALUE_RANGE, f"transmission type {value} unsupported")
            elif sub == 6 and value > 240:  # a SYNC counter runs 1..240
                raise SdoAbort(ABORT_VALUE_HIGH, f"SYNC start value {value}")
            return
        # mapping parameter: only while the PDO is not valid (CiA 301 7.5.2.36)
        if p.valid:
            raise SdoAbort(ABORT_DEVICE_STATE, "PDO mapping written while the PDO is valid")
        if sub == 0:
            if value > 8 or (index, value) not in self.values and value:
                raise SdoAbort(ABORT_VALUE_HIGH, f"0x{index:04X}:00 = {value}")
            total = sum(self._check_mapping_entry(p, self.values[(index, i)])
                        for i in range(1, value + 1))
            if total > MAX_PDO_BITS:
                raise SdoAbort(ABORT_PDO_LENGTH, f"{total} bits mapped")
        else:
            if self.values[(index, 0)] != 0:
                raise SdoAbort(ABORT_DEVICE_STATE, "mapping entry written with a count != 0")
            if value:
                self._check_mapping_entry(p, value)

    # ---------------------------------------------------------------- SYNC and PDOs
    def _on_sync(self, now_s: float, counter: int | None = None) -> None:
        """``counter``: the SYNC's counter byte, if it has one. A TPDO with a SYNC start
        value (0x18xx sub 6, 1..240) starts counting at the SYNC whose counter equals it
        (CiA 301: that SYNC is the first received); without a counter, or with start value
        0, it counts from the first SYNC in operational."""
        self.sync_count += 1
        if self._any_pending:
            self._any_pending = False
            for p in self._sync_rpdos:  # in PDO order, as the RPDOs' objects are written
                if p.pending is not None:
                    values, p.pending = p.pending, None
                    for key, v in zip(p.keys, values, strict=True):
                        self._master_write(key, v)
        for fn in self._sync_listeners:
            fn(now_s)
        if self.before_tpdo is not None:
            self.before_tpdo(self, now_s)
        values = self.values
        send = self.send
        for p in self._tpdos:
            if p.trans_type == 0:
                payload = p.payload(values)  # type: ignore[misc]
                if payload != p.last_payload:
                    p.last_payload = payload
                    send(p.cob_id, payload)
                continue
            if not p.started:
                start = values.get((p.com_index, 6), 0)
                if start and counter is not None and counter != start:
                    continue
                p.started, p.sync_count = True, 0
            p.sync_count += 1
            if p.sync_count >= p.trans_type:
                p.sync_count = 0
                send(p.cob_id, p.payload(values))  # type: ignore[misc]

    def _on_rpdo(self, p: _Pdo, data: bytes | bytearray) -> None:
        assert p.codec is not None
        try:
            decoded = p.codec.decode(data)
        except FrameError:
            # CiA 301: a PDO of the wrong length is not processed, and an EMCY says so
            self.emcy(EMCY_PDO_LENGTH if len(data) < p.codec.length
                      else EMCY_PDO_LENGTH_EXCEEDED)
            return
        if p.trans_type <= 240:
            p.pending = decoded
            self._any_pending = True
        else:
            for key, v in zip(p.keys, decoded, strict=True):
                self._master_write(key, v)

    def tpdo_codec(self, number: int) -> PdoCodec | None:
        for p in self._pdos:
            if p.is_tpdo and p.number == number:
                return p.codec
        return None

    # ---------------------------------------------------------------- SDO server
    def _sdo_send(self, data: bytes | bytearray) -> None:
        self.send(0x580 + self.id, bytes(data).ljust(8, b"\x00"))

    def _sdo_abort(self, index: int, sub: int, code: int) -> None:
        self._sdo = None
        self._sdo_send(struct.pack("<BHBI", 0x80, index, sub, code))

    def _lookup(self, index: int, sub: int) -> ODVariable:
        obj = self.od.indices.get(index)
        if obj is None:
            raise SdoAbort(ABORT_NO_OBJECT)
        if isinstance(obj, ODVariable):
            if sub != 0:
                raise SdoAbort(ABORT_NO_SUBINDEX)
            return obj
        var = obj.subindices.get(sub)
        if var is None:
            raise SdoAbort(ABORT_NO_SUBINDEX)
        return var

    def _encode_value(self, var: ODVariable, value: Any) -> bytes:
        if var.data_type in var.STRUCT_TYPES:
            return var.STRUCT_TYPES[var.data_type].pack(value)
        if var.data_type == dt.VISIBLE_STRING:
            return str(value).encode("ascii", errors="replace")
        if var.data_type == dt.UNICODE_STRING:
            return str(value).encode("utf_16_le")
        return bytes(value)

    def _write_from_sdo(self, var: ODVariable, data: bytes) -> None:
        key = (var.index, var.subindex)
        if var.data_type in var.STRUCT_TYPES:
            size = var.STRUCT_TYPES[var.data_type].size
            if len(data) != size:
                raise SdoAbort(ABORT_LENGTH, f"{len(data)} bytes for a {size}-byte object")
            value: Any = var.STRUCT_TYPES[var.data_type].unpack(data)[0]
            if var.min is not None and value < var.min:
                raise SdoAbort(ABORT_VALUE_LOW)
            if var.max is not None and value > var.max:
                raise SdoAbort(ABORT_VALUE_HIGH)
        elif var.data_type in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
            if len(data) > MAX_STRING_BYTES:
                raise SdoAbort(ABORT_LENGTH_HIGH)
            value = var.decode_raw(data)
        else:
            value = bytes(data)
        for check in self._validators.get(key, ()):
            code = check(value)
            if code:
                raise SdoAbort(code)
        comm = 0x1000 <= key[0] <= 0x1FFF
        if comm:
            self._check_comm_write(key, value)
        self._master_write(key, value)
        if comm:
            self._reconfigure()
            if key == (0x1017, 0):
                self._hb_next = self._now + value / 1000.0 if value else None
            elif key == (0x1003, 0):  # writing 0 deletes the error history (CiA 301)
                for k in self.values:
                    if k[0] == 0x1003:
                        self.values[k] = 0

    def _on_sdo(self, data: bytes) -> None:
        data = data.ljust(8, b"\x00")
        cmd = data[0]
        ccs = cmd >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        if ccs == 4:  # abort from the client
            self._sdo = None
            return
        try:
            if ccs in (1, 2):
                self._sdo = None
                code = self._abort_next.pop(index, None)
                if code is not None:
                    raise SdoAbort(code, "injected")
                var = self._lookup(index, sub)
                if ccs == 2:
                    self._initiate_upload(var)
                else:
                    self._initiate_download(var, cmd, data)
            elif ccs == 0:
                self._download_segment(cmd, data)
            elif ccs == 3:
                self._upload_segment(cmd)
            else:  # block transfers (5, 6) and the unknown command 7
                if ccs in (5, 6) and index in self._abort_next:
                    raise SdoAbort(self._abort_next.pop(index), "injected")
                raise SdoAbort(ABORT_COMMAND)
        except SdoAbort as exc:
            if self._sdo is not None and ccs in (0, 3):
                index, sub = self._sdo.key
            self._sdo_abort(index, sub, exc.code)

    def _initiate_upload(self, var: ODVariable) -> None:
        if not var.readable:
            raise SdoAbort(ABORT_READ_WRITE_ONLY)
        key = (var.index, var.subindex)
        payload = self._encode_value(var, self.values[key])
        head = struct.pack("<HB", var.index, var.subindex)
        if 0 < len(payload) <= 4:
            cmd = 0x43 | ((4 - len(payload)) << 2)
            self._sdo_send(bytes((cmd,)) + head + payload)
            return
        self._sdo = _SdoTransfer(True, key, var, buffer=bytearray(payload), size=len(payload))
        self._sdo_send(bytes((0x41,)) + head + struct.pack("<I", len(payload)))

    def _upload_segment(self, cmd: int) -> None:
        t = self._sdo
        if t is None or not t.upload:
            raise SdoAbort(ABORT_COMMAND)
        toggle = cmd & 0x10
        if toggle != t.toggle:
            raise SdoAbort(ABORT_TOGGLE)
        chunk = bytes(t.buffer[t.pos:t.pos + 7])
        t.pos += len(chunk)
        last = t.pos >= len(t.buffer)
        self._sdo_send(bytes((toggle | ((7 - len(chunk)) << 1) | int(last),)) + chunk)
        t.toggle ^= 0x10
        if last:
            self._sdo = None

    def _initiate_download(self, var: ODVariable, cmd: int, data: bytes) -> None:
        if not var.writable:
            raise SdoAbort(ABORT_WRITE_READ_ONLY)
        head = struct.pack("<HB", var.index, var.subindex)
        if cmd & 0x02:  # expedited
            n = (cmd >> 2) & 0x3 if cmd & 0x01 else 0
            payload = data[4:8 - n]
            if not cmd & 0x01 and var.data_type in var.STRUCT_TYPES:
                # size not indicated: the object's own size
                payload = payload[:var.STRUCT_TYPES[var.data_type].size]
            self._write_from_sdo(var, payload)
            self._sdo_send(bytes((0x60,)) + head)
            return
        size = struct.unpack_from("<I", data, 4)[0] if cmd & 0x01 else None
        if size is not None and var.data_type in var.STRUCT_TYPES and \
                size != var.STRUCT_TYPES[var.data_type].size:
            raise SdoAbort(ABORT_LENGTH)
        if size is not None and size > MAX_STRING_BYTES:
            raise SdoAbort(ABORT_LENGTH_HIGH)
        self._sdo = _SdoTransfer(False, (var.index, var.subindex), var, size=size)
        self._sdo_send(bytes((0x60,)) + head)

    def _download_segment(self, cmd: int, data: bytes) -> None:
        t = self._sdo
        if t is None or t.upload:
            raise SdoAbort(ABORT_COMMAND)
        toggle = cmd & 0x10
        if toggle != t.toggle:
            raise SdoAbort(ABORT_TOGGLE)
        n = (cmd >> 1) & 0x7
        t.buffer += data[1:8 - n]
        if len(t.buffer) > MAX_STRING_BYTES:
            raise SdoAbort(ABORT_LENGTH_HIGH)
        if cmd & 0x01:  # last segment: the write happens (or aborts) now
            if t.size is not None and len(t.buffer) != t.size:
                raise SdoAbort(ABORT_LENGTH)
            self._write_from_sdo(t.var, bytes(t.buffer))
            self._sdo = None
        else:
            t.toggle ^= 0x10
        self._sdo_send(bytes((0x20 | toggle,)))
