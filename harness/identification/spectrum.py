"""FFT view of a free decay: windowed, zero-padded amplitude spectrum and its peaks.

This is the paper's view (Xu 2018, Table 1: "FFT of free decay"). The peak frequency of a
free decay is its *damped* frequency; it is refined between bins by interpolation:

- ``"parabolic"``: a parabola through the log-amplitude of the three bins around the peak
  (Gaussian interpolation). Works for any window and any zero padding.
- ``"quinn"``: Quinn's second estimator, which uses the complex DFT values. It is only valid
  for the rectangular window without zero padding, and raises ``ValueError`` otherwise.

The half-power (-3 dB) bandwidth damping is returned as ``damping_ratio_half_power_rough``:
it is resolution-limited, biased by noise and by neighbouring modes, and is only a rough
check on the parametric fit (``decay_fit``). With the exponential window the decay rate
that the window itself adds is subtracted.

Window choice for a free decay: a Hann window is zero at the start, exactly where a decaying
record holds its signal, so it suppresses fast-decaying modes. The default is therefore an
exponential window (``exp(-t / T_w)``, falling to ``exp_end_fraction`` at the record end):
it removes truncation leakage and adds a known decay rate ``1 / T_w``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WINDOWS = ("rect", "hann", "exponential")
INTERPOLATIONS = ("parabolic", "quinn")


@dataclass(frozen=True)
class Spectrum:
    """One-sided amplitude spectrum of a (windowed, zero-padded) record.

    ``amplitude`` is scaled so that a steady sinusoid of amplitude A shows a peak of A
    (``2 |X| / sum(window)``); for a decaying signal it is a relative measure only.
    """

    freq_hz: np.ndarray
    amplitude: np.ndarray
    values: np.ndarray  # complex DFT values (same scaling), used by Quinn's estimator
    fs_hz: float
    n_samples: int
    n_fft: int
    window: str
    window_decay_rate_1_s: float  # decay rate added by the window (exponential), else 0
    noise_floor: float  # median amplitude over the band: a robust noise-level estimate

    @property
    def resolution_hz(self) -> float:
        """Rayleigh resolution of the record, 1 / duration (not the padded bin width)."""
        return self.fs_hz / self.n_samples


@dataclass(frozen=True)
class SpectralPeak:
    """A peak of the amplitude spectrum, with its interpolated (damped) frequency."""

    freq_hz: float
    omega_rad_s: float
    amplitude: float
    snr: float  # peak amplitude / spectrum noise floor
    damping_ratio_half_power_rough: float | None  # rough, labelled; None if not measurable


def _window(name: str, n: int, fs_hz: float, exp_end_fraction: float) -> tuple[np.ndarray, float]:
    if name == "rect":
        return np.ones(n), 0.0
    if name == "hann":
        # on use: scipy.signal pulls in scipy.stats, 0.25 s of every harness start
        from scipy import signal as sps
        return sps.get_window("hann", n, fftbins=False), 0.0
    if name == "exponential":
        if not 0.0 < exp_end_fraction < 1.0:
            raise ValueError(f"exp_end_fraction must be in (0, 1), got {exp_end_fraction!r}")
        duration_s = n / fs_hz
        decay_rate = np.log(1.0 / exp_end_fraction) / duration_s
        return np.exp(-decay_rate * np.arange(n) / fs_hz), float(decay_rate)
    raise ValueError(f"window must be one of {WINDOWS}, got {name!r}")


def amplitude_spectrum(
    x: np.ndarray,
    fs_hz: float,
    *,
    window: str = "exponential",
    pad_factor: int = 8,
    exp_end_fraction: float = 0.01,
    remove_mean: bool = True,
) -> Spectrum:
    """Windowed, zero-padded one-sided amplitude spectrum of ``x`` sampled at ``fs_hz``.

    The FFT length is the next power of two at or above ``pad_factor * len(x)``.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.size < 8:
        raise ValueError(f"x must be a 1-D array of at least 8 samples, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x must be finite (no NaN or inf)")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"fs_hz must be a positive finite number, got {fs_hz!r}")
    if int(pad_factor) != pad_factor or pad_factor < 1:
        raise ValueError(f"pad_factor must be an integer >= 1, got {pad_factor!r}")
    n = x.size
    w, decay_rate = _window(window, n, fs_hz, exp_end_fraction)
    xd = x - x.mean() if remove_mean else x
    n_fft = n if pad_factor == 1 else int(2 ** np.ceil(np.log2(pad_factor * n)))
    values = np.fft.rfft(xd * w, n_fft) * (2.0 / w.sum())
    freq = np.fft.rfftfreq(n_fft, 1.0 / fs_hz)
    amp = np.abs(values)
    # Noise floor: median amplitude away from DC (most bins of a decay record are noise).
    lo = int(np.searchsorted(freq, 3.0 * fs_hz / n))
    floor = float(np.median(amp[lo:])) if amp[lo:].size else float(np.median(amp))
    return Spectrum(
        freq_hz=freq,
        amplitude=amp,
        values=values,
        fs_hz=float(fs_hz),
        n_samples=n,
        n_fft=n_fft,
        window=window,
        window_decay_rate_1_s=decay_rate,
        noise_floor=floor,
    )


