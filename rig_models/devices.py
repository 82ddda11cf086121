"""Emulation of the rig's devices: what each one does to the physics and how it measures.

Each emulator advances by one fixed step ``dt_s`` and knows nothing about CAN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

G0_M_S2 = 9.80665  # standard gravity


def quantise(value: float, lsb: float) -> float:
    return round(value / lsb) * lsb if lsb > 0 else value


class NoiseSource:
    """Gaussian samples drawn in blocks (one generator per rig: deterministic runs).

    A block is drawn as one vector and kept as a Python list: a sample is then a list item,
    not a numpy scalar converted to float (the sensors draw two to four a tick)."""

    def __init__(self, seed: int, block: int = 4096) -> None:
        self._rng = np.random.default_rng(seed)
        self._block = block
        self._buf: list[float] = self._rng.standard_normal(block).tolist()
        self._i = 0

    def normal(self) -> float:
        i = self._i
        if i >= self._block:
            self._buf = self._rng.standard_normal(self._block).tolist()
            i = 0
        self._i = i + 1
        return self._buf[i]

    def normal2(self) -> tuple[float, float]:
        """The next two samples (what two ``normal()`` calls return)."""
        i = self._i
        if i + 2 > self._block:
            return self.normal(), self.normal()
        self._i = i + 2
        buf = self._buf
        return buf[i], buf[i + 1]


@dataclass
class ReactionWheel:
    """Torque-mode wheel: first-order torque lag, torque limit, speed limit, bearing
    friction.

    ``torque_n_m`` is the motor's torque on the hub (what the drive's current measures);
    the rotor speed (relative to the hub) changes by -torque / rotor inertia. Friction
    (Coulomb + viscous, a breakaway torque at rest) acts between rotor and hub: it slows the
    rotor relative to the hub and the hub takes its reaction, so what ``step`` returns (every
    torque on the hub) is always -rotor inertia x the rotor's speed change / dt.
    """

    max_torque_n_m: float
    max_speed_rad_s: float
    rotor_inertia_kg_m2: float
    torque_lag_s: float
    dt_s: float
    torque_n_m: float = 0.0
    speed_rad_s: float = 0.0
    enabled: bool = False
    fault: bool = False
    speed_limited: bool = False
    torque_limited: bool = False
    command_n_m: float = 0.0
    friction_coulomb_n_m: float = 0.0
    friction_viscous_n_m_s: float = 0.0  # N m per rad/s of rotor speed
    friction_breakaway_n_m: float | None = None  # None: the Coulomb friction

    def __post_init__(self) -> None:
        self._alpha = (
            1.0 - math.exp(-self.dt_s / self.torque_lag_s) if self.torque_lag_s > 0 else 1.0
        )
        self._breakaway = (self.friction_coulomb_n_m if self.friction_breakaway_n_m is None
                           else self.friction_breakaway_n_m)
        if self.friction_coulomb_n_m or self.friction_viscous_n_m_s or self._breakaway:
            self.step = self._step_with_friction  # type: ignore[method-assign]

    def command(self, torque_n_m: float, enable: bool) -> None:
        self.enabled = enable and not self.fault
        lim = self.max_torque_n_m
        self.torque_limited = abs(torque_n_m) > lim
        self.command_n_m = max(-lim, min(lim, torque_n_m)) if self.enabled else 0.0

    def make_safe(self) -> None:
        self.command(0.0, False)

    def step(self) -> float:
        """Advance one step; return the torque on the hub held over the step."""
        target = 0.0 if self.fault else self.command_n_m
        if target == 0.0 and self.torque_n_m == 0.0:
            # at rest (most ticks of a run without the wheel): what the full step gives
            self.speed_limited = False
            return 0.0
        # speed limit: refuse torque that would spin the rotor further past its limit
        self.speed_limited = False
        if self.speed_rad_s >= self.max_speed_rad_s and target < 0:
            target, self.speed_limited = 0.0, True
        elif self.speed_rad_s <= -self.max_speed_rad_s and target > 0:
            target, self.speed_limited = 0.0, True
        applied = self.torque_n_m
        self.torque_n_m += self._alpha * (target - self.torque_n_m)
        self.speed_rad_s -= applied * self.dt_s / self.rotor_inertia_kg_m2
        return applied

    def _step_with_friction(self) -> float:
        """``step`` with bearing friction (the wheel's ``step`` when it has any). A wheel at
        rest whose motor torque is within the breakaway friction stays at rest (the torque
        stays inside the wheel: none on the hub); a wheel whose speed would reach zero
        within the step stops there (friction never reverses it) and, if its motor torque
        exceeds the breakaway, starts the other way for the rest of the step."""
        target = 0.0 if self.fault else self.command_n_m
        w = self.speed_rad_s
        self.speed_limited = False
        if target == 0.0 and self.torque_n_m == 0.0 and w == 0.0:
            return 0.0
        if w >= self.max_speed_rad_s and target < 0:
            target, self.speed_limited = 0.0, True
        elif w <= -self.max_speed_rad_s and target > 0:
            target, self.speed_limited = 0.0, True
        motor = self.torque_n_m
        self.torque_n_m += self._alpha * (target - motor)
        j, dt, coulomb = self.rotor_inertia_kg_m2, self.dt_s, self.friction_coulomb_n_m
        if w == 0.0:
            if abs(motor) <= self._breakaway:
                return 0.0
            hub = motor - math.copysign(coulomb, motor)
            self.speed_rad_s = -hub * dt / j
            return hub
        # friction on the rotor opposes its speed; the hub takes the reaction
        hub = motor + math.copysign(coulomb + self.friction_viscous_n_m_s * abs(w), w)
        new = w - hub * dt / j
        if new != 0.0 and (new > 0.0) == (w > 0.0):
            self.speed_rad_s = new
            return hub
        # zero within the step, after t0 = w j / hub (hub has w's sign here)
        if abs(motor) <= self._breakaway:
            self.speed_rad_s = 0.0
            return w * j / dt
        rest = dt - w * j / hub
        after = motor - math.copysign(coulomb, motor)
        self.speed_rad_s = -after * rest / j
        return (w * j + after * rest) / dt


@dataclass
class ThrusterValves:
    """Two opposed cold-gas valves making a torque couple of +-``couple_n_m``.

    A command takes effect after the opening/closing delay (rounded to whole steps); once
    open, a valve stays open for at least ``min_on_time_s``. Counts firings and on-time.
    """

    couple_n_m: float
    open_delay_s: float
    close_delay_s: float
    min_on_time_s: float
    dt_s: float
    state: int = 0  # +1 positive valve open, -1 negative, 0 closed
    firings: int = 0
    on_time_s: float = 0.0
    fault: bool = False
    _pending: list[tuple[int, int]] = field(default_factory=list)  # (due step, state)
    _step: int = 0
    _opened_at: int = 0
    commanded: int = 0
    stuck_open: bool = False  # fault: the positive valve stays open whatever it is told
    couple_negative_n_m: float | None = None
    open_delay_negative_s: float | None = None
    close_delay_negative_s: float | None = None

    def __post_init__(self) -> None:
        self._couple_neg = (self.couple_n_m if self.couple_negative_n_m is None
                            else self.couple_negative_n_m)
        self._open_neg = (self.open_delay_s if self.open_delay_negative_s is None
                          else self.open_delay_negative_s)
        self._close_neg = (self.close_delay_s if self.close_delay_negative_s is None
                           else self.close_delay_negative_s)

    def command(self, direction: int) -> None:
        direction = 1 if direction > 0 else -1 if direction < 0 else 0
        before = self.commanded
        if direction == before:
            return
        self.commanded = direction
        if direction > 0:
            delay = self.open_delay_s
        elif direction < 0:
            delay = self._open_neg
        else:
            delay = self._close_neg if before < 0 else self.close_delay_s
        self._pending.append((self._step + round(delay / self.dt_s), direction))

    def make_safe(self) -> None:
        self._pending.clear()
        self.commanded = 0
        self.state = 1 if self.stuck_open else 0

    def step(self) -> float:
        if not self._pending and not self.state and not self.stuck_open:
            self._step += 1  # closed, nothing pending (most ticks): what the full step gives
            return self.state * self.couple_n_m
        min_on = round(self.min_on_time_s / self.dt_s)
        while self._pending and self._pending[0][0] <= self._step:
            _, new = self._pending[0]
            if self.state != 0 and new != self.state and self._step - self._opened_at < min_on:
                break  # hold the valve open for its minimum on-time
            self._pending.pop(0)
            if new != self.state:
                if new != 0:
                    self.firings += 1
                    self._opened_at = self._step
                self.state = new
        if self.stuck_open:
            if self.state != 1:
                self.firings += 1
            self.state = 1
        state = self.state
        torque = (self.couple_n_m if state > 0 else -self._couple_neg if state < 0
                  else 0.0)
        if state != 0:
            self.on_time_s += self.dt_s
        self._step += 1
        return torque


@dataclass
class Accelerometer:
    """Range clipping, first-order bandwidth, white noise and quantisation; as built, a
    bias, a scale error and a tilt of its sensitive axis (``sensed``)."""

    range_m_s2: float
    bandwidth_hz: float
    noise_rms_m_s2: float
    lsb_m_s2: float
    dt_s: float
    noise: NoiseSource
    filtered: float = 0.0
    counter: int = 0
    saturated: bool = False
    bias_m_s2: float = 0.0
    scale_error: float = 0.0
    tilt_rad: float = 0.0
    tilt_azimuth_rad: float = 0.0

    def __post_init__(self) -> None:
        self._alpha = 1.0 - math.exp(-2.0 * math.pi * self.bandwidth_hz * self.dt_s)
        self._gravity = G0_M_S2 * math.sin(self.tilt_rad)

    @property
    def ideal(self) -> bool:
        """No bias, scale error or tilt: ``sensed`` is the identity."""
        return not (self.bias_m_s2 or self.scale_error or self.tilt_rad)

    def sensed(self, true_accel_m_s2: float, hub_angle_rad: float) -> float:
        """What the sensing element reads before its filter: (1 + scale error) x (the true
        acceleration + the gravity its tilted axis picks up at this hub angle) + bias."""
        if self._gravity:
            true_accel_m_s2 += self._gravity * math.cos(hub_angle_rad - self.tilt_azimuth_rad)
        return (1.0 + self.scale_error) * true_accel_m_s2 + self.bias_m_s2

    def sample(self, true_accel_m_s2: float) -> float:
        self.filtered += self._alpha * (true_accel_m_s2 - self.filtered)
        v = self.filtered + self.noise_rms_m_s2 * self.noise.normal()
        rng = self.range_m_s2
        self.saturated = abs(v) >= rng
        v = v if v < rng else rng  # max(-rng, min(rng, v)), NaN included, inline
        v = v if v > -rng else -rng
        self.counter = (self.counter + 1) & 0xFFFF
        lsb = self.lsb_m_s2
        return round(v / lsb) * lsb if lsb > 0 else v  # quantise(v, lsb), inline: every tick


@dataclass
class HubSensor:
    """White noise and quantisation; as built, reading = (1 + scale error) x true + bias,
    the rate's bias walking randomly (``rate_random_walk_rad_s_sqrt_s`` per sqrt(s), a step
    each sample ``sample_dt_s`` apart, drawn from the rig's noise)."""

    angle_noise_rms_rad: float
    rate_noise_rms_rad_s: float
    angle_lsb_rad: float
    rate_lsb_rad_s: float
    noise: NoiseSource
    angle_bias_rad: float = 0.0
    rate_bias_rad_s: float = 0.0
    angle_scale_error: float = 0.0
    rate_scale_error: float = 0.0
    rate_random_walk_rad_s_sqrt_s: float = 0.0
    sample_dt_s: float = 0.0
    rate_walk_rad_s: float = 0.0  # the random walk's part of the rate bias so far

    def __post_init__(self) -> None:
        self._walk_step = self.rate_random_walk_rad_s_sqrt_s * math.sqrt(self.sample_dt_s)
        if (self.angle_bias_rad or self.rate_bias_rad_s or self.angle_scale_error
                or self.rate_scale_error or self._walk_step):
            self.sample = self._sample_as_built  # type: ignore[method-assign]

    def _sample_as_built(self, angle_rad: float, rate_rad_s: float) -> tuple[float, float]:
        n_angle, n_rate = self.noise.normal2()
        if self._walk_step:
            self.rate_walk_rad_s += self._walk_step * self.noise.normal()
        a = ((1.0 + self.angle_scale_error) * angle_rad + self.angle_bias_rad
             + self.angle_noise_rms_rad * n_angle)
        r = ((1.0 + self.rate_scale_error) * rate_rad_s + self.rate_bias_rad_s
             + self.rate_walk_rad_s + self.rate_noise_rms_rad_s * n_rate)
        return quantise(a, self.angle_lsb_rad), quantise(r, self.rate_lsb_rad_s)

    def sample(self, angle_rad: float, rate_rad_s: float) -> tuple[float, float]:
        n_angle, n_rate = self.noise.normal2()
        a = angle_rad + self.angle_noise_rms_rad * n_angle
        r = rate_rad_s + self.rate_noise_rms_rad_s * n_rate
        # quantise(), inline: every tick
        lsb_a, lsb_r = self.angle_lsb_rad, self.rate_lsb_rad_s
        return (round(a / lsb_a) * lsb_a if lsb_a > 0 else a,
                round(r / lsb_r) * lsb_r if lsb_r > 0 else r)


@dataclass
class DisturbanceRotor:
    """Eccentric mass m at radius sigma on a dish at distance ``dish_radius_m`` from the axis,
    spun about an axis parallel to the rig's at a commanded speed (first-order speed lag).

    Torque on the hub from the mass's reaction: with the mass at angle phi on the dish, its
    position relative to the axis is p = P + sigma (cos phi, sin phi) (P on the dish axis).
    The torque the mass exerts on the hub about the axis is -m (p x a)_z with the centripetal
    and tangential accelerations of the spinning mass (hub motion neglected, as in the paper:
    W_m Omega_m^2 = P_m sigma_m m_m Omega_m^2 sin(phi)).
    """

    mass_kg: float
    eccentricity_m: float
    dish_radius_m: float
    max_speed_rad_s: float
    speed_lag_s: float
    dt_s: float
    angle_rad: float = 0.0
    speed_rad_s: float = 0.0
    command_rad_s: float = 0.0
    enabled: bool = False

    def command(self, speed_rad_s: float, enable: bool) -> None:
        self.enabled = enable
        lim = self.max_speed_rad_s
        self.command_rad_s = max(-lim, min(lim, speed_rad_s)) if enable else 0.0

    def make_safe(self) -> None:
        self.command(0.0, False)

    def torque_n_m(self) -> float:
        w = self.speed_rad_s
        # p x a for circular motion at constant speed about the dish centre (P, 0):
        # a = -w^2 sigma (cos, sin); p x a = -P w^2 sigma sin(phi)
        return self.mass_kg * self.dish_radius_m * self.eccentricity_m * w * w * math.sin(
            self.angle_rad
        )

    def step(self) -> float:
        if self.speed_rad_s == 0.0 and self.command_rad_s == 0.0:
            return 0.0  # at rest (no rotor in most runs): nothing moves, no torque
        torque = self.torque_n_m()
        alpha = 1.0 - math.exp(-self.dt_s / self.speed_lag_s) if self.speed_lag_s > 0 else 1.0
        self.speed_rad_s += alpha * (self.command_rad_s - self.speed_rad_s)
        self.angle_rad = (self.angle_rad + self.speed_rad_s * self.dt_s) % (2.0 * math.pi)
        return torque


@dataclass
class PiezoAmplifier:
    """Two channels with a voltage limit; the current into each patch's capacitance,
    C dV/dt, trips the amplifier (output 0 V, over-current flag) beyond ``max_current_a``."""

    max_voltage_v: float
    max_current_a: float = float("inf")
    capacitance_f: tuple[float, float] = (0.0, 0.0)
    dt_s: float = 1.0
    voltages_v: tuple[float, float] = (0.0, 0.0)
    overcurrent: bool = False

    def command(self, ch1_v: float, ch2_v: float) -> None:
        if self.overcurrent:  # tripped: output stays at 0 V until reset
            self.voltages_v = (0.0, 0.0)
            return
        lim = self.max_voltage_v
        v1, v2 = max(-lim, min(lim, ch1_v)), max(-lim, min(lim, ch2_v))
        # each channel's C dV/dt against the limit (both channels written out: every tick
        # of a piezo run)
        (c1, c2), (old1, old2) = self.capacitance_f, self.voltages_v
        dt, i_max = self.dt_s, self.max_current_a
        if c1 * abs(v1 - old1) / dt > i_max or c2 * abs(v2 - old2) / dt > i_max:
            self.overcurrent = True
            self.voltages_v = (0.0, 0.0)
            return
        self.voltages_v = (v1, v2)

    def make_safe(self) -> None:
        self.voltages_v = (0.0, 0.0)
