"""CANopen devices (CiA 301 with the CiA 401/402/406 profiles), bound by the rig file.

A rig file binds a device to a node and names, per quantity, the object (and sub-index)
that carries it and its conversion to SI; the objects are checked against the node's EDS.
The harness decides the PDO mapping from those objects (packed into at most four TPDOs and
four RPDOs per node, 64 bits each, synchronous transmission type = the device's SYNC
divider) and writes it during set-up (``drivers.binding.canopen_master``); in the tick it
encodes and decodes PDOs with the codecs compiled here, never through the library's
threads. Frame and object names live in the rig file and the EDS, not here; what is here
is CiA 301 itself (COB-IDs, the SYNC counter, NMT, EMCY meanings).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, cast

from drivers.binding.frames import BindingError, linear_conversion
from drivers.binding.quantities import COMMANDS, REQUIRED_COMMANDS, REQUIRED_TELEMETRY, TELEMETRY

PROFILES = ("cia401", "cia402", "cia406")
SYNC_COB_ID = 0x080
SYNC_COUNTER_OVERFLOW = 240  # 0x1019: the SYNC carries a counter 1..240
NMT_COB_ID = 0x000
EMCY_BASE = 0x080
EMCY_HEARTBEAT_ERROR = 0x8130  # CiA 301: life guard or heartbeat consumer time-out
TPDO_BASE = (0x180, 0x280, 0x380, 0x480)
RPDO_BASE = (0x200, 0x300, 0x400, 0x500)
SDO_TX_BASE, SDO_RX_BASE = 0x580, 0x600
HEARTBEAT_BASE = 0x700
NMT_STATES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}

# CiA 301 emergency error codes (the high byte's class, and the codes the profiles use)
EMCY_CLASSES = {
    0x00: "error reset or no error", 0x10: "generic error", 0x20: "current",
    0x21: "current, device input side", 0x22: "current inside the device",
    0x23: "current, device output side", 0x30: "voltage", 0x31: "mains voltage",
    0x32: "voltage inside the device", 0x33: "output voltage", 0x40: "temperature",
    0x41: "ambient temperature", 0x42: "device temperature", 0x50: "device hardware",
    0x60: "device software", 0x61: "internal software", 0x62: "user software",
    0x63: "data set", 0x70: "additional modules", 0x80: "monitoring",
    0x81: "communication", 0x82: "protocol error", 0x90: "external error",
    0xF0: "additional functions", 0xFF: "device specific",
}
EMCY_CODES = {
    0x2310: "continuous over-current (CiA 402)", 0x3210: "DC link over-voltage (CiA 402)",
    0x4310: "drive temperature (CiA 402)", 0x5530: "EEPROM/flash error",
    0x7500: "communication (CiA 402)", 0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode", 0x8130: "life guard error or heartbeat error",
    0x8140: "recovered from bus off", 0x8150: "CAN-ID collision",
    0x8210: "PDO not processed due to length error", 0x8220: "PDO length exceeded",
    0x8240: "unexpected SYNC data length", 0x8250: "RPDO time-out",
    0x8611: "following error (CiA 402)", 0xFF00: "device specific",
}
ERROR_REGISTER_BITS = ("generic", "current", "voltage", "temperature", "communication",
                       "device profile specific", "reserved", "manufacturer specific")


CIA402_STATES = (  # (mask, value, name) of the statusword, CiA 402's state table
    (0x4F, 0x00, "not ready to switch on"), (0x4F, 0x40, "switch on disabled"),
    (0x6F, 0x21, "ready to switch on"), (0x6F, 0x23, "switched on"),
    (0x6F, 0x27, "operation enabled"), (0x6F, 0x07, "quick stop active"),
    (0x4F, 0x0F, "fault reaction active"), (0x4F, 0x08, "fault"),
)


def cia402_state(statusword: int) -> str:
    """The CiA 402 drive state a statusword reports, by name."""
    for mask, value, name in CIA402_STATES:
        if statusword & mask == value:
            return name
    return "an undefined state"


def emcy_meaning(code: int, register: int) -> str:
    """An EMCY's error code and error register in words (CiA 301 / the profiles)."""
    text = EMCY_CODES.get(code) or EMCY_CLASSES.get(code >> 8) or EMCY_CLASSES.get(
        (code >> 8) & 0xF0, "unknown class")
    bits = [n for i, n in enumerate(ERROR_REGISTER_BITS) if register >> i & 1]
    return (f"error code 0x{code:04X} ({text}), error register 0x{register:02X}"
            f"{' (' + ', '.join(bits) + ')' if bits else ''}")


# ----------------------------------------------------------------------------- EDS
_TYPES = {  # CiA 301 data type -> (bits, signed, struct code)
    0x1: (8, False, "B"), 0x2: (8, True, "b"), 0x3: (16, True, "h"), 0x4: (32, True, "i"),
    0x5: (8, False, "B"), 0x6: (16, False, "H"), 0x7: (32, False, "I"), 0x8: (32, True, "f"),
    0x15: (64, True, "q"), 0x1B: (64, False, "Q"), 0x11: (64, True, "d"),
}


@cache
def load_eds(path: str, node_id: int) -> Any:
    """The node's object dictionary (the ``canopen`` library's EDS/DCF parser)."""
    return parse_od(path, node_id, BindingError)


