"""The rig's CAN protocol: a DBC is the single source of truth for every frame.

`sgsrt.dbc` is the rig's own; `load_protocol(path)` reads any lab's DBC. cantools parses the
DBC; for the 500 Hz loop each message is compiled into a small codec (`FrameCodec`) because
cantools' own encode/decode cost more than the tick budget. The codecs are checked against
cantools' encoder/decoder in the tests (tests/test_dbc.py).

What a codec supports (docs/protocol.md): Intel (little-endian) and Motorola (big-endian)
signals at any start bit and length, with cantools' start-bit convention (an Intel signal's
start is its least significant bit, a Motorola signal's its most significant bit in the
DBC's "sawtooth" numbering); signed and unsigned integers with scale and offset; IEEE
single and double floats; standard and extended (29-bit) ids; simple multiplexing (one
multiplexer signal selecting which signals are present). Extended multiplexing is refused.

How it stays cheap: the payload read as one little-endian integer holds every Intel signal
as a contiguous bit field, and read as one big-endian integer holds every Motorola signal
as one, so each signal is a shift and a mask of one of those two integers. Each message's
encode and decode are generated as straight-line Python (no per-signal loop, constants
inlined) once, when the DBC is loaded.

Encode clamps each physical value to the signal's DBC range and to what its raw field can
hold, then rounds to the nearest step, so an encode never overflows a field; a missing
signal encodes as 0 (clamped). A non-numeric or NaN value is a ValueError naming the
signal.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import cast

import cantools

DBC_PATH = Path(__file__).with_name("sgsrt.dbc")


class FrameError(ValueError):
    """A frame cannot be decoded or encoded (wrong length, unknown multiplexer value,
    multiplexer value missing)."""


class DbcError(ValueError):
    """A DBC file cannot be read, parsed or compiled into codecs; names the file."""


@dataclass(frozen=True)
class SignalCodec:
    name: str
    start: int  # cantools' start bit (Intel: the LSB; Motorola: the MSB, sawtooth numbering)
    length: int
    signed: bool
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str
    byte_order: str = "little_endian"
    is_float: bool = False
    # simple multiplexing: the multiplexer signal itself, or the multiplexer values under
    # which this signal is present (None: always present)
    is_multiplexer: bool = False
    multiplexer_ids: tuple[int, ...] | None = None

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1

    @property
    def word_order(self) -> str:
        """The byte order to read the payload in so that this signal is one bit field."""
        return "big" if self.byte_order == "big_endian" else "little"

    def shift(self, frame_length: int) -> int:
        """The field's LSB in the payload read as one integer in ``word_order``:
        raw = (int.from_bytes(data, word_order) >> shift) & mask (vectorised readers use
        this; for Intel signals it is ``start``)."""
        if self.byte_order != "big_endian":
            return self.start
        # Motorola: the MSB is bit start % 8 of byte start // 8; byte b of a big-endian
        # integer of L bytes holds its bits 8 (L - 1 - b) .. 8 (L - 1 - b) + 7
        msb = 8 * (frame_length - 1 - self.start // 8) + self.start % 8
        return msb - self.length + 1


_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")


def _number(x: float | int) -> str:
    """A finite number as a Python literal (repr round-trips floats exactly)."""
    if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
        raise ValueError(f"not a finite number: {x!r}")
    return repr(x)


class FrameCodec:
    """Encode/decode one DBC message (see the module docstring for what is supported)."""

    def __init__(self, message: cantools.database.Message) -> None:
        self._message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.length: int = message.length
        self.is_extended: bool = message.is_extended_frame
        self.comment: str = message.comment or ""
        muxes = [s for s in message.signals if s.is_multiplexer]
        if len(muxes) > 1 or any(s.multiplexer_ids is not None and s.is_multiplexer
                                 for s in message.signals):
            raise ValueError(f"{message.name}: extended multiplexing (more than one "
                             f"multiplexer signal, or a multiplexed multiplexer) is not "
                             f"supported; only simple multiplexing is")
        signals = [self._signal(message, s) for s in message.signals]
        self.signals: tuple[SignalCodec, ...] = tuple(signals)
        self.signal_names: tuple[str, ...] = tuple(s.name for s in signals)
        mux = next((s for s in signals if s.is_multiplexer), None)
        self.multiplexer: str | None = mux.name if mux is not None else None
        self.multiplexer_ids: tuple[int, ...] = ()
        if mux is not None:
            choices = message.get_signal_by_name(mux.name).conversion.choices or {}
            ids = {i for s in signals if s.multiplexer_ids for i in s.multiplexer_ids}
            ids.update(int(k) for k in choices)  # cantools counts named values as ids too
            self.multiplexer_ids = tuple(sorted(ids))
            if not ids:  # nothing to select: a plain signal (as cantools decodes it)
                self.multiplexer = None
            elif mux.scale != 1 or mux.offset != 0 or mux.is_float:
                raise ValueError(f"{message.name}.{mux.name}: a multiplexer signal must be an "
                                 f"integer with scale 1 and offset 0")
        self.source = self._generate()
        self._encoders: dict[tuple[str, ...], Callable[..., bytes]] = {}
        namespace = self._namespace()
        exec(compile(self.source, f"<codec {self.name}>", "exec"), namespace)  # noqa: S102
        # instance attributes, not methods: one call level less on the hot path
        self.encode = cast(Callable[[dict[str, float]], bytes], namespace["encode"])
        self.decode = cast(Callable[[bytes | bytearray], dict[str, float]], namespace["decode"])

    def __reduce__(self) -> tuple[type[FrameCodec], tuple[cantools.database.Message]]:
        # generated functions do not pickle: a process receiving a codec regenerates it
        return FrameCodec, (self._message,)

    @staticmethod
    def _signal(message: cantools.database.Message, s: cantools.database.Signal) -> SignalCodec:
        where = f"{message.name}.{s.name}"
        if s.is_float and s.length not in (32, 64):
            raise ValueError(f"{where}: a float signal must be 32 or 64 bits, not {s.length}")
        if s.multiplexer_signal is not None and s.multiplexer_ids is None:
            raise ValueError(f"{where}: multiplexed by {s.multiplexer_signal} without ids")
        for name, x in (("scale", s.scale), ("offset", s.offset)):
            if not math.isfinite(x):
                raise ValueError(f"{where}: {name} {x} is not finite")
        if s.scale == 0:
            raise ValueError(f"{where}: scale 0")
        return SignalCodec(
            name=s.name,
            start=s.start,
            length=s.length,
            signed=s.is_signed,
            scale=float(s.scale),
            offset=float(s.offset),
            minimum=s.minimum if s.minimum is not None else -math.inf,
            maximum=s.maximum if s.maximum is not None else math.inf,
            unit=s.unit or "",
            byte_order=s.byte_order,
            is_float=s.is_float,
            is_multiplexer=s.is_multiplexer,
            multiplexer_ids=tuple(s.multiplexer_ids) if s.multiplexer_ids is not None else None,
        )

    # -- code generation ---------------------------------------------------------------
    # Every name in the generated source is ours; a DBC's signal names only appear as
    # repr() string literals and its numbers as checked finite literals.

    def _groups(self) -> list[tuple[int | None, list[SignalCodec]]]:
        """(mux value, signals present under it); [(None, all)] without multiplexing."""
        if self.multiplexer is None:
            return [(None, list(self.signals))]
        return [(i, [s for s in self.signals
                     if s.multiplexer_ids is None or i in s.multiplexer_ids])
                for i in self.multiplexer_ids]

    def _range(self, s: SignalCodec) -> tuple[float | int | None, float | int | None]:
        """The physical clamp: the DBC range within what the raw field holds."""
        lo, hi = s.minimum, s.maximum
        if not s.is_float:
            raw_lo = -(1 << (s.length - 1)) if s.signed else 0
            raw_hi = (1 << (s.length - 1)) - 1 if s.signed else (1 << s.length) - 1
            a, b = raw_lo * s.scale + s.offset, raw_hi * s.scale + s.offset
            if s.scale == 1 and s.offset == 0:  # exact ints, also beyond 2**53
                a, b = raw_lo, raw_hi
            lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
        return (lo if math.isfinite(lo) else None), (hi if math.isfinite(hi) else None)

    def _encode_lines(self, s: SignalCodec, indent: str,
                      params: dict[str, str] | None = None) -> list[str]:
        """``params``: a positional encoder's parameter per signal name (a signal not in it
        encodes as 0, as a missing key does); None: the dict encoder's ``values``."""
        if params is None:
            src = f"values.get({s.name!r}, 0.0)"
        else:
            src = params.get(s.name, "0.0")
        lines = [f"{indent}v = {src}"]
        lo, hi = self._range(s)
        if lo is not None and hi is not None:
            lines += [f"{indent}if v < {_number(lo)}: v = {_number(lo)}",
                      f"{indent}elif v > {_number(hi)}: v = {_number(hi)}"]
        elif lo is not None:
            lines.append(f"{indent}if v < {_number(lo)}: v = {_number(lo)}")
        elif hi is not None:
            lines.append(f"{indent}if v > {_number(hi)}: v = {_number(hi)}")
        x = "v" if s.offset == 0 else f"(v - {_number(s.offset)})"
        if s.is_float:
            x = x if s.scale == 1 else f"{x} / {_number(s.scale)}"
            f = "_F32" if s.length == 32 else "_F64"
            raw = f"int.from_bytes({f}.pack({x}), 'little')"
        elif s.scale == 1 and s.offset == 0:
            raw = "round(v)"
        else:
            raw = f"round({x} / {_number(s.scale)})"
        word = "wb" if s.byte_order == "big_endian" else "wl"
        sh = s.shift(self.length)
        lines.append(f"{indent}{word} |= ({raw} & {s.mask})" + (f" << {sh}" if sh else ""))
        return lines

    def _decode_expr(self, s: SignalCodec, var: str) -> list[str]:
        """Lines that set ``var`` to the physical value."""
        word = "wb" if s.byte_order == "big_endian" else "wl"
        sh = s.shift(self.length)
        field_ = f"(({word} >> {sh}) & {s.mask})" if sh else f"({word} & {s.mask})"
        phys = f" * {_number(s.scale)}" + (f" + {_number(s.offset)}" if s.offset != 0 else "")
        if s.is_float:
            f = "_F32" if s.length == 32 else "_F64"
            return [f"    {var} = {f}.unpack({field_}.to_bytes({s.length // 8}, 'little'))[0]"
                    f"{phys}"]
        if not s.signed:
            return [f"    {var} = {field_}{phys}"]
        return [f"    {var} = {field_}",
                f"    if {var} >= {1 << (s.length - 1)}: {var} -= {1 << s.length}",
                f"    {var} = {var}{phys}"]

    def _generate(self) -> str:
        return "\n".join(["from struct import error as struct_error",
                          *self._encode_source(), *self._decode_source(), ""])

    def _return_line(self) -> str:
        n = self.length
        orders = {s.byte_order for s in self.signals}
        big, little = "big_endian" in orders, "little_endian" in orders
        if big and little:  # each word's bytes OR-ed together in one order
            return (f"return (wl | int.from_bytes(wb.to_bytes({n}, 'big'), 'little'))"
                    f".to_bytes({n}, 'little')")
        if big:
            return f"return wb.to_bytes({n}, 'big')"
        return f"return wl.to_bytes({n}, 'little')"

    def _encode_source(self, names: tuple[str, ...] | None = None) -> list[str]:
        """The encoder: ``encode(values)`` (a dict by signal name), or with ``names`` a
        positional ``encode(p0, p1, ...)`` taking those signals in that order (a name that
        is not a signal of this message is taken and ignored, as a dict's extra key is)."""
        ret = self._return_line()
        n = self.length
        mux = self.multiplexer
        if names is None:
            params = None
            enc = ["def encode(values):", "    wl = wb = 0", "    try:"]
            mux_src = f"values.get({mux!r})"
            as_dict = "values"
        else:
            params = {}
            for k, name in enumerate(names):
                params[name] = f"p{k}"  # a repeated name: the last, as in a dict
            enc = [f"def encode({', '.join(f'p{k}' for k in range(len(names)))}):",
                   "    wl = wb = 0", "    try:"]
            mux_src = params.get(mux, "None") if mux is not None else "None"
            # only for an error's message: the values by name, as the dict encoder has them
            as_dict = "{" + ", ".join(f"{name!r}: p{k}" for k, name in enumerate(names)) + "}"
        if mux is None:
            for s in self.signals:
                enc += self._encode_lines(s, "        ", params)
            if not self.signals:  # a frame with no signal (a bare request) is all zeros
                enc.append("        pass")
        else:
            enc += [f"        m = {mux_src}",
                    "        if m is None:",
                    f"            raise FrameError({f'{self.name}: multiplexer {mux} missing'!r})"]
            for k, (i, sigs) in enumerate(self._groups()):
                enc.append(f"        {'if' if k == 0 else 'elif'} m == {i}:")
                for s in sigs:
                    if s.name == mux:  # the value selected this branch: no clamp, no scale
                        word = "wb" if s.byte_order == "big_endian" else "wl"
                        enc.append(f"            {word} |= {(i & s.mask) << s.shift(n)}"
                                   if i & s.mask else "            pass")
                    else:
                        enc += self._encode_lines(s, "            ", params)
            enc += ["        else:",
                    f"            raise FrameError({f'{self.name}: multiplexer {mux} = '!r} "
                    f"+ repr(m) + {f' not one of {list(self.multiplexer_ids)} in the DBC'!r})"]
        enc += ["    except (TypeError, ValueError, OverflowError, struct_error) as exc:",
                "        if isinstance(exc, FrameError): raise",
                f"        raise _encode_error({as_dict}, exc) from exc",
                "    " + ret]
        return enc

    def _decode_source(self) -> list[str]:
        n = self.length
        orders = {s.byte_order for s in self.signals}
        big, little = "big_endian" in orders, "little_endian" in orders
        mux = self.multiplexer
        where = f"{self.name} (0x{self.frame_id:03X})"
        dec = ["def decode(data):",
               f"    if len(data) != {n}:",
               f"        raise FrameError({where + ': expected ' + str(n) + ' data bytes, got '!r}"
               " + str(len(data)))"]
        if little:
            dec.append("    wl = int.from_bytes(data, 'little')")
        if big:
            dec.append("    wb = int.from_bytes(data, 'big')")
        if mux is None:
            for k, s in enumerate(self.signals):
                dec += self._decode_expr(s, f"r{k}")
            items = ", ".join(f"{s.name!r}: r{k}" for k, s in enumerate(self.signals))
            dec.append(f"    return {{{items}}}")
        else:
            ms = next(s for s in self.signals if s.name == mux)
            word = "wb" if ms.byte_order == "big_endian" else "wl"
            dec.append(f"    m = ({word} >> {ms.shift(n)}) & {ms.mask}")
            index = {s.name: k for k, s in enumerate(self.signals)}
            for i, sigs in self._groups():
                dec.append(f"    if m == {i}:")
                body: list[str] = []
                for s in sigs:
                    if s.name != mux:
                        body += self._decode_expr(s, f"r{index[s.name]}")
                items = ", ".join(f"{s.name!r}: r{index[s.name]}" if s.name != mux
                                  else f"{s.name!r}: {float(i)!r}" for s in sigs)
                dec += ["    " + line for line in body]
                dec.append(f"        return {{{items}}}")
            dec.append(f"    raise FrameError({where + ': multiplexer ' + mux + ' = '!r} + str(m)"
                       f" + {' not one of ' + str(list(self.multiplexer_ids)) + ' in the DBC'!r})")
        return dec

    def encoder(self, names: tuple[str, ...]) -> Callable[..., bytes]:
        """A positional encoder: ``encoder(names)(v0, v1, ...)`` is ``encode(dict(zip(names,
        (v0, v1, ...))))``, byte for byte, without building the dict (a tick's frames).
        Generated once per ``names`` and kept."""
        names = tuple(names)
        fn = self._encoders.get(names)
        if fn is None:
            if any(not isinstance(n, str) for n in names):
                raise TypeError(f"{self.name}: signal names must be strings: {names!r}")
            source = "\n".join(["from struct import error as struct_error",
                                *self._encode_source(names), ""])
            namespace = self._namespace()
            exec(compile(source, f"<codec {self.name} encoder>", "exec"), namespace)  # noqa: S102
            fn = self._encoders[names] = cast(Callable[..., bytes], namespace["encode"])
        return fn

    def _namespace(self) -> dict[str, object]:
        return {"FrameError": FrameError, "_F32": _F32, "_F64": _F64,
                "_encode_error": self._encode_error}

    def _encode_error(self, values: dict[str, float], exc: Exception) -> ValueError:
        """The first signal whose value cannot be encoded, named."""
        for s in self.signals:
            v = values.get(s.name, 0.0)
            if not isinstance(v, int | float) or math.isnan(v):
                return ValueError(f"{self.name}.{s.name}: cannot encode {v!r} {s.unit}".rstrip())
            if s.is_float and s.length == 32 and abs(v) > 3.4e38:
                return ValueError(f"{self.name}.{s.name}: {v!r} does not fit a 32-bit float")
        return ValueError(f"{self.name}: cannot encode {values!r}: {exc}")


