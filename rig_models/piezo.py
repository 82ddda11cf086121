"""Piezoelectric patches on the beam: sensor voltage from the strain, actuator moment from the
amplifier voltage (Euler-Bernoulli, thin patches; the patches' own mass and stiffness are
neglected, as in paper 001's model).

A patch from x1 to x2 (from the root) on a beam of thickness t_b:

- actuator: a voltage V across a pair of patches poled opposite on both faces bends the beam
  with a moment M = E_p d31 w_p (t_b + t_p) V at both patch ends, i.e. generalised modal force
  f_i = M (phi_i'(x2) - phi_i'(x1));
- sensor: a patch on one face collects the charge q = E_p d31 w_p (t_b + t_p) / 2 *
  (w'(x2) - w'(x1)), read as V_s = q / C_p with C_p = eps33 w_p L_p / t_p.

Patch ends are taken at the nearest element nodes (where the slopes are degrees of freedom).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rig_models.beam import BeamModes, BeamSpec


@dataclass(frozen=True)
class PiezoPatch:
    start_m: float
    length_m: float
    width_m: float
    thickness_m: float
    youngs_modulus_pa: float = 61e9  # PZT-5A
    d31_m_v: float = -171e-12
    permittivity_f_m: float = 1730 * 8.854e-12

    def __post_init__(self) -> None:
        for name in ("length_m", "width_m", "thickness_m", "youngs_modulus_pa",
                     "permittivity_f_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"piezo patch {name} must be > 0, got {getattr(self, name)}")
        if self.start_m < 0:
            raise ValueError(f"piezo patch start_m must be >= 0, got {self.start_m}")

    @property
    def capacitance_f(self) -> float:
        return self.permittivity_f_m * self.width_m * self.length_m / self.thickness_m

    def moment_per_volt(self, beam: BeamSpec) -> float:
        return abs(self.youngs_modulus_pa * self.d31_m_v) * self.width_m * (
            beam.thickness_m + self.thickness_m)

    def charge_per_rad(self, beam: BeamSpec) -> float:
        return 0.5 * self.moment_per_volt(beam)


def slope_difference(modes: BeamModes, patch: PiezoPatch) -> np.ndarray:
    """phi_i'(x2) - phi_i'(x1) for every mode (1/m per unit modal coordinate ... in rad)."""
    x = modes.node_x_m
    end = patch.start_m + patch.length_m
    if end > x[-1] + 1e-9:
        raise ValueError(f"piezo patch ends at {end} m, beyond the beam's {x[-1]} m")
    i1 = int(np.argmin(np.abs(x - patch.start_m)))
    i2 = int(np.argmin(np.abs(x - end)))
    if i2 <= i1:
        raise ValueError("piezo patch shorter than one beam element")

    def slope(node: int) -> np.ndarray:
        if node == 0:
            return np.zeros(modes.shapes.shape[1])  # clamped root
        return modes.shapes[2 * (node - 1) + 1]

    return slope(i2) - slope(i1)


@dataclass(frozen=True)
class PatchGains:
    """Modal actuator forces per volt (n_modes,) and sensor volts per modal coordinate."""

    actuator: np.ndarray
    sensor: np.ndarray
    capacitance_f: float


def patch_gains(modes: BeamModes, beam: BeamSpec, patch: PiezoPatch) -> PatchGains:
    dphi = slope_difference(modes, patch)
    return PatchGains(actuator=patch.moment_per_volt(beam) * dphi,
                      sensor=patch.charge_per_rad(beam) / patch.capacitance_f * dphi,
                      capacitance_f=patch.capacitance_f)
