"""Thruster slew of the rig with Hu (2006)'s methods: CSVS-shaped step reference -> PD -> PWPF
-> valve pair, and OPPF-designed PPF banks on the piezo amplifier channels.

Run-file controller type ``thruster_pd_pwpf`` (keys in ``THRUSTER_SLEW_SCHEMA``). Per tick::

    theta_ref = angle * sum_k a_k H(t - start - t_k)      (CSVS; a plain step without it)
    tau       = kp (theta_ref - theta) - kd rate           (N m)
    u         = PWPF(tau / couple)  in {-1, 0, +1}         (paper's U_m = 1 = the full couple)
    valves    = u  (held on for at least the valves' minimum on-time)
    piezo_v   = -PPF_ch(sensor_ch)  for each channel with a bank (rate- and voltage-limited)

**PD gains.** The paper's 15 / 50 are for its plant (J_p = 8.92 kg m^2 in our reference model
``rig_models/reference/hu2006_hub_beam``, thruster torque U_p = 1 N m; the run file gives them
as ``pd.paper_inertia_kg_m2`` / ``pd.paper_torque_n_m``, so this controller does not depend on
the paper's model). ``pd.gains:
paper_scaled`` keeps the paper's loop in dimensionless form on the rig (J_r, couple U_r): the
torque demand in units of the couple, the angle in rad and time scaled by
``s = sqrt((U_p/J_p) / (U_r/J_r))`` (4.1 for the SGSRT: the rig has 1/16.8 of the paper's
angular acceleration), so::

    kp_r = kp_p U_r / U_p,     kd_r = kd_p sqrt(U_r J_r / (U_p J_p))

give the same PWPF dead zone and saturation in angle, the same closed-loop damping, and the
paper's responses 4.1 times slower (1.5 N m/rad and 20.5 N m s/rad on the SGSRT).
``pd.gains: given`` takes ``kp_n_m_per_rad`` and ``kd_n_m_s_per_rad`` as they are. The PWPF
keeps the paper's parameters (k_m, tau_m, U_on, U_off); its tau_m is not time-scaled.

**CSVS.** Modes from the rig model's hub-free modes (``rig.plant.hub_free_modes`` and the
damping ratios of the damped hub-free poles) or given in the run file; paper default: mode 1
second-order robust (2-component stages, 4 components), mode 2 zero-order robust (2
components), applied to the attitude reference as in ``harness.studies.hu2006``.

**OPPF.** For each listed channel, ``harness.controllers.oppf.design_oppf`` on the rig's modal
model (first ``design_modes`` hub-free modes, their damping, the channel's actuator
participation ``b_i = v_i^T a`` with ``v_i`` the mass-normalised hub-free mode and ``a`` the patch's
modal force per volt, sensor constant ``gamma = a_j / s_j``), computed when the controller is
built. The rig's patch pushes ``+a V`` on the modes while the paper's eq (2) has ``-B e_a``: the
command is ``V = -e_a``. ``linear_closed_loop`` checks the combined loop (PD with the PWPF as
unit gain, every bank, all rig modes) and ``design_report()`` returns the whole design.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from harness.controllers.oppf import (
    OPPFDesign,
    OPPFWeights,
    PPFDesignModel,
    design_oppf,
)
from harness.controllers.ppf import PPFController
from harness.controllers.pwpf import PWPFModulator, PWPFParameters
from harness.shaping.csvs import ComponentSequence, ModeDesign, multimode_sequence
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field

PAPER_KP_N_M_PER_RAD = 15.0  # paper's PD gains (section 6), for its own plant
PAPER_KD_N_M_S_PER_RAD = 50.0

THRUSTER_SLEW_SCHEMA: dict[str, Any] = {
    "type": Field("str", required=True),
    "angle_deg": Field("number", "deg", required=True),
    "start_s": Field("number", "s", default=1.0, minimum=0.0),
    "pd": {
        "gains": Field("str", default="paper_scaled", choices=("paper_scaled", "given")),
        "kp_paper": Field("number", "N m/rad", default=PAPER_KP_N_M_PER_RAD,
                          exclusive_minimum=0.0),
        "kd_paper": Field("number", "N m s/rad", default=PAPER_KD_N_M_S_PER_RAD, minimum=0.0),
        # the paper's plant that kp_paper / kd_paper were tuned on (paper_scaled only): our
        # reference model of it (rig_models/reference/hu2006_hub_beam) gives J 8.9236 kg m^2
        # and U_m 1 N m; tests/test_thruster_rig.py checks the run files against it
        "paper_inertia_kg_m2": Field("number", "kg m^2", default=0.0, minimum=0.0),
        "paper_torque_n_m": Field("number", "N m", default=0.0, minimum=0.0),
        "kp_n_m_per_rad": Field("number", "N m/rad", default=0.0, minimum=0.0),
        "kd_n_m_s_per_rad": Field("number", "N m s/rad", default=0.0, minimum=0.0),
    },
    "pwpf": {
        "k_m": Field("number", default=3.0, exclusive_minimum=0.0),
        "tau_m_s": Field("number", "s", default=0.15, exclusive_minimum=0.0),
        "u_on": Field("number", default=0.4, exclusive_minimum=0.0),
        "u_off": Field("number", default=0.15, minimum=0.0),
    },
    # hold a valve command on for at least this long; < 0: the rig file's valve min on-time
    "min_pulse_s": Field("number", "s", default=-1.0),
    "csvs": {
        "modes": Field("list[number]", default=[], minimum=1),
        "orders": Field("list[number]", default=[], minimum=0),
        "components": Field("int", default=2, minimum=2),
        "frequencies": Field("str", default="model", choices=("model", "given")),
        "freqs_rad_s": Field("list[number]", "rad/s", default=[], exclusive_minimum=0.0),
        "damping_ratios": Field("list[number]", default=[], minimum=0.0, maximum=0.99),
    },
    "piezo": {
        "channels": Field("list[number]", default=[], minimum=1, maximum=2),
        "design_modes": Field("int", default=2, minimum=1),
        "voltage_weight": Field("number", "J/V^2", default=1e-8, minimum=0.0),
        "min_margin": Field("number", default=0.05, minimum=0.0, maximum=0.99),
    },
}


# ----------------------------------------------------------------------------- design pieces
@dataclass(frozen=True)
class PDGains:
    kp_n_m_per_rad: float
    kd_n_m_s_per_rad: float
    source: str
    time_scale: float = math.nan  # rig time / paper time for the same dimensionless response


def scaled_pd_gains(kp_paper: float, kd_paper: float, rig_inertia: float, rig_couple: float,
                    paper_inertia: float, paper_thrust: float) -> PDGains:
    """The paper's PD loop in dimensionless form on the rig (see the module docstring)."""
    for name, v in (("rig_inertia", rig_inertia), ("rig_couple", rig_couple),
                    ("paper_inertia", paper_inertia), ("paper_thrust", paper_thrust)):
        if not v > 0:
            raise ValueError(f"{name} must be > 0, got {v!r}")
    scale = math.sqrt((paper_thrust / paper_inertia) / (rig_couple / rig_inertia))
    return PDGains(kp_paper * rig_couple / paper_thrust,
                   kd_paper * math.sqrt(rig_couple * rig_inertia / (paper_thrust * paper_inertia)),
                   "paper_scaled", scale)


