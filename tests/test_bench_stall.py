"""Late is not silent: on the wall clock, every device stopping at once is the bench (the
host, the transport, the bus), not one device. Its frames are late: the run goes on, the
stall counted and measured (summary.json ``monitor_bench``); past ``monitor.bench_stall_s``
it stops naming the bus, never a device. One device silent while the others answer is that
device's fault, as before."""

from __future__ import annotations

import pytest

from harness.core.runs import load_run
from harness.core.session import execute_run
from rig_models.faults import TELEMETRY_DEVICES, parse_fault


def _run(tmp_path, fault: str, duration_s: float = 3.0, **over):
    """``fault`` on its device, or on every device when it names none."""
    run = load_run("slew-rw", {"duration_s": duration_s, "clock": "realtime", **over})
    head, eq, value = fault.partition("=")
    specs = [fault] if ":" in head else [f"{head}:{d}{eq}{value}" for d in TELEMETRY_DEVICES]
    return execute_run(run, out_dir=tmp_path, show_progress=False,
                       faults=[parse_fault(f) for f in specs]).summary


@pytest.mark.slow
def test_every_device_late_for_a_moment_is_a_bench_stall_not_a_device_fault(tmp_path):
    # no device answers from 1.0 s to 1.2 s (four times the 50 ms real-time grace)
    s = _run(tmp_path, "silent_sensor@1.0+0.2")
    assert s["stopped_by"] == "completed", s["faults"]
    bench = s["monitor_bench"]
    assert bench["stalls"] >= 1 and 0.15 <= bench["longest_stall_s"] <= 0.4, bench


@pytest.mark.slow
def test_a_stall_past_its_limit_stops_the_run_naming_the_bus(tmp_path):
    s = _run(tmp_path, "silent_sensor@1.0+1.5", monitor={"bench_stall_s": 0.5})
    assert s["stopped_by"] == "fault"
    fault = s["faults"][0]
    assert fault["device"] == "bus" and fault["kind"] == "silent", fault
    assert "not one device" in fault["message"]
    assert 1.45 <= fault["time_s"] <= 1.7, fault


@pytest.mark.slow
def test_one_device_silent_while_the_others_answer_is_still_its_fault(tmp_path):
    s = _run(tmp_path, "silent_sensor@1.0+0.2:hub_sensor")
    assert s["stopped_by"] == "fault"
    fault = s["faults"][0]
    assert fault["device"] == "hub_sensor" and fault["kind"] == "silent", fault


@pytest.mark.slow
def test_every_device_delayed_past_the_grace_is_the_bench_behind_not_a_device(tmp_path):
    # every device's telemetry held back 40 ticks (80 ms, past the 50 ms grace) for 0.4 s
    s = _run(tmp_path, "delay_frames@1.0+0.4=40")
    assert s["stopped_by"] == "completed", s["faults"]
    bench = s["monitor_bench"]
    assert bench["stalls"] + bench["behind_episodes"] >= 1, bench
