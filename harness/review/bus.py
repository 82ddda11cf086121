"""The CAN bus in the recording: every frame of a run's CAN log decoded with the DBC at its
own time, per device, and the telemetry that came late or not at all at each tick.

Entities (``time`` timeline, seconds): ``/bus/<device>/tlm/<signal>_<unit>`` (telemetry),
``/bus/<device>/cmd/<signal>_<unit>`` (commands), ``/bus/harness/sync/tick`` and
``/bus/harness/heartbeat/...``, ``/bus/<device>/rx_after_sync_ms`` (the frame's timestamp
minus its tick's SYNC's, wall clock; a frame sent before the SYNC it was read after
counts for the tick before, late) and ``/bus/late_or_missing`` (devices due at a tick
whose telemetry did not come before the next SYNC), with a warning under ``/events/can_log`` for
the first ticks that lack one.

Where a frame is placed on the ``time`` timeline. The tick is the last SYNC before the frame
(its ``tick`` signal). On the real-time clock a frame sits at its timestamp minus the time
tick 0 was due, taken as the smallest (SYNC timestamp - tick x period) over the log (a
first pass over the SYNCs; the first SYNC is often the latest of all): a late frame, or a
late SYNC, shows where it really came. In lockstep the
wall clock is not simulated time (a tick takes microseconds of wall time, or longer), so a
frame sits at its tick's time plus its wall-clock offset after that SYNC, clamped below 90 %
of the period: it stays in its own tick, and ``rx_after_sync_ms`` keeps the true wall
offset. Frames before the first SYNC sit at the first tick's time.

The CAN log is streamed (python-can's BLF reader reads it in blocks); each frame id's
payloads are kept as integers in blocks of ``block_rows``, decoded with numpy by the DBC's
fields (``drivers.dbc``) and sent with ``send_columns``, so memory does not grow with the
run's length. It runs after the run, before run.rrd is closed, never in the tick.
"""

from __future__ import annotations

from array import array
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr

from drivers.binding import SGSRT_FRAMES
from drivers.dbc import FrameCodec, Protocol, load_protocol
from harness.record.blf_frames import read_frames
from harness.review.names import log_series_names

# device -> (telemetry frame, command frame or None): the sgsrt protocol's, as its binding
# defines them (another binding's frames: harness.review.bus_binding)
DEVICES: dict[str, tuple[str, str | None]] = SGSRT_FRAMES
UNIT_SUFFIX = {"N.m": "n_m", "rad/s": "rad_s", "rad": "rad", "m/s^2": "m_s2", "V": "v",
               "s": "s"}
MAX_WARNINGS = 20
LOCKSTEP_CLAMP = 0.9


def signal_entity(base: str, name: str, unit: str) -> str:
    suffix = UNIT_SUFFIX.get(unit, unit.replace("/", "_").replace(".", "_").lower())
    return f"{base}/{name}_{suffix}" if suffix else f"{base}/{name}"


class _Sink:
    """``send_columns`` that waits for the recording's file sink every ``flush_every``
    sends: the decoder produces columns far faster than the sink writes them, and without
    the wait Rerun queues them all in memory (a 10-minute real-time run's bus took 0.7 GB
    after the run before this)."""

    def __init__(self, rec: rr.RecordingStream, flush_every: int = 20) -> None:
        self.rec = rec
        self.flush_every = flush_every
        self.sent = 0

    def send_columns(self, entity: str, indexes: list, columns: object) -> None:
        self.rec.send_columns(entity, indexes=indexes, columns=columns)
        self.sent += 1
        if self.sent % self.flush_every == 0:
            self.rec.flush()


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


class _Frames:
    """One frame id's frames (time, payload as a little-endian integer) in compact arrays,
    decoded with numpy (the codec's fields) and sent when ``block_rows`` are held, and at
    the end: memory is ``block_rows`` x 16 bytes per frame id, whatever the run's length."""

    def __init__(self, rec: _Sink, codec: FrameCodec, entities: list[str],
                 block_rows: int) -> None:
        self.rec = rec
        self.codec = codec
        self.entities = entities
        self.block = block_rows
        self.t = array("d")
        self.word = array("Q")

    def add(self, t: float, data: bytes) -> None:
        self.t.append(t)
        self.word.append(int.from_bytes(data, "little"))
        if len(self.t) >= self.block:
            self.flush()

    def flush(self) -> None:
        if not len(self.t):
            return
        t = np.frombuffer(self.t).copy()
        word = np.frombuffer(self.word, dtype=np.uint64)
        index = [rr.TimeColumn("time", duration=t)]
        for entity, s in zip(self.entities, self.codec.signals, strict=True):
            raw = ((word >> np.uint64(s.start)) & np.uint64(s.mask)).astype(np.int64)
            if s.signed:
                raw = np.where(raw >= 1 << (s.length - 1), raw - (1 << s.length), raw)
            self.rec.send_columns(entity, indexes=index,
                                  columns=rr.Scalars.columns(scalars=raw * s.scale + s.offset))
        self.t = array("d")
        self.word = array("Q")


class _Series:
    """Derived values of one entity (receive offsets, late-or-missing counts), sent in
    blocks like ``_Frames``."""

    def __init__(self, rec: _Sink, entity: str, block_rows: int) -> None:
        self.rec = rec
        self.entity = entity
        self.block = block_rows
        self.t = array("d")
        self.v = array("d")

    def add(self, t: float, v: float) -> None:
        self.t.append(t)
        self.v.append(v)
        if len(self.t) >= self.block:
            self.flush()

    def flush(self) -> None:
        if len(self.t):
            self.rec.send_columns(
                self.entity, indexes=[rr.TimeColumn("time", duration=np.frombuffer(self.t).copy())],
                columns=rr.Scalars.columns(scalars=np.frombuffer(self.v).copy()))
        self.t = array("d")
        self.v = array("d")


