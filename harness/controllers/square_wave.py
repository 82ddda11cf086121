"""Square-wave compensation of a periodic disturbance through the reaction wheel (paper 003).

The eccentric rotor puts T_d = A sin(phi) on the hub, A = m_m P_m sigma_m w_m^2 (phi: rotor
angle, P_m: dish distance from the axis, sigma_m: eccentricity). The wheel answers with a
square wave of amplitude U = beta A at the rotor's frequency, in anti-phase:

    T_c = -U sign(sin(phi_hat)),

phase-locked to the rotor angle read from the bus (phi_hat extrapolates the last rotor sample
with its measured speed to the middle of the interval the command will act on: the command
computed at tick k acts over [t_k, t_k+1]). While the rotor spins up, U follows the measured
speed (beta m P sigma w^2), so the compensation tracks the disturbance it cancels. The
fundamental of the square wave is 4U/pi, so beta = pi/4 cancels the fundamental exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from harness.state import RigCommand, RigState


@dataclass(frozen=True)
class DisturbanceLaw:
    mass_kg: float
    eccentricity_m: float
    dish_radius_m: float

    def amplitude_n_m(self, speed_rad_s: float) -> float:
        return self.mass_kg * self.dish_radius_m * self.eccentricity_m * speed_rad_s**2


def square_wave_torque(beta: float, law: DisturbanceLaw, rotor_angle_rad: float,
                       rotor_speed_rad_s: float) -> float:
    """The compensation torque on the hub for the rotor's angle and speed (pure)."""
    u = beta * law.amplitude_n_m(rotor_speed_rad_s)
    s = math.sin(rotor_angle_rad)
    return 0.0 if s == 0.0 else (-u if s > 0 else u)


@dataclass
class SquareWaveCompensator:
    beta: float
    law: DisturbanceLaw
    rotor_speed_rad_s: float
    dt_s: float
    max_torque_n_m: float
    compensate: bool = True

    def __post_init__(self) -> None:
        u = self.beta * self.law.amplitude_n_m(self.rotor_speed_rad_s)
        if u > self.max_torque_n_m + 1e-12:
            raise ValueError(
                f"compensation amplitude U = beta x A = {self.beta:g} x "
                f"{self.law.amplitude_n_m(self.rotor_speed_rad_s):.4f} = {u:.4f} N m exceeds "
                f"the wheel's torque limit {self.max_torque_n_m:g} N m")

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.rotor_speed_rad_s

    @property
    def amplitude_n_m(self) -> float:
        return self.beta * self.law.amplitude_n_m(self.rotor_speed_rad_s)

    def reset(self) -> None:
        pass

    def step(self, state: RigState) -> RigCommand:
        torque = 0.0
        if self.compensate and "disturbance_rotor" not in state.stale:
            age = (state.tick - state.rotor_sample_tick + 0.5) * self.dt_s
            phi = state.rotor_angle_rad + state.rotor_speed_rad_s * age
            torque = square_wave_torque(self.beta, self.law, phi, state.rotor_speed_rad_s)
        return RigCommand(wheel_torque_n_m=torque, rotor_speed_rad_s=self.rotor_speed_rad_s,
                          rotor_enable=True)
