"""Parametric fit of a free decay as a sum of damped sinusoids plus an offset.

Model (time ``tau`` from the start of the free decay, SI units)::

    x(tau) = offset + sum_k A_k exp(-zeta_k w_k tau) cos(w_k sqrt(1 - zeta_k^2) tau + phi_k)

with ``w_k`` the undamped natural frequency (rad/s), ``zeta_k`` the damping ratio,
``A_k`` (m/s^2) and ``phi_k`` the amplitude and phase at ``tau = 0``.

Steps (``fit_free_decay``):

1. Decimation. A causal linear-phase FIR low-pass (Kaiser window, 60 dB stop band) is
   applied with ``numpy.convolve(..., "valid")``: the first ``numtaps - 1`` outputs, which
   depend on samples before the start, are never formed (the start transient is dropped,
   ``DecimationPlan.dropped_s``), and each remaining output is an exact steady-state
   convolution. Every ``q``-th output is kept, ``q`` chosen for an output rate of at least
   16 x ``f_max_hz`` (a wide transition band keeps the filter, hence the dropped start,
   short). Passband edge ``f_max_hz``; stop band from the new Nyquist frequency up, so
   nothing aliases into the decimated band (60 dB). No zero-phase
   (forward-backward) filtering is used: it would need samples beyond the record edges.
   A damped exponential ``exp(s tau)`` passes an FIR exactly as ``H(s) exp(s tau)`` with
   ``H(s) = sum_n h[n] exp(-s n dt)``; the fit model includes ``H(s)``, so frequency,
   damping, amplitude and phase refer to the raw (unfiltered) signal.
2. Start values by the matrix pencil method (Hua & Sarkar) on the decimated record (its
   first 1200 samples at most). The
   model order is the number of Hankel singular values above ``sv_threshold`` times their
   median (pure-noise Hankel matrices give a max/median ratio of about 2-2.6). Poles that are
   real, growing (zeta < -0.02), overdamped (zeta > ``zeta_max``), in the filter's stop band
   or too weak to be told from noise are discarded.
3. Nonlinear least squares (``scipy.optimize.least_squares``, trust-region reflective)
   over (w, zeta, A, phi) per mode plus the offset, with an analytic Jacobian. Modes known
   from another record (``known_modes``, e.g. another free-decay window of the same run)
   that the pencil does not find here are added with w and zeta held, (A, phi) fitted, so
   that a leftover below this record's detection threshold does not bias the others; they
   are reported apart (``DecayFit.fixed_modes``).
4. 1-sigma uncertainties from the Jacobian and the residual variance. The FIR colours the
   noise, so the covariance is the sandwich ``B^-1 (J^T R J) B^-1``, ``B = J^T J``, with
   ``R`` the known autocorrelation of the filter (white noise assumed at the raw rate).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import eigh, hankel, lstsq
from scipy.optimize import least_squares

from harness.identification.spectrum import (
    SpectralPeak,
    Spectrum,
    amplitude_spectrum,
    find_spectral_peaks,
)

N_MODE_PARAMS = 4  # (omega_rad_s, damping_ratio, amplitude, phase_rad) per mode
KNOWN_MATCH_REL = 0.03  # a known mode counts as found if a pencil mode lies this close
RATE_FACTOR = 16.0  # decimated sample rate >= RATE_FACTOR x f_max_hz


@dataclass(frozen=True)
class IdentifiedMode:
    """One identified mode. ``omega_rad_s`` is the undamped natural frequency."""

    omega_rad_s: float
    freq_hz: float
    damping_ratio: float
    amplitude: float  # m/s^2 at the start of the free decay
    phase_rad: float
    sigma_omega_rad_s: float
    sigma_damping: float
    sigma_amplitude: float
    sigma_phase_rad: float

    @property
    def omega_damped_rad_s(self) -> float:
        """Damped frequency w sqrt(1 - zeta^2): what an FFT peak shows."""
        return self.omega_rad_s * float(np.sqrt(max(1.0 - self.damping_ratio**2, 0.0)))

    @property
    def sigma_freq_hz(self) -> float:
        return self.sigma_omega_rad_s / (2.0 * np.pi)


@dataclass(frozen=True)
class DecimationPlan:
    """Causal FIR low-pass + downsampling by ``factor`` (``factor == 1``: no filter)."""

    factor: int
    fs_in_hz: float
    taps: np.ndarray
    f_pass_hz: float
    f_stop_hz: float

    @property
    def fs_out_hz(self) -> float:
        return self.fs_in_hz / self.factor

    @property
    def dropped_s(self) -> float:
        """Length of the start transient that is dropped (numtaps - 1 samples)."""
        return (self.taps.size - 1) / self.fs_in_hz

    def response(self, s: complex) -> tuple[complex, complex]:
        """FIR response H(s) = sum h[n] exp(-s n dt) at a complex pole, and dH/ds."""
        dt = 1.0 / self.fs_in_hz
        n = np.arange(self.taps.size)
        e = self.taps * np.exp(-s * n * dt)
        return complex(e.sum()), complex(np.sum(-n * dt * e))

    def noise_autocorrelation(self) -> np.ndarray:
        """r[m] = sum_n h[n] h[n + m * factor]: autocorrelation of filtered white noise
        (unit variance) at the decimated lags m = 0, 1, ..."""
        full = np.correlate(self.taps, self.taps, mode="full")[self.taps.size - 1 :]
        return full[:: self.factor].copy()


@dataclass(frozen=True)
class PencilResult:
    """Matrix-pencil start: continuous-time poles, complex amplitudes at the first sample."""

    poles: np.ndarray  # s = -zeta w + j w_d (rad/s), all poles of the selected order
    amplitudes: np.ndarray
    singular_values: np.ndarray
    order: int
    n_samples: int  # leading samples of the record that the pencil used


@dataclass
class DecayFit:
    """Result of ``fit_free_decay``. Parameter order of ``covariance``: offset, then
    (omega_rad_s, damping_ratio, amplitude, phase_rad) per mode, modes by frequency."""

    modes: list[IdentifiedMode]
    offset: float
    sigma_offset: float
    residual_rms: float  # raw-rate data minus fitted model over the fitted span (m/s^2)
    residual_rms_filtered: float  # on the filtered, decimated samples that were fitted
    noise_rms_estimate: float  # white-noise rms at the raw rate implied by the fit
    spectrum: Spectrum
    spectral_peaks: list[SpectralPeak]
    decimation: DecimationPlan
    pencil: PencilResult
    covariance: np.ndarray
    f_max_hz: float
    n_fit_samples: int
    fit_start_s: float  # first fitted (decimated) sample, seconds from the decay start
    success: bool
    message: str
    notes: list[str] = field(default_factory=list)
    # ``known_modes`` added with frequency and damping held (their sigmas are 0); not in
    # ``modes``, ``covariance`` or the mode count, but in the fitted model and residual
    fixed_modes: list[IdentifiedMode] = field(default_factory=list)


# ----------------------------------------------------------------------------- model


def mode_pole(omega: float, zeta: float) -> complex:
    """Continuous-time pole s = -zeta w + j w sqrt(1 - zeta^2)."""
    return complex(-zeta * omega, omega * np.sqrt(1.0 - zeta * zeta))


def damped_sinusoid_sum(
    tau: np.ndarray,
    params: np.ndarray,
    plan: DecimationPlan | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Model and Jacobian at times ``tau`` (s) for ``params`` = [offset, (w, zeta, A, phi)...].

    With ``plan`` the model is the FIR-filtered signal: each term is multiplied by the
    filter response ``H(s)`` at its pole (exact for the steady-state FIR output).
    """
    params = np.asarray(params, dtype=float)
    n_modes = (params.size - 1) // N_MODE_PARAMS
    model = np.full(tau.shape, params[0])
    jac = np.empty((tau.size, params.size))
    jac[:, 0] = 1.0
    for k in range(n_modes):
        w, z, a, ph = params[1 + N_MODE_PARAMS * k : 1 + N_MODE_PARAMS * (k + 1)]
        root = np.sqrt(max(1.0 - z * z, 1e-12))
        s = complex(-z * w, w * root)
        h, dh = (1.0 + 0j, 0j) if plan is None else plan.response(s)
        est = np.exp(s * tau)
        c = a * np.exp(1j * ph)
        term = c * h * est
        g = c * (dh + tau * h) * est  # d(term)/ds
        ds_dw = complex(-z, root)
        ds_dz = complex(-w, -w * z / root)
        i = 1 + N_MODE_PARAMS * k
        model += term.real
        jac[:, i] = (g * ds_dw).real
        jac[:, i + 1] = (g * ds_dz).real
        jac[:, i + 2] = (h * np.exp(1j * ph) * est).real
        jac[:, i + 3] = (1j * term).real
    return model, jac