def _sync_origin(blf: Path, sync_id: int, tick_mask: int, dt_s: float) -> float | None:
    """min over the SYNCs of (timestamp - tick x period): when tick 0 was due."""
    best: float | None = None
    for ts, fid, _ext, _remote, is_error, _rx, _dlc, data, _ch in read_frames(blf):
        if fid == sync_id and not is_error and len(data) >= 4:
            tick = int.from_bytes(data, "little") & tick_mask
            o = ts - tick * dt_s
            if best is None or o < best:
                best = o
    return best


def write_bus(rec: rr.RecordingStream, blf: Path, dt_s: float, realtime: bool,
              dividers: Mapping[str, int], protocol: Protocol | None = None,
              block_rows: int = 10_000) -> BusStats:
    """Decode ``blf`` into ``rec`` (see the module docstring); returns counts."""
    protocol = protocol or load_protocol()
    by_id = protocol.by_id
    sync = protocol["SYNC"]
    sync_id = sync.frame_id
    device_of: dict[int, tuple[str, str]] = {}
    for device, (tlm, cmd) in DEVICES.items():
        device_of[protocol[tlm].frame_id] = (device, "tlm")
        if cmd is not None:
            device_of[protocol[cmd].frame_id] = (device, "cmd")
    device_of[protocol["HEARTBEAT"].frame_id] = ("harness", "heartbeat")
    device_of[sync_id] = ("harness", "sync")
    sink = _Sink(rec)
    frames = {fid: _Frames(sink, by_id[fid], [signal_entity(f"/bus/{dev}/{kind}", s.name, s.unit)
                                             for s in by_id[fid].signals], block_rows)
              for fid, (dev, kind) in device_of.items()}
    length = {fid: by_id[fid].length for fid in frames}
    tlm_device = {protocol[t].frame_id: d for d, (t, _) in DEVICES.items()}
    rx_after = {fid: _Series(sink, f"/bus/{d}/rx_after_sync_ms", block_rows)
                for fid, d in tlm_device.items()}
    missing_series = _Series(sink, "/bus/late_or_missing", block_rows)
    # the legends' names: the frame and signal (``WHEEL_CMD torque_cmd``), the device
    log_series_names(rec, [e for fid, f in frames.items() for e in f.entities],
                     {e: f"{by_id[fid].name} {s.name}" for fid, f in frames.items()
                      for e, s in zip(f.entities, by_id[fid].signals, strict=True)})
    log_series_names(rec, [r.entity for r in rx_after.values()] + [missing_series.entity])
    due = {d: int(dividers.get(d, 1)) for d in DEVICES if d in dividers}
    tick_mask = sync.signals[0].mask
    stats = BusStats()
    # real time: the schedule's start, from the SYNC least late against it (a first pass
    # over the SYNCs only; tick 0's own SYNC is often the latest of all)
    origin = _sync_origin(blf, sync_id, tick_mask, dt_s) if realtime else None
    first_sync_ts: float | None = None
    tick = -1
    sync_ts = 0.0
    prev_sync_ts: float | None = None
    seen: set[str] = set()
    clamp = LOCKSTEP_CLAMP * dt_s

    def close_tick() -> None:
        if tick < 0:
            return
        missing = [d for d, n in due.items() if tick % n == 0 and d not in seen]
        t_tick = tick * dt_s
        missing_series.add(t_tick, float(len(missing)))
        stats.ticks += 1
        if missing:
            stats.late_or_missing += len(missing)
            if len(stats.warnings) < MAX_WARNINGS:
                stats.warnings.append((t_tick, f"can log: no telemetry from {', '.join(missing)} "
                                       f"before the next SYNC (tick {tick}, t = "
                                       f"{t_tick:.3f} s)"))

    for ts, fid, _ext, _remote, is_error, _rx, _dlc, data, _ch in read_frames(blf):
        stats.frames += 1
        if is_error:
            stats.error_frames += 1
            continue
        out = frames.get(fid)
        if out is None:
            stats.unknown += 1
            continue
        if len(data) != length[fid]:
            stats.malformed += 1
            continue
        if fid == sync_id:
            close_tick()
            tick = int.from_bytes(data, "little") & tick_mask
            prev_sync_ts = sync_ts if first_sync_ts is not None else None
            sync_ts = ts
            seen = set()
            if first_sync_ts is None:
                first_sync_ts = ts
        if origin is not None:
            t = max(0.0, ts - origin)
        elif first_sync_ts is None:
            t = 0.0
        else:
            t = tick * dt_s + min(max(ts - sync_ts, 0.0), clamp)
        rx = rx_after.get(fid)
        if rx is not None and tick >= 0:
            if ts >= sync_ts or prev_sync_ts is None:
                seen.add(tlm_device[fid])
                rx.add(t, (ts - sync_ts) * 1e3)
            else:  # sent before this tick's SYNC, read after it: late for its own tick
                rx.add(t, (ts - prev_sync_ts) * 1e3)
        out.add(t, data)
        stats.decoded += 1
    close_tick()
    for f in frames.values():
        f.flush()
    for r in rx_after.values():
        r.flush()
    missing_series.flush()
    return stats
