"""CSVS commands: lemma 1 cancellation, lemma 2 robustness order, lemma 3 multi-mode."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from harness.shaping.csvs import (
    ComponentSequence,
    CSVSShaper,
    ModeDesign,
    lemma1_sequence,
    multimode_sequence,
    residual_vibration,
    robust_sequence,
    robustness_order,
    shaped_step,
)

W1, W2 = 3.161, 16.954


def residual_response(seq: ComponentSequence, w: float, zeta: float, t: np.ndarray) -> np.ndarray:
    """Response of eq (4) to the impulse components, for t after the last one (written out
    independently of the module)."""
    wd = w * math.sqrt(1 - zeta**2)
    x = np.zeros_like(t, dtype=np.result_type(t, w))
    for tk, a in zip(seq.times, seq.amplitudes, strict=True):
        tau = t - tk
        x += a * np.exp(-zeta * w * tau) * np.sin(wd * tau) / wd
    return x


def scaled_derivatives(seq, w_m, zeta, max_order, radius=0.05, n_points=64):
    """``rho^j / j! * d^j X / dw^j`` at ``w_m`` for several times after the command, from
    Cauchy's integral on a circle of radius ``rho = radius * w_m`` (X is analytic in w)."""
    t = seq.duration + np.linspace(0.1, 3.0, 7) * 2 * math.pi / w_m
    rho = radius * w_m
    theta = 2 * math.pi * np.arange(n_points) / n_points
    w = w_m + rho * np.exp(1j * theta)
    data = np.array([residual_response(seq, wk, zeta, t.astype(complex)) for wk in w])
    coef = np.fft.fft(data, axis=0) / n_points  # coef[j] = a_j rho^j
    return np.real_if_close(coef[: max_order + 1], tol=1e6)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
@pytest.mark.parametrize("zeta", [0.0, 0.01, 0.1])
def test_lemma1_cancels_the_design_mode(n, zeta):
    seq = lemma1_sequence(W1, zeta, n)
    assert seq.n_components == n
    assert seq.amplitudes.sum() == pytest.approx(1.0)
    td = 2 * math.pi / (W1 * math.sqrt(1 - zeta**2))
    np.testing.assert_allclose(seq.times, np.arange(n) * td / n)
    # damping scaling: a_k proportional to exp(-zeta w t_k)
    np.testing.assert_allclose(seq.amplitudes / seq.amplitudes[0],
                               np.exp(-zeta * W1 * seq.times))
    assert residual_vibration(seq, W1, zeta) < 1e-12
    t = seq.duration + np.linspace(0.01, 10, 200)
    unshaped = ComponentSequence(np.array([0.0]), np.array([1.0]))
    peak = np.max(np.abs(residual_response(unshaped, W1, zeta, t)))
    assert np.max(np.abs(residual_response(seq, W1, zeta, t))) < 1e-12 * max(peak, 1e-3)
    assert residual_vibration(seq, 1.2 * W1, zeta) > 1e-3  # a different mode is not cancelled


@pytest.mark.parametrize("order", [0, 1, 2])
@pytest.mark.parametrize("n", [2, 3])
def test_lemma2_derivatives_vanish_up_to_the_robust_order(order, n):
    zeta = 0.01
    seq = robust_sequence(W1, zeta, n, order)
    coef = np.abs(scaled_derivatives(seq, W1, zeta, max_order=order + 1))
    lead = np.max(coef[order + 1])
    assert lead > 1e-6  # the (p+1)-th derivative does not vanish
    for j in range(order + 1):
        assert np.max(coef[j]) < 1e-9 * lead, f"derivative {j} does not vanish"
    assert robustness_order(seq, W1, zeta) == order
    # residual grows like |error|^(p+1): halving the error divides it by 2^(p+1)
    r1 = residual_vibration(seq, W1 * 1.02, zeta)
    r2 = residual_vibration(seq, W1 * 1.01, zeta)
    assert math.log2(r1 / r2) == pytest.approx(order + 1, abs=0.15)