# ----------------------------------------------------------------------------- decimation


def design_decimation(
    fs_hz: float, f_max_hz: float, *, rate_factor: float = RATE_FACTOR, atten_db: float = 60.0
) -> DecimationPlan:
    """Causal FIR decimation keeping [0, f_max_hz]: output rate at least ``rate_factor``
    x f_max_hz, stop band from the output Nyquist frequency up with ``atten_db`` attenuation.

    The filter length (hence the dropped start) falls with the transition width, so a high
    output rate keeps the dropped start short (about 0.6 / f_max_hz seconds at 16 x)."""
    if not (np.isfinite(f_max_hz) and 0.0 < f_max_hz < fs_hz / 2.0):
        raise ValueError(f"f_max_hz must be in (0, fs/2 = {fs_hz / 2.0:g}) Hz, got {f_max_hz!r}")
    if not rate_factor > 2.0:
        raise ValueError(f"rate_factor must be > 2, got {rate_factor!r}")
    q = max(1, int(np.floor(fs_hz / (rate_factor * f_max_hz))))
    if q == 1:
        return DecimationPlan(1, fs_hz, np.ones(1), f_max_hz, fs_hz / 2.0)
    f_stop = fs_hz / (2.0 * q)
    width = (f_stop - f_max_hz) / (fs_hz / 2.0)
    # on use: scipy.signal pulls in scipy.stats, 0.25 s of every harness start
    from scipy import signal as sps
    numtaps, beta = sps.kaiserord(atten_db, width)
    numtaps = int(numtaps) | 1  # odd length: integer group delay, type I linear phase
    taps = sps.firwin(numtaps, 0.5 * (f_max_hz + f_stop), window=("kaiser", beta), fs=fs_hz)
    return DecimationPlan(q, fs_hz, taps, f_max_hz, f_stop)