def hub_free_modes_with_damping(rig: RigConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hub-free frequencies (rad/s), damping ratios of the damped hub-free poles, and the
    mass-normalised mode vectors over ``[theta, eta]`` (columns)."""
    freqs, vecs = rig.plant.hub_free_modes()
    wn, zeta = rig.plant.hub_free_modal_damping()
    # pair each undamped hub-free mode with the nearest damped pole
    z = np.array([zeta[int(np.argmin(np.abs(wn - w)))] for w in freqs])
    return freqs, z, vecs


def _int_list(values: list[float], name: str) -> list[int]:
    out = []
    for v in values:
        if float(v) != int(v):
            raise ValueError(f"{name}: expected whole numbers, got {values!r}")
        out.append(int(v))
    return out


def rig_csvs_sequence(rig: RigConfig, c: dict[str, Any]) -> tuple[ComponentSequence | None,
                                                                   list[ModeDesign]]:
    """The CSVS command of the run's ``csvs`` section (None without modes)."""
    modes = _int_list(c["modes"], "csvs.modes")
    if not modes:
        return None, []
    orders = _int_list(c["orders"], "csvs.orders") if c["orders"] else [
        2 if m == 1 else 0 for m in modes]  # paper: mode 1 second order, mode 2 zero order
    if len(orders) != len(modes):
        raise ValueError(f"csvs.orders: expected one order per mode ({len(modes)}), got "
                         f"{len(orders)}")
    if c["frequencies"] == "given":
        f, z = list(c["freqs_rad_s"]), list(c["damping_ratios"])
        if len(f) != len(modes) or len(z) != len(modes):
            raise ValueError("csvs.freqs_rad_s and csvs.damping_ratios: expected one value per "
                             f"mode ({len(modes)}) with frequencies: given")
        designs = [ModeDesign(float(w), float(zz), c["components"], o)
                   for w, zz, o in zip(f, z, orders, strict=True)]
    else:
        freqs, zetas, _ = hub_free_modes_with_damping(rig)
        if max(modes) > len(freqs):
            raise ValueError(f"csvs.modes: the rig model has {len(freqs)} hub-free modes, "
                             f"got mode {max(modes)}")
        designs = [ModeDesign(float(freqs[m - 1]), float(zetas[m - 1]), c["components"], o)
                   for m, o in zip(modes, orders, strict=True)]
    return multimode_sequence(designs), designs


def rig_ppf_design_model(rig: RigConfig, channel: int, n_modes: int) -> PPFDesignModel:
    """Eqs (5)-(6) for one amplifier channel on the rig's first ``n_modes`` hub-free modes."""
    gains = rig.piezo_gains
    if not 1 <= channel <= len(gains):
        raise ValueError(f"piezo.channels: channel {channel} has no patch in the rig file "
                         f"({len(gains)} piezo_patches)")
    freqs, zetas, vecs = hub_free_modes_with_damping(rig)
    if n_modes > len(freqs):
        raise ValueError(f"piezo.design_modes: expected <= {len(freqs)} (the rig model's "
                         f"modes), got {n_modes}")
    g = gains[channel - 1]
    ratio = g.actuator / g.sensor
    gamma = float(np.mean(ratio))
    if not np.allclose(ratio, gamma, rtol=1e-9):
        raise ValueError("piezo patch: actuator and sensor gains are not proportional; the "
                         "collocated PPF design of paper 001 does not apply")
    participation = vecs[1:, :].T @ g.actuator
    return PPFDesignModel(freqs[:n_modes], zetas[:n_modes], participation[:n_modes], gamma)


def linear_closed_loop(rig: RigConfig, kp: float, kd: float,
                       designs: dict[int, OPPFDesign]) -> np.ndarray:
    """Continuous closed-loop matrix: the rig's plant (all modes), hub torque
    ``-kp theta - kd rate`` (PWPF as unit gain) and a PPF bank per channel with the rig's sign
    (patch force ``+a V``, ``V = -e_a``)."""
    p = rig.plant
    n = p.n_modes
    nq = n + 1
    ns = p.a.shape[0]
    comps = [(ch, c) for ch, d in sorted(designs.items()) for c in d.compensator_parameters()]
    big = np.zeros((ns + 2 * len(comps), ns + 2 * len(comps)))
    big[:ns, :ns] = p.a
    big[:ns, 0] -= kp * p.b[:, 0]
    big[:ns, nq] -= kd * p.b[:, 0]
    for i, (ch, c) in enumerate(comps):
        g = rig.piezo_gains[ch - 1]
        j = ns + 2 * i
        big[:ns, j] += -c.output_gain * (p.b[:, 1:] @ g.actuator)  # V = -e_a, force a V
        big[j, j + 1] = 1.0
        big[j + 1, j] = -c.freq_rad_s**2
        big[j + 1, j + 1] = -2 * c.zeta * c.freq_rad_s
        big[j + 1, 1:nq] += c.freq_rad_s**2 * c.input_gain * g.sensor
    return big


def quasi_static_energy_ratio(rig: RigConfig, designs: dict[int, OPPFDesign]) -> float:
    """Modal energy ``eta^T Lambda eta`` of the beam's quasi-static deflection under a constant
    hub torque, with the PPF banks over without. At DC each compensator passes
    ``xi_i = k_in,i e_s``, so the banks add ``sum_i k_out,i k_in,i a s^T`` to the modal
    stiffness: positive position feedback softens the beam statically (eq 7 keeps it > 0)."""
    lam = rig.beam_modes.omega_rad_s**2
    k_eff = np.diag(lam)
    for ch, d in designs.items():
        g = rig.piezo_gains[ch - 1]
        dc = sum(c.output_gain * c.input_gain for c in d.compensator_parameters())
        k_eff = k_eff + dc * np.outer(g.actuator, g.sensor)  # V = -e_a, force a V
    load = -rig.beam_modes.coupling_kg_m  # per unit hub acceleration (eta'' = 0)
    eta0 = load / lam
    eta1 = np.linalg.solve(k_eff, load)
    return float(np.sum(lam * eta1**2) / np.sum(lam * eta0**2))


def modal_damping_of(a: np.ndarray, freqs_rad_s: np.ndarray) -> list[float]:
    """Damping ratio of the pole of ``a`` nearest each frequency."""
    poles = np.linalg.eigvals(a)
    osc = poles[poles.imag > 1e-6]
    out = []
    for w in freqs_rad_s:
        k = int(np.argmin(np.abs(np.abs(osc) - w)))
        out.append(float(-osc[k].real / abs(osc[k])))
    return out


# ----------------------------------------------------------------------------- controller
@dataclass
class ThrusterSlewController:
    """The run-file controller (pure: telemetry in, command out; see the module docstring)."""

    angle_rad: float
    start_s: float
    gains: PDGains
    couple_n_m: float
    pwpf: PWPFParameters
    dt_s: float
    min_pulse_s: float
    csvs: ComponentSequence | None = None
    csvs_modes: list[ModeDesign] = field(default_factory=list)
    oppf: dict[int, OPPFDesign] = field(default_factory=dict)
    voltage_limit_v: float = 200.0
    max_step_v: tuple[float, float] = (math.inf, math.inf)
    closed_loop: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.couple_n_m > 0:
            raise ValueError(f"thruster_valves.couple_n_m must be > 0, got {self.couple_n_m}")
        if not self.dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {self.dt_s}")
        self.modulator = PWPFModulator(self.pwpf)
        self.banks: dict[int, PPFController] = {
            ch: d.controller(self.voltage_limit_v) for ch, d in self.oppf.items()}
        self._min_pulse_ticks = max(1, math.ceil(self.min_pulse_s / self.dt_s - 1e-9))
        if self.csvs is not None:
            # the staircase as Python floats: the reference is looked up every tick (a bisect
            # on a list, cheaper than numpy's searchsorted on a scalar; the same index)
            self._times = self.csvs.times.tolist()
            self._cum = np.cumsum(self.csvs.amplitudes).tolist()
        self.reset()

    def reset(self) -> None:
        self.modulator.reset()
        for bank in self.banks.values():
            bank.reset()
        self._direction = 0
        self._on_ticks = 0
        self._last_v = [0.0, 0.0]
        self.extended_pulses = 0
        self.rate_limited_steps = 0
        self.last_demand_n_m = 0.0

    def reference(self, t_s: float) -> tuple[float, float, float]:
        """(angle rad, rate 0, acceleration 0): the step, or its CSVS staircase."""
        tau = t_s - self.start_s
        if tau < 0:
            return 0.0, 0.0, 0.0
        if self.csvs is None:
            return self.angle_rad, 0.0, 0.0
        k = bisect.bisect_right(self._times, tau + 1e-9) - 1
        return self.angle_rad * self._cum[k], 0.0, 0.0

    def _valve(self, u: int) -> int:
        if self._direction != 0 and self._on_ticks < self._min_pulse_ticks and u != \
                self._direction:
            self.extended_pulses += 1  # the valve cannot close yet: hold it
            u = self._direction
        if u != self._direction:
            self._on_ticks = 0
        self._direction = u
        if u != 0:
            self._on_ticks += 1
        return u

    def step(self, state: RigState) -> RigCommand:
        ref = self.reference(state.time_s)[0]
        demand = (self.gains.kp_n_m_per_rad * (ref - state.hub_angle_rad)
                  - self.gains.kd_n_m_s_per_rad * state.hub_rate_rad_s)
        if not math.isfinite(demand):
            demand = 0.0
        self.last_demand_n_m = demand
        u = self.modulator.step(demand / self.couple_n_m, self.dt_s) / self.pwpf.u_m
        direction = self._valve(int(round(u)))
        volts = [0.0, 0.0]
        for ch, bank in self.banks.items():
            v = -bank.step(state.piezo_sensor_v[ch - 1], self.dt_s)
            step_lim = self.max_step_v[ch - 1]
            last = self._last_v[ch - 1]
            if abs(v - last) > step_lim:  # the amplifier trips on C dV/dt > I_max
                self.rate_limited_steps += 1
                v = last + math.copysign(step_lim, v - last)
            volts[ch - 1] = v
        self._last_v = volts
        return RigCommand(valve_direction=direction, piezo_v=(volts[0], volts[1]))

    def design_report(self) -> dict[str, Any]:
        """Everything the controller was built from (JSON-ready)."""
        return {
            "pd": {"kp_n_m_per_rad": self.gains.kp_n_m_per_rad,
                   "kd_n_m_s_per_rad": self.gains.kd_n_m_s_per_rad,
                   "gains": self.gains.source,
                   "time_scale_vs_paper": None if math.isnan(self.gains.time_scale)
                   else self.gains.time_scale},
            "couple_n_m": self.couple_n_m,
            "pwpf": {"k_m": self.pwpf.k_m, "tau_m_s": self.pwpf.tau_m, "u_on": self.pwpf.u_on,
                     "u_off": self.pwpf.u_off, "u_m": self.pwpf.u_m,
                     "dead_zone_deg": math.degrees(self.pwpf.dead_zone * self.couple_n_m
                                                   / self.gains.kp_n_m_per_rad)
                     if self.gains.kp_n_m_per_rad > 0 else None},
            "min_pulse_s": self._min_pulse_ticks * self.dt_s,
            "csvs": None if self.csvs is None else {
                "modes": [{"freq_rad_s": m.freq_rad_s, "zeta": m.zeta, "order": m.order,
                           "components": m.n_components} for m in self.csvs_modes],
                "times_s": self.csvs.times.tolist(),
                "amplitudes": self.csvs.amplitudes.tolist()},
            "oppf": {str(ch): {
                "design_freqs_rad_s": d.model.freqs_rad_s.tolist(),
                "design_damping": d.model.damping_ratios.tolist(),
                "participation": d.model.participation.tolist(), "gamma": d.model.gamma,
                "gains": d.gains.tolist(), "w_c_rad_s": d.comp_freqs_rad_s.tolist(),
                "zeta_c": d.comp_zetas.tolist(), "cost": d.cost,
                "open_loop_cost": d.open_loop_cost, "stability_margin": d.margin,
                "stability_condition_holds": d.stability_condition_holds(),
                "optimiser_success": d.success, "voltage_weight": d.weights.voltage_weight,
                "input_gains": d.model.input_gains().tolist(),
                "output_gains_v": (-d.model.output_gains(d.gains)).tolist()}
                for ch, d in sorted(self.oppf.items())},
            "closed_loop": self.closed_loop,
        }


def build_thruster_slew(c: dict[str, Any], rig: RigConfig, dt_s: float) -> ThrusterSlewController:
    tv = rig.section("thruster_valves")
    couple = tv["couple_n_m"]
    inertia = rig.plant.inertia_kg_m2
    pd = c["pd"]
    if pd["gains"] == "given":
        if not pd["kp_n_m_per_rad"] > 0:
            raise ValueError("pd.kp_n_m_per_rad: expected a number > 0 (N m/rad) with gains: "
                             "given")
        gains = PDGains(pd["kp_n_m_per_rad"], pd["kd_n_m_s_per_rad"], "given")
    else:
        j_p, u_p = pd["paper_inertia_kg_m2"], pd["paper_torque_n_m"]
        if not (j_p > 0 and u_p > 0):
            raise ValueError("pd.paper_inertia_kg_m2 and pd.paper_torque_n_m: expected the "
                             "paper plant's inertia (> 0 kg m^2) and thruster torque (> 0 N m) "
                             "with gains: paper_scaled")
        gains = scaled_pd_gains(pd["kp_paper"], pd["kd_paper"], inertia, couple, j_p, u_p)
    pw = c["pwpf"]
    pwpf = PWPFParameters(k_m=pw["k_m"], tau_m=pw["tau_m_s"], u_on=pw["u_on"],
                          u_off=pw["u_off"], u_m=1.0)
    seq, modes = rig_csvs_sequence(rig, c["csvs"])
    pz = c["piezo"]
    channels = _int_list(pz["channels"], "piezo.channels")
    if len(set(channels)) != len(channels):
        raise ValueError(f"piezo.channels: expected distinct channels, got {channels}")
    weights = OPPFWeights(voltage_weight=pz["voltage_weight"], min_margin=pz["min_margin"])
    designs = {ch: design_oppf(rig_ppf_design_model(rig, ch, pz["design_modes"]), weights)
               for ch in channels}
    pa = rig.section("piezo_amplifier")
    caps = [g.capacitance_f for g in rig.piezo_gains] + [0.0, 0.0]
    # the amplifier trips when C dV/dt exceeds its current limit: stay at 90 % of it
    max_step = tuple(0.9 * pa["max_current_a"] * dt_s / cap if cap > 0 else math.inf
                     for cap in caps[:2])
    freqs, _, _ = hub_free_modes_with_damping(rig)
    open_loop = linear_closed_loop(rig, gains.kp_n_m_per_rad, gains.kd_n_m_s_per_rad, {})
    closed = linear_closed_loop(rig, gains.kp_n_m_per_rad, gains.kd_n_m_s_per_rad, designs)
    report = {
        "hub_free_freqs_rad_s": freqs.tolist(),
        "damping_pd_only": modal_damping_of(open_loop, freqs),
        "damping_with_ppf": modal_damping_of(closed, freqs),
        "max_real_eig_pd_only": float(np.max(np.linalg.eigvals(open_loop).real)),
        "max_real_eig_with_ppf": float(np.max(np.linalg.eigvals(closed).real)),
        "quasi_static_energy_ratio": quasi_static_energy_ratio(rig, designs),
    }
    if report["max_real_eig_with_ppf"] >= 0:
        raise ValueError(f"piezo.channels {channels}: the PPF banks designed one channel at a "
                         "time destabilise the combined linear loop (max Re(eig) "
                         f"{report['max_real_eig_with_ppf']:.3g} 1/s)")
    min_pulse = tv["min_on_time_s"] if c["min_pulse_s"] < 0 else c["min_pulse_s"]
    return ThrusterSlewController(
        angle_rad=math.radians(c["angle_deg"]), start_s=c["start_s"], gains=gains,
        couple_n_m=couple, pwpf=pwpf, dt_s=dt_s, min_pulse_s=min_pulse, csvs=seq,
        csvs_modes=modes, oppf=designs, voltage_limit_v=pa["max_voltage_v"],
        max_step_v=(max_step[0], max_step[1]), closed_loop=report)


CONTROLLER_TYPES = {"thruster_pd_pwpf": (THRUSTER_SLEW_SCHEMA, build_thruster_slew)}
