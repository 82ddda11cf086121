"""The rig's CAN protocol: `sgsrt.dbc` is the single source of truth for every frame.

cantools parses the DBC; for the 500 Hz loop each message is compiled into a small codec
(`FrameCodec`) that packs the signals into one little-endian integer. The codecs are
checked against cantools' own encoder/decoder in the tests. Physical values are clamped to
the signal's DBC range before scaling, so an encode never overflows a field.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path

import cantools

DBC_PATH = Path(__file__).with_name("sgsrt.dbc")


class FrameError(ValueError):
    """A frame cannot be decoded (wrong length or unknown id)."""


@dataclass(frozen=True)
class SignalCodec:
    name: str
    start: int
    length: int
    signed: bool
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1


class FrameCodec:
    """Encode/decode one DBC message (Intel byte order signals only)."""

    def __init__(self, message: cantools.database.Message) -> None:
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.length: int = message.length
        self.is_extended: bool = message.is_extended_frame
        self.comment: str = message.comment or ""
        signals = []
        for s in message.signals:
            if s.byte_order != "little_endian":
                raise ValueError(f"{message.name}.{s.name}: only little-endian signals supported")
            signals.append(
                SignalCodec(
                    name=s.name,
                    start=s.start,
                    length=s.length,
                    signed=s.is_signed,
                    scale=float(s.scale),
                    offset=float(s.offset),
                    minimum=float(s.minimum if s.minimum is not None else -float("inf")),
                    maximum=float(s.maximum if s.maximum is not None else float("inf")),
                    unit=s.unit or "",
                )
            )
        self.signals: tuple[SignalCodec, ...] = tuple(signals)
        self.signal_names: tuple[str, ...] = tuple(s.name for s in signals)
        self._enc = [
            (s.name, s.start, s.mask, s.scale, s.offset, s.minimum, s.maximum) for s in signals
        ]
        self._dec = [
            (s.name, s.start, s.mask, s.signed, 1 << (s.length - 1), 1 << s.length, s.scale,
             s.offset)
            for s in signals
        ]

    def encode(self, values: dict[str, float]) -> bytes:
        """Physical values -> payload. Missing signals encode as 0; values are clamped to the
        DBC range and rounded to the nearest step."""
        word = 0
        for name, start, mask, scale, offset, lo, hi in self._enc:
            v = values.get(name, 0.0)
            if v < lo:
                v = lo
            elif v > hi:
                v = hi
            raw = round((v - offset) / scale)
            word |= (raw & mask) << start
        return word.to_bytes(self.length, "little")

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        if len(data) != self.length:
            raise FrameError(
                f"{self.name} (0x{self.frame_id:03X}): expected {self.length} data bytes, "
                f"got {len(data)}"
            )
        word = int.from_bytes(data, "little")
        out: dict[str, float] = {}
        for name, start, mask, signed, half, full, scale, offset in self._dec:
            raw = (word >> start) & mask
            if signed and raw >= half:
                raw -= full
            out[name] = raw * scale + offset
        return out


@dataclass(frozen=True)
class Protocol:
    """Every frame of the rig, by name and by id."""

    database: cantools.database.Database
    by_name: dict[str, FrameCodec]
    by_id: dict[int, FrameCodec]

    def __getitem__(self, name: str) -> FrameCodec:
        return self.by_name[name]


@cache
def load_protocol(path: str | None = None) -> Protocol:
    db = cantools.database.load_file(str(path or DBC_PATH))
    codecs = [FrameCodec(m) for m in db.messages]
    return Protocol(
        database=db,
        by_name={c.name: c for c in codecs},
        by_id={c.frame_id: c for c in codecs},
    )


def frame_bits_worst_case(data_bytes: int, extended: bool = False) -> int:
    """Bits on the wire of a classic CAN data frame with worst-case bit stuffing
    (including the 3-bit interframe space)."""
    if extended:
        return 67 + 8 * data_bytes + (54 + 8 * data_bytes - 1) // 4
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4
