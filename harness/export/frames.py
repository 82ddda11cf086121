"""The CAN frames of can.blf on the run's time axis, with their direction, block by block.

A channel's sample of tick k is at k x period (the loop's ``time`` timeline); can.blf
stamps each frame with the host's clock. The recording's own bus view
(``harness.review.bus`` for the sgsrt protocol, ``harness.review.bus_binding`` for any other
binding) already places every frame on the run's time, and the export places them by the
same rules, so a frame sits where the viewer shows it:

- a frame's tick is the last SYNC before it (the SYNC frame of the run's binding, its tick
  counter unwrapped as ``bus_binding`` does for a counter that wraps: CANopen's 1..240);
- lockstep (the host's clock is not the run's: a tick takes microseconds of wall time):
  tick x period plus the frame's host-clock offset after its SYNC, clamped below
  ``LOCKSTEP_CLAMP`` of the period (it stays in its tick); a SYNC is exactly at its tick's
  time, the time of that tick's row of channels;
- real time: the host time stamp minus the host time at which tick 0 was due (sgsrt: the
  smallest SYNC time stamp - tick x period over the log, ``harness.review.bus``'s first
  pass; another binding: the first SYNC's time stamp, as ``bus_binding``), never below 0;
- frames before the first SYNC are at 0.

Run times are taken to whole nanoseconds as the recording takes the channels' (Rerun
truncates seconds to integer nanoseconds), so a SYNC's time and its tick's channel time
are the same float. The host time stamp stays beside it (``host_time_s``, POSIX seconds).

The direction is can.blf's own: the recorder marks what the harness sent (``is_rx``
False, the BLF direction flag) apart from what it received.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from harness.export.source import ExportError


@dataclass
class Frames:
    """A block of CAN frames: run time (s), host time stamp (POSIX s), id, extended, error
    frame, sent by the harness (Tx), data length, and the data as 8 bytes a frame (zero
    past the length)."""

    time_s: np.ndarray
    host_time_s: np.ndarray
    can_id: np.ndarray
    extended: np.ndarray
    error: np.ndarray
    tx: np.ndarray
    length: np.ndarray
    data: np.ndarray  # (n, 8) uint8


FRAME_FIELDS = ("time_s", "host_time_s", "can_id", "extended", "error", "tx", "length",
                "data")


def joined(blocks: list[Frames]) -> Frames:
    return Frames(*(np.concatenate([getattr(b, k) for b in blocks]) for k in FRAME_FIELDS))


@dataclass
class _Block:
    """can.blf's frames as arrays (``harness.record.blf_frames``' blocks, with the
    direction)."""

    timestamp: np.ndarray
    can_id: np.ndarray
    extended: np.ndarray
    error: np.ndarray
    tx: np.ndarray
    length: np.ndarray
    word: np.ndarray  # uint64: the first 8 data bytes, little-endian, zero past the length


def _blocks(blf: Path, min_frames: int = 8192) -> Iterator[_Block]:
    """``harness.record.blf_frames.read_blocks`` with each frame's direction: its fast
    path (a container of CAN messages parsed with numpy) and python-can's parser for any
    other container, the same bounds on what a container may inflate to."""
    from can.io import blf as _blf

    from harness.record.blf_frames import _OBJ_BYTES, _containers

    parts: list[_Block] = []
    held = 0
    for fast, frames in _containers(blf):
        if fast is not None:
            objs, ts = fast
            raw_id = objs["can_id"].astype(np.int64)
            length = np.minimum(objs["dlc"], 8).astype(np.int64)
            word = np.frombuffer(objs.tobytes(), dtype="<u8")[5::_OBJ_BYTES // 8].copy()
            keep = np.where(length >= 8, np.uint64(0xFFFFFFFFFFFFFFFF),
                            (np.uint64(1) << (8 * length).astype(np.uint64)) - np.uint64(1))
            part = _Block(ts, raw_id & 0x1FFFFFFF, (raw_id & _blf.CAN_MSG_EXT) != 0,
                          np.zeros(len(objs), dtype=bool),
                          (objs["msg_flags"] & _blf.DIR) != 0, length, word & keep)
        elif frames:
            part = _Block(
                np.array([f[0] for f in frames], dtype=np.float64),
                np.array([f[1] for f in frames], dtype=np.int64),
                np.array([f[2] for f in frames], dtype=bool),
                np.array([f[4] for f in frames], dtype=bool),
                np.array([not f[5] for f in frames], dtype=bool),
                np.array([min(len(f[7]), 8) for f in frames], dtype=np.int64),
                np.array([int.from_bytes(f[7][:8], "little") for f in frames],
                         dtype=np.uint64))
        else:
            continue
        parts.append(part)
        held += len(part.timestamp)
        if held >= min_frames:
            yield _join(parts)
            parts, held = [], 0
    if parts:
        yield _join(parts)


def _join(parts: list[_Block]) -> _Block:
    if len(parts) == 1:
        return parts[0]
    return _Block(*(np.concatenate([getattr(p, k) for p in parts])
                    for k in ("timestamp", "can_id", "extended", "error", "tx", "length",
                              "word")))


@dataclass
class TimeBase:
    """How the run's frames map onto its time (see the module docstring)."""

    dt_s: float
    realtime: bool
    sync_key: tuple[int, bool]
    sync_length: int | None  # the sgsrt SYNC's length (its bus view takes no other)
    decode: Callable[[bytes], int]  # a SYNC's payload -> its tick counter
    modulus: int  # the counter wraps at this
    sgsrt: bool
    clock: str
    dbc_files: list[Path]
    eds_files: list[Path]
    used_frames: set[tuple[tuple[int, bool], str]]
    """(id, extended) and name of every frame the binding uses."""


