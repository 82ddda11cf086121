"""`harness study wang2022`: variable-amplitude ZV / ZVD slews of Wang, Wu & Zou (2022).

Rest-to-rest slew of the paper's spacecraft (rotating solar wing, six constrained modes) from
zero to Euler angles [60, 45, 30] deg in 20 s. For each shaper the acceleration profile is
solved by SQP (``harness.shaping.variable_amplitude``) on the nominal, undamped design model;
then the plant differs from the design (modal frequencies +5 %, +10 %; modal damping 0.01)
and we measure what is left after the slew.

Two ways of driving the plant (the paper does not say which it used):

* ``tracked``: the planned acceleration is imposed on the plant (an ideal attitude loop during
  the slew, torque off after it). This is the premise of the shaper (eq 23): the wing then
  responds with its true frequencies and damping, and the residual vibration moves the free
  body after t_f.
* ``feedforward``: the open-loop torque computed on the nominal design model (inverse
  dynamics of eq 1) is applied to the plant.

Everything is computed here from our models and solvers; the paper's statements appear only
in ``PAPER_WANG2022`` as the comparison column.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from harness.shaping.variable_amplitude import (
    FeedforwardTorque,
    ManeuverSpec,
    PathTrackingTorque,
    VariableAmplitudeProfile,
    prescribed_motion_residual,
    solve_variable_amplitude,
    summarize,
)
from rig_models.reference.wang2022_spacecraft import (
    SimulationResult,
    Wang2022Spacecraft,
    quaternion_angle_error,
    simulate,
)

# Paper (REFERENCE.md, section 004; Wang 2022 section 4.3 and conclusions 2-3). The paper
# gives its robustness results as figures and words only; comparison column only.
PAPER_WANG2022: dict[str, Any] = {
    "maneuver": "Euler angles 0 -> [60, 45, 30] deg in 20 s, rest to rest",
    "freq_error_5pct": "ZVD keeps residual vibration small, ZV does not "
    "(ZV: large residual, body rate oscillates, attitude drifts from target)",
    "freq_error_10pct": "ZVD keeps residual vibration small, ZV does not",
    "damping_0p01": "ZV residual vibration grows markedly; ZVD hardly increases it",
    "nominal": "both shapers reach the target; residual vibration very small",
}

SHAPERS = ("zv", "zvd")
SENSITIVITY_RATIOS = (0.9, 0.95, 1.0, 1.05, 1.1)


@dataclass(frozen=True)
class PlantCase:
    key: str
    label: str
    frequency_scale: float = 1.0
    damping_ratio: float = 0.0
    paper_key: str = "nominal"


DEFAULT_CASES = (
    PlantCase("nominal", "nominal"),
    PlantCase("freq_plus5", "freq +5 %", 1.05, 0.0, "freq_error_5pct"),
    PlantCase("freq_plus10", "freq +10 %", 1.10, 0.0, "freq_error_10pct"),
    PlantCase("damping_0p01", "damping 0.01", 1.0, 0.01, "damping_0p01"),
)
NEGATIVE_CASES = (
    PlantCase("freq_minus5", "freq -5 %", 0.95, 0.0, "freq_error_5pct"),
    PlantCase("freq_minus10", "freq -10 %", 0.90, 0.0, "freq_error_10pct"),
)


def run_case(
    model: Wang2022Spacecraft,
    profile: VariableAmplitudeProfile,
    case: PlantCase,
    drive: str,
    coast_s: float,
) -> tuple[dict[str, Any], SimulationResult]:
    """Simulate one plant case under one drive; metrics over the coast after the slew."""
    plant = model.perturbed(case.frequency_scale, case.damping_ratio)
    if drive == "tracked":
        law: FeedforwardTorque | PathTrackingTorque = PathTrackingTorque(plant, profile)
    elif drive == "feedforward":
        law = FeedforwardTorque(model, profile)
    else:
        raise ValueError(f"drive: expected 'tracked' or 'feedforward', got {drive!r}")
    t_f = profile.spec.duration_s
    t_eval = np.concatenate(
        [np.arange(0.0, t_f, 0.02), np.linspace(t_f, t_f + coast_s, int(coast_s / 0.025) + 1)]
    )
    result = simulate(plant, law, t_f + coast_s, breakpoints=law.breakpoints, t_eval=t_eval)
    q_target = profile.spec.target_quaternion
    err_deg = np.degrees(quaternion_angle_error(result.q, q_target))
    tip = result.eta @ model.tip_gain
    during = result.t < t_f
    after = result.t >= t_f
    i_f = int(np.argmax(after))
    metrics = {
        "eta_residual": np.max(np.abs(result.eta[after]), axis=0).tolist(),
        "eta1_residual": float(np.max(np.abs(result.eta[after, 0]))),
        "tip_residual_m": float(np.max(np.abs(tip[after]))),
        "tip_peak_during_slew_m": float(np.max(np.abs(tip[during]))),
        "attitude_error_tf_deg": float(err_deg[i_f]),
        "attitude_error_end_deg": float(err_deg[-1]),
        "body_rate_residual_rad_s": float(np.max(np.linalg.norm(result.omega[after], axis=1))),
        "peak_torque_n_m": float(np.max(np.abs(result.torque))),
    }
    return metrics, result


def sensitivity_table(
    model: Wang2022Spacecraft, profiles: dict[str, VariableAmplitudeProfile]
) -> dict[str, Any]:
    """Mode residuals left at t_f with the plan imposed (eq 23), vs plant frequency / damping."""
    table: dict[str, Any] = {"ratios": list(SENSITIVITY_RATIOS)}
    for name, profile in profiles.items():
        rows = [
            prescribed_motion_residual(model.perturbed(r), profile).tolist()
            for r in SENSITIVITY_RATIOS
        ]
        damped = prescribed_motion_residual(model.perturbed(1.0, 0.01), profile).tolist()
        table[name] = {"by_ratio": rows, "damping_0.01": damped}
    return table


def run_study(
    *,
    dt_s: float = 0.005,
    coast_s: float = 20.0,
    drives: tuple[str, ...] = ("tracked", "feedforward"),
    cases: tuple[PlantCase, ...] = DEFAULT_CASES,
    modes: tuple[int, ...] = (0, 1, 2, 3, 4, 5),
    reference: bool = True,
    progress: Any = None,
) -> tuple[dict[str, Any], dict[str, SimulationResult]]:
    """The whole study; returns (JSON-ready results, histories keyed 'drive/shaper/case')."""

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    model = Wang2022Spacecraft()
    profiles: dict[str, VariableAmplitudeProfile] = {}
    names = (("none",) if reference else ()) + SHAPERS
    for name in names:
        spec = ManeuverSpec(dt_s=dt_s, shaper=name, modes=modes)
        start = time.perf_counter()
        profiles[name] = solve_variable_amplitude(model, spec)
        say(
            f"{name}: SQP converged in {profiles[name].iterations} iterations, "
            f"{time.perf_counter() - start:.1f} s"
        )
    sens = sensitivity_table(model, profiles)
    results: dict[str, Any] = {
        "maneuver": {
            "target_euler_deg": [60.0, 45.0, 30.0],
            "euler_sequence": "3-2-1 (yaw z, pitch y, roll x)",
            "duration_s": 20.0,
            "dt_s": dt_s,
            "shaped_modes": [m + 1 for m in modes],
            "coast_s": coast_s,
            "wing_rate_deg_s": math.degrees(model.wing_rate_rad_s),
            "tip_gain_assumption": f"uniform cantilever, length {model.wing_length_m} m",
        },
        "solver": {name: summarize(p) for name, p in profiles.items()},
        "sensitivity_prescribed_motion": sens,
        "robustness": {},
        "paper": PAPER_WANG2022,
    }
    histories: dict[str, SimulationResult] = {}
    for drive in drives:
        rows = []
        for case in cases:
            row: dict[str, Any] = {"case": case.key, "label": case.label}
            for shaper in SHAPERS:
                start = time.perf_counter()
                metrics, hist = run_case(model, profiles[shaper], case, drive, coast_s)
                row[shaper] = metrics
                histories[f"{drive}/{shaper}/{case.key}"] = hist
                say(f"{drive} {shaper} {case.label}: {time.perf_counter() - start:.1f} s")
            row["paper"] = PAPER_WANG2022[case.paper_key]
            rows.append(row)
        results["robustness"][drive] = rows
    results["measures"] = claim_measures(results)
    return results, histories


def _ratio_name(r: float) -> str:
    return f"{r:.2f}".replace(".", "p")


def claim_measures(results: dict[str, Any]) -> dict[str, float | bool]:
    """Flat, named scalars (unit in the name; none = a ratio) that the paper suite's
    criteria read (``measures.<name>``), computed from the study's results."""
    m: dict[str, float | bool] = {}
    for name, solve in results["solver"].items():
        m[f"{name}_sqp_converged"] = bool(solve["converged"])
        m[f"{name}_end_attitude_error_deg"] = abs(float(solve["end_attitude_error_deg"]))
    sens = results["sensitivity_prescribed_motion"]
    if "zv" in sens and "zvd" in sens:
        for k, r in enumerate(sens["ratios"]):
            zv, zvd = sens["zv"]["by_ratio"][k][0], sens["zvd"]["by_ratio"][k][0]
            m[f"mode1_zv_residual_at_{_ratio_name(r)}"] = float(zv)
            m[f"mode1_zvd_residual_at_{_ratio_name(r)}"] = float(zvd)
            if r != 1.0:  # both vanish at the design frequency
                m[f"mode1_zvd_over_zv_at_{_ratio_name(r)}"] = float(zvd / zv)
        zv, zvd = sens["zv"]["damping_0.01"][0], sens["zvd"]["damping_0.01"][0]
        m["mode1_zvd_over_zv_damping_0p01"] = float(zvd / zv)
    for drive, rows in results["robustness"].items():
        for row in rows:
            zv, zvd = row["zv"], row["zvd"]
            base = f"{drive}_{row['case']}"
            m[f"{base}_zv_tip_residual_m"] = float(zv["tip_residual_m"])
            m[f"{base}_zvd_tip_residual_m"] = float(zvd["tip_residual_m"])
            m[f"{base}_zvd_over_zv_tip_residual"] = float(
                zvd["tip_residual_m"] / zv["tip_residual_m"])
            m[f"{base}_zv_attitude_error_deg"] = float(zv["attitude_error_tf_deg"])
            m[f"{base}_zvd_attitude_error_deg"] = float(zvd["attitude_error_tf_deg"])
    return m


