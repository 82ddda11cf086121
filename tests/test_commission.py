"""`harness commission`: the shipped rigs PASS on the virtual rig in lockstep; rig files that
each break one thing the way a lab does FAIL naming the quantity.

A broken rig file is judged against the devices as they are: the virtual rig's devices
and physics come from the shipped rig file (``--devices-rig``), the harness reads them
through the broken one (on the virtual rig alone both ends would use the same binding and
agree by construction)."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest
import yaml

from harness.commissioning.workflow import Options, commission
from rig_models.rig_file import load_rig
from tests.in_process import harness_in_process

G = 9.80665


def _device(rig: str, device: str) -> dict:
    return copy.deepcopy(load_rig(rig).data["devices"][device])


def _rig_file(tmp_path: Path, name: str, base: str, devices: dict, **extra) -> str:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"extends": base, "name": name, "devices": devices,
                                    **extra}))
    return str(path)


def _run(tmp_path: Path, rig: str, devices_rig: str | None = None):
    return commission(Options(rig=rig, out=tmp_path / "logs", devices_rig=devices_rig))


def _failed(result, device: str, quantity: str, check: str = "") -> list:
    return [c for c in result.checks if c.device == device and c.quantity == quantity
            and c.verdict == "FAIL" and check in c.check]


# the devices as the model says (ideal) and as built (friction, lags, biases, the beam's
# damping and modes, the valves' couples: rig_models/rigs/sgsrt-as-built.yaml): a binding
# error FAILs against both
TRUTHS = ["", "-as-built"]


@pytest.mark.parametrize("rig", ["sgsrt", "sgsrt-canopen", "sgsrt-dbc2"])
def test_shipped_rigs_pass_commissioning(tmp_path, rig):
    r = harness_in_process("commission", "--rig", rig, "--out", str(tmp_path), "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    data = json.loads(r.stdout)
    assert data["verdict"] == "PASS" and not data["failed"]
    checks = data["checks"]
    judged = {(c["device"], c["quantity"]) for c in checks if c["verdict"] == "PASS"}
    # every bound device has a quantity proved by motion, not only at rest
    for device in ("hub_sensor", "accelerometer", "reaction_wheel", "thruster_valves",
                   "piezo_amplifier", "disturbance_rotor"):
        assert any(d == device for d, _ in judged), device
    assert any("momentum balance" in c["check"] for c in checks)
    folder = Path(data["runs"]["moving"]).parent.parent
    for name in ("commission.json", "report.html", "commission.rrd"):
        assert (folder / name).stat().st_size > 0
    assert "PASS" in (folder / "report.html").read_text()
    if rig == "sgsrt-canopen":  # the drive's rated torque and the encoder's units, by SDO
        scaled = [c for c in checks if "scaling object" in c["check"] and c["verdict"] == "PASS"]
        assert {c["quantity"] for c in scaled} >= {"torque", "torque_cmd", "angle", "rate"}


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_quantity_bound_to_a_wrong_but_existing_object_fails(tmp_path, truth):
    """The wheel's speed bound to the drive's target torque (0x6071) instead of its
    velocity actual value (0x606C): probe is happy, the physics is not."""
    wheel = _device("sgsrt-canopen", "reaction_wheel")
    wheel["telemetry"]["speed"] = {"object": 0x6071, "scale": 0.001}
    rig = _rig_file(tmp_path, "wrong-object", "sgsrt-canopen", {"reaction_wheel": wheel})
    res = _run(tmp_path, rig, "sgsrt-canopen" + truth)
    assert res.verdict == "FAIL" and res.exit_code == 1
    # before anything moves: 0x6071 counts per mille of the rated torque 0x6076
    (bad,) = _failed(res, "reaction_wheel", "speed", "scaling object 0x6076")
    assert "is bound to 0x6071" in bad.cause and "a wrong object" in bad.cause
    assert "moving" not in res.runs


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_scale_off_by_1000_fails_naming_the_factor(tmp_path, truth):
    """The tip accelerometer's milli-g signal converted as g (9.80665 instead of 9.80665e-3)."""
    acc = _device("sgsrt-dbc2", "accelerometer")
    acc["telemetry"]["accel"]["scale"] = G
    rig = _rig_file(tmp_path, "scale-1000", "sgsrt-dbc2", {"accelerometer": acc})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    assert res.exit_code == 1
    # at rest its noise reads 1000 x its spec; moving, the monitor stops the run at the
    # tip acceleration limit the misread noise passes (a failed check of the same quantity)
    (noise,) = _failed(res, "accelerometer", "accel", "noise at rest")
    assert "a factor of 1000" in noise.cause and noise.value / noise.expected == \
        pytest.approx(1000, rel=0.3)
    assert _failed(res, "accelerometer", "accel", "monitor stopped")


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_sign_flipped_fails_naming_the_sign(tmp_path, truth):
    """The wheel's speed with its sign reversed (a negative scale, a motor wired the other
    way)."""
    wheel = _device("sgsrt-dbc2", "reaction_wheel")
    wheel["telemetry"]["speed"]["scale"] = -wheel["telemetry"]["speed"]["scale"]
    rig = _rig_file(tmp_path, "sign", "sgsrt-dbc2", {"reaction_wheel": wheel})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    bad = _failed(res, "reaction_wheel", "speed", "torque integral")
    assert len(bad) == 2 and all(c.cause.startswith("a sign") for c in bad)
    assert all(c.value == pytest.approx(-1.0, abs=0.1) for c in bad)


