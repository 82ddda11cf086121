"""`harness study parman2022`: two-amplitude shapers on the flexible satellite (seed 002).

Reproduces, from our own FE model and solver:
  1. the satellite model: DOF count, inertia, first roll/yaw-coupled frequencies;
  2. Table 3: the shortest LHHL / HLLH sequences for the paper's design problem (its inertia,
     T = 8 N m, roll 3 deg / yaw -2 deg, V(0.3354) < 0.001 %, V(1.082) < 1 %);
  3. the evaluator's V's of the paper's own published sequences;
  4. the manoeuvre (-3, -1, 2) deg -> 0 on our model: bang-bang on all axes, then LHHL and
     HLLH on roll and yaw (designed for our model's frequencies and inertia) with bang-bang
     pitch: node-27 residual / peak deflection, impulses, durations;
  5. a diagnostic: the same satellite with a zero panel offset angle, whose frequencies are
     the paper's, driven by the paper's own Table 3 sequences.
Paper numbers live only in PAPER_PARMAN2022 (quoted from REFERENCE.md) and are printed as
the "paper" column, except the design problem of item 2, which is the paper's input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from harness.shaping.two_amplitude import (
    ModeConstraint,
    TwoAmplitudeDesign,
    design_two_amplitude,
    evaluate_sequence,
    shaper_amplitudes,
)
from rig_models.reference.parman2022_satellite import (
    Discretisation,
    SatelliteModel,
    SatelliteParameters,
    TorqueSchedule,
    build_satellite,
    simulate,
)

# Quoted from /work/shared/REFERENCE.md (002, Parman 2022). The "paper" column only, plus
# the design problem of Table 3 (inertia, frequencies, limits), which the paper poses.
PAPER_PARMAN2022: dict = {
    "elastic_dof": 144,
    "inertia_kg_m2": {"Ixx": 17731.0, "Iyy": 2580.0, "Izz": 15557.0, "Ixz": 43.0},
    "freqs_rad_s": (0.3354, 1.082),
    "vmax_percent": (0.001, 1.0),
    "bang_bang_s": {"roll": 21.528, "pitch": 4.744, "yaw": 16.444},
    "bang_bang_residual_m": 1.46,
    "bang_bang_period_s": 18.73,
    "table3_s": {
        ("LHHL", "roll"): (0, 1.240, 3.270, 8.730, 21.229, 26.689, 28.719, 29.959),
        ("LHHL", "yaw"): (0, 1.630, 2.360, 5.140, 19.834, 22.614, 23.344, 24.974),
        ("HLLH", "roll"): (0, 6.040, 7.880, 8.220, 16.753, 17.093, 18.933, 24.973),
        ("HLLH", "yaw"): (0, 1.720, 2.420, 6.230, 17.780, 21.590, 22.290, 24.010),
    },
    "peak_deflection_m_at_s": {"LHHL": (0.55, 9.98), "HLLH": (0.62, 7.84)},
    "impulse_n_m_s": {
        ("LHHL", "roll"): 97.28,
        ("LHHL", "yaw"): 57.52,
        ("HLLH", "roll"): 99.36,
        ("HLLH", "yaw"): 58.0,
    },
    "fuel_on_s": {
        ("LHHL", "roll"): 13.400,
        ("LHHL", "yaw"): 8.820,
        ("HLLH", "roll"): 12.760,
        ("HLLH", "yaw"): 11.060,
    },
}

# The manoeuvre (the paper's section 3 and 5): inputs, not results.
TORQUE_N_M = 8.0
INITIAL_ATTITUDE_DEG = (-3.0, -1.0, 2.0)  # roll, pitch, yaw; target 0
AXES = ("roll", "pitch", "yaw")
KINDS = ("LHHL", "HLLH")
NODE = 27
STEP_S = 0.02
DURATION_S = 100.0


@dataclass(frozen=True)
class CaseResult:
    name: str
    end_s: float  # last torque switch
    first_peak_m: float  # |w27| at its first transient extremum (the paper's figure)
    first_peak_time_s: float
    peak_m: float  # max |w27| over the run
    peak_time_s: float
    residual_m: float  # max |w27| after the manoeuvre
    period_s: float | None  # dominant residual period from zero crossings
    final_attitude_deg: tuple[float, float, float]
    attitude_ripple_deg: tuple[float, float, float]  # max |angle| after the manoeuvre
    time_s: np.ndarray
    attitude_deg: np.ndarray
    w27_m: np.ndarray
    torque_n_m: np.ndarray

    def summary(self) -> dict:
        return {
            "end_s": self.end_s,
            "first_peak_m": self.first_peak_m,
            "first_peak_time_s": self.first_peak_time_s,
            "peak_m": self.peak_m,
            "peak_time_s": self.peak_time_s,
            "residual_m": self.residual_m,
            "period_s": self.period_s,
            "final_attitude_deg": self.final_attitude_deg,
            "attitude_ripple_deg": self.attitude_ripple_deg,
        }


def bang_bang(delta_rad: float, inertia_kg_m2: float, torque_n_m: float) -> tuple[list, list]:
    """Impulses (units of T) of the rest-to-rest bang-bang move by delta_rad (eq. 10)."""
    tau = math.sqrt(abs(delta_rad) * inertia_kg_m2 / torque_n_m)
    s = math.copysign(1.0, delta_rad)
    return [0.0, tau, 2 * tau], [s, -2 * s, s]


def run_case(
    name: str,
    model: SatelliteModel,
    axes: list[tuple[list, list]],
    duration_s: float,
    discretisation: Discretisation | None = None,
) -> CaseResult:
    """Simulate one manoeuvre; `discretisation` (of `model`) shares matrix exponentials
    between the cases of one model (the same numbers, computed once)."""
    schedule = TorqueSchedule.from_impulses(axes, TORQUE_N_M)
    sim = simulate(
        model,
        schedule,
        duration_s=duration_s,
        step_s=STEP_S,
        initial_attitude_rad=np.radians(INITIAL_ATTITUDE_DEG),
        discretisation=discretisation,
    )
    w = sim.q[:, model.w_dof_of_node(NODE)]
    att = np.degrees(sim.attitude_rad())
    t = sim.time_s
    end = float(max(max(times) for times, _ in axes))
    k = int(np.argmax(np.abs(w)))
    k1 = _first_extremum(w, 0.25 * abs(w[k]))
    after = t > end + 1e-9
    zc = np.flatnonzero(np.diff(np.sign(w[after])) != 0)
    period = float(2 * np.median(np.diff(t[after][zc]))) if zc.size >= 3 else None
    torque = schedule.at_times(t)
    return CaseResult(
        name=name,
        end_s=end,
        first_peak_m=float(abs(w[k1])),
        first_peak_time_s=float(t[k1]),
        peak_m=float(abs(w[k])),
        peak_time_s=float(t[k]),
        residual_m=float(np.abs(w[after]).max()),
        period_s=period,
        final_attitude_deg=tuple(float(a) for a in att[-1]),
        attitude_ripple_deg=tuple(float(a) for a in np.abs(att[after]).max(axis=0)),
        time_s=t,
        attitude_deg=att,
        w27_m=w,
        torque_n_m=torque,
    )


def _first_extremum(w: np.ndarray, floor: float) -> int:
    """Index of the first local extremum of w whose magnitude exceeds floor."""
    dw = np.diff(w)
    turns = np.flatnonzero(dw[:-1] * dw[1:] <= 0) + 1
    for k in turns:
        if abs(w[k]) >= floor:
            return int(k)
    return int(np.argmax(np.abs(w)))


def _coupled_freqs(model: SatelliteModel, n: int = 2) -> tuple[float, ...]:
    return tuple(float(f) for f in model.roll_yaw_frequencies()[:n])


def _design(kind: str, axis: str, inertia: float, freqs, starts: int) -> TwoAmplitudeDesign:
    delta = math.radians(-INITIAL_ATTITUDE_DEG[AXES.index(axis)])
    modes = [
        ModeConstraint(f, v) for f, v in zip(freqs, PAPER_PARMAN2022["vmax_percent"], strict=True)
    ]
    return design_two_amplitude(
        kind,
        inertia_kg_m2=inertia,
        torque_n_m=TORQUE_N_M,
        angle_rad=delta,
        modes=modes,
        n_starts=starts,
    )


def run_study(starts: int = 128, duration_s: float = DURATION_S) -> tuple[dict, list[CaseResult]]:
    log = lambda msg: print(msg, file=sys.stderr)  # noqa: E731
    paper = PAPER_PARMAN2022
    out: dict = {"paper": _jsonable(paper)}

    # 1. models
    log("building the FE satellite (as specified, and diagnostic variants) ...")
    spec = build_satellite()
    no_offset = build_satellite(SatelliteParameters(offset_angle_deg=0.0))
    heavy = SatelliteParameters(
        lumped_masses=tuple(
            replace(m, mass_kg=600.0) if m.mass_kg == 550.0 else m
            for m in SatelliteParameters().lumped_masses
        )
    )
    heavy_model = build_satellite(heavy)
    omega_all, _ = spec.natural_frequencies()
    out["model"] = {
        "elastic_dof": spec.n_elastic,
        "inertia_kg_m2": _inertia_dict(spec),
        "first_elastic_freqs_rad_s": [float(f) for f in omega_all[:6]],
        "roll_yaw_freqs_rad_s": {
            "as_specified": _coupled_freqs(spec),
            "offset_0deg": _coupled_freqs(no_offset),
            "z_masses_600kg": _coupled_freqs(heavy_model),
        },
        "inertia_z_masses_600kg": _inertia_dict(heavy_model),
        "node27_position_m": [float(x) for x in spec.node_positions_m[NODE - 1]],
    }

    # 2. Table 3 on the paper's design problem
    log(f"solving the four Table 3 problems ({starts} starts + dense scan each) ...")
    i_paper = {"roll": paper["inertia_kg_m2"]["Ixx"], "yaw": paper["inertia_kg_m2"]["Izz"]}
    table3 = {}
    paper_designs: dict[tuple[str, str], TwoAmplitudeDesign] = {}
    for (kind, axis), t_paper in paper["table3_s"].items():
        d = _design(kind, axis, i_paper[axis], paper["freqs_rad_s"], starts)
        paper_designs[(kind, axis)] = d
        sign = math.copysign(1.0, -INITIAL_ATTITUDE_DEG[AXES.index(axis)])
        ev = evaluate_sequence(
            t_paper,
            [sign * a for a in shaper_amplitudes(kind)],
            inertia_kg_m2=i_paper[axis],
            torque_n_m=TORQUE_N_M,
            freqs_rad_s=paper["freqs_rad_s"],
            vmax_percent=paper["vmax_percent"],
            reference_angle_rad=math.radians(-INITIAL_ATTITUDE_DEG[AXES.index(axis)]),
        )
        table3[f"{kind} {axis}"] = {
            "ours_times_s": d.times_s,
            "paper_times_s": t_paper,
            "t8_diff_percent": 100 * (d.t8_s / t_paper[-1] - 1),
            "ours_V_percent": d.residual_percent,
            "constraints_met": d.constraints_met,
            "ours_impulse_n_m_s": d.impulse_n_m_s,
            "ours_fuel_on_s": d.fuel_on_time_s,
            "search": _jsonable(asdict(d.search)),
            "paper_sequence_V_percent": ev.residual_percent,
            "paper_sequence_angle_deg": math.degrees(ev.angle_rad),
            "paper_sequence_impulse_n_m_s": ev.impulse_n_m_s,
            "paper_sequence_fuel_on_s": ev.fuel_on_time_s,
            "paper_implied_inertia_kg_m2": i_paper[axis]
            * abs(math.degrees(ev.angle_rad) / INITIAL_ATTITUDE_DEG[AXES.index(axis)]),
        }
    out["table3"] = table3

    # 3. the manoeuvre on our model, shapers designed for our model
    inertia = np.diag(spec.inertia_kg_m2)
    deltas = -np.radians(INITIAL_ATTITUDE_DEG)
    bb_axes = [bang_bang(deltas[k], inertia[k], TORQUE_N_M) for k in range(3)]
    cases: list[CaseResult] = []
    log("simulating bang-bang on the as-specified model ...")
    # one per model: its cases share switch times (the pitch bang-bang, the step)
    disc_spec = Discretisation(spec)
    cases.append(run_case("bang-bang", spec, bb_axes, duration_s, disc_spec))
    freqs_ours = _coupled_freqs(spec)
    ours: dict = {"bang_bang_s": {a: 2 * bb_axes[k][0][1] for k, a in enumerate(AXES)}}
    for kind in KINDS:
        log(f"designing {kind} for our model's modes {np.round(freqs_ours, 4)} rad/s ...")
        d_roll = _design(kind, "roll", inertia[0], freqs_ours, starts)
        d_yaw = _design(kind, "yaw", inertia[2], freqs_ours, starts)
        axes = [(list(d_roll.times_s), list(d_roll.amplitudes)), bb_axes[1]]
        axes.append((list(d_yaw.times_s), list(d_yaw.amplitudes)))
        log(f"simulating {kind} ...")
        cases.append(run_case(kind, spec, axes, duration_s, disc_spec))
        ours[kind] = {
            axis: {
                "times_s": d.times_s,
                "V_percent": d.residual_percent,
                "constraints_met": d.constraints_met,
                "impulse_n_m_s": d.impulse_n_m_s,
                "fuel_on_s": d.fuel_on_time_s,
                "search": _jsonable(asdict(d.search)),
            }
            for axis, d in (("roll", d_roll), ("yaw", d_yaw))
        }
    out["our_model"] = ours

    # 4. diagnostic: zero offset (the paper's frequencies), the paper's own sequences
    log("diagnostic: zero-offset satellite with bang-bang and the paper's Table 3 sequences ...")
    inertia0 = np.diag(no_offset.inertia_kg_m2)
    bb0 = [bang_bang(deltas[k], inertia0[k], TORQUE_N_M) for k in range(3)]
    disc_no_offset = Discretisation(no_offset)
    cases.append(run_case("bang-bang, offset 0", no_offset, bb0, duration_s, disc_no_offset))
    for kind in KINDS:
        axes = []
        for k, axis in enumerate(AXES):
            if axis == "pitch":
                axes.append(bb0[1])
                continue
            sign = math.copysign(1.0, deltas[k])
            axes.append(
                (
                    list(paper["table3_s"][(kind, axis)]),
                    [sign * a for a in shaper_amplitudes(kind)],
                )
            )
        cases.append(
            run_case(f"{kind} paper seq., offset 0", no_offset, axes, duration_s, disc_no_offset)
        )
    out["cases"] = {c.name: c.summary() for c in cases}
    out["measures"] = claim_measures(out)
    return out, cases


def claim_measures(out: dict) -> dict[str, float | bool]:
    """Flat, named scalars (unit in the name; none = a ratio or a count) that the paper
    suite's criteria read (``measures.<name>``); every one is computed from ``out``."""
    paper = out["paper"]
    m: dict[str, float | bool] = {}
    missing = 0
    for key, row in out["table3"].items():
        kind, axis = key.split()
        name = f"{kind.lower()}_{axis}"
        m[f"{name}_t8_s"] = float(row["ours_times_s"][-1])
        m[f"{name}_t8_paper_s"] = float(row["paper_times_s"][-1])
        m[f"{name}_t8_diff_percent"] = float(row["t8_diff_percent"])
        m[f"{name}_constraints_met"] = bool(row["constraints_met"])
        m[f"{name}_mode1_residual_percent"] = float(row["ours_V_percent"][0])
        m[f"{name}_mode2_residual_percent"] = float(row["ours_V_percent"][1])
        pv = row["paper_sequence_V_percent"]
        m[f"{name}_paper_sequence_mode1_residual_percent"] = float(pv[0])
        m[f"{name}_paper_sequence_mode2_residual_percent"] = float(pv[1])
        printed = paper["impulse_n_m_s"][key]
        m[f"{name}_paper_sequence_impulse_error_percent"] = float(
            100 * (row["paper_sequence_impulse_n_m_s"] / printed - 1))
        missing += int(pv[0] > paper["vmax_percent"][0] or pv[1] > paper["vmax_percent"][1])
    m["paper_sequences_over_limit_count"] = missing
    f_paper = paper["freqs_rad_s"]
    for variant, freqs in out["model"]["roll_yaw_freqs_rad_s"].items():
        for k in (0, 1):
            m[f"fe_{variant}_mode{k + 1}_freq_error_percent"] = float(
                100 * (freqs[k] / f_paper[k] - 1))
    cases = out["cases"]
    lhhl, hllh, bb = cases["LHHL"], cases["HLLH"], cases["bang-bang"]
    m["hllh_shorter_than_lhhl_percent"] = float(100 * (1 - hllh["end_s"] / lhhl["end_s"]))
    m["hllh_first_peak_above_lhhl_percent"] = float(
        100 * (hllh["first_peak_m"] / lhhl["first_peak_m"] - 1))
    m["bang_bang_residual_m"] = float(bb["residual_m"])
    m["bang_bang_period_s"] = float(bb["period_s"])
    m["lhhl_residual_over_bang_bang"] = float(lhhl["residual_m"] / bb["residual_m"])
    m["hllh_residual_over_bang_bang"] = float(hllh["residual_m"] / bb["residual_m"])
    return m


