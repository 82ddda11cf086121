"""OPPF design: gains come out of the optimiser, eq (7) holds, closed loops are stable."""

import numpy as np
import pytest
from scipy.linalg import expm

from harness.controllers.oppf import (
    OPPFWeights,
    PPFDesignModel,
    closed_loop_matrix,
    design_oppf,
    initial_covariance,
    oppf_cost,
    stability_margin,
    stability_matrix,
)
from harness.controllers.ppf import PPFCompensatorParameters, PPFController
from harness.studies.hu2006 import linear_closed_loop_matrix, ppf_design_model
from rig_models.reference.hu2006_hub_beam import Hu2006HubBeam


@pytest.fixture(scope="module")
def plant():
    return Hu2006HubBeam()


@pytest.fixture(scope="module")
def design(plant):
    return design_oppf(ppf_design_model(plant), OPPFWeights(voltage_weight=1e-8))


def test_gains_come_from_the_optimiser(design):
    model = design.model
    assert design.success
    assert design.cost < 0.2 * design.open_loop_cost
    g, wc, zc = design.gains, design.comp_freqs_rad_s, design.comp_zetas
    # not the starting point, not the paper's values
    assert not np.allclose(g, 0.2) and not np.allclose(g, [0.5, 0.7])
    # local optimality: no small feasible perturbation lowers the cost
    rng = np.random.default_rng(1)
    for _ in range(40):
        dg = g * (1 + 0.03 * rng.standard_normal(2))
        dw = wc * (1 + 0.03 * rng.standard_normal(2))
        dz = zc * (1 + 0.03 * rng.standard_normal(2))
        if stability_margin(model, dg) < design.weights.min_margin:
            continue
        assert oppf_cost(model, dg, dw, dz, design.weights) >= design.cost * (1 - 1e-6)


def test_stability_condition_eq7_holds_with_margin(design):
    assert design.stability_condition_holds()
    assert np.all(np.linalg.eigvalsh(stability_matrix(design.model, design.gains)) > 0)
    assert design.margin >= design.weights.min_margin - 1e-9
    assert design.max_real_eig < 0


def test_eq7_predicts_instability():
    model = PPFDesignModel([3.0], 0.01, [1e-3], 1e-6)
    assert stability_margin(model, [0.9]) > 0
    assert stability_margin(model, [1.1]) < 0  # classical single-mode g < 1
    stable = closed_loop_matrix(model, [0.9], [3.0], [0.3])
    unstable = closed_loop_matrix(model, [1.1], [3.0], [0.3])
    assert np.max(np.linalg.eigvals(stable).real) < 0
    assert np.max(np.linalg.eigvals(unstable).real) > 0
    assert oppf_cost(model, np.array([1.1]), np.array([3.0]), np.array([0.3])) == np.inf


def test_lyapunov_cost_equals_integrated_energy(design):
    """eqs (11)-(14): 1/2 trace(P X0) equals 1/2 of the integral of x^T Q x, summed over the
    initial states spanning X0 (checked by exact discrete propagation)."""
    model = design.model
    weights = OPPFWeights(voltage_weight=0.0)
    a = closed_loop_matrix(model, design.gains, design.comp_freqs_rad_s, design.comp_zetas)
    n = model.n
    q = np.zeros_like(a)
    q[:n, :n] = model.omega
    q[n:2 * n, n:2 * n] = np.eye(n)
    x0 = initial_covariance(model)
    vals, vecs = np.linalg.eigh(x0)
    dt = 2e-3
    phi = expm(a * dt)
    total = 0.0
    for lam, v in zip(vals, vecs.T, strict=True):
        if lam <= 0:
            continue
        x = np.sqrt(lam) * v
        for _ in range(int(60 / dt)):
            x_next = phi @ x
            total += 0.5 * dt * (x @ q @ x + x_next @ q @ x_next) / 2
            x = x_next
    cost = oppf_cost(model, design.gains, design.comp_freqs_rad_s, design.comp_zetas, weights)
    assert total == pytest.approx(cost, rel=1e-3)


def test_full_five_mode_closed_loops_are_stable(plant, design):
    eig = np.linalg.eigvals(linear_closed_loop_matrix(plant, design))
    assert np.max(eig.real) < 0
    # hub free (no PD): only the rigid-body pair sits at zero
    free = np.linalg.eigvals(linear_closed_loop_matrix(plant, design, kp=0.0, kd=0.0))
    assert np.sum(np.abs(free) < 1e-6) == 2
    assert np.max(free.real[np.abs(free) > 1e-6]) < 0


def test_ppf_bank_damps_free_vibration_of_the_plant(plant, design):
    """The discrete PPF bank on the simulated plant (hub free) removes a mode-1 vibration far
    faster than structural damping alone, below the voltage limit."""
    freqs, vecs = plant.coupled_modes()
    dt = 1e-3
    ad, bd = plant.discretize(dt)
    n1 = plant.n_modes + 1
    sensor = plant.piezo_b / plant.gamma

    def energy_after(controller, seconds=5.0):
        x = np.zeros(plant.n_states)
        x[:n1] = 0.003 * vecs[:, 0]
        for _ in range(int(seconds / dt)):
            e_a = controller.step(float(sensor @ x[1:n1]), dt) if controller else 0.0
            x = ad @ x + bd @ np.array([0.0, e_a])
        return float(plant.vibration_energy(x)), x

    e0 = float(plant.vibration_energy(np.r_[0.003 * vecs[:, 0], np.zeros(n1)]))
    passive, _ = energy_after(None)
    bank = design.controller(plant.params.voltage_limit)
    active, _ = energy_after(bank)
    assert passive > 0.5 * e0
    assert active < 1e-2 * e0
    assert bank.saturated_steps == 0


def test_compensator_discretisation_is_exact():
    p = PPFCompensatorParameters(10.0, 0.2, input_gain=2.0, output_gain=3.0)
    fine = PPFController([p])
    coarse = PPFController([p])
    for _ in range(1000):
        fine.step(1.0, 1e-4)
    for _ in range(10):
        coarse.step(1.0, 1e-2)
    np.testing.assert_allclose(fine.compensators[0].state, coarse.compensators[0].state,
                               rtol=1e-9, atol=1e-12)
    # steady state: xi -> input_gain * y
    c = PPFController([p])
    for _ in range(2000):
        out = c.step(1.0, 1e-2)
    assert out == pytest.approx(3.0 * 2.0, rel=1e-6)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="participation"):
        PPFDesignModel([3.0], 0.01, [0.0], 1.0)
    with pytest.raises(ValueError, match="gamma"):
        PPFDesignModel([3.0], 0.01, [1.0], -1.0)
    with pytest.raises(ValueError, match="zeta"):
        PPFCompensatorParameters(3.0, 0.0)
    with pytest.raises(ValueError, match="output_limit"):
        PPFController([PPFCompensatorParameters(3.0, 0.1)], output_limit=0.0)
    with pytest.raises(ValueError, match="min_margin"):
        OPPFWeights(min_margin=1.5)
