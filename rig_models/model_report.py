"""What the rig model gives, from its physics (``harness model``): the constrained and
hub-free frequencies, the coupling coefficients, the tip's mode shape, beside paper 003's."""

from __future__ import annotations

import math
from typing import Any

from rig_models.paper003 import PAPER_003
from rig_models.rig_file import RigConfig


def model_report(rig: RigConfig) -> dict[str, Any]:
    """The model's figures as ``harness model --json`` prints them."""
    plant = rig.plant
    modes = rig.beam_modes
    free, _ = plant.hub_free_modes()
    return {
        "rig": rig.name,
        "source": rig.source,
        "inertia_kg_m2": plant.inertia_kg_m2,
        "beam_mass_kg": rig.beam_spec.mass_kg,
        "beam_rigid_inertia_kg_m2": modes.rigid_inertia_kg_m2,
        "constrained_omega_rad_s": modes.omega_rad_s.tolist(),
        "constrained_freq_hz": (modes.omega_rad_s / (2 * math.pi)).tolist(),
        "hub_free_omega_rad_s": free.tolist(),
        "hub_free_freq_hz": (free / (2 * math.pi)).tolist(),
        "coupling_kg_m": modes.coupling_kg_m.tolist(),
        "tip_mode_shape": modes.tip_deflection.tolist(),
        "damping_ratio": plant.damping_ratio.tolist(),
        "paper_003": PAPER_003,
    }