# ------------------------------------------------------------------------------ reporting


def _fmt(x: float) -> str:
    return f"{x:.2e}"


def format_tables(results: dict[str, Any]) -> str:
    lines = []
    man = results["maneuver"]
    lines.append(
        f"Wang 2022: slew to {man['target_euler_deg']} deg ({man['euler_sequence']}) in "
        f"{man['duration_s']} s, dt {man['dt_s']} s, shaped modes {man['shaped_modes']}"
    )
    lines.append("")
    lines.append("SQP (trust-constr) convergence")
    lines.append("shaper | status | iter | v(chi) eq 28 | max |A chi| | end att. err (deg)")
    for name, s in results["solver"].items():
        lines.append(
            f"{name:6} | {s['status']} {'ok' if s['converged'] else 'FAILED'} | "
            f"{s['iterations']:4d} | {s['smoothness_v']:.3f} | {s['max_linear_residual']:.1e} | "
            f"{s['end_attitude_error_deg']:.1e}"
        )
    lines.append("")
    sens = results["sensitivity_prescribed_motion"]
    lines.append(
        "Mode-1 amplitude left at t_f with the plan imposed (eq 23), vs plant/design frequency"
    )
    header = " | ".join(f"{r:.2f}" for r in sens["ratios"]) + " | zeta 0.01"
    lines.append(f"shaper | {header}")
    for name in results["solver"]:
        vals = [row[0] for row in sens[name]["by_ratio"]] + [sens[name]["damping_0.01"][0]]
        lines.append(f"{name:6} | " + " | ".join(_fmt(v) for v in vals))
    for drive, rows in results["robustness"].items():
        lines.append("")
        lines.append(
            f"Robustness, drive '{drive}': max over {man['coast_s']:.0f} s after the slew "
            "(eta_1 modal amplitude, kg^0.5 m; tip deflection, mm); attitude error (deg)"
        )
        lines.append(
            "case | eta1 ZV | eta1 ZVD | tip ZV | tip ZVD | att@tf ZV | att@tf ZVD | "
            "att@end ZV | att@end ZVD | paper"
        )
        for row in rows:
            zv, zvd = row["zv"], row["zvd"]
            lines.append(
                f"{row['label']} | {_fmt(zv['eta1_residual'])} | {_fmt(zvd['eta1_residual'])} | "
                f"{1e3 * zv['tip_residual_m']:.3g} | {1e3 * zvd['tip_residual_m']:.3g} | "
                f"{zv['attitude_error_tf_deg']:.1e} | {zvd['attitude_error_tf_deg']:.1e} | "
                f"{zv['attitude_error_end_deg']:.3g} | {zvd['attitude_error_end_deg']:.3g} | "
                f"{row['paper']}"
            )
    return "\n".join(lines)


