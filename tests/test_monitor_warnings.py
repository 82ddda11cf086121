"""The fault monitor's warnings (harness/core/monitor.py, docs/faults.md): conditions short of a
fault, logged once when they start (hysteresis), as WARN events under /events/monitor in
run.rrd at their time, marked on the plots, counted in summary.json; thresholds from the run
file, a bad one refused by its key path."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from harness.core.monitor import WARNING_KINDS, FaultMonitor, Hysteresis, MonitorWarning
from harness.core.runs import load_run
from harness.core.session import execute_run
from harness.record.reader import read_scalar_channel
from harness.review.reader import entities, read_events, read_text
from harness.state import RigCommand, RigState
from rig_models.schema import ConfigError

FIXTURE = Path(__file__).parent / "fixtures" / "runs" / "wheel-near-limit.yaml"
DT = 0.002


def test_hysteresis_starts_once_while_a_signal_hovers():
    h = Hysteresis(on=1.0, off=0.95)
    rng = np.random.default_rng(3)
    hovering = 1.0 + rng.uniform(-0.03, 0.03, 2000)  # crosses 1.0 hundreds of times
    assert sum(np.diff((hovering > 1.0).astype(int)) == 1) > 100
    starts = [h.update(x) for x in hovering]
    assert sum(starts) == 1 and h.active
    assert not h.update(0.96)  # still above off: not ended
    assert h.active
    h.update(0.94)  # below off: ended
    assert not h.active
    assert h.update(1.01)  # starts again
    # without hysteresis (off == on) the same signal would start every time it crosses
    bare = Hysteresis(on=1.0, off=1.0)
    assert sum(bare.update(x) for x in hovering) > 100


class _Driver:
    def __init__(self) -> None:
        self.last_tick = -(10**9)


def _monitor(**cfg: float) -> tuple[FaultMonitor, list[MonitorWarning], dict[str, _Driver]]:
    """A monitor over stand-in drivers (its warnings only; the fault checks need a bus)."""
    drivers = {"hub_sensor": _Driver(), "thruster_valves": _Driver()}
    iface = SimpleNamespace(divider={"hub_sensor": 1, "thruster_valves": 5}, drivers=drivers)
    run = load_run("slew-rw", {"monitor": cfg} if cfg else None)
    got: list[MonitorWarning] = []
    mon = FaultMonitor(iface, run.data["monitor"], run.data["limits"],  # type: ignore[arg-type]
                       wheel_max_speed_rad_s=100.0, accel_range_m_s2=20.0,
                       valve_close_delay_s=0.0, dt_s=DT, wheel_max_torque_n_m=0.05,
                       on_warning=got.append)
    return mon, got, drivers


def _tick(mon: FaultMonitor, drivers: dict[str, _Driver], tick: int, speed: float = 0.0,
          torque: float = 0.0, answered: bool = True) -> None:
    for d in drivers.values():
        if answered:
            d.last_tick = tick
    state = RigState()
    state.wheel_speed_rad_s = speed
    mon._warnings(tick, state, RigCommand(wheel_torque_n_m=torque))


def test_wheel_speed_warns_once_per_excursion_with_hysteresis():
    mon, got, drivers = _monitor()
    # 80 % of the 100 rad/s limit, hovering +-1 rad/s around it for 2 s: one warning
    speeds = -(80.0 + np.random.default_rng(0).uniform(-1.0, 1.0, 1000))
    for k, v in enumerate(speeds):
        _tick(mon, drivers, k, speed=float(v))
    assert [w.kind for w in got] == ["wheel_speed"]
    assert got[0].tick == int(np.argmax(np.abs(speeds) > 80.0))
    assert "is past 80 % of the wheel speed limit 100 rad/s (80 rad/s)" in got[0].message
    # down to 70 rad/s (below 95 % of the threshold) ends it; 85 rad/s starts a second
    for k in range(1000, 1010):
        _tick(mon, drivers, k, speed=70.0)
    _tick(mon, drivers, 1010, speed=85.0)
    assert [w.tick for w in got][1:] == [1010]
    assert mon.warning_counts["wheel_speed"] == 2
    assert set(mon.warning_counts) == set(WARNING_KINDS)


def test_torque_saturated_after_the_hold_time_only():
    mon, got, drivers = _monitor(warn_torque_saturated_s=0.5)  # 250 ticks
    for k in range(100):  # 0.2 s at the limit, then off: no warning
        _tick(mon, drivers, k, torque=0.05 if k < 100 else 0.0)
    _tick(mon, drivers, 100, torque=0.0)
    assert not got
    for k in range(200, 800):
        _tick(mon, drivers, k, torque=-0.05)
    (w,) = got
    assert w.kind == "torque_saturated" and w.tick == 200 + 250
    assert w.time_s == pytest.approx((200 + 250) * DT)
    assert "since t = 0.400 s" in w.message
    # held on, released just below the limit (within the hysteresis), on again: no new one
    for k in range(800, 1400):
        _tick(mon, drivers, k, torque=0.049 if k % 2 else 0.05)
    assert len(got) == 1


def test_missing_telemetry_is_a_rate_limited_count():
    mon, got, drivers = _monitor(warn_missing_interval_s=1.0)
    for k in range(10):
        _tick(mon, drivers, k)
    for k in range(10, 2010):  # the hub sensor stops answering for 4 s
        drivers["thruster_valves"].last_tick = k
        state = RigState()
        mon._warnings(k, state, RigCommand())
    mon.finish()
    assert [w.kind for w in got] == ["telemetry_missing"] * 5
    assert got[0].tick == 10 and "no telemetry from hub_sensor at its tick 10" in got[0].message
    assert [w.tick for w in got[1:4]] == [510, 1010, 1510]
    assert "500 due telemetry frames missing" in got[2].message
    assert got[-1].tick == 2009 and "499 due telemetry frames" in got[-1].message
    assert sum(int(w.message.split()[0]) if w.message[0].isdigit() else 1 for w in got) == 2000


def test_bad_threshold_is_refused_with_its_key_path():
    with pytest.raises(ConfigError, match=r"slew-rw\.yaml: monitor\.warn_limits_fraction: "
                                          r"expected a finite number > 0 <= 1 \(fraction"):
        load_run("slew-rw", {"monitor": {"warn_limits_fraction": 1.5}})
    with pytest.raises(ConfigError, match=r"monitor\.warn_torque_saturated_s: .*\(s\)"):
        load_run(str(FIXTURE), {"monitor": {"warn_torque_saturated_s": "long"}})
    with pytest.raises(ConfigError, match=r"monitor\.warn_speed: unknown key"):
        load_run("slew-rw", {"monitor": {"warn_speed": 0.8}})


@pytest.fixture(scope="module")
def near_limit(tmp_path_factory):
    """The fixture's wheel pulse with the wheel speed limit lowered so that the wheel ends
    the pulse at about 90 % of it (from the rig file: torque x width / rotor inertia)."""
    run = load_run(str(FIXTURE))
    wheel = run.rig.section("reaction_wheel")
    ctrl = run.controller
    assert ctrl["torque_n_m"] == wheel["max_torque_n_m"]  # the pulse sits at the limit
    peak = ctrl["torque_n_m"] * ctrl["width_s"] / wheel["rotor_inertia_kg_m2"]
    limit = round(peak / 0.9, 1)
    run = load_run(str(FIXTURE), {"limits": {"max_wheel_speed_rad_s": limit}})
    res = execute_run(run, out_dir=tmp_path_factory.mktemp("near_limit"), show_progress=False)
    return res, limit


def test_wheel_near_its_limit_warns_in_the_recording_and_summary(near_limit):
    res, limit = near_limit
    s = res.summary
    assert s["stopped_by"] == "completed" and not s["faults"]  # warnings never stop a run
    assert s["monitor_warnings"] == {k: int(k in ("wheel_speed", "torque_saturated"))
                                     for k in WARNING_KINDS}
    on_disk = json.loads((res.run_dir / "summary.json").read_text())
    assert on_disk["monitor_warnings"] == s["monitor_warnings"]
    rrd = res.run_dir / "run.rrd"
    events = [e for e in read_events(rrd) if e.entity == "/events/monitor"]
    assert [e.level for e in events] == ["WARN", "WARN"]
    by_kind = {e.text.split(": ")[1]: e for e in events}
    # at the first recorded sample above 80 % of the limit
    t, speed = read_scalar_channel(rrd, "/wheel/speed_rad_s")
    first = t[np.argmax(np.abs(speed) > 0.8 * limit)]
    assert np.abs(speed).max() < limit and np.abs(speed).max() > 0.85 * limit
    ev = by_kind["wheel speed"]
    assert ev.time_s == pytest.approx(first, abs=1e-9)
    assert f"of the wheel speed limit {limit:g} rad/s" in ev.text
    assert f"(t = {first:.3f} s)" in ev.text
    # the torque command at its limit since the pulse's start, warned 1 s later
    tc, cmd = read_scalar_channel(rrd, "/wheel/torque_cmd_n_m")
    at_limit = tc[np.argmax(np.abs(cmd) >= res.summary["wheel_torque_limit_n_m"])]
    hold = load_run(str(FIXTURE)).data["monitor"]["warn_torque_saturated_s"]
    assert by_kind["torque saturated"].time_s == pytest.approx(at_limit + hold, abs=1e-9)
    # marked on the plots, on the plot's own signal at the warning's time
    have = entities(rrd)
    for plot in ("wheel_speed", "wheel_torque", "tip", "angle"):
        assert f"/markers/{plot}/warning/wheel_speed" in have, plot
        assert f"/markers/{plot}/warning/torque_saturated" in have, plot
    from harness.review.reader import read_series_names

    assert read_series_names(rrd, points=True)["/markers/tip/warning/torque_saturated"] == [
        "WARNING torque saturated"]
    tm, marked = read_scalar_channel(rrd, "/markers/wheel_speed/warning/wheel_speed")
    assert tm == pytest.approx([first]) and marked[0] == pytest.approx(
        speed[np.searchsorted(t, first)])
    summary = read_text(rrd, "/run/summary")
    assert "| monitor warnings | wheel speed 1, torque saturated 1 |" in summary


def test_nominal_slew_has_no_warnings(slew_result):
    """slew-rw on the virtual rig in lockstep: the wheel peaks far below 80 % of its limit,
    the torque command at 0.8 of its limit never saturates, angle 20 of 180 deg, the rate
    and tip acceleration well inside the run's limits, every frame on time: no warning."""
    s = slew_result.summary
    assert s["monitor_warnings"] == dict.fromkeys(WARNING_KINDS, 0)
    assert not [e for e in read_events(slew_result.run_dir / "run.rrd")
                if e.entity == "/events/monitor"]
    assert "| monitor warnings | none |" in read_text(slew_result.run_dir / "run.rrd",
                                                       "/run/summary")
    limits = load_run("slew-rw").data["limits"]
    assert s["max_wheel_torque_cmd_n_m"] < s["wheel_torque_limit_n_m"]
    assert s["peak_tip_accel_m_s2"] < 0.8 * limits["max_tip_accel_m_s2"]
    assert not math.isnan(s["final_angle_deg"])