def decimate_causal(x: np.ndarray, plan: DecimationPlan) -> tuple[np.ndarray, np.ndarray]:
    """Filtered, decimated samples and their indices in ``x``.

    Output ``y[m]`` is the causal FIR output at input index ``idx[m]``; the first
    ``numtaps - 1`` outputs (the start transient) are not produced.
    """
    if plan.taps.size > x.size:
        raise ValueError(
            f"record of {x.size} samples is shorter than the decimation filter "
            f"({plan.taps.size} taps); lower the decimation (raise f_max_hz)"
        )
    if plan.factor == 1:
        return x.copy(), np.arange(x.size)
    y = np.convolve(x, plan.taps, mode="valid")[:: plan.factor]
    idx = plan.taps.size - 1 + plan.factor * np.arange(y.size)
    return y, idx


# ----------------------------------------------------------------------------- pencil


def matrix_pencil(
    y: np.ndarray,
    dt: float,
    *,
    order: int | None = None,
    sv_threshold: float = 6.0,
    max_samples: int = 1200,
) -> PencilResult:
    """Matrix pencil estimate of the poles of ``y`` (first ``max_samples`` samples).

    ``order`` None: the number of singular values above ``sv_threshold * median``.
    Poles are returned in continuous time, s = log(z) / dt.
    """
    y = np.asarray(y, dtype=float)[:max_samples]
    n = y.size
    if n < 12:
        raise ValueError(f"matrix pencil needs at least 12 samples, got {n}")
    pencil_l = n // 3
    data = hankel(y[: n - pencil_l], y[n - pencil_l - 1 :])  # (n - L) x (L + 1)
    # Right singular vectors and singular values from the (L + 1) x (L + 1) Gram matrix:
    # several times cheaper than a full SVD, and accurate enough for a start value.
    eigval, eigvec = eigh(data.T @ data)
    sv = np.sqrt(np.maximum(eigval[::-1], 0.0))
    if order is None:
        order = int(np.count_nonzero(sv > sv_threshold * np.median(sv)))
    order = int(np.clip(order, 1, pencil_l))
    v = eigvec[:, ::-1][:, :order]  # (L + 1) x M
    z = np.linalg.eigvals(np.linalg.pinv(v[:-1]) @ v[1:])
    vander = z[np.newaxis, :] ** np.arange(n)[:, np.newaxis]
    amps = lstsq(vander, y.astype(complex))[0]
    with np.errstate(divide="ignore"):
        poles = np.log(z.astype(complex)) / dt
    return PencilResult(poles=poles, amplitudes=amps, singular_values=sv, order=order, n_samples=n)


