"""PWPF modulator: static characteristic (dead zone, saturation, near-linear range)."""

import numpy as np
import pytest

from harness.controllers.pwpf import (
    PWPFModulator,
    PWPFParameters,
    pwpf_static_analytic,
    pwpf_static_characteristic,
)

PAPER = PWPFParameters()  # k_m 3, tau_m 0.15, U_on 0.4, U_off 0.15, U_m 1


def test_paper_defaults_sit_in_table_one_ranges():
    assert 2 < PAPER.k_m < 6
    assert 0.1 < PAPER.tau_m < 0.5
    assert PAPER.u_on > 0.3
    assert PAPER.u_off < 0.8 * PAPER.u_on
    assert PAPER.u_m == 1.0


def test_dead_zone_below_u_on_over_k_m():
    dz = PAPER.dead_zone
    assert dz == pytest.approx(0.4 / 3)
    below = pwpf_static_characteristic([0.0, 0.5 * dz, 0.98 * dz], dt=1e-3, measure_time=20.0)
    assert np.all(below.duty_cycle == 0)
    assert np.all(below.pulse_freq_hz == 0)
    above = pwpf_static_characteristic([1.05 * dz], dt=1e-4, measure_time=10.0)
    assert above.pulse_freq_hz[0] > 0 and above.duty_cycle[0] > 0


def test_saturation_above_u_m_plus_u_off_over_k_m():
    sat = PAPER.saturation
    assert sat == pytest.approx(1.0 + 0.15 / 3)
    res = pwpf_static_characteristic([1.02 * sat, 2.0], dt=1e-4, measure_time=5.0)
    assert np.all(res.duty_cycle == 1.0)
    assert np.all(res.pulse_freq_hz == 0)
    just_below = pwpf_static_characteristic([0.97 * sat], dt=1e-4, measure_time=5.0)
    assert 0.8 < just_below.duty_cycle[0] < 1.0
    assert just_below.pulse_freq_hz[0] > 0


def test_near_linear_range_and_agreement_with_closed_form():
    r = np.linspace(0.3, 0.9, 7)
    sim = pwpf_static_characteristic(r, dt=1e-4, measure_time=5.0)
    ana = pwpf_static_analytic(r)
    np.testing.assert_allclose(sim.duty_cycle, ana.duty_cycle, atol=0.01)
    np.testing.assert_allclose(sim.pulse_freq_hz, ana.pulse_freq_hz, rtol=0.05)
    assert np.all(np.diff(sim.duty_cycle) > 0)
    slope, offset = np.polyfit(r, sim.mean_output, 1)
    fit = slope * r + offset
    assert np.max(np.abs(fit - sim.mean_output)) < 0.01  # near-linear
    assert 0.95 < slope < 1.05
    assert abs(offset) < 0.15


def test_output_is_odd_and_three_level():
    mod = PWPFModulator()
    outs = {mod.step(-0.6, 1e-3) for _ in range(5000)}
    assert outs <= {-1.0, 0.0}
    assert -1.0 in outs
    pos = pwpf_static_characteristic([0.6], dt=1e-4, measure_time=3.0)
    neg = pwpf_static_characteristic([-0.6], dt=1e-4, measure_time=3.0)
    assert neg.mean_output[0] == pytest.approx(-pos.mean_output[0], abs=0.01)


def test_reset_restores_initial_state():
    mod = PWPFModulator()
    first = [mod.step(0.5, 1e-3) for _ in range(500)]
    mod.reset()
    second = [mod.step(0.5, 1e-3) for _ in range(500)]
    assert first == second


@pytest.mark.parametrize(
    "kwargs",
    [{"k_m": 0.0}, {"tau_m": -1.0}, {"u_off": 0.5}, {"u_m": float("nan")}],
)
def test_bad_parameters_raise(kwargs):
    with pytest.raises(ValueError):
        PWPFParameters(**kwargs)


def test_bad_step_raises():
    with pytest.raises(ValueError, match="dt"):
        PWPFModulator().step(0.1, 0.0)
