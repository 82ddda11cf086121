"""Fault detection: every tick, the telemetry and the bus counters against what a healthy rig
does. The first fault stops the run: the loop commands the safe state and records the event.

Detection bounds (ticks from the fault's first effect on the bus to its detection), with d
the device's SYNC divider (1 for hub sensor, accelerometer, wheel, piezo; 5 for valves and
rotor in the default rig file):

| check | fault | bound (ticks) |
|---|---|---|
| silent | no telemetry from a device | 2 d + 2 |
| frames lost | `lost_frames` of the device's last 20 due frames missing | 2 lost_frames d |
| late | accelerometer sample counter behind the SYNC count by > `late_ticks` | late_ticks + 1 |
| stuck | accel counter frozen 3 samples; hub values equal `stuck_ticks` times | 3 d; stuck_ticks |
| malformed | a frame of the wrong length (more than `max_malformed_frames`) | 1 |
| implausible | a value no healthy device sends (rate > 5 rad/s, angle step > 0.05 rad, ...) | 1 |
| unknown ids | more than `max_unknown_frames` frames with ids no device uses | that many frames |
| error frames | more than `max_error_frames` error frames; any bus-off | that many frames; 1 |
| flags | accelerometer saturated, wheel fault, piezo over-current | d |
| overspeed | wheel speed beyond 1.02 x its limit | 1 |
| valve stuck | open while commanded closed past closing delay + min on-time | that + 2 d + 1 |
| EMCY (CANopen) | a node's emergency frame, a drive fault; an EMCY not 8 bytes long | 1 |
| node rebooted (CANopen) | a node's boot-up frame mid-run | 1 |
| NMT state (CANopen) | a node's heartbeat says it is not operational | its heartbeat period |
| heartbeat lost (CANopen) | no heartbeat for 3 periods (or the real-time grace) | 3 periods + 1 |
| harness heartbeat lost (CANopen) | a node's EMCY 0x8130 (after a held-back tick: `bus` late) | 1 |
| second master | a SYNC, NMT, SDO request, command or heartbeat the harness did not send | 1 |
| drive disabled | a drive commanded enabled reports otherwise (its CiA 402 state named) | 2 d + 2 |
| frames lost (wall clock) | frames older than the grace g not come (see below) | 2 (g+6) d |
| duplicate frames | a device's frames beyond what the SYNCs asked for | 20 + s; s |
| node id used twice | twice 8 heartbeats of a CANopen node within 5 of its periods | 16 beats |
| physics: hub | the angle's change against its rate's integral over a window | a window |
| physics: wheel | the speed's change against -(torque sent) dt / rotor inertia | a window |
| physics: momentum | hub momentum change vs the wheel's and the valves' (a fit) | 2+ windows |
| stuck (noise) | a channel equal for longer than its noise and resolution make likely | that |
| limits | hub angle, rate, wheel speed or tip acceleration beyond the run's `limits` | 1 |

On the real-time clock, frames may arrive a few ticks late with nothing wrong (a busy
machine): there "silent" and "late" wait at least `realtime_grace_s` (50 ms), and missing
frames count through the frame counters (sequence gaps) and against the SYNCs that asked for
them (a CANopen PDO has no counter): frames asked for more than the grace g ago and not come,
`lost_frames` more than their least count over the last 4 (g + 20 d) ticks, are lost (every
other frame missing: within 2 (g + lost_frames + 1) d ticks). More frames than the SYNCs asked
for (a second node with a device's id) are counted every 20 ticks in lockstep, every tick on
the wall clock, past a slack s of (g / d + 2) frames + 2. A device never heard from is
reported silent only after `startup_s` (0.5 s).

The safe state is commanded in the tick the fault is detected, so the actuators are safe one
tick after detection at the latest (the virtual rig applies commands at the next SYNC).

Warnings: conditions short of a fault that a lab engineer wants flagged without stopping
the run. Each is logged once when its condition starts (WARN, ``/events/monitor`` in the
recording, marked on the plots) and counted in summary.json (``monitor_warnings``); it ends
only when the signal falls below ``1 - warn_hysteresis_fraction`` of its threshold, so a
signal hovering at the threshold warns once. Thresholds are ``monitor:`` keys of the run
file, against the run's ``limits`` and the rig file; warnings never stop a run or change
its verdict by themselves.

| warning | starts when | `monitor:` key, default |
|---|---|---|
| wheel_speed | wheel speed > a fraction of its limit | warn_wheel_speed_fraction 0.8 |
| torque_saturated | torque command at its limit for longer than | warn_torque_saturated_s 1 |
| hub_angle, hub_rate, tip_accel | > a fraction of the run's limits | warn_limits_fraction 0.8 |
| accel_range | tip acceleration > a fraction of the sensor range | warn_accel_range_fraction 0.9 |
| telemetry_missing | frames missing at their tick (count), once per | warn_missing_interval_s 1 |

The wheel's limit is the run's `limits.max_wheel_speed_rad_s` or the rig's, the smaller.
`warn_hysteresis_fraction` (0.05) sets where a warning ends; `warnings: false` turns them off.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from drivers.binding.canopen import cia402_state
from harness.bus.rig_interface import HARNESS_HEARTBEAT_LOST, RigInterface
from harness.core.plausibility import (
    INTEGRATION_FRACTION,
    SIGMAS,
    ChannelQuality,
    binding_step,
    healthy_repeats,
    hub_is_stuck,
    likely_cause,
    sensor_quality,
)
from harness.state import RigCommand, RigState
from rig_models.schema import Field

MONITOR_SCHEMA = {
    "enabled": Field("bool", default=True),
    "stuck_ticks": Field("int", default=50, minimum=2),
    "late_ticks": Field("int", default=2, minimum=1),
    "lost_frames": Field("int", default=5, minimum=1, maximum=20),
    "max_malformed_frames": Field("int", default=0, minimum=0),
    "max_unknown_frames": Field("int", default=10, minimum=0),
    "max_error_frames": Field("int", default=10, minimum=0),
    "realtime_grace_s": Field("number", "s", default=0.05, minimum=0.0),
    "startup_s": Field("number", "s", default=0.5, minimum=0.0),
    # on the wall clock: every device silent at once is the bench (host, transport, bus),
    # waited for this long before the run stops naming the bus (docs/faults.md)
    "bench_stall_s": Field("number", "s", default=1.0, exclusive_minimum=0.0,
                           maximum=60.0),
    # the rig's physics every run: hub angle against its rate's integral, wheel speed
    # against the commanded torque's integral, over windows of this length (docs/faults.md)
    "plausibility": Field("bool", default=True),
    "plausibility_window_s": Field("number", "s", default=1.0, exclusive_minimum=0.0),
    # warnings (conditions short of a fault; see the module docstring)
    "warnings": Field("bool", default=True),
    "warn_wheel_speed_fraction": Field("number", "fraction of the wheel speed limit",
                                       default=0.8, exclusive_minimum=0.0, maximum=1.0),
    "warn_torque_saturated_s": Field("number", "s", default=1.0, minimum=0.0),
    "warn_limits_fraction": Field("number", "fraction of the run's limits", default=0.8,
                                  exclusive_minimum=0.0, maximum=1.0),
    "warn_accel_range_fraction": Field("number", "fraction of the accelerometer's range",
                                       default=0.9, exclusive_minimum=0.0, maximum=1.0),
    "warn_hysteresis_fraction": Field("number", "fraction of the threshold", default=0.05,
                                      minimum=0.0, maximum=0.5),
    "warn_missing_interval_s": Field("number", "s", default=1.0, exclusive_minimum=0.0),
}
WARNING_KINDS = ("wheel_speed", "torque_saturated", "hub_angle", "hub_rate", "tip_accel",
                 "accel_range", "telemetry_missing")
LOST_WINDOW = 20
# a hub sample no healthy sensor sends: a rate beyond this, an angle step beyond this in a
# tick (the hub check and its inline all-clear path in check() both read these)
HUB_RATE_PLAUSIBLE_RAD_S = 5.0
HUB_ANGLE_STEP_PLAUSIBLE_RAD = 0.05
"""A device's frames lost: ``lost_frames`` of its last this many due frames missing."""

SURPLUS_EVERY = 20
"""In lockstep, frames are counted against the SYNCs that asked for them every this many
ticks (a second node with a device's id doubles its frames); on the wall clock every tick."""


