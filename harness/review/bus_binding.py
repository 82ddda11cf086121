"""The CAN bus in the recording for any binding (a custom DBC, CANopen): every frame of the
run's CAN log decoded through the rig file's binding, the same maps the harness and the
virtual rig use, so the bus view shows what the devices really said, by name.

``harness.review.bus`` decodes the sgsrt protocol with vectorised little-endian fields; a
vendor's DBC (Motorola signals, extended ids, multiplexed pages) or CANopen PDOs need the
binding's own decoders, one frame at a time, after the run (never in the tick). Entities
(``time`` timeline, seconds): ``/bus/<device>/tlm/<quantity>`` and ``/bus/<device>/cmd/
<quantity>`` in SI, ``/bus/harness/sync/tick``, ``/bus/<device>/rx_after_sync_ms``,
``/bus/late_or_missing``; CANopen service frames by name: ``/bus/canopen/node_<id>/
nmt_state`` (each heartbeat's state: 0 boot-up, 4 stopped, 5 operational, 127
pre-operational), and NMT commands, boot-ups and EMCYs (their meaning in words) as events
under ``/events/canopen``. Frames are placed on the timeline as ``harness.review.bus``
places them (the tick is the last SYNC; lockstep frames inside their tick). Values are sent
in blocks, so memory does not grow with the run's length.
"""

from __future__ import annotations

from array import array
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr

from drivers.binding import RigBinding
from drivers.binding.quantities import COMMANDS, TELEMETRY
from drivers.dbc import FrameError
from harness.record.blf_frames import read_frames
from harness.review.bus import LOCKSTEP_CLAMP, MAX_WARNINGS, BusStats, _Sink, signal_entity
from harness.review.names import log_series_names

NMT_COMMANDS = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational",
                0x81: "reset node", 0x82: "reset communication"}


class _Column:
    def __init__(self, sink: _Sink, entity: str, block: int) -> None:
        self.sink, self.entity, self.block = sink, entity, block
        self.t = array("d")
        self.v = array("d")

    def add(self, t: float, v: float) -> None:
        self.t.append(t)
        self.v.append(v)
        if len(self.t) >= self.block:
            self.flush()

    def flush(self) -> None:
        if not len(self.t):
            return
        self.sink.send_columns(
            self.entity, indexes=[rr.TimeColumn("time", duration=np.frombuffer(self.t))],
            columns=rr.Scalars.columns(scalars=np.frombuffer(self.v)))
        self.t, self.v = array("d"), array("d")


