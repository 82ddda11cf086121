"""`harness study shaped-rig`: shaped slews on the virtual SGSRT over CAN.

Every slew is a built-in run file (``harness/runs/slew-rw-*.yaml``,
``slew-thruster-*.yaml``) executed through the harness (``execute_run``: CAN bus, drivers,
virtual rig, recording). The shapers are designed with the modes in the run files, which
were identified from a free decay with ``harness identify`` (``--identify`` repeats that now,
the same way: ``free-decay``'s windows from its burst schedule, ``identify_windows``, and
designs with the fresh numbers instead). The wheel shapers use all three identified modes;
the thruster runs list all three but design for the first two (``design_modes``); their
``damped-zv3`` variants then convolve that design with a ZV shaper for mode 3
(``extra_zv_modes``), every fractional level made by PWM.

Residual vibration, one definition for every run: the tip acceleration over the window
``[end + 0.1 s, end + 0.1 s + W]``, ``end`` being the end of that run's own manoeuvre (every
actuator command zero from then on; 0.1 s lets the wheel's 10 ms torque lag and the valves'
4 ms closing delay die out), W = the run file's ``residual_window_s`` (6 s). Each run's
duration is set so the run ends at the window's end, so the summary's
``residual_tip_accel_m_s2`` / ``_rms_`` are this window's. Three readings of it:

* ``measured``: peak and rms of the recorded accelerometer signal. Its noise (0.005 m/s^2
  rms, 0.02 m/s^2 peaks over 6 s) floors both, well above what a shaped slew leaves.
* ``fitted``: a least-squares fit of the identified modes' free decay (damped sinusoids at
  their frequency and damping, one per mode in the run file, plus an offset) to the recorded
  signal over the window; the peak of the fitted vibration, and each mode's amplitude at the
  window's start. Noise averages out over the ~3000 samples (``sigma``: the
  fit's 1-sigma uncertainty of that signal at its worst point). This is what the lab rig
  would measure; the study's 10x checks use it.
* ``truth``: the noise-free tip acceleration of the virtual rig's own state (its final state
  propagated back over the window; the window is free motion), every mode included.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from harness.calibration.residual import fit_modal_residual, true_residual
from harness.controllers.shaped_wheel_slew import Mode, parse_modes
from harness.controllers.thruster_two_level import damped_residual_percent
from harness.core.identify import analysis_windows, identify_samples, load_windows
from harness.core.runs import RunConfig, build_controller, load_run
from harness.core.session import execute_run

MARGIN_S = 0.1  # after the manoeuvre's end, before the residual window

# Paper 002 (Parman 2022), REFERENCE.md section 002: the satellite's roll / yaw manoeuvres
# (T = 8 N m). Comparison column only (relative duration and impulse against bang-bang).
PAPER_PARMAN2022: dict[str, Any] = {
    "torque_n_m": 8.0,
    "bang_bang_duration_s": {"roll": 21.528, "yaw": 16.444},
    "t8_s": {"LHHL": {"roll": 29.959, "yaw": 24.974}, "HLLH": {"roll": 24.973, "yaw": 24.010}},
    "impulse_n_m_s": {"LHHL": {"roll": 97.28, "yaw": 57.52},
                      "HLLH": {"roll": 99.36, "yaw": 58.0}},
}
# Paper 004 (Wang 2022), REFERENCE.md section 004: words only.
PAPER_WANG2022 = "frequency error 5 % and 10 %: ZVD keeps residual vibration small, ZV does not"


@dataclass(frozen=True)
class Slew:
    key: str  # row key in the results
    run: str  # built-in run file
    variant: str | None
    label: str


WHEEL_SLEWS = (
    Slew("unshaped", "slew-rw-unshaped", None, "unshaped bang-bang"),
    *(Slew(f"{s}-{v}", f"slew-rw-{s}", f"modes-{v}", f"{s.upper()}, modes {lbl}")
      for s in ("zv", "zvd", "ei")
      for v, lbl in (("exact", "as identified"), ("minus-10", "-10 %"), ("plus-10", "+10 %"))),
)
THRUSTER_SLEWS = (
    Slew("bang-bang", "slew-thruster-bangbang", None, "bang-bang (full couple)"),
    Slew("lhhl-paper", "slew-thruster-lhhl", "paper", "LHHL, paper's design (undamped)"),
    Slew("hllh-paper", "slew-thruster-hllh", "paper", "HLLH, paper's design (undamped)"),
    Slew("lhhl-damped", "slew-thruster-lhhl", "damped", "LHHL, damped design"),
    Slew("hllh-damped", "slew-thruster-hllh", "damped", "HLLH, damped design"),
    Slew("lhhl-damped-zv3", "slew-thruster-lhhl", "damped-zv3",
         "LHHL, damped design * ZV mode 3"),
    Slew("hllh-damped-zv3", "slew-thruster-hllh", "damped-zv3",
         "HLLH, damped design * ZV mode 3"),
)


# --------------------------------------------------------------------------- residuals


# --------------------------------------------------------------------------- runs


def slew_run(slew: Slew, modes: Sequence[Mode] | None = None,
             window_s: float | None = None) -> tuple[RunConfig, Any]:
    """The run of ``slew`` with its duration set to end at the residual window's end (and
    the modes / window replaced if given). Returns the run and its controller."""
    base = load_run(slew.run)
    over: dict[str, Any] = {}
    if slew.variant is not None:
        variants = base.data["variants"] or {}
        if slew.variant not in variants:
            raise ValueError(f"{slew.run}: no variant {slew.variant!r}")
        over = dict(variants[slew.variant])
        over["name"] = f"{base.name}-{slew.variant}"
    if modes is not None:
        ctrl = dict(over.get("controller", {}))
        ctrl["modes"] = [{"omega_rad_s": m.omega_rad_s, "damping_ratio": m.damping_ratio}
                         for m in modes]
        over["controller"] = ctrl
    if window_s is not None:
        over["residual_window_s"] = window_s
    run = load_run(slew.run, over)
    controller = build_controller(run)
    window = run.data["residual_window_s"]
    over["duration_s"] = round(controller.end_s + MARGIN_S + window, 6)
    run = load_run(slew.run, over)
    return run, build_controller(run)


def measure(slew: Slew, out_dir: Path, modes: Sequence[Mode] | None = None,
            window_s: float | None = None) -> dict[str, Any]:
    """Run one slew through the harness and read its residual vibration three ways."""
    run, controller = slew_run(slew, modes, window_s)
    result = execute_run(run, out_dir=out_dir, show_progress=False)
    s = result.summary
    if s["stopped_by"] != "completed":
        raise RuntimeError(f"{run.name}: stopped by {s['stopped_by']}: {s['error']} "
                           f"{s['faults']}")
    rec = result.columns()
    t = rec.time_s[: rec.rows]
    accel = rec.column("/tip/accel_m_s2")
    analysis_modes = parse_modes(run.controller["modes"])
    t0 = controller.end_s + MARGIN_S
    window = t >= t0 - 1e-9
    angle = rec.column("/attitude/angle_deg")
    row: dict[str, Any] = {
        "label": slew.label,
        "run": run.name,
        "run_dir": str(result.run_dir),
        "manoeuvre_s": controller.duration_s,
        "window_s": [t0, float(t[-1])],
        "measured": {"peak_m_s2": float(np.max(np.abs(accel[window]))),
                     "rms_m_s2": float(np.sqrt(np.mean(accel[window] ** 2)))},
        "fitted": fit_modal_residual(t, accel, analysis_modes, t0),
        "truth": true_residual(result.virtual_rig, t0),
        "target_deg": run.controller["angle_deg"],
        "final_angle_deg": float(np.mean(angle[window])),
        "summary_residual_m_s2": s["residual_tip_accel_m_s2"],
    }
    row["final_angle_error_deg"] = row["final_angle_deg"] - row["target_deg"]
    if "mode_scale" in run.controller:
        row["mode_scale"] = run.controller["mode_scale"]
        row["shaper"] = run.controller["shaper"]
        row["peak_torque_n_m"] = s["max_wheel_torque_cmd_n_m"]
    if hasattr(controller, "design"):
        d = controller.design
        couple = run.rig.section("thruster_valves")["couple_n_m"]
        on_time = float(rec.column("/thrusters/on_time_s")[-1])
        tau = d.bang_bang_duration_s / 2
        steps = np.diff(np.r_[0.0, controller.directions.astype(float), 0.0])
        k = np.flatnonzero(steps)
        ticks = np.rint(np.asarray(d.times_s) / run.dt_s) * run.dt_s
        row.update({
            "design": d.design,
            "design_modes": [[m.omega_rad_s, m.damping_ratio] for m in d.modes],
            "extra_zv_modes": list(run.controller.get("extra_zv_modes") or []),
            "design_residual_percent": list(d.damped_residual_percent),
            # V_d at every mode of the analysis (designed for or not), of the design's switch
            # times and of the valve schedule actually sent (ticks, PWM half couple)
            "analysis_residual_percent": damped_residual_percent(
                d.times_s, d.amplitudes, analysis_modes, tau).tolist(),
            "realised_residual_percent": damped_residual_percent(
                k * run.dt_s, steps[k], analysis_modes, tau).tolist(),
            # the design's levels exactly, its switch times rounded to ticks: the ticks' share
            # of the difference between the two above (the rest is the PWM's)
            "ticks_residual_percent": damped_residual_percent(
                ticks, d.amplitudes, analysis_modes, tau).tolist(),
            "design_undamped_residual_percent": list(d.undamped_residual_percent),
            "design_t8_s": d.t8_s,
            "design_search": {"starts": d.n_starts, "feasible": d.n_feasible,
                              "agree": d.n_agree},
            "firings": int(rec.column("/thrusters/firings")[-1]),
            "valve_on_time_s": on_time,
            "impulse_n_m_s": on_time * couple,
            "schedule": controller.usage,
        })
    return row


def identify_modes(out_dir: Path, n_modes: int | None = None,
                   free_decay: Any = None) -> tuple[tuple[Mode, ...], dict[str, Any]]:
    """Run ``free-decay`` through the harness (or take ``free_decay``, the result of such a
    run) and identify its modes as ``harness identify RUN_DIR`` does: every free-decay
    window of the run's burst schedule (``analysis_windows``), ``identify_windows``.
    ``n_modes``: the lowest N (default: every mode identified)."""
    if free_decay is None:
        free_decay = execute_run(load_run("free-decay"), out_dir=out_dir, show_progress=False)
    # the recording and config.yaml of the run directory, read as `harness identify` reads them
    rec = load_windows(Path(free_decay.run_dir))  # the windows' samples only
    if analysis_windows(rec.cfg) is None:
        raise ValueError(f"{free_decay.run_dir}: not a free-decay run (no free-decay windows)")
    ident = identify_samples(rec, n_modes=n_modes)
    modes = tuple(Mode(m.omega_rad_s, m.damping_ratio) for m in ident.modes)
    info = {"run_dir": str(free_decay.run_dir), "modes": [
        {"omega_rad_s": m.omega_rad_s, "sigma_omega_rad_s": m.sigma_omega_rad_s,
         "damping_ratio": m.damping_ratio, "sigma_damping": m.sigma_damping,
         "source": ident.experiment_label(m.experiment)}
        for m in ident.modes], "notes": list(ident.notes)}
    return modes, info


def ratios(rows: dict[str, dict[str, Any]], reference: str) -> None:
    """Add reference / this for the fitted and true residual peaks (in place)."""
    ref = rows[reference]
    for row in rows.values():
        row["ratio_fitted"] = ref["fitted"]["peak_m_s2"] / row["fitted"]["peak_m_s2"]
        row["ratio_truth"] = ref["truth"]["peak_m_s2"] / row["truth"]["peak_m_s2"]


def paper_relative() -> dict[str, dict[str, list[float]]]:
    """The paper's t8 and impulse relative to its bang-bang (roll, yaw), from PAPER_PARMAN2022."""
    p = PAPER_PARMAN2022
    out: dict[str, dict[str, list[float]]] = {}
    for kind in ("LHHL", "HLLH"):
        bb = p["bang_bang_duration_s"]
        out[kind] = {
            "duration": [p["t8_s"][kind][ax] / bb[ax] for ax in ("roll", "yaw")],
            "impulse": [p["impulse_n_m_s"][kind][ax] / (p["torque_n_m"] * bb[ax])
                        for ax in ("roll", "yaw")],
        }
    return out


