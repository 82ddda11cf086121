"""`harness study hu2006`: the 60 deg slew study of Hu (2006) on our reference plant.

Five configurations, PD gains 15 / 50 and PWPF (k_m 3, tau_m 0.15 s, U_on 0.4, U_off 0.15,
U_m 1) throughout:

1. PD + PWPF
2. PD + PWPF + CSVS (mode 1 second-order robust, 4 components; mode 2 zero-order, 2 components)
3. PD + PWPF + OPPF (piezo patch, gains from our optimiser)
4. PD + PWPF + CSVS mode 1 + OPPF
5. PD + PWPF + CSVS modes 1 and 2 + OPPF

The CSVS commands and the OPPF design are computed from the plant model (hub-free modes,
``rig_models.reference.hu2006_hub_beam``); nothing below is tuned to the paper's figures, which
appear only in ``PAPER_HU2006`` for the comparison columns.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field, replace

import numpy as np

from harness.controllers.oppf import OPPFDesign, OPPFWeights, PPFDesignModel, design_oppf
from harness.controllers.pd_thruster import (
    CSVSPlacement,
    PDThrusterController,
    ThrusterAttitudeController,
)
from harness.controllers.pwpf import PWPFParameters
from harness.shaping.csvs import ComponentSequence, ModeDesign, multimode_sequence
from rig_models.reference.hu2006_hub_beam import (
    Hu2006HubBeam,
    HubBeamParameters,
    OnOffThrusters,
)

# Paper figures (REFERENCE.md, section 001; Hu 2006 section 6). Comparison column only.
PAPER_HU2006: dict = {
    "coupled_freqs_rad_s": [3.161, 16.954],
    "pd_gains": {"kp": 15.0, "kd": 50.0},
    "pwpf": {"k_m": 3.0, "tau_m": 0.15, "u_on": 0.4, "u_off": 0.15, "u_m": 1.0},
    "oppf": {"g": [0.5, 0.7], "w_c_rad_s": [2.55, 16.025], "zeta_c": [0.5, 0.5]},
    "slew": {
        "pd_pwpf": {"settle_s": 20.0, "angle_err_deg": 0.25, "rate_err_deg_s": 0.1,
                    "peak_energy": 1.05},
        "pd_pwpf_csvs": {"settle_s": 18.0, "angle_err_deg": 0.1, "rate_err_deg_s": 0.02,
                         "peak_energy": 0.35},
        "pd_pwpf_oppf": {"settle_s": None, "angle_err_deg": 0.1, "rate_err_deg_s": 0.015,
                         "peak_energy": 0.6},
        "pd_pwpf_csvs1_oppf": {"settle_s": None, "angle_err_deg": None, "rate_err_deg_s": None,
                               "peak_energy": "< 0.35"},
        "pd_pwpf_csvs12_oppf": {"settle_s": None, "angle_err_deg": None, "rate_err_deg_s": None,
                                "peak_energy": "< 0.12"},
    },
}

PD_KP = 15.0
PD_KD = 50.0
SLEW_DEG = 60.0
OPPF_VOLTAGE_WEIGHT = 1e-8  # r in E + r e_a^2 (J per V^2); see oppf.OPPFWeights
SETTLE_BAND_FRACTION = 0.01  # settle: |angle error| stays within 1 % of the slew
STEADY_WINDOW_S = 10.0  # steady-state errors: max over the last 10 s


@dataclass(frozen=True)
class SlewConfiguration:
    key: str
    label: str
    csvs_modes: tuple[int, ...] = ()  # which hub-free modes (1-based) the CSVS command cancels
    oppf: bool = False


CONFIGURATIONS: tuple[SlewConfiguration, ...] = (
    SlewConfiguration("pd_pwpf", "PD + PWPF"),
    SlewConfiguration("pd_pwpf_csvs", "PD + PWPF + CSVS (m1 SOR-4, m2 ZOR-2)", (1, 2)),
    SlewConfiguration("pd_pwpf_oppf", "PD + PWPF + OPPF", (), True),
    SlewConfiguration("pd_pwpf_csvs1_oppf", "PD + PWPF + CSVS m1 + OPPF", (1,), True),
    SlewConfiguration("pd_pwpf_csvs12_oppf", "PD + PWPF + CSVS m1+m2 + OPPF", (1, 2), True),
)


def csvs_command(plant: Hu2006HubBeam, modes: tuple[int, ...]) -> ComponentSequence | None:
    """Paper's CSVS: mode 1 second-order robust with 2-component stages (4 components),
    mode 2 zero-order robust with 2 components; frequencies from the plant's hub-free modes."""
    if not modes:
        return None
    freqs = plant.coupled_freqs()
    zeta = plant.params.modal_damping_ratio
    order_of = {1: 2, 2: 0}
    designs = [ModeDesign(float(freqs[m - 1]), zeta, 2, order_of.get(m, 0)) for m in modes]
    return multimode_sequence(designs)


