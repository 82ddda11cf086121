"""Wang 2022's simulation fast path against plain reference formulations.

The right-hand side, the two torque laws and ``simulate`` run on plain floats and scipy's
DOP853 stepped directly (the study calls them ~10^6 times). Here each is compared with the
equations written plainly in numpy (the mass matrix assembled and solved by LAPACK, the
torque laws as eq 1 reads, the integration by ``solve_ivp`` segment by segment) at random
states, wing angles and plants: a wrong coefficient, sign or index in the fast path fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from harness.shaping.variable_amplitude import (
    FeedforwardTorque,
    ManeuverSpec,
    PathTrackingTorque,
    VariableAmplitudeProfile,
    _modal_response,
    _rates,
    design_modal_states,
    solve_variable_amplitude,
)
from rig_models.reference.wang2022_spacecraft import (
    STATE_SIZE,
    Wang2022Spacecraft,
    quaternion_multiply,
    simulate,
)

FAST = {"dt_s": 0.02, "modes": (0, 2)}


def reference_rhs(
    model: Wang2022Spacecraft, t: float, x: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Paper eq 1 as written: [[J, C], [C^T, I]] [w', eta''] = [tau - w x h, modal forces]."""
    gamma = float(model.wing_angle(t))
    j, c = model.inertia(gamma), model.coupling(gamma)
    w, eta, deta = x[4:7], x[7:13], x[13:19]
    lam, zeta = model.modal_omega, model.modal_damping
    mass = np.block([[j, c], [c.T, np.eye(6)]])
    force = np.concatenate(
        [tau - np.cross(w, j @ w + c @ deta), -2.0 * zeta * lam * deta - lam**2 * eta]
    )
    acc = np.linalg.solve(mass, force)
    dq = 0.5 * quaternion_multiply(x[0:4], np.concatenate([[0.0], w]))
    return np.concatenate([dq, acc[:3], deta, acc[3:]])


def reference_tracking_torque(
    plant: Wang2022Spacecraft, acc: np.ndarray, t: float, x: np.ndarray
) -> np.ndarray:
    """tau = J a + C eta'' + w x (J w + C eta'), eta'' from the modal equation under w' = a."""
    gamma = float(plant.wing_angle(t))
    j, c = plant.inertia(gamma), plant.coupling(gamma)
    w, eta, deta = x[4:7], x[7:13], x[13:19]
    lam, zeta = plant.modal_omega, plant.modal_damping
    ddeta = -2.0 * zeta * lam * deta - lam**2 * eta - c.T @ acc
    return j @ acc + c @ ddeta + np.cross(w, j @ w + c @ deta)


def reference_feedforward_torque(
    model: Wang2022Spacecraft, profile: VariableAmplitudeProfile, t: float
) -> np.ndarray:
    """The design model's inverse dynamics, its modal response by the numpy closed form."""
    spec = profile.spec
    if t < 0.0 or t >= spec.duration_s:
        return np.zeros(3)
    eta_k, deta_k, force = design_modal_states(model, profile)
    rates, _ = _rates(profile.chi, spec.a0, spec.dt_s)
    i = min(int(t / spec.dt_s), spec.n_intervals - 1)
    s = t - i * spec.dt_s
    zeta = np.full(6, spec.design_damping)
    eta, deta, ddeta = _modal_response(
        eta_k[i], deta_k[i], force[i], model.modal_omega, zeta, s
    )
    acc = profile.acceleration[i]
    w = rates[i] + acc * s
    gamma = float(model.wing_angle(t))
    j, c = model.inertia(gamma), model.coupling(gamma)
    return j @ acc + c @ ddeta + np.cross(w, j @ w + c @ deta)


def random_state(rng: np.random.Generator) -> np.ndarray:
    x = np.empty(STATE_SIZE)
    x[0:4] = rng.normal(size=4)
    x[0:4] /= np.linalg.norm(x[0:4])
    x[4:7] = rng.normal(scale=0.05, size=3)  # rad/s
    x[7:13] = rng.normal(scale=0.2, size=6)
    x[13:19] = rng.normal(scale=0.5, size=6)
    return x


PLANTS = [
    Wang2022Spacecraft(),
    Wang2022Spacecraft().perturbed(1.1, 0.02),
    Wang2022Spacecraft(wing_angle0_rad=0.7, wing_rate_rad_s=-0.2, n_wings=3),
]


@pytest.fixture(scope="module")
def profile() -> VariableAmplitudeProfile:
    return solve_variable_amplitude(Wang2022Spacecraft(), ManeuverSpec(shaper="zvd", **FAST))


