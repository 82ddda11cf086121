"""A cascaded reaction-wheel slew: an example of a lab's own controller as a harness plugin.

Run-file type ``cascade_slew`` (registered in this package's pyproject.toml). Structure, per
tick (SI units)::

    rate_cmd = clamp(rate_ref + k_angle (theta_ref - theta), +-max_rate)    outer: angle loop
    T        = J (accel_ref + k_rate (rate_cmd - rate))                     inner: rate loop
    T        = clamp(T, +-T_max)

The reference is a rate-limited rest-to-rest profile: the acceleration rises and falls as
sin^2 (no step in acceleration, so the beam is barely excited) up to ``max_rate_deg_s``,
coasts at that rate, and comes back down the same way. The closed loop (rigid body) is
s^2 + k_rate s + k_rate k_angle: natural frequency sqrt(k_rate k_angle), damping ratio
k_rate / (2 sqrt(k_rate k_angle)) (1.0 with the defaults).
"""

from __future__ import annotations

import math
from typing import Any

from harness.controllers.api import Field, RigCommand, RigConfig, RigState, controller_factory

SCHEMA = {
    "angle_deg": Field("number", "deg", required=True),
    "start_s": Field("number", "s", default=0.5, minimum=0.0),
    "max_rate_deg_s": Field("number", "deg/s", default=0.5, exclusive_minimum=0.0),
    "torque_fraction": Field("number", default=0.8, exclusive_minimum=0.0, maximum=1.0),
    "angle_bandwidth_rad_s": Field("number", "rad/s", default=0.2, exclusive_minimum=0.0),
    "rate_bandwidth_rad_s": Field("number", "rad/s", default=0.8, exclusive_minimum=0.0),
    "feedforward": Field("bool", default=True),
}
"""The run file's ``controller:`` keys (``type: cascade_slew`` is added by the harness)."""


class RateLimitedSlew:
    """Rest-to-rest reference: sin^2 acceleration ramps of peak ``accel`` to the rate
    ``rate`` (lowered so that a short slew never coasts), a coast, the mirror ramp down."""

    def __init__(self, angle_rad: float, max_rate_rad_s: float, accel_rad_s2: float,
                 start_s: float) -> None:
        if not (max_rate_rad_s > 0 and accel_rad_s2 > 0):
            raise ValueError(f"max rate and acceleration must be > 0, got {max_rate_rad_s}, "
                             f"{accel_rad_s2}")
        self.sign = 1.0 if angle_rad >= 0 else -1.0
        theta = abs(angle_rad)
        # a ramp of peak acceleration A and length Ta reaches the rate A Ta / 2 over the
        # angle A Ta^2 / 4; a slew too short to reach max rate ramps up and straight down
        rate = min(max_rate_rad_s, math.sqrt(theta * accel_rad_s2 / 2.0))
        self.accel = accel_rad_s2
        self.rate = rate
        self.ramp_s = 2.0 * rate / accel_rad_s2 if rate > 0 else 0.0
        ramp_angle = accel_rad_s2 * self.ramp_s**2 / 4.0
        self.coast_s = (theta - 2.0 * ramp_angle) / rate if rate > 0 else 0.0
        self.start_s = start_s
        self.angle_rad = angle_rad
        self.end_s = start_s + 2.0 * self.ramp_s + self.coast_s

    def _ramp(self, t: float) -> tuple[float, float, float]:
        """(angle, rate, accel) t seconds into the ramp up."""
        a, ta = self.accel, self.ramp_s
        w = 2.0 * math.pi / ta
        return (a * (t * t / 4.0 + (math.cos(w * t) - 1.0) / (2.0 * w * w)),
                a * (t / 2.0 - math.sin(w * t) / (2.0 * w)),
                a * math.sin(math.pi * t / ta) ** 2)

    def __call__(self, t_s: float) -> tuple[float, float, float]:
        t = t_s - self.start_s
        if t <= 0.0 or self.ramp_s == 0.0:
            return 0.0, 0.0, 0.0
        if t_s >= self.end_s:
            return self.angle_rad, 0.0, 0.0
        s, ta = self.sign, self.ramp_s
        if t < ta:
            th, w, a = self._ramp(t)
        elif t < ta + self.coast_s:
            th0 = self._ramp(ta)[0]
            th, w, a = th0 + self.rate * (t - ta), self.rate, 0.0
        else:  # the ramp down: the ramp up mirrored about the slew's end
            th_end, w_end, a_end = self._ramp(self.end_s - t_s)
            th, w, a = abs(self.angle_rad) - th_end, w_end, -a_end
        return s * th, s * w, s * a


class CascadeSlewController:
    """The angle loop commands a rate, the rate loop a torque (see the module)."""

    def __init__(self, profile: RateLimitedSlew, inertia_kg_m2: float, k_angle_rad_s: float,
                 k_rate_rad_s: float, max_rate_rad_s: float, max_torque_n_m: float,
                 feedforward: bool) -> None:
        self.profile = profile
        self.inertia = inertia_kg_m2
        self.k_angle, self.k_rate = k_angle_rad_s, k_rate_rad_s
        self.max_rate, self.max_torque = max_rate_rad_s, max_torque_n_m
        self.feedforward = feedforward

    def reset(self) -> None:
        pass  # no state between ticks: the profile is a function of time

    def reference(self, t_s: float) -> tuple[float, float, float]:
        """The attitude reference (angle, rate, acceleration) the loop records."""
        return self.profile(t_s)

    def step(self, state: RigState) -> RigCommand:
        ref, rate_ref, acc_ref = self.profile(state.time_s)
        rate_cmd = rate_ref + self.k_angle * (ref - state.hub_angle_rad)
        lim = self.max_rate
        rate_cmd = -lim if rate_cmd < -lim else lim if rate_cmd > lim else rate_cmd
        accel = self.k_rate * (rate_cmd - state.hub_rate_rad_s)
        if self.feedforward:
            accel += acc_ref
        torque = self.inertia * accel
        if math.isnan(torque):  # a stale or broken sensor: command nothing
            torque = 0.0
        t_max = self.max_torque
        torque = -t_max if torque < -t_max else t_max if torque > t_max else torque
        return RigCommand(wheel_torque_n_m=torque)


@controller_factory(SCHEMA)
def build_cascade_slew(c: dict[str, Any], rig: RigConfig, dt_s: float) -> CascadeSlewController:
    """The run file's section (validated against SCHEMA), the rig, the loop period (s)."""
    inertia = rig.plant.inertia_kg_m2
    t_max = rig.section("reaction_wheel")["max_torque_n_m"]
    max_rate = math.radians(c["max_rate_deg_s"])
    profile = RateLimitedSlew(math.radians(c["angle_deg"]), max_rate,
                              c["torque_fraction"] * t_max / inertia, c["start_s"])
    if c["rate_bandwidth_rad_s"] * dt_s > 0.5:
        raise ValueError(f"rate_bandwidth_rad_s {c['rate_bandwidth_rad_s']:g} is too fast "
                         f"for the loop period {dt_s:g} s (at most {0.5 / dt_s:g} rad/s)")
    # the rate command may exceed the reference's limit by half of it: room to correct
    return CascadeSlewController(profile, inertia, c["angle_bandwidth_rad_s"],
                                 c["rate_bandwidth_rad_s"], 1.5 * max_rate, t_max,
                                 c["feedforward"])