def run_study(out_dir: Path, groups: Sequence[str] = ("wheel", "thruster"),
              identify_first: bool = False, window_s: float | None = None,
              progress: Callable[[str], None] = lambda msg: None) -> dict[str, Any]:
    results: dict[str, Any] = {"residual_definition": (
        f"tip acceleration over [end + {MARGIN_S} s, end + {MARGIN_S} s + window], end = the "
        "run's own manoeuvre end; measured (accelerometer, noise incl.), fitted (identified "
        "modes' free decay fitted to the measured signal), truth (noise-free rig state)"),
        "ratios_use": "fitted"}
    modes = None
    if identify_first:
        progress("shaped-rig: free decay and identification ...")
        modes, info = identify_modes(out_dir)
        results["identified"] = info
    for group, slews, ref in (("wheel", WHEEL_SLEWS, "unshaped"),
                              ("thruster", THRUSTER_SLEWS, "bang-bang")):
        if group not in groups:
            continue
        rows: dict[str, dict[str, Any]] = {}
        for slew in slews:
            progress(f"shaped-rig: {slew.run}" + (f" ({slew.variant})" if slew.variant else ""))
            rows[slew.key] = measure(slew, out_dir, modes, window_s)
        ratios(rows, ref)
        results[group] = rows
    results["checks"] = checks(results)
    results["measures"] = claim_measures(results)
    results["paper_parman2022_relative"] = paper_relative()
    results["paper_wang2022"] = PAPER_WANG2022
    return results