_SECTION = re.compile(r"^\s*\[([^\]]*)\]", re.M)
_EMPTY_KEY = re.compile(r"^[ \t]*[A-Za-z_0-9]+[ \t]*=[ \t]*\r?$\n?", re.M)


def _without_empty_device_info(text: str) -> str:
    """The file as the ``canopen`` library's parser can take it, its meaning unchanged: the
    ``[DeviceInfo]`` keys with no value left out (CiA 306 makes most of them optional,
    editors write them empty, ``VendorNumber=``, and the parser fails on an empty number),
    and the ``[Comments]`` section left out (free text whose ``Lines=`` count editors get
    wrong, which the parser checks)."""
    out = []
    pos = 0
    for m in _SECTION.finditer(text):
        name = m.group(1).strip().lower()
        if name not in ("deviceinfo", "comments"):
            continue
        nxt = _SECTION.search(text, m.end())
        end = nxt.start() if nxt else len(text)
        out.append(text[pos:m.start()])
        if name == "deviceinfo":
            out.append(text[m.start():m.end()] + _EMPTY_KEY.sub("", text[m.end():end]))
        pos = end
    out.append(text[pos:])
    return "".join(out)


def parse_od(path: str | Path, node_id: int, error: type[Exception]) -> Any:
    """``canopen.import_od`` of a bounded read of the file (``drivers.device_file``): a
    special file, an oversized one or one the parser chokes on is ``error`` naming the file,
    never a traceback or a hang."""
    import io

    import canopen

    from drivers.device_file import DeviceFileError, read_text

    name = Path(path).name
    try:
        text = read_text(path)
    except DeviceFileError as exc:
        raise error(str(exc)) from None
    source = io.StringIO(_without_empty_device_info(text))
    source.name = str(path)  # the parser tells an EDS from a DCF by the name
    try:
        return canopen.import_od(source, node_id)
    except RecursionError:
        raise error(f"{name}: not a loadable EDS/DCF file (nested too deeply)") from None
    except Exception as exc:  # the parser raises many kinds for a bad file
        text = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise error(f"{name}: not a loadable EDS/DCF file ({text})") from None


@dataclass(frozen=True)
class ObjRef:
    index: int
    sub: int
    bits: int
    signed: bool
    code: str  # struct format character
    name: str
    data_type: int = 0  # CiA 301 data type

    @property
    def label(self) -> str:
        return f"0x{self.index:04X}.{self.sub}"

    @property
    def mapping_entry(self) -> int:
        """The 32-bit PDO mapping entry (index << 16 | sub << 8 | bits)."""
        return self.index << 16 | self.sub << 8 | self.bits


def object_ref(od: Any, index: Any, sub: Any, key: str, eds: str) -> ObjRef:
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index <= 0xFFFF:
        raise BindingError(f"{key}.object: expected an object index such as 0x6071, got "
                           f"{index!r}")
    if isinstance(sub, bool) or not isinstance(sub, int) or not 0 <= sub <= 0xFF:
        raise BindingError(f"{key}.sub: expected a sub-index 0..255, got {sub!r}")
    if index not in od:
        raise BindingError(f"{key}.object: 0x{index:04X} is not in {Path(eds).name}")
    obj = od[index]
    try:
        var = obj[sub] if hasattr(obj, "subindices") or not hasattr(obj, "data_type") else obj
        if hasattr(obj, "data_type") and sub != 0:
            raise KeyError(sub)
    except (KeyError, IndexError):
        raise BindingError(f"{key}.sub: 0x{index:04X} has no sub-index {sub} in "
                           f"{Path(eds).name}") from None
    t = _TYPES.get(var.data_type)
    if t is None:
        raise BindingError(f"{key}.object: 0x{index:04X}.{sub} has data type "
                           f"0x{var.data_type:X}, which a PDO codec here cannot carry")
    if getattr(var, "pdo_mappable", True) is False:
        raise BindingError(f"{key}.object: 0x{index:04X}.{sub} ({var.name}) is not PDO "
                           f"mappable in {Path(eds).name}")
    return ObjRef(index, sub, t[0], t[1], t[2], var.name, var.data_type)


# ----------------------------------------------------------------------------- codecs
class PdoCodec:
    """One PDO of the binding: its COB-ID, mapped objects and labels; the payload is packed
    by ``drivers.canopen_pdo.PdoCodec``, the codec the virtual nodes use too."""

    __slots__ = ("name", "frame_id", "is_extended", "length", "entries", "_codec",
                 "signal_names", "signals", "decode_raw", "encode_raw")

    def __init__(self, name: str, cob_id: int, entries: tuple[ObjRef, ...]) -> None:
        bits = sum(e.bits for e in entries)
        if bits > 64:
            raise BindingError(f"{name}: mapping of {bits} bits (a PDO carries 64 at most)")
        from drivers.canopen_pdo import PdoCodec as Packer

        self.name = name
        self.frame_id = cob_id
        self.is_extended = False
        self.entries = entries
        self._codec = Packer(f"{name} (0x{cob_id:03X})",
                             [(e.index, e.sub, e.bits, e.data_type) for e in entries])
        self.length = self._codec.length
        self.signal_names = tuple(e.label for e in entries)
        self.signals = ()
        # the hot path calls the packer's own methods (one attribute lookup, no wrapper)
        self.decode_raw = self._codec.decode
        self.encode_raw = self._codec.encode

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        """By object label ("0x6077.0"), raw values (review, replay)."""
        return dict(zip(self.signal_names, self.decode_raw(data), strict=True))