def parabolic_peak(spec: Spectrum, k: int) -> tuple[float, float]:
    """(freq_hz, amplitude) of the peak at bin ``k`` by a parabola on log-amplitude."""
    a = spec.amplitude
    if k <= 0 or k >= a.size - 1:
        return float(spec.freq_hz[k]), float(a[k])
    lm, l0, lp = np.log(np.maximum(a[k - 1 : k + 2], np.finfo(float).tiny))
    denom = lm - 2.0 * l0 + lp
    if denom >= 0.0:  # not a strict maximum: no refinement
        return float(spec.freq_hz[k]), float(a[k])
    delta = 0.5 * (lm - lp) / denom
    bin_hz = spec.fs_hz / spec.n_fft
    return float(spec.freq_hz[k] + delta * bin_hz), float(np.exp(l0 - 0.25 * (lm - lp) * delta))


def _quinn_tau(x: float) -> float:
    r = np.sqrt(2.0 / 3.0)
    return 0.25 * np.log(3 * x * x + 6 * x + 1) - np.sqrt(6.0) / 24.0 * np.log(
        (x + 1 - r) / (x + 1 + r)
    )


def quinn_peak(spec: Spectrum, k: int) -> tuple[float, float]:
    """(freq_hz, amplitude) of the peak at bin ``k`` by Quinn's second estimator.

    Valid only for a rectangular window without zero padding (``pad_factor=1``).
    """
    if spec.window != "rect" or spec.n_fft != spec.n_samples:
        raise ValueError(
            "interpolation='quinn' needs window='rect' and pad_factor=1 "
            f"(got window={spec.window!r}, n_fft={spec.n_fft}, n_samples={spec.n_samples})"
        )
    v = spec.values
    if k <= 0 or k >= v.size - 1:
        return float(spec.freq_hz[k]), float(abs(v[k]))
    den = float(np.real(v[k] * np.conj(v[k])))
    ap = float(np.real(v[k + 1] * np.conj(v[k]))) / den
    am = float(np.real(v[k - 1] * np.conj(v[k]))) / den
    dp = -ap / (1.0 - ap)
    dm = am / (1.0 - am)
    delta = 0.5 * (dp + dm) + _quinn_tau(dp * dp) - _quinn_tau(dm * dm)
    bin_hz = spec.fs_hz / spec.n_fft
    # Amplitude of a sinusoid whose frequency is off-bin by delta (Dirichlet kernel).
    amp = abs(v[k]) / max(abs(np.sinc(delta)), 1e-12)
    return float(spec.freq_hz[k] + delta * bin_hz), float(amp)


