"""Every wait bounded, every heartbeat in time, nothing to run refused: each case one line
naming the key, exit 2, before anything is sent."""

from __future__ import annotations

import pytest
from in_process import harness_in_process

from harness.core.runs import load_run
from rig_models.schema import ConfigError


@pytest.mark.parametrize("over, words", [
    ({"receive_timeout_ms": 1e7}, "receive_timeout_ms: 1e+07 ms: at most 1000 ms"),
    ({"heartbeat_hz": 3.0}, "watchdog.heartbeat_timeout_s of 250 ms"),
    ({"heartbeat_hz": 4.5, "rig": "sgsrt-canopen"}, "bus.heartbeat_consumer_ms of 200 ms"),
])
def test_a_wait_past_its_bound_or_a_heartbeat_slower_than_the_watchdog_is_refused(over,
                                                                                    words):
    with pytest.raises(ConfigError, match="heartbeat_hz|receive_timeout_ms") as info:
        load_run("slew-rw", over)
    assert words in str(info.value)


def test_a_heartbeat_within_the_watchdog_is_accepted():
    assert load_run("slew-rw", {"heartbeat_hz": 5.0}).data["heartbeat_hz"] == 5.0


def test_a_rig_binding_no_device_is_refused_naming_it(tmp_path):
    rig = tmp_path / "none-rig.yaml"
    rig.write_text("extends: sgsrt\nname: none-rig\ndevices:\n" + "".join(
        f"  {d}: {{binding: none}}\n" for d in (
            "hub_sensor", "accelerometer", "reaction_wheel", "thruster_valves",
            "piezo_amplifier", "disturbance_rotor")))
    r = harness_in_process("run", "slew-rw", "--rig", str(rig), "--out", str(tmp_path / "o"),
                           "--quiet")
    assert r.returncode == 2, r.stderr
    assert "every device is bound 'binding: none'" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "o").exists()