@dataclass(frozen=True)
class Conversion:
    """Raw object value <-> one quantity. Linear (SI = raw * scale + offset, from the rig
    file's scale/offset or sensitivity/offset: ``frames.linear_conversion``), one bit of
    it, a masked comparison (a status word's state), or a table (a control word)."""

    scale: float = 1.0
    offset: float = 0.0
    bit: int | None = None
    mask: int | None = None
    equals: int | None = None
    values: tuple[tuple[int, int], ...] | None = None  # command: quantity value -> raw

    def to_si(self, raw: Any) -> float:
        if self.bit is not None:
            return float(int(raw) >> self.bit & 1)
        if self.mask is not None:
            return float((int(raw) & self.mask) == self.equals)
        if self.values is not None:
            for q, r in self.values:
                if r == raw:
                    return float(q)
            return 0.0
        return raw * self.scale + self.offset

    def si_function(self) -> Any:
        """``to_si`` as one small function with its constants bound: the tick decodes every
        PDO field through it."""
        if self.bit is not None:
            b = self.bit
            return lambda raw: float(int(raw) >> b & 1)
        if self.mask is not None:
            m, e = self.mask, self.equals
            return lambda raw: float((int(raw) & m) == e)
        if self.values is not None:
            return self.to_si
        a, o = self.scale, self.offset
        if o == 0.0:
            return lambda raw: raw * a
        return lambda raw: raw * a + o

    def raw_expression(self, x: str, ref: ObjRef, r: str) -> str | None:
        """``to_raw(x, ref)`` as Python source over the expression ``x`` (``r``: a free name
        for the rounded value), for writers compiled once (the virtual rig's telemetry into
        its nodes' objects, every tick); None for a table (call ``to_raw``)."""
        if self.values is not None:
            return None
        if self.bit is not None:
            return f"((int({x}) & 1) << {self.bit!r})"
        if ref.code in "fd":
            return f"float(({x} - {self.offset!r}) / {self.scale!r})"
        lo, hi = ((-(1 << ref.bits - 1), (1 << ref.bits - 1) - 1) if ref.signed
                  else (0, (1 << ref.bits) - 1))
        return (f"({lo!r} if ({r} := round(({x} - {self.offset!r}) / {self.scale!r})) < {lo!r}"
                f" else {hi!r} if {r} > {hi!r} else {r})")

    def si_expression(self, x: str) -> str | None:
        """``si_function()(x)`` as Python source over the expression ``x`` (the harness's
        PDO decoders, compiled once); None for a table (call the function)."""
        if self.bit is not None:
            return f"float(int({x}) >> {self.bit!r} & 1)"
        if self.mask is not None:
            return f"float((int({x}) & {self.mask!r}) == {self.equals!r})"
        if self.values is not None:
            return None
        if self.offset == 0.0:
            return f"{x} * {self.scale!r}"
        return f"{x} * {self.scale!r} + {self.offset!r}"

    def to_raw(self, si: float, ref: ObjRef) -> Any:
        if self.values is not None:
            key = int(si)
            for q, r in self.values:
                if q == key:
                    return r
            return self.values[0][1]
        if self.bit is not None:
            return (int(si) & 1) << self.bit
        if ref.code in "fd":
            return float((si - self.offset) / self.scale)
        raw = round((si - self.offset) / self.scale)
        lo, hi = ((-(1 << ref.bits - 1), (1 << ref.bits - 1) - 1) if ref.signed
                  else (0, (1 << ref.bits) - 1))
        return lo if raw < lo else hi if raw > hi else raw


@dataclass(frozen=True)
class QuantityRef:
    quantity: str
    ref: ObjRef
    conv: Conversion


class PdoTelemetryMap:
    """The quantities one device takes from one TPDO (a TPDO may serve several devices)."""

    __slots__ = ("device", "codec", "key", "fields", "mux", "identity", "_f", "decode")

    def __init__(self, device: str, codec: PdoCodec, fields: tuple[QuantityRef, ...]) -> None:
        self.device = device
        self.codec = codec
        self.key = (codec.frame_id, False)
        self.fields = fields
        self.mux = None
        self.identity = False
        pos = {e: i for i, e in enumerate(codec.entries)}
        self._f = tuple((f.quantity, pos[f.ref], f.conv.si_function()) for f in fields)
        #: payload -> {quantity: SI value}; FrameError on a wrong length. One compiled
        #: function (every TPDO of every tick), equal to
        #: ``{q: conv(raw[i]) for q, i, conv in _f}`` over ``codec.decode_raw(data)``
        self.decode: Callable[[bytes | bytearray], dict[str, float] | None] = \
            self._compile_decode()

    def _compile_decode(self) -> Callable[[bytes | bytearray], dict[str, float] | None]:
        namespace: dict[str, Any] = {"_raw": self.codec.decode_raw}
        items = []
        for n, (f, (q, i, conv)) in enumerate(zip(self.fields, self._f, strict=True)):
            expr = f.conv.si_expression(f"raw[{i}]")
            if expr is None:
                namespace[f"_c{n}"] = conv
                expr = f"_c{n}(raw[{i}])"
            items.append(f"{q!r}: {expr}")
        source = f"def decode(data):\n    raw = _raw(data)\n    return {{{', '.join(items)}}}\n"
        exec(compile(source, f"<{self.device} from {self.codec.name}>", "exec"), namespace)  # noqa: S102
        return cast(Callable[[bytes | bytearray], dict[str, float] | None],
                    namespace["decode"])


