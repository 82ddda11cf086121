"""Parman 2022 satellite: ACM plate element, FE satellite, simulation, study plumbing."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg as sla

from rig_models.reference.parman2022_satellite import (
    AcmPlateElement,
    SatelliteParameters,
    TorqueSchedule,
    build_satellite,
    rectangular_plate,
    simulate,
)

E, NU, T, RHO = 0.6e8, 0.3, 0.03, 120.0
D_PLATE = E * T**3 / (12 * (1 - NU**2))
PAPER_FREQS = (0.3354, 1.082)  # REFERENCE.md, seed 002


@pytest.fixture(scope="module")
def satellite():
    return build_satellite()


@pytest.fixture(scope="module")
def satellite_no_offset():
    return build_satellite(SatelliteParameters(offset_angle_deg=0.0))


def _plate_freqs(mesh, fixed: set[int], n: int = 3) -> np.ndarray:
    free = [k for k in range(mesh.stiffness.shape[0]) if k not in fixed]
    w2 = sla.eigh(
        mesh.stiffness[np.ix_(free, free)], mesh.mass[np.ix_(free, free)], eigvals_only=True
    )
    return np.sqrt(w2[:n])


# ------------------------------------------------------------------ element sanity


def test_element_rigid_modes_mass_and_symmetry():
    el = AcmPlateElement(1.5, 1.2, E, NU, T, RHO)
    assert np.allclose(el.stiffness, el.stiffness.T)
    eig = np.linalg.eigvalsh(el.stiffness)
    assert np.sum(np.abs(eig) < 1e-9 * eig.max()) == 3  # w = const and two tilts
    translation = np.zeros(12)
    translation[0::3] = 1.0
    assert translation @ el.mass @ translation == pytest.approx(RHO * T * 1.5 * 1.2)
    assert np.all(np.linalg.eigvalsh(el.mass) > 0)


def test_simply_supported_square_plate_exact_frequency():
    # SSSS square plate: w11 = 2 pi^2 sqrt(D / rho t) / a^2 (exact)
    a, n = 2.0, 8
    mesh = rectangular_plate(
        n, n, a, a, youngs_modulus_pa=E, poisson_ratio=NU, thickness_m=T, density_kg_m3=RHO
    )
    fixed: set[int] = set()
    for i in range(n + 1):
        for j in range(n + 1):
            w, tx, ty = mesh.dofs(i, j)
            if i in (0, n):  # edge along y: w = 0, slope along it (dw/dy = theta_x) = 0
                fixed |= {w, tx}
            if j in (0, n):  # edge along x: w = 0, dw/dx = -theta_y = 0
                fixed |= {w, ty}
    exact = 2 * math.pi**2 / a**2 * math.sqrt(D_PLATE / (RHO * T))
    assert _plate_freqs(mesh, fixed)[0] == pytest.approx(exact, rel=0.01)


def test_clamped_square_plate_leissa_frequency():
    a, n = 1.0, 8
    mesh = rectangular_plate(
        n, n, a, a, youngs_modulus_pa=E, poisson_ratio=NU, thickness_m=T, density_kg_m3=RHO
    )
    fixed = {
        d for i in range(n + 1) for j in range(n + 1) if i in (0, n) or j in (0, n)
        for d in mesh.dofs(i, j)
    }  # fmt: skip
    leissa = 35.985 / a**2 * math.sqrt(D_PLATE / (RHO * T))  # CCCC square, Leissa (1969)
    assert _plate_freqs(mesh, fixed)[0] == pytest.approx(leissa, rel=0.02)


def _clamped_panel_freqs(nx: int, ny: int) -> np.ndarray:
    mesh = rectangular_plate(
        nx, ny, 12.0, 2.4, youngs_modulus_pa=E, poisson_ratio=NU, thickness_m=T,
        density_kg_m3=RHO,
    )  # fmt: skip
    return _plate_freqs(mesh, {d for j in range(ny + 1) for d in mesh.dofs(0, j)}, n=2)


def test_clamped_panel_between_beam_bounds_and_mesh_converged():
    """One paper panel (12 x 2.4 m) clamped at its root. A free-edged strip bends between
    Euler-Bernoulli with E b t^3 / 12 (narrow: no Poisson stiffening) and with D b (wide);
    the paper's 8 x 2 mesh is within 0.5 % of a 32 x 8 mesh."""
    coarse, fine = _clamped_panel_freqs(8, 2), _clamped_panel_freqs(32, 8)
    assert coarse == pytest.approx(fine, rel=5e-3)
    m_per_l = RHO * T * 2.4
    for k, lam in enumerate((1.8751, 4.6941)):
        lo = lam**2 * math.sqrt(E * 2.4 * T**3 / 12 / (m_per_l * 12.0**4))
        hi = lam**2 * math.sqrt(D_PLATE * 2.4 / (m_per_l * 12.0**4))
        assert lo < fine[k] < hi