@pytest.mark.parametrize("truth", TRUTHS)
def test_degrees_bound_as_radians_fails_naming_180_over_pi(tmp_path, truth):
    """The hub rate signal in deg/s with no conversion (scale 1): read as rad/s."""
    hub = _device("sgsrt-dbc2", "hub_sensor")
    hub["telemetry"]["rate"]["scale"] = 1.0
    rig = _rig_file(tmp_path, "deg-as-rad", "sgsrt-dbc2", {"hub_sensor": hub})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    bad = _failed(res, "hub_sensor", "rate", "torque integral")
    assert bad and all("180/pi" in c.cause for c in bad)
    (angle,) = _failed(res, "hub_sensor", "angle", "rate's integral")
    assert "pi/180" in angle.cause


@pytest.mark.parametrize("truth", TRUTHS)
def test_rpm_read_as_rad_s_fails_naming_60_over_2_pi(tmp_path, truth):
    """The wheel's speed signal in rpm converted as rad/s: its friction, measured with the
    misread speed, is taken back by the factor, so the hub's checks stay clean."""
    wheel = _device("sgsrt-dbc2", "reaction_wheel")
    wheel["telemetry"]["speed"]["scale"] *= 60 / (2 * math.pi)
    rig = _rig_file(tmp_path, "rpm", "sgsrt-dbc2", {"reaction_wheel": wheel})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    bad = _failed(res, "reaction_wheel", "speed", "torque integral")
    assert len(bad) == 2 and all("60/(2 pi)" in c.cause for c in bad)
    assert not _failed(res, "hub_sensor", "rate", "torque integral")


def _offset_truth(tmp_path: Path, offset_counts: int, truth: str = "") -> str:
    """The I/O module's accelerometer input: a 1 V/g sensor centred on 2.5 V (3276.8 counts
    a volt: 334.1 counts per m/s^2, 8192 counts at rest)."""
    acc = _device("sgsrt-canopen", "accelerometer")
    acc["telemetry"]["accel"] = {"object": 0x6401, "sub": 1, "sensitivity": 3276.8 / G,
                                 "offset": offset_counts}
    return _rig_file(tmp_path, f"accel-offset-{offset_counts}{truth}", "sgsrt-canopen" + truth,
                     {"accelerometer": acc})


@pytest.mark.parametrize("truth", TRUTHS)
def test_an_offset_applied_twice_fails_at_rest_naming_the_offset(tmp_path, truth):
    devices = _offset_truth(tmp_path, 8192, truth)
    res = _run(tmp_path, _offset_truth(tmp_path, 16384), devices)
    (off,) = _failed(res, "accelerometer", "accel", "offset at rest")
    assert "an offset" in off.cause and off.value == pytest.approx(-8192 / (3276.8 / G),
                                                                   rel=0.01)


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_sensor_pinned_constant_fails(tmp_path, truth):
    """The accelerometer's quantity bound to a signal that never moves (its saturation
    flag): the reading sits at 0 whatever the beam does."""
    acc = _device("sgsrt-dbc2", "accelerometer")
    acc["telemetry"]["accel"] = {"message": "ACC_Tlm", "signal": "ACC_Sat", "scale": 1.0}
    rig = _rig_file(tmp_path, "pinned", "sgsrt-dbc2", {"accelerometer": acc})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    (noise,) = _failed(res, "accelerometer", "accel", "noise at rest")
    assert "pinned" in noise.cause
    (ring,) = _failed(res, "accelerometer", "accel", "ring-down")
    assert "no response" in ring.cause
    # the beam's modes come from the other sensors' ring-down (the hub rate, the patch
    # sensors): the hub's and the patches' checks are judged with them and pass
    assert {c.device for c in res.failed()} == {"accelerometer"}


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_scaling_object_that_disagrees_fails_before_anything_moves(tmp_path, truth):
    """The wheel's torque converted as if the drive were rated 100 mN m (1e-4 N m per per
    mille) while its 0x6076 says 65: named with both numbers, and nothing moves."""
    wheel = _device("sgsrt-canopen", "reaction_wheel")
    wheel["telemetry"]["torque"]["scale"] = 1.0e-4
    wheel["commands"]["torque_cmd"]["scale"] = 1.0e-4
    rig = _rig_file(tmp_path, "rated-torque", "sgsrt-canopen", {"reaction_wheel": wheel})
    out = tmp_path / "cli"
    r = harness_in_process("commission", "--rig", rig, "--devices-rig",
                           "sgsrt-canopen" + truth, "--out", str(out))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "FAIL reaction_wheel.torque: conversion of 0x6077" in r.stdout
    assert "0.0001" in r.stdout and "6.5e-05" in r.stdout and "0x6076 = 65 mN m" in r.stdout
    (data,) = [json.loads(p.read_text()) for p in out.rglob("commission.json")]
    assert "moving" not in data["runs"]  # nothing moved on a conversion known wrong
    assert {c["quantity"] for c in data["checks"] if c["verdict"] == "FAIL"} == {
        "torque", "torque_cmd"}


