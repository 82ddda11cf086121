"""`harness model [RIG] [--json]`: what the rig model gives, from its physics.

The constrained (hub clamped) and hub-free natural frequencies of the flexible appendage,
the coupling coefficients delta (kg m) between hub and beam, the damping ratios and the tip's
mode shape phi(L), beside paper 003's (Xu 2018) values. RIG is a built-in rig's name
(``sgsrt``, ``sgsrt-canopen``, ...) or a rig file's path; nothing is sent on a bus.
"""

from __future__ import annotations

import argparse
import json
import sys

from harness.commands import examples


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("model", help="print the rig model's frequencies, coupling, mode shapes",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog=examples("harness model", "harness model my-rig.yaml --json"))
    p.add_argument("rig", nargs="?", default="sgsrt",
                   help="rig name or YAML path (default sgsrt)")
    p.add_argument("--json", action="store_true", help="JSON on stdout")
    p.set_defaults(func=cmd_model)


def cmd_model(args: argparse.Namespace) -> int:
    # numpy and scipy only when the model is built (start-up of `harness --help`)
    from rig_models.model_report import model_report
    from rig_models.paper003 import PAPER_003
    from rig_models.rig_file import load_rig
    from rig_models.schema import ConfigError

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
