"""Ctrl-C and SIGTERM in real time leave complete logs; random frames never crash a driver."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time

import can
import pytest
from rerun.chunk import RrdReader

from drivers.dbc import load_protocol
from harness.bus import CopyingVirtualBus
from harness.bus.rig_interface import RigInterface
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import VirtualRig

P = load_protocol()


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_a_realtime_run(tmp_path, sig):
    # the in-process rig thread can stall on a loaded machine: relax the monitor's grace
    run_file = tmp_path / "rt.yaml"
    run_file.write_text(
        "name: rt\nduration_s: 30\nclock: realtime\nmonitor: {realtime_grace_s: 2.0}\n"
        "controller: {type: pd_wheel, angle_deg: 20}\n")
    out_dir = tmp_path / "logs"
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness", "run", str(run_file), "--out", str(out_dir)],
        stderr=subprocess.PIPE, text=True)
    # wait until the loop runs (first progress line), then signal
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if "tick" in line:
            break
    time.sleep(1.5)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    (run_dir,) = [p for p in out_dir.iterdir() if p.is_dir()]  # beside: history.sqlite
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["stopped_by"] == "interrupted" and sig.name in summary["error"]
    ticks = summary["ticks"]
    assert 100 < ticks < 15000
    rows = sum(c.num_rows for c in RrdReader(run_dir / "run.rrd").stream().to_chunks()
               if c.entity_path == "/attitude/angle_deg" and not c.is_static)  # the legend's name
    assert rows == ticks
    frames = list(can.LogReader(str(run_dir / "can.blf")))
    syncs = [f for f in frames if f.arbitration_id == P["SYNC"].frame_id]
    assert len(syncs) == ticks
    wheel = [f for f in frames if f.arbitration_id == P["WHEEL_CMD"].frame_id]
    assert P["WHEEL_CMD"].decode(wheel[-1].data)["enable"] == 0


def _random_frame(rng: random.Random) -> can.Message:
    ids = list(P.by_id) + [rng.randrange(0x800) for _ in range(4)]
    frame_id = rng.choice(ids)
    length = rng.randrange(0, 9)
    return can.Message(arbitration_id=frame_id, data=bytes(rng.randrange(256)
                                                           for _ in range(length)),
                       is_extended_id=False, is_error_frame=rng.random() < 0.01)


def test_fuzz_random_frames_at_the_drivers_and_the_rig():
    rng = random.Random(7)
    rig_cfg = load_rig("sgsrt")
    a = CopyingVirtualBus(channel="fuzz-drivers")
    b = CopyingVirtualBus(channel="fuzz-drivers")
    try:
        iface = RigInterface(a, P, rig_cfg, None)
        rig = VirtualRig(rig_cfg, b, 0.002)
        sent = 0
        for tick in range(2000):
            for _ in range(10):
                msg = _random_frame(rng)
                b.send(msg)  # towards the harness's drivers
                a.send(msg)  # towards the virtual rig
                sent += 1
            iface.receive(tick, 0.0)
            while iface.receive(tick, 0.0):
                pass
            iface.snapshot(tick, tick * 0.002)
            rig.service()
        assert sent == 20000
        malformed = sum(d.counters.malformed for d in iface.drivers.values())
        assert malformed > 0 and iface.counters.unknown > 0
        assert rig.counters.malformed > 0 and rig.counters.unknown > 0
    finally:
        a.shutdown()
        b.shutdown()