@dataclass(frozen=True)
class Protocol:
    """Every frame of a DBC, by name and by id.

    ``by_id`` holds the standard (11-bit) ids only, so that an extended frame is never taken
    for the standard frame of equal id value; ``by_key[(id, is_extended)]`` and ``get`` hold
    every frame."""

    database: cantools.database.Database
    by_name: dict[str, FrameCodec]
    by_id: dict[int, FrameCodec]
    by_key: dict[tuple[int, bool], FrameCodec] = field(default_factory=dict)
    #: message name -> why it is not exact (overlapping signals, a signal outside the
    #: payload, a VAL_ table of a signal it lacks, a form the codecs do not support, an id
    #: another message has): a rig that binds it is refused, any other rig is warned
    problems: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, name: str) -> FrameCodec:
        return self.by_name[name]

    def get(self, arbitration_id: int, is_extended: bool = False) -> FrameCodec | None:
        """The codec of a received frame (python-can's ``arbitration_id``,
        ``is_extended_id``), or None."""
        return self.by_key.get((arbitration_id, is_extended))


_UNUSED_ENTRY = re.compile(r"^\s*(VAL_|SIG_VALTYPE_)\s+(\d+)\s+(\w+)", re.M)


def _parse_dbc(text: str, where: str) -> tuple[cantools.database.Database, dict[int, str]]:
    """cantools' non-strict parse of a DBC, as real files are read (a whole vehicle's DBC
    often has one message with overlapping signals); a ``VAL_`` or ``SIG_VALTYPE_`` entry for
    a signal a message lacks (cantools refuses the whole file for it) is dropped and noted
    against that message's id."""
    notes: dict[int, str] = {}
    for _ in range(3):
        try:
            return cantools.database.load_string(text, database_format="dbc",
                                                 strict=False), notes
        except Exception as exc:  # cantools wraps the parser's ValueError in its own
            entries = _UNUSED_ENTRY.findall(str(exc))
            if not entries or "unused " not in str(exc):
                raise
            for kind, frame_id, signal in entries:
                notes[int(frame_id)] = f"{kind} entry for a signal it lacks ({signal})"
                text = re.sub(rf"^\s*{kind}\s+{frame_id}\s+{re.escape(signal)}\b.*$", "",
                              text, flags=re.M)
    raise DbcError(f"{where}: not a valid DBC: entries for signals no message has")