@pytest.mark.parametrize("plant", PLANTS, ids=["nominal", "perturbed", "other-geometry"])
def test_rhs_matches_the_mass_matrix_solve(plant: Wang2022Spacecraft) -> None:
    rng = np.random.default_rng(4)
    for _ in range(50):
        t = float(rng.uniform(0.0, 60.0))
        x = random_state(rng)
        tau = rng.normal(scale=200.0, size=3)
        ref = reference_rhs(plant, t, x, tau)
        fast = plant.rhs(t, x, tau)
        floats = plant.rhs_floats(t, x.tolist(), tau.tolist())
        assert isinstance(floats, list) and all(type(v) is float for v in floats)
        np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-12 * np.max(np.abs(ref)))
        np.testing.assert_array_equal(np.array(floats), fast)
        # and every block of the state really enters: a zero torque or state gives another
        assert np.max(np.abs(plant.rhs(t, x, 0.0 * tau) - fast)) > 1e-6


def test_rhs_float_constants_are_per_plant() -> None:
    """Perturbed plants share J and C (the geometry) but not the modes; the one-entry
    cache of the geometry returns the value of the time asked."""
    model = Wang2022Spacecraft()
    plant = model.perturbed(1.2, 0.05)
    assert plant._geometry() is model._geometry()
    rng = np.random.default_rng(5)
    x, tau = random_state(rng), rng.normal(size=3)
    for t in (1.0, 2.0, 1.0, 1.0, 37.5):
        for m in (model, plant):
            np.testing.assert_allclose(
                m.rhs(t, x, tau), reference_rhs(m, t, x, tau), rtol=1e-10, atol=1e-12
            )
            j, ct = m.inertia_and_coupling_floats(t)
            jj, cc = m.inertia_and_coupling(t)
            np.testing.assert_array_equal(np.reshape(j, (3, 3)), jj)
            np.testing.assert_array_equal(np.array(ct), cc.T)
    assert not np.allclose(model.rhs(1.0, x, tau), plant.rhs(1.0, x, tau))


