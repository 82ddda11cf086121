"""Drivers: clamping to the rig file's limits, staleness, malformed frames counted."""

from __future__ import annotations

import pytest

from drivers.dbc import load_protocol
from drivers.hub_sensor import HubSensorDriver
from drivers.piezo_amplifier import PiezoAmplifierDriver
from drivers.reaction_wheel import ReactionWheelDriver
from drivers.thruster_valves import ThrusterValvesDriver

P = load_protocol()


def test_wheel_torque_clamped_to_rig_limit():
    drv = ReactionWheelDriver(P, max_torque_n_m=0.065)
    out = P["WHEEL_CMD"].decode(drv.encode(0.5, True, 1))
    assert out["torque_cmd"] == pytest.approx(0.065, abs=1e-5)
    out = P["WHEEL_CMD"].decode(drv.encode(-0.5, True, 1))
    assert out["torque_cmd"] == pytest.approx(-0.065, abs=1e-5)
    assert drv.clamp(float("nan")) == 0.0
    out = P["WHEEL_CMD"].decode(drv.encode(0.03, False, 1))
    assert out["torque_cmd"] == 0.0 and out["enable"] == 0


def test_piezo_voltage_clamped():
    drv = PiezoAmplifierDriver(P, max_voltage_v=150.0)
    out = P["PIEZO_CMD"].decode(drv.encode(400.0, -400.0, 3))
    assert out["voltage_ch1"] == pytest.approx(150.0)
    assert out["voltage_ch2"] == pytest.approx(-150.0)


def test_valves_never_both_open():
    drv = ThrusterValvesDriver(P)
    for d in (-3, -1, 0, 1, 5):
        out = P["VALVE_CMD"].decode(drv.encode(d, 0))
        assert not (out["valve_pos"] and out["valve_neg"])


def test_malformed_counted_and_staleness():
    drv = HubSensorDriver(P, stale_after_ticks=2)
    assert drv.is_stale(0)
    assert not drv.handle(b"\x01\x02", tick=0)
    assert drv.counters.malformed == 1 and "HUB_TLM" in drv.counters.last_error
    good = P["HUB_TLM"].encode({"angle": 0.5, "rate": -0.25})
    assert drv.handle(good, tick=5)
    assert drv.angle_rad == pytest.approx(0.5) and drv.rate_rad_s == pytest.approx(-0.25)
    assert not drv.is_stale(7)
    assert drv.is_stale(8)