def half_power_damping(spec: Spectrum, k: int, peak_freq_hz: float) -> float | None:
    """Rough damping ratio from the -3 dB bandwidth around bin ``k``.

    zeta ~= (half bandwidth [rad/s] - window decay rate) / omega_peak. Returns ``None`` when
    a -3 dB crossing is not found on both sides before the spectrum rises again.
    """
    a = spec.amplitude
    f = spec.freq_hz
    level = a[k] / np.sqrt(2.0)

    def crossing(step: int) -> float | None:
        i = k
        while 0 < i < a.size - 1:
            j = i + step
            if a[j] < level:
                # linear interpolation between bins i and j
                frac = (a[i] - level) / (a[i] - a[j])
                return float(f[i] + frac * (f[j] - f[i]))
            if a[j] > a[i] * 1.0001:  # rising again: another peak before -3 dB
                return None
            i = j
        return None

    f_lo = crossing(-1)
    f_hi = crossing(+1)
    if f_lo is None or f_hi is None or peak_freq_hz <= 0:
        return None
    half_bw_rad_s = np.pi * (f_hi - f_lo)
    zeta = (half_bw_rad_s - spec.window_decay_rate_1_s) / (2.0 * np.pi * peak_freq_hz)
    return float(zeta)


def _sidelobe_envelope(spec: Spectrum, df_hz: float) -> float:
    """Envelope of the window's spectral leakage at ``df_hz`` from a peak (relative)."""
    u = df_hz * spec.n_samples / spec.fs_hz  # distance in Rayleigh resolutions
    if spec.window == "rect":
        return 1.0 if u < 1.0 else 1.0 / (np.pi * u)
    if spec.window == "hann":
        return 1.0 if u < 2.0 else 1.0 / (np.pi * u * (u * u - 1.0))
    return 0.0  # exponential: smooth Lorentzian skirt, no sidelobes to mistake for peaks


def find_spectral_peaks(
    spec: Spectrum,
    *,
    f_min_hz: float | None = None,
    f_max_hz: float | None = None,
    min_snr: float = 10.0,
    min_prominence_db: float = 6.0,
    max_peaks: int | None = None,
    interpolation: str = "parabolic",
) -> list[SpectralPeak]:
    """Significant peaks of ``spec``, sorted by frequency.

    A peak counts if its amplitude exceeds ``min_snr`` times the spectrum's noise floor and
    it stands ``min_prominence_db`` above the valleys around it; with the rect and hann
    windows it must also stand 6 dB above the sidelobe envelopes of the stronger peaks
    (so window sidelobes are not taken for modes). ``max_peaks`` keeps the
    strongest. ``f_min_hz`` defaults to three Rayleigh resolutions (clear of the DC leak).
    """
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    if min_snr <= 0:
        raise ValueError(f"min_snr must be positive, got {min_snr!r}")
    if max_peaks is not None and max_peaks < 1:
        raise ValueError(f"max_peaks must be >= 1 or None, got {max_peaks!r}")
    f_lo = 3.0 * spec.resolution_hz if f_min_hz is None else f_min_hz
    f_hi = spec.fs_hz / 2.0 if f_max_hz is None else f_max_hz
    log_a = 20.0 * np.log10(np.maximum(spec.amplitude, np.finfo(float).tiny))
    # on use: scipy.signal pulls in scipy.stats, 0.25 s of every harness start
    from scipy import signal as sps
    idx, _ = sps.find_peaks(log_a, prominence=min_prominence_db)
    cands = [
        int(k)
        for k in idx
        if f_lo <= spec.freq_hz[k] <= f_hi and spec.amplitude[k] >= min_snr * spec.noise_floor
    ]
    cands.sort(key=lambda k: spec.amplitude[k], reverse=True)
    # Sidelobe guard (rect, hann): a peak must stand 6 dB above the summed sidelobe
    # envelopes of the stronger peaks already kept.
    keep: list[int] = []
    for k in cands:
        leak = sum(
            spec.amplitude[j] * _sidelobe_envelope(spec, abs(spec.freq_hz[k] - spec.freq_hz[j]))
            for j in keep
        )
        if spec.amplitude[k] >= 2.0 * leak:
            keep.append(k)
    if max_peaks is not None:
        keep = keep[:max_peaks]
    refine = parabolic_peak if interpolation == "parabolic" else quinn_peak
    peaks = []
    for k in sorted(keep):
        freq_hz, amp = refine(spec, k)
        peaks.append(
            SpectralPeak(
                freq_hz=freq_hz,
                omega_rad_s=2.0 * np.pi * freq_hz,
                amplitude=amp,
                snr=float(spec.amplitude[k] / spec.noise_floor),
                damping_ratio_half_power_rough=half_power_damping(spec, k, freq_hz),
            )
        )
    return peaks
