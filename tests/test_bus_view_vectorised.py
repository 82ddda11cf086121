"""The bus view's vectorised decoder against the frame-by-frame decoder it replaced.

``harness.review.bus.write_bus`` places every frame of a run's CAN log on the timeline by
its tick (the last SYNC before it), computes each telemetry frame's receive offset (late
frames counted against the tick before) and the devices late or missing at each tick, a
few containers at a time with numpy. ``_reference`` below is the per-frame loop it replaced
(the same rules, one frame at a time); both must give the same series, counts and warnings
on lockstep and real-time logs, late frames and error frames included.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

import harness.review.bus as bus
from drivers.dbc import load_protocol
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.blf_frames import read_frames
from rig_models.faults import parse_fault


def _reference(blf: Path, dt_s: float, realtime: bool, dividers: dict[str, int]
               ) -> tuple[dict[str, list[tuple[float, float]]], dict]:  # type: ignore[type-arg]
    """Per series (a frame id's payloads, a device's receive offsets, late or missing):
    (t, value) in order, and the counts, one frame at a time."""
    protocol = load_protocol()
    sync = protocol["SYNC"]
    sync_id, tick_mask = sync.frame_id, sync.signals[0].mask
    ids = {protocol[t].frame_id for t, _ in bus.DEVICES.values()}
    ids |= {protocol[c].frame_id for _, c in bus.DEVICES.values() if c is not None}
    ids |= {protocol["HEARTBEAT"].frame_id, sync_id}
    length = {f: protocol.by_id[f].length for f in ids}
    tlm_device = {protocol[t].frame_id: d for d, (t, _) in bus.DEVICES.items()}
    due = {d: int(dividers.get(d, 1)) for d in bus.DEVICES if d in dividers}
    out: dict[str, list[tuple[float, float]]] = {}
    stats = {"frames": 0, "decoded": 0, "unknown": 0, "malformed": 0, "error_frames": 0,
             "ticks": 0, "late_or_missing": 0, "warnings": []}
    origin = None
    if realtime:
        for ts, fid, _e, _r, err, _x, _d, data, _c in read_frames(blf):
            if fid == sync_id and not err and len(data) >= 4:
                o = ts - (int.from_bytes(data, "little") & tick_mask) * dt_s
                origin = o if origin is None or o < origin else origin
    first: float | None = None
    prev: float | None = None
    tick, sync_ts = -1, 0.0
    seen: set[str] = set()

    def close() -> None:
        if tick < 0:
            return
        missing = [d for d, n in due.items() if tick % n == 0 and d not in seen]
        out.setdefault("missing", []).append((tick * dt_s, float(len(missing))))
        stats["ticks"] += 1
        if missing:
            stats["late_or_missing"] += len(missing)
            if len(stats["warnings"]) < bus.MAX_WARNINGS:
                stats["warnings"].append((tick * dt_s, ", ".join(missing), tick))

    for ts, fid, _e, _r, err, _x, _d, data, _c in read_frames(blf):
        stats["frames"] += 1
        if err:
            stats["error_frames"] += 1
            continue
        if fid not in ids:
            stats["unknown"] += 1
            continue
        if len(data) != length[fid]:
            stats["malformed"] += 1
            continue
        if fid == sync_id:
            close()
            tick = int.from_bytes(data, "little") & tick_mask
            prev = sync_ts if first is not None else None
            sync_ts = ts
            seen = set()
            first = ts if first is None else first
        if origin is not None:
            t = max(0.0, ts - origin)
        elif first is None:
            t = 0.0
        else:
            t = tick * dt_s + min(max(ts - sync_ts, 0.0), bus.LOCKSTEP_CLAMP * dt_s)
        if fid in tlm_device and tick >= 0:
            if ts >= sync_ts or prev is None:
                seen.add(tlm_device[fid])
                v = (ts - sync_ts) * 1e3
            else:
                v = (ts - prev) * 1e3
            out.setdefault(f"rx {tlm_device[fid]}", []).append((t, v))
        out.setdefault(f"frame {fid}", []).append((t, float(int.from_bytes(data, "little"))))
        stats["decoded"] += 1
    close()
    return out, stats


def _vectorised(blf: Path, dt_s: float, realtime: bool, dividers: dict[str, int],
                monkeypatch: pytest.MonkeyPatch) -> tuple[dict, dict]:  # type: ignore[type-arg]
    got: dict[str, list[tuple[float, float]]] = {}
    protocol = load_protocol()
    rx_entity = {f"/bus/{d}/rx_after_sync_ms": f"rx {d}" for d in bus.DEVICES}

    def frames_add(self, t, word):  # noqa: ANN001, ANN202
        got.setdefault(f"frame {self.codec.frame_id}", []).extend(
            zip(np.asarray(t).tolist(), np.asarray(word, dtype=np.uint64).astype(float).tolist(),
                strict=True))

    def series_add(self, t, v):  # noqa: ANN001, ANN202
        name = "missing" if self.entity == "/bus/late_or_missing" else rx_entity[self.entity]
        got.setdefault(name, []).extend(zip(np.asarray(t).tolist(), np.asarray(v).tolist(),
                                            strict=True))

    monkeypatch.setattr(bus._Frames, "add_many", frames_add)
    monkeypatch.setattr(bus._Series, "add_many", series_add)
    stats = bus.write_bus(rr.RecordingStream("test-bus-view"), blf, dt_s, realtime, dividers,
                          protocol=protocol)
    d = asdict(stats)
    d["warnings"] = [(t, m.split("from ")[1].split(" before")[0],
                      int(m.split("(tick ")[1].split(",")[0])) for t, m in d["warnings"]]
    return got, d


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> list[tuple[Path, bool]]:  # type: ignore[type-arg]
    out = tmp_path_factory.mktemp("bus-view")
    runs = [({}, [], False),
            ({}, ["error_frames@0.5+0.3", "wrong_length@1.0+0.2:accelerometer"], False),
            ({"clock": "realtime"}, ["delay_frames@0.5+0.5:hub_sensor"], True),
            ({"clock": "realtime"}, ["drop_frames@0.5+0.5:reaction_wheel"], True)]
    made = []
    for overrides, faults, realtime in runs:
        res = execute_run(load_run("slew-rw", {"duration_s": 1.5, **overrides}), out_dir=out,
                          show_progress=False, faults=[parse_fault(f) for f in faults])
        made.append((res.run_dir / "can.blf", realtime))
    return made


@pytest.mark.slow
def test_the_vectorised_bus_view_is_the_frame_by_frame_one(logs, monkeypatch):
    dividers = {"hub_sensor": 1, "accelerometer": 1, "reaction_wheel": 1,
                "thruster_valves": 5, "piezo_amplifier": 1, "disturbance_rotor": 5}
    late = 0
    for blf, realtime in logs:
        for clock in {False, realtime}:  # a real-time log placed both ways
            want, want_stats = _reference(blf, 0.002, clock, dividers)
            got, got_stats = _vectorised(blf, 0.002, clock, dividers, monkeypatch)
            assert got_stats == want_stats, (blf.parent.name, clock)
            assert got.keys() == want.keys()
            for name, series in want.items():
                assert len(got[name]) == len(series), name
                assert all(a == b or (math.isnan(a[1]) and math.isnan(b[1]))
                           for a, b in zip(got[name], series, strict=True)), name
            late += want_stats["late_or_missing"]
    assert late > 0  # the faults made ticks with telemetry late or missing


def test_edge_cases_of_a_made_up_log(tmp_path, monkeypatch):
    """Frames before the first SYNC, a first tick with late frames (no SYNC before it),
    frames stamped exactly at their SYNC, frames sent before the SYNC they were read after,
    unknown ids, wrong lengths, error frames, a tick counter that jumps, over many blocks."""
    import random

    import can

    protocol = load_protocol()
    sync = protocol["SYNC"]
    tlm = [protocol[t] for t, _ in bus.DEVICES.values()]
    rng = random.Random(7)
    path = tmp_path / "made-up.blf"
    t0 = 1_800_000_000.0
    with can.BLFWriter(str(path)) as w:
        def put(t: float, fid: int, data: bytes, **kw: object) -> None:
            w.on_message_received(can.Message(timestamp=t, arbitration_id=fid, data=data,
                                              is_extended_id=False, **kw))
        for codec in tlm[:3]:  # before the first SYNC
            put(t0 - 0.001, codec.frame_id, bytes(codec.length))
        tick = 0
        for k in range(6000):
            ts = t0 + k * 0.002 + rng.uniform(0, 3e-4)
            if rng.random() < 0.02:
                tick += rng.randint(2, 9)  # a jump
            put(ts, sync.frame_id, sync.encode({"tick": tick}))
            for codec in tlm:
                r = rng.random()
                if r < 0.05:
                    continue  # missing
                at = ts if r < 0.15 else ts - rng.uniform(0, 4e-4) if r < 0.3 else \
                    ts + rng.uniform(0, 2e-3)
                put(at, codec.frame_id, bytes(rng.randrange(256) for _ in range(codec.length)))
            if rng.random() < 0.01:
                put(ts, 0x7A5, b"\x01")  # unknown
            if rng.random() < 0.01:
                put(ts, tlm[0].frame_id, b"\x00")  # wrong length
            if rng.random() < 0.01:
                w.on_message_received(can.Message(timestamp=ts, is_error_frame=True,
                                                  arbitration_id=0x20000004))
            tick += 1
    dividers = {d: rng.choice([1, 1, 2, 5]) for d in bus.DEVICES}
    for realtime in (False, True):
        want, want_stats = _reference(path, 0.002, realtime, dividers)
        got, got_stats = _vectorised(path, 0.002, realtime, dividers, monkeypatch)
        assert got_stats == want_stats, realtime
        assert got == want, realtime
    assert want_stats["late_or_missing"] > 0 and want_stats["malformed"] > 0
