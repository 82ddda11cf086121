"""The virtual rig's protocol behaviour: interlock, watchdog, malformed frames."""

from __future__ import annotations

import can
import pytest

from drivers.dbc import load_protocol
from harness.bus import CopyingVirtualBus
from rig_models.rig_file import load_rig
from rig_models.virtual_rig import VirtualRig

P = load_protocol()


@pytest.fixture
def pair(request):
    name = f"test-{request.node.name}"
    harness_bus = CopyingVirtualBus(channel=name)
    rig_bus = CopyingVirtualBus(channel=name)
    rig = VirtualRig(load_rig("sgsrt"), rig_bus, 0.002)
    yield harness_bus, rig
    harness_bus.shutdown()
    rig_bus.shutdown()


def send(bus, name, **values):
    bus.send(can.Message(arbitration_id=P[name].frame_id, data=P[name].encode(values),
                         is_extended_id=False))


def tick(bus, rig, k):
    send(bus, "SYNC", tick=k)
    rig.service()
    frames = {}
    while (m := bus.recv(0)) is not None:
        frames[P.by_id[m.arbitration_id].name] = P.by_id[m.arbitration_id].decode(m.data)
    return frames


def test_answers_sync_with_every_device_due(pair):
    bus, rig = pair
    frames = tick(bus, rig, 0)
    assert set(frames) == {"HUB_TLM", "ACCEL_TLM", "WHEEL_TLM", "VALVE_TLM", "PIEZO_TLM",
                           "ROTOR_TLM"}
    frames = tick(bus, rig, 1)
    assert set(frames) == {"HUB_TLM", "ACCEL_TLM", "WHEEL_TLM", "PIEZO_TLM"}


def test_actuators_stay_at_rest_until_armed(pair):
    bus, rig = pair
    send(bus, "HEARTBEAT", counter=1, armed=0)
    send(bus, "WHEEL_CMD", torque_cmd=0.05, enable=1)
    for k in range(50):
        tick(bus, rig, k)
    assert rig.wheel.torque_n_m == 0.0 and rig.x[0] == 0.0
    send(bus, "HEARTBEAT", counter=2, armed=1)
    send(bus, "WHEEL_CMD", torque_cmd=0.05, enable=1)
    for k in range(50, 100):
        frames = tick(bus, rig, k)
    assert frames["WHEEL_TLM"]["torque"] == pytest.approx(0.05, abs=1e-3)
    assert rig.x[0] > 0


def test_watchdog_makes_devices_safe_without_heartbeat(pair):
    bus, rig = pair
    send(bus, "HEARTBEAT", counter=1, armed=1)
    send(bus, "WHEEL_CMD", torque_cmd=0.05, enable=1)
    send(bus, "VALVE_CMD", valve_pos=1)
    timeout_ticks = int(rig.watchdog_timeout_s / 0.002)
    for k in range(timeout_ticks - 5):
        frames = tick(bus, rig, k)
    assert frames["WHEEL_TLM"]["enabled"] == 1 and rig.valves.state == 1
    for k in range(timeout_ticks - 5, timeout_ticks + 10):
        frames = tick(bus, rig, k)
    assert rig.counters.watchdog_trips == 1
    assert frames["WHEEL_TLM"]["enabled"] == 0
    assert rig.valves.state == 0 and rig.piezo.voltages_v == (0.0, 0.0)
    # commands after the trip are ignored until the harness re-arms
    send(bus, "WHEEL_CMD", torque_cmd=0.05, enable=1)
    tick(bus, rig, timeout_ticks + 11)
    assert rig.wheel.command_n_m == 0.0


def test_malformed_and_unknown_frames_are_counted(pair):
    bus, rig = pair
    bus.send(can.Message(arbitration_id=P["WHEEL_CMD"].frame_id, data=b"\x01",
                         is_extended_id=False))
    bus.send(can.Message(arbitration_id=0x7FF, data=b"\x00" * 8, is_extended_id=False))
    rig.service()
    assert rig.counters.malformed == 1 and rig.counters.unknown == 1


def test_valves_count_firings_and_on_time(pair):
    bus, rig = pair
    send(bus, "HEARTBEAT", counter=1, armed=1)
    tick(bus, rig, 0)
    send(bus, "VALVE_CMD", valve_pos=1)
    for k in range(1, 51):  # 0.1 s
        tick(bus, rig, k)
    send(bus, "VALVE_CMD", valve_pos=0)
    for k in range(51, 101):
        frames = tick(bus, rig, k)
    assert rig.valves.firings == 1
    assert rig.valves.on_time_s == pytest.approx(0.1, abs=0.005)
    assert frames["VALVE_TLM"]["firings"] == 1


def test_physics_step_matches_the_plain_state_space_step(pair):
    """The rig's step (one fused product, piezo forces only while a voltage is applied,
    wheel and rotor at rest skipped) against x = Ad x + Bd u with every actuator's force
    computed every step, through piezo on, piezo off, wheel and rotor on."""
    import numpy as np

    _, rig = pair
    d = rig.plant
    gains = rig.piezo_gains
    assert gains  # the sgsrt rig has patches: the skip is exercised
    rig.armed, rig.safe = True, False
    x = np.zeros_like(rig.x)
    for k in range(600):
        rig.last_heartbeat_s = rig.time_s  # no watchdog trip in this test
        if k == 100:
            rig.piezo.command(20.0, -10.0)
        if k == 200:
            rig.piezo.command(0.0, 0.0)
        if k == 300:
            rig.wheel.command(0.02, True)
        if k == 400:
            rig.rotor.command(5.0, True)
        hub = rig.wheel.torque_n_m  # what the wheel applies over this step
        hub += rig.valves.state * rig.valves.couple_n_m
        hub += rig.rotor.torque_n_m()
        u = np.r_[hub, sum(g.actuator * v for g, v in zip(gains, rig.piezo.voltages_v,
                                                            strict=False))]
        rig.step()
        x = d.ad @ x + d.bd @ u
        np.testing.assert_allclose(rig.x, x, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(rig.y, d.c @ x + d.d @ u, rtol=1e-9, atol=1e-15)
    assert abs(rig.x[0]) > 0 and rig.rotor.speed_rad_s > 0
