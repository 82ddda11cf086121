"""Piezo patches on the rig's beam: gains from the physics, sensing and actuation on the bus."""

from __future__ import annotations

import numpy as np
import pytest

from rig_models.beam import BeamSpec, beam_modes
from rig_models.devices import PiezoAmplifier
from rig_models.piezo import PiezoPatch, patch_gains, slope_difference
from rig_models.rig_file import load_rig


def test_patch_gains_follow_the_slope_difference():
    spec = BeamSpec(2.48, 0.2, 0.0025, 70e9, 2700.0, 0.05)
    modes = beam_modes(spec, 3)
    patch = PiezoPatch(0.0, 0.31, 0.08, 0.0005)
    g = patch_gains(modes, spec, patch)
    dphi = slope_difference(modes, patch)
    # a root patch: the slope difference is the slope at its end
    np.testing.assert_allclose(dphi, modes.shapes[2 * 4 + 1], rtol=1e-12)  # node 5 = 0.31 m
    m_per_v = 61e9 * 171e-12 * 0.08 * (0.0025 + 0.0005)
    np.testing.assert_allclose(g.actuator, m_per_v * dphi)
    np.testing.assert_allclose(g.sensor, 0.5 * m_per_v / patch.capacitance_f * dphi)


def test_collocated_patch_energy_balance():
    """A static actuator voltage: the work of the patch moments equals the strain energy."""
    rig = load_rig("sgsrt")
    g = rig.piezo_gains[0]
    w = rig.beam_modes.omega_rad_s
    eta = g.actuator * 100.0 / w**2  # static modal response to 100 V
    work = 0.5 * 100.0 * g.actuator @ eta
    strain = 0.5 * np.sum(w**2 * eta**2)
    assert work == pytest.approx(strain, rel=1e-12)


def test_amplifier_trips_on_over_current():
    amp = PiezoAmplifier(max_voltage_v=200, max_current_a=0.1, capacitance_f=(1e-6, 1e-6),
                         dt_s=0.002)
    amp.command(100.0, 0.0)  # 1e-6 * 100 / 0.002 = 0.05 A: fine
    assert amp.voltages_v == (100.0, 0.0) and not amp.overcurrent
    amp.command(-200.0, 0.0)  # 0.15 A: trips
    assert amp.overcurrent and amp.voltages_v == (0.0, 0.0)
    amp.command(10.0, 10.0)
    assert amp.voltages_v == (0.0, 0.0)


def test_bad_patch_names_the_key():
    from rig_models.rig_file import rig_from_dict
    from rig_models.schema import ConfigError

    data = dict(load_rig("sgsrt").data)
    data["piezo_patches"] = [{"start_m": 2.4, "length_m": 0.3, "width_m": 0.08,
                              "thickness_m": 0.0005}]
    with pytest.raises(ConfigError, match="piezo_patches"):
        _ = rig_from_dict(data, "rig file x.yaml").piezo_gains