# ------------------------------------------------------------------ satellite


def test_satellite_dofs_and_inertia(satellite):
    assert satellite.n_elastic == 144
    assert satellite.n_dof == 150
    i = satellite.inertia_kg_m2
    # hand calculation from Tables 1-2: hub + two panels (y from 1.8 to 13.8 m, width 2.4 m
    # turned 30 deg about Y_b)
    m_p = RHO * T * 12 * 2.4
    span = 2 * m_p / 12 * (13.8**3 - 1.8**3) / 3
    width = 2 * m_p * 2.4**2 / 12
    assert i[0, 0] == pytest.approx(2 * 500 * 0.25 + 2 * 550 * 1.96 + span + width / 4)
    assert i[2, 2] == pytest.approx(2 * 400 * 0.16 + 2 * 500 * 0.25 + span + 0.75 * width)
    assert i[0, 2] == pytest.approx(width * math.sin(math.radians(60)) / 2)  # the paper's 43
    assert satellite.total_mass_kg == pytest.approx(2900 + 2 * m_p)
    np.testing.assert_allclose(satellite.mass, satellite.mass.T)
    assert satellite.node_positions_m[26] == pytest.approx(
        [1.2 * math.cos(math.radians(30)), 13.8, -1.2 * math.sin(math.radians(30))]
    )


def _with_z_masses(mass_kg: float) -> SatelliteParameters:
    base = SatelliteParameters()
    return SatelliteParameters(
        lumped_masses=tuple(
            replace(m, mass_kg=mass_kg) if m.mass_kg == 550.0 else m for m in base.lumped_masses
        )
    )


def test_printed_inertia_confirms_the_geometry_and_points_at_table1():
    """The paper prints I (17731, 2580, 15557, Ixz 43). Our 30 deg geometry gives its Izz and
    Ixz to 0.01 kg m^2 (so the offset is a turn about Y_b, the same for both panels); Ixx and
    Iyy both come out 196 kg m^2 low, which is exactly 2 x 50 kg x 1.4^2: with 600 kg instead
    of Table 1's 550 kg at z = +-1.4 m all four printed components are met."""
    printed = {"Ixx": 17731.0, "Iyy": 2580.0, "Izz": 15557.0, "Ixz": 43.0}
    idx = {"Ixx": (0, 0), "Iyy": (1, 1), "Izz": (2, 2), "Ixz": (0, 2)}
    as_printed = build_satellite().inertia_kg_m2
    assert as_printed[idx["Izz"]] == pytest.approx(printed["Izz"], abs=0.5)
    assert as_printed[idx["Ixz"]] == pytest.approx(printed["Ixz"], abs=0.5)
    for key in ("Ixx", "Iyy"):
        assert printed[key] - as_printed[idx[key]] == pytest.approx(2 * 50 * 1.4**2, abs=1.0)
    heavy = build_satellite(_with_z_masses(600.0)).inertia_kg_m2
    for key, value in printed.items():
        assert heavy[idx[key]] == pytest.approx(value, abs=0.6), key


