"""The CAN bus in the recording: every frame of a run's CAN log decoded with the DBC at its
own time, per device, and the telemetry that came late or not at all at each tick.

Entities (``time`` timeline, seconds): ``/bus/<device>/tlm/<signal>_<unit>`` (telemetry),
``/bus/<device>/cmd/<signal>_<unit>`` (commands), ``/bus/harness/sync/tick`` and
``/bus/harness/heartbeat/...``, ``/bus/<device>/rx_after_sync_ms`` (the frame's timestamp
minus its tick's SYNC's, wall clock) and ``/bus/late_or_missing`` (devices due at a tick
whose telemetry did not come before the next SYNC), with a warning under ``/events/bus`` for
the first ticks that lack one.

Where a frame is placed on the ``time`` timeline. The tick is the last SYNC before the frame
(its ``tick`` signal). On the real-time clock a frame sits at its timestamp minus the first
SYNC's, plus that SYNC's tick time: a late frame shows where it really came. In lockstep the
wall clock is not simulated time (a tick takes microseconds of wall time, or longer), so a
frame sits at its tick's time plus its wall-clock offset after that SYNC, clamped below 90 %
of the period: it stays in its own tick, and ``rx_after_sync_ms`` keeps the true wall
offset. Frames before the first SYNC sit at the first tick's time.

The CAN log is streamed (python-can's BLF reader reads it in blocks) and the decoded values
are sent with ``send_columns`` every ``block_values`` values, so memory does not grow with
the run's length. It runs after the run, before run.rrd is closed, never in the tick.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import rerun as rr

from drivers.dbc import Protocol, load_protocol

# device -> (telemetry frame, command frame or None), as the drivers define them
DEVICES: dict[str, tuple[str, str | None]] = {
    "hub_sensor": ("HUB_TLM", None),
    "accelerometer": ("ACCEL_TLM", None),
    "reaction_wheel": ("WHEEL_TLM", "WHEEL_CMD"),
    "thruster_valves": ("VALVE_TLM", "VALVE_CMD"),
    "piezo_amplifier": ("PIEZO_TLM", "PIEZO_CMD"),
    "disturbance_rotor": ("ROTOR_TLM", "ROTOR_CMD"),
}
UNIT_SUFFIX = {"N.m": "n_m", "rad/s": "rad_s", "rad": "rad", "m/s^2": "m_s2", "V": "v",
               "s": "s"}
MAX_WARNINGS = 20
LOCKSTEP_CLAMP = 0.9


def signal_entity(base: str, name: str, unit: str) -> str:
    suffix = UNIT_SUFFIX.get(unit, unit.replace("/", "_").replace(".", "_").lower())
    return f"{base}/{name}_{suffix}" if suffix else f"{base}/{name}"


@dataclass
class BusStats:
    frames: int = 0
    decoded: int = 0
    unknown: int = 0
    malformed: int = 0
    error_frames: int = 0
    ticks: int = 0
    late_or_missing: int = 0
    warnings: list[tuple[float, str]] = field(default_factory=list)


class _Columns:
    """Values per entity, sent in blocks."""

    def __init__(self, rec: rr.RecordingStream, block_values: int) -> None:
        self.rec = rec
        self.block = block_values
        self.t: dict[str, list[float]] = {}
        self.v: dict[str, list[float]] = {}
        self.n = 0

    def add(self, entity: str, t: float, v: float) -> None:
        ts = self.t.get(entity)
        if ts is None:
            ts = self.t[entity] = []
            self.v[entity] = []
        ts.append(t)
        self.v[entity].append(v)
        self.n += 1
        if self.n >= self.block:
            self.flush()

    def flush(self) -> None:
        for entity, ts in self.t.items():
            if ts:
                self.rec.send_columns(
                    entity, indexes=[rr.TimeColumn("time", duration=np.asarray(ts))],
                    columns=rr.Scalars.columns(scalars=np.asarray(self.v[entity])))
        self.t = {}
        self.v = {}
        self.n = 0


def write_bus(rec: rr.RecordingStream, blf: Path, dt_s: float, realtime: bool,
              dividers: Mapping[str, int], protocol: Protocol | None = None,
              block_values: int = 50_000) -> BusStats:
    """Decode ``blf`` into ``rec`` (see the module docstring); returns counts."""
    protocol = protocol or load_protocol()
    by_id = protocol.by_id
    sync_id = protocol["SYNC"].frame_id
    device_of: dict[int, tuple[str, str]] = {}
    for device, (tlm, cmd) in DEVICES.items():
        device_of[protocol[tlm].frame_id] = (device, "tlm")
        if cmd is not None:
            device_of[protocol[cmd].frame_id] = (device, "cmd")
    device_of[protocol["HEARTBEAT"].frame_id] = ("harness", "heartbeat")
    device_of[sync_id] = ("harness", "sync")
    entities = {fid: [signal_entity(f"/bus/{dev}/{kind}", s.name, s.unit)
                      for s in by_id[fid].signals] for fid, (dev, kind) in device_of.items()}
    tlm_device = {protocol[t].frame_id: d for d, (t, _) in DEVICES.items()}
    due = {d: int(dividers.get(d, 1)) for d in DEVICES if d in dividers}
    cols = _Columns(rec, block_values)
    stats = BusStats()
    first_sync_ts: float | None = None
    first_tick_t = 0.0
    tick = -1
    sync_ts = 0.0
    seen: set[str] = set()

    def close_tick() -> None:
        if tick < 0:
            return
        missing = [d for d, n in due.items() if tick % n == 0 and d not in seen]
        t_tick = tick * dt_s
        cols.add("/bus/late_or_missing", t_tick, float(len(missing)))
        stats.ticks += 1
        if missing:
            stats.late_or_missing += len(missing)
            if len(stats.warnings) < MAX_WARNINGS:
                stats.warnings.append((t_tick, f"tick {tick}: no telemetry before the next "
                                       f"SYNC from {', '.join(missing)}"))

    with can.BLFReader(str(blf)) as reader:
        for msg in reader:
            stats.frames += 1
            if msg.is_error_frame:
                stats.error_frames += 1
                continue
            fid = msg.arbitration_id
            codec = by_id.get(fid)
            if codec is None or fid not in device_of:
                stats.unknown += 1
                continue
            try:
                values = codec.decode(msg.data)
            except ValueError:
                stats.malformed += 1
                continue
            ts = float(msg.timestamp)
            if fid == sync_id:
                close_tick()
                tick = int(values["tick"])
                sync_ts = ts
                seen = set()
                if first_sync_ts is None:
                    first_sync_ts = ts
                    first_tick_t = tick * dt_s
            if first_sync_ts is None:
                t = 0.0
            elif realtime:
                t = first_tick_t + (ts - first_sync_ts)
            else:
                t = tick * dt_s + min(max(ts - sync_ts, 0.0), LOCKSTEP_CLAMP * dt_s)
            device = tlm_device.get(fid)
            if device is not None and tick >= 0:
                seen.add(device)
                cols.add(f"/bus/{device}/rx_after_sync_ms", t, (ts - sync_ts) * 1e3)
            for entity, v in zip(entities[fid], values.values(), strict=True):
                if not math.isnan(v):
                    cols.add(entity, t, v)
            stats.decoded += 1
    close_tick()
    cols.flush()
    return stats
