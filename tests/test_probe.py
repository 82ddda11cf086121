"""`harness probe`: every device answers, problems are named, the rig is never armed."""

from __future__ import annotations

import json
import threading

import pytest

from drivers.dbc import load_protocol
from harness.bus import open_bus, parse_bus
from harness.cli import main
from harness.core.probe import probe
from rig_models.faults import make_fault, parse_fault
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import VirtualRig


def _probe_in_process(channel: str, faults=(), rate_hz: float = 100.0, duration_s: float = 1.0,
                      settle_s: float = 0.0):
    spec = parse_bus(f"virtual:{channel}")
    rig_cfg = load_rig("sgsrt")
    bus, rig_bus = open_bus(spec), open_bus(spec)
    try:
        rig = VirtualRig(rig_cfg, rig_bus, 1.0 / rate_hz,
                         faults=[parse_fault(f) if isinstance(f, str) else f for f in faults])
        return probe(bus, rig_cfg, rate_hz, duration_s, bus_name=str(spec), pump=rig.service,
                     realtime=False, settle_s=settle_s)
    finally:
        bus.shutdown()
        rig_bus.shutdown()


def test_healthy_virtual_rig_answers_every_sync():
    r = _probe_in_process("probe-ok", settle_s=0.5)  # 50 SYNCs first, not counted
    assert r.ok and r.ticks == 100
    by = {d.device: d for d in r.devices}
    assert set(by) == {"hub_sensor", "accelerometer", "reaction_wheel", "thruster_valves",
                       "piezo_amplifier", "disturbance_rotor"}
    for d in r.devices:
        assert d.due == 100 // d.sync_divider and d.received == d.due and d.missing == 0
        assert d.frames == 150 // d.sync_divider  # settling time included
        assert d.status == "ok"
    assert by["reaction_wheel"].last_values["enabled"] == 0  # never armed
    assert "angle" in by["hub_sensor"].last_values


def test_probe_sends_no_command_and_a_disarmed_heartbeat():
    spec = parse_bus("virtual:probe-listen")
    listener = open_bus(spec)
    try:
        _probe_in_process("probe-listen", duration_s=0.5)
        protocol = load_protocol()
        ids = []
        while (msg := listener.recv(0)) is not None:
            ids.append(msg.arbitration_id)
            if msg.arbitration_id == protocol["HEARTBEAT"].frame_id:
                assert protocol["HEARTBEAT"].decode(msg.data)["armed"] == 0
    finally:
        listener.shutdown()
    commands = {protocol[n].frame_id for n in ("WHEEL_CMD", "VALVE_CMD", "PIEZO_CMD",
                                                "ROTOR_CMD")}
    assert ids and not commands & set(ids)
    assert protocol["SYNC"].frame_id in ids and protocol["HUB_TLM"].frame_id in ids


def test_settling_time_is_not_counted():
    # silent for the first 0.3 s only: inside the 0.5 s settle, not counted
    brief = make_fault({"kind": "silent_sensor", "at_s": 0.0, "duration_s": 0.3,
                        "device": "hub_sensor"}, "test")
    r = _probe_in_process("probe-settle", faults=[brief], duration_s=0.5, settle_s=0.5)
    hub = next(d for d in r.devices if d.device == "hub_sensor")
    assert r.ok and hub.due == 50 and hub.missing == 0
    # silent throughout: still caught after the settle
    r = _probe_in_process("probe-settle2", faults=["silent_sensor@0.0:hub_sensor"],
                          duration_s=0.5, settle_s=0.5)
    hub = next(d for d in r.devices if d.device == "hub_sensor")
    assert hub.due == 50 and hub.missing == 50 and hub.status == "silent"
    with pytest.raises(ValueError, match="settle_s"):
        _probe_in_process("probe-settle-bad", settle_s=-1.0)


def test_silent_and_malformed_devices_and_unknown_ids_are_named():
    r = _probe_in_process("probe-bad", faults=[
        "silent_sensor@0.5:accelerometer", "wrong_length@0.2:reaction_wheel",
        "unknown_ids@0.8"])
    by = {d.device: d for d in r.devices}
    assert not r.ok
    acc = by["accelerometer"]
    assert acc.missing == pytest.approx(50, abs=1) and "SYNCs unanswered" in acc.status
    wheel = by["reaction_wheel"]
    assert wheel.malformed >= 75 and "malformed" in wheel.status and "WHEEL_TLM" in \
        wheel.last_error
    assert by["hub_sensor"].ok and r.unknown >= 15


def test_real_time_probe_against_a_rig_thread():
    spec = parse_bus("virtual:probe-rt")
    rig_cfg = load_rig("sgsrt")
    bus, rig_bus = open_bus(spec), open_bus(spec)
    stop = threading.Event()
    rig = VirtualRig(rig_cfg, rig_bus, 0.01)
    thread = threading.Thread(target=rig.run_forever, args=(stop.is_set, 0.001), daemon=True)
    thread.start()
    try:
        r = probe(bus, rig_cfg, 100.0, 0.5, bus_name=str(spec), receive_timeout_s=0.005)
    finally:
        stop.set()
        thread.join(timeout=2)
        bus.shutdown()
        rig_bus.shutdown()
    hub = next(d for d in r.devices if d.device == "hub_sensor")
    assert r.ticks == 50 and hub.received >= 25  # a loaded machine may make some late


def test_cli_exit_codes_and_json(capsys):
    assert main(["probe", "--duration-s", "0.3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] and len(report["devices"]) == 6
    assert main(["probe", "--duration-s", "0.5", "--bus", "virtual:probe-cli",
                 "--fault", "silent_sensor@0.1:hub_sensor"]) == 3
    out = capsys.readouterr().out
    assert "PROBLEM" in out and "hub_sensor" in out
    assert main(["probe", "--rate-hz", "0"]) == 2
    assert "--rate-hz" in capsys.readouterr().err
    assert main(["probe", "--bus", "udp_multicast:224.0.0.1"]) == 2
    assert main(["probe", "--bus", "socketcand:127.0.0.1:1", "--fault",
                 "silent_sensor@0:hub_sensor"]) == 2
    assert "--fault" in capsys.readouterr().err


def test_probe_names_the_rig_it_probed(capsys):
    from rig_models.rig_file import load_rig, rig_sha256

    assert main(["probe", "--rig", "sgsrt-dbc2", "--duration-s", "0.2"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    sha = rig_sha256(load_rig("sgsrt-dbc2").data)
    assert first == (f"rig sgsrt-dbc2 (sha256 {sha[:12]}), bus virtual:sgsrt-dbc2, binding "
                     "dbc sgsrt_dbc2.dbc: every device")
    assert main(["probe", "--rig", "sgsrt-canopen", "--duration-s", "0.2", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["rig"] == "sgsrt-canopen" and report["bus"] == "virtual:sgsrt-canopen"
    assert report["binding"]["hub_sensor"] == {"binding": "canopen", "node_id": 4,
                                               "eds": "sgsrt_encoder.eds"}


def test_last_values_carry_their_units(capsys):
    assert main(["probe", "--duration-s", "0.2"]) == 0
    out = capsys.readouterr().out
    hub = next(line for line in out.splitlines() if line.strip().startswith("hub_sensor")
               and "angle" in line)
    assert " rad," in hub and hub.rstrip().endswith("rad/s")
    wheel = next(line for line in out.splitlines() if "torque_limited" in line)
    assert "rad/s" in wheel and "N m" in wheel