def test_thirty_degree_offset_misses_the_papers_frequencies(satellite):
    """As specified (30 deg offset, Table 1 masses) the first two roll/yaw-coupled frequencies
    are 0.3592 and 1.1189 rad/s, +7.1 % / +3.4 % from the paper's 0.3354 / 1.082; with the
    inertia matched to the paper's printed values (600 kg) still +5.2 % / +2.5 %. This is the
    reported mismatch (docs/claims.md), held as a regression value, not a pass against the paper."""
    freqs = satellite.roll_yaw_frequencies()[:2]
    assert freqs == pytest.approx((0.3592, 1.1189), rel=2e-3)
    heavy = build_satellite(_with_z_masses(600.0)).roll_yaw_frequencies()[:2]
    assert heavy == pytest.approx((0.3530, 1.1091), rel=2e-3)
    assert heavy[0] > PAPER_FREQS[0] * 1.02  # the 2 % criterion is not met
    omega, vecs = satellite.natural_frequencies()
    # the lowest elastic mode (symmetric bending, ~0.155 rad/s) is not excited by torques
    assert omega[0] == pytest.approx(0.1547, rel=5e-3)
    assert np.abs(vecs[3:6, 0]).max() < 1e-9


def test_coupled_frequency_follows_the_inertia_about_the_bending_axis(satellite_no_offset):
    """The first coupled frequency is governed by the hub inertia about the panels' bending
    axis (cos d, 0, -sin d): at 0 deg it is Ixx alone and the model lands within 0.3 % of the
    paper's pair; with the printed Ixx (600 kg) at 0 deg, -1.8 %. Sensitivity, not a match."""
    freqs = satellite_no_offset.roll_yaw_frequencies()[:2]
    assert freqs == pytest.approx((0.3363, 1.0851), rel=2e-3)
    no_offset_heavy = build_satellite(
        replace(_with_z_masses(600.0), offset_angle_deg=0.0)
    ).roll_yaw_frequencies()[:2]
    assert no_offset_heavy == pytest.approx((0.3295, 1.0762), rel=2e-3)


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="panel_thickness_m"):
        SatelliteParameters(panel_thickness_m=0.0)
    with pytest.raises(ValueError, match="poisson_ratio"):
        AcmPlateElement(1, 1, E, 0.7, T, RHO)
    with pytest.raises(ValueError, match="node"):
        build_satellite().w_dof_of_node(99)


def test_torque_schedule_from_impulses():
    sch = TorqueSchedule.from_impulses(
        [([0, 2, 4], [1, -2, 1]), ([1, 3], [0.5, -0.5]), ([0], [0])], 8.0
    )
    assert sch.at(0.5) == pytest.approx([8, 0, 0])
    assert sch.at(2.5) == pytest.approx([-8, 4, 0])
    assert sch.at(5.0) == pytest.approx([0, 0, 0])


def test_simulation_conserves_angular_momentum(satellite):
    """Rows 3:6 of eq. (1) with no orbit rate: I theta' + A d' = integral of the torque."""
    model = build_satellite(SatelliteParameters(orbit_rate_rad_s=0.0))
    sch = TorqueSchedule.from_impulses([([0, 3.3], [1, -1]), ([0.7], [0]), ([1.1], [0])], 8.0)
    sim = simulate(model, sch, duration_s=6.0, step_s=0.1)
    momentum = sim.qdot @ model.mass[3:6, :].T
    expected = np.outer(np.minimum(sim.time_s, 3.3) * 8.0, [1, 0, 0])
    np.testing.assert_allclose(momentum, expected, atol=1e-9 * 8 * 3.3)
    # and it deflected the panel tip
    assert np.abs(sim.q[:, model.w_dof_of_node(27)]).max() > 1e-3


