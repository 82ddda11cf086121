"""`harness study xu2018`: paper 003 (Xu 2018) on the virtual SGSRT, as one study.

Four parts, each what an existing command does, gathered so that one JSON holds every
measure the paper 003 suite judges (``measures``: flat names, unit in the name):

- ``model``: the rig model's constrained and hub-free frequencies and coupling delta beside
  the paper's (``harness model``);
- ``cases``: the run files ``case-a``, ``case-b``, ``case-c`` with every variant (beta 0.6,
  0.8, 1.0) on the virtual rig over CAN, their steady tip-acceleration amplitudes beside
  Table 2 (``harness run case-X`` then ``harness report table2``);
- ``identify``: the ``free-decay`` run and the identification of its modes, exactly as
  ``harness identify RUN_DIR`` (every free-decay window of the run's burst schedule),
  beside the model's hub-free modes;
- ``sweep``: the lambda x beta sweep on the rig model (``harness sweep``'s default grid,
  lambda against the hub-free mode).

``--only PART`` (repeatable) runs some parts. Run directories go to ``--out`` (``logs/``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from harness.core.identify import analysis_windows, identify_samples, load_windows, model_modes
from harness.core.runs import RunConfig, load_run
from harness.core.session import execute_run
from harness.studies.sweep import SweepSpec, run_sweep
from harness.studies.sweep_report import analyse
from rig_models.model_report import model_report
from rig_models.paper003 import PAPER_003, PAPER_TABLE1, PAPER_TABLE2
from rig_models.rig_file import load_rig

PARTS = ("model", "cases", "identify", "sweep")
CASES = ("case-a", "case-b", "case-c")


def _pct(ours: float, paper: float) -> float:
    return float(100 * (ours / paper - 1))


def model_part(rig_name: str = "sgsrt") -> tuple[dict[str, Any], dict[str, float]]:
    rep = model_report(load_rig(rig_name))
    m: dict[str, float] = {}
    for k, (ours, paper) in enumerate(zip(rep["constrained_omega_rad_s"],
                                          PAPER_003["constrained_omega_rad_s"], strict=False)):
        m[f"constrained_mode{k + 1}_error_percent"] = _pct(ours, paper)
    for k, (ours, paper) in enumerate(zip(rep["coupling_kg_m"], PAPER_003["coupling_kg_m"],
                                          strict=False)):
        # the sign of delta_2 is a mode-shape convention: compare magnitudes
        m[f"coupling_mode{k + 1}_error_percent"] = _pct(abs(ours), paper)
    for k, (ours, calc, meas) in enumerate(zip(rep["hub_free_omega_rad_s"],
                                               PAPER_003["hub_free_omega_rad_s"],
                                               PAPER_003["hub_free_measured_omega_rad_s"],
                                               strict=False)):
        m[f"hub_free_mode{k + 1}_vs_paper_calculated_percent"] = _pct(ours, calc)
        m[f"hub_free_mode{k + 1}_vs_paper_measured_percent"] = _pct(ours, meas)
    return rep, m


def _variant_runs(name: str, duration_s: float | None = None):
    base = load_run(name)
    extra = {} if duration_s is None else {"duration_s": duration_s}
    for vname, over in (base.data["variants"] or {}).items():
        yield vname, load_run(name, dict(over) | {"name": f"{base.name}-{vname}"} | extra)


RunSummary = Callable[[RunConfig, Path], tuple[dict[str, Any], Path]]


def _execute(run: RunConfig, out_dir: Path) -> tuple[dict[str, Any], Path]:
    result = execute_run(run, out_dir=out_dir, show_progress=False)
    return result.summary, result.run_dir


def cases_part(out_dir: Path, progress=None, duration_s: float | None = None,
               execute: RunSummary = _execute
               ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The nine case runs' steady amplitudes beside Table 2. ``execute(run, out_dir)`` gives
    a run's (summary, run directory): the runs made here by default, or ones already made
    (the paper suite's, read back by the tests, so that no case runs twice)."""
    rows: list[dict[str, Any]] = []
    m: dict[str, Any] = {}
    for case in CASES:
        amps: dict[float, float] = {}
        for _vname, run in _variant_runs(case, duration_s):
            if progress:
                progress(f"xu2018: running {run.name}")
            s, run_dir = execute(run, out_dir)
            if s.get("stopped_by") != "completed":
                raise RuntimeError(f"{run.name}: stopped by {s.get('stopped_by')}")
            beta = round(float(s["beta"]), 3)
            amp = float(s["steady_tip_accel_amplitude_m_s2"])
            amps[beta] = amp
            paper = PAPER_TABLE2[case].get(beta)
            rows.append({"case": case, "beta": beta, "frequency_ratio": s["frequency_ratio"],
                         "rotor_speed_rad_s": s["rotor_speed_rad_s"], "ours_m_s2": amp,
                         "paper_m_s2": paper, "run_dir": str(run_dir)})
            tag = f"{case.replace('-', '_')}_beta_{beta:.1f}".replace(".", "p")
            m[f"{tag}_amplitude_m_s2"] = amp
            if paper is not None:
                m[f"{tag}_over_paper"] = amp / paper
        worst = max(amps, key=amps.get)
        best = min(amps, key=amps.get)
        others = [v for b, v in amps.items() if b != 1.0]
        key = case.replace("-", "_")
        m[f"{key}_worst_beta"] = worst
        m[f"{key}_best_beta"] = best
        if 1.0 in amps and others:
            m[f"{key}_beta_1p0_over_largest_other"] = amps[1.0] / max(others)
    return rows, m