@cache
def load_protocol(path: str | Path | None = None) -> Protocol:
    """The codecs of a DBC (the rig's own ``sgsrt.dbc`` by default). DbcError naming the
    file if it cannot be read or parsed at all. A message that is not exact (see
    ``Protocol.problems``) is kept out of the codecs or marked, not fatal: only a rig that
    binds it is refused (``drivers.binding``)."""
    from drivers.device_file import DeviceFileError, read_device_file

    where = str(path or DBC_PATH)
    try:
        # cantools reads DBC files as Windows-1252, their usual encoding
        text = read_device_file(where).decode("cp1252", errors="replace")
    except DeviceFileError as exc:
        raise DbcError(str(exc)) from None
    try:
        db, notes = _parse_dbc(text, where)
    except DbcError:
        raise
    except RecursionError:
        raise DbcError(f"{where}: not a valid DBC: nested too deeply") from None
    except Exception as exc:  # cantools raises its own errors and plain ones on bad input
        first = str(exc).splitlines()[0][:300] if str(exc) else type(exc).__name__
        raise DbcError(f"{where}: not a valid DBC: {first}") from None
    codecs = []
    by_key: dict[tuple[int, bool], FrameCodec] = {}
    problems: dict[str, str] = {}
    for m in db.messages:
        if m.frame_id in notes:
            problems[m.name] = notes[m.frame_id]
        try:
            m.refresh(strict=True)
        except Exception as exc:  # overlapping signals, a signal outside the payload
            problems.setdefault(m.name, str(exc).splitlines()[0][:300])
            m.refresh(strict=False)
        try:
            c = FrameCodec(m)
        except (ValueError, TypeError, OverflowError) as exc:
            problems[m.name] = str(exc)
            continue
        key = (c.frame_id, c.is_extended)
        if key in by_key:
            first = by_key[key].name
            why = (f"{first} and {c.name} have the same "
                   f"{'extended' if c.is_extended else 'standard'} id 0x{c.frame_id:X}")
            problems[c.name] = problems[first] = why
            continue
        by_key[key] = c
        codecs.append(c)
    return Protocol(
        database=db,
        by_name={c.name: c for c in codecs},
        by_id={c.frame_id: c for c in codecs if not c.is_extended},
        by_key=by_key,
        problems=problems,
    )


def frame_bits_worst_case(data_bytes: int, extended: bool = False) -> int:
    """Bits on the wire of a classic CAN data frame with worst-case bit stuffing
    (including the 3-bit interframe space)."""
    if extended:
        return 67 + 8 * data_bytes + (54 + 8 * data_bytes - 1) // 4
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4
