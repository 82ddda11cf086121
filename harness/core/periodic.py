"""Steady-state amplitude of a periodic response (pure functions)."""

from __future__ import annotations

import numpy as np


def periodic_fit(t_s: np.ndarray, y: np.ndarray, omega_rad_s: float,
                 n_harmonics: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares fit of y by a mean plus harmonics 1..n of omega.

    Returns (coefficients [mean, a1, b1, a2, b2, ...], the fitted waveform over one period
    sampled at 720 points). Noise uncorrelated with the rotor averages out."""
    if len(t_s) != len(y) or len(t_s) < 2 * n_harmonics + 1:
        raise ValueError("periodic_fit: need matching t and y with enough samples")
    cols = [np.ones_like(t_s)]
    for k in range(1, n_harmonics + 1):
        cols += [np.cos(k * omega_rad_s * t_s), np.sin(k * omega_rad_s * t_s)]
    basis = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    tt = np.linspace(0.0, 2 * np.pi / omega_rad_s, 720, endpoint=False)
    wave = np.full_like(tt, coef[0])
    for k in range(1, n_harmonics + 1):
        wave += coef[2 * k - 1] * np.cos(k * omega_rad_s * tt) + coef[2 * k] * np.sin(
            k * omega_rad_s * tt)
    return coef, wave


def steady_state_amplitude(t_s: np.ndarray, y: np.ndarray, omega_rad_s: float,
                           window_s: float, n_harmonics: int = 15) -> float:
    """Half the peak-to-peak of the periodic fit over the last ``window_s`` seconds (a whole
    number of periods, at least one): the steady-state amplitude."""
    period = 2 * np.pi / omega_rad_s
    n_periods = max(1, int(window_s // period))
    start = t_s[-1] - n_periods * period
    sel = t_s > start
    _, wave = periodic_fit(t_s[sel], y[sel], omega_rad_s, n_harmonics)
    return float(0.5 * (wave.max() - wave.min()))