def _mode_energy(c: complex, z: complex, n: int) -> float:
    """Energy of Re(c z^m), m = 0..n-1, with conjugate pair included: ~0.5|2c|^2 sum|z|^2m."""
    r2 = abs(z) ** 2
    geom = n if abs(r2 - 1.0) < 1e-12 else (1.0 - r2**n) / (1.0 - r2)
    return 2.0 * abs(c) ** 2 * float(geom)


def _physical_modes(
    pencil: PencilResult,
    y: np.ndarray,
    dt: float,
    *,
    f_stop_hz: float,
    zeta_max: float,
    min_energy_snr: float,
) -> list[tuple[float, float, complex, float]]:
    """(omega, zeta, complex amplitude at y[0], energy) of the physical pencil poles."""
    n = pencil.n_samples
    recon = np.zeros(n, dtype=complex)
    z_all = np.exp(pencil.poles * dt)
    for c, z in zip(pencil.amplitudes, z_all, strict=True):
        recon += c * z ** np.arange(n)
    noise_var = max(float(np.mean((y[:n] - recon.real) ** 2)), np.finfo(float).tiny)
    out = []
    for s, c, z in zip(pencil.poles, pencil.amplitudes, z_all, strict=True):
        if not np.isfinite(s) or s.imag <= 0.0:
            continue  # real poles (offset, drift) and the negative-frequency twins
        omega = abs(s)
        zeta = -s.real / omega
        if zeta < -0.02 or zeta > zeta_max or s.imag / (2 * np.pi) > f_stop_hz:
            continue
        energy = _mode_energy(c, z, n)
        if energy / noise_var < min_energy_snr:
            continue
        out.append((float(omega), float(zeta), complex(2.0 * c), energy))
    return out


# ----------------------------------------------------------------------------- fit


def _sandwich_covariance(
    jac: np.ndarray, residual: np.ndarray, plan: DecimationPlan
) -> tuple[np.ndarray, float]:
    """Parameter covariance for FIR-coloured white noise, and the raw-rate noise rms."""
    n, p = jac.shape
    r = plan.noise_autocorrelation()
    sigma2_in = float(residual @ residual) / max(n - p, 1) / r[0]
    b = jac.T @ jac
    meat = r[0] * b
    for m in range(1, min(r.size, n)):
        cross = jac[:-m].T @ jac[m:]
        meat += r[m] * (cross + cross.T)
    b_inv = np.linalg.pinv(b)
    return sigma2_in * b_inv @ meat @ b_inv, float(np.sqrt(sigma2_in))


