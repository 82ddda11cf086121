"""What every device driver shares: decoding into typed telemetry, staleness and counters.

A driver never sleeps and never raises on bad bus data: a frame of the wrong length is
counted as malformed and dropped. Telemetry older than ``stale_after_ticks`` SYNC ticks is
reported stale.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

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
    multi_frame: bool = False  # the binding spreads its telemetry over several frames

    name = "device"
    telemetry_frame = ""
    command_frame = ""
    # (signal, modulus) of a counter that advances by one per frame, if the frame has one
    sequence: tuple[str, int] | None = None
    _last_seq: ClassVar[int | None] = None  # the last sequence counter (set per instance)
    # the command quantities, in the order ``command_args`` gives them (an actuator's)
    command_quantities: ClassVar[tuple[str, ...]] = ()

    @property
    def telemetry_codec(self) -> FrameCodec:
        return self.protocol[self.telemetry_frame]

    def handle(self, data: bytes | bytearray, tick: int) -> bool:
        """Decode an sgsrt telemetry payload received during ``tick``; False if malformed.
        (The harness decodes through the rig's binding and calls ``update``.)"""
        try:
            values = self.telemetry_codec.decode(data)
        except FrameError as exc:
            self.malformed(str(exc))
            return False
        self.update(values, tick)
        return True

    def malformed(self, reason: str) -> None:
        self.counters.malformed += 1
        self.counters.last_error = reason

    def update(self, values: dict[str, float], tick: int) -> None:
        """New telemetry quantities (``drivers.binding.quantities``, SI) from one frame
        received during ``tick``. A device with several frames merges them."""
        if self.multi_frame:  # one frame of several: keep the others' values
            self.values = {**self.values, **values}
        else:
            self.values = values
        self.counters.received += 1
        sequence = self.sequence
        if sequence is not None and sequence[0] in values:
            name, modulus = sequence
            new = int(values[name])
            last = self._last_seq
            if last is not None and (new - last) % modulus != 1:
                self.counters.sequence_errors += 1
                self.counters.last_error = f"{self.name}: {name} went {last} -> {new}"
            self._last_seq = new
        self.last_tick = tick

    def is_stale(self, tick: int) -> bool:
        return tick - self.last_tick > self.stale_after_ticks

    def value(self, name: str, default: float = 0.0) -> float:
        return self.values.get(name, default)