def claim_measures(results: dict[str, Any]) -> dict[str, Any]:
    """Flat, named scalars (unit in the name; none = a ratio) that the paper suites'
    criteria read (``measures.<name>``): per slew the residual (fitted and truth) and the
    unshaped / this ratios, and ZVD against ZV with the modes 10 % off."""
    m: dict[str, Any] = {}
    for group in ("wheel", "thruster"):
        for key, row in (results.get(group) or {}).items():
            k = f"{group}_{key.replace('-', '_')}"
            m[f"{k}_fitted_m_s2"] = float(row["fitted"]["peak_m_s2"])
            m[f"{k}_truth_m_s2"] = float(row["truth"]["peak_m_s2"])
            m[f"{k}_reduction_fitted"] = float(row["ratio_fitted"])
            m[f"{k}_reduction_truth"] = float(row["ratio_truth"])
            m[f"{k}_final_angle_error_deg"] = float(row["final_angle_error_deg"])
            if "design_t8_s" in row:
                m[f"{k}_manoeuvre_s"] = float(row["manoeuvre_s"])
                m[f"{k}_firings_count"] = int(row["firings"])
    wheel = results.get("wheel") or {}
    for off in ("minus_10", "plus_10"):
        zv, zvd = wheel.get(f"zv-{off.replace('_', '-')}"), wheel.get(
            f"zvd-{off.replace('_', '-')}")
        if zv and zvd:
            for kind in ("fitted", "truth"):
                m[f"wheel_zvd_over_zv_{off}_{kind}"] = float(
                    zvd[kind]["peak_m_s2"] / zv[kind]["peak_m_s2"])
    return m


