"""Bus load of a configuration, computed from the DBC before a run."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.binding import RigBinding
from drivers.dbc import Protocol, frame_bits_worst_case


@dataclass(frozen=True)
class BusLoad:
    frames_per_s: float
    bits_per_s: float
    bitrate_bit_s: int
    rows: tuple[tuple[str, float, float], ...]  # (frame, frames/s, bits/s)

    @property
    def percent(self) -> float:
        return 100.0 * self.bits_per_s / self.bitrate_bit_s


# which telemetry frame each device answers SYNC with
DEVICE_TELEMETRY = {
    "hub_sensor": "HUB_TLM",
    "accelerometer": "ACCEL_TLM",
    "reaction_wheel": "WHEEL_TLM",
    "thruster_valves": "VALVE_TLM",
    "piezo_amplifier": "PIEZO_TLM",
    "disturbance_rotor": "ROTOR_TLM",
}


def compute_bus_load(
    protocol: Protocol,
    rate_hz: float,
    sync_divider: dict[str, int],
    command_frames: list[str],
    heartbeat_hz: float,
    bitrate_bit_s: int,
) -> BusLoad:
    """Worst-case (maximum bit stuffing) load of SYNC + commands + telemetry + heartbeat."""
    per_s: dict[str, float] = {"SYNC": rate_hz, "HEARTBEAT": heartbeat_hz}
    for name in command_frames:
        per_s[name] = rate_hz
    for device, frame in DEVICE_TELEMETRY.items():
        per_s[frame] = rate_hz / sync_divider[device]
    rows = []
    total_bits = 0.0
    for name, fps in per_s.items():
        codec = protocol[name]
        bits = fps * frame_bits_worst_case(codec.length, codec.is_extended)
        rows.append((name, fps, bits))
        total_bits += bits
    return BusLoad(sum(r[1] for r in rows), total_bits, bitrate_bit_s, tuple(rows))


def binding_bus_load(binding: RigBinding, rate_hz: float, sync_divider: dict[str, int],
                     actuators: tuple[str, ...] | list[str], heartbeat_hz: float,
                     bitrate_bit_s: int) -> BusLoad:
    """The same worst case for any binding (sgsrt, a DBC, CANopen PDOs): every frame the
    binding sends, at its device's rate."""
    rows = []
    total_bits = 0.0
    for f in binding.frames():
        if f.kind == "sync":
            fps = rate_hz
        elif f.kind == "heartbeat":
            fps = heartbeat_hz
        elif f.kind == "cmd":
            if f.device not in actuators:
                continue
            fps = rate_hz
        else:
            fps = rate_hz / sync_divider[f.device]
        bits = fps * frame_bits_worst_case(f.codec.length, f.codec.is_extended)
        rows.append((f.name, fps, bits))
        total_bits += bits
    return BusLoad(sum(r[1] for r in rows), total_bits, bitrate_bit_s, tuple(rows))