def identify_part(out_dir: Path, progress=None) -> tuple[dict[str, Any], dict[str, Any]]:
    run = load_run("free-decay")
    if progress:
        progress("xu2018: running free-decay")
    result = execute_run(run, out_dir=out_dir, show_progress=False)
    rec = load_windows(result.run_dir)  # the windows' samples only
    cfg = rec.cfg
    if analysis_windows(cfg) is None:
        raise RuntimeError(f"{result.run_dir}: no free-decay windows in its config")
    ident = identify_samples(rec)
    truth = model_modes(cfg)
    assert truth is not None
    modes = []
    m: dict[str, Any] = {"mode_count": len(ident.to_dict()["modes"])}
    worst_f = worst_z = 0.0
    for mode in ident.to_dict()["modes"]:
        i = int(np.argmin([abs(math.log(mode["omega_rad_s"] / w))
                           for w in truth["omega_rad_s"]]))
        f_err = _pct(mode["omega_rad_s"], truth["omega_rad_s"][i])
        z_err = _pct(mode["damping_ratio"], truth["damping_ratio"][i])
        modes.append({"model_mode": i + 1, "omega_rad_s": mode["omega_rad_s"],
                      "sigma_omega_rad_s": mode["sigma_omega_rad_s"],
                      "damping_ratio": mode["damping_ratio"],
                      "sigma_damping": mode["sigma_damping"],
                      "fft_peak_omega_rad_s": mode.get("fft_peak_omega_rad_s"),
                      "model_omega_rad_s": truth["omega_rad_s"][i],
                      "model_damping_ratio": truth["damping_ratio"][i],
                      "omega_error_percent": f_err, "damping_error_percent": z_err})
        m[f"mode{i + 1}_omega_rad_s"] = mode["omega_rad_s"]
        m[f"mode{i + 1}_omega_error_percent"] = f_err
        m[f"mode{i + 1}_damping_error_percent"] = z_err
        if i < 2:
            m[f"mode{i + 1}_vs_paper_measured_percent"] = _pct(
                mode["omega_rad_s"], PAPER_TABLE1["measured_fft"][i])
        worst_f = max(worst_f, abs(f_err))
        worst_z = max(worst_z, abs(z_err))
    m["worst_omega_error_percent"] = worst_f
    m["worst_damping_error_percent"] = worst_z
    return {"run_dir": str(result.run_dir), "modes": modes, "model_hub_free": truth}, m


def sweep_part(workers: int = 1, rig_name: str = "sgsrt") -> tuple[dict[str, Any],
                                                                   dict[str, Any]]:
    rig = load_rig(rig_name)
    w_ref = float(rig.plant.hub_free_modes()[0][0])
    lambdas = np.linspace(0.3, 3.2, 30)
    betas = np.linspace(0.3, 1.0, 8)
    spec = SweepSpec(lambdas, betas, w_ref, 0.4, 0.04, 0.6)
    amps = run_sweep(rig.plant, spec, workers)
    laws = analyse(lambdas, betas, amps)
    m: dict[str, Any] = {}
    for name, short in (("tip_deflection_m", "deflection"), ("tip_accel_m_s2", "accel")):
        law = laws[name]
        m[f"{short}_best_beta_median"] = law["best_beta_median_lambda_gt_0.5"]
        m[f"{short}_share_best_beta_in_0p6_0p85"] = law[
            "share_lambda_gt_0.5_with_best_beta_in_0.6_0.85"]
        m[f"{short}_resonance_near_lambda_1_count"] = sum(
            1 for lam in law["resonance_lambdas"] if abs(lam - 1.0) < 0.051)
    return {"omega_ref_rad_s": w_ref, "grid": [len(lambdas), len(betas)], "laws": laws}, m