def auto_f_max_hz(peaks: list[SpectralPeak], fs_hz: float, resolution_hz: float) -> float:
    """Default band: 1.5 x the highest significant spectral peak (within 0.45 fs)."""
    top = max((p.freq_hz for p in peaks), default=fs_hz / 8.0)
    return float(min(max(1.5 * top, 10.0 * resolution_hz), 0.45 * fs_hz))


def _fixed_mode_amplitudes(
    fixed: list[tuple[float, float]],
    cands: list[tuple[float, float, complex, float]],
    tau: np.ndarray,
    y: np.ndarray,
    plan: DecimationPlan,
) -> list[complex]:
    """Start complex amplitudes (at tau = 0, raw signal) of the held modes: linear least
    squares of ``y`` on the held and the pencil's modes plus an offset."""
    if not fixed:
        return []
    cols = [np.ones(tau.size)]
    for omega, zeta in [*fixed, *((c[0], min(max(c[1], 1e-4), 0.95)) for c in cands)]:
        s = mode_pole(omega, zeta)
        g = plan.response(s)[0] * np.exp(s * tau)
        cols += [g.real, -g.imag]
    coef = lstsq(np.column_stack(cols), y)[0]
    return [complex(coef[1 + 2 * k], coef[2 + 2 * k]) for k in range(len(fixed))]