def _simulate_plain(model, schedule, *, duration_s, step_s, initial_attitude_rad=(0, 0, 0)):
    # simulate()'s plain form: a fresh matrix exponential per sub-interval, the switches
    # inside each step and the torque found per step
    n = model.n_dof
    m_inv = np.linalg.inv(model.mass)
    a = np.zeros((2 * n, 2 * n))
    a[:n, n:] = np.eye(n)
    a[n:, :n] = -m_inv @ model.stiffness
    a[n:, n:] = -m_inv @ model.damping
    b = np.zeros((2 * n, 3))
    b[n:, :] = m_inv[:, 3:6]

    def discretise(dt):
        aug = np.zeros((2 * n + 3, 2 * n + 3))
        aug[: 2 * n, : 2 * n] = a * dt
        aug[: 2 * n, 2 * n :] = b * dt
        e = sla.expm(aug)
        return e[: 2 * n, : 2 * n], e[: 2 * n, 2 * n :]

    n_steps = int(round(duration_s / step_s))
    times = np.arange(n_steps + 1) * step_s
    phi, gam = discretise(step_s)
    x = np.zeros(2 * n)
    x[3:6] = np.asarray(initial_attitude_rad, dtype=float)
    out = np.empty((n_steps + 1, 2 * n))
    out[0] = x
    switches = schedule.times_s
    for k in range(n_steps):
        t0, t1 = times[k], times[k + 1]
        inner = switches[(switches > t0 + 1e-12) & (switches < t1 - 1e-12)]
        if inner.size == 0:
            x = phi @ x + gam @ schedule.at(t0)
        else:
            t = t0
            for ts in [*inner, t1]:
                ph, gm = discretise(ts - t)
                x = ph @ x + gm @ schedule.at(t)
                t = ts
        out[k + 1] = x
    return out


def test_simulate_and_a_shared_discretisation_match_the_plain_simulation(satellite):
    # the switches and torques are looked up for all steps at once and a
    # Discretisation shares the matrix exponentials between runs: the same numbers exactly
    from rig_models.reference.parman2022_satellite import Discretisation

    # switches inside steps, on step boundaries (0.4, 1.0) and two in one step (1.23, 1.27)
    sch_a = TorqueSchedule.from_impulses(
        [([0.4, 1.23, 1.27, 2.05], [1, -1, -1, 1]), ([0.33, 1.0], [1, -1]), ([0.0], [0.0])], 8.0
    )
    sch_b = TorqueSchedule.from_impulses(
        [([0.55], [0.0]), ([0.33, 1.0], [1, -1]), ([0.2, 0.9, 1.6], [-1, 2, -1])], 8.0
    )
    kw = dict(duration_s=2.5, step_s=0.1, initial_attitude_rad=(0.01, -0.02, 0.03))
    shared = Discretisation(satellite, max_kept=3)  # small: entries are dropped and redone
    for sch in (sch_a, sch_b, sch_a):
        plain = _simulate_plain(satellite, sch, **kw)
        alone = simulate(satellite, sch, **kw)
        reused = simulate(satellite, sch, discretisation=shared, **kw)
        assert len(shared._kept) <= 3
        for sim in (alone, reused):
            np.testing.assert_array_equal(np.hstack([sim.q, sim.qdot]), plain)
    with pytest.raises(ValueError, match="another model"):
        simulate(build_satellite(SatelliteParameters(offset_angle_deg=0.0)), sch_a,
                 discretisation=shared, **kw)
    t = np.array([-1.0, 0.0, 0.2, 0.33, 0.5, 0.9, 1.0, 1.6, 3.0])
    np.testing.assert_array_equal(sch_b.at_times(t), np.array([sch_b.at(x) for x in t]))


