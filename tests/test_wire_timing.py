"""Timing on the wire: the per-tick figures from synthetic time stamps, the bus watch taking
the kernel's echo (and a kernel-sent SYNC) as the harness's own frames, and what the summary
says on each kind of bus (in process, over socketcand) it can and cannot measure."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from drivers.dbc import load_protocol
from harness.bus.rig_interface import RigInterface
from harness.core.loop import CHANNELS
from harness.core.runs import load_run, run_path
from harness.core.session import RunRefused, execute_run
from harness.core.wire_timing import WireTiming
from harness.record.reader import read_scalar_channels
from rig_models.rig_file import load_rig

DT = 0.01


# ---------------------------------------------------------------------- the computation
def test_jitter_latency_and_margin_from_synthetic_time_stamps():
    w = WireTiming(DT, ("hub", "wheel"), "kernel")
    # tick 0: SYNC at 100.0, answers 0.3 ms and 0.5 ms after it, no command before it
    assert w.tick(100.0, math.nan, [("hub", 100.0003), ("wheel", 100.0005)])[0] != 0.0
    # tick 1: SYNC 0.2 ms late (period 10.2 ms); a stale hub frame stamped before the SYNC
    # (an answer to the previous one) is not this SYNC's answer; the command of tick 0 went
    # out at 100.008, 2.2 ms before this SYNC
    jit, latest, margin = w.tick(100.0102, 100.008, [
        ("hub", 100.0099), ("hub", 100.0106), ("hub", 100.0107), ("wheel", 100.0110)])
    assert jit == pytest.approx(0.2, abs=1e-6)
    assert latest == pytest.approx(0.8, abs=1e-6)  # the wheel's first answer
    assert margin == pytest.approx(2.2, abs=1e-6)
    # tick 2: SYNC 0.3 ms early; the command of tick 1 went out after it (negative margin)
    jit, latest, margin = w.tick(100.0199, 100.0201, [("hub", 100.0201)])
    assert jit == pytest.approx(-0.3, abs=1e-6)
    assert margin == pytest.approx(-0.2, abs=1e-6)
    # tick 3: no SYNC time stamp (its echo not read): nothing measured this tick
    assert all(math.isnan(x) for x in w.tick(math.nan, math.nan, [("hub", 100.03)]))
    s = w.summary()
    assert s["source"] == "kernel" and s["syncs_time_stamped"] == 3
    j = s["sync_period_jitter_ms"]
    assert j["max"] == pytest.approx(0.3, abs=2e-3)
    assert j["min_signed"] == pytest.approx(-0.3, abs=1e-6)
    assert j["max_signed"] == pytest.approx(0.2, abs=1e-6)
    hub = s["answer_latency_ms"]["hub"]  # 0.3, 0.4, 0.2 ms: the stale one left out
    assert hub["max"] == pytest.approx(0.4, abs=1e-6)
    assert hub["p50"] == pytest.approx(0.3, abs=2e-3)
    assert s["answer_latency_ms"]["wheel"]["max"] == pytest.approx(0.8, abs=1e-6)
    m = s["command_margin_ms"]
    assert m["min"] == pytest.approx(-0.2, abs=1e-6) and m["commands_after_next_sync"] == 1


def test_a_command_before_the_previous_sync_is_no_margin():
    """A tick without a command (a dry run) has no margin: the last command is older than
    the previous SYNC."""
    w = WireTiming(DT, ("hub",), "sender")
    w.tick(1.0, 0.5, [])
    assert math.isnan(w.tick(1.01, 0.5, [])[2])
    assert w.summary()["command_margin_ms"] is None


def test_lockstep_measures_latency_only_and_none_measures_nothing():
    w = WireTiming(DT, ("hub",), "kernel", paced=False)
    w.tick(5.0, math.nan, [("hub", 5.001)])
    jit, latest, margin = w.tick(5.5, 5.2, [("hub", 5.5002)])
    assert math.isnan(jit) and math.isnan(margin) and latest == pytest.approx(0.2, abs=1e-6)
    s = w.summary()
    assert s["sync_period_jitter_ms"] is None and s["command_margin_ms"] is None
    assert "not measured" in s["note"] and s["answer_latency_ms"]["hub"]["max"] > 0
    n = WireTiming(DT, ("hub",), "none")
    assert all(math.isnan(x) for x in n.tick(1.0, 0.9, [("hub", 1.001)]))
    s = n.summary()
    assert s["answer_latency_ms"] is None and s["sync_period_jitter_ms"] is None
    with pytest.raises(ValueError, match="source"):
        WireTiming(DT, (), "wall")


# ---------------------------------------------------------------------- the bus watch
class EchoBus:
    """A bus with an echo switch (as ``EchoSocketcanBus``) that records what is sent."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []
        self.echo = False
        self.periodic: list[tuple[can.Message, float]] = []

    def enable_echo(self, on: bool = True) -> None:
        self.echo = on

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return None

    def send_periodic(self, msg: can.Message, period: float) -> Any:
        self.periodic.append((msg, period))

        class Task:
            def __init__(self) -> None:
                self.data: list[bytes] = []

            def modify_data(self, m: can.Message) -> None:
                self.data.append(bytes(m.data))

            def stop(self) -> None:
                pass

        return Task()


