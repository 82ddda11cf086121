"""Cramer-Rao lower bound for a sum of damped sinusoids plus offset in white Gaussian noise.

For ``x[n] = m(tau_n; theta) + e[n]``, ``e ~ N(0, sigma^2)`` white, the Fisher information is
``F = J^T J / sigma^2`` with ``J = dm/dtheta`` (analytic, from ``decay_fit``), and any
unbiased estimator has ``cov(theta_hat) >= F^-1``. Parameters as in ``decay_fit``: offset,
then (omega_rad_s, damping_ratio, amplitude, phase_rad) per mode; all are unknown.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from harness.identification.decay_fit import N_MODE_PARAMS, damped_sinusoid_sum


@dataclass(frozen=True)
class DampedMode:
    """True parameters of one mode (amplitude and phase at tau = 0)."""

    omega_rad_s: float
    damping_ratio: float
    amplitude: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class ModeBound:
    """1-sigma Cramer-Rao bounds of one mode."""

    sigma_omega_rad_s: float
    sigma_damping: float
    sigma_amplitude: float
    sigma_phase_rad: float


@dataclass(frozen=True)
class CramerRaoBound:
    modes: list[ModeBound]
    sigma_offset: float
    covariance: np.ndarray  # F^-1, parameter order as in decay_fit


def cramer_rao_bound(
    modes: Sequence[DampedMode],
    *,
    fs_hz: float,
    n_samples: int,
    noise_rms: float,
    offset: float = 0.0,
    tau0_s: float = 0.0,
) -> CramerRaoBound:
    """CRLB for ``n_samples`` samples at ``fs_hz`` starting ``tau0_s`` after the decay start,
    in white Gaussian noise of standard deviation ``noise_rms``."""
    if not modes:
        raise ValueError("modes must hold at least one DampedMode")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"fs_hz must be a positive number, got {fs_hz!r}")
    if int(n_samples) != n_samples or n_samples < 1 + N_MODE_PARAMS * len(modes):
        raise ValueError(
            f"n_samples must be an integer >= the {1 + N_MODE_PARAMS * len(modes)} parameters, "
            f"got {n_samples!r}"
        )
    if not (np.isfinite(noise_rms) and noise_rms > 0):
        raise ValueError(f"noise_rms must be a positive number, got {noise_rms!r}")
    for m in modes:
        if not (m.omega_rad_s > 0 and 0.0 <= m.damping_ratio < 1.0):
            raise ValueError(
                f"each mode needs omega_rad_s > 0 and 0 <= damping_ratio < 1, got {m!r}"
            )
    params = [offset]
    for m in modes:
        params += [m.omega_rad_s, m.damping_ratio, m.amplitude, m.phase_rad]
    tau = tau0_s + np.arange(int(n_samples)) / fs_hz
    _, jac = damped_sinusoid_sum(tau, np.asarray(params))
    # Scale columns to unit norm before inverting (parameters differ by orders of magnitude).
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0.0] = 1.0
    js = jac / scale
    cov = noise_rms**2 * np.linalg.inv(js.T @ js) / np.outer(scale, scale)
    sig = np.sqrt(np.diag(cov))
    bounds = [
        ModeBound(*(float(v) for v in sig[1 + N_MODE_PARAMS * k : 1 + N_MODE_PARAMS * (k + 1)]))
        for k in range(len(modes))
    ]
    return CramerRaoBound(modes=bounds, sigma_offset=float(sig[0]), covariance=cov)
