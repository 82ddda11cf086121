"""What every device driver shares: decoding into typed telemetry, staleness and counters.

A driver never sleeps and never raises on bad bus data: a frame of the wrong length is
counted as malformed and dropped. Telemetry older than ``stale_after_ticks`` SYNC ticks is
reported stale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from drivers.dbc import FrameCodec, FrameError, Protocol


@dataclass
class FrameCounters:
    received: int = 0
    malformed: int = 0
    sequence_errors: int = 0  # a frame counter that did not advance by exactly one step
    last_error: str = ""


@dataclass
class DeviceDriver:
    """Base class: one device, its telemetry frames and its command frame."""

    protocol: Protocol
    stale_after_ticks: int = 3
    counters: FrameCounters = field(default_factory=FrameCounters)
    last_tick: int = -(10**9)
    values: dict[str, float] = field(default_factory=dict)

    name = "device"
    telemetry_frame = ""
    command_frame = ""
    # (signal, modulus) of a counter that advances by one per frame, if the frame has one
    sequence: tuple[str, int] | None = None

    @property
    def telemetry_codec(self) -> FrameCodec:
        return self.protocol[self.telemetry_frame]

    def handle(self, data: bytes | bytearray, tick: int) -> bool:
        """Decode a telemetry payload received during ``tick``; False if malformed."""
        try:
            self.values = self.telemetry_codec.decode(data)
        except FrameError as exc:
            self.counters.malformed += 1
            self.counters.last_error = str(exc)
            return False
        self.counters.received += 1
        if self.sequence is not None:
            name, modulus = self.sequence
            new = int(self.values.get(name, 0))
            last = getattr(self, "_last_seq", None)
            if last is not None and (new - last) % modulus != 1:
                self.counters.sequence_errors += 1
                self.counters.last_error = f"{self.telemetry_frame}: {name} went {last} -> {new}"
            self._last_seq = new
        self.last_tick = tick
        return True

    def is_stale(self, tick: int) -> bool:
        return tick - self.last_tick > self.stale_after_ticks

    def value(self, name: str, default: float = 0.0) -> float:
        return self.values.get(name, default)