def _interface(bus: EchoBus) -> RigInterface:
    return RigInterface(bus, load_protocol(), load_rig("sgsrt"), None,  # type: ignore[arg-type]
                        actuators=("reaction_wheel",))


def _own(iface: RigInterface, key: tuple[int, bool], ts: float, is_rx: bool) -> can.Message:
    return can.Message(arbitration_id=key[0], is_extended_id=key[1], data=b"\0" * 8,
                       timestamp=ts, is_rx=is_rx, check=False)


def test_the_kernels_echo_is_the_harness_own_frame_not_another_master():
    bus = EchoBus()
    iface = _interface(bus)
    sync_key = iface.binding.sync.key
    cmd_key = iface.binding.commands["reaction_wheel"][0].key
    # without the echo on, a SYNC the harness did not send is another master's
    iface.feed(_own(iface, sync_key, 1.0, is_rx=False), 0)
    assert iface.counters.foreign == 1
    iface = _interface(bus)
    assert iface.start_wire_timing() == "kernel" and bus.echo
    iface.feed(_own(iface, cmd_key, 2.001, is_rx=False), 0)
    iface.send_sync(1)
    iface.feed(_sync_echo(iface, 1, 2.005), 1)
    c = iface.counters
    assert c.foreign == 0 and c.received == 0 and c.unknown == 0
    assert iface.wire_sync_ts == 2.005 and iface.wire_prev_cmd_ts == 2.001
    # a SYNC from anyone else (is_rx) is still another master's
    iface.feed(_own(iface, sync_key, 2.006, is_rx=True), 1)
    assert c.foreign == 1
    # a device's answer is time stamped for its tick
    hub = iface.binding.telemetry["hub_sensor"][0]
    msg = can.Message(arbitration_id=hub.key[0], is_extended_id=hub.key[1], data=bytes(8),
                      timestamp=2.0053, is_rx=True, check=False)
    iface.feed(msg, 1)
    assert [(iface.device_of_driver[id(d)], ts) for d, ts in iface.wire_rx or []] == [
        ("hub_sensor", 2.0053)]


def _sync_echo(iface: RigInterface, tick: int, ts: float) -> can.Message:
    key = iface.binding.sync.key
    return can.Message(arbitration_id=key[0], is_extended_id=key[1],
                       data=iface._sync_payload(tick), timestamp=ts, is_rx=False, check=False)


def test_a_late_echo_of_an_earlier_sync_times_no_tick():
    """On a stalled host the echo of tick 1's SYNC may come only after tick 2's SYNC went
    out: it is known by its payload (the SYNC counter) and times no tick, so tick 2 is
    not measured rather than measured with tick 1's time."""
    bus = EchoBus()
    iface = _interface(bus)
    assert iface.start_wire_timing() == "kernel"
    iface.send_sync(1)
    iface.send_sync(2)
    iface.feed(_sync_echo(iface, 1, 3.000), 2)
    assert math.isnan(iface.wire_sync_ts) and iface.late_sync_echoes == 1
    assert iface.counters.foreign == 0 and iface.counters.received == 0
    iface.feed(_sync_echo(iface, 2, 3.002), 2)
    assert iface.wire_sync_ts == 3.002 and iface.late_sync_echoes == 1


