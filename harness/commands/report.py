"""`harness report table2 [--logs DIR]`: our case A/B/C amplitudes beside paper 003's Table 2.

Reads the newest ``summary.json`` of every ``case-X-beta-B`` run under the logs directory
(run them first with ``harness run case-a`` etc.).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

# Paper 003 (Xu 2018), Table 2: tip acceleration amplitude (m/s^2). Comparison only.
PAPER_TABLE2 = {
    "case-a": {0.6: 0.020, 0.8: 0.025, 1.0: 0.041},
    "case-b": {0.6: 0.043, 0.8: 0.046, 1.0: 0.072},
    "case-c": {0.6: 0.018, 0.8: 0.023, 1.0: 0.037},
}


def collect(logs: Path) -> dict[str, dict[float, dict]]:
    found: dict[str, dict[float, dict]] = {}
    for path in sorted(logs.glob("*/summary.json")):  # names start with UTC time: newest last
        try:
            s = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        case = next((c for c in PAPER_TABLE2 if str(s.get("run", "")).startswith(c)), None)
        if case is None or s.get("steady_tip_accel_amplitude_m_s2") is None:
            continue
        if s.get("stopped_by") != "completed":
            continue
        found.setdefault(case, {})[round(float(s["beta"]), 3)] = s | {"dir": str(path.parent)}
    return found


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="print our results beside a paper's table",
                       description=__doc__)
    p.add_argument("table", choices=["table2"], help="table2: paper 003 cases A/B/C")
    p.add_argument("--logs", type=Path, default=Path("logs"), help="logs directory (./logs)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_report)


def cmd_report(args: argparse.Namespace) -> int:
    found = collect(args.logs)
    if not found:
        print(f"harness report: no case-a/b/c runs under {args.logs}; run "
              "'harness run case-a' (and case-b, case-c) first", file=sys.stderr)
        return 1
    rows = []
    for case, paper in PAPER_TABLE2.items():
        for beta, p_val in paper.items():
            s = found.get(case, {}).get(beta)
            rows.append({"case": case, "beta": beta, "paper_m_s2": p_val,
                         "ours_m_s2": None if s is None else s["steady_tip_accel_amplitude_m_s2"],
                         "frequency_ratio": None if s is None else s["frequency_ratio"],
                         "rotor_speed_rad_s": None if s is None else s["rotor_speed_rad_s"],
                         "run_dir": None if s is None else s["dir"]})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("Tip acceleration amplitude, steady state (m/s^2): ours (virtual rig over CAN) "
          "beside paper 003 Table 2")
    print(f"{'case':<7} {'lambda':>6} {'w_m rad/s':>9} {'beta':>5} {'paper':>7} {'ours':>8} "
          f"{'ours/paper':>10}")
    for r in rows:
        ours = r["ours_m_s2"]
        print(f"{r['case']:<7} {r['frequency_ratio'] or float('nan'):>6.2f} "
              f"{r['rotor_speed_rad_s'] or float('nan'):>9.3f} {r['beta']:>5.1f} "
              f"{r['paper_m_s2']:>7.3f} "
              + (f"{ours:>8.4f} {ours / r['paper_m_s2']:>10.2f}" if ours is not None
                 else f"{'(no run)':>8}"))
    for case in PAPER_TABLE2:
        vals = {b: s["steady_tip_accel_amplitude_m_s2"] for b, s in found.get(case, {}).items()}
        if len(vals) == 3:
            largest = max(vals, key=vals.get)
            print(f"{case}: largest at beta {largest:g} (paper: beta 1.0)")
    return 0
