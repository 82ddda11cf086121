"""`harness model [RIG.yaml] [--json]`: what the rig model gives, from its physics."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from rig_models.rig_file import RigConfig, load_rig
from rig_models.schema import ConfigError

# Paper 003 (Xu 2018) values, for the comparison column only.
PAPER_003 = {
    "constrained_omega_rad_s": [2.11, 13.28, 37.15],
    "coupling_kg_m": [2.65, 0.54, 0.21],
    "hub_free_omega_rad_s": [2.8081, 13.643],
    "hub_free_measured_omega_rad_s": [2.7382, 13.9487],
}


def model_report(rig: RigConfig) -> dict[str, Any]:
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


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("model", help="print the rig model's frequencies, coupling, mode shapes")
    p.add_argument("rig", nargs="?", default="sgsrt", help="rig name or YAML path")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.set_defaults(func=cmd_model)


def cmd_model(args: argparse.Namespace) -> int:
    try:
        report = model_report(load_rig(args.rig))
    except ConfigError as exc:
        print(f"harness: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    paper = PAPER_003
    print(f"rig {report['rig']} ({report['source']}): J = {report['inertia_kg_m2']} kg m^2, "
          f"beam {report['beam_mass_kg']:.3f} kg, rigid inertia "
          f"{report['beam_rigid_inertia_kg_m2']:.3f} kg m^2")
    print(f"{'mode':>4} {'constrained rad/s':>18} {'paper':>7} {'hub-free rad/s':>15} "
          f"{'paper':>7} {'Hz':>7} {'delta kg m':>11} {'paper':>6} {'phi(L)':>8}")
    for i, w in enumerate(report["constrained_omega_rad_s"]):
        pc = paper["constrained_omega_rad_s"][i] if i < 3 else float("nan")
        hf = report["hub_free_omega_rad_s"][i]
        ph = paper["hub_free_omega_rad_s"][i] if i < 2 else float("nan")
        pd = paper["coupling_kg_m"][i] if i < 3 else float("nan")
        print(f"{i + 1:>4} {w:>18.4f} {pc:>7.3f} {hf:>15.4f} {ph:>7.4f} "
              f"{report['hub_free_freq_hz'][i]:>7.4f} {report['coupling_kg_m'][i]:>11.4f} "
              f"{pd:>6.2f} {report['tip_mode_shape'][i]:>8.4f}")
    return 0