class DeviceWatch:
    """What the monitor keeps of one device between ticks (its frames due and lost)."""

    __slots__ = ("name", "driver", "divider", "stale_ticks", "misses", "due", "silent_after",
                 "frames", "base_rx", "base_due", "window", "lost_at", "span", "slack",
                 "behind", "deficit")

    def __init__(self, name: str, driver: Any, divider: int, stale_ticks: int,
                 grace_ticks: int, frames: int) -> None:
        self.name = name
        self.driver = driver
        self.divider = divider
        self.stale_ticks = stale_ticks
        # lockstep: the numbers of its due frames that were missing among its last
        # LOST_WINDOW due frames, and how many of its frames were due so far
        self.misses: deque[int] = deque()
        self.due = 0
        # silent past this age: its stale ticks, and on the wall clock at least the grace
        self.silent_after = max(stale_ticks, grace_ticks)
        # frames it sends per SYNC that asks (a device over several frames sends each)
        self.frames = frames
        # counted from the first tick it was heard from: its frames received then, and the
        # frames due by then
        self.base_rx: int | None = None
        self.base_due = 0
        # on the wall clock: (tick, frames not come) for the running minimum over the last
        # ``span`` ticks, increasing values (a monotonic queue: amortised O(1) a tick); a
        # loss beyond its limit is ``lost_at`` frames more than that minimum, the grace's
        # frames in flight included
        self.window: deque[tuple[int, int]] = deque()
        self.lost_at = frames * (grace_ticks // divider + 1)
        self.span = 4 * (grace_ticks + LOST_WINDOW * divider)
        # frames beyond those asked for that a healthy device can show: its frames of the
        # SYNCs before it was first counted that were still on their way (the grace)
        self.slack = frames * (grace_ticks // divider + 2) + 2
        # on the wall clock: its frames asked for and not come, beyond the least over the
        # last ``span`` ticks (what ``lost_at`` bounds); a bench behind shows in every device
        self.behind = 0
        # ... and since it was first heard from (frames in flight included)
        self.deficit = 0

    def due_by(self, tick: int) -> int:
        """Its frames due at ticks 0..tick."""
        return self.frames * (tick // self.divider + 1) if tick >= 0 else 0


class PlausibilityWindow:
    """What the physics checks gather over one window (``_plausible_window``): the hub's
    angle and its rate's trapezoid integral, the wheel's speed and the torque sent."""

    __slots__ = ("every", "end", "angle", "rate", "rate_bias", "noise_factor",
                 "wheel_inertia", "wheel_lag_s", "torque_fraction", "wheel_step",
                 "wheel_speed_max", "hub_tick", "hub_tick0", "hub_n", "angle0", "angle_last",
                 "rate_last", "rate_int", "wheel_tick", "wheel_tick0", "wheel_n", "speed0",
                 "speed_last", "wheel_ok", "torque_int", "torque_abs", "torque_peak",
                 "rate_tv", "wheel_speed_near", "rate0", "valve_int", "rotor_on",
                 "friction_coulomb", "friction_viscous", "friction_tol", "friction_int",
                 "rate_bias_model", "torque_at_sample", "friction_at_sample",
                 "direction", "reversed_at", "ring_ticks", "reverse_min",
                 "stale_windows", "hub_div", "wheel_div",
                 "hub_inertia", "couple", "balance_min", "inertia_fraction",
                 "couple_fraction", "wheel_checked")

    def __init__(self, every: int, angle: ChannelQuality | None, rate: ChannelQuality | None,
                 rate_bias: float, noise_factor: float, wheel_inertia: float,
                 wheel_lag_s: float, torque_fraction: float, wheel_step: float,
                 wheel_speed_max: float) -> None:
        self.every = every
        self.angle, self.rate = angle, rate
        self.rate_bias, self.noise_factor = rate_bias, noise_factor
        self.wheel_inertia, self.wheel_lag_s = wheel_inertia, wheel_lag_s
        self.torque_fraction, self.wheel_step = torque_fraction, wheel_step
        self.wheel_speed_max = wheel_speed_max
        # near its limit the wheel refuses torque: such a window is not judged
        self.wheel_speed_near = 0.95 * wheel_speed_max
        # the wheel's bearing friction as the rig file models it, and how much friction the
        # file allows beyond its model (``friction``)
        self.friction_coulomb = self.friction_viscous = self.friction_tol = 0.0
        self.rate_bias_model = 0.0  # the hub rate's bias as the file models it
        # the torque (and modelled friction) summed up to the wheel's last sample: the
        # torque sent after it belongs to the next window (its next sample shows it)
        self.torque_at_sample = self.friction_at_sample = 0.0
        self.torque_int = self.friction_int = 0.0
        # windows not judged for samples that did not come in time (a stalled bench): a
        # check must not judge stale data
        self.stale_windows = 0
        self.hub_div = self.wheel_div = 1
        # the sign of the last excitation (wheel torque, or the valves' couple), the tick it
        # last reversed, and how long a reversal keeps the momentum balance from judging
        self.direction = 0
        self.reversed_at = -(1 << 62)
        self.ring_ticks = 0
        self.reverse_min = math.inf
        # the momentum balance (``FaultMonitor._balance``): off until ``balance``
        self.hub_inertia = self.couple = 0.0
        self.balance_min = math.inf
        self.inertia_fraction = self.couple_fraction = 0.0
        self.hub_tick = self.wheel_tick = -1
        self.rate_last = self.angle_last = self.speed_last = 0.0
        self.restart(0)

    def balance(self, hub_inertia: float, couple: float, window_s: float,
                min_torque: float, inertia_fraction: float, couple_fraction: float) -> None:
        """Judge the momentum balance in windows whose exchanged momentum is at least
        ``BALANCE_MIN_FRACTION`` of ``min_torque`` over the window."""
        self.hub_inertia, self.couple = hub_inertia, couple
        self.balance_min = BALANCE_MIN_FRACTION * min_torque * window_s
        self.reverse_min = 0.1 * min_torque
        self.inertia_fraction, self.couple_fraction = inertia_fraction, couple_fraction

    def restart(self, tick: int) -> None:
        """A new window from ``tick``, from the last samples of the one before."""
        self.end = tick + self.every
        self.hub_tick0, self.angle0, self.rate_int = self.hub_tick, self.angle_last, 0.0
        self.rate0 = self.rate_last
        self.rate_tv = 0.0
        self.valve_int = 0
        self.rotor_on = False
        # the modelled friction torque on the rotor summed over the window's ticks (N m);
        # both integrals carry what was sent after the wheel's last sample over
        self.friction_int -= self.friction_at_sample
        self.wheel_checked = False
        self.hub_n = 1 if self.hub_tick >= 0 else 0
        self.wheel_tick0, self.speed0 = self.wheel_tick, self.speed_last
        self.wheel_n = 1 if self.wheel_tick >= 0 else 0
        self.wheel_ok = True
        self.torque_int -= self.torque_at_sample
        self.torque_at_sample = self.friction_at_sample = 0.0
        self.torque_abs = 0.0
        # the torque loop's output at the window's start trails the last window's commands:
        # their peak bounds it (no torque commanded in this window can still turn the wheel)
        self.torque_peak = getattr(self, "torque_peak", 0.0)


BALANCE_MIN_FRACTION = 0.25
"""The momentum balance judges a window whose predicted momentum change is at least this
fraction of the smaller of the wheel's torque limit and the valves' couple held over the
window (0.016 N m s on the sgsrt: a wheel at a quarter of its torque for 1 s)."""

BALANCE_BAND_FRACTION = 0.5
"""... and its regression slope, the hub's momentum change on the prediction over the
windows so far, must lie within 1 +- this plus the file's inertia (and for the valves
couple) tolerance, within ``BALANCE_SIGMAS`` standard errors. Wide, since the check is for
what no tolerance explains: a reversed hub sensor or swapped valves (a slope of -1), a
gross factor. The valves' state is read every few ticks (the sgsrt's every 5th), and PWM
pulses shorter than that alias their open time: their slope scatters more, and its
standard error says so."""


STALE_FRACTION = 0.9
"""A physics window is judged only with this fraction of its device's samples (one per
SYNC that asks) come each in a tick of its own; fewer, the samples were late (a stalled
host, a slow transport) and the window is counted as stale (``monitor_stale_windows`` in
summary.json), not judged."""

BALANCE_RING_PERIODS = 2.0
"""After the excitation reverses (the wheel's torque, the valves' couple), the momentum
balance judges no window for this many periods of the first hub-free mode: a reversal can
pump the beam's modes, and the momentum they then carry and give back is not in the rigid
prediction."""

BALANCE_SIGMAS = 4.0
"""The momentum balance's slope is judged this many standard errors from its band."""


class SlopeFit:
    """A least-squares slope through the origin, y = k x, from running sums."""

    __slots__ = ("n", "spp", "smp", "smm")

    def __init__(self) -> None:
        self.n = 0
        self.spp = self.smp = self.smm = 0.0

    def add(self, x: float, y: float) -> None:
        self.n += 1
        self.spp += x * x
        self.smp += x * y
        self.smm += y * y

    def slope(self) -> tuple[float, float]:
        """The slope and its standard error (the residuals' scatter)."""
        k = self.smp / self.spp
        rss = max(0.0, self.smm - k * self.smp)
        return k, math.sqrt(rss / max(1, self.n - 1) / self.spp)


def _cause(measured: float, predicted: float, band: float, still: str) -> str:
    """The likely cause of a measured change against the physics' prediction."""
    if abs(predicted) <= band:
        return (f"a reading that moves where {still}: a wrong object or signal, an offset "
                "that changes, or a torque the rig file does not know of")
    # the band over SIGMAS: the ratio's noise, as well as a window's sums tell it
    return likely_cause(measured / predicted, band / abs(predicted) / SIGMAS)


def _quantity_step(rig: Any, device: str, quantity: str) -> float:
    """The step of a telemetry quantity as the rig's binding carries it (SI; 0 unknown)."""
    return binding_step(rig.binding, device, quantity)


def _frames_per_due(interface: Any) -> dict[str, int]:
    """Each device's distinct telemetry frames (or multiplexed pages) per due SYNC."""
    b = getattr(interface, "binding", None)
    if b is None:
        return {}
    return {name: len({(m.key, m.mux) for m in maps}) or 1
            for name, maps in b.telemetry.items()}


LIMITS_SCHEMA = {
    "max_angle_deg": Field("number", "deg", default=180.0, exclusive_minimum=0.0),
    "max_rate_deg_s": Field("number", "deg/s", default=10.0, exclusive_minimum=0.0),
    "max_wheel_speed_rad_s": Field("number", "rad/s", default=0.0, minimum=0.0),
    "max_tip_accel_m_s2": Field("number", "m/s^2", default=15.0, exclusive_minimum=0.0),
}


@dataclass(frozen=True)
class FaultEvent:
    tick: int
    time_s: float
    device: str
    kind: str
    message: str

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def __str__(self) -> str:
        return f"{self.device}: {self.kind}: {self.message} (t = {self.time_s:.3f} s)"


@dataclass(frozen=True)
class MonitorWarning:
    """A condition short of a fault, at its start (``kind`` one of ``WARNING_KINDS``)."""

    tick: int
    time_s: float
    kind: str
    message: str

    def __str__(self) -> str:
        return f"monitor: {self.kind.replace('_', ' ')}: {self.message} (t = {self.time_s:.3f} s)"


class Hysteresis:
    """``x > on`` starts the condition (``update`` returns True once, at its start); it ends
    only when ``x < off`` (``off <= on``), so a signal hovering at ``on`` starts it once."""

    __slots__ = ("on", "off", "active")

    def __init__(self, on: float, off: float) -> None:
        self.on, self.off, self.active = on, min(off, on), False

    def update(self, x: float) -> bool:
        if self.active:
            if x < self.off:
                self.active = False
            return False
        if x > self.on:
            self.active = True
            return True
        return False


class FaultMonitor:
    def __init__(self, interface: RigInterface, monitor: dict[str, Any], limits: dict[str, Any],
                 wheel_max_speed_rad_s: float, accel_range_m_s2: float, valve_close_delay_s: float,
                 dt_s: float, realtime: bool = False, valve_min_on_s: float = 0.0,
                 wheel_max_torque_n_m: float = math.inf,
                 on_warning: Callable[[MonitorWarning], None] | None = None,
                 rig: Any = None) -> None:
        self.iface = interface
        # on the wall clock a frame can be a few ticks late without anything being wrong
        self.realtime_grace = math.ceil(monitor["realtime_grace_s"] / dt_s) if realtime else 0
        self.cfg = monitor
        self.limits = dict(limits)
        if not self.limits["max_wheel_speed_rad_s"]:
            self.limits["max_wheel_speed_rad_s"] = wheel_max_speed_rad_s
        self.wheel_max = wheel_max_speed_rad_s
        self.accel_range = accel_range_m_s2
        self.dt_s = dt_s
        self.div = interface.divider
        # a valve may close late by its closing delay, and a short pulse is stretched to the
        # valve's minimum on-time
        self.valve_close_ticks = math.ceil((valve_close_delay_s + valve_min_on_s) / dt_s)
        self.grace = max(2 * d + 2 for d in self.div.values())
        self.startup_ticks = math.ceil(monitor["startup_s"] / dt_s)
        # per device, built once (the tick's checks then touch only what changed)
        frames_per_due = _frames_per_due(interface)
        self._lost: list[DeviceWatch] = [
            DeviceWatch(name, drv, self.div[name],
                        getattr(drv, "stale_after_ticks", 2 * self.div[name] + 1),
                        self.realtime_grace, frames_per_due.get(name, 1))
            for name, drv in interface.drivers.items()]
        self._drivers = list(interface.drivers.items())
        self._frame_counters = tuple(drv.counters for _, drv in self._drivers
                                     if hasattr(drv, "counters"))
        # _silent_and_lost: no device can be silent before this tick (from the last full
        # pass); the devices due at each tick modulo the dividers' least common multiple
        self._silent_from = 0
        # a stall of the whole bench on the wall clock (_bench_stall): since when, how many
        self._stall_from: int | None = None
        self._resumed_at: int | None = None
        # never shorter than two graces: a device is called silent only past the grace
        self._bench_stall_s = max(float(monitor.get("bench_stall_s", 1.0)),
                                  2.0 * float(monitor.get("realtime_grace_s", 0.0)))
        self.bench_stalls = 0
        self.bench_behind = 0  # episodes of every device's frames late beyond the grace
        self._behind_since: int | None = None
        self._behind_last = 0
        self.not_held_tick = -(1 << 62)  # the last tick the loop did not hold (wall clock)
        # the last tick late by half a CANopen node's heartbeat consumer time or more: the
        # harness's heartbeat (sent every tick) may have come too late at a node
        co = getattr(interface, "co", None)
        consumer_s = getattr(co, "consumer_timeout_ms", 0) * 1e-3
        self._hb_late_s = 0.5 * consumer_s if consumer_s > 0 else math.inf
        self.hb_late_tick = -(1 << 62)
        self._watchdog_ticks = math.ceil(
            float(rig.data["watchdog"]["heartbeat_timeout_s"]) / dt_s) if rig is not None else 0
        self.bench_stall_max_s = 0.0
        lost_period = math.lcm(*(w.divider for w in self._lost)) if self._lost else 1
        self._lost_due_period = lost_period if lost_period <= 10_000 else 0
        self._lost_due_at = [tuple(w for w in self._lost if k % w.divider == 0)
                             for k in range(self._lost_due_period)]
        # frames counted against the SYNCs that asked for them (every tick on the wall
        # clock, where no frame counter tells a missing frame; every SURPLUS_EVERY ticks in
        # lockstep, for frames beyond what the SYNCs asked for)
        self._count_every = 1 if self.realtime_grace else SURPLUS_EVERY
        self._max_error_frames = monitor["max_error_frames"]
        self._max_unknown_frames = monitor["max_unknown_frames"]
        self._lost_limit = int(monitor["lost_frames"])
        self._max_malformed = monitor["max_malformed_frames"]
        self._accel_div = self.div.get("accelerometer", 1)
        # a reading within this is plausible (the accelerometer's check, inline in check())
        self._accel_plausible = accel_range_m_s2 + 0.01
        # a wheel speed within this is neither implausible nor an overspeed
        self._wheel_implausible = 1.5 * wheel_max_speed_rad_s + 1.0
        self._wheel_overspeed_at = 1.02 * wheel_max_speed_rad_s
        self._wheel_overspeed = min(self._wheel_implausible, self._wheel_overspeed_at)
        self._bus_counters = getattr(interface, "counters", None)
        self._late_limit = max(monitor["late_ticks"], self.realtime_grace)
        lim = self.limits
        # the limits in SI, a hair inside: a value this side is within its limit for sure;
        # anything else is judged in the limits' own units (_limits)
        inside = 1.0 - 1e-9
        self._limit_bounds = (math.radians(lim["max_angle_deg"]) * inside,
                              math.radians(lim["max_rate_deg_s"]) * inside,
                              lim["max_wheel_speed_rad_s"] * inside,
                              lim["max_tip_accel_m_s2"] * inside)
        # the bus protocol's own fault reports only where the interface has them (CANopen)
        self._protocol_fault = (getattr(interface, "protocol_fault", None)
                                if getattr(interface, "has_protocol_faults", True) else None)
        self._enabled = bool(monitor["enabled"])
        # the devices whose telemetry check() looks at (None: not on this rig's bus)
        self._device_drivers = tuple(interface.drivers.get(name) for name in (
            "accelerometer", "hub_sensor", "reaction_wheel", "thruster_valves",
            "piezo_amplifier"))
        self._accel_offset: int | None = None
        self._accel_last: tuple[int, int] | None = None  # (counter, tick of that counter)
        self._accel_same = 0
        self._hub_last: tuple[float, float] | None = None
        self._hub_same = 0
        self._hub_tick = -1
        self._wheel_tick = -1
        # armed means enabled: a drive the harness commands enabled that reports otherwise
        # (another master's controlword, its own quick stop) after the command's delay
        acting = () if getattr(interface, "dry_run", False) else getattr(
            interface, "actuators", ())
        self._enable_lag = {name: 2 * d + 2 + self.realtime_grace
                            for name, d in self.div.items()}
        self._watch_wheel_enable = "reaction_wheel" in acting
        self._rotor_drv = (interface.drivers.get("disturbance_rotor")
                           if "disturbance_rotor" in acting else None)
        self._rotor_enabled_since: int | None = None
        # the tick since which each drive has reported itself disabled (None: enabled); a
        # drive that stays off past the command's delay is a fault, one whose own watchdog
        # blinked it off (a stalled host) and the next command brought back is not
        self._wheel_off_since: int | None = None
        self._rotor_off_since: int | None = None
        self._valve_closed_since = 0
        self._seen_tick: dict[str, int] = {}
        self.on_warning = on_warning
        self._init_warnings(monitor, wheel_max_torque_n_m)
        self._init_plausibility(rig, monitor)

    # ------------------------------------------------------------------ plausibility
    def _init_plausibility(self, rig: Any, cfg: dict[str, Any]) -> None:
        """The rig file's sensors (resolution, noise) and model (wheel inertia, torque lag)
        and its tolerances, for the checks that hold every run to the physics: a channel
        still for longer than its noise allows, the hub angle against its rate's integral,
        the wheel speed against the commanded torque's integral (a mis-bound quantity stops
        the run naming it)."""
        self._pw: PlausibilityWindow | None = None
        self._half_dt = 0.5 * self.dt_s
        self._accel_const_limit = self._piezo_const_limit = 1 << 62
        self._q: dict[str, ChannelQuality] = {}
        self._accel_value = self._piezo_value = None
        self._accel_const = self._piezo_const = 0
        if rig is None or not cfg.get("enabled", True):
            return
        q = self._q = sensor_quality(rig)
        stuck = int(cfg["stuck_ticks"])
        def limit(channels: tuple[ChannelQuality, ...]) -> int:
            # equal samples in a row past which a healthy sensor is improbable (never, for
            # a sensor whose noise stays well inside one step)
            healthy = healthy_repeats(channels)
            return max(stuck, math.floor(healthy) + 1) if math.isfinite(healthy) else 1 << 62

        if "accelerometer.accel" in q:
            self._accel_const_limit = limit((q["accelerometer.accel"],))
        piezo = tuple(q[c] for c in ("piezo_amplifier.sensor_ch1",
                                     "piezo_amplifier.sensor_ch2") if c in q)
        if len(piezo) == 2 and rig.data.get("piezo_patches"):  # no patches: nothing to sense
            self._piezo_const_limit = limit(piezo)
        if not cfg.get("plausibility", True):
            return
        tol = rig.data.get("tolerances") or {}
        wheel = rig.section("reaction_wheel")
        self._pw = PlausibilityWindow(
            every=max(1, round(float(cfg.get("plausibility_window_s", 1.0)) / self.dt_s)),
            angle=q.get("hub_sensor.angle"), rate=q.get("hub_sensor.rate"),
            rate_bias=float(tol.get("rate_bias_rad_s", 0.0)),
            noise_factor=float(tol.get("noise_factor", 1.0)),
            wheel_inertia=float(wheel["rotor_inertia_kg_m2"]),
            wheel_lag_s=float(wheel.get("torque_lag_s", 0.0)),
            torque_fraction=float(tol.get("torque_fraction", 0.0))
            + float(tol.get("inertia_fraction", 0.0)),
            wheel_step=_quantity_step(rig, "reaction_wheel", "speed"),
            wheel_speed_max=self.wheel_max)
        # the wheel's friction as the file models it (a coasting wheel slows by it), and
        # the friction it allows unmodelled (a torque below it may not turn a wheel at rest)
        self._pw.friction_coulomb = float(wheel.get("friction_coulomb_n_m") or 0.0)
        self._pw.friction_viscous = float(wheel.get("friction_viscous_n_m_s") or 0.0)
        self._pw.friction_tol = float(tol.get("wheel_friction_n_m") or 0.0)
        self._pw.hub_div = self.div.get("hub_sensor", 1)
        self._pw.wheel_div = self.div.get("reaction_wheel", 1)
        self._pw.rate_bias_model = float(
            rig.section("hub_sensor").get("rate_bias_rad_s") or 0.0)
        acting = set(getattr(self.iface, "actuators", ()) or ())
        wheel_on = "reaction_wheel" in acting and "reaction_wheel" in self.div
        valves_on = "thruster_valves" in acting and "thruster_valves" in self.div
        self._fit_wheel, self._fit_valves = SlopeFit(), SlopeFit()
        if "hub_sensor" in self.div and (wheel_on or valves_on):
            valves = rig.section("thruster_valves")
            couple = float(valves["couple_n_m"])
            # a reversal of the excitation can pump a mode: the balance waits two periods of
            # the first hub-free mode after one (the free decay's bursts at resonance gave
            # the rigid prediction a slope of -1.65 over 70 windows)
            w1 = float(rig.plant.hub_free_modes()[0][0])
            self._pw.ring_ticks = math.ceil(BALANCE_RING_PERIODS * 2 * math.pi / w1 / self.dt_s)
            self._pw.balance(
                hub_inertia=float(rig.plant.inertia_kg_m2), couple=couple,
                window_s=self._pw.every * self.dt_s,
                min_torque=min(float(wheel["max_torque_n_m"]) if wheel_on else math.inf,
                               couple if valves_on else math.inf),
                inertia_fraction=float(tol.get("inertia_fraction", 0.0)),
                couple_fraction=float(tol.get("couple_fraction", 0.0)))

    def _plausible_window(self, tick: int) -> FaultEvent | None:
        """At the end of a window: the hub angle's change against its rate's integral, the
        wheel speed's change against minus the commanded torque's integral over the
        rotor's inertia, each within the rig file's noise and tolerances."""
        pw = self._pw
        assert pw is not None
        event = None
        dt = self.dt_s
        # a device whose samples did not all come in time (late frames on a stalled bench
        # arrive together and the monitor sees the last): its checks skip the window
        hub_stale = pw.hub_n < STALE_FRACTION * pw.every / pw.hub_div
        wheel_stale = pw.wheel_n < STALE_FRACTION * pw.every / pw.wheel_div
        if self.not_held_tick >= tick - pw.every - self.realtime_grace:
            # the loop itself held a tick back in the window (note_not_held): its samples
            # came bunched, their ticks are when they came, not when they were taken
            hub_stale = wheel_stale = True
        if (hub_stale and pw.hub_n) or (wheel_stale and pw.wheel_n):
            pw.stale_windows += 1
        if pw.hub_n >= 2 and pw.angle is not None and pw.rate is not None and not hub_stale:
            moved = pw.angle_last - pw.angle0
            span_s = (pw.hub_tick - pw.hub_tick0) * dt
            # the rate's bias the file models is no motion of the angle
            integral = pw.rate_int - pw.rate_bias_model * span_s
            sample_dt = span_s / max(1, pw.hub_n - 1)
            noise = pw.noise_factor * math.sqrt(
                2.0 * pw.angle.noise_rms ** 2
                + (pw.hub_n - 1) * (pw.rate.noise_rms * sample_dt) ** 2)
            # on the wall clock a sample's tick is when it came, up to the grace late: the
            # trapezoid's weights move by that much against the rate's changes
            band = (INTEGRATION_FRACTION * max(abs(moved), abs(integral)) + SIGMAS * noise
                    + pw.rate_bias * span_s + 2.0 * pw.angle.resolution
                    + pw.rate.resolution * span_s + self.realtime_grace * dt * pw.rate_tv)
            if abs(moved - integral) > band:
                cause = _cause(moved, integral, band, "the rate says the hub is still")
                event = self._event(tick, "hub_sensor", "implausible", (
                    f"angle and rate disagree: the angle moved {math.degrees(moved):+.4g} deg "
                    f"in {span_s:.3g} s, the rate's integral says "
                    f"{math.degrees(integral):+.4g} deg (within "
                    f"{math.degrees(band):.3g} deg); likely {cause}"))
        if event is None and pw.wheel_n >= 2 and pw.wheel_ok and not wheel_stale:
            pw.wheel_checked = True
            changed = pw.speed_last - pw.speed0
            predicted = -(pw.torque_at_sample + pw.friction_at_sample) * dt \
                / pw.wheel_inertia
            span_s = (pw.wheel_tick - pw.wheel_tick0) * dt
            band = (pw.torque_fraction * pw.torque_abs * dt
                    # friction the file does not model: at most its tolerance, all along
                    + pw.friction_tol * span_s
                    # the torque loop's lag: its output trails the command by lag x the
                    # change of its output over the window, at most twice the peak; the
                    # command acts a tick late (on the wall clock up to the grace later)
                    + 2.0 * pw.torque_peak * (pw.wheel_lag_s + (1 + self.realtime_grace) * dt)
                    ) / pw.wheel_inertia + 2.0 * pw.wheel_step
            if abs(changed - predicted) > band:
                cause = _cause(changed, predicted, band, "no torque was commanded")
                event = self._event(tick, "reaction_wheel", "implausible", (
                    f"speed against the commanded torque: it changed by {changed:+.4g} rad/s "
                    f"in {span_s:.3g} s, the torque's integral over the rotor's inertia says "
                    f"{predicted:+.4g} rad/s (within {band:.3g}); likely {cause}"))
                pw.wheel_checked = False
        if (event is None and pw.hub_inertia > 0.0 and not pw.rotor_on and pw.hub_n >= 2
                and not hub_stale and not (wheel_stale and pw.wheel_n)):
            event = self._balance(tick, pw)
        pw.restart(tick)
        return event

    def _balance(self, tick: int, pw: PlausibilityWindow) -> FaultEvent | None:
        """The momentum balance: the hub's momentum change over each window (its rate's
        change times the rig file's inertia) against the prediction, minus the wheel's
        measured momentum change plus the valves' couple over their reported open time.
        Friction, the torque loop's lag and the wheel's limits are all inside the wheel's
        measured speed, so they cannot upset it; what can is a hub sensor mounted reversed,
        valves swapped, a gross scale.

        The beam's vibration carries momentum the rigid prediction leaves out, as much as
        the prediction itself in a window of the free-decay run's bursts: one window proves
        nothing. So the windows so far are regressed, the hub's change on the prediction
        through the origin, the windows of the wheel alone apart from those of the valves
        alone (the attribution), and the slope ``k`` is judged with its standard error
        ``se`` (the scatter of the windows about the fit): a fault when
        ``|k - 1| - BALANCE_SIGMAS se`` is beyond ``BALANCE_BAND_FRACTION`` plus the file's
        inertia (or couple) tolerance, once the windows' predictions add up to at least
        one window's worth (``balance_min``). Windows with the disturbance rotor turning
        (its torque is not measured), a driven wheel whose own speed check did not run, or
        both actuators at once are left out."""
        if tick - pw.reversed_at < pw.every + pw.ring_ticks:
            return None  # the excitation reversed: the beam may ring with the momentum
        wheel = 0.0
        if pw.wheel_n >= 2:
            if not pw.wheel_checked and pw.torque_abs > 0.0:
                return None  # driven, its speed unverified this window: no prediction
            wheel = -(pw.speed_last - pw.speed0) * pw.wheel_inertia
        valve = pw.valve_int * self.dt_s * pw.couple
        measured = pw.hub_inertia * (pw.rate_last - pw.rate0)
        if abs(valve) <= 0.1 * abs(wheel) or (valve == 0.0 and wheel == 0.0):
            fit, predicted, tol = self._fit_wheel, wheel, pw.inertia_fraction
        elif abs(wheel) <= 0.1 * abs(valve):
            fit, predicted, tol = self._fit_valves, valve, pw.inertia_fraction \
                + pw.couple_fraction
        else:
            return None
        fit.add(predicted, measured)
        if not fit.spp >= pw.balance_min ** 2 or fit.n < 2:
            return None
        k, se = fit.slope()
        allowed = BALANCE_BAND_FRACTION + tol
        if abs(k - 1.0) - BALANCE_SIGMAS * se <= allowed:
            return None
        span_s = fit.n * pw.every * self.dt_s
        said = (f"over {fit.n} windows ({span_s:.3g} s) the hub's momentum changed by "
                f"{k:+.3g} +- {se:.2g} x the prediction (its rate's change x the rig file's "
                f"inertia {pw.hub_inertia:g} kg m^2; allowed 1 +- {allowed:.2g})")
        cause = likely_cause(k, se)
        if fit is self._fit_wheel:
            return self._event(tick, "hub_sensor", "implausible", (
                f"momentum balance against the wheel: {said}; likely {cause} of the hub "
                "sensor's angle and rate (they agree with each other), or the rig file's "
                "hub.inertia_kg_m2"))
        w = self._fit_wheel
        vouched = w.n >= 2 and w.spp >= pw.balance_min ** 2
        blame = ("the positive and negative valve swapped (their commands or their "
                 "read-back), the wheel's windows having vouched for the hub sensor"
                 if vouched else "the valves swapped or the hub sensor reversed (no "
                 "window of the wheel alone vouched for the hub sensor in this run)")
        return self._event(tick, "thruster_valves", "implausible", (
            f"momentum balance against the valves' couple: {said}; likely {cause}: {blame}"))

    @property
    def stale_windows(self) -> int:
        """Physics windows not judged for late samples (``STALE_FRACTION``)."""
        return self._pw.stale_windows if self._pw is not None else 0

    # ------------------------------------------------------------------ warnings
    def _init_warnings(self, cfg: dict[str, Any], wheel_max_torque_n_m: float) -> None:
        get = cfg.get
        self.warnings_on = bool(get("enabled", True) and get("warnings", True))
        self.warning_counts: dict[str, int] = dict.fromkeys(WARNING_KINDS, 0)
        off = 1.0 - float(get("warn_hysteresis_fraction", 0.05))
        lim = self.limits
        speed_limit = min(lim["max_wheel_speed_rad_s"], self.wheel_max)
        f_lim = float(get("warn_limits_fraction", 0.8))
        # kind -> (fraction, limit, unit, what the limit is): |value| > fraction x limit
        self._levels = {
            "wheel_speed": (float(get("warn_wheel_speed_fraction", 0.8)), speed_limit, "rad/s",
                            "the wheel speed limit"),
            "hub_angle": (f_lim, lim["max_angle_deg"], "deg", "limits.max_angle_deg"),
            "hub_rate": (f_lim, lim["max_rate_deg_s"], "deg/s", "limits.max_rate_deg_s"),
            "tip_accel": (f_lim, lim["max_tip_accel_m_s2"], "m/s^2",
                          "limits.max_tip_accel_m_s2"),
            "accel_range": (float(get("warn_accel_range_fraction", 0.9)), self.accel_range,
                            "m/s^2", "the accelerometer's range"),
        }
        self._hyst = {k: Hysteresis(f * limit, off * f * limit)
                      for k, (f, limit, _, _) in self._levels.items()}
        self._torque_limit = wheel_max_torque_n_m
        self._torque_hold_ticks = math.ceil(float(get("warn_torque_saturated_s", 1.0))
                                            / self.dt_s - 1e-9)
        self._torque_held = 0
        self._torque_active = False  # saturated past the hold, not yet released
        self._torque_off = off * wheel_max_torque_n_m
        self._missing_every = max(1, round(float(get("warn_missing_interval_s", 1.0)) / self.dt_s))
        self._missing_next = 0  # first tick a missing-frame count may be reported at
        self._missing: dict[str, int] = dict.fromkeys(self.div, 0)
        self._missing_since: int | None = None
        self._last_tick = 0
        self._due = [(name, drv, self.div[name]) for name, drv in self.iface.drivers.items()]
        # the devices due at each tick, by tick modulo the dividers' least common multiple
        # (built once; the tick then looks only at what is due)
        period = math.lcm(*self.div.values()) if self.div else 1
        self._due_period = period if period <= 10_000 else 0
        self._due_at = [tuple((name, drv) for name, drv, div in self._due if k % div == 0)
                        for k in range(self._due_period)]
        h = self._hyst
        self._hyst_seq = (h["wheel_speed"], h["hub_angle"], h["hub_rate"], h["tip_accel"],
                          h["accel_range"])
        # the levels' thresholds (speed, angle, rate, acceleration: the lower of tip_accel's
        # and accel_range's); _quiet_levels is them while no warning is active, else None
        self._levels_on = (h["wheel_speed"].on, h["hub_angle"].on, h["hub_rate"].on,
                           min(h["tip_accel"].on, h["accel_range"].on))
        self._quiet_levels: tuple[float, float, float, float] | None = self._levels_on
        self._torque_at_limit = wheel_max_torque_n_m * (1.0 - 1e-9)

    def _warn(self, tick: int, kind: str, message: str) -> None:
        self.warning_counts[kind] += 1
        if self.on_warning is not None:
            self.on_warning(MonitorWarning(tick, tick * self.dt_s, kind, message))

    def _warnings(self, tick: int, state: RigState, sent: RigCommand) -> None:
        self._last_tick = tick
        accel = abs(state.tip_accel_m_s2)
        speed = abs(state.wheel_speed_rad_s)
        angle = abs(state.hub_angle_rad) * 57.29577951308232
        rate = abs(state.hub_rate_rad_s) * 57.29577951308232
        # the usual tick: no warning active and every value below its level (one test
        # each, in the order the warnings are reported); with none active, the levels'
        # thresholds first, all at once
        quiet = self._quiet_levels
        if not (quiet is not None and speed <= quiet[0] and angle <= quiet[1]
                and rate <= quiet[2] and accel <= quiet[3]):
            h_speed, h_angle, h_rate, h_tip, h_range = self._hyst_seq
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
            self._quiet_levels = (None if any(h.active for h in self._hyst_seq) else
                                  self._levels_on)
        torque = abs(sent.wheel_torque_n_m)
        if torque >= self._torque_at_limit:
            self._torque_held += 1
            if self._torque_active:
                if torque < self._torque_off:
                    self._torque_active = False
            elif self._torque_held > self._torque_hold_ticks:
                self._torque_active = True
                self._warn(tick, "torque_saturated",
                           f"commanded wheel torque held at its limit {self._torque_limit:g} "
                           f"N m for {self._torque_held * self.dt_s:.3g} s (since t = "
                           f"{(tick - self._torque_held + 1) * self.dt_s:.3f} s)")
        else:  # below the limit (or NaN): nothing held, nothing to start
            self._torque_held = 0
            if self._torque_active and torque < self._torque_off:
                self._torque_active = False
        missed = False
        if self._due_period:
            for name, drv in self._due_at[tick % self._due_period]:
                if drv.last_tick != tick \
                        and (drv.last_tick > -10**8 or tick >= self.startup_ticks):
                    self._missing[name] += 1
                    missed = True
        else:
            for name, drv, div in self._due:
                if tick % div == 0 and drv.last_tick != tick \
                        and (drv.last_tick > -10**8 or tick >= self.startup_ticks):
                    self._missing[name] += 1
                    missed = True
        if missed:
            if self._missing_since is None:
                self._missing_since = tick
            if tick >= self._missing_next:
                self._report_missing(tick)

    def _level(self, tick: int, kind: str, hyst: Hysteresis, x: float) -> None:
        """One value past (or back under) its warning level."""
        if hyst.update(x):
            frac, limit, unit, what = self._levels[kind]
            self._warn(tick, kind, f"{x:.5g} {unit} is past {100 * frac:g} % of {what} "
                                   f"{limit:.4g} {unit} ({frac * limit:.5g} {unit})")

    def _report_missing(self, tick: int) -> None:
        counts = {n: c for n, c in self._missing.items() if c}
        if not counts:
            return
        since = self._missing_since if self._missing_since is not None else tick
        total = sum(counts.values())
        if since == tick and total == len(counts):
            message = f"no telemetry from {', '.join(counts)} at its tick {tick}"
        else:
            message = (f"{total} due telemetry frames missing at their ticks since t = "
                       f"{since * self.dt_s:.3f} s (" +
                       ", ".join(f"{n} {c}" for n, c in counts.items()) + ")")
        self._warn(tick, "telemetry_missing", message)
        self._missing = dict.fromkeys(self._missing, 0)
        self._missing_since = None
        self._missing_next = tick + self._missing_every

    def finish(self) -> None:
        """At the end of a run: report, at the last tick checked, the missing frames counted
        since the last report (the rate limit held them back)."""
        if self.warnings_on and self._missing_since is not None:
            self._report_missing(self._last_tick)

    # ------------------------------------------------------------------
    def check(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        if not self._enabled:
            return None
        if self.warnings_on:
            self._warnings(tick, state, sent)
        # driven by what changed: a device's checks run only in a tick its telemetry came
        # (or, for the valves, a tick they were commanded open), the limits' messages only
        # past a limit; the order of the checks (the first event wins) is unchanged. Each
        # check's all-clear path is inline here (one call a tick); anything past
        # it goes to the check's own method, which decides and words the event.
        c = self._bus_counters
        if c.foreign:  # another master first: what the nodes report next may be its doing
            return self._bus(tick, state, sent)
        if self._protocol_fault is not None:
            event = self._protocol(tick, state, sent)
            if event is not None:
                return event
        if (c.bus_off or c.error_frames > self._max_error_frames
                or c.unknown > self._max_unknown_frames):
            return self._bus(tick, state, sent)
        max_malformed = self._max_malformed
        for counters in self._frame_counters:  # the usual tick: none past its limit
            if counters.malformed > max_malformed or counters.sequence_errors:
                event = self._bus(tick, state, sent)
                if event is not None:
                    return event
                break
        if tick % self._count_every == 0 and tick >= self.grace:
            event = self._count_frames(tick)
            if event is not None:
                return event
        if tick >= self.grace:
            if tick < self._silent_from and self._lost_due_period:
                # _silent_and_lost's usual tick: no device can be silent yet, only the
                # windows of the devices due now (a due device that came, with no miss in
                # its window, only counts its frame)
                if not self.realtime_grace:
                    for watch in self._lost_due_at[tick % self._lost_due_period]:
                        last = watch.driver.last_tick
                        if last == tick and not watch.misses:
                            watch.due += 1
                            continue
                        if tick - last > watch.silent_after:
                            continue  # not heard from yet, in the start-up time
                        event = self._count_due(tick, watch, last)
                        if event is not None:
                            return event
            else:
                event = self._silent_and_lost(tick, state, sent)
                if event is not None:
                    return event
        accel, hub, wheel, valves, piezo = self._device_drivers
        if accel is not None and accel.last_tick == tick:
            v = accel.values
            counter = v.get("sample_counter")
            last = self._accel_last
            if (v.get("saturated") or v.get("fault") or counter is None or last is None
                    or not abs(v.get("accel", 0.0)) <= self._accel_plausible):
                event = self._accelerometer(tick, state, sent)
                if event is not None:
                    return event
            else:
                # _accelerometer's usual sample: counter moved on, not late
                counter = int(counter)
                if counter == last[0]:
                    event = self._accelerometer(tick, state, sent)
                    if event is not None:
                        return event
                else:
                    self._accel_same = 0
                    offset = (tick // self._accel_div - counter) % 65536
                    late = (offset - self._accel_offset) % 65536  # type: ignore[operator]
                    if self._late_limit < late < 32768:
                        event = self._accelerometer(tick, state, sent)
                        if event is not None:
                            return event
                    else:
                        self._accel_last = (counter, tick)
        if hub is not None and hub.last_tick == tick and tick != self._hub_tick:
            v = hub.values
            angle, rate = v.get("angle", 0.0), v.get("rate", 0.0)
            last_hub = self._hub_last
            if (last_hub is None or not abs(rate) <= HUB_RATE_PLAUSIBLE_RAD_S
                    or not abs(angle - last_hub[0]) <= HUB_ANGLE_STEP_PLAUSIBLE_RAD
                    or (angle == last_hub[0] and rate == last_hub[1])):
                event = self._hub(tick, state, sent)
                if event is not None:
                    return event
            else:  # _hub's usual sample: plausible, moved
                self._hub_tick = tick
                self._hub_same = 0
                self._hub_last = (angle, rate)
        if wheel is not None and wheel.last_tick == tick and tick != self._wheel_tick:
            v = wheel.values
            if (v.get("fault") or not abs(v.get("speed", 0.0)) <= self._wheel_overspeed
                    or (not v.get("enabled", 1.0) and self._watch_wheel_enable)):
                event = self._wheel(tick, state, sent)
                if event is not None:
                    return event
            else:
                self._wheel_tick = tick
                self._wheel_off_since = None
        if sent.valve_direction != 0 or (valves is not None and valves.last_tick == tick):
            event = self._valves(tick, state, sent)
            if event is not None:
                return event
        rotor = self._rotor_drv
        if rotor is not None:
            if not sent.rotor_enable:
                self._rotor_enabled_since = None
            elif self._rotor_enabled_since is None:
                self._rotor_enabled_since = tick
            elif rotor.last_tick == tick:
                lag = self._enable_lag["disturbance_rotor"]
                if rotor.values.get("enabled", 1.0):
                    self._rotor_off_since = None
                elif tick - self._rotor_enabled_since > lag:
                    if self._rotor_off_since is None:
                        self._rotor_off_since = tick
                    if tick - self._rotor_off_since >= lag:
                        event = self._disabled(tick, "disturbance_rotor", rotor.values)
                        if event is not None:
                            return event
        if piezo is not None and piezo.last_tick == tick:
            pv = piezo.values
            if pv.get("overcurrent"):
                event = self._piezo(tick, state, sent)
                if event is not None:
                    return event
            reading = (pv.get("sensor_ch1"), pv.get("sensor_ch2"))
            if reading == self._piezo_value:
                self._piezo_const += 1
                if self._piezo_const >= self._piezo_const_limit:
                    return self._constant(tick, "piezo_amplifier", "sensor_ch1/ch2",
                                          self._piezo_const, reading, "V")
            else:
                self._piezo_value, self._piezo_const = reading, 1
        if accel is not None and accel.last_tick == tick:
            a = accel.values.get("accel")
            if a == self._accel_value:
                self._accel_const += 1
                if self._accel_const >= self._accel_const_limit:
                    return self._constant(tick, "accelerometer", "accel", self._accel_const,
                                          a, "m/s^2")
            else:
                self._accel_value, self._accel_const = a, 1
        pw = self._pw
        if pw is not None:
            # the physics checks' window: the hub's rate integrated sample to sample, the
            # wheel's speed, the torque sent (one multiply-add or two a tick)
            if hub is not None and hub.last_tick == tick and tick != pw.hub_tick:
                v = hub.values
                r = v.get("rate", 0.0)
                if pw.hub_tick >= 0:
                    pw.rate_int += (r + pw.rate_last) * (tick - pw.hub_tick) * self._half_dt
                    pw.rate_tv += abs(r - pw.rate_last)
                    pw.hub_n += 1
                else:  # its first sample: the first window starts here
                    pw.hub_tick0, pw.angle0, pw.hub_n = tick, v.get("angle", 0.0), 1
                    pw.rate0 = r
                pw.rate_last, pw.angle_last, pw.hub_tick = r, v.get("angle", 0.0), tick
            if wheel is not None and wheel.last_tick == tick and tick != pw.wheel_tick:
                v = wheel.values
                speed = v.get("speed", 0.0)
                if pw.wheel_tick >= 0:
                    pw.wheel_n += 1
                else:
                    pw.wheel_tick0, pw.speed0, pw.wheel_n = tick, speed, 1
                if (not abs(speed) <= pw.wheel_speed_near or v.get("speed_limited")
                        or not v.get("enabled", 1.0)):
                    pw.wheel_ok = False  # held at its limit or off: torque not applied
                pw.speed_last, pw.wheel_tick = speed, tick
                pw.torque_at_sample, pw.friction_at_sample = pw.torque_int, pw.friction_int
            valve = state.valve_state
            pw.valve_int += valve
            # the excitation's direction: a reversal can pump the beam's modes, whose
            # momentum the rigid prediction leaves out (the balance waits it out)
            drive = sent.wheel_torque_n_m if valve == 0 else valve * pw.couple
            if abs(drive) >= pw.reverse_min:  # a hold's small corrections are no reversal
                direction = 1 if drive > 0 else -1
                if direction != pw.direction:
                    if pw.direction:
                        pw.reversed_at = tick
                    pw.direction = direction
            if state.rotor_speed_rad_s:
                pw.rotor_on = True
            if pw.wheel_n:
                torque = sent.wheel_torque_n_m
                pw.torque_int += torque
                w = pw.speed_last
                if w and (pw.friction_coulomb or pw.friction_viscous):
                    pw.friction_int += (pw.friction_coulomb if w > 0.0
                                        else -pw.friction_coulomb) + pw.friction_viscous * w
                magnitude = abs(torque)
                pw.torque_abs += magnitude
                if magnitude > pw.torque_peak:
                    pw.torque_peak = magnitude
            if tick >= pw.end:
                event = self._plausible_window(tick)
                if event is not None:
                    return event
        bounds = self._limit_bounds
        if (abs(state.hub_angle_rad) <= bounds[0] and abs(state.hub_rate_rad_s) <= bounds[1]
                and abs(state.wheel_speed_rad_s) <= bounds[2]
                and abs(state.tip_accel_m_s2) <= bounds[3]):
            return None
        return self._limits(tick, state, sent)

    def _constant(self, tick: int, device: str, quantity: str, n: int, value: Any,
                  unit: str) -> FaultEvent:
        """A channel still for longer than its noise and resolution allow."""
        return self._event(tick, device, "stuck", (
            f"{quantity} read {value} {unit} for {n} samples in a row, which its noise and "
            "resolution in the rig file make improbable: pinned at a constant, or bound to "
            "an object or signal that does not carry it"))

    def _protocol(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        """The bus protocol's own fault reports (CANopen: EMCY, boot-up, NMT state,
        heartbeat lost), by node and device."""
        get = self._protocol_fault
        found = get(tick) if get is not None else None
        if found is None:
            return None
        device, kind, message = found
        held_back = max(self.not_held_tick, self.hb_late_tick)
        if kind == HARNESS_HEARTBEAT_LOST and self.realtime_grace and \
                tick - held_back <= self._watchdog_ticks + 2 * self.realtime_grace:
            # the node went safe because the harness's heartbeat came late after the loop
            # itself was held back (the host or the transport): the bench's, as a drive
            # its own watchdog disabled (_disabled); the node has left operational, so the
            # run stops, naming the bench
            self._note_behind(tick)
            return self._event(tick, "bus", "late", (
                f"{device}: {message}, after the loop held back tick {held_back} "
                f"(t = {held_back * self.dt_s:.3f} s): the host or the transport "
                "kept the harness's heartbeat from the node, not the node's fault"))
        return self._event(tick, device, kind, message)

    def _event(self, tick: int, device: str, kind: str, message: str) -> FaultEvent:
        return FaultEvent(tick, tick * self.dt_s, device, kind, message)

    def _bus(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        c = self.iface.counters
        if c.foreign:
            return self._event(tick, "bus", "second master", c.first_foreign)
        if c.bus_off:
            return self._event(tick, "bus", "bus-off", "error frame with the bus-off class")
        if c.error_frames > self._max_error_frames:
            return self._event(tick, "bus", "error frames",
                               f"{c.error_frames} error frames on the bus")
        if c.unknown > self._max_unknown_frames:
            return self._event(tick, "bus", "unknown ids",
                               f"{c.unknown} frames with ids no device uses "
                               f"(last 0x{c.last_unknown_id:03X})")
        max_malformed = self._max_malformed
        for counters in self._frame_counters:  # the usual tick: none past its limit
            if counters.malformed > max_malformed or counters.sequence_errors:
                break
        else:
            return None
        for name, drv in self._drivers:
            counters = drv.counters
            if counters.malformed > max_malformed:
                return self._event(tick, name, "malformed frame", counters.last_error)
            if counters.sequence_errors:
                return self._event(tick, name, "frames lost", counters.last_error)
        return None

    def _silent_and_lost(self, tick: int, state: RigState, sent: RigCommand
                         ) -> FaultEvent | None:
        if tick < self.grace:
            return None
        grace = self.realtime_grace
        if tick < self._silent_from and self._lost_due_period:
            # no device can be silent before then (a driver's last tick only grows): only
            # the windows of the devices due now, in the same order as below
            if grace:
                return None
            for watch in self._lost_due_at[tick % self._lost_due_period]:
                last = watch.driver.last_tick
                if last == tick and not watch.misses:
                    watch.due += 1  # came, no miss in its window: _count_due's whole work
                    continue
                if tick - last > watch.silent_after:
                    continue  # not heard from yet, in the start-up time (skipped below too)
                event = self._count_due(tick, watch, last)
                if event is not None:
                    return event
            return None
        startup = tick < self.startup_ticks
        silent_from = 1 << 62
        for watch in self._lost:
            last = watch.driver.last_tick
            age = tick - last
            limit = watch.silent_after
            if age > limit:
                if age > 10**8 and startup:
                    # not heard from yet: a device may take a moment to answer at first;
                    # silent from the end of the start-up time on
                    silent_from = min(silent_from, self.startup_ticks - 1)
                    continue
                if grace and age < 10**8:
                    stalled = self._bench_stall(tick, watch)
                    if stalled is not None:
                        return stalled if isinstance(stalled, FaultEvent) else None
                return self._event(tick, watch.name, "silent",
                                   f"no telemetry for {age if age < 10**8 else 'all'} ticks")
            if last + limit < silent_from:
                silent_from = last + limit
            if not grace and tick % watch.divider == 0:
                event = self._count_due(tick, watch, last)
                if event is not None:
                    return event
        # the first tick a device could be silent at (its age past its limit)
        self._silent_from = silent_from + 1
        if self._stall_from is not None:  # every device is answering again: a stall ended
            self._end_stall(tick)
        return None

    def _bench_stall(self, tick: int, watch: DeviceWatch) -> FaultEvent | bool | None:
        """On the wall clock, ``watch``'s device is past its silence limit. If no other
        device has answered since this one's next answer was due, every device stopped at
        once, which no one device does: its frames are late, not lost; the host, the
        transport or the bus held them (the bench's time, which the verdict judges by its
        timing criteria).
        True while such a stall lasts, up to ``bench_stall_s``, and while the devices
        catch up after it (each within its own silence limit of the first answer); past
        ``bench_stall_s`` the run stops, the bench named (device ``bus``). None: the
        device's own silence."""
        if self._stall_from is None:
            others = [w.driver.last_tick for w in self._lost if w is not watch]
            if not others:
                return None
            if max(others) > watch.driver.last_tick + watch.divider:
                # another answered after this one's next was due: its own silence, unless
                # every other device is behind as well (a backlog on the transport: frames
                # late in bursts, a device answering every 5th SYNC the first past its
                # limit), for at most bench_stall_s
                if not self._bench_behind(tick, watch, since_start=True):
                    return None
                assert self._behind_since is not None
                behind_s = (tick - self._behind_since) * self.dt_s
                if behind_s <= self._bench_stall_s:
                    return True
                return self._event(tick, "bus", "late", (
                    f"every device's telemetry has come late for {behind_s:.3f} s (the "
                    "transport or the host behind, not one device); monitor.bench_stall_s "
                    f"{self._bench_stall_s:g} s"))
            # none has answered since this device's next answer was due: the bench may have
            # stopped them all (a device answering every 5th SYNC is the first past its
            # limit); it is a stall for as long as no device answers
            self._stall_from = max(w.driver.last_tick for w in self._lost)
        self._silent_from = tick + 1  # look again next tick
        if self._resumed_at is None and any(
                w.driver.last_tick > self._stall_from for w in self._lost):
            self._resumed_at = tick
        if self._resumed_at is not None:  # the devices are coming back: each gets its limit
            return True if tick - self._resumed_at <= watch.silent_after else None
        quiet = tick - self._stall_from
        if quiet * self.dt_s <= self._bench_stall_s:
            return True
        return self._event(tick, "bus", "silent", (
            f"no device has answered for {quiet * self.dt_s:.3f} s (every one stopped at "
            f"t = {self._stall_from * self.dt_s:.3f} s): the bus, the CAN adapter, the "
            "transport or the host, not one device; monitor.bench_stall_s "
            f"{self._bench_stall_s:g} s"))

    def _bench_behind(self, tick: int, watch: DeviceWatch | None,
                      since_start: bool = False) -> bool:
        """On the wall clock, ``watch``'s frames are past their loss limit (or the
        accelerometer's samples behind the SYNC count, ``watch`` None): lost or late,
        unless every other device is behind too, each by at least half the grace in time
        (its frames not come, over its frames per SYNC, times its divider; since it was
        first heard from with ``since_start``, else beyond the least over its window), or
        the loop itself did not hold a tick within the frames' reach
        (``note_not_held``): then the bench (the transport, the host, the harness's own
        loop) is delivering late, not one device. Counted
        once per episode (``bench_behind``); the missing frames are the bench's timing
        criteria's to judge."""
        others = [w for w in self._lost if w is not watch and w.base_rx is not None
                  and (watch is not None or w.name != "accelerometer")]
        half = 0.5 * self.realtime_grace
        # a tick the loop did not hold (it overran, or woke half a period late) within
        # the frames' reach: what is missing since is the bench's, whatever each device shows
        not_held = tick - self.not_held_tick <= 2 * self.realtime_grace
        if not not_held and (not others or any(
                (w.deficit if since_start else w.behind) / w.frames * w.divider < half
                for w in others)):
            self._behind_since = None
            return False
        self._note_behind(tick)
        return True

    def _note_behind(self, tick: int) -> None:
        """Count an episode of the bench's lateness: a new one when none is in progress or
        the last ended a grace ago (the checks that ask run only while a device is past a
        limit)."""
        if self._behind_since is None or tick - self._behind_last > self.realtime_grace:
            self._behind_since = tick
            self.bench_behind += 1
        self._behind_last = tick

    def note_not_held(self, tick: int, late_s: float) -> None:
        """The loop did not hold ``tick``: it woke or finished ``late_s`` late. One late by
        half the grace or more keeps frames back long enough to look like a device's
        silence or loss: those around it are the bench's (``_bench_behind``)."""
        if late_s >= 0.5 * self.realtime_grace * self.dt_s:
            self.not_held_tick = tick
        if late_s >= self._hb_late_s:
            self.hb_late_tick = tick

    def _end_stall(self, tick: int) -> None:
        """Telemetry came again after a stall of the whole bench: counted and measured
        (summary.json ``monitor_bench_stalls``), a warning logged."""
        start = self._stall_from
        assert start is not None
        resumed = self._resumed_at if self._resumed_at is not None else tick
        self._stall_from = self._resumed_at = None
        length_s = (resumed - start) * self.dt_s
        self.bench_stalls += 1
        self.bench_stall_max_s = max(self.bench_stall_max_s, length_s)
        for w in self._lost:  # the frames the stall kept back are the bench's, not lost
            w.window.clear()
        if self.on_warning is not None:
            self.on_warning(MonitorWarning(tick, tick * self.dt_s, "telemetry_missing", (
                f"no device answered for {length_s:.3f} s from t = {start * self.dt_s:.3f} "
                "s, then all did: the bench stalled (late frames, not a device's silence)")))

    def _count_frames(self, tick: int) -> FaultEvent | None:
        """Each device's frames against the SYNCs that asked for them, from the first tick
        it was heard from: more than asked is a second node answering with its id; on the
        wall clock (no frame counter in a CANopen PDO tells a frame missing), frames not
        come within the grace of their SYNC, ``lost_frames`` of them among its last
        LOST_WINDOW due frames, are lost."""
        grace = self.realtime_grace
        for w in self._lost:
            rx = w.driver.counters.received
            if w.base_rx is None:
                if rx:
                    w.base_rx, w.base_due = rx, w.due_by(tick)
                continue
            got = rx - w.base_rx
            surplus = got - (w.due_by(tick) - w.base_due)
            if surplus > w.slack:
                return self._event(tick, w.name, "duplicate frames", (
                    f"{surplus} frames more than its SYNCs asked for since t = "
                    f"{self._base_time(w):.3f} s: a second node answers with its id"))
            if (grace and self._stall_from is None
                    and tick - w.driver.last_tick <= w.silent_after):
                # frames asked for and not come, counted in order (a PDO carries no
                # counter: a lost frame and a late one look alike until the grace is past);
                # a device that stopped answering altogether is the silent rule's
                window = w.window
                deficit = w.due_by(tick) - w.base_due - got
                while window and window[-1][1] >= deficit:
                    window.pop()
                window.append((tick, deficit))
                if window[0][0] <= tick - w.span:
                    window.popleft()
                w.behind, w.deficit = deficit - window[0][1], deficit
                lost = w.behind - w.lost_at
                if lost >= self._lost_limit * w.frames and not self._bench_behind(tick, w):
                    return self._event(tick, w.name, "frames lost", (
                        f"{lost} of its frames asked for more than "
                        f"{grace * self.dt_s * 1e3:.0f} ms ago did not come (counted over "
                        f"{w.span * self.dt_s:.2f} s)"))
        return None

    def _base_time(self, w: DeviceWatch) -> float:
        return (w.base_due // w.frames - 1) * w.divider * self.dt_s

    def _count_due(self, tick: int, watch: DeviceWatch, last: int) -> FaultEvent | None:
        """One due frame of a device (lockstep): the missing ones among its last
        LOST_WINDOW due frames, kept by number (a tick whose frame came touches no
        window)."""
        n = watch.due = watch.due + 1
        misses = watch.misses
        if last != tick:
            misses.append(n)
        if misses:
            while misses and misses[0] <= n - LOST_WINDOW:
                misses.popleft()
            if len(misses) >= self._lost_limit:
                return self._event(tick, watch.name, "frames lost",
                                   f"{len(misses)} of its last {min(n, LOST_WINDOW)} "
                                   "frames missing")
        return None

    def _accelerometer(self, tick: int, state: RigState, sent: RigCommand
                       ) -> FaultEvent | None:
        drv = self.iface.accel
        if drv.last_tick != tick:
            return None
        v = drv.values
        if v.get("saturated"):
            return self._event(tick, "accelerometer", "saturated",
                               f"reading {v.get('accel', 0.0):+.3f} m/s^2 at its +-"
                               f"{self.accel_range:.2f} m/s^2 range")
        if v.get("fault"):
            return self._event(tick, "accelerometer", "fault flag", "device reports a fault")
        if abs(v.get("accel", 0.0)) > self._accel_plausible:
            return self._event(tick, "accelerometer", "implausible",
                               f"{v['accel']:+.3f} m/s^2 beyond its range")
        if "sample_counter" not in v:
            return None  # its binding carries no sample counter (a CANopen analog input)
        counter = int(v["sample_counter"])
        if self._accel_last is not None and counter == self._accel_last[0]:
            self._accel_same += 1
            if self._accel_same >= 2:
                return self._event(tick, "accelerometer", "stuck",
                                   f"sample counter frozen at {counter}")
        else:
            self._accel_same = 0
        offset = (tick // self._accel_div - counter) % 65536
        late = (offset - self._accel_offset) % 65536 if self._accel_offset is not None else 0
        if self._accel_offset is None:
            self._accel_offset = offset
        elif self._late_limit < late < 32768 and not (
                self.realtime_grace and self._bench_behind(tick, None, since_start=True)):
            return self._event(tick, "accelerometer", "late",
                               f"telemetry {(offset - self._accel_offset) % 65536} samples "
                               "behind the SYNC count")
        self._accel_last = (counter, tick)
        return None

    def _hub(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        drv = self.iface.hub
        if drv.last_tick != tick or drv.last_tick == self._hub_tick:
            return None
        self._hub_tick = tick
        angle, rate = drv.values.get("angle", 0.0), drv.values.get("rate", 0.0)
        if abs(rate) > HUB_RATE_PLAUSIBLE_RAD_S or (
                self._hub_last is not None
                and abs(angle - self._hub_last[0]) > HUB_ANGLE_STEP_PLAUSIBLE_RAD):
            return self._event(tick, "hub_sensor", "implausible",
                               f"angle {angle:+.4f} rad, rate {rate:+.4f} rad/s")
        if self._hub_last == (angle, rate):
            self._hub_same += 1
            qa, qr = self._q.get("hub_sensor.angle"), self._q.get("hub_sensor.rate")
            stuck_ticks = self.cfg["stuck_ticks"]
            if (self._hub_same >= stuck_ticks if qa is None or qr is None else hub_is_stuck(
                    self._hub_same, rate, self.dt_s * self.div.get("hub_sensor", 1), qa, qr,
                    stuck_ticks)):
                return self._event(tick, "hub_sensor", "stuck",
                                   f"angle and rate identical for {self._hub_same} samples")
        else:
            self._hub_same = 0
        self._hub_last = (angle, rate)
        return None

    def _wheel(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        drv = self.iface.wheel
        if drv.last_tick != tick or drv.last_tick == self._wheel_tick:
            return None
        self._wheel_tick = tick
        v = drv.values
        if v.get("fault"):
            return self._event(tick, "reaction_wheel", "fault flag", "wheel reports a fault")
        speed = v.get("speed", 0.0)
        if abs(speed) > self._wheel_implausible:
            return self._event(tick, "reaction_wheel", "implausible",
                               f"speed {speed:+.1f} rad/s")
        if abs(speed) > self._wheel_overspeed_at:
            return self._event(tick, "reaction_wheel", "overspeed",
                               f"speed {speed:+.1f} rad/s beyond {self.wheel_max:g} rad/s")
        if not v.get("enabled", 1.0):
            lag = self._enable_lag["reaction_wheel"]
            if self._watch_wheel_enable and tick > lag:
                if self._wheel_off_since is None:
                    self._wheel_off_since = tick
                if tick - self._wheel_off_since >= lag:
                    return self._disabled(tick, "reaction_wheel", v)
        else:
            self._wheel_off_since = None
        return None

    def _disabled(self, tick: int, device: str, values: dict[str, float]
                  ) -> FaultEvent | None:
        """A drive the harness commands enabled reports it is not (another master's
        controlword, a quick stop, a drive that dropped its power stage). None on the wall
        clock within the devices' watchdog time (and the drive's lag) of a tick the loop
        held back by half the grace or more: its heartbeat may have come too late and the
        drive rightly went safe by itself (the bench's doing, counted in
        ``bench_behind``)."""
        if self.realtime_grace and tick - self.not_held_tick <= self._watchdog_ticks \
                + self._enable_lag.get(device, 0):
            self._note_behind(tick)
            return None
        status = values.get("status")
        if status is None:
            state = "its enabled flag is 0"
        else:
            state = f"statusword 0x{int(status):04X}: {cia402_state(int(status))}"
        return self._event(tick, device, "drive disabled", (
            f"left operation enabled while the rig is armed and the harness commands it "
            f"enabled ({state})"))

    def _valves(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        if sent.valve_direction != 0:
            self._valve_closed_since = tick + 1
        drv = self.iface.valves
        if drv.last_tick != tick:
            return None
        v = drv.values
        if v.get("fault"):
            return self._event(tick, "thruster_valves", "fault flag", "valves report a fault")
        is_open = v.get("valve_pos_open", 0) or v.get("valve_neg_open", 0)
        if is_open and tick - self._valve_closed_since > self.valve_close_ticks + 1:
            which = "positive" if v.get("valve_pos_open") else "negative"
            return self._event(tick, "thruster_valves", "stuck open",
                               f"{which} valve open, commanded closed since tick "
                               f"{self._valve_closed_since}")
        return None

    def _piezo(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        drv = self.iface.piezo
        if drv.last_tick == tick and drv.values.get("overcurrent"):
            return self._event(tick, "piezo_amplifier", "over-current",
                               "amplifier tripped on over-current")
        return None

    def _limits(self, tick: int, state: RigState, sent: RigCommand) -> FaultEvent | None:
        bounds = self._limit_bounds
        if (abs(state.hub_angle_rad) <= bounds[0] and abs(state.hub_rate_rad_s) <= bounds[1]
                and abs(state.wheel_speed_rad_s) <= bounds[2]
                and abs(state.tip_accel_m_s2) <= bounds[3]):
            return None
        lim = self.limits
        checks = (
            ("hub_sensor", "angle limit", abs(math.degrees(state.hub_angle_rad)),
             lim["max_angle_deg"], "deg"),
            ("hub_sensor", "rate limit", abs(math.degrees(state.hub_rate_rad_s)),
             lim["max_rate_deg_s"], "deg/s"),
            ("reaction_wheel", "speed limit", abs(state.wheel_speed_rad_s),
             lim["max_wheel_speed_rad_s"], "rad/s"),
            ("accelerometer", "tip acceleration limit", abs(state.tip_accel_m_s2),
             lim["max_tip_accel_m_s2"], "m/s^2"),
        )
        for device, kind, value, limit, unit in checks:
            if value > limit:
                return self._event(tick, device, kind, f"{value:.3f} {unit} > {limit:g} {unit}")
        return None