def run_study(parts: tuple[str, ...] = PARTS, out_dir: Path = Path("logs"), workers: int = 1,
              progress=None, cases_duration_s: float | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"paper": {"table1_rad_s": PAPER_TABLE1, "model": PAPER_003,
                                     "table2_m_s2": {c: {str(b): v for b, v in t.items()}
                                                     for c, t in PAPER_TABLE2.items()}}}
    measures: dict[str, Any] = {}
    if "model" in parts:
        out["model"], m = model_part()
        measures |= {f"model_{k}": v for k, v in m.items()}
    if "cases" in parts:
        out["cases"], m = cases_part(out_dir, progress, cases_duration_s)
        measures |= m
    if "identify" in parts:
        out["identify"], m = identify_part(out_dir, progress)
        measures |= {f"identified_{k}": v for k, v in m.items()}
    if "sweep" in parts:
        if progress:
            progress("xu2018: sweep 30 x 8")
        out["sweep"], m = sweep_part(workers)
        measures |= {f"sweep_{k}": v for k, v in m.items()}
    out["measures"] = measures
    return out


def format_report(out: dict[str, Any]) -> str:
    lines = []
    if "model" in out:
        r = out["model"]
        lines.append("Rig model against paper 003 (rad/s; delta kg m):")
        for k in range(3):
            hf = r["hub_free_omega_rad_s"][k]
            lines.append(f"  mode {k + 1}: constrained {r['constrained_omega_rad_s'][k]:.4f}"
                         f" (paper {PAPER_003['constrained_omega_rad_s'][k]}), hub-free "
                         f"{hf:.4f}, delta {r['coupling_kg_m'][k]:+.4f} "
                         f"(paper {PAPER_003['coupling_kg_m'][k]})")
    if "cases" in out:
        lines.append("Cases A/B/C, steady tip acceleration amplitude (m/s^2):")
        for row in out["cases"]:
            lines.append(f"  {row['case']} beta {row['beta']:.1f}: ours {row['ours_m_s2']:.4f}"
                         f", paper {row['paper_m_s2']:.3f}")
    if "identify" in out:
        lines.append("Identified modes (free-decay run) against the model's hub-free modes:")
        for md in out["identify"]["modes"]:
            lines.append(f"  mode {md['model_mode']}: {md['omega_rad_s']:.4f} rad/s "
                         f"({md['omega_error_percent']:+.3f} %), zeta "
                         f"{md['damping_ratio']:.4f} ({md['damping_error_percent']:+.2f} %)")
    if "sweep" in out:
        m = out["measures"]
        lines.append(f"Sweep: best beta median {m['sweep_deflection_best_beta_median']:.2f} "
                     f"(deflection), share in [0.6, 0.85]: "
                     f"{m['sweep_deflection_share_best_beta_in_0p6_0p85']:.2f} (deflection), "
                     f"{m['sweep_accel_share_best_beta_in_0p6_0p85']:.2f} (acceleration)")
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    parts = tuple(args.only) if args.only else PARTS
    out = run_study(parts, args.out, args.workers,
                    progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    if args.json:
        print(json.dumps(out, indent=1, default=float))
    else:
        print(format_report(out))
    return 0


def register_study(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "xu2018", help="paper 003 on the virtual rig: model, cases A/B/C, identified modes, "
        "ratio sweep", description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print results as JSON on stdout")
    parser.add_argument("--only", action="append", choices=PARTS, metavar="PART",
                        help=f"run only this part ({', '.join(PARTS)}); repeatable")
    parser.add_argument("--out", type=Path, default=Path("logs"),
                        help="directory for the run directories (default logs/)")
    parser.add_argument("--workers", type=int, default=1,
                        help="processes for the sweep (default 1)")
    parser.set_defaults(func=_run)