def test_paper_mode1_command_is_second_order_robust_with_four_components():
    seq = robust_sequence(W1, 0.0, 2, 2)
    assert seq.n_components == 4
    np.testing.assert_allclose(seq.amplitudes * 8, [1, 3, 3, 1])
    np.testing.assert_allclose(seq.times, np.arange(4) * math.pi / W1)


def test_lemma3_multimode_command_cancels_both_modes():
    zeta = 0.01
    seq = multimode_sequence([ModeDesign(W1, zeta, 2, 2), ModeDesign(W2, zeta, 2, 0)])
    assert seq.n_components == 8
    assert seq.amplitudes.sum() == pytest.approx(1.0)
    assert robustness_order(seq, W1, zeta) == 2
    assert robustness_order(seq, W2, zeta) == 0
    for w in (W1, W2):
        t = seq.duration + np.linspace(0.01, 5, 100)
        assert np.max(np.abs(residual_response(seq, w, zeta, t))) < 1e-12
    mode1_only = robust_sequence(W1, zeta, 2, 2)
    assert residual_vibration(mode1_only, W2, zeta) > 0.1


def test_shaped_time_function_leaves_no_residual_vibration_in_simulation():
    """Components may be time functions (remark 2): a rest-to-rest bang-bang force, shaped,
    simulated through eq (4) with scipy."""
    zeta = 0.02
    seq = robust_sequence(W1, zeta, 2, 1)
    pulse = 0.3

    def base(tau):
        tau = np.asarray(tau)
        return np.where((tau >= 0) & (tau < pulse), 1.0,
                        np.where((tau >= pulse) & (tau < 2 * pulse), -1.0, 0.0))

    def run(sequence, w):
        # integrate segment by segment between the command's discontinuities
        edges = np.concatenate([sequence.times + k * pulse for k in range(3)])
        edges = np.unique(np.r_[0.0, edges, sequence.duration + 2 * pulse + 6.0])
        y = np.zeros(2)
        for t0, t1 in zip(edges[:-1], edges[1:], strict=True):
            f = float(sequence.apply(base, 0.5 * (t0 + t1)))
            sol = solve_ivp(lambda t, y, f=f: [y[1], f - 2 * zeta * w * y[1] - w**2 * y[0]],
                            (t0, t1), y, rtol=1e-11, atol=1e-13, dense_output=True)
            y = sol.y[:, -1]
        t = np.linspace(t0, t1, 200)
        return np.max(np.hypot(sol.sol(t)[0] * w, sol.sol(t)[1]))

    single = ComponentSequence(np.array([0.0]), np.array([1.0]))
    unshaped = run(single, W1)
    shaped = run(seq, W1)
    assert unshaped > 1e-2
    assert shaped < 1e-6 * unshaped
    assert run(seq, 1.5 * W1) > 1e-2 * unshaped  # not a mode the command was designed for


def test_streaming_shaper_reproduces_the_staircase():
    seq = multimode_sequence([ModeDesign(W1, 0.01, 2, 2), ModeDesign(W2, 0.01, 2, 0)])
    dt = 1e-3
    sh = CSVSShaper(seq, initial_value=0.0)
    out = np.array([sh.step(2.0, dt) for _ in range(4000)])
    t = np.arange(4000) * dt
    # compare away from the component edges (the shaper holds samples)
    ref = shaped_step(2.0, seq)
    mask = np.min(np.abs(t[:, None] - seq.times[None, :]), axis=1) > 2 * dt
    np.testing.assert_allclose(out[mask], ref(t[mask]), atol=1e-12)
    assert out[-1] == pytest.approx(2.0)
    sh.reset()
    assert sh.step(2.0, dt) == pytest.approx(2.0 * seq.amplitudes[0])


@pytest.mark.parametrize(
    "call",
    [
        lambda: lemma1_sequence(-1.0, 0.01, 2),
        lambda: lemma1_sequence(W1, 1.0, 2),
        lambda: lemma1_sequence(W1, 0.01, 1),
        lambda: robust_sequence(W1, 0.01, 2, -1),
        lambda: multimode_sequence([]),
        lambda: ComponentSequence(np.array([0.0, 0.0]), np.array([0.5, 0.5])),
    ],
)
def test_bad_input_raises(call):
    with pytest.raises(ValueError):
        call()