def ppf_design_model(plant: Hu2006HubBeam, n_design_modes: int = 2) -> PPFDesignModel:
    """Eqs (5)-(6) on the first hub-free modes (the piezo pair does not see the rigid mode);
    their structural damping is taken as the plant's modal damping ratio."""
    freqs, vecs = plant.coupled_modes()
    participation = vecs[1:, :].T @ plant.piezo_b
    k = n_design_modes
    return PPFDesignModel(freqs[:k], plant.params.modal_damping_ratio, participation[:k],
                          plant.gamma)


def design_plant_oppf(plant: Hu2006HubBeam, voltage_weight: float = OPPF_VOLTAGE_WEIGHT
                      ) -> OPPFDesign:
    return design_oppf(ppf_design_model(plant), OPPFWeights(voltage_weight=voltage_weight))


def linear_closed_loop_matrix(
    plant: Hu2006HubBeam, design: OPPFDesign | None, kp: float = PD_KP, kd: float = PD_KD
) -> np.ndarray:
    """Full five-mode plant with the PWPF replaced by unit gain (its near-linear range), PD on
    the hub and, if given, the PPF bank on the piezo pair. Its eigenvalues check spillover."""
    a, b = plant.state_space()
    n1 = plant.n_modes + 1
    ns = a.shape[0]
    comps = design.compensator_parameters() if design is not None else []
    nc = 2 * len(comps)
    big = np.zeros((ns + nc, ns + nc))
    big[:ns, :ns] = a
    # PD: T = -kp theta - kd thetadot
    big[:ns, 0] -= kp * b[:, 0]
    big[:ns, n1] -= kd * b[:, 0]
    sensor = np.zeros(ns)
    sensor[1:n1] = plant.piezo_b / plant.gamma
    for i, c in enumerate(comps):
        j = ns + 2 * i
        big[:ns, j] += c.output_gain * b[:, 1]
        big[j, j + 1] = 1.0
        big[j + 1, j] = -c.freq_rad_s**2
        big[j + 1, j + 1] = -2 * c.zeta * c.freq_rad_s
        big[j + 1, :ns] += c.freq_rad_s**2 * c.input_gain * sensor
    return big


@dataclass
class SlewResult:
    key: str
    label: str
    settle_s: float
    angle_err_deg: float
    rate_err_deg_s: float
    peak_energy: float
    residual_energy: float
    firings: int
    on_time_s: float
    piezo_saturation_fraction: float
    series: dict = field(default_factory=dict, repr=False)


