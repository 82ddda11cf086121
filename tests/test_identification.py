"""Tests of harness.identification on synthetic free decays with known modes."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from harness.identification import (
    DampedMode,
    amplitude_spectrum,
    cramer_rao_bound,
    damped_sinusoid_sum,
    decimate_causal,
    design_decimation,
    find_spectral_peaks,
    identify,
    matrix_pencil,
    read_accel_csv,
)

FS = 500.0
NOISE = 0.005  # m/s^2 rms
QUANT = 1e-3  # m/s^2


def synth(
    modes: list[DampedMode],
    *,
    duration_s: float = 60.0,
    noise: float = NOISE,
    quant: float | None = QUANT,
    offset: float = 0.0,
    t0: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Free decay starting at ``t0`` (zero before it), white noise, quantisation."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration_s * FS))) / FS
    tau = t - t0
    x = np.full(t.size, offset)
    for m in modes:
        wd = m.omega_rad_s * math.sqrt(1.0 - m.damping_ratio**2)
        term = (
            m.amplitude
            * np.exp(-m.damping_ratio * m.omega_rad_s * tau)
            * np.cos(wd * tau + m.phase_rad)
        )
        x += np.where(tau >= 0.0, term, 0.0)
    x = x + noise * rng.standard_normal(t.size)
    if quant is not None:
        x = np.round(x / quant) * quant
    return t, x


def nearest(result, omega: float):
    return min(result.modes, key=lambda m: abs(m.omega_rad_s - omega))


def assert_mode(result, true: DampedMode, *, freq_tol=0.005, zeta_tol=0.10, n_sigma=4.0):
    m = nearest(result, true.omega_rad_s)
    assert abs(m.omega_rad_s / true.omega_rad_s - 1.0) < freq_tol
    assert abs(m.damping_ratio / true.damping_ratio - 1.0) < zeta_tol
    # reported uncertainties consistent with the actual error
    assert abs(m.omega_rad_s - true.omega_rad_s) < n_sigma * m.sigma_omega_rad_s
    assert abs(m.damping_ratio - true.damping_ratio) < n_sigma * m.sigma_damping
    assert abs(m.amplitude - true.amplitude) < n_sigma * m.sigma_amplitude
    dphi = math.remainder(m.phase_rad - true.phase_rad, 2.0 * math.pi)
    assert abs(dphi) < n_sigma * m.sigma_phase_rad
    assert m.freq_hz == pytest.approx(m.omega_rad_s / (2.0 * math.pi))
    return m


RIG = [
    DampedMode(2.9, 0.05, 0.5, 0.3),
    DampedMode(13.5, 0.05, 0.3, 1.0),
    DampedMode(37.0, 0.05, 0.2, 2.0),
]


# ----------------------------------------------------------------------------- identify


def test_single_mode() -> None:
    true = DampedMode(2.9, 0.05, 0.5, 0.3)
    t, x = synth([true])
    res = identify(t, x)
    assert len(res.modes) == 1
    m = assert_mode(res, true, freq_tol=0.001, zeta_tol=0.02)
    assert m.omega_damped_rad_s == pytest.approx(2.9 * math.sqrt(1 - 0.05**2), rel=1e-3)
    assert res.fit.noise_rms_estimate == pytest.approx(NOISE, rel=0.15)


@pytest.mark.parametrize("zeta", [0.005, 0.02, 0.05])
def test_rig_modes_noisy_record(zeta: float) -> None:
    """The brief's acceptance case: 60 s at 500 Hz, noise 0.005, quantisation 1e-3."""
    modes = [DampedMode(m.omega_rad_s, zeta, m.amplitude, m.phase_rad) for m in RIG]
    t, x = synth(modes, offset=0.02, seed=3)
    res = identify(t, x)
    assert len(res.modes) == 3
    for true in modes[:2]:
        m = assert_mode(res, true)
        peak = res.matching_fft_peak(m)  # the paper's view sees modes 1 and 2 too
        assert peak is not None
        assert abs(peak.omega_rad_s / m.omega_damped_rad_s - 1.0) < 0.01
    assert_mode(res, modes[2], freq_tol=0.01, zeta_tol=0.2)
    assert res.fit.offset == pytest.approx(0.02, abs=4 * res.fit.sigma_offset + 1e-4)
    assert res.fit.residual_rms == pytest.approx(NOISE, rel=0.1)


