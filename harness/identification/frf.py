"""Frequency responses from a measured input and output, and modes fitted to them.

- ``periodic_frf``: a periodic excitation (multisine) averaged over whole periods: the DFT
  of each period at the excited lines, H1 = Gxy / Gxx, H2 = Gyy / Gyx and the coherence
  |Gxy|^2 / (Gxx Gyy), the average over the periods.
- ``welch_frf``: a non-periodic excitation (chirp, random) by Welch segments (Hann window,
  half overlap; ``scipy.signal.csd`` / ``welch``).
- ``PeriodicSpectra`` and ``WelchSpectra``: the same two estimates fed block by block (a
  long record read as it comes, one input and several outputs at once): the sums over
  periods or segments are all they keep, with at most one period or segment of samples, so
  their memory does not grow with the record's length.
- Each point's 1-sigma of |H| relative to |H| (Bendat & Piersol, eq. 9.90):
  ``sqrt(1 - coh) / (sqrt(2 n_avg) sqrt(coh))``; the same in radians for the phase.
- ``fit_modes``: a sum of second-order modes ``(A_k + B_k s) / (s^2 + 2 zeta_k w_k s + w_k^2)``
  plus residual terms ``R_{-1} / s + R_0 + R_1 s`` (the rigid body, modes outside the band),
  times a delay ``exp(-s tau)``, fitted to H1 by weighted nonlinear least squares
  (``scipy.optimize.least_squares``, weights 1 / sigma) from the frequencies of the FRF's
  peaks; each mode's frequency and damping with 1-sigma from the Jacobian (scaled by the
  fit's reduced chi-square when above 1).
- ``state_space_frf``: a model's ``C (sI - A)^-1 B + D`` at given frequencies.

Pure: arrays in, results out (numpy, scipy). Frequencies in Hz carry it in their names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import fft as sp_fft
from scipy import optimize, signal

SIGMA_FLOOR = 1e-6
"""The smallest relative sigma a point is given (a coherence of exactly 1)."""


def relative_sigma(coherence: np.ndarray, n_avg: int) -> np.ndarray:
    """1-sigma of |H| relative to |H| from the coherence and the number of averages."""
    coh = np.clip(np.asarray(coherence, dtype=float), 1e-12, 1.0)
    return np.maximum(np.sqrt(1.0 - coh) / (math.sqrt(2 * n_avg) * np.sqrt(coh)), SIGMA_FLOOR)


@dataclass
class FrfEstimate:
    """H1, H2 and the coherence at ``freq_hz``, from ``n_avg`` averages."""

    freq_hz: np.ndarray
    h1: np.ndarray
    h2: np.ndarray
    coherence: np.ndarray
    n_avg: int
    method: str

    @property
    def sigma_rel(self) -> np.ndarray:
        return relative_sigma(self.coherence, self.n_avg)

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method, "n_avg": self.n_avg,
            "freq_hz": self.freq_hz.tolist(),
            "h1_mag": np.abs(self.h1).tolist(),
            "h1_phase_rad": np.angle(self.h1).tolist(),
            "h1_real": self.h1.real.tolist(), "h1_imag": self.h1.imag.tolist(),
            "h2_mag": np.abs(self.h2).tolist(),
            "coherence": self.coherence.tolist(),
            "sigma_mag_rel": self.sigma_rel.tolist(),
        }


def _spectra(gxx: np.ndarray, gyy: np.ndarray, gxy: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h1 = gxy / gxx
    h2 = gyy / np.conj(gxy)
    coh = np.abs(gxy) ** 2 / (gxx * gyy)
    return h1, h2, np.clip(coh.real, 0.0, 1.0)


def periodic_frf(u: np.ndarray, y: np.ndarray, period_samples: int, dt_s: float,
                 lines: np.ndarray | None = None, min_line_power: float = 1e-3
                 ) -> FrfEstimate:
    """H1, H2, coherence of a periodic excitation: ``u`` and ``y`` start at the first
    measured period (the settling dropped); every whole period is one average. ``lines``:
    the excited DFT lines (default: those whose input power is above ``min_line_power``
    times the strongest's). Period by period, never a copy of the record."""
    n = int(period_samples)
    periods = min(len(u), len(y)) // n
    if periods < 2:
        raise ValueError(f"{periods} whole period(s) of {n} samples in the record: "
                         "at least 2 are needed for a coherence")
    gxx = np.zeros(n // 2 + 1)
    gyy = np.zeros(n // 2 + 1)
    gxy = np.zeros(n // 2 + 1, dtype=complex)
    for p in range(periods):
        uf = np.fft.rfft(u[p * n:(p + 1) * n])
        yf = np.fft.rfft(y[p * n:(p + 1) * n])
        gxx += np.abs(uf) ** 2
        gyy += np.abs(yf) ** 2
        gxy += np.conj(uf) * yf
    return _periodic_estimate(gxx, gyy, gxy, n, periods, dt_s, lines, min_line_power)


def _periodic_estimate(gxx: np.ndarray, gyy: np.ndarray, gxy: np.ndarray, n: int,
                       periods: int, dt_s: float, lines: np.ndarray | None,
                       min_line_power: float) -> FrfEstimate:
    if lines is None:
        power = gxx.copy()
        power[0] = 0.0
        if not power.max() > 0:
            raise ValueError("the input carries no periodic excitation (no line above DC)")
        lines = np.flatnonzero(power > min_line_power * power.max())
    lines = np.asarray(lines, dtype=int)
    h1, h2, coh = _spectra(gxx[lines], gyy[lines], gxy[lines])
    return FrfEstimate(lines / (n * dt_s), h1, h2, coh, periods, "periodic")


def _as_rows(u: np.ndarray, ys: np.ndarray | list[np.ndarray]) -> np.ndarray:
    """One block: the input's samples in row 0, each output's in the rows after."""
    rows = np.vstack([np.asarray(u, dtype=float)[None, :], np.asarray(ys, dtype=float)
                      .reshape(-1, len(u))])
    return rows


class PeriodicSpectra:
    """``periodic_frf`` fed block by block, for one input and ``n_outputs`` outputs: each
    block's samples fill the current period (blocks may split a period anywhere); at each
    period's end its DFT is added to the sums |X|^2, |Y|^2 and X* Y at every line. Holds
    one period of samples and the sums (a few times the period's length in floats)."""

    def __init__(self, period_samples: int, n_outputs: int) -> None:
        self.n = int(period_samples)
        if self.n < 2:
            raise ValueError(f"period_samples: expected at least 2, got {period_samples}")
        self.n_outputs = int(n_outputs)
        bins = self.n // 2 + 1
        self.buffer = np.empty((1 + self.n_outputs, self.n))
        self.fill = 0
        self.gxx = np.zeros(bins)
        self.gyy = np.zeros((self.n_outputs, bins))
        self.gxy = np.zeros((self.n_outputs, bins), dtype=complex)
        self.periods = 0

    def add(self, u: np.ndarray, ys: np.ndarray | list[np.ndarray]) -> None:
        """The next samples of the input ``u`` and of each output (``ys``: one row an
        output, as long as ``u``)."""
        rows = _as_rows(u, ys)
        pos, m = 0, rows.shape[1]
        while pos < m:
            take = min(self.n - self.fill, m - pos)
            self.buffer[:, self.fill:self.fill + take] = rows[:, pos:pos + take]
            self.fill += take
            pos += take
            if self.fill == self.n:
                self._close_period()

    def _close_period(self) -> None:
        uf = np.fft.rfft(self.buffer[0])
        self.gxx += np.abs(uf) ** 2
        for r in range(self.n_outputs):
            yf = np.fft.rfft(self.buffer[1 + r])
            self.gyy[r] += np.abs(yf) ** 2
            self.gxy[r] += np.conj(uf) * yf
        self.periods += 1
        self.fill = 0

    def estimates(self, dt_s: float, lines: np.ndarray | None = None,
                  min_line_power: float = 1e-3) -> list[FrfEstimate]:
        """Each output's estimate over the whole periods added so far (a last, partial
        period is left out, as ``periodic_frf`` does)."""
        if self.periods < 2:
            raise ValueError(f"{self.periods} whole period(s) of {self.n} samples in the "
                             "record: at least 2 are needed for a coherence")
        return [_periodic_estimate(self.gxx, self.gyy[r], self.gxy[r], self.n, self.periods,
                                   dt_s, lines, min_line_power)
                for r in range(self.n_outputs)]


def welch_frf(u: np.ndarray, y: np.ndarray, dt_s: float, segment_samples: int,
              f0_hz: float = 0.0, f1_hz: float = math.inf) -> FrfEstimate:
    """H1, H2, coherence by Welch segments (Hann, half overlap) within [f0_hz, f1_hz]."""
    fs = 1.0 / dt_s
    n = int(segment_samples)
    m = min(len(u), len(y))
    if m < 2 * n:
        raise ValueError(f"{m} samples: at least two segments of {n} are needed")
    kw = {"fs": fs, "nperseg": n, "noverlap": n // 2, "window": "hann", "detrend": "constant"}
    f, gxx = signal.welch(u[:m], **kw)
    _, gyy = signal.welch(y[:m], **kw)
    _, gxy = signal.csd(u[:m], y[:m], **kw)
    keep = (f >= f0_hz) & (f <= f1_hz) & (f > 0)
    h1, h2, coh = _spectra(gxx[keep], gyy[keep], gxy[keep])
    n_avg = (m - n) // (n - n // 2) + 1
    return FrfEstimate(f[keep], h1, h2, coh, n_avg, "welch")


class WelchSpectra:
    """``welch_frf`` fed block by block, for one input and ``n_outputs`` outputs: Hann
    segments of ``segment_samples`` with half overlap, each segment's mean removed (as
    ``scipy.signal.csd``'s ``detrend="constant"``), their cross and auto spectra summed as
    the segments complete; the samples a segment still needs (fewer than one segment's)
    are carried to the next block. The same density scaling as scipy's, so the sums are
    scipy's averages times the number of segments."""

    def __init__(self, segment_samples: int, n_outputs: int, dt_s: float) -> None:
        self.n = int(segment_samples)
        if self.n < 2:
            raise ValueError(f"segment_samples: expected at least 2, got {segment_samples}")
        self.step = self.n - self.n // 2
        self.n_outputs = int(n_outputs)
        self.dt_s = float(dt_s)
        self.window = signal.get_window("hann", self.n)
        self.scale = 1.0 / ((1.0 / self.dt_s) * (self.window * self.window).sum())
        bins = self.n // 2 + 1
        self.carry = np.empty((1 + self.n_outputs, 0))
        self.gxx = np.zeros(bins)
        self.gyy = np.zeros((self.n_outputs, bins))
        self.gxy = np.zeros((self.n_outputs, bins), dtype=complex)
        self.segments = 0
        self.samples = 0

    def add(self, u: np.ndarray, ys: np.ndarray | list[np.ndarray]) -> None:
        """The next samples of the input ``u`` and of each output (``ys``: one row an
        output, as long as ``u``)."""
        rows = _as_rows(u, ys)
        self.samples += rows.shape[1]
        data = np.concatenate([self.carry, rows], axis=1) if self.carry.shape[1] else rows
        pos = 0
        while pos + self.n <= data.shape[1]:
            seg = data[:, pos:pos + self.n]
            seg = seg - seg.mean(axis=1, keepdims=True)
            spec = sp_fft.rfft(seg * self.window, axis=1)
            uf = spec[0]
            self.gxx += (np.conj(uf) * uf).real
            for r in range(self.n_outputs):
                yf = spec[1 + r]
                self.gyy[r] += (np.conj(yf) * yf).real
                self.gxy[r] += np.conj(uf) * yf
            self.segments += 1
            pos += self.step
        self.carry = data[:, pos:].copy()

    def estimates(self, f0_hz: float = 0.0, f1_hz: float = math.inf) -> list[FrfEstimate]:
        """Each output's estimate within [f0_hz, f1_hz] over the segments so far."""
        if self.samples < 2 * self.n:
            raise ValueError(f"{self.samples} samples: at least two segments of {self.n} "
                             "are needed")
        f = sp_fft.rfftfreq(self.n, self.dt_s)
        keep = (f >= f0_hz) & (f <= f1_hz) & (f > 0)
        # scipy's density scaling and one-sided doubling, averaged over the segments
        factor = np.full(len(f), 2.0 * self.scale / self.segments)
        factor[0] = self.scale / self.segments
        if self.n % 2 == 0:
            factor[-1] = self.scale / self.segments
        gxx = (self.gxx * factor)[keep]
        out = []
        for r in range(self.n_outputs):
            h1, h2, coh = _spectra(gxx, (self.gyy[r] * factor)[keep],
                                   (self.gxy[r] * factor)[keep])
            out.append(FrfEstimate(f[keep], h1, h2, coh, self.segments, "welch"))
        return out


def state_space_frf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float | np.ndarray,
                    freq_hz: np.ndarray) -> np.ndarray:
    """``c (sI - a)^-1 b + d`` at s = j 2 pi f (``b`` a column, ``c`` a row)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float).reshape(-1)
    c = np.asarray(c, dtype=float).reshape(-1)
    eye = np.eye(a.shape[0])
    out = np.empty(len(freq_hz), dtype=complex)
    for i, f in enumerate(np.asarray(freq_hz, dtype=float)):
        out[i] = c @ np.linalg.solve(2j * math.pi * f * eye - a, b)
    return out + float(np.asarray(d))


@dataclass
class FittedMode:
    omega_rad_s: float
    sigma_omega_rad_s: float
    damping_ratio: float
    sigma_damping: float

    @property
    def freq_hz(self) -> float:
        return self.omega_rad_s / (2 * math.pi)

    def to_dict(self) -> dict[str, Any]:
        return {"omega_rad_s": self.omega_rad_s, "sigma_omega_rad_s": self.sigma_omega_rad_s,
                "freq_hz": self.freq_hz, "damping_ratio": self.damping_ratio,
                "sigma_damping": self.sigma_damping}


@dataclass
class ModalFit:
    modes: list[FittedMode]
    residual_powers: tuple[int, ...]
    coefficients: np.ndarray
    delay_s: float
    chi2_reduced: float
    n_points: int
    notes: list[str] = field(default_factory=list)

    def evaluate(self, freq_hz: np.ndarray) -> np.ndarray:
        theta = np.r_[[m.omega_rad_s for m in self.modes],
                      [m.damping_ratio for m in self.modes], self.delay_s]
        return _model(theta, self.coefficients, np.asarray(freq_hz), len(self.modes),
                      self.residual_powers)

    def to_dict(self) -> dict[str, Any]:
        return {"modes": [m.to_dict() for m in self.modes], "delay_s": self.delay_s,
                "residual_powers": list(self.residual_powers),
                "chi2_reduced": self.chi2_reduced, "n_points": self.n_points,
                "notes": list(self.notes)}


def _basis(theta: np.ndarray, s: np.ndarray, n_modes: int,
           powers: tuple[int, ...]) -> np.ndarray:
    """Columns: per mode 1/D and s/D, then s^p per residual power, all times the delay."""
    w, z, tau = theta[:n_modes], theta[n_modes:2 * n_modes], theta[2 * n_modes]
    cols = []
    for k in range(n_modes):
        den = s * s + 2 * z[k] * w[k] * s + w[k] ** 2
        cols += [1 / den, s / den]
    cols += [s ** p for p in powers]
    return np.column_stack(cols) * np.exp(-s * tau)[:, None]


def _model(theta: np.ndarray, coef: np.ndarray, freq_hz: np.ndarray, n_modes: int,
           powers: tuple[int, ...]) -> np.ndarray:
    s = 2j * math.pi * freq_hz
    return _basis(theta, s, n_modes, powers) @ coef


def _linear_coefficients(theta: np.ndarray, s: np.ndarray, h: np.ndarray, weight: np.ndarray,
                         n_modes: int, powers: tuple[int, ...]) -> np.ndarray:
    basis = _basis(theta, s, n_modes, powers) * weight[:, None]
    lhs = np.vstack([basis.real, basis.imag])
    rhs = np.r_[(h * weight).real, (h * weight).imag]
    coef, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    return coef


def peak_guesses(freq_hz: np.ndarray, h: np.ndarray, n_peaks: int) -> np.ndarray:
    """The ``n_peaks`` most prominent local maxima of log |H|, as omega (rad/s), ascending."""
    logmag = np.log(np.abs(h))
    idx, props = signal.find_peaks(logmag, prominence=0.0)
    order = np.argsort(props["prominences"])[::-1][:n_peaks]
    return np.sort(2 * math.pi * np.asarray(freq_hz)[idx[order]])


def refine_guess(freq_hz: np.ndarray, h: np.ndarray, omega_rad_s: float,
                 rel_span: float = 0.15) -> float:
    """The frequency (rad/s) of |H|'s largest value within ``rel_span`` of a guess: the
    FRF's own peak near a model mode (the guess itself when no local maximum is there)."""
    w = 2 * math.pi * np.asarray(freq_hz)
    near = np.flatnonzero(np.abs(w / omega_rad_s - 1) <= rel_span)
    if len(near) < 3:
        return omega_rad_s
    i = near[np.argmax(np.abs(h[near]))]
    if i in (near[0], near[-1]):
        return omega_rad_s
    return float(w[i])


def fit_modes(freq_hz: np.ndarray, h: np.ndarray, sigma_rel: np.ndarray,
              omega_guess_rad_s: np.ndarray, damping_guess: float = 0.03,
              residual_powers: tuple[int, ...] = (-1, 0, 1)) -> ModalFit:
    """Modes fitted to H (see the module's docstring); ``sigma_rel`` each point's relative
    1-sigma of |H| (its absolute sigma, |H| sigma_rel, weights both real and imaginary
    parts)."""
    freq_hz = np.asarray(freq_hz, dtype=float)
    h = np.asarray(h, dtype=complex)
    n_modes = len(omega_guess_rad_s)
    s = 2j * math.pi * freq_hz
    sigma_abs = np.maximum(np.abs(h) * np.asarray(sigma_rel), 1e-300)
    weight = 1.0 / sigma_abs
    n_par = 2 * n_modes + 1 + 2 * n_modes + len(residual_powers)
    if 2 * len(h) <= n_par:
        raise ValueError(f"{len(h)} points cannot determine {n_par} parameters")
    theta0 = np.r_[np.asarray(omega_guess_rad_s, dtype=float),
                   np.full(n_modes, damping_guess), 0.0]
    coef0 = _linear_coefficients(theta0, s, h, weight, n_modes, residual_powers)
    p0 = np.r_[theta0, coef0]
    nt = len(theta0)

    def residuals(p: np.ndarray) -> np.ndarray:
        r = (_basis(p[:nt], s, n_modes, residual_powers) @ p[nt:] - h) * weight
        return np.r_[r.real, r.imag]

    w_max = 2 * math.pi * freq_hz.max() * 2
    lower = np.r_[np.full(n_modes, 1e-6), np.full(n_modes, 1e-5), -1.0,
                  np.full(len(coef0), -np.inf)]
    upper = np.r_[np.full(n_modes, w_max), np.full(n_modes, 0.9), 1.0,
                  np.full(len(coef0), np.inf)]
    p0 = np.clip(p0, lower + 1e-12, upper - 1e-12)
    x_scale = np.r_[np.abs(theta0[:n_modes]), np.full(n_modes, 0.01), 1e-3,
                    np.maximum(np.abs(coef0), 1e-12)]
    sol = optimize.least_squares(residuals, p0, bounds=(lower, upper), x_scale=x_scale,
                                 method="trf", max_nfev=2000)
    dof = max(1, 2 * len(h) - len(sol.x))
    chi2 = float(np.sum(sol.fun ** 2) / dof)
    jac = sol.jac
    notes = []
    try:
        cov = np.linalg.pinv(jac.T @ jac) * max(1.0, chi2)
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sig = np.full(len(sol.x), np.nan)
        notes.append("singular Jacobian: no 1-sigma")
    if not sol.success:
        notes.append(f"least squares: {sol.message}")
    theta = sol.x[:nt]
    modes = [FittedMode(float(theta[k]), float(sig[k]), float(theta[n_modes + k]),
                        float(sig[n_modes + k])) for k in range(n_modes)]
    order = np.argsort([m.omega_rad_s for m in modes])
    modes = [modes[i] for i in order]
    # the coefficients follow the modes' order
    coef = sol.x[nt:]
    pairs = coef[:2 * n_modes].reshape(n_modes, 2)[order].reshape(-1)
    return ModalFit(modes, tuple(residual_powers), np.r_[pairs, coef[2 * n_modes:]],
                    float(theta[2 * n_modes]), chi2, len(h), notes)