def simulate_slew(
    plant: Hu2006HubBeam,
    config: SlewConfiguration,
    oppf: OPPFDesign | None,
    dt: float = 1e-3,
    duration: float = 40.0,
    slew_deg: float = SLEW_DEG,
    csvs_placement: CSVSPlacement = "reference",
    keep_series: bool = False,
) -> SlewResult:
    """Rest-to-rest slew from 0 to ``slew_deg`` with a step reference at t = 0; the plant is
    advanced with its exact zero-order-hold discretisation at the control step ``dt``."""
    if dt <= 0 or duration <= STEADY_WINDOW_S:
        raise ValueError("dt must be positive and duration longer than the steady window")
    if config.oppf and oppf is None:
        raise ValueError(f"configuration {config.key!r} needs an OPPF design (oppf=None given)")
    ad, bd = plant.discretize(dt)
    target = math.radians(slew_deg)
    controller = ThrusterAttitudeController(
        PDThrusterController(PD_KP, PD_KD), PWPFParameters(),
        csvs_command(plant, config.csvs_modes), csvs_placement,
    )
    thrusters = OnOffThrusters(plant.params.thruster_torque)
    ppf = oppf.controller(plant.params.voltage_limit) if config.oppf and oppf else None
    n1 = plant.n_modes + 1
    steps = int(round(duration / dt))
    x = np.zeros(plant.n_states)
    states = np.empty((steps + 1, plant.n_states))
    states[0] = x
    volts = np.zeros(steps)
    torque = np.zeros(steps)
    sensor_row = plant.piezo_b / plant.gamma
    for k in range(steps):
        cmd = controller.step((target, x[0], x[n1]), dt)
        t_k = thrusters.step(cmd, dt)
        e_a = ppf.step(float(sensor_row @ x[1:n1]), dt) if ppf is not None else 0.0
        x = ad @ x + bd @ np.array([t_k, e_a])
        states[k + 1] = x
        volts[k] = e_a
        torque[k] = t_k
    t = np.arange(steps + 1) * dt
    err = states[:, 0] - target
    rate = states[:, n1]
    band = SETTLE_BAND_FRACTION * abs(target)
    outside = np.nonzero(np.abs(err) > band)[0]
    settle = float(t[outside[-1] + 1]) if outside.size and outside[-1] + 1 < t.size else (
        math.nan if outside.size else 0.0)
    window = t >= t[-1] - STEADY_WINDOW_S
    energy = plant.vibration_energy(states)
    lim = plant.params.voltage_limit
    result = SlewResult(
        key=config.key, label=config.label, settle_s=settle,
        angle_err_deg=math.degrees(float(np.max(np.abs(err[window])))),
        rate_err_deg_s=math.degrees(float(np.max(np.abs(rate[window])))),
        peak_energy=float(np.max(energy)), residual_energy=float(np.mean(energy[window])),
        firings=thrusters.firings, on_time_s=thrusters.on_time,
        piezo_saturation_fraction=float(np.mean(np.abs(volts) >= lim * (1 - 1e-12)))
        if ppf is not None else 0.0,
    )
    if keep_series:
        result.series = {"t": t, "theta": states[:, 0], "rate": rate, "energy": energy,
                         "torque": torque, "volts": volts}
    return result


def run_study(dt: float = 1e-3, duration: float = 40.0,
              csvs_placement: CSVSPlacement = "reference",
              configurations: tuple[SlewConfiguration, ...] = CONFIGURATIONS,
              params: HubBeamParameters | None = None,
              progress=None) -> dict:
    plant = Hu2006HubBeam(params)
    design = design_plant_oppf(plant)
    eig_pd = np.linalg.eigvals(linear_closed_loop_matrix(plant, None))
    eig_ppf = np.linalg.eigvals(linear_closed_loop_matrix(plant, design))
    results = []
    for cfg in configurations:
        if progress:
            progress(f"hu2006: simulating {cfg.label}")
        results.append(simulate_slew(plant, cfg, design, dt, duration,
                                     csvs_placement=csvs_placement))
    base = results[0].peak_energy
    seqs = {cfg.key: csvs_command(plant, cfg.csvs_modes) for cfg in configurations}
    return {
        "plant": {
            "coupled_freqs_rad_s": plant.coupled_freqs().tolist(),
            "constrained_freqs_rad_s": plant.constrained_freqs.tolist(),
            "inertia_kg_m2": plant.inertia,
            "thruster_torque_nm": plant.params.thruster_torque,
            "voltage_limit_v": plant.params.voltage_limit,
        },
        "oppf": {
            "gains": design.gains.tolist(),
            "w_c_rad_s": design.comp_freqs_rad_s.tolist(),
            "zeta_c": design.comp_zetas.tolist(),
            "cost": design.cost, "open_loop_cost": design.open_loop_cost,
            "stability_margin": design.margin,
            "stability_condition_holds": design.stability_condition_holds(),
            "design_max_real_eig": design.max_real_eig,
            "full_linear_max_real_eig_pd_only": float(np.max(eig_pd.real)),
            "full_linear_max_real_eig_pd_ppf": float(np.max(eig_ppf.real)),
            "optimiser_success": design.success, "voltage_weight": OPPF_VOLTAGE_WEIGHT,
        },
        "csvs": {k: (None if s is None else {"times_s": s.times.tolist(),
                                             "amplitudes": s.amplitudes.tolist()})
                 for k, s in seqs.items()},
        "settings": {"dt_s": dt, "duration_s": duration, "slew_deg": SLEW_DEG,
                     "csvs_placement": csvs_placement,
                     "settle_band_deg": SETTLE_BAND_FRACTION * SLEW_DEG,
                     "steady_window_s": STEADY_WINDOW_S},
        "results": [
            {"key": r.key, "label": r.label,
             "settle_s": None if math.isnan(r.settle_s) else r.settle_s,
             "angle_err_deg": r.angle_err_deg, "rate_err_deg_s": r.rate_err_deg_s,
             "peak_energy": r.peak_energy, "peak_energy_rel": r.peak_energy / base,
             "residual_energy": r.residual_energy, "firings": r.firings,
             "on_time_s": r.on_time_s,
             "piezo_saturation_fraction": r.piezo_saturation_fraction,
             "paper": PAPER_HU2006["slew"].get(r.key)}
            for r in results
        ],
        "paper": PAPER_HU2006,
    } | {"measures": claim_measures(plant, design, results)}