@pytest.mark.parametrize("zeta", [0.005, 0.02])
def test_two_close_modes(zeta: float) -> None:
    """2.0 and 2.15 rad/s over 60 s: about 1.4 FFT resolutions apart."""
    modes = [DampedMode(2.0, zeta, 0.5, 0.3), DampedMode(2.15, zeta, 0.4, 1.0)]
    t, x = synth(modes, seed=4)
    res = identify(t, x)
    assert len(res.modes) == 2
    for true in modes:
        assert_mode(res, true)


def test_forced_start_is_skipped_and_phase_refers_to_start() -> None:
    t, x = synth(RIG, duration_s=70.0, t0=10.0, seed=5)
    rng = np.random.default_rng(6)
    before = t < 10.0
    x[before] = 0.4 * np.sin(1.3 * t[before]) + NOISE * rng.standard_normal(before.sum())
    res = identify(t, x, start_s=10.0)
    assert res.start_s == 10.0
    assert res.fit_start_s > 10.0  # the decimation filter's start transient is dropped
    for true in RIG[:2]:
        assert_mode(res, true)


def test_start_between_samples() -> None:
    true = DampedMode(2.9, 0.05, 0.5, 0.3)
    t, x = synth([true], duration_s=61.0, t0=1.0011, seed=7)
    res = identify(t, x, start_s=1.0011)
    assert_mode(res, true)


def test_clipped_start_is_dropped() -> None:
    modes = [DampedMode(2.9, 0.05, 30.0, 0.3), DampedMode(13.5, 0.05, 3.0, 1.0)]
    t, x = synth(modes, seed=8)
    x = np.clip(x, -19.6, 19.6)
    res = identify(t, x)
    assert res.n_clipped > 0
    assert any("clipped" in n for n in res.notes)
    assert res.fit_start_s > t[np.flatnonzero(np.abs(x) >= 19.6)[-1]]
    for true in modes:
        assert_mode(res, true)
    with pytest.raises(ValueError, match="clip_level_m_s2"):
        identify(t, x, clip_level_m_s2=-1.0)


def test_n_modes_reports_lowest_and_fits_the_rest() -> None:
    modes = [DampedMode(m.omega_rad_s, 0.02, m.amplitude, m.phase_rad) for m in RIG]
    t, x = synth(modes, seed=9)
    res = identify(t, x, n_modes=2)
    assert len(res.modes) == 2
    for true in modes[:2]:
        assert_mode(res, true)
    others = res.to_dict()["fit"]["other_fitted_modes"]
    assert len(others) == 1
    assert others[0]["omega_rad_s"] == pytest.approx(37.0, rel=0.01)


