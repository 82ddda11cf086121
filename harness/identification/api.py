"""`identify()`: modes of a tip-accelerometer free decay, by FFT peaks and by a parametric fit.

The two views are kept side by side:

- FFT view (the paper's): peaks of the windowed, zero-padded amplitude spectrum of the free
  decay, at the *damped* frequency, with a rough half-power damping.
- Parametric view: matrix pencil + nonlinear least squares on a sum of damped sinusoids,
  giving the undamped natural frequency, damping ratio, amplitude and phase at ``start_s``
  with 1-sigma uncertainties (see ``decay_fit``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.identification.decay_fit import DecayFit, IdentifiedMode, fit_free_decay
from harness.identification.spectrum import SpectralPeak, Spectrum, amplitude_spectrum

STANDARD_GRAVITY_M_S2 = 9.80665
DEFAULT_CLIP_LEVEL_M_S2 = 2.0 * STANDARD_GRAVITY_M_S2  # Silicon Designs 2220-020: +-2 g
CLIP_FRACTION = 0.99  # |a| >= 0.99 x clip level counts as clipped
CLIP_GUARD_SAMPLES = 5  # samples skipped after the last clipped one (sensor recovery)
MIN_DECAY_SAMPLES = 64


@dataclass
class IdentificationResult:
    """Both views of one free decay. ``modes`` are the parametric estimates."""

    modes: list[IdentifiedMode]  # the n_modes lowest fitted modes (all if n_modes is None)
    fft_peaks: list[SpectralPeak]
    spectrum: Spectrum
    fit: DecayFit
    fs_hz: float
    start_s: float
    fit_start_s: float  # absolute time of the first fitted sample (after clipping/filter)
    duration_s: float  # length of the free decay analysed
    n_clipped: int
    notes: list[str] = field(default_factory=list)

    def matching_fft_peak(self, mode: IdentifiedMode) -> SpectralPeak | None:
        """The FFT peak nearest the mode's damped frequency, if within its half-power
        band (or three Rayleigh resolutions, whichever is wider)."""
        if not self.fft_peaks:
            return None
        wd = mode.omega_damped_rad_s
        best = min(self.fft_peaks, key=lambda p: abs(p.omega_rad_s - wd))
        tol = max(
            3.0 * 2.0 * np.pi * self.spectrum.resolution_hz,
            2.0 * mode.damping_ratio * mode.omega_rad_s,
        )
        return best if abs(best.omega_rad_s - wd) <= tol else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (rad/s, Hz, damping ratio, m/s^2, 1-sigma)."""
        modes = []
        for m in self.modes:
            peak = self.matching_fft_peak(m)
            modes.append(
                {
                    "omega_rad_s": m.omega_rad_s,
                    "freq_hz": m.freq_hz,
                    "omega_damped_rad_s": m.omega_damped_rad_s,
                    "damping_ratio": m.damping_ratio,
                    "amplitude_m_s2": m.amplitude,
                    "phase_rad": m.phase_rad,
                    "sigma_omega_rad_s": m.sigma_omega_rad_s,
                    "sigma_freq_hz": m.sigma_freq_hz,
                    "sigma_damping": m.sigma_damping,
                    "sigma_amplitude_m_s2": m.sigma_amplitude,
                    "sigma_phase_rad": m.sigma_phase_rad,
                    "fft_peak_omega_rad_s": None if peak is None else peak.omega_rad_s,
                }
            )
        peaks = [
            {
                "omega_rad_s": p.omega_rad_s,
                "freq_hz": p.freq_hz,
                "spectral_amplitude_m_s2": p.amplitude,
                "snr": p.snr,
                "damping_ratio_half_power_rough": p.damping_ratio_half_power_rough,
            }
            for p in self.fft_peaks
        ]
        fit = self.fit
        return {
            "fs_hz": self.fs_hz,
            "start_s": self.start_s,
            "fit_start_s": self.fit_start_s,
            "duration_s": self.duration_s,
            "n_clipped": self.n_clipped,
            "modes": modes,
            "fft": {
                "window": self.spectrum.window,
                "resolution_hz": self.spectrum.resolution_hz,
                "n_fft": self.spectrum.n_fft,
                "peaks": peaks,
            },
            "fit": {
                "offset_m_s2": fit.offset,
                "sigma_offset_m_s2": fit.sigma_offset,
                "residual_rms_m_s2": fit.residual_rms,
                "residual_rms_filtered_m_s2": fit.residual_rms_filtered,
                "noise_rms_estimate_m_s2": fit.noise_rms_estimate,
                "f_max_hz": fit.f_max_hz,
                "decimation_factor": fit.decimation.factor,
                "fs_decimated_hz": fit.decimation.fs_out_hz,
                "filter_taps": int(fit.decimation.taps.size),
                "dropped_filter_transient_s": fit.decimation.dropped_s,
                "n_fit_samples": fit.n_fit_samples,
                "pencil_order": fit.pencil.order,
                "other_fitted_modes": [
                    {
                        "omega_rad_s": m.omega_rad_s,
                        "damping_ratio": m.damping_ratio,
                        "amplitude_m_s2": m.amplitude,
                    }
                    for m in fit.modes[len(self.modes) :]
                ],
                "converged": fit.success,
            },
            "notes": list(self.notes),
        }


