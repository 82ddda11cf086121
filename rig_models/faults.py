"""Fault injection in the virtual rig: what can go wrong on the bench, on demand.

A fault is ``kind`` starting at ``at_s`` (rig time) for ``duration_s`` (0: to the end), on a
``device`` where it applies. Frame faults act on the telemetry the rig sends; device faults
change a device's state. Every kind is listed in FAULT_KINDS with what it does.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field, replace
from typing import Any

from rig_models.schema import ConfigError

TELEMETRY_DEVICES = ("hub_sensor", "accelerometer", "reaction_wheel", "thruster_valves",
                     "piezo_amplifier", "disturbance_rotor")

FAULT_KINDS: dict[str, str] = {
    "drop_frames": "drops every other telemetry frame of the device",
    "delay_frames": "holds the device's telemetry back by `value` ticks (default 3)",
    "corrupt_payload": "inverts byte `value` (default: the last) of the device's frames",
    "wrong_length": "sends the device's frames one byte short",
    "bad_checksum": "inverts the checksum byte of the device's telemetry frames that declare "
                    "one (a DBC binding's checksums:); frames without one are sent as they are",
    "unknown_ids": "adds a frame with an id no device uses, every tick",
    "stuck_sensor": "the device repeats its last frame, byte for byte",
    "silent_sensor": "the device stops answering",
    "accel_saturation": "the tip sees `value` m/s^2 more (default 30), beyond the +-2 g range",
    "wheel_fault": "the wheel raises its fault flag and stops producing torque",
    "wheel_overspeed": "the wheel's rotor runs away to 1.1 x its speed limit",
    "valve_stuck_open": "the positive-torque valve sticks open whatever it is commanded",
    "piezo_overcurrent": "the piezo amplifier trips on over-current and outputs 0 V",
    "error_frames": "puts `value` error frames (default 2) on the bus every tick",
    "bus_off": "an error frame with the bus-off class, then no device answers",
    # CANopen devices (a rig file binding the device to a node): faults CANopen's way
    "node_heartbeat_lost": "the device's CANopen node stops its heartbeat (PDOs go on)",
    "node_emcy": "the device's CANopen node sends an EMCY with error code `value` "
                 "(default 0x5000, device hardware)",
    "drive_fault": "the device's CiA 402 drive faults: EMCY 0x2310 (over-current), the status "
                   "word's fault bit, no torque",
    "drive_disabled": "the device's CiA 402 drive drops to switch on disabled by itself, no "
                      "EMCY (its safe-torque-off input, or another master's controlword)",
    "node_reboot": "the device's CANopen node resets by itself: boot-up frame, pre-operational",
    "node_stopped": "the device's CANopen node goes to NMT stopped by itself (no PDOs)",
    "sdo_abort": "during set-up the device's node aborts the SDO to object `value` (default "
                 "0x1017, the heartbeat time) with 0x08000020 (cannot store)",
}
DEVICE_FAULTS = {"drop_frames", "delay_frames", "corrupt_payload", "wrong_length",
                 "bad_checksum", "stuck_sensor", "silent_sensor", "node_heartbeat_lost",
                 "node_emcy",
                 "drive_fault", "drive_disabled", "node_reboot", "node_stopped", "sdo_abort"}
CANOPEN_FAULTS = {"node_heartbeat_lost", "node_emcy", "drive_fault", "drive_disabled",
                  "node_reboot", "node_stopped", "sdo_abort"}
UNKNOWN_ID = 0x6A5
"""The id of the ``unknown_ids`` fault's frames: used by no device of any shipped binding
(a rig file's ``bus.fault_insertion_id`` must differ from it)."""

# ------------------------------------------------------------------ the fault-insertion unit
FAULT_CLEAR = "clear"
"""The fault-insertion frame's kind that ends every fault of the rig (given at start or
inserted) from the next SYNC on."""
FAULT_CODES: dict[str, int] = {
    FAULT_CLEAR: 0,
    "drop_frames": 1,
    "delay_frames": 2,
    "corrupt_payload": 3,
    "wrong_length": 4,
    "bad_checksum": 5,
    "unknown_ids": 6,
    "stuck_sensor": 7,
    "silent_sensor": 8,
    "accel_saturation": 9,
    "wheel_fault": 10,
    "wheel_overspeed": 11,
    "valve_stuck_open": 12,
    "piezo_overcurrent": 13,
    "error_frames": 14,
    "bus_off": 15,
    "node_heartbeat_lost": 16,
    "node_emcy": 17,
    "drive_fault": 18,
    "drive_disabled": 19,
    "node_reboot": 20,
    "node_stopped": 21,
    "sdo_abort": 22,
}
"""The fault-insertion frame's kind codes: fixed numbers, a new kind takes the next free
one (never a renumbering: a lab's sequences and logs carry these bytes)."""
KIND_OF_CODE = {code: kind for kind, code in FAULT_CODES.items()}
NO_DEVICE = 0xFF
FAULT_INSERTION_LENGTH = 8
DURATION_UNIT_S = 0.01
_PAYLOAD = struct.Struct("<BBHf")


class FaultFrameError(ValueError):
    """A fault-insertion frame the rig cannot act on (its message names the frame and the
    field)."""


@dataclass(frozen=True)
class FaultSpec:
    kind: str
    at_s: float
    duration_s: float = 0.0
    device: str = ""
    value: float | None = None

    def active(self, t_s: float) -> bool:
        return t_s >= self.at_s - 1e-12 and (
            self.duration_s <= 0 or t_s < self.at_s + self.duration_s - 1e-12)


def parse_fault(text: str) -> FaultSpec:
    """``KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]``, e.g. ``silent_sensor@5:hub_sensor`` or,
    silent for 0.2 s only, ``silent_sensor@5+0.2:hub_sensor``."""
    value = None
    if "=" in text:
        text, v = text.rsplit("=", 1)
        try:
            value = float(v)
        except ValueError as exc:
            raise ConfigError(f"--fault {text}={v}: value must be a number") from exc
    kind, sep, rest = text.partition("@")
    if not sep:
        raise ConfigError(f"--fault {text!r}: expected KIND@AT_S[+DURATION_S][:DEVICE][=VALUE]")
    when, _, device = rest.partition(":")
    at, plus, dur = when.partition("+")
    try:
        at_s = float(at)
    except ValueError as exc:
        raise ConfigError(f"--fault {text!r}: AT_S must be a number of seconds") from exc
    duration_s = 0.0
    if plus:
        try:
            duration_s = float(dur)
        except ValueError as exc:
            raise ConfigError(f"--fault {text!r}: DURATION_S must be a number of seconds"
                              ) from exc
        if not duration_s > 0:
            raise ConfigError(f"--fault {text!r}: DURATION_S must be > 0 s, got {dur}")
    return make_fault({"kind": kind, "at_s": at_s, "device": device, "value": value,
                       "duration_s": duration_s}, f"--fault {text}")


def make_fault(raw: Any, where: str) -> FaultSpec:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected {{kind, at_s, device?, duration_s?, value?}}")
    unknown = set(raw) - {"kind", "at_s", "duration_s", "device", "value"}
    if unknown:
        raise ConfigError(f"{where}.{sorted(unknown)[0]}: unknown key")
    kind = raw.get("kind")
    if kind not in FAULT_KINDS:
        raise ConfigError(f"{where}.kind: expected one of {sorted(FAULT_KINDS)}, got {kind!r}")
    at_s = raw.get("at_s")
    if not isinstance(at_s, int | float) or at_s < 0:
        raise ConfigError(f"{where}.at_s: expected a number >= 0 (s), got {at_s!r}")
    device = raw.get("device") or ""
    if kind in DEVICE_FAULTS and device not in TELEMETRY_DEVICES:
        raise ConfigError(f"{where}.device: {kind} needs a device from {list(TELEMETRY_DEVICES)}"
                          f", got {device!r}")
    dur = raw.get("duration_s") or 0.0
    value = raw.get("value")
    return FaultSpec(kind, float(at_s), float(dur), device,
                     None if value is None else float(value))


@dataclass
class FaultInjector:
    faults: list[FaultSpec]
    _held: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    _last: dict[str, bytes] = field(default_factory=dict)
    _dropped: dict[str, int] = field(default_factory=dict)

    def active(self, t_s: float, kind: str, device: str = "") -> FaultSpec | None:
        for f in self.faults:
            if f.kind == kind and (not device or f.device == device) and f.active(t_s):
                return f
        return None

    def any_active(self, t_s: float, kind: str) -> FaultSpec | None:
        return self.active(t_s, kind)

    def telemetry(self, t_s: float, tick: int, device: str, data: bytes,
                  checksum_byte: int | None = None) -> list[bytes]:
        """The payloads the device really puts on the bus this tick (maybe none);
        ``checksum_byte``: where the frame's end-to-end checksum is, if it has one."""
        if self.active(t_s, "bus_off") or self.active(t_s, "silent_sensor", device):
            return []
        if self.active(t_s, "stuck_sensor", device):
            data = self._last.setdefault(device, data)
        else:
            self._last[device] = data
        if self.active(t_s, "drop_frames", device):
            n = self._dropped.get(device, 0)
            self._dropped[device] = n + 1
            if n % 2 == 0:
                return []
        f = self.active(t_s, "corrupt_payload", device)
        if f is not None:
            i = int(f.value) if f.value is not None else len(data) - 1
            i = max(0, min(len(data) - 1, i))
            data = data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:]
        if checksum_byte is not None and self.active(t_s, "bad_checksum", device):
            data = (data[:checksum_byte] + bytes([data[checksum_byte] ^ 0xFF])
                    + data[checksum_byte + 1:])
        if self.active(t_s, "wrong_length", device):
            data = data[:-1]
        f = self.active(t_s, "delay_frames", device)
        held = self._held.setdefault(device, [])
        if f is not None:
            held.append((tick + int(f.value if f.value is not None else 3), data))
            out = [d for due, d in held if due <= tick]
            self._held[device] = [(due, d) for due, d in held if due > tick]
            return out
        if held:  # flush what was held when the fault ends
            out = [d for _, d in held] + [data]
            held.clear()
            return out
        return [data]