def test_explicit_f_max() -> None:
    t, x = synth(RIG[:2], seed=10)
    res = identify(t, x, f_max_hz=3.0)
    assert res.fit.f_max_hz == 3.0
    assert res.fit.decimation.factor == int(FS // (16 * 3.0))
    for true in RIG[:2]:
        assert_mode(res, true)


def test_to_dict_is_json_ready() -> None:
    t, x = synth(RIG[:2], seed=11)
    d = json.loads(json.dumps(identify(t, x).to_dict()))
    assert {
        "omega_rad_s",
        "freq_hz",
        "damping_ratio",
        "amplitude_m_s2",
        "sigma_omega_rad_s",
        "sigma_damping",
        "sigma_amplitude_m_s2",
    } <= set(d["modes"][0])
    assert d["modes"][0]["omega_rad_s"] == pytest.approx(2.9, rel=0.005)
    assert d["fft"]["peaks"][0]["damping_ratio_half_power_rough"] is not None
    assert d["fit"]["dropped_filter_transient_s"] > 0


def test_pure_noise_has_no_modes() -> None:
    t, x = synth([], seed=12)
    with pytest.raises(ValueError, match="no physical mode"):
        identify(t, x, f_max_hz=5.0)


def test_identify_input_errors() -> None:
    t, x = synth(RIG[:1], duration_s=5.0)
    with pytest.raises(ValueError, match="equal length"):
        identify(t, x[:-1])
    t_bad = t.copy()
    t_bad[100] = t_bad[99]
    with pytest.raises(ValueError, match=r"t must be strictly increasing: t\[100\]"):
        identify(t_bad, x)
    t_gap = t.copy()
    t_gap[200:] += 0.5 / FS
    with pytest.raises(ValueError, match="uniformly sampled"):
        identify(t_gap, x)
    x_nan = x.copy()
    x_nan[7] = np.nan
    with pytest.raises(ValueError, match=r"accel\[7\]"):
        identify(t, x_nan)
    with pytest.raises(ValueError, match="start_s"):
        identify(t, x, start_s=t[-1] + 1.0)
    with pytest.raises(ValueError, match="f_max_hz"):
        identify(t, x, f_max_hz=-1.0)
    with pytest.raises(ValueError, match="n_modes"):
        identify(t, x, n_modes=0)


def test_uncertainty_matches_spread_small_monte_carlo() -> None:
    """Reported sigma ~ actual spread ~ Cramer-Rao bound (10 records, single mode)."""
    true = DampedMode(13.5, 0.02, 0.3, 1.0)
    est, sig = [], []
    for seed in range(10):
        t, x = synth([true], duration_s=30.0, seed=100 + seed)
        m = identify(t, x).modes[0]
        est.append(m.omega_rad_s)
        sig.append(m.sigma_omega_rad_s)
    bound = cramer_rao_bound([true], fs_hz=FS, n_samples=t.size, noise_rms=NOISE)
    crlb = bound.modes[0].sigma_omega_rad_s
    spread = float(np.std(est, ddof=1))
    assert 0.4 < spread / crlb < 2.0
    assert 0.8 < float(np.mean(sig)) / crlb < 1.5


@pytest.mark.slow
def test_uncertainty_matches_spread_rig_monte_carlo() -> None:
    modes = RIG
    errs = {k: [] for k in range(2)}
    for seed in range(30):
        t, x = synth(modes, seed=200 + seed)
        res = identify(t, x)
        for k in range(2):
            m = nearest(res, modes[k].omega_rad_s)
            errs[k].append((m.damping_ratio - modes[k].damping_ratio) / m.sigma_damping)
    for k in range(2):
        z = np.asarray(errs[k])
        assert 0.6 < float(np.std(z)) < 1.5  # normalised errors ~ N(0, 1)
        assert abs(float(np.mean(z))) < 0.6


# ----------------------------------------------------------------------------- spectrum


def _sine(freq_hz: float, amp: float, n: int = 30000) -> np.ndarray:
    t = np.arange(n) / FS
    rng = np.random.default_rng(1)
    return amp * np.cos(2 * np.pi * freq_hz * t + 0.3) + 0.01 * rng.standard_normal(n)


@pytest.mark.parametrize(
    ("window", "pad", "interp", "tol_hz"),
    [
        ("rect", 1, "quinn", 1e-5),
        ("rect", 8, "parabolic", 2e-4),
        ("hann", 8, "parabolic", 1e-4),
        ("exponential", 8, "parabolic", 2e-4),
    ],
)
def test_spectral_peak_interpolation(window: str, pad: int, interp: str, tol_hz: float) -> None:
    f0 = 1.2345  # between FFT bins (resolution 1/60 Hz)
    spec = amplitude_spectrum(_sine(f0, 0.7), FS, window=window, pad_factor=pad)
    peaks = find_spectral_peaks(spec, interpolation=interp)
    assert len(peaks) == 1  # no window sidelobe is taken for a peak
    assert abs(peaks[0].freq_hz - f0) < tol_hz
    assert peaks[0].omega_rad_s == pytest.approx(2 * math.pi * peaks[0].freq_hz)
    if window != "exponential":
        assert peaks[0].amplitude == pytest.approx(0.7, rel=0.02)


def test_quinn_needs_unpadded_rect_spectrum() -> None:
    spec = amplitude_spectrum(_sine(1.0, 1.0), FS, window="hann", pad_factor=8)
    with pytest.raises(ValueError, match="quinn"):
        find_spectral_peaks(spec, interpolation="quinn")


def test_half_power_damping_is_a_rough_estimate() -> None:
    for zeta in (0.01, 0.05):
        _, x = synth([DampedMode(13.5, zeta, 0.5, 0.0)], seed=2)
        peaks = find_spectral_peaks(amplitude_spectrum(x, FS))
        assert len(peaks) == 1
        assert peaks[0].damping_ratio_half_power_rough == pytest.approx(zeta, rel=0.2)


def test_spectrum_input_errors() -> None:
    with pytest.raises(ValueError, match="window"):
        amplitude_spectrum(np.ones(100), FS, window="blackman-ish")
    with pytest.raises(ValueError, match="pad_factor"):
        amplitude_spectrum(np.ones(100), FS, pad_factor=0)
    with pytest.raises(ValueError, match="fs_hz"):
        amplitude_spectrum(np.ones(100), -1.0)


# ----------------------------------------------------------------------------- decay fit


def test_fir_passes_damped_sinusoid_as_h_of_s() -> None:
    """After the dropped start, the causal FIR output equals the model with H(s)."""
    params = np.array([0.01, 2.9, 0.05, 0.5, 0.3, 13.5, 0.05, 0.3, 1.0])
    t = np.arange(6000) / FS
    x, _ = damped_sinusoid_sum(t, params)
    plan = design_decimation(FS, 3.0)
    y, idx = decimate_causal(x, plan)
    assert idx[0] == plan.taps.size - 1
    model, _ = damped_sinusoid_sum(t[idx], params, plan)
    assert np.max(np.abs(y - model)) < 1e-12


def test_decimation_filter_design() -> None:
    plan = design_decimation(FS, 3.0)
    assert plan.fs_out_hz >= 16 * 3.0
    passband = [abs(plan.response(2j * np.pi * f)[0]) for f in np.linspace(0.0, 3.0, 50)]
    assert max(abs(g - 1.0) for g in passband) < 2e-3  # flat pass band
    stop = [abs(plan.response(2j * np.pi * f)[0]) for f in np.linspace(plan.f_stop_hz, 250, 400)]
    assert max(stop) < 10 ** (-55 / 20)
    with pytest.raises(ValueError, match="f_max_hz"):
        design_decimation(FS, 300.0)


def test_jacobian_matches_finite_differences() -> None:
    params = np.array([0.01, 2.9, 0.05, 0.5, 0.3, 13.5, 0.02, 0.3, 1.0])
    tau = np.arange(0.3, 20.0, 0.02)
    plan = design_decimation(FS, 3.0)
    _, jac = damped_sinusoid_sum(tau, params, plan)
    for i in range(params.size):
        step = 1e-6 * max(abs(params[i]), 1e-3)
        hi, lo = params.copy(), params.copy()
        hi[i] += step
        lo[i] -= step
        num = (damped_sinusoid_sum(tau, hi, plan)[0] - damped_sinusoid_sum(tau, lo, plan)[0]) / (
            2 * step
        )
        assert np.allclose(jac[:, i], num, rtol=1e-5, atol=1e-7 * np.max(np.abs(num)) + 1e-12)


def test_matrix_pencil_noise_free_poles() -> None:
    dt = 0.05
    params = np.array([0.0, 2.9, 0.05, 0.5, 0.3, 13.5, 0.02, 0.3, 1.0])
    y, _ = damped_sinusoid_sum(np.arange(600) * dt, params)
    res = matrix_pencil(y, dt, order=4)
    upper = sorted((s for s in res.poles if s.imag > 0), key=lambda s: s.imag)
    for s, (w, z) in zip(upper, [(2.9, 0.05), (13.5, 0.02)], strict=True):
        assert abs(s) == pytest.approx(w, rel=1e-8)
        assert -s.real / abs(s) == pytest.approx(z, rel=1e-6)


# ----------------------------------------------------------------------------- Cramer-Rao


def test_crlb_frequency_matches_kay_for_undamped_sinusoid() -> None:
    """Kay: var(omega) >= 24 sigma^2 / (A^2 N (N^2 - 1)) (rad/sample)^2, for a real
    sinusoid; the unknown damping and offset are nearly orthogonal to omega at zeta = 0."""
    fs, n, amp, sigma = 100.0, 3000, 0.5, 0.01
    b = cramer_rao_bound(
        [DampedMode(2 * math.pi * 1.37, 0.0, amp, 0.4)], fs_hz=fs, n_samples=n, noise_rms=sigma
    )
    kay = math.sqrt(24 * sigma**2 / (amp**2 * n * (n**2 - 1))) * fs
    assert b.modes[0].sigma_omega_rad_s == pytest.approx(kay, rel=0.02)


def test_crlb_scales_with_noise_and_validates() -> None:
    modes = RIG[:2]
    b1 = cramer_rao_bound(modes, fs_hz=FS, n_samples=30000, noise_rms=0.005)
    b2 = cramer_rao_bound(modes, fs_hz=FS, n_samples=30000, noise_rms=0.010)
    for m1, m2 in zip(b1.modes, b2.modes, strict=True):
        assert m2.sigma_damping == pytest.approx(2 * m1.sigma_damping)
        assert m2.sigma_omega_rad_s == pytest.approx(2 * m1.sigma_omega_rad_s)
    with pytest.raises(ValueError, match="noise_rms"):
        cramer_rao_bound(modes, fs_hz=FS, n_samples=100, noise_rms=0.0)
    with pytest.raises(ValueError, match="damping_ratio"):
        cramer_rao_bound([DampedMode(1.0, 1.5, 1.0)], fs_hz=FS, n_samples=100, noise_rms=1.0)


# ----------------------------------------------------------------------------- CSV input


def _csv(rows: list[str]) -> io.StringIO:
    return io.StringIO("\n".join(rows) + "\n")


def test_csv_with_and_without_header() -> None:
    rows = [f"{i / FS:.6f},{math.sin(i / 10):.6f}" for i in range(50)]
    rec = read_accel_csv(_csv(rows))
    assert rec.t.size == 50 and rec.column_names is None
    assert rec.accel[10] == pytest.approx(math.sin(1.0), abs=1e-6)
    rec = read_accel_csv(
        _csv(
            ["# tip accelerometer", "time_s;x;accel_m_s2"] + [r.replace(",", ";0;") for r in rows]
        ),
        accel_column="accel_m_s2",
    )
    assert rec.column_names == ("time_s", "accel_m_s2")
    assert rec.accel[10] == pytest.approx(math.sin(1.0), abs=1e-6)
    rec = read_accel_csv(_csv([r.replace(",", "  ") for r in rows]))
    assert rec.t[-1] == pytest.approx(49 / FS)


def test_csv_round_trip_through_identify(tmp_path) -> None:
    t, x = synth(RIG[:2], seed=13)
    path = tmp_path / "decay.csv"
    np.savetxt(
        path,
        np.column_stack([t, x]),
        delimiter=",",
        header="t_s,accel_m_s2",
        comments="",
        fmt="%.6f",
    )
    rec = read_accel_csv(path)
    res = identify(rec.t, rec.accel)
    for true in RIG[:2]:
        assert_mode(res, true)


@pytest.mark.parametrize(
    ("rows", "kwargs", "match"),
    [
        (["t,a", "0.000,1", "0.002,abc", "0.004,1"], {}, r"line 3, column 2 \(acceleration"),
        (["0.000,1", "0.002,nan"], {}, r"line 2, column 2.*not finite"),
        (["0.000,1", "0.002,1", "0.001,1"], {}, r"line 3, column 1 \(time\).*strictly"),
        (["0.000,1", "0.002,1", "0.004,1", "0.009,1", "0.011,1"], {}, r"line 4.*uniformly"),
        (["0.000,1", "0.002"], {}, r"line 2 has 1 column"),
        (["# only a comment"], {}, "no data lines"),
        (["0.000,1"], {}, "at least 2 data lines"),
        (["0.000,1", "0.002,1"], {"accel_column": "acc"}, "no header"),
        (["t,a", "0.000,1", "0.002,1"], {"accel_column": "acc"}, "not in the header"),
    ],
)
def test_csv_errors_name_line_and_column(rows: list[str], kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        read_accel_csv(_csv(rows), **kwargs)