def checks(results: dict[str, Any]) -> dict[str, bool]:
    """The study's claims (the 10x targets), on the fitted residual and on the truth."""
    out: dict[str, bool] = {}
    w = results.get("wheel")
    if w:
        for src in ("fitted", "truth"):
            out[f"wheel: ZVD (exact modes) >= 10x below unshaped [{src}]"] = (
                w["zvd-exact"][f"ratio_{src}"] >= 10)
            for v in ("minus-10", "plus-10"):
                out[f"wheel: ZVD below ZV, modes {v} [{src}]"] = (
                    w[f"zvd-{v}"][src]["peak_m_s2"] < w[f"zv-{v}"][src]["peak_m_s2"])
    th = results.get("thruster")
    if th:
        for src in ("fitted", "truth"):
            best = max((k for k in th if k != "bang-bang"), key=lambda k: th[k][f"ratio_{src}"])
            out[f"thrusters: best two-level ({best}) >= 10x below bang-bang [{src}]"] = (
                th[best][f"ratio_{src}"] >= 10)
    return out


# --------------------------------------------------------------------------- output


def _e(x: float) -> str:
    return f"{x:.2e}"


def _residual_row(r: dict[str, Any]) -> str:
    """One markdown row of the residual table."""
    return (f"| {r['label']} | {r['manoeuvre_s']:.3f} | {r['measured']['peak_m_s2']:.4f} / "
            f"{r['measured']['rms_m_s2']:.4f} | {_e(r['fitted']['peak_m_s2'])} +- "
            f"{_e(r['fitted']['sigma_m_s2'])} | {_e(r['truth']['peak_m_s2'])} | "
            f"{r['ratio_fitted']:.1f} | {r['ratio_truth']:.1f} | "
            f"{r['final_angle_error_deg']:+.4f} |")