def test_shaped_roll_leaves_much_less_residual_than_bang_bang(satellite_no_offset):
    """On the zero-offset satellite (coupled frequencies within 0.3 % of the paper's) the
    paper's LHHL roll sequence leaves a small fraction of the bang-bang residual at node 27,
    whose period is the first mode's."""
    model = satellite_no_offset
    i_xx = model.inertia_kg_m2[0, 0]
    tau = math.sqrt(math.radians(3) * i_xx / 8.0)
    none = ([0.0], [0.0])
    bb = simulate(
        model,
        TorqueSchedule.from_impulses([([0, tau, 2 * tau], [1, -2, 1]), none, none], 8.0),
        duration_s=2 * tau + 40,
        step_s=0.05,
    )
    lhhl_times = (0, 1.240, 3.270, 8.730, 21.229, 26.689, 28.719, 29.959)
    sh = simulate(
        model,
        TorqueSchedule.from_impulses(
            [(lhhl_times, [0.5, -0.5, 1, -1, -1, 1, -0.5, 0.5]), none, none], 8.0
        ),
        duration_s=lhhl_times[-1] + 40,
        step_s=0.05,
    )
    k = model.w_dof_of_node(27)
    res_bb = np.abs(bb.q[bb.time_s > 2 * tau, k]).max()
    res_sh = np.abs(sh.q[sh.time_s > lhhl_times[-1], k]).max()
    assert 1.0 < res_bb < 1.6
    assert res_sh < 0.05 * res_bb
    w = bb.q[bb.time_s > 2 * tau, k]
    crossings = np.flatnonzero(np.diff(np.sign(w)) != 0)
    period = 2 * np.median(np.diff(bb.time_s[bb.time_s > 2 * tau][crossings]))
    assert period == pytest.approx(2 * math.pi / model.roll_yaw_frequencies()[0], rel=0.02)


# ------------------------------------------------------------------ study plumbing


def test_study_recording_and_first_extremum(tmp_path):
    from harness.studies.parman2022 import CaseResult, _first_extremum, write_rrd

    t = np.linspace(0, 10, 501)
    w = -np.sin(t) * np.exp(-0.01 * t)
    assert t[_first_extremum(w, 0.1)] == pytest.approx(math.pi / 2, abs=0.03)
    case = CaseResult(
        name="demo case", end_s=1.0, first_peak_m=1.0, first_peak_time_s=1.0, peak_m=1.0,
        peak_time_s=1.0, residual_m=0.1, period_s=6.28, final_attitude_deg=(0, 0, 0),
        attitude_ripple_deg=(0, 0, 0), time_s=t, attitude_deg=np.zeros((t.size, 3)),
        w27_m=w, torque_n_m=np.zeros((t.size, 3)),
    )  # fmt: skip
    path = tmp_path / "p.rrd"
    write_rrd(path, [case])
    assert path.stat().st_size > 1000


@pytest.mark.slow
def test_study_runs_end_to_end(paper_suites):
    """The whole study, as paper002's suite runs it (`harness study parman2022 --json`,
    128 starts, 100 s; shared for the session by conftest's paper_suites: it runs once)."""
    out = paper_suites.document("parman2022-satellite")
    assert out["model"]["elastic_dof"] == 144
    for row in out["table3"].values():
        assert row["constraints_met"]
        assert row["t8_diff_percent"] <= 1.0
    bb = out["cases"]["bang-bang"]
    assert bb["residual_m"] > 1.0
    for kind in ("LHHL", "HLLH"):
        assert out["cases"][kind]["residual_m"] < 0.1 * bb["residual_m"]
    m = out["measures"]  # the paper suite's flat measures
    assert m["lhhl_roll_constraints_met"] and m["hllh_yaw_constraints_met"]
    assert m["lhhl_roll_t8_diff_percent"] == out["table3"]["LHHL roll"]["t8_diff_percent"]
    assert abs(m["lhhl_roll_paper_sequence_impulse_error_percent"]) < 1e-6
    assert m["paper_sequences_over_limit_count"] == 3
    assert 6.0 < m["fe_as_specified_mode1_freq_error_percent"] < 8.0