def fit_free_decay(
    x: np.ndarray,
    fs_hz: float,
    *,
    tau0_s: float = 0.0,
    n_modes: int | None = None,
    f_max_hz: float | None = None,
    spectrum: Spectrum | None = None,
    zeta_max: float = 0.5,
    min_energy_snr: float = 50.0,
    known_modes: Sequence[tuple[float, float]] = (),
) -> DecayFit:
    """Fit a free decay ``x`` (uniformly sampled at ``fs_hz``; ``x[0]`` at ``tau0_s`` seconds
    after the start of the decay, to which amplitudes and phases refer).

    Every physical, significant mode that the matrix pencil finds below the filter's stop
    band is fitted (leaving one out would bias the others). ``n_modes``: at least this many
    modes are fitted; if the pencil finds fewer, start values are completed from FFT peaks.
    ``f_max_hz`` None: 1.5 x the highest significant FFT peak (of the ``n_modes`` lowest,
    if given). ``known_modes``: (omega_rad_s, damping_ratio) of modes identified in another
    record of the same structure; each one below the stop band that the pencil does not find
    here (none within ``KNOWN_MATCH_REL``) is added to the model with frequency and damping
    held, only amplitude and phase fitted, and is left out of ``modes`` (``fixed_modes``):
    a leftover too weak to be identified here would otherwise bias the modes that are.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or x.size < 32:
        raise ValueError(f"x must be a 1-D record of at least 32 samples, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x must be finite (no NaN or inf)")
    if n_modes is not None and (int(n_modes) != n_modes or n_modes < 1):
        raise ValueError(f"n_modes must be a positive integer or None, got {n_modes!r}")
    if not (np.isfinite(fs_hz) and fs_hz > 0):
        raise ValueError(f"fs_hz must be a positive finite number, got {fs_hz!r}")
    notes: list[str] = []
    dt = 1.0 / fs_hz
    spec = spectrum if spectrum is not None else amplitude_spectrum(x, fs_hz)
    peaks = find_spectral_peaks(spec, f_max_hz=f_max_hz)
    if f_max_hz is None:
        f_max_hz = auto_f_max_hz(peaks[:n_modes], fs_hz, spec.resolution_hz)
    plan = design_decimation(fs_hz, f_max_hz)
    y, idx = decimate_causal(x, plan)
    tau = tau0_s + idx * dt
    dt_dec = plan.factor * dt
    if y.size < 32:
        raise ValueError(
            f"only {y.size} samples remain after decimation; the record is too short for "
            f"f_max_hz = {f_max_hz:g} Hz"
        )

    pencil = matrix_pencil(y, dt_dec)
    if n_modes is not None and pencil.order < 2 * n_modes + 1:
        pencil = matrix_pencil(y, dt_dec, order=2 * n_modes + 1)
    cands = _physical_modes(
        pencil,
        y,
        dt_dec,
        f_stop_hz=plan.f_stop_hz,
        zeta_max=zeta_max,
        min_energy_snr=min_energy_snr,
    )
    if n_modes is not None:
        for pk in peaks:  # complete from FFT peaks not already matched
            if len(cands) >= n_modes:
                break
            if all(abs(pk.omega_rad_s - c[0]) > 2 * np.pi * 2 * spec.resolution_hz for c in cands):
                cands.append((pk.omega_rad_s, 0.02, complex(pk.amplitude), 0.0))
                notes.append(f"start value for the mode near {pk.freq_hz:.4g} Hz from the FFT")
        if len(cands) < n_modes:
            notes.append(f"asked for {n_modes} modes, found {len(cands)}")
    if not cands:
        raise ValueError("no physical mode found in the record (is it a free decay above noise?)")

    # Known modes (from another record) that the pencil did not find here: fitted with
    # frequency and damping held, amplitude and phase free (start values by linear LS).
    fixed: list[tuple[float, float]] = []
    for omega_k, zeta_k in known_modes:
        if not (omega_k > 0 and 0.0 <= zeta_k < 1.0):
            raise ValueError(f"known_modes: need omega > 0 and 0 <= zeta < 1, got "
                             f"({omega_k!r}, {zeta_k!r})")
        if omega_k >= 2.0 * np.pi * plan.f_stop_hz:
            continue  # the decimation filter removes it
        if any(abs(c[0] - omega_k) <= KNOWN_MATCH_REL * omega_k for c in cands):
            continue  # found here: fitted freely
        if any(abs(f[0] - omega_k) <= KNOWN_MATCH_REL * omega_k for f in fixed):
            continue
        fixed.append((float(omega_k), float(zeta_k)))
    fixed_amps = _fixed_mode_amplitudes(fixed, cands, tau, y, plan)

    # Start values: complex amplitudes refer to y[0]; move them to tau = 0, remove H(s).
    x0 = [float(np.median(y[-max(y.size // 5, 1) :]))]
    entries = [(c[0], c[1], c[2], False) for c in cands]
    entries += [(w, z, c, True) for (w, z), c in zip(fixed, fixed_amps, strict=True)]
    entries.sort(key=lambda m: m[0])
    is_fixed = [e[3] for e in entries]
    for omega, zeta, c, held in entries:
        zeta0 = zeta if held else min(max(zeta, 1e-4), zeta_max)
        s = mode_pole(omega, zeta0)
        h, _ = plan.response(s)
        c0 = c if held else c / (h * np.exp(s * tau[0]))
        x0 += [omega, zeta0, abs(c0), float(np.angle(c0))]
    x0_arr = np.asarray(x0)
    n_fit = (x0_arr.size - 1) // N_MODE_PARAMS
    free = np.ones(x0_arr.size, dtype=bool)
    for k, held in enumerate(is_fixed):
        if held:
            free[1 + N_MODE_PARAMS * k : 3 + N_MODE_PARAMS * k] = False  # omega, zeta
    w_hi = 2.0 * np.pi * plan.f_stop_hz
    lower = np.asarray([-np.inf] + [0.0, -0.2, -np.inf, -np.inf] * n_fit)[free]
    upper = np.asarray([np.inf] + [w_hi, 0.95, np.inf, np.inf] * n_fit)[free]
    template = x0_arr.copy()
    x0_free = np.clip(x0_arr[free], lower + 1e-9, upper - 1e-9)

    def full(pf: np.ndarray) -> np.ndarray:
        q = template.copy()
        q[free] = pf
        return q

    def residual(pf: np.ndarray) -> np.ndarray:
        return damped_sinusoid_sum(tau, full(pf), plan)[0] - y

    def jacobian(pf: np.ndarray) -> np.ndarray:
        return damped_sinusoid_sum(tau, full(pf), plan)[1][:, free]

    sol = least_squares(
        residual,
        x0_free,
        jac=jacobian,
        bounds=(lower, upper),
        method="trf",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-10,
        max_nfev=500,
    )
    p = full(sol.x)
    res = sol.fun
    cov_free, noise_rms = _sandwich_covariance(sol.jac, res, plan)
    cov = np.zeros((p.size, p.size))
    cov[np.ix_(free, free)] = cov_free

    # Normalise signs (A > 0, phase in (-pi, pi]) and sort by frequency.
    for k in range(n_fit):
        i = 1 + N_MODE_PARAMS * k
        if p[i + 2] < 0:
            p[i + 2] = -p[i + 2]
            p[i + 3] += np.pi
        p[i + 3] = float(np.angle(np.exp(1j * p[i + 3])))
    order = np.argsort([p[1 + N_MODE_PARAMS * k] for k in range(n_fit)])
    perm = [0] + [1 + N_MODE_PARAMS * int(k) + j for k in order for j in range(N_MODE_PARAMS)]
    p = p[perm]
    cov = cov[np.ix_(perm, perm)]
    is_fixed = [is_fixed[int(k)] for k in order]
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    modes = []
    fixed_modes = []
    for k in range(n_fit):
        i = 1 + N_MODE_PARAMS * k
        omega, zeta, amp, phase = p[i : i + N_MODE_PARAMS]
        mode = IdentifiedMode(
            omega_rad_s=float(omega),
            freq_hz=float(omega / (2.0 * np.pi)),
            damping_ratio=float(zeta),
            amplitude=float(amp),
            phase_rad=float(phase),
            sigma_omega_rad_s=float(sig[i]),
            sigma_damping=float(sig[i + 1]),
            sigma_amplitude=float(sig[i + 2]),
            sigma_phase_rad=float(sig[i + 3]),
        )
        if is_fixed[k]:
            fixed_modes.append(mode)
            continue
        modes.append(mode)
        if zeta <= 0.0:
            notes.append(f"mode at {omega:.4g} rad/s has non-positive damping {zeta:.3g}")
        if omega / (2.0 * np.pi) > f_max_hz:
            gain = abs(plan.response(1j * omega)[0])
            notes.append(
                f"mode at {omega:.4g} rad/s lies above f_max_hz = {f_max_hz:.4g} Hz, in the "
                f"decimation filter's transition band (gain {gain:.3g}, corrected)"
            )
    if fixed_modes:
        notes.append(
            "held at known frequency and damping (amplitude fitted): "
            + ", ".join(f"{m.omega_rad_s:.4g} rad/s ({m.amplitude:.2g} m/s^2)"
                        for m in fixed_modes))
    # covariance of the offset and the reported modes only
    keep = [0] + [1 + N_MODE_PARAMS * k + j for k in range(n_fit) if not is_fixed[k]
                  for j in range(N_MODE_PARAMS)]
    cov = cov[np.ix_(keep, keep)]
    raw_start = int(idx[0])
    tau_raw = tau0_s + np.arange(raw_start, x.size) * dt
    raw_res = x[raw_start:] - damped_sinusoid_sum(tau_raw, p)[0]
    if not sol.success:
        notes.append(f"least squares did not converge: {sol.message}")
    return DecayFit(
        modes=modes,
        offset=float(p[0]),
        sigma_offset=float(sig[0]),
        residual_rms=float(np.sqrt(np.mean(raw_res**2))),
        residual_rms_filtered=float(np.sqrt(np.mean(res**2))),
        noise_rms_estimate=noise_rms,
        spectrum=spec,
        spectral_peaks=peaks,
        decimation=plan,
        pencil=pencil,
        covariance=cov,
        f_max_hz=float(f_max_hz),
        n_fit_samples=int(y.size),
        fit_start_s=float(tau[0]),
        success=bool(sol.success),
        message=str(sol.message),
        notes=notes,
        fixed_modes=fixed_modes,
    )
