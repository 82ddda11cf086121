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

The CAN log is streamed a few containers at a time (``harness.record.blf_frames``, arrays
of frames) and each block placed with numpy (a frame's tick from the running count of
SYNCs, the rules above; tests/test_bus_view_vectorised.py holds them against a frame-by-
frame decoder); each frame id's payloads are kept as integers in blocks of about
``block_rows``, decoded with numpy by the DBC's fields (``drivers.dbc``) and sent with
``send_columns``, so memory does not grow with the run's length. It runs after the run,
before run.rrd is closed, never in the tick.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr

from drivers.binding import SGSRT_FRAMES
from drivers.dbc import FrameCodec, Protocol, load_protocol
from harness.record.blf_frames import read_blocks
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

    def add_many(self, t: np.ndarray, word: np.ndarray) -> None:
        """Frames at times ``t`` with payloads ``word`` (each a little-endian integer)."""
        self.t.frombytes(np.ascontiguousarray(t, dtype=np.float64).tobytes())
        self.word.frombytes(np.ascontiguousarray(word, dtype=np.uint64).tobytes())
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

    def add_many(self, t: np.ndarray, v: np.ndarray) -> None:
        self.t.frombytes(np.ascontiguousarray(t, dtype=np.float64).tobytes())
        self.v.frombytes(np.ascontiguousarray(v, dtype=np.float64).tobytes())
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
    for block in read_blocks(blf):
        sel = ((block.arbitration_id == sync_id) & ~block.is_error_frame
               & (block.length >= 4))
        if sel.any():
            ticks = (block.word[sel] & np.uint64(tick_mask)).astype(np.int64)
            o = float(np.min(block.timestamp[sel] - ticks * dt_s))
            if best is None or o < best:
                best = o
    return best


def write_bus(rec: rr.RecordingStream, blf: Path, dt_s: float, realtime: bool,
              dividers: Mapping[str, int], protocol: Protocol | None = None,
              block_rows: int = 10_000, fault_insertion_id: int | None = None) -> BusStats:
    """Decode ``blf`` into ``rec`` (see the module docstring); returns counts.
    ``fault_insertion_id``: the rig's fault-insertion frame (the harness's, counted as
    decoded, not unknown)."""
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
    # vectorised over each container of the log (harness.record.blf_frames.read_blocks),
    # frame for frame what a loop over the frames gives: a frame's tick is its last SYNC's
    known = np.array(sorted(frames), dtype=np.int64)
    frame_length = np.array([length[f] for f in known.tolist()], dtype=np.int64)
    due_items = list(due.items())
    due_n = np.array([n for _, n in due_items], dtype=np.int64)
    due_col = {fid: next(k for k, (d, _) in enumerate(due_items) if d == dev)
               for fid, dev in tlm_device.items() if dev in due}
    clamp = LOCKSTEP_CLAMP * dt_s
    nan = math.nan
    # the open tick, carried from block to block: its number, its SYNC's timestamp, the
    # SYNC's before it (NaN: none), the first SYNC's (NaN: none yet), the due devices seen
    tick, sync_ts, prev_ts, first_ts = -1, 0.0, nan, nan
    seen_open = np.zeros(len(due_items), dtype=bool)

    def close_ticks(ticks: np.ndarray, seen: np.ndarray) -> None:
        """Closed ticks (and the due devices seen in each): the late-or-missing count at
        each tick and the first warnings."""
        keep = ticks >= 0
        ticks, seen = ticks[keep], seen[keep]
        if not len(ticks):
            return
        missing = ((ticks[:, None] % due_n[None, :]) == 0) & ~seen
        counts = missing.sum(axis=1)
        t_ticks = ticks * dt_s
        missing_series.add_many(t_ticks, counts.astype(np.float64))
        stats.ticks += len(ticks)
        stats.late_or_missing += int(counts.sum())
        for k in np.flatnonzero(counts).tolist():
            if len(stats.warnings) >= MAX_WARNINGS:
                break
            names = ", ".join(due_items[j][0] for j in np.flatnonzero(missing[k]).tolist())
            t_tick = float(t_ticks[k])
            stats.warnings.append((t_tick, f"can log: no telemetry from {names} before the "
                                   f"next SYNC (tick {int(ticks[k])}, t = {t_tick:.3f} s)"))

    for block in read_blocks(blf):
        stats.frames += len(block.timestamp)
        err = block.is_error_frame
        stats.error_frames += int(err.sum())
        fid_all = block.arbitration_id
        at = np.minimum(np.searchsorted(known, fid_all), len(known) - 1)
        is_known = (known[at] == fid_all) & ~err
        not_known = ~err & ~is_known
        if fault_insertion_id is not None:
            fi = not_known & (fid_all == fault_insertion_id)
            stats.decoded += int(fi.sum())
            not_known &= ~fi
        stats.unknown += int(not_known.sum())
        ok = is_known & (block.length == frame_length[at])
        stats.malformed += int((is_known & ~ok).sum())
        n_ok = int(ok.sum())
        if not n_ok:
            continue
        stats.decoded += n_ok
        ts, fid, word = block.timestamp[ok], fid_all[ok], block.word[ok]
        is_sync = fid == sync_id
        k = np.cumsum(is_sync)  # the frame's SYNC: 0 the open tick's, j the block's j-th
        s_tick = (word[is_sync] & np.uint64(tick_mask)).astype(np.int64)
        s_ts = ts[is_sync]
        n_sync = len(s_ts)
        # a SYNC's "SYNC before it": the one before in the block, or for the block's first
        # the open tick's (none if no SYNC came yet)
        s_prev = np.concatenate(([sync_ts if not math.isnan(first_ts) else nan],
                                 s_ts[:-1])) if n_sync else s_ts
        tick_of = np.concatenate(([tick], s_tick))
        ts_of = np.concatenate(([sync_ts], s_ts))
        prev_of = np.concatenate(([prev_ts], s_prev))
        f_tick, f_sync, f_prev = tick_of[k], ts_of[k], prev_of[k]
        if origin is not None:
            t = np.maximum(0.0, ts - origin)
        else:
            t = f_tick * dt_s + np.minimum(np.maximum(ts - f_sync, 0.0), clamp)
            if math.isnan(first_ts):  # frames before the first SYNC: at the first tick
                t[k == 0] = 0.0
        if math.isnan(first_ts) and n_sync:
            first_ts = float(s_ts[0])
        # receive offsets and the devices seen in each of the block's ticks
        seen = np.zeros((n_sync + 1, len(due_items)), dtype=bool)
        seen[0] = seen_open
        for f, rx in rx_after.items():
            sel = (fid == f) & (f_tick >= 0)
            if not sel.any():
                continue
            on_time = (ts[sel] >= f_sync[sel]) | np.isnan(f_prev[sel])
            rx.add_many(t[sel], np.where(on_time, ts[sel] - f_sync[sel],
                                         ts[sel] - f_prev[sel]) * 1e3)
            col = due_col.get(f)
            if col is not None:
                seen[k[sel][on_time], col] = True
        close_ticks(tick_of[:n_sync], seen[:n_sync])
        tick, sync_ts, prev_ts = int(tick_of[-1]), float(ts_of[-1]), float(prev_of[-1])
        seen_open = seen[n_sync]
        for f in np.unique(fid).tolist():
            sel = fid == f
            frames[f].add_many(t[sel], word[sel])
    close_ticks(np.array([tick]), seen_open[None, :])
    for f in frames.values():
        f.flush()
    for r in rx_after.values():
        r.flush()
    missing_series.flush()
    return stats
