"""Impulse shapers: closed forms, residual vibration against direct simulation, sensitivity."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from harness.shaping.impulse_shapers import (
    ImpulseSequence,
    ShapedCommand,
    convolve,
    damped_period,
    ei,
    multi_mode,
    residual_vibration,
    sensitivity_curve,
    shape_command,
    zv,
    zvd,
    zvdd,
)


def _k(zeta: float) -> float:
    return math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))


# ----------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.1, 0.3])
def test_zvd_closed_form(zeta: float) -> None:
    omega = 2.7
    seq = zvd(omega, zeta)
    k = _k(zeta)
    period = 2 * math.pi / (omega * math.sqrt(1 - zeta**2))
    np.testing.assert_allclose(seq.amplitudes, np.array([1, 2 * k, k * k]) / (1 + k) ** 2)
    np.testing.assert_allclose(seq.times_s, [0.0, period / 2, period])
    assert residual_vibration(seq, omega, zeta) == pytest.approx(0.0, abs=1e-10)


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.2])
def test_zv_and_zvdd_closed_forms(zeta: float) -> None:
    omega = 1.3
    k = _k(zeta)
    period = damped_period(omega, zeta)
    s_zv = zv(omega, zeta)
    np.testing.assert_allclose(s_zv.amplitudes, [1 / (1 + k), k / (1 + k)])
    np.testing.assert_allclose(s_zv.times_s, [0.0, period / 2])
    s_zvdd = zvdd(omega, zeta)
    expected = np.array([1, 3 * k, 3 * k**2, k**3]) / (1 + k) ** 3
    np.testing.assert_allclose(s_zvdd.amplitudes, expected)
    for seq in (s_zv, s_zvdd):
        assert seq.total == pytest.approx(1.0)
        assert residual_vibration(seq, omega, zeta) == pytest.approx(0.0, abs=1e-10)


def test_undamped_sensitivity_matches_textbook_curves() -> None:
    """Undamped: V_ZV(r) = |cos(pi r / 2)|, V_ZVD = cos^2, V_ZVDD = |cos|^3 (percent)."""
    ratios = np.linspace(0.5, 1.5, 41)
    c = np.abs(np.cos(np.pi * ratios / 2))
    np.testing.assert_allclose(sensitivity_curve(zv(2.0), 2.0, 0.0, ratios), 100 * c, atol=1e-9)
    np.testing.assert_allclose(sensitivity_curve(zvd(2.0), 2.0, 0.0, ratios), 100 * c**2, atol=1e-9)
    np.testing.assert_allclose(
        sensitivity_curve(zvdd(2.0), 2.0, 0.0, ratios), 100 * c**3, atol=1e-9
    )


@pytest.mark.parametrize("zeta", [0.0, 0.03, 0.1])
@pytest.mark.parametrize("v_tol", [0.02, 0.05, 0.1])
def test_ei_vibration_at_design_equals_tolerance(zeta: float, v_tol: float) -> None:
    omega = 3.0
    seq = ei(omega, zeta, v_tol)
    assert seq.total == pytest.approx(1.0)
    assert residual_vibration(seq, omega, zeta) == pytest.approx(100 * v_tol, rel=1e-8)
    # a hump: the design frequency is a local maximum of V ...
    v_near = residual_vibration(seq, omega * np.array([0.99, 1.01]), zeta)
    assert np.all(v_near < 100 * v_tol)
    # ... between two zeros
    below = residual_vibration(seq, omega * np.linspace(0.6, 1.0, 4001), zeta)
    above = residual_vibration(seq, omega * np.linspace(1.0, 1.4, 4001), zeta)
    assert below.min() < 1e-2 and above.min() < 1e-2


def test_ei_undamped_closed_form_and_wider_than_zvd() -> None:
    v = 0.05
    seq = ei(1.0, 0.0, v)
    np.testing.assert_allclose(seq.amplitudes, [(1 + v) / 4, (1 - v) / 2, (1 + v) / 4])
    # the band where V <= 5 % is wider for EI than for ZVD
    ratios = np.linspace(0.5, 1.5, 2001)
    width_ei = np.ptp(ratios[sensitivity_curve(seq, 1.0, 0.0, ratios) <= 5.0 + 1e-9])
    width_zvd = np.ptp(ratios[sensitivity_curve(zvd(1.0), 1.0, 0.0, ratios) <= 5.0])
    assert width_ei > 1.3 * width_zvd


def test_multi_mode_convolution_zero_at_both_modes() -> None:
    w1, w2, z1, z2 = 1.2, 7.5, 0.02, 0.05
    seq = multi_mode([zvd(w1, z1), zv(w2, z2)])
    assert len(seq) == 6
    assert seq.total == pytest.approx(1.0)
    assert residual_vibration(seq, w1, z1) == pytest.approx(0.0, abs=1e-9)
    assert residual_vibration(seq, w2, z2) == pytest.approx(0.0, abs=1e-9)
    # a mode between them is not cancelled
    assert residual_vibration(seq, 3.0, 0.0) > 1.0


def test_convolution_merges_coincident_impulses() -> None:
    """ZV * ZV (same undamped mode) is ZVD: [1, 2, 1] / 4 at 0, T/2, T."""
    seq = convolve(zv(2.0), zv(2.0))
    ref = zvd(2.0)
    np.testing.assert_allclose(seq.times_s, ref.times_s)
    np.testing.assert_allclose(seq.amplitudes, ref.amplitudes)


@settings(max_examples=40, deadline=None)
@given(
    omega=st.floats(0.05, 200.0),
    zeta=st.floats(0.0, 0.6),
)
def test_zero_vibration_at_design_property(omega: float, zeta: float) -> None:
    for seq in (zv(omega, zeta), zvd(omega, zeta), zvdd(omega, zeta)):
        assert abs(seq.total - 1.0) < 1e-12
        assert residual_vibration(seq, omega, zeta) < 1e-8


# -------------------------------------------------------------------- direct simulation


def _simulated_ratio(seq: ImpulseSequence, omega: float, zeta: float) -> float:
    """Residual amplitude of a damped oscillator under the shaped step, over the unshaped one.

    x'' + 2 zeta w x' + w^2 x = w^2 u(t), u the shaped unit step (piecewise constant); the
    amplitude measure sqrt(y^2 + ((y' + zeta w y)/w_d)^2) of y = x - 1 is exact for a free
    damped oscillation; for an unshaped unit step applied at t_N (the reference of the
    standard V) it is exp(-zeta w (t - t_N)) sqrt(1 + r^2) with r = zeta / sqrt(1 - zeta^2).
    """
    wd = omega * math.sqrt(1 - zeta**2)
    t_end = seq.duration_s + 0.37
    edges = np.concatenate([seq.times_s, [t_end]])
    state = np.zeros(2)
    level = 0.0
    for i in range(len(seq)):
        level += seq.amplitudes[i]
        if edges[i + 1] <= edges[i]:
            continue

        def rhs(_t: float, x: np.ndarray, u: float = level) -> list[float]:
            return [x[1], omega**2 * (u - x[0]) - 2 * zeta * omega * x[1]]

        sol = solve_ivp(rhs, (edges[i], edges[i + 1]), state, rtol=1e-11, atol=1e-13)
        state = sol.y[:, -1]
    y, dy = state[0] - 1.0, state[1]
    shaped = math.hypot(y, (dy + zeta * omega * y) / wd)
    r = zeta / math.sqrt(1 - zeta**2)
    unshaped = math.exp(-zeta * omega * (t_end - seq.duration_s)) * math.sqrt(1 + r * r)
    return shaped / unshaped


@pytest.mark.parametrize("factory", [zv, zvd, zvdd])
@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_simulated_oscillator_matches_residual_vibration(factory, zeta: float) -> None:
    omega_design = 2.0
    seq = factory(omega_design, zeta)
    # at the design frequency: no vibration left
    assert _simulated_ratio(seq, omega_design, zeta) < 1e-6
    # off design, the simulation agrees with the formula
    for ratio in (0.8, 1.15):
        sim = _simulated_ratio(seq, ratio * omega_design, zeta)
        formula = residual_vibration(seq, ratio * omega_design, zeta) / 100.0
        assert sim == pytest.approx(formula, rel=1e-5, abs=1e-8)


def test_simulated_oscillator_ei() -> None:
    seq = ei(2.0, 0.05, 0.05)
    assert _simulated_ratio(seq, 2.0, 0.05) == pytest.approx(0.05, rel=1e-5)


# ---------------------------------------------------------------------------- sensitivity


@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_zvd_flatter_than_zv(zeta: float) -> None:
    ratios = np.array([0.8, 0.9, 0.95, 1.05, 1.1, 1.2])
    v_zv = sensitivity_curve(zv(1.0, zeta), 1.0, zeta, ratios)
    v_zvd = sensitivity_curve(zvd(1.0, zeta), 1.0, zeta, ratios)
    v_zvdd = sensitivity_curve(zvdd(1.0, zeta), 1.0, zeta, ratios)
    assert np.all(v_zvd < v_zv)
    assert np.all(v_zvdd < v_zvd)
    # insensitivity (V <= 5 %) band: ZVD's is about 3.5x ZV's (undamped: 0.06 vs 0.2... )
    fine = np.linspace(0.5, 1.5, 4001)
    band_zv = np.ptp(fine[sensitivity_curve(zv(1.0, zeta), 1.0, zeta, fine) <= 5.0])
    band_zvd = np.ptp(fine[sensitivity_curve(zvd(1.0, zeta), 1.0, zeta, fine) <= 5.0])
    assert band_zvd > 3.0 * band_zv


def test_damping_mismatch_hurts_zv_more() -> None:
    """Designed for zeta = 0, plant damped 0.05: ZVD leaves far less vibration."""
    v_zv = residual_vibration(zv(1.0), 1.0, 0.05)
    v_zvd = residual_vibration(zvd(1.0), 1.0, 0.05)
    assert v_zv > 5.0 and v_zvd < 0.2 * v_zv


# ------------------------------------------------------------------------ shaping commands


def test_shape_command_step_is_staircase() -> None:
    seq = zvd(2 * math.pi)  # T = 1 s: impulses at 0, 0.5, 1
    t = np.arange(0.0, 2.0, 0.1)
    u = np.ones_like(t)
    y = shape_command(t, u, seq)
    expected = np.where(t < 0.5 - 1e-12, 0.25, np.where(t < 1.0 - 1e-12, 0.75, 1.0))
    np.testing.assert_allclose(y, expected)


def test_shape_command_multi_axis_and_initial() -> None:
    seq = zv(math.pi)  # impulses at 0 and 1 s
    t = np.linspace(0.0, 3.0, 31)
    u = np.column_stack([np.full_like(t, 2.0), t])
    y = shape_command(t, u, seq, initial=0.0)
    assert y.shape == (31, 2)
    np.testing.assert_allclose(y[t >= 1.0, 0], 2.0)
    np.testing.assert_allclose(y[t < 1.0 - 1e-9, 0], 1.0)
    # ramp through a ZV shaper lags by half the shaper duration once both impulses act
    late = t >= 1.0
    np.testing.assert_allclose(y[late, 1], t[late] - 0.5, atol=1e-12)
    # a command already at 5 before t[0] stays at 5 when constant
    np.testing.assert_allclose(shape_command(t, np.full_like(t, 5.0), seq, initial=5.0), 5.0)


def test_shaped_command_matches_shape_command_on_grid() -> None:
    seq = zvd(2 * math.pi / 0.8)  # impulses at 0, 0.4, 0.8 s
    dt = 0.01
    t = np.arange(0, 300) * dt
    rng = np.random.default_rng(1)
    u = np.cumsum(rng.normal(size=t.size))
    shaper = ShapedCommand(seq, dt)
    np.testing.assert_array_equal(shaper.delay_ticks, [0, 40, 80])
    online = shaper.process(u)
    offline = shape_command(t, u, seq, interpolation="previous")
    np.testing.assert_allclose(online, offline, atol=1e-12)


def test_shaped_command_rounding_modes() -> None:
    seq = zv(2 * math.pi / 0.5)  # impulse at 0.25 s; dt 0.1 -> 2.5 ticks
    nearest = ShapedCommand(seq, 0.1)
    np.testing.assert_array_equal(nearest.delay_ticks, [0, 3])  # half a tick rounds up
    split = ShapedCommand(seq, 0.1, rounding="split")
    q = split.quantized_sequence
    np.testing.assert_allclose(q.times_s, [0.0, 0.2, 0.3])
    np.testing.assert_allclose(q.amplitudes, [0.5, 0.25, 0.25])
    # split keeps amplitude sum and first moment; nearest keeps only the sum
    first_moment = float(np.sum(seq.amplitudes * seq.times_s))
    assert q.total == pytest.approx(1.0)
    assert float(np.sum(q.amplitudes * q.times_s)) == pytest.approx(first_moment)
    v_split = residual_vibration(q, 2 * math.pi / 0.5)
    v_nearest = residual_vibration(nearest.quantized_sequence, 2 * math.pi / 0.5)
    assert v_split < v_nearest


def test_shaped_command_vector_samples_and_reset() -> None:
    shaper = ShapedCommand(zv(math.pi), 0.5, initial=np.zeros(3))  # impulse at 1 s = 2 ticks
    out = [shaper.step(np.array([1.0, 2.0, 3.0])) for _ in range(4)]
    np.testing.assert_allclose(out[0], [0.5, 1.0, 1.5])
    np.testing.assert_allclose(out[3], [1.0, 2.0, 3.0])
    shaper.reset(np.ones(3))
    np.testing.assert_allclose(shaper.step(np.ones(3)), 1.0)
    with pytest.raises(ValueError, match="u"):
        shaper.step(1.0)


# ------------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("call", "word"),
    [
        (lambda: zv(0.0), "omega"),
        (lambda: zvd(-1.0), "omega"),
        (lambda: zvd(1.0, 1.0), "zeta"),
        (lambda: zv(1.0, -0.1), "zeta"),
        (lambda: ei(1.0, 0.0, 0.0), "v_tol"),
        (lambda: ImpulseSequence(np.array([0.5, 0.1]), np.array([0.5, 0.5])), "times_s"),
        (lambda: ImpulseSequence(np.array([0.0, 0.1]), np.array([1.0])), "amplitudes"),
        (lambda: ImpulseSequence(np.array([]), np.array([])), "times_s"),
        (lambda: residual_vibration(zv(1.0), 0.0), "omega"),
        (lambda: sensitivity_curve(zv(1.0), 1.0, 0.0, [0.0]), "ratios"),
        (lambda: shape_command([0.0, 0.0], [1.0, 1.0], zv(1.0)), "t"),
        (lambda: shape_command([0.0, 1.0], [1.0], zv(1.0)), "u"),
        (lambda: shape_command([0.0, 1.0], [1.0, 1.0], zv(1.0), interpolation="x"), "interp"),
        (lambda: ShapedCommand(zv(1.0), 0.0), "dt_s"),
        (lambda: ShapedCommand(zv(1.0), 0.1, rounding="up"), "rounding"),
        (lambda: multi_mode([]), "sequences"),
    ],
)
def test_bad_input_raises_value_error(call, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        call()


@pytest.mark.parametrize("rounding", ["nearest", "split"])
@pytest.mark.parametrize("initial", [0.0, 0.3, np.array([0.2, -1.0, 0.0])])
def test_process_is_step_on_every_sample_bit_for_bit(rounding, initial):
    # process() gathers the delayed samples at once; the plain path is step() per
    # sample. Same values exactly, and the same state afterwards (chunks continue alike).
    seq = multi_mode([zvdd(2.8827, 0.0686), ei(13.3588, 0.0513), zvd(36.9511, 0.0502)])
    shape = np.shape(initial)
    rng = np.random.default_rng(7)
    chunks = [rng.normal(size=(n, *shape)) for n in (1, 3, 250, 40, 700)]
    fast = ShapedCommand(seq, 0.002, initial=initial, rounding=rounding)
    plain = ShapedCommand(seq, 0.002, initial=initial, rounding=rounding)
    assert len(fast.delay_ticks) > 32  # more than BLAS's unrolled block: order matters
    for x in chunks:
        got = fast.process(x)
        want = np.array([plain.step(s) for s in x])
        assert got.shape == want.shape == x.shape
        np.testing.assert_array_equal(got, want)
    nxt = rng.normal(size=shape)
    assert np.array_equal(fast.step(nxt), plain.step(nxt))
    assert fast.process(np.zeros((0, *shape))).size == 0
    with pytest.raises(ValueError, match="shape"):
        fast.process(np.zeros((4, 2)))


def test_si_designs_are_cached_by_their_inputs_and_equal_a_fresh_design() -> None:
    """A calibration builds each candidate's controller several times: the SI design (a few
    linear programs) is computed once per input, and the cached sequence is the
    one the design gives afresh; bad input still raises every time (never cached)."""
    from harness.shaping.impulse_shapers import _si_design, si

    first = si(2.6, 3.4, 0.0, 0.02, 0.05)
    assert si(2.6, 3.4, 0.0, 0.02, 0.05) is first
    fresh = _si_design.__wrapped__(2.6, 3.4, 0.0, 0.02, 0.05, 16, 24, 400)
    assert np.array_equal(fresh.times_s, first.times_s)
    assert np.array_equal(fresh.amplitudes, first.amplitudes)
    assert si(2.6, 3.6, 0.0, 0.02, 0.05) is not first  # another band, another design
    for _ in range(2):
        with pytest.raises(ValueError, match="v_tol"):
            si(2.6, 3.4, 0.0, 0.02, 1.5)
        with pytest.raises(ValueError, match="omega_hi"):
            si(3.4, 2.6)