def test_a_kernel_sent_sync_is_logged_as_the_harness_own_and_paces_the_loop():
    bus = EchoBus()
    iface = _interface(bus)
    iface.start_kernel_sync(DT)
    msg, period = bus.periodic[0]
    assert period == DT and bytes(msg.data) == iface._sync_payload(0)
    sync_key = iface.binding.sync.key
    # the broadcast manager's socket is not the harness's raw socket: is_rx, yet its own
    iface.feed(_own(iface, sync_key, 3.0, is_rx=True), 0)
    assert iface.counters.foreign == 0 and iface.counters.sent == 1
    # the next SYNC's counter (the kernel's SYNCs read so far) into the task; nothing sent
    iface.send_sync(0)
    assert bus.sent == [] and iface.kernel_sync.data == [  # type: ignore[union-attr]
        iface._sync_payload(1)]
    assert iface.wait_kernel_sync(1, 0.0) == 3.0 and iface.wire_sync_ts == 3.0
    assert iface.wait_kernel_sync(2, 0.0) is None  # no SYNC waiting, the bus silent


# ---------------------------------------------------------------------- whole runs
def _short_run(tmp_path: Path, name: str, **overrides: Any) -> str:
    raw = yaml.safe_load(run_path("slew-rw").read_text())
    raw.update(name=name, duration_s=0.4, rate_hz=100, **overrides)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return str(path)


def _channels(run_dir: Path) -> dict[str, Any]:
    return read_scalar_channels(run_dir / "run.rrd", [
        "/timing/sync_jitter_ms", "/timing/answer_latency_ms", "/timing/command_margin_ms"])


def test_in_process_lockstep_says_it_measures_nothing(tmp_path):
    r = execute_run(load_run(_short_run(tmp_path, "wire-lockstep")), out_dir=tmp_path,
                    show_progress=False)
    w = r.summary["wire_timing"]
    assert w["source"] == "none" and "no wire" in w["note"]
    assert w["sync_period_jitter_ms"] is None and w["answer_latency_ms"] is None
    assert {"/timing/sync_jitter_ms", "/timing/answer_latency_ms",
            "/timing/command_margin_ms"} <= set(CHANNELS)
    for _t, v in _channels(r.run_dir).values():
        assert len(v) == r.summary["ticks"] and all(math.isnan(x) for x in v)


@pytest.mark.parametrize("rig_mode", ["thread", "process-tcp"])
def test_real_time_in_process_and_over_socketcand_measure_sender_time_stamps(
        tmp_path, rig_mode):
    """The rig as a thread on the virtual bus, and as its own process over socketcand: the
    frames carry their senders' clocks, which the summary says."""
    # a loaded machine may hold a tick back for long: the monitor waits (as in CI's VM)
    r = execute_run(load_run(_short_run(
        tmp_path, f"wire-{rig_mode}", clock="realtime", realtime={"virtual_rig": rig_mode},
        monitor={"realtime_grace_s": 10.0, "startup_s": 10.0})),
        out_dir=tmp_path, show_progress=False)
    s = r.summary
    assert s["stopped_by"] == "completed", s["error"]
    if rig_mode == "process-tcp":
        assert s["bus"].startswith("socketcand:")
    w = s["wire_timing"]
    assert w["source"] == "sender" and "no transport delay" in w["note"]
    assert w["sync_sent_by"] == "loop" and w["syncs_time_stamped"] == s["ticks"]
    assert w["sync_period_jitter_ms"]["max"] >= 0.0
    assert set(w["answer_latency_ms"]) >= {"hub_sensor", "accelerometer", "reaction_wheel"}
    for p in w["answer_latency_ms"].values():
        assert 0.0 <= p["p50"] <= p["max"]
    assert w["command_margin_ms"]["p50"] > 0.0
    ch = _channels(r.run_dir)
    lat = ch["/timing/answer_latency_ms"][1]
    assert len(lat) == s["ticks"] and any(not math.isnan(x) for x in lat)
    assert math.isnan(ch["/timing/sync_jitter_ms"][1][0])  # no period before the first SYNC


def test_kernel_sync_is_refused_on_a_bus_without_a_broadcast_manager(tmp_path):
    run = load_run(_short_run(tmp_path, "wire-kernel", clock="realtime",
                              sync_source="kernel"))
    with pytest.raises(RunRefused, match="sync_source: kernel needs a SocketCAN bus"):
        execute_run(run, out_dir=tmp_path / "out", show_progress=False)
    assert not (tmp_path / "out").exists() or not any(
        p.is_dir() for p in (tmp_path / "out").iterdir())
    with pytest.raises(RunRefused, match="needs --clock realtime"):
        execute_run(run, out_dir=tmp_path / "out", bus="socketcan:vcan0", clock="lockstep",
                    show_progress=False)


