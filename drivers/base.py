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
        self.last_tick = tick
        return True

    def is_stale(self, tick: int) -> bool:
        return tick - self.last_tick > self.stale_after_ticks

    def value(self, name: str, default: float = 0.0) -> float:
        return self.values.get(name, default)
