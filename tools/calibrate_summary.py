"""Markdown tables of one or more `harness calibrate` results (docs/calibrate.md's tables).

    .venv/bin/python tools/calibrate_summary.py logs/*-calibrate-*/results.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _e(x: float | None) -> str:
    return "-" if x is None else f"{x:.2e}"


def summary(paths: list[Path]) -> str:
    lines = ["| rig | actuator | identified modes (rad/s, damping) | candidate | added s | "
             "worst V in band (%) | impulse (N m s) / firings | fitted (m/s^2) | ratio fitted "
             "(2-sigma floor) | truth (m/s^2) | ratio truth | recommended |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in paths:
        d = json.loads(p.read_text())
        modes = "; ".join(f"{m['omega_rad_s']:.4f} +- {m['sigma_omega_rad_s']:.2g}, "
                          f"{m['damping_ratio']:.4f}" for m in d["identified_modes"])
        rig = Path(d["rig"]).stem
        b = d["baseline"]
        lines.append(f"| {rig} | {d['actuator']} | {modes} | unshaped | 0 | 100 | - | "
                     f"{_e(b['fitted']['peak_m_s2'])} | 1 | "
                     f"{_e(b['truth']['peak_m_s2'] if b['truth'] else None)} | 1 | |")
        for c in d["candidates"]:
            m = c.get("measured")
            if not c["feasible"] or m is None:
                continue
            worst = " / ".join(f"{v:.2g}" for v in c["worst_percent"])
            floor = f"{m.get('ratio_resolvable', float('nan')):.1f}"
            truth = m["truth"]["peak_m_s2"] if m.get("truth") else None
            fuel = ("-" if c.get("impulse_n_m_s") is None
                    else f"{c['impulse_n_m_s']:.4f} / {c['firings']}")
            lines.append(
                f"| {rig} | {d['actuator']} | | {c['label']} | {c['added_s']:.3f} | {worst} | "
                f"{fuel} | "
                f"{_e(m['fitted']['peak_m_s2'])} | {m['ratio_fitted']:.1f} ({floor}) | "
                f"{_e(truth)} | {m.get('ratio_truth', float('nan')):.1f} | "
                f"{'**yes**' if c['key'] == d['recommended'] else ''} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(summary([Path(a) for a in sys.argv[1:]]))
