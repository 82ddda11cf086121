"""Real-time measures are requested by default in real-time runs; a refused one is a warning
recorded in the summary; the virtual rig runs in its own process over a Unix socket."""

from __future__ import annotations

import os

import can
import pytest

from harness.bus import parse_bus
from harness.bus.unix import UnixCanBus, UnixCanServerBus
from harness.core.clock import RealTimeClock, RealTimeSetup
from harness.core.runs import load_run
from harness.core.session import REALTIME_RIG_DEFAULT, execute_run, virtual_rig_mode
from rig_models.faults import make_fault


def _rt_run(tmp_path, over=None, **kw):
    data = {"duration_s": 1.0, "monitor": {"realtime_grace_s": 1.0}}
    data.update(over or {})
    return execute_run(load_run("slew-rw", data), out_dir=tmp_path, clock="realtime",
                       show_progress=False, **kw)


def test_measures_requested_by_default_and_recorded(tmp_path):
    s = _rt_run(tmp_path).summary
    m = s["realtime_measures"]
    assert any(r.startswith("SCHED_FIFO priority 50") for r in m["requested"])
    assert "mlockall" in m["requested"]
    assert any(r.startswith("cpu affinity") for r in m["requested"])
    for r in m["requested"]:  # each one granted or refused, never lost
        assert any(x.startswith(r) for x in m["applied"] + m["refused"]), r
    assert s["virtual_rig_mode"] == REALTIME_RIG_DEFAULT
    assert s["stopped_by"] == "completed"
    assert s["frames"]["received"] > 0.8 * 5 * s["ticks"]
    # the rig process took its own memory measures and said how it answered each SYNC
    assert any(r.startswith("rig process mlockall") for r in m["requested"])
    assert any(r.startswith("rig process gc.freeze") for r in m["applied"])
    t = s["virtual_rig_timing"]
    assert t["syncs"] == s["ticks"]  # one per tick, the last answered before the stop
    assert 0 < t["wake_ms"]["p50"] <= t["wake_ms"]["p99"] <= t["wake_ms"]["max"]
    assert 0 < t["work_ms"]["p50"] <= t["work_ms"]["max"]
    f = s["frames"]
    assert f["missing_in_ticks_held_by_both"] + f["missing_in_ticks_host_delayed"] \
        == f["missing_in_ticks_on_time"]
    # everything undone after the run
    assert os.sched_getscheduler(0) == os.SCHED_OTHER


def test_refused_measure_is_a_warning_and_recorded(tmp_path, monkeypatch, capsys):
    def refuse(*_a, **_k):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    res = _rt_run(tmp_path, {"realtime": {"virtual_rig": "thread"}})
    s = res.summary
    assert s["stopped_by"] == "completed"  # the run goes on without it
    refused = s["realtime_measures"]["refused"]
    assert refused and refused[0].startswith("SCHED_FIFO priority 50: ")
    assert "Operation not permitted" in refused[0]
    assert "WARNING: real-time measure not granted: SCHED_FIFO" in capsys.readouterr().err


def test_measures_opt_out(tmp_path):
    s = _rt_run(tmp_path, {"realtime": {"sched_fifo": False, "lock_memory": False,
                                        "pin_cpu": False, "gc_freeze": False,
                                        "virtual_rig": "thread"}}).summary
    assert s["realtime_measures"] == {"requested": [], "applied": [], "refused": []}
    assert s["virtual_rig_mode"] == "thread"


def test_rig_mode_choice():
    run = load_run("slew-rw")
    virt = parse_bus("virtual:sgsrt")
    assert virtual_rig_mode(run, virt, "lockstep") == "lockstep"
    assert virtual_rig_mode(run, virt, "realtime") == REALTIME_RIG_DEFAULT
    assert virtual_rig_mode(run, virt, "realtime", rig_process=True) == "process-tcp"
    assert virtual_rig_mode(run, parse_bus("socketcan:vcan0"), "realtime") == "external"
    # a fault with a duration goes to the rig process like any other
    timed = make_fault({"kind": "silent_sensor", "at_s": 0.5, "device": "hub_sensor",
                        "duration_s": 0.2}, "test")
    assert virtual_rig_mode(run, virt, "realtime", faults=[timed]) == REALTIME_RIG_DEFAULT


def test_clock_never_spins_a_whole_period(monkeypatch):
    clock = RealTimeClock(0.002)
    assert clock.spin_s <= 0.0002
    sleeps = []
    monkeypatch.setattr("time.sleep", lambda s: sleeps.append(s))
    clock.t0 = __import__("time").perf_counter() + 0.0015
    clock.wait(0)
    assert sleeps and sleeps[0] > 0.001  # slept, then spun at most spin_s


def test_setup_restores_what_it_changed(monkeypatch):
    before = os.sched_getaffinity(0)
    setup = RealTimeSetup().apply(False, 50, -1, False, True)
    assert len(os.sched_getaffinity(0)) == 1
    import gc

    assert not gc.isenabled()
    setup.restore()
    assert gc.isenabled() and os.sched_getaffinity(0) == before


def test_unix_bus_keeps_frame_semantics():
    server = UnixCanServerBus("test-" + str(os.getpid()))
    client = UnixCanBus("test-" + str(os.getpid()))
    try:
        sent = [can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False),
                can.Message(arbitration_id=0x1ABCDEF0, data=bytes(8), is_extended_id=True),
                can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=4,
                            is_extended_id=False)]
        for m in sent:
            client.send(m)
        got = [server.recv(1.0) for _ in sent]
        for a, b in zip(sent, got, strict=True):
            assert b is not None and a.equals(b, timestamp_delta=None, check_channel=False,
                                              check_direction=False)
        server.send(can.Message(arbitration_id=0x80, data=b"\x05\x00\x00\x00",
                                is_extended_id=False))
        back = client.recv(1.0)
        assert back is not None and back.arbitration_id == 0x80 and back.data == b"\x05\0\0\0"
        assert client.recv(0) is None
        with pytest.raises(ValueError, match="CAN FD"):
            client.send(can.Message(arbitration_id=1, is_fd=True, data=bytes(12)))
    finally:
        client.shutdown()
        server.shutdown()


def test_unix_bus_server_survives_a_client_that_leaves_with_frames_unread():
    # the harness closes its end while the rig's answers are still queued: the rig must
    # not die on ECONNRESET (it used to, with a traceback in rig.log, losing its timing)
    name = "reset-" + str(os.getpid())
    server = UnixCanServerBus(name)
    try:
        client = UnixCanBus(name)
        client.send(can.Message(arbitration_id=0x80, data=bytes(4), is_extended_id=False))
        assert server.recv(1.0) is not None  # accepted and read
        for _ in range(5):  # answers the client will never read
            server.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
        client.shutdown()
        assert server.recv(0.2) is None  # the peer left: no frame, no exception
        again = UnixCanBus(name)  # and the next client is served
        again.send(can.Message(arbitration_id=0x80, data=bytes(4), is_extended_id=False))
        assert server.recv(1.0) is not None
        again.shutdown()
    finally:
        server.shutdown()
