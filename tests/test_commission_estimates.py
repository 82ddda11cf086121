"""The commissioning estimators (harness/commissioning/estimates.py) on synthetic data with
a known truth: each recovers it within 3 sigma, and its sigma is the spread it shows over
noise draws (within the spread's own sampling error), not a number that only looks
small."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.commissioning import estimates as est

DT = 0.002


def _spread_ok(values: list[float], sigmas: list[float]) -> None:
    """The observed spread over draws against the mean sigma: within a factor the
    sampling error of a spread over len(values) draws allows (and not 3x too large or
    too small, which a missing correlation or a wrong formula gives)."""
    spread = float(np.std(values, ddof=1))
    mean_sigma = float(np.mean(sigmas))
    assert 0.5 < spread / mean_sigma < 1.8, (spread, mean_sigma)


def test_mean_estimate_white_and_correlated_noise():
    means, sigmas = [], []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        white = rng.standard_normal(2000)
        # AR(1), correlation 0.9: 19x the variance of a white mean
        ar = np.empty(2000)
        ar[0] = white[0]
        for i in range(1, 2000):
            ar[i] = 0.9 * ar[i - 1] + math.sqrt(1 - 0.81) * white[i]
        e = est.mean_estimate(0.5 + 0.01 * ar)
        means.append(e.value)
        sigmas.append(e.sigma)
        assert abs(e.value - 0.5) < 4 * e.sigma
    _spread_ok(means, sigmas)
    # a white-noise sigma would be sqrt(19) x smaller: the blocks see the correlation
    assert np.mean(sigmas) > 3 * 0.01 / math.sqrt(2000)


def test_mean_of_a_reading_that_never_moves_knows_no_more_than_its_step():
    e = est.mean_estimate(np.full(1000, 0.02), resolution=0.02)
    assert e.value == pytest.approx(0.02)
    assert e.sigma >= 0.99 * 0.02 / math.sqrt(12) / math.sqrt(40)


def _coast(w0: float, c: float, v: float, j: float, t: np.ndarray) -> np.ndarray:
    """J dw/dt = -(c sign(w) + v w): w(t) = (w0 + s c/v) e^(-v t / J) - s c/v, to rest."""
    s = math.copysign(1.0, w0)
    w = (w0 + s * c / v) * np.exp(-v * t / j) - s * c / v
    return np.where(np.sign(w) == s, w, 0.0)


def test_coast_down_friction_recovers_coulomb_and_viscous():
    j, c, v = 0.0016, 6e-4, 1e-5
    t = np.arange(0, 8.0, DT)
    cs, vs, sc, sv = [], [], [], []
    for seed in range(25):
        rng = np.random.default_rng(seed)
        w = np.concatenate((_coast(-60.0, c, v, j, t[:2000]), _coast(30.0, c, v, j,
                                                                      t[2000:] - t[2000])))
        w = np.round((w + 0.005 * rng.standard_normal(w.size)) / 0.02) * 0.02
        fr = est.coast_down_friction(t, w, [(0.0, 4.0), (4.0, 8.0)], j, 0.1, 0.02)
        assert abs(fr.coulomb_n_m.value - c) < 3 * fr.coulomb_n_m.sigma
        assert abs(fr.viscous_n_m_s.value - v) < 3 * fr.viscous_n_m_s.sigma
        cs.append(fr.coulomb_n_m.value)
        vs.append(fr.viscous_n_m_s.value)
        sc.append(fr.coulomb_n_m.sigma)
        sv.append(fr.viscous_n_m_s.sigma)
    _spread_ok(cs, sc)
    _spread_ok(vs, sv)
    assert fr.torque_at(60.0).value == pytest.approx(c + 60 * v, rel=0.05)


def test_coast_down_stops_where_the_wheel_stops():
    """A window whose wheel comes to rest: the samples at rest are not fitted (friction
    never reverses a wheel)."""
    j, c = 0.0016, 6e-4
    t = np.arange(0, 6.0, DT)
    w = np.round(_coast(2.0, c, 1e-9, j, t) / 0.001) * 0.001  # stops after 5.3 s
    fr = est.coast_down_friction(t, w, [(0.0, 6.0)], j, 0.05, 0.001)
    assert fr.coulomb_n_m.value == pytest.approx(c, rel=0.01)
    assert fr.speed_range_rad_s[0] > 0.05


def test_first_order_lag_recovers_lag_gain_and_dead_ticks():
    u = np.zeros(3000)
    u[100:350] = 0.016
    u[900:1150] = -0.016
    u[1500:1800] = 0.03
    lags, sigmas = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        y = 0.97 * est.lag_response(u, 0.012, DT, 1)
        y = np.round((y + 1e-5 * rng.standard_normal(u.size)) / 1e-5) * 1e-5
        lag = est.first_order_lag(u, y, DT, resolution=1e-5)
        assert lag.dead_ticks == 1
        assert abs(lag.lag_s.value - 0.012) < 3 * lag.lag_s.sigma
        assert abs(lag.gain.value - 0.97) < 3 * lag.gain.sigma
        lags.append(lag.lag_s.value)
        sigmas.append(lag.lag_s.sigma)
    _spread_ok(lags, sigmas)


def test_ring_down_modes_recover_frequency_and_damping():
    t = np.arange(0, 15.0, DT)
    truth = [(2.76, 0.012, 0.04), (13.6, 0.012, 0.005)]
    x = sum(a * np.exp(-z * w * t) * np.cos(w * math.sqrt(1 - z * z) * t + 0.3)
            for w, z, a in truth)
    ws, sw = [], []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        modes, _ = est.ring_down_modes(t, x + 0.005 * rng.standard_normal(t.size), 0.0, 15.0)
        assert len(modes) == 2
        for m, (w, z, _) in zip(modes, truth, strict=True):
            assert abs(m.omega_rad_s.value - w) < 3 * m.omega_rad_s.sigma
            assert abs(m.damping_ratio.value - z) < 3 * m.damping_ratio.sigma
        ws.append(modes[0].omega_rad_s.value)
        sw.append(modes[0].omega_rad_s.sigma)
    _spread_ok(ws, sw)


def test_a_record_that_does_not_ring_gives_no_mode():
    t = np.arange(0, 10.0, DT)
    with pytest.raises(est.EstimateError):
        est.ring_down_modes(t, np.zeros(t.size), 0.0, 10.0)


def test_modes_of_several_readings_combine_and_disagreeing_ones_widen():
    a = est.Mode(est.Estimate(2.76, 0.001), est.Estimate(0.012, 1e-4), 0.04)
    b = est.Mode(est.Estimate(2.7605, 0.0005), est.Estimate(0.0121, 1e-4), 3e-3)
    spurious = est.Mode(est.Estimate(2.3, 0.05), est.Estimate(0.18, 0.02), 1e-3)
    m2 = est.Mode(est.Estimate(13.6, 0.01), est.Estimate(0.012, 1e-3), 0.005)
    out, notes = est.combine_modes([("accel", [spurious, a, m2]), ("rate", [b])],
                                   [2.88, 13.3, 37.0])
    assert out[2] is None and out[1] is not None and out[1].omega_rad_s.value == 13.6
    w = out[0].omega_rad_s
    assert w.value == pytest.approx((2.76 / 1e-6 + 2.7605 / 0.25e-6) / (1 / 1e-6 + 1 / 0.25e-6))
    assert w.sigma == pytest.approx(1 / math.sqrt(1 / 1e-6 + 1 / 0.25e-6))
    far = est.Mode(est.Estimate(2.78, 0.0005), est.Estimate(0.012, 1e-4), 3e-3)
    out2, notes2 = est.combine_modes([("accel", [a]), ("rate", [far])], [2.88, 13.3])
    assert out2[0].omega_rad_s.sigma > 10 * w.sigma and notes2 and not notes


def test_constrained_modes_invert_the_models_map():
    """A model whose hub-free frequency is 1.05 x the constrained one times the factor and
    whose damping is 1.37 x: the factor and damping that reproduce the measured modes."""
    base = np.array([2.7, 13.5, 37.0])

    def hub_free(f, z):
        return 1.05 * base * np.asarray(f), 1.37 * np.asarray(z)

    measured = [est.Mode(est.Estimate(1.05 * 2.7 * 0.975, 1e-3), est.Estimate(1.37 * 0.012,
                                                                                1e-4), 1.0),
                est.Mode(est.Estimate(1.05 * 13.5 * 1.022, 1e-2), est.Estimate(1.37 * 0.013,
                                                                                1e-3), 0.1)]
    inv = est.constrained_modes(measured, hub_free, [1.0, 1.0, 1.0], [0.05] * 3)
    assert inv.factors[0].value == pytest.approx(0.975, rel=1e-9)
    assert inv.factors[1].value == pytest.approx(1.022, rel=1e-9)
    assert inv.dampings[0].value == pytest.approx(0.012, rel=1e-9)
    assert inv.factors[2] is None and inv.matched == [0, 1, None]
    assert inv.factors[0].sigma == pytest.approx(1e-3 / (1.05 * 2.7), rel=1e-3)
    assert inv.dampings[1].sigma == pytest.approx(1e-3 / 1.37, rel=1e-3)


def _hub(t, segments, j, j_r, w, steps, impulses, beam_modes, rng):
    """The hub rate of a rig that keeps H = J rate + J_r w + beam, H changed by each step's
    impulse; a beam free decay after each segment start; the sensor's noise and bias."""
    h = sum(i * (t > s) for s, i in zip(steps, impulses, strict=True))
    rate = (h - j_r * w) / j + 3e-5 + 2e-5 * rng.standard_normal(t.size)
    for seg in (s for s in segments if s.excited):
        tau = t - seg.start_s
        on = (tau >= 0) & (tau < seg.end_s - seg.start_s)
        for k, (om, z) in enumerate(beam_modes):
            wd = om * math.sqrt(1 - z * z)
            a = 2e-4 / (k + 1) * np.exp(-z * om * tau) * np.cos(wd * tau + k)
            rate = rate + np.where(on, a, 0.0)
    return rate


