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

**Half couple and other fractions.** The valves are on/off (0 or +-T), with a 10 ms minimum
on-time and equal opening and closing delays. The nearest they allow to a level of a fraction
``duty`` in (0, 1) of T (T/2 in the two-level designs; also the levels of ``extra_zv_modes``)
is pulse-width modulation: within a segment of n ticks at that level, round(duty x n) ticks of
full couple (the segment's impulse, to half a tick) in pulses of at least the minimum on-time,
about one per ``pwm_period_s`` (20 ms by default: at 50 % 10 ms pulses, the minimum on-time;
at lower duties fewer, since no pulse is shorter than 10 ms), leftover on-ticks spread
symmetrically over the pulses, and each pulse centred in its share of the segment, the shares
in proportion to the pulses' widths, so the segment's time centroid is kept (to half a tick;
until 2026-11-22 the shares were equal, which moved it by up to 0.8 tick at 50 % and by
several ticks at low duties with two unequal pulses). At 50 % the ripple is at 50 Hz, 8.5
times the beam's third mode (5.9 Hz). Every switch time is rounded to the tick; equal
open/close delays shift every edge alike, so pulse widths reach the hub unchanged. A segment
whose round(duty x n) is not zero but less than one minimum pulse cannot be made (ValueError).

**``extra_zv_modes``** (default none): 1-based numbers of run-file modes (e.g. ``[3]``) for
which the designed sequence is afterwards convolved with a damped ZV shaper (impulses
1/(1+K), K/(1+K) half a damped period apart, K = exp(-zeta pi / sqrt(1 - zeta^2)); for the
rig's mode 3 0.539 / 0.461, 0.085 s): every switch becomes two smaller ones, the profile
gains intermediate levels (0.23 / 0.27 of T where a half step is split, 0.46 / 0.54 where a
full one is, -0.04 where T/2 reverses to -T/2, 0.73 / 0.77 where the copies of two switches
less than 0.085 s apart overlap), the angle and zero final rate are kept, the manoeuvre is
0.085 s longer, V_d at that mode is zero for the continuous profile and at the other modes
the design's times |a_1 exp(-s T_d/2) + a_2| < 1. Every intermediate level is made by PWM of
its duty. A level can last too short for one pulse (LHHL: -0.73 of T for 10 ms; HLLH: -0.04
for 85 ms); such a segment is modulated together with its neighbour of the same sign and a
fractional level (the pulses at the centroids of their shares of the pair's impulse), else
the schedule is refused (a ZV-shaped bang-bang: -0.08 of T for 0.085 s between two full
segments). The valves do not keep the cancellation exactly: an 85 ms level of 0.23 T is two
10 ms pulses 43 ms apart, only four times mode 3's frequency, which alone leaves about 4 % of
the bang-bang's mode 3; the valve schedules leave 2-11 % of it (docs/shaped_rig.md, "ZV for
mode 3 on the valves").

The valve direction of every tick is computed when the controller is built (no state).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Any

import numpy as np
from scipy.optimize import minimize

from harness.controllers.shaped_wheel_slew import (
    Mode,
    ScheduledSlew,
    TickSchedule,
    parse_modes,
)
from harness.shaping.impulse_shapers import ImpulseSequence, convolve, zv
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
    # modes whose ZV shaper the sequence was convolved with afterwards (``with_extra_zv``)
    zv_modes: tuple[Mode, ...] = ()


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
    """The paper's (undamped, symmetric) design: switch times and amplitudes (pure).

    Cached: a ``paper`` profile and the ``damped`` one of the same slew (whose homotopy
    starts from it) need the same design; it is computed once per process."""
    return _paper_design_cached(kind.upper(), float(angle), float(inertia), float(torque),
                                tuple(modes), float(vmax))


@lru_cache(maxsize=64)
def _paper_design_cached(kind: str, angle: float, inertia: float, torque: float,
                         modes: tuple[Mode, ...], vmax: float) -> tuple[tuple[float, ...],
                                                                       tuple[float, ...]]:
    d = design_two_amplitude(kind, inertia_kg_m2=inertia, torque_n_m=torque,
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
    # imported here: scipy.stats is a quarter of a harness process's start
    from scipy.stats import qmc

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


def with_extra_zv(design: TwoLevelDesign, zv_modes: Sequence[Mode], *, angle_rad: float,
                  inertia_kg_m2: float, torque_n_m: float) -> TwoLevelDesign:
    """``design``'s step sequence convolved with a damped ZV shaper (two impulses 1/(1+K),
    K/(1+K), half a damped period apart) for each of ``zv_modes`` (pure).

    Every switch becomes two smaller ones, so the profile gains intermediate levels; the
    angle and the zero final rate are kept (the shaper's gain is 1), the manoeuvre is longer
    by the shapers' spans, and the residual at the design modes is the design's times
    |a_1 exp(-s T_d/2) + a_2| < 1 each. V_d fields are recomputed for the longer sequence."""
    if not zv_modes:
        return design
    seq = ImpulseSequence(np.asarray(design.times_s), np.asarray(design.amplitudes))
    for m in zv_modes:
        seq = convolve(seq, zv(m.omega_rad_s, m.damping_ratio))
    out = _finish(design.profile, design.design, seq.times_s, seq.amplitudes, design.modes,
                  design.vmax_percent, inertia_kg_m2, torque_n_m, angle_rad,
                  (design.n_starts, design.n_feasible, design.n_agree))
    return replace(out, zv_modes=tuple(zv_modes))


# --------------------------------------------------------------------------- valves


def _share_centres(k0: int, blocks: Sequence[tuple[int, float]],
                   widths: np.ndarray) -> np.ndarray:
    """Centre (in ticks) of each pulse of ``widths`` in a run of consecutive segments
    ``blocks`` = [(ticks, duty), ...] from tick ``k0``: the run's wanted impulse is cut into
    shares in proportion to the pulses' widths, and each pulse sits at the centroid of its
    share (one segment: the middle of its share of the time), so that the pulses' centroid is
    the run's, before rounding to ticks."""
    frac = np.concatenate([[0.0], np.cumsum(widths)]) / float(np.sum(widths))
    if len(blocks) == 1:
        n = blocks[0][0]
        return k0 + n * (frac[:-1] + frac[1:]) / 2
    x = np.concatenate([[0.0], np.cumsum([b[0] for b in blocks])])
    duty = np.array([b[1] for b in blocks])
    f = np.concatenate([[0.0], np.cumsum(duty * np.diff(x))])  # wanted impulse up to x
    out = np.empty(len(widths))
    for j in range(len(widths)):
        a, b = frac[j] * f[-1], frac[j + 1] * f[-1]
        lo, hi = np.clip(a, f[:-1], f[1:]), np.clip(b, f[:-1], f[1:])
        mass = hi - lo
        mid = x[:-1] + ((lo + hi) / 2 - f[:-1]) / duty
        out[j] = k0 + float(np.sum(mass * mid) / np.sum(mass))
    return out


def _pwm(out: np.ndarray, k0: int, blocks: Sequence[tuple[int, float]], sign: int,
         min_on: int, dt_s: float, pwm_period_s: float) -> None:
    """Pulse-width modulate consecutive segments ``blocks`` [(ticks, duty), ...] from tick k0:
    round(sum duty x ticks) on-ticks in pulses of at least ``min_on`` ticks, about one per
    ``pwm_period_s``, each centred in its share (``_share_centres``)."""
    n = sum(b[0] for b in blocks)
    n_on = int(round(sum(b[0] * b[1] for b in blocks)))
    if n_on == 0:
        return
    n_pulses = min(max(1, int(round(n * dt_s / pwm_period_s))), n_on // min_on)
    widths = np.full(n_pulses, n_on // n_pulses)
    extra = n_on - int(widths.sum())
    # the leftover ticks go to pulses spread symmetrically over the segment (all at the
    # front would move its time centroid by up to half a pulse period)
    widths[((np.arange(extra) + 0.5) * n_pulses / max(extra, 1)).astype(int)] += 1
    starts = [int(math.floor(c - w / 2 + 0.5))
              for c, w in zip(_share_centres(k0, blocks, widths), widths, strict=True)]
    # a safety net: every share is at least as long as its pulse (duty <= 1), so only the
    # rounding could make neighbours overlap or leave the run; it would push them apart,
    # keeping every on-tick (it moves none in the run files' schedules)
    for j in range(n_pulses):
        starts[j] = max(starts[j], k0 if j == 0 else starts[j - 1] + int(widths[j - 1]))
    for j in reversed(range(n_pulses)):
        end = k0 + n if j == n_pulses - 1 else starts[j + 1]
        starts[j] = min(starts[j], end - int(widths[j]))
    for s, w in zip(starts, widths, strict=True):
        out[s:s + w] = sign


def valve_schedule(times_s: Sequence[float], amplitudes: Sequence[float], dt_s: float,
                   min_on_s: float, pwm_period_s: float,
                   merge_short: bool = False) -> np.ndarray:
    """Valve direction (+1, -1, 0) of every tick from the first switch to the last.

    Switch times are rounded to ticks. Full-couple segments are on for every tick; a segment
    at a fraction ``duty`` in (0, 1) of the couple is pulse-width modulated (module
    docstring): round(duty x n) of its n ticks on (its impulse to half a tick), in pulses of
    at least the minimum on-time, about one per ``pwm_period_s``, each centred in its share
    of the segment (its time centroid to about half a tick). A segment whose on-ticks are
    fewer than one minimum pulse (but not zero) cannot be made: ValueError, or with
    ``merge_short`` it is modulated together with its neighbour of the same sign and a
    fractional level (the one with the larger impulse; each pulse then sits at the centroid
    of its share of the pair's impulse, so impulse and centroid are still kept).
    Raises ValueError for a pulse the valves cannot make."""
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
    # runs of modulated segments: [first tick, sign, [(ticks, duty), ...]]
    runs: list[list[Any]] = []
    for k0, k1, level in zip(ticks[:-1], ticks[1:], levels, strict=True):
        n = int(k1 - k0)
        mag = abs(level)
        if mag < 1e-9 or n == 0:
            continue
        if mag > 1.0 + 1e-9:
            raise ValueError(f"amplitudes: torque level {level:g} exceeds the couple")
        sign = 1 if level > 0 else -1
        if abs(mag - 1.0) < 1e-9:
            if n < min_on:
                raise ValueError(f"a full-couple pulse of {n * dt_s:.4f} s is shorter than "
                                 f"the valves' minimum on-time {min_on_s} s")
            out[k0:k1] = sign
            continue
        runs.append([int(k0), sign, [(n, float(mag))]])

    def on_ticks(r: list[Any]) -> int:
        return int(round(sum(n * d for n, d in r[2])))

    def short(r: list[Any]) -> bool:
        return 0 < on_ticks(r) < min_on

    def end(r: list[Any]) -> int:
        return int(r[0] + sum(n for n, _ in r[2]))

    while any(short(r) for r in runs):
        i = next(i for i, r in enumerate(runs) if short(r))
        r = runs[i]
        n = sum(b[0] for b in r[2])
        level = r[1] * sum(b[0] * b[1] for b in r[2]) / n
        if not merge_short:
            raise ValueError(
                f"a segment at {level:.3g} of the couple over {n * dt_s:.4f} s (from "
                f"{r[0] * dt_s:.4f} s) needs {on_ticks(r)} on-tick(s), fewer than one pulse "
                f"of the valves' minimum on-time {min_on_s} s")
        nb = [j for j in (i - 1, i + 1) if 0 <= j < len(runs) and runs[j][1] == r[1]
              and (end(runs[j]) == r[0] if j < i else end(r) == runs[j][0])]
        if not nb:
            raise ValueError(
                f"a segment at {level:.3g} of the couple over {n * dt_s:.4f} s (from "
                f"{r[0] * dt_s:.4f} s) needs {on_ticks(r)} on-tick(s), fewer than one pulse "
                f"of the valves' minimum on-time {min_on_s} s, and has no neighbouring "
                "fractional segment of the same sign to be modulated with")
        j = max(nb, key=lambda j: sum(n * d for n, d in runs[j][2]))
        a, b = (runs[j], r) if j < i else (r, runs[j])
        runs[min(i, j)] = [a[0], r[1], a[2] + b[2]]
        del runs[max(i, j)]
    for k0, sign, blocks in runs:
        _pwm(out, k0, blocks, sign, min_on, dt_s, pwm_period_s)
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
        if design.profile == "bang_bang" and not design.zv_modes:
            n = max(1, round(times[1] / dt_s))  # both halves the same whole number of ticks
            times = (0.0, n * dt_s, 2 * n * dt_s)
        try:
            self.directions = valve_schedule(times, design.amplitudes, dt_s, min_on_s,
                                             pwm_period_s, merge_short=bool(design.zv_modes))
        except ValueError as exc:
            if not design.zv_modes:
                raise
            raise ValueError(f"extra_zv_modes: the valves cannot make the ZV-shaped profile: "
                             f"{exc}") from exc
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
    "extra_zv_modes": Field("any", default=None),
    "n_starts": Field("int", default=128, minimum=1),
    "seed": Field("int", default=0, minimum=0),
}


def parse_extra_zv_modes(raw: Any, modes: Sequence[Mode]) -> tuple[Mode, ...]:
    """The modes named by ``extra_zv_modes`` (1-based numbers into the run file's ``modes``)."""
    if raw is None or (isinstance(raw, list) and not raw):
        return ()
    if not modes:
        raise ValueError(f"extra_zv_modes: {raw!r} needs the run file's modes, none given")
    ok = (isinstance(raw, list)
          and all(isinstance(i, int) and not isinstance(i, bool) for i in raw)
          and len(set(raw)) == len(raw) and all(1 <= i <= len(modes) for i in raw))
    if not ok:
        raise ValueError(f"extra_zv_modes: expected a list of distinct mode numbers in "
                         f"1..{len(modes)} (the run file's modes, in their order), got {raw!r}")
    return tuple(modes[i - 1] for i in raw)


def build_thruster_two_level(c: dict[str, Any], rig: RigConfig,
                             dt_s: float) -> ThrusterTwoLevelSlew:
    tv = rig.section("thruster_valves")
    modes: tuple[Mode, ...] = ()
    if c["profile"] != "bang_bang" or c["modes"] is not None:
        modes = parse_modes(c["modes"])
    zv_modes = parse_extra_zv_modes(c["extra_zv_modes"], modes)
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
    design = with_extra_zv(design, zv_modes, angle_rad=math.radians(c["angle_deg"]),
                           inertia_kg_m2=inertia, torque_n_m=tv["couple_n_m"])
    return ThrusterTwoLevelSlew(design, tv["couple_n_m"], inertia, c["start_s"], dt_s,
                                tv["min_on_time_s"], c["pwm_period_s"])


CONTROLLER_TYPES = {"thruster_two_level": (THRUSTER_TWO_LEVEL_SCHEMA, build_thruster_two_level)}