def _inertia_dict(model: SatelliteModel) -> dict:
    i = model.inertia_kg_m2
    return {"Ixx": i[0, 0], "Iyy": i[1, 1], "Izz": i[2, 2], "Ixz": i[0, 2], "Ixy": i[0, 1]}


def _jsonable(obj):
    if isinstance(obj, dict):
        return {(" ".join(k) if isinstance(k, tuple) else k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.floating | np.integer):
        return obj.item()
    return obj


def _pct(ours: float, paper: float) -> str:
    return f"{100 * (ours / paper - 1):+.1f} %"


def print_tables(out: dict) -> None:
    p = PAPER_PARMAN2022
    m = out["model"]
    print("== Satellite model (Tables 1-2, ACM plates, 16 per panel, clamped roots) ==")
    print(f"elastic DOF: ours {m['elastic_dof']}, paper {p['elastic_dof']}")
    for key in ("Ixx", "Iyy", "Izz", "Ixz"):
        ours, heavy = m["inertia_kg_m2"][key], m["inertia_z_masses_600kg"][key]
        print(
            f"{key} (kg m^2): ours {ours:9.1f}  paper {p['inertia_kg_m2'][key]:9.1f}  "
            f"({_pct(ours, p['inertia_kg_m2'][key])});  with 600 kg z-masses {heavy:9.1f}"
        )
    print(
        "first elastic frequencies (rad/s): "
        + ", ".join(f"{f:.4f}" for f in m["first_elastic_freqs_rad_s"])
    )
    print("roll/yaw-coupled frequencies (rad/s)   w1       w2      vs paper 0.3354 / 1.082")
    for label, fr in m["roll_yaw_freqs_rad_s"].items():
        print(
            f"  {label:<28s} {fr[0]:.4f}   {fr[1]:.4f}   "
            f"{_pct(fr[0], p['freqs_rad_s'][0])} / {_pct(fr[1], p['freqs_rad_s'][1])}"
        )
    print("\n== Table 3: solver on the paper's design problem (I, T = 8 N m, 3 / -2 deg) ==")
    for row, r in out["table3"].items():
        s = r["search"]
        print(f"{row:<10s} ours  " + " ".join(f"{t:7.3f}" for t in r["ours_times_s"]))
        print(f"{'':<10s} paper " + " ".join(f"{t:7.3f}" for t in r["paper_times_s"]))
        v = r["ours_V_percent"]
        vp = r["paper_sequence_V_percent"]
        print(
            f"{'':<10s} t8 {r['t8_diff_percent']:+.2f} %; ours V = {v[0]:.5f} / {v[1]:.3f} % "
            f"(met: {r['constraints_met']}); paper's sequence V = {vp[0]:.5f} / {vp[1]:.3f} %, "
            f"angle {r['paper_sequence_angle_deg']:.4f} deg"
        )
        grid = "none" if s["grid_t8_s"] is None else f"{s['grid_t8_s']:.3f} s"
        print(
            f"{'':<10s} search: {s['n_agree']}/{s['n_feasible']} feasible starts at the best "
            f"(of {s['n_starts']}); dense scan first feasible t8 {grid}"
            f"{', improved' if s['improved_by_grid'] else ''}"
        )
    print("\n== Impulse and fuel-on time (N m s / s) ==")
    print(
        f"{'row':<11s}{'paper':>8s}{'paper seq':>11s}{'Table3 ours':>13s}{'our model':>11s}"
        f"{'fuel paper':>12s}{'fuel ours':>11s}"
    )
    for (kind, axis), imp in p["impulse_n_m_s"].items():
        r = out["table3"][f"{kind} {axis}"]
        om = out["our_model"][kind][axis]
        print(
            f"{kind + ' ' + axis:<11s}{imp:8.2f}{r['paper_sequence_impulse_n_m_s']:11.2f}"
            f"{r['ours_impulse_n_m_s']:13.2f}{om['impulse_n_m_s']:11.2f}"
            f"{p['fuel_on_s'][(kind, axis)]:12.3f}{r['ours_fuel_on_s']:11.3f}"
        )
    print("\n== Manoeuvre (-3, -1, 2) deg -> 0, node-27 deflection ==")
    bb = out["our_model"]["bang_bang_s"]
    print(
        "bang-bang durations (s): ours "
        + ", ".join(f"{a} {bb[a]:.3f}" for a in AXES)
        + "; paper "
        + ", ".join(f"{a} {p['bang_bang_s'][a]:.3f}" for a in AXES)
    )
    print(
        f"{'case':<27s}{'end s':>6s}{'1st peak m':>11s}{'at s':>6s}{'max m':>7s}{'at s':>6s}"
        f"{'resid m':>8s}{'period s':>9s}{'ripple deg r,p,y':>20s}"
    )
    for name, c in out["cases"].items():
        per = "-" if c["period_s"] is None else f"{c['period_s']:.2f}"
        rip = ",".join(f"{a:.3f}" for a in c["attitude_ripple_deg"])
        print(
            f"{name:<27s}{c['end_s']:6.2f}{c['first_peak_m']:11.3f}{c['first_peak_time_s']:6.2f}"
            f"{c['peak_m']:7.3f}{c['peak_time_s']:6.2f}{c['residual_m']:8.3f}{per:>9s}{rip:>20s}"
        )
    pk = p["peak_deflection_m_at_s"]
    print(
        f"paper: bang-bang residual {p['bang_bang_residual_m']} m, period "
        f"{p['bang_bang_period_s']} s; LHHL peak {pk['LHHL'][0]} m at {pk['LHHL'][1]} s; "
        f"HLLH peak {pk['HLLH'][0]} m at {pk['HLLH'][1]} s"
    )
    cs = out["cases"]
    for tag, l_name, h_name in (
        ("our model, own designs", "LHHL", "HLLH"),
        ("offset 0, paper seq.", "LHHL paper seq., offset 0", "HLLH paper seq., offset 0"),
    ):
        lh, hl = cs[l_name], cs[h_name]
        print(
            f"{tag}: HLLH {100 * (1 - hl['end_s'] / lh['end_s']):.1f} % faster, HLLH first peak "
            f"{100 * (hl['first_peak_m'] / lh['first_peak_m'] - 1):+.1f} % vs LHHL "
            f"(paper: 17 % faster, +13 %)"
        )


def write_rrd(path: Path, cases: list[CaseResult]) -> None:
    import rerun as rr

    from harness.record.recording import close_stream
    from harness.record.streams import sweep_orphans
    from harness.review.names import log_series_names

    rec = rr.RecordingStream("harness_parman2022")
    rec.save(str(path))
    for c in cases:
        base = "parman2022/" + c.name.replace(" ", "_").replace(",", "").replace(".", "")
        times = [rr.TimeColumn("time", duration=c.time_s)]
        rec.send_columns(
            f"{base}/node27_m", indexes=times, columns=rr.Scalars.columns(scalars=c.w27_m)
        )
        for k, axis in enumerate(AXES):
            rec.send_columns(
                f"{base}/attitude_deg/{axis}",
                indexes=times,
                columns=rr.Scalars.columns(scalars=c.attitude_deg[:, k]),
            )
            rec.send_columns(
                f"{base}/torque_n_m/{axis}",
                indexes=times,
                columns=rr.Scalars.columns(scalars=c.torque_n_m[:, k]),
            )
        # legends: the axis (roll, pitch, yaw) and "node27", not the entity path
        log_series_names(rec, [f"{base}/node27_m"]
                         + [f"{base}/{q}/{axis}" for q in ("attitude_deg", "torque_n_m")
                            for axis in AXES])
    try:
        close_stream(rec, path)  # bounded: a full disk's stuck sink never hangs the study
    finally:
        del rec
        sweep_orphans()  # the stream dropped: its threads end


def _run(args: argparse.Namespace) -> int:
    if args.starts < 1:
        print("harness study parman2022: --starts must be >= 1", file=sys.stderr)
        return 2
    out, cases = run_study(starts=args.starts)
    if args.rrd:
        write_rrd(Path(args.rrd), cases)
        print(f"wrote {args.rrd}", file=sys.stderr)
    if args.json:
        print(json.dumps(_jsonable(out), indent=2))
    else:
        print_tables(out)
    return 0


def register_study(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "parman2022",
        help="two-amplitude LHHL/HLLH shapers on the flexible satellite (Parman 2022)",
    )
    parser.add_argument("--json", action="store_true", help="print machine-readable results")
    parser.add_argument("--rrd", default=None, help="write a Rerun recording to this path")
    parser.add_argument(
        "--starts", type=int, default=128, help="multi-start count per design (default 128)"
    )
    parser.set_defaults(func=_run)
