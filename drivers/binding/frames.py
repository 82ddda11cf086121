"""Frame maps: one DBC message (or one multiplexed page of it) <-> one device's quantities.

The same map serves both ends of the bus: the harness decodes telemetry and encodes
commands with it, the virtual rig encodes telemetry and decodes commands with it, so CI runs
exactly the frames a lab's devices speak. A quantity in SI is ``physical * scale + offset``
of its DBC signal (``physical`` being the DBC's own scaled value, in the DBC's unit); a rig
file gives that conversion as ``scale``/``offset`` or as a sensor's ``sensitivity``/``offset``
(``linear_conversion``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, cast

from drivers.binding.e2e import BYTE, Checksum
from drivers.dbc import FrameCodec, FrameError


class BindingError(ValueError):
    """A rig file's device binding is wrong; the message starts with the key path."""


def finite_number(value: Any, key: str, nonzero: bool = False) -> float:
    """A rig file's conversion constant: a real, finite number (non-zero for a scale); NaN
    or infinity would turn every value it converts into nonsense."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BindingError(f"{key}: expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        raise BindingError(f"{key}: expected a finite number, got {value!r}") from None
    if not math.isfinite(v) or (nonzero and v == 0.0):
        raise BindingError(f"{key}: expected a finite{' non-zero' if nonzero else ''} number, "
                           f"got {value!r}")
    return v


def linear_conversion(spec: Mapping[str, Any], key: str, unit: str = "value"
                      ) -> tuple[float, float]:
    """A rig file's linear conversion as ``(scale, offset)`` with SI = value x scale + offset
    (``value``: a DBC signal's physical value or a CANopen object's raw count). Two forms,
    each with one meaning, for telemetry and commands alike:

    - ``scale`` (SI per unit of the value) and ``offset`` (the SI quantity at a value of
      0): SI = value x scale + offset, a DBC's own factor/offset convention. A command is
      sent as value = (SI - offset) / scale.
    - ``sensitivity`` (units of the value per SI unit) and ``offset`` (the value at a
      quantity of 0, in the value's unit): what a sensor's data sheet gives, the sensor
      reading value = offset + sensitivity x SI, so SI = (value - offset) / sensitivity.
      E.g. an accelerometer of 100 mV/g centred on 2.5 V, read in volts:
      ``sensitivity: 0.0101972`` (0.1 V / 9.80665 m/s^2), ``offset: 2.5``.

    Raises BindingError naming the key."""
    if "sensitivity" in spec and "scale" in spec:
        raise BindingError(f"{key}: give scale (SI per {unit}; SI = {unit} x scale + offset) "
                           f"or sensitivity ({unit} per SI unit; {unit} = offset + "
                           "sensitivity x SI), not both")
    offset = finite_number(spec.get("offset", 0.0), f"{key}.offset")
    if "sensitivity" in spec:
        sens = finite_number(spec["sensitivity"], f"{key}.sensitivity", nonzero=True)
        return 1.0 / sens, -offset / sens
    return finite_number(spec.get("scale", 1.0), f"{key}.scale", nonzero=True), offset


@dataclass(frozen=True)
class SignalMap:
    quantity: str
    signal: str
    scale: float = 1.0  # SI per DBC unit
    offset: float = 0.0  # SI at a DBC value of 0
    modulus: int = 0  # a counter: sent modulo this (its signal's width)

    @property
    def identity(self) -> bool:
        return (self.scale == 1.0 and self.offset == 0.0 and self.quantity == self.signal
                and not self.modulus)


def _mux_signal(codec: FrameCodec) -> str | None:
    return getattr(codec, "multiplexer", None)


class TelemetryMap:
    """One telemetry frame of one device (a multiplexed message: one mux value of it)."""

    __slots__ = ("device", "codec", "mux", "mux_signal", "fields", "identity", "_dec", "_enc",
                 "key", "_wrap", "checksum")

    def __init__(self, device: str, codec: FrameCodec, fields: tuple[SignalMap, ...],
                 mux: int | None = None, checksum: Checksum | None = None) -> None:
        self.device = device
        self.codec = codec
        self.checksum = checksum  # end-to-end protection (drivers.binding.e2e), or None
        self.mux = mux
        self.mux_signal = _mux_signal(codec) if mux is not None else None
        self.fields = fields
        self.key = (codec.frame_id, codec.is_extended)
        # the sgsrt DBC's frames carry exactly the quantities, by name, in SI: its maps pass
        # the codec's dict through (one dict per frame, no copy: the tick budget)
        self.identity = (mux is None and checksum is None and all(f.identity for f in fields)
                         and {f.signal for f in fields} == set(codec.signal_names))
        self._dec = tuple((f.quantity, f.signal, f.scale, f.offset) for f in fields)
        self._enc = tuple((f.quantity, f.signal, 1.0 / f.scale, f.offset) for f in fields)
        self._wrap = tuple((f.quantity, f.modulus) for f in fields if f.modulus)

    def decode(self, data: bytes | bytearray) -> dict[str, float] | None:
        """Payload -> quantities; None when it is another mux page of the message. Raises
        FrameError on a wrong length, and on a wrong checksum (this page's, if declared)."""
        v = self.codec.decode(data)
        if self.identity:
            return v
        if self.mux is not None and v.get(self.mux_signal) != self.mux:  # type: ignore[arg-type]
            return None
        if self.checksum is not None:
            why = self.checksum.error(data)
            if why is not None:
                raise FrameError(f"{self.device}: {why}")
        return {q: v[s] * a + b for q, s, a, b in self._dec if s in v}

    def encoder(self, quantities: tuple[str, ...]) -> Callable[..., bytes]:
        """A positional encoder: ``encoder(quantities)(v0, v1, ...)`` is ``encode(dict(zip(
        quantities, (v0, v1, ...))))`` byte for byte, without a dict per frame (the virtual
        rig's telemetry, every tick). A quantity the map does not carry is taken and
        ignored; one it carries that is not given encodes as a missing key does."""
        quantities = tuple(quantities)
        if self.identity:
            return self.codec.encoder(quantities)
        arg = {q: f"p{k}" for k, q in enumerate(quantities)}  # a repeated name: the last
        wrap = dict(self._wrap)
        signals: list[str] = []
        exprs: list[str] = []
        for q, sig, inv, b in self._enc:
            # as encode(): a counter modulo its field first, then (q - offset) / scale
            x = arg.get(q, "0" if q in wrap else "0.0")
            if q in wrap:
                x = f"({x} % {wrap[q]!r})"
            signals.append(sig)
            exprs.append(f"({x} - {float(b)!r}) * {float(inv)!r}")
        if self.mux is not None:
            signals.append(self.mux_signal)  # type: ignore[arg-type]
            exprs.append(repr(self.mux))
        params = ", ".join(f"p{k}" for k in range(len(quantities)))
        return _compiled_encoder(f"<map {self.device} {self.codec.name}>", params, signals,
                                 exprs, self.codec, self.checksum)

    def encode(self, quantities: dict[str, float]) -> bytes:
        if self.identity:
            return self.codec.encode(quantities)
        if self._wrap:
            quantities = {**quantities, **{q: quantities.get(q, 0) % m for q, m in self._wrap}}
        values = {s: (quantities.get(q, 0.0) - b) * inv for q, s, inv, b in self._enc}
        if self.mux is not None:
            values[self.mux_signal] = self.mux  # type: ignore[index]
        data = self.codec.encode(values)
        return data if self.checksum is None else self.checksum.seal(data)


def _compiled_encoder(name: str, params: str, signals: list[str], exprs: list[str],
                      codec: FrameCodec, checksum: Checksum | None = None
                      ) -> Callable[..., bytes]:
    """``def encode(PARAMS): return codec.encoder(signals)(*exprs)`` compiled once: the
    maps' positional encoders (each expression is a quantity's conversion to its signal).
    With a checksum, its byte is set last, over the payload as encoded (counter included,
    the checksum's own byte 0 as the codec leaves a signal it is not given)."""
    call = f"_codec({', '.join(exprs)})"
    if checksum is None:
        source = f"def encode({params}):\n    return {call}\n"
    else:
        i = checksum.byte
        source = (f"def encode({params}):\n    d = {call}\n"
                  f"    return d[:{i}] + _BYTE[_sum(d)] + d[{i + 1}:]\n")
    namespace: dict[str, Any] = {"_codec": codec.encoder(tuple(signals)), "_BYTE": BYTE,
                                 "_sum": checksum.compute if checksum is not None else None}
    exec(compile(source, name, "exec"), namespace)  # noqa: S102
    return cast(Callable[..., bytes], namespace["encode"])


class CommandMap:
    """One command frame of one device; an optional alive counter the sender fills in."""

    __slots__ = ("device", "codec", "mux", "mux_signal", "fields", "counter", "key",
                 "_enc", "_dec", "checksum")

    def __init__(self, device: str, codec: FrameCodec, fields: tuple[SignalMap, ...],
                 counter: tuple[str, int] | None = None, mux: int | None = None,
                 checksum: Checksum | None = None) -> None:
        self.device = device
        self.codec = codec
        self.fields = fields
        self.counter = counter
        self.checksum = checksum  # end-to-end protection (drivers.binding.e2e), or None
        self.mux = mux
        self.mux_signal = _mux_signal(codec) if mux is not None else None
        self.key = (codec.frame_id, codec.is_extended)
        self._enc = tuple((f.quantity, f.signal, 1.0 / f.scale, f.offset) for f in fields)
        self._dec = tuple((f.quantity, f.signal, f.scale, f.offset) for f in fields)

    def encoder(self, quantities: tuple[str, ...]) -> Callable[..., bytes]:
        """A positional encoder: ``encoder(quantities)(v0, v1, ..., counter)`` is
        ``encode(dict(zip(quantities, (v0, v1, ...))), counter)`` byte for byte, without a
        dict per frame (the harness's commands, every tick)."""
        quantities = tuple(quantities)
        arg = {q: f"p{k}" for k, q in enumerate(quantities)}  # a repeated name: the last
        signals: list[str] = []
        exprs: list[str] = []
        for q, sig, inv, b in self._enc:
            signals.append(sig)
            exprs.append(f"({arg.get(q, '0.0')} - {float(b)!r}) * {float(inv)!r}")
        if self.counter is not None:  # after the fields, as encode() sets it (it wins)
            signals.append(self.counter[0])
            exprs.append(f"counter % {int(self.counter[1])!r}")
        if self.mux is not None:
            signals.append(self.mux_signal)  # type: ignore[arg-type]
            exprs.append(repr(self.mux))
        params = "".join(f"p{k}, " for k in range(len(quantities))) + "counter"
        return _compiled_encoder(f"<map {self.device} {self.codec.name}>", params, signals,
                                 exprs, self.codec, self.checksum)

    def encode(self, quantities: dict[str, float], counter: int) -> bytes:
        values = {s: (quantities.get(q, 0.0) - b) * inv for q, s, inv, b in self._enc}
        if self.counter is not None:
            name, modulus = self.counter
            values[name] = counter % modulus
        if self.mux is not None:
            values[self.mux_signal] = self.mux  # type: ignore[index]
        data = self.codec.encode(values)
        return data if self.checksum is None else self.checksum.seal(data)

    def decode(self, data: bytes | bytearray) -> dict[str, float] | None:
        """Payload -> command quantities; None for another mux page. Raises FrameError on a
        wrong length or a wrong checksum (a device drops such a frame)."""
        v = self.codec.decode(data)
        if self.mux is not None and v.get(self.mux_signal) != self.mux:  # type: ignore[arg-type]
            return None
        if self.checksum is not None:
            why = self.checksum.error(data)
            if why is not None:
                raise FrameError(f"{self.device}: {why}")
        return {q: v[s] * a + b for q, s, a, b in self._dec if s in v}

    def decoder(self, quantities: tuple[str, ...], defaults: tuple[float, ...],
                with_counter: bool = False
                ) -> Callable[[bytes | bytearray], tuple[float, ...] | None]:
        """A positional decoder: ``decoder(quantities, defaults)(data)`` is the tuple of
        ``decode(data).get(q, default)`` for each quantity (None for another mux page),
        without a dict of quantities (the virtual rig's commands, every tick). A wrong
        checksum raises FrameError as ``decode`` does. ``with_counter`` (a map with a
        counter): the frame's alive counter follows the quantities (the receiver checks
        it)."""
        exprs = []
        for q, default in zip(quantities, defaults, strict=True):
            expr = repr(default)
            for _, s, a, b in (f for f in self._dec if f[0] == q):
                # decode()'s dict: the last field of the quantity present in the frame wins
                expr = f"(v[{s!r}] * {float(a)!r} + {float(b)!r} if {s!r} in v else {expr})"
            exprs.append(expr)
        lines = ["def decode(data):", "    v = _codec(data)"]
        if self.mux is not None:
            lines.append(f"    if v.get({self.mux_signal!r}) != {self.mux!r}: return None")
        if self.checksum is not None:
            lines += ["    why = _error(data)",
                      f"    if why is not None: raise _FrameError({self.device + ': '!r} + why)"]
        if with_counter and self.counter is not None:
            exprs.append(f"int(v[{self.counter[0]!r}])")
        lines.append(f"    return ({''.join(e + ', ' for e in exprs)})")
        namespace: dict[str, Any] = {
            "_codec": self.codec.decode, "_FrameError": FrameError,
            "_error": self.checksum.error if self.checksum is not None else None}
        exec(compile("\n".join(lines) + "\n", f"<map {self.device} {self.codec.name} decoder>",  # noqa: S102
                     "exec"), namespace)
        return cast(Callable[[bytes | bytearray], tuple[float, ...] | None],
                    namespace["decode"])


class SyncMap:
    """The harness's SYNC frame of a DBC: a tick counter signal."""

    __slots__ = ("codec", "signal", "modulus", "key")

    def __init__(self, codec: FrameCodec, signal: str) -> None:
        self.codec = codec
        self.signal = signal
        sig = next(s for s in codec.signals if s.name == signal)
        self.modulus = 1 << sig.length
        self.key = (codec.frame_id, codec.is_extended)

    def encode(self, tick: int) -> bytes:
        return self.codec.encode({self.signal: tick % self.modulus})

    def decode(self, data: bytes | bytearray) -> int:
        return int(self.codec.decode(data)[self.signal])


class HeartbeatMap:
    """The harness's heartbeat of a DBC: an alive counter and an ``armed`` flag; with none
    for ``heartbeat_timeout_s`` (or armed 0) every device keeps its actuators safe."""

    __slots__ = ("codec", "counter", "armed", "modulus", "key")

    def __init__(self, codec: FrameCodec, counter: str | None, armed: str) -> None:
        self.codec = codec
        self.counter = counter
        self.armed = armed
        self.modulus = 256
        if counter is not None:
            sig = next(s for s in codec.signals if s.name == counter)
            self.modulus = 1 << sig.length
        self.key = (codec.frame_id, codec.is_extended)

    def encode(self, counter: int, armed: bool) -> bytes:
        values = {self.armed: int(armed)}
        if self.counter is not None:
            values[self.counter] = counter % self.modulus
        return self.codec.encode(values)

    def decode_armed(self, data: bytes | bytearray) -> bool:
        return bool(self.codec.decode(data)[self.armed])