def write_recording(
    path: str,
    histories: dict[str, SimulationResult],
    model: Wang2022Spacecraft,
    q_target: np.ndarray,
) -> None:
    """Histories to a Rerun .rrd (columnar sends, no viewer): wang2022/drive/shaper/case/..."""
    import rerun as rr

    from harness.record.recording import close_stream
    from harness.record.streams import sweep_orphans
    from harness.review.names import log_multi_series_names

    rec = rr.RecordingStream("sgsrt_wang2022")
    rec.save(path)
    for key, hist in histories.items():
        times = [rr.TimeColumn("time", duration=hist.t)]
        base = f"wang2022/{key}"
        series = {
            "eta": hist.eta,
            "tip_deflection_m": (hist.eta @ model.tip_gain)[:, None],
            "body_rate_rad_s": hist.omega,
            "torque_n_m": hist.torque,
            "quaternion": hist.q,
            "attitude_error_deg": np.degrees(quaternion_angle_error(hist.q, q_target))[:, None],
        }
        legends = {
            "eta": [f"mode {i + 1}" for i in range(hist.eta.shape[1])],
            "tip_deflection_m": ["tip deflection"],
            "body_rate_rad_s": ["x", "y", "z"],
            "torque_n_m": ["x", "y", "z"],
            "quaternion": ["q0 (scalar)", "q1", "q2", "q3"],
            "attitude_error_deg": ["attitude error"],
        }
        for name, values in series.items():
            log_multi_series_names(rec, f"{base}/{name}", legends[name][: values.shape[1]])
            rec.send_columns(
                f"{base}/{name}", indexes=times, columns=rr.Scalars.columns(scalars=values)
            )
    try:
        close_stream(rec, path)  # bounded: a full disk's stuck sink never hangs the study
    finally:
        del rec
        sweep_orphans()  # the stream dropped: its threads end