def sample_rate_hz(t: np.ndarray, *, rel_tol: float = 0.05) -> float:
    """Mean sample rate of a strictly increasing, uniformly sampled time vector ``t``.

    Every interval must lie within ``rel_tol`` of the median interval.
    """
    dt = np.diff(t)
    if np.any(dt <= 0.0):
        i = int(np.argmax(dt <= 0.0)) + 1
        raise ValueError(
            f"t must be strictly increasing: t[{i}] = {t[i]!r} s is not after "
            f"t[{i - 1}] = {t[i - 1]!r} s"
        )
    med = float(np.median(dt))
    dev = np.abs(dt - med)
    if np.any(dev > rel_tol * med):
        i = int(np.argmax(dev > rel_tol * med)) + 1
        raise ValueError(
            f"t must be uniformly sampled: interval t[{i}] - t[{i - 1}] = {dt[i - 1]:.6g} s "
            f"differs from the median {med:.6g} s by more than {rel_tol:.0%}"
        )
    return float((t.size - 1) / (t[-1] - t[0]))


def identify(
    t: np.ndarray,
    accel: np.ndarray,
    *,
    n_modes: int | None = None,
    f_max_hz: float | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
    clip_level_m_s2: float | None = DEFAULT_CLIP_LEVEL_M_S2,
    window: str = "exponential",
    pad_factor: int = 8,
    time_rel_tol: float = 0.05,
    known_modes: Sequence[tuple[float, float]] = (),
) -> IdentificationResult:
    """Identify the modes of the free decay in ``accel`` (m/s^2) sampled at times ``t`` (s).

    ``start_s``: start of the free decay (default ``t[0]``); earlier samples (forced part)
    are ignored, and amplitudes/phases refer to ``start_s``. ``end_s``: end of the free
    decay (default: the end of the record); samples at or after it are ignored (a later
    excitation). ``identify_windows`` analyses several such windows of one record. Samples with
    ``|accel| >= 0.99 clip_level_m_s2`` count as clipped: the analysis starts after the last
    one (``None`` disables the check). ``n_modes``: report the ``n_modes`` lowest-frequency
    modes (all modes found are still fitted together; see ``fit_free_decay``). ``f_max_hz``:
    upper edge of the analysed band (default from the FFT peaks). ``known_modes``:
    (omega_rad_s, damping_ratio) of modes identified elsewhere, held in the fit if this
    record does not show them (see ``fit_free_decay``).
    """
    t = np.asarray(t, dtype=float)
    a = np.asarray(accel, dtype=float)
    if t.ndim != 1 or a.ndim != 1 or t.size != a.size:
        raise ValueError(
            f"t and accel must be 1-D arrays of equal length, got shapes {t.shape} and {a.shape}"
        )
    if t.size < MIN_DECAY_SAMPLES:
        raise ValueError(f"t must hold at least {MIN_DECAY_SAMPLES} samples, got {t.size}")
    for name, arr in (("t", t), ("accel", a)):
        if not np.all(np.isfinite(arr)):
            i = int(np.argmax(~np.isfinite(arr)))
            raise ValueError(f"{name} must be finite: {name}[{i}] = {arr[i]!r}")
    if f_max_hz is not None and not (np.isfinite(f_max_hz) and f_max_hz > 0):
        raise ValueError(f"f_max_hz must be a positive number or None, got {f_max_hz!r}")
    if clip_level_m_s2 is not None and not clip_level_m_s2 > 0:
        raise ValueError(f"clip_level_m_s2 must be positive or None, got {clip_level_m_s2!r}")
    if not time_rel_tol > 0:
        raise ValueError(f"time_rel_tol must be positive, got {time_rel_tol!r}")
    fs = sample_rate_hz(t, rel_tol=time_rel_tol)
    dt = 1.0 / fs
    if start_s is None:
        start_s = float(t[0])
    if not (t[0] - 0.5 * dt <= start_s < t[-1]):
        raise ValueError(
            f"start_s must lie within the record [{t[0]:g}, {t[-1]:g}) s, got {start_s!r}"
        )
    if end_s is not None and not end_s > start_s:
        raise ValueError(f"end_s must be after start_s = {start_s:g} s, got {end_s!r}")
    notes: list[str] = []
    i0 = int(np.searchsorted(t, start_s - 1e-6 * dt))
    i1 = t.size if end_s is None else int(np.searchsorted(t, end_s - 1e-6 * dt))
    t, a = t[:i1], a[:i1]
    n_clipped = 0
    if clip_level_m_s2 is not None:
        clipped = np.flatnonzero(np.abs(a[i0:]) >= CLIP_FRACTION * clip_level_m_s2)
        n_clipped = int(clipped.size)
        if n_clipped:
            new_i0 = i0 + int(clipped[-1]) + 1 + CLIP_GUARD_SAMPLES
            notes.append(
                f"{n_clipped} clipped samples (|a| >= {CLIP_FRACTION:g} x "
                f"{clip_level_m_s2:g} m/s^2); analysis starts at t = "
                f"{t[min(new_i0, t.size - 1)]:.4f} s instead of {t[i0]:.4f} s"
            )
            i0 = new_i0
    if t.size - i0 < MIN_DECAY_SAMPLES:
        raise ValueError(
            f"only {max(t.size - i0, 0)} samples remain after start_s = {start_s:g} s "
            f"(and clipping{'' if end_s is None else f', before end_s = {end_s:g} s'}); "
            f"need at least {MIN_DECAY_SAMPLES}"
        )
    x = a[i0:]
    tau0 = float(t[i0] - start_s)
    spec = amplitude_spectrum(x, fs, window=window, pad_factor=pad_factor)
    fit = fit_free_decay(x, fs, tau0_s=tau0, n_modes=n_modes, f_max_hz=f_max_hz, spectrum=spec,
                         known_modes=known_modes)
    notes.extend(fit.notes)
    return IdentificationResult(
        modes=fit.modes if n_modes is None else fit.modes[:n_modes],
        fft_peaks=fit.spectral_peaks,
        spectrum=spec,
        fit=fit,
        fs_hz=fs,
        start_s=float(start_s),
        fit_start_s=float(start_s + fit.fit_start_s),
        duration_s=float(x.size * dt),
        n_clipped=n_clipped,
        notes=notes,
    )
