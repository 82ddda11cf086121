"""The rig model against closed forms and against paper 003 (REFERENCE.md)."""

from __future__ import annotations

import numpy as np
import pytest

from rig_models.beam import BeamSpec, beam_modes, cantilever_omega_exact
from rig_models.rig_file import load_rig

# paper 003 values (comparison only)
PAPER_CONSTRAINED = [2.11, 13.28, 37.15]
PAPER_DELTA_1 = 2.65
PAPER_HUB_FREE = [2.8081, 13.643]


@pytest.fixture(scope="module")
def rig():
    return load_rig("sgsrt")


def test_elements_converge_to_exact_cantilever():
    spec = BeamSpec(2.48, 0.2, 0.0025, 70e9, 2700.0, 0.05, n_elements=40)
    fe = beam_modes(spec, 4).omega_rad_s
    exact = cantilever_omega_exact(spec, 4)
    np.testing.assert_allclose(fe, exact, rtol=1e-5)


def test_constrained_frequencies_match_paper(rig):
    w = rig.beam_modes.omega_rad_s
    np.testing.assert_allclose(w[:3], PAPER_CONSTRAINED, rtol=0.015)


def test_coupling_delta1_matches_paper(rig):
    assert abs(rig.beam_modes.coupling_kg_m[0] - PAPER_DELTA_1) / PAPER_DELTA_1 < 0.03


def test_hub_free_modes_near_paper(rig):
    """Ours 2.882 / 13.341 rad/s against the paper's calculated 2.8081 / 13.643: within 3 %.
    The paper's J = 15 kg m^2 and its coupling [2.65 0.54 0.21] (modes 2, 3 larger than a
    uniform Euler-Bernoulli beam gives) are not fully consistent; see docs/papers.md."""
    free, _ = rig.plant.hub_free_modes()
    rel = np.abs(free[:2] - PAPER_HUB_FREE) / PAPER_HUB_FREE
    assert np.all(rel < 0.03), rel
    # hub-free modes are stiffer than clamped ones (the hub moves against the beam)
    assert np.all(free > rig.beam_modes.omega_rad_s)


def test_modes_are_mass_normalised_and_rigid_inertia_closed_form(rig):
    m = rig.beam_modes
    gen_mass = np.einsum("ij,ik,kj->j", m.shapes, m.mass, m.shapes)
    np.testing.assert_allclose(gen_mass, 1.0, rtol=1e-10)
    spec = rig.beam_spec
    r0, r1 = spec.hub_radius_m, spec.hub_radius_m + spec.length_m
    closed = spec.density_kg_m3 * spec.area_m2 * (r1**3 - r0**3) / 3.0
    assert m.rigid_inertia_kg_m2 == pytest.approx(closed, rel=1e-9)


def test_tip_mass_lowers_frequencies():
    base = BeamSpec(2.48, 0.2, 0.0025, 70e9, 2700.0, 0.05)
    heavy = BeamSpec(2.48, 0.2, 0.0025, 70e9, 2700.0, 0.05, tip_mass_kg=0.5)
    assert np.all(beam_modes(heavy, 3).omega_rad_s < beam_modes(base, 3).omega_rad_s)


def test_bad_geometry_names_the_field():
    with pytest.raises(ValueError, match="thickness_m"):
        BeamSpec(2.48, 0.2, -1.0, 70e9, 2700.0, 0.05)