def _run(args: argparse.Namespace) -> int:
    drives = ("tracked", "feedforward") if args.drive == "both" else (args.drive,)
    cases = DEFAULT_CASES + (NEGATIVE_CASES if args.negative_errors else ())

    def progress(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    try:
        results, histories = run_study(
            dt_s=args.dt, coast_s=args.coast, drives=drives, cases=cases, progress=progress
        )
    except (RuntimeError, ValueError) as exc:
        print(f"wang2022: {exc}", file=sys.stderr)
        return 1
    if args.rrd:
        write_recording(
            args.rrd, histories, Wang2022Spacecraft(), ManeuverSpec().target_quaternion
        )
        progress(f"recording written to {args.rrd}")
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(format_tables(results))
    return 0


def register_study(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "wang2022",
        help="Wang 2022: variable-amplitude ZV/ZVD slew of a spacecraft with a rotating wing",
    )
    parser.add_argument("--json", action="store_true", help="print results as JSON on stdout")
    parser.add_argument("--rrd", metavar="PATH", help="write the histories to a Rerun .rrd file")
    parser.add_argument(
        "--drive",
        choices=("tracked", "feedforward", "both"),
        default="both",
        help="impose the planned acceleration on the plant (tracked), apply the open-loop "
        "design torque (feedforward), or both (default)",
    )
    parser.add_argument(
        "--negative-errors", action="store_true", help="also run plant frequencies -5 %% and -10 %%"
    )
    parser.add_argument("--dt", type=float, default=0.005, help="shaper grid dt, s (default 0.005)")
    parser.add_argument(
        "--coast", type=float, default=20.0, help="time simulated after the slew, s (default 20)"
    )
    parser.set_defaults(func=_run)
