"""The virtual rig in its own process on the wall clock, stalled by its host: its devices
judge the harness's frames by when they came, as real devices that never stall would, so
frames that waited in the socket are not a lost heartbeat; a harness that really stops
sending still trips the watchdog."""

from __future__ import annotations

import threading
import time
import uuid

import can

from rig_models.rig_file import load_rig
from rig_models.virtual_rig import VirtualRig

PERIOD_S = 0.02


def _drive(stall_once_s: float, silent_from_s: float | None, length_s: float = 1.0) -> int:
    """Run the rig's own-process loop on a virtual bus while a sender plays the harness
    (armed heartbeat and SYNC every 20 ms, or nothing from ``silent_from_s``); the rig's
    loop stalls ``stall_once_s`` once, right after the first heartbeat it handles. The
    watchdog's trips."""
    ch = f"stall-{uuid.uuid4().hex}"
    rig_bus = can.Bus(interface="virtual", channel=ch)
    harness = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    rig = VirtualRig(load_rig("sgsrt"), rig_bus, 0.002)
    binding = rig.binding
    hb_id, _ = binding.heartbeat.key  # type: ignore[union-attr]
    sync_id, _ = binding.sync.key
    handle = rig.handle
    stalled = []

    def handle_then_stall(msg: can.Message) -> None:
        handle(msg)
        if msg.arbitration_id == hb_id and not stalled:
            stalled.append(True)
            time.sleep(stall_once_s)  # the host took the CPU: frames queue in the socket

    rig.handle = handle_then_stall  # type: ignore[method-assign]
    done = threading.Event()
    loop = threading.Thread(target=rig.run_forever, args=(done.is_set,), daemon=True)
    loop.start()
    try:
        t0 = time.monotonic()
        tick = 0
        while (now := time.monotonic() - t0) < length_s:
            if silent_from_s is None or now < silent_from_s:
                for fid, data in ((sync_id, binding.sync.encode(tick)),
                                  (hb_id, binding.heartbeat.encode(tick, True))):
                    harness.send(can.Message(arbitration_id=fid, data=data,
                                             is_extended_id=False, timestamp=time.time()))
                tick += 1
            time.sleep(PERIOD_S)
    finally:
        done.set()
        loop.join(5.0)
        harness.shutdown()
        rig_bus.shutdown()
    return rig.counters.watchdog_trips


def test_frames_that_waited_for_a_stalled_rig_process_are_no_lost_heartbeat():
    # 0.4 s stalled, past the rig's 0.25 s watchdog; the heartbeats came every 20 ms
    assert load_rig("sgsrt").data["watchdog"]["heartbeat_timeout_s"] < 0.4
    assert _drive(stall_once_s=0.4, silent_from_s=None) == 0


def test_a_harness_that_stops_sending_still_trips_the_watchdog():
    assert _drive(stall_once_s=0.0, silent_from_s=0.3) == 1