class PdoCommandMap:
    """One device's RPDO: its command quantities packed into the mapped objects (the harness
    never shares an RPDO between devices, so a frame always carries one device's whole
    command)."""

    __slots__ = ("device", "codec", "key", "fields", "counter", "mux", "_f", "_n")

    def __init__(self, device: str, codec: PdoCodec, fields: tuple[QuantityRef, ...]) -> None:
        self.device = device
        self.codec = codec
        self.key = (codec.frame_id, False)
        self.fields = fields
        self.counter = None
        self.mux = None
        pos = {e: i for i, e in enumerate(codec.entries)}
        self._n = len(codec.entries)
        self._f = tuple((f.quantity, pos[f.ref], f.ref, f.conv) for f in fields)

    def encoder(self, quantities: tuple[str, ...]) -> Callable[..., bytes]:
        """A positional encoder: ``encoder(quantities)(v0, v1, ..., counter)`` is
        ``encode(dict(zip(quantities, (v0, v1, ...))), counter)`` (as ``CommandMap``'s)."""
        # compiled once into one function (every tick): each mapped object's raw
        # value as an expression, a bit-packed object OR-ed together, as encode() does
        arg = {q: f"p{k}" for k, q in enumerate(quantities)}  # a repeated name: the last
        namespace: dict[str, Any] = {"_encode_raw": self.codec.encode_raw}
        slots: list[list[str]] = [[] for _ in range(self._n)]
        for n, (q, i, ref, conv) in enumerate(self._f):
            x = arg.get(q, "0.0")
            expr = conv.raw_expression(x, ref, f"r{n}")
            if expr is None:
                namespace[f"_c{n}"], namespace[f"_ref{n}"] = conv, ref
                expr = f"_c{n}.to_raw({x}, _ref{n})"
            if conv.bit is not None:
                slots[i].append(expr)
            else:
                slots[i] = [expr]  # a later plain field replaces what was there
        raws = ", ".join(" | ".join(e) if e else "0" for e in slots)
        params = "".join(f"p{k}, " for k in range(len(quantities))) + "*_"
        source = f"def encode({params}):\n    return _encode_raw([{raws}])\n"
        exec(compile(source, f"<{self.device} into {self.codec.name}>", "exec"), namespace)  # noqa: S102
        return cast(Callable[..., bytes], namespace["encode"])

    def encode(self, quantities: dict[str, float], counter: int = 0) -> bytes:
        raw: list[Any] = [0] * self._n
        for q, i, ref, conv in self._f:
            v = conv.to_raw(quantities.get(q, 0.0), ref)
            raw[i] = raw[i] | v if conv.bit is not None else v
        return self.codec.encode_raw(raw)

    def decode(self, data: bytes | bytearray) -> dict[str, float] | None:
        raw = self.codec.decode_raw(data)
        return {q: conv.to_si(raw[i]) for q, i, _, conv in self._f}


# ----------------------------------------------------------------------------- SYNC, NMT
class CanopenSync:
    """CiA 301 SYNC with a counter (0x1019 = 240): tick n sends n mod 240 + 1."""

    key = (SYNC_COB_ID, False)
    modulus = SYNC_COUNTER_OVERFLOW

    class _Codec:
        name = "SYNC"
        frame_id = SYNC_COB_ID
        is_extended = False
        length = 1
        signal_names = ("counter",)
        signals = ()

        def decode(self, data: bytes | bytearray) -> dict[str, float]:
            return {"counter": float(data[0]) if data else 0.0}

    codec = _Codec()

    def encode(self, tick: int) -> bytes:
        return bytes((tick % SYNC_COUNTER_OVERFLOW + 1,))

    def decode(self, data: bytes | bytearray) -> int:
        """The tick modulo 240 (a SYNC without a counter counts as the next tick: -1)."""
        return data[0] - 1 if data else -1


class CanopenHeartbeat:
    """The harness's own heartbeat as a CANopen node (its consumers' 0x1016 entry): state
    operational. ``armed`` is not a CANopen notion: the drives' state machine and the
    outputs' values are what the harness arms and disarms."""

    def __init__(self, master_id: int) -> None:
        self.key = (HEARTBEAT_BASE + master_id, False)
        self.master_id = master_id

        class _Codec:
            name = f"HEARTBEAT master {master_id}"
            frame_id = HEARTBEAT_BASE + master_id
            is_extended = False
            length = 1
            signal_names = ("state",)
            signals = ()

            def decode(self, data: bytes | bytearray) -> dict[str, float]:
                return {"state": float(data[0]) if data else 0.0}

        self.codec = _Codec()

    def encode(self, counter: int, armed: bool) -> bytes:
        return b"\x05"

    def decode_armed(self, data: bytes | bytearray) -> bool:
        return bool(data) and data[0] == 0x05


# ----------------------------------------------------------------------------- nodes
@dataclass
class PdoSpec:
    number: int  # 1..4
    cob_id: int
    trans_type: int  # 1..240: every n-th SYNC
    codec: PdoCodec