def run_clock(meta: Mapping[str, Any], run_dir: Path) -> tuple[float, str]:
    """(period s, "lockstep" | "realtime") of the run: the rate from config.yaml's run
    (summary.json's when config.yaml has none), the clock from summary.json (the clock the
    run had: ``--clock`` may override the run file's), else config.yaml's run.clock."""
    run = (meta.get("config") or {}).get("run")
    run = run if isinstance(run, Mapping) else {}
    summary = meta.get("summary") or {}
    rate = run.get("rate_hz", summary.get("rate_hz"))
    if (isinstance(rate, bool) or not isinstance(rate, int | float) or not math.isfinite(rate)
            or not 0 < rate <= 1e6):
        raise ExportError(f"{run_dir / 'config.yaml'}: run.rate_hz: expected a number > 0 "
                          f"(Hz), got {str(rate)[:80]!r}")
    clock = summary.get("clock", run.get("clock", "lockstep"))
    if clock not in ("lockstep", "realtime"):
        raise ExportError(f"{run_dir / 'summary.json'}: clock: expected lockstep or "
                          f"realtime, got {str(clock)[:80]!r}")
    return 1.0 / float(rate), str(clock)


def time_base(meta: Mapping[str, Any], run_dir: Path) -> TimeBase:
    """The run's binding (config.yaml's rig, as the judge reads it) and clock; ExportError
    naming the key when the binding cannot be built (a DBC file no longer there)."""
    from drivers.binding import FAULT_INSERTION_NAME, BindingError, build_binding, resolve_file

    dt_s, clock = run_clock(meta, run_dir)
    rig = (meta.get("config") or {}).get("rig")
    if rig is not None and not isinstance(rig, Mapping):
        raise ExportError(f"{run_dir / 'config.yaml'}: rig: expected the rig file's data (a "
                          f"mapping), got {type(rig).__name__}")
    try:
        binding = build_binding(rig if isinstance(rig, Mapping) and rig else {"bus": {}})
    except (BindingError, OSError, ValueError) as exc:
        raise ExportError(f"{run_dir / 'config.yaml'}: rig: the run's binding "
                          f"(its SYNC frame puts the CAN frames on the run's time): "
                          f"{str(exc)[:300]}") from None
    sync = binding.sync
    sgsrt = binding.is_sgsrt()
    files = {Path(p) for p in binding.files.values()}
    bus = rig.get("bus") if isinstance(rig, Mapping) else None
    for key in ("sync", "heartbeat"):
        cfg = bus.get(key) if isinstance(bus, Mapping) else None
        if isinstance(cfg, Mapping) and cfg.get("dbc"):
            try:
                files.add(resolve_file(cfg["dbc"], f"bus.{key}.dbc", None))
            except BindingError:  # the binding was built: not reached
                pass
    dbc = sorted(p for p in files if p.suffix.lower() == ".dbc")
    eds = sorted(p for p in files if p.suffix.lower() != ".dbc")
    return TimeBase(dt_s, clock == "realtime", tuple(sync.key),  # type: ignore[arg-type]
                    int(sync.codec.length) if sgsrt else None, sync.decode,
                    int(getattr(sync, "modulus", 1 << 32)), sgsrt, clock, dbc, eds,
                    {(tuple(f.key), f.name) for f in binding.frames()}  # type: ignore[misc]
                    | ({(binding.fault_insertion, FAULT_INSERTION_NAME)}
                       if binding.fault_insertion is not None else set()))


def _ns(t: np.ndarray) -> np.ndarray:
    """Seconds to whole nanoseconds and back, as the recording takes the channels' times."""
    return (t * 1e9).astype(np.int64) * 1e-9