def write_bus_binding(rec: rr.RecordingStream, blf: Path, dt_s: float, realtime: bool,
                      dividers: Mapping[str, int], binding: RigBinding,
                      block_rows: int = 10_000) -> BusStats:
    """Decode ``blf`` into ``rec`` through ``binding`` (see the module docstring)."""
    from drivers.binding.canopen import emcy_meaning
    from drivers.binding.canopen_master import heartbeat_state
    from harness.review.events import log_event

    sink = _Sink(rec)
    tlm = binding.telemetry_by_key()
    cmd = binding.commands_by_key()
    sync = binding.sync
    hb = binding.heartbeat
    co = binding.canopen
    units = {("tlm", d): TELEMETRY[d] for d in TELEMETRY}
    units.update({("cmd", d): COMMANDS[d] for d in COMMANDS})
    columns: dict[str, _Column] = {}
    names: dict[str, str] = {}

    def column(entity: str, name: str) -> _Column:
        c = columns.get(entity)
        if c is None:
            c = columns[entity] = _Column(sink, entity, block_rows)
            names[entity] = name
        return c

    # a map's decoded quantities -> their columns, resolved at the map's first frame (the
    # entity's name and unit looked up once, not once a value)
    resolved: dict[tuple[str, str, str, tuple[str, ...]], list[tuple[str, _Column]]] = {}

    def values(kind: str, device: str, frame: str, t: float, decoded: dict[str, float]) -> None:
        key = (kind, device, frame, tuple(decoded))
        cols = resolved.get(key)
        if cols is None:
            u = units.get((kind, device), {})
            cols = resolved[key] = [
                (q, column(signal_entity(f"/bus/{device}/{kind}", q, u[q]), f"{frame} {q}"))
                for q in decoded if q in u]
        for q, c in cols:
            c.add(t, float(decoded[q]))

    due = {d: int(dividers.get(d, 1)) for d in binding.bound if binding.telemetry[d]}
    stats = BusStats()
    tick_col = column("/bus/harness/sync/tick", "SYNC tick")
    missing_col = column("/bus/late_or_missing", "late or missing")
    rx_cols = {d: column(f"/bus/{d}/rx_after_sync_ms", f"{d} after SYNC") for d in due}
    events: list[tuple[float, str, str]] = []
    modulus = int(getattr(sync, "modulus", 1 << 32))
    tick = -1
    raw_last: int | None = None
    sync_ts = 0.0
    first_ts: float | None = None
    origin: float | None = None
    seen: set[str] = set()
    clamp = LOCKSTEP_CLAMP * dt_s

    def close_tick() -> None:
        if tick < 0:
            return
        # tick 0: a CANopen TPDO every n-th SYNC (n > 1) first comes at tick n (CiA 301)
        missing = [d for d, n in due.items() if tick % n == 0 and d not in seen
                   and not (tick == 0 and n > 1 and co is not None)]
        missing_col.add(tick * dt_s, float(len(missing)))
        stats.ticks += 1
        if missing:
            stats.late_or_missing += len(missing)
            if len(stats.warnings) < MAX_WARNINGS:
                stats.warnings.append((tick * dt_s, (
                    f"can log: no telemetry from {', '.join(missing)} before the next SYNC "
                    f"(tick {tick}, t = {tick * dt_s:.3f} s)")))

    for ts, cid, ext, _remote, is_error, _rx, _dlc, data, _ch in read_frames(blf):
        stats.frames += 1
        if is_error:
            stats.error_frames += 1
            continue
        key = (cid, ext)
        if key == binding.fault_insertion:  # the harness's fault-insertion unit: not a device
            stats.decoded += 1
            continue
        if key == sync.key:
            close_tick()
            raw = sync.decode(data)
            # unwrap the SYNC's counter (CANopen: 1..240) into the run's tick
            tick = raw if raw_last is None else tick + ((raw - raw_last) % modulus or 1)
            raw_last = raw
            sync_ts = ts
            seen = set()
            if first_ts is None:
                first_ts = ts
                if realtime:
                    origin = ts
            tick_col.add(tick * dt_s, float(tick))
            stats.decoded += 1
            continue
        if origin is not None:
            t = max(0.0, ts - origin)
        elif first_ts is None or tick < 0:
            t = 0.0
        else:
            t = tick * dt_s + min(max(ts - sync_ts, 0.0), clamp)
        if hb is not None and key == hb.key:
            stats.decoded += 1
            continue
        maps: Any = tlm.get(key)
        if maps is not None:
            try:
                for m in maps:
                    out = m.decode(data)
                    if out is not None:
                        values("tlm", m.device, m.codec.name, t, out)
                        if tick >= 0 and m.device in rx_cols:
                            seen.add(m.device)
                            rx_cols[m.device].add(t, (ts - sync_ts) * 1e3)
                stats.decoded += 1
            except FrameError:
                stats.malformed += 1
            continue
        cmaps: Any = cmd.get(key)
        if cmaps is not None:
            try:
                for c in cmaps:
                    out = c.decode(data)
                    if out is not None:
                        values("cmd", c.device, c.codec.name, t, out)
                stats.decoded += 1
            except FrameError:
                stats.malformed += 1
            continue
        if co is not None and not ext:
            nid, fn = cid & 0x7F, cid & 0x780
            if cid == 0 and len(data) >= 2:
                what = NMT_COMMANDS.get(data[0], f"command 0x{data[0]:02X}")
                events.append((t, f"NMT {what} to "
                               f"{'every node' if data[1] == 0 else f'node {data[1]}'}",
                               "INFO"))
                stats.decoded += 1
                continue
            if nid in co.nodes and fn == 0x700 and data:
                column(f"/bus/canopen/node_{nid}/nmt_state",
                       f"node {nid} ({co.device_of_node(nid)}) NMT state").add(
                    t, float(data[0] & 0x7F))
                if data[0] == 0:
                    events.append((t, f"node {nid} ({co.device_of_node(nid)}): boot-up",
                                   "WARN" if tick > 0 else "INFO"))
                elif tick > 0 and data[0] & 0x7F != 0x05 and len(events) < 200:
                    events.append((t, f"node {nid}: NMT state {heartbeat_state(data)}",
                                   "WARN"))
                stats.decoded += 1
                continue
            if nid in co.nodes and fn == 0x080 and len(data) >= 3:
                code = int.from_bytes(data[:2], "little")
                events.append((t, f"node {nid} ({co.device_of_node(nid)}) EMCY: "
                               f"{emcy_meaning(code, data[2])}",
                               "INFO" if code == 0 else "ERROR"))
                stats.decoded += 1
                continue
            if nid in co.nodes and fn in (0x580, 0x600):
                stats.decoded += 1  # set-up's SDO (counted; its meaning is the set-up's)
                continue
        stats.unknown += 1
    close_tick()
    for c in columns.values():
        c.flush()
    log_series_names(rec, list(columns), names)
    for t, text, level in events[:200]:
        log_event(rec, t, "/events/canopen", text, level)
    return stats
