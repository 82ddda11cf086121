"""Open-loop thruster slews: bang-bang, or two-level LHHL / HLLH (Parman 2022) on the valves.

Profiles, in units of the valves' couple T (``thruster_valves.couple_n_m``):

* ``bang_bang``: +T for tau, -T for tau, tau = sqrt(theta J / T) rounded to whole ticks.
* ``lhhl`` / ``hllh``: the eight-switch sequences of ``harness.shaping.two_amplitude`` (low
  level T/2), the shortest meeting V(w_k) <= ``vmax_percent`` at every mode the run file
  gives (identified from a free decay), against the bang-bang of the same angle;
  ``design_modes: N`` constrains only the first N of them (listed by frequency: the rest
  stay listed for the residual analysis; docs/shaped_rig.md says why the rig's third mode
  is not designed for).
  ``design: paper`` is the paper's design as published: undamped modes (eq 9), symmetric
  switch times (eq 7), solved by ``design_two_amplitude``. ``design: damped`` (default) keeps
  the amplitude pattern but lets the seven gaps between switches vary freely and requires the
  *damped* residual at each mode, with the identified damping ratio zeta,

      V_d(w, zeta) = |sum_i A_i exp(-s u_i)| / |1 - 2 exp(-s tau) + exp(-2 s tau)|,
      s = zeta w + j w sqrt(1 - zeta^2),  u_i = t_8 - t_i,

  i.e. the vibration left at the end of the manoeuvre over that of the bang-bang at its own
  end (eq 9-10 with damping). The rig's modes are damped 5-7 %, and over a slew of t_8 ~ 10 s
  the early switches' vibration has decayed by exp(-zeta w t_8) before the late ones act, so
  the undamped, symmetric solution cancels little on the rig (see docs/shaped_rig.md). The
  damped problem (minimise t_8 subject to the angle, zero final rate and the V_d limits) is
  solved by SLSQP from the paper's optimum and from scrambled Sobol starts on the angle
  manifold; the report says how many starts reached the returned t_8.

**Half couple.** The valves are on/off (0 or +-T), with a 10 ms minimum on-time and equal
opening and closing delays. The nearest they allow to T/2 is pulse-width modulation at 50 %
duty: within a half-level segment of n ticks, round(n/2) ticks of full couple (the segment's
impulse, to half a tick) in pulses spread evenly over the segment (about one per
``pwm_period_s``, 20 ms by default: 10 ms pulses, the minimum on-time), each centred in its
share of the segment so the segment's impulse and time centroid are kept. The ripple is at
50 Hz, 8.5 times the beam's third mode (5.9 Hz). Every switch time is rounded to the tick;
equal open/close delays shift every edge alike, so pulse widths reach the hub unchanged.

The valve direction of every tick is computed when the controller is built (no state).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.stats import qmc

from harness.controllers.shaped_wheel_slew import (
    Mode,
    ScheduledSlew,
    TickSchedule,
    parse_modes,
)
from harness.shaping.two_amplitude import (
    ModeConstraint,
    design_two_amplitude,
    evaluate_sequence,
    shaper_amplitudes,
)
from harness.state import RigCommand, RigState
from rig_models.rig_file import RigConfig
from rig_models.schema import Field

PROFILES = ("bang_bang", "lhhl", "hllh")
DESIGNS = ("damped", "paper")


# --------------------------------------------------------------------------- residuals


def _s(mode: Mode) -> complex:
    z = mode.damping_ratio
    return complex(z * mode.omega_rad_s, mode.omega_rad_s * math.sqrt(1.0 - z * z))


def end_residual(times_s: Sequence[float], amplitudes: Sequence[float],
                 modes: Sequence[Mode]) -> np.ndarray:
    """|sum_i A_i exp(-s u_i)| per mode: the vibration left at the last switch (units of one
    step of amplitude 1 applied then)."""
    t = np.asarray(times_s, dtype=float)
    amp = np.asarray(amplitudes, dtype=float)
    u = t[-1] - t
    return np.array([abs(np.sum(amp * np.exp(-_s(m) * u))) for m in modes])


def damped_residual_percent(times_s: Sequence[float], amplitudes: Sequence[float],
                            modes: Sequence[Mode], bang_bang_tau_s: float) -> np.ndarray:
    """V_d (percent) of a step sequence at each mode against the bang-bang of half-time
    ``bang_bang_tau_s`` (module docstring)."""
    tau = bang_bang_tau_s
    ref = end_residual([0.0, tau, 2 * tau], [1.0, -2.0, 1.0], modes)
    return 100.0 * end_residual(times_s, amplitudes, modes) / ref


# --------------------------------------------------------------------------- designs


@dataclass(frozen=True)
class TwoLevelDesign:
    """Switch times (s, from the start) and amplitudes (units of the couple, signed)."""

    profile: str
    design: str  # "bang-bang", "paper" (undamped, symmetric) or "damped"
    times_s: tuple[float, ...]
    amplitudes: tuple[float, ...]
    modes: tuple[Mode, ...]
    vmax_percent: float | None
    damped_residual_percent: tuple[float, ...]  # V_d at each mode (with its damping)
    undamped_residual_percent: tuple[float, ...]  # eq 9 at each mode's frequency
    t8_s: float
    fuel_on_time_s: float
    impulse_n_m_s: float
    bang_bang_duration_s: float
    n_starts: int = 0
    n_feasible: int = 0
    n_agree: int = 0


def _finish(profile: str, design: str, times: Sequence[float], amps: Sequence[float],
            modes: Sequence[Mode], vmax: float | None, inertia: float, torque: float,
            angle: float, starts: tuple[int, int, int] = (0, 0, 0)) -> TwoLevelDesign:
    rep = evaluate_sequence(times, amps, inertia_kg_m2=inertia, torque_n_m=torque,
                            freqs_rad_s=[m.omega_rad_s for m in modes],
                            reference_angle_rad=angle)
    tau = rep.bang_bang_duration_s / 2
    vd = damped_residual_percent(times, amps, modes, tau) if modes else np.zeros(0)
    return TwoLevelDesign(profile, design, tuple(float(t) for t in times),
                          tuple(float(a) for a in amps), tuple(modes), vmax,
                          tuple(float(v) for v in vd), rep.residual_percent, rep.t8_s,
                          rep.fuel_on_time_s, rep.impulse_n_m_s, rep.bang_bang_duration_s,
                          *starts)


def design_bang_bang(angle_rad: float, inertia_kg_m2: float, torque_n_m: float,
                     modes: Sequence[Mode] = ()) -> TwoLevelDesign:
    tau = math.sqrt(abs(angle_rad) * inertia_kg_m2 / torque_n_m)
    sign = math.copysign(1.0, angle_rad)
    return _finish("bang_bang", "bang-bang", (0.0, tau, 2 * tau),
                   (sign, -2 * sign, sign), modes, None, inertia_kg_m2, torque_n_m, angle_rad)


def _paper_design(kind: str, angle: float, inertia: float, torque: float,
                  modes: Sequence[Mode], vmax: float) -> tuple[tuple[float, ...],
                                                               tuple[float, ...]]:
    d = design_two_amplitude(kind.upper(), inertia_kg_m2=inertia, torque_n_m=torque,
                             angle_rad=angle,
                             modes=[ModeConstraint(m.omega_rad_s, vmax) for m in modes],
                             n_starts=64, grid_points=200)
    return d.times_s, d.amplitudes


class _DampedProblem:
    """Minimise t_8 = sum(g) over the seven gaps g between switches, subject to the angle, a
    zero final rate, V_d(w_k) <= vmax at every mode and the shortest segments."""

    def __init__(self, kind: str, theta: float, accel: float, modes: Sequence[Mode],
                 vmax: float, min_full_s: float, min_half_s: float,
                 margin: float = 1e-3) -> None:
        self.amps = np.array(shaper_amplitudes(kind.upper()))  # positive angle
        self.a, self.theta = accel, theta
        self.tau = math.sqrt(theta / accel)
        levels = np.cumsum(self.amps)[:-1]
        self.lower = np.where(np.abs(np.abs(levels) - 1) < 1e-9, min_full_s,
                              np.where(np.abs(levels) > 1e-9, min_half_s, 0.0))
        self.upper_i = np.triu(np.ones((8, 7)))  # u_i = t_8 - t_i = sum_{j >= i} g_j
        self.s = np.array([_s(m) for m in modes])
        tau = self.tau
        ref = end_residual([0.0, tau, 2 * tau], [1.0, -2.0, 1.0], modes)
        self.tol2 = ((1 - margin) * vmax / 100.0 * ref) ** 2

    def eq(self, g: np.ndarray) -> np.ndarray:
        u = self.upper_i @ g
        return np.array([(self.a * np.sum(self.amps * u**2) / 2 - self.theta) / self.theta,
                         np.sum(self.amps * u) / self.tau])

    def eq_jac(self, g: np.ndarray) -> np.ndarray:
        u = self.upper_i @ g
        return np.vstack([self.a * (self.amps * u) @ self.upper_i / self.theta,
                          self.amps @ self.upper_i / self.tau])

    def _terms(self, g: np.ndarray) -> np.ndarray:  # (modes, 8)
        return self.amps[None, :] * np.exp(-self.s[:, None] * (self.upper_i @ g)[None, :])

    def ineq(self, g: np.ndarray) -> np.ndarray:
        return 1.0 - np.abs(self._terms(g).sum(axis=1)) ** 2 / self.tol2

    def ineq_jac(self, g: np.ndarray) -> np.ndarray:
        tm = self._terms(g)
        d_total = (-self.s[:, None] * tm) @ self.upper_i  # d S_k / d g
        return -2 * (np.conj(tm.sum(axis=1))[:, None] * d_total).real / self.tol2[:, None]

    def feasible(self, g: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(g)) and np.all(np.abs(self.eq(g)) < 1e-8)
                    and np.all(self.ineq(g) >= -1e-9) and np.all(g >= self.lower - 1e-12))

    def on_angle(self, g: np.ndarray) -> np.ndarray:
        """g scaled onto the angle manifold (the angle grows as g^2)."""
        u = self.upper_i @ g
        k = math.sqrt(self.theta / max(self.a * np.sum(self.amps * u**2) / 2, 1e-300))
        return np.maximum(g * k, self.lower)

    def solve(self, g0: np.ndarray) -> np.ndarray:
        tau = self.tau
        with np.errstate(all="ignore"):
            res = minimize(lambda g: g.sum() / tau, g0, jac=lambda g: np.ones(7) / tau,
                           method="SLSQP", bounds=[(lo, 20 * tau) for lo in self.lower],
                           constraints=[{"type": "eq", "fun": self.eq, "jac": self.eq_jac},
                                        {"type": "ineq", "fun": self.ineq,
                                         "jac": self.ineq_jac}],
                           options={"maxiter": 400, "ftol": 1e-12})
        return np.asarray(res.x, dtype=float)


def _damped_search(kind: str, angle: float, inertia: float, torque: float,
                   modes: Sequence[Mode], vmax: float, min_full_s: float, min_half_s: float,
                   n_starts: int, seed: int, n_homotopy: int = 8
                   ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Multi-start SLSQP. Starts: the paper's undamped optimum carried to the identified
    damping in ``n_homotopy`` steps (damping ratios scaled 1/n ... 1, each solve starting
    from the last), and ``n_starts`` scrambled Sobol points scaled onto the angle."""
    theta, accel = abs(angle), torque / inertia
    prob = _DampedProblem(kind, theta, accel, modes, vmax, min_full_s, min_half_s)
    found: list[np.ndarray] = []
    n_tried = 0
    try:
        t_paper, _ = _paper_design(kind, theta, inertia, torque, modes, vmax)
        g = np.maximum(np.diff(t_paper), prob.lower)
        for f in np.linspace(0.0, 1.0, n_homotopy + 1)[1:]:
            step = _DampedProblem(kind, theta, accel,
                                  [Mode(m.omega_rad_s, m.damping_ratio * f) for m in modes],
                                  vmax, min_full_s, min_half_s)
            g = step.solve(step.on_angle(g))
            if not step.feasible(g):
                break
        n_tried += 1
        if prob.feasible(g):
            found.append(g)
    except ValueError:  # no undamped design: the Sobol starts remain
        pass
    base2 = max(0, math.ceil(math.log2(max(n_starts, 1))))
    for r in qmc.Sobol(7, scramble=True, seed=seed).random_base2(base2)[:n_starts]:
        g = prob.solve(prob.on_angle(prob.lower + r * 2 * prob.tau))
        n_tried += 1
        if prob.feasible(g):
            found.append(g)
    if not found:
        raise ValueError(f"vmax_percent {vmax}: no feasible damped {kind.upper()} sequence "
                         "found; loosen vmax_percent or add starts")
    found.sort(key=lambda g: g.sum())
    best = found[0]
    n_agree = sum(1 for g in found if g.sum() - best.sum() <= 1e-3)
    return np.concatenate([[0.0], np.cumsum(best)]), prob.amps, (n_tried, len(found), n_agree)