def claim_measures(plant: Hu2006HubBeam, design, results) -> dict[str, float | bool]:
    """Flat, named scalars (unit in the name; none = a ratio) that the paper suite's
    criteria read (``measures.<name>``). Energies and residuals are relative to PD + PWPF."""
    m: dict[str, float | bool] = {}
    freqs = plant.coupled_freqs()
    for k, f_paper in enumerate(PAPER_HU2006["coupled_freqs_rad_s"]):
        m[f"plant_mode{k + 1}_freq_error_percent"] = float(100 * (freqs[k] / f_paper - 1))
    base = results[0]
    for r in results:
        if not math.isnan(r.settle_s):
            m[f"{r.key}_settle_s"] = float(r.settle_s)
        m[f"{r.key}_angle_error_deg"] = float(r.angle_err_deg)
        m[f"{r.key}_rate_error_deg_s"] = float(r.rate_err_deg_s)
        m[f"{r.key}_peak_energy_ratio"] = float(r.peak_energy / base.peak_energy)
        m[f"{r.key}_residual_energy_ratio"] = float(r.residual_energy / base.residual_energy)
    m["oppf_stability_margin"] = float(design.margin)
    m["oppf_stability_condition_holds"] = bool(design.stability_condition_holds())
    m["oppf_cost_over_open_loop"] = float(design.cost / design.open_loop_cost)
    return m


def _fmt(v, spec: str = ".3g") -> str:
    if v is None:
        return "-"
    if isinstance(v, str):
        return v
    if isinstance(v, float) and math.isnan(v):
        return "n/a"
    return format(v, spec)