def encode_fault_insertion(spec: FaultSpec) -> bytes:
    """The fault-insertion frame's 8 bytes (little-endian) for ``spec`` (its ``at_s`` is
    not sent: the rig starts the fault at its next SYNC): kind code u8 (``FAULT_CODES``),
    device u8 (index in ``TELEMETRY_DEVICES``, 0xFF none), duration u16 in 10 ms (0: to the
    end), value float32 (NaN: none). ``ConfigError`` naming the field it cannot carry."""
    code = FAULT_CODES.get(spec.kind)
    if code is None:
        raise ConfigError(f"fault insertion: kind: expected one of {sorted(FAULT_CODES)}, "
                          f"got {spec.kind!r}")
    if spec.device:
        if spec.device not in TELEMETRY_DEVICES:
            raise ConfigError(f"fault insertion {spec.kind}: device: expected one of "
                              f"{list(TELEMETRY_DEVICES)}, got {spec.device!r}")
        device = TELEMETRY_DEVICES.index(spec.device)
    elif spec.kind in DEVICE_FAULTS:
        raise ConfigError(f"fault insertion {spec.kind}: device: {spec.kind} needs a device "
                          f"from {list(TELEMETRY_DEVICES)}")
    else:
        device = NO_DEVICE
    dur = spec.duration_s
    if not math.isfinite(dur) or dur < 0:
        raise ConfigError(f"fault insertion {spec.kind}: duration_s: expected a number >= 0 "
                          f"(s; 0 to the end), got {dur!r}")
    units = round(dur / DURATION_UNIT_S)
    if dur > 0 and units == 0:
        raise ConfigError(f"fault insertion {spec.kind}: duration_s: {dur!r} s is less than "
                          "the frame's 10 ms step (0 would mean to the end)")
    if units > 0xFFFF:
        raise ConfigError(f"fault insertion {spec.kind}: duration_s: at most 655.35 s (or 0 "
                          f"to the end), got {dur!r}")
    value = math.nan if spec.value is None else float(spec.value)
    if math.isinf(value) or (spec.value is not None and math.isnan(value)):
        raise ConfigError(f"fault insertion {spec.kind}: value: expected a finite number or "
                          f"none, got {spec.value!r}")
    if not math.isnan(value) and abs(value) > 3.4e38:
        raise ConfigError(f"fault insertion {spec.kind}: value: {value!r} does not fit a "
                          "float32")
    return _PAYLOAD.pack(code, device, units, value)