def format_tables(results: dict[str, Any]) -> str:
    lines: list[str] = []
    if "identified" in results:
        lines.append("Modes identified now (free decay): " + ", ".join(
            f"{m['omega_rad_s']:.4f} rad/s zeta {m['damping_ratio']:.4f}"
            for m in results["identified"]["modes"]))
        lines.append("")
    head = ("| {} | manoeuvre (s) | measured peak / rms (m/s^2) | fitted peak +- 1 sigma "
            "(m/s^2) | truth peak (m/s^2) | ref / this: fitted | truth | final angle error "
            "(deg) |")

    def residual_table(title: str, rows: dict[str, Any]) -> None:
        lines.extend([title, "", head.format("slew"), "|---|---|---|---|---|---|---|---|"])
        lines.extend(_residual_row(r) for r in rows.values())
        lines.append("")

    w = results.get("wheel")
    if w:
        residual_table("Reaction-wheel slews, 20 deg, bang-bang 0.06 N m", w)
        lines.append(f"Paper 004 (Wang 2022): {PAPER_WANG2022}.")
        lines.append("")
    th = results.get("thruster")
    if th:
        residual_table("Thruster slews, 5 deg, couple 0.1 N m, fractional levels by PWM",
                       th)
        bb = th["bang-bang"]
        rel = results["paper_parman2022_relative"]
        n_modes = len(bb["analysis_residual_percent"])
        per_mode = " / ".join(str(i + 1) for i in range(n_modes))
        lines.append(f"| slew | modes designed for | V_d mode {per_mode} (%), design | V_d on the "
                     "valves (%) | firings | valve on-time (s) | impulse (N m s) | impulse / "
                     "bang-bang | duration / bang-bang | paper impulse / bang-bang (roll, yaw) "
                     "| paper duration / bang-bang (roll, yaw) |")
        lines.append("|---|---|---|---|---|---|---|---|---|---|---|")
        for key, r in th.items():
            kind = key.split("-")[0].upper()
            paper = rel.get(kind)
            pi = "" if paper is None else f"{paper['impulse'][0]:.2f}, {paper['impulse'][1]:.2f}"
            pd = "" if paper is None else (f"{paper['duration'][0]:.2f}, "
                                           f"{paper['duration'][1]:.2f}")
            vd = " / ".join(f"{v:.3g}" for v in r["analysis_residual_percent"])
            vr = " / ".join(f"{v:.3g}" for v in r["realised_residual_percent"])
            designed = len(r["design_modes"]) if r["design"] != "bang-bang" else "-"
            if r["extra_zv_modes"]:
                designed = f"{designed} + ZV " + ", ".join(map(str, r["extra_zv_modes"]))
            lines.append(
                f"| {r['label']} | {designed} | {vd} | {vr} | {r['firings']} | "
                f"{r['valve_on_time_s']:.3f} | "
                f"{r['impulse_n_m_s']:.4f} | {r['impulse_n_m_s'] / bb['impulse_n_m_s']:.2f} | "
                f"{r['manoeuvre_s'] / bb['manoeuvre_s']:.2f} | {pi} | {pd} |")
        lines.append("")
    lines.append("Checks (ratios on the fitted residual; the truth alongside):")
    for name, ok in results["checks"].items():
        lines.append(f"  {'PASS' if ok else 'FAIL'}  {name}")
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    groups = ("wheel", "thruster") if args.only is None else (args.only,)

    def progress(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    try:
        results = run_study(args.out, groups, args.identify, args.window_s, progress)
    except (RuntimeError, ValueError) as exc:
        print(f"shaped-rig: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(results, indent=2) if args.json else format_tables(results))
    return 0


def register_study(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "shaped-rig",
        help="shaped slews on the virtual rig over CAN: wheel ZV/ZVD/EI vs unshaped, "
        "thruster LHHL/HLLH vs bang-bang")
    p.add_argument("--json", action="store_true", help="print results as JSON on stdout")
    p.add_argument("--out", type=Path, default=Path("logs"),
                   help="parent directory of the run directories (default: ./logs)")
    p.add_argument("--only", choices=("wheel", "thruster"), help="run one group only")
    p.add_argument("--identify", action="store_true",
                   help="first run free-decay, identify its modes and design every shaper "
                   "with them (default: the identified modes in the run files)")
    p.add_argument("--window-s", type=float, help="residual window (s; default: the run "
                   "files' residual_window_s)")
    p.set_defaults(func=_run)