@dataclass
class NodeSpec:
    """One CANopen node of the rig, as the rig file binds it."""

    node_id: int
    eds: str
    profile: str
    devices: list[str]
    od: Any
    mode_of_operation: int | None = None
    identity: dict[str, int] = field(default_factory=dict)
    # where each expected identity value comes from (the rig file's key or the file's)
    identity_source: dict[str, str] = field(default_factory=dict)
    device_type: int | None = None
    parameters: list[tuple[ObjRef, int]] = field(default_factory=list)
    heartbeat_ms: int = 50
    # False: the rig file says the node cannot consume the harness's heartbeat (0x1016 is
    # not written); what replaces it for safety is the lab's (docs/lab.md)
    heartbeat_consumer: bool = True
    verify: bool = False  # a DCF: its PDO mapping is verified on the device, not written
    tpdos: list[PdoSpec] = field(default_factory=list)
    rpdos: list[PdoSpec] = field(default_factory=list)
    # device -> its quantities on this node (both directions), for the virtual rig
    telemetry: dict[str, tuple[QuantityRef, ...]] = field(default_factory=dict)
    commands: dict[str, tuple[QuantityRef, ...]] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"node {self.node_id} ({', '.join(self.devices)})"


@dataclass
class CanopenBus:
    """Every CANopen node of a rig, and the master's own settings."""

    master_id: int
    nodes: dict[int, NodeSpec]
    consumer_timeout_ms: int = 200  # the harness's heartbeat, as each node consumes it
    node_of: dict[str, int] = field(default_factory=dict)  # device -> node id

    def device_of_node(self, node_id: int) -> str:
        n = self.nodes.get(node_id)
        return "/".join(n.devices) if n is not None else f"node {node_id}"


_DEVICE_KEYS = {"binding", "node_id", "eds", "profile", "mode_of_operation", "identity",
                "device_type", "parameters", "telemetry", "commands", "heartbeat_ms",
                "heartbeat_consumer"}
# CiA 402 modes of operation (0x6060) and their bit in the supported drive modes (0x6502)
MODE_NAMES = {1: "profile position", 2: "velocity", 3: "profile velocity",
              4: "profile torque", 6: "homing", 7: "interpolated position",
              8: "cyclic synchronous position", 9: "cyclic synchronous velocity",
              10: "cyclic synchronous torque"}
MODE_BITS = {1: 0, 2: 1, 3: 2, 4: 3, 6: 5, 7: 6, 8: 7, 9: 8, 10: 9}
_QTY_KEYS = {"object", "sub", "scale", "offset", "sensitivity", "bit", "mask", "equals",
             "values"}