def encode_fault_clear() -> bytes:
    """The fault-insertion frame that ends every fault of the rig from its next SYNC on."""
    return _PAYLOAD.pack(FAULT_CODES[FAULT_CLEAR], NO_DEVICE, 0, math.nan)


def decode_fault_insertion(data: bytes | bytearray, where: str
                           ) -> tuple[str, str, float, float | None]:
    """(kind, device, duration_s, value) of a fault-insertion frame; ``FaultFrameError``
    naming ``where`` (the frame) and the field when it is not one the rig can act on. ``kind``
    ``FAULT_CLEAR``: end every fault."""
    if len(data) != FAULT_INSERTION_LENGTH:
        raise FaultFrameError(f"{where}: expected {FAULT_INSERTION_LENGTH} bytes, got {len(data)}")
    code, dev, units, value = _PAYLOAD.unpack(bytes(data))
    kind = KIND_OF_CODE.get(code)
    if kind is None:
        raise FaultFrameError(f"{where}: kind code {code} is not one of the fault kinds (0-"
                         f"{max(KIND_OF_CODE)})")
    if dev == NO_DEVICE:
        device = ""
    elif dev < len(TELEMETRY_DEVICES):
        device = TELEMETRY_DEVICES[dev]
    else:
        raise FaultFrameError(f"{where}: device code {dev} is not a device (0-"
                         f"{len(TELEMETRY_DEVICES) - 1}, or 0xFF none)")
    if kind in DEVICE_FAULTS and not device:
        raise FaultFrameError(f"{where}: {kind} needs a device, the frame names none")
    return (kind, device, units * DURATION_UNIT_S,
            None if math.isnan(value) else float(value))


def ended(faults: list[FaultSpec], end_s: float) -> list[FaultSpec]:
    """``faults`` each ended at ``end_s`` (none active from then on), in the same order: a
    fault that would start at or after ``end_s`` becomes one of no kind (never active)."""
    out = []
    for f in faults:
        if f.at_s >= end_s - 1e-12:
            out.append(replace(f, kind=""))
        elif f.duration_s <= 0 or f.at_s + f.duration_s > end_s:
            out.append(replace(f, duration_s=end_s - f.at_s))
        else:
            out.append(f)
    return out
