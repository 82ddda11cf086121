"""The fault monitor's inline all-clear paths (``FaultMonitor.check`` runs each
check's usual tick inline and calls the check's own method only past it) decide exactly
what the checks' methods decide: on random ticks of a rig whose drivers see healthy
frames, missing frames, frozen and jumping counters, implausible values, flags, NaNs,
malformed frames and bus errors, the monitor and a monitor that calls every method as
before give the same first fault, at the same tick with the same message, and the same
warnings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.dbc import load_protocol
from harness.bus.rig_interface import RigInterface
from harness.core.monitor import FaultEvent, FaultMonitor, MonitorWarning
from harness.core.runs import load_run
from harness.state import RigCommand, RigState


class _AsBefore(FaultMonitor):
    """``check`` and ``_warnings`` as they were before the inline paths: every check
    through its own method (main at 97812d7)."""

    def check(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        if not self._enabled:
            return None
        if self.warnings_on:
            self._warnings(tick, state, sent)
        if self._protocol_fault is not None:
            event = self._protocol(tick, state, sent)
            if event is not None:
                return event
        event = self._bus(tick, state, sent) or self._silent_and_lost(tick, state, sent)
        if event is not None:
            return event
        accel, hub, wheel, valves, piezo = self._device_drivers
        if accel is not None and accel.last_tick == tick:
            event = self._accelerometer(tick, state, sent)
            if event is not None:
                return event
        if hub is not None and hub.last_tick == tick and tick != self._hub_tick:
            event = self._hub(tick, state, sent)
            if event is not None:
                return event
        if wheel is not None and wheel.last_tick == tick and tick != self._wheel_tick:
            event = self._wheel(tick, state, sent)
            if event is not None:
                return event
        if sent.valve_direction != 0 or (valves is not None and valves.last_tick == tick):
            event = self._valves(tick, state, sent)
            if event is not None:
                return event
        if piezo is not None and piezo.last_tick == tick:
            event = self._piezo(tick, state, sent)
            if event is not None:
                return event
        return self._limits(tick, state, sent)

    def _warnings(self, tick: int, state: RigState, sent: RigCommand) -> None:
        self._last_tick = tick
        h_speed, h_angle, h_rate, h_tip, h_range = self._hyst_seq
        accel = abs(state.tip_accel_m_s2)
        speed = abs(state.wheel_speed_rad_s)
        angle = abs(state.hub_angle_rad) * 57.29577951308232
        rate = abs(state.hub_rate_rad_s) * 57.29577951308232
        if h_speed.active or speed > h_speed.on:
            self._level(tick, "wheel_speed", h_speed, speed)
        if h_angle.active or angle > h_angle.on:
            self._level(tick, "hub_angle", h_angle, angle)
        if h_rate.active or rate > h_rate.on:
            self._level(tick, "hub_rate", h_rate, rate)
        if h_tip.active or accel > h_tip.on:
            self._level(tick, "tip_accel", h_tip, accel)
        if h_range.active or accel > h_range.on:
            self._level(tick, "accel_range", h_range, accel)
        torque = abs(sent.wheel_torque_n_m)
        if torque >= self._torque_limit * (1.0 - 1e-9):
            self._torque_held += 1
        else:
            self._torque_held = 0
        if self._torque_active:
            if torque < self._torque_off:
                self._torque_active = False
        elif self._torque_held > self._torque_hold_ticks:
            self._torque_active = True
            self._warn(tick, "torque_saturated",
                       f"commanded wheel torque held at its limit {self._torque_limit:g} N m for "
                       f"{self._torque_held * self.dt_s:.3g} s (since t = "
                       f"{(tick - self._torque_held + 1) * self.dt_s:.3f} s)")
        missed = False
        for name, drv in self._due_at[tick % self._due_period]:
            if drv.last_tick != tick and (drv.last_tick > -10**8 or tick >= self.startup_ticks):
                self._missing[name] += 1
                missed = True
        if missed:
            if self._missing_since is None:
                self._missing_since = tick
            if tick >= self._missing_next:
                self._report_missing(tick)


def _monitors(realtime: bool) -> tuple[RigInterface, FaultMonitor, FaultMonitor,
                                        list[MonitorWarning], list[MonitorWarning]]:
    run = load_run("slew-rw", {"monitor": {"warn_torque_saturated_s": 0.02,
                                           "warn_missing_interval_s": 0.05}})
    bus = type("NoBus", (), {"send": lambda self, m: None})()
    iface = RigInterface(bus, load_protocol(), run.rig, None, run.actuators)
    monitors, warned = [], []
    for cls in (FaultMonitor, _AsBefore):
        got: list[MonitorWarning] = []
        monitors.append(cls(
            iface, run.data["monitor"], run.data["limits"], wheel_max_speed_rad_s=100.0,
            accel_range_m_s2=19.6, valve_close_delay_s=0.004, dt_s=run.dt_s,
            realtime=realtime, valve_min_on_s=0.002, wheel_max_torque_n_m=0.065,
            on_warning=got.append))
        warned.append(got)
    return iface, monitors[0], monitors[1], warned[0], warned[1]


def _odd(rng: np.random.Generator, p: float) -> bool:
    return bool(rng.random() < p)


def _play(seed: int, realtime: bool, n_ticks: int = 4000) -> tuple[object, int]:
    """Both monitors on the same random ticks until the first fault; returns it."""
    rng = np.random.default_rng(seed)
    iface, new, old, new_warned, old_warned = _monitors(realtime)
    p = 10 ** rng.uniform(-4.0, -2.3)  # how often something is odd, per draw
    div = iface.divider
    hub_angle, counter, silent_until = 0.1, 0, {n: -1 for n in div}
    state = RigState()
    for tick in range(n_ticks):
        for name, drv in iface.drivers.items():
            if tick % div[name] or tick < silent_until[name]:
                continue
            if _odd(rng, p):
                silent_until[name] = tick + int(rng.integers(1, 40))
                continue
            if _odd(rng, p):
                drv.counters.malformed += 1
            if _odd(rng, p):
                drv.counters.sequence_errors += 1
            if name == "hub_sensor":
                hub_angle += 0.2 if _odd(rng, p) else 1e-4 * rng.standard_normal()
                rate = 6.0 if _odd(rng, p) else math.nan if _odd(rng, p) else 0.01
                values = {"angle": hub_angle, "rate": rate}
                if _odd(rng, 30 * p):
                    values = dict(drv.values) or values  # the same values again
            elif name == "accelerometer":
                counter = (counter + (0 if _odd(rng, 20 * p) else
                                      int(rng.integers(2, 6)) if _odd(rng, p) else 1)) % 65536
                values = {"accel": 25.0 if _odd(rng, p) else math.nan if _odd(rng, p)
                          else rng.normal(0.0, 0.5),
                          "saturated": int(_odd(rng, p)), "fault": int(_odd(rng, p)),
                          "sample_counter": counter}
                if _odd(rng, p):
                    del values["sample_counter"]
            elif name == "reaction_wheel":
                values = {"speed": 103.0 if _odd(rng, p) else 400.0 if _odd(rng, p)
                          else math.nan if _odd(rng, p) else rng.normal(0.0, 30.0),
                          "torque": 0.0, "fault": int(_odd(rng, p))}
            elif name == "thruster_valves":
                values = {"valve_pos_open": int(_odd(rng, 3 * p)), "valve_neg_open": 0,
                          "fault": int(_odd(rng, p))}
            elif name == "piezo_amplifier":
                values = {"sensor_ch1": 0.0, "sensor_ch2": 0.0,
                          "overcurrent": int(_odd(rng, p))}
            else:
                values = {"angle": 0.0, "speed": 0.0}
            drv.values, drv.last_tick = values, tick
        c = iface.counters
        c.unknown += _odd(rng, 5 * p)
        c.error_frames += _odd(rng, 5 * p)
        c.bus_off = c.bus_off or _odd(rng, p / 5)
        state.hub_angle_rad = rng.normal(0.0, 0.5) if not _odd(rng, p) else 4.0
        state.hub_rate_rad_s = rng.normal(0.0, 0.05) if not _odd(rng, p) else math.nan
        state.wheel_speed_rad_s = rng.normal(0.0, 40.0)
        state.tip_accel_m_s2 = rng.normal(0.0, 4.0) if not _odd(rng, p) else 30.0
        sent = RigCommand(wheel_torque_n_m=(0.065 if rng.random() < 0.3 else
                                            math.nan if _odd(rng, p) else 0.01),
                          valve_direction=int(rng.choice([-1, 0, 1], p=[0.02, 0.96, 0.02])))
        event_new = new.check(tick, state, sent)
        event_old = old.check(tick, state, sent)
        assert event_new == event_old, (seed, tick)
        assert [str(w) for w in new_warned] == [str(w) for w in old_warned], (seed, tick)
        if event_new is not None:
            return event_new, len(new_warned)
    new.finish()
    old.finish()
    assert [str(w) for w in new_warned] == [str(w) for w in old_warned]
    return None, len(new_warned)


@pytest.mark.parametrize("realtime", [False, True])
def test_inline_checks_decide_what_the_methods_decide(realtime):
    kinds = set()
    warnings = 0
    for seed in range(60):
        event, n_warned = _play(seed, realtime)
        warnings += n_warned
        if event is not None:
            kinds.add(event.kind)  # type: ignore[attr-defined]
    # the random ticks reached the checks' own methods, not only the usual tick
    assert len(kinds) >= 8, kinds
    assert warnings > 20