def _int(value: Any, key: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise BindingError(f"{key}: expected an integer {lo}..{hi}, got {value!r}")
    return value


def _quantity(q: str, spec: Any, key: str, od: Any, eds: str, command: bool) -> QuantityRef:
    if not isinstance(spec, Mapping):
        raise BindingError(f"{key}: expected a mapping with object (and sub, scale, ...), got "
                           f"{spec!r}")
    unknown = sorted(set(spec) - _QTY_KEYS, key=str)
    if unknown:
        raise BindingError(f"{key}.{unknown[0]}: unknown key (expected one of: "
                           f"{', '.join(sorted(_QTY_KEYS))})")
    ref = object_ref(od, spec.get("object"), spec.get("sub", 0), key, eds)
    kinds = [k for k in ("bit", "mask", "values") if k in spec]
    if len(kinds) > 1 or (kinds and ({"scale", "offset", "sensitivity"} & set(spec))):
        raise BindingError(f"{key}: give one conversion: scale/offset (or sensitivity), bit, "
                           "mask with equals, or values")
    if "bit" in spec:
        return QuantityRef(q, ref, Conversion(bit=_int(spec["bit"], f"{key}.bit", 0,
                                                       ref.bits - 1)))
    if "mask" in spec:
        if command:
            raise BindingError(f"{key}.mask: a command is written whole: use values")
        return QuantityRef(q, ref, Conversion(
            mask=_int(spec["mask"], f"{key}.mask", 0, 2**ref.bits - 1),
            equals=_int(spec.get("equals"), f"{key}.equals", 0, 2**ref.bits - 1)))
    if "values" in spec:
        vals = spec["values"]
        if not isinstance(vals, Mapping) or not vals:
            raise BindingError(f"{key}.values: expected a mapping quantity value -> raw value")
        pairs = tuple((_int(k, f"{key}.values", -2**31, 2**31), _int(
            v, f"{key}.values.{k}", -(2**63), 2**64 - 1)) for k, v in vals.items())
        return QuantityRef(q, ref, Conversion(values=pairs))
    scale, offset = linear_conversion(spec, key, "raw count")
    return QuantityRef(q, ref, Conversion(scale=scale, offset=offset))


def _pack(name: str, refs: list[ObjRef], base: tuple[int, ...], node_id: int, trans: int,
          key: str, first: int = 1) -> list[PdoSpec]:
    """Objects into PDOs of at most 64 bits, in order, numbered from ``first`` (of four)."""
    pdos: list[list[ObjRef]] = []
    for r in refs:
        if pdos and sum(e.bits for e in pdos[-1]) + r.bits <= 64:
            pdos[-1].append(r)
        else:
            pdos.append([r])
    if first - 1 + len(pdos) > len(base):
        raise BindingError(f"{key}: its objects need {len(pdos)} more {name}s of 64 bits; the "
                           f"node has {len(base) - first + 1} left of {len(base)}")
    out = []
    for i, p in enumerate(pdos):
        n = first + i
        cob = base[n - 1] + node_id
        out.append(PdoSpec(n, cob, trans, PdoCodec(f"{name}{n} node {node_id}", cob, tuple(p))))
    return out


def build_canopen(devices: Mapping[str, Mapping[str, Any]], dividers: Mapping[str, int],
                  master_id: int, base_dir: Path | None, consumer_ms: int = 200
                  ) -> tuple[CanopenBus, dict[str, tuple[Any, ...]], dict[str, tuple[Any, ...]],
                             dict[str, str]]:
    """The CANopen part of a binding: (the nodes, device -> telemetry maps, device ->
    command maps, device -> EDS path). Raises BindingError naming the key."""
    from drivers.binding import resolve_file

    nodes: dict[int, NodeSpec] = {}
    files: dict[str, str] = {}
    node_of: dict[str, int] = {}
    for device, cfg in devices.items():
        key = f"devices.{device}"
        unknown = sorted(set(cfg) - _DEVICE_KEYS, key=str)
        if unknown:
            raise BindingError(f"{key}.{unknown[0]}: unknown key (expected one of: "
                               f"{', '.join(sorted(_DEVICE_KEYS))})")
        node_id = _int(cfg.get("node_id"), f"{key}.node_id", 1, 127)
        if node_id == master_id:
            raise BindingError(f"{key}.node_id: {node_id} is the harness's own node id "
                               "(bus.master_node_id)")
        eds = str(resolve_file(cfg.get("eds"), f"{key}.eds", base_dir, "eds"))
        profile = cfg.get("profile")
        if profile not in PROFILES:
            raise BindingError(f"{key}.profile: expected one of {', '.join(PROFILES)}, got "
                               f"{profile!r}")
        try:
            od = load_eds(eds, node_id)
        except BindingError as exc:
            raise BindingError(f"{key}.eds: {exc}") from None
        node = nodes.get(node_id)
        if node is None:
            node = nodes[node_id] = NodeSpec(node_id, eds, profile, [], od,
                                             verify=eds.lower().endswith(".dcf"))
        elif node.eds != eds or node.profile != profile:
            raise BindingError(f"{key}.node_id: node {node_id} is also the "
                               f"{'/'.join(node.devices)} with another EDS or profile (a node "
                               "id twice)")
        node.devices.append(device)
        node_of[device] = node_id
        files[device] = eds
        if "mode_of_operation" in cfg:
            if profile != "cia402":
                raise BindingError(f"{key}.mode_of_operation: only a CiA 402 drive has one")
            node.mode_of_operation = _int(cfg["mode_of_operation"], f"{key}.mode_of_operation",
                                          -128, 127)
        elif profile == "cia402":
            raise BindingError(f"{key}.mode_of_operation: missing (10 cyclic synchronous "
                               "torque, 9 velocity, 8 position)")
        if node.mode_of_operation is not None:
            supported = _od_value(od, 0x6502, 0)
            bit = MODE_BITS.get(node.mode_of_operation)
            if supported is not None and bit is not None and not supported >> bit & 1:
                have = [f"{m} {MODE_NAMES[m]}" for m, b in MODE_BITS.items()
                        if supported >> b & 1]
                raise BindingError(
                    f"{key}.mode_of_operation: {node.mode_of_operation} "
                    f"({MODE_NAMES[node.mode_of_operation]}) is not among "
                    f"{Path(eds).name}'s supported drive modes (0x6502 = 0x{supported:X}: "
                    f"{', '.join(have) or 'none of the standard ones'})")
        if "heartbeat_consumer" in cfg:
            if not isinstance(cfg["heartbeat_consumer"], bool):
                raise BindingError(f"{key}.heartbeat_consumer: expected true or false, got "
                                   f"{cfg['heartbeat_consumer']!r}")
            node.heartbeat_consumer = node.heartbeat_consumer and cfg["heartbeat_consumer"]
        if "heartbeat_ms" in cfg:
            node.heartbeat_ms = _int(cfg["heartbeat_ms"], f"{key}.heartbeat_ms", 1, 65535)
        ident = cfg.get("identity") or {}
        if not isinstance(ident, Mapping) or set(ident) - {"vendor_id", "product_code",
                                                           "revision"}:
            raise BindingError(f"{key}.identity: expected vendor_id, product_code, revision")
        if not node.identity_source:
            for name, (value, source) in file_identity(od, Path(eds).name).items():
                node.identity[name] = value
                node.identity_source[name] = source
        for k, v in ident.items():
            node.identity[k] = _int(v, f"{key}.identity.{k}", 0, 2**32 - 1)
            node.identity_source[k] = f"the rig file's {key}.identity.{k}"
        if "device_type" in cfg:
            node.device_type = _int(cfg["device_type"], f"{key}.device_type", 0, 2**32 - 1)
        for i, p in enumerate(cfg.get("parameters") or []):
            pkey = f"{key}.parameters[{i}]"
            if not isinstance(p, Mapping) or set(p) - {"object", "sub", "value"}:
                raise BindingError(f"{pkey}: expected object, sub, value")
            ref = _param_ref(od, p, pkey, eds)
            node.parameters.append((ref, _int(p.get("value"), f"{pkey}.value", -(2**63),
                                              2**64 - 1)))
        tlm_cfg = cfg.get("telemetry") or {}
        if not isinstance(tlm_cfg, Mapping):
            raise BindingError(f"{key}.telemetry: expected a mapping quantity -> object")
        tl = []
        for q, spec in tlm_cfg.items():
            if q not in TELEMETRY[device]:
                raise BindingError(f"{key}.telemetry.{q}: unknown quantity of {device} "
                                   f"(expected one of: {', '.join(TELEMETRY[device])})")
            tl.append(_quantity(q, spec, f"{key}.telemetry.{q}", od, eds, command=False))
        missing = [q for q in REQUIRED_TELEMETRY[device] if q not in tlm_cfg]
        if missing:
            raise BindingError(f"{key}.telemetry.{missing[0]}: missing; the harness needs "
                               f"{', '.join(REQUIRED_TELEMETRY[device])} of the {device}")
        node.telemetry[device] = tuple(tl)
        cmd_cfg = cfg.get("commands") or {}
        if not isinstance(cmd_cfg, Mapping):
            raise BindingError(f"{key}.commands: expected a mapping quantity -> object")
        if cmd_cfg and device not in COMMANDS:
            raise BindingError(f"{key}.commands: the {device} takes no commands")
        cl = []
        for q, spec in cmd_cfg.items():
            if q not in COMMANDS[device]:
                raise BindingError(f"{key}.commands.{q}: unknown command of {device} "
                                   f"(expected one of: {', '.join(COMMANDS[device])})")
            cl.append(_quantity(q, spec, f"{key}.commands.{q}", od, eds, command=True))
        if device in COMMANDS:
            missing = [q for q in REQUIRED_COMMANDS[device] if q not in cmd_cfg]
            if missing:
                raise BindingError(f"{key}.commands.{missing[0]}: missing; the harness "
                                   f"commands {', '.join(REQUIRED_COMMANDS[device])}")
        node.commands[device] = tuple(cl)
    # PDOs: each device's telemetry objects into TPDOs of its own (transmission type = its
    # SYNC divider), each device's commands into RPDOs of its own: a frame is one device's
    tlm_maps: dict[str, list[Any]] = {d: [] for d in devices}
    cmd_maps: dict[str, list[Any]] = {d: [] for d in devices}
    for node in nodes.values():
        if node.verify:
            _dcf_maps(node, dividers, tlm_maps, cmd_maps)
            continue
        n_tpdo = 0
        for d, qrefs in node.telemetry.items():
            if SYNC_COUNTER_OVERFLOW % int(dividers.get(d, 1)):
                raise BindingError(f"bus.sync_divider.{d}: a CANopen device's divider must "
                                   f"divide the SYNC counter's {SYNC_COUNTER_OVERFLOW} (1, 2, 3, "
                                   "4, 5, 6, 8, 10, ...) so its phase holds across the wrap")
            refs: list[ObjRef] = []
            for qr in qrefs:
                if qr.ref not in refs:
                    refs.append(qr.ref)
            packed = _pack("TPDO", refs, TPDO_BASE, node.node_id, int(dividers.get(d, 1)),
                           f"devices.{d}.telemetry", first=n_tpdo + 1)
            n_tpdo += len(packed)
            node.tpdos.extend(packed)
            for pdo in packed:
                fields = tuple(qr for qr in qrefs if qr.ref in pdo.codec.entries)
                tlm_maps[d].append(PdoTelemetryMap(d, pdo.codec, fields))
        n_rpdo = 0
        for d, qrefs in node.commands.items():
            crefs: list[ObjRef] = []
            for qr in qrefs:
                if qr.ref not in crefs:
                    crefs.append(qr.ref)
            if not crefs:
                continue
            # event-driven RPDOs (type 255): a command applies on receipt, and so over the
            # next physics step, as the sgsrt devices' do; the safe command at the end of a
            # run needs no further SYNC to take effect
            packed = _pack("RPDO", crefs, RPDO_BASE, node.node_id, 255,
                           f"devices.{d}.commands", first=n_rpdo + 1)
            n_rpdo += len(packed)
            node.rpdos.extend(packed)
            for pdo in packed:
                fields = tuple(qr for qr in qrefs if qr.ref in pdo.codec.entries)
                cmd_maps[d].append(PdoCommandMap(d, pdo.codec, fields))
    bus = CanopenBus(master_id, nodes, consumer_timeout_ms=consumer_ms, node_of=node_of)
    return (bus, {d: tuple(v) for d, v in tlm_maps.items()},
            {d: tuple(v) for d, v in cmd_maps.items()}, files)


def _od_value(od: Any, index: int, sub: int) -> int | None:
    """A DCF's configured value (ParameterValue), else the EDS default; None if absent."""
    obj = od.get(index) if hasattr(od, "get") else None
    if obj is None:
        return None
    var = obj if hasattr(obj, "data_type") else obj.subindices.get(sub)
    if var is None:
        return None
    v = var.value if getattr(var, "value", None) is not None else var.default
    # a number; anything else (an object the file gives a string or domain type) is not
    # a value the harness can use here
    return int(v) if isinstance(v, int) else None


_IDENTITY = ((1, "vendor_id", "vendor_number", "VendorNumber"),
             (2, "product_code", "product_number", "ProductNumber"),
             (3, "revision", "revision_number", "RevisionNumber"))


def file_identity(od: Any, name: str) -> dict[str, tuple[int, str]]:
    """The identity (0x1018) the device file expects, with where each value comes from: a
    DCF's configured value (ParameterValue), else 0x1018's default, else the file's
    ``[DeviceInfo]`` VendorNumber / ProductNumber / RevisionNumber (vendor files often leave
    0x1018's defaults empty or 0 and name the device there). The revision is checked only
    when a DCF configures it or the rig file names it: a device of a newer firmware is still
    the device. A value known nowhere (or 0 everywhere) is not checked."""
    info = getattr(od, "device_information", None)
    obj = od.get(0x1018) if hasattr(od, "get") else None
    out: dict[str, tuple[int, str]] = {}
    for sub, key, attr, ini in _IDENTITY:
        var = getattr(obj, "subindices", {}).get(sub) if obj is not None else None
        configured = getattr(var, "value", None) if var is not None else None
        default = getattr(var, "default", None) if var is not None else None
        from_info = getattr(info, attr, None) if info is not None else None
        if isinstance(configured, int) and configured:
            out[key] = (configured, f"{name}'s configured 0x1018.{sub} (ParameterValue)")
        elif sub == 3:
            continue
        elif isinstance(default, int) and default:
            out[key] = (default, f"{name}'s 0x1018.{sub} default")
        elif isinstance(from_info, int) and from_info:
            out[key] = (from_info, f"{name}'s [DeviceInfo] {ini}")
    return out


def dcf_pdos(od: Any, node_id: int, comm_base: int, map_base: int, name: str,
             eds: str) -> list[PdoSpec]:
    """The enabled PDOs a DCF configures (COB-ID, transmission type, mapped objects)."""
    out = []
    for n in range(1, 5):
        cob = _od_value(od, comm_base + n - 1, 1)
        count = _od_value(od, map_base + n - 1, 0)
        if cob is None or cob & 0x80000000 or not count:
            continue
        refs = []
        for i in range(1, count + 1):
            word = _od_value(od, map_base + n - 1, i) or 0
            refs.append(object_ref(od, word >> 16, word >> 8 & 0xFF,
                                   f"{Path(eds).name}: {name}{n} mapped object {i}", eds))
        trans = _od_value(od, comm_base + n - 1, 2)
        try:
            codec = PdoCodec(f"{name}{n} node {node_id}", cob & 0x7FF, tuple(refs))
        except BindingError as exc:  # a DCF mapping more than 8 bytes
            raise BindingError(f"{Path(eds).name}: {exc}") from None
        out.append(PdoSpec(n, cob & 0x7FF, 255 if trans is None else trans, codec))
    return out


def _dcf_maps(node: NodeSpec, dividers: Mapping[str, int], tlm_maps: dict[str, list[Any]],
              cmd_maps: dict[str, list[Any]]) -> None:
    """A DCF's node: its PDOs are the DCF's (the harness verifies them on the device during
    set-up instead of writing them); each quantity must be in one of them."""
    key = f"devices.{node.devices[-1]}.eds"
    try:
        node.tpdos = dcf_pdos(node.od, node.node_id, 0x1800, 0x1A00, "TPDO", node.eds)
        node.rpdos = dcf_pdos(node.od, node.node_id, 0x1400, 0x1600, "RPDO", node.eds)
    except BindingError as exc:
        raise BindingError(f"{key}: {exc}") from None
    for d, qrefs in node.telemetry.items():
        for qr in qrefs:
            pdo = next((p for p in node.tpdos if qr.ref in p.codec.entries), None)
            if pdo is None:
                raise BindingError(f"devices.{d}.telemetry.{qr.quantity}: {qr.ref.label} is in "
                                   f"no TPDO of {Path(node.eds).name}'s mapping")
            if pdo.trans_type != int(dividers.get(d, 1)):
                raise BindingError(f"bus.sync_divider.{d}: {dividers.get(d, 1)}, but "
                                   f"{Path(node.eds).name} sends TPDO{pdo.number} every "
                                   f"{pdo.trans_type} SYNC (transmission type)")
        for pdo in node.tpdos:
            fields = tuple(qr for qr in qrefs if qr.ref in pdo.codec.entries)
            if fields:
                tlm_maps[d].append(PdoTelemetryMap(d, pdo.codec, fields))
    owner: dict[int, str] = {}
    for d, qrefs in node.commands.items():
        for qr in qrefs:
            pdo = next((p for p in node.rpdos if qr.ref in p.codec.entries), None)
            if pdo is None:
                raise BindingError(f"devices.{d}.commands.{qr.quantity}: {qr.ref.label} is in "
                                   f"no RPDO of {Path(node.eds).name}'s mapping")
            if owner.setdefault(pdo.number, d) != d:
                raise BindingError(f"devices.{d}.commands.{qr.quantity}: RPDO{pdo.number} of "
                                   f"{Path(node.eds).name} also carries the {owner[pdo.number]}'s "
                                   "commands; the harness sends one device's command a frame")
        for pdo in node.rpdos:
            fields = tuple(qr for qr in qrefs if qr.ref in pdo.codec.entries)
            if fields:
                cmd_maps[d].append(PdoCommandMap(d, pdo.codec, fields))


def _param_ref(od: Any, p: Mapping[str, Any], key: str, eds: str) -> ObjRef:
    index, sub = p.get("object"), p.get("sub", 0)
    if isinstance(index, bool) or not isinstance(index, int) or index not in od:
        raise BindingError(f"{key}.object: {index!r} is not an object of {Path(eds).name}")
    obj = od[index]
    try:
        var = obj if hasattr(obj, "data_type") else obj[sub]
    except (KeyError, IndexError):
        raise BindingError(f"{key}.sub: 0x{index:04X} has no sub-index {sub}") from None
    t = _TYPES.get(var.data_type, (32, False, "I"))
    return ObjRef(index, sub, t[0], t[1], t[2], var.name, var.data_type)
