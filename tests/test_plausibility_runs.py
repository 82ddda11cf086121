"""Every run is held to the rig's physics (harness/core/monitor.py, plausibility): a rig
file that binds a quantity wrongly stops a plain run naming the channel, where before the
run passed. The virtual rig's devices and physics come from the shipped rig file; the
harness reads them through the broken one (on the virtual rig alone both ends would use the
same binding and agree by construction)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.rig_file import load_rig

G = 9.80665


def _device(rig: str, device: str) -> dict:
    return copy.deepcopy(load_rig(rig).data["devices"][device])


def _rig_file(tmp_path: Path, name: str, base: str, devices: dict) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"extends": base, "name": name, "devices": devices}))
    return str(path)


def _slew(tmp_path: Path, rig: str, truth: str, case: str = "slew-rw",
          duration_s: float = 8.0) -> dict:
    run = load_run(case, {"rig": rig, "duration_s": duration_s})
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False,
                         device_rig=load_rig(truth))
    return result.summary


def _wheel_speed_wrong_object(tmp_path: Path) -> str:
    wheel = _device("sgsrt-canopen", "reaction_wheel")
    wheel["telemetry"]["speed"] = {"object": 0x6071, "scale": 0.001}  # target torque
    return _rig_file(tmp_path, "wrong-object", "sgsrt-canopen", {"reaction_wheel": wheel})


def _wheel_speed_sign(tmp_path: Path) -> str:
    wheel = _device("sgsrt-dbc2", "reaction_wheel")
    wheel["telemetry"]["speed"]["scale"] = -wheel["telemetry"]["speed"]["scale"]
    return _rig_file(tmp_path, "sign", "sgsrt-dbc2", {"reaction_wheel": wheel})


def _hub_rate_deg_as_rad(tmp_path: Path) -> str:
    hub = _device("sgsrt-dbc2", "hub_sensor")
    hub["telemetry"]["rate"]["scale"] = 1.0  # deg/s read as rad/s
    return _rig_file(tmp_path, "deg-as-rad", "sgsrt-dbc2", {"hub_sensor": hub})


def _accel_pinned(tmp_path: Path) -> str:
    """The accelerometer bound to the I/O module's analog output 2 (an object that exists,
    with the input's scale) instead of its input 1: it reads the output's 0 V for ever."""
    acc = _device("sgsrt-canopen", "accelerometer")
    acc["telemetry"]["accel"] = {"object": 0x6411, "sub": 2, "scale": 1.52587890625e-3}
    return _rig_file(tmp_path, "pinned", "sgsrt-canopen", {"accelerometer": acc})


CASES = {
    # (rig file maker, the rig it misdescribes, device, kind, words in the message)
    "wheel speed bound to the target torque": (
        _wheel_speed_wrong_object, "sgsrt-canopen", "reaction_wheel", "implausible",
        "speed against the commanded torque"),
    "wheel speed's sign flipped": (
        _wheel_speed_sign, "sgsrt-dbc2", "reaction_wheel", "implausible", "a sign"),
    "hub rate in deg/s read as rad/s": (
        _hub_rate_deg_as_rad, "sgsrt-dbc2", "hub_sensor", "implausible", "pi/180"),
    "accelerometer pinned at a constant": (
        _accel_pinned, "sgsrt-canopen", "accelerometer", "stuck", "improbable"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_mis_bound_quantity_stops_a_plain_run_naming_it(tmp_path, case):
    make, truth, device, kind, words = CASES[case]
    summary = _slew(tmp_path, make(tmp_path), truth)
    assert summary["stopped_by"] == "fault", summary["stopped_by"]
    fault = summary["faults"][0]
    assert fault["device"] == device, fault
    assert kind in fault["kind"] and words in (fault["kind"] + fault["message"]), fault


@pytest.mark.parametrize("rig", ["sgsrt", "sgsrt-canopen", "sgsrt-dbc2"])
def test_the_shipped_rigs_pass_their_own_physics(tmp_path, rig):
    summary = _slew(tmp_path, rig, rig, duration_s=20.0)
    assert summary["stopped_by"] == "completed", summary["faults"]


def test_without_the_checks_the_mis_bound_wheel_completes(tmp_path):
    """The control case: the same wrong object with the physics checks off runs to the end
    (what the harness did before them)."""
    run = load_run("slew-rw", {"rig": _wheel_speed_wrong_object(tmp_path), "duration_s": 8.0,
                               "monitor": {"plausibility": False}})
    result = execute_run(run, out_dir=tmp_path / "logs", show_progress=False,
                         device_rig=load_rig("sgsrt-canopen"))
    assert result.summary["stopped_by"] == "completed"


@pytest.mark.slow
def test_the_acceptance_suite_does_not_pass_a_mis_bound_wheel(tmp_path):
    """The lab's daily check with the wheel's speed bound to the drive's target torque:
    probe is happy (the frames are right), every run that moves the wheel stops naming it."""
    from in_process import harness_in_process

    r = harness_in_process("test", "acceptance", "--rig", _wheel_speed_wrong_object(tmp_path),
                           "--devices-rig", "sgsrt-canopen", "--out", str(tmp_path / "out"))
    assert r.returncode not in (0, 5, 6), r.stdout[-2000:]
    assert "reaction_wheel: implausible: speed against the commanded torque" in r.stdout


# ---------------------------------------------------------------- the momentum balance


def _hub_reversed(tmp_path: Path) -> str:
    """The hub sensor mounted the other way round: angle and rate both read x -1 (they
    still agree with each other, so the angle-against-rate check cannot see it)."""
    hub = _device("sgsrt-dbc2", "hub_sensor")
    for q in ("angle", "rate"):
        hub["telemetry"][q]["scale"] = -hub["telemetry"][q]["scale"]
    return _rig_file(tmp_path, "hub-reversed", "sgsrt-dbc2", {"hub_sensor": hub})


def _valves_swapped(tmp_path: Path) -> str:
    """The positive and negative valve swapped, in their commands and their read-back."""
    v = _device("sgsrt-dbc2", "thruster_valves")
    c, t = v["commands"], v["telemetry"]
    c["valve_pos"], c["valve_neg"] = c["valve_neg"], c["valve_pos"]
    t["valve_pos_open"], t["valve_neg_open"] = t["valve_neg_open"], t["valve_pos_open"]
    return _rig_file(tmp_path, "valves-swapped", "sgsrt-dbc2", {"thruster_valves": v})


@pytest.mark.parametrize("make, case, device, words", [
    (_hub_reversed, "slew-rw", "hub_sensor", "momentum balance against the wheel"),
    (_valves_swapped, "slew-thruster-bangbang", "thruster_valves",
     "momentum balance against the valves' couple"),
])
def test_a_reversed_hub_sensor_or_swapped_valves_stop_the_run_naming_it(
        tmp_path, make, case, device, words):
    summary = _slew(tmp_path, make(tmp_path), "sgsrt-dbc2", case=case, duration_s=8.0)
    assert summary["stopped_by"] == "fault", summary["stopped_by"]
    fault = summary["faults"][0]
    assert fault["device"] == device and words in fault["message"], fault
    assert "a sign" in fault["message"], fault
    # within a second of the motion's first significant window (the slews start at rest)
    assert fault["time_s"] <= 3.0 + 1e-9, fault


@pytest.mark.parametrize("case", ["slew-rw-zv", "free-decay", "slew-thruster-hllh",
                                  "thruster-pd-pwpf"])
def test_the_momentum_balance_passes_the_shipped_rig_through_vibration_and_pwm(tmp_path,
                                                                                case):
    """The beam's vibration (the free decay's bursts near mode 3) and PWM valve pulses
    shorter than the valves' telemetry period scatter single windows: no false fault."""
    summary = _slew(tmp_path, "sgsrt-dbc2", "sgsrt-dbc2", case=case, duration_s=30.0)
    assert summary["stopped_by"] == "completed", summary["faults"]


def test_without_the_balance_a_reversed_hub_sensor_runs_on(tmp_path, monkeypatch):
    """The control case: the same reversed sensor with the balance removed is not stopped
    for the hub sensor (positive feedback until some other limit trips)."""
    from harness.core import monitor

    monkeypatch.setattr(monitor.FaultMonitor, "_balance", lambda self, tick, pw: None)
    summary = _slew(tmp_path, _hub_reversed(tmp_path), "sgsrt-dbc2", duration_s=8.0)
    assert all(f["device"] != "hub_sensor" for f in summary["faults"]), summary["faults"]
