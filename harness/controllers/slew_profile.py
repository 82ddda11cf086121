"""Rest-to-rest reference profiles for slews (pure functions of time)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class CycloidalSlew:
    """theta(t) = A (t/T - sin(2 pi t/T) / (2 pi)): zero rate and acceleration at both ends;
    peak acceleration 2 pi A / T^2."""

    angle_rad: float
    duration_s: float
    start_s: float = 0.0
    # where the slew starts from: a slew retargeted in a run starts at the last reference
    from_angle_rad: float = 0.0

    def __post_init__(self) -> None:
        if not self.duration_s > 0:
            raise ValueError(f"slew duration_s must be > 0, got {self.duration_s}")

    @staticmethod
    def shortest(angle_rad: float, max_accel_rad_s2: float, start_s: float = 0.0,
                 from_angle_rad: float = 0.0) -> CycloidalSlew:
        """The shortest cycloidal slew through ``angle_rad`` whose peak acceleration is
        ``max_accel_rad_s2``."""
        if not max_accel_rad_s2 > 0:
            raise ValueError(f"max_accel_rad_s2 must be > 0, got {max_accel_rad_s2}")
        duration = math.sqrt(2.0 * math.pi * abs(angle_rad) / max_accel_rad_s2)
        return CycloidalSlew(angle_rad, max(duration, 1e-6), start_s, from_angle_rad)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def target_rad(self) -> float:
        return self.from_angle_rad + self.angle_rad

    @property
    def peak_accel_rad_s2(self) -> float:
        return 2.0 * math.pi * abs(self.angle_rad) / self.duration_s**2

    def __call__(self, t_s: float) -> tuple[float, float, float]:
        """(angle, rate, acceleration) of the reference at time t."""
        tau = (t_s - self.start_s) / self.duration_s
        a, big_t, a0 = self.angle_rad, self.duration_s, self.from_angle_rad
        if tau <= 0.0:
            return a0, 0.0, 0.0
        if tau >= 1.0:
            return a0 + a, 0.0, 0.0
        w = 2.0 * math.pi * tau
        return (a0 + a * (tau - math.sin(w) / (2.0 * math.pi)),
                a / big_t * (1.0 - math.cos(w)),
                a * 2.0 * math.pi / big_t**2 * math.sin(w))