def test_a_bus_without_a_broadcast_manager_and_a_kernel_sync_that_never_comes():
    from harness.bus import CopyingVirtualBus
    from harness.bus.socketcan_echo import broadcast_manager_missing
    from harness.core.clock import KernelSyncClock, KernelSyncLost

    bus = CopyingVirtualBus(channel="wire-no-bcm")
    try:
        assert "not a SocketCAN bus" in (broadcast_manager_missing(bus) or "")
    finally:
        bus.shutdown()

    class NoBcm:
        def start_kernel_sync(self, dt_s: float) -> None:
            raise OSError(93, "Protocol not supported")

        def wait_kernel_sync(self, tick: int, timeout_s: float) -> float | None:
            return None

    clock = KernelSyncClock(DT, NoBcm())
    with pytest.raises(KernelSyncLost, match="did not start SYNC"):
        clock.start()
    with pytest.raises(KernelSyncLost, match="no SYNC from the kernel"):
        clock.wait(3)


def test_the_suite_report_shows_the_wire_timing_beside_the_loops_lateness(tmp_path):
    """report.md / report.html: each run's timing line, the loop's lateness and what the
    frames' time stamps say (or, in lockstep in process, that there is no wire)."""
    from harness.testing.report import timing_line

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    measured = {"lateness_ms": {"p50": 0.1, "p99": 0.4, "max": 2.0},
                "wire_timing": {"source": "kernel", "sync_sent_by": "kernel", "note": "n",
                                "sync_period_jitter_ms": {"p50": 0.02, "p99": 0.3, "max": 1.0},
                                "answer_latency_ms": {
                                    "hub_sensor": {"p50": 0.1, "p99": 0.2, "max": 0.3},
                                    "reaction_wheel": {"p50": 0.3, "p99": 0.9, "max": 1.1}},
                                "command_margin_ms": {"p50": 1.5, "p99": 1.9, "max": 1.95,
                                                      "min": 0.7,
                                                      "commands_after_next_sync": 0}}}
    (run_dir / "summary.json").write_text(json.dumps(measured))
    line = timing_line(tmp_path, "run")
    assert line is not None and "loop lateness p50/p99/max 0.1/0.4/2 ms" in line
    assert "SYNC jitter p50/p99/max 0.02/0.3/1 ms" in line
    assert "slowest answer after SYNC reaction_wheel" in line and "min 0.7 ms" in line
    (run_dir / "summary.json").write_text(json.dumps({
        "lateness_ms": {"p50": 0.0, "p99": 0.0, "max": 0.0},
        "wire_timing": {"source": "none", "note": "in-process lockstep: no wire",
                        "sync_period_jitter_ms": None, "answer_latency_ms": None,
                        "command_margin_ms": None}}))
    assert "on the wire: not measured (in-process lockstep: no wire)" in timing_line(
        tmp_path, "run")
    (run_dir / "summary.json").write_text("[1, 2")
    assert timing_line(tmp_path, "run") is None


def test_the_kernels_drop_count_is_read_from_each_frames_ancillary_data(monkeypatch):
    """SO_RXQ_OVFL: each received frame carries the socket's running count of frames the
    kernel dropped (its queue full); the bus keeps the latest, beside the time stamp."""
    import socket
    import struct

    from can.interfaces.socketcan import constants

    from harness.bus.socketcan_echo import SO_RXQ_OVFL, EchoSocketcanBus

    frame = struct.pack("=IB3x8s", 0x123, 2, b"\x01\x02")
    stamp = struct.pack("@ll", 1700000000, 250_000_000)

    class FakeSocket:
        drops = 0

        def recvmsg(self, size, ancillary_size):
            assert ancillary_size >= socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4)
            return frame, [(socket.SOL_SOCKET, constants.SO_TIMESTAMPNS, stamp),
                           (socket.SOL_SOCKET, SO_RXQ_OVFL, struct.pack("@I", self.drops))], 0, None

    bus = EchoSocketcanBus.__new__(EchoSocketcanBus)
    bus.socket, bus.channel, bus._is_filtered, bus.kernel_drops = FakeSocket(), "vcan0", False, 0
    import select as select_module

    monkeypatch.setattr(select_module, "select", lambda r, w, x, t: (r, [], []))
    msg, _ = bus._recv_internal(0.1)
    assert msg.arbitration_id == 0x123 and bytes(msg.data) == b"\x01\x02"
    assert msg.timestamp == pytest.approx(1700000000.25) and bus.kernel_drops == 0
    bus.socket.drops = 17
    bus._recv_internal(0.1)
    assert bus.kernel_drops == 17
