"""Shaped-slew candidates over the identified modes, and their predicted scores (pure: no bus).

Every candidate is a run-file controller section; it is scored on the controller that the
harness would build from it (``harness.core.runs``), so the score is of what would be sent:

* wheel (``shaped_wheel_slew``): the same bang-bang convolved with one ZV, ZVD, EI (5 %) or
  SI shaper per identified mode (SI: specified insensitivity, residual below
  ``SI_TOLERANCE_PERCENT`` over each mode's whole band). Residual vibration V (percent of the
  unshaped slew's, per mode) of the shaper as applied on the tick grid.
* valves (``thruster_two_level``): the damped LHHL and HLLH two-level designs on the lowest
  identified modes (two, else one), each also convolved with a ZV for every higher mode (the
  valves' PWM makes the intermediate levels). V_d (percent of the bang-bang's, per mode) of
  the valve schedule actually sent (ticks, PWM), fuel (impulse, on-time) and firings.

Each mode's band is +-max(3 sigma, 5 %) in frequency and +-3 sigma in damping
(``harness.shaping.robust.mode_band``); a candidate's score per mode is its worst V over the
band, and its predicted residual ratio (unshaped / this) weighs the modes by ``weights`` (the
unshaped slew's residual amplitude per mode, measured; equal weights before that).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.controllers.shaped_wheel_slew import Mode
from harness.controllers.thruster_two_level import damped_residual_percent
from harness.core.runs import RunConfig, build_controller, run_from_dict
from harness.shaping.impulse_shapers import residual_vibration
from harness.shaping.robust import ModeBand, mode_band
from rig_models.rig_file import RigConfig
from rig_models.schema import ConfigError

WHEEL_SHAPERS = ("zv", "zvd", "ei", "si")
EI_TOLERANCE_PERCENT = 5.0
SI_TOLERANCE_PERCENT = 5.0
BAND_SIGMAS = 3.0
BAND_MIN_PERCENT = 5.0
VALVE_VMAX_PERCENT = (1.0, 2.0, 5.0)  # the damped design's V_d limit, tried in turn
SLEW_START_S = 1.0
MARGIN_S = 0.1  # after the manoeuvre's end, before the residual window
TORQUE_FRACTION = 0.9
SPARE = 0.9
LABELS = {"zv": "ZV", "zvd": "ZVD", "ei": f"EI ({EI_TOLERANCE_PERCENT:g} %)",
          "si": f"SI ({SI_TOLERANCE_PERCENT:g} % over the band)", "none": "unshaped",
          "bang_bang": "bang-bang", "lhhl": "LHHL", "hllh": "HLLH"}


@dataclass(frozen=True)
class SlewSpec:
    actuator: str  # "wheel" | "valves"
    angle_deg: float
    torque_n_m: float  # wheel torque of the bang-bang (valves: their couple)
    rate_hz: float
    rig_ref: str
    bus: str = "virtual:sgsrt"
    clock: str = "lockstep"
    window_s: float = 6.0
    notes: tuple[str, ...] = ()


@dataclass
class Candidate:
    key: str
    label: str
    controller: dict[str, Any]
    manoeuvre_s: float = math.nan
    added_s: float = math.nan  # manoeuvre minus the unshaped one
    nominal_percent: list[float] = field(default_factory=list)  # V at each identified mode
    worst_percent: list[float] = field(default_factory=list)  # worst V over each band
    impulse_n_m_s: float | None = None
    firings: int | None = None
    on_time_s: float | None = None
    feasible: bool = True
    reason: str = ""
    predicted_ratio: float = math.nan  # unshaped / this, weighted worst over the bands
    predicted_nominal_ratio: float = math.nan
    design_note: str = ""

    def cost(self) -> tuple[float, ...]:
        """Wheel: the added duration. Valves: fuel, then duration, then firings."""
        if self.impulse_n_m_s is None:
            return (self.added_s,)
        return (self.impulse_n_m_s, self.added_s, float(self.firings or 0))

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items()}


def slew_spec(rig: RigConfig, actuator: str, angle_deg: float, rate_hz: float, rig_ref: str,
              bus: str, clock: str, window_s: float) -> SlewSpec:
    """The slew every candidate makes: a bang-bang of ``angle_deg`` at ``TORQUE_FRACTION`` of
    the wheel's maximum torque, lowered to keep the wheel within 90 % of its maximum speed
    (the rotor's speed at the bang-bang's middle is T tau / J_rotor = sqrt(theta J T) /
    J_rotor); with the valves, their couple."""
    if not (math.isfinite(angle_deg) and angle_deg != 0):
        raise ConfigError(f"--angle-deg: expected a non-zero angle in deg, got {angle_deg!r}")
    notes: list[str] = []
    if actuator == "wheel":
        w = rig.section("reaction_wheel")
        torque = TORQUE_FRACTION * w["max_torque_n_m"]
        theta_j = math.radians(abs(angle_deg)) * rig.plant.inertia_kg_m2
        t_speed = (SPARE * w["max_speed_rad_s"] * w["rotor_inertia_kg_m2"]) ** 2 / theta_j
        if t_speed < torque:
            notes.append(f"slew torque lowered from {torque:.4g} to {t_speed:.4g} N m to keep "
                         "the wheel within 90 % of reaction_wheel.max_speed_rad_s")
            torque = t_speed
    else:
        torque = rig.section("thruster_valves")["couple_n_m"]
    return SlewSpec(actuator, float(angle_deg), torque, rate_hz, rig_ref, bus, clock, window_s,
                    tuple(notes))


def bands_of(modes: Sequence[Mode]) -> list[ModeBand]:
    return [mode_band(m.omega_rad_s, m.damping_ratio, m.sigma_omega_rad_s, m.sigma_damping,
                      BAND_SIGMAS, BAND_MIN_PERCENT / 100) for m in modes]


def modes_yaml(modes: Sequence[Mode]) -> list[dict[str, float]]:
    return [{"omega_rad_s": round(m.omega_rad_s, 6), "damping_ratio": round(m.damping_ratio, 6),
             "sigma_omega_rad_s": round(m.sigma_omega_rad_s, 6),
             "sigma_damping": round(m.sigma_damping, 6)} for m in modes]


def run_dict(spec: SlewSpec, name: str, description: str, controller: dict[str, Any],
             duration_s: float = 60.0) -> dict[str, Any]:
    return {"name": name, "description": description, "rig": spec.rig_ref, "bus": spec.bus,
            "clock": spec.clock, "rate_hz": spec.rate_hz, "duration_s": duration_s,
            "actuators": ["reaction_wheel" if spec.actuator == "wheel" else "thruster_valves"],
            "controller": controller, "residual_window_s": spec.window_s}


def build(spec: SlewSpec, name: str, description: str,
          controller: dict[str, Any]) -> tuple[RunConfig, Any]:
    """The run (its duration ending ``MARGIN_S`` + the residual window after the manoeuvre)
    and its controller."""
    raw = run_dict(spec, name, description, controller)
    run = run_from_dict(raw, source=f"calibrate candidate {name}")
    ctrl = build_controller(run)
    raw["duration_s"] = round(ctrl.end_s + MARGIN_S + spec.window_s, 3)
    run = run_from_dict(raw, source=f"calibrate candidate {name}")
    return run, build_controller(run)


def baseline_controller(spec: SlewSpec, modes: Sequence[Mode]) -> dict[str, Any]:
    if spec.actuator == "wheel":
        return {"type": "shaped_wheel_slew", "angle_deg": spec.angle_deg,
                "start_s": SLEW_START_S, "torque_n_m": round(spec.torque_n_m, 6),
                "shaper": "none", "modes": modes_yaml(modes)}
    return {"type": "thruster_two_level", "profile": "bang_bang", "angle_deg": spec.angle_deg,
            "start_s": SLEW_START_S, "modes": modes_yaml(modes)}


def _band_modes(band: ModeBand, n: int = 41) -> list[Mode]:
    return [Mode(float(w), float(z)) for z in band.zetas() for w in band.omegas(n)]


def wheel_candidates(spec: SlewSpec, modes: Sequence[Mode],
                     kinds: Sequence[str] = WHEEL_SHAPERS) -> list[Candidate]:
    """ZV / ZVD / EI / SI over every identified mode, scored on the tick grid."""
    bands = bands_of(modes)
    _, base = build(spec, "calibrate-unshaped", "", baseline_controller(spec, modes))
    out = []
    for kind in kinds:
        c = dict(baseline_controller(spec, modes), shaper=kind,
                 ei_tolerance_percent=EI_TOLERANCE_PERCENT,
                 si_tolerance_percent=SI_TOLERANCE_PERCENT, band_sigmas=BAND_SIGMAS,
                 band_min_percent=BAND_MIN_PERCENT)
        cand = Candidate(kind, LABELS[kind], c)
        try:
            _, ctrl = build(spec, f"calibrate-{kind}", "", c)
        except (ConfigError, ValueError, RuntimeError) as exc:
            cand.feasible, cand.reason = False, str(exc)
            out.append(cand)
            continue
        seq = ctrl.applied_shaper
        cand.manoeuvre_s = ctrl.duration_s
        cand.added_s = ctrl.duration_s - base.duration_s
        cand.nominal_percent = [float(residual_vibration(seq, m.omega_rad_s, m.damping_ratio))
                                for m in modes]
        cand.worst_percent = [max(float(np.max(residual_vibration(seq, b.omegas(), z)))
                                  for z in b.zetas()) for b in bands]
        out.append(cand)
    return out


def valve_candidates(spec: SlewSpec, modes: Sequence[Mode], dt_s: float) -> list[Candidate]:
    """Damped LHHL / HLLH on the lowest identified modes (two, else one; V_d limit 1 %, else
    2 %, else 5 %), with and without a ZV for each higher mode."""
    bands = bands_of(modes)
    _, base = build(spec, "calibrate-bang-bang", "", baseline_controller(spec, modes))
    tau = base.design.bang_bang_duration_s / 2
    out = []
    n = len(modes)
    for profile in ("lhhl", "hllh"):
        design: tuple[int, float] | None = None
        reason = ""
        for k in sorted({min(2, n), 1}, reverse=True):
            for vmax in VALVE_VMAX_PERCENT:
                c = {"type": "thruster_two_level", "profile": profile,
                     "angle_deg": spec.angle_deg, "start_s": SLEW_START_S,
                     "modes": modes_yaml(modes), "design": "damped", "design_modes": k,
                     "vmax_percent": vmax}
                try:
                    build(spec, f"calibrate-{profile}", "", c)
                except (ConfigError, ValueError) as exc:
                    reason = str(exc)
                    continue
                design = (k, vmax)
                break
            if design is not None:
                break
        variants: list[tuple[str, list[int]]] = [("", [])]
        if design is not None and design[0] < n:
            variants.append(("-zv", list(range(design[0] + 1, n + 1))))
        for suffix, extra in variants:
            key = profile + suffix
            label = LABELS[profile] + (f" damped (modes 1-{design[0]}, V_d <= {design[1]:g} %)"
                                       if design else "")
            if extra:
                label += " * ZV modes " + ", ".join(map(str, extra))
            if design is None:
                out.append(Candidate(key, LABELS[profile], {}, feasible=False,
                                     reason=f"no damped design found: {reason}"))
                continue
            c = {"type": "thruster_two_level", "profile": profile, "angle_deg": spec.angle_deg,
                 "start_s": SLEW_START_S, "modes": modes_yaml(modes), "design": "damped",
                 "design_modes": design[0], "vmax_percent": design[1]}
            if extra:
                c["extra_zv_modes"] = extra
            cand = Candidate(key, label, c)
            try:
                _, ctrl = build(spec, f"calibrate-{key}", "", c)
            except (ConfigError, ValueError) as exc:
                cand.feasible, cand.reason = False, str(exc)
                out.append(cand)
                continue
            steps = np.diff(np.r_[0.0, ctrl.directions.astype(float), 0.0])
            k_sw = np.flatnonzero(steps)
            t_sw, a_sw = k_sw * dt_s, steps[k_sw]
            cand.manoeuvre_s = ctrl.duration_s
            cand.added_s = ctrl.duration_s - base.duration_s
            cand.nominal_percent = damped_residual_percent(t_sw, a_sw, modes, tau).tolist()
            cand.worst_percent = [float(np.max(damped_residual_percent(
                t_sw, a_sw, _band_modes(b), tau))) for b in bands]
            cand.impulse_n_m_s = ctrl.usage["impulse_n_m_s"]
            cand.firings = ctrl.usage["firings"]
            cand.on_time_s = ctrl.usage["on_time_s"]
            d = ctrl.design
            cand.design_note = (f"t8 {d.t8_s:.3f} s, design V_d " + " / ".join(
                f"{v:.2g}" for v in d.damped_residual_percent) + " %")
            out.append(cand)
    return out


def predict_ratios(cands: Sequence[Candidate], weights: Sequence[float] | None) -> None:
    """Predicted residual ratio (unshaped / candidate) of every feasible candidate, in place:
    sum w_k / sum w_k V_k (V as a fraction), worst over the bands and at the nominal modes."""
    for c in cands:
        if not c.feasible:
            continue
        w = np.ones(len(c.worst_percent)) if weights is None else np.asarray(weights, float)
        if w.sum() <= 0:
            w = np.ones_like(w)
        for attr, vals in (("predicted_ratio", c.worst_percent),
                           ("predicted_nominal_ratio", c.nominal_percent)):
            left = float(np.sum(w * np.asarray(vals)) / 100.0)
            setattr(c, attr, float(w.sum() / left) if left > 0 else math.inf)