@lru_cache(maxsize=64)
def _design_cached(profile: str, design: str, angle: float, inertia: float, torque: float,
                   modes: tuple[Mode, ...], vmax: float, min_full_s: float, min_half_s: float,
                   n_starts: int, seed: int) -> TwoLevelDesign:
    if profile == "bang_bang":
        return design_bang_bang(angle, inertia, torque, modes)
    if not modes:
        raise ValueError(f"modes: profile {profile} needs at least one mode")
    sign = math.copysign(1.0, angle)
    if design == "paper":
        times, amps = _paper_design(profile, angle, inertia, torque, modes, vmax)
        return _finish(profile, "paper", times, amps, modes, vmax, inertia, torque, angle)
    times, amps, starts = _damped_search(profile, angle, inertia, torque, modes, vmax,
                                         min_full_s, min_half_s, n_starts, seed)
    return _finish(profile, "damped", times, sign * amps, modes, vmax, inertia, torque, angle,
                   starts)


def design_profile(profile: str, *, angle_rad: float, inertia_kg_m2: float, torque_n_m: float,
                   modes: Sequence[Mode] = (), vmax_percent: float = 1.0,
                   design: str = "damped", min_full_s: float = 0.01, min_half_s: float = 0.04,
                   n_starts: int = 128, seed: int = 0) -> TwoLevelDesign:
    """The switch sequence of ``profile`` (``PROFILES``) for a rest-to-rest slew (pure; cached).

    ``min_full_s`` / ``min_half_s``: shortest full-couple / half-couple segment the damped
    design may use (the valves' minimum on-time; two PWM periods)."""
    if profile not in PROFILES:
        raise ValueError(f"profile: expected one of {PROFILES}, got {profile!r}")
    if design not in DESIGNS:
        raise ValueError(f"design: expected one of {DESIGNS}, got {design!r}")
    if not (math.isfinite(angle_rad) and angle_rad != 0):
        raise ValueError(f"angle_deg: expected a non-zero angle, got {angle_rad!r} rad")
    for name, v in (("inertia_kg_m2", inertia_kg_m2), ("torque_n_m", torque_n_m),
                    ("vmax_percent", vmax_percent)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected a value > 0, got {v!r}")
    if n_starts < 1:
        raise ValueError(f"n_starts: expected >= 1, got {n_starts!r}")
    return _design_cached(profile, design, float(angle_rad), float(inertia_kg_m2),
                          float(torque_n_m), tuple(modes), float(vmax_percent),
                          float(min_full_s), float(min_half_s), int(n_starts), int(seed))


# --------------------------------------------------------------------------- valves


def valve_schedule(times_s: Sequence[float], amplitudes: Sequence[float], dt_s: float,
                   min_on_s: float, pwm_period_s: float) -> np.ndarray:
    """Valve direction (+1, -1, 0) of every tick from the first switch to the last.

    Full-couple segments are on for every tick; half-couple segments are pulse-width
    modulated (module docstring). Raises ValueError for a pulse the valves cannot make."""
    if not dt_s > 0:
        raise ValueError(f"dt_s: expected > 0 s, got {dt_s}")
    if not pwm_period_s >= 2 * min_on_s:
        raise ValueError(f"pwm_period_s: expected >= 2 x the valves' minimum on-time "
                         f"({2 * min_on_s:g} s), got {pwm_period_s}")
    ticks = np.rint(np.asarray(times_s, dtype=float) / dt_s).astype(int)
    ticks -= ticks[0]
    levels = np.cumsum(np.asarray(amplitudes, dtype=float))[:-1]
    min_on = max(1, math.ceil(min_on_s / dt_s - 1e-9))
    out = np.zeros(int(ticks[-1]), dtype=np.int8)
    for k0, k1, level in zip(ticks[:-1], ticks[1:], levels, strict=True):
        n = int(k1 - k0)
        mag = abs(level)
        if mag < 1e-9 or n == 0:
            continue
        sign = 1 if level > 0 else -1
        if abs(mag - 1.0) < 1e-9:
            if n < min_on:
                raise ValueError(f"a full-couple pulse of {n * dt_s:.4f} s is shorter than "
                                 f"the valves' minimum on-time {min_on_s} s")
            out[k0:k1] = sign
            continue
        if abs(mag - 0.5) > 1e-9:
            raise ValueError(f"amplitudes: torque level {level:g} is neither 0, 1/2 nor 1 "
                             "couple")
        n_on = int(round(n / 2))
        n_pulses = min(max(1, int(round(n * dt_s / pwm_period_s))), n_on // min_on)
        if n_pulses < 1:
            raise ValueError(f"a half-couple segment of {n * dt_s:.4f} s is too short for "
                             f"one {min_on_s} s valve pulse")
        widths = np.full(n_pulses, n_on // n_pulses)
        extra = n_on - int(widths.sum())
        # the leftover ticks go to pulses spread symmetrically over the segment (all at the
        # front would move its time centroid by up to half a pulse period)
        widths[((np.arange(extra) + 0.5) * n_pulses / max(extra, 1)).astype(int)] += 1
        for j, w in enumerate(widths):
            centre = k0 + (j + 0.5) * n / n_pulses
            start = int(math.floor(centre - w / 2 + 0.5))
            out[start:start + w] = sign
    return out


def valve_usage(directions: np.ndarray, dt_s: float, couple_n_m: float) -> dict[str, float]:
    """Firings (openings, a reversal counts as one), on-time and impulse of a schedule."""
    d = np.asarray(directions)
    prev = np.r_[0, d[:-1]]
    firings = int(np.sum((d != 0) & (d != prev)))
    on = float(np.count_nonzero(d) * dt_s)
    return {"firings": firings, "on_time_s": on, "impulse_n_m_s": on * couple_n_m}


class ThrusterTwoLevelSlew(ScheduledSlew):
    """Open-loop valve sequence of a two-level (or bang-bang) design."""

    def __init__(self, design: TwoLevelDesign, couple_n_m: float, inertia_kg_m2: float,
                 start_s: float, dt_s: float, min_on_s: float, pwm_period_s: float) -> None:
        if not start_s >= 0:
            raise ValueError(f"start_s: expected a time >= 0 s, got {start_s}")
        self.design = design
        times = design.times_s
        if design.profile == "bang_bang":  # both halves the same whole number of ticks
            n = max(1, round(times[1] / dt_s))
            times = (0.0, n * dt_s, 2 * n * dt_s)
        self.directions = valve_schedule(times, design.amplitudes, dt_s, min_on_s,
                                         pwm_period_s)
        self.usage = valve_usage(self.directions, dt_s, couple_n_m)
        self.schedule = TickSchedule(self.directions, round(start_s / dt_s), dt_s,
                                     inertia_kg_m2, couple_n_m)

    def step(self, state: RigState) -> RigCommand:
        return RigCommand(valve_direction=int(self.schedule.at_tick(state.tick)))


THRUSTER_TWO_LEVEL_SCHEMA = {
    "type": Field("str", required=True),
    "profile": Field("str", required=True, choices=PROFILES),
    "angle_deg": Field("number", "deg", required=True),
    "start_s": Field("number", "s", default=1.0, minimum=0.0),
    "modes": Field("any", default=None),
    "vmax_percent": Field("number", "%", default=1.0, exclusive_minimum=0.0),
    "design": Field("str", default="damped", choices=DESIGNS),
    "pwm_period_s": Field("number", "s", default=0.02, exclusive_minimum=0.0),
    "design_modes": Field("int", default=None, minimum=1),
    "n_starts": Field("int", default=128, minimum=1),
    "seed": Field("int", default=0, minimum=0),
}


def build_thruster_two_level(c: dict[str, Any], rig: RigConfig,
                             dt_s: float) -> ThrusterTwoLevelSlew:
    tv = rig.section("thruster_valves")
    modes: tuple[Mode, ...] = ()
    if c["profile"] != "bang_bang" or c["modes"] is not None:
        modes = parse_modes(c["modes"])
    if c["design_modes"] is not None:
        if c["design_modes"] > len(modes):
            raise ValueError(f"design_modes {c['design_modes']}: only {len(modes)} modes given")
        modes = modes[: c["design_modes"]]
    inertia = rig.plant.inertia_kg_m2
    design = design_profile(c["profile"], angle_rad=math.radians(c["angle_deg"]),
                            inertia_kg_m2=inertia, torque_n_m=tv["couple_n_m"], modes=modes,
                            vmax_percent=c["vmax_percent"], design=c["design"],
                            min_full_s=tv["min_on_time_s"], min_half_s=2 * c["pwm_period_s"],
                            n_starts=c["n_starts"], seed=c["seed"])
    return ThrusterTwoLevelSlew(design, tv["couple_n_m"], inertia, c["start_s"], dt_s,
                                tv["min_on_time_s"], c["pwm_period_s"])


CONTROLLER_TYPES = {"thruster_two_level": (THRUSTER_TWO_LEVEL_SCHEMA, build_thruster_two_level)}
