"""Uncertainty bands of identified modes, and shapers scored or designed over them (pure).

An identified mode (frequency and damping with 1-sigma uncertainties) is taken to lie
anywhere in its band: frequency within +-max(``n_sigma`` sigma, ``min_rel`` x omega), damping
within +-``n_sigma`` sigma (clipped to [0, 0.99)). A shaper's robustness on that mode is its
worst residual vibration over the band (:func:`worst_residual_percent`); a
specified-insensitivity shaper (:func:`si_for_band`) is designed to keep it below a limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from harness.shaping.impulse_shapers import ImpulseSequence, residual_vibration, si

DEFAULT_N_SIGMA = 3.0
DEFAULT_MIN_REL = 0.05


@dataclass(frozen=True)
class ModeBand:
    """An identified mode and the band it may lie in (rad/s, damping ratio)."""

    omega_rad_s: float
    damping_ratio: float
    omega_lo_rad_s: float
    omega_hi_rad_s: float
    zeta_lo: float
    zeta_hi: float

    @property
    def half_width_percent(self) -> float:
        return 100.0 * (self.omega_hi_rad_s - self.omega_rad_s) / self.omega_rad_s

    def omegas(self, n: int = 61) -> np.ndarray:
        return np.linspace(self.omega_lo_rad_s, self.omega_hi_rad_s, n)

    def zetas(self) -> np.ndarray:
        return np.unique([self.zeta_lo, self.damping_ratio, self.zeta_hi])


def mode_band(omega_rad_s: float, damping_ratio: float, sigma_omega_rad_s: float = 0.0,
              sigma_damping: float = 0.0, n_sigma: float = DEFAULT_N_SIGMA,
              min_rel: float = DEFAULT_MIN_REL) -> ModeBand:
    """The band of a mode identified with 1-sigma ``sigma_omega_rad_s`` / ``sigma_damping``."""
    if not (math.isfinite(omega_rad_s) and omega_rad_s > 0):
        raise ValueError(f"omega_rad_s: expected a frequency > 0 rad/s, got {omega_rad_s!r}")
    if not (math.isfinite(damping_ratio) and 0 <= damping_ratio < 1):
        raise ValueError(f"damping_ratio: expected a value in [0, 1), got {damping_ratio!r}")
    for name, v in (("sigma_omega_rad_s", sigma_omega_rad_s), ("sigma_damping", sigma_damping),
                    ("n_sigma", n_sigma), ("min_rel", min_rel)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a value >= 0, got {v!r}")
    half = max(n_sigma * sigma_omega_rad_s, min_rel * omega_rad_s)
    half = min(half, 0.9 * omega_rad_s)
    dz = n_sigma * sigma_damping
    return ModeBand(omega_rad_s, damping_ratio, omega_rad_s - half, omega_rad_s + half,
                    max(0.0, damping_ratio - dz), min(0.99, damping_ratio + dz))


def worst_residual_percent(seq: ImpulseSequence, band: ModeBand, n: int = 61) -> float:
    """Largest residual vibration (percent) of ``seq`` over the band's frequencies (``n``
    points) and damping ratios (its edges and centre)."""
    w = band.omegas(n)
    return max(float(np.max(residual_vibration(seq, w, z))) for z in band.zetas())


def si_for_band(band: ModeBand, v_tol: float) -> ImpulseSequence:
    """Specified-insensitivity shaper keeping the residual below ``v_tol`` (fraction) over
    the whole band (frequency and damping)."""
    return si(band.omega_lo_rad_s, band.omega_hi_rad_s, band.zeta_lo, band.zeta_hi, v_tol)
