"""PD attitude control of the hub through the reaction wheel, tracking a slew profile.

    T = J a_ref + kp (theta_ref - theta) + kd (rate_ref - rate),  |T| <= T_max

The feed-forward J a_ref uses the rig's inertia about the axis; the torque limit is the
wheel's (the driver clamps as well, but the controller must not ask for more).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from harness.controllers.slew_profile import CycloidalSlew
from harness.state import RigCommand, RigState


@dataclass
class PDWheelController:
    profile: CycloidalSlew
    kp_n_m_per_rad: float
    kd_n_m_s_per_rad: float
    inertia_kg_m2: float
    max_torque_n_m: float
    feedforward: bool = True
    # a retargeted slew's peak acceleration (rad/s^2); 0: the first profile's
    slew_accel_rad_s2: float = 0.0

    def __post_init__(self) -> None:
        for name in ("kp_n_m_per_rad", "kd_n_m_s_per_rad", "max_torque_n_m"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"controller.{name} must be >= 0, got {getattr(self, name)}")

    @classmethod
    def from_bandwidth(cls, profile: CycloidalSlew, inertia_kg_m2: float, bandwidth_rad_s: float,
                       damping_ratio: float, max_torque_n_m: float,
                       feedforward: bool = True) -> PDWheelController:
        """Gains that place the rigid-body closed loop at ``bandwidth_rad_s``."""
        return cls(profile, inertia_kg_m2 * bandwidth_rad_s**2,
                   2.0 * damping_ratio * bandwidth_rad_s * inertia_kg_m2, inertia_kg_m2,
                   max_torque_n_m, feedforward, profile.peak_accel_rad_s2)

    def reset(self) -> None:
        pass

    def retarget(self, angle_rad: float, t_s: float) -> None:
        """Slew to ``angle_rad`` from ``t_s`` on: the shortest cycloidal profile from the
        reference at ``t_s`` (mid-slew, the reference's rate is dropped to zero) with the
        first profile's peak acceleration. A test sequence's ``slew:`` and ``hold:`` call it
        between two ticks; no allocation beyond the new profile."""
        start = self.profile(t_s)[0]
        accel = self.slew_accel_rad_s2 or self.profile.peak_accel_rad_s2
        if not accel > 0:
            accel = 0.8 * self.max_torque_n_m / self.inertia_kg_m2
        self.profile = CycloidalSlew.shortest(angle_rad - start, accel, t_s, start)

    def reference(self, t_s: float) -> tuple[float, float, float]:
        return self.profile(t_s)

    def torque(self, t_s: float, angle_rad: float, rate_rad_s: float) -> float:
        ref, rate_ref, acc_ref = self.profile(t_s)
        u = (self.kp_n_m_per_rad * (ref - angle_rad)
             + self.kd_n_m_s_per_rad * (rate_ref - rate_rad_s))
        if self.feedforward:
            u += self.inertia_kg_m2 * acc_ref
        if math.isnan(u):
            return 0.0
        lim = self.max_torque_n_m
        return -lim if u < -lim else lim if u > lim else u

    def step(self, state: RigState) -> RigCommand:
        return RigCommand(wheel_torque_n_m=self.torque(state.time_s, state.hub_angle_rad,
                                                       state.hub_rate_rad_s))