def format_report(study: dict) -> str:
    p = study["paper"]
    f = study["plant"]["coupled_freqs_rad_s"]
    lines = [
        "Hu (2006) 60 deg slew on the reference hub-beam (rig_models/reference/hu2006_hub_beam)",
        f"hub-free frequencies (rad/s): ours {f[0]:.3f}, {f[1]:.3f}   paper "
        f"{p['coupled_freqs_rad_s'][0]}, {p['coupled_freqs_rad_s'][1]}",
    ]
    o = study["oppf"]
    po = p["oppf"]
    lines += [
        "OPPF (ours from the optimiser | paper):",
        f"  g     {o['gains'][0]:.3f} {o['gains'][1]:.3f} | {po['g'][0]} {po['g'][1]}",
        f"  w_c   {o['w_c_rad_s'][0]:.3f} {o['w_c_rad_s'][1]:.3f} | "
        f"{po['w_c_rad_s'][0]} {po['w_c_rad_s'][1]}",
        f"  zeta  {o['zeta_c'][0]:.3f} {o['zeta_c'][1]:.3f} | "
        f"{po['zeta_c'][0]} {po['zeta_c'][1]}",
        f"  cost {o['cost']:.4g} (no PPF {o['open_loop_cost']:.4g}), margin eq (7) "
        f"{o['stability_margin']:.3f}, holds {o['stability_condition_holds']}, "
        f"max Re(eig): design {o['design_max_real_eig']:.3g}, full 5-mode + linear PD "
        f"{o['full_linear_max_real_eig_pd_ppf']:.3g}",
        f"settle band {study['settings']['settle_band_deg']:.2f} deg; steady errors = max over "
        f"last {study['settings']['steady_window_s']:.0f} s; CSVS on the "
        f"{study['settings']['csvs_placement']}; dt {study['settings']['dt_s']} s",
        "",
        f"{'configuration':38s} {'settle s':>12s} {'angle err deg':>14s} {'rate err deg/s':>15s} "
        f"{'peak E (rel)':>26s} {'resid E':>8s} {'fires':>5s} {'on s':>5s}",
        f"{'':38s} {'ours|paper':>12s} {'ours|paper':>14s} {'ours|paper':>15s} "
        f"{'ours|paper':>26s}",
    ]
    base_paper = p["slew"]["pd_pwpf"]["peak_energy"]
    for r in study["results"]:
        pp = r["paper"] or {}
        pe = pp.get("peak_energy")
        if isinstance(pe, (int, float)):
            pe_s = f"{pe:.3g} ({pe / base_paper:.2f})"
        elif isinstance(pe, str):
            num = float(pe.split()[-1])
            pe_s = f"{pe} ({'<' if '<' in pe else ''}{num / base_paper:.2f})"
        else:
            pe_s = "-"
        settle = math.nan if r["settle_s"] is None else r["settle_s"]
        lines.append(
            f"{r['label']:38s} {_fmt(settle, '.1f'):>5s}|{_fmt(pp.get('settle_s')):<6s} "
            f"{_fmt(r['angle_err_deg'], '.3f'):>6s}|{_fmt(pp.get('angle_err_deg')):<7s} "
            f"{_fmt(r['rate_err_deg_s'], '.3f'):>6s}|{_fmt(pp.get('rate_err_deg_s')):<8s} "
            f"{r['peak_energy']:8.3g} ({r['peak_energy_rel']:.2f})|{pe_s:<14s} "
            f"{r['residual_energy']:8.1e} {r['firings']:5d} {r['on_time_s']:5.2f}"
        )
    lines.append("E = qdot^T qdot + q^T Lambda q in N m (J), mass-normalised modes; (rel) = "
                 "divided by PD + PWPF; resid E = mean E over the steady window")
    return "\n".join(lines)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def _run(args: argparse.Namespace) -> int:
    if args.dt <= 0 or args.duration <= STEADY_WINDOW_S:
        print(f"error: --dt must be > 0 and --duration > {STEADY_WINDOW_S} s", file=sys.stderr)
        return 2
    if not args.thruster_torque > 0:
        print("error: --thruster-torque must be > 0 (N m)", file=sys.stderr)
        return 2
    params = replace(HubBeamParameters(), thruster_torque=args.thruster_torque)
    study = run_study(args.dt, args.duration, args.csvs_placement, params=params,
                      progress=lambda m: print(m, file=sys.stderr))
    if args.json:
        print(json.dumps(study, default=_json_default, indent=1))
    else:
        print(format_report(study))
    return 0


def register_study(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "hu2006", help="Hu 2006: PD+PWPF thruster slew with CSVS commands and OPPF piezo damping"
    )
    parser.add_argument("--json", action="store_true", help="print results as JSON on stdout")
    parser.add_argument("--dt", type=float, default=1e-3, help="control/simulation step, s")
    parser.add_argument("--duration", type=float, default=40.0, help="simulated time, s")
    parser.add_argument("--csvs-placement", choices=("reference", "torque"), default="reference",
                        help="apply the CSVS command to the attitude reference (default) or to "
                             "the PD torque demand ahead of the PWPF modulator (inside the "
                             "loop: unstable with these gains, kept for comparison)")
    parser.add_argument("--thruster-torque", type=float, default=1.0,
                        help="thruster torque per unit PWPF output, N m (default 1: the paper's "
                             "U_m = 1 read in N m)")
    parser.set_defaults(func=_run)
