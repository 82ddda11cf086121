"""CANopen PDO codecs compiled from a PDO mapping (pure: used by the harness's master side
and by the virtual rig's nodes, so both sides pack a PDO the same way).

A mapping is a list of (index, subindex, bit length, data type) entries, packed in order from
bit 0 of the payload, little-endian (CiA 301). Values are raw CANopen values (ints; floats
for REAL32/REAL64): scaling to SI is the caller's. The canopen library's own PdoMap packs
through its Variable objects and a thread; these codecs are a `struct.Struct` when every
entry is a whole 8/16/32/64-bit field on a byte boundary (the usual case), else one
little-endian integer with shifts and masks. The tests check both against canopen's packing.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.objectdictionary import datatypes as dt

from drivers.dbc import FrameError

MAX_PDO_BITS = 64

# struct codes of the types a byte-aligned whole field can use
_STRUCT_CODES: dict[tuple[int, int], str] = {
    (dt.BOOLEAN, 8): "B", (dt.INTEGER8, 8): "b", (dt.UNSIGNED8, 8): "B",
    (dt.INTEGER16, 16): "h", (dt.UNSIGNED16, 16): "H",
    (dt.INTEGER32, 32): "i", (dt.UNSIGNED32, 32): "I",
    (dt.INTEGER64, 64): "q", (dt.UNSIGNED64, 64): "Q",
    (dt.REAL32, 32): "f", (dt.REAL64, 64): "d",
}
_FLOAT_CODES = {dt.REAL32: ("<f", "<I"), dt.REAL64: ("<d", "<Q")}


class PdoMappingError(ValueError):
    """A PDO mapping that cannot be compiled (over 64 bits, unknown type, bad length)."""


@dataclass(frozen=True)
class PdoEntry:
    index: int
    subindex: int
    bit_length: int
    data_type: int

    @property
    def signed(self) -> bool:
        return self.data_type in dt.SIGNED_TYPES

    @property
    def label(self) -> str:
        return f"0x{self.index:04X}:{self.subindex:02X}"


class PdoCodec:
    """encode(raw values) -> payload and decode(payload) -> raw values for one PDO."""

    def __init__(self, name: str, entries: Sequence[PdoEntry | tuple[int, int, int, int]]):
        self.name = name
        self.entries: tuple[PdoEntry, ...] = tuple(
            e if isinstance(e, PdoEntry) else PdoEntry(*e) for e in entries)
        bits = 0
        for e in self.entries:
            if e.bit_length <= 0:
                raise PdoMappingError(f"{name}: {e.label} has bit length {e.bit_length}")
            if e.data_type not in dt.INTEGER_TYPES + dt.FLOAT_TYPES + (dt.BOOLEAN,):
                raise PdoMappingError(
                    f"{name}: {e.label} has data type 0x{e.data_type:X}, not a number")
            if e.data_type in _FLOAT_CODES and (e.data_type, e.bit_length) not in _STRUCT_CODES:
                raise PdoMappingError(f"{name}: {e.label} is a float of {e.bit_length} bits")
            bits += e.bit_length
        if bits > MAX_PDO_BITS:
            raise PdoMappingError(
                f"{name}: mapping of {bits} bits exceeds a PDO's {MAX_PDO_BITS} bits")
        self.bit_length = bits
        self.length = (bits + 7) // 8
        codes = [_STRUCT_CODES.get((e.data_type, e.bit_length)) for e in self.entries]
        # struct's fast path needs whole fields on byte boundaries; offsets then are too
        if all(codes) and all(e.bit_length % 8 == 0 for e in self.entries):
            self._struct: struct.Struct | None = struct.Struct("<" + "".join(codes))
        else:
            self._struct = None
            fields = []
            offset = 0
            for e in self.entries:
                mask = (1 << e.bit_length) - 1
                fields.append((offset, mask, e.signed, 1 << (e.bit_length - 1),
                               1 << e.bit_length, _FLOAT_CODES.get(e.data_type)))
                offset += e.bit_length
            self._fields = tuple(fields)

    def __repr__(self) -> str:
        return f"PdoCodec({self.name!r}, {[e.label for e in self.entries]})"

    def encode(self, values: Sequence[int | float]) -> bytes:
        """Raw values (one per entry, in mapping order) -> payload of `length` bytes."""
        if len(values) != len(self.entries):
            raise ValueError(
                f"{self.name}: {len(values)} values for {len(self.entries)} mapped objects")
        if self._struct is not None:
            try:
                return self._struct.pack(*values)
            except struct.error as exc:
                raise ValueError(f"{self.name}: {self._out_of_range(values)} ({exc})") from None
        word = 0
        for (offset, mask, signed, half, _full, fcodes), v, e in zip(
                self._fields, values, self.entries, strict=True):
            if fcodes is not None:
                v = struct.unpack(fcodes[1], struct.pack(fcodes[0], v))[0]
            elif not (-half if signed else 0) <= v <= (half - 1 if signed else mask):
                raise ValueError(f"{self.name}: {e.label} = {v} does not fit "
                                 f"{e.bit_length} bits")
            word |= (int(v) & mask) << offset
        return word.to_bytes(self.length, "little")

    def packer(self) -> Callable[..., bytes]:
        """``packer()(v0, v1, ...)`` is ``encode([v0, v1, ...])`` byte for byte, the same
        errors included, without the list and the length check (the virtual nodes' TPDOs,
        every SYNC, in the tick)."""
        s = self._struct
        if s is None:
            encode = self.encode
            return lambda *values: encode(values)
        pack, encode = s.pack, self.encode

        def pack_checked(*values: int | float) -> bytes:
            try:
                return pack(*values)
            except struct.error:
                return encode(values)  # raises encode()'s error, naming the object
        return pack_checked

    def decode(self, data: bytes | bytearray | memoryview) -> tuple[int | float, ...]:
        """Payload -> raw values; a payload of another length than the mapping's is refused
        (CiA 301: such a PDO is not processed)."""
        if len(data) != self.length:
            raise FrameError(f"{self.name}: {len(data)} bytes, the mapping has {self.length}")
        if self._struct is not None:
            return self._struct.unpack(data)
        word = int.from_bytes(data, "little")
        out: list[int | float] = []
        for offset, mask, signed, half, full, fcodes in self._fields:
            v = (word >> offset) & mask
            if fcodes is not None:
                out.append(struct.unpack(fcodes[0], struct.pack(fcodes[1], v))[0])
                continue
            if signed and v >= half:
                v -= full
            out.append(v)
        return tuple(out)

    def _out_of_range(self, values: Sequence[int | float]) -> str:
        for e, v in zip(self.entries, values, strict=True):
            code = _STRUCT_CODES[(e.data_type, e.bit_length)]
            try:
                struct.pack("<" + code, v)
            except struct.error:
                return f"{e.label} = {v!r} does not fit its {e.bit_length}-bit type"
        return "a value does not fit"


def entry_from_mapping_word(word: int, data_type: int) -> PdoEntry:
    """A mapping object's 32-bit entry (index << 16 | sub << 8 | bits) with the object's
    data type (from the object dictionary) -> PdoEntry."""
    return PdoEntry(word >> 16, (word >> 8) & 0xFF, word & 0xFF, data_type)


def compile_mapping(name: str, od: ObjectDictionary, words: Sequence[int]) -> PdoCodec:
    """The codec of a PDO from its mapping entries (the 32-bit words of 0x1600.. / 0x1A00..,
    as read by SDO or from an EDS/DCF), the data types coming from the object dictionary."""
    entries = []
    for word in words:
        index, sub = word >> 16, (word >> 8) & 0xFF
        obj = od.indices.get(index)
        # not od.get_variable: an ODArray makes up any sub-index from its first entry
        var = (obj if sub == 0 else None) if isinstance(obj, ODVariable) else \
            None if obj is None else obj.subindices.get(sub)
        if var is None or var.data_type is None:
            raise PdoMappingError(f"{name}: maps 0x{index:04X}:{sub:02X}, which the object "
                                  "dictionary does not define")
        entries.append(entry_from_mapping_word(word, var.data_type))
    return PdoCodec(name, entries)