@pytest.mark.parametrize("plant", PLANTS[:2], ids=["nominal", "perturbed"])
def test_tracking_torque_matches_eq1_and_imposes_the_plan(
    plant: Wang2022Spacecraft, profile: VariableAmplitudeProfile
) -> None:
    law = PathTrackingTorque(plant, profile)
    rng = np.random.default_rng(6)
    for t in rng.uniform(0.0, profile.spec.duration_s, 40):
        x = random_state(rng)
        tau = law(float(t), x)
        i = min(int(t / profile.spec.dt_s), profile.spec.n_intervals - 1)
        acc = profile.acceleration[i]
        np.testing.assert_allclose(
            tau, reference_tracking_torque(plant, acc, float(t), x), rtol=1e-11, atol=1e-9
        )
        assert law.floats(float(t), x.tolist()) == tuple(tau.tolist())
        # the premise of the law: under it the plant's body acceleration is the planned one
        np.testing.assert_allclose(plant.rhs(float(t), x, tau)[4:7], acc, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(law(profile.spec.duration_s, random_state(rng)), 0.0)
    np.testing.assert_array_equal(law(-1e-3, random_state(rng)), 0.0)


def test_feedforward_torque_matches_the_numpy_form(profile: VariableAmplitudeProfile) -> None:
    model = Wang2022Spacecraft()
    law = FeedforwardTorque(model, profile)
    rng = np.random.default_rng(7)
    t_f, dt = profile.spec.duration_s, profile.spec.dt_s
    times = np.concatenate([rng.uniform(0.0, t_f, 40), [0.0, dt, 7 * dt, t_f - 1e-9, t_f, 25.0]])
    peak = 0.0
    for t in times:
        ref = reference_feedforward_torque(model, profile, float(t))
        tau = law(float(t))
        np.testing.assert_allclose(tau, ref, rtol=1e-11, atol=1e-9)
        assert law.floats(float(t)) == tuple(tau.tolist())
        peak = max(peak, float(np.max(np.abs(ref))))
    assert peak > 1.0  # N m: the comparison saw real torques


def test_feedforward_torque_with_design_damping() -> None:
    """The damped closed form (decay, damped frequency) of the design model's modes."""
    model = Wang2022Spacecraft()
    spec = ManeuverSpec(shaper="none", dt_s=0.02, modes=(0,), design_damping=0.05)
    prof = solve_variable_amplitude(model, spec)
    law = FeedforwardTorque(model, prof)
    for t in np.linspace(0.013, 19.9, 23):
        np.testing.assert_allclose(
            law(float(t)), reference_feedforward_torque(model, prof, float(t)),
            rtol=1e-11, atol=1e-9,
        )


def reference_simulate(
    model: Wang2022Spacecraft,
    torque: object,
    t_end: float,
    edges: np.ndarray,
    samples: np.ndarray,
    x0: np.ndarray,
) -> np.ndarray:
    """The integration as solve_ivp does it, one call per segment, the reference rhs."""
    state = x0.copy()
    out = np.empty((samples.size, STATE_SIZE))
    filled = np.zeros(samples.size, dtype=bool)
    for t0, t1 in zip(edges[:-1], edges[1:], strict=True):
        eps = 1e-9 * (t1 - t0)

        def fun(t: float, x: np.ndarray, t0: float = t0, t1: float = t1, eps: float = eps):
            tau = np.asarray(torque(min(max(t, t0 + eps), t1 - eps), x), dtype=float)  # type: ignore[operator]
            return reference_rhs(model, t, x, tau)

        mask = (samples >= t0) & (samples <= t1) & ~filled
        t_seg = samples[mask]
        if t_seg.size == 0 or t_seg[-1] < t1:
            t_seg = np.append(t_seg, t1)
        sol = solve_ivp(
            fun, (t0, t1), state, method="DOP853", rtol=1e-9, atol=1e-11,
            t_eval=t_seg, first_step=min(t1 - t0, 0.05),
        )
        assert sol.success
        out[mask] = sol.y[:, : int(mask.sum())].T
        filled |= mask
        state = sol.y[:, -1].copy()
        state[0:4] /= np.linalg.norm(state[0:4])
    assert filled.all()
    return out


class _SlewThenCoast:
    """A torque law cut to zero from t_cut on (a breakpoint): a short slew, then a coast."""

    def __init__(self, law: PathTrackingTorque | FeedforwardTorque, t_cut: float) -> None:
        self.law, self.t_cut = law, t_cut

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        return self.law(t, x) if t < self.t_cut else np.zeros(3)

    def floats(self, t: float, x: list[float]) -> tuple[float, float, float]:
        return self.law.floats(t, x) if t < self.t_cut else (0.0, 0.0, 0.0)


@pytest.mark.parametrize("drive", ["tracked", "feedforward", "plain-callable"])
def test_simulate_matches_solve_ivp_per_segment(
    drive: str, profile: VariableAmplitudeProfile
) -> None:
    """Breakpoints every grid step, samples on breakpoints, inside steps and at t = 0."""
    model = Wang2022Spacecraft()
    plant = model.perturbed(1.05, 0.01)
    t_end = 0.9
    breakpoints = profile.interval_times_s[:31]  # the slew's grid to 0.6 s, then a coast
    if drive == "tracked":
        law: object = _SlewThenCoast(PathTrackingTorque(plant, profile), breakpoints[-1])
    elif drive == "feedforward":
        law = _SlewThenCoast(FeedforwardTorque(model, profile), breakpoints[-1])
    else:  # no float path: the simulator's array call
        base = _SlewThenCoast(FeedforwardTorque(model, profile), breakpoints[-1])

        def law(t: float, x: np.ndarray) -> np.ndarray:
            return base(t, x) + 5.0 * x[4:7]

    samples = np.concatenate(
        [[0.0], breakpoints[3:10], np.linspace(0.6, t_end, 17), [0.6137, 0.8]]
    )
    samples = np.unique(samples)
    x0 = np.zeros(STATE_SIZE)
    x0[0] = 1.0
    x0[7:13] = 1e-3  # the wing starts out of rest: the coast is not trivial
    res = simulate(plant, law, t_end, x0=x0, breakpoints=breakpoints, t_eval=samples)  # type: ignore[arg-type]
    edges = np.unique(np.concatenate([[0.0, t_end], breakpoints[breakpoints > 0.0]]))
    ref = reference_simulate(plant, law, t_end, edges, samples, x0)
    ref[:, 0:4] /= np.linalg.norm(ref[:, 0:4], axis=1, keepdims=True)
    scale = np.max(np.abs(ref), axis=0) + 1e-30
    # round-off apart (3e-14 measured): a sample from the wrong step or segment, or a step
    # straddling a breakpoint, is off by 1e-7 here
    np.testing.assert_allclose(res.state / scale, ref / scale, rtol=0.0, atol=1e-10)
    assert np.max(np.abs(res.omega)) > 1e-3 and np.ptp(res.eta[:, 0]) > 1e-4
    np.testing.assert_array_equal(res.state[0], x0)
    taus = np.array(
        [law(min(t, t_end - 1e-9 * t_end), x) for t, x in zip(res.t, res.state, strict=True)]  # type: ignore[operator]
    )
    np.testing.assert_allclose(res.torque, taus, rtol=1e-9, atol=1e-9)


def test_simulate_rejects_an_unknown_method() -> None:
    with pytest.raises(ValueError, match="method"):
        simulate(Wang2022Spacecraft(), lambda t, x: np.zeros(3), 1.0, method="Euler")
    # scipy's other solvers still run
    res = simulate(
        Wang2022Spacecraft(wing_rate_rad_s=0.0), lambda t, x: np.array([10.0, 0.0, 0.0]),
        0.05, method="RK45",
    )
    assert res.omega[-1, 0] > 0.0 and math.isfinite(res.omega[-1, 0])