def test_devices_rig_only_on_the_virtual_bus(tmp_path):
    r = harness_in_process("commission", "--devices-rig", "sgsrt", "--bus",
                           "socketcand:127.0.0.1:1", "--out", str(tmp_path))
    assert r.returncode == 2 and "Traceback" not in r.stderr


@pytest.mark.parametrize("truth", TRUTHS)
def test_a_reversed_hub_sensor_fails_once_at_the_hub_the_valves_follow_from_it(tmp_path,
                                                                              truth):
    """Angle and rate both reversed: the hub sensor's rate fails naming the sign; the
    valves, the inertia and the couples, read through the hub's rate, say they follow from
    it instead of failing on their own ("swapped")."""
    hub = _device("sgsrt-dbc2", "hub_sensor")
    for q in ("angle", "rate"):
        hub["telemetry"][q]["scale"] = -hub["telemetry"][q]["scale"]
    rig = _rig_file(tmp_path, "hub-reversed", "sgsrt-dbc2", {"hub_sensor": hub})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    failed = {c.name for c in res.failed()}
    assert failed == {"hub_sensor.rate"}, [(c.name, c.cause) for c in res.failed()]
    assert all(c.cause.startswith("a sign") for c in res.failed())
    follows = [c for c in res.checks if c.verdict == "NOT JUDGED"
               and c.cause.startswith("follows from hub_sensor.rate")]
    assert {c.device for c in follows} >= {"thruster_valves"}, follows


@pytest.mark.parametrize("truth", TRUTHS)
def test_swapped_valves_fail_once_as_swapped_healthy_sensors_pass(tmp_path, truth):
    v = _device("sgsrt-dbc2", "thruster_valves")
    c, t = v["commands"], v["telemetry"]
    c["valve_pos"], c["valve_neg"] = c["valve_neg"], c["valve_pos"]
    t["valve_pos_open"], t["valve_neg_open"] = t["valve_neg_open"], t["valve_pos_open"]
    rig = _rig_file(tmp_path, "valves-swapped", "sgsrt-dbc2", {"thruster_valves": v})
    res = _run(tmp_path, rig, "sgsrt-dbc2" + truth)
    failed = {c.name for c in res.failed()}
    assert failed == {"thruster_valves.valve_pos", "thruster_valves.valve_neg"}, \
        [(c.name, c.cause) for c in res.failed()]
    assert all("valve swapped" in c.cause for c in res.failed())


@pytest.mark.slow
@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_signal_during_commissioning_exits_130_rig_safe_commission_json_written(tmp_path,
                                                                                  sig):
    """As `harness run` takes them: the first SIGTERM or SIGINT stops the moving run at its
    next tick (the rig left safe), commission.json says INTERRUPTED, exit 130."""
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    root = Path(__file__).resolve().parent.parent
    proc = subprocess.Popen(
        [sys.executable, "-m", "harness", "commission", "--clock", "realtime", "--out",
         str(tmp_path / "out")], stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONPATH=str(root)), cwd=tmp_path)
    assert proc.stderr is not None
    seen = ""
    deadline = time.monotonic() + 180
    while "commission 2/2" not in seen and time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        seen += line
    assert "commission 2/2" in seen, seen
    time.sleep(1.0)
    proc.send_signal(getattr(signal, sig))
    out, rest = proc.communicate(timeout=60)
    assert proc.returncode == 130, seen + rest
    (report,) = (tmp_path / "out").glob("*/commission.json")
    data = json.loads(report.read_text())
    assert data["verdict"] == "INTERRUPTED" and data["exit_code"] == 130
    moving = json.loads((Path(data["runs"]["moving"]) / "summary.json").read_text())
    assert moving["stopped_by"] == "interrupted"
    assert "INTERRUPTED" in out
