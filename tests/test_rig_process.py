"""`harness run --rig-process`: the virtual rig in its own process for a real-time run."""

from __future__ import annotations

import pytest

from harness.bus.rig_process import fault_argument
from harness.core.runs import load_run
from harness.core.session import RunRefused, execute_run
from rig_models.faults import make_fault, parse_fault
from rig_models.schema import ConfigError


def _run(tmp_path, **kw):
    # a wide real-time grace: this shared machine may be busy; the test is about plumbing
    run = load_run("slew-rw", {"duration_s": 2.0, "monitor": {"realtime_grace_s": 1.0}})
    return execute_run(run, out_dir=tmp_path, clock="realtime", show_progress=False,
                       rig_process=True, **kw)


@pytest.mark.slow
def test_real_time_run_against_a_rig_process(tmp_path):
    res = _run(tmp_path)
    s = res.summary
    assert s["stopped_by"] == "completed" and s["clock"] == "realtime"
    assert s["bus"].startswith("socketcand:127.0.0.1:")
    assert s["frames"]["received"] > 0.8 * 5 * s["ticks"]  # ~5.6 frames a tick
    assert res.virtual_rig is None  # no rig in this process
    log = (res.run_dir / "rig.log").read_text()
    assert "on socketcand:127.0.0.1:" in log and "stopped after" in log  # stopped cleanly
    assert (res.run_dir / "rig.yaml").exists()


def test_faults_reach_the_rig_process(tmp_path):
    res = _run(tmp_path, faults=[parse_fault("silent_sensor@0.5:hub_sensor")])
    s = res.summary
    assert s["stopped_by"] == "fault"
    assert s["faults"][0]["device"] == "hub_sensor" and s["faults"][0]["kind"] == "silent"
    assert "--fault" not in (res.run_dir / "rig.log").read_text()  # parsed, not echoed


@pytest.mark.slow
def test_a_timed_fault_reaches_the_default_rig_process_and_ends(tmp_path):
    # the hub sensor silent for 0.4 s of a 2 s real-time run, the monitor off so the run
    # goes on: about 200 of its frames are missing (all 750 from 0.5 s on, were the
    # duration lost on the way to the rig process)
    run = load_run("slew-rw", {"duration_s": 2.0, "monitor": {"enabled": False}})
    res = execute_run(run, out_dir=tmp_path, clock="realtime", show_progress=False,
                      faults=[parse_fault("silent_sensor@0.5+0.4:hub_sensor")])
    s = res.summary
    assert s["virtual_rig_mode"].startswith("process") and s["stopped_by"] == "completed"
    assert 180 <= s["frames"]["missing"] <= 400, s["frames"]


def test_rig_process_is_refused_outside_real_time_on_the_virtual_bus(tmp_path):
    with pytest.raises(RunRefused, match="--rig-process"):
        execute_run(load_run("slew-rw"), out_dir=tmp_path, clock="lockstep",
                    show_progress=False, rig_process=True)
    with pytest.raises(RunRefused, match="--rig-process"):
        execute_run(load_run("slew-rw"), out_dir=tmp_path, clock="realtime",
                    bus="socketcand:127.0.0.1:1", show_progress=False, rig_process=True)


def test_fault_argument_round_trips_with_durations():
    for text in ("silent_sensor@0.5:hub_sensor", "accel_saturation@1.25=40.0", "bus_off@2.0",
                 "silent_sensor@0.5+0.2:hub_sensor", "accel_saturation@1+0.5=40.0"):
        f = parse_fault(text)
        assert parse_fault(fault_argument(f)) == f
    timed = make_fault({"kind": "silent_sensor", "at_s": 1.0, "duration_s": 0.5,
                        "device": "hub_sensor"}, "test")
    assert fault_argument(timed) == "silent_sensor@1.0+0.5:hub_sensor"
    assert parse_fault("silent_sensor@1+0.5:hub_sensor") == timed
    for bad, field in (("silent_sensor@1+x:hub_sensor", "DURATION_S"),
                       ("silent_sensor@1+0:hub_sensor", "DURATION_S"),
                       ("silent_sensor@y:hub_sensor", "AT_S")):
        with pytest.raises(ConfigError, match=field):
            parse_fault(bad)
