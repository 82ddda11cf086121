"""Paper 003: square-wave compensation, the periodic amplitude, the sweep, cases A/B/C."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.controllers.square_wave import DisturbanceLaw, square_wave_torque
from harness.core.periodic import steady_state_amplitude
from harness.core.runs import load_run
from harness.studies.sweep import SweepSpec, harmonic_steady_state, run_sweep, simulate_lambda
from harness.studies.sweep_report import analyse
from harness.testing.paper_tables import collect
from rig_models.devices import DisturbanceRotor
from rig_models.rig_file import load_rig
from rig_models.schema import ConfigError


def test_rotor_torque_is_the_rotating_mass_reaction():
    r = DisturbanceRotor(mass_kg=0.4, eccentricity_m=0.08, dish_radius_m=0.6,
                         max_speed_rad_s=30, speed_lag_s=0.0, dt_s=0.001)
    r.command(2.0, True)
    torques = []
    for _ in range(4000):
        torques.append(r.step())
    a = np.array(torques[100:])
    assert np.max(np.abs(a)) == pytest.approx(0.4 * 0.6 * 0.08 * 4.0, rel=1e-3)


def test_square_wave_opposes_the_disturbance():
    law = DisturbanceLaw(0.4, 0.08, 0.6)
    amp = law.amplitude_n_m(2.0)
    for phi in (0.3, 1.5, 2.9, 3.5, 5.0):
        u = square_wave_torque(0.8, law, phi, 2.0)
        assert abs(u) == pytest.approx(0.8 * amp)
        assert u * math.sin(phi) < 0  # against the rotor's A sin(phi)


def test_compensation_above_wheel_limit_refused_before_the_run():
    run = load_run("case-a", {"controller": {"beta": 3.0}})
    from harness.core.runs import build_controller

    with pytest.raises(ConfigError, match="exceeds the wheel's torque limit"):
        build_controller(run)


def test_steady_state_amplitude_of_a_noisy_periodic_signal():
    rng = np.random.default_rng(3)
    t = np.arange(0, 60, 0.002)
    w = 1.7
    y = 0.02 * np.sin(w * t + 0.3) + 0.006 * np.sin(3 * w * t) + 0.005 * rng.standard_normal(
        t.size)
    ref = 0.5 * np.ptp(0.02 * np.sin(w * t + 0.3) + 0.006 * np.sin(3 * w * t))
    assert steady_state_amplitude(t, y, w, 30.0) == pytest.approx(ref, rel=0.03)


@pytest.fixture(scope="module")
def plant():
    return load_rig("sgsrt").plant


def test_sweep_simulation_matches_closed_form_harmonics(plant):
    w_ref = plant.hub_free_modes()[0][0]
    spec = SweepSpec(np.array([0.8]), np.array([0.5, 0.8, 1.0]), w_ref, 0.4, 0.04, 0.6)
    sim = simulate_lambda(plant, spec, 0.8)
    w = 0.8 * w_ref
    for j, beta in enumerate(spec.betas):
        acc, dfl = harmonic_steady_state(plant, w, spec.amplitude_n_m(w), beta)
        assert sim[j, 0] == pytest.approx(acc, rel=0.02)
        assert sim[j, 1] == pytest.approx(dfl, rel=0.02)


def test_sweep_shows_the_papers_laws(plant):
    w_ref = plant.hub_free_modes()[0][0]
    lambdas = np.array([0.6, 0.8, 0.9, 1.0, 1.1, 1.3, 2.0, 3.0])
    betas = np.linspace(0.3, 1.0, 8)
    amps = run_sweep(plant, SweepSpec(lambdas, betas, w_ref, 0.4, 0.04, 0.6, settle_s=50.0),
                     workers=2)
    laws = analyse(lambdas, betas, amps)
    # minimum of the residual deflection near beta 0.7-0.8 for lambda > 0.5
    assert laws["tip_deflection_m"]["share_lambda_gt_0.5_with_best_beta_in_0.6_0.85"] == 1.0
    # resonance at lambda = 1
    assert 1.0 in laws["tip_deflection_m"]["resonance_lambdas"]


@pytest.mark.slow
def test_case_a_beta_one_is_the_largest(paper_suites):
    """Case A at beta 0.6 / 0.8 / 1.0: the runs paper003's suite made (100 s each; shared for
    the session by conftest's paper_suites, so no case runs twice), found as `harness report
    table2` finds them."""
    [folder] = {p.parent.parent for p in paper_suites.out.glob("*/*-case-a-beta-*/summary.json")}
    found = collect(folder)
    assert set(found["case-a"]) == {0.6, 0.8, 1.0}
    amps = {}
    for beta, s in found["case-a"].items():
        assert s["run"] == f"case-a-beta-{beta}" and s["stopped_by"] == "completed"
        assert s["simulated_time_s"] >= 80.0  # the 80 s this test ran before, at least
        amps[beta] = s["steady_tip_accel_amplitude_m_s2"]
        assert s["wheel_torque_within_limit"]
    assert max(amps, key=amps.get) == 1.0