def test_momentum_exchange_recovers_inertia_and_impulses():
    t = np.arange(0, 20.0, DT)
    j, j_r = 15.6, 0.0016
    w = np.where(t < 1.5, 0.0, np.where(t < 6.5, -5.0 + 0.3 * (t - 1.5), 0.0))
    w = np.where((t >= 6.5) & (t < 10.5), 1.6 - 0.3 * (t - 6.5), w)
    segs = [est.Segment(0.5, 1.0, False), est.Segment(1.6, 6.0, True),
            est.Segment(6.6, 10.0, True), est.Segment(11.0, 13.0, True),
            est.Segment(13.5, 20.0, True)]
    modes = [(2.76, 0.016), (13.6, 0.012)]
    js, sj, imps, si = [], [], [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        rate = _hub(t, segs, j, j_r, w, [10.5, 13.2], [0.019, -0.0188], modes, rng)
        mom = est.momentum_exchange(t, rate, w, j_r, segs, [10.5, 13.2], modes, 1e-7)
        assert abs(mom.inertia_kg_m2.value - j) < 3 * mom.inertia_kg_m2.sigma
        for e, truth in zip(mom.impulses_n_m_s, (0.019, -0.0188), strict=True):
            assert abs(e.value - truth) < 3 * e.sigma
        js.append(mom.inertia_kg_m2.value)
        sj.append(mom.inertia_kg_m2.sigma)
        imps.append(mom.impulses_n_m_s[0].value)
        si.append(mom.impulses_n_m_s[0].sigma)
    _spread_ok(js, sj)
    _spread_ok(imps, si)
    # without the wheel: the rate's steps only
    mom = est.momentum_exchange(t, rate, None, j_r, segs[3:], [13.2], modes)
    assert mom.inertia_kg_m2 is None
    assert mom.rate_steps_rad_s[0].value == pytest.approx(-0.0188 / j, rel=0.02)


def test_a_hub_that_ignores_the_wheel_gives_no_inertia():
    t = np.arange(0, 10.0, DT)
    w = np.where(t < 2, 0.0, -5.0)
    rate = np.full(t.size, 1e-5)
    with pytest.raises(est.EstimateError):
        est.momentum_exchange(t, rate, w, 0.0016, [est.Segment(0.5, 1.9, False),
                                                   est.Segment(2.1, 10, False)], [], [], 1e-7)


def test_readback_delay_is_the_interval_its_period_allows():
    t = np.arange(0, 1.0, DT)
    state = np.zeros(t.size)
    # the valve opens 6 ms after the command at 0.1 s; the read-back answers every 10 ms
    opened = t >= 0.106
    sample_times = t[::5]
    shown = np.zeros(t.size)
    for k, ts in enumerate(t):
        last = sample_times[sample_times <= ts + 1e-12][-1]
        shown[k] = 1.0 if last >= 0.106 - 1e-12 else 0.0
    state = np.where(opened, shown, 0.0)
    d = est.readback_delay(t, state, 0.1, 1.0, 0.010, 0.5)
    lo, hi = d.value - d.sigma * math.sqrt(3), d.value + d.sigma * math.sqrt(3)
    assert lo <= 0.006 <= hi and hi - lo == pytest.approx(0.010)
    assert est.readback_delay(t, state, 0.1, -1.0, 0.010, 0.5) is None