class FramePlacer:
    """Places blocks of frames on the run's time (the module docstring's rules), carrying
    the open tick from block to block."""

    def __init__(self, tb: TimeBase, blf: Path) -> None:
        from harness.review.bus import LOCKSTEP_CLAMP, _sync_origin

        self.tb = tb
        self.clamp = LOCKSTEP_CLAMP * tb.dt_s
        self.tick = -1
        self.raw_last: int | None = None
        self.sync_ts = math.nan
        self.first_sync_ts: float | None = None
        self.first_ts: float | None = None
        self.origin: float | None = None
        if tb.realtime and tb.sgsrt:
            # harness.review.bus's first pass: when tick 0 was due, from the least late SYNC
            try:
                self.origin = _sync_origin(blf, tb.sync_key[0], (1 << 32) - 1, tb.dt_s)
            except Exception as exc:  # noqa: BLE001 - python-can and zlib raise many kinds
                raise ExportError(f"{blf}: cannot read ({type(exc).__name__}: "
                                  f"{str(exc)[:200]})") from None

    def _sync_ticks(self, b: _Block) -> tuple[np.ndarray, np.ndarray]:
        """The block's SYNC frames (a mask) and their ticks, the counter unwrapped."""
        key_id, key_ext = self.tb.sync_key
        cand = (b.can_id == key_id) & (b.extended == key_ext) & ~b.error
        if self.tb.sync_length is not None:
            cand &= b.length == self.tb.sync_length
        idx = np.flatnonzero(cand)
        ticks = np.empty(len(idx), dtype=np.int64)
        keep = np.ones(len(idx), dtype=bool)
        decode, modulus = self.tb.decode, self.tb.modulus
        words, lengths = b.word[idx].tolist(), b.length[idx].tolist()
        for j, (w, n) in enumerate(zip(words, lengths, strict=True)):
            try:
                raw = int(decode(int(w).to_bytes(8, "little")[:n]))
            except Exception:  # noqa: BLE001 - a malformed SYNC is no SYNC (the bus view's)
                keep[j] = False
                continue
            self.tick = raw if self.raw_last is None else (
                self.tick + ((raw - self.raw_last) % modulus or 1))
            self.raw_last = raw
            ticks[j] = self.tick
        mask = np.zeros(len(b.timestamp), dtype=bool)
        mask[idx[keep]] = True
        return mask, ticks[keep]

    def place(self, b: _Block) -> np.ndarray:
        """Run times (s) of a block's frames."""
        ts = b.timestamp
        if self.first_ts is None and len(ts):
            self.first_ts = float(ts[0])
        open_tick, open_ts = self.tick, self.sync_ts
        is_sync, s_tick = self._sync_ticks(b)
        s_ts = ts[is_sync]
        k = np.cumsum(is_sync)  # 0: the open tick's frames, j: after the block's j-th SYNC
        f_tick = np.concatenate(([open_tick], s_tick))[k]
        f_sync = np.concatenate(([open_ts], s_ts))[k]
        no_sync = (f_tick < 0) | np.isnan(f_sync)
        if len(s_ts):
            if self.first_sync_ts is None:
                self.first_sync_ts = float(s_ts[0])
                if self.tb.realtime and not self.tb.sgsrt:
                    self.origin = self.first_sync_ts  # harness.review.bus_binding's rule
            self.sync_ts = float(s_ts[-1])
        if self.tb.realtime and self.origin is not None:
            t = np.maximum(0.0, ts - self.origin)
            if not self.tb.sgsrt:  # before the first SYNC: at 0 (bus_binding)
                t[np.isnan(f_sync)] = 0.0
        else:
            t = f_tick * self.tb.dt_s + np.minimum(np.maximum(ts - f_sync, 0.0), self.clamp)
            t[no_sync] = 0.0
        return _ns(t)

    @property
    def host_origin(self) -> float | None:
        """The host time of run time 0: real time, when tick 0 was due; lockstep, the first
        SYNC's time stamp (the first frame's without one)."""
        if self.tb.realtime and self.origin is not None:
            return self.origin
        return self.first_sync_ts if self.first_sync_ts is not None else self.first_ts


def frame_blocks(blf: Path, placer: FramePlacer) -> Iterator[Frames]:
    """can.blf's frames a few containers at a time, on the run's time (``placer``)."""
    try:
        for b in _blocks(blf):
            if not len(b.timestamp):
                continue
            data = b.word.astype("<u8").view(np.uint8).reshape(-1, 8)
            yield Frames(placer.place(b), b.timestamp.astype(np.float64),
                         b.can_id.astype(np.uint32), b.extended.astype(bool),
                         b.error.astype(bool), b.tx.astype(bool),
                         np.minimum(b.length, 8).astype(np.uint8), data)
    except ExportError:
        raise
    except Exception as exc:  # python-can and zlib raise many kinds for a damaged file
        raise ExportError(f"{blf}: cannot read ({type(exc).__name__}: "
                          f"{str(exc)[:200]})") from None
