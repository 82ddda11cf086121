"""What a run recorded and checked, as one JSON file, to compare two versions of the code
(a tick made cheaper must not change what a run records or checks).

    PYTHONPATH=<checkout> python tools/run_digest.py OUT.json [--quick]

runs lockstep slew-rw and fault runs on sgsrt and sgsrt-canopen and writes, per run: every
frame of can.blf as python-can's BLFReader reads it (timestamp, id, flags, dlc, data,
channel), summary.json without its timing fields, every event the run logged (the monitor's
warnings and faults, the harness's) and every recorded channel but /timing. The wall clock
the frames are stamped with is replaced, for the whole process, by a counter that advances
1 us a call, so two versions that read the clock equally often give identical timestamps;
on a CANopen rig the set-up's threads (SDO, boot-up) read it too and make such a count
differ from run to run, so there the wall clock stays and the timestamps are left out.
Compare two outputs with ``python tools/run_digest.py --diff A.json B.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

RUNS: list[tuple[str, str, list[str]] | tuple[str, str, list[str], dict[str, Any]]] = [
    # (name, rig, faults[, overrides])
    ("slew-rw", "sgsrt", []),
    ("slew-rw", "sgsrt", ["drop_frames@3:hub_sensor"]),
    ("slew-rw", "sgsrt", ["silent_sensor@3:disturbance_rotor"]),
    ("slew-rw", "sgsrt", ["delay_frames@3:accelerometer"]),
    ("slew-rw", "sgsrt", ["stuck_sensor@3:hub_sensor"]),
    ("slew-rw", "sgsrt", ["wrong_length@3:reaction_wheel"]),
    ("slew-rw", "sgsrt", ["unknown_ids@3"]),
    ("slew-rw", "sgsrt", ["valve_stuck_open@3"]),
    ("slew-rw", "sgsrt", ["error_frames@3"]),
    ("slew-rw", "sgsrt", ["wheel_overspeed@3"]),
    ("slew-rw", "sgsrt-canopen", []),
    ("slew-rw", "sgsrt-canopen", ["node_heartbeat_lost@3:reaction_wheel"]),
    ("slew-rw", "sgsrt-canopen", ["drop_frames@3:hub_sensor"]),
    ("slew-rw", "sgsrt-canopen", ["node_emcy@3:accelerometer"]),
    ("slew-rw", "sgsrt-canopen", ["silent_sensor@3:disturbance_rotor"]),
    ("thruster-csvs12-oppf", "sgsrt", []),
    # the monitor's warnings: the wheel near its speed and torque limits; every level low
    ("tests/fixtures/runs/wheel-near-limit.yaml", "sgsrt", [],
     {"limits": {"max_wheel_speed_rad_s": 60.0}}),
    ("slew-rw", "sgsrt", [], {"duration_s": 12.0, "monitor": {
        "warn_limits_fraction": 0.05, "warn_accel_range_fraction": 0.005,
        "warn_wheel_speed_fraction": 0.05, "warn_torque_saturated_s": 0.0}}),
]
TIMING_KEYS = ("wall_time_s", "real_time_factor", "lateness_ms", "work_ms", "timing",
               "loop_work", "started_utc", "run_dir")


REAL_TIME = time.time


def _fake_clock() -> None:
    lock = threading.Lock()
    counter = itertools.count()

    def fake_time() -> float:
        with lock:
            return 1.7e9 + next(counter) * 1e-6

    time.time = fake_time  # type: ignore[assignment]


def _strip(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _strip(v) for k, v in d.items()
                if not any(t in k for t in TIMING_KEYS)}
    if isinstance(d, list):
        return [_strip(v) for v in d]
    return d


def digest(out: Path, quick: bool) -> dict[str, Any]:
    import can

    from harness.core.runs import load_run
    from harness.core.session import execute_run
    from harness.record.recording import Recorder
    from rig_models.faults import parse_fault

    events: list[list[Any]] = []
    own_log, own_queue = Recorder.log_event, Recorder.queue_event

    def log_event(self, time_s, entity, text, level="WARN"):  # noqa: ANN001, ANN202
        events.append([time_s, entity, text, level])
        return own_log(self, time_s, entity, text, level)

    def queue_event(self, time_s, entity, text, level="WARN", *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
        events.append([time_s, entity, text, level])
        return own_queue(self, time_s, entity, text, level, *a, **k)

    Recorder.log_event, Recorder.queue_event = log_event, queue_event
    result: dict[str, Any] = {}
    for name, rig, faults, *more in RUNS:
        events.clear()
        canopen = "canopen" in rig
        if canopen:
            time.time = REAL_TIME
        else:
            _fake_clock()
        key = f"{name}:{rig}:{','.join(faults) or 'clean'}" + (
            f":{json.dumps(more[0])}" if more else "")
        over: dict[str, Any] = {"rig": rig}
        if quick or faults:
            over["duration_s"] = 6.0 if faults else 10.0
        if more:
            over.update(more[0])
        res = execute_run(load_run(name, over), out_dir=out, show_progress=False,
                          faults=[parse_fault(f) for f in faults])
        frames = [[None if canopen else m.timestamp, m.arbitration_id, m.is_extended_id, m.is_rx,
                   m.is_error_frame, m.is_remote_frame, m.dlc, m.data.hex(), m.channel]
                  for m in can.BLFReader(str(res.run_dir / "can.blf"))]
        cols = res.columns()
        channels = {}
        for ch in cols._channels:
            if ch.startswith("/timing"):
                continue
            t, v = cols._channels[ch]
            channels[ch] = hashlib.sha256(t.tobytes() + v.tobytes()).hexdigest()
        result[key] = {"frames": frames, "summary": _strip(res.summary),
                       "events": list(events), "channels": channels}
        print(f"{key}: {len(frames)} frames, stopped_by {res.summary['stopped_by']}, "
              f"{len(events)} events", file=sys.stderr)
        del res
    return result


def diff(a_path: Path, b_path: Path) -> int:
    a, b = json.loads(a_path.read_text()), json.loads(b_path.read_text())
    bad = 0
    for key in sorted(set(a) | set(b)):
        if key not in a or key not in b:
            print(f"{key}: only in one")
            bad += 1
            continue
        for part in ("frames", "summary", "events", "channels"):
            x, y = a[key][part], b[key][part]
            if x == y:
                continue
            bad += 1
            if part == "frames":
                n = next((i for i, (p, q) in enumerate(zip(x, y, strict=False)) if p != q),
                         min(len(x), len(y)))
                print(f"{key}: frames differ: {len(x)} vs {len(y)}, first at {n}: "
                      f"{x[n] if n < len(x) else None} vs {y[n] if n < len(y) else None}")
            elif part == "summary":
                ks = sorted(k for k in set(x) | set(y) if x.get(k) != y.get(k))
                print(f"{key}: summary differs in {ks}")
            else:
                print(f"{key}: {part} differ: {x if part == 'events' else ''} vs "
                      f"{y if part == 'events' else ''}")
        if all(a[key][p] == b[key][p] for p in ("frames", "summary", "events", "channels")):
            print(f"{key}: identical ({len(a[key]['frames'])} frames, "
                  f"{len(a[key]['events'])} events, {len(a[key]['channels'])} channels)")
    print("IDENTICAL" if not bad else f"{bad} DIFFERENCES")
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", type=Path)
    ap.add_argument("--quick", action="store_true", help="clean runs of 10 s, not their own")
    ap.add_argument("--diff", nargs=2, type=Path)
    args = ap.parse_args()
    if args.diff:
        return diff(*args.diff)
    with tempfile.TemporaryDirectory() as tmp:
        args.out.write_text(json.dumps(digest(Path(tmp), args.quick)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
